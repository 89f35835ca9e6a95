"""``shoha score`` run as a user runs it: JSON keys, Unity saves, bad input (docs/contract.md)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from geometry.layout import read_layout
from tests.conftest import shoha

DATA = Path(__file__).parent / "data"
REFERENCE = DATA / "mini-reference.json"
CONTRACT_KEYS = {"score", "porosity_percent", "reference_porosity_percent", "out_of_tolerance", "collisions",
                 "stable", "blocks", "required_blocks"}


def to_unity_save(layout, origin) -> dict:
    """A layout as the simulator saves it (docs/contract.md, "Simulator saves"), written out by hand.

    World (x, y, z) = (x_u, z_u, y_u) + origin, and a world quaternion
    [w, X, Y, Z] is the Unity quaternion (x, y, z, w) = (-X, -Z, -Y, w).
    """
    ox, oy, oz = origin
    blocks = []
    for p in layout.blocks:
        x, y, z = p.pose.position
        w, qx, qy, qz = p.pose.quaternion
        blocks.append({"type": p.type, "position": {"x": x - ox, "y": z - oz, "z": y - oy},
                       "rotation": {"x": -qx, "y": -qz, "z": -qy, "w": w}})
    return {"blocks": blocks}


def _json(result):
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


@pytest.fixture(scope="module")
def layout_score() -> dict:
    return _json(shoha("score", str(REFERENCE), "--reference", str(REFERENCE), "--json"))


def test_score_json_has_the_contract_keys(layout_score):
    assert set(layout_score) >= CONTRACT_KEYS
    assert layout_score["score"] == 100.0
    assert layout_score["blocks"] == layout_score["required_blocks"] == 75
    assert layout_score["seconds"] > 0


@pytest.mark.parametrize("how", [["--from", "unity"], []], ids=["from-unity", "autodetect"])
def test_unity_save_scores_like_the_layout(tmp_path, layout_score, how):
    origin = (2.5, -1.0, 0.25)
    save = tmp_path / "trainee.json"
    # The "type" key is optional in saves: leave it out, --block supplies it.
    data = to_unity_save(read_layout(REFERENCE), origin)
    for b in data["blocks"]:
        del b["type"]
    save.write_text(json.dumps(data))
    got = _json(shoha("score", str(save), "--reference", str(REFERENCE), *how, "--block", "shake-4t",
                      "--origin", ",".join(map(str, origin)), "--json"))
    np.testing.assert_allclose(got["porosity_percent"], layout_score["porosity_percent"], atol=1e-9)
    for key in ("score", "out_of_tolerance", "collisions", "stable", "blocks", "required_blocks",
                "remaining_blocks", "unstable_blocks"):
        assert got[key] == layout_score[key], key
    assert [b["contacts"] for b in got["interlock"]["blocks"]] == \
        [b["contacts"] for b in layout_score["interlock"]["blocks"]]


def test_completion_time_from_a_save_with_times(tmp_path, layout_score):
    """Block times give the completion time and blocks per hour; they cost nothing by default (issue 25)."""
    data = to_unity_save(read_layout(REFERENCE), (0.0, 0.0, 0.0))
    for i, block in enumerate(data["blocks"]):
        block["time_s"] = 30.0 * (i + 1)
    save = tmp_path / "timed.json"
    save.write_text(json.dumps(data))
    got = _json(shoha("score", str(save), "--reference", str(REFERENCE), "--json"))
    last = 30.0 * len(data["blocks"])
    assert got["elapsed_s"] == got["completion_time_s"] == last
    assert got["blocks_per_hour"] == 3600.0 * 75 / last
    assert got["score"] == layout_score["score"] == 100.0
    assert [p["points"] for p in got["penalties"] if p["name"] == "time"] == [0.0]
    # A partial save with the session's elapsed time: no completion time yet, blocks per hour so far.
    data["blocks"] = data["blocks"][:30]
    data["elapsed_s"] = 1250.0
    save.write_text(json.dumps(data))
    got = _json(shoha("score", str(save), "--reference", str(REFERENCE), "--json"))
    assert got["elapsed_s"] == 1250.0 and got["completion_time_s"] is None
    assert got["blocks_per_hour"] == 3600.0 * 30 / 1250.0
    assert "1250 s, 86.4 blocks per hour" in shoha("score", str(save), "--reference", str(REFERENCE)).stdout
    # Times too short for any rate (3600 / 5e-324 is infinite, and was a traceback, with the
    # --html report written all the same): no rate, and the report.
    for block in data["blocks"]:
        block["time_s"] = 5e-324
    del data["elapsed_s"]
    save.write_text(json.dumps(data))
    html = tmp_path / "report.html"
    got = _json(shoha("score", str(save), "--reference", str(REFERENCE), "--json", "--html", str(html)))
    assert got["elapsed_s"] == 5e-324 and got["blocks_per_hour"] is None and html.is_file()


def test_a_save_without_times_reports_none(layout_score):
    assert layout_score["elapsed_s"] is None and layout_score["completion_time_s"] is None
    assert layout_score["blocks_per_hour"] is None


def test_unity_save_at_the_wrong_origin_is_out_of_tolerance(tmp_path):
    save = tmp_path / "trainee.json"
    save.write_text(json.dumps(to_unity_save(read_layout(REFERENCE), (0.0, 0.0, 0.0))))
    # Read with an origin 30 m off: every block lies outside the breakwater.
    got = _json(shoha("score", str(save), "--reference", str(REFERENCE), "--from", "unity",
                      "--origin", "30,0,0", "--json"))
    assert len(got["out_of_tolerance"]) == 75 and got["porosity_percent"] == 100.0
    assert got["score"] < 60


def test_an_origin_beyond_any_breakwater_is_bad_usage(tmp_path):
    """``--origin 1e300,0,0`` put every block at 1e300 m and scored with exit 1."""
    save = tmp_path / "trainee.json"
    save.write_text(json.dumps(to_unity_save(read_layout(REFERENCE), (0.0, 0.0, 0.0))))
    done = shoha("score", str(save), "--reference", str(REFERENCE), "--from", "unity",
                 "--origin", "1e300,0,0")
    assert done.returncode == 2 and done.stderr.strip().splitlines() == [
        "shoha: --origin '1e300,0,0': more than 1e+06 m from the world origin"]


def test_html_report_is_written_whole_and_offline(tmp_path):
    out = tmp_path / "report.html"
    got = _json(shoha("score", str(REFERENCE), "--reference", str(REFERENCE), "--html", str(out), "--json"))
    assert got["html"] == str(out)
    text = out.read_text()
    assert text.startswith("<!DOCTYPE html>") and text.rstrip().endswith("</html>")
    assert "Plotly.newPlot" in text
    # Nothing is loaded from elsewhere: no tag names a remote or local source.
    # (plotly's bundle holds URL strings as defaults of features not used here,
    # such as topojsonURL; tests/test_report.py checks in a browser that no
    # request leaves the page.)
    assert not re.search(r"<(script|link|img|iframe)\b[^>]*\b(src|href)=", text, re.IGNORECASE)


def _bad(tmp_path: Path) -> dict[str, tuple[list[str], str]]:
    """Bad invocations: arguments, and a word the one-line message must hold."""
    malformed = tmp_path / "malformed.json"
    malformed.write_text('{"blocks": [')
    bad_quat = tmp_path / "bad-quaternion.json"
    data = to_unity_save(read_layout(REFERENCE), (0.0, 0.0, 0.0))
    data["blocks"][3]["rotation"] = {"x": 0.5, "y": 0.0, "z": 0.0, "w": 0.5}
    bad_quat.write_text(json.dumps(data))
    neither = tmp_path / "neither.json"
    neither.write_text('{"blocks": 3}')
    negative_time = tmp_path / "negative-time.json"
    data = to_unity_save(read_layout(REFERENCE), (0.0, 0.0, 0.0))
    data["blocks"][5]["time_s"] = -2.0
    negative_time.write_text(json.dumps(data))
    early = tmp_path / "early-elapsed.json"
    layout = json.loads(REFERENCE.read_text())
    layout["blocks"][0]["time_s"] = 90.0
    layout["elapsed_s"] = 60.0
    early.write_text(json.dumps(layout))
    ref = str(REFERENCE)
    html = str(tmp_path / "r.html")
    return {
        "missing save": (["nope.json", "--reference", ref, "--html", html], "nope.json"),
        "malformed save": ([str(malformed), "--reference", ref, "--html", html], "malformed"),
        "bad quaternion": ([str(bad_quat), "--reference", ref, "--from", "unity", "--html", html],
                           "quaternion"),
        "neither format": ([str(neither), "--reference", ref, "--html", html], "neither"),
        "negative time": ([str(negative_time), "--reference", ref, "--html", html], "time_s"),
        "elapsed before a block": ([str(early), "--reference", ref, "--html", html], "elapsed_s 60"),
        "missing reference": ([ref, "--reference", "nope-ref.json", "--html", html], "nope-ref.json"),
        "reference is a save": ([ref, "--reference", str(neither), "--html", html], "format"),
        "other scene": ([ref, "--reference", ref, "--scene", "mini-section", "--html", html], "scene"),
        "html suffix": ([ref, "--reference", ref, "--html", str(tmp_path / "r.txt")], ".html"),
        "html folder": ([ref, "--reference", ref, "--html", str(tmp_path / "no" / "r.html")],
                        "does not exist"),
        "bad origin": ([ref, "--reference", ref, "--origin", "1,2", "--html", html], "origin"),
        "bad seconds": ([ref, "--reference", ref, "--seconds", "0", "--html", html], "seconds"),
        "bad from": ([ref, "--reference", ref, "--from", "excel", "--html", html], "excel"),
    }


@pytest.mark.parametrize("case", list(_bad(Path("/tmp")).keys()))
def test_bad_input_exits_2_with_one_line_and_writes_nothing(tmp_path, case):
    args, word = _bad(tmp_path)[case]
    r = shoha("score", *args, "--json")
    assert r.returncode == 2, (case, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and word in lines[0], lines
    assert "Traceback" not in r.stderr and r.stdout == ""
    assert not any(p.suffix in (".html", ".txt") for p in tmp_path.rglob("*")), "an output file was written"


def test_the_worked_example_in_the_docs_is_what_shoha_prints():
    """docs/scoring.md quotes ``shoha score`` on docs/examples/partial-save.json; the quote must stay true."""
    from optimizer.score import Reference, score

    root = Path(__file__).resolve().parents[1]
    example = root / "docs" / "examples" / "partial-save.json"
    r = shoha("score", "docs/examples/partial-save.json", "--reference", "tests/data/mini-reference.json",
              cwd=root)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() in (root / "docs" / "scoring.md").read_text()
    # Its counterfactuals: stopping before block 39, or laying block 39 in its place, leave two faults
    # (10 points) and a finished layout that is the reference's.
    ref = read_layout(REFERENCE)
    scene = ref.load_scene()
    reference = Reference.of(scene, ref.placed())
    placed = read_layout(example).placed()
    assert placed[39][0] == 39
    for save, blocks in ((placed[:39], 39), (placed[:39] + [ref.placed()[39]], 40)):
        np.testing.assert_allclose(score(scene, save, reference).score, 100.0 * blocks / 75 * 0.99 ** 10,
                                   rtol=1e-12)
