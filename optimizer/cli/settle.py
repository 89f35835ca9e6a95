"""``shoha settle``: physics settle and stability verdict (docs/contract.md, "CLI").

The table from backend names to classes lives here, at the CLI edge; the
library takes backend instances (settle/base.py).
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import click

from geometry.errors import InputError

from .common import check_not_input, check_out, emit, json_option

#: Runs longer than this many wall-clock seconds show a progress line on stderr.
PROGRESS_AFTER = 1.0

BACKENDS = ("auto", "mujoco", "pymunk")


def _backend(name: str) -> Any:
    """The backend instance for a ``--backend`` name (None: chosen by the scene's kind)."""
    from settle import MujocoBackend, PymunkBackend

    classes = {"mujoco": MujocoBackend, "pymunk": PymunkBackend}
    return classes[name]() if name in classes else None


class _ProgressLine:
    """A rich progress bar on stderr that appears only once a run has taken a while."""

    def __init__(self) -> None:
        self.start = time.perf_counter()
        self.bar: Any = None
        self.task: Any = None

    def __call__(self, simulated: float, total: float) -> None:
        if self.bar is None:
            if time.perf_counter() - self.start < PROGRESS_AFTER:
                return
            from rich.console import Console
            from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

            self.bar = Progress(
                TextColumn("settling"), BarColumn(), TextColumn("{task.completed:.2f}/{task.total:.2f} s"),
                TimeElapsedColumn(), console=Console(stderr=True),
            )
            self.bar.start()
            self.task = self.bar.add_task("settle", total=total)
        self.bar.update(self.task, completed=simulated)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.stop()


def _scene_reference(spec: str, base_dir: str | None, out: Path) -> str:
    """``spec`` as the settled layout should name it: built-in names as they are,
    scene files relative to the folder the layout is written to."""
    from geometry.scene import builtin_scenes

    if spec in builtin_scenes():
        return spec
    path = Path(spec).expanduser()
    if not path.is_absolute() and base_dir is not None and (Path(base_dir) / path).is_file():
        path = Path(base_dir) / path
    return os.path.relpath(path.resolve(), out.resolve().parent)


@click.command("settle")
@click.argument("layout_path", metavar="LAYOUT")
@click.option("--scene", "scene_name", default=None, help="Scene, instead of the layout's own.")
@click.option("--seconds", type=float, default=2.0, show_default=True,
              help="Simulated time, seconds (at most 60); stops early once all blocks rest.")
@click.option("--out", default=None, help="Write the settled poses as a layout (shoha-layout/1).")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Seeds the tiny initial kick of each block; same seed, same result.")
@click.option("--backend", "backend_name", type=click.Choice(BACKENDS), default="auto",
              show_default=True, help="Physics engine; auto: MuJoCo for 3d scenes, pymunk for section.")
@json_option
def settle_cmd(layout_path: str, scene_name: str | None, seconds: float, out: str | None, seed: int,
               backend_name: str, as_json: bool) -> None:
    """Settle a layout under gravity and judge whether it stands.

    A block is stable if it moved at most 0.05 H and turned at most 5 degrees;
    the layout is stable if every block is.
    """
    from geometry.layout import Layout, Placement, read_layout, write_layout
    from settle import settle
    from settle.base import MAX_SECONDS

    start = time.perf_counter()
    if not 0 < seconds <= MAX_SECONDS:
        raise InputError(f"--seconds {seconds}: must be more than 0 and at most {MAX_SECONDS:g}")
    path = check_out(out, (".json",)) if out is not None else None
    if path is not None:
        check_not_input(path, [(layout_path, "layout settled")])
    layout = read_layout(layout_path)
    scene = layout.load_scene(scene_name)
    placed = layout.placed()
    progress = _ProgressLine()
    try:
        result = settle(scene, placed, seconds=seconds, seed=seed, backend=_backend(backend_name),
                        progress=progress)
    finally:
        progress.close()
    payload = result.to_dict()
    if path is not None:
        spec = scene_name if scene_name is not None else layout.scene
        base = str(Path.cwd()) if scene_name is not None else layout.base_dir
        poses = result.poses
        blocks = [Placement(p.id, p.type, poses[p.id], p.time_s) for p in layout.blocks]
        settled = Layout(_scene_reference(spec, base, path), blocks, dict(layout.extra), layout.base_dir)
        write_layout(settled, path)
        payload["path"] = str(path)
    payload["seconds"] = time.perf_counter() - start
    human = result.summary() + (f"; wrote {path}" if path is not None else "")
    emit(payload, as_json, human)
