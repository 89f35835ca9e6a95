"""Layout files: shoha-layout/1, validated at the boundary, lossless."""

from __future__ import annotations

import json

import numpy as np
import pytest

from geometry.errors import InputError
from geometry.layout import Layout, Placement, read_layout, write_layout
from geometry.pose import Pose
from geometry.samples import random_quaternion


def _layout(n: int = 5, seed: int = 0) -> Layout:
    rng = np.random.default_rng(seed)
    blocks = [Placement(i * 3 + 1, "shake-4t", Pose(rng.normal(size=3) * 5, random_quaternion(rng)))
              for i in range(n)]
    return Layout("mini", blocks, {"note": "kept", "generator": {"seed": seed}})


def test_round_trip_is_lossless(tmp_path):
    layout = _layout()
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    write_layout(layout, a)
    back = read_layout(a)
    write_layout(back, b)
    assert a.read_bytes() == b.read_bytes()
    for p, q in zip(layout.blocks, back.blocks, strict=True):
        assert p.id == q.id and p.type == q.type
        assert np.array_equal(p.pose.position, q.pose.position)
        assert np.array_equal(p.pose.quaternion, q.pose.quaternion)
    assert back.extra == {"note": "kept", "generator": {"seed": 0}}
    assert [p.id for p in back.blocks] == [1, 4, 7, 10, 13]  # order is installation order


def test_written_file_follows_the_contract(tmp_path):
    path = tmp_path / "l.json"
    write_layout(_layout(2), path)
    data = json.loads(path.read_text())
    assert data["format"] == "shoha-layout/1" and data["scene"] == "mini"
    assert set(data["blocks"][0]) == {"id", "type", "position", "quaternion"}


def test_session_times_are_read_and_written_back(tmp_path):
    """``time_s`` on blocks and ``elapsed_s`` on the save are optional, kept, and give the session's time."""
    layout = _layout(3)
    timed = Layout("mini", [Placement(p.id, p.type, p.pose, 30.0 * (i + 1)) for i, p in
                            enumerate(layout.blocks[:2])] + layout.blocks[2:], {"elapsed_s": 95})
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    write_layout(timed, a)
    data = json.loads(a.read_text())
    assert data["elapsed_s"] == 95
    assert [blk.get("time_s") for blk in data["blocks"]] == [30.0, 60.0, None]
    back = read_layout(a)
    assert [p.time_s for p in back.blocks] == [30.0, 60.0, None]
    assert back.session_seconds() == 95.0
    write_layout(back, b)
    assert a.read_bytes() == b.read_bytes()
    # Without elapsed_s, the latest block time; without any time, None.
    back.extra.pop("elapsed_s")
    assert back.session_seconds() == 60.0
    assert _layout(2).session_seconds() is None


def test_near_unit_quaternion_is_normalised(tmp_path):
    path = tmp_path / "q.json"
    path.write_text(json.dumps({"format": "shoha-layout/1", "scene": "mini", "blocks": [
        {"id": 0, "type": "shake-4t", "position": [0, 1, 2], "quaternion": [1.0000005, 0, 0, 0]}]}))
    q = read_layout(path).blocks[0].pose.quaternion
    np.testing.assert_allclose(np.linalg.norm(q), 1.0, atol=1e-15)


def _block(**over):
    b = {"id": 0, "type": "shake-4t", "position": [0.0, 1.0, 1.0], "quaternion": [1.0, 0.0, 0.0, 0.0]}
    b.update(over)
    return b


