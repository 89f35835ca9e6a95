"""Blocks out of the tolerance zone, measured exactly."""

from __future__ import annotations

import pytest

from geometry.pose import Pose
from geometry.tolerance import out_of_tolerance, outside_volume


def test_inside_block_is_not_reported(mini, inside_block):
    assert out_of_tolerance([inside_block], mini.tolerance) == []


def test_protruding_block_is_reported_with_its_volume(mini, protruding_block):
    ((key, v),) = out_of_tolerance([protruding_block], mini.tolerance)
    assert key == protruding_block[0] and 0 < v < protruding_block[1].volume


@pytest.mark.parametrize("lift, expected", [(0.0, 0.0), (0.25, 0.25), (0.5, 0.5), (2.0, 1.0)])
def test_box_above_the_crest_has_analytic_outside_volume(mini, cube, lift, expected):
    # A unit cube whose top sits `lift` above the tolerance crest, on the centre line.
    z_top = mini.tolerance.z_top
    pose = Pose([0.0, 6.0, z_top + lift - 0.5], [1, 0, 0, 0])
    assert outside_volume(cube, pose, mini.tolerance) == pytest.approx(expected, abs=1e-9)


def test_box_past_the_end_is_out(mini, cube):
    pose = Pose([0.0, mini.tolerance.y_end + 0.2, 0.5], [1, 0, 0, 0])
    assert outside_volume(cube, pose, mini.tolerance) == pytest.approx(0.7, abs=1e-9)
