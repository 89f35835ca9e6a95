"""Coverage: how much of the mound's surface the blocks cover.

Waves meet a wave-dissipating mound on its seaward face, and its toe holds the
slope up: a layout that meets the porosity with a dense core and bare slopes
does its job badly. A point of the design prism's slopes and crest is *bare*
when it lies more than ``H / 2`` from every block, H being the block height.
The ends, the base and a wall face are left out: no wave reaches them.

:func:`coverage` measures a layout (``shoha check``, the report, the score):

* ``bare_share_percent``: the share of the slopes' and crest's area that is bare;
* ``max_bare_m``: the largest distance from a point of them to the nearest block;
* ``worst_point``: where that distance is.

The surface is sampled on a grid of cells about ``H / 16`` wide, each point
standing for its cell's area. A point's distance to a block is exact: zero
inside a convex piece, else the distance to the nearest triangle of a piece's
hull. Most points are settled without it: each block's surface is also sampled,
no two samples further apart than ``spacing``, so the distance to the nearest
sample is at least the true distance and at most ``spacing`` more; only points
that bound leaves undecided, and the points near the largest distance, are
measured exactly.

The optimizer measures its layouts with the same function (``optimizer.api``);
its covering repair (``optimizer.search.cover``) moves blocks to bare areas and
measures each move with :func:`coverage_after`, which measures again only near
the blocks that changed and gives the same figures (docs/coverage-study.md).
"""

from __future__ import annotations

import functools
import math
import time
import weakref
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from .blocks import Block
from .pose import Pose
from .scene import Scene

#: Surface cells per block height: the design surface is sampled every H / 16
#: (10 cm for the 4-ton Shake Block), fine enough that a bare patch a tenth of
#: H wide is seen.
CELLS_PER_H = 16

#: The most surface samples the default spacing gives: ``full`` (2310 m^2 at H / 16) has 214 000.
MAX_SAMPLES = 500_000

#: The most samples on one block's surface: a box of 100 x 100 x 2 m (a size and shape the
#: block rules allow) had 1.3 million at its H / 16, and three such held ``shoha check``
#: for 62 s and 3.4 GB. A Shake Block has about a thousand.
MAX_BLOCK_SAMPLES = 20_000
#: The halving meets that aim only roughly, and on long slivers not at all: a 4 m cylinder of
#: 96 triangles had 158 000 at the spacing the aim gives, and the coverage of 16 of them took
#: 215 s. Past this many the spacing is widened until it is not.
MOST_BLOCK_SAMPLES = 2 * MAX_BLOCK_SAMPLES

#: Surface points per nearest-sample query, the deadline read between them: 0.015 s on the
#: ``mini`` reference (16 874 points, 0.06 s in all), 0.55 s among 27 slender beams.
QUERY_CHUNK = 4096

#: Bare means further than this fraction of the block height H from every block.
BARE_FRACTION = 0.5

#: What a covered mound aims at (issue 24): at most this share of the slopes and crest bare,
#: and no point of them further than this many block heights from a block.
AIM_BARE_PERCENT = 5.0
AIM_MAX_BARE_H = 1.0

Placed = Sequence[tuple[int, Block, Pose]]


@dataclass(frozen=True)
class SurfaceSamples:
    """Points standing for the design prism's slopes and crest.

    Attributes
    ----------
    points : (n, 3) float, metres, world frame
    area : (n,) float, square metres
        The area each point stands for: a cell's, or zero for the points on
        a face's edges, which only the largest bare distance looks at.
    face : (n,) int
        0 the seaward slope (+x), 1 the crest, 2 the landward slope (absent behind a wall).
    spacing : float, metres
    """

    points: np.ndarray
    area: np.ndarray
    face: np.ndarray
    spacing: float

    FACES = ("seaward slope", "crest", "landward slope")

    @functools.cached_property
    def tree(self) -> cKDTree:
        """A k-d tree of ``points``, built once (each covering move asked for one anew)."""
        return quick_tree(self.points)


