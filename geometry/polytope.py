"""Convex polytopes: the pieces blocks are made of, and the prisms of a scene.

A convex polytope is kept in both of its forms: its vertices (for hulls,
collision shapes and bounding boxes) and its half-spaces ``n . p <= d`` (for
containment and for the vertical column intervals the voxel methods use).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.spatial import ConvexHull, HalfspaceIntersection, QhullError

from .constants import tol
from .errors import InputError


@dataclass(frozen=True, eq=False)
class ConvexPolytope:
    """A bounded convex polytope.

    Attributes
    ----------
    vertices : (n, 3) float, metres
        Hull vertices, in whatever frame the polytope was built in.
    faces : (m, 3) int
        Triangles of the hull surface, counter-clockwise seen from outside.
    normals : (k, 3) float
        Unit outward normals of its distinct facet planes.
    offsets : (k,) float, metres
        Plane offsets: a point ``p`` is inside when ``normals @ p <= offsets``.
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    offsets: np.ndarray

    @classmethod
    def from_points(cls, points: np.ndarray, name: str = "polytope") -> ConvexPolytope:
        """Convex hull of ``(n, 3)`` points.

        Raises
        ------
        InputError
            If the points span no volume (fewer than 4 points off one plane).
        """
        points = np.asarray(points, dtype=float)
        if points.ndim != 2 or points.shape[1] != 3 or not np.isfinite(points).all():
            raise InputError(f"{name}: points must be a finite (n, 3) array")
        try:
            hull = ConvexHull(points)
        except QhullError as exc:
            raise InputError(f"{name}: points span no volume ({len(points)} points)") from exc
        used = np.unique(hull.simplices)
        remap = np.full(len(points), -1)
        remap[used] = np.arange(len(used))
        vertices = points[used]
        faces = remap[hull.simplices]
        # qhull does not orient simplices; flip those whose normal points inward.
        tri = vertices[faces]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        flip = np.einsum("ij,ij->i", n, hull.equations[:, :3]) < 0
        faces[flip] = faces[flip][:, ::-1]
        normals, offsets = _distinct_planes(hull.equations, scale=np.ptp(points, axis=0).max())
        return cls(vertices, faces, normals, offsets)

    @classmethod
    def from_halfspaces(
        cls, normals: np.ndarray, offsets: np.ndarray, interior: np.ndarray
    ) -> ConvexPolytope:
        """Intersection of half-spaces ``normals @ p <= offsets``.

        ``interior`` is a point strictly inside.
        """
        normals = np.asarray(normals, dtype=float)
        offsets = np.asarray(offsets, dtype=float)
        hs = np.hstack([normals, -offsets[:, None]])
        points = HalfspaceIntersection(hs, np.asarray(interior, dtype=float)).intersections
        return cls.from_points(points)

    # --- measures -----------------------------------------------------------

    @cached_property
    def volume(self) -> float:
        """Volume in cubic metres (divergence theorem over the triangles)."""
        tri = self.vertices[self.faces]
        return float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6)

    @cached_property
    def aabb(self) -> np.ndarray:
        """(2, 3) float: lower and upper corner of the axis-aligned bounding box."""
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])

    @cached_property
    def edges(self) -> np.ndarray:
        """(e, 2) int: unique edges of the triangulated hull."""
        e = np.concatenate([self.faces[:, [0, 1]], self.faces[:, [1, 2]], self.faces[:, [2, 0]]])
        return np.unique(np.sort(e, axis=1), axis=0)

    # --- maps and tests -------------------------------------------------------

    def transformed(self, rotation: np.ndarray, translation: np.ndarray) -> ConvexPolytope:
        """The polytope moved by ``p -> rotation @ p + translation``."""
        normals = self.normals @ rotation.T
        return ConvexPolytope(
            self.vertices @ rotation.T + translation,
            self.faces,
            normals,
            self.offsets + normals @ translation,
        )

    def contains(self, points: np.ndarray, margin: float = tol.distance) -> np.ndarray:
        """Which ``(n, 3)`` points lie inside, allowing ``margin`` metres outside."""
        return np.all(np.asarray(points) @ self.normals.T <= self.offsets + margin, axis=1)

    @cached_property
    def edge_face_normals(self) -> np.ndarray:
        """(e, 2, 3) float: unit normals of the two triangles that meet at each hull edge."""
        tri = self.vertices[self.faces]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        e = np.concatenate([self.faces[:, [0, 1]], self.faces[:, [1, 2]], self.faces[:, [2, 0]]])
        owner = np.tile(np.arange(len(self.faces)), 3)
        key = np.sort(e, axis=1)
        order = np.lexsort((key[:, 1], key[:, 0]))
        # A closed triangulated surface has each edge twice: consecutive after sorting.
        k = key[order]
        if len(k) % 2 or not (k[0::2] == k[1::2]).all():
            raise ValueError("hull surface is not closed: an edge does not join two triangles")
        return n[owner[order].reshape(-1, 2)]

    def eroded_box_planes(self, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Half-spaces of the set of centres whose box ``[-half, half]`` fits inside.

        For a convex polytope this is exact: each plane moves in by the box's
        support along its normal, ``sum_i half_i |n_i|``.
        """
        return self.normals, self.offsets - np.abs(self.normals) @ np.asarray(half)


class PieceStack:
    """A block's convex pieces stacked once, to move them all in one pass.

    The voxel trackers move one block per step (their hot path); this keeps
    that to one pass over every piece rather than one per piece.

    :meth:`planes` gives each moved piece's half-spaces, or, with a box
    ``half``, those of its Minkowski sum with the axis-aligned box
    ``[-half, half]``: an axis-aligned box centred at ``c`` touches the piece
    exactly when ``c`` lies in the sum, which the ``voxel-any`` porosity rule
    relies on. The sum is the hull of every vertex moved to every box corner,
    but qhull takes about 0.8 ms a piece, so the planes are built directly
    (the tests hold them to that hull). The sum's facet normals are the
    piece's, the box's six, and, for each edge whose two faces lie on either
    side of a box axis ``a`` (the edge is on the silhouette seen along
    ``a``), the normal between them perpendicular to ``a``. Each plane sits
    at the sum's support along its normal. Normals that are not facets would
    only repeat a bound, so none are pruned.
    """

    _AXES = np.concatenate([np.eye(3), -np.eye(3)])

    def __init__(self, pieces: tuple[ConvexPolytope, ...]):
        self.count = len(pieces)
        self.vertices = np.concatenate([p.vertices for p in pieces])
        self.vertex_piece = np.repeat(np.arange(self.count), [len(p.vertices) for p in pieces])
        self.vertex_start = np.cumsum([0] + [len(p.vertices) for p in pieces[:-1]])
        self.normals = np.concatenate([p.normals for p in pieces])
        self.offsets = np.concatenate([p.offsets for p in pieces])
        self.normal_split = np.cumsum([len(p.normals) for p in pieces])[:-1]
        self._pieces = pieces

    @cached_property
    def _pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """Every piece's :attr:`ConvexPolytope.edge_face_normals`, and the piece of each edge."""
        pairs = np.concatenate([p.edge_face_normals for p in self._pieces])  # (e, 2, 3)
        return pairs, np.repeat(np.arange(self.count), [len(p.edge_face_normals) for p in self._pieces])

    def planes(self, rotation: np.ndarray, translation: np.ndarray, half: np.ndarray | None = None
               ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        """Each piece moved by ``p -> R p + t``, or its sum with the box ``half``.

        Returns ``(normals, offsets, lo, hi)`` per piece: its half-spaces
        ``normals @ p <= offsets`` and its bounding box.
        """
        vertices = self.vertices @ rotation.T + translation
        own = self.normals @ rotation.T
        own_offsets = self.offsets + own @ translation
        lo = np.minimum.reduceat(vertices, self.vertex_start)
        hi = np.maximum.reduceat(vertices, self.vertex_start)
        normals = np.split(own, self.normal_split)
        if half is None:
            return list(zip(normals, np.split(own_offsets, self.normal_split), lo, hi, strict=True))
        half = np.asarray(half, dtype=float)
        own_offsets += np.abs(own) @ half
        pairs, pair_piece = self._pairs
        pairs = pairs @ rotation.T
        n1, n2 = pairs[:, 0], pairs[:, 1]
        # For edge e and axis a (n1[e, a] and n2[e, a] of opposite signs), the
        # combination n2[e, a] n1[e] - n1[e, a] n2[e], perpendicular to a, turned
        # to a positive combination of the two faces' normals.
        e, a = np.nonzero(n1 * n2 < 0)
        s1, s2 = n1[e, a][:, None], n2[e, a][:, None]
        m = (s2 * n1[e] - s1 * n2[e]) * np.sign(s2)
        m /= np.sqrt(np.einsum("ij,ij->i", m, m))[:, None]
        m_piece = pair_piece[e]  # ascending: np.nonzero goes edge by edge
        # Support of each silhouette normal over its own piece's vertices.
        along = vertices @ m.T
        along[self.vertex_piece[:, None] != m_piece[None, :]] = -np.inf
        m_offsets = along.max(axis=0) + np.abs(m) @ half
        # The box's six planes at each piece's bounding box, grown by the box.
        box_offsets = np.concatenate([hi + half, half - lo], axis=1)  # (pieces, 6)
        m_split = np.searchsorted(m_piece, np.arange(1, self.count))
        return [(np.concatenate([n, self._AXES, mn]), np.concatenate([d, box, md]), low - half, high + half)
                for n, d, mn, md, box, low, high in zip(
                    normals, np.split(own_offsets, self.normal_split), np.split(m, m_split),
                    np.split(m_offsets, m_split), box_offsets, lo, hi, strict=True)]


def column_intervals(
    normals: np.ndarray, offsets: np.ndarray, xy: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Where vertical lines cross a convex polytope.

    Parameters
    ----------
    normals : (k, 3) float
        Plane normals; a point is inside when ``normals @ p <= offsets``.
    offsets : (k,) float, metres
    xy : (c, 2) float, metres
        Horizontal positions of the vertical lines (columns).

    Returns
    -------
    lo, hi : (c,) float, metres
        Each line is inside for ``lo <= z <= hi``; ``lo > hi`` where it misses.

    Notes
    -----
    Costs ``O(c k)``: one pass over the planes for all columns, against
    ``O(c k nz)`` for testing every voxel centre of a column.
    """
    rhs = offsets[None, :] - xy @ normals[:, :2].T  # (c, k): nz * z <= rhs
    nz = normals[:, 2]
    up = nz > tol.distance
    down = nz < -tol.distance
    flat = ~(up | down)
    hi = np.min(rhs[:, up] / nz[up], axis=1, initial=np.inf)
    lo = np.max(rhs[:, down] / nz[down], axis=1, initial=-np.inf)
    if flat.any():
        outside = np.any(rhs[:, flat] < -tol.distance, axis=1)
        lo = np.where(outside, np.inf, lo)
        hi = np.where(outside, -np.inf, hi)
    return lo, hi


def _distinct_planes(equations: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Merge qhull's per-triangle equations ``[n, -d]`` into distinct planes."""
    normals = equations[:, :3]
    offsets = -equations[:, 3]
    # Round in units of tol.facet_rounding of the part's size: coplanar triangles of one
    # facet agree to ~1e-15, distinct facets differ by far more.
    key = np.round(np.hstack([normals, offsets[:, None] / max(scale, tol.length_floor)])
                   / tol.facet_rounding)
    _, first = np.unique(key, axis=0, return_index=True)
    first = np.sort(first)
    return normals[first].copy(), offsets[first].copy()
