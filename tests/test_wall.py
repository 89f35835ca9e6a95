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


def test_a_block_settled_a_hair_into_the_wall_is_set_back_inside(walled, shake):
    """``physics.within``: a block a settle left pressed into the wall face by less than the
    contact tolerance (the engine's soft contact) is moved back out of it, and is then inside
    the zone; one through it by more stays where it is, out."""
    from geometry.constants import tol
    from geometry.pose import Pose
    from optimizer.search.physics import within

    zone = walled.tolerance.polytope

    def against(depth: float) -> Pose:
        pose = standing(shake, 0.0, 7.0)
        face = pose.apply(shake.vertices)[:, 0].min()
        return Pose(pose.position - [face + 1.5 + depth, 0.0, 0.0], pose.quaternion)

    pressed = against(1.5e-4)
    assert [k for k, _ in out_of_tolerance([(0, shake, pressed)], walled.tolerance)] == [0]
    moved = within(zone, shake, pressed)
    assert out_of_tolerance([(0, shake, moved)], walled.tolerance) == []
    shift = moved.position - pressed.position
    assert shift[0] == pytest.approx(1.5e-4, abs=1e-5) and shift[1:] == pytest.approx([0.0, 0.0])
    np.testing.assert_array_equal(moved.quaternion, pressed.quaternion)
    through = against(2 * tol.contact_depth)
    assert within(zone, shake, through) is through
    inside = standing(shake, 0.0, 7.0)
    assert within(zone, shake, inside) is inside


def test_wall_must_be_a_boolean():
    with pytest.raises(InputError, match="wall must be true or false"):
        parse_scene(WALL_TOML.format(wall='"yes"'), "bad.toml", None)


def test_the_settle_holds_the_wall(walled, open_):
    """A slab leaning on the wall face stays; the same slab with no wall behind it falls."""
    from geometry.blocks import get_block
    from geometry.pose import Pose, axis_angle_quat
    from settle import settle

    slab = get_block("box:0.3x2x2")
    # Tilted 20 degrees towards the wall, its upper edge against the face at x = -1.5.
    tilt = np.radians(20.0)
    q = axis_angle_quat([0.0, 1.0, 0.0], -tilt)
    pose = Pose([0.0, 7.0, 0.0], q)
    w = pose.apply(slab.vertices)
    pose = Pose([-1.5 - w[:, 0].min() + 0.001, 7.0, -w[:, 2].min() + 0.001], q)
    held = settle(walled, [(0, slab, pose)], seconds=2.0)
    fell = settle(open_, [(0, slab, pose)], seconds=2.0)
    assert held.stable, held.summary()
    assert not fell.stable and fell.max_rotation_deg > 10.0


def test_scene_export_writes_the_foundation_and_the_wall(tmp_path):
    import json

    import trimesh

    from tests.conftest import shoha

    scene = tmp_path / "wall.toml"
    scene.write_text(WALL_TOML.format(wall="true") + '\n[foundation]\nkind = "rough"\namplitude_m = 0.1\n')
    r = shoha("scene", "export", str(scene), "--out", str(tmp_path / "out"), "--json")
    assert r.returncode == 0, r.stderr
    names = sorted(p.rsplit("/", 1)[1] for p in json.loads(r.stdout)["paths"])
    assert names == ["design.stl", "foundation.stl", "tolerance.stl", "wall.stl"]
    for name in names:
        mesh = trimesh.load(tmp_path / "out" / name)
        assert mesh.is_watertight and mesh.volume > 0, name
    wall = trimesh.load(tmp_path / "out" / "wall.stl")
    assert wall.bounds[1, 0] == pytest.approx(-1.5)  # its face is the design's landward side
    foundation = trimesh.load(tmp_path / "out" / "foundation.stl")
    assert foundation.bounds[1, 2] == pytest.approx(0.1, abs=0.02)  # the rubble's top, 0.1 m at most
    open_ = shoha("scene", "export", "mini", "--out", str(tmp_path / "mini"), "--json")
    assert sorted(p.rsplit("/", 1)[1] for p in json.loads(open_.stdout)["paths"]) == [
        "design.stl", "foundation.stl", "tolerance.stl"]


def test_an_optimized_layout_never_crosses_the_wall():
    """Every block of a wall-backed reference lies on the seaward side of the wall face.

    A 4 m slice of the wall scene, so that the search has the whole wall to press
    against in its 20 s.
    """
    from optimizer.api import optimize

    short = parse_scene(WALL_TOML.format(wall="true").replace("length_m = 15.0", "length_m = 4.0"),
                        "short.toml", None)
    r = optimize(short, seed=1, time_limit=20)
    x = [pose.apply(block.vertices)[:, 0].min() for _, block, pose in r.layout.placed()]
    assert r.blocks > 0.6 * short.required_blocks and r.collisions == 0 and r.out_of_tolerance == 0
    assert min(x) >= -1.5 - 1e-9
    assert min(x) < -1.5 + 0.5  # blocks do come up to the wall: the test tests something