def quick_tree(points: np.ndarray) -> cKDTree:
    """A k-d tree built for one use: split at the sliding midpoint, its nodes left as they are.
    Half the build time of the default (a tree of a layout's block samples, about 15 000 of
    them, was built about eleven times a covering move: two thirds of its measures' time) for
    the same exact answers, queried as fast."""
    return cKDTree(points, balanced_tree=False, compact_nodes=False)


def default_spacing(scene: Scene) -> float:
    """The sampling cell of the design surface: H / ``CELLS_PER_H``, or wider where that would
    give more than ``MAX_SAMPLES``. Tiny blocks on a big mound would need tens of millions of
    samples (a 5 cm tetrapod on mini: 19 million, 16 s for one block)."""
    prism = scene.design
    run = math.hypot(prism.bottom_half_width - prism.top_half_width, prism.height)
    area = (run * (1 if prism.wall_x is not None else 2) + 2 * prism.top_half_width) * prism.length
    return max(scene.block.height / CELLS_PER_H, math.sqrt(area / MAX_SAMPLES))


def surface_samples(scene: Scene, spacing: float | None = None) -> SurfaceSamples:
    """Cell-centred samples of the design prism's slopes and crest (ends, base and a wall left out)."""
    prism = scene.design
    spacing = float(default_spacing(scene) if spacing is None else spacing)
    ny = max(1, math.ceil(prism.length / spacing))
    ys = prism.y_start + (np.arange(ny) + 0.5) * prism.length / ny
    dy = prism.length / ny
    parts = []
    top, bottom = prism.top_half_width, prism.bottom_half_width
    z0, z1 = prism.z_bottom, prism.z_top
    # (start (x, z), end (x, z), face) of each face of the section, as lines in x-z.
    lines = [((bottom, z0), (top, z1), 0), ((prism.left(z1), z1), (top, z1), 1)]
    if prism.wall_x is None:
        lines.append(((-bottom, z0), (-top, z1), 2))
    for (xa, za), (xb, zb), face in lines:
        length = math.hypot(xb - xa, zb - za)
        if length <= 0.0:
            continue
        n = max(1, math.ceil(length / spacing))
        # Cell centres carry the area; the face's two edges (the toe, the crest's edge) are
        # sampled too, with no area, so that the largest bare distance is found where it
        # usually is, at the toe, and not half a cell from it.
        t = np.concatenate([(np.arange(n) + 0.5) / n, [0.0, 1.0]])
        weight = np.concatenate([np.full(n, length / n * dy), [0.0, 0.0]])
        xz = np.column_stack([xa + t * (xb - xa), za + t * (zb - za)])
        grid = np.column_stack([np.repeat(xz[:, 0], ny), np.tile(ys, len(t)), np.repeat(xz[:, 1], ny)])
        parts.append((grid, np.repeat(weight, ny), np.full(len(grid), face)))
    points = np.concatenate([p for p, _, _ in parts])
    return SurfaceSamples(points, np.concatenate([a for _, a, _ in parts]),
                          np.concatenate([f for _, _, f in parts]), spacing)


# --- a block's own surface, sampled -----------------------------------------------------------

_SAMPLES: weakref.WeakKeyDictionary[Block, dict[float, np.ndarray]] = weakref.WeakKeyDictionary()
_SPACINGS: weakref.WeakKeyDictionary[Block, dict[float, float]] = weakref.WeakKeyDictionary()


