"""Collisions (python-fcl on convex pieces, our broadphase)."""

from __future__ import annotations

import numpy as np
import pytest

from geometry.collision import CollisionWorld, collisions
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


def test_broadphase_finds_the_same_pairs_as_all_pairs(mini, shake):
    rng = np.random.default_rng(9)
    placed = [(i, shake, Pose(rng.uniform([-5, 0, 0], [5, 12, 3]),
                                axis_angle_quat(rng.normal(size=3), rng.uniform(0, 3))))
              for i in range(60)]
    fast = {(c.a, c.b) for c in collisions(placed)}
    world = CollisionWorld(cell=100.0)  # one cell: every pair goes to the narrow phase
    for k, b, p in placed:
        world.add(k, b, p)
    assert fast == {(c.a, c.b) for c in world.pairs()}
    assert len(fast) > 5
