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
   nothing.

The hint is the block where it comes to rest, so laid as given it touches
what carries it, collides with nothing and is inside the tolerance zone.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from geometry.blocks import Block
from geometry.constants import tol
from geometry.pose import Pose
from geometry.scene import Scene
from geometry.tolerance import outside_volume

from ..search.drop import DropWorld, Shape
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


def first_fitting(scene: Scene, live: LiveLayout, plan: Sequence[PlanBlock]) -> Hint | None:
    """The first block of ``plan``, in its order, that fits (module docstring); None if none does."""
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
        if outside_volume(b.block, pose, zone) > tol.volume or live.collides(b.block, pose):
            continue
        return Hint(b.id, b.type, pose)
    return None
