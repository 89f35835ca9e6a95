"""Coverage of the design surface: the bare share, the largest bare distance, where it is."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from geometry.coverage import (
    AIM_BARE_PERCENT,
    BARE_FRACTION,
    CoverageReport,
    SurfaceSamples,
    block_samples,
    coverage,
    distance_to_block,
    point_triangle_distance,
    surface_samples,
)
from geometry.pose import Pose, axis_angle_quat
from geometry.scene import parse_scene

# A box scene: 1 m cubes, a 4 m crest 1 m high with 1:1 slopes, 4 m long.
BOX_TOML = """
name = "boxes"
block = "box:1x1x1"
[design]
crest_width_m = 4.0
height_m = 1.0
slope_rise_run = [1.0, 1.0]
length_m = 4.0
"""


@pytest.fixture(scope="module")
def boxes():
    return parse_scene(BOX_TOML, "boxes.toml", None)


def test_surface_samples_cover_the_slopes_and_crest_by_area(boxes, mini):
    s = surface_samples(boxes)
    # Two slopes of sqrt(2) m and a 4 m crest, 4 m long.
    np.testing.assert_allclose(s.area.sum(), (2 * np.sqrt(2) + 4.0) * 4.0, rtol=1e-12)
    m = surface_samples(mini)
    np.testing.assert_allclose(m.area.sum(), (2 * 5.0 + 4.0) * mini.length, rtol=1e-12)


def test_a_known_bare_patch(boxes):
    """Cubes along the whole crest, none on the slopes: the slopes' far halves are bare.

    A row of cubes standing on the foundation under the crest, at x = -1.5, -0.5,
    0.5 and 1.5, covers the crest (their tops are the crest). A slope point at
    height z lies (2 + (1 - z)) - 2 = 1 - z metres beyond the outer cube's face
    in x, at the cube's height: bare when further than H/2 = 0.5 m, so the
    lower half of each slope, z < 0.5, is bare, and the toe is 1 m away.
    """
    cube = boxes.block
    spots = [(x, y) for x in (-1.5, -0.5, 0.5, 1.5) for y in (0.5, 1.5, 2.5, 3.5)]
    placed = [(i, cube, Pose([x, y, 0.5], [1, 0, 0, 0])) for i, (x, y) in enumerate(spots)]
    c = coverage(boxes, placed)
    slope = 2 * np.sqrt(2) * 4.0
    total = slope + 4.0 * 4.0
    # The bare part: the lower half of each slope (up to the sampling cell).
    assert c.bare_share_percent == pytest.approx(100 * (slope / 2) / total, abs=1.5)
    assert c.max_bare_m == pytest.approx(1.0, abs=1e-6)
    assert abs(c.worst_point[0]) == pytest.approx(3.0, abs=0.05) and c.worst_point[2] < 0.05
    faces = c.by_face()
    assert faces["crest"] == 0.0 and faces["seaward slope"] == pytest.approx(50.0, abs=3.0)


def test_blocks_far_from_the_mound_change_nothing_and_are_left_out(boxes):
    """The crest row of the known bare patch, with 400 cubes 30-90 m away: the same figures, and
    the search leaves the far cubes out (10 000 blocks spread over a square kilometre took 15 s).
    A cube just off the toe, which does change the figures, is kept."""
    from geometry.coverage import _reaching

    cube = boxes.block
    q = np.array([1.0, 0.0, 0.0, 0.0])
    row = [(k, cube, Pose([x, y, 0.5], q)) for k, (x, y) in
           enumerate((x, y) for x in (-1.5, -0.5, 0.5, 1.5) for y in (0.5, 1.5, 2.5, 3.5))]
    far = [(100 + k, cube, Pose([30.0 + 3 * (k % 20), 3.0 * (k // 20), 0.5], q)) for k in range(400)]
    near_toe = [(999, cube, Pose([3.2, 2.0, 0.5], q))]
    alone, crowded = coverage(boxes, row), coverage(boxes, row + far)
    assert crowded.bare_share_percent == alone.bare_share_percent
    assert crowded.max_bare_m == alone.max_bare_m and crowded.worst_point == alone.worst_point
    assert np.array_equal(crowded.bare, alone.bare)
    points = surface_samples(boxes).points
    assert _reaching(points, row + far) == row
    assert _reaching(points, row + far + near_toe) == row + near_toe
    assert coverage(boxes, row + far + near_toe).bare_share_percent < alone.bare_share_percent


@pytest.mark.parametrize("scene_name", ["boxes", "mini"])
def test_no_blocks_is_all_bare(boxes, scene_name):
    from geometry.scene import load_scene

    c = coverage(boxes if scene_name == "boxes" else load_scene(scene_name), [])
    assert c.bare_share_percent == 100.0  # exactly: 100.00000000000001 on mini once
    assert all(v == 100.0 for v in c.by_face().values())
    assert c.to_dict()["max_bare_m"] is None and c.to_dict()["worst_point"] is None


def test_point_triangle_distance_against_trimesh():
    rng = np.random.default_rng(0)
    tri = rng.normal(size=(300, 3, 3))
    p = rng.normal(size=(300, 3)) * 2
    ours = point_triangle_distance(p, tri)
    for i in range(300):
        mesh = trimesh.Trimesh(tri[i], [[0, 1, 2]], process=False)
        _, d, _ = trimesh.proximity.closest_point(mesh, p[i:i + 1])
        assert ours[i] == pytest.approx(d[0], abs=1e-9)


def test_distance_to_a_block_is_exact_and_zero_inside(shake):
    pose = Pose([0.3, 5.0, 1.0], axis_angle_quat([1, 2, 3], 0.7))
    rng = np.random.default_rng(1)
    pts = pose.position + rng.normal(size=(200, 3)) * 1.5
    ours = distance_to_block(pts, shake, pose)
    # Against trimesh on the block's own surface, for points outside every piece.
    mesh = trimesh.Trimesh(pose.apply(shake.vertices), shake.faces, process=False)
    inside = mesh.contains(pts)
    _, d, _ = trimesh.proximity.closest_point(mesh, pts[~inside])
    np.testing.assert_allclose(ours[~inside], d, atol=1e-6)
    assert np.all(ours[inside] == 0.0) and inside.any()


def test_block_samples_leave_no_gap_wider_than_the_spacing(shake):
    spacing = 0.1
    pts = block_samples(shake, spacing)
    rng = np.random.default_rng(2)
    surface = trimesh.Trimesh(shake.vertices, shake.faces, process=False).sample(2000, seed=rng)
    from scipy.spatial import cKDTree
    d, _ = cKDTree(pts).query(surface)
    assert d.max() <= spacing


def test_a_slender_block_is_sampled_by_its_area_not_its_longest_edge():
    """A 6 m by 0.3 m face cut k x k by its longest edge held 51 000 samples (a layout of 27
    such beams took 137 s to measure); halving across the longest edge keeps every point
    within the spacing with a tenth of them per square metre."""
    from scipy.spatial import cKDTree

    from geometry.blocks import get_block

    beam = get_block("box:6x0.3x0.3")
    spacing = beam.height / 16
    pts = block_samples(beam, spacing)
    surface = trimesh.Trimesh(beam.vertices, beam.faces, process=False).sample(5000, seed=3)
    assert cKDTree(pts).query(surface)[0].max() <= spacing
    assert len(pts) < 20 * beam.surface_area / spacing**2


def test_a_sliver_block_is_sampled_no_finer_than_its_bound_allows(tmp_path, mini):
    """A 4 m cylinder 0.24 m thick (96 triangles, long slivers): halving took 158 000 samples at
    the spacing MAX_BLOCK_SAMPLES gives, and 16 such blocks took 215 s to measure. The spacing
    is widened until it takes at most MOST_BLOCK_SAMPLES, every point of the surface still
    within it of a sample, and the bare samples are the ones measured exactly everywhere."""
    import geometry.coverage as cov
    from geometry.blocks import get_block

    path = tmp_path / "rod.stl"
    trimesh.creation.cylinder(radius=0.12, height=4.0, sections=32).export(path)
    rod = get_block(f"mesh:{path}")
    first = max(rod.height / cov.CELLS_PER_H, np.sqrt(4.0 * rod.surface_area / cov.MAX_BLOCK_SAMPLES))
    assert block_samples(rod, first, most=cov.MOST_BLOCK_SAMPLES) is None  # the case itself
    spacing = cov.block_spacing(rod, 0.0)
    pts = block_samples(rod, spacing)
    assert spacing > first and len(pts) <= cov.MOST_BLOCK_SAMPLES
    surface = trimesh.Trimesh(rod.vertices, rod.faces, process=False).sample(5000, seed=4)
    from scipy.spatial import cKDTree
    assert cKDTree(pts).query(surface)[0].max() <= spacing
    placed = [(i, rod, Pose([x, 6.0, mini.design.z_top], axis_angle_quat([0, 1, 0], np.pi / 2)))
              for i, x in enumerate((-1.0, 0.0, 1.0))]
    c = coverage(mini, placed)
    exact = cov._distances(c.samples.points, placed, c.spacing_m, c.bare_distance_m, exact=True)
    np.testing.assert_array_equal(c.bare, exact > c.bare_distance_m)
    assert c.max_bare_m == pytest.approx(exact.max(), abs=1e-12)


@pytest.mark.timeout(120)
def test_a_block_of_more_corners_than_the_sample_bound_is_sampled_at_its_corners(tmp_path):
    """A 2 x 1 x 1 m box cut into 196 608 triangles has 98 306 corners, more than
    MOST_BLOCK_SAMPLES, at any spacing: the widening ran for ever (every coverage of it hung).
    It stops at the block's width, where the corners are the samples; and a refusal by the
    bound holds when asked again (the cache gave the refused samples the second time)."""
    import geometry.coverage as cov
    from geometry.blocks import get_block

    mesh = trimesh.creation.box(extents=[2.0, 1.0, 1.0])
    for _ in range(7):
        mesh = mesh.subdivide()
    path = tmp_path / "fine-box.stl"
    mesh.export(path)
    block = get_block(f"mesh:{path}")
    assert len(block.vertices) > cov.MOST_BLOCK_SAMPLES
    spacing = cov.block_spacing(block, 0.0)
    assert 2.0 * block.bounding_radius <= spacing < 3.0 * block.bounding_radius
    assert len(block_samples(block, spacing)) == len(block.vertices)
    assert block_samples(block, spacing, most=cov.MOST_BLOCK_SAMPLES) is None  # asked again: still None


def test_tiny_blocks_on_a_big_mound_are_measured_with_a_bounded_sample():
    """5 cm tetrapods on mini would have taken 19 million samples of the surface."""
    from geometry.coverage import MAX_SAMPLES

    text = BOX_TOML.replace('block = "box:1x1x1"', 'block = "tetrapod:0.05"\nrequired_blocks = 10')
    tiny = parse_scene(text.replace("length_m = 4.0", "length_m = 400.0"), "tiny.toml", None)
    samples = surface_samples(tiny)
    assert len(samples.points) <= 1.2 * MAX_SAMPLES  # rounding up per face, and its edge rows
    assert samples.spacing > tiny.block.height / 16
    assert samples.area.sum() == pytest.approx(surface_samples(tiny, 0.5).area.sum())


def test_blocks_far_larger_than_the_scenes_are_sampled_by_their_own_size(boxes, monkeypatch):
    """Cubes of 1 m checked against a scene of 5 cm tetrapods (bare beyond 2.5 cm): each cube
    is sampled at its own H / 16, not the scene's (a layout of Shake Blocks so took 30 s and
    670 MB), and the exact distances still decide every sample: the same bare samples and
    largest distance as measured exactly everywhere."""
    import geometry.coverage as cov

    text = BOX_TOML.replace('block = "box:1x1x1"', 'block = "tetrapod:0.05"\nrequired_blocks = 10')
    tiny = parse_scene(text, "tiny.toml", None)
    cube = boxes.block
    placed = [(i, cube, Pose([x, 1.7 + 0.3 * i, 0.5], [1, 0, 0, 0])) for i, x in enumerate((-1.5, -0.2, 1.1))]
    asked = []
    real = cov.block_samples
    monkeypatch.setattr(cov, "block_samples",
                        lambda block, spacing, most=None: asked.append(spacing) or real(block, spacing, most))
    c = coverage(tiny, placed)
    assert min(asked) == pytest.approx(cube.height / 16)
    pts = c.samples.points
    exact = cov._distances(pts, placed, c.spacing_m, c.bare_distance_m, exact=True)
    np.testing.assert_array_equal(c.bare, exact > c.bare_distance_m)
    assert c.max_bare_m == pytest.approx(exact.max(), abs=1e-12)


def test_the_design_surface_inside_a_thick_block_is_covered(mini, monkeypatch):
    """A 20 x 20 x 4 m slab through ``mini``'s crest: the crest inside it lies 2 m from the slab's
    faces, past H/2 = 0.83 m, yet inside a block (it was called bare). The slab is sampled no
    finer than MAX_BLOCK_SAMPLES over its surface (at H / 16 it had 1.3 million samples for a
    100 m slab), and the exact distances still decide: the same bare samples as measured
    exactly everywhere, and no crest point under the slab bare."""
    import geometry.coverage as cov
    from geometry.blocks import get_block

    slab = get_block("box:20x20x4")
    placed = [(0, slab, Pose([0.0, 6.0, mini.design.z_top], [1, 0, 0, 0]))]
    asked = []
    real = cov.block_samples
    monkeypatch.setattr(cov, "block_samples",
                        lambda block, spacing, most=None: asked.append(spacing) or real(block, spacing, most))
    c = coverage(mini, placed)
    assert min(asked) == pytest.approx(np.sqrt(4.0 * slab.surface_area / cov.MAX_BLOCK_SAMPLES))
    assert len(real(slab, min(asked))) <= 1.2 * cov.MAX_BLOCK_SAMPLES
    pts = c.samples.points
    exact = cov._distances(pts, placed, c.spacing_m, c.bare_distance_m, exact=True)
    np.testing.assert_array_equal(c.bare, exact > c.bare_distance_m)
    crest = np.abs(pts[:, 2] - mini.design.z_top) < 1e-9
    assert crest.sum() > 100 and not c.bare[crest].any()


def test_mirror_images_have_the_same_coverage(boxes):
    """A block and its mirror image across the axis: the section is symmetric, so is the measure."""
    cube = boxes.block
    a = [(0, cube, Pose([1.0, 2.0, 0.5], [1, 0, 0, 0]))]
    b = [(0, cube, Pose([-1.0, 2.0, 0.5], [1, 0, 0, 0]))]
    ca, cb = coverage(boxes, a), coverage(boxes, b)
    assert ca.bare_share_percent == pytest.approx(cb.bare_share_percent, abs=1e-9)  # mirror images


def _report(bare: float, max_bare: float, h: float = 2.0) -> CoverageReport:
    return CoverageReport(bare, max_bare, (0.0, 0.0, 0.0), BARE_FRACTION * h, 0.1, np.zeros(0, bool),
                          SurfaceSamples(np.zeros((0, 3)), np.zeros(0), np.zeros(0, int), 0.1))


def test_the_aims_are_five_percent_bare_and_nothing_further_than_h():
    """Issue 24's aims, at their edges, for a block 2 m high."""
    assert _report(AIM_BARE_PERCENT, 2.0).aims_met() == 2
    assert _report(AIM_BARE_PERCENT + 0.01, 2.0).aims_met() == 1
    assert _report(1.0, 2.01).aims_met() == 1
    assert _report(6.0, 2.5).aims_met() == 0


