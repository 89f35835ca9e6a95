"""``shoha optimize``: a reference layout for a scene (docs/contract.md, "CLI").

The only place where strategy names map to strategy classes.
"""

from __future__ import annotations

import time
from dataclasses import replace

import click

from geometry.errors import InputError

from .common import (
    check_not_input,
    check_out,
    check_time_limit,
    emit,
    json_option,
    parse_origin,
    save_options,
)

#: The share of the time limit (or of the least default limit) that a mesh block's first cut
#: into convex pieces may take; the rest is left to place blocks with it.
CUT_SHARE = 0.75


def _strategies(names: str) -> list:
    from optimizer.api import rows_first
    from optimizer.search.anneal import Annealing
    from optimizer.search.beam import BeamSearch
    from optimizer.search.cpsat import CpSat
    from optimizer.search.fill import PocketFill
    from optimizer.search.physics import raised_check, stands

    table = {
        "toe": None,  # rows along the toes first: the others then run around them (rows_first)
        "beam": lambda: BeamSearch(accept=raised_check, judge=stands),
        "fill": lambda: PocketFill(accept=raised_check),
        "anneal": lambda: Annealing(accept=raised_check),
        "cpsat": lambda: CpSat(),
    }
    listed = [n.strip() for n in names.split(",") if n.strip()]
    out = []
    for i, name in enumerate(listed):
        if name not in table:
            raise InputError(f"--strategy {name!r}: use a comma-separated list of {', '.join(table)}")
        if name == "toe":
            if i != 0:
                raise InputError("--strategy: toe lays its rows before any other block, so it comes first")
            continue
        out.append(table[name]())
    if not out:
        raise InputError("--strategy: name at least one strategy" + (" besides toe" if listed else ""))
    return rows_first(out) if listed[0] == "toe" else out


@click.command("optimize")
@click.argument("scene_name", metavar="SCENE")
@click.option("--out", required=True, help="Layout file to write (shoha-layout/1).")
@click.option("--seed", type=click.IntRange(0, 2**31 - 1), default=0, show_default=True,
              help="Random seed; the same seed gives the same layout.")
@click.option("--time-limit", type=float, default=None,
              help="Wall-clock budget in seconds, kept to within 2 s; the best valid layout so far is "
                   "written. Default: 0.5 s a required block, at least 120 s and at most 1200 s "
                   "(mini: 120 s; full, 1005 blocks: 502.5 s).")
@click.option("--strategy", "strategy_names", default="beam,fill,anneal", show_default=True,
              help="Strategies, run in order: beam, fill, anneal, cpsat; toe first lays rows along "
                   "the toes before them (for a big mound whose time holds one attempt only).")
@click.option("--bound", is_flag=True,
              help="Add the CP-SAT bound on the ground layer after the strategies (its gap in --json; "
                   "about a quarter of a default run on mini).")
@click.option("--no-settle", is_flag=True, help="Skip the physics confirmation.")
@click.option("--keep", "keep_path", default=None,
              help="A partial layout to complete (a layout file or a simulator save): its blocks stay "
                   "exactly where they are, and the rest is placed around and on them.")
