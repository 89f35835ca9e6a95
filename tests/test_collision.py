"""Collisions (python-fcl on convex pieces, our broadphase)."""

from __future__ import annotations

import itertools

import fcl
import numpy as np
import pytest

from geometry.collision import CollisionWorld, collisions, fcl_objects, overlap_groups
from geometry.constants import tol
from geometry.pose import Pose, axis_angle_quat
from geometry.samples import random_inside


def test_colliding_pair_reports_its_depth(colliding_pair):
    (c,) = collisions(colliding_pair)
    assert (c.a, c.b) == (0, 1)
    assert c.depth == pytest.approx(0.2, abs=1e-9)


@pytest.mark.parametrize("gap, expected", [(0.1, 0), (0.0, 0), (-tol.contact_depth / 2, 0), (-0.01, 1)])
def test_contact_is_not_collision(cube, gap, expected):
    pair = [(0, cube, Pose([0, 0, 0.5], [1, 0, 0, 0])), (1, cube, Pose([1.0 + gap, 0, 0.5], [1, 0, 0, 0]))]
    assert len(collisions(pair)) == expected


def test_random_inside_layout_is_collision_free(mini, shake):
    placed = random_inside(shake, mini.design, 25, seed=3)
    assert collisions(placed, threshold=-1) == []


def test_world_is_incremental(shake):
    world = CollisionWorld(cell=2 * shake.bounding_radius)
    world.add(0, shake, Pose([0, 0, 0], [1, 0, 0, 0]))
    world.add(1, shake, Pose([5, 0, 0], [1, 0, 0, 0]))
    assert world.pairs() == []
    world.move(1, Pose([0.4, 0, 0], [1, 0, 0, 0]))
    assert [(c.a, c.b) for c in world.pairs()] == [(0, 1)]
    hits = world.query(shake, Pose([0.0, 0.3, 0.0], [1, 0, 0, 0]))
    assert sorted(k for k, _ in hits) == [0, 1]
    assert world.query(shake, Pose([0.0, 0.3, 0.0], [1, 0, 0, 0]), exclude=[0, 1]) == []
    world.remove(0)
    assert world.pairs() == []


def _all_pairs(placed, threshold: float) -> dict[tuple[int, int], float]:
    """Brute force with no broadphase: FCL's penetration depth on every piece pair of every block pair."""
    objects = {k: fcl_objects(b, p) for k, b, p in placed}
    request = fcl.CollisionRequest(num_max_contacts=1, enable_contact=True)
    out = {}
    for (ka, _, _), (kb, _, _) in itertools.combinations(placed, 2):
        depths = []
        for oa in objects[ka]:
            for ob in objects[kb]:
                result = fcl.CollisionResult()
                if fcl.collide(oa, ob, request, result):
                    depths.append(max(c.penetration_depth for c in result.contacts))
        if depths and max(depths) > threshold:
            out[(min(ka, kb), max(ka, kb))] = max(depths)
    return out


@pytest.mark.parametrize("threshold", [tol.contact_depth, 0.0])
def test_broadphase_finds_the_same_pairs_and_depths_as_all_pairs(shake, cube, threshold):
    """The k-d tree, sphere and piece-box prunings drop no pair that brute force finds.

    Two block types (their radii differ, so the sphere test is not symmetric)
    in a crowded box, every block pair checked piece by piece without pruning.
    """
    rng = np.random.default_rng(9)
    placed = [(i, shake if i % 3 else cube, Pose(rng.uniform([-5, 0, 0], [5, 12, 3]),
                                                 axis_angle_quat(rng.normal(size=3), rng.uniform(0, 3))))
              for i in range(60)]
    fast = {(c.a, c.b): c.depth for c in collisions(placed, threshold)}
    slow = _all_pairs(placed, threshold)
    assert len(slow) > 5, "the layout must have collisions for the test to mean anything"
    assert fast.keys() == slow.keys()
    for pair, depth in slow.items():
        assert fast[pair] == pytest.approx(depth, rel=1e-9)


def test_overlap_groups_are_the_connected_touching_blocks(cube):
    """A chain 0-1-2 touching end to end, a pair 4-5, and a block 3 alone: two groups."""
    at = [0.0, 0.99, 1.98, 10.0, 20.0, 20.9]
    placed = [(k, cube, Pose([x, 0, 0.5], [1, 0, 0, 0])) for k, x in enumerate(at)]
    groups = sorted(sorted(placed[i][0] for i in g) for g in overlap_groups(placed))
    assert groups == [[0, 1, 2], [4, 5]]
