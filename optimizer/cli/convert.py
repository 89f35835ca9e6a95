"""``shoha convert``: a simulator save to a layout file."""

from __future__ import annotations

from pathlib import Path

import click

from geometry.errors import InputError

from .common import block_from_cwd, check_out, emit, json_option, parse_origin


@click.command("convert")
@click.argument("save")
@click.option("--from", "source", type=click.Choice(["unity"]), required=True,
              help="Format of SAVE: the training simulator's Unity JSON.")
@click.option("--out", required=True, help="Layout file to write (shoha-layout/1).")
@click.option("--block", "block_type", default="shake-4t", show_default=True, callback=block_from_cwd,
              help="Block type for saved blocks that name none.")
@click.option("--scene", "scene_name", default="mini", show_default=True,
              help="Scene the layout belongs to.")
@click.option("--origin", default="0,0,0", show_default=True,
              help="World position X,Y,Z (m) of Unity's origin.")
@json_option
def convert(save: str, source: str, out: str, block_type: str, scene_name: str, origin: str,
            as_json: bool) -> None:
    """Convert a simulator save to a shoha-layout/1 file."""
    from geometry.layout import write_layout
    from geometry.scene import load_scene
    from geometry.unity import read_unity_save

    path = check_out(out)
    if path.resolve() == Path(save).resolve():
        raise InputError(f"--out {out}: is the SAVE itself; write the layout elsewhere, or the save is lost")
    # The layout names its scene relative to itself (docs/contract.md), not to the working folder.
    reference = load_scene(scene_name).reference(path.parent)
    layout = read_unity_save(save, scene=reference, block=block_type, origin=parse_origin(origin))
    write_layout(layout, path)
    emit({"blocks": len(layout.blocks), "path": str(path)}, as_json,
         f"wrote {len(layout.blocks)} blocks to {path}")
