"""The ``shoha`` command line (CONTRACT.md, "CLI").

Every command takes ``--json`` and then prints exactly one JSON object on
stdout; progress and messages go to stderr. Bad input or usage exits with
status 2 and one line on stderr naming the file and the problem, with no
traceback and no output file written. Any other failure is a bug (status 1).

Heavy modules are imported inside the commands, so ``shoha --help`` is quick.
This is the only place where method and strategy names map to classes.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import click

from geometry.errors import InputError


def _emit(payload: dict[str, Any], as_json: bool, human: str) -> None:
    if as_json:
        click.echo(json.dumps(payload, allow_nan=False))
    else:
        click.echo(human)


def _check_out(path: str, suffixes: tuple[str, ...] | None = None) -> Path:
    """Validate an output path before any work is done."""
    p = Path(path)
    if suffixes and p.suffix.lower() not in suffixes:
        raise InputError(f"{path}: output must end in {' or '.join(suffixes)}")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(f"{path}: folder {parent} does not exist")
    if p.is_dir():
        raise InputError(f"{path}: is a folder, not a file")
    return p


class _Group(click.Group):
    """A click group that lists commands in the order they were added."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return list(self.commands)


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="shoha")
def cli() -> None:
    """shoha: compute and check wave-dissipating block placement in breakwaters."""


# --- block ------------------------------------------------------------------------


@cli.group(cls=_Group)
def block() -> None:
    """Block models: measures and meshes."""


@block.command("info")
@click.argument("name")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
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
    _emit(payload, as_json, human)


@block.command("export")
@click.argument("name")
@click.option("--out", required=True, help="Mesh file: .stl, .obj or .glb (block frame).")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
def block_export(name: str, out: str, as_json: bool) -> None:
    """Write a block's mesh in its block frame."""
    from geometry.blocks import get_block

    path = _check_out(out, (".stl", ".obj", ".glb"))
    get_block(name, Path.cwd()).export(path)
    _emit({"path": str(path)}, as_json, f"wrote {path}")


# --- scene ------------------------------------------------------------------------


@cli.group(cls=_Group)
def scene() -> None:
    """Breakwater scenes: design prism, tolerance zone, foundation."""


@scene.command("info")
@click.argument("scene_name", metavar="SCENE")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
def scene_info(scene_name: str, as_json: bool) -> None:
    """A scene's measures."""
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
    }
    human = (f"{s.name}: {s.block_type}, design {s.design_volume:.2f} m3, tolerance "
             f"{s.tolerance.volume:.2f} m3, {s.required_blocks} blocks required for "
             f"{s.target_porosity:g}% porosity")
    _emit(payload, as_json, human)


