"""Porosity: exact against Table V and Monte Carlo, voxels against exact, the tracker."""

from __future__ import annotations

import fcl
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from geometry.errors import InputError
from geometry.polytope import ConvexPolytope, PieceStack
from geometry.porosity import PorosityTracker, VoxelGrid, exact_filled_volume, porosity
from geometry.pose import Pose, axis_angle_quat
from geometry.samples import random_inside, random_quaternion
from tests.conftest import standing


@pytest.fixture(scope="module")
def inside25(mini, shake):
    return random_inside(shake, mini.design, 25, seed=16)


@pytest.fixture(scope="module")
def messy(mini, shake):
    """Blocks that stick out of the prism on every face, and two that overlap."""
    rng = np.random.default_rng(7)
    lo, hi = mini.design.bounds
    placed = []
    for i in range(14):
        placed.append((i, shake, Pose(rng.uniform(lo - 0.5, hi + 0.5), random_quaternion(rng))))
    a = standing(shake, 0.0, 6.0)
    placed.append((14, shake, a))
    placed.append((15, shake, Pose(a.position + [0.35, 0.2, 0.1], axis_angle_quat([0, 0, 1], 0.7))))
    return placed


@pytest.mark.parametrize("n, correct", [(9, 94.68), (17, 89.94), (25, 85.21)])
def test_exact_reproduces_table_v_correct_values(mini, inside25, n, correct):
    r = porosity(mini, inside25[:n], "exact")
    assert round(r.percent, 2) == correct
    assert abs(r.percent - correct) <= 0.01


def _monte_carlo(mini, placed, n, seed):
    """Share of uniform points in the prism inside any block (trimesh's ray test)."""
    rng = np.random.default_rng(seed)
    lo, hi = mini.design.bounds
    pts = rng.uniform(lo, hi, (int(n * 2.2), 3))
    pts = pts[mini.design.polytope.contains(pts, margin=0.0)][:n]
    hit = np.zeros(len(pts), bool)
    for _, block, pose in placed:
        near = np.linalg.norm(pts - pose.position, axis=1) <= block.bounding_radius
        local = pose.inverse_apply(pts[near])
        hit[np.flatnonzero(near)[block.trimesh.contains(local)]] = True
    return 100.0 * (1 - hit.mean()), len(pts)


def test_exact_agrees_with_independent_monte_carlo(mini, messy):
    exact = porosity(mini, messy, "exact").percent
    mc, n = _monte_carlo(mini, messy, 400_000, seed=11)
    sigma = 100 * np.sqrt((mc / 100) * (1 - mc / 100) / n)
    assert abs(exact - mc) < 4 * sigma, (exact, mc, sigma)


def test_exact_unions_overlapping_blocks(mini, shake):
    a = standing(shake, 0.0, 6.0)
    pair = [(0, shake, a), (1, shake, Pose(a.position + [0.3, 0, 0], a.quaternion))]
    single = porosity(mini, pair[:1], "exact").percent
    both = porosity(mini, pair, "exact").percent
    mc, n = _monte_carlo(mini, pair, 300_000, seed=3)
    sigma = 100 * np.sqrt((mc / 100) * (1 - mc / 100) / n)
    assert single > both > single - 100 * shake.volume / mini.design_volume  # less than a whole block added
    assert abs(both - mc) < 4 * sigma
    # Two copies of the same pose are one block.
    twin = [(0, shake, a), (1, shake, a)]
    assert porosity(mini, twin, "exact").percent == pytest.approx(single, abs=1e-9)


def _rigid(rng):
    return Pose(rng.normal(size=3) * 20, random_quaternion(rng))


def test_exact_and_tolerance_are_invariant_under_rigid_motion(mini, messy):
    from geometry.clip import volume_inside
    from geometry.collision import collisions

    rng = np.random.default_rng(2)
    for _ in range(3):
        t = _rigid(rng)
        moved = [(k, b, t.compose(p)) for k, b, p in messy]
        d, dm = mini.design.polytope, mini.design.polytope.transformed(t.rotation, t.position)
        z, zm = mini.tolerance.polytope, mini.tolerance.polytope.transformed(t.rotation, t.position)
        assert abs(exact_filled_volume(d, messy) - exact_filled_volume(dm, moved)) < 1e-9
        for (_, b, p), (_, _, pm) in zip(messy, moved, strict=True):
            assert abs(volume_inside(b, p, z) - volume_inside(b, pm, zm)) < 1e-9
        before = {(c.a, c.b): c.depth for c in collisions(messy)}
        after = {(c.a, c.b): c.depth for c in collisions(moved)}
        assert before.keys() == after.keys()
        for key in before:
            assert abs(before[key] - after[key]) < 1e-9


