"""Does the score order layouts the way a trainer would? A ladder of saves of ``mini``, scored (issue 26).

The ladder, all against the 75-block reference (``benchmarks/layouts/mini-75.json``):

* nothing laid;
* the reference's first 10, 30, 50 and all 75 blocks in crane order;
* the random-drop baseline: ``settle.pour.pour(mini, 75, seed=1)``, the pile of
  ``benchmarks/optimizer_quality.py``;
* the reference with 1, 5 and 20 faults of each kind (tests/perturb.py): blocks
  lifted out of tolerance, pairs pushed together, blocks stood on a leg tip,
  the last blocks missing, and blocks nudged by a hand on the joystick
  (3 cm, 2 degrees). Where a fault's rule finds fewer blocks to put it in
  than asked, the row says how many it put in.

Each save is scored by ``optimizer.score.score`` with the default weights, as
``shoha score`` scores it. The score, its two parts (progress and quality) and
each penalty's points go to ``benchmarks/results/score_ordering.csv``, the chart
to ``score_ordering.png``.

Run::

    .venv/bin/python benchmarks/score_ordering.py
"""

from __future__ import annotations

import sys
import time

import numpy as np
from common import MINI_75, Run

from geometry.layout import read_layout
from optimizer.score import Reference, score
from settle.pour import pour
from tests.perturb import (
    jitter,
    lift_out_of_tolerance,
    push_together,
    remove_last,
    repeated,
    stand_on_leg_tip,
)

PREFIXES = (10, 30, 50, 75)
COUNTS = (1, 5, 20)
POUR_SEED = 1
JITTER_SEED = 0
PENALTIES = ("tolerance", "collisions", "stability", "porosity", "interlock", "coverage", "time")


def ladder(scene, reference):
    """(group, rung name, faults asked, faults put in, blocks) in ladder order."""
    placed = reference.placed()
    yield "progress", "empty", 0, 0, []
    for n in PREFIXES:
        yield "progress", f"first {n}", 0, 0, placed[:n]
    yield "baseline", f"random drop (pour, seed {POUR_SEED})", 0, 0, pour(scene, len(placed), seed=POUR_SEED)
    kinds = (("out of tolerance", lift_out_of_tolerance), ("pushed together", push_together),
             ("on a leg tip", stand_on_leg_tip))
    for label, fault in kinds:
        for count in COUNTS:
            layout, touched = repeated(fault, scene, reference, count)
            yield label, f"{count} {label}", count, len(touched), layout.placed()
    for count in COUNTS:
        yield "missing", f"{count} missing", count, count, remove_last(reference, count)[0].placed()
    for count in COUNTS:
        layout, _ = jitter(reference, np.random.default_rng(JITTER_SEED), count)
        yield "nudged", f"{count} nudged", count, count, layout.placed()


def chart(run: Run, rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {"progress": "#4c72b0", "baseline": "#c44e52", "out of tolerance": "#dd8452",
               "pushed together": "#8172b3", "on a leg tip": "#937860", "missing": "#55a868",
               "nudged": "#64b5cd"}
    fig, ax = plt.subplots(figsize=(9.5, 0.34 * len(rows) + 1.4))
    y = np.arange(len(rows))[::-1]
    ax.barh(y, [r["score"] for r in rows], color=[colours[r["group"]] for r in rows], height=0.7,
            label="score")
    ax.scatter([r["progress_percent"] for r in rows], y, marker="|", s=160, color="black", zorder=3,
               label="progress %")
    ax.scatter([r["quality"] for r in rows], y, marker="o", s=22, facecolor="white", edgecolor="black",
               zorder=3, label="quality %")
    for yi, r in zip(y, rows, strict=True):
        ax.text(103.0, yi, f"{r['score']:.1f}", va="center", ha="left", fontsize=8)
    ax.set_yticks(y, [r["rung"] + ("" if r["faults_put_in"] == r["faults_asked"]
                                   else f" ({r['faults_put_in']} fit)") for r in rows], fontsize=8)
    ax.set_xlim(0, 111)
    ax.axvline(101.5, color="0.6", lw=0.6)
    ax.set_xlabel("score out of 100 (bar) = progress x quality / 100")
    ax.set_title("shoha score on a ladder of mini saves against the seed-1 reference", fontsize=10)
    ax.legend(loc="lower right", fontsize=8)
    ax.grid(axis="x", alpha=0.3)
    fig.tight_layout()
    run.figure("score_ordering", fig)
    plt.close(fig)


def main() -> int:
    reference = read_layout(MINI_75)
    scene = reference.load_scene()
    run = Run("score_ordering", {"layout": MINI_75.name, "prefixes": PREFIXES, "counts": COUNTS,
                                 "pour_seed": POUR_SEED, "jitter_seed": JITTER_SEED,
                                 "weights": "ScoreWeights() defaults"})
    ref = Reference.of(scene, reference.placed())
    rows = []
    for group, rung, asked, put_in, placed in ladder(scene, reference):
        t = time.perf_counter()
        result = score(scene, placed, ref)
        seconds = time.perf_counter() - t
        d = result.to_dict()
        points = {p["name"]: p["points"] for p in d["penalties"]}
        rows.append({
            "group": group, "rung": rung, "faults_asked": asked, "faults_put_in": put_in,
            "blocks": d["blocks"], "score": d["score"], "progress_percent": d["progress_percent"],
            "quality": d["quality"], "penalty_points": d["penalty_points"],
            "out_of_tolerance": len(d["out_of_tolerance"]), "collisions": len(d["collisions"]),
            "unstable": len(d["unstable_blocks"]),
            "finished_porosity_percent": d["finished"]["porosity_percent"],
            "finished_poorly_interlocked": d["finished"]["poorly_interlocked"],
            "finished_bare_share_percent": d["finished"]["bare_share_percent"],
            **{f"points_{name}": points[name] for name in PENALTIES},
            "score_seconds": seconds,
        })
        charged = ", ".join(f"{k} {v:.1f}" for k, v in points.items() if v)
        print(f"{rung:32s} {d['blocks']:3d} blocks  score {d['score']:5.1f} = progress "
              f"{d['progress_percent']:5.1f} x quality {d['quality']:5.1f}  "
              f"({d['penalty_points']:6.1f} points: {charged})", flush=True)
    run.csv("score_ordering", rows)
    chart(run, rows)
    run.done()
    return 0


if __name__ == "__main__":
    sys.exit(main())
