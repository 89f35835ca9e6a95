"""The README and docs: every link and path they name is in the repository, and exists.

A user's clone has only the repository, so a link that leaves it is dead.
Checked: Markdown links and images, and paths in backticks that look like
files of the repository (``geometry/porosity.py``, ``docs/scoring.md``).
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

from tests.conftest import ROOT

PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
#: A backticked path of the repository: starts with one of its top folders, ends in a file suffix.
PATH = re.compile(r"`((?:geometry|settle|optimizer|benchmarks|tests|docs|scenes|\.ci)/[\w./-]+\.\w+)`")


def _targets(page: Path) -> list[tuple[str, Path]]:
    text = page.read_text()
    out = []
    for link in LINK.findall(text):
        if re.match(r"^[a-z]+:", link) or link.startswith("#"):
            continue  # an address elsewhere (none expected) or an anchor on the page
        out.append((link, (page.parent / link.split("#")[0]).resolve()))
    for path in PATH.findall(text):
        out.append((path, (ROOT / path).resolve()))
    return out


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_link_and_path_stays_in_the_repository_and_exists(page):
    targets = _targets(page)
    outside = [link for link, target in targets if not target.is_relative_to(ROOT)]
    missing = [link for link, target in targets if target.is_relative_to(ROOT) and not target.exists()]
    assert outside == [], f"{page.name} links outside the repository: {outside}"
    assert missing == [], f"{page.name} names files that do not exist: {missing}"


def test_no_tracked_file_names_a_path_outside_the_repository():
    tracked = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True)
    hits = []
    for name in tracked.stdout.split():
        path = ROOT / name
        if name == "tests/test_docs.py":
            continue  # this test names what it looks for
        if path.suffix not in (".py", ".md", ".toml", ".txt", "") or not path.is_file():
            continue
        text = path.read_text(errors="ignore")
        if "../shared" in text or "CONTRACT.md" in text:
            hits.append(name)
    assert hits == [], f"these files point outside the repository: {hits}"


def test_the_readme_links_the_contract():
    assert "(docs/contract.md)" in (ROOT / "README.md").read_text()