BAD = [
    ("{not json", "malformed JSON"),
    # json keeps the last of two keys: a save's first list of blocks was lost without a word.
    ('{"format": "shoha-layout/1", "scene": "mini", "blocks": [' + json.dumps(_block()) + '], "blocks": []}',
     "the key 'blocks' appears twice in one object"),
    ('{"format": "shoha-layout/1", "scene": "mini", "blocks": [{"id": 0, "type": "shake-4t", '
     '"position": [0, 1, 1], "position": [0, 5, 1], "quaternion": [1, 0, 0, 0]}]}',
     "the key 'position' appears twice"),
    ('{"format": "shoha-layout/1", "scene": "mini", "blocks": [{"id": 0, "type": "shake-4t", '
     '"position": [NaN, 0, 0], "quaternion": [1, 0, 0, 0]}]}', "NaN"),
    (json.dumps({"format": "shoha-layout/1", "scene": "mini", "blocks": [_block(quaternion=[0, 0, 0, 0])]}),
     "quaternion norm 0 is not 1"),
    (json.dumps({"format": "shoha-layout/1", "scene": "mini", "blocks": [_block(quaternion=[0.9, 0, 0, 0])]}),
     "quaternion norm 0.9 is not 1"),
    (json.dumps({"format": "shoha-layout/1", "scene": "mini", "blocks": [_block(type="brick")]}),
     "unknown block type"),
    (json.dumps({"format": "shoha-layout/1", "scene": "mini", "blocks": [_block(), _block()]}),
     "duplicate id"),
    (json.dumps({"format": "shoha-layout/1", "scene": "mini", "blocks": [_block(colour="red")]}),
     "unknown key 'colour'"),
    (json.dumps({"format": "shoha-layout/1", "scene": "mini", "blocks": [_block(id=-1)]}), "id must be"),
    # Times of a training session (docs/contract.md): finite, non-negative seconds.
    (json.dumps({"format": "shoha-layout/1", "scene": "mini", "blocks": [_block(time_s=-0.5)]}),
     "time_s must be a finite, non-negative"),
    (json.dumps({"format": "shoha-layout/1", "scene": "mini", "blocks": [_block(time_s="12")]}),
     "time_s must be a number"),
    (json.dumps({"format": "shoha-layout/1", "scene": "mini", "blocks": [_block(time_s=True)]}),
     "time_s must be a number"),
    ('{"format": "shoha-layout/1", "scene": "mini", "blocks": [{"id": 0, "type": "shake-4t", '
     '"position": [0, 1, 1], "quaternion": [1, 0, 0, 0], "time_s": Infinity}]}', "Infinity"),
    (json.dumps({"format": "shoha-layout/1", "scene": "mini", "elapsed_s": -1, "blocks": []}),
     "elapsed_s must be a finite, non-negative"),
    (json.dumps({"format": "shoha-layout/1", "scene": "mini", "elapsed_s": None, "blocks": []}),
     "elapsed_s must be a number"),
    (json.dumps({"format": "shoha-layout/1", "scene": "mini", "elapsed_s": 10,
                 "blocks": [_block(time_s=12.5)]}), "elapsed_s 10 is earlier than block 0's time_s 12.5"),
    (json.dumps({"format": "shoha-layout/1", "scene": "mini", "blocks": [_block(id=True)]}), "id must be"),
    (json.dumps({"format": "shoha-layout/1", "scene": "mini", "blocks": [_block(position=[0, 1])]}),
     "position must be"),
    (json.dumps({"format": "shoha-layout/1", "scene": "mini", "blocks": [_block(position=["0", 1, 2])]}),
     "position must be"),
    (json.dumps({"format": "shoha-layout/1", "scene": "mini", "blocks": [_block(position=[1e300, 1, 2])]}),
     "from the origin"),
    (json.dumps({"format": "shoha-layout/1", "scene": "mini", "blocks": {}}), "blocks must be a list"),
    (json.dumps({"format": "shoha-layout/2", "scene": "mini", "blocks": []}), "format must be"),
    (json.dumps({"format": "shoha-layout/1", "blocks": []}), "scene must be"),
    (json.dumps([1, 2, 3]), "JSON object"),
    (json.dumps({"format": "shoha-layout/1", "scene": "mini", "blocks": [{}] * 100_001}), "more than 100000"),
    ("[" * 100_000 + "]" * 100_000, "nested too deeply"),
    # An integer no float holds passes every type check as an int, then overflows in arithmetic.
    (json.dumps({"format": "shoha-layout/1", "scene": "mini", "blocks": [_block(position=[10**400, 1, 1])]}),
     "401 digits is too large"),
    # 309 digits pass the count of digits, and 9...9 (1e309) is still past the largest float: a
    # quaternion or a time of it gave exit 1 in every verb that reads a layout.
    (json.dumps({"format": "shoha-layout/1", "scene": "mini",
                 "blocks": [_block(quaternion=[int("9" * 309), 0, 0, 1])]}),
     "309 digits is too large for a float"),
]


@pytest.mark.parametrize("text, message", BAD, ids=[m for _, m in BAD])
def test_bad_layouts_are_input_errors(tmp_path, text, message):
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(InputError, match=message) as info:
        read_layout(path)
    assert str(path) in str(info.value)
    assert "\n" not in str(info.value)


