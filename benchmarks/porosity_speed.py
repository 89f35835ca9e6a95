"""How fast porosity is: issue 2's targets, on this machine.

Measures, with ``geometry.porosity`` (the one porosity module):

* ``exact`` on the collision-free 75-block reference layout of ``mini``
  (``benchmarks/layouts/mini-75.json``), twice: as ``shoha porosity`` runs it,
  searching for overlapping blocks first (``porosity(scene, placed)``), and as
  the optimizer calls it, told the blocks are disjoint
  (``exact_filled_volume(..., assume_disjoint=True)``). Target: under 20 ms.
* ``voxel`` (and ``voxel-any``, the paper's rule) at 50, 100, 150 and 200
  divisions on 25 blocks wholly inside ``mini`` (the paper's Fig. 16 setting,
  seed 0). Each call builds its grid, as the CLI does. Target at 200: under
  0.5 s (the paper's Table VI: 32.89 s).
* the incremental move of one block in a ``PorosityTracker`` holding the 75
  blocks, ``exact`` and ``voxel``: each block in turn is moved by up to 5 cm
  and 5 degrees (seed 0) and back. Target: under 2 ms.

Figures are medians of repeated calls after a warm-up call (imports, the
block's mesh and convex pieces, FCL's geometry are not the measured work),
in wall time; the CPU time of the same calls is saved beside it, since the
machine is shared and CPU time moves less with the load. The targets are
judged on wall time.

Run::

    .venv/bin/python benchmarks/porosity_speed.py

Writes ``benchmarks/results/porosity_speed.csv`` and ``.json`` (the machine).
"""

from __future__ import annotations

import numpy as np
from common import Run, Timing, jittered, mini, mini_reference, move_times, paper_layout, timed

from geometry.collision import collisions
from geometry.porosity import PorosityTracker, exact_filled_volume, porosity

TARGET_EXACT_MS = 20.0
TARGET_VOXEL_200_MS = 500.0
TARGET_MOVE_MS = 2.0
DIVISIONS = (50, 100, 150, 200)


def main() -> None:
    scene = mini()
    ref = mini_reference()
    p25 = paper_layout(25)
    run = Run("porosity_speed", {"layout_75": "benchmarks/layouts/mini-75.json",
                                 "layout_25": "random_inside(mini, 25, seed=0)",
                                 "move": "each block moved by up to 5 cm / 5 deg (seed 0) and back"})
    assert not collisions(ref), "the reference layout must be collision-free"
    rows = []

    def row(case, method, blocks, divisions, timing, percent, target_ms, note=""):
        rows.append({"case": case, "method": method, "blocks": blocks, "divisions": divisions,
                     "median_ms": timing.ms, "cpu_median_ms": 1e3 * timing.cpu_median,
                     "best_ms": 1e3 * timing.best, "worst_ms": 1e3 * timing.worst,
                     "repeats": timing.repeats, "porosity_percent": percent, "target_ms": target_ms,
                     "meets_target": "" if target_ms is None else timing.ms < target_ms, "note": note})
        print(f"{case:<34} {method:<10} {blocks:>4} blocks {divisions or '':>4}  "
              f"{timing.ms:10.3f} ms (CPU {1e3 * timing.cpu_median:8.3f} ms)  ({percent:.4f} %)")

    t, r = timed(lambda: porosity(scene, ref, "exact"), repeats=21, warmup=2)
    row("exact, overlap search (CLI)", "exact", len(ref), None, t, r.percent, TARGET_EXACT_MS)
    prism, v_b = scene.design.polytope, scene.design_volume
    t, filled = timed(lambda: exact_filled_volume(prism, ref, assume_disjoint=True), repeats=21, warmup=2)
    row("exact, assume_disjoint (optimizer)", "exact", len(ref), None, t, 100 * (v_b - filled) / v_b,
        TARGET_EXACT_MS)

    for method in ("voxel", "voxel-any"):
        for d in DIVISIONS:
            t, r = timed(lambda m=method, d=d: porosity(scene, p25, m, divisions=d), repeats=7, warmup=1)
            target = TARGET_VOXEL_200_MS if (method, d) == ("voxel", 200) else None
            row("full layout", method, len(p25), d, t, r.percent, target)

    moves = jittered(ref, shift=0.05, degrees=5.0, seed=0)
    for method, d in (("exact", None), ("voxel", 100), ("voxel", 200), ("voxel-any", 200)):
        tracker = PorosityTracker(scene, method, divisions=d)
        for key, block, pose in ref:
            tracker.add(key, block, pose)
        times = move_times(tracker, ref, moves, rounds=3)
        wall, cpu = times[:, 0], times[:, 1]
        timing_ = Timing(float(np.median(wall)), float(wall.min()), float(wall.max()), len(wall),
                         float(np.mean(cpu)))  # the mean: CPU clock ticks are coarser than one move
        row("incremental move of one block", method, len(ref), d, timing_, tracker.percent, TARGET_MOVE_MS,
            "PorosityTracker.move, median over every block moved and back, 3 rounds")

    run.csv("porosity_speed", rows)
    print()
    for r_ in rows:
        if r_["target_ms"] is not None:
            verdict = "meets" if r_["meets_target"] else "MISSES"
            print(f"{verdict} target {r_['target_ms']:g} ms: {r_['case']}, {r_['method']} "
                  f"{r_['divisions'] or ''} -> {r_['median_ms']:.3f} ms")
    run.done()


if __name__ == "__main__":
    main()
