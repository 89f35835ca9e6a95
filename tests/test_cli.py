"""The shoha command line, run as a user runs it (docs/contract.md, "CLI")."""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path

import pytest
import trimesh

from geometry.layout import Layout, Placement, write_layout
from geometry.samples import random_inside
from tests.conftest import ROOT, shoha


@pytest.fixture(scope="module")
def layout25(tmp_path_factory, mini, shake):
    path = tmp_path_factory.mktemp("cli") / "l25.json"
    placed = random_inside(shake, mini.design, 25, seed=16)
    write_layout(Layout("mini", [Placement(k, "shake-4t", p) for k, _, p in placed]), path)
    return path


def _json(result):
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


def test_help_is_quick_and_lists_commands():
    r = shoha("--help")
    assert r.returncode == 0
    for verb in ("block", "scene", "convert", "porosity", "check"):
        assert verb in r.stdout


def test_block_info_meets_table_i():
    d = _json(shoha("block", "info", "shake-4t", "--json"))
    assert set(d) >= {"name", "volume_m3", "surface_area_m2", "height_m", "mass_t", "convex_pieces"}
    assert abs(d["volume_m3"] / 1.735 - 1) < 0.005 and abs(d["surface_area_m2"] / 9.796 - 1) < 0.005


def test_block_export(tmp_path):
    out = tmp_path / "b.glb"
    d = _json(shoha("block", "export", "tetrapod", "--out", str(out), "--json"))
    assert d["path"] == str(out) and trimesh.load(out, force="mesh").is_watertight


def test_scene_info_and_export(tmp_path):
    d = _json(shoha("scene", "info", "mini", "--json"))
    assert set(d) >= {"name", "block", "design_volume_m3", "tolerance_volume_m3", "required_blocks",
                      "target_porosity_percent"}
    assert d["required_blocks"] == 75 and abs(d["design_volume_m3"] - 293.3) < 1e-9
    d = _json(shoha("scene", "export", "mini", "--out", str(tmp_path / "m"), "--json"))
    meshes = [trimesh.load(p) for p in d["paths"]]
    assert [Path(p).name for p in d["paths"]] == ["design.stl", "tolerance.stl", "foundation.stl"]
    assert all(m.is_watertight for m in meshes)
    assert abs(meshes[0].volume - 293.3) < 1e-3


@pytest.mark.parametrize("method, divisions", [("exact", None), ("voxel", "100"), ("voxel-any", "50")])
def test_porosity_keys(layout25, method, divisions):
    args = ["porosity", str(layout25), "--method", method, "--json"]
    if divisions:
        args += ["--divisions", divisions]
    d = _json(shoha(*args))
    assert set(d) >= {"porosity_percent", "method", "divisions", "blocks", "design_volume_m3", "seconds"}
    assert d["blocks"] == 25 and d["method"] == method
    if method == "exact":
        assert round(d["porosity_percent"], 2) == 85.21


def test_check_keys(layout25):
    d = _json(shoha("check", str(layout25), "--json"))
    assert set(d) >= {"blocks", "required_blocks", "remaining_blocks", "out_of_tolerance", "collisions",
                      "porosity_percent"}
    assert (d["blocks"], d["required_blocks"], d["remaining_blocks"]) == (25, 75, 50)
    assert d["out_of_tolerance"] == [] and d["collisions"] == []


def test_check_reports_faults(tmp_path, colliding_pair, protruding_block):
    path = tmp_path / "f.json"
    blocks = [Placement(k, "box:1x1x1", p) for k, _, p in colliding_pair]
    blocks.append(Placement(7, "shake-4t", protruding_block[2]))
    write_layout(Layout("mini", blocks), path)
    d = _json(shoha("check", str(path), "--json"))
    assert [(c["a"], c["b"]) for c in d["collisions"]] == [(0, 1)]
    assert abs(d["collisions"][0]["depth_m"] - 0.2) < 1e-6
    assert [o["id"] for o in d["out_of_tolerance"]] == [7]
    assert d["out_of_tolerance"][0]["outside_volume_m3"] > 0


