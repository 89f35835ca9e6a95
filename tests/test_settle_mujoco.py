"""The MuJoCo backend on real blocks: the Shake Block's stability boundaries, the
model it builds, rough foundations and piles.

The tipping boundary of a Shake Block stood on one leg comes from its
geometry: the leg's end face is a regular hexagon of circumradius ``r`` at
distance ``L`` from the centroid along the leg. Tilted by ``alpha`` towards the
midpoint of one of the hexagon's edges, the centre of mass stays over the face
while ``L tan(alpha) <= r cos(30 deg)``.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from geometry.blocks import LEG_DIRECTIONS, Block, get_block
from geometry.pose import Pose, axis_angle_quat, quat_multiply
from geometry.scene import Scene, parse_scene
from settle import MujocoBackend, settle
from settle.base import SettleBody
from tests.conftest import standing

X = np.array([1.0, 0.0, 0.0])
Y = np.array([0.0, 1.0, 0.0])


@pytest.fixture(scope="module")
def end_face(shake: Block) -> tuple[float, float, np.ndarray]:
    """(L, inradius, unit vector to an edge midpoint) of leg 0's end face, block frame."""
    leg = shake.pieces[1]
    reach = leg.vertices @ LEG_DIRECTIONS[0]
    face = leg.vertices[reach > reach.max() - 1e-9]
    centre = face.mean(axis=0)
    assert len(face) == 6 and np.allclose(centre[:2], 0.0)
    corners = face - centre
    mids = (corners + np.roll(corners, 1, axis=0)) / 2  # edge midpoints of the hexagon
    k = int(np.argmax(mids[:, 0]))
    return float(reach.max()), float(np.linalg.norm(mids[k])), mids[k] / np.linalg.norm(mids[k])


def tipping_angle(end_face) -> float:
    length, inradius, _ = end_face
    return math.atan(inradius / length)


def on_end_face(shake: Block, end_face, alpha: float, ground: Pose | None = None) -> Pose:
    """The block stood on leg 0's end face, its face flat on a surface tilted by
    ``alpha`` so that the centre of mass leans towards an edge midpoint.

    ``ground`` is the pose of that surface's centre (flat ground at z = 0 by
    default); the surface's normal is its local +z.
    """
    _, _, towards = end_face
    # Leg 0 down: a half turn about the axis through the edge midpoint keeps
    # that midpoint where it is.
    flip = axis_angle_quat(towards, math.pi)
    # Then turn about the axis along the edge, so that +z leans towards it.
    axis = np.cross([0.0, 0.0, 1.0], towards)
    q = quat_multiply(axis_angle_quat(axis, alpha), flip)
    surface = ground if ground is not None else Pose([0.0, 6.0, 0.0], [1, 0, 0, 0])
    normal = surface.rotation[:, 2]
    pose = Pose(surface.position, q)
    # Slide along the normal until the face touches the surface.
    gap = ((pose.apply(shake.vertices) - surface.position) @ normal).min()
    return pose.translated(-gap * normal)


def leg_tilt(pose: Pose) -> float:
    """Angle of leg 0 from straight down, degrees."""
    return float(np.degrees(np.arccos(np.clip(-pose.rotation[:, 2] @ [0, 0, 1], -1, 1))))


# --- the Shake Block on flat ground ---------------------------------------------------------


def test_tipping_angle_from_geometry(end_face):
    # Regular hexagon: inradius = circumradius cos 30; about 16 degrees.
    length, inradius, _ = end_face
    assert 15.0 < math.degrees(tipping_angle(end_face)) < 17.0
    assert inradius < length


def test_shake_on_three_legs_is_stable(mini, shake):
    for yaw in (0.0, 0.7):
        r = settle(mini, [(0, shake, standing(shake, 0.0, 6.0, yaw))])
        assert r.stable and r.max_displacement_m < 1e-3 and r.max_rotation_deg < 0.1


def test_shake_upright_on_its_end_face_is_stable(mini, shake, end_face):
    pose = on_end_face(shake, end_face, 0.0)
    assert leg_tilt(pose) < 1e-9
    r = settle(mini, [(0, shake, pose)])
    assert r.stable and r.max_displacement_m < 1e-3 and r.max_rotation_deg < 0.1


