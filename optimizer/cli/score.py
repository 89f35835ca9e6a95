"""``shoha score``, ``shoha batch`` and ``shoha render`` (CONTRACT.md, "CLI"; docs/scoring.md).

Registered on the ``shoha`` group by ``optimizer.cli._register_optional_commands``.
Every command takes ``--json`` and then prints one JSON object on stdout;
progress goes to stderr. Bad input exits with status 2, one line on stderr,
and no output file written.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import click

from geometry.errors import InputError
from optimizer.cli import _check_out, _emit, _parse_origin

_FROM = click.Choice(["auto", "layout", "unity"])


def _save_options(f: Any) -> Any:
    """The options that say how to read a save (as in ``shoha convert``)."""
    f = click.option("--origin", default="0,0,0", show_default=True,
                     help="Unity saves: world position X,Y,Z (m) of Unity's origin.")(f)
    f = click.option("--block", "block_type", default="shake-4t", show_default=True,
                     help="Unity saves: block type of saved blocks that name none.")(f)
    f = click.option("--from", "source", type=_FROM, default="auto", show_default=True,
                     help="Format of the save: shoha-layout/1, the simulator's Unity JSON, "
                          "or auto (told apart by content).")(f)
    return f


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
        self.bar.stop()


def register(cli: click.Group) -> None:
    """Add ``score``, ``batch`` and ``render`` to the ``shoha`` command group."""

    @cli.command("score")
    @click.argument("save")
    @click.option("--reference", required=True, help="The reference layout (shoha-layout/1).")
    @_save_options
    @click.option("--scene", "scene_name", default=None, help="Scene, instead of the save's own.")
    @click.option("--seconds", type=float, default=2.0, show_default=True,
                  help="Simulated seconds of the stability settle.")
    @click.option("--html", "html_out", default=None, help="Write the report: one self-contained HTML file.")
    @click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
    def score_cmd(save: str, reference: str, source: str, block_type: str, origin: str,
                  scene_name: str | None, seconds: float, html_out: str | None, as_json: bool) -> None:
        """Score a trainee's save against the reference layout, out of 100.

        The score is 100 minus six capped penalties (docs/scoring.md): porosity
        further from the target than the reference's, missing blocks, blocks out
        of tolerance, collisions, unstable blocks, and poorly interlocked blocks
        beyond the reference's count.
        """
        from geometry.layout import read_layout
        from settle.base import MAX_SECONDS

        from .batch import load_save
        from .report import write_report
        from .score import Reference, check_same_scene, score

        start = time.perf_counter()
        if not 0 < seconds <= MAX_SECONDS:
            raise InputError(f"--seconds {seconds}: must be more than 0 and at most {MAX_SECONDS:g}")
        html_path = _check_out(html_out, (".html", ".htm")) if html_out is not None else None
        ref_layout = read_layout(reference)
        ref_scene = ref_layout.load_scene()
        layout, scene = load_save(save, source, ref_layout, ref_scene, block_type, _parse_origin(origin),
                                  scene_name)
        check_same_scene(scene, ref_scene, save)
        placed = layout.placed()
        ref = Reference.of(ref_scene, ref_layout.placed())
        result = score(scene, placed, ref, seconds=seconds)
        if html_path is not None:
            title = f"{Path(save).name} against {Path(reference).name}"
            write_report(html_path, scene, placed, result, title=title)
        payload = result.to_dict()
        payload["save"] = save
        payload["reference"] = reference
        if html_path is not None:
            payload["html"] = str(html_path)
        payload["seconds"] = time.perf_counter() - start
        human = result.summary() + (f"\nwrote {html_path}" if html_path is not None else "")
        _emit(payload, as_json, human)

    @cli.group("batch")
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
    @_save_options
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
        from settle.base import MAX_SECONDS

        from .batch import SCORE_COLUMNS, Item, RowFile, expand_saves, run_batch, score_task, sha256_file

        if not 0 < seconds <= MAX_SECONDS:
            raise InputError(f"--seconds {seconds}: must be more than 0 and at most {MAX_SECONDS:g}")
        rows = RowFile(_check_out(out, (".csv", ".jsonl")), SCORE_COLUMNS)
        read_layout(reference).load_scene()  # a bad reference is bad usage, not 200 error rows
        ref_sha = sha256_file(reference)
        xyz = _parse_origin(origin)
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
        _emit(summary.to_dict(), as_json,
              f"{summary.ran} saves scored ({summary.errors} errors), {summary.skipped} already done; "
              f"{summary.path}")

    @batch.command("optimize")
    @click.argument("scenes", nargs=-1, required=True)
    @click.option("--seeds", default="0", show_default=True, help="Seeds: 0-9, 1,4,7 or 0-3,10.")
    @click.option("--time-limit", type=click.FloatRange(min=0.0, min_open=True), default=120.0,
                  show_default=True, help="Wall-clock seconds per run.")
    @click.option("--layouts", required=True, help="Folder for the layouts, SCENE-seedN.json.")
    @_runner_options
    def batch_optimize(scenes: tuple[str, ...], seeds: str, time_limit: float, layouts: str, out: str,
                       workers: int, scheduler: str | None, as_json: bool) -> None:
        """Optimize every scene with every seed; one row per run, layouts into a folder."""
        from geometry.scene import load_scene

        from .batch import OPTIMIZE_COLUMNS, Item, RowFile, optimize_task, parse_seeds, run_batch

        rows = RowFile(_check_out(out, (".csv", ".jsonl")), OPTIMIZE_COLUMNS)
        folder = Path(layouts)
        if folder.exists() and not folder.is_dir():
            raise InputError(f"{layouts}: is a file, not a folder")
        seed_list = parse_seeds(seeds)
        for s in scenes:
            load_scene(s)  # a bad scene name is bad usage
        folder.mkdir(parents=True, exist_ok=True)
        items = [Item(f"{s}:seed{n}", {"scene": s, "seed": n, "time_limit": time_limit,
                                        "layouts": str(folder)}) for s in scenes for n in seed_list]
        bar = _Bar("optimizing")
        try:
            summary = run_batch(items, optimize_task, rows, workers, scheduler, progress=bar,
                                on_start=bar.start)
        finally:
            bar.close()
        _emit(summary.to_dict(), as_json,
              f"{summary.ran} runs ({summary.errors} errors), {summary.skipped} already done; {summary.path}")

    @cli.command("render")
    @click.argument("layout_path", metavar="LAYOUT")
    @click.option("--out", required=True, help="Figure file: .png, .pdf or .svg.")
    @click.option("--scene", "scene_name", default=None, help="Scene, instead of the layout's own.")
    @click.option("--section-y", type=float, default=None,
                  help="Where the cross-section cuts, m along the crest (default: the middle).")
    @click.option("--settle", "run_settle", is_flag=True, help="Settle first, to draw unstable blocks red.")
    @click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
    def render_cmd(layout_path: str, out: str, scene_name: str | None, section_y: float | None,
                   run_settle: bool, as_json: bool) -> None:
        """Plan and cross-section drawings of a layout, for print (matplotlib)."""
        import math

        from geometry.checks import check_layout
        from geometry.layout import read_layout

        from .render import FORMATS, render

        start = time.perf_counter()
        path = _check_out(out, FORMATS)
        if section_y is not None and not math.isfinite(section_y):
            raise InputError(f"--section-y {section_y}: must be a finite number of metres")
        layout = read_layout(layout_path)
        scene = layout.load_scene(scene_name)
        placed = layout.placed()
        report = check_layout(scene, placed)
        unstable: list[int] = []
        if run_settle:
            from settle import settle

            unstable = settle(scene, placed).unstable_ids
        protruding = [k for k, _ in report.out_of_tolerance]
        colliding = sorted({c.a for c in report.collisions} | {c.b for c in report.collisions})
        title = f"{Path(layout_path).name}: {len(placed)} blocks, porosity {report.porosity_percent:.1f}%"
        render(scene, placed, path, protruding, unstable, colliding, section_y, title=title)
        payload = {"path": str(path), "blocks": len(placed), "out_of_tolerance": protruding,
                   "collisions": len(report.collisions), "unstable": unstable if run_settle else None,
                   "seconds": time.perf_counter() - start}
        _emit(payload, as_json, f"wrote {path}")