def test_convert_unity_save(tmp_path):
    save = tmp_path / "save.json"
    save.write_text(json.dumps({"blocks": [{"position": {"x": 1, "y": 2, "z": 3},
                                            "rotation": {"x": 0, "y": 0, "z": 0, "w": 1}}]}))
    out = tmp_path / "l.json"
    d = _json(shoha("convert", str(save), "--from", "unity", "--out", str(out), "--origin", "1,0,0",
                    "--json"))
    assert d == {"blocks": 1, "path": str(out)}
    block = json.loads(out.read_text())["blocks"][0]
    assert block["position"] == [2.0, 3.0, 2.0] and block["type"] == "shake-4t"


def test_convert_names_a_scene_file_relative_to_the_layout(tmp_path):
    (tmp_path / "scenes").mkdir()
    (tmp_path / "out").mkdir()
    scene = tmp_path / "scenes" / "s.toml"
    scene.write_text((ROOT / "tests" / "data" / "tiny.toml").read_text())
    save = tmp_path / "save.json"
    save.write_text(json.dumps({"blocks": []}))
    out = tmp_path / "out" / "l.json"
    r = shoha("convert", str(save), "--from", "unity", "--out", str(out), "--scene", "scenes/s.toml",
              cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert json.loads(out.read_text())["scene"] == "../scenes/s.toml"
    assert shoha("check", str(out), cwd=tmp_path / "out").returncode == 0


def _broken_stl(tmp_path):
    mesh = trimesh.creation.box([1, 1, 1])
    mesh.update_faces([True] * (len(mesh.faces) - 1) + [False])
    path = tmp_path / "open.stl"
    mesh.export(path)
    return path


def _layout_text(**block):
    b = {"id": 0, "type": "shake-4t", "position": [0.0, 1.0, 1.0], "quaternion": [1.0, 0.0, 0.0, 0.0]}
    b.update(block)
    return json.dumps({"format": "shoha-layout/1", "scene": "mini", "blocks": [b]})


BAD_LAYOUTS = {
    "malformed JSON": "{\"format\": ",
    "NaN": _layout_text().replace("0.0, 1.0, 1.0", "NaN, 1.0, 1.0"),
    "quaternion norm 0": _layout_text(quaternion=[0, 0, 0, 0]),
    "unknown block type": _layout_text(type="dolos"),
    "duplicate ids": json.dumps({"format": "shoha-layout/1", "scene": "mini", "blocks": [
        json.loads(_layout_text())["blocks"][0]] * 2}),
    "wrong types": _layout_text(position="here"),
    "unknown scene": _layout_text().replace('"mini"', '"atlantis"'),
}


def _assert_bad(r, name_in_message):
    assert r.returncode == 2, (r.returncode, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert "Traceback" not in r.stderr and name_in_message in lines[0]
    assert r.stdout == ""


@pytest.mark.parametrize("case", list(BAD_LAYOUTS))
@pytest.mark.parametrize("verb", ["porosity", "check"])
def test_bad_layouts_exit_2_with_one_line(tmp_path, case, verb):
    path = tmp_path / "bad.json"
    path.write_text(BAD_LAYOUTS[case])
    # The message names the file, and for a scene it names that does not load, the scene too.
    _assert_bad(shoha(verb, str(path), "--json"),
                "bad.json" if case != "unknown scene" else "bad.json: atlantis: no such scene")


def test_missing_file_exits_2(tmp_path):
    _assert_bad(shoha("porosity", str(tmp_path / "none.json")), "none.json")


def test_non_watertight_mesh_exits_2(tmp_path):
    path = _broken_stl(tmp_path)
    _assert_bad(shoha("block", "info", f"mesh:{path}", "--json"), "open.stl")
    lay = tmp_path / "lay.json"
    lay.write_text(_layout_text(type=f"mesh:{path}"))
    _assert_bad(shoha("check", str(lay)), "open.stl")


def _sparse(path, size):
    """A file of ``size`` bytes that takes no disk (a hole): a mesh file too big to read."""
    with open(path, "wb") as f:
        f.truncate(size)


def _one_triangle_stl(path):
    trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False).export(path)


@pytest.mark.parametrize("block, make, said", [
    # Bytes that are neither binary nor ASCII STL: the message says so, not what trimesh tripped on.
    ("mesh:junk.stl", lambda d: (d / "junk.stl").write_bytes(bytes(range(256)) * 4),
     "not an STL file"),
    ("mesh:junk.obj", lambda d: (d / "junk.obj").write_bytes(bytes(range(256)) * 4),
     "mesh has no triangles"),
    ("mesh:empty.stl", lambda d: (d / "empty.stl").write_bytes(b""), "the mesh file is empty"),
    ("mesh:tri.stl", lambda d: _one_triangle_stl(d / "tri.stl"), "1 triangle(s)"),
    ("mesh:.", lambda d: None, "is a folder, not a file"),
    ("mesh:pipe.stl", lambda d: os.mkfifo(d / "pipe.stl"), "not a regular file"),
    ("mesh:big.stl", lambda d: _sparse(d / "big.stl", 300 * 2**20), "more than 268435456"),
    ("tetrapod:0.01", lambda d: None, "between 0.05 and 100 m"),
    ("tetrapod:", lambda d: None, "between 0.05 and 100 m"),
    # A mesh in millimetres read as metres: a 2 km block, not a 2 m one.
    ("mesh:mm.stl", lambda d: trimesh.creation.box([2000.0, 1500.0, 1000.0]).export(d / "mm.stl"),
     "the block is 2000 m across, and blocks are 0.05 to 100 m (mesh files are read in metres"),
])
def test_a_scene_with_a_bad_block_names_the_scene_file_and_the_problem(tmp_path, block, make, said):
    make(tmp_path)
    scene = tmp_path / "own.toml"
    scene.write_text(f'block = "{block}"\n[design]\ncrest_width_m = 4.0\nheight_m = 3.0\n'
                     'slope_rise_run = [3.0, 4.0]\nlength_m = 12.0\n')
    r = shoha("scene", "info", str(scene), "--json")
    _assert_bad(r, "own.toml")
    assert f"block = '{block}'" in r.stderr and said in r.stderr
    assert "ModuleNotFoundError" not in r.stderr and r.stderr.count("block type") == 0


def test_a_save_is_not_converted_over_itself(tmp_path):
    save = tmp_path / "save.json"
    text = json.dumps({"blocks": [{"position": {"x": 0.0, "y": 1.0, "z": 3.0},
                                   "rotation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}]})
    save.write_text(text)
    (tmp_path / "sub").mkdir()
    for out in (save, tmp_path / "sub" / ".." / "save.json"):
        _assert_bad(shoha("convert", str(save), "--from", "unity", "--out", str(out)), "is the SAVE itself")
    assert save.read_text() == text


def test_no_command_writes_over_its_own_input(tmp_path):
    """``--out`` naming a file the command reads (the scene, the block's mesh, the layout) is
    refused before any work, and that file is left as it was: writing it would destroy it."""
    mesh = tmp_path / "m" / "block.stl"
    mesh.parent.mkdir()
    assert shoha("block", "export", "box:1.6x1.6x1.6", "--out", str(mesh)).returncode == 0
    scene = tmp_path / "own.toml"
    scene.write_text('block = "mesh:m/block.stl"\n[design]\ncrest_width_m = 4.0\nheight_m = 3.0\n'
                     'slope_rise_run = [3.0, 4.0]\nlength_m = 4.0\n')
    layout = tmp_path / "layout.json"
    layout.write_text((ROOT / "tests" / "data" / "mini-reference.json").read_text())
    before = {p: p.read_bytes() for p in (mesh, scene, layout)}
    (tmp_path / "sub").mkdir()
    cases = [
        (("optimize", str(scene), "--out", str(scene), "--time-limit", "5"), "is the scene file"),
        (("optimize", str(scene), "--out", str(tmp_path / "sub" / ".." / "own.toml"), "--time-limit", "5"),
         "is the scene file"),
        (("optimize", str(scene), "--out", str(mesh), "--time-limit", "5"), "is the block's mesh"),
        (("block", "export", f"mesh:{mesh}", "--out", str(mesh)), "is the block's own mesh"),
        (("settle", str(layout), "--out", str(layout)), "is the layout settled"),
    ]
    # A layout to keep that names a copy of the scene: that copy was read too.
    copy = tmp_path / "copy.toml"
    copy.write_text(scene.read_text())
    partial = tmp_path / "partial.json"
    partial.write_text('{"format": "shoha-layout/1", "scene": "copy.toml", "blocks": []}')
    before.update({copy: copy.read_bytes(), partial: partial.read_bytes()})
    cases.append((("optimize", str(scene), "--keep", str(partial), "--out", str(copy), "--time-limit", "5"),
                  "is the scene file of the --keep layout"))
    for args, said in cases:
        _assert_bad(shoha(*args), said)
    assert {p: p.read_bytes() for p in before} == before
    # A built-in scene's name is not the file of that name beside it: that one was not read.
    (tmp_path / "mini").write_text("notes")
    r = shoha("optimize", "mini", "--out", "mini", "--time-limit", "3", cwd=tmp_path)
    assert r.returncode == 0, r.stderr


def test_bad_save_writes_nothing(tmp_path):
    save = tmp_path / "save.json"
    save.write_text(json.dumps({"blocks": [{"position": {"x": 1, "y": 2, "z": 3},
                                            "rotation": {"x": 0, "y": 0, "z": 0, "w": 0}}]}))
    out = tmp_path / "out.json"
    _assert_bad(shoha("convert", str(save), "--from", "unity", "--out", str(out)), "save.json")
    assert not out.exists() and list(tmp_path.iterdir()) == [save]


@pytest.mark.parametrize("args, word", [
    (["porosity"], "LAYOUT"),
    (["porosity", "x.json", "--method", "magic"], "magic"),
    (["porosity", "x.json", "--divisions", "0"], "divisions"),
    (["convert", "s.json", "--out", "o.json"], "--from"),
    (["convert", "s.json", "--from", "unity", "--out", "o.json", "--origin", "1,2"], "origin"),
    (["convert", "s.json", "--from", "unity", "--out", "o.json", "--origin", "1_0,2,3"], "origin"),
    (["convert", "s.json", "--from", "unity", "--out", "o.json", "--block", "dolos"],
     "--block dolos: unknown block type"),
    (["score", "s.json", "--reference", "s.json", "--block", "mesh:none.stl"], "--block mesh:"),
    (["frobnicate"], "frobnicate"),
    # How to read a kept save, with no save to keep: taken and ignored, exit 0.
    (["optimize", "mini", "--out", "o.json", "--origin", "1,2,3"], "--origin: says how to read the --keep"),
    (["optimize", "mini", "--out", "o.json", "--block", "tetrapod"], "--block: says how to read the --keep"),
    (["optimize", "mini", "--out", "o.json", "--from", "unity"], "--from: says how to read the --keep"),
])
def test_bad_usage_exits_2_with_one_line(tmp_path, args, word):
    (tmp_path / "s.json").write_text('{"blocks": []}')
    _assert_bad(shoha(*args, cwd=tmp_path), word)


def test_a_refusal_that_overflows_on_the_way_is_still_one_line():
    """A voxel of 1e-320 m overflows numpy's division before the grid is refused: its warning,
    with its source line, came above the refusal (three lines on stderr)."""
    reference = str(ROOT / "tests" / "data" / "mini-reference.json")
    _assert_bad(shoha("porosity", reference, "--method", "voxel", "--voxel-size", "1e-320"), "voxel size")


def test_wheel_holds_exactly_the_three_packages(tmp_path):
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
                        "-w", str(tmp_path), str(ROOT)], capture_output=True, text=True, timeout=300)
    if r.returncode != 0 and "setuptools" in r.stderr:
        r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-w", str(tmp_path),
                            str(ROOT)],
                           capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    (wheel,) = tmp_path.glob("shoha-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    top = {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}
    assert top == {"geometry", "settle", "optimizer"}
    assert "geometry/scenes/mini.toml" in names


def test_optimize_refuses_a_section_scene_naming_its_file(tmp_path):
    section = tmp_path / "slice.toml"
    section.write_text((ROOT / "geometry" / "scenes" / "mini-section.toml").read_text())
    r = shoha("optimize", str(section), "--out", str(tmp_path / "out.json"), "--time-limit", "3")
    _assert_bad(r, str(section))
    assert "a section scene is a 2D slice" in r.stderr and not (tmp_path / "out.json").exists()


def test_paths_the_system_refuses_exit_2_with_one_line(tmp_path):
    """A name too long for the file system, a loop of links, a device or a pipe: refused
    with one line naming it, and nothing written (a device or pipe is never read: /dev/zero
    reports no size and never ends, a pipe with no writer blocks its reader)."""
    good = tmp_path / "good.json"
    good.write_text(_layout_text())
    long_out = tmp_path / ("a" * 300 + ".stl")
    _assert_bad(shoha("block", "export", "shake-4t", "--out", str(long_out)), "File name too long")
    _assert_bad(shoha("scene", "info", str(tmp_path / ("b" * 300 + ".toml"))), "File name too long")
    (tmp_path / "loop1.json").symlink_to(tmp_path / "loop2.json")
    (tmp_path / "loop2.json").symlink_to(tmp_path / "loop1.json")
    _assert_bad(shoha("settle", str(good), "--out", str(tmp_path / "loop1.json")), "loop1.json")
    _assert_bad(shoha("check", "/dev/zero"), "not a regular file")
    os.mkfifo(tmp_path / "pipe.json")
    _assert_bad(shoha("check", str(tmp_path / "pipe.json"), timeout=60), "not a regular file")
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["good.json", "loop1.json", "loop2.json", "pipe.json"]


@pytest.mark.parametrize("verb, suffix", [
    (["convert", "{good}", "--from", "unity", "--out"], ".json"),
    (["settle", "{good}", "--seconds", "0.1", "--out"], ".json"),
    (["render", "{good}", "--out"], ".png"),
    (["score", "{good}", "--reference", "{good}", "--html"], ".html"),
    (["block", "export", "shake-4t", "--out"], ".stl"),
    (["scene", "export", "mini", "--out"], ""),
])
def test_an_output_that_is_a_pipe_is_refused_and_left_a_pipe(tmp_path, verb, suffix):
    """Outputs are written by a rename over the path: over a device or a pipe that would put a
    file in its place (as root, ``--out /dev/null`` replaced the machine's /dev/null)."""
    good = tmp_path / "good.json"
    if verb[0] == "convert":
        good.write_text(json.dumps({"blocks": [{"position": {"x": 0.0, "y": 1.0, "z": 3.0},
                                                "rotation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}]}))
    else:
        good.write_text(_layout_text())
    target = tmp_path / f"pipe{suffix}"
    if suffix:
        os.mkfifo(target)
        out = target
    else:  # scene export writes a folder of meshes: one of them is the pipe
        target.mkdir()
        os.mkfifo(target / "foundation.stl")
        out = target
    r = shoha(*[a.format(good=good) for a in verb], str(out), timeout=120)
    _assert_bad(r, "not a regular file")
    for p in [target] if suffix else list(target.iterdir()):
        assert p.is_fifo() or p.is_dir(), p
    assert not suffix or sorted(q.name for q in tmp_path.iterdir()) == sorted(["good.json", target.name])
    if not suffix:
        assert [q.name for q in target.iterdir()] == ["foundation.stl"]


def test_a_deeply_nested_scene_file_exits_2_with_one_line(tmp_path):
    scene = tmp_path / "deep.toml"
    scene.write_text('block = "shake-4t"\nfoo = ' + "[" * 2000 + "]" * 2000 + "\n")
    _assert_bad(shoha("scene", "info", str(scene)), "TOML nested too deeply")


def test_a_name_with_a_newline_is_shown_escaped_on_its_one_line(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text(_layout_text().replace('"mini"', '"mi\\nni\\u0000"'))
    r = shoha("check", str(path))
    _assert_bad(r, "bad.json: mi\\nni\\x00: no such scene")


def test_a_relative_mesh_block_on_the_command_line_is_the_working_folders(tmp_path):
    """``--block mesh:meshes/b.stl`` names a file in the working folder (docs/contract.md); it
    was looked for beside the save, in ``saves/meshes/b.stl``."""
    (tmp_path / "meshes").mkdir()
    (tmp_path / "saves").mkdir()
    trimesh.creation.box([1.2, 1.0, 0.8]).export(tmp_path / "meshes" / "b.stl")
    (tmp_path / "saves" / "s.json").write_text(json.dumps({"blocks": [
        {"position": {"x": 0.0, "y": 0.4, "z": 3.0}, "rotation": {"x": 0, "y": 0, "z": 0, "w": 1}}]}))
    r = shoha("convert", "saves/s.json", "--from", "unity", "--out", "out.json",
              "--block", "mesh:meshes/b.stl", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    r = shoha("check", str(tmp_path / "out.json"), "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["blocks"] == 1


def test_scene_export_writes_all_its_files_or_none(tmp_path):
    """A ``tolerance.stl`` that is a folder was found only after ``design.stl`` was written
    over; a missing folder above ``--out`` was made, and ``--out ''`` wrote into the working folder."""
    out = tmp_path / "out"
    (out / "tolerance.stl").mkdir(parents=True)
    (out / "design.stl").write_text("mine")
    _assert_bad(shoha("scene", "export", "mini", "--out", str(out)), "tolerance.stl: is a folder")
    assert (out / "design.stl").read_text() == "mine" and sorted(p.name for p in out.iterdir()) == [
        "design.stl", "tolerance.stl"]
    _assert_bad(shoha("scene", "export", "mini", "--out", str(tmp_path / "a" / "b")), "does not exist")
    _assert_bad(shoha("scene", "export", "mini", "--out", "", cwd=tmp_path), "name a folder")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_an_output_name_the_file_system_refuses_is_refused_before_the_work(tmp_path, monkeypatch, capsys):
    """``--out`` with a name too long for the file system: refused with one line before the
    search (the optimizer is never called), where it was found only once a run had spent its
    whole limit (stop 77's probe)."""
    import optimizer.api
    from optimizer.cli import main

    called = []
    monkeypatch.setattr(optimizer.api, "optimize", lambda *a, **k: called.append(a))
    out = tmp_path / ("a" * 300 + ".json")
    assert main(["optimize", str(ROOT / "tests" / "data" / "tiny.toml"), "--out", str(out),
                 "--time-limit", "60"]) == 2
    assert "cannot write (File name too long)" in capsys.readouterr().err
    assert not called and list(tmp_path.iterdir()) == []


def test_a_batch_rows_file_appended_to_needs_no_new_file_beside_it(tmp_path, monkeypatch):
    """A batch appends its rows in place: an existing rows file is checked for writing, not by
    a temporary file beside it, which a folder closed to new files refuses (a review of stop 77
    found a resumed batch refused so). An output written whole still gets the probe."""
    from geometry.errors import InputError
    from optimizer.cli import common

    def closed_folder(path):
        raise InputError(f"{path}: cannot write (Permission denied)")

    monkeypatch.setattr(common, "check_writable", closed_folder)
    rows = tmp_path / "rows.csv"
    rows.write_text("scene,score\n")
    assert common.check_out(str(rows), (".csv", ".jsonl"), atomic=False) == rows
    with pytest.raises(InputError):
        common.check_out(str(tmp_path / "new.csv"), (".csv", ".jsonl"), atomic=False)
    with pytest.raises(InputError):
        common.check_out(str(rows), (".csv",))
