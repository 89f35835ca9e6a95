"""``shoha scene``: a scene's measures and its meshes."""

from __future__ import annotations

import math
from pathlib import Path

import click

from geometry.errors import InputError

from .common import Group, emit, json_option


@click.group("scene", cls=Group)
def scene() -> None:
    """Breakwater scenes: design prism, tolerance zone, foundation."""


@scene.command("info")
@click.argument("scene_name", metavar="SCENE")
@click.option("--floor", is_flag=True,
              help="Also measure what the tolerance zone keeps out of any block's reach "
                   "(coverage_floor; a few seconds).")
@json_option
def scene_info(scene_name: str, floor: bool, as_json: bool) -> None:
    """A scene's measures.

    With --floor, the coverage floor: the share of the design slopes and
    crest that lies further than H/2 from any block that fits inside the
    tolerance zone, in any of the orientations tried, and the largest such
    distance. No valid layout can be less bare.
    """
    from geometry.scene import load_scene

    s = load_scene(scene_name)
    payload = {
        "name": s.name,
        "kind": s.kind,
        "block": s.block_type,
        "design_volume_m3": s.design_volume,
        "tolerance_volume_m3": s.tolerance.volume,
        "required_blocks": s.required_blocks,
        "target_porosity_percent": s.target_porosity,
        "crest_width_m": s.crest_width,
        "height_m": s.height,
        "slope_run_per_rise": s.slope,
        "length_m": s.length,
        "foundation": s.foundation.kind,
        "wall": s.wall,
        "block_height_m": s.block.height,
    }
    human = (f"{s.name}: {s.block_type}, design {s.design_volume:.2f} m3, tolerance "
             f"{s.tolerance.volume:.2f} m3, {s.required_blocks} blocks required for "
             f"{s.target_porosity:g}% porosity")
    if floor:
        from geometry.coverage import AIM_BARE_PERCENT
        from geometry.reach import coverage_floor

        f = coverage_floor(s)
        payload["coverage_floor"] = f.to_dict()
        h = s.block.height
        verdict = ("so no layout of this block can meet the coverage aims" if f.rules_out(h)
                   else "which does not rule the coverage aims out")
        farthest = (f"the point ({f.worst_point[0]:.2f}, z {f.worst_point[1]:.2f}) {f.max_bare_m:.2f} m "
                    "from one" if math.isfinite(f.max_bare_m) else "no block fits inside the zone at all")
        human += (f"\ncoverage floor: {f.bare_share_percent:.1f}% of the slopes and crest lies over "
                  f"H/2 = {h / 2:.2f} m from any block inside the tolerance zone, and {farthest} "
                  f"(aims: at most {AIM_BARE_PERCENT:g}%, within H = {h:.2f} m), {verdict}, "
                  f"to the {f.orientations} orientations tried")
    emit(payload, as_json, human)


@scene.command("export")
@click.argument("scene_name", metavar="SCENE")
@click.option("--out", required=True, help="Folder for the meshes.")
@json_option
def scene_export(scene_name: str, out: str, as_json: bool) -> None:
    """Write the scene as watertight STL meshes, world frame.

    design.stl and tolerance.stl (the prisms), foundation.stl (the
    foundation's top, flat or rough, as a closed slab) and, behind a
    wall-backed section, wall.stl.
    """
    import trimesh

    from geometry.fileio import atomic_write, check_replaceable
    from geometry.scene import load_scene

    s = load_scene(scene_name)
    if not out.strip():
        raise InputError("--out: name a folder for the meshes")
    folder = Path(out)
    if folder.exists() and not folder.is_dir():
        raise InputError(f"{out}: is a file, not a folder")
    # The folder may be new, as other verbs' files are, but not the folders above it.
    if not folder.expanduser().absolute().parent.is_dir():
        raise InputError(f"{out}: folder {folder.parent} does not exist")
    meshes = {label: (prism.polytope.vertices, prism.polytope.faces)
              for label, prism in (("design", s.design), ("tolerance", s.tolerance))}
    meshes["foundation"] = s.foundation.slab()
    if s.wall_box is not None:
        wall = trimesh.creation.box(bounds=s.wall_box)
        meshes["wall"] = (wall.vertices, wall.faces)
    # Every file checked and made before the first is written: none is left half done.
    files = {folder / f"{label}.stl": trimesh.Trimesh(v, f, process=True).export(file_type="stl")
             for label, (v, f) in meshes.items()}
    for path in files:
        check_replaceable(path)
    folder.mkdir(exist_ok=True)
    paths = []
    for path, data in files.items():
        atomic_write(path, data)
        paths.append(str(path))
    emit({"paths": paths}, as_json, "wrote " + ", ".join(paths))
