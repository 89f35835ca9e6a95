"""Scoring a trainee's layout against the reference (``shoha score``, docs/scoring.md).

The score is the share of the required blocks laid, times the quality of
what is laid::

    progress_percent = 100 x min(blocks, required) / required
    quality          = 100 x 0.99 ** points
    score            = progress_percent x quality / 100

Quality starts at 100 % and each penalty point takes 1 % of the quality that
is left, so every fault costs, however many came before it, and quality never
goes below 0. The points (``ScoreWeights``) are for:

=============  ==========================================================
penalty        points, by default
=============  ==========================================================
tolerance      5 per block sticking out of the tolerance zone
collisions     5 per pair of blocks pushed into each other
stability      5 per block the settle moves or turns too far
porosity       2.5 per percentage point further from the target than the
               reference
interlock      2 per poorly interlocked block beyond the reference's count
coverage       1 per percentage point of bare slope and crest beyond the
               reference's
time           0 per second of mean time per block above a par
=============  ==========================================================

The first three are faults of a block of its own, judged on the blocks laid;
such a block is charged for its fault and takes no further part. The next
three are judged at the trainee's stage: the save's good blocks are
*finished* with the reference's own blocks for the places they do not fill,
as many as the save lacks (:meth:`Reference.finish`), and the finished save
is compared with the whole reference. A block that is not laid yet is then
neither charged (it is the reference's own) nor excused, a missing block
costs only progress, and each fault is charged once. Adding the block the
reference lays next, where it fits and stands, leaves the finished save as
it was, so it costs no quality while progress rises: the score rises with
every block laid well, for any non-negative weights.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Collection, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from geometry.blocks import Block
from geometry.collision import Collision, collisions
from geometry.coverage import CoverageReport, coverage, coverage_after
from geometry.errors import InputError, finite_number, shown
from geometry.porosity import exact_filled_volume, porosity
from geometry.pose import Pose
from geometry.scene import Scene
from geometry.tolerance import TrapezoidalPrism, out_of_tolerance
from settle import SettleResult, settle

from .interlock import InterlockReport, InterlockRule, interlock

Placed = Sequence[tuple[int, Block, Pose]]

#: Zones of the porosity map: slices along the crest (y) and layers (z).
DEFAULT_SLICES = 4
DEFAULT_LAYERS = 2
#: Seed of the settle a score runs: the same save always gets the same score.
SETTLE_SEED = 0
#: Each penalty point keeps this share of the quality that is left (takes 1 %).
POINT_KEEPS = 0.99
#: A laid block fills a place of the reference when its centroid is within
#: this fraction of the block height H of the reference block's (0.25 H,
#: 0.42 m for the 4-ton Shake Block: well under half the 1.3 m or more between
#: neighbouring centroids, so a block fills at most one place).
PLACE_FRACTION = 0.25
#: Most finished saves whose coverage a Reference keeps (docs/scoring.md).
CACHED_STAGES = 256



#: The shortest session, in seconds, over which a rate of blocks per hour is given: a save
#: whose blocks all carry ``time_s`` 5e-324 gave an infinite rate, which no JSON can hold.
MIN_RATE_SECONDS = 1e-3


def per_hour(blocks: int, elapsed_s: float | None) -> float | None:
    """Blocks per hour over ``elapsed_s`` seconds; None without a time, or under ``MIN_RATE_SECONDS``."""
    if elapsed_s is None or elapsed_s < MIN_RATE_SECONDS:
        return None
    return 3600.0 * blocks / elapsed_s

@dataclass(frozen=True)
class ScoreWeights:
    """Points per fault (docs/scoring.md); a trainer may change any of them.

    Every weight is a non-negative number; 0 makes that kind of fault free.
    Each point takes 1 % of the quality that is left.

    Attributes
    ----------
    tolerance_per_block : float, points
        Per block sticking out of the tolerance zone.
    collision_per_pair : float, points
        Per pair of blocks pushed into each other (deeper than 5 mm).
    unstable_per_block : float, points
        Per block the settle moves more than 0.05 H or turns more than 5 degrees.
    porosity_per_percent : float, points
        Per percentage point the finished save's porosity is further from the
        target than the reference's.
    interlock_per_block : float, points
        Per poorly interlocked block of the finished save beyond the reference's count.
    coverage_per_percent : float, points
        Per percentage point of the slopes' and crest's area the finished save
        leaves bare beyond the reference's.
    time_per_second : float, points
        Per second the mean time per block laid is above ``par_seconds_per_block``;
        0 by default: the time is reported, not scored.
    par_seconds_per_block : float, seconds
        The par time per block for ``time_per_second``.
    """

    tolerance_per_block: float = 5.0
    collision_per_pair: float = 5.0
    unstable_per_block: float = 5.0
    porosity_per_percent: float = 2.5
    interlock_per_block: float = 2.0
    coverage_per_percent: float = 1.0
    time_per_second: float = 0.0
    par_seconds_per_block: float = 60.0

    def __post_init__(self) -> None:
        for name, v in self.__dict__.items():
            if not finite_number(v) or v < 0:
                raise InputError(f"score weights: {name} must be a non-negative number, not {shown(v)}")

    def to_dict(self) -> dict[str, float]:
        return dict(self.__dict__)


@dataclass(frozen=True)
class Zone:
    """One zone of the porosity map: a slice along the crest, lower or upper layer.

    Attributes
    ----------
    slice : int
        0 at y = 0, counting along the crest.
    layer : int
        0 for the lower layer (from the foundation), 1 above it.
    y0, y1, z0, z1 : float, metres, world frame
        The zone is the part of the design prism with y0 <= y <= y1 and
        z0 <= z <= z1.
    volume_m3 : float
        Its volume.
    filled_m3 : float
        Block volume inside it (exact).
    """

    slice: int
    layer: int
    y0: float
    y1: float
    z0: float
    z1: float
    volume_m3: float
    filled_m3: float

    @property
    def porosity_percent(self) -> float:
        """Porosity of the zone, eq. (1) of the reference paper, percent in [0, 100]."""
        return float(min(100.0, max(0.0, 100.0 * (self.volume_m3 - self.filled_m3) / self.volume_m3)))

    def to_dict(self) -> dict[str, Any]:
        return {"slice": self.slice, "layer": self.layer, "y0_m": self.y0, "y1_m": self.y1,
                "z0_m": self.z0, "z1_m": self.z1, "volume_m3": self.volume_m3,
                "filled_m3": self.filled_m3, "porosity_percent": self.porosity_percent}


def zone_prisms(scene: Scene, slices: int = DEFAULT_SLICES, layers: int = DEFAULT_LAYERS
                ) -> list[tuple[int, int, TrapezoidalPrism]]:
    """The design prism cut into ``slices`` along y and ``layers`` of equal height.

    Each zone of a trapezoidal prism cut by planes y = const and z = const is
    again a trapezoidal prism, whose half widths follow the design slopes.

    Returns
    -------
    list of (slice, layer, TrapezoidalPrism), world frame, slice-major.
    """
    for name, n in (("slices", slices), ("layers", layers)):
        if not isinstance(n, int) or isinstance(n, bool) or not 1 <= n <= 100:
            raise InputError(f"porosity map: {name} must be an integer from 1 to 100, not {n!r}")
    parts = scene.design.cut(slices, layers)
    return [(i, j, parts[i * layers + j]) for i in range(slices) for j in range(layers)]


def porosity_map(scene: Scene, placed: Placed, slices: int = DEFAULT_SLICES,
                 layers: int = DEFAULT_LAYERS) -> list[Zone]:
    """Exact porosity of each zone of the design prism (see :func:`zone_prisms`).

    Each zone's filled volume comes from the porosity module
    (``geometry.porosity.exact_filled_volume``), which clips every block to
    the zone and unions overlapping blocks, so the zones' filled volumes add
    up to the whole prism's.
    """
    out = []
    for i, j, prism in zone_prisms(scene, slices, layers):
        # Only blocks whose bounding sphere reaches the zone can fill it.
        near = [(k, b, p) for k, b, p in placed
                if prism.y_start - b.bounding_radius <= p.position[1] <= prism.y_end + b.bounding_radius
                and prism.z_bottom - b.bounding_radius <= p.position[2] <= prism.z_top + b.bounding_radius]
        filled = exact_filled_volume(prism.polytope, near) if near else 0.0
        out.append(Zone(i, j, prism.y_start, prism.y_end, prism.z_bottom, prism.z_top, prism.volume,
                        float(filled)))
    return out


@dataclass(frozen=True)
class Stage:
    """The reference after its first ``blocks`` blocks in crane order, for display beside a save.

    Attributes
    ----------
    blocks : int
    porosity_percent : float
        Exact porosity of the design prism.
    flagged : list of int
        Ids of its poorly interlocked blocks.
    zones : list of Zone
    """

    blocks: int
    porosity_percent: float
    flagged: list[int]
    zones: list[Zone]


@dataclass
class Reference:
    """What a score needs from the reference layout, computed once and reused (a batch, a session).

    Attributes
    ----------
    scene : Scene
    placed : list of (id, Block, Pose)
        In crane order.
    porosity_percent : float
        Exact porosity of the design prism.
    flagged : list of int
        Its poorly interlocked blocks.
    zones : list of Zone
    out_of_tolerance, collisions : int
        Its own faults (zero for a valid reference).
    slices, layers : int
        Of the porosity maps.
    rule : InterlockRule

    Notes
    -----
    The reference's coverage (0.2-0.8 s) and its stages are computed when a
    score first needs them and kept: a batch or a live session pays once.
    """

    scene: Scene
    placed: list[tuple[int, Block, Pose]]
    porosity_percent: float
    flagged: list[int]
    zones: list[Zone]
    out_of_tolerance: int
    collisions: int
    slices: int
    layers: int
    rule: InterlockRule = field(default_factory=InterlockRule)
    _coverage: CoverageReport | None = field(default=None, repr=False, compare=False)
    _stages: dict[int, Stage] = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def of(cls, scene: Scene, placed: Placed, slices: int = DEFAULT_SLICES, layers: int = DEFAULT_LAYERS,
           rule: InterlockRule | None = None) -> Reference:
        placed = list(placed)
        rule = rule if rule is not None else InterlockRule()
        return cls(
            scene=scene,
            placed=placed,
            porosity_percent=porosity(scene, placed, "exact").percent,
            flagged=interlock(placed, scene.foundation, rule).flagged,
            zones=porosity_map(scene, placed, slices, layers),
            out_of_tolerance=len(out_of_tolerance(placed, scene.tolerance)),
            collisions=len(collisions(placed)),
            slices=slices,
            layers=layers,
            rule=rule,
        )

    @property
    def coverage(self) -> CoverageReport:
        """Coverage of the whole reference (computed once)."""
        if self._coverage is None:
            self._coverage = coverage(self.scene, self.placed)
        return self._coverage

    def coverage_of(self, placed: Placed) -> CoverageReport:
        """Coverage of a layout that shares blocks with the reference: the reference's own,
        measured again only near the blocks where the two differ (:func:`coverage_after`, same
        figures as :func:`coverage`). A save finished with the reference's blocks differs from
        it only where the trainee laid blocks of their own."""
        placed = list(placed)
        ours = {_pose_key(block, pose) for _, block, pose in self.placed}
        theirs = {_pose_key(block, pose) for _, block, pose in placed}
        put_in = [pose.position for _, block, pose in placed if _pose_key(block, pose) not in ours]
        taken_out = [pose.position for _, block, pose in self.placed if _pose_key(block, pose) not in theirs]
        if not put_in and not taken_out:
            return self.coverage
        return coverage_after(self.scene, placed, self.coverage, put_in + taken_out)

    def stage(self, blocks: int) -> Stage:
        """The reference after its first ``blocks`` blocks (at most all of them), computed once."""
        n = min(max(0, blocks), len(self.placed))
        cached = self._stages.get(n)
        if cached is None:
            if n == len(self.placed):
                cached = Stage(n, self.porosity_percent, list(self.flagged), list(self.zones))
            else:
                first = self.placed[:n]
                cached = Stage(n, porosity(self.scene, first, "exact").percent,
                               interlock(first, self.scene.foundation, self.rule).flagged,
                               porosity_map(self.scene, first, self.slices, self.layers))
            if len(self._stages) >= CACHED_STAGES:
                self._stages.pop(next(iter(self._stages)))
            self._stages[n] = cached
        return cached

    def place_radius(self) -> float:
        """Metres: a laid block within this of a reference block's centroid fills its place."""
        return PLACE_FRACTION * self.scene.block.height

    def finish(self, placed: Placed, left_out: Collection[int] = ()
               ) -> tuple[list[tuple[int, Block, Pose]], list[int]]:
        """A save finished with the reference's blocks for the places its good blocks do not fill.

        A laid block fills a reference place when its centroid is within
        :meth:`place_radius` of the reference block's; pairs are matched
        nearest first, each block and place once (:func:`filled_places`).
        The blocks ``left_out`` (those with a fault of their own, charged for
        it) are taken out, and the places they filled are free again. The
        free places get the reference's blocks, in crane order, as many as
        the save has fewer good blocks than the reference. A save that
        follows the crane order is thus finished with the reference's
        remaining blocks, and one laid in another order with the same blocks
        finishes as the reference.

        Returns
        -------
        (finished, added)
            ``finished``: the good blocks and the added reference blocks,
            ordered by the place they fill (crane order; good blocks that
            fill no place last, in save order), so that the reference's own
            blocks in any order give the reference's list exactly. ``added``:
            the reference ids of the added blocks, in crane order. The added
            blocks keep their reference ids unless one is also a save id;
            then they all move up past the save's largest id.
        """
        placed = list(placed)
        skip = set(left_out)
        places = filled_places(placed, self.placed, self.place_radius())
        good = [i for i, (k, _, _) in enumerate(placed) if k not in skip]
        key = {i: len(self.placed) + i for i in good}
        for place, i in places.items():
            if i in key:
                key[i] = place
        filled = {key[i] for i in good if key[i] < len(self.placed)}
        todo = max(0, len(self.placed) - len(good))
        free = [k for k in range(len(self.placed)) if k not in filled][:todo]
        ids = {k for k, _, _ in placed}
        added = [self.placed[k] for k in free]
        shift = max(ids) + 1 if any(k in ids for k, _, _ in added) else 0
        rows = [(key[i], placed[i]) for i in good]
        rows += [(k, (rk + shift, b, p)) for k, (rk, b, p) in zip(free, added, strict=True)]
        rows.sort(key=lambda row: row[0])
        return [b for _, b in rows], [k for k, _, _ in added]


