"""Lowering a block along -z until it first touches, as a crane lowers it.

The resting height of a block lowered from above onto what is already placed
is decided piece by piece. For a moving convex piece P and a placed convex
piece Q, the block must rise above ``top_Q(x, y) - bottom_P(x, y)`` on every
vertical line through both. That difference is concave over the overlap of
their footprints (top_Q is concave, bottom_P convex), so its maximum lies on a
vertex of the arrangement of their projected edges: a projected vertex of
either piece, or a crossing of a projected edge of each. Evaluating the exact
vertical extent of both pieces at those points gives the first-contact height
exactly, with no stepping: :func:`geometry.polytope.column_intervals` point by
point, in a loop compiled by numba (:mod:`optimizer.search._contact`), since the
numpy call's cost on a few dozen points was most of a drop's time. Pairs are
visited in order of their best possible height and the search stops once no
pair can beat the height found.

The foundation is the plane z = 0, or a rough height field sampled at its
nodes and at the block's lower vertices.
"""

from __future__ import annotations

import functools
import weakref
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linprog

from geometry.blocks import Block
from geometry.constants import tol
from geometry.polytope import ConvexPolytope
from geometry.pose import Pose, quat_to_matrix
from geometry.scene import Foundation


@dataclass(frozen=True, eq=False)
class Shape:
    """A block's pieces turned to one orientation, positioned at the origin.

    Attributes
    ----------
    quaternion : (4,) float
    pieces : list of ConvexPolytope, world orientation, block centroid at the origin
    lows : (k,) float, metres: lowest z of each piece
    highs : (k,) float, metres: highest z of each piece
    xy_boxes : (k, 2, 2) float, metres: footprint boxes of the pieces
    radius_xy : float, metres: footprint radius about the centroid
    lower, upper : list of (edges (e, 2, 3), vertices (v, 3)) per piece
        The edges and vertices of each piece's downward-facing (lower) and
        upward-facing (upper) faces: only a moving piece's lower side and a
        fixed piece's upper side can meet first.
    """

    block: Block
    quaternion: np.ndarray
    pieces: list[ConvexPolytope]
    lows: np.ndarray
    highs: np.ndarray
    xy_boxes: np.ndarray
    radius_xy: float
    lower: list[tuple[np.ndarray, np.ndarray]] = field(repr=False)
    upper: list[tuple[np.ndarray, np.ndarray]] = field(repr=False)
    vertices_xy: np.ndarray = field(repr=False, default=None)  # (v, 2): every piece's vertices, x and y
    #: Every piece's planes one after another, and where each piece's begin (p + 1,); and the
    #: whole block's footprint box (2, 2): for the compiled ground test, which takes one array.
    planes: tuple[np.ndarray, np.ndarray, np.ndarray] = field(repr=False, default=None)
    footprint: np.ndarray = field(repr=False, default=None)

    @classmethod
    def of(cls, block: Block, quaternion: np.ndarray) -> Shape:
        """The block turned by ``quaternion`` (scalar first).

        Every piece is turned and sorted into faces in one pass over the block's arrays
        (:class:`_Faces`): the search builds a shape for each new yaw, and piece by piece it
        took 285 us (2026-11-28)."""
        f = _faces_of(block)
        r = quat_to_matrix(quaternion)
        turned = f.vertices @ r.T
        normals = f.normals @ r.T
        pieces = [ConvexPolytope(turned[a:b], faces, normals[c:d], offsets)
                  for (a, b), (c, d), faces, offsets in zip(f.vertex_spans, f.plane_spans, f.faces, f.offsets,
                                                            strict=True)]
        z = turned[:, 2]
        lows, highs = np.minimum.reduceat(z, f.vertex_starts), np.maximum.reduceat(z, f.vertex_starts)
        boxes = np.stack([np.minimum.reduceat(turned[:, :2], f.vertex_starts),
                          np.maximum.reduceat(turned[:, :2], f.vertex_starts)], axis=1)
        xy = np.ascontiguousarray(turned[:, :2])
        radius = float(np.sqrt((xy * xy).sum(axis=1)).max())
        along = f.triangle_normals @ r[2]  # each triangle's normal along the world's z, unscaled
        lower = f.sides(turned, -along > tol.orientation * f.lengths)
        upper = f.sides(turned, along > tol.orientation * f.lengths)
        planes = (normals, f.plane_offsets, f.plane_starts)
        footprint = np.stack([boxes[:, 0].min(axis=0), boxes[:, 1].max(axis=0)])
        return cls(block, np.asarray(quaternion, float), pieces, lows, highs, boxes, radius, lower, upper, xy,
                   planes, footprint)


