"""``shoha render``: plan and cross-section drawings for print (optimizer/render.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from geometry.layout import read_layout, write_layout
from geometry.pose import Pose
from optimizer.score.render import COLOURS, piece_section
from tests.conftest import shoha
from tests.perturb import lift_out_of_tolerance

REFERENCE = Path(__file__).parent / "data" / "mini-reference.json"


def _pixels_of(png: Path, colour: str) -> int:
    """How many pixels of a PNG have (nearly) the colour ``#rrggbb``."""
    from matplotlib.image import imread

    rgb = np.array([int(colour[i:i + 2], 16) / 255 for i in (1, 3, 5)])
    image = imread(png)[:, :, :3]
    return int(np.count_nonzero(np.all(np.abs(image - rgb) < 0.02, axis=2)))


@pytest.mark.parametrize(
    "y, area",
    [(0.3, 1.0), (-0.49, 1.0), (0.0, 1.0), (0.7, None), (-0.5000001, None)],  # last rows: misses
)
def test_piece_section_of_a_unit_cube(cube, y, area):
    (piece,) = cube.pieces
    moved = piece.transformed(Pose([0.0, 0.0, 0.5], [1, 0, 0, 0]).rotation, np.array([0.0, 0.0, 0.5]))
    poly = piece_section(moved.vertices, moved.edges, y)
    if area is None:
        assert poly is None
        return
    x, z = poly[:, 0], poly[:, 1]
    shoelace = 0.5 * abs(np.dot(x, np.roll(z, 1)) - np.dot(z, np.roll(x, 1)))
    np.testing.assert_allclose(shoelace, area, rtol=1e-12)
    np.testing.assert_allclose([x.min(), x.max(), z.min(), z.max()], [-0.5, 0.5, 0.0, 1.0], atol=1e-12)


def test_render_png_and_protruding_blocks_in_yellow(tmp_path):
    ref_png = tmp_path / "reference.png"
    r = shoha("render", str(REFERENCE), "--out", str(ref_png), "--json")
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["path"] == str(ref_png) and d["blocks"] == 75 and d["out_of_tolerance"] == []
    assert ref_png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    legend_only = _pixels_of(ref_png, COLOURS["protruding"])  # the legend's swatch

    ref = read_layout(REFERENCE)
    layout, key = lift_out_of_tolerance(ref.load_scene(), ref)
    layout.scene = "mini"
    save = tmp_path / "lifted.json"
    write_layout(layout, save)
    out = tmp_path / "lifted.png"
    d = json.loads(shoha("render", str(save), "--out", str(out), "--json").stdout)
    assert d["out_of_tolerance"] == [key]
    # The block seen from above in the plan: thousands of pixels at 150 dpi.
    assert _pixels_of(out, COLOURS["protruding"]) > legend_only + 1000


def test_render_pdf(tmp_path):
    out = tmp_path / "plan.pdf"
    r = shoha("render", str(REFERENCE), "--out", str(out), "--section-y", "3.0")
    assert r.returncode == 0, r.stderr
    assert out.read_bytes()[:5] == b"%PDF-"


@pytest.mark.parametrize(
    "args, word",
    [
        (["--out", "{tmp}/x.jpg"], ".png"),
        (["--out", "{tmp}/none/x.png"], "does not exist"),
        (["--out", "{tmp}/x.png", "--scene", "nope"], "nope"),
        (["--out", "{tmp}/x.png", "--section-y", "nan"], "section-y"),
        (["--out", "{tmp}/x.png", "--section-y", "-5"], "must lie along the mound"),
        (["--out", "{tmp}/x.png", "--section-y", "1e300"], "must lie along the mound"),
    ],
)
def test_render_bad_input(tmp_path, args, word):
    r = shoha("render", str(REFERENCE), *[a.format(tmp=tmp_path) for a in args])
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and word in lines[0]
    assert not list(tmp_path.rglob("x.*"))


def test_render_missing_layout(tmp_path):
    r = shoha("render", str(tmp_path / "none.json"), "--out", str(tmp_path / "x.png"))
    assert r.returncode == 2 and "none.json" in r.stderr and not (tmp_path / "x.png").exists()
