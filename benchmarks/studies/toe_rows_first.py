"""Toe rows laid first, then the default search: what it does to count, porosity and coverage.

A study for issue 24 (not run by ``make bench``). docs/coverage-study.md found, on
``mini``'s finished reference, that blocks added later cannot reach the toes and
that rows along the toes must come first. This script makes that a search step
and measures it on whole runs: ``ToeRows`` (``optimizer.search.toe``, where the
step is described) lays one row along each toe (the seaward one only behind a
wall), then ``optimize``'s default strategies lay the rest around it, at the
default limit. Each scene and seed is also run without the rows, with the same
code, for the comparison. (``optimize`` itself now tries the rows in a later
attempt, with its strategies run around them and its beam leaving out the sites
the rows are in the way of, ``BeamSearch.around_laid``; this study, written before
that, lays them first in every run with a plain beam, and ``optimize``'s own
attempt may then lay a second set: its figures in docs/coverage-study.md are from
before the attempt existed.)

Nothing in it is tuned to a scene. Run::

    .venv/bin/python benchmarks/studies/toe_rows_first.py --scenes wall-shake mini --seeds 1 2 3

Writes ``benchmarks/results/toe_rows_first.{csv,json}``.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/common.py
from common import Run  # noqa: E402

from geometry.scene import load_scene  # noqa: I001
from optimizer.api import default_strategies, optimize
from optimizer.search.toe import ToeRows

SCENES_DIR = Path(__file__).resolve().parents[1] / "scenes"


def _scene(name: str):
    path = SCENES_DIR / f"{name}.toml"
    return load_scene(str(path) if path.exists() else name)


def one(job: tuple[str, int, bool]) -> dict:
    """One ``optimize`` run at the default limit, with or without the toe rows first."""
    name, seed, rows = job
    scene = _scene(name)
    strategies = ([ToeRows()] if rows else []) + default_strategies()
    r = optimize(scene, seed=seed, strategies=strategies, cover=not rows)
    c = r.coverage or {}
    toe = next((p for p in r.phases if p["strategy"] == "toe"), {})
    return {"scene": name, "seed": seed, "toe_rows": rows, "row_blocks": toe.get("placed", 0),
            "row_hangings": " / ".join(toe.get("hangings", [])), "blocks": r.blocks,
            "required": r.required_blocks, "porosity_percent": round(r.porosity_percent, 3),
            "points_off": round(r.porosity_percent - r.target_porosity_percent, 3), "valid": r.valid,
            "bare_share_percent": c.get("bare_share_percent"), "max_bare_m": c.get("max_bare_m"),
            "block_height_m": scene.block.height, "seconds": round(r.seconds, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=["wall-shake", "mini"])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    run = Run("toe_rows_first", vars(args))
    jobs = [(s, seed, rows) for s in args.scenes for seed in args.seeds for rows in (False, True)]
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(one, jobs))
    for r in rows:
        print(r)  # noqa: T201
    run.csv("toe_rows_first", rows)


if __name__ == "__main__":
    main()
