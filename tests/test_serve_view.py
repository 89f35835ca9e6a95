"""The live view of ``shoha serve`` in a real browser: Debian's headless Chromium, driven by Playwright.

The service runs as a user starts it; the page is opened from it with every
other address refused. Blocks are laid over HTTP while the page is open,
and the test sees them arrive over the WebSocket: the counters change, each
block is drawn, and a block standing on the crest is drawn in the report's
yellow (optimizer/score/render.py ``COLOURS``). It saves a screenshot in its
temporary folder; ``make screenshots`` copies it to docs/serve-screenshot.png.
"""

from __future__ import annotations

import json
from pathlib import Path

import httpx
import numpy as np
import pytest

from geometry.blocks import get_block
from geometry.layout import read_layout
from geometry.pose import Pose
from optimizer.score.render import COLOURS
from optimizer.serve.session import world_to_unity
from tests.browser import offline_page
from tests.conftest import Served

REFERENCE = Path(__file__).parent / "data" / "mini-reference.json"
SCREENSHOT = "serve-screenshot.png"

pytestmark = [pytest.mark.browser, pytest.mark.timeout(600)]


def _standing_on_crest() -> Pose:
    """A Shake Block standing on mini's crest, its feet 0.5 m below the crest's top: above the crest."""
    block = get_block("shake-4t")
    scene = read_layout(REFERENCE).load_scene()
    pose = Pose([0.0, 3.0, 0.0], [1.0, 0.0, 0.0, 0.0])
    lowest = pose.apply(block.vertices)[:, 2].min()
    return Pose([0.0, 3.0, scene.height - 0.5 - lowest], [1.0, 0.0, 0.0, 0.0])


def test_the_view_shows_each_change_live(tmp_path, keep_screenshot):
    reference = read_layout(REFERENCE)
    with Served("--reference", str(REFERENCE), "--reference-time-limit", "0") as served, \
            httpx.Client(base_url=served.url, timeout=60) as http:
        sid = http.post("/sessions", json={"scene": "mini"}).json()["session"]
        with offline_page((served.url,), {"width": 1400, "height": 900}, "the view") as page:
            page.goto(f"{served.url}/sessions/{sid}/view")
            page.wait_for_function("() => window.shohaView && window.shohaView.version === 0",
                                   timeout=60_000)
            assert page.inner_text("#blocks") == "0"
            assert page.inner_text("#status") == "live"

            def lay(key: int, pose: Pose) -> dict:
                r = http.put(f"/sessions/{sid}/blocks/{key}",
                             json={**world_to_unity(pose, np.zeros(3)), "type": "shake-4t"})
                assert r.status_code == 200, r.text
                state = r.json()
                page.wait_for_function(f"() => window.shohaView.version === {state['version']}",
                                       timeout=30_000)
                return state

            # Three reference blocks: drawn grey, counted.
            for p in reference.blocks[:3]:
                state = lay(p.id, p.pose)
            assert state["protruding"] == [] and state["out_of_tolerance"] == []
            assert page.inner_text("#blocks") == "3"
            assert page.inner_text("#remaining") == str(state["remaining_blocks"])
            assert page.inner_text("#porosity") == f"{state['porosity_percent']:.2f} %"
            statuses = page.evaluate("window.shohaView.statuses")
            assert statuses == {str(p.id): "block" for p in reference.blocks[:3]}
            vertices = len(get_block("shake-4t").vertices)
            traces = page.evaluate("document.getElementById('plot').data"
                                   ".map(t => [t.name, t.color, t.x.length])")
            grey = [t for t in traces if t[0].startswith("blocks:")]
            assert grey == [["blocks: 3", COLOURS["block"], 3 * vertices]]
            before = page.locator("#plot").screenshot()

            # A block standing on the crest: yellow, and counted above the crest.
            state = lay(100, _standing_on_crest())
            assert state["protruding"] == [100]
            assert page.inner_text("#blocks") == "4"
            assert page.inner_text("#protruding") == "1"
            assert page.evaluate("window.shohaView.statuses")["100"] == "protruding"
            traces = page.evaluate("document.getElementById('plot').data"
                                   ".map(t => [t.name, t.color, t.x.length])")
            yellow = [t for t in traces if t[1] == COLOURS["protruding"]]
            assert len(yellow) == 1 and yellow[0][2] == vertices, traces
            page.wait_for_timeout(500)  # let WebGL draw the frame
            after = page.locator("#plot").screenshot()
            assert after != before

            # Taken out again: the page follows.
            r = http.delete(f"/sessions/{sid}/blocks/100")
            page.wait_for_function(f"() => window.shohaView.version === {r.json()['version']}",
                                   timeout=30_000)
            assert page.inner_text("#protruding") == "0" and page.inner_text("#blocks") == "3"
            state = lay(100, _standing_on_crest())

            shot = tmp_path / SCREENSHOT
            page.screenshot(path=str(shot))
    assert json.loads(json.dumps(state))["blocks"] == 4
    assert shot.stat().st_size > 30_000
    keep_screenshot(shot)
