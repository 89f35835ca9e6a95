"""Scenes: the mini breakwater, Table II's tolerance zone, TOML loading."""

from __future__ import annotations

import numpy as np
import pytest

from geometry.constants import tol
from geometry.errors import InputError
from geometry.scene import builtin_scenes, load_scene, parse_scene

MINI_TOML = """
name = "t"
block = "shake-4t"
[design]
crest_width_m = 4.0
height_m = 3.0
slope_rise_run = [3.0, 4.0]
length_m = 12.220833333333333
"""


def test_mini_reproduces_the_paper(mini):
    np.testing.assert_allclose(mini.design_volume, 293.3, rtol=1e-12)
    assert mini.required_blocks == 75  # ceil(0.44 * 293.3 / 1.735)
    assert mini.target_porosity == 56.0
    assert mini.block_type == "shake-4t"
    # Table V's "correct value" column is 1 - n 1.735 / 293.3.
    for n, correct in ((9, 94.68), (17, 89.94), (25, 85.21)):
        assert round(100 * (1 - n * 1.735 / mini.design_volume), 2) == correct


def test_tolerance_zone_meets_table_ii(mini):
    h3 = mini.block.height / 3
    d, t = mini.design, mini.tolerance
    np.testing.assert_allclose(t.z_top - d.z_top, h3, rtol=1e-12)  # base height + H/3
    np.testing.assert_allclose(2 * (t.top_half_width - d.top_half_width), h3, rtol=1e-12)  # top width
    slope_d = np.hypot(d.height, d.bottom_half_width - d.top_half_width)
    # Table II measures from the foundation top (z = 0); the zone reaches 5 mm below it.
    run_per_rise = (t.bottom_half_width - t.top_half_width) / t.height
    half_at_ground = t.top_half_width + run_per_rise * t.z_top
    slope_t = np.hypot(t.z_top, half_at_ground - t.top_half_width)
    np.testing.assert_allclose(slope_t - slope_d, h3, rtol=1e-12)  # slope length (法長) + H/3
    assert t.z_bottom == pytest.approx(-tol.contact_depth)
    np.testing.assert_allclose([d.y_start - t.y_start, t.y_end - d.y_end], h3, rtol=1e-12)


def test_design_prism_lies_in_the_tolerance_zone(mini):
    assert mini.tolerance.polytope.contains(mini.design.corners).all()
    assert mini.tolerance.volume > mini.design_volume


def test_builtin_scenes_load():
    assert "mini" in builtin_scenes()
    for name in builtin_scenes():
        s = load_scene(name)
        assert s.required_blocks > 0 and s.design_volume > 0


