"""Toe rows laid first, then the default search: what it does to count, porosity and coverage.

A study for issue 24 (not run by ``make bench``). docs/coverage-study.md found, on
``mini``'s finished reference, that blocks added later cannot reach the toes and
that rows along the toes must come first. This script makes that a search step
and measures it on whole runs: ``ToeRows`` (below) lays one row along each toe
(the seaward one only behind a wall), then ``optimize``'s default strategies lay
the rest around it, at the default limit. Each scene and seed is also run
without the rows, with the same code, for the comparison.

The step, for each toe:

1. at mid-length, each hanging of the block at ``yaws`` yaws over its
   symmetry's period is lowered as far out towards the toe as it rests
   inside the zone (bisection, to ``RESOLUTION`` of H);
2. of those whose surface comes within ``REACH`` of H / 2 of the design toe
   line, the one with the most volume inside the design prism is kept; if
   none does, the nearest;
3. the row is laid from one end of the zone to the other, each block as near
   the one before as it lands on the ground, as far out as fits there.

Nothing in it is tuned to a scene. Run::

    .venv/bin/python benchmarks/studies/toe_rows_first.py --scenes wall-shake mini --seeds 1 2 3

Writes ``benchmarks/results/toe_rows_first.{csv,json}``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/common.py
from common import Run  # noqa: E402

from geometry.coverage import BARE_FRACTION, distance_to_block  # noqa: I001
from geometry.scene import load_scene
from optimizer.api import default_strategies, optimize
from optimizer.search.build import GROUND, Build, Candidate
from optimizer.search.drop import Shape
from optimizer.search.hangings import symmetry
from optimizer.search.physics import raised_check
from optimizer.search.problem import Phase, Problem, Stats, Strategy
from optimizer.search.shapes import ShapeCache

SCENES_DIR = Path(__file__).resolve().parents[1] / "scenes"


#: A hanging is said to reach the toe when its surface comes within this share of the bare
#: distance of the design toe line (the toe between two blocks of a row lies a little further).
REACH = 0.9
#: How finely the outermost place is found, as a share of the block height.
RESOLUTION = 0.01
#: Steps along the row from one block to the next, as a share of the block height.
ROW_STEP = 0.03


@dataclass(frozen=True)
class ToeStats(Stats):
    """Figures of the toe rows.

    Attributes
    ----------
    placed : int
        Blocks laid in the rows.
    hangings : tuple of str
        The hanging and yaw (degrees) of each side's row.
    reach_m : tuple of float
        How near each row's block at mid-length comes to the design toe line.
    """

    placed: int = 0
    hangings: tuple[str, ...] = ()
    reach_m: tuple[float, ...] = ()


class ToeRows(Strategy):
    """Lay a row of blocks along each toe (the seaward one only behind a wall).

    Parameters
    ----------
    accept : callable, optional
        ``accept(problem, build, candidate) -> Candidate | None``, as the beam
        search's: where a row block comes to rest (on a rough underlayer).
    yaws : int
        Yaws tried per hanging, over one period of its symmetry.
    """

    name = "toe"

    def __init__(self, accept: Callable[[Problem, Build, Candidate], Candidate | None] | None = None,
                 yaws: int = 12):
        self.accept = accept
        self.yaws = yaws

    def run(self, problem: Problem, previous: Phase | None, rng: np.random.Generator) -> Phase:
        build = previous.build.copy() if previous is not None else Build(problem.scene)
        origin = previous.origin if previous is not None else None
        shapes = ShapeCache(problem.scene.block)
        design = problem.scene.design
        sides = (1.0,) if design.wall_x is not None else (1.0, -1.0)
        placed, names, reach = 0, [], []
        for side in sides:
            if problem.time_left() <= 0:
                break
            chosen = self._hanging(problem, build, shapes, side)
            if chosen is None:
                continue
            fam, yaw, dist = chosen
            names.append(f"{fam} {np.degrees(yaw):.0f}")
            reach.append(dist)
            placed += self._row(problem, build, shapes, side, fam, yaw)
        return Phase(build, ToeStats(placed, tuple(names), tuple(reach)), origin)

    # --- which hanging ---------------------------------------------------------------

    def _hanging(self, problem: Problem, build: Build, shapes: ShapeCache,
                 side: float) -> tuple[str, float, float] | None:
        """The (hanging, yaw, distance to the toe) a row should be laid in, or None if none fits."""
        scene = problem.scene
        block, design = scene.block, scene.design
        y = 0.5 * (design.y_start + design.y_end)
        toe = np.array([[side * design.bottom_half_width, y, design.z_bottom]])
        limit = REACH * BARE_FRACTION * block.height
        found = []
        for fam in problem.families:
            if fam == "free":
                continue
            period = 2 * np.pi / symmetry(block, fam)
            for yaw in np.arange(self.yaws) * period / self.yaws:
                c = _outermost(problem, build, shapes.hung(fam, float(yaw)), side, y)
                if c is None:
                    continue
                dist = float(distance_to_block(toe, block, c.pose)[0])
                found.append((max(dist, limit), -c.inside, dist, fam, float(yaw)))
        if not found:
            return None
        _, _, dist, fam, yaw = min(found)
        return fam, yaw, dist

    # --- the row ---------------------------------------------------------------------------

    def _row(self, problem: Problem, build: Build, shapes: ShapeCache, side: float, fam: str,
             yaw: float) -> int:
        """Lay the row from the zone's start to its end; returns how many blocks it placed."""
        zone = problem.scene.tolerance
        h = problem.scene.block.height
        shape = shapes.hung(fam, yaw)
        width = float(shape.xy_boxes[:, 1, 1].max() - shape.xy_boxes[:, 0, 1].min())
        y, placed = zone.y_start, 0
        while y <= zone.y_end and len(build) < problem.required and problem.time_left() > 0:
            c = _outermost(problem, build, shape, side, y)
            if c is not None and c.support == (GROUND,) and self.accept is not None:
                c = self.accept(problem, build, c)
            if c is None or GROUND not in c.support:
                y += ROW_STEP * h
                continue
            build.place(c)
            placed += 1
            problem.tell(self.name, build, f"{len(build)} placed")
            # The next block cannot stand nearer than this one's half width along the row.
            y = float(c.pose.position[1]) + 0.5 * width + ROW_STEP * h
        return placed


