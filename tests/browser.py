"""Chromium for the tests that open shoha's pages (the HTML report, the live view).

Headless, and offline: a page may load only the URLs its test allows, and it
must log no console error. Both are checked when the page is closed.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import pytest

CHROMIUM = "/usr/bin/chromium"
#: Headless, and nothing that talks to the network (the machine may have none).
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run"]
#: What a page read from a file may load: itself and what it builds in memory.
LOCAL = ("file:", "data:", "blob:")


def chromium() -> str:
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


@contextmanager
def offline_page(allowed: tuple[str, ...], viewport: dict[str, int], what: str = "the page") -> Iterator[Any]:
    """A Chromium page that may load only URLs starting with one of ``allowed``.

    Any other request is aborted and recorded. On leaving, the test fails if
    there was one, or if the page logged a console error.
    """
    executable = chromium()
    from playwright.sync_api import sync_playwright

    errors: list[str] = []
    remote: list[str] = []
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=executable, args=FLAGS, headless=True)
        try:
            page = browser.new_page(viewport=viewport)
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))

            def only_allowed(route: Any) -> None:
                if route.request.url.startswith(allowed):
                    route.continue_()
                else:
                    remote.append(route.request.url)
                    route.abort()

            page.route("**/*", only_allowed)
            yield page
        finally:
            browser.close()
    assert remote == [], f"{what} asked the network for {remote}"
    assert errors == [], f"console errors: {errors}"
