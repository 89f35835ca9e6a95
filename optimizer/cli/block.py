"""``shoha block``: a block's measures and its mesh."""

from __future__ import annotations

from pathlib import Path

import click

from .common import Group, check_out, emit, json_option


@click.group("block", cls=Group)
def block() -> None:
    """Block models: measures and meshes."""


@block.command("info")
@click.argument("name")
@json_option
def block_info(name: str, as_json: bool) -> None:
    """A block's volume, area, height H, mass and convex pieces."""
    from geometry.blocks import get_block

    b = get_block(name, Path.cwd())
    payload = {
        "name": name,
        "volume_m3": b.volume,
        "surface_area_m2": b.surface_area,
        "height_m": b.height,
        "mass_t": b.mass / 1000.0,
        "convex_pieces": len(b.pieces),
        "density_kg_m3": b.density,
    }
    human = (f"{name}: volume {b.volume:.4f} m3, area {b.surface_area:.4f} m2, "
             f"H {b.height:.4f} m, mass {b.mass / 1000:.3f} t, {len(b.pieces)} convex pieces")
    emit(payload, as_json, human)


@block.command("export")
@click.argument("name")
@click.option("--out", required=True, help="Mesh file: .stl, .obj or .glb (block frame).")
@json_option
def block_export(name: str, out: str, as_json: bool) -> None:
    """Write a block's mesh in its block frame."""
    from geometry.blocks import get_block

    path = check_out(out, (".stl", ".obj", ".glb"))
    get_block(name, Path.cwd()).export(path)
    emit({"path": str(path)}, as_json, f"wrote {path}")
