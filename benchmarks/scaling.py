"""How compute time grows with the number of blocks: 10, 75, 300, 1000, 3000.

The layouts are the 75-block mini reference (its first 10 blocks for 10) and
copies of it laid end to end along the crest for 300, 1000 and 3000 blocks,
in scenes of mini's cross-section made as long as the copies need
(``benchmarks/scenes/mini-x{4,14,40}.toml``, ``common.tiled``): a long
breakwater filled the way the short one is. The copies neither collide nor
touch (checked here).

Timed, each through the module the CLI uses:

* ``exact`` porosity with its overlap search (``shoha porosity``), and with
  ``assume_disjoint`` (the optimizer's call);
* ``voxel`` porosity at a fixed voxel size of 0.1 m (the grid grows with the
  breakwater, as it must);
* the collision check (``geometry.collision.collisions``, ``shoha check``);
* the physics settle (``settle.settle``, MuJoCo, 2 s simulated, every step
  run: ``early_stop=False``). ``--settle-cap N`` makes layouts of more than
  N blocks simulate only 0.2 s (a tenth of the steps), for a quick run; such
  a figure is that time times 10, marked as extrapolated on the chart and
  left out of the fit. ``make bench`` runs without a cap.

Slopes are least-squares fits of log(time) on log(blocks) over 75 to 3000
blocks: a slope of 1 is linear growth.

Run::

    .venv/bin/python benchmarks/scaling.py [--settle-cap 1000]

Writes ``benchmarks/results/scaling.{csv,json,png}``.
"""

from __future__ import annotations

import argparse
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from common import Run, repeats_for, tiled, timed  # noqa: E402

from geometry.collision import collisions  # noqa: E402
from geometry.porosity import exact_filled_volume, porosity  # noqa: E402
from settle import settle  # noqa: E402

COUNTS = (10, 75, 300, 1000, 3000)
VOXEL_SIZE = 0.1  # metres
SETTLE_SECONDS = 2.0
#: With --settle-cap, layouts above the cap settle SETTLE_SHORT seconds, scaled up.
SETTLE_SHORT = 0.2
FIT_FROM = 75

SERIES = {
    "exact": ("exact porosity, overlap search (shoha porosity)", "black", "o"),
    "exact_disjoint": ("exact porosity, assume_disjoint (optimizer)", "0.5", "o"),
    "voxel": (f"voxel porosity, {VOXEL_SIZE} m voxels", "tab:blue", "s"),
    "collisions": ("collision check (shoha check)", "tab:green", "^"),
    "settle": (f"settle, MuJoCo, {SETTLE_SECONDS:g} s simulated", "tab:red", "D"),
}