def filled_places(placed: Placed, reference: Placed, radius: float) -> dict[int, int]:
    """Which laid block fills each reference place: ``{reference index: save index}``.

    A laid block fills a place when its centroid is within ``radius``
    metres of the reference block's. Pairs are taken nearest first (ties by
    save index, then reference index), each block and each place at most
    once. Adding a block exactly at a free place leaves every other pair as
    it was: its pair comes first, and no other pair held that place.
    """
    if not placed or not reference:
        return {}
    mine = cKDTree(np.array([p.position for _, _, p in placed]))
    theirs = cKDTree(np.array([p.position for _, _, p in reference]))
    pairs = mine.sparse_distance_matrix(theirs, radius, output_type="ndarray")
    taken: set[int] = set()
    filled: dict[int, int] = {}
    for k in np.lexsort((pairs["j"], pairs["i"], pairs["v"])):
        i, j = int(pairs["i"][k]), int(pairs["j"][k])
        if i not in taken and j not in filled:
            taken.add(i)
            filled[j] = i
    return filled


def _pose_key(block: Block, pose: Pose) -> tuple[int, bytes, bytes]:
    """A block as the coverage sees it: the block itself (not its name: a relative ``mesh:``
    path names other files beside other saves) and its pose, to the last bit."""
    return id(block), pose.position.tobytes(), pose.quaternion.tobytes()