def test_missing_and_binary_files(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_layout(tmp_path / "nope.json")
    path = tmp_path / "bin.json"
    path.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(InputError):
        read_layout(path)


def test_mesh_type_resolves_relative_to_the_layout(tmp_path, shake):
    (tmp_path / "meshes").mkdir()
    shake.export(tmp_path / "meshes" / "b.stl")
    path = tmp_path / "l.json"
    path.write_text(json.dumps({"format": "shoha-layout/1", "scene": "mini",
                                "blocks": [_block(type="mesh:meshes/b.stl")]}))
    (_, block, _), = read_layout(path).placed()
    np.testing.assert_allclose(block.volume, shake.volume, rtol=1e-5)


def test_a_mesh_layout_written_to_another_folder_still_finds_its_mesh(tmp_path, shake):
    (tmp_path / "here" / "meshes").mkdir(parents=True)
    (tmp_path / "there").mkdir()
    shake.export(tmp_path / "here" / "meshes" / "b.stl")
    source = tmp_path / "here" / "l.json"
    source.write_text(json.dumps({"format": "shoha-layout/1", "scene": "mini",
                                  "blocks": [_block(type="mesh:meshes/b.stl")]}))
    layout = read_layout(source)
    for out in (tmp_path / "there" / "l.json", tmp_path / "here" / "again.json"):
        write_layout(layout, out)
        (_, block, _), = read_layout(out).placed()
        np.testing.assert_allclose(block.volume, shake.volume, rtol=1e-5)
    # Written beside the original, the type is the same text as before.
    def written(name: str) -> str:
        return json.loads((tmp_path / name).read_text())["blocks"][0]["type"]

    assert written("here/again.json") == "mesh:meshes/b.stl"
    assert written("there/l.json") == "mesh:../here/meshes/b.stl"


@pytest.mark.parametrize("spread", [0.0, 2.0])
def test_a_layout_of_blocks_one_inside_another_is_refused_on_reading(tmp_path, spread):
    """300 copies of one pose (every check grew with the square of the count: ``shoha check``
    took 13 s, and 100 000 copies ran it out of memory), or 300 blocks in a cube twice the
    reach across (about 150 within reach of each, where 84 Shake Blocks fit)."""
    from geometry.blocks import get_block

    reach = 2.0 * get_block("shake-4t").bounding_radius
    rng = np.random.default_rng(0)
    centre = np.array([0.0, 6.0, 3.0])
    blocks = [_block(id=i, position=list(centre + spread * reach * (rng.random(3) - 0.5)))
              for i in range(300)]
    path = tmp_path / "heap.json"
    path.write_text(json.dumps({"format": "shoha-layout/1", "scene": "mini", "blocks": blocks}))
    said = r"heap.json: block \d+ has \d+ blocks within reach, more than the 84"
    with pytest.raises(InputError, match=said):
        read_layout(path)
    # The same blocks spread along the mound are a layout (with collisions, for check to report).
    for i, b in enumerate(blocks):
        b["position"] = [0.0, 0.5 * i, 3.0]
    path.write_text(json.dumps({"format": "shoha-layout/1", "scene": "mini", "blocks": blocks}))
    assert len(read_layout(path).blocks) == 300


def _heap(tmp_path, types, copies):
    """A layout of ``copies`` blocks of each type in ``types``, every one at one pose."""
    blocks = [_block(id=i * copies + j, type=kind, position=[0.0, 6.0, 3.0])
              for i, kind in enumerate(types) for j in range(copies)]
    path = tmp_path / "heap.json"
    path.write_text(json.dumps({"format": "shoha-layout/1", "scene": "mini", "blocks": blocks}))
    return path


def test_one_block_under_several_names_is_one_block_in_the_crowding_check(tmp_path):
    """tetrapod:2, tetrapod:02 and tetrapod:2.0 are one shape: 150 copies of one pose, 50 under
    each name, are refused as 150 of one block would be (113 tetrapods fit within reach)."""
    with pytest.raises(InputError, match=r"has 149 blocks within reach, more than the 113"):
        read_layout(_heap(tmp_path, ["tetrapod:2", "tetrapod:02", "tetrapod:2.0"], 50))


def test_blocks_of_many_sizes_in_one_place_are_refused(tmp_path):
    """Sixteen tetrapod sizes, ten copies each, at one pose: no size alone is crowded, all
    together are; and more than sixteen types are refused before any is built (1500 sizes
    held shoha check for minutes)."""
    sizes = [f"tetrapod:{2.0 + 0.001 * i:.3f}" for i in range(16)]
    with pytest.raises(InputError, match=r"m3 of blocks no larger than it within reach, more than"):
        read_layout(_heap(tmp_path, sizes, 10))
    with pytest.raises(InputError, match=r"heap.json: 17 block types, more than 16"):
        read_layout(_heap(tmp_path, sizes + ["tetrapod:3"], 1))
    # Two sizes side by side along the mound, as a layout of two block types may be, are read.
    blocks = [_block(id=i, type=sizes[i % 2], position=[0.0, 1.5 * i, 3.0]) for i in range(40)]
    path = tmp_path / "two.json"
    path.write_text(json.dumps({"format": "shoha-layout/1", "scene": "mini", "blocks": blocks}))
    assert len(read_layout(path).blocks) == 40


def test_an_integer_no_float_holds_is_not_a_finite_number():
    """Numbers from a TOML file or a caller are not bounded by the JSON reader: an int past the
    largest float is refused as not finite, not met with an OverflowError (exit 1)."""
    from geometry.errors import finite_number
    from settle.base import Thresholds

    assert finite_number(1) and finite_number(-2.5) and finite_number(10**308)
    refused = (10**309, -(10**400), float("nan"), float("inf"), True, "1", None)
    assert not any(finite_number(v) for v in refused)
    with pytest.raises(InputError, match=r"rotation_deg must be a non-negative number, not 1{37}\.\.\."):
        Thresholds(rotation_deg=int("1" * 400))