def test_scene_file_with_defaults(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text(MINI_TOML)
    s = load_scene(str(p))
    assert s.required_blocks == 75 and s.foundation.kind == "flat"


def test_rough_foundation_is_seeded_and_bounded(tmp_path):
    text = MINI_TOML + '[foundation]\nkind = "rough"\namplitude_m = 0.2\nseed = 3\n'
    a, b = parse_scene(text, "a", None), parse_scene(text, "b", None)
    xy = np.random.default_rng(0).uniform([-6, 0], [6, 12], (500, 2))
    ha, hb = a.foundation.height_at(xy), b.foundation.height_at(xy)
    np.testing.assert_array_equal(ha, hb)
    assert ha.min() >= -0.2 and ha.max() <= 0.2 and ha.std() > 0.02
    assert a.tolerance.z_bottom == pytest.approx(-0.2 - tol.contact_depth)


@pytest.mark.parametrize(
    "text, message",
    [
        ("name = 1\n[design]\n", "name"),
        ("[design]\ncrest_width_m = 4.0\n", "missing"),
        (MINI_TOML.replace("[3.0, 4.0]", "[0, 4]"), "slope_rise_run"),
        (MINI_TOML.replace("4.0\nheight", "nan\nheight"), "finite"),
        (MINI_TOML.replace("12.220833333333333", "-1"), "length_m"),
        # A prism 5e-324 m long: its coverage floor was NaN (exit 1 with --json), and later
        # commands said "prism: points span no volume", naming neither the file nor the key.
        (MINI_TOML.replace("12.220833333333333", "5e-324"),
         r"bad.toml: \[design\] length_m = 4.94066e-324 m"),
        (MINI_TOML.replace("height_m = 3.0", "height_m = 1e-9"), r"bad.toml: \[design\] height_m = 1e-09 m"),
        (MINI_TOML + "colour = 'red'\n", "unknown key"),
        (MINI_TOML.replace('"shake-4t"', '"brick"'), "unknown block"),
        (MINI_TOML + "required_blocks = 1e9\n", "required_blocks"),
        ("this is = = not toml", "malformed TOML"),
        # A cell of 1e308 m overflowed the height field's count (exit 1).
        (MINI_TOML + "[foundation]\nkind = 'rough'\ncell_m = 1e308\n",
         r"bad.toml: \[foundation\] cell_m = 1e\+308 m is wider than the foundation"),
        (MINI_TOML + "[foundation]\nkind = 'lava'\n", "flat or rough"),
        (MINI_TOML + "[tolerance]\nend_extension_m = 1e6\n", r"bad.toml: \[tolerance\] end_extension_m"),
        (MINI_TOML + "[tolerance]\ncrest_rise_m = 5000\n", "bad.toml: tolerance: slope length"),
        (MINI_TOML.replace("[3.0, 4.0]", "[1, 1000]").replace("12.220833333333333", "10000"),
         "bad.toml: the design prism .* takes"),
        # A run 1e300 times the rise overflowed, with a warning on stderr; 1e300 is not "positive"'s fault.
        (MINI_TOML.replace("[3.0, 4.0]", "[1e-300, 1]"), "run from 1/1000 to 1000 times the rise"),
        (MINI_TOML.replace("[3.0, 4.0]", "[1e300, 1e300]"), "two positive numbers below 1e6"),
        # An integer no float holds (TOML has no limit on digits) passed as an int, then overflowed
        # with exit 1; the message shows a cut of it, not 400 digits.
        (MINI_TOML.replace("height_m = 3.0", "height_m = " + "9" * 400),
         r"bad.toml: height_m must be a finite number, not 9{37}\.\.\.$"),
        # A NUL in a name went through to every JSON answer; a 10 MB name into every report.
        (MINI_TOML.replace('"t"', '"mi\\u0000ni"', 1),
         "bad.toml: name 'mi\\\\x00ni' holds a control character"),
        (MINI_TOML.replace('"t"', '"' + "x" * 2000 + '"', 1),
         "bad.toml: name is 2000 characters long; at most 1000"),
    ],
)
def test_bad_scene_files_are_input_errors(text, message):
    with pytest.raises(InputError, match=message):
        parse_scene(text, "bad.toml", None)


def test_a_name_in_any_script_is_kept():
    """Only control characters are refused: a name in Japanese, with spaces, stays as written."""
    name = "消波 ブロック 2"
    assert parse_scene(MINI_TOML.replace('"t"', f'"{name}"', 1), "ok.toml", None).name == name


def test_missing_scene_is_an_input_error():
    with pytest.raises(InputError, match="no such scene"):
        load_scene("atlantis")


def test_rough_foundation_is_the_surface_mujoco_collides_with():
    """Ray casts onto the settle's own MuJoCo height field land where ``height_at`` says."""
    import mujoco

    from settle.mujoco_backend import MujocoBackend

    rough = '[foundation]\nkind = "rough"\namplitude_m = 0.15\ncell_m = 0.5\nseed = 3\n'
    scene = parse_scene(MINI_TOML + rough, "rough.toml", None)
    model = MujocoBackend().build(scene, [])
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    rng = np.random.default_rng(0)
    xy = rng.uniform([-5.0, 1.0], [5.0, 11.0], (200, 2))
    hit = []
    for x, y in xy:
        geom = np.zeros(1, np.int32)
        hit.append(5.0 - mujoco.mj_ray(model, data, np.array([x, y, 5.0]), np.array([0.0, 0.0, -1.0]),
                                       None, 1, -1, geom))
    np.testing.assert_allclose(hit, scene.foundation.height_at(xy), atol=1e-6)
    assert np.ptp(hit) > 0.1  # the ground is rough: the test compares something


def test_every_built_in_scene_keeps_its_name():
    """A loop over the tolerance keys once reused ``name``, and every scene was called
    ``slope_lengthening``; ``shoha serve`` then refused every reference."""
    assert [load_scene(n).name for n in builtin_scenes()] == builtin_scenes()


def test_a_flat_foundation_is_a_box_however_wide():
    """A flat foundation's slab is its corners: gridded every cell, a tolerance zone widened by
    10 km took 6 GB to export (the kernel killed it)."""
    wide = MINI_TOML + "[tolerance]\ncrest_widening_m = 10000.0\nend_extension_m = 10000.0\n"
    scene = parse_scene(wide, "wide.toml", None)
    vertices, faces = scene.foundation.slab()
    assert len(vertices) == 8 and len(faces) == 12
    x0, x1, y0, y1 = scene.foundation.extent
    assert x1 - x0 > 10_000 and y1 - y0 > 20_000
    np.testing.assert_array_equal(vertices[:, :2].min(axis=0), [x0, y0])
    np.testing.assert_array_equal(vertices[:, :2].max(axis=0), [x1, y1])
    assert vertices[:, 2].max() == 0.0


def test_scene_files_with_a_byte_order_mark_load_and_others_are_named(tmp_path):
    """A scene saved with a UTF-8 byte-order mark was "malformed TOML"; a folder was "no such
    scene"; a file of 80 MB took 73 s and 1 GB before its refusal."""
    from geometry.scene import MAX_SCENE_BYTES

    bom = tmp_path / "bom.toml"
    bom.write_bytes(b"\xef\xbb\xbf" + MINI_TOML.encode())
    plain = parse_scene(MINI_TOML, "m", None)
    assert load_scene(str(bom)).design_volume == pytest.approx(plain.design_volume)
    with pytest.raises(InputError, match=f"{tmp_path}: is a folder, not a file"):
        load_scene(str(tmp_path))
    big = tmp_path / "big.toml"
    big.write_text(MINI_TOML + "#" * MAX_SCENE_BYTES + "\n")
    with pytest.raises(InputError, match=f"big.toml: scene file is {big.stat().st_size} bytes, more than"):
        load_scene(str(big))