@dataclass(frozen=True)
class Measures:
    """What a score counts, before the weights (docs/scoring.md).

    Attributes
    ----------
    blocks, required_blocks : int
    out_of_tolerance, collisions, unstable : int
        Faults of the blocks laid: blocks, pairs, blocks.
    porosity_percent, reference_porosity_percent, target_porosity_percent : float
        The finished save's porosity, the reference's, and the scene's target.
    flagged, reference_flagged : int
        Poorly interlocked blocks of the finished save, and of the reference.
    bare_share_percent, reference_bare_share_percent : float
        Bare share of the slopes and crest, finished save and reference.
    seconds_per_block : float or None
        Mean time per block laid, seconds; None without times.
    """

    blocks: int
    required_blocks: int
    out_of_tolerance: int
    collisions: int
    unstable: int
    porosity_percent: float
    reference_porosity_percent: float
    target_porosity_percent: float
    flagged: int
    reference_flagged: int
    bare_share_percent: float
    reference_bare_share_percent: float
    seconds_per_block: float | None = None


@dataclass(frozen=True)
class Penalty:
    """Points for one kind of fault.

    Attributes
    ----------
    name : str
        ``tolerance``, ``collisions``, ``stability``, ``porosity``,
        ``interlock``, ``coverage`` or ``time``.
    amount : float
        What was counted: blocks, pairs, percentage points beyond the
        reference's, or seconds per block above par.
    points : float
        ``amount`` times its weight.
    rule : str
        The rule in words, for the report.
    """

    name: str
    amount: float
    points: float
    rule: str

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "amount": self.amount, "points": self.points, "rule": self.rule}