@pytest.mark.parametrize("delta_deg, topples", [(-1.0, False), (1.0, True), (10.0, True)])
def test_shake_on_one_leg_topples_iff_com_passes_face_edge(mini, shake, end_face, delta_deg, topples):
    # Flat ground, the block tilted on the edge of its end face: past the
    # boundary the centre of mass is outside the face and it falls over;
    # short of it the block drops back onto its face. A slender block on a
    # small face then rocks from edge to edge for seconds (Housner's rocking
    # block; the same at 1, 2 and 4 ms steps), so it is given 5 s to settle.
    alpha = tipping_angle(end_face) + math.radians(delta_deg)
    q = on_end_face(shake, end_face, alpha).quaternion
    pose = Pose([0.0, 6.0, 0.0], q)
    pose = pose.translated([0.0, 0.0, -pose.apply(shake.vertices)[:, 2].min()])
    r = settle(mini, [(0, shake, pose)], seconds=2.0 if topples else 5.0)
    final = r.blocks[0].pose
    if topples:
        assert not r.stable
        assert leg_tilt(final) > 40.0  # fallen onto its other legs
    else:
        # Standing on its face again. It turned by alpha on the way, which the
        # 5-degree rule counts as unstable, so the physics is what is checked.
        assert leg_tilt(final) < 2.0
        assert final.position[2] == pytest.approx(end_face[0], abs=0.01)  # centroid L above ground


@pytest.mark.parametrize("delta_deg, stable", [(-0.5, True), (0.5, False)])
def test_shake_on_one_leg_on_a_slope_stands_iff_com_is_over_its_face(mini, shake, end_face,
                                                                     delta_deg, stable):
    # The end face flat on a fixed concrete slab tilted by alpha (below the
    # friction angle, 31 deg, so it cannot slide): it stands while the centre
    # of mass is over the face and topples just past that.
    alpha = tipping_angle(end_face) + math.radians(delta_deg)
    _, _, towards = end_face
    slab = get_slab()
    axis = np.cross([0.0, 0.0, 1.0], towards)
    tilt = axis_angle_quat(axis, alpha)
    slab_pose = Pose([0.0, 6.0, 4.0], tilt)
    top = Pose(slab_pose.apply(np.array([[0.0, 0.0, 0.5]]))[0], tilt)
    pose = on_end_face(shake, end_face, alpha, ground=top)
    r = settle(mini, [(0, slab, slab_pose), (1, shake, pose)], movable=[1])
    assert r.stable is stable
    if stable:
        assert r.blocks[1].displacement_m < 2e-3 and r.blocks[1].rotation_deg < 0.2
    else:
        assert r.blocks[1].rotation_deg > 30.0


def get_slab() -> Block:
    return get_block("box:8x8x1")


def test_floating_shake_pile_is_unstable(mini, shake):
    placed = [(i, shake, standing(shake, 2.5 * i - 2.5, 6.0, 0.3 * i, ground=1.5)) for i in range(3)]
    r = settle(mini, placed)
    assert not r.stable and all(not b.stable for b in r.blocks)
    np.testing.assert_allclose([b.displacement_m for b in r.blocks], 1.5, atol=0.01)


@pytest.mark.parametrize("copies", [20, 60])
def test_blocks_one_inside_another_get_no_answer_not_a_crash(mini, shake, copies, capfd):
    """A hostile save of one pose many times over: MuJoCo's stack overflowed (20 copies) or its
    contacts filled the arena (50), and settle, score and optimize --keep ended with exit 1.
    The settle now says it has no answer: diverged, nothing stable; and MuJoCo's own warning
    lines stay off stderr, where a command's one-line summary goes."""
    pose = standing(shake, 0.0, 6.0, 0.0)
    r = settle(mini, [(i, shake, pose) for i in range(copies)])
    assert r.diverged and not r.stable and not any(b.stable for b in r.blocks)
    out, err = capfd.readouterr()
    assert "WARNING" not in out + err, (out + err)[:300]


# --- the model --------------------------------------------------------------------------------


def _bodies(placed, movable=None):
    return [SettleBody(k, b, p, movable is None or k in movable, np.zeros(3), np.zeros(3))
            for k, b, p in placed]


def test_model_geoms_are_the_pieces_and_mass_is_the_blocks(mini, shake):
    pose = Pose([0.3, 5.0, 1.2], axis_angle_quat([1, 2, 3], 0.8))
    model = MujocoBackend().build(mini, _bodies([(0, shake, pose)]))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    body = model.body("block0").id
    geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] == body]
    assert len(geoms) == len(shake.pieces)
    for g, piece in zip(geoms, shake.pieces, strict=True):
        assert model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH
        m = model.geom_dataid[g]
        verts = model.mesh_vert[model.mesh_vertadr[m]:model.mesh_vertadr[m] + model.mesh_vertnum[m]]
        world = verts @ data.geom_xmat[g].reshape(3, 3).T + data.geom_xpos[g]
        expected = pose.apply(piece.vertices)
        # Same point sets (MuJoCo recentres each mesh on its own centroid).
        dist = np.linalg.norm(world[:, None] - expected[None], axis=2)
        assert dist.min(axis=1).max() < 1e-6 and dist.min(axis=0).max() < 1e-6
    assert model.body_mass[body] == pytest.approx(shake.mass)
    np.testing.assert_allclose(model.body_ipos[body], 0.0, atol=1e-12)
    np.testing.assert_allclose(np.sort(model.body_inertia[body]), np.linalg.eigvalsh(shake.inertia),
                               rtol=1e-9)
    # The foundation is a box, never a plane (mujoco#3524).
    assert mujoco.mjtGeom.mjGEOM_PLANE not in set(model.geom_type)
    assert model.geom("foundation").type == mujoco.mjtGeom.mjGEOM_BOX


