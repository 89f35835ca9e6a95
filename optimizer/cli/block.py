"""``shoha block``: a block's measures and its mesh."""

from __future__ import annotations

from pathlib import Path

import click

from geometry.errors import InputError

from .common import Group, check_not_input, check_out, emit, json_option


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
    from geometry.blocks import get_block, mesh_path

    path = check_out(out, (".stl", ".obj", ".glb"))
    check_not_input(path, [(mesh_path(name, Path.cwd()), "block's own mesh")])
    get_block(name, Path.cwd()).export(path)
    emit({"path": str(path)}, as_json, f"wrote {path}")


class _Seconds(click.ParamType):
    """The tuner's time, 1 to 7200 s; click's FloatRange lets NaN through (every comparison is false)."""

    name = "seconds"

    def convert(self, value, param, ctx):  # noqa: ANN001 - click's signature
        try:
            seconds = float(value)
        except (TypeError, ValueError):
            self.fail(f"{value!r} is not a number", param, ctx)
        if not 1.0 <= seconds <= 7200.0:
            self.fail(f"{value!r} is not in 1 to 7200 s", param, ctx)
        return seconds


SECONDS = _Seconds()


@block.command("tune")
@click.argument("name")
@click.option("--seconds", type=SECONDS, default=180.0, show_default=True,
              help="Most time the tuner may take, 1 to 7200 s. It ends at its count of generations "
                   "first where the machine is fast enough, with the same pattern on every run.")
@click.option("--force", is_flag=True, help="Tune again even if a tuned pattern is cached.")
@json_option
def block_tune(name: str, seconds: float, force: bool, as_json: bool) -> None:
    """Tune a block's placement pattern and cache it for `shoha optimize`.

    The pattern is a two-site lattice of the block's own hangings, made as
    dense as a crane can lay it (each block lowered after the ones before it
    reaches the ground). It is cached by the SHA-256 of the block's mesh, so
    every later run with the same block reuses it; `shoha optimize` tunes an
    uncached block by itself, within a quarter of its time limit. The
    built-in blocks come tuned.
    """
    import time

    from geometry.blocks import get_block
    from optimizer.search import patterns

    b = get_block(name, Path.cwd())
    start = time.perf_counter()
    lattice, tuning = patterns.pattern_for(b, name, seconds, force=force)
    if tuning.source == "bond":
        raise InputError(f"{name}: no crane-feasible lattice found in {seconds:g} s")
    path = None if tuning.source == "built in" else str(patterns.cache_path(b))
    payload = {"name": name, "source": tuning.source, "area_per_block_m2": lattice.area_per_block,
               "area_per_block_per_h2": lattice.area_per_block / b.height**2,
               "families": [lattice.family_a, lattice.family_b], "path": path,
               "seconds": time.perf_counter() - start, "generations": tuning.generations,
               "clock_cut": tuning.clock_cut}
    cut = (f"; the clock ended its tuning after {tuning.generations} generations, so another machine "
           "may tune another pattern" if tuning.clock_cut else "")
    human = (f"{name}: {tuning.source} pattern, {lattice.area_per_block:.3f} m2 a block "
             f"({lattice.area_per_block / b.height**2:.3f} H^2), hangings {lattice.family_a} and "
             f"{lattice.family_b}" + (f"; {path}" if path else "") + cut)
    emit(payload, as_json, human)