def penalties(m: Measures, weights: ScoreWeights | None = None) -> list[Penalty]:
    """The seven penalties of a score (module docstring, docs/scoring.md)."""
    w = weights if weights is not None else ScoreWeights()
    target = m.target_porosity_percent
    porosity_excess = max(0.0, abs(m.porosity_percent - target) - abs(m.reference_porosity_percent - target))
    flagged_excess = max(0, m.flagged - m.reference_flagged)
    bare_excess = max(0.0, m.bare_share_percent - m.reference_bare_share_percent)
    slow = max(0.0, m.seconds_per_block - w.par_seconds_per_block) if m.seconds_per_block is not None else 0.0
    amounts = [
        ("tolerance", float(m.out_of_tolerance), w.tolerance_per_block,
         f"{w.tolerance_per_block:g} per block out of the tolerance zone"),
        ("collisions", float(m.collisions), w.collision_per_pair,
         f"{w.collision_per_pair:g} per pair of blocks pushed into each other"),
        ("stability", float(m.unstable), w.unstable_per_block,
         f"{w.unstable_per_block:g} per block that moves or turns in the settle"),
        ("porosity", porosity_excess, w.porosity_per_percent,
         f"{w.porosity_per_percent:g} per percentage point the finished layout is further from the "
         f"{target:g}% target than the reference"),
        ("interlock", float(flagged_excess), w.interlock_per_block,
         f"{w.interlock_per_block:g} per poorly interlocked block of the finished layout beyond the "
         f"reference's"),
        ("coverage", bare_excess, w.coverage_per_percent,
         f"{w.coverage_per_percent:g} per percentage point of slope and crest the finished layout "
         f"leaves bare beyond the reference"),
        ("time", slow, w.time_per_second,
         f"{w.time_per_second:g} per second of mean time per block above {w.par_seconds_per_block:g} s"),
    ]
    return [Penalty(name, amount, weight * amount, rule) for name, amount, weight, rule in amounts]