def test_voxel_converges_to_exact(mini, messy):
    exact = porosity(mini, messy, "exact").percent
    errors = [abs(porosity(mini, messy, "voxel", divisions=d).percent - exact) for d in (25, 50, 100, 200)]
    assert errors[-1] < 0.1
    assert errors[-1] < errors[0]
    assert max(errors[2:]) < 0.25


@pytest.mark.parametrize("divisions", [20, 50, 100, 150, 200])
def test_voxel_any_stays_below_exact(mini, inside25, divisions):
    for n in (9, 17, 25):
        exact = porosity(mini, inside25[:n], "exact").percent
        assert porosity(mini, inside25[:n], "voxel-any", divisions=divisions).percent < exact


def test_voxel_any_gap_shrinks_with_divisions(mini, inside25):
    exact = porosity(mini, inside25, "exact").percent
    gaps = [exact - porosity(mini, inside25, "voxel-any", divisions=d).percent for d in (50, 100, 150, 200)]
    assert all(a > b for a, b in zip(gaps, gaps[1:], strict=False))


def _box_objects(grid):
    """FCL boxes for every voxel of a coarse grid, and their indices."""
    half = grid.size / 2
    box = fcl.Box(*(2 * half))
    cx, cy, cz = np.meshgrid(*grid.centres, indexing="ij")
    centres = np.stack([cx, cy, cz], -1).reshape(-1, 3)
    return box, centres


def test_voxel_any_matches_brute_force_box_overlap(mini, shake):
    # Independent check of the Minkowski-sum rule: FCL box-vs-piece tests, voxel by voxel.
    pose = Pose([0.3, 5.1, 1.2], axis_angle_quat([1, 2, 3], 0.9))
    grid = VoxelGrid.for_scene(mini, "voxel-any", divisions=24)
    sl, mask = grid.block_cells(shake, pose)
    full = np.zeros(grid.shape, bool)
    full[sl] = mask
    box, centres = _box_objects(grid)
    pieces = [fcl.CollisionObject(fcl.Convex(p.vertices, len(p.faces),
                                             np.hstack([np.full((len(p.faces), 1), 3), p.faces]).ravel()),
                                  fcl.Transform(pose.rotation, pose.position)) for p in shake.pieces]
    near = np.linalg.norm(centres - pose.position, axis=1) < shake.bounding_radius + np.linalg.norm(grid.size)
    brute = np.zeros(len(centres), bool)
    req = fcl.CollisionRequest()
    for i in np.flatnonzero(near):
        o = fcl.CollisionObject(box, fcl.Transform(np.eye(3), centres[i]))
        brute[i] = any(fcl.collide(o, p, req, fcl.CollisionResult()) for p in pieces)
    mismatch = np.flatnonzero(brute != full.reshape(-1))
    # FCL's GJK decides exact-touch ties either way; allow a handful of grazing voxels.
    assert len(mismatch) <= 3, len(mismatch)
    assert full.sum() > 100


@pytest.mark.parametrize("name", ["shake-4t", "tetrapod"])
def test_box_sum_planes_bound_the_hull_of_the_minkowski_sum(name):
    """The voxel-any rule's planes, built without a hull, cut out the same set as the
    qhull hull of every vertex moved to every box corner (the Minkowski sum), at
    random poses and boxes."""
    from geometry.blocks import get_block

    block = get_block(name)
    rng = np.random.default_rng(3)
    for _ in range(10):
        pose = Pose(rng.uniform(-3, 3, 3), random_quaternion(rng))
        half = rng.uniform(0.01, 0.3, 3)
        # As the voxel grid calls it (every piece at once), and for one moved piece on its own.
        sums = block.stack.planes(pose.rotation, pose.position, half)
        assert len(sums) == len(block.pieces)
        for piece, (normals, offsets, box_lo, box_hi) in zip(block.pieces, sums, strict=True):
            moved = piece.transformed(pose.rotation, pose.position)
            corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * half
            hull = ConvexPolytope.from_points((moved.vertices[:, None, :] + corners).reshape(-1, 3))
            own_normals, own_offsets, _, _ = PieceStack((moved,)).planes(np.eye(3), np.zeros(3), half)[0]
            assert np.allclose(normals, own_normals) and np.allclose(offsets, own_offsets)
            assert np.allclose([box_lo, box_hi], hull.aabb)
            lo, hi = hull.aabb
            points = rng.uniform(lo - 0.3, hi + 0.3, (3000, 3))
            expected = hull.contains(points, margin=0.0)
            assert expected.sum() > 100 and (~expected).sum() > 100
            got = np.all(points @ normals.T <= offsets, axis=1)
            assert np.array_equal(got, expected)


