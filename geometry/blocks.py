"""Wave-dissipating blocks: their solid, their convex pieces and their measures.

Built-in names (docs/contract.md, "Built-in names"):

``shake-4t``
    The 4-ton Shake Block of the reference paper, fitted to its Table I.
``tetrapod`` or ``tetrapod:H``
    A parametric tetrapod of height ``H`` metres (2.0 m by default).
``mesh:PATH``
    A user's watertight mesh (STL, OBJ or GLB), cut into convex pieces grown
    from its flat faces, or with CoACD where that does not fit; the pieces are
    cached on disk, keyed by the mesh hash.
``box:AxBxC``
    A rectangular block ``A`` by ``B`` by ``C`` metres, for tests and for
    section (2D) scenes.

Every block is given in its block frame: origin at its centroid, and for the
tetrapod-like blocks one leg along local +z, so that the block as given stands
on its other three legs. Its height ``H``, the ``H`` of Table II, is its height
standing on its most stable rest pose: for the built-in blocks, whose frames
are chosen so, its extent along local z; for a ``mesh:`` block, whose frame is
its file's and may be turned any way, that height worked out from its shape
(:attr:`Block.rest_poses`).
"""

from __future__ import annotations

import hashlib
import os
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from functools import cache, cached_property, lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

import manifold3d as m3
import numpy as np
import trimesh
from scipy.optimize import brentq
from scipy.spatial import HalfspaceIntersection

from .constants import CONCRETE_DENSITY, tol
from .errors import InputError
from .fileio import atomic_write, regular_file
from .polytope import ConvexPolytope, PieceStack

if TYPE_CHECKING:
    from .pose import Pose

#: Table I of the reference paper: the 4-ton Shake Block.
SHAKE_4T_VOLUME = 1.735  # m^3
SHAKE_4T_AREA = 9.796  # m^2

#: Largest user mesh accepted, in triangles. Manufacturer CAD of a block is a
#: few thousand; CoACD on millions would run for hours.
MAX_MESH_FACES = 500_000
#: Most corners of a mesh block's convex hull (a Shake Block's has 24; a ball cut into
#: 81 920 triangles, 40 962).
MAX_HULL_VERTICES = 20_000
#: A mesh file's largest size, checked before it is read: an ASCII STL of MAX_MESH_FACES
#: triangles is about 130 MB.
MAX_MESH_BYTES = 256 * 2**20


