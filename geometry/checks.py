"""The checks of a layout: counts, tolerance, collisions and porosity.

These are the simulator's UI counters (Table III of the reference paper:
block requirement, remaining blocks, out-of-tolerance blocks, porosity),
computed exactly. ``shoha check``, the scorer and the optimizer all use this.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from .blocks import Block
from .collision import Collision, collisions
from .coverage import CoverageReport, coverage
from .errors import InputError
from .porosity import porosity
from .pose import Pose
from .scene import Scene
from .tolerance import out_of_tolerance


@dataclass
class CheckReport:
    """What ``shoha check`` reports (docs/contract.md keys via :meth:`to_dict`)."""

    blocks: int
    required_blocks: int
    out_of_tolerance: list[tuple[int, float]] = field(default_factory=list)
    collisions: list[Collision] = field(default_factory=list)
    porosity_percent: float = 100.0
    coverage: CoverageReport | None = None
    seconds: float = 0.0

    @property
    def remaining_blocks(self) -> int:
        return max(0, self.required_blocks - self.blocks)

    def to_dict(self) -> dict[str, Any]:
        return {
            "blocks": self.blocks,
            "required_blocks": self.required_blocks,
            "remaining_blocks": self.remaining_blocks,
            "out_of_tolerance": [{"id": k, "outside_volume_m3": v} for k, v in self.out_of_tolerance],
            "collisions": [{"a": c.a, "b": c.b, "depth_m": c.depth} for c in self.collisions],
            "porosity_percent": self.porosity_percent,
            **({"coverage": self.coverage.to_dict()} if self.coverage is not None else {}),
            "seconds": self.seconds,
        }

    def summary(self) -> str:
        lines = [
            f"blocks {self.blocks} of {self.required_blocks} required ({self.remaining_blocks} remaining)",
            f"porosity {self.porosity_percent:.2f}% (exact)",
            f"out of tolerance: {len(self.out_of_tolerance)}"
            + "".join(f"\n  block {k}: {v:.4f} m3 outside" for k, v in self.out_of_tolerance),
            f"collisions: {len(self.collisions)}"
            + "".join(f"\n  blocks {c.a} and {c.b}: {c.depth * 1000:.1f} mm deep" for c in self.collisions),
        ]
        if self.coverage is not None:
            c = self.coverage
            worst = ("" if c.to_dict()["max_bare_m"] is None else
                     f", farthest {c.max_bare_m:.2f} m from a block at "
                     f"({', '.join(f'{v:.2f}' for v in c.worst_point)})")
            lines.append(f"bare: {c.bare_share_percent:.1f}% of the slopes and crest more than "
                         f"{c.bare_distance_m:.2f} m (H/2) from every block{worst}")
        return "\n".join(lines)


def check_layout(scene: Scene, placed: Sequence[tuple[int, Block, Pose]],
                 with_coverage: bool = True) -> CheckReport:
    """Run every check on a layout; ``with_coverage=False`` leaves out the coverage (tenths of a second)."""
    start = time.perf_counter()
    report = CheckReport(
        blocks=len(placed),
        required_blocks=scene.required_blocks,
        out_of_tolerance=out_of_tolerance(list(placed), scene.tolerance),
        collisions=collisions(placed),
        porosity_percent=porosity(scene, placed, "exact").percent,
        coverage=coverage(scene, placed) if with_coverage else None,
    )
    report.seconds = time.perf_counter() - start
    return report


def most_within_reach(block: Block) -> int:
    """The most blocks of ``block``'s shape whose bounding spheres can reach a given one's with no
    two overlapping: each lies within three bounding radii of its centroid, so at most that
    sphere's volume over the block's (84 Shake Blocks)."""
    return int(4.0 / 3.0 * math.pi * (3.0 * block.bounding_radius) ** 3 / block.volume)


def crowding(block: Block, key: int, near: int) -> str | None:
    """What is wrong where block ``key`` has ``near`` blocks within reach, more than
    :func:`most_within_reach` allows; None where it has not."""
    most = most_within_reach(block)
    if near <= most:
        return None
    return (f"block {key} has {near} blocks within reach, more than the {most} that could lie there "
            "without overlapping; blocks one inside another by the dozen are not a layout")


def overlapping(block: Block, key: int, overlap_m3: float) -> str | None:
    """What is wrong where block ``key`` overlaps the blocks it touches by ``overlap_m3`` in sum
    (each pair's intersection), more than its own volume; None where it does not.

    Blocks that do not overlap one another can share at most the whole of a
    block between them, so a sum beyond its volume means they overlap one
    another inside it too: blocks heaped one inside another, not a layout. A
    valid layout's sum is a hair (contacts), and a laid block sunk a little into
    its neighbours well under its volume. The live service measures the union
    of those intersections for every block laid (:mod:`optimizer.serve.live`),
    and for 45 copies of a block a centimetre apart that took 0.8 s a block,
    with every session held meanwhile (stop 76's probe).
    """
    if overlap_m3 <= block.volume * (1.0 + 1e-9):
        return None
    return (f"block {key} overlaps the blocks it touches by {overlap_m3:.3g} m3 in sum, more than its own "
            f"{block.volume:.3g} m3: they overlap one another inside it; blocks heaped one inside another "
            "are not a layout")


def check_not_crowded_across(groups: Sequence[tuple[Block, np.ndarray, Sequence[int]]], where: str) -> None:
    """:func:`check_not_crowded` across blocks of different shapes, each group one shape
    (``(block, positions, ids)``), each group already checked on its own.

    The blocks no larger than a block (bounding radius) whose centroids lie
    within two of its bounding radii lie wholly within three, so without
    overlapping their volumes sum to at most that sphere's: for one shape,
    the count of :func:`most_within_reach`. Raise InputError where they sum to
    more (1500 tetrapods of 1500 sizes in one place passed every check of a single
    shape and held ``shoha check`` for minutes).
    """
    groups = sorted(groups, key=lambda g: g[0].bounding_radius)
    trees = [cKDTree(np.asarray(positions).reshape(-1, 3)) for _, positions, _ in groups]
    for t, (block, positions, ids) in enumerate(groups):
        positions = np.asarray(positions).reshape(-1, 3)
        reach = 2.0 * block.bounding_radius
        # Counts, not lists: each group passed its own check, so none is heaped in one place.
        filled = sum(smaller.volume * trees[u].query_ball_point(positions, reach, return_length=True)
                     for u, (smaller, _, _) in enumerate(groups[:t + 1])) - block.volume
        room = 4.0 / 3.0 * math.pi * (3.0 * block.bounding_radius) ** 3
        worst = int(np.argmax(filled))
        if filled[worst] > room * (1.0 + 1e-9):
            raise InputError(f"{where}: block {ids[worst]} has {filled[worst]:.3g} m3 of blocks no larger "
                             f"than it within reach, more than the {room:.3g} m3 that could lie there "
                             "without overlapping; blocks one inside another by the dozen are not a layout")


def check_not_crowded(block: Block, positions: np.ndarray, ids: Sequence[int], where: str) -> None:
    """Raise InputError if more blocks reach one than :func:`most_within_reach` allows.

    Such a layout has blocks one inside another by the dozen (2000 copies of one pose, or
    1000 blocks in a 12 m cube), which no crane lays; its pairwise checks grow with the
    square of the count (100 copies of one pose took 25 s in ``shoha serve``).
    """
    most = most_within_reach(block)
    if len(positions) <= most:
        return
    reach = 2.0 * block.bounding_radius
    # First by cells whose diagonal is the reach: blocks sharing a cell reach each other, so
    # a cell of more is crowded at once (100 000 copies of one pose would have the tree count
    # 10^10 neighbours), and otherwise no block has more than a few cells' worth in reach.
    _, cell, per_cell = np.unique(np.floor(positions / (reach / math.sqrt(3.0))), axis=0,
                                  return_inverse=True, return_counts=True)
    if per_cell.max() - 1 > most:
        first = int(np.argmax(cell.ravel() == int(np.argmax(per_cell))))
        raise InputError(f"{where}: {crowding(block, ids[first], int(per_cell.max()) - 1)}")
    counts = cKDTree(positions).query_ball_point(positions, reach, return_length=True)
    worst = int(np.argmax(counts))
    if (wrong := crowding(block, ids[worst], int(counts[worst]) - 1)) is not None:
        raise InputError(f"{where}: {wrong}")
