"""Wall-backed sections: ``[design] wall = true`` puts a vertical wall face on the landward side."""

from __future__ import annotations

import numpy as np
import pytest

from geometry.errors import InputError
from geometry.scene import parse_scene
from geometry.tolerance import out_of_tolerance
from tests.conftest import standing

WALL_TOML = """
name = "wall"
block = "shake-4t"
[design]
crest_width_m = 3.0
height_m = 3.5
slope_rise_run = [3.0, 4.0]
length_m = 15.0
wall = {wall}
"""


@pytest.fixture(scope="module")
def walled():
    return parse_scene(WALL_TOML.format(wall="true"), "wall.toml", None)


@pytest.fixture(scope="module")
def open_():
    return parse_scene(WALL_TOML.format(wall="false"), "open.toml", None)


def test_the_design_stops_at_the_wall(walled, open_):
    d = walled.design
    # The seaward half of the open section, plus the crest's landward half, which the wall keeps.
    half = (open_.design.bottom_half_width + open_.design.top_half_width) / 2 * 3.5
    np.testing.assert_allclose(d.section_area, half + 1.5 * 3.5, rtol=1e-12)
    np.testing.assert_allclose(walled.design_volume, d.section_area * 15.0, rtol=1e-12)
    assert d.wall_x == -1.5 and d.left(0.0) == -1.5 and d.left(3.5) == -1.5
    assert walled.required_blocks < open_.required_blocks


def test_the_zone_stops_at_the_wall_and_widens_seaward(walled, open_):
    t = walled.tolerance
    assert t.wall_x == -1.5
    assert t.polytope.vertices[:, 0].min() == pytest.approx(-1.5)
    # Behind a wall the crest takes its whole H/3 of widening on the seaward side.
    h3 = walled.block.height / 3
    assert t.top_half_width - walled.design.top_half_width == pytest.approx(h3)
    assert open_.tolerance.top_half_width - open_.design.top_half_width == pytest.approx(h3 / 2)


def test_a_block_through_the_wall_is_out_of_tolerance(walled, shake):
    inside = standing(shake, 0.5, 7.0)
    through = standing(shake, -1.7, 7.0)  # its centroid 0.2 m behind the wall face
    out = out_of_tolerance([(0, shake, inside), (1, shake, through)], walled.tolerance)
    assert [k for k, _ in out] == [1]


def test_wall_must_be_a_boolean():
    with pytest.raises(InputError, match="wall must be true or false"):
        parse_scene(WALL_TOML.format(wall='"yes"'), "bad.toml", None)