def block_samples(block: Block, spacing: float, most: int | None = None) -> np.ndarray | None:
    """Points on the block's surface, block frame, no point of it further than ``spacing`` from one;
    None if that takes more than ``most`` of them.

    Each triangle is halved across its longest edge until no edge is longer
    than ``spacing``, and the corners are kept: every point of a triangle
    lies within its longest edge of a corner. (Cutting each triangle into
    ``k x k`` by its longest edge put 51 000 points on each 6 m by 0.3 m face
    of a beam-like block, which needs 2 500; coverage of 27 such blocks took
    137 s.)
    """
    cache = _SAMPLES.setdefault(block, {})
    out = cache.get(spacing)
    if out is not None:
        return None if most is not None and len(out) > most else out
    tri = block.vertices[block.faces]
    pts = [block.vertices]
    while len(tri):
        edges = np.linalg.norm(tri - np.roll(tri, -1, axis=1), axis=2)  # edge i runs from corner i to i+1
        long = edges.max(axis=1) > spacing
        tri = tri[long]
        if not len(tri):
            break
        if most is not None and sum(map(len, pts)) + len(tri) // 2 > most:
            return None  # each triangle left adds a point, which at most one neighbour shares
        i = edges[long].argmax(axis=1)
        rows = np.arange(len(tri))
        a, b, c = tri[rows, i], tri[rows, (i + 1) % 3], tri[rows, (i + 2) % 3]
        mid = 0.5 * (a + b)
        pts.append(mid)
        tri = np.concatenate([np.stack([a, mid, c], axis=1), np.stack([mid, b, c], axis=1)])
    out = np.unique(np.round(np.concatenate(pts), 12), axis=0)
    cache[spacing] = out
    return None if most is not None and len(out) > most else out


# --- exact distances ---------------------------------------------------------------------------


