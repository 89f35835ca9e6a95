"""Scoring a trainee's layout against the reference (``shoha score``, docs/scoring.md).

The metrics are the simulator's own (Table III of the reference paper:
porosity, required and remaining blocks, out-of-tolerance blocks), with the
stability verdict of a physics settle, the collisions, the interlock of each
block and a porosity map by zone, each beside the reference's. They are
combined into one score out of 100::

    score = 100 - (porosity + missing + tolerance + collisions + stability + interlock)

where each penalty is capped, and the caps add up to 100 (``ScoreWeights``):

=============  ==========================================================  ====
penalty        points                                                      cap
=============  ==========================================================  ====
porosity       2.5 per percentage point the porosity is further from the    25
               target than the reference's is
missing        25 x (blocks still to place) / (blocks required)             25
tolerance      5 per block sticking out of the tolerance zone               20
collisions     5 per pair of blocks pushed into each other                  10
stability      5 per block the settle moves or turns too far                10
interlock      2 per poorly interlocked block beyond the reference's count  10
=============  ==========================================================  ====

Porosity and interlock are measured against the reference, because the
reference shows what the scene allows: a trainee loses points only where they
do worse than it. The other four are faults against the rules (Table II of
the paper, physics) and count in full. A valid reference (complete, inside
the tolerance zone, free of collisions, stable) therefore scores 100 against
itself, and no layout scores higher.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from geometry.blocks import Block
from geometry.collision import Collision, collisions
from geometry.constants import tol
from geometry.errors import InputError
from geometry.porosity import exact_filled_volume, porosity
from geometry.pose import Pose
from geometry.scene import Scene
from geometry.tolerance import TrapezoidalPrism, out_of_tolerance, tolerance_prism
from settle import SettleResult, settle

from .interlock import InterlockReport, InterlockRule, interlock

Placed = Sequence[tuple[int, Block, Pose]]

#: Zones of the porosity map: slices along the crest (y) and layers (z).
DEFAULT_SLICES = 4
DEFAULT_LAYERS = 2
#: Seed of the settle a score runs: the same save always gets the same score.
SETTLE_SEED = 0


@dataclass(frozen=True)
class ScoreWeights:
    """Points per fault and the cap of each penalty (docs/scoring.md).

    The caps add up to 100, so the score stays in [0, 100]. All points are
    points of the score out of 100.
    """

    porosity_per_percent: float = 2.5
    porosity_max: float = 25.0
    missing_max: float = 25.0
    tolerance_per_block: float = 5.0
    tolerance_max: float = 20.0
    collision_per_pair: float = 5.0
    collision_max: float = 10.0
    unstable_per_block: float = 5.0
    stability_max: float = 10.0
    interlock_per_block: float = 2.0
    interlock_max: float = 10.0

    def __post_init__(self) -> None:
        for name, v in self.__dict__.items():
            if not isinstance(v, (int, float)) or not np.isfinite(v) or v < 0:
                raise InputError(f"score weights: {name} must be a non-negative number, not {v!r}")
        caps = (self.porosity_max + self.missing_max + self.tolerance_max + self.collision_max
                + self.stability_max + self.interlock_max)
        if abs(caps - 100.0) > tol.points:
            raise InputError(f"score weights: the caps must add up to 100, not {caps:g}")


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


def scoring_zone(scene: Scene) -> TrapezoidalPrism:
    """The tolerance zone a score judges blocks against.

    It is the scene's tolerance prism (Table II), reaching ``tol.contact_depth``
    (5 mm) deeper, its slopes carried down. A block resting on the foundation
    in a physics engine sinks into it by a fraction of a millimetre (MuJoCo)
    to a few (PhysX); that is contact, not a block out of place, and must not
    count as sticking out through the bottom of the zone. Every other face is
    the scene's own.
    """
    lowest = min(scene.tolerance.z_bottom, scene.foundation.lowest)
    return tolerance_prism(scene.design, scene.allowance, lowest - tol.contact_depth)


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


@dataclass
class Reference:
    """What a score needs from the reference layout, computed once per batch.

    Attributes
    ----------
    scene : Scene
    placed : list of (id, Block, Pose)
    porosity_percent : float
        Exact porosity of the design prism.
    flagged : list of int
        Its poorly interlocked blocks.
    zones : list of Zone
    out_of_tolerance, collisions : int
        Its own faults (zero for a valid reference).
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

    @classmethod
    def of(cls, scene: Scene, placed: Placed, slices: int = DEFAULT_SLICES, layers: int = DEFAULT_LAYERS,
           rule: InterlockRule | None = None) -> Reference:
        placed = list(placed)
        return cls(
            scene=scene,
            placed=placed,
            porosity_percent=porosity(scene, placed, "exact").percent,
            flagged=interlock(placed, scene.foundation, rule).flagged,
            zones=porosity_map(scene, placed, slices, layers),
            out_of_tolerance=len(out_of_tolerance(placed, scoring_zone(scene))),
            collisions=len(collisions(placed)),
            slices=slices,
            layers=layers,
        )


