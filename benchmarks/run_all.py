"""Run every benchmark in ``benchmarks/``, one process each, and record how long each took.

``make bench`` runs this. The order is fixed for the scripts named in
``ORDER`` (fast ones first); any other script in ``benchmarks/`` follows,
alphabetically, so a new benchmark is run without editing this file. Each
script writes its own results to ``benchmarks/results/``; this one adds
``run_all.csv`` and ``.json``: every script's wall time and exit status,
the total, and the machine; then ``summary.md``, the headline figures of
every result file (``summary.py``).

Run::

    .venv/bin/python benchmarks/run_all.py [--only NAME ...]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import summary
from common import BENCH, ROOT, Run

ORDER = ("porosity_speed", "paper_tables", "collision_speed", "speed_vs_accuracy", "scaling",
         "settle_speed", "score_speed", "optimizer_quality", "optimizer_scaling", "batch_cluster")
NOT_BENCHMARKS = {"common", "run_all", "summary"}


def scripts() -> list[Path]:
    """The benchmark scripts, in running order."""
    found = {p.stem: p for p in BENCH.glob("*.py") if p.stem not in NOT_BENCHMARKS}
    named = [found.pop(n) for n in ORDER if n in found]
    return named + sorted(found.values())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="*", default=None, help="script stems to run")
    args = parser.parse_args()
    todo = [p for p in scripts() if args.only is None or p.stem in args.only]
    run = Run("run_all", {"scripts": [p.stem for p in todo]})
    rows, failed = [], []
    start = time.perf_counter()
    for path in todo:
        print(f"\n=== {path.relative_to(ROOT)}", flush=True)
        t = time.perf_counter()
        status = subprocess.call([sys.executable, str(path)], cwd=ROOT)
        wall = time.perf_counter() - t
        rows.append({"script": path.name, "wall_s": wall, "exit_status": status})
        print(f"=== {path.name}: {wall:.1f} s, exit {status}", flush=True)
        if status:
            failed.append(path.name)
    total = time.perf_counter() - start
    rows.append({"script": "TOTAL", "wall_s": total, "exit_status": int(bool(failed))})
    run.params["total_wall_s"] = round(total, 1)
    run.csv("run_all", rows)
    summary.main()
    print(f"\nmake bench: {len(todo)} scripts in {total / 60:.1f} min"
          + (f"; FAILED: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