def point_triangle_distance(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Distances from points ``p`` (m, 3) to triangles ``tri`` (m, 3, 3), pairwise, metres.

    The closest point on each triangle by its Voronoi regions (Ericson,
    *Real-Time Collision Detection*, 5.1.5), vectorised.
    """
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = 1.0 / (va + vb + vc)
        v, w = vb * denom, vc * denom
        closest = a + ab * v[:, None] + ac * w[:, None]  # inside the face
        # Edges and corners, from the last region checked to the first, so the first that holds wins.
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        edge_bc = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
        closest = np.where(edge_bc[:, None], b + (c - b) * t_bc[:, None], closest)
        t_ac = d2 / (d2 - d6)
        edge_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        closest = np.where(edge_ac[:, None], a + ac * t_ac[:, None], closest)
        t_ab = d1 / (d1 - d3)
        edge_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        closest = np.where(edge_ab[:, None], a + ab * t_ab[:, None], closest)
    closest = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, closest)
    closest = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, closest)
    closest = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, closest)
    return np.linalg.norm(p - closest, axis=1)


def _inside_any(points: np.ndarray, placed: Placed, centres: cKDTree, radius: float) -> np.ndarray:
    """Whether each world point (n, 3) lies inside a piece of any placed block (``centres``:
    their positions; ``radius``: the largest bounding radius)."""
    held = np.zeros(len(points), dtype=bool)
    groups: dict[int, list[int]] = {}
    for i, near in enumerate(centres.query_ball_point(points, radius) if len(points) else ()):
        for k in near:
            groups.setdefault(int(k), []).append(i)
    for k, members in groups.items():
        idx = np.array(members)
        _, block, pose = placed[k]
        local = pose.inverse_apply(points[idx])
        for piece in block.pieces:
            held[idx[np.all(local @ piece.normals.T <= piece.offsets, axis=1)]] = True
    return held


def distance_to_block(points: np.ndarray, block: Block, pose: Pose) -> np.ndarray:
    """Exact distance (m) from world points (n, 3) to a posed block: 0 inside a piece, else to its hulls."""
    local = pose.inverse_apply(points)
    out = np.full(len(points), np.inf)
    for piece in block.pieces:
        inside = np.all(local @ piece.normals.T <= piece.offsets, axis=1)
        out[inside] = 0.0
        todo = np.flatnonzero(~inside & (out > 0.0))
        if not len(todo):
            continue
        tri = piece.vertices[piece.faces]  # (t, 3, 3)
        pp = np.repeat(local[todo], len(tri), axis=0)
        d = point_triangle_distance(pp, np.tile(tri, (len(todo), 1, 1))).reshape(len(todo), len(tri))
        out[todo] = np.minimum(out[todo], d.min(axis=1))
    return out


# --- the measure ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class CoverageReport:
    """How much of the design surface the blocks cover.

    Attributes
    ----------
    bare_share_percent : float
        Area share of the slopes and crest more than ``bare_distance_m`` from every block.
    max_bare_m : float
        The largest distance from a point of them to the nearest block.
    worst_point : (3,) float
        Where that distance is, world frame (the first such point).
    bare_distance_m : float
        ``H / 2``.
    spacing_m : float
        The sampling cell.
    bare : (n,) bool
        Which samples are bare (for the report's picture).
    samples : SurfaceSamples
    distance : (n,) float, optional
        Each sample's distance to the nearest block, exact where it decides
        whether the sample is bare or where it is near the largest
        (:func:`coverage_after` starts from it).
    radius_m : float
        The largest bounding radius of the blocks measured: how far from a block's centroid
        a sample it was nearest to may lie (:func:`coverage_after` reaches that far from a
        block taken out).
    """

    bare_share_percent: float
    max_bare_m: float
    worst_point: tuple[float, float, float]
    bare_distance_m: float
    spacing_m: float
    bare: np.ndarray
    samples: SurfaceSamples
    distance: np.ndarray | None = None
    radius_m: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        """The ``coverage`` object of ``shoha check --json`` (docs/contract.md)."""
        empty = not math.isfinite(self.max_bare_m)
        return {"bare_share_percent": self.bare_share_percent,
                "max_bare_m": None if empty else self.max_bare_m,
                "worst_point": None if empty else list(self.worst_point),
                "bare_distance_m": self.bare_distance_m, "spacing_m": self.spacing_m}

    def aims_met(self) -> int:
        """How many of the two aims the layout meets: ``AIM_BARE_PERCENT``, ``AIM_MAX_BARE_H``."""
        h = self.bare_distance_m / BARE_FRACTION
        return int(self.bare_share_percent <= AIM_BARE_PERCENT) + int(self.max_bare_m <= AIM_MAX_BARE_H * h)

    def better_than(self, other: CoverageReport) -> bool:
        """Covers better: meets more of the aims, or as many with less of the surface bare."""
        return (self.aims_met(), -self.bare_share_percent) > (other.aims_met(), -other.bare_share_percent)

    def by_face(self) -> dict[str, float]:
        """Bare share (percent) of each face."""
        out = {}
        for i, name in enumerate(SurfaceSamples.FACES):
            on = self.samples.face == i
            if on.any():
                area = self.samples.area[on]
                out[name] = percent_of(area[self.bare[on]].sum(), area.sum())
        return out


class TimeUp(RuntimeError):
    """The coverage was not measured by the deadline it was given."""


def coverage(scene: Scene, placed: Placed, spacing: float | None = None,
             deadline: float | None = None, clock: Callable[[], float] = time.monotonic) -> CoverageReport:
    """Bare share, largest bare distance and where it is, for a layout (module docstring).

    With no blocks every point is bare, and the largest distance is infinite
    (``max_bare_m`` and ``worst_point`` are then None in :meth:`CoverageReport.to_dict`).
    With a ``deadline`` (on ``clock``), raises :class:`TimeUp` once past it, between
    blocks: a run with a time limit asks for it so (many slender blocks, each near much
    of the surface, took 137 s where a 75-block mound takes 0.24 s).
    """
    samples = surface_samples(scene, spacing)
    limit = BARE_FRACTION * scene.block.height
    return _report(samples, limit, _largest_radius(placed),
                   _distances(samples.points, placed, samples.spacing, limit,
                                              due=None if deadline is None else (deadline, clock)))


def coverage_after(scene: Scene, placed: Placed, before: CoverageReport, changed: Sequence[np.ndarray]
                   ) -> CoverageReport:
    """The coverage of ``placed``, which differs from the layout ``before`` measured only in blocks
    taken out or put in with their centroids at ``changed``: the same figures as :func:`coverage`,
    measured again only near them.

    Only a sample whose nearest block was taken out, and so lay within ``before.max_bare_m``
    and a bounding radius of its centroid (the largest of either layout's blocks), or that
    a block put in comes nearer to than its nearest before, can change: those within that
    reach of a changed centroid are measured again, against the blocks near them. The reach
    has a sampling cell more: a sample's distance kept from ``before`` may be the bound, up to
    a cell over the true one.
    """
    if before.distance is None or not math.isfinite(before.max_bare_m) or not placed:
        return coverage(scene, placed, before.spacing_m)
    samples = before.samples
    limit = before.bare_distance_m
    # A block taken out was one of ``before``'s: its samples lay within its radius, which may be
    # larger than any block left (1 m cubes in place of an 8 m slab kept the slab's distances).
    own = _largest_radius(placed)
    radius = max(own, before.radius_m)
    reach = before.max_bare_m + radius + samples.spacing
    tree = samples.tree
    idx = np.unique(np.concatenate([np.asarray(tree.query_ball_point(c, reach), dtype=int) for c in changed]))
    dist = before.distance.copy()
    centres = np.array([pose.position for _, _, pose in placed])
    if len(idx):
        # A block further than 3 reaches from every change is more than 2 reaches from these
        # samples: if one lies further than that from its nearest block here, measure it all.
        local = _near(placed, centres, np.asarray(changed), 3 * reach)
        dist[idx] = _distances(samples.points[idx], local, samples.spacing, limit)
        if not local or dist[idx].max() > 2 * reach - radius:
            return coverage(scene, placed, before.spacing_m)
    # Far from the changes a sample's distance may be the bound, up to a cell over the true one;
    # the largest must be exact, as coverage() has it: measure exactly from the top down until
    # every sample within a cell of the largest is.
    exact = np.zeros(len(dist), bool)
    while True:
        top = np.flatnonzero((dist >= dist.max() - samples.spacing) & ~exact)
        if not len(top):
            break
        pts = samples.points[top]
        dist[top] = _distances(pts, _near(placed, centres, pts, float(dist[top].max()) + radius),
                               samples.spacing, limit, exact=True)
        exact[top] = True
    return _report(samples, limit, own, dist)


def _near(placed: Placed, centres: np.ndarray, points: np.ndarray, reach: float) -> list:
    """The blocks whose centroids lie within ``reach`` of any of ``points``."""
    hit = quick_tree(points).query_ball_point(centres, reach, return_length=True)
    return [p for p, h in zip(placed, hit, strict=True) if h]


def percent_of(part: float, whole: float) -> float:
    """``part`` as a percentage of ``whole``, a sum it is part of: 100 exactly when it is all of it
    (``100 * a / a`` came to 100.00000000000001 on ``mini``), never more."""
    return min(100.0, 100.0 * float(part / whole))


def _largest_radius(placed: Placed) -> float:
    return max((block.bounding_radius for _, block, _ in placed), default=0.0)


def _report(samples: SurfaceSamples, limit: float, radius: float, dist: np.ndarray) -> CoverageReport:
    bare = dist > limit
    share = percent_of(samples.area[bare].sum(), samples.area.sum())
    worst = int(np.argmax(dist))
    return CoverageReport(share, float(dist[worst]), tuple(float(v) for v in samples.points[worst]),
                          float(limit), samples.spacing, bare, samples, dist, radius)


def _reaching(pts: np.ndarray, placed: Placed) -> Placed:
    """The blocks that may be the nearest to one of ``pts``; the others change no distance.

    Every point lies within ``U`` (its nearest centroid, plus a bounding radius R) of a
    block, and a block whose centroid is further than ``U + 2 R`` from every point is
    further than that from each of them. 10 000 blocks laid 3 m apart over a square
    kilometre, around a mound of 300 m^3, put 10 million samples into one search: 15 s.
    """
    centres = np.array([pose.position for _, _, pose in placed])
    nearest, _ = cKDTree(centres).query(pts)
    return _near(placed, centres, pts, float(nearest.max()) + 2.0 * _largest_radius(placed))


def block_spacing(block: Block, step: float) -> float:
    """The spacing a block is sampled at: no finer than ``step``, its own H / CELLS_PER_H and
    MAX_BLOCK_SAMPLES over its surface, and widened by half again while that takes more than
    MOST_BLOCK_SAMPLES, up to the block's width, where its corners alone are the samples (a
    mesh of 98 000 corners has no fewer: the widening ran for ever)."""
    chosen = _SPACINGS.setdefault(block, {})
    if step not in chosen:
        spacing = max(step, block.height / CELLS_PER_H,
                      math.sqrt(4.0 * block.surface_area / MAX_BLOCK_SAMPLES))
        while (block_samples(block, spacing, most=MOST_BLOCK_SAMPLES) is None
               and spacing < 2.0 * block.bounding_radius):
            spacing *= 1.5
        chosen[step] = spacing
    return chosen[step]


def _distances(pts: np.ndarray, placed: Placed, step: float, limit: float, exact: bool = False,
               due: tuple[float, Callable[[], float]] | None = None) -> np.ndarray:
    """Each point's distance to the nearest block: exact where it decides the point is bare, and
    near the largest (everywhere with ``exact``); elsewhere an upper bound at most ``step`` over it.
    ``due``: (deadline, clock), checked between blocks (:class:`TimeUp`)."""

    def check() -> None:
        if due is not None and due[1]() > due[0]:
            raise TimeUp("the coverage was not measured by its deadline")

    dist = np.full(len(pts), np.inf)
    placed = _reaching(pts, placed) if placed and len(pts) else placed
    if placed and len(pts):
        # A block is sampled no finer than its own H / CELLS_PER_H: a layout of Shake Blocks
        # checked against a scene of 5 cm tetrapods put 47 000 samples on each (30 s, 670 MB).
        # The bound below then holds to the coarsest spacing, and the exact distances decide.
        # And no finer than MAX_BLOCK_SAMPLES over its surface (the halving leaves about four
        # samples to each spacing squared of it).
        kinds = {id(block): block for _, block, _ in placed}
        spacing = {k: block_spacing(block, step) for k, block in kinds.items()}
        step = max(spacing.values())
        clouds = []
        for _, block, pose in placed:
            check()
            clouds.append(pose.apply(block_samples(block, spacing[id(block)])))
        owner = np.repeat(np.arange(len(placed)), [len(c) for c in clouds])
        tree = quick_tree(np.concatenate(clouds))
        upper, nearest = np.empty(len(pts)), np.empty(len(pts), int)
        # In parts, the deadline read between them: 27 slender blocks (3.9 million samples)
        # against 240 000 surface points took one 32 s query.
        for lo in range(0, len(pts), QUERY_CHUNK):
            check()
            upper[lo:lo + QUERY_CHUNK], nearest[lo:lo + QUERY_CHUNK] = tree.query(pts[lo:lo + QUERY_CHUNK])
        dist = upper.copy()  # the true distance is in [upper - step, upper], or 0 inside a block
        # Exact where the bound leaves the verdict open, and near the largest distance.
        todo = ((upper - step <= limit) & (upper > limit)) | (upper >= upper.max() - step) | exact
        centres = cKDTree(np.array([pose.position for _, _, pose in placed]))
        radius = max(block.bounding_radius for block in kinds.values())
        # A point inside a block is at 0, however far the block's surface: the design surface
        # inside a box 2 m thick was called bare 0.96 m from its sides. Only a point no further
        # from a sample than the deepest any block's inside lies can be one.
        deep = np.flatnonzero(~todo & (upper > limit)
                              & (upper <= max(block.depth for block in kinds.values()) + step))
        dist[deep[_inside_any(pts[deep], placed, centres, radius)]] = 0.0
        points = np.flatnonzero(todo)
        dist[points] = np.inf
        # The blocks that may hold each open point's nearest surface, gathered per block, so
        # that each block measures all its points in one vectorised call (a call per point
        # and block cost 0.8 of the 1 s a 75-block layout took; the distances are the same).
        # In parts too, the deadline read between them: 16 needles 0.1 m thick left 500 000 open
        # points on a mound, gathered for 3.6 s past a 10 s limit.
        pairs: dict[int, list[int]] = {}
        for lo in range(0, len(points), QUERY_CHUNK):
            check()
            part = points[lo:lo + QUERY_CHUNK]
            for i, near in zip(part, centres.query_ball_point(pts[part], upper[part] + radius), strict=True):
                for k in {int(owner[nearest[i]]), *near}:
                    pairs.setdefault(k, []).append(int(i))
        for k, members in pairs.items():
            check()
            idx = np.array(members)
            dist[idx] = np.minimum(dist[idx], distance_to_block(pts[idx], placed[k][1], placed[k][2]))
    return dist