@dataclass(frozen=True)
class Penalty:
    """Points taken off the score for one kind of fault.

    Attributes
    ----------
    name : str
        ``porosity``, ``missing``, ``tolerance``, ``collisions``, ``stability`` or ``interlock``.
    amount : float
        What was counted: percentage points beyond the reference's porosity
        gap, missing blocks, blocks or pairs.
    points : float
        Points taken off (at most ``cap``).
    cap : float
    rule : str
        The rule in words, for the report.
    """

    name: str
    amount: float
    points: float
    cap: float
    rule: str

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "amount": self.amount, "points": self.points, "cap": self.cap,
                "rule": self.rule}


def penalties(
    *,
    porosity_percent: float,
    reference_porosity_percent: float,
    target_porosity_percent: float,
    blocks: int,
    required_blocks: int,
    out_of_tolerance: int,
    collisions: int,
    unstable: int,
    flagged: int,
    reference_flagged: int,
    weights: ScoreWeights | None = None,
) -> list[Penalty]:
    """The six penalties of the score (module docstring, docs/scoring.md)."""
    w = weights if weights is not None else ScoreWeights()
    excess = max(0.0, abs(porosity_percent - target_porosity_percent)
                 - abs(reference_porosity_percent - target_porosity_percent))
    missing = max(0, required_blocks - blocks)
    extra_flagged = max(0, flagged - reference_flagged)
    return [
        Penalty("porosity", excess, min(w.porosity_max, w.porosity_per_percent * excess), w.porosity_max,
                f"{w.porosity_per_percent:g} per percentage point further from the "
                f"{target_porosity_percent:g}% target than the reference"),
        Penalty("missing", float(missing),
                w.missing_max * missing / required_blocks if required_blocks else 0.0, w.missing_max,
                f"{w.missing_max:g} x blocks still to place / blocks required"),
        Penalty("tolerance", float(out_of_tolerance),
                min(w.tolerance_max, w.tolerance_per_block * out_of_tolerance), w.tolerance_max,
                f"{w.tolerance_per_block:g} per block out of the tolerance zone"),
        Penalty("collisions", float(collisions), min(w.collision_max, w.collision_per_pair * collisions),
                w.collision_max, f"{w.collision_per_pair:g} per pair of blocks pushed into each other"),
        Penalty("stability", float(unstable), min(w.stability_max, w.unstable_per_block * unstable),
                w.stability_max, f"{w.unstable_per_block:g} per block that moves or turns in the settle"),
        Penalty("interlock", float(extra_flagged),
                min(w.interlock_max, w.interlock_per_block * extra_flagged), w.interlock_max,
                f"{w.interlock_per_block:g} per poorly interlocked block beyond the reference's"),
    ]