@scene.command("export")
@click.argument("scene_name", metavar="SCENE")
@click.option("--out", required=True, help="Folder for design.stl and tolerance.stl.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
def scene_export(scene_name: str, out: str, as_json: bool) -> None:
    """Write the design and tolerance prisms as watertight STL meshes (world frame)."""
    import trimesh

    from geometry.fileio import atomic_write
    from geometry.scene import load_scene

    s = load_scene(scene_name)
    folder = Path(out)
    if folder.exists() and not folder.is_dir():
        raise InputError(f"{out}: is a file, not a folder")
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for label, prism in (("design", s.design), ("tolerance", s.tolerance)):
        poly = prism.polytope
        mesh = trimesh.Trimesh(poly.vertices, poly.faces, process=True)
        path = folder / f"{label}.stl"
        atomic_write(path, mesh.export(file_type="stl"))
        paths.append(str(path))
    _emit({"paths": paths}, as_json, "wrote " + ", ".join(paths))


# --- convert ---------------------------------------------------------------------------


def _parse_origin(text: str) -> tuple[float, float, float]:
    import math

    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise InputError(f"--origin {text!r}: expected three numbers X,Y,Z in metres")
    return values  # type: ignore[return-value]


@cli.command("convert")
@click.argument("save")
@click.option("--from", "source", type=click.Choice(["unity"]), required=True,
              help="Format of SAVE: the training simulator's Unity JSON.")
@click.option("--out", required=True, help="Layout file to write (shoha-layout/1).")
@click.option("--block", "block_type", default="shake-4t", show_default=True,
              help="Block type for saved blocks that name none.")
@click.option("--scene", "scene_name", default="mini", show_default=True,
              help="Scene the layout belongs to.")
@click.option("--origin", default="0,0,0", show_default=True,
              help="World position X,Y,Z (m) of Unity's origin.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
def convert(save: str, source: str, out: str, block_type: str, scene_name: str, origin: str,
            as_json: bool) -> None:
    """Convert a simulator save to a shoha-layout/1 file."""
    from geometry.layout import write_layout
    from geometry.scene import load_scene
    from geometry.unity import read_unity_save

    path = _check_out(out)
    # The layout names its scene relative to itself (CONTRACT.md), not to the working folder.
    reference = load_scene(scene_name).reference(path.parent)
    layout = read_unity_save(save, scene=reference, block=block_type, origin=_parse_origin(origin))
    write_layout(layout, path)
    _emit({"blocks": len(layout.blocks), "path": str(path)}, as_json,
          f"wrote {len(layout.blocks)} blocks to {path}")


# --- porosity and check --------------------------------------------------------------------


@cli.command("porosity")
@click.argument("layout_path", metavar="LAYOUT")
@click.option("--scene", "scene_name", default=None, help="Scene, instead of the layout's own.")
@click.option("--method", type=click.Choice(["exact", "voxel", "voxel-any"]), default="exact",
              show_default=True, help="exact: solid geometry; voxel: voxel centres; "
              "voxel-any: the paper's OverlapBox rule.")
@click.option("--divisions", type=click.IntRange(1, 2000), default=None,
              help="GridDivisionCount per axis of the prism's bounding box (voxel methods; 100).")
@click.option("--voxel-size", type=float, default=None, help="Cubic voxel edge, m, instead of --divisions.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
def porosity_cmd(layout_path: str, scene_name: str | None, method: str, divisions: int | None,
                 voxel_size: float | None, as_json: bool) -> None:
    """Porosity of the design prism: solid geometry or voxels.

    Eq. (1) of the reference paper for exact, eq. (2) for the voxel methods.
    """
    from geometry.layout import read_layout
    from geometry.porosity import porosity

    if method == "exact" and (divisions is not None or voxel_size is not None):
        raise InputError("--divisions and --voxel-size apply to the voxel methods only")
    layout = read_layout(layout_path)
    s = layout.load_scene(scene_name)
    placed = layout.placed()
    r = porosity(s, placed, method=method, divisions=divisions, voxel_size=voxel_size)
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
    _emit(payload, as_json, f"porosity {r.percent:.2f}% ({r.method}{grid}, {r.blocks} blocks, "
          f"{r.seconds * 1000:.1f} ms)")


@cli.command("check")
@click.argument("layout_path", metavar="LAYOUT")
@click.option("--scene", "scene_name", default=None, help="Scene, instead of the layout's own.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
def check(layout_path: str, scene_name: str | None, as_json: bool) -> None:
    """Counts, blocks out of tolerance, collisions and porosity."""
    from geometry.checks import check_layout
    from geometry.layout import read_layout

    layout = read_layout(layout_path)
    s = layout.load_scene(scene_name)
    report = check_layout(s, layout.placed())
    payload = report.to_dict()
    _emit(payload, as_json, report.summary())


# --- entry point ------------------------------------------------------------------------------


def _register_optional_commands() -> None:
    """Commands that live in their own modules (settle, optimize, score, ...)."""
    import importlib

    for module in ("optimizer.cli_settle", "optimizer.cli_optimize", "optimizer.cli_score"):
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name != module:
                raise
            continue
        mod.register(cli)


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit status (0 done, 2 bad input, 1 bug)."""
    _register_optional_commands()
    try:
        cli.main(args=argv, prog_name="shoha", standalone_mode=False)
    except click.exceptions.Exit as exc:
        return int(exc.exit_code)
    except click.exceptions.Abort:
        click.echo("shoha: aborted", err=True)
        return 130
    except click.exceptions.ClickException as exc:
        # Usage errors: one line, as for bad files (click prints three).
        ctx = getattr(exc, "ctx", None)
        where = f"{ctx.command_path}: " if ctx is not None else "shoha: "
        click.echo(where + exc.format_message().replace("\n", " "), err=True)
        return 2
    except InputError as exc:
        click.echo(f"shoha: {str(exc).splitlines()[0] if str(exc) else 'bad input'}", err=True)
        return 2
    except KeyboardInterrupt:
        click.echo("shoha: interrupted", err=True)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
