"""The contract every settle backend passes (STYLE.md: optuna's BasicSamplerTestCase).

:class:`SettleBackendContract` holds the tests; each backend supplies only a
``make_backend`` fixture (a factory taking the backend's keyword options). The
scenes are extruded boxes in the ``mini-section`` scene, which both the 3D
and the 2D engine can model, and each test has an analytic or obvious answer.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from geometry.blocks import Block, get_block
from geometry.constants import GRAVITY
from geometry.errors import InputError
from geometry.pose import Pose, axis_angle_quat
from geometry.scene import Scene, load_scene
from settle import MujocoBackend, PymunkBackend, Thresholds, settle

#: Coulomb friction of the backends' defaults (docs/settle.md).
MU = 0.6

Y = np.array([0.0, 1.0, 0.0])


@pytest.fixture(scope="module")
def section() -> Scene:
    return load_scene("mini-section")


def box(a: float, c: float) -> Block:
    """A box ``a`` wide (x) and ``c`` high (z), 1 m along the crest."""
    return get_block(f"box:{a:g}x1x{c:g}")


def on_ground(block: Block, x: float, z: float = 0.0, theta: float = 0.0) -> Pose:
    """``block`` turned by ``theta`` about +y, its lowest point at height ``z``."""
    q = axis_angle_quat(Y, theta)
    pose = Pose([x, 0.5, 0.0], q)
    low = pose.apply(block.vertices)[:, 2].min()
    return Pose([x, 0.5, z - low], q)


def incline(theta: float, block: Block) -> list[tuple[int, Block, Pose]]:
    """A fixed 20 m slab tilted by ``theta`` about +y, high above the ground, with
    ``block`` resting on it at its middle, turned with it (surface contact)."""
    slab = get_block("box:20x1x1")
    q = axis_angle_quat(Y, theta)
    s = Pose([0.0, 0.5, 8.0], q)
    c = float(np.ptp(block.vertices[:, 2]))
    b = Pose(s.apply(np.array([[0.0, 0.0, 0.5 + c / 2]]))[0], q)
    return [(0, slab, s), (1, block, b)]


def stack(offsets: list[float], a: float = 1.2, c: float = 0.6, lift: float = 0.0) -> list:
    """Boxes stacked face on face, each shifted along x by its offset from the one below."""
    b = box(a, c)
    x, out = 0.0, []
    for i, dx in enumerate(offsets):
        x += dx
        out.append((i, b, Pose([x, 0.5, lift + c / 2 + i * c], [1, 0, 0, 0])))
    return out


class SettleBackendContract:
    """Tests every backend must pass; subclasses provide ``make_backend``."""

    @pytest.fixture
    def make_backend(self):  # pragma: no cover - replaced by each backend
        raise NotImplementedError

    # --- trivial cases ---------------------------------------------------------

    def test_empty_layout_is_stable(self, make_backend, section):
        r = settle(section, [], backend=make_backend())
        assert r.stable and r.blocks == [] and r.steps == 0
        assert r.max_displacement_m == 0.0 and r.max_rotation_deg == 0.0

    def test_block_on_ground_stays_and_stops_early(self, make_backend, section):
        b = box(1.2, 0.6)
        r = settle(section, [(7, b, on_ground(b, 0.0))], backend=make_backend())
        assert r.stable and r.blocks[0].id == 7
        assert r.max_displacement_m < 1e-3 and r.max_rotation_deg < 0.1
        assert r.at_rest and r.simulated_seconds < 1.0

    def test_full_run_without_early_stop(self, make_backend, section):
        b = box(1.2, 0.6)
        backend = make_backend()
        r = settle(section, [(0, b, on_ground(b, 0.0))], seconds=0.5, early_stop=False, backend=backend)
        assert not r.at_rest and r.steps == round(0.5 / backend.timestep)
        assert r.simulated_seconds == pytest.approx(0.5)

    def test_free_fall_follows_gravity(self, make_backend, section):
        b = box(1.2, 0.6)
        t = 0.5
        r = settle(section, [(0, b, on_ground(b, 0.0, z=10.0))], seconds=t, backend=make_backend())
        # Semi-implicit Euler is first order: g t dt / 2 = 5 mm of 1.23 m at 2 ms.
        np.testing.assert_allclose(r.max_displacement_m, GRAVITY * t**2 / 2, rtol=0.01)
        assert not r.stable

    def test_floating_pile_is_unstable(self, make_backend, section):
        placed = stack([0.0, 0.1, -0.1], lift=2.0)
        r = settle(section, placed, backend=make_backend())
        assert not r.stable and all(not b.stable for b in r.blocks)
        # They land: every block drops by the 2 m gap.
        assert min(b.displacement_m for b in r.blocks) > 1.9

    def test_fixed_blocks_hold_what_rests_on_them(self, make_backend, section):
        placed = stack([0.0, 0.2], lift=3.0)  # block 0 floats 3 m up, block 1 rests on it
        r = settle(section, placed, movable=[1], backend=make_backend())
        assert r.stable
        fixed, free = r.blocks
        assert not fixed.movable and fixed.displacement_m == 0.0 and free.movable
        assert free.displacement_m < 1e-3

    # --- the analytic thresholds -------------------------------------------------------

    @pytest.mark.parametrize("delta_deg, slides", [(-1.5, False), (1.5, True), (3.0, True)])
    def test_incline_slides_iff_tan_theta_exceeds_mu(self, make_backend, section, delta_deg, slides):
        theta = math.atan(MU) + math.radians(delta_deg)
        b = box(1.0, 0.5)  # tips only past atan(1.0 / 0.5) = 63 deg
        r = settle(section, incline(theta, b), movable=[1], backend=make_backend())
        block = r.blocks[1]
        assert block.stable is not slides
        assert block.rotation_deg < 1.0  # it slides; it does not tip
        if slides:
            # Constant acceleration down the slope for the whole 2 s.
            a = GRAVITY * (math.sin(theta) - MU * math.cos(theta))
            np.testing.assert_allclose(block.displacement_m, a * r.simulated_seconds**2 / 2, rtol=0.05)
        else:
            assert block.displacement_m < 1e-3

    @pytest.mark.parametrize("delta_deg, topples", [(-1.5, False), (1.5, True)])
    def test_incline_topples_once_com_passes_support_edge(self, make_backend, section, delta_deg, topples):
        # A box 0.4 wide and 1.0 high tips at atan(0.4 / 1.0) = 21.8 deg,
        # before it can slide (31.0 deg).
        theta = math.atan(0.4 / 1.0) + math.radians(delta_deg)
        r = settle(section, incline(theta, box(0.4, 1.0)), movable=[1], backend=make_backend())
        block = r.blocks[1]
        assert block.stable is not topples
        if topples:
            assert block.rotation_deg > 60.0  # it has fallen onto its side
        else:
            assert block.displacement_m < 1e-3 and block.rotation_deg < 0.1

    @pytest.mark.parametrize("overhang, stable", [(0.55, True), (0.65, False)])
    def test_overhanging_block_topples_iff_com_passes_edge(self, make_backend, section, overhang, stable):
        # The top box's centre lies past the lower box's edge (0.6) or not.
        r = settle(section, stack([0.0, overhang]), backend=make_backend())
        assert r.stable is stable
        assert r.blocks[0].stable  # the bottom box stays put either way
        assert r.blocks[1].stable is stable

    # --- numerics -------------------------------------------------------------------------

    @pytest.mark.parametrize("overlap", [0.002, 0.005])
    def test_overlap_neither_explodes_nor_injects_unbounded_speed(self, make_backend, section, overlap):
        # Trainee saves start with millimetres of overlap: into the ground,
        # and between two stacked blocks.
        b = box(1.2, 0.6)
        placed = [(0, b, on_ground(b, 0.0, z=-overlap)), (1, b, on_ground(b, 3.0)),
                  (2, b, on_ground(b, 3.0, z=0.6 - overlap))]
        backend = make_backend(check_every=1)
        r = settle(section, placed, backend=backend)
        assert all(np.isfinite(p.position).all() and np.isfinite(p.quaternion).all()
                   for p in r.poses.values())
        assert r.stable
        # A critically damped contact spring of time constant 2 dt pushes an
        # overlap p out at no more than p / (2 dt) (MuJoCo reaches about half
        # of that; pymunk's split impulses leave no speed at all) ...
        assert r.peak_speed <= overlap / (2 * backend.timestep)
        # ... and does not launch the block: it ends where it would touch.
        assert r.max_displacement_m <= 2 * overlap

    def test_verdicts_unchanged_when_timestep_halved(self, make_backend, section):
        cases = {
            "resting": [(0, box(1.2, 0.6), on_ground(box(1.2, 0.6), 0.0))],
            "stable stack": stack([0.0, 0.3, -0.2]),
            "overhang": stack([0.0, 0.7]),
            "sliding": incline(math.atan(MU) + math.radians(3), box(1.0, 0.5)),
            "holding": incline(math.atan(MU) - math.radians(3), box(1.0, 0.5)),
            "tipping": incline(math.atan(0.4) + math.radians(3), box(0.4, 1.0)),
        }
        coarse, fine = make_backend(), make_backend()
        fine = make_backend(timestep=coarse.timestep / 2)
        for name, placed in cases.items():
            movable = [1] if len(placed) == 2 and placed[0][1].name == "box:20x1x1" else None
            a = settle(section, placed, backend=coarse, movable=movable)
            b = settle(section, placed, backend=fine, movable=movable)
            assert [x.stable for x in a.blocks] == [x.stable for x in b.blocks], name

    def test_same_seed_is_bit_identical_and_seed_matters(self, make_backend, section):
        placed = stack([0.0, 0.45, 0.45])  # the top two lean out past the edge and fall
        runs = [settle(section, placed, seed=s, backend=make_backend()) for s in (3, 3, 4)]

        def state(r):
            return b"".join(p.position.tobytes() + p.quaternion.tobytes() for p in r.poses.values())

        assert state(runs[0]) == state(runs[1])
        assert runs[0].to_dict() | {"seconds": 0} == runs[1].to_dict() | {"seconds": 0}
        assert state(runs[0]) != state(runs[2])

    def test_translation_leaves_the_verdict_unchanged(self, make_backend, section):
        # STYLE.md, "Check invariance": moving the whole scene changes nothing.
        for offsets in ([0.0, 0.4], [0.0, 0.7]):
            base = stack(offsets)
            moved = [(k, b, p.translated([7.25, 0.0, 0.0])) for k, b, p in base]
            a = settle(section, base, backend=make_backend())
            b = settle(section, moved, backend=make_backend())
            assert [x.stable for x in a.blocks] == [x.stable for x in b.blocks]
            np.testing.assert_allclose([x.displacement_m for x in a.blocks],
                                       [x.displacement_m for x in b.blocks], atol=0.01)

    # --- results and arguments ------------------------------------------------------------

    def test_result_has_the_contract_keys(self, make_backend, section):
        r = settle(section, stack([0.0, 0.7]), backend=make_backend())
        d = json.loads(json.dumps(r.to_dict(), allow_nan=False))
        assert set(d) >= {"stable", "max_displacement_m", "max_rotation_deg", "blocks", "seconds"}
        assert [set(b) for b in d["blocks"]] == [{"id", "displacement_m", "rotation_deg", "stable"}] * 2
        assert d["max_displacement_m"] == max(b["displacement_m"] for b in d["blocks"])
        assert set(r.poses) == {0, 1}

    def test_thresholds_are_configurable(self, make_backend, section):
        placed = stack([0.0, 0.7])
        strict = settle(section, placed, backend=make_backend())
        lax = settle(section, placed, backend=make_backend(),
                     thresholds=Thresholds(displacement_fraction=100.0, rotation_deg=180.0))
        assert not strict.stable and lax.stable

    def test_bad_arguments_are_input_errors(self, make_backend, section):
        placed = stack([0.0])
        with pytest.raises(InputError, match="movable block 5"):
            settle(section, placed, movable=[5], backend=make_backend())
        with pytest.raises(InputError, match="settle time"):
            settle(section, placed, seconds=0.0, backend=make_backend())
        with pytest.raises(InputError, match="unique"):
            settle(section, placed + placed, backend=make_backend())


class TestMujocoContract(SettleBackendContract):
    @pytest.fixture
    def make_backend(self):
        return MujocoBackend


class TestPymunkContract(SettleBackendContract):
    @pytest.fixture
    def make_backend(self):
        return PymunkBackend


# --- the rest rule, backend-free ------------------------------------------------------------


def _rests_after(motion, seconds: float = 1.0, dt: float = 0.04) -> float | None:
    """First time a RestMonitor, sampling every ``dt`` from t = 0, calls a block
    moving along x by ``motion(t)`` at rest."""
    from settle.base import RestMonitor

    monitor = RestMonitor(np.array([1.0]))
    q = np.array([[1.0, 0.0, 0.0, 0.0]])
    for k in range(round(seconds / dt) + 1):
        t = k * dt
        if monitor.update(t, np.array([[motion(t), 0.0, 0.0]]), q, np.zeros((1, 3)), np.zeros((1, 3))):
            return t
    return None


def test_rest_rule_ignores_vibration_and_catches_slow_acceleration():
    from geometry.constants import tol

    # Vibrating in place by 5 micrometres at 30 Hz (1 mm/s peaks): at rest
    # as soon as a full window has passed.
    vibrating = _rests_after(lambda t: 5e-6 * math.sin(2 * math.pi * 30 * t))
    assert vibrating == pytest.approx(tol.rest_time)
    # Constant acceleration from rest: at rest iff a < rest_speed / rest_time.
    limit = tol.rest_speed / tol.rest_time
    assert _rests_after(lambda t: 0.9 * limit * t**2 / 2, seconds=0.2) is not None
    assert _rests_after(lambda t: 1.1 * limit * t**2 / 2, seconds=0.2) is None
    # Creeping steadily at the rest speed: never at rest.
    assert _rests_after(lambda t: tol.rest_speed * t) is None