def test_covering_better_is_more_aims_met_then_less_bare():
    """A layout that meets the distance aim covers better than a less bare one that meets none."""
    assert _report(6.0, 1.5).better_than(_report(5.5, 2.5))
    assert not _report(5.5, 2.5).better_than(_report(6.0, 1.5))
    assert _report(7.0, 2.5).better_than(_report(8.0, 2.1))
    assert not _report(7.0, 1.5).better_than(_report(7.0, 1.5))


def test_coverage_measured_again_near_a_change_is_the_whole_measure():
    """``coverage_after`` measures only near the blocks taken out or put in; its figures must be
    those of ``coverage`` on the whole layout: a block of the ``mini`` reference taken out, one
    moved, and one put in where the toe is bare."""
    from geometry.coverage import coverage_after
    from geometry.layout import read_layout
    from geometry.scene import load_scene
    from tests.conftest import ROOT

    scene = load_scene("mini")
    placed = read_layout(ROOT / "tests" / "data" / "mini-reference.json").placed()
    before = coverage(scene, placed)
    k = int(np.argmax([p.position[2] for _, _, p in placed]))  # a block of the crest
    _, block, pose = placed[k]
    out = placed[:k] + placed[k + 1:]
    moved = out + [(k, block, Pose(pose.position + [0.0, 0.0, 0.6], pose.quaternion))]
    toe = Pose([5.5, 6.0, 0.6], pose.quaternion)
    put = placed + [(999, block, toe)]
    # Put in at the farthest point, the largest distance moves to where it was only bounded.
    worst = Pose([5.5, before.worst_point[1], 0.6], pose.quaternion)
    for layout, changed in ((out, [pose.position]), (moved, [pose.position, pose.position + [0, 0, 0.6]]),
                            (put, [toe.position]), (placed + [(999, block, worst)], [worst.position])):
        whole, local = coverage(scene, layout), coverage_after(scene, layout, before, changed)
        assert local.bare_share_percent == pytest.approx(whole.bare_share_percent, abs=1e-9)
        assert local.max_bare_m == pytest.approx(whole.max_bare_m, abs=1e-9)
        assert np.array_equal(local.bare, whole.bare)
    assert coverage(scene, put).bare_share_percent < before.bare_share_percent
    assert coverage(scene, out).bare_share_percent > before.bare_share_percent


def test_the_nearest_sample_search_stops_at_its_deadline(boxes, monkeypatch):
    """27 slender blocks made one nearest-sample query over 240 000 surface points take 32 s.
    The query runs in parts, the deadline read before each: one block (so one read before
    the query, where the block samples are taken) and a clock a second on at each read stop
    it in its second part, and a deadline past every part measures all of it, as without."""
    import geometry.coverage as cov

    monkeypatch.setattr(cov, "QUERY_CHUNK", 64)
    placed = [(0, boxes.block, Pose([0.0, 2.0, 0.5], [1, 0, 0, 0]))]
    parts = -(-len(surface_samples(boxes).points) // 64)
    assert parts > 3
    reads = []

    def clock() -> float:
        reads.append(1)
        return float(len(reads))

    with pytest.raises(cov.TimeUp):
        coverage(boxes, placed, deadline=2.5, clock=clock)
    assert len(reads) == 3, "the samples' read, the first part's, then the second part's"
    reads.clear()
    whole = coverage(boxes, placed)
    timed = coverage(boxes, placed, deadline=1e9, clock=clock)
    assert timed.bare_share_percent == whole.bare_share_percent and timed.max_bare_m == whole.max_bare_m
    assert len(reads) >= 1 + parts
