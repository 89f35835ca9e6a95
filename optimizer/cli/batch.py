"""``shoha batch``: many saves scored, or many scenes optimized, into one results file."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from geometry.errors import InputError

from .common import Group, check_out, check_time_limit, emit, parse_origin, save_options


class _Bar:
    """A rich progress bar on stderr for a batch."""

    def __init__(self, label: str) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        self.bar = Progress(TextColumn(label), BarColumn(), MofNCompleteColumn(),
                            TextColumn("{task.fields[errors]} errors"), TimeRemainingColumn(),
                            console=Console(stderr=True))
        self.task: Any = None
        self.errors = 0

    def start(self, todo: int, skipped: int) -> None:
        if skipped:
            self.bar.console.print(f"{skipped} items already done; {todo} to run")
        self.task = self.bar.add_task("batch", total=todo, errors=0)
        self.bar.start()

    def __call__(self, done: int, total: int, row: dict[str, Any]) -> None:
        self.errors += row.get("status") != "ok"
        self.bar.update(self.task, completed=done, errors=self.errors)

    def close(self) -> None:
        if self.task is not None:  # a bar never started printed an empty line above a refusal
            self.bar.stop()


@click.group("batch", cls=Group)
def batch() -> None:
    """Many saves scored, or many optimizer runs, into one CSV or JSON Lines file.

    Each finished item is appended as one row at once; a re-run skips the
    items already in the file. Runs on a local process pool (--workers) or a
    Dask cluster (--scheduler).
    """

def _runner_options(f: Any) -> Any:
    f = click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")(f)
    f = click.option("--scheduler", default=None,
                     help="Address of a Dask scheduler (tcp://host:8786) to run on instead.")(f)
    f = click.option("--workers", type=click.IntRange(1, 1024), default=1, show_default=True,
                     help="Local worker processes.")(f)
    f = click.option("--out", required=True,
                     help="Results: .csv or .jsonl (appended; re-runs resume).")(f)
    return f

@batch.command("score")
@click.argument("saves", nargs=-1, required=True)
@click.option("--reference", required=True, help="The reference layout (shoha-layout/1).")
@save_options
@click.option("--scene", "scene_name", default=None, help="Scene, instead of each save's own.")
@click.option("--seconds", type=float, default=2.0, show_default=True,
              help="Simulated seconds of each stability settle.")
@click.option("--retry-errors", is_flag=True, help="Run again the items whose row is an error.")
@_runner_options
def batch_score(saves: tuple[str, ...], reference: str, source: str, block_type: str, origin: str,
                scene_name: str | None, seconds: float, retry_errors: bool, out: str, workers: int,
                scheduler: str | None, as_json: bool) -> None:
    """Score every save (files, folders of .json, or glob patterns) against one reference."""
    from geometry.layout import read_layout
    from optimizer.batch import (
        SCORE_COLUMNS,
        Item,
        RowFile,
        check_scheduler,
        expand_saves,
        run_batch,
        score_task,
        sha256_file,
    )
    from settle.base import MAX_SECONDS

    if not 0 < seconds <= MAX_SECONDS:
        raise InputError(f"--seconds {seconds}: must be more than 0 and at most {MAX_SECONDS:g}")
    check_scheduler(scheduler)
    rows = RowFile(check_out(out, (".csv", ".jsonl"), atomic=False), SCORE_COLUMNS)
    read_layout(reference).load_scene()  # a bad reference is bad usage, not 200 error rows
    ref_sha = sha256_file(reference)
    xyz = parse_origin(origin)
    paths = expand_saves(saves, exclude=(reference, out))
    shas = {p: sha256_file(p) for p in paths}
    for row in rows.read():
        if row.get("status") == "ok" and row.get("reference_sha256") not in ("", None, ref_sha):
            raise InputError(f"{out}: holds scores against another reference; use a new --out")

    def done(row: dict[str, Any]) -> bool:
        if retry_errors and row.get("status") != "ok":
            return False
        return row.get("save_sha256") == shas.get(str(row.get("item")))

    items = [Item(p, {"save": p, "reference": reference, "source": source, "block": block_type,
                      "origin": xyz, "scene": scene_name, "seconds": seconds}) for p in paths]
    bar = _Bar("scoring")
    try:
        summary = run_batch(items, score_task, rows, workers, scheduler, done=done, progress=bar,
                            on_start=bar.start)
    finally:
        bar.close()
    emit(summary.to_dict(), as_json,
          f"{summary.ran} saves scored ({summary.errors} errors), {summary.skipped} already done; "
          f"{summary.path}")

@batch.command("optimize")
@click.argument("scenes", nargs=-1, required=True)
@click.option("--seeds", default="0", show_default=True, help="Seeds: 0-9, 1,4,7 or 0-3,10.")
@click.option("--time-limit", type=float, default=None,
              help="Wall-clock seconds per run; default as shoha optimize's, by each scene's count.")
@click.option("--layouts", required=True, help="Folder for the layouts, SCENE-seedN.json.")
@_runner_options
def batch_optimize(scenes: tuple[str, ...], seeds: str, time_limit: float | None, layouts: str, out: str,
                   workers: int, scheduler: str | None, as_json: bool) -> None:
    """Optimize every scene with every seed; one row per run, layouts into a folder."""
    from geometry.scene import load_scene
    from optimizer.batch import (
        OPTIMIZE_COLUMNS,
        Item,
        RowFile,
        check_scheduler,
        optimize_task,
        parse_seeds,
        run_batch,
    )

    check_time_limit(time_limit)
    check_scheduler(scheduler)  # before the layouts' folder is made
    rows = RowFile(check_out(out, (".csv", ".jsonl"), atomic=False), OPTIMIZE_COLUMNS)
    folder = Path(layouts)
    if folder.exists() and not folder.is_dir():
        raise InputError(f"{layouts}: is a file, not a folder")
    seed_list = parse_seeds(seeds)
    for s in scenes:
        load_scene(s)  # a bad scene name is bad usage
    # Each run writes SCENE-seedN.json by the scene's stem: two scenes of one stem (a.toml and
    # x/a.toml, or one scene named twice) would write each other's layouts.
    stems: dict[str, str] = {}
    for s in scenes:
        if (other := stems.setdefault(Path(s).stem, s)) != s or scenes.count(s) > 1:
            raise InputError(f"{s}: its layouts would be written over those of {other} "
                             f"({Path(s).stem}-seedN.json); give each scene once, with its own name")
    items = [Item(f"{s}:seed{n}", {"scene": s, "seed": n, "time_limit": time_limit,
                                    "layouts": str(folder)}) for s in scenes for n in seed_list]
    bar = _Bar("optimizing")
    try:
        def start(todo: int, skipped: int) -> None:
            # Made once --out reads as this batch's and the scheduler answers: not before a refusal.
            folder.mkdir(parents=True, exist_ok=True)
            bar.start(todo, skipped)

        summary = run_batch(items, optimize_task, rows, workers, scheduler, progress=bar, on_start=start)
    finally:
        bar.close()
    emit(summary.to_dict(), as_json,
          f"{summary.ran} runs ({summary.errors} errors), {summary.skipped} already done; {summary.path}")