def test_voxel_centres_match_point_in_mesh(mini, shake):
    pose = Pose([-1.0, 7.3, 1.0], axis_angle_quat([0.2, 1, 0.1], 2.1))
    grid = VoxelGrid.for_scene(mini, "voxel", divisions=60)
    sl, mask = grid.block_cells(shake, pose)
    full = np.zeros(grid.shape, bool)
    full[sl] = mask
    cx, cy, cz = np.meshgrid(*grid.centres, indexing="ij")
    centres = np.stack([cx, cy, cz], -1).reshape(-1, 3)
    near = np.linalg.norm(centres - pose.position, axis=1) < shake.bounding_radius
    inside = np.zeros(len(centres), bool)
    inside[np.flatnonzero(near)] = shake.trimesh.contains(pose.inverse_apply(centres[near]))
    assert np.array_equal(inside, full.reshape(-1))


def test_voxel_size_instead_of_divisions(mini, inside25):
    r = porosity(mini, inside25, "voxel", voxel_size=0.05)
    assert r.voxel_size == (0.05, 0.05, 0.05) and r.divisions is None
    assert abs(r.percent - porosity(mini, inside25, "exact").percent) < 0.3
    with pytest.raises(InputError):
        porosity(mini, inside25, "voxel", divisions=10, voxel_size=0.1)
    with pytest.raises(InputError, match="more than"):
        porosity(mini, inside25, "voxel", divisions=2000)
    # Sizes so small that the voxel counts overflow a 64-bit integer are refused all the same.
    for tiny in (1e-4, 1e-18, 1e-19, 1e-300):
        with pytest.raises(InputError, match=f"voxel size {tiny:g} m makes a grid of"):
            porosity(mini, inside25, "voxel", voxel_size=tiny)


@pytest.mark.parametrize("method", ["exact", "voxel", "voxel-any"])
def test_degenerate_layouts(mini, shake, method):
    far = [(0, shake, Pose([100.0, 100.0, 100.0], [1, 0, 0, 0]))]
    assert porosity(mini, [], method).percent == 100.0
    assert porosity(mini, far, method).percent == 100.0
    # A block whose centroid lies exactly on the crest plane: partly in, partly out.
    on_crest = [(0, shake, Pose([0.0, 6.0, mini.height], [1, 0, 0, 0]))]
    full = porosity(mini, [(0, shake, Pose([0.0, 6.0, 1.0], [1, 0, 0, 0]))], method).percent
    assert full < porosity(mini, on_crest, method).percent < 100.0


@pytest.mark.parametrize("method, divisions", [("exact", None), ("voxel", 60), ("voxel-any", 60)])
def test_tracker_equals_full_recompute(mini, shake, inside25, method, divisions):
    rng = np.random.default_rng(4)
    tracker = PorosityTracker(mini, method, divisions=divisions)
    current = {}
    for k, b, p in inside25[:12]:
        tracker.add(k, b, p)
        current[k] = p
    for step in range(15):
        key = int(rng.choice(list(current)))
        if step % 3 == 2:
            tracker.remove(key)
            del current[key]
        else:
            moved = Pose(current[key].position + rng.normal(scale=0.05, size=3), current[key].quaternion)
            tracker.move(key, moved)
            current[key] = moved
        full = porosity(mini, [(k, shake, p) for k, p in current.items()], method, divisions=divisions)
        if method == "exact":
            # The exact tracker sums blocks; compare with the disjoint sum.
            filled = exact_filled_volume(mini.design.polytope, [(k, shake, p) for k, p in current.items()],
                                         assume_disjoint=True)
            assert tracker.filled == pytest.approx(filled, abs=1e-9)
        else:
            assert tracker.percent == pytest.approx(full.percent, abs=1e-12)


def test_tracker_occupied_voxels_are_what_it_counts_as_filled(mini, inside25):
    """The occupancy a voxel tracker exposes is the set its porosity counts, after removals too."""
    tracker = PorosityTracker(mini, "voxel", divisions=50)
    for k, b, p in inside25[:12]:
        tracker.add(k, b, p)
    tracker.remove(inside25[3][0])
    occupied = tracker.occupied()
    assert occupied.shape == tracker.grid.shape and not (occupied & ~tracker.grid.prism_mask).any()
    assert occupied.sum() == tracker.filled > 0
    with pytest.raises(NotImplementedError):
        PorosityTracker(mini, "exact").occupied()


