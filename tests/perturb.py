"""Trainee-like faults put into a layout on purpose.

Trainers use these to make exercises, and the tests and benchmarks use them
to check that ``shoha score`` sees exactly the faults put in
(tests/test_score.py) and to make many saves to score (benchmarks/batch_*.py).
Each function returns a new layout (same scene, same ids, same extra keys)
and the ids it touched; the input is never changed.

Which block gets each fault is decided by a written rule on the geometry, so
that the same reference always gives the same exercise. Only
:func:`stand_on_leg_tip` runs a physics settle, of its one block, to be sure
the block it sets on a tip falls. Whether a fault is *only* that fault (a
block lifted out of tolerance that still stands, say) is for the scorer to
find, and for the tests to check.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Iterator
from typing import Any

import numpy as np

from geometry.blocks import Block, get_block
from geometry.errors import InputError
from geometry.layout import Layout, Placement
from geometry.pose import Pose, quat_multiply
from geometry.scene import Scene
from geometry.tolerance import outside_volume
from optimizer.score.interlock import BlockInterlock, interlock
from optimizer.search.drop import DropWorld, Shape
from settle import settle
from settle.base import Thresholds

#: Sideways step of :func:`lift_out_of_tolerance`, metres.
LIFT_STEP = 0.1
#: How far :func:`lift_out_of_tolerance` moves a block at most, metres.
LIFT_MAX = 3.0
#: Yaw angles tried by :func:`stand_on_leg_tip`, degrees.
TIP_YAWS_DEG = tuple(range(0, 360, 30))
#: How far off plumb :func:`stand_on_leg_tip` sets the leg, degrees: a hand on a crane does not
#: hang a block exactly plumb, and a leg exactly plumb under the centroid balances in a settle.
TIP_TILT_DEG = 4.0
#: How many times a stability threshold :func:`stand_on_leg_tip`'s block must move past, held
#: alone: twice, so that a settle of every block sees the same fall.
FALL_MARGIN = 2.0


def _replace(layout: Layout, poses: dict[int, Pose]) -> Layout:
    blocks = [Placement(p.id, p.type, poses.get(p.id, p.pose), p.time_s) for p in layout.blocks]
    return Layout(layout.scene, blocks, dict(layout.extra), layout.base_dir)


def _carriers(scene: Scene, layout: Layout) -> tuple[dict[int, BlockInterlock], set[int]]:
    """Interlock of each block, and the ids of blocks that something rests on.

    Block b rests on block a when they touch, b does not touch the
    foundation, and b's centroid is higher than a's.
    """
    placed = layout.placed()
    report = interlock(placed, scene.foundation).by_id()
    z = {k: p.position[2] for k, _, p in placed}
    carrying = set()
    for k, info in report.items():
        if info.foundation:
            continue
        carrying.update(a for a in info.contacts if z[a] < z[k])
    return report, carrying


def _drop_world(scene: Scene, layout: Layout, without: set[int]) -> DropWorld:
    return DropWorld.of(scene.foundation, [b for b in layout.placed() if b[0] not in without])


def lift_out_of_tolerance(scene: Scene, layout: Layout, skip: Collection[int] = ()) -> tuple[Layout, int]:
    """One block lifted by the crane and set down further out, through the tolerance slope.

    Rule: of the blocks on the foundation that carry no other block, take the
    one farthest from the crest line (largest ``|x|``, then the lowest id).
    Move it straight away from the crest line (along ``sign(x)`` x) in steps
    of ``LIFT_STEP`` until, lowered there by the crane, it stands on the
    foundation alone and part of it lies outside the tolerance zone. Its
    orientation is kept, so it stands as it stood. Blocks in ``skip`` are
    not taken.

    Returns
    -------
    (Layout, id of the moved block)
    """
    report, carrying = _carriers(scene, layout)
    poses = {p.id: p for p in layout.blocks}
    candidates = sorted((k for k, info in report.items()
                         if info.foundation and k not in carrying and k not in skip),
                        key=lambda k: (-abs(poses[k].pose.position[0]), k))
    for key in candidates:
        p = poses[key]
        block = get_block(p.type, layout.base_dir)
        world = _drop_world(scene, layout, {key})
        shape = Shape.of(block, p.pose.quaternion)
        sign = 1.0 if p.pose.position[0] >= 0 else -1.0
        for step in range(1, int(round(LIFT_MAX / LIFT_STEP)) + 1):
            x = p.pose.position[0] + sign * step * LIFT_STEP
            z, support, on_ground = world.drop(shape, x, p.pose.position[1])
            pose = world.pose(shape, x, p.pose.position[1], z)
            if on_ground and not support and outside_volume(block, pose, scene.tolerance) > 0:
                return _replace(layout, {key: pose}), key
    raise InputError("lift_out_of_tolerance: no block on the foundation is free to move")


def push_together(scene: Scene, layout: Layout, push: float = 0.02, skip: Collection[int] = ()
                  ) -> tuple[Layout, tuple[int, int]]:
    """Two touching blocks pushed into each other.

    Rule: of the pairs of touching blocks that both stand on the foundation
    and carry no other block, take the first by ids. Each moves ``push``
    metres horizontally towards the other's centroid. Pairs with a block in
    ``skip`` are not taken.

    Returns
    -------
    (Layout, (a, b)) with a < b.
    """
    report, carrying = _carriers(scene, layout)
    poses = {p.id: p.pose for p in layout.blocks}
    for a in sorted(report):
        if not report[a].foundation or a in carrying or a in skip:
            continue
        for b in report[a].contacts:
            if b <= a or not report[b].foundation or b in carrying or b in skip:
                continue
            u = poses[b].position - poses[a].position
            u[2] = 0.0
            u /= np.linalg.norm(u)
            moved = {a: Pose(poses[a].position + push * u, poses[a].quaternion),
                     b: Pose(poses[b].position - push * u, poses[b].quaternion)}
            return _replace(layout, moved), (a, b)
    raise InputError("push_together: no two touching blocks stand free on the foundation")


def _falls(scene: Scene, layout: Layout, key: int, block: Block) -> bool:
    """Block ``key``, let go with every other block held, moves at least ``FALL_MARGIN`` times past
    a stability threshold: a fall, not a wobble that a full settle may judge either way."""
    limits = Thresholds()
    moved = next(b for b in settle(scene, layout.placed(), seed=0, movable={key}).blocks if b.id == key)
    return (moved.displacement_m >= FALL_MARGIN * limits.displacement_limit(block)
            or moved.rotation_deg >= FALL_MARGIN * limits.rotation_deg)


def stand_on_leg_tip(scene: Scene, layout: Layout, skip: Collection[int] = ()) -> tuple[Layout, int]:
    """One block turned upside down and set on the tip of its single leg, ``TIP_TILT_DEG`` off plumb.

    For tetrapod-like blocks (one leg along local +z) upside down means that
    leg points down. Rule: of the blocks that touch no foundation and carry
    no other block, highest centroid first (then lowest id), and of the yaws
    ``TIP_YAWS_DEG`` in order, take the first that, lowered by the crane at
    the block's own (x, y), stays inside the tolerance zone, first touches
    exactly one block and not the foundation, and, let go there with every
    other block held, falls (moves ``FALL_MARGIN`` times past a stability
    threshold: a block wedged on its tip between neighbours is no fault). Blocks in ``skip`` are not
    taken.

    Returns
    -------
    (Layout, id of the turned block)
    """
    report, carrying = _carriers(scene, layout)
    poses = {p.id: p.pose for p in layout.blocks}
    types = {p.id: p.type for p in layout.blocks}
    candidates = sorted((k for k, info in report.items()
                         if not info.foundation and k not in carrying and k not in skip),
                        key=lambda k: (-poses[k].position[2], k))
    # Half a turn about the block's x axis, and a few degrees more.
    half = np.radians(180.0 + TIP_TILT_DEG) / 2
    flip = np.array([np.cos(half), np.sin(half), 0.0, 0.0])
    for key in candidates:
        block = get_block(types[key], layout.base_dir)
        world = _drop_world(scene, layout, {key})
        x, y = poses[key].position[:2]
        for yaw_deg in TIP_YAWS_DEG:
            yaw = np.radians(yaw_deg)
            q = quat_multiply(np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]), flip)
            shape = Shape.of(block, q)
            z, support, on_ground = world.drop(shape, x, y)
            pose = world.pose(shape, x, y, z)
            if len(support) == 1 and not on_ground and outside_volume(block, pose, scene.tolerance) == 0:
                tipped = _replace(layout, {key: pose})
                if _falls(scene, tipped, key, block):
                    return tipped, key
    raise InputError("stand_on_leg_tip: no block can be stood on a leg tip inside the tolerance zone")


def three_faults(scene: Scene, layout: Layout) -> Layout:
    """One block lifted out of tolerance, one stood on a leg tip, and two pushed together.

    The faulty save that the report, the service's tests and the scoring
    benchmarks share: one fault of each kind, in that order.
    """
    layout, _ = lift_out_of_tolerance(scene, layout)
    layout, _ = stand_on_leg_tip(scene, layout)
    layout, _ = push_together(scene, layout)
    return layout


def repeated(fault: Callable[..., tuple[Layout, Any]], scene: Scene, layout: Layout, count: int
             ) -> tuple[Layout, list[Any]]:
    """``fault`` put in up to ``count`` times, each time into blocks no earlier time touched.

    ``fault`` is :func:`lift_out_of_tolerance`, :func:`push_together` or
    :func:`stand_on_leg_tip`. It stops early when its rule finds no block
    left (the caller sees fewer than ``count`` in the list it returns).

    Returns
    -------
    (Layout, list of what each call returned: an id, or a pair of ids)
    """
    touched: list[Any] = []
    skip: set[int] = set()
    for _ in range(count):
        try:
            layout, what = fault(scene, layout, skip=skip)
        except InputError:
            break
        touched.append(what)
        skip.update(what if isinstance(what, tuple) else (what,))
    return layout, touched


def remove_last(layout: Layout, count: int) -> tuple[Layout, list[int]]:
    """The layout without its last ``count`` blocks in installation order (a trainee who stopped early)."""
    if not 0 <= count <= len(layout.blocks):
        raise InputError(f"remove_last: cannot remove {count} of {len(layout.blocks)} blocks")
    keep = layout.blocks[: len(layout.blocks) - count]
    removed = [p.id for p in layout.blocks[len(keep):]]
    return Layout(layout.scene, list(keep), dict(layout.extra), layout.base_dir), removed


def jitter(layout: Layout, rng: np.random.Generator, count: int, sigma_m: float = 0.03,
           sigma_deg: float = 2.0) -> tuple[Layout, list[int]]:
    """``count`` random blocks nudged: normal noise of ``sigma_m`` metres and ``sigma_deg`` degrees.

    The rotation is about a random axis (a hand on the crane joystick).
    """
    ids = sorted(int(k) for k in rng.choice([p.id for p in layout.blocks], size=count, replace=False))
    poses = {p.id: p.pose for p in layout.blocks}
    moved = {}
    for k in ids:
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = np.radians(rng.normal(scale=sigma_deg))
        dq = np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis])
        q = quat_multiply(dq, poses[k].quaternion)
        moved[k] = Pose(poses[k].position + rng.normal(scale=sigma_m, size=3), q / np.linalg.norm(q))
    return _replace(layout, moved), ids


def trainee_saves(scene: Scene, layout: Layout, count: int, seed: int = 0) -> Iterator[tuple[str, Layout]]:
    """``count`` varied saves made from a reference, the same for the same seed.

    Save ``i`` draws from ``numpy.random.default_rng([seed, i])``: a few blocks
    nudged, sometimes the last few missing, and every tenth save carries one
    of the named faults above.

    Yields
    ------
    (name, Layout)
    """
    faults = (lift_out_of_tolerance, push_together, stand_on_leg_tip)
    for i in range(count):
        rng = np.random.default_rng([seed, i])
        save = layout
        parts = []
        if i % 10 == 9:
            fault = faults[(i // 10) % len(faults)]
            save, _ = fault(scene, save)
            parts.append(fault.__name__)
        if rng.random() < 0.3:
            n = int(rng.integers(1, 11))
            save, _ = remove_last(save, n)
            parts.append(f"missing{n}")
        n = int(rng.integers(0, 6))
        if n:
            save, _ = jitter(save, rng, n)
            parts.append(f"jitter{n}")
        yield f"save-{i:04d}" + ("-" + "-".join(parts) if parts else ""), save