@dataclass
class ScoreReport:
    """A trainee's layout scored against the reference.

    Attributes
    ----------
    score : float
        Out of 100, rounded to 0.1.
    penalties : list of Penalty
    porosity_percent, reference_porosity_percent, target_porosity_percent : float
    blocks, required_blocks : int
    out_of_tolerance : list of (id, outside volume m^3)
    collisions : list of Collision
    settle : SettleResult
    interlock : InterlockReport
    zones, reference_zones : list of Zone
    reference_flagged : list of int
    seconds : float
        Compute time, seconds.
    """

    score: float
    penalties: list[Penalty]
    porosity_percent: float
    reference_porosity_percent: float
    target_porosity_percent: float
    blocks: int
    required_blocks: int
    out_of_tolerance: list[tuple[int, float]]
    collisions: list[Collision]
    settle: SettleResult
    interlock: InterlockReport
    zones: list[Zone]
    reference_zones: list[Zone]
    reference_flagged: list[int]
    scene: str
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

    def to_dict(self) -> dict[str, Any]:
        """The keys of ``shoha score --json`` (docs/contract.md, "CLI"), and more."""
        s = self.settle
        return {
            "score": self.score,
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
            "zones": {
                "save": [z.to_dict() for z in self.zones],
                "reference": [z.to_dict() for z in self.reference_zones],
            },
            "penalties": [p.to_dict() for p in self.penalties],
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
        """The score and its penalties in plain words."""
        lines = [f"score {self.score:.1f} / 100",
                 f"porosity {self.porosity_percent:.2f}% (target {self.target_porosity_percent:g}%, "
                 f"reference {self.reference_porosity_percent:.2f}%)",
                 f"blocks {self.blocks} of {self.required_blocks} required "
                 f"({self.remaining_blocks} remaining)",
                 f"out of tolerance: {len(self.out_of_tolerance)}; collisions: {len(self.collisions)}; "
                 f"{'stable' if self.stable else 'UNSTABLE: blocks ' + str(self.unstable_ids)}; "
                 f"poorly interlocked: {len(self.interlock.flagged)} "
                 f"(reference {len(self.reference_flagged)})"]
        for p in self.penalties:
            if p.points > 0:
                lines.append(f"  -{p.points:.1f} {p.name}: {p.rule}")
        return "\n".join(lines)


def check_same_scene(scene: Scene, reference: Scene, where: str) -> None:
    """Raise InputError if a save and the reference are not for the same breakwater."""
    if scene.design != reference.design or scene.block_type != reference.block_type:
        raise InputError(f"{where}: scene {scene.name!r} is not the reference's scene {reference.name!r}")


def score(
    scene: Scene,
    placed: Placed,
    reference: Reference,
    seconds: float = 2.0,
    seed: int = SETTLE_SEED,
    weights: ScoreWeights | None = None,
    rule: InterlockRule | None = None,
) -> ScoreReport:
    """Score a layout against a reference.

    Parameters
    ----------
    scene : Scene
        The scene the layout is for; its design must be the reference's.
    placed : sequence of (id, Block, Pose)
        The trainee's blocks, world frame.
    reference : Reference
        ``Reference.of(scene, reference_layout.placed())``.
    seconds : float
        Simulated seconds of the stability settle.
    seed : int
        Seed of the settle; fixed so that a save always gets the same score.
    weights : ScoreWeights, optional
    rule : InterlockRule, optional

    Returns
    -------
    ScoreReport
    """
    start = time.perf_counter()
    check_same_scene(scene, reference.scene, "score")
    placed = list(placed)
    phi = porosity(scene, placed, "exact").percent
    outside = out_of_tolerance(placed, scoring_zone(scene))
    pairs = collisions(placed)
    settled = settle(scene, placed, seconds=seconds, seed=seed)
    held = interlock(placed, scene.foundation, rule)
    zones = porosity_map(scene, placed, reference.slices, reference.layers)
    pens = penalties(
        porosity_percent=phi,
        reference_porosity_percent=reference.porosity_percent,
        target_porosity_percent=scene.target_porosity,
        blocks=len(placed),
        required_blocks=scene.required_blocks,
        out_of_tolerance=len(outside),
        collisions=len(pairs),
        unstable=len(settled.unstable_ids),
        flagged=len(held.flagged),
        reference_flagged=len(reference.flagged),
        weights=weights,
    )
    value = max(0.0, 100.0 - sum(p.points for p in pens))
    return ScoreReport(
        score=round(value, 1),
        penalties=pens,
        porosity_percent=phi,
        reference_porosity_percent=reference.porosity_percent,
        target_porosity_percent=scene.target_porosity,
        blocks=len(placed),
        required_blocks=scene.required_blocks,
        out_of_tolerance=outside,
        collisions=pairs,
        settle=settled,
        interlock=held,
        zones=zones,
        reference_zones=reference.zones,
        reference_flagged=reference.flagged,
        scene=scene.name,
        seconds=time.perf_counter() - start,
    )
