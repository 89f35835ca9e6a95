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
import os
import shutil
from pathlib import Path

import pytest

from geometry.layout import read_layout, write_layout
from optimizer.score.render import COLOURS
from tests.conftest import shoha
from tests.perturb import lift_out_of_tolerance, push_together, stand_on_leg_tip

REFERENCE = Path(__file__).parent / "data" / "mini-reference.json"
SCREENSHOT = "report-screenshot.png"
CHROMIUM = "/usr/bin/chromium"
#: Headless, and nothing that talks to the network (the machine may have none).
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run"]

pytestmark = [pytest.mark.browser, pytest.mark.timeout(600)]


def _chromium() -> str:
    """The Chromium binary, or skip (fail in CI) with the reason."""
    path = CHROMIUM if os.access(CHROMIUM, os.X_OK) else shutil.which("chromium")
    reason = None
    if path is None:
        reason = f"no Chromium at {CHROMIUM} or on PATH (Debian: apt-get install chromium)"
    else:
        try:
            import playwright.sync_api  # noqa: F401
        except ImportError:
            reason = "the playwright package is missing (pip install -e '.[test]')"
    if reason is not None:
        if os.environ.get("CI"):
            pytest.fail(f"CI must run the browser test, but {reason}")
        pytest.skip(reason)
    return path


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> tuple[Path, dict]:
    """A save with three faults, scored with --html by the CLI."""
    folder = tmp_path_factory.mktemp("report")
    ref = read_layout(REFERENCE)
    scene = ref.load_scene()
    layout, _ = lift_out_of_tolerance(scene, ref)
    layout, _ = stand_on_leg_tip(scene, layout)
    layout, _ = push_together(scene, layout)
    layout.scene = "mini"
    save = folder / "trainee.json"
    write_layout(layout, save)
    out = folder / "trainee-report.html"
    r = shoha("score", str(save), "--reference", str(REFERENCE), "--html", str(out), "--json")
    assert r.returncode == 0, r.stderr
    return out, json.loads(r.stdout)


def test_report_in_headless_chromium(report, tmp_path, keep_screenshot):
    executable = _chromium()
    shot = tmp_path / SCREENSHOT
    from playwright.sync_api import sync_playwright

    path, scored = report
    assert scored["out_of_tolerance"] and scored["collisions"] and not scored["stable"]
    errors: list[str] = []
    remote: list[str] = []
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=executable, args=FLAGS, headless=True)
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 1000})
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))

            def block_remote(route):
                if route.request.url.startswith(("file:", "data:", "blob:")):
                    route.continue_()
                else:
                    remote.append(route.request.url)
                    route.abort()

            page.route("**/*", block_remote)
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
        finally:
            browser.close()
    assert remote == [], f"the report asked the network for {remote}"
    assert errors == [], f"console errors: {errors}"
    assert shot.stat().st_size > 50_000
    keep_screenshot(shot)


def test_a_partial_save_shows_progress_and_quality_apart(tmp_path):
    """The reference's first 45 blocks: 60 % done, and what is done is excellent (issue 26, property 5)."""
    executable = _chromium()
    from playwright.sync_api import sync_playwright

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
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=executable, args=FLAGS, headless=True)
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 1000})
            page.route("**/*", lambda route: route.continue_() if route.request.url.startswith(
                ("file:", "data:", "blob:")) else route.abort())
            page.goto(out.as_uri())
            for element, text in (("#score", "60.0"), ("#progress", "60.0"), ("#quality", "100.0")):
                assert page.is_visible(element), element
                assert page.inner_text(element) == text, element
            parts = page.inner_text(".parts")
            assert "45 of 75 blocks laid" in parts and "0.0 penalty points" in parts
        finally:
            browser.close()
