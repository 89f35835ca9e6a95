"""Simulator saves: Unity's left-handed, y-up frame to shoha's world frame."""

from __future__ import annotations

import json

import numpy as np
import pytest

from geometry.errors import InputError
from geometry.pose import quat_to_matrix
from geometry.unity import SWAP_YZ, read_unity_save


def _unity_matrix(x, y, z, w):
    """Unity's Quaternion -> Matrix4x4 (the same algebra as Hamilton's)."""
    return quat_to_matrix([w, x, y, z])


def test_hand_computed_transform(tmp_path):
    # A block 90 degrees about Unity's up axis (y), at Unity (1, 0.9, 2).
    s, c = np.sin(np.pi / 4), np.cos(np.pi / 4)
    save = {"blocks": [{"type": "shake-4t", "position": {"x": 1.0, "y": 0.9, "z": 2.0},
                        "rotation": {"x": 0.0, "y": s, "z": 0.0, "w": c}}]}
    path = tmp_path / "save.json"
    path.write_text(json.dumps(save))
    layout = read_unity_save(path, origin=(10.0, 20.0, 0.5))
    (p,) = layout.blocks
    # Position: (x, z, y) + origin, by hand.
    np.testing.assert_allclose(p.pose.position, [11.0, 22.0, 1.4], atol=1e-12)
    # Rotation: turning about Unity's up (+y) is turning about world up (+z) the other way,
    # because Unity's frame is left-handed: R_world = Rz(-90 deg).
    rz = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(p.pose.rotation, rz, atol=1e-12)


def test_matches_contract_matrix_formula_for_random_rotations(tmp_path):
    rng = np.random.default_rng(5)
    blocks = []
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        blocks.append({"position": dict(zip("xyz", rng.normal(size=3), strict=True)),
                       "rotation": dict(zip("xyzw", q, strict=True))})
    path = tmp_path / "save.json"
    path.write_text(json.dumps({"blocks": blocks}))
    layout = read_unity_save(path)
    for raw, p in zip(blocks, layout.blocks, strict=True):
        r = raw["rotation"]
        expected = SWAP_YZ @ _unity_matrix(r["x"], r["y"], r["z"], r["w"]) @ SWAP_YZ
        np.testing.assert_allclose(p.pose.rotation, expected, atol=1e-12)
        assert np.linalg.det(p.pose.rotation) == pytest.approx(1.0)
        # A block's "up" leg, local +y in Unity, is local +z in shoha; both point the same way.
        up_unity = _unity_matrix(r["x"], r["y"], r["z"], r["w"]) @ [0.0, 1.0, 0.0]
        np.testing.assert_allclose(p.pose.rotation @ [0.0, 0.0, 1.0], SWAP_YZ @ up_unity, atol=1e-12)
    assert [p.id for p in layout.blocks] == list(range(20))
    assert all(p.type == "shake-4t" for p in layout.blocks)


def test_times_are_kept(tmp_path):
    """A save's ``time_s`` per block and ``elapsed_s`` come through to the layout (docs/contract.md)."""
    still = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
    save = {"elapsed_s": 120.5, "blocks": [
        {"position": {"x": 0.0, "y": 0.9, "z": 2.0}, "rotation": still, "time_s": 41.0},
        {"position": {"x": 2.0, "y": 0.9, "z": 2.0}, "rotation": still}]}
    path = tmp_path / "save.json"
    path.write_text(json.dumps(save))
    layout = read_unity_save(path)
    assert [p.time_s for p in layout.blocks] == [41.0, None]
    assert layout.extra == {"elapsed_s": 120.5} and layout.session_seconds() == 120.5
    assert [b.get("time_s") for b in layout.to_dict()["blocks"]] == [41.0, None]


@pytest.mark.parametrize("save, message", [
    ({"blocks": [{"position": {"x": 0, "y": 0}, "rotation": {"x": 0, "y": 0, "z": 0, "w": 1}}]},
     "position.z"),
    ({"blocks": [{"position": {"x": 0, "y": 0, "z": 0}, "rotation": {"x": 0, "y": 0, "z": 0, "w": 0}}]},
     "norm 0 is not 1"),
    ({"blocks": [{"type": "tetrapodd", "position": {"x": 0, "y": 0, "z": 0},
                  "rotation": {"x": 0, "y": 0, "z": 0, "w": 1}}]}, "unknown block type"),
    ({"blockz": []}, "blocks"),
    ({"blocks": [{"position": {"x": "1", "y": 0, "z": 0}, "rotation": {"x": 0, "y": 0, "z": 0, "w": 1}}]},
     "must be a number"),
    ({"blocks": [{"position": {"x": 0, "y": 0, "z": 0}, "rotation": {"x": 0, "y": 0, "z": 0, "w": 1},
                  "time_s": -3}]}, "time_s must be a finite, non-negative"),
    ({"blocks": [{"position": {"x": 0, "y": 0, "z": 0}, "rotation": {"x": 0, "y": 0, "z": 0, "w": 1},
                  "time_s": [1]}]}, "time_s must be a number"),
    ({"elapsed_s": "late", "blocks": []}, "elapsed_s must be a number"),
    ({"elapsed_s": 5, "blocks": [{"position": {"x": 0, "y": 0, "z": 0},
                                  "rotation": {"x": 0, "y": 0, "z": 0, "w": 1}, "time_s": 7}]},
     "earlier than block 0's time_s 7"),
    # As a layout's: a save at 1e308 m scored with exit 1 (overflow in the coverage's tree).
    ({"blocks": [{"position": {"x": 1e308, "y": 1e308, "z": 2},
                  "rotation": {"x": 0, "y": 0, "z": 0, "w": 1}}]},
     "position is more than 1e\\+06 m from the origin"),
    ({"blocks": [{"position": {"x": 0, "y": 0, "z": 0},
                  "rotation": {"x": 1e200, "y": 1e200, "z": 0, "w": 0}}]},
     "norm inf is not 1"),
])
def test_bad_saves(tmp_path, save, message):
    path = tmp_path / "save.json"
    path.write_text(json.dumps(save))
    with pytest.raises(InputError, match=message):
        read_unity_save(path)


def test_a_save_of_blocks_one_inside_another_is_refused(tmp_path):
    block = {"position": {"x": 0.0, "y": 3.0, "z": 6.0}, "rotation": {"x": 0, "y": 0, "z": 0, "w": 1}}
    path = tmp_path / "heap.json"
    path.write_text(json.dumps({"blocks": [block] * 100}))
    with pytest.raises(InputError, match="heap.json: block 0 has 99 blocks within reach"):
        read_unity_save(path)
    # Under several names of one block, or of many sizes, they are refused all the same.
    names = [{**block, "type": kind} for kind in ("tetrapod:2", "tetrapod:2.0", "tetrapod:02")]
    path.write_text(json.dumps({"blocks": names * 50}))
    with pytest.raises(InputError, match="heap.json: block 0 has 149 blocks within reach"):
        read_unity_save(path)
    sizes = [{**block, "type": f"tetrapod:{2.0 + 0.001 * i:.3f}"} for i in range(17)]
    path.write_text(json.dumps({"blocks": sizes}))
    with pytest.raises(InputError, match="heap.json: 17 block types, more than 16"):
        read_unity_save(path)
