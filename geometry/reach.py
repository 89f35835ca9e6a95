"""How near the tolerance zone lets a block come to the design surface: a floor under the coverage.

Coverage (:mod:`geometry.coverage`) calls a point of the design prism's slopes
and crest bare when it lies more than H/2 from every block. A valid block lies
wholly inside the tolerance zone, and near a toe that zone is a thin wedge:
on ``mini`` it reaches 0.54 m past the design toe on the ground and closes at
40 degrees. So some points may lie more than H/2 from every block that fits,
in every valid layout. :func:`coverage_floor` measures that:

* for one orientation of the block, the block's allowed places in the zone's
  cross-section form a convex polygon ``P`` (the zone's edges, each moved in
  by the block's extent along its normal), and the nearest a convex piece
  ``K`` of the block can come to a point of the section is the point's
  distance to the Minkowski sum ``K + P``; the nearest the block can come
  is the least over its pieces. The mound's ends are left out, so the
  block may stand at any y, and it need not rest, stand or miss other
  blocks: for the orientation, this is a lower bound on the point's
  distance to the block in any valid layout;
* over orientations it is the least over those tried: every stable rest pose
  at ``yaws`` yaws (the crane's), ``random`` random turns, and a local search
  over the turn (Nelder-Mead on a rotation vector) from the ``refine`` best
  for up to ``REFINE_POINTS`` points still over H/2, spread over them, each
  turn found then measured at every point. A minimum over orientations tried, not a
  proof over all of them; the more tried, the lower it can only go.

The points are the coverage's own samples of one cross-section, so the bare
share of the floor is in the same units as ``bare_share_percent``: no layout
of the scene's block can have less bare than the floor (to the orientations
tried), nor a smaller largest bare distance than ``max_bare_m``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import minimize
from scipy.spatial import ConvexHull, QhullError
from scipy.spatial.transform import Rotation

from .coverage import AIM_BARE_PERCENT, AIM_MAX_BARE_H, BARE_FRACTION, surface_samples
from .scene import Scene

#: Yaws per rest pose, over a full turn.
YAWS = 72
#: Random turns tried on top of the rest poses, by default.
RANDOM = 1000
#: Orientations each searched point starts a local search from.
REFINE = 2
#: Points still bare that are searched, spread over them.
REFINE_POINTS = 8


@dataclass(frozen=True)
class CoverageFloor:
    """What no valid layout of a scene's block can cover, to the orientations tried.

    Attributes
    ----------
    bare_share_percent : float
        Share of the slopes and crest further than H/2 from any block inside the zone.
    max_bare_m : float
        The largest least distance: no layout has a smaller ``max_bare_m``.
    worst_point : (x, z), metres
        Where it is, in the cross-section (at any y).
    toe_m : float
        The least distance at the seaward toe.
    orientations : int
        Orientations tried, local searches not counted.
    """

    bare_share_percent: float
    max_bare_m: float
    worst_point: tuple[float, float]
    toe_m: float
    orientations: int

    def rules_out(self, block_height: float) -> bool:
        """Whether no layout can meet the coverage aims (``AIM_BARE_PERCENT``, ``AIM_MAX_BARE_H``)."""
        return self.bare_share_percent > AIM_BARE_PERCENT or self.max_bare_m > AIM_MAX_BARE_H * block_height

    def to_dict(self) -> dict[str, Any]:
        """The ``coverage_floor`` object; where no block fits in the zone, the distances are
        infinite, and given as null (JSON has no infinity)."""
        empty = not math.isfinite(self.max_bare_m)
        return {"bare_share_percent": self.bare_share_percent,
                "max_bare_m": None if empty else self.max_bare_m,
                "worst_point": None if empty else list(self.worst_point),
                "toe_m": self.toe_m if math.isfinite(self.toe_m) else None,
                "orientations": self.orientations}


def section_samples(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """The coverage's samples of one cross-section: ``(n, 2)`` (x, z) points and their weights.

    The first point is a cell by the seaward toe; the toe itself is among the
    points of no weight.
    """
    s = surface_samples(scene)
    row = s.points[:, 1] == s.points[0, 1]
    return s.points[row][:, [0, 2]], s.area[row]


class Reach:
    """The nearest a scene's block, turned a given way, can come to points of its section."""

    def __init__(self, scene: Scene):
        self.pieces = [p.vertices for p in scene.block.pieces]
        sec = scene.tolerance.section  # counter-clockwise
        edge = np.roll(sec, -1, axis=0) - sec
        normals = np.column_stack([edge[:, 1], -edge[:, 0]])
        self.normals = normals / np.linalg.norm(normals, axis=1)[:, None]
        self.offsets = np.einsum("ij,ij->i", self.normals, sec)
        lo, hi = sec.min(axis=0), sec.max(axis=0)
        pad = hi - lo
        self.box = np.array([lo - pad, [hi[0] + pad[0], lo[1] - pad[1]], hi + pad,
                             [lo[0] - pad[0], hi[1] + pad[1]]])

    def allowed(self, xz: np.ndarray) -> np.ndarray:
        """Where a block whose section is the points ``xz`` (at the origin) may be moved in the
        section and lie inside the zone: a convex polygon of translations, fewer than 3 corners
        where there is none."""
        allowed = self.box
        for n, c in zip(self.normals, self.offsets, strict=True):
            allowed = _clip(allowed, n, c - float((xz @ n).max()))
            if len(allowed) < 3:
                break
        return allowed

    def swept(self, rotation: np.ndarray) -> list[np.ndarray]:
        """Where each piece of the block turned by ``rotation`` (3x3) can lie inside the zone:
        a convex polygon per piece, ``K + P``; none where the block fits nowhere."""
        xz = [(v @ rotation.T)[:, [0, 2]] for v in self.pieces]
        allowed = self.allowed(np.concatenate(xz))
        if len(allowed) < 3:
            return []
        return [_hull((_hull(k)[:, None, :] + allowed[None]).reshape(-1, 2)) for k in xz]

    def __call__(self, rotation: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Least distance of each ``(n, 2)`` point to the block turned by ``rotation`` (3x3)
        anywhere inside the zone; infinite where it fits nowhere."""
        return nearest(points, self.swept(rotation))


def nearest(points: np.ndarray, polygons: list[np.ndarray], least: np.ndarray | None = None) -> np.ndarray:
    """Distance of each ``(n, 2)`` point to the nearest of convex ``polygons``, or its ``least``
    so far where that is nearer.

    A point is measured against a polygon only where the polygon's bounding box
    comes nearer than that: no polygon is nearer than its box, so the result
    is exact. Over a thousand orientations most points are soon reached (0) or
    far from every new polygon; on a 1:1000 slope of 15 822 samples this
    took the floor from 68 s to a few.
    """
    least = np.full(len(points), np.inf) if least is None else least.copy()
    for poly in polygons:
        lo, hi = poly.min(axis=0), poly.max(axis=0)
        box = np.linalg.norm(np.maximum(np.maximum(lo - points, points - hi), 0.0), axis=1)
        near = np.flatnonzero(box < least)
        if len(near):
            least[near] = np.minimum(least[near], _polygon_distance(points[near], poly))
    return least


def crane_rotations(scene: Scene, yaws: int = YAWS) -> list[np.ndarray]:
    """Every stable rest pose of the scene's block at ``yaws`` yaws over a full turn (3x3 each)."""
    out = []
    for rest in scene.block.rest_poses:
        base = Rotation.from_quat(rest.quaternion, scalar_first=True)
        for yaw in np.linspace(0.0, 2.0 * np.pi, yaws, endpoint=False):
            out.append((Rotation.from_rotvec([0.0, 0.0, yaw]) * base).as_matrix())
    return out


def least_distances(scene: Scene, random: int = RANDOM, yaws: int = YAWS, refine: int = REFINE,
                    seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """The least distance any block inside the zone comes to each section sample.

    Returns the ``(n, 2)`` points, their weights, the ``(n,)`` least
    distances and how many orientations were tried.
    """
    reach = Reach(scene)
    points, weights = section_samples(scene)
    rotations = crane_rotations(scene, yaws)
    if random > 0:
        # Unit quaternions of normal draws: uniform over the rotations.
        q = np.random.default_rng(seed).normal(size=(random, 4))
        rotations += list(Rotation.from_quat(q / np.linalg.norm(q, axis=1)[:, None]).as_matrix())
    swept = [reach.swept(r) for r in rotations]
    least = np.full(len(points), np.inf)
    for polygons in swept:
        least = nearest(points, polygons, least)
    half = BARE_FRACTION * scene.block.height
    bare = np.flatnonzero(least > half)
    # A few points still bare, spread over them, and the furthest, each searched from its
    # best orientations; every orientation found is measured at every point.
    spread = bare[np.linspace(0, len(bare) - 1, min(len(bare), REFINE_POINTS)).astype(int)]
    # Where no orientation tried fits in the zone, every distance is infinite and a local
    # search has nothing to descend (Nelder-Mead warned on its infinite values).
    fits = bool(np.isfinite(least).any())
    searched = np.union1d(spread, [np.argmax(least)]) if refine and fits else np.array([], dtype=int)
    each = np.array([nearest(points[searched], polygons) for polygons in swept])
    for column, i in enumerate(searched):
        def at_point(v: np.ndarray, p: np.ndarray = points[i:i + 1]) -> float:
            return float(reach(Rotation.from_rotvec(v).as_matrix(), p)[0])

        for j in np.argsort(each[:, column], kind="stable")[:refine]:
            found = minimize(at_point, Rotation.from_matrix(rotations[j]).as_rotvec(), method="Nelder-Mead",
                             options={"xatol": 1e-3, "fatol": 1e-4, "maxiter": 300})
            least = nearest(points, reach.swept(Rotation.from_rotvec(found.x).as_matrix()), least)
    return points, weights, least, len(rotations)


def coverage_floor(scene: Scene, random: int = RANDOM, yaws: int = YAWS, refine: int = REFINE,
                   seed: int = 0) -> CoverageFloor:
    """The share of the slopes and crest, and the largest distance, that no valid layout can cover."""
    return floor_of(scene, *least_distances(scene, random, yaws, refine, seed))


def floor_of(scene: Scene, points: np.ndarray, weights: np.ndarray, least: np.ndarray,
             tried: int) -> CoverageFloor:
    """The floor that the least distances of :func:`least_distances` give."""
    bare = least > BARE_FRACTION * scene.block.height
    worst = int(np.argmax(least))
    toe = int(np.argmin(np.hypot(points[:, 0] - scene.design.bottom_half_width,
                                 points[:, 1] - scene.design.z_bottom)))
    return CoverageFloor(100.0 * float(weights[bare].sum() / weights.sum()), float(least[worst]),
                         (float(points[worst, 0]), float(points[worst, 1])), float(least[toe]), tried)


def _clip(poly: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:
    """A convex polygon cut to ``normal @ p <= offset`` (Sutherland-Hodgman)."""
    out = []
    for p, q in zip(poly, np.roll(poly, -1, axis=0), strict=True):
        dp, dq = normal @ p - offset, normal @ q - offset
        if dp <= 0:
            out.append(p)
        if dp * dq < 0:
            out.append(p + dp / (dp - dq) * (q - p))
    return np.array(out).reshape(-1, 2)


def _hull(points: np.ndarray) -> np.ndarray:
    """Counter-clockwise hull of 2D points; a piece seen edge-on is given a micrometre of thickness."""
    try:
        return points[ConvexHull(points).vertices]
    except QhullError:
        hair = np.array([[0.0, 0.0], [1e-6, 0.0], [0.0, 1e-6]])
        return _hull((points[:, None, :] + hair[None]).reshape(-1, 2))


def _polygon_distance(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Distance of ``(n, 2)`` points to a counter-clockwise convex polygon, zero inside."""
    a, b = poly, np.roll(poly, -1, axis=0)
    ab = b - a
    ap = points[:, None, :] - a[None]
    inside = (ab[None, :, 0] * ap[..., 1] - ab[None, :, 1] * ap[..., 0] >= 0).all(axis=1)
    t = np.clip(np.einsum("nkj,kj->nk", ap, ab) / np.einsum("kj,kj->k", ab, ab), 0.0, 1.0)
    d = np.linalg.norm(ap - t[..., None] * ab[None], axis=2).min(axis=1)
    return np.where(inside, 0.0, d)
