"""``shoha check``: counts, blocks out of tolerance, collisions and porosity."""

from __future__ import annotations

import click

from .common import emit, json_option


@click.command("check")
@click.argument("layout_path", metavar="LAYOUT")
@click.option("--scene", "scene_name", default=None, help="Scene, instead of the layout's own.")
@json_option
def check(layout_path: str, scene_name: str | None, as_json: bool) -> None:
    """Counts, blocks out of tolerance, collisions and porosity."""
    from geometry.checks import check_layout
    from geometry.layout import read_layout

    layout = read_layout(layout_path)
    s = layout.load_scene(scene_name)
    report = check_layout(s, layout.placed())
    emit(report.to_dict(), as_json, report.summary())
