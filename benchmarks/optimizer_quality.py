"""Optimizer quality against the time budget, beside what a user would otherwise do.

On ``mini`` (75 Shake Blocks, 56 % target), for time budgets of 5 to 40 s:

* ``beam``: beam search alone (then the physics confirmation);
* ``beam+anneal``: beam search, then simulated annealing;
* ``random drop``: the baseline of dropping random blocks and settling them,
  as one would in Blender or Bullet (``settle.pour``: 75 blocks in batches,
  each batch settled in MuJoCo on the pile below). It has no budget to give;
  it is plotted at the time it took.

Each result is checked the same way (``geometry.checks``, and a settle):
porosity error ``|porosity - 56|`` in points, and violations = blocks short
of 75 + colliding pairs + blocks out of tolerance + unstable blocks.

Writes ``results/optimizer_quality.{csv,json,png}``. Seeds are fixed.
"""

from __future__ import annotations

import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from common import Run, mini  # noqa: E402

from geometry.checks import check_layout  # noqa: E402
from optimizer.api import optimize  # noqa: E402
from optimizer.search.anneal import Annealing  # noqa: E402
from optimizer.search.beam import BeamSearch  # noqa: E402
from optimizer.search.physics import raised_check, stands  # noqa: E402
from settle import settle  # noqa: E402
from settle.pour import pour  # noqa: E402

BUDGETS = (5.0, 10.0, 20.0, 40.0)
SEED = 1

CONFIGS = {
    "beam": lambda: [BeamSearch(accept=raised_check, judge=stands)],
    "beam+anneal": lambda: [BeamSearch(accept=raised_check, judge=stands), Annealing(accept=raised_check)],
}


def judge(scene, placed, seconds: float, name: str, budget: float | None) -> dict:
    report = check_layout(scene, placed)
    verdict = settle(scene, placed, seed=0)
    unstable = len(verdict.unstable_ids)
    violations = (max(0, scene.required_blocks - len(placed)) + len(report.collisions)
                  + len(report.out_of_tolerance) + unstable)
    return {
        "method": name,
        "budget_s": budget,
        "seconds": round(seconds, 2),
        "blocks": len(placed),
        "porosity_percent": round(report.porosity_percent, 3),
        "porosity_error": round(abs(report.porosity_percent - scene.target_porosity), 3),
        "collisions": len(report.collisions),
        "out_of_tolerance": len(report.out_of_tolerance),
        "unstable": unstable,
        "violations": violations,
        "valid": violations == 0,
    }


def chart(rows: list[dict]) -> plt.Figure:
    """Porosity error and violations against the budget, the random drop at its own time."""
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.6))
    for name in CONFIGS:
        pts = [r for r in rows if r["method"] == name]
        a.plot([r["budget_s"] for r in pts], [r["porosity_error"] for r in pts], "o-", label=name)
        b.plot([r["budget_s"] for r in pts], [r["violations"] for r in pts], "o-", label=name)
    base = [r for r in rows if r["method"] == "random drop"]
    for ax, key in ((a, "porosity_error"), (b, "violations")):
        if base:
            ax.plot([base[0]["seconds"]], [base[0][key]], "k^", ms=9,
                    label="random drop + settle (at the time it took)")
        ax.set_xlabel("time budget (s)")
        ax.grid(alpha=0.3)
        ax.set_yscale("symlog", linthresh=1.0)
        ax.legend(fontsize=8)
    a.set_ylabel("porosity error |porosity - 56 %| (points)")
    a.set_title("porosity error", fontsize=10)
    b.set_ylabel("violations (count)")
    b.set_title("violations: blocks missing + colliding pairs\n+ blocks out of tolerance + unstable blocks",
                fontsize=9)
    fig.suptitle("shoha optimize on mini: quality against time budget (seed 1)", y=0.98)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    return fig


def replot() -> None:
    """Redraw the chart from ``results/optimizer_quality.csv`` (``--replot``), measuring nothing."""
    import csv

    from common import RESULTS

    with (RESULTS / "optimizer_quality.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    for r in rows:
        for k in ("budget_s", "seconds", "porosity_error", "violations"):
            r[k] = float(r[k]) if r[k] != "" else None
    import json

    m = json.loads((RESULTS / "optimizer_quality.json").read_text())["machine"]
    fig = chart(rows)
    # The caption Run.figure gives a chart, from the run that measured the rows.
    fig.text(0.995, 0.995, f"{m['cpu_model']}, {m['cores']} cores, load {m['load_average'][0]}, "
             f"shoha {m['commit']}, {m['date'][:10]}", ha="right", va="top", fontsize=7, color="0.4")
    fig.savefig(RESULTS / "optimizer_quality.png", dpi=130)


def main() -> None:
    scene = mini()
    run = Run("optimizer_quality", {"scene": "mini", "seed": SEED, "budgets_s": BUDGETS})
    rows = []
    for name, make in CONFIGS.items():
        for budget in BUDGETS:
            t0 = time.perf_counter()
            r = optimize(scene, seed=SEED, time_limit=budget, strategies=make())
            row = judge(scene, r.layout.placed(), time.perf_counter() - t0, name, budget)
            rows.append(row)
            print(row, flush=True)
    t0 = time.perf_counter()
    poured = pour(scene, scene.required_blocks, seed=SEED)
    row = judge(scene, poured, time.perf_counter() - t0, "random drop", None)
    rows.append(row)
    print(row, flush=True)
    run.csv("optimizer_quality", rows)
    run.figure("optimizer_quality", chart(rows))
    run.done()


if __name__ == "__main__":
    import sys

    replot() if "--replot" in sys.argv[1:] else main()
