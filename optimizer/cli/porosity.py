"""``shoha porosity``: porosity of the design prism, exact or by voxels."""

from __future__ import annotations

import click

from geometry.errors import InputError

from .common import emit, json_option


@click.command("porosity")
@click.argument("layout_path", metavar="LAYOUT")
@click.option("--scene", "scene_name", default=None, help="Scene, instead of the layout's own.")
@click.option("--method", type=click.Choice(["exact", "voxel", "voxel-any"]), default="exact",
              show_default=True, help="exact: solid geometry; voxel: voxel centres; "
              "voxel-any: the paper's OverlapBox rule.")
@click.option("--divisions", type=click.IntRange(1, 2000), default=None,
              help="GridDivisionCount per axis of the prism's bounding box (voxel methods; 100).")
@click.option("--voxel-size", type=float, default=None, help="Cubic voxel edge, m, instead of --divisions.")
@json_option
def porosity(layout_path: str, scene_name: str | None, method: str, divisions: int | None,
             voxel_size: float | None, as_json: bool) -> None:
    """Porosity of the design prism: solid geometry or voxels.

    Eq. (1) of the reference paper for exact, eq. (2) for the voxel methods.
    """
    from geometry.layout import read_layout
    from geometry.porosity import porosity as measure

    if method == "exact" and (divisions is not None or voxel_size is not None):
        raise InputError("--divisions and --voxel-size apply to the voxel methods only")
    layout = read_layout(layout_path)
    s = layout.load_scene(scene_name)
    r = measure(s, layout.placed(), method=method, divisions=divisions, voxel_size=voxel_size)
    payload = {
        "porosity_percent": r.percent,
        "method": r.method,
        "divisions": r.divisions,
        "blocks": r.blocks,
        "design_volume_m3": r.design_volume,
        "seconds": r.seconds,
    }
    if r.voxel_size is not None:
        payload["voxel_size_m"] = list(r.voxel_size)
        payload["prism_voxels"] = r.prism_voxels
        payload["occupied_voxels"] = int(r.filled)
    else:
        payload["filled_volume_m3"] = r.filled
    grid = f", {r.divisions} divisions" if r.divisions else ""
    emit(payload, as_json, f"porosity {r.percent:.2f}% ({r.method}{grid}, {r.blocks} blocks, "
         f"{r.seconds * 1000:.1f} ms)")
