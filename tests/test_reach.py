"""The coverage floor (geometry.reach): how near any block inside the tolerance zone can come."""

from __future__ import annotations

import json

import numpy as np
from scipy.spatial.transform import Rotation

from geometry.coverage import distance_to_block
from geometry.pose import Pose
from geometry.reach import Reach, _polygon_distance, least_distances, nearest, section_samples
from geometry.scene import load_scene
from geometry.tolerance import outside_volume
from tests.conftest import shoha


def _cube_scene(tmp_path):
    path = tmp_path / "cubes.toml"
    path.write_text('block = "box:1.6x1.6x1.6"\ntarget_porosity_percent = 47.0\n[design]\n'
                    'crest_width_m = 4.0\nheight_m = 3.2\nslope_rise_run = [2.0, 3.0]\nlength_m = 12.0\n')
    return load_scene(str(path))


def test_a_box_on_its_face_comes_no_nearer_the_toe_than_its_top_edge_lets_it(tmp_path):
    """By hand: a cube lying on a face, pushed seaward until its top edge meets the zone's slope,
    has its foot that far from the design toe. Yawed, its section only widens landward."""
    scene = _cube_scene(tmp_path)
    zone, design = scene.tolerance, scene.design
    points, _, least, tried = least_distances(scene, random=0, refine=0)
    assert tried > 1  # yaws of the one rest pose (the cube's faces are alike)
    foot = zone.half_width(zone.z_bottom + 1.6)  # the zone's slope at the cube's top
    toe = np.argmin(np.hypot(points[:, 0] - design.bottom_half_width, points[:, 1] - design.z_bottom))
    assert abs(least[toe] - (design.bottom_half_width - foot)) < 1e-9
    assert least[toe] > 1.6  # further than H from the toe: the aim of max_bare_m cannot be met
    # The middle of the crest is within reach: a cube can stand on it.
    crest = np.argmin(np.hypot(points[:, 0], points[:, 1] - design.z_top))
    assert least[crest] == 0.0


def test_a_block_where_reach_allows_it_lies_in_the_zone_and_no_nearer_than_reach(mini, shake):
    reach = Reach(mini)
    points, _ = section_samples(mini)
    y = 0.5 * (mini.design.y_start + mini.design.y_end)
    world = np.column_stack([points[:, 0], np.full(len(points), y), points[:, 1]])
    q = np.random.default_rng(3).normal(size=(4, 4))
    for rotation in Rotation.from_quat(q / np.linalg.norm(q, axis=1)[:, None]):
        matrix = rotation.as_matrix()
        xz = np.concatenate([(p.vertices @ matrix.T)[:, [0, 2]] for p in shake.pieces])
        allowed = reach.allowed(xz)
        least = reach(matrix, points)
        centre = allowed.mean(axis=0)
        for corner in allowed:
            slack = reach.offsets - (xz @ reach.normals.T).max(axis=0) - reach.normals @ corner
            active = reach.normals[np.abs(slack) < 1e-9]
            assert len(active) >= 1
            out = active.sum(axis=0) / np.linalg.norm(active.sum(axis=0))
            quat = rotation.as_quat(scalar_first=True)
            for shift, inside in ((1e-3 * (centre - corner) / np.linalg.norm(centre - corner), True),
                                  (0.01 * out, False)):
                pose = Pose(np.array([corner[0] + shift[0], y, corner[1] + shift[1]]), quat)
                assert (outside_volume(shake, pose, mini.tolerance) == 0.0) == inside
                if inside:
                    assert (distance_to_block(world, shake, pose) >= least - 1e-9).all()


def test_nearest_skips_only_polygons_no_nearer_than_the_distance_so_far(mini):
    """The box test that spares most distance sums changes no distance: against every polygon
    measured in full, from a start that is infinite, zero, or in between."""
    reach = Reach(mini)
    points, _ = section_samples(mini)
    q = np.random.default_rng(5).normal(size=(12, 4))
    polygons = [p for r in Rotation.from_quat(q / np.linalg.norm(q, axis=1)[:, None]).as_matrix()
                for p in reach.swept(r)]
    assert len(polygons) > 12
    full = np.min([_polygon_distance(points, p) for p in polygons], axis=0)
    assert (full > 0).any() and (full == 0).any()
    np.testing.assert_array_equal(nearest(points, polygons), full)
    start = np.random.default_rng(6).uniform(0.0, 2.0 * full.max(), len(points))
    start[::7] = 0.0
    np.testing.assert_array_equal(nearest(points, polygons, start), np.minimum(full, start))


def test_scene_info_floor(tmp_path):
    _cube_scene(tmp_path)
    d = json.loads(shoha("scene", "info", str(tmp_path / "cubes.toml"), "--floor", "--json").stdout)
    floor = d["coverage_floor"]
    assert set(floor) == {"bare_share_percent", "max_bare_m", "worst_point", "toe_m", "orientations"}
    assert floor["bare_share_percent"] > 5.0 and floor["max_bare_m"] > 1.6
    text = shoha("scene", "info", "mini", "--floor").stdout
    assert "coverage floor: 0.0% of the slopes and crest" in text and "does not rule" in text
    assert "coverage_floor" not in json.loads(shoha("scene", "info", "mini", "--json").stdout)


def test_scene_info_floor_where_no_block_fits(tmp_path):
    """A mound too small for one Shake Block: every point is bare, no distance is finite, and
    ``--json`` gives null for them (JSON has no infinity) rather than failing."""
    path = tmp_path / "tiny.toml"
    path.write_text('block = "shake-4t"\n[design]\ncrest_width_m = 1.0\nheight_m = 1.0\n'
                    'slope_rise_run = [1.0, 1.0]\nlength_m = 2.0\n')
    r = shoha("scene", "info", str(path), "--floor", "--json")
    assert r.stderr == ""  # no warning from a local search over infinite distances
    floor = json.loads(r.stdout)["coverage_floor"]
    assert floor["bare_share_percent"] == 100.0
    assert floor["max_bare_m"] is None and floor["worst_point"] is None and floor["toe_m"] is None
    assert "no block fits inside the zone" in shoha("scene", "info", str(path), "--floor").stdout
