"""``shoha settle`` as a user runs it (docs/contract.md, "CLI" and "Exit codes and errors")."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from geometry.checks import check_layout
from geometry.layout import Layout, Placement, read_layout, write_layout
from geometry.pose import Pose
from settle.pour import pour
from tests.conftest import ROOT, shoha, standing

CONTRACT_KEYS = {"stable", "max_displacement_m", "max_rotation_deg", "blocks", "seconds"}


def _json(result: subprocess.CompletedProcess) -> dict:
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


@pytest.fixture
def two(tmp_path, shake):
    """A Shake Block standing on mini's floor, and one hanging 2 m above it."""
    path = tmp_path / "two.json"
    blocks = [Placement(4, "shake-4t", standing(shake, 0.0, 6.0)),
              Placement(9, "shake-4t", standing(shake, 3.0, 6.0, ground=2.0))]
    write_layout(Layout("mini", blocks, {"note": "kept"}), path)
    return path


def test_settle_json_has_the_contract_keys(two):
    d = _json(shoha("settle", str(two), "--json"))
    assert set(d) >= CONTRACT_KEYS
    assert [b["id"] for b in d["blocks"]] == [4, 9]
    assert all(set(b) == {"id", "displacement_m", "rotation_deg", "stable"} for b in d["blocks"])
    assert d["stable"] is False and d["blocks"][0]["stable"] and not d["blocks"][1]["stable"]
    assert d["blocks"][1]["displacement_m"] == pytest.approx(2.0, abs=0.01)
    assert d["max_displacement_m"] == d["blocks"][1]["displacement_m"] and d["seconds"] > 0


def test_settle_without_json_prints_one_line(two):
    r = shoha("settle", str(two))
    assert r.returncode == 0 and r.stdout.count("\n") == 1 and "UNSTABLE" in r.stdout


def test_settle_out_writes_the_settled_layout(two, tmp_path, mini):
    out = tmp_path / "settled.json"
    d = _json(shoha("settle", str(two), "--out", str(out), "--json"))
    settled = read_layout(out)
    assert [(p.id, p.type) for p in settled.blocks] == [(4, "shake-4t"), (9, "shake-4t")]
    assert settled.scene == "mini" and settled.extra == {"note": "kept"}
    # The hanging block landed on the floor; settled again, everything stands.
    assert settled.blocks[1].pose.position[2] == pytest.approx(standing(mini.block, 3, 6).position[2],
                                                               abs=1e-3)
    again = _json(shoha("settle", str(out), "--json"))
    assert again["stable"] and d["path"] == str(out)


def test_same_seed_same_output(two):
    a, b = (_json(shoha("settle", str(two), "--seed", "5", "--json")) for _ in range(2))
    assert a["blocks"] == b["blocks"]


def test_scene_file_is_referenced_from_the_output_folder(tmp_path, section_file):
    layout = tmp_path / "in" / "l.json"
    layout.parent.mkdir()
    rel = Path("..") / section_file.name
    b = Placement(0, "box:1.2x1x0.6", Pose([0.0, 0.5, 0.3], [1, 0, 0, 0]))
    write_layout(Layout(str(rel), [b]), layout)
    out_dir = tmp_path / "out" / "deeper"
    out_dir.mkdir(parents=True)
    d = _json(shoha("settle", str(layout), "--out", str(out_dir / "s.json"), "--json"))
    assert d["stable"] and d["backend"] == "pymunk"  # a section scene settles in 2D
    written = read_layout(out_dir / "s.json")
    assert (out_dir / written.scene).resolve() == section_file.resolve()
    assert written.load_scene().kind == "section"


@pytest.fixture
def section_file(tmp_path):
    path = tmp_path / "slice.toml"
    path.write_text((ROOT / "geometry" / "scenes" / "mini-section.toml").read_text().replace(
        'name = "mini-section"', 'name = "slice"'))
    return path


@pytest.mark.parametrize("args, message", [
    (["missing.json"], "missing.json: file not found"),
    (["{layout}", "--seconds", "0"], "--seconds 0.0: must be more than 0"),
    (["{layout}", "--seconds", "nan"], "--seconds nan"),
    (["{layout}", "--scene", "nowhere"], "nowhere: no such scene"),
    (["{layout}", "--backend", "pymunk"], "section scenes only"),
    (["{layout}", "--out", "{tmp}/no/such/dir/x.json"], "does not exist"),
    (["{layout}", "--out", "{tmp}/x.txt"], "must end in .json"),
    (["{layout}", "--seed", "-1"], "--seed"),
])
def test_bad_input_exits_2_with_one_line_and_no_output(two, tmp_path, args, message):
    out = tmp_path / "settled.json"
    argv = [a.format(layout=two, tmp=tmp_path) for a in args]
    if "--out" not in argv:
        argv += ["--out", str(out)]
    r = shoha("settle", *argv, "--json", cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert r.stdout == "" and len(r.stderr.strip().splitlines()) == 1 and message in r.stderr
    assert "Traceback" not in r.stderr
    assert not out.exists() and not (tmp_path / "x.txt").exists()


@pytest.fixture(scope="module")
def pile75(mini):
    """75 Shake Blocks poured onto mini's floor: a pile at rest, free of collisions."""
    return pour(mini, 75, seed=0)


def test_75_block_pile_of_mini_settles_stable(pile75, mini, tmp_path):
    # The acceptance case: a 75-block collision-free layout of mini.
    assert check_layout(mini, pile75).to_dict()["collisions"] == []
    assert max(p.position[2] for _, _, p in pile75) > 2.0  # several layers, not a carpet
    path = tmp_path / "pile.json"
    write_layout(Layout("mini", [Placement(k, "shake-4t", p) for k, _, p in pile75]), path)
    d = _json(shoha("settle", str(path), "--json"))
    assert set(d) >= CONTRACT_KEYS and len(d["blocks"]) == 75
    assert d["stable"] and d["max_displacement_m"] < 0.05 * mini.block.height


def test_settle_package_never_imports_optimizer():
    # STYLE.md: settle/ imports geometry, never optimizer.
    code = ("import sys, settle, settle.pour, settle.section; "
            "print(any(m == 'optimizer' or m.startswith('optimizer.') for m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0 and r.stdout.strip() == "False", r.stderr


def test_progress_is_reported_in_simulated_seconds(mini, shake):
    from settle import settle

    seen: list[tuple[float, float]] = []
    settle(mini, [(0, shake, standing(shake, 0, 6, ground=1.0))], seconds=1.0, early_stop=False,
           progress=lambda t, total: seen.append((t, total)))
    times = np.array([t for t, _ in seen])
    assert len(seen) >= 5 and np.all(np.diff(times) > 0) and times[-1] <= 1.0
    assert {total for _, total in seen} == {1.0}
