"""The HTML report in a real browser: Debian's headless Chromium, driven by Playwright.

The report of a save with one block out of tolerance, one on a leg tip and
two pushed into each other is opened from disk with the network off. The
test checks that nothing is requested from elsewhere, that no error reaches
the console, that the three toggles (design prism, tolerance prism, crest)
hide and show their traces and change the picture, and that the faulty
blocks have their colours. It saves a screenshot in its temporary folder;
``make screenshots`` copies it to docs/report-screenshot.png for the README
(the ``--screenshots`` option of tests/conftest.py), and no other run writes
outside a temporary folder.

Where no Chromium is installed (a user's laptop) the test skips and says why;
in CI (the ``CI`` environment variable set, as .ci/run does) it fails instead,
because there it must run.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from geometry.layout import read_layout, write_layout
from optimizer.score.render import COLOURS
from tests.browser import LOCAL, offline_page
from tests.conftest import shoha
from tests.perturb import three_faults

REFERENCE = Path(__file__).parent / "data" / "mini-reference.json"
SCREENSHOT = "report-screenshot.png"

pytestmark = [pytest.mark.browser, pytest.mark.timeout(600)]


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> tuple[Path, dict]:
    """A save with three faults, scored with --html by the CLI."""
    folder = tmp_path_factory.mktemp("report")
    ref = read_layout(REFERENCE)
    scene = ref.load_scene()
    layout = three_faults(scene, ref)
    layout.scene = "mini"
    save = folder / "trainee.json"
    write_layout(layout, save)
    out = folder / "trainee-report.html"
    r = shoha("score", str(save), "--reference", str(REFERENCE), "--html", str(out), "--json")
    assert r.returncode == 0, r.stderr
    return out, json.loads(r.stdout)


def test_report_in_headless_chromium(report, tmp_path, keep_screenshot):
    shot = tmp_path / SCREENSHOT

    path, scored = report
    assert scored["out_of_tolerance"] and scored["collisions"] and not scored["stable"]
    with offline_page(LOCAL, {"width": 1400, "height": 1000}, "the report") as page:
        page.goto(path.as_uri())
        page.wait_for_function(
            "() => { const g = document.getElementById('view3d');"
            " return g && g._fullLayout && g.querySelector('canvas') !== null; }", timeout=60_000)
        page.wait_for_timeout(1000)  # let WebGL draw the first frame

        # The score on the page is the one the CLI printed, with its two parts apart.
        assert page.inner_text("#score") == f"{scored['score']:.1f}"
        assert page.inner_text("#progress") == f"{scored['progress_percent']:.1f}"
        assert page.inner_text("#quality") == f"{scored['quality']:.1f}"

        # Faulty blocks in their colours: yellow (Fig. 11), red, orange.
        traces = page.evaluate("document.getElementById('view3d').data.map(t => [t.name, t.color])")
        colours = {name.split(":")[0]: colour for name, colour in traces}
        assert colours["out of tolerance (yellow)"] == COLOURS["protruding"]
        assert colours["unstable (red)"] == COLOURS["unstable"]
        assert colours["colliding (orange)"] == COLOURS["colliding"]

        # Both porosity maps are drawn, side by side.
        assert page.evaluate("document.getElementById('porosity-map').data.length") == 2
        drawn = page.evaluate("document.querySelectorAll('#porosity-map .hm, #porosity-map image')"
                              ".length")
        assert drawn >= 2

        view = page.locator("#view3d")
        for toggle in ("toggle-design", "toggle-tolerance", "toggle-crest"):
            indices = json.loads(page.get_attribute(f"#{toggle}", "data-traces"))
            assert indices
            others = [i for i in range(len(traces)) if i not in indices]
            before = view.screenshot()
            page.uncheck(f"#{toggle}")
            page.wait_for_timeout(500)
            visible = page.evaluate("document.getElementById('view3d').data.map(t => t.visible)")
            assert all(visible[i] is False for i in indices), (toggle, visible)
            assert all(visible[i] is not False for i in others), (toggle, visible)
            hidden = view.screenshot()
            assert hidden != before, f"{toggle}: the picture did not change"
            page.check(f"#{toggle}")
            page.wait_for_timeout(500)
            visible = page.evaluate("document.getElementById('view3d').data.map(t => t.visible)")
            assert all(visible[i] is True for i in indices), (toggle, visible)

        page.screenshot(path=str(shot), full_page=True)
    assert shot.stat().st_size > 50_000
    keep_screenshot(shot)


def test_a_partial_save_shows_progress_and_quality_apart(tmp_path):
    """The reference's first 45 blocks: 60 % done, and what is done is excellent (issue 26, property 5)."""
    layout = read_layout(REFERENCE)
    layout.blocks = layout.blocks[:45]
    layout.base_dir = None
    save = tmp_path / "first-45.json"
    write_layout(layout, save)
    out = tmp_path / "first-45.html"
    r = shoha("score", str(save), "--reference", str(REFERENCE), "--html", str(out), "--json")
    assert r.returncode == 0, r.stderr
    scored = json.loads(r.stdout)
    assert (scored["progress_percent"], scored["quality"], scored["score"]) == (60.0, 100.0, 60.0)
    with offline_page(LOCAL, {"width": 1400, "height": 1000}, "the report") as page:
        page.goto(out.as_uri())
        for element, text in (("#score", "60.0"), ("#progress", "60.0"), ("#quality", "100.0")):
            assert page.is_visible(element), element
            assert page.inner_text(element) == text, element
        parts = page.inner_text(".parts")
        assert "45 of 75 blocks laid" in parts and "0.0 penalty points" in parts