@pytest.mark.parametrize("gap_h", [0.3, 0.45])
def test_a_pattern_block_near_the_wall_is_set_down_against_it(walled, open_, gap_h):
    """``beam.set_against_wall``: a block standing less than ``WALL_GAP_H`` block heights off the
    wall is lowered again against it, no higher, inside the zone; one further off, or with no
    wall, stays as it was."""
    from geometry.checks import check_layout
    from optimizer.search.beam import WALL_GAP_H, WALL_RISE, WALL_STEP, set_against_wall
    from optimizer.search.build import Build
    from optimizer.search.shapes import ShapeCache
    from tests.test_strategies import problem

    h = walled.block.height
    shape = ShapeCache(walled.block).hung("crown", 0.4)
    lower = lambda pr, b, sh, x, y: b.lower(sh, x, y)  # noqa: E731 - the beam's own lowering
    build = Build(walled)
    probe = build.lower(shape, 0.0, 7.0)
    half = -probe.pose.apply(walled.block.vertices)[:, 0].min()  # centroid to its landward side
    near = build.lower(shape, -1.5 + half + gap_h * h, 7.0)
    moved = set_against_wall(problem(walled), build, near, lower)
    gap = moved.pose.apply(walled.block.vertices)[:, 0].min() + 1.5
    assert 0.0 <= gap < WALL_STEP
    assert moved.pose.position[2] <= near.pose.position[2] + WALL_RISE
    build.place(moved)
    report = check_layout(walled, build.placed(), with_coverage=False)
    assert not report.out_of_tolerance and not report.collisions

    far = Build(walled).lower(shape, -1.5 + half + (WALL_GAP_H + 0.1) * h, 7.0)
    assert set_against_wall(problem(walled), Build(walled), far, lower) is far
    open_build = Build(open_)
    beside = open_build.lower(shape, -1.5 + half + gap_h * h, 7.0)
    assert set_against_wall(problem(open_), open_build, beside, lower) is beside


def test_behind_a_wall_the_toe_row_is_laid_seaward_and_brings_the_toe_within_h(walled, open_):
    """Behind a wall only the seaward toe is open: the rows (``ToeRows``) lay one row there, none
    against the wall, and every point of the seaward toe line, end to end, is within H of a block
    of it (the coverage aim). Where the mound is open, the landward toe gets its row too.

    Until stop 54 this was checked through the whole ``optimize`` run on ``wall-shake`` seed 2,
    which keeps an attempt with rows only when its clock allows (it did not on 2026-11-28)."""
    from geometry.coverage import AIM_MAX_BARE_H, distance_to_block, surface_samples
    from optimizer.search.hangings import families
    from optimizer.search.patterns import lattice_for
    from optimizer.search.problem import Problem
    from optimizer.search.toe import ToeRows

    def rows(scene):
        problem = Problem(scene=scene, required=scene.required_blocks, target=scene.target_porosity,
                          lattice=lattice_for(scene.block, scene.block_type), families=families(scene.block))
        return ToeRows().run(problem, None, np.random.default_rng(1)).build.placed()

    walled_rows, open_rows = rows(walled), rows(open_)
    x = np.array([pose.position[0] for _, _, pose in walled_rows])
    assert len(x) >= 6 and (x > 0).all(), x
    assert out_of_tolerance(walled_rows, walled.tolerance) == []
    assert (np.array([pose.position[0] for _, _, pose in open_rows]) < 0).sum() >= 6
    samples = surface_samples(walled)
    toe = (samples.face == 0) & (samples.points[:, 2] == walled.design.z_bottom)
    assert toe.sum() >= 20
    near = np.min([distance_to_block(samples.points[toe], block, pose) for _, block, pose in walled_rows],
                  axis=0)
    assert near.max() <= AIM_MAX_BARE_H * walled.block.height, near.max()


def test_a_block_let_go_that_comes_to_rest_against_the_wall_is_kept():
    """``physics.settle_in``: a slab lowered upright beside the wall, tipped towards it, falls
    onto the wall face and rests there, pressed into it by the engine's soft contact. It is
    kept where it rests, set back out of the wall (``physics.within``), not refused as out of
    the zone."""
    from geometry.checks import check_layout
    from geometry.clip import volume_inside
    from geometry.pose import Pose, axis_angle_quat
    from optimizer.search.build import GROUND, Build, Candidate
    from optimizer.search.drop import Shape
    from optimizer.search.patterns import staggered
    from optimizer.search.physics import settle_in
    from optimizer.search.problem import Problem

    scene = parse_scene(WALL_TOML.format(wall="true").replace('"shake-4t"', '"box:0.3x2x2"'), "slab.toml",
                        None)
    slab = scene.block
    q = axis_angle_quat([0.0, 1.0, 0.0], -np.radians(10.0))  # tipped towards the wall (-x)
    pose = Pose([0.0, 7.0, 0.0], q)
    w = pose.apply(slab.vertices)
    pose = Pose([-1.5 - w[:, 0].min() + 0.3, 7.0, -w[:, 2].min()], q)
    problem = Problem(scene, scene.required_blocks, scene.target_porosity, staggered(slab))
    build = Build(scene)
    candidate = Candidate(Shape.of(slab, q), pose, (GROUND,),
                          volume_inside(slab, pose, scene.design.polytope))
    rested = settle_in(problem, build, candidate)
    assert rested is not None and rested is not candidate
    tilt = np.degrees(np.arccos(np.clip(rested.pose.rotation[2, 2], -1.0, 1.0)))
    assert tilt > 5.0  # it fell onto the wall
    x = rested.pose.apply(slab.vertices)[:, 0].min()
    assert -1.5 <= x < -1.5 + 0.01  # against the face, not through it
    report = check_layout(scene, [(0, slab, rested.pose)], with_coverage=False)
    assert not report.out_of_tolerance