def _outermost(problem: Problem, build: Build, shape: Shape, side: float, y: float
               ) -> Candidate | None:
    """The block lowered at ``y`` as far out towards the ``side`` toe as it rests inside the zone."""
    zone = problem.scene.tolerance
    h = problem.scene.block.height
    lo, hi = 0.0, float(zone.bottom_half_width)
    inner = build.lower(shape, side * lo, y)
    # From the axis outwards, the first place it fits (a mound's core may be taken already).
    step = 0.25 * h
    while inner is None and lo < hi:
        lo += step
        inner = build.lower(shape, side * lo, y)
    if inner is None:
        return None
    # Then bisect between the last place it fits and the zone's edge.
    best = inner
    while hi - lo > RESOLUTION * h:
        mid = 0.5 * (lo + hi)
        c = build.lower(shape, side * mid, y)
        if c is None:
            hi = mid
        else:
            lo, best = mid, c
    return best


def _scene(name: str):
    path = SCENES_DIR / f"{name}.toml"
    return load_scene(str(path) if path.exists() else name)


def one(job: tuple[str, int, bool]) -> dict:
    """One ``optimize`` run at the default limit, with or without the toe rows first."""
    name, seed, rows = job
    scene = _scene(name)
    strategies = ([ToeRows(accept=raised_check)] if rows else []) + default_strategies()
    r = optimize(scene, seed=seed, strategies=strategies)
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
