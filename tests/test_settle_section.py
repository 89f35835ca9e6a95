"""Section scenes: extruded blocks in 2D, and MuJoCo (3D) against pymunk (2D) on them."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from geometry.blocks import get_block
from geometry.errors import InputError
from geometry.pose import Pose, axis_angle_quat
from geometry.scene import Scene, load_scene, parse_scene
from settle import MujocoBackend, PymunkBackend, settle
from settle.pour import pour
from settle.section import foundation_profile, from_plane, outlines, to_plane
from tests.conftest import ROOT
from tests.test_settle_contract import MU, box, incline, on_ground, stack

Y = np.array([0.0, 1.0, 0.0])


@pytest.fixture(scope="module")
def section() -> Scene:
    return load_scene("mini-section")


def test_mini_section_is_a_2d_scene(section):
    assert section.kind == "section" and section.block_type == "box:1.2x1x0.6"
    assert section.length == 1.0 and section.design.section_area == pytest.approx(24.0)


def test_outline_of_a_box_is_its_rectangle():
    (outline,) = outlines(get_block("box:1.2x1x0.6"))
    np.testing.assert_allclose(np.sort(np.abs(outline), axis=0), [[0.6, 0.3]] * 4)
    # Counter-clockwise: positive signed area 1.2 x 0.6.
    x, z = outline.T
    assert 0.5 * np.sum(x * np.roll(z, -1) - np.roll(x, -1) * z) == pytest.approx(0.72)


@settings(max_examples=50, deadline=None)
@given(st.floats(-math.pi, math.pi), st.floats(-5, 5), st.floats(0, 5))
def test_plane_mapping_matches_the_3d_pose(theta, x, z):
    # The 2D position and counter-clockwise angle put every block point where
    # the 3D pose does.
    b = get_block("box:1.2x1x0.6")
    pose = Pose([x, 0.5, z], axis_angle_quat(Y, theta))
    (u, v), angle = to_plane(pose)
    c, s = math.cos(angle), math.sin(angle)
    pts = b.vertices[:, [0, 2]] @ np.array([[c, s], [-s, c]]) + [u, v]
    np.testing.assert_allclose(pts, pose.apply(b.vertices)[:, [0, 2]], atol=1e-12)
    back = from_plane((u, v), angle, 0.5)
    assert back.close_to(pose, atol=1e-12)


def test_pymunk_refuses_what_is_not_2d(mini, section, shake):
    b = box(1.2, 0.6)
    flat = [(0, b, on_ground(b, 0.0))]
    with pytest.raises(InputError, match="section scenes only"):
        settle(mini, flat, backend=PymunkBackend())
    tilted = [(0, b, Pose([0, 0.5, 1.0], axis_angle_quat([1, 0, 0], 0.1)))]
    with pytest.raises(InputError, match="block 0: .* only about the y axis"):
        settle(section, tilted)
    with pytest.raises(InputError, match="not a prism along its local y axis"):
        settle(section, [(0, shake, Pose([0, 0.5, 1.0], [1, 0, 0, 0]))])


def test_section_scene_settles_with_pymunk_by_default(section):
    r = settle(section, stack([0.0, 0.2]))
    assert r.backend == "pymunk" and r.stable


@pytest.fixture(scope="module")
def section_pile(section):
    """Twenty blocks poured into mini-section, at rest (2D)."""
    return pour(section, 20, seed=1, backend=PymunkBackend())


CASES = {
    "stable stack": (stack([0.0, 0.3, -0.25, 0.2]), None, True),
    "overhang": (stack([0.0, 0.65]), None, False),
    "staircase past the edge": (stack([0.0, 0.45, 0.45]), None, False),  # COM of the top two at 0.675 > 0.6
    "floating": (stack([0.0, 0.2], lift=1.0), None, False),
    "holds on incline": (incline(math.atan(MU) - math.radians(2), box(1.0, 0.5)), [1], True),
    "slides on incline": (incline(math.atan(MU) + math.radians(2), box(1.0, 0.5)), [1], False),
    "tips on incline": (incline(math.atan(0.4) + math.radians(2), box(0.4, 1.0)), [1], False),
    "standing on its end": ([(0, box(0.4, 1.0), on_ground(box(0.4, 1.0), 0.0))], None, True),
    "leaning on a corner": ([(0, box(1.2, 0.6), on_ground(box(1.2, 0.6), 0.0, theta=0.5))], None, False),
}


@pytest.mark.parametrize("name", list(CASES))
def test_mujoco_and_pymunk_give_the_same_verdict(section, name):
    placed, movable, expected = CASES[name]
    verdicts = []
    for backend in (MujocoBackend(), PymunkBackend()):
        r = settle(section, placed, movable=movable, backend=backend)
        verdicts.append([b.stable for b in r.blocks])
        assert r.stable is expected, (name, backend.name)
    assert verdicts[0] == verdicts[1]


def test_poured_section_pile_is_stable_in_both_engines(section, section_pile):
    assert len(section_pile) == 20
    assert max(p.position[2] for _, _, p in section_pile) > 1.5  # a pile, not a row
    for backend in (PymunkBackend(), MujocoBackend()):
        r = settle(section, section_pile, backend=backend)
        assert r.stable, backend.name


@pytest.fixture(scope="module")
def rough_section() -> Scene:
    text = (ROOT / "geometry" / "scenes" / "mini-section.toml").read_text()
    text += '\n[foundation]\nkind = "rough"\namplitude_m = 0.15\ncell_m = 0.5\nseed = 2\n'
    return parse_scene(text, source="rough-section", base_dir=None)


def test_rough_section_foundation_is_extruded_in_3d(rough_section):
    # MuJoCo's height field follows the 2D profile at every y of the slice.
    import mujoco

    xs, zs = foundation_profile(rough_section)
    assert np.ptp(zs) > 0.1  # it is rough
    model = MujocoBackend().build(rough_section, [])
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    geomid = np.zeros(1, dtype=np.int32)
    for i in range(1, len(xs) - 1, 3):
        for y in (0.05, 0.5, 0.95):
            dist = mujoco.mj_ray(model, data, np.array([xs[i], y, 5.0]), np.array([0.0, 0.0, -1.0]),
                                 None, 1, -1, geomid)
            assert 5.0 - dist == pytest.approx(zs[i], abs=1e-6)


def test_pile_on_rough_section_same_verdict_in_both_engines(rough_section):
    pile = pour(rough_section, 15, seed=2, backend=PymunkBackend())
    assert min(p.position[2] for _, _, p in pile) < 0.3  # some rest in the hollows
    for backend in (PymunkBackend(), MujocoBackend()):
        assert settle(rough_section, pile, backend=backend).stable, backend.name


@settings(max_examples=15, deadline=None)
@given(st.floats(-1.0, 1.0).filter(lambda d: abs(abs(d) - 0.6) > 0.02))
def test_two_box_stack_stands_iff_top_centre_is_over_the_lower_box(offset):
    # Property: a 1.2 m box on another stands iff its centre is within 0.6 m
    # of the lower one's centre line, in both engines.
    section = load_scene("mini-section")
    for backend in (PymunkBackend(), MujocoBackend()):
        r = settle(section, stack([0.0, offset]), backend=backend)
        assert r.stable is (abs(offset) < 0.6), backend.name
