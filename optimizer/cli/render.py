"""``shoha render``: plan and cross-section drawings of a layout, for print."""

from __future__ import annotations

import time
from pathlib import Path

import click

from geometry.errors import InputError

from .common import check_out, emit, json_option


@click.command("render")
@click.argument("layout_path", metavar="LAYOUT")
@click.option("--out", required=True, help="Figure file: .png, .pdf or .svg.")
@click.option("--scene", "scene_name", default=None, help="Scene, instead of the layout's own.")
@click.option("--section-y", type=float, default=None,
              help="Where the cross-section cuts, m along the crest (default: the middle).")
@click.option("--settle", "run_settle", is_flag=True, help="Settle first, to draw unstable blocks red.")
@json_option
def render_cmd(layout_path: str, out: str, scene_name: str | None, section_y: float | None,
               run_settle: bool, as_json: bool) -> None:
    """Plan and cross-section drawings of a layout, for print (matplotlib)."""
    import math

    from geometry.checks import check_layout
    from geometry.layout import read_layout
    from optimizer.score.render import FORMATS, render

    start = time.perf_counter()
    path = check_out(out, FORMATS)
    if section_y is not None and not math.isfinite(section_y):
        raise InputError(f"--section-y {section_y}: must be a finite number of metres")
    layout = read_layout(layout_path)
    scene = layout.load_scene(scene_name)
    design = scene.design
    if section_y is not None and not design.y_start <= section_y <= design.y_end:
        raise InputError(f"--section-y {section_y:g}: the cross-section must lie along the mound, "
                         f"from {design.y_start:g} to {design.y_end:g} m")
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
    emit(payload, as_json, f"wrote {path}")