@dataclass(frozen=True, eq=False)
class _Faces:
    """A block's pieces, their arrays one after another, once per block: each turn of it only
    rotates them and selects among their faces.

    Attributes
    ----------
    vertices : (v, 3) float
        Every piece's vertices, block frame; piece ``p``'s are ``vertex_spans[p]``.
    normals, plane_offsets : (k, 3), (k,) float
        Every piece's planes; piece ``p``'s are ``plane_spans[p]``.
    faces, offsets : per piece, its triangles (its own vertex indices) and plane offsets.
    triangle_normals, lengths : (t, 3), (t,) float
        Each triangle's (unnormalised) normal, and its length.
    edges : (e, 2) int
        Each piece's hull edges (unique, sorted), as indices into ``vertices``;
        ``edge_faces`` (e, 2) the two triangles at each, ``edge_starts`` where each piece's begin.
    corners : (t, 3) int
        Each triangle's corners, as indices into ``vertices``. (A vertices-by-triangles table
        took 158 ms a turn for a mesh cut into 16 pieces of 300 vertices.)
    """

    vertices: np.ndarray
    vertex_starts: np.ndarray
    vertex_spans: list[tuple[int, int]]
    normals: np.ndarray
    plane_offsets: np.ndarray
    plane_starts: np.ndarray
    plane_spans: list[tuple[int, int]]
    faces: list[np.ndarray]
    offsets: list[np.ndarray]
    triangle_normals: np.ndarray
    lengths: np.ndarray
    edges: np.ndarray
    edge_faces: np.ndarray
    edge_starts: np.ndarray
    corners: np.ndarray

    def sides(self, turned: np.ndarray, facing: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per piece, the edges ``(e, 2, 3)`` and vertices ``(v, 3)`` of its triangles that are
        ``facing`` (up or down), in the turned block's ``turned`` vertices."""
        edges = facing[self.edge_faces].any(axis=1)
        points = np.zeros(len(self.vertices), dtype=bool)
        points[self.corners[facing].ravel()] = True
        e = np.add.reduceat(edges.astype(np.intp), self.edge_starts).cumsum().tolist()
        v = np.add.reduceat(points.astype(np.intp), self.vertex_starts).cumsum().tolist()
        chosen_edges, chosen_points = turned[self.edges[edges]], turned[points]
        return [(chosen_edges[e0:e1], chosen_points[v0:v1])
                for e0, e1, v0, v1 in zip([0, *e[:-1]], e, [0, *v[:-1]], v, strict=True)]


_FACES: weakref.WeakKeyDictionary[Block, _Faces] = weakref.WeakKeyDictionary()


def _faces_of(block: Block) -> _Faces:
    faces = _FACES.get(block)
    if faces is None:
        pieces = block.pieces
        counts = [len(p.vertices) for p in pieces]
        vertex_starts = np.cumsum([0] + counts[:-1])
        planes = [len(p.normals) for p in pieces]
        plane_starts = np.cumsum([0] + planes)
        tri_starts = np.cumsum([0] + [len(p.faces) for p in pieces])
        normals, lengths, edges, edge_faces, edge_counts = [], [], [], [], []
        for p, v0, t0 in zip(pieces, vertex_starts, tri_starts, strict=False):
            tri = p.vertices[p.faces]
            n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            e = np.concatenate([p.faces[:, [0, 1]], p.faces[:, [1, 2]], p.faces[:, [2, 0]]])
            owner = np.tile(np.arange(len(p.faces)), 3)
            unique, inverse = np.unique(np.sort(e, axis=1), axis=0, return_inverse=True)
            # A closed hull has every edge in exactly two triangles: grouped by edge, they pair up.
            normals.append(n)
            lengths.append(np.linalg.norm(n, axis=1))
            edges.append(unique + v0)
            edge_faces.append(owner[np.argsort(inverse.ravel(), kind="stable")].reshape(-1, 2) + t0)
            edge_counts.append(len(unique))
        faces = _FACES[block] = _Faces(
            np.concatenate([p.vertices for p in pieces]), vertex_starts,
            [(int(a), int(a) + c) for a, c in zip(vertex_starts, counts, strict=True)],
            np.concatenate([p.normals for p in pieces]), np.concatenate([p.offsets for p in pieces]),
            plane_starts,
            [(int(a), int(b)) for a, b in zip(plane_starts[:-1], plane_starts[1:], strict=True)],
            [p.faces for p in pieces], [p.offsets for p in pieces],
            np.concatenate(normals), np.concatenate(lengths), np.concatenate(edges),
            np.concatenate(edge_faces), np.cumsum([0] + edge_counts[:-1]),
            np.concatenate([p.faces + v0 for p, v0 in zip(pieces, vertex_starts, strict=True)]))
    return faces


def rest_height(moving: ConvexPolytope, moving_lower: tuple[np.ndarray, np.ndarray], fixed: ConvexPolytope,
                fixed_upper: tuple[np.ndarray, np.ndarray], offset_xy: np.ndarray) -> float:
    """Lowest height ``z`` at which ``moving + (offset_xy, z)`` clears ``fixed``.

    Returns ``-inf`` when their footprints do not overlap (lowering never
    meets). ``moving`` is given with its reference point at the origin;
    ``moving_lower`` and ``fixed_upper`` are the (edges, vertices) of the
    moving piece's lower side and the fixed piece's upper side, whose
    projections hold every breakpoint of bottom_P and top_Q.

    The breakpoints are visited one by one in compiled code (numba,
    :mod:`optimizer.search._contact`): the arrays are a few dozen rows, and numpy's cost per
    call, not the arithmetic, was the drop's time. ``benchmarks/drop_speed.py`` measures
    both (10 against 98 us a pair on ``mini``'s reference, 2026-11-28).
    """
    if len(moving.normals) + len(fixed.normals) > MANY_PLANES:
        return _rest_height_lp(moving, fixed, offset_xy)
    me, mvert = moving_lower
    fe, fvert = fixed_upper
    return _kernel()(moving.normals, moving.offsets, me, mvert, fixed.normals, fixed.offsets, fe, fvert,
                     float(offset_xy[0]), float(offset_xy[1]), tol.distance, tol.parallel)


@functools.cache
def _ground_kernel():
    """The compiled ground test (:mod:`optimizer.search._contact`), imported on first use."""
    from ._contact import ground_kernel

    return ground_kernel


@functools.cache
def _kernel():
    """The compiled loop (:mod:`optimizer.search._contact`), imported on first use: importing
    numba takes 0.6 s, which the verbs that lower no block do not pay."""
    from ._contact import rest_height_kernel

    return rest_height_kernel


#: Pieces with more planes than this between them are lowered by a linear programme: the
#: breakpoints of two 2500-vertex spheres (thousands of edge crossings, each crossed with
#: 5000 planes) took 0.7 s a drop.
MANY_PLANES = 200


def _rest_height_lp(moving: ConvexPolytope, fixed: ConvexPolytope, offset_xy: np.ndarray) -> float:
    """:func:`rest_height` as the most that a point ``a`` of ``fixed`` can stand over a point
    ``b`` of ``moving`` straight under it (``a_xy = b_xy + offset_xy``): the top of one minus the
    bottom of the other is concave, so its largest value over their common footprint is the
    optimum of a linear programme in ``(b_x, b_y, a_z, b_z)``."""
    nq, nm = fixed.normals, moving.normals
    a_ub = np.zeros((len(nq) + len(nm), 4))
    a_ub[:len(nq), :2], a_ub[:len(nq), 2] = nq[:, :2], nq[:, 2]
    a_ub[len(nq):, :2], a_ub[len(nq):, 3] = nm[:, :2], nm[:, 2]
    b_ub = np.concatenate([fixed.offsets - nq[:, :2] @ offset_xy, moving.offsets])
    res = linprog([0.0, 0.0, -1.0, 1.0], A_ub=a_ub, b_ub=b_ub, bounds=[(None, None)] * 4, method="highs")
    return -float(res.fun) if res.status == 0 else -np.inf


class DropWorld:
    """Placed blocks and the ground, for lowering new blocks onto them.

    Parameters
    ----------
    foundation : Foundation
    cell : float, metres
        Horizontal hash cell for finding blocks under a footprint.
    """

    def __init__(self, foundation: Foundation, cell: float = 2.0):
        self.foundation = foundation
        self.cell = cell
        # Per key: its shape, position, pieces where it stands, their upper sides, and their
        # bounding boxes (p, 2, 3).
        self._placed: dict[int, tuple[Shape, np.ndarray, list[ConvexPolytope],
                                      list[tuple[np.ndarray, np.ndarray]], np.ndarray]] = {}
        self._grid: dict[tuple[int, int], set[int]] = {}
        self._max_r = 0.0

    @classmethod
    def of(cls, foundation: Foundation, placed: list) -> DropWorld:
        """A world of ``placed`` blocks ``(key, block, pose)`` as they stand, on ``foundation``."""
        cell = 2.0 * max((block.bounding_radius for _, block, _ in placed), default=1.0)
        world = cls(foundation, cell=cell)
        for key, block, pose in placed:
            world.add(key, Shape.of(block, pose.quaternion), pose.position)
        return world

    def __len__(self) -> int:
        return len(self._placed)

    def poses(self) -> dict[int, Pose]:
        """Where each placed block stands, by key: the inverse of :meth:`of`."""
        return {k: Pose(pos, shape.quaternion) for k, (shape, pos, *_) in self._placed.items()}

    def _cells(self, x: float, y: float, r: float) -> list[tuple[int, int]]:
        c = self.cell
        return [(i, j) for i in range(int(np.floor((x - r) / c)), int(np.floor((x + r) / c)) + 1)
                for j in range(int(np.floor((y - r) / c)), int(np.floor((y + r) / c)) + 1)]

    def add(self, key: int, shape: Shape, position: np.ndarray) -> None:
        position = np.asarray(position, dtype=float)
        pieces = [ConvexPolytope(p.vertices + position, p.faces, p.normals, p.offsets + p.normals @ position)
                  for p in shape.pieces]
        upper = [(e + position, v + position) for e, v in shape.upper]
        self._placed[key] = (shape, position, pieces, upper, np.array([p.aabb for p in pieces]))
        for cell in self._cells(position[0], position[1], shape.radius_xy):
            self._grid.setdefault(cell, set()).add(key)
        self._max_r = max(self._max_r, shape.radius_xy)

    def remove(self, key: int) -> None:
        shape, position, *_ = self._placed.pop(key)
        for cell in self._cells(position[0], position[1], shape.radius_xy):
            self._grid[cell].discard(key)

    def top(self) -> float:
        """The highest point of the placed blocks, m; 0.0 while none is placed."""
        return max((float(pos[2] + shape.highs.max()) for shape, pos, *_ in self._placed.values()),
                   default=0.0)

    def copy(self) -> DropWorld:
        """An independent world sharing the immutable placed entries."""
        other = DropWorld(self.foundation, self.cell)
        other._placed = dict(self._placed)
        other._grid = {c: set(k) for c, k in self._grid.items() if k}
        other._max_r = self._max_r
        return other

    def under(self, x: float, y: float, r: float, exclude: frozenset[int] = frozenset()) -> list[int]:
        """Keys of blocks whose footprint circles reach within ``r`` of (x, y)."""
        keys: set[int] = set()
        for cell in self._cells(x, y, r):
            keys |= self._grid.get(cell, set())
        out = []
        for k in keys - exclude:
            shape, pos, *_ = self._placed[k]
            if (pos[0] - x) ** 2 + (pos[1] - y) ** 2 <= (r + shape.radius_xy) ** 2:
                out.append(k)
        return out

    def ground_height(self, shape: Shape, x: float, y: float) -> float:
        """Lowest centroid height at which the shape clears the foundation.

        On rough ground, the field is sampled at the block's vertices and at its nodes under
        the block's footprint box, and each piece meets it where its own column is (a point
        outside its footprint misses it): a compiled loop
        (:func:`optimizer.search._contact.ground_kernel`). In numpy this was a fifth of a run
        on ``mini-rough`` (386 us a call, 2026-11-28); ``benchmarks/drop_speed.py`` measures both.
        """
        if self.foundation.kind != "rough":
            return float(-shape.lows.min())
        xs, ys, h = self.foundation.grid
        normals, offsets, starts = shape.planes
        return _ground_kernel()(normals, offsets, starts, shape.vertices_xy, shape.footprint, xs, ys, h,
                                float(self.foundation.cell), tol.grid_edge, float(x), float(y), tol.distance)

    def drop(self, shape: Shape, x: float, y: float, exclude: frozenset[int] = frozenset(),
             ground: float | None = None) -> tuple[float, list[int], bool]:
        """Lower ``shape`` at (x, y) from above until it first touches.

        ``ground`` is :meth:`ground_height` at (x, y), where the caller has it already.

        Returns
        -------
        z : float, metres
            Centroid height at first contact, raised by ``tol.drop_resolution``
            so that it rests a hair above what it touches.
        support : list of int
            Keys of the blocks it touches at that height.
        on_ground : bool
            Whether it touches the foundation.
        """
        offset = np.array([x, y])
        if ground is None:
            ground = self.ground_height(shape, x, y)
        best = ground
        pairs = self._pairs(shape, offset, self.under(x, y, shape.radius_xy, exclude))
        heights: list[tuple[float, int]] = []
        for bound, k, i, fp, fe in pairs:
            if bound < best - tol.drop_resolution:
                break
            z = rest_height(shape.pieces[i], shape.lower[i], fp, fe, offset)
            if z > -np.inf:
                heights.append((z, k))
                best = max(best, z)
        support = sorted({k for z, k in heights if z >= best - tol.drop_resolution})
        return best + tol.drop_resolution, support, ground >= best - tol.drop_resolution

    def _pairs(self, shape: Shape, offset: np.ndarray, keys: list[int]
               ) -> Iterator[tuple[float, int, int, ConvexPolytope, tuple[np.ndarray, np.ndarray]]]:
        """The pairs (a piece of ``shape`` at ``offset``, a piece of a block ``keys``) whose
        footprint boxes overlap, highest first by the most the moving piece can rest at on
        that one (its top less the moving piece's lowest point): ``(bound, key, moving piece,
        fixed piece, its upper side)``. The boxes of every pair are compared at once (a drop
        among a dozen blocks of six pieces each weighs hundreds of pairs)."""
        if not keys:
            return
        entries = [self._placed[k] for k in keys]
        boxes = np.concatenate([e[4] for e in entries])  # (f, 2, 3)
        owner = np.repeat(np.arange(len(keys)), [len(e[4]) for e in entries])
        piece = np.concatenate([np.arange(len(e[4])) for e in entries])
        mb = shape.xy_boxes + offset  # (m, 2, 2)
        apart = ((mb[:, None, 0, 0] > boxes[None, :, 1, 0]) | (boxes[None, :, 0, 0] > mb[:, None, 1, 0])
                 | (mb[:, None, 0, 1] > boxes[None, :, 1, 1]) | (boxes[None, :, 0, 1] > mb[:, None, 1, 1]))
        ii, jj = np.nonzero(~apart)
        bounds = boxes[jj, 1, 2] - shape.lows[ii]
        for n in np.argsort(-bounds, kind="stable"):
            i, j = int(ii[n]), int(jj[n])
            _, _, pieces, upper, _ = entries[owner[j]]
            yield float(bounds[n]), keys[owner[j]], i, pieces[piece[j]], upper[piece[j]]

    def blockers(self, shape: Shape, x: float, y: float, floor: float,
                 exclude: frozenset[int] = frozenset()) -> set[int]:
        """Placed blocks that would stop ``shape``, lowered at (x, y), above height ``floor``.

        The same contact test as :meth:`drop`, asked of each block separately;
        a piece pair whose best possible height is below ``floor`` is skipped.
        """
        offset = np.array([x, y])
        out: set[int] = set()
        for bound, k, i, fp, fe in self._pairs(shape, offset, self.under(x, y, shape.radius_xy, exclude)):
            if bound <= floor:
                break  # highest first: no pair after this one rises above the floor either
            if k not in out and rest_height(shape.pieces[i], shape.lower[i], fp, fe, offset) > floor:
                out.add(k)
        return out

    def pose(self, shape: Shape, x: float, y: float, z: float) -> Pose:
        return Pose([x, y, z], shape.quaternion)