def quick(fn) -> float:
    """Median seconds of ``fn`` after one warm-up call; repeats fit ~2 s."""
    t = time.perf_counter()
    fn()
    first = time.perf_counter() - t
    timing, _ = timed(fn, repeats=repeats_for(first, budget=2.0, lo=3, hi=11), warmup=0)
    return timing.median


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--settle-cap", type=int, default=None, metavar="N",
                        help=f"settle layouts above N blocks for {SETTLE_SHORT} s only, scaled up")
    cap = parser.parse_args().settle_cap
    run = Run("scaling", {"counts": COUNTS, "voxel_size_m": VOXEL_SIZE, "settle_seconds": SETTLE_SECONDS,
                          "settle_cap_blocks": cap, "settle_short_seconds": SETTLE_SHORT,
                          "layouts": "common.tiled(n): copies of layouts/mini-75.json along the crest",
                          "settle_seed": 0, "fit_from_blocks": FIT_FROM})
    rows = []
    for n in COUNTS:
        scene, placed = tiled(n)
        touching = collisions(placed, threshold=-1.0)
        assert not touching, f"tiled layout of {n} blocks has touching blocks"
        prism = scene.design.polytope
        row = {"blocks": n, "scene": scene.name, "scene_length_m": scene.length}
        row["exact_s"] = quick(lambda s=scene, p=placed: porosity(s, p, "exact"))
        row["exact_disjoint_s"] = quick(lambda pr=prism, p=placed: exact_filled_volume(pr, p, True))
        row["voxel_s"] = quick(lambda s=scene, p=placed: porosity(s, p, "voxel", voxel_size=VOXEL_SIZE))
        row["collisions_s"] = quick(lambda p=placed: collisions(p))
        row["exact_percent"] = porosity(scene, placed, "exact").percent
        simulated = SETTLE_SECONDS if cap is None or n <= cap else SETTLE_SHORT
        t = time.perf_counter()
        result = settle(scene, placed, seconds=simulated, seed=0, early_stop=False)
        wall = time.perf_counter() - t
        row.update({"settle_simulated_s": simulated, "settle_steps": result.steps, "settle_wall_s": wall,
                    "settle_s": wall * SETTLE_SECONDS / simulated,
                    "settle_extrapolated": simulated != SETTLE_SECONDS,
                    "settle_stable": result.stable, "settle_max_displacement_m": result.max_displacement_m})
        rows.append(row)
        print(f"{n:>5} blocks ({scene.name}): exact {1e3 * row['exact_s']:8.2f} ms  "
              f"disjoint {1e3 * row['exact_disjoint_s']:8.2f} ms  voxel {1e3 * row['voxel_s']:8.1f} ms  "
              f"collisions {1e3 * row['collisions_s']:8.1f} ms  settle {row['settle_s']:7.2f} s"
              + (f" (from {simulated} s simulated)" if row["settle_extrapolated"] else ""))

    slopes = {}
    for key in SERIES:
        pts = [(r["blocks"], r[f"{key}_s"]) for r in rows
               if r["blocks"] >= FIT_FROM and not (key == "settle" and r["settle_extrapolated"])]
        x, y = np.log10([p[0] for p in pts]), np.log10([p[1] for p in pts])
        slope, intercept = np.polyfit(x, y, 1)
        slopes[key] = (float(slope), float(intercept), [p[0] for p in pts])
    for r in rows:
        for key, (slope, _, _) in slopes.items():
            r[f"{key}_slope"] = slope
    run.params["slopes"] = {k: round(v[0], 3) for k, v in slopes.items()}
    run.csv("scaling", rows)
    chart(run, rows, slopes)
    for key, (slope, _, fitted) in slopes.items():
        print(f"slope {key:<15} {slope:5.2f}  (fit over {fitted[0]}-{fitted[-1]} blocks)")
    run.done()


def chart(run: Run, rows: list[dict], slopes: dict) -> None:
    fig, ax = plt.subplots(figsize=(9, 6.2))
    counts = np.array([r["blocks"] for r in rows])
    for key, (label, color, marker) in SERIES.items():
        ys = np.array([r[f"{key}_s"] for r in rows])
        measured = np.array([not (key == "settle" and r["settle_extrapolated"]) for r in rows])
        slope, intercept, fitted = slopes[key]
        ax.plot(counts[measured], ys[measured], marker=marker, color=color, lw=1.2,
                label=f"{label}: slope {slope:.2f}")
        if not measured.all():
            scale = SETTLE_SECONDS / SETTLE_SHORT
            ax.plot(counts[~measured], ys[~measured], marker=marker, color=color, mfc="white", lw=0, ms=8,
                    label=f"settle: {SETTLE_SHORT:g} s simulated x {scale:g} (extrapolated, not fitted)")
        fx = np.array([fitted[0], fitted[-1]])
        ax.plot(fx, 10 ** (intercept + slope * np.log10(fx)), color=color, ls="--", lw=0.8, alpha=0.6)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("blocks in the layout (log)")
    ax.set_ylabel("compute time (s, log)")
    ax.set_title("Time against block count: mini's section, reference layout tiled along the crest\n"
                 f"(dashed: least-squares fit in log-log over {FIT_FROM}+ blocks)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    run.figure("scaling", fig)
    plt.close(fig)


if __name__ == "__main__":
    main()
