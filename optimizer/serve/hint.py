"""The next block to lay: the first block of a plan whose place is still free and reachable.

A plan is a layout in crane order: the scene's reference, or a re-plan around
what the trainee has laid (:mod:`optimizer.serve.workers`). A plan block
fits when

1. it does not collide with a laid block where the plan puts it (else its
   place is taken);
2. lowered by the crane at its plan position and orientation, along -z from
   above (``optimizer.search.drop``, the optimizer's own exact drop), it
   comes to rest within :data:`HEIGHT_SLACK` of the block's height H of its
   plan height: lower means what should carry it is missing, higher means
   something is in the way or it would rest on a block out of place;
3. where it comes to rest it is inside the tolerance zone and collides with
   nothing;
4. let go there, with the laid blocks held still (the optimizer's own check,
   :func:`optimizer.search.physics.let_go`), it stays, or it comes to rest
   within a place's reach of its plan position (``PLACE_FRACTION`` of H, the
   distance at which ``shoha score`` counts a block in its place), inside the
   tolerance zone and colliding with nothing.

The hint is the block where it comes to rest, so laid as given it touches
what carries it, stays there while the laid blocks stay as they are,
collides with nothing and is inside the tolerance zone.

Why the let go: a reference on rubble keeps the blocks lowered onto the bare
rubble where they first touched (``optimizer.search.physics.raised_check``);
they stand once their neighbours are laid, not alone. Laid as lowered, the
hints of the ``mini-rough`` reference of ``tests/data`` left 12 blocks that
did not stand among the first 50; let go, none (stop 77). The laid blocks
themselves may still give under the new one: on a ``tetrapod-big`` reference
3 of 38 hinted blocks did not stand, against 11 of 48 as lowered
(``benchmarks/hint_follow.py``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from geometry.blocks import Block
from geometry.constants import tol
from geometry.pose import Pose
from geometry.scene import Scene
from geometry.tolerance import TrapezoidalPrism, outside_volume

from ..score.scoring import PLACE_FRACTION
from ..search.drop import DropWorld, Shape
from ..search.physics import LET_GO_REACH, let_go
from .live import LiveLayout

#: How far from its plan height (a fraction of the block height H) a lowered
#: block may come to rest and still be the plan's block. A simulator's blocks
#: settle centimetres from where a plan puts them (PhysX contact offsets, a
#: pile that gives); a tenth of H (17 cm for the 4-ton Shake Block) takes that
#: and is well short of a block resting on another block's leg instead.
HEIGHT_SLACK = 0.1


@dataclass(frozen=True)
class PlanBlock:
    """One block of a plan: ``(id, type, Block, Pose)``, world frame."""

    id: int
    type: str
    block: Block
    pose: Pose


@dataclass(frozen=True)
class Hint:
    """A plan block where it comes to rest, world frame.

    Attributes
    ----------
    plan_id : int
        Its id in the plan.
    type : str
    pose : Pose
    """

    plan_id: int
    type: str
    pose: Pose


def first_fitting(scene: Scene, live: LiveLayout, plan: Sequence[PlanBlock],
                  let_go_hints: bool = True) -> Hint | None:
    """The first block of ``plan``, in its order, that fits (module docstring); None if none does.

    ``let_go_hints=False`` leaves out the let go (4): the hint is the block as lowered, as before stop 77
    (``benchmarks/hint_follow.py`` measures both).
    """
    drops: DropWorld | None = None
    zone = scene.tolerance
    for b in plan:
        if live.collides(b.block, b.pose):
            continue
        if drops is None:
            drops = DropWorld.of(scene.foundation, live.placed())
        x, y, z = (float(v) for v in b.pose.position)
        shape = Shape.of(b.block, b.pose.quaternion)
        rest, _, _ = drops.drop(shape, x, y)
        if not np.isfinite(rest) or abs(rest - z) > HEIGHT_SLACK * b.block.height:
            continue
        pose = Pose([x, y, rest], b.pose.quaternion)
        if not _valid(zone, live, b.block, pose):
            continue
        pose = _at_rest(scene, live, b, pose) if let_go_hints else pose
        if pose is None:
            continue
        return Hint(b.id, b.type, pose)
    return None


def _valid(zone: TrapezoidalPrism, live: LiveLayout, block: Block, pose: Pose) -> bool:
    return outside_volume(block, pose, zone) <= tol.volume and not live.collides(block, pose)


def _at_rest(scene: Scene, live: LiveLayout, b: PlanBlock, pose: Pose) -> Pose | None:
    """Where plan block ``b`` lowered to ``pose`` comes to rest when let go among the laid blocks
    (held still), if that is still its place and valid (module docstring, 4); None otherwise."""
    key = -1  # a block id is never negative
    around = live.near(pose.position, LET_GO_REACH * b.block.bounding_radius)
    result = let_go(scene, [*around, (key, b.block, pose)], key)
    if result is None:
        return None
    if result.stable:
        return pose
    rested = result.poses[key]
    moved = float(np.linalg.norm(rested.position - b.pose.position))
    if not result.at_rest or moved > PLACE_FRACTION * b.block.height:
        return None
    return rested if _valid(scene.tolerance, live, b.block, rested) else None