def progress_percent(blocks: int, required: int) -> float:
    """Blocks laid of those required, percent in [0, 100] (100 when none are required)."""
    if required <= 0:
        return 100.0
    return 100.0 * min(blocks, required) / required


def quality_percent(points: float) -> float:
    """Quality from penalty points: 100 x 0.99 ** points, percent in (0, 100].

    Any points at all keep it under 100, however few: 0.99 ** 1e-91 is 1.0 in floating
    point, and a save with a fault must not score as the reference does.
    """
    quality = 100.0 * POINT_KEEPS ** points
    return min(quality, math.nextafter(100.0, 0.0)) if points > 0.0 else quality


def combined(progress: float, quality: float) -> float:
    """The score: progress times quality, out of 100."""
    return progress * quality / 100.0


@dataclass
class ScoreReport:
    """A trainee's layout scored against the reference.

    Attributes
    ----------
    score : float
        ``progress_percent x quality / 100``, in [0, 100]; not rounded, so
        that every fault shows in it (the text and the report show 0.1).
    progress_percent : float
        Blocks laid of those required, percent.
    quality : float
        Percent in (0, 100]: ``100 x 0.99 ** (sum of the penalty points)``.
    penalties : list of Penalty
    weights : ScoreWeights
    measures : Measures
        What the penalties count, before the weights.
    porosity_percent : float
        The save's own porosity.
    reference_porosity_percent : float
        The reference's after as many blocks as the save has (its first in
        crane order): the porosity the save's stage compares with.
    target_porosity_percent : float
    blocks, required_blocks : int
    out_of_tolerance : list of (id, outside volume m^3)
    collisions : list of Collision
    settle : SettleResult
    interlock : InterlockReport
        Of the save's own blocks.
    coverage : CoverageReport
        Of the save's own blocks.
    finished_coverage : CoverageReport
        Of the save finished with the reference's blocks.
    added : list of int
        Reference ids of the blocks that finish the save.
    left_out : list of int
        Ids of the save's blocks with a fault of their own (out of
        tolerance, colliding, unstable), left out of the finished save.
    zones, reference_zones : list of Zone
        The save's porosity map, and the reference's at the same stage.
    reference_flagged : list of int
        Poorly interlocked blocks of the reference at the same stage.
    stage_blocks : int
        The stage: the reference's first blocks the save is shown beside
        (as many as the save has, at most all).
    elapsed_s : float or None
        Seconds from the session's start to the save.
    scene : str
    seconds : float
        Compute time, seconds.
    """

    score: float
    progress_percent: float
    quality: float
    penalties: list[Penalty]
    weights: ScoreWeights
    measures: Measures
    porosity_percent: float
    reference_porosity_percent: float
    target_porosity_percent: float
    blocks: int
    required_blocks: int
    out_of_tolerance: list[tuple[int, float]]
    collisions: list[Collision]
    settle: SettleResult
    interlock: InterlockReport
    coverage: CoverageReport
    finished_coverage: CoverageReport
    added: list[int]
    left_out: list[int]
    zones: list[Zone]
    reference_zones: list[Zone]
    reference_flagged: list[int]
    stage_blocks: int
    scene: str
    elapsed_s: float | None = None
    seconds: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def remaining_blocks(self) -> int:
        return max(0, self.required_blocks - self.blocks)

    @property
    def stable(self) -> bool:
        return bool(self.settle.stable)

    @property
    def unstable_ids(self) -> list[int]:
        return self.settle.unstable_ids

    @property
    def points(self) -> float:
        """Sum of the penalty points."""
        return float(sum(p.points for p in self.penalties))

    @property
    def completion_time_s(self) -> float | None:
        """Seconds to lay the required blocks: ``elapsed_s`` of a complete save, else None."""
        return self.elapsed_s if self.remaining_blocks == 0 else None

    @property
    def blocks_per_hour(self) -> float | None:
        """Blocks laid per hour of the session, or None without times (:func:`per_hour`)."""
        return per_hour(self.blocks, self.elapsed_s)

    def reweighted(self, weights: ScoreWeights) -> ScoreReport:
        """The same measurements scored with other weights (no settle or geometry again)."""
        pens = penalties(self.measures, weights)
        quality = quality_percent(sum(p.points for p in pens))
        return dataclasses.replace(self, penalties=pens, weights=weights, quality=quality,
                                   score=combined(self.progress_percent, quality))

    def to_dict(self) -> dict[str, Any]:
        """The keys of ``shoha score --json`` (docs/contract.md, "CLI"), and more."""
        s, m = self.settle, self.measures
        return {
            "score": self.score,
            "progress_percent": self.progress_percent,
            "quality": self.quality,
            "penalty_points": self.points,
            "porosity_percent": self.porosity_percent,
            "reference_porosity_percent": self.reference_porosity_percent,
            "target_porosity_percent": self.target_porosity_percent,
            "porosity_gap_to_target_percent": self.porosity_percent - self.target_porosity_percent,
            "porosity_gap_to_reference_percent": self.porosity_percent - self.reference_porosity_percent,
            "out_of_tolerance": [{"id": k, "outside_volume_m3": v} for k, v in self.out_of_tolerance],
            "collisions": [{"a": c.a, "b": c.b, "depth_m": c.depth} for c in self.collisions],
            "stable": self.stable,
            "unstable_blocks": self.unstable_ids,
            "blocks": self.blocks,
            "required_blocks": self.required_blocks,
            "remaining_blocks": self.remaining_blocks,
            "interlock": self.interlock.to_dict(),
            "reference_flagged": list(self.reference_flagged),
            "stage_blocks": self.stage_blocks,
            "coverage": self.coverage.to_dict(),
            "finished": {
                "left_out": list(self.left_out),
                "added_reference_blocks": list(self.added),
                "porosity_percent": m.porosity_percent,
                "reference_porosity_percent": m.reference_porosity_percent,
                "poorly_interlocked": m.flagged,
                "reference_poorly_interlocked": m.reference_flagged,
                "bare_share_percent": m.bare_share_percent,
                "reference_bare_share_percent": m.reference_bare_share_percent,
            },
            "zones": {
                "save": [z.to_dict() for z in self.zones],
                "reference": [z.to_dict() for z in self.reference_zones],
            },
            "penalties": [p.to_dict() for p in self.penalties],
            "weights": self.weights.to_dict(),
            "elapsed_s": self.elapsed_s,
            "completion_time_s": self.completion_time_s,
            "blocks_per_hour": self.blocks_per_hour,
            "settle": {
                "max_displacement_m": s.max_displacement_m,
                "max_rotation_deg": s.max_rotation_deg,
                "simulated_seconds": s.simulated_seconds,
                "backend": s.backend,
                "blocks": [{"id": b.id, "displacement_m": b.displacement_m, "rotation_deg": b.rotation_deg,
                            "stable": b.stable} for b in s.blocks],
            },
            "scene": self.scene,
            "seconds": self.seconds,
            **self.extra,
        }

    def summary(self) -> str:
        """The score, its two parts and its penalties in plain words."""
        m = self.measures
        stage = f"the reference at {self.stage_blocks} blocks"
        lines = [
            f"score {self.score:.1f} / 100: progress {self.progress_percent:.1f}% "
            f"({self.blocks} of {self.required_blocks} blocks), quality {self.quality:.1f}%",
            f"porosity {self.porosity_percent:.2f}% ({stage}: {self.reference_porosity_percent:.2f}%)",
            f"out of tolerance: {len(self.out_of_tolerance)}; collisions: {len(self.collisions)}; "
            f"{'stable' if self.stable else 'UNSTABLE: blocks ' + str(self.unstable_ids)}; "
            f"poorly interlocked: {len(self.interlock.flagged)} ({stage}: {len(self.reference_flagged)})",
        ]
        if self.added or self.left_out:
            parts = ([f"{len(self.left_out)} faulty blocks left out"] if self.left_out else []) + (
                [f"the reference's blocks added at {len(self.added)} places"] if self.added else [])
            lines.append(f"finished ({', '.join(parts)}): porosity {m.porosity_percent:.2f}% (reference "
                         f"{m.reference_porosity_percent:.2f}%, target {m.target_porosity_percent:g}%); "
                         f"poorly interlocked {m.flagged} (reference {m.reference_flagged}); bare slope and "
                         f"crest {m.bare_share_percent:.2f}% "
                         f"(reference {m.reference_bare_share_percent:.2f}%)")
        else:
            lines.append(f"bare slope and crest {m.bare_share_percent:.2f}% "
                         f"(reference {m.reference_bare_share_percent:.2f}%)")
        if self.elapsed_s is not None:
            rate = self.blocks_per_hour
            lines.append(f"time {self.elapsed_s:g} s"
                         + (f", {rate:.1f} blocks per hour" if rate is not None else "")
                         + ("" if self.completion_time_s is None else " (complete)"))
        for p in self.penalties:
            if p.points > 0:
                lines.append(f"  -{p.points:.2f} points {p.name}: {p.rule}")
        return "\n".join(lines)


