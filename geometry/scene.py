"""The breakwater scene: design prism, tolerance zone, crest, foundation.

Scenes load from TOML. The built-in ones live in ``geometry/scenes/`` and are
named by their file stem (``mini``). A scene file looks like this::

    name = "mini"
    kind = "3d"                      # or "section": blocks extruded along y, 2D physics
    block = "shake-4t"
    target_porosity_percent = 56.0
    # required_blocks = 75           # default: ceil((1 - target) V_B / V_block)

    [design]
    crest_width_m = 4.0
    height_m = 3.0
    slope_rise_run = [3.0, 4.0]      # 3 up for 4 across
    length_m = 12.220833333333333
    # wall = true                    # a wall face on the landward side (-x), at -crest_width_m / 2

    [tolerance]                      # optional; each defaults to H/3 (Table II)
    crest_rise_m = 0.5533

    [foundation]                     # optional; flat by default
    kind = "rough"                   # a rubble underlayer, as a height field
    amplitude_m = 0.15
    cell_m = 0.5
    seed = 0
"""

from __future__ import annotations

import math
import os
import tomllib
from dataclasses import dataclass, field
from functools import cached_property
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from .blocks import Block, get_block
from .constants import tol
from .errors import InputError, finite_number, shown
from .fileio import regular_file
from .tolerance import Allowance, TrapezoidalPrism, design_prism, tolerance_prism

SCENE_KINDS = ("3d", "section")

#: Thickness of the foundation slab ``shoha scene export`` writes, below its lowest point, metres.
FOUNDATION_SLAB = 1.0

#: Thickness of the wall behind its face, metres. A caisson or seawall is thicker;
#: the face is what the blocks meet, and the settle holds the whole slab fixed.
WALL_THICKNESS = 1.0


