"""The import direction, enforced by import-linter (pyproject.toml, ``[tool.importlinter]``).

``optimizer`` may import ``settle`` and ``geometry``, ``settle`` may import
``geometry``, never the other way, and no module or subpackage is in an
import cycle with a sibling. The second test breaks a copy of the code on
purpose, to show that the check can fail.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import ROOT

LINT = Path(sys.executable).parent / "lint-imports"


def _lint(cwd: Path) -> subprocess.CompletedProcess:
    # lint-imports finds the packages on sys.path: the folder it runs in comes first.
    env = {"PYTHONPATH": str(cwd), "PATH": str(Path(sys.executable).parent)}
    return subprocess.run([str(LINT), "--no-cache"], cwd=cwd, capture_output=True, text=True, env=env,
                          timeout=120)


def test_the_import_contracts_hold():
    r = _lint(ROOT)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "2 kept, 0 broken" in r.stdout


@pytest.mark.parametrize("module, line, broken", [
    ("geometry/constants.py", "import settle.base  # noqa", "never the other way"),
    ("optimizer/search/beam.py", "from optimizer.search import physics  # noqa",
     "no import cycle between sibling modules or subpackages, at any depth"),
])
def test_a_wrong_import_breaks_a_contract(tmp_path, module, line, broken):
    for package in ("geometry", "settle", "optimizer"):
        shutil.copytree(ROOT / package, tmp_path / package, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    target = tmp_path / module
    target.write_text(target.read_text() + f"\n{line}\n")
    r = _lint(tmp_path)
    assert r.returncode != 0
    words = " ".join(r.stdout.split())  # contract names wrap across lines
    assert f"{broken} BROKEN" in words and "1 kept, 1 broken" in words, r.stdout