def test_tracker_gain_does_not_change_state(mini, shake, inside25):
    tracker = PorosityTracker(mini, "voxel", divisions=50)
    for k, b, p in inside25[:5]:
        tracker.add(k, b, p)
    before = tracker.percent
    gain = tracker.gain(shake, inside25[5][2])
    assert tracker.percent == before and gain > 0
    tracker.add(5, shake, inside25[5][2])
    assert tracker.filled == pytest.approx(porosity(mini, inside25[:6], "voxel", divisions=50).filled)


poses = st.builds(
    lambda x, y, z, q: Pose([x, y, z], np.array(q) / np.linalg.norm(q)),
    st.floats(-7, 7), st.floats(-1, 13), st.floats(-1, 4),
    st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda v: np.linalg.norm(v) > 0.2),
)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(poses, min_size=0, max_size=6))
def test_properties_of_porosity(mini, shake, pose_list):
    placed = [(i, shake, p) for i, p in enumerate(pose_list)]
    exact = porosity(mini, placed, "exact").percent
    any_ = porosity(mini, placed, "voxel-any", divisions=40).percent
    assert 0.0 <= exact <= 100.0 and 0.0 <= any_ <= 100.0
    # Adding a block never raises porosity.
    if placed:
        assert porosity(mini, placed[:-1], "exact").percent >= exact - 1e-9
        assert porosity(mini, placed[:-1], "voxel-any", divisions=40).percent >= any_
    # Fine voxels agree with exact (about 0.05 points per block at this grid).
    fine = porosity(mini, placed, "voxel", divisions=160).percent
    assert abs(fine - exact) < 0.05 + 0.1 * len(placed)


def test_convex_polytope_volume_matches_hull():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(40, 3))
    from scipy.spatial import ConvexHull

    assert ConvexPolytope.from_points(pts).volume == pytest.approx(ConvexHull(pts).volume, rel=1e-12)


@pytest.mark.parametrize("name", ["shake-4t", "tetrapod:2.0"])
def test_volume_inside_matches_the_boolean_against_the_prism(mini, name):
    """A posed block against the design prism, straddling one, two or three of its planes; below a plane.

    The one-plane cut sums the triangles' shares in closed form, the two-plane
    cut finds its apex in closed form: both against manifold3d's intersection.
    """
    import manifold3d as m3

    from geometry.blocks import get_block
    from geometry.clip import volume_below, volume_inside
    from geometry.constants import tol

    block = get_block(name)
    prism = mini.design.polytope
    solid = m3.Manifold.hull_points(prism.vertices)
    rng = np.random.default_rng(5)
    lo, hi = mini.design.bounds
    seen: dict[int, int] = {}
    for _ in range(120):
        # Poses near the prism's surface: a point on a random face, pushed in or out by up to a block.
        corner = prism.vertices[rng.integers(len(prism.vertices), size=3)]
        weights = rng.dirichlet(np.ones(3))
        at = weights @ corner + rng.normal(0.0, 0.4, 3)
        pose = Pose(np.clip(at, lo - 1.0, hi + 1.0), random_quaternion(rng))
        world = pose.apply(block.vertices)
        crossed = int(((world @ prism.normals.T - prism.offsets).max(axis=0) > tol.distance).sum())
        seen[crossed] = seen.get(crossed, 0) + 1
        posed = block.posed_solid(pose)
        expected = (posed ^ solid).volume()
        assert volume_inside(block, pose, prism) == pytest.approx(expected, abs=1e-9, rel=1e-9)
        # And below a plane of any direction through the block (the live layout's volume above the crest).
        normal = random_quaternion(rng)[1:]
        normal /= np.linalg.norm(normal)
        offset = float(normal @ pose.position) + rng.uniform(-1.0, 1.0)
        below = posed.trim_by_plane(-normal, -offset).volume()
        assert volume_below(block, pose, normal, offset) == pytest.approx(below, abs=1e-9, rel=1e-9)
        doubled = volume_below(block, pose, 2.0 * normal, 2.0 * offset)  # the same plane, a longer normal
        assert doubled == pytest.approx(below, abs=1e-9, rel=1e-9)
    assert seen.get(1, 0) >= 10 and seen.get(2, 0) >= 10, seen