def check_same_scene(scene: Scene, reference: Scene, where: str, against: str = "the reference's") -> None:
    """Raise InputError if a save and the reference (or ``against`` another: "the optimized")
    are not for the same breakwater."""
    if scene.design != reference.design or scene.block_type != reference.block_type:
        # Two files may share a name and differ (a probe's "scene 'tiny' is not the optimized
        # scene 'tiny'"): the file and what differs are named.
        ours, theirs = (f"{s.name!r}" + (f" ({s.source})" if s.source and s.source != s.name else "")
                        for s in (scene, reference))
        what = ("its block" if scene.design == reference.design
                else f"its section ({_section_difference(scene, reference)})")
        raise InputError(f"{where}: scene {ours} is not {against} scene {theirs}: {what} differs")


def _section_difference(scene: Scene, reference: Scene) -> str:
    """The first measure of the design section in which two scenes differ, in words."""
    measures = (("crest_width", "crest"), ("height", "height"), ("slope", "slopes"), ("length", "length"),
                ("wall", "wall"))
    for name, label in measures:
        a, b = getattr(scene, name), getattr(reference, name)
        if a != b:
            return f"{label} {a} against {b}"
    return "its prism"


def score(
    scene: Scene,
    placed: Placed,
    reference: Reference,
    seconds: float = 2.0,
    seed: int = SETTLE_SEED,
    weights: ScoreWeights | None = None,
    rule: InterlockRule | None = None,
    elapsed_s: float | None = None,
) -> ScoreReport:
    """Score a layout against a reference.

    Parameters
    ----------
    scene : Scene
        The scene the layout is for; its design must be the reference's.
    placed : sequence of (id, Block, Pose)
        The trainee's blocks, world frame, in the order laid.
    reference : Reference
        ``Reference.of(scene, reference_layout.placed())``; keep it to score
        many saves (it caches what it computes).
    seconds : float
        Simulated seconds of the stability settle.
    seed : int
        Seed of the settle; fixed so that a save always gets the same score.
    weights : ScoreWeights, optional
    rule : InterlockRule, optional
        The reference's rule by default.
    elapsed_s : float, optional
        Seconds from the session's start to the save (``Layout.session_seconds``),
        for the completion time, the blocks per hour and the time penalty.

    Returns
    -------
    ScoreReport
    """
    start = time.perf_counter()
    check_same_scene(scene, reference.scene, "score")
    weights = weights if weights is not None else ScoreWeights()
    rule = rule if rule is not None else reference.rule
    placed = list(placed)
    n = len(placed)
    # MuJoCo lets go of the GIL while it steps, so the settle runs on a second core beside the
    # geometry that does not need its verdict: a score takes the longer of the two, not their sum.
    with ThreadPoolExecutor(1, thread_name_prefix="shoha-settle") as pool:
        settling = pool.submit(settle, scene, placed, seconds=seconds, seed=seed)
        own_porosity = porosity(scene, placed, "exact").percent
        # The scene's own zone, as ``shoha check`` judges it (5 mm below the foundation: a block
        # an engine sinks into it is in contact). Until stop 76 a zone of its own reached 15 mm
        # below, and a block sunk 8 mm was out to ``check`` and not to ``score``.
        outside = out_of_tolerance(placed, scene.tolerance)
        pairs = collisions(placed)
        held = interlock(placed, scene.foundation, rule)
        own_cover = coverage(scene, placed)
        zones = porosity_map(scene, placed, reference.slices, reference.layers)
        settled = settling.result()
    stage = reference.stage(n)
    # Judged at the trainee's stage: the save's good blocks finished with the reference's own.
    # A block with a fault of its own is charged for that fault and left out here.
    left_out = sorted({k for k, _ in outside} | {c.a for c in pairs} | {c.b for c in pairs}
                      | set(settled.unstable_ids))
    finished, added = reference.finish(placed, left_out)
    if added or left_out:
        finished_porosity = porosity(scene, finished, "exact").percent
        finished_flagged = len(interlock(finished, scene.foundation, rule).flagged)
        finished_cover = reference.coverage_of(finished)
    else:
        finished_porosity, finished_flagged, finished_cover = own_porosity, len(held.flagged), own_cover
    measures = Measures(
        blocks=n,
        required_blocks=scene.required_blocks,
        out_of_tolerance=len(outside),
        collisions=len(pairs),
        unstable=len(settled.unstable_ids),
        porosity_percent=finished_porosity,
        reference_porosity_percent=reference.porosity_percent,
        target_porosity_percent=scene.target_porosity,
        flagged=finished_flagged,
        reference_flagged=len(reference.flagged),
        bare_share_percent=finished_cover.bare_share_percent,
        reference_bare_share_percent=reference.coverage.bare_share_percent,
        seconds_per_block=elapsed_s / n if elapsed_s is not None and n else None,
    )
    pens = penalties(measures, weights)
    progress = progress_percent(n, scene.required_blocks)
    quality = quality_percent(sum(p.points for p in pens))
    return ScoreReport(
        score=combined(progress, quality),
        progress_percent=progress,
        quality=quality,
        penalties=pens,
        weights=weights,
        measures=measures,
        porosity_percent=own_porosity,
        reference_porosity_percent=stage.porosity_percent,
        target_porosity_percent=scene.target_porosity,
        blocks=n,
        required_blocks=scene.required_blocks,
        out_of_tolerance=outside,
        collisions=pairs,
        settle=settled,
        interlock=held,
        coverage=own_cover,
        finished_coverage=finished_cover,
        added=added,
        left_out=left_out,
        zones=zones,
        reference_zones=stage.zones,
        reference_flagged=stage.flagged,
        stage_blocks=stage.blocks,
        scene=scene.name,
        elapsed_s=elapsed_s,
        seconds=time.perf_counter() - start,
    )