@dataclass(frozen=True)
class Foundation:
    """The top of the foundation: flat at z = 0, or a rough rubble underlayer.

    A rough underlayer is a height field: heights drawn uniformly from
    ``[-amplitude, amplitude]`` on a square grid of spacing ``cell``, seeded so
    the same scene is the same ground. Between the nodes it is the surface
    MuJoCo's height field collides with: each cell is two flat triangles,
    split along the diagonal of rising x and y. So the ground a block is
    lowered onto, the ground the physics settle has and the ground
    ``shoha scene export`` writes are one surface.
    """

    kind: str = "flat"
    amplitude: float = 0.0
    cell: float = 0.5
    seed: int = 0
    #: (xmin, xmax, ymin, ymax), metres: the area the height field covers.
    extent: tuple[float, float, float, float] = (-1.0, 1.0, -1.0, 1.0)

    @property
    def lowest(self) -> float:
        """Lowest point of the foundation top, m."""
        return -self.amplitude if self.kind == "rough" else 0.0

    @cached_property
    def grid(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Height field: x nodes (nx,), y nodes (ny,), heights (nx, ny), metres."""
        x0, x1, y0, y1 = self.extent
        if self.kind != "rough":
            # Flat: the corners hold it (a zone 20 km wide gridded every cell took 6 GB to export).
            return np.array([x0, x1]), np.array([y0, y1]), np.zeros((2, 2))
        xs = np.arange(x0, x1 + self.cell, self.cell)
        ys = np.arange(y0, y1 + self.cell, self.cell)
        rng = np.random.default_rng(self.seed)
        return xs, ys, rng.uniform(-self.amplitude, self.amplitude, (len(xs), len(ys)))

    def slab(self, thickness: float = FOUNDATION_SLAB) -> tuple[np.ndarray, np.ndarray]:
        """The foundation as a closed slab over :attr:`extent`: its top surface and ``thickness`` below.

        Returns
        -------
        vertices : (n, 3) float, metres, world frame
        faces : (m, 3) int, outward facing
            A rough top is the grid's own triangles, split as :meth:`height_at` splits them.
        """
        xs, ys, h = self.grid
        nx, ny = len(xs), len(ys)
        gx, gy = np.meshgrid(xs, ys, indexing="ij")
        bottom = self.lowest - thickness
        top = np.column_stack([gx.ravel(), gy.ravel(), h.ravel()])
        base = np.column_stack([gx.ravel(), gy.ravel(), np.full(nx * ny, bottom)])
        index = np.arange(nx * ny).reshape(nx, ny)
        a, b = index[:-1, :-1].ravel(), index[1:, :-1].ravel()  # (i, j), (i+1, j)
        c, d = index[1:, 1:].ravel(), index[:-1, 1:].ravel()  # (i+1, j+1), (i, j+1)
        # Each cell split along its rising diagonal a-c, counter-clockwise seen from above.
        up = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
        down = up[:, ::-1] + nx * ny  # the base, seen from below
        ring = np.concatenate([index[:, 0], index[-1, 1:], index[-2::-1, -1], index[0, -2:0:-1]])
        nxt = np.roll(ring, -1)
        # Sides: each boundary edge of the top joined to the same edge of the base.
        sides = np.concatenate([np.column_stack([ring, ring + nx * ny, nxt]),
                                np.column_stack([nxt, ring + nx * ny, nxt + nx * ny])])
        return np.concatenate([top, base]), np.concatenate([up, down, sides])

    def height_at(self, xy: np.ndarray) -> np.ndarray:
        """Foundation top height under ``(n, 2)`` points, metres.

        Linear on the two triangles of each cell: (0, 0)-(1, 0)-(1, 1) where
        ``tx >= ty``, else (0, 0)-(0, 1)-(1, 1), in the cell's own coordinates:
        MuJoCo's split (probed by ray casts onto a one-cell height field).
        """
        xy = np.atleast_2d(xy)
        if self.kind != "rough":
            return np.zeros(len(xy))
        xs, ys, h = self.grid
        fx = np.clip((xy[:, 0] - xs[0]) / self.cell, 0, len(xs) - 1 - tol.grid_edge)
        fy = np.clip((xy[:, 1] - ys[0]) / self.cell, 0, len(ys) - 1 - tol.grid_edge)
        i, j = fx.astype(int), fy.astype(int)
        tx, ty = fx - i, fy - j
        h00, h10, h01, h11 = h[i, j], h[i + 1, j], h[i, j + 1], h[i + 1, j + 1]
        return np.where(tx >= ty, h00 + tx * (h10 - h00) + ty * (h11 - h10),
                        h00 + ty * (h01 - h00) + tx * (h11 - h01))


@dataclass(frozen=True)
class Scene:
    """A breakwater to fill with blocks.

    Attributes
    ----------
    name : str
    kind : str
        ``"3d"``, or ``"section"``: a slice whose blocks are prisms extruded
        along y and move only in x-z (settled in 2D).
    block_type : str
        The block type name, as in layout files.
    crest_width, height, slope, length : float
        The design parameters, metres; ``slope`` is run per unit rise.
    wall : bool
        The landward side (-x) is a vertical wall face at ``x = -crest_width / 2``
        (a mound in front of a caisson or seawall): the design and tolerance
        prisms stop at it, blocks may not cross it, and the settle holds it fixed.
    target_porosity : float, percent
    required_blocks : int
    allowance : Allowance
        Table II's allowances, metres.
    foundation : Foundation
    base_dir : str or None
        Folder that relative ``mesh:`` block paths resolve against.
    source : str or None
        How to find the scene again: a built-in name, or the scene file's
        absolute path (see :meth:`reference`).
    """

    name: str
    kind: str
    block_type: str
    crest_width: float
    height: float
    slope: float
    length: float
    target_porosity: float
    required_blocks: int
    allowance: Allowance
    foundation: Foundation = field(default_factory=Foundation)
    base_dir: str | None = None
    source: str | None = None
    wall: bool = False

    def reference(self, layout_dir: str | os.PathLike | None = None) -> str:
        """The ``scene`` value of a layout file that refers to this scene.

        A built-in name as it is; a scene file as a path relative to the
        layout's folder (docs/contract.md: resolved relative to the layout file).
        """
        if scene_file(self.source) is None:
            return self.source or self.name
        if layout_dir is None:
            return self.source
        return os.path.relpath(self.source, os.path.abspath(layout_dir))

    @property
    def block(self) -> Block:
        return get_block(self.block_type, self.base_dir)

    @cached_property
    def design(self) -> TrapezoidalPrism:
        return design_prism(self.crest_width, self.height, self.slope, self.length, self.wall)

    @cached_property
    def tolerance(self) -> TrapezoidalPrism:
        return tolerance_prism(self.design, self.allowance, min(0.0, self.foundation.lowest))

    @property
    def design_volume(self) -> float:
        """V_B of eq. (1), m^3."""
        return self.design.volume

    @property
    def wall_box(self) -> np.ndarray | None:
        """(2, 3) float: the wall's lower and upper corners, world frame; None without a wall.

        Its face is the design's landward side, ``x = -crest_width / 2``, and it is
        :data:`WALL_THICKNESS` thick behind it. It runs from ``FOUNDATION_SLAB``
        below the foundation's lowest point to a block height above the
        tolerance crest, and a block height past each end of the zone.
        """
        if not self.wall:
            return None
        zone, h = self.tolerance, self.block.height
        x = float(self.design.wall_x)
        return np.array([[x - WALL_THICKNESS, zone.y_start - h, self.foundation.lowest - FOUNDATION_SLAB],
                         [x, zone.y_end + h, zone.z_top + h]])

    @property
    def crest(self) -> np.ndarray:
        """(4, 3) float: corners of the crest top (天端), the face cranes place against."""
        w = self.crest_width / 2
        return np.array([[-w, 0, self.height], [w, 0, self.height], [w, self.length, self.height],
                         [-w, self.length, self.height]])


# --- loading ---------------------------------------------------------------------


def builtin_scenes() -> list[str]:
    """Names of the built-in scenes."""
    folder = resources.files("geometry") / "scenes"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def scene_file(spec: str | os.PathLike | None) -> str | None:
    """The file a scene spec (or a scene's ``source``) reads, as :func:`load_scene` takes it:
    None for a built-in name, which no file of that name beside it shadows, or for none."""
    if spec is None or str(spec) in builtin_scenes():
        return None
    return str(spec)


def load_scene(spec: str | os.PathLike, base_dir: str | os.PathLike | None = None) -> Scene:
    """A scene by built-in name, or from a TOML file.

    A relative path is resolved against ``base_dir`` (the layout file's
    folder, docs/contract.md), then the working directory.

    Raises
    ------
    InputError
        If no such scene exists or its file is invalid.
    """
    spec = str(spec)
    if spec in builtin_scenes():
        text = (resources.files("geometry") / "scenes" / f"{spec}.toml").read_text()
        return parse_scene(text, source=spec, base_dir=None, reference=spec)
    path = Path(spec).expanduser()
    if not path.is_absolute() and base_dir is not None and (Path(base_dir) / path).is_file():
        path = Path(base_dir) / path
    if not path.exists():
        names = ", ".join(builtin_scenes())
        raise InputError(f"{spec}: no such scene (built-in scenes: {names}; or a .toml file)")
    size = regular_file(path).st_size  # a folder, device or pipe is named as such
    if size > MAX_SCENE_BYTES:
        # An 80 MB array in a scene file took 73 s and 1 GB to be refused for its unknown key.
        raise InputError(f"{path}: scene file is {size} bytes, more than {MAX_SCENE_BYTES}")
    try:
        text = path.read_text(encoding="utf-8-sig")  # an editor's byte-order mark is no TOML error
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read scene ({exc})") from None
    return parse_scene(text, source=str(path), base_dir=str(path.resolve().parent),
                       reference=str(path.resolve()))


#: A scene file's largest size: the built-in ones are under 1 KB.
MAX_SCENE_BYTES = 1 << 20

_TOP_KEYS = {"name", "kind", "block", "target_porosity_percent", "required_blocks",
             "design", "tolerance", "foundation"}
#: The least height and length a design prism may have, metres.
MIN_DESIGN_M = 1e-3
_DESIGN_KEYS = {"crest_width_m", "height_m", "slope_rise_run", "length_m", "wall"}
_TOLERANCE_KEYS = {"crest_rise_m", "crest_widening_m", "slope_lengthening_m", "end_extension_m"}
_FOUNDATION_KEYS = {"kind", "amplitude_m", "cell_m", "seed"}


def parse_scene(text: str, source: str, base_dir: str | None, reference: str | None = None) -> Scene:
    """Build a Scene from TOML text; ``source`` names it in error messages.

    ``reference`` is how a layout file finds it again (built-in name or path).
    """
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{source}: malformed TOML: {exc}") from None
    except RecursionError:
        raise InputError(f"{source}: TOML nested too deeply") from None
    _check_keys(data, _TOP_KEYS, source)
    design = _table(data, "design", source, required=True)
    _check_keys(design, _DESIGN_KEYS, f"{source}: [design]")
    tol_table = _table(data, "tolerance", source)
    _check_keys(tol_table, _TOLERANCE_KEYS, f"{source}: [tolerance]")
    found = _table(data, "foundation", source)
    _check_keys(found, _FOUNDATION_KEYS, f"{source}: [foundation]")

    name = _str(data, "name", source, default=Path(source).stem)
    kind = _str(data, "kind", source, default="3d")
    if kind not in SCENE_KINDS:
        raise InputError(f"{source}: kind must be one of {', '.join(SCENE_KINDS)}, not {shown(kind)}")
    block_type = _str(data, "block", source, default="shake-4t")
    try:
        block = get_block(block_type, base_dir)
    except InputError as exc:
        # A mesh's own errors name the mesh file; the scene file is named too, with its key.
        said = str(exc).removeprefix(f"block type {block_type!r}: ")
        raise InputError(f"{source}: block = {block_type!r}: {said}") from exc

    crest_width = _num(design, "crest_width_m", source, lo=0.0)
    height = _num(design, "height_m", source, lo=0.0, lo_open=True)
    length = _num(design, "length_m", source, lo=0.0, lo_open=True)
    rise_run = design.get("slope_rise_run")
    if (not isinstance(rise_run, list) or len(rise_run) != 2
            or not all(finite_number(v) and 0 < v < 1e6 for v in rise_run)
            or not 1e-3 <= rise_run[1] / rise_run[0] <= 1e3):
        raise InputError(f"{source}: [design] slope_rise_run must be two positive numbers below 1e6, "
                         "the run from 1/1000 to 1000 times the rise, e.g. [3, 4]")
    slope = float(rise_run[1]) / float(rise_run[0])
    wall = design.get("wall", False)
    if not isinstance(wall, bool):
        raise InputError(f"{source}: [design] wall must be true or false, not {shown(wall)}")
    for key, value in (("crest_width_m", crest_width), ("height_m", height), ("length_m", length)):
        if value > 10_000:
            raise InputError(f"{source}: [design] {key} = {value} m is not a breakwater")
    for key, value in (("height_m", height), ("length_m", length)):
        # A prism a hair long or high (1e-300 m) spans no volume that geometry can measure:
        # its coverage floor came out NaN, and later commands failed without naming the file.
        if value < MIN_DESIGN_M:
            raise InputError(f"{source}: [design] {key} = {value:g} m is less than {MIN_DESIGN_M:g} m")

    default = Allowance.table_ii(block.height)
    allowed = {}
    for key in sorted(_TOLERANCE_KEYS):
        field = key.removesuffix("_m")  # not ``name``: that is the scene's
        allowed[field] = _num(tol_table, key, source, default=getattr(default, field), lo=0.0)
        if allowed[field] > 10_000:
            raise InputError(f"{source}: [tolerance] {key} = {allowed[field]} m is more than any "
                             "length shoha takes (10000 m)")
    allowance = Allowance(**allowed)

    target = _num(data, "target_porosity_percent", source, default=56.0, lo=0.0, lo_open=True)
    if target >= 100.0:
        raise InputError(f"{source}: target_porosity_percent must be below 100")

    f_kind = _str(found, "kind", source, default="flat")
    if f_kind not in ("flat", "rough"):
        raise InputError(f"{source}: [foundation] kind must be flat or rough, not {shown(f_kind)}")
    amplitude = _num(found, "amplitude_m", source, default=0.0 if f_kind == "flat" else 0.1, lo=0.0)
    cell = _num(found, "cell_m", source, default=0.5, lo=0.05)
    seed = found.get("seed", 0)
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise InputError(f"{source}: [foundation] seed must be a non-negative integer")
    if f_kind == "rough" and amplitude > height:
        raise InputError(f"{source}: [foundation] amplitude_m exceeds the design height")

    scene = Scene(
        name=name, kind=kind, block_type=block_type, crest_width=crest_width, height=height,
        slope=slope, length=length, target_porosity=target, required_blocks=0,
        allowance=allowance, foundation=Foundation(), base_dir=base_dir, wall=wall,
    )
    try:
        zone = scene.tolerance
    except InputError as exc:
        raise InputError(f"{source}: {exc}") from None
    margin = 2.0 * block.bounding_radius
    extent = (-zone.bottom_half_width - margin, zone.bottom_half_width + margin,
              zone.y_start - margin, zone.y_end + margin)
    foundation = Foundation(f_kind, amplitude if f_kind == "rough" else 0.0, cell, seed, extent)
    if f_kind == "rough" and ((extent[1] - extent[0]) / cell) * ((extent[3] - extent[2]) / cell) > 4e6:
        raise InputError(f"{source}: [foundation] cell_m = {cell} m makes too fine a height field")
    if f_kind == "rough" and cell > min(extent[1] - extent[0], extent[3] - extent[2]):
        # One cell past the foundation holds no rubble to speak of (1e308 overflowed its area).
        raise InputError(f"{source}: [foundation] cell_m = {cell:g} m is wider than the foundation "
                         f"({extent[1] - extent[0]:.4g} by {extent[3] - extent[2]:.4g} m)")

    default_required = math.ceil((1 - target / 100) * scene.design_volume / block.volume - tol.relative)
    if "required_blocks" not in data and not 0 <= default_required <= 100_000:
        raise InputError(f"{source}: the design prism ({scene.design_volume:.4g} m³) takes "
                         f"{default_required} blocks of {block.volume:.4g} m³ at the target porosity; "
                         "at most 100000 are placed")
    required = data.get("required_blocks", default_required)
    if not isinstance(required, int) or isinstance(required, bool) or not 0 <= required <= 100_000:
        raise InputError(f"{source}: required_blocks must be an integer from 0 to 100000")

    return Scene(
        name=name, kind=kind, block_type=block_type, crest_width=crest_width, height=height,
        slope=slope, length=length, target_porosity=target, required_blocks=required,
        allowance=allowance, foundation=foundation, base_dir=base_dir, source=reference, wall=wall,
    )


def _check_keys(table: dict[str, Any], allowed: set[str], where: str) -> None:
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise InputError(f"{where}: unknown key {shown(unknown[0])} (allowed: {', '.join(sorted(allowed))})")


def _table(data: dict[str, Any], key: str, source: str, required: bool = False) -> dict[str, Any]:
    value = data.get(key)
    if value is None:
        if required:
            raise InputError(f"{source}: missing [{key}] table")
        return {}
    if not isinstance(value, dict):
        raise InputError(f"{source}: {key} must be a table")
    return value


def _num(table: dict[str, Any], key: str, source: str, default: float | None = None,
         lo: float | None = None, lo_open: bool = False) -> float:
    if key not in table:
        if default is None:
            raise InputError(f"{source}: missing {key}")
        return float(default)
    v = table[key]
    if not finite_number(v):
        raise InputError(f"{source}: {key} must be a finite number, not {shown(v)}")
    if lo is not None and (v < lo or (lo_open and v == lo)):
        raise InputError(f"{source}: {key} = {shown(v)} must be {'>' if lo_open else '>='} {lo}")
    return float(v)


#: A scene's text values (name, kind, block) are at most this long.
MAX_TEXT = 1000


def _str(table: dict[str, Any], key: str, source: str, default: str) -> str:
    """A text value: a string of at most ``MAX_TEXT`` printable characters. (A NUL in a name
    went through to every JSON answer and report; a path with one cannot be opened.)"""
    v = table.get(key, default)
    if not isinstance(v, str):
        raise InputError(f"{source}: {key} must be a string")
    if len(v) > MAX_TEXT:
        raise InputError(f"{source}: {key} is {len(v)} characters long; at most {MAX_TEXT}")
    if any(ord(c) < 32 or 127 <= ord(c) < 160 for c in v):
        raise InputError(f"{source}: {key} {v[:60]!r} holds a control character (a line break, a tab, a NUL)")
    return v