def test_fixed_blocks_have_no_joint(mini, shake):
    placed = [(0, shake, standing(shake, 0, 4)), (1, shake, standing(shake, 0, 8))]
    model = MujocoBackend().build(mini, _bodies(placed, movable={1}))
    assert model.njnt == 1 and model.jnt_bodyid[0] == model.body("block1").id


@pytest.fixture(scope="module")
def rough() -> Scene:
    text = """
    name = "mini-rough"
    block = "shake-4t"
    [design]
    crest_width_m = 4.0
    height_m = 3.0
    slope_rise_run = [3.0, 4.0]
    length_m = 12.2
    [foundation]
    kind = "rough"
    amplitude_m = 0.15
    cell_m = 0.5
    seed = 3
    """
    return parse_scene(text, source="rough", base_dir=None)


def test_rough_foundation_is_the_height_field(rough):
    model = MujocoBackend().build(rough, [])
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    xs, ys, h = rough.foundation.grid
    rng = np.random.default_rng(0)
    geomid = np.zeros(1, dtype=np.int32)
    for i, j in zip(rng.integers(1, len(xs) - 1, 40), rng.integers(1, len(ys) - 1, 40), strict=True):
        # A ray straight down onto a grid node hits the field at its height.
        top = np.array([xs[i], ys[j], 5.0])
        dist = mujoco.mj_ray(model, data, top, np.array([0.0, 0.0, -1.0]), None, 1, -1, geomid)
        assert model.geom(geomid[0]).name == "underlayer"
        assert 5.0 - dist == pytest.approx(h[i, j], abs=1e-6)


def test_shake_settles_onto_rough_foundation(rough, shake):
    # Lowered onto the rubble from above its highest point, it lands and then
    # stays put when settled again from where it landed.
    pose = standing(shake, 0.4, 6.1, 0.2, ground=rough.foundation.amplitude + 0.05)
    first = settle(rough, [(0, shake, pose)])
    assert first.blocks[0].displacement_m < 0.5 and first.at_rest
    again = settle(rough, [(0, shake, first.poses[0])])
    assert again.stable and again.max_displacement_m < 2e-3


@pytest.mark.parametrize("overlap", [0.005, 0.02])
def test_overlap_push_out_speed_follows_the_contact_time_constant(mini, overlap):
    # A critically damped contact of time constant tau pushes an overlap p out
    # at about p / (2 tau) at most, and leaves the block touching, not flying:
    # even 2 cm (twice PhysX's contact offset) is no launch.
    b = get_block("box:2x2x1")
    placed = [(0, b, Pose([0.0, 6.0, 0.5], [1, 0, 0, 0])),
              (1, b, Pose([0.0, 6.0, 1.5 - overlap], [1, 0, 0, 0]))]
    backend = MujocoBackend(check_every=1)
    r = settle(mini, placed, movable=[1], backend=backend)
    tau = backend.solref[0]
    assert r.peak_speed <= overlap / (2 * tau)
    assert r.stable and r.max_displacement_m == pytest.approx(overlap, abs=1e-3)


def test_turning_and_moving_the_whole_layout_leaves_the_verdict(mini, shake):
    # STYLE.md, "Check invariance": two blocks standing on three legs and one
    # hanging 0.8 m above the ground, turned about the vertical by 0.6 rad and
    # moved, settle to the same verdicts and displacements.
    placed = [(0, shake, standing(shake, -3.0, 6.0, 0.3)),
              (1, shake, standing(shake, 0.5, 6.0, 1.1, ground=0.8)),
              (2, shake, standing(shake, 3.0, 6.0, 2.0))]
    turn = Pose([1.0, -2.0, 0.0], axis_angle_quat([0, 0, 1], 0.6))
    moved = [(k, b, turn.compose(p)) for k, b, p in placed]
    a, b = settle(mini, placed), settle(mini, moved)
    assert [x.stable for x in a.blocks] == [x.stable for x in b.blocks] == [True, False, True]
    np.testing.assert_allclose([x.displacement_m for x in a.blocks], [x.displacement_m for x in b.blocks],
                               atol=2e-3)