@save_options
@json_option
def optimize_cmd(scene_name: str, out: str, seed: int, time_limit: float | None, strategy_names: str,
                 bound: bool, no_settle: bool, keep_path: str | None, source: str, block_type: str,
                 origin: str, as_json: bool) -> None:
    """Find a reference layout: valid blocks in crane order, near the target porosity.

    With --keep, complete a partial layout instead: a trainee's blocks so far,
    or a layout cut short. The save options (--from, --block, --origin) say
    how to read it.
    """
    started = time.monotonic()  # the limit covers reading the scene and cutting a mesh too
    from geometry.blocks import cut_by, mesh_path
    from geometry.layout import MAX_ID, write_layout
    from geometry.scene import load_scene, scene_file
    from optimizer.api import MIN_DEFAULT_LIMIT, check_keep, optimize
    from optimizer.batch import load_save
    from optimizer.score import check_same_scene

    check_time_limit(time_limit)
    if keep_path is None:
        _save_options_need_keep()
    path = check_out(out)
    # Before the scene is read: a mesh block's first cut may take most of the limit.
    check_not_input(path, [(scene_file(scene_name), "scene file"), (keep_path, "--keep file")])
    # A mesh block's first cut into convex pieces may take at most this share of the limit.
    with cut_by(started + CUT_SHARE * (time_limit or MIN_DEFAULT_LIMIT)):
        scene = load_scene(scene_name)
    check_not_input(path, [(mesh_path(scene.block_type, scene.base_dir), "block's mesh")])
    keep = None
    if keep_path is not None:
        partial, partial_scene = load_save(keep_path, source, scene.reference(), scene, block_type,
                                           parse_origin(origin))
        check_same_scene(partial_scene, scene, keep_path, against="the optimized")
        # The scene file the kept layout names was read too (a copy of SCENE, say).
        check_not_input(path, [(scene_file(partial_scene.source), "scene file of the --keep layout")])
        # A mesh named by another path to the same file (the layout's own folder, not the
        # scene's: optimize's output fed back) is the scene's block, under the scene's name.
        own = mesh_path(scene.block_type, scene.base_dir)
        keep = [replace(p, type=scene.block_type)
                if own is not None and mesh_path(p.type, partial.base_dir) == own else p
                for p in partial.blocks]
        last = max((p.id for p in keep), default=-1)
        if last + scene.required_blocks > MAX_ID:
            # New blocks are numbered on from the largest kept id, and must read back too.
            raise InputError(f"{keep_path}: kept ids up to {last} leave no room to "
                             f"number {scene.required_blocks} more blocks within 2**53")
        check_keep(scene, keep, keep_path)  # here, where the file is known and nothing is written
    names = strategy_names + (",cpsat" if bound and "cpsat" not in strategy_names.split(",") else "")
    strategies = _strategies(names)
    with _Progress(scene.required_blocks, scene.target_porosity) as progress:
        result = optimize(scene, seed=seed, time_limit=time_limit, strategies=strategies,
                          settle_layout=not no_settle, report=progress.update, keep=keep, started=started)
    result.layout.scene = scene.reference(path.parent)
    write_layout(result.layout, path)
    result.path = str(path)
    payload = result.to_dict()
    human = f"{result.summary()}\nwrote {path}"
    if as_json:
        # stdout holds the one JSON object; what the run found is still said, on stderr.
        click.echo(human, err=True)
    emit(payload, as_json, human)




def _save_options_need_keep() -> None:
    """Refuse --from, --block or --origin without --keep: they say how to read the kept save,
    and given alone they were taken and ignored."""
    from click.core import ParameterSource

    ctx = click.get_current_context()
    for option, param in (("--from", "source"), ("--block", "block_type"), ("--origin", "origin")):
        if ctx.get_parameter_source(param) is ParameterSource.COMMANDLINE:
            raise InputError(f"{option}: says how to read the --keep save, and no --keep is given")


class _Progress:
    """A rich status line on stderr: phase, blocks, best porosity, what is missing."""

    def __init__(self, required: int, target: float):
        self.required = required
        self.target = target
        self._live = None
        self._start = time.monotonic()
        self._last = 0.0
        self._bucket = 0
        self._best: tuple[int, float] | None = None

    def __enter__(self) -> _Progress:
        from rich.console import Console
        from rich.live import Live

        console = Console(stderr=True)
        if console.is_terminal:
            self._live = Live(console=console, refresh_per_second=4, transient=True)
            self._live.__enter__()
        self._console = console
        return self

    def __exit__(self, *exc) -> None:
        if self._live is not None:
            self._live.__exit__(*exc)

    def update(self, phase: str, build, message: str = "") -> None:
        n, porosity = len(build), build.porosity.percent
        key = (n, -abs(porosity - self.target))
        if self._best is None or key > (self._best[0], -abs(self._best[1] - self.target)):
            self._best = (n, porosity)
        now = time.monotonic()
        if now - self._last < 0.25:
            return
        self._last = now
        best_n, best_p = self._best
        short = self.required - best_n
        violations = f"{short} short of {self.required}" if short > 0 else "none"
        line = (f"[bold]{phase}[/bold] {now - self._start:5.1f} s | best: {best_n}/{self.required} blocks, "
                f"porosity {best_p:.2f}% (target {self.target:g}%), violations: {violations} | {message}")
        if self._live is not None:
            self._live.update(line)
        elif int((now - self._start) / 10) > self._bucket:
            # Not a terminal (a log file): one plain line every ten seconds.
            self._bucket = int((now - self._start) / 10)
            self._console.print(line, highlight=False, soft_wrap=True)

