"""Optimizer run time against block count, up to the full-scale scene.

``shoha optimize``'s default pipeline (beam, anneal, CP-SAT, settle) on
scenes of mini's cross-section and growing length: ``mini`` (75 blocks),
``mini-x4`` (300) and the built-in ``full`` (1005 blocks, 165 m); ``--x8``
adds ``mini-x8`` (600), which ``make bench`` leaves out for time. Each run
gets a 30-minute limit it should not need; the figures
are its wall time per phase, the validity of its result, and the fitted
log-log slope of time against block count (1 is linear).

The beam search restarts from several pattern origins on scenes of up to
100 blocks and from fewer on larger ones (``restarts * 100 / required``),
so ``mini`` costs more per block than the long scenes; the slope is fitted
over the long scenes, where the algorithm is the same.

Writes ``results/optimizer_scaling.{csv,json,png}``.
"""

from __future__ import annotations

import sys
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from common import BENCH, Run  # noqa: E402

from geometry.scene import load_scene  # noqa: E402
from optimizer.api import optimize  # noqa: E402

SCENES = ("mini", str(BENCH / "scenes" / "mini-x4.toml"), "full")
X8 = str(BENCH / "scenes" / "mini-x8.toml")
SEED = 1
LIMIT = 1800.0


def main() -> None:
    scenes = list(SCENES)
    if "--x8" in sys.argv[1:]:
        scenes.insert(2, X8)
    run = Run("optimizer_scaling", {"scenes": [load_scene(s).name for s in scenes], "seed": SEED,
                                    "time_limit_s": LIMIT})
    rows = []
    for spec in scenes:
        scene = load_scene(spec)
        t0 = time.perf_counter()
        r = optimize(scene, seed=SEED, time_limit=LIMIT)
        wall = time.perf_counter() - t0
        phases: dict[str, float] = {}  # seconds by strategy, summed over the run's attempts
        for p in r.phases:
            if "seconds" in p:
                phases[p["strategy"]] = round(phases.get(p["strategy"], 0.0) + p["seconds"], 1)
        row = {
            "scene": scene.name,
            "required_blocks": scene.required_blocks,
            "blocks": r.blocks,
            "seconds": round(wall, 1),
            "seconds_per_block": round(wall / scene.required_blocks, 3),
            "beam_s": phases.get("beam"),
            "anneal_s": phases.get("anneal"),
            "cpsat_s": phases.get("cpsat"),
            "settle_s": round(r.settle.get("seconds", 0.0), 1),
            "porosity_percent": round(r.porosity_percent, 3),
            "collisions": r.collisions,
            "out_of_tolerance": r.out_of_tolerance,
            "stable": r.stable,
            "valid": r.valid,
            "cpsat_gap_percent": round(r.gap.get("gap_percent", float("nan")), 4),
        }
        rows.append(row)
        print(row, flush=True)
    long = [r for r in rows if r["required_blocks"] > 100]
    slope = float(np.polyfit(np.log([r["required_blocks"] for r in long]),
                             np.log([r["seconds"] for r in long]), 1)[0])
    for r in rows:
        r["fitted_slope_long_scenes"] = round(slope, 3)
    run.csv("optimizer_scaling", rows)

    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    n = np.array([r["required_blocks"] for r in rows], float)
    t = np.array([r["seconds"] for r in rows], float)
    ax.loglog(n, t, "o-", label="shoha optimize (beam, anneal, CP-SAT, settle)")
    ref = n[-1] and t[-1] * n / n[-1]
    ax.loglog(n, ref, "k--", lw=0.8, label="linear in block count, through full")
    for r in rows:
        ax.annotate(f"{r['scene']}\n{r['seconds']:.0f} s", (r["required_blocks"], r["seconds"]),
                    textcoords="offset points", xytext=(6, -14), fontsize=8)
    ax.axhline(1200, color="r", lw=0.8, ls=":", label="20 min target for ~1000 blocks")
    ax.set_xlabel("blocks required")
    ax.set_ylabel("wall time (s)")
    ax.set_title(f"optimizer scaling, slope {slope:.2f} over the long scenes")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    run.figure("optimizer_scaling", fig)
    run.done()


if __name__ == "__main__":
    main()
