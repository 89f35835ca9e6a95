"""How long the optimizer's stability verdict takes, its two settles in turn and side by side.

``shoha optimize`` calls a layout stable only if it stands from two kicks: its own random one
and ``VERDICT_SEED``'s (``optimizer.search.physics.verdict``). On two cores or more the two
settles run side by side, each in its own thread (MuJoCo lets go of Python's lock while it
steps). This measures both ways on the layouts ``settle_speed.py`` uses (the 75 blocks of
``mini``'s reference; 300 and 1000 of the full-scale reference), and checks that they give
the same answer, pose for pose.

Each way is timed ``--repeats`` times (best kept) on the same random kick. Times are wall
clock; the machine may be shared, so the load average is saved with the results.

Run::

    .venv/bin/python benchmarks/verdict_speed.py
    .venv/bin/python benchmarks/verdict_speed.py --counts 75,300 --repeats 3

Writes ``benchmarks/results/verdict_speed.csv`` and ``verdict_speed.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from optimizer.search.patterns import lattice_for  # noqa: E402
from optimizer.search.physics import verdict  # noqa: E402
from optimizer.search.problem import Problem  # noqa: E402

sys.path.insert(0, str(ROOT / "benchmarks"))
from common import Run  # noqa: E402
from settle_speed import reference  # noqa: E402


def timed_verdict(scene, placed, side_by_side: bool) -> tuple[float, object]:
    """Seconds of one verdict on ``placed`` (the random kick drawn from seed 1), and its result."""
    problem = Problem(scene, len(placed), scene.target_porosity, lattice_for(scene.block, scene.block_type),
                      deadline=time.monotonic() + 3600.0)
    t = time.perf_counter()
    result = verdict(problem, placed, np.random.default_rng(1), side_by_side=side_by_side)
    return time.perf_counter() - t, result


def same(a, b) -> bool:
    """Whether two settle results agree pose for pose, bit for bit."""
    return a.stable == b.stable and [(x.id, x.pose.position.tobytes(), x.pose.quaternion.tobytes())
                                     for x in a.blocks] == [
        (x.id, x.pose.position.tobytes(), x.pose.quaternion.tobytes()) for x in b.blocks]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--counts", default="75,300,1000")
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args(argv)
    counts = [int(c) for c in args.counts.split(",")]
    run = Run("verdict_speed", {"counts": counts, "repeats": args.repeats})
    rows = []
    for n in counts:
        scene, placed = reference(n)
        times: dict[bool, list[float]] = {False: [], True: []}
        results = {}
        for _ in range(args.repeats):
            for side in (False, True):
                seconds, results[side] = timed_verdict(scene, placed, side)
                times[side].append(seconds)
        in_turn, side = min(times[False]), min(times[True])
        row = {"layout": "reference", "blocks": n, "scene": scene.name, "in_turn_s": round(in_turn, 3),
               "side_by_side_s": round(side, 3), "speedup": round(in_turn / side, 2),
               "stable": results[True].stable, "same_answer": same(results[False], results[True])}
        rows.append(row)
        print(f"{n:5d} blocks: in turn {in_turn:7.2f} s, side by side {side:7.2f} s ({in_turn / side:.2f}x), "
              f"stable {row['stable']}, same answer {row['same_answer']}", flush=True)
    run.csv("verdict_speed", rows)
    run.done()
    return 0 if all(r["same_answer"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
