"""Whether "no room was found" holds: every place on a grid tried where random drops found none.

Where ``shoha optimize`` ends short of its count, it says no room was found for
more: its pocket fill drew thousands of random drops over the mound, in every
hanging at random yaws, and let the most promising go, and none came to rest
inside the tolerance zone. Random drops can miss a narrow pocket. This study
lays a layout such a run wrote and lowers the scene's block at every node of a
grid over the fill window (``SWEEP_STEP`` of H apart), in each hanging at
``SWEEP_YAWS`` yaws over its symmetry's period, as the crane would: the refill's
own sweep (``optimizer.search.fill.sweep``), whose candidates are all let go
here, where the refill lets go only the best:

* a drop whose first contact leaves it inside the zone is *valid as lowered*;
* each such drop is let go among its fixed neighbours, as the search does
  (``physics.raised_check``; one on the bare foundation is kept where it
  touched): it *rests* if it comes to rest inside the zone;
* each distinct place where one rests is added to the layout, and the whole
  layout settled (MuJoCo, seed 0): it *stands* if the settle's verdict is stable.

Drops whose first contact is out of the zone (on a neighbour's shoulder) are
counted, not let go: the pocket fill lets the best of them go, and this study
asks only what a systematic search adds to that.

The layouts are the ones ``optimize`` writes at the default limit for the
cases named on the command line, ``SCENE:SEED`` (a built-in scene, one under
``benchmarks/scenes``, or ``wall-rough``, written by ``pattern_capacity.py``), or
``keep-scatter:SEED`` for ``mini`` completed from 30 random drops
(``benchmarks/keep.py``'s poor start).

Writes ``results/room_sweep.csv`` (one row per case), or ``results/STEM.csv`` with
``--stem``: ``room_sweep_46ae9e7.csv`` is the run at 46ae9e7, before ``optimize``'s
refills swept the mound themselves. That run laid its own grid, and counted every node's
drops; the product's sweep does not lower a block where it would cross the zone's ceiling
even on the foundation's lowest point, so ``drops`` now counts fewer for the same grid.

Run::

    python benchmarks/studies/room_sweep.py [CASE ...] [--stem STEM]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common import Run, mini  # noqa: E402
from pattern_capacity import scene_of  # noqa: E402

from optimizer.api import optimize  # noqa: E402
from optimizer.search.build import Build, fill_window  # noqa: E402
from optimizer.search.fill import SWEEP_STEP, SWEEP_YAWS  # noqa: E402
from optimizer.search.fill import sweep as grid_sweep  # noqa: E402
from optimizer.search.hangings import families  # noqa: E402
from optimizer.search.patterns import lattice_for  # noqa: E402
from optimizer.search.physics import raised_check  # noqa: E402
from optimizer.search.problem import Problem  # noqa: E402
from optimizer.search.scatter import scatter  # noqa: E402
from optimizer.search.shapes import ShapeCache  # noqa: E402
from settle import settle  # noqa: E402

CASES = ("wall-rough:1", "tetrapod-big:1", "keep-scatter:1")


def layout_of(case: str):
    """The scene and the layout ``optimize`` writes for ``case``, and what it said."""
    name, seed = case.rsplit(":", 1)
    if name == "keep-scatter":
        scene = mini()
        start = scatter(scene, 30, seed=1).layout({}).blocks
        r = optimize(scene, seed=int(seed), keep=start)
    else:
        scene = scene_of(name)
        r = optimize(scene, seed=int(seed))
    return scene, r


def sweep(scene, placements) -> dict:
    """Every grid drop onto ``placements`` (kept where they are), as the module says."""
    problem = Problem(scene=scene, required=scene.required_blocks, target=scene.target_porosity,
                      lattice=lattice_for(scene.block, scene.block_type), families=families(scene.block),
                      deadline=time.monotonic() + 1e6)
    build = Build(scene)
    for p in placements:
        build.keep(p.id, p.type, p.pose)
    t0 = time.perf_counter()
    # The product's own grid (``optimizer.search.fill.sweep``); every candidate it finds is let go
    # here, where the refill lets go only the best.
    found, drops, _ = grid_sweep(problem, build, ShapeCache(scene.block), fill_window(scene),
                                 np.random.default_rng(0))
    rested: dict[tuple, object] = {}
    for c in found:
        r = raised_check(problem, build, c)
        if r is not None:
            rested.setdefault(tuple(np.round(r.pose.position, 2)), r)
    valid = len(found)
    sweep_s = time.perf_counter() - t0
    stands = 0
    for r in rested.values():
        trial = build.copy()
        trial.place(r)
        stands += settle(scene, trial.placed(), seed=0).stable
    return {"drops": drops, "valid_as_lowered": valid, "rest_places": len(rested), "stand": stands,
            "sweep_s": round(sweep_s, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cases", nargs="*", default=list(CASES))
    parser.add_argument("--stem", default="room_sweep")
    args = parser.parse_args()
    run = Run("room_sweep", {"cases": args.cases, "step_h": SWEEP_STEP, "yaws": SWEEP_YAWS})
    rows = []
    for case in args.cases:
        scene, r = layout_of(case)
        row = {"case": case, "blocks": r.blocks, "required": r.required_blocks,
               "porosity_percent": round(r.porosity_percent, 2), "stable": r.stable,
               "said": next((line for line in r.summary().splitlines() if "room" in line), "")[:120]}
        row.update(sweep(scene, r.layout.blocks))
        rows.append(row)
        print(row, flush=True)
    run.csv(args.stem, rows)
    run.done()


if __name__ == "__main__":
    main()
