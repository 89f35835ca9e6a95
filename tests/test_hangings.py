"""Hangings from a block's own shape: its rest poses, whatever frame its file comes in."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

from geometry.blocks import get_block
from optimizer.search.hangings import BASE, families, hanging_of, symmetry
from tests.conftest import export_turned


def _profile(vertices: np.ndarray, q: np.ndarray) -> np.ndarray:
    """What a yaw cannot change: each hull vertex's height, and its distance from the vertical axis."""
    v = Rotation.from_quat(q, scalar_first=True).apply(vertices)
    v = v[ConvexHull(v).vertices]
    return np.sort(np.column_stack([v[:, 2] - v[:, 2].min(), np.hypot(v[:, 0], v[:, 1])]), axis=0)


@pytest.fixture(scope="module")
def turned(tmp_path_factory, shake):
    """The Shake Block exported, turned by an arbitrary rotation and moved off its centroid."""
    return get_block(f"mesh:{export_turned(shake, tmp_path_factory.mktemp('mesh') / 'turned.stl')}")


def test_a_turned_mesh_rests_the_ways_the_built_in_block_does(shake, turned):
    """Same rest poses, in the same order, up to a turn about the vertical and the block's symmetry."""
    assert len(turned.rest_poses) == len(shake.rest_poses) == 3
    for a, b in zip(shake.rest_poses, turned.rest_poses, strict=True):
        assert a.tip_deg == pytest.approx(b.tip_deg, abs=0.05)
        assert a.symmetry == b.symmetry
        np.testing.assert_allclose(_profile(shake.vertices, a.quaternion),
                                   _profile(turned.vertices, b.quaternion), atol=2e-3)
    # Its height is the built-in block's standing height, not its extent along its file's z.
    assert turned.height == pytest.approx(shake.height, rel=1e-6)
    assert np.ptp(turned.vertices[:, 2]) > shake.height + 0.1


def test_derived_hangings_are_the_crane_hangings_of_the_built_in_block(shake, turned):
    """rest-1, rest-2, rest-3 of the turned mesh are crown, level and horizontal, up to yaw."""
    assert families(shake) == ("crown", "level", "horizontal")
    assert families(turned) == ("rest-1", "rest-2", "rest-3")
    for name, derived in zip(("crown", "level", "horizontal"), families(turned), strict=True):
        np.testing.assert_allclose(_profile(shake.vertices, BASE[name]),
                                   _profile(turned.vertices, hanging_of(turned, derived, 0.4)), atol=2e-3)
        assert symmetry(shake, name) == symmetry(turned, derived)


@pytest.mark.parametrize("name, expected", [
    ("box:1.6x1.6x1.6", [(45.0, 4)]),
    ("box:2x1x0.8", [(51.3, 2), (38.7, 2), (21.8, 2)]),  # on its 2x1, 2x0.8 and 1x0.8 faces
    ("tetrapod:2", [(37.1, 3), (13.5, 3)]),  # on three legs, on one: conical legs give no edge to rest on
])
def test_rest_poses_of_simple_shapes(name, expected):
    poses = get_block(name).rest_poses
    assert [(round(p.tip_deg, 1), p.symmetry) for p in poses] == expected


def test_a_hanging_the_block_has_not_is_an_error(shake, cube):
    with pytest.raises(ValueError, match="no hanging"):
        hanging_of(cube, "crown", 0.0)
    with pytest.raises(ValueError, match="no hanging"):
        hanging_of(cube, "rest-2", 0.0)
    with pytest.raises(ValueError, match="no hanging"):  # int() reads "١" (Arabic-Indic one) as 1
        hanging_of(shake, "rest-\u0661", 0.0)
    hanging_of(shake, "rest-1", 0.0)


@pytest.mark.parametrize("name", ["shake-4t", "tetrapod:2", "box:2x1x0.8", "random hulls"])
def test_rest_poses_found_from_the_facets_under_the_centroid_are_those_of_every_facet(name, monkeypatch):
    """Facets whose triangles do not hold the centroid's foot are left out before their
    outline is drawn (a 5000-facet sphere took 2.2 s); the rest poses are the same as when
    every facet is drawn."""
    import trimesh

    import geometry.blocks as blocks

    rng = np.random.default_rng(7)
    solids = [get_block(name).vertices] if name != "random hulls" else [
        (m := trimesh.convex.convex_hull(rng.normal(size=(int(rng.integers(6, 80)), 3))
                                         * rng.uniform(0.3, 2.0, 3))).vertices - m.center_mass
        for _ in range(25)]
    for v in solids:
        found = blocks.rest_poses(v)
        with monkeypatch.context() as m:
            m.setattr(blocks, "_under_centroid", lambda hull, scale: np.ones(len(hull.simplices), bool))
            every = blocks.rest_poses(v)
        assert [(p.tip_deg, p.symmetry) for p in found] == [(p.tip_deg, p.symmetry) for p in every]
        for p, q in zip(found, every, strict=True):
            np.testing.assert_array_equal(p.quaternion, q.quaternion)