@dataclass(frozen=True, eq=False)
class Block:
    """A rigid concrete block.

    Attributes
    ----------
    name : str
        Its type name, as written in layout files.
    vertices : (n, 3) float, metres, block frame
        Vertices of its closed surface, centroid at the origin.
    faces : (m, 3) int
        Outward-facing triangles of that surface.
    pieces : tuple of ConvexPolytope, block frame
        Convex pieces whose union is the block (or, for a ``mesh:`` block
        CoACD cuts, covers it to CoACD's concavity threshold). The same pieces serve
        collision checks and physics.
    density : float, kg/m^3
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    pieces: tuple[ConvexPolytope, ...]
    density: float = CONCRETE_DENSITY
    #: Whether the block frame is the one its file came in, not one chosen to stand
    #: the block up (``mesh:`` blocks): its height is then taken from its rest poses.
    file_frame: bool = False

    @cached_property
    def stack(self) -> PieceStack:
        """The pieces stacked, to move them in one pass (the voxel porosity trackers)."""
        return PieceStack(self.pieces)

    @cached_property
    def manifold(self) -> m3.Manifold:
        """The solid as a manifold3d object, block frame."""
        return _manifold(self.vertices, self.faces, self.name)

    def posed_solid(self, pose: Pose) -> m3.Manifold:
        """The solid moved to ``pose`` (block frame to world frame), as a manifold3d object."""
        return self.manifold.transform(np.hstack([pose.rotation, pose.position[:, None]]))

    @cached_property
    def volume(self) -> float:
        """Volume, m^3."""
        return float(self.manifold.volume())

    @cached_property
    def surface_area(self) -> float:
        """Surface area, m^2."""
        return float(self.manifold.surface_area())

    @cached_property
    def depth(self) -> float:
        """The deepest a point inside the block can lie under its surface, at most, m: half its
        thinnest extent (of its oriented bounding box, which holds any ball inside it)."""
        return 0.5 * float(self.trimesh.bounding_box_oriented.primitive.extents.min())

    @cached_property
    def height(self) -> float:
        """Height H, m: its height standing on its most stable rest pose.

        The extent along local z for the built-in blocks; for a block in its
        file's frame, the extent along z of :attr:`rest_poses` ``[0]``.
        """
        if self.file_frame and self.rest_poses:
            return float(np.ptp(self.rest_poses[0].turn(self.vertices)[:, 2]))
        return float(np.ptp(self.vertices[:, 2]))

    @cached_property
    def rest_poses(self) -> tuple[RestPose, ...]:
        """How the block can rest on flat ground, most stable first (:func:`rest_poses`)."""
        return rest_poses(self.vertices)

    @property
    def mass(self) -> float:
        """Mass, kg."""
        return self.density * self.volume

    @cached_property
    def inertia(self) -> np.ndarray:
        """(3, 3) inertia tensor about the centroid, kg m^2, block frame."""
        return self.trimesh.moment_inertia * self.density

    @cached_property
    def bounding_radius(self) -> float:
        """Radius of the smallest origin-centred sphere holding the block, m."""
        return float(np.linalg.norm(self.vertices, axis=1).max())

    @cached_property
    def trimesh(self) -> trimesh.Trimesh:
        return trimesh.Trimesh(self.vertices, self.faces, process=False)

    def export(self, path: str | os.PathLike) -> None:
        """Write the block frame mesh; the format follows the suffix (stl, obj, glb)."""
        suffix = Path(path).suffix.lower().lstrip(".")
        if suffix not in ("stl", "obj", "glb"):
            raise InputError(f"{path}: block export takes .stl, .obj or .glb, not {suffix!r}")
        data = self.trimesh.export(file_type=suffix)
        atomic_write(Path(path), data if isinstance(data, bytes) else data.encode())


@dataclass(frozen=True, eq=False)
class RestPose:
    """One way a block rests on flat ground: a face of its convex hull down.

    Attributes
    ----------
    quaternion : (4,) float, scalar first
        The orientation (block frame to world) that puts the face down, its
        outward normal along -z.
    tip_deg : float, degrees
        How far it must be tipped before it falls over: the angle at the
        centroid between the vertical and the nearest edge of the face.
    margin : float, metres
        How far inside the face the centroid's projection lies.
    centroid_height : float, metres
        The centroid's height above the face.
    contacts : int
        Hull vertices on the face.
    symmetry : int
        The order of its symmetry about the vertical through the centroid: a
        turn of ``2 pi / symmetry`` brings the block onto itself (1 if none).
    """

    quaternion: np.ndarray
    tip_deg: float
    margin: float
    centroid_height: float
    contacts: int
    symmetry: int = 1

    def turn(self, points: np.ndarray) -> np.ndarray:
        """Block-frame points turned into this pose (about the centroid)."""
        from scipy.spatial.transform import Rotation

        return Rotation.from_quat(self.quaternion, scalar_first=True).apply(points)


#: A rest pose must resist a tip of at least this much to count (degrees): a block
#: balanced on a point or an edge is not at rest on its own.
MIN_TIP_DEG = 1.0


def rest_poses(vertices: np.ndarray) -> tuple[RestPose, ...]:
    """The stable ways a solid with these vertices (centroid at the origin) rests on flat ground.

    Each facet of the convex hull is a candidate: the solid rests on it when
    the centroid's projection lies inside the facet, by at least
    :data:`MIN_TIP_DEG` of tipping. Orientations that differ only by a turn
    about the vertical (the same facet up to the block's symmetry) count once.
    Most stable (largest tipping angle) first.
    """
    from scipy.spatial import ConvexHull, QhullError
    from scipy.spatial.transform import Rotation

    v = np.asarray(vertices, dtype=float)
    hull = ConvexHull(v)
    scale = float(np.ptp(v, axis=0).max())
    _, first, plane = np.unique(np.round(hull.equations / max(scale, tol.length_floor) * 1e6), axis=0,
                                return_index=True, return_inverse=True)
    carries = np.zeros(len(first), bool)
    carries[plane.ravel()[_under_centroid(hull, scale)]] = True
    out: list[RestPose] = []
    seen: set[tuple] = set()
    for i in sorted(first[carries]):
        n, d = hull.equations[i, :3], -hull.equations[i, 3]  # the facet is n . p = d, n outward
        on = np.abs(v @ n - d) <= 1e-6 * scale
        turn, _ = Rotation.align_vectors([[0.0, 0.0, -1.0]], [n])
        flat = turn.apply(v[on])[:, :2]
        foot = turn.apply(d * n)[:2]  # the centroid's projection onto the facet
        if len(flat) < 3:
            continue
        try:
            outline = ConvexHull(flat)
        except QhullError:
            continue
        margin = float(np.min(-(outline.equations[:, :2] @ foot + outline.equations[:, 2])))
        tip = float(np.degrees(np.arctan2(margin, d)))
        if margin <= 0.0 or tip < MIN_TIP_DEG:
            continue
        # The same pose turned about the vertical has the same heights: one signature.
        signature = tuple(np.round(np.sort(turn.apply(v)[:, 2]) / scale, 4))
        if signature in seen:
            continue
        seen.add(signature)
        turned = turn.apply(v[hull.vertices])
        out.append(RestPose(turn.as_quat(scalar_first=True), tip, margin, float(d), int(on.sum()),
                            _vertical_symmetry(turned, scale)))
    out.sort(key=lambda r: -r.tip_deg)
    return tuple(out)


def _under_centroid(hull, scale: float) -> np.ndarray:
    """Which of the hull's triangles hold the foot of the centroid (the origin) on their plane.

    A facet can carry the solid only where that foot is inside it, and so on one
    of its triangles: facets with none are left out before the outline of each
    is drawn (a 5000-facet sphere took 2.2 s, 0.2 ms a facet). Degenerate
    triangles are kept, to be judged as before.
    """
    tri = hull.points[hull.simplices]  # (f, 3, 3)
    foot = -hull.equations[:, 3:] * hull.equations[:, :3]
    # Barycentric coordinates of the foot in each triangle (in its plane).
    e1, e2, w = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], foot - tri[:, 0]
    d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    w1, w2 = (w * e1).sum(1), (w * e2).sum(1)
    det = d11 * d22 - d12 * d12
    flat = det <= 1e-18 * scale**4
    det = np.where(flat, 1.0, det)
    u, v = (d22 * w1 - d12 * w2) / det, (d11 * w2 - d12 * w1) / det
    slack = 1e-9
    return flat | ((u >= -slack) & (v >= -slack) & (u + v <= 1 + slack))


#: Orders of symmetry about the vertical that :func:`rest_poses` looks for, highest first.
SYMMETRY_ORDERS = (6, 4, 3, 2)


def _vertical_symmetry(points: np.ndarray, scale: float) -> int:
    """The highest order k in :data:`SYMMETRY_ORDERS` whose turn about z maps ``points`` onto themselves."""
    from scipy.spatial import cKDTree

    tree = cKDTree(points)
    for k in SYMMETRY_ORDERS:
        c, s = np.cos(2 * np.pi / k), np.sin(2 * np.pi / k)
        turned = points @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
        if tree.query(turned)[0].max() <= 1e-4 * scale:
            return k
    return 1


# --- registry -----------------------------------------------------------------


def mesh_path(name: str, base_dir: str | os.PathLike | None = None) -> Path | None:
    """The file a ``mesh:PATH`` block type names, a relative one resolved against ``base_dir``
    as :func:`get_block` resolves it; None for any other type."""
    if not name.startswith("mesh:"):
        return None
    path = Path(name[5:]).expanduser()
    if not path.is_absolute() and base_dir is not None:
        path = Path(base_dir) / path
    return path.resolve()


def get_block(name: str, base_dir: str | os.PathLike | None = None) -> Block:
    """The block a type name stands for.

    Parameters
    ----------
    name : str
        ``shake-4t``, ``tetrapod``, ``tetrapod:H``, ``box:AxBxC`` or ``mesh:PATH``.
    base_dir : path, optional
        Where a relative ``mesh:PATH`` is resolved (the layout file's folder).

    Raises
    ------
    InputError
        For an unknown name, bad parameters or a bad mesh.
    """
    if not isinstance(name, str):
        raise InputError(f"block type must be a string, not {type(name).__name__}")
    if name == "shake-4t":
        return shake_block()
    sized = _sizes(name)
    if sized is not None:
        kind, *sizes = sized
        if kind == "tetrapod":
            return tetrapod(sizes[0])
        check_aspect(sizes, f"block type {name!r}")
        return box_block(*sizes)
    path = mesh_path(name, base_dir)
    if path is not None:
        return mesh_block(str(path), name)
    raise InputError(
        f"unknown block type {name!r}: use shake-4t, tetrapod[:H], box:AxBxC or mesh:PATH"
    )


#: The sizes a block may have, metres: a box's edges, a tetrapod's height, a mesh's extent.
MIN_SIZE, MAX_SIZE = 0.05, 100.0
#: How many times its thinnest extent a block may be across. A search steps over a mound in
#: steps of about a block's thinnest size: a mesh 1 m square and 1e-7 m thick ran a
#: 5 s ``optimize`` past 60 s and 900 MB, listing pattern sites. The slender 6 x 0.3 x 0.3 m
#: beams of ``benchmarks/time_limits.py`` are 20.
MAX_ASPECT = 50.0


def check_aspect(extents: Sequence[float], what: str) -> None:
    """Refuse a block thinner than ``MIN_SIZE`` or more than ``MAX_ASPECT`` times as wide as thin."""
    thin, wide = float(min(extents)), float(max(extents))
    if thin < MIN_SIZE or wide > MAX_ASPECT * thin:
        raise InputError(f"{what}: the block is {wide:g} m across and {thin:g} m thin; a block is at "
                         f"least {MIN_SIZE:g} m thin and at most {MAX_ASPECT:g} times as wide as thin")


def plain_number(text: str) -> bool:
    """Whether ``text`` is written as a number is in a file: ASCII, with no ``_`` (Python's
    ``float`` and ``int`` read ``1_0`` as 10 and Arabic-Indic ``٣`` as 3)."""
    return text.isascii() and "_" not in text


def size_key(name: str) -> tuple | None:
    """A built-in block's kind and sizes, for telling two spellings of one size apart from two
    sizes (``tetrapod``, ``tetrapod:2`` and ``tetrapod:2.0`` are one), without building it;
    None for a name of no size (``shake-4t``, ``mesh:PATH``) or one that does not parse."""
    try:
        return _sizes(name)
    except InputError:
        return None


def _sizes(name: str) -> tuple | None:
    """``("tetrapod", H)`` or ``("box", A, B, C)`` for a sized built-in name (``tetrapod`` is
    2 m high); None for any other name. Raises InputError for sizes that do not parse."""
    if name == "tetrapod":
        return ("tetrapod", 2.0)
    if name.startswith("tetrapod:"):
        return ("tetrapod", *_parse_floats(name, name[len("tetrapod:"):], 1))
    if name.startswith("box:"):
        return ("box", *_parse_floats(name, name[4:].replace("x", ","), 3))
    return None


def _parse_floats(name: str, text: str, n: int) -> list[float]:
    try:
        values = [float(v) for v in text.split(",")] if plain_number(text) else []
    except ValueError:
        values = []
    if len(values) != n or not all(np.isfinite(v) and MIN_SIZE <= v <= MAX_SIZE for v in values):
        raise InputError(f"block type {name!r}: expected {n} size(s) between {MIN_SIZE:g} and {MAX_SIZE:g} m")
    return values


# --- shake-4t -------------------------------------------------------------------

# Directions of the four legs: leg 0 along +z (docs/contract.md), legs 1-3 at the
# tetrahedral angle arccos(-1/3) from it, 120 degrees apart in azimuth.
_S = np.sqrt(8.0 / 9.0)
LEG_DIRECTIONS = np.array(
    [[0.0, 0.0, 1.0]]
    + [[_S * np.cos(2 * np.pi * k / 3), _S * np.sin(2 * np.pi * k / 3), -1.0 / 3.0] for k in range(3)]
)

# Shape ratios of the Shake Block model, as fractions of the circumradius R of
# the underlying regular tetrahedron. The maker describes the block as a
# chamfered, truncated regular tetrahedron with four hexagonal-prism legs; the
# ratios below give that look, and the leg length is then fitted so that
# area / volume^(2/3) matches Table I, and R so that the volume does.
_SHAKE_TRUNCATION = 0.40  # vertex cut at d_i . p = 0.40 R
_SHAKE_CHAMFER = 0.50  # edge cut at m_ij . p = 0.50 R (edge midpoints lie at 0.577 R)
_SHAKE_LEG_RADIUS = 0.22  # circumradius of the hexagonal leg section
_SHAKE_LEG_EMBED = 0.10  # legs start 0.1 R inside the body, so the union is a clean boolean


def _shake_pieces(radius: float, leg_length: float) -> list[np.ndarray]:
    """Vertex sets of the Shake Block's five convex pieces (body, four legs)."""
    d = LEG_DIRECTIONS
    normals, offsets = [], []
    for i in range(4):
        normals += [-d[i], d[i]]
        offsets += [radius / 3.0, _SHAKE_TRUNCATION * radius]
    for i in range(4):
        for j in range(i + 1, 4):
            m = d[i] + d[j]
            normals.append(m / np.linalg.norm(m))
            offsets.append(_SHAKE_CHAMFER * radius)
    hs = np.hstack([np.array(normals), -np.array(offsets)[:, None]])
    body = HalfspaceIntersection(hs, np.zeros(3)).intersections
    pieces = [body]
    angles = np.arange(6) * np.pi / 3 + np.pi / 6
    for i in range(4):
        # Orient each hexagon towards a neighbouring leg, so that all four legs
        # look alike under the block's tetrahedral symmetry.
        toward = d[1] if i == 0 else d[0]
        u = toward - d[i] * (toward @ d[i])
        u /= np.linalg.norm(u)
        v = np.cross(d[i], u)
        ring = _SHAKE_LEG_RADIUS * radius * (np.cos(angles)[:, None] * u + np.sin(angles)[:, None] * v)
        start = (_SHAKE_TRUNCATION - _SHAKE_LEG_EMBED) * radius
        end = (_SHAKE_TRUNCATION + leg_length) * radius
        pieces.append(np.vstack([start * d[i] + ring, end * d[i] + ring]))
    return pieces


def _union_of_hulls(pieces: list[np.ndarray]) -> m3.Manifold:
    return m3.Manifold.batch_boolean([m3.Manifold.hull_points(p) for p in pieces], m3.OpType.Add)


@cache
def shake_fit() -> tuple[float, float]:
    """Fitted ``(R, leg_length)`` of the Shake Block model (R in m, leg length in R)."""

    def shape_ratio(leg: float) -> float:
        u = _union_of_hulls(_shake_pieces(1.0, leg))
        return u.surface_area() / u.volume() ** (2.0 / 3.0)

    target = SHAKE_4T_AREA / SHAKE_4T_VOLUME ** (2.0 / 3.0)
    leg = brentq(lambda x: shape_ratio(x) - target, 0.05, 0.6, xtol=tol.fit)
    unit_volume = _union_of_hulls(_shake_pieces(1.0, leg)).volume()
    return (SHAKE_4T_VOLUME / unit_volume) ** (1.0 / 3.0), leg


@cache
def shake_block() -> Block:
    """The ``shake-4t`` block: volume 1.735 m^3 and area 9.796 m^2 (Table I)."""
    radius, leg = shake_fit()
    pieces = _shake_pieces(radius, leg)
    return _block_from_union("shake-4t", _union_of_hulls(pieces), pieces)


# --- tetrapod ------------------------------------------------------------------

# Tetrapod proportions: legs are truncated cones from the centre, narrowing at
# 10 degrees (the issue's "about 10°"; the inventors' patent gives a half-angle
# of 9-14 degrees). The base diameter is 0.85 of the leg length, the patent's
# lower bound for leg length : base width (0.85-1.15), which gives a volume of
# about 0.28 H^3, the figure commonly quoted for tetrapods.
_TETRAPOD_BASE_RADIUS = 0.425
_TETRAPOD_TAPER = np.radians(10.0)
_TETRAPOD_SIDES = 12  # a 12-gon keeps each leg a small convex piece for FCL


@cache
def tetrapod(height: float = 2.0) -> Block:
    """A tetrapod of standing height ``height`` metres.

    Its legs are truncated cones along the tetrahedral directions. The leg
    length L (centre to tip face) follows from the height: the upper tip is at
    ``z = L`` and the lowest point is the rim of a lower tip face, at
    ``z = -L/3 - r_tip sqrt(8/9)``.
    """
    tip_ratio = _TETRAPOD_BASE_RADIUS - np.tan(_TETRAPOD_TAPER)
    length = height / (4.0 / 3.0 + tip_ratio * _S)
    angles = np.arange(_TETRAPOD_SIDES) * 2 * np.pi / _TETRAPOD_SIDES
    pieces = []
    for i, d in enumerate(LEG_DIRECTIONS):
        toward = LEG_DIRECTIONS[1] if i == 0 else LEG_DIRECTIONS[0]
        u = toward - d * (toward @ d)
        u /= np.linalg.norm(u)
        v = np.cross(d, u)
        ring = np.cos(angles)[:, None] * u + np.sin(angles)[:, None] * v
        base = _TETRAPOD_BASE_RADIUS * length * ring
        tip = length * d + tip_ratio * length * ring
        pieces.append(np.vstack([base, tip]))
    return _block_from_union(f"tetrapod:{height:g}", _union_of_hulls(pieces), pieces)


# --- box -------------------------------------------------------------------------


@cache
def box_block(a: float, b: float, c: float) -> Block:
    """A rectangular block of ``a`` x ``b`` x ``c`` metres along local x, y, z."""
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    corners *= np.array([a, b, c]) / 2.0
    return _block_from_union(f"box:{a:g}x{b:g}x{c:g}", m3.Manifold.hull_points(corners), [corners])


# --- mesh:PATH ---------------------------------------------------------------------


def cache_dir() -> Path:
    """Where mesh decompositions are cached: ``$SHOHA_CACHE`` or ``~/.cache/shoha``."""
    return Path(os.environ.get("SHOHA_CACHE", Path.home() / ".cache" / "shoha"))


@lru_cache(maxsize=64)
def mesh_block(path: str, name: str | None = None) -> Block:
    """A block from a user's watertight mesh file.

    The mesh is moved so that its centroid is the block frame's origin; its
    orientation is kept. Its convex pieces are grown from its flat faces
    (:func:`_facet_pieces`), or where that does not fit cut by CoACD; either is
    cached in :func:`cache_dir`, keyed by the SHA-256 of the file and the settings.

    Raises
    ------
    InputError
        If the file is missing or unreadable, or the mesh is not a watertight,
        consistently wound solid of positive volume.
    """
    name = name or f"mesh:{path}"
    p = Path(path)
    size = regular_file(p).st_size  # not a folder, device or pipe (a pipe blocks its reader)
    if size > MAX_MESH_BYTES:
        raise InputError(f"{path}: mesh file is {size} bytes, more than {MAX_MESH_BYTES}")
    try:
        raw = p.read_bytes()
    except OSError as exc:  # /proc/self/mem said only "Input/output error"
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    digest = hashlib.sha256(raw).hexdigest()
    vertices, faces = _load_mesh(p)
    mesh = trimesh.Trimesh(vertices, faces, process=True)
    if len(mesh.faces) > MAX_MESH_FACES:
        raise InputError(f"{path}: mesh has {len(mesh.faces)} triangles, more than {MAX_MESH_FACES}")
    if not mesh.is_watertight:
        raise InputError(f"{path}: mesh is not watertight (it has holes or open edges)")
    if not mesh.is_winding_consistent:
        raise InputError(f"{path}: mesh triangles are not consistently wound")
    if (bodies := mesh.body_count) > 1:
        # Two closed shells, overlapping or apart, are not one block: two overlapping unit
        # cubes were read as 2.0 m3 where the solid they make is 1.875 m3.
        raise InputError(f"{path}: mesh has {bodies} separate closed shells; a block is one solid "
                         "(join them into one, a union, before exporting)")
    size = float(np.ptp(mesh.vertices, axis=0).max())
    if not MIN_SIZE <= size <= MAX_SIZE:
        raise InputError(f"{path}: the block is {size:g} m across, and blocks are {MIN_SIZE:g} to "
                         f"{MAX_SIZE:g} m (mesh files are read in metres: one in millimetres "
                         "must be scaled by 0.001)")
    if mesh.volume <= tol.volume:
        if mesh.volume < -tol.volume:
            mesh.invert()
        else:
            raise InputError(f"{path}: mesh encloses no volume")
    hull = len(np.unique(mesh.convex_hull.faces))
    if hull > MAX_HULL_VERTICES:
        # Its rest poses look at every facet of the hull that carries the centroid: on a ball of
        # 327 680 triangles each of them does, and `shoha block info` ran past 10 minutes.
        raise InputError(f"{path}: the block's convex hull has {hull} corners, more than "
                         f"{MAX_HULL_VERTICES}; simplify (decimate) the mesh: its rest poses and pieces "
                         "are found from them")
    check_aspect(mesh.bounding_box_oriented.primitive.extents, str(path))
    centroid = np.asarray(mesh.center_mass)
    if not rest_poses(mesh.vertices - centroid):
        # Placement hangs a block as it rests on flat ground; a rounded solid has no such
        # pose (an ellipsoid's hull facets all tip), and its search had no hanging at all.
        raise InputError(f"{path}: the block rests stably on none of its faces (each tips under "
                         f"{MIN_TIP_DEG:g} degree), so a crane cannot set it down in a known pose")
    solid = _manifold(mesh.vertices, mesh.faces, path)
    solid = solid.translate(-centroid)
    pieces = _facet_pieces(mesh.vertices - centroid, mesh.faces, solid, digest, path)
    if pieces is None:
        pieces = _coacd_pieces(mesh.vertices - centroid, mesh.faces, digest, path)
    return _block_from_union(name, solid, pieces, file_frame=True)


def _load_mesh(p: Path) -> tuple[np.ndarray, np.ndarray]:
    suffix = p.suffix.lower().lstrip(".")
    if suffix not in ("stl", "obj", "glb"):
        raise InputError(f"{p}: mesh blocks take .stl, .obj or .glb, not {suffix!r}")
    if suffix == "stl":
        _check_stl(p)
    try:
        loaded = trimesh.load(str(p), file_type=suffix, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types on malformed files
        # The reader's own words where they are about the file; an index or a key out of
        # range in its code says only that the file is malformed (stop 77's probe showed
        # "IndexError: index 98 is out of bounds" for an OBJ face naming a missing vertex).
        why = ("its faces or fields name parts it does not have" if isinstance(exc, (IndexError, KeyError))
               else str(exc) or type(exc).__name__)
        raise InputError(f"{p}: cannot read the mesh as .{suffix}: {why}") from exc
    vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=float)
    faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    if len(faces) == 0:
        raise InputError(f"{p}: mesh has no triangles")
    if len(faces) < 4 or len(vertices) < 4:
        raise InputError(f"{p}: mesh has {len(faces)} triangle(s) and {len(vertices)} vertices; "
                         "a block is a closed solid, at least a tetrahedron")
    if not np.isfinite(vertices).all():
        raise InputError(f"{p}: mesh has non-finite vertex coordinates")
    return vertices, faces


def _check_stl(p: Path) -> None:
    """An STL file is binary (an 80-byte header, a triangle count, 50 bytes a triangle) or
    ASCII text beginning with ``solid``; anything else is refused before trimesh guesses at it
    (it tries to decode unknown bytes as text, and fails with errors about that)."""
    with p.open("rb") as f:
        head = f.read(84)
    size = p.stat().st_size
    if size == 0:
        raise InputError(f"{p}: the mesh file is empty")
    if len(head) == 84 and 84 + 50 * int.from_bytes(head[80:84], "little") == size:
        return  # trimesh reads a binary file only at exactly this size
    if head.lstrip(b"\xef\xbb\xbf \t\r\n").lower().startswith(b"solid"):
        return
    raise InputError(f"{p}: not an STL file: neither binary (its size does not match its triangle "
                     "count) nor ASCII (it does not begin with 'solid')")


# Facet growing (_facet_pieces): how much of a piece may lie outside the block, as a
# share of its volume; the most hull tests before CoACD is used instead. Part of the
# cache key with the version.
_FACET_OUTSIDE = 1e-4
_FACET_MAX_TESTS = 1500
_FACET_VERSION = 2


def _facet_pieces(vertices: np.ndarray, faces: np.ndarray, solid: m3.Manifold, digest: str, path: str
                  ) -> list[np.ndarray] | None:
    """Convex pieces grown from the mesh's own flat faces, or None where that does not fit.

    Most block meshes are made as a union of convex solids (a body and its
    legs), and each solid's visible faces span it. Coplanar faces are taken
    together; from the largest not yet used, a piece grows by the faces
    next to it while the hull of its vertices stays inside the block (at
    most ``_FACET_OUTSIDE`` of the block's volume outside). What no hull
    covers (where legs meet inside the body) is added as the hull of that
    region where it lies inside too. On the exported Shake Block, turned
    and moved, this finds the block's own 5 pieces, exactly, where CoACD
    gave 16 whose union is 0.7 % larger; a drop on 16 pieces took four
    times as long. A curved or hollow mesh (many faces, no flat parts to
    grow) ends the growth after ``_FACET_MAX_TESTS`` hull tests, or gives
    more pieces than CoACD may, and CoACD decomposes it instead (None).
    The outcome is cached by the mesh's hash.
    """
    key = f"{digest}-facets-v{_FACET_VERSION}-o{_FACET_OUTSIDE}-n{_FACET_MAX_TESTS}-h{_COACD_MAX_HULLS}"
    cached = cache_dir() / "pieces" / f"{key}.npz"
    if cached.is_file():
        with np.load(cached) as data:
            return [data[k] for k in sorted(data.files, key=lambda s: int(s[1:]))] or None
    pieces = _grow_facets(np.asarray(vertices, float), np.asarray(faces, np.int64), solid, path)
    cached.parent.mkdir(parents=True, exist_ok=True)
    tmp = cached.with_suffix(f".{os.getpid()}.tmp.npz")
    np.savez(tmp, **{f"p{i}": v for i, v in enumerate(pieces or [])})
    os.replace(tmp, cached)
    return pieces


def _grow_facets(vertices: np.ndarray, faces: np.ndarray, solid: m3.Manifold, path: str
                 ) -> list[np.ndarray] | None:
    """The growth of :func:`_facet_pieces`, uncached; it stops at the deadline :func:`cut_by` set."""
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    limit = _FACET_OUTSIDE * solid.volume()
    tests = 0
    deadline = _CUT_DEADLINE.get()

    def outside(points: np.ndarray) -> float:
        nonlocal tests
        tests += 1
        if deadline is not None and time.monotonic() > deadline:
            raise _too_long(path)
        return (m3.Manifold.hull_points(points) - solid).volume()

    grouped = np.zeros(len(faces), bool)
    units = [np.asarray(f) for f in mesh.facets]
    for f in units:
        grouped[f] = True
    units += [np.array([i]) for i in np.flatnonzero(~grouped)]
    unit_vertices = [np.unique(faces[u]) for u in units]
    area = np.array([mesh.area_faces[u].sum() for u in units])
    at_vertex: dict[int, set[int]] = {}
    for k, vs in enumerate(unit_vertices):
        for v in vs.tolist():
            at_vertex.setdefault(v, set()).add(k)
    beside = [set().union(*(at_vertex[v] for v in vs.tolist())) - {k} for k, vs in enumerate(unit_vertices)]
    used = np.zeros(len(units), bool)
    groups: list[np.ndarray] = []
    for seed in np.argsort(-area, kind="stable").tolist():
        if used[seed]:
            continue
        members, points, refused = {seed}, set(unit_vertices[seed].tolist()), set()
        grew = True
        while grew:
            grew = False
            for k in sorted(set().union(*(beside[m] for m in members)) - members - refused,
                            key=lambda k: -area[k]):
                if tests >= _FACET_MAX_TESTS:
                    return None
                more = points | set(unit_vertices[k].tolist())
                if outside(vertices[sorted(more)]) <= limit:
                    members.add(k)
                    points, grew = more, True
                else:
                    refused.add(k)
        used[list(members)] = True
        groups.append(vertices[sorted(points)])
        if len(groups) > _COACD_MAX_HULLS:
            return None
    # A flat hull holds nothing (one face of a ring of boxes grew no further).
    hulls = [h for h in (m3.Manifold.hull_points(g) for g in groups) if h.volume() > limit]
    # A piece inside the others adds nothing; the smallest go first.
    for i in sorted(range(len(hulls)), key=lambda i: hulls[i].volume()):
        rest = [h for j, h in enumerate(hulls) if j != i and h is not None]
        if rest and (hulls[i] - m3.Manifold.batch_boolean(rest, m3.OpType.Add)).volume() <= limit:
            hulls[i] = None
    hulls = [h for h in hulls if h is not None]
    if not hulls:
        return None
    missed = solid - m3.Manifold.batch_boolean(hulls, m3.OpType.Add)
    for part in missed.decompose() if missed.volume() > limit else []:
        points = np.asarray(part.to_mesh64().vert_properties, float)[:, :3]
        if len(points) >= 4 and part.volume() > limit and outside(points) <= limit:
            hulls.append(m3.Manifold.hull_points(points))
    # Pieces that leave part of the block out would let others pass through it: CoACD then.
    if len(hulls) > _COACD_MAX_HULLS:
        return None
    if (solid - m3.Manifold.batch_boolean(hulls, m3.OpType.Add)).volume() > limit:
        return None
    return [np.asarray(h.to_mesh64().vert_properties, float)[:, :3] for h in hulls]


# CoACD settings; part of the cache key, so changing one re-decomposes.
_COACD_THRESHOLD = 0.05
_COACD_MAX_HULLS = 16
_COACD_SEED = 0


def _decomposition_frame(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """A rotation that lines a mesh's two largest flat directions up with z and x.

    CoACD cuts along the axes of the frame it is given. A block's file may
    come turned any way: the exported Shake Block turned by an arbitrary
    rotation decomposed into pieces whose union is 4.4 % larger than the
    block, against 1.1 % when first turned by this frame. Face normals are
    grouped by direction (a normal and its opposite are one), weighted by
    area; the heaviest group is z, and the heaviest one near square to it is x.

    Returns
    -------
    (3, 3) float
        Rows: the frame's axes in the mesh's frame (``vertices @ R.T`` is the
        mesh in the frame, ``local @ R`` back).
    """
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = np.linalg.norm(cross, axis=1)
    keep = area > 0.0
    normal, area = cross[keep] / area[keep, None], area[keep]
    largest = np.abs(normal).argmax(axis=1)
    normal *= np.sign(normal[np.arange(len(normal)), largest])[:, None]  # one sign per direction
    groups, member = np.unique(np.round(normal / 0.02).astype(np.int64), axis=0, return_inverse=True)
    member = member.ravel()
    weight = np.bincount(member, weights=area, minlength=len(groups))
    mean = np.zeros((len(groups), 3))
    np.add.at(mean, member, normal * area[:, None])
    mean /= np.linalg.norm(mean, axis=1)[:, None]
    order = np.argsort(-weight, kind="stable")
    z = mean[order[0]]
    x = next((mean[j] for j in order[1:] if abs(mean[j] @ z) < 0.05), np.eye(3)[np.abs(z).argmin()])
    x = x - (x @ z) * z
    x /= np.linalg.norm(x)
    return np.array([x, np.cross(z, x), z])


#: When a mesh's first CoACD cut must be done by (``time.monotonic()``), or None: no limit.
_CUT_DEADLINE: ContextVar[float | None] = ContextVar("cut_deadline", default=None)


@contextmanager
def cut_by(deadline: float | None) -> Iterator[None]:
    """Within this block, a mesh block's CoACD cut must end by ``deadline`` (``time.monotonic()``).

    A command with a time limit (``shoha optimize --time-limit``) reads its
    scene in here: the cut, which for a curved mesh can take longer than the
    whole limit, then runs in a child process that is stopped at the deadline,
    and the block is refused with :class:`CutTooLong`. A cut that ends is
    cached as any other, so it is made once.
    """
    token = _CUT_DEADLINE.set(deadline)
    try:
        yield
    finally:
        _CUT_DEADLINE.reset(token)


class CutTooLong(InputError):
    """A mesh's CoACD cut did not end by the deadline :func:`cut_by` set."""


def _too_long(path: str) -> CutTooLong:
    return CutTooLong(f"{path}: cutting the mesh into convex pieces takes longer than the time limit "
                      f"leaves; cut it once with `shoha block info mesh:{path}` (it is cached), or give "
                      "a longer --time-limit")


def _coacd_pieces(
    vertices: np.ndarray, faces: np.ndarray, digest: str, path: str
) -> list[np.ndarray]:
    key = f"{digest}-t{_COACD_THRESHOLD}-h{_COACD_MAX_HULLS}-s{_COACD_SEED}-framed"
    cached = cache_dir() / "coacd" / f"{key}.npz"
    if not cached.is_file():
        try:
            import coacd  # noqa: F401  (the cut, maybe in a child, imports it again)
        except ImportError as exc:  # pragma: no cover - coacd is a dependency
            raise InputError(f"{path}: mesh blocks need CoACD (pip install coacd)") from exc
        deadline = _CUT_DEADLINE.get()
        if deadline is None:
            _cut(vertices, faces, cached)
        else:
            _cut_within(vertices, faces, cached, deadline, path)
    with np.load(cached) as data:
        return [data[k] for k in sorted(data.files, key=lambda s: int(s[1:]))]


def _cut(vertices: np.ndarray, faces: np.ndarray, cached: Path) -> None:
    """Cut the mesh with CoACD, in its decomposition frame, into the cache file ``cached``."""
    import coacd

    coacd.set_log_level("error")
    frame = _decomposition_frame(np.asarray(vertices, float), np.asarray(faces))
    parts = coacd.run_coacd(
        coacd.Mesh(np.asarray(vertices, float) @ frame.T, np.asarray(faces, np.int32)),
        threshold=_COACD_THRESHOLD,
        max_convex_hull=_COACD_MAX_HULLS,
        seed=_COACD_SEED,
    )
    pieces = [np.asarray(v, float) @ frame for v, _ in parts]
    cached.parent.mkdir(parents=True, exist_ok=True)
    tmp = cached.with_suffix(f".{os.getpid()}.tmp.npz")
    np.savez(tmp, **{f"p{i}": v for i, v in enumerate(pieces)})
    os.replace(tmp, cached)


def _cut_within(vertices: np.ndarray, faces: np.ndarray, cached: Path, deadline: float, path: str) -> None:
    """:func:`_cut` in a child process, stopped at ``deadline`` (CoACD cannot be interrupted)."""
    import multiprocessing

    child = multiprocessing.get_context("spawn").Process(
        target=_cut, args=(np.asarray(vertices, float), np.asarray(faces), cached), daemon=True)
    child.start()
    child.join(max(0.0, deadline - time.monotonic()))
    if child.is_alive():
        child.terminate()
        child.join()
        cached.with_suffix(f".{child.pid}.tmp.npz").unlink(missing_ok=True)
        raise _too_long(path)
    if child.exitcode != 0 or not cached.is_file():
        raise InputError(f"{path}: CoACD could not cut the mesh into convex pieces "
                         f"(exit status {child.exitcode})")


# --- shared construction ---------------------------------------------------------------


def _manifold(vertices: np.ndarray, faces: np.ndarray, name: str) -> m3.Manifold:
    mesh = m3.Mesh64(
        np.ascontiguousarray(vertices, dtype=np.float64),
        np.ascontiguousarray(faces, dtype=np.uint64),
    )
    solid = m3.Manifold(mesh)
    if solid.status() != m3.Error.NoError or solid.is_empty():
        raise InputError(f"{name}: mesh is not a closed manifold solid ({solid.status().name})")
    return solid


def _block_from_union(name: str, solid: m3.Manifold, pieces: list[np.ndarray],
                      file_frame: bool = False) -> Block:
    """Build a Block from its solid, moved so that its centroid is the origin."""
    out = solid.to_mesh64()
    vertices = np.asarray(out.vert_properties, dtype=float)[:, :3]
    faces = np.asarray(out.tri_verts, dtype=np.int64)
    centroid = trimesh.Trimesh(vertices, faces, process=False).center_mass
    polys = tuple(ConvexPolytope.from_points(p - centroid, name=f"{name} piece") for p in pieces)
    return Block(name, vertices - centroid, faces, polys, file_frame=file_frame)
