"""Can ``mini`` meet the block count, the porosity window and the coverage at once? (issue 24)

Issue 24 asks for layouts with the required count, porosity within 1 point of
the target, and at most 5 % of the slopes and crest bare (more than H/2 from
every block; ``geometry.coverage``), no point further than H from a block.
The seed-1 reference layout of ``mini`` (``tests/data/mini-reference.json``)
meets the first two and leaves its toes bare. This script measures what
covering them costs, on that layout:

* the reference as it is: bare share (in all and by face), largest bare
  distance, exact porosity, validity, the settle verdict;
* blocks added one at a time where the surface is bare, as the crane lays
  them: each candidate is a block in one of the crane's hangings at a few
  yaws, lowered at a node of a ``GRID`` m grid within ``REACH`` m
  (horizontally) of a bare sample until it first touches, and let go among
  its neighbours (``optimizer.search.physics.settle_in``, the optimizer's
  own check), which keeps it where it comes to rest only if that is inside
  the tolerance zone, pressing into nothing. A first contact out of the zone
  is let go too (``Build.lower(..., loose=True)``): it may slide into a
  pocket. Candidates are ranked by a cheap bound on the bare area they cover
  (block surface samples within H/2 of a bare sample); the ``SETTLE_TOP``
  best are let go, the ``VERIFY_TOP`` best resting ones are measured with the
  exact coverage, and the one that leaves the least bare area is placed. The
  reference blocks stay where they are, first in crane order. After each
  block: count, exact porosity, bare share (in all and by face), largest bare
  distance, validity (``geometry.checks.check_layout``: tolerance and
  collisions), and every ``SETTLE_EVERY`` blocks and at the end the
  whole-layout settle verdict (``settle.settle``, seed 0). It stops when
  coverage is met (bare <= 5 % and largest bare <= H), after ``MAX_ADDED``
  blocks, or when no candidate lowers the bare area;
* the porosity the added blocks cost: the porosity when coverage is first
  met, and how many blocks wholly inside the design prism would have to come
  out to bring it back to the target, or to 1 point under it (arithmetic
  from the blocks' volume inside the prism); then those blocks taken out in
  fact, each the one of the ``REMOVE_TOP`` highest blocks that carry nothing
  and lie wholly inside the prism whose removal bares least, while coverage
  holds, and the result settled (only if coverage was met);
* toe rows laid first: for each hanging, the yaw (of ``ROW_YAWS``) whose
  outermost valid block on the empty foundation comes nearest the design toe
  line, and a row of such blocks along each toe (``toe_rows``); then the
  reference with the rows, overlapping it, and with the reference blocks
  they interpenetrate taken out: count, porosity, coverage, validity, settle,
  and the lowest porosity the blocks still short of the count could give,
  each wholly inside the prism.

Writes ``results/toe_coverage.{csv,json}``: one row per layout (``stage``
``reference``, ``added``, ``removed``, ``toe row``, ``reference + rows``,
``rows, hit out``), with the arithmetic in the JSON's params.

* with ``--optimize``: the optimizer's default pipeline (and limit) laying the
  rest of the mound around each hanging's toe rows, which it keeps where they
  are (as ``shoha optimize --keep``), seeds 1, 2 and 3: count, porosity,
  coverage, validity (about 10 minutes more).

Run::

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/studies/toe_coverage.py [--optimize]

It is a study, not a benchmark: ``make bench`` does not run it (it takes
minutes). Its findings are written up in docs/coverage-study.md.
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/common.py
from common import ROOT, Run  # noqa: E402

from geometry.checks import check_layout  # noqa: I001
from geometry.clip import volume_inside
from geometry.collision import world_of
from geometry.coverage import CoverageReport, coverage, distance_to_block
from geometry.layout import read_layout
from geometry.porosity import porosity
from geometry.scene import Scene
from optimizer.search.build import Build, Candidate
from optimizer.search.cover import BareArea
from optimizer.search.drop import Shape
from optimizer.search.hangings import families, hanging_of, spread_yaws, symmetry
from optimizer.search.patterns import lattice_for
from optimizer.search.physics import settle_in
from optimizer.search.problem import Problem
from settle import settle

REFERENCE = ROOT / "tests" / "data" / "mini-reference.json"
#: Spacing of the candidate grid, m.
GRID = 0.5
#: Candidate nodes lie within this horizontal distance of a bare sample, m: a block's
#: centroid sits up to about its footprint radius (1.09 m for the Shake Block) from what it covers.
REACH = 1.2
#: Yaws per hanging, spread over its symmetry period.
YAWS = 2
#: Candidates let go per step (the best by the bound; None: all), and resting ones measured exactly.
SETTLE_TOP = None
VERIFY_TOP = 3
#: Most blocks added; the whole layout is settled every this many.
MAX_ADDED = 30
SETTLE_EVERY = 5
#: Coverage met (issue 24).
BARE_LIMIT = 5.0
#: Removal: the highest free blocks wholly inside the prism tried per block taken out.
REMOVE_TOP = 6
#: A block is wholly inside when this share of its volume is.
WHOLE = 0.999
#: Bands of distance from the axis reported on the slopes, m (the toes are at 6 m).
BANDS = ((4.5, 5.0), (5.0, 5.5), (5.5, 6.0))
#: Toe rows: yaws tried per hanging and the step of the sweeps, m.
ROW_YAWS = 24
ROW_STEP = 0.02
#: With ``--optimize``: the seeds of the optimizer's runs around the toe rows.
OPTIMIZE_SEEDS = (1, 2, 3)
#: A lowering or a let-go is measured again when the block placed last is this close, m
#: (horizontally for lowerings: two footprint radii and a margin; in 3D for let-gos, whose
#: neighbours are those within 2.5 bounding radii).
LOWER_RADIUS = 2.4
SETTLE_RADIUS = 4.0


def measure(scene: Scene, placed: list, stage: str, added: int, settled: bool | None = None,
            cov: CoverageReport | None = None, extra: dict | None = None) -> tuple[dict, CoverageReport]:
    """One row: count, exact porosity, coverage, validity and (when asked) the settle verdict."""
    cov = cov if cov is not None else coverage(scene, placed)
    check = check_layout(scene, placed, with_coverage=False)
    faces = cov.by_face()
    row = {"stage": stage, "added": added, "blocks": len(placed),
           "porosity_percent": round(porosity(scene, placed, "exact").percent, 3),
           "bare_share_percent": round(cov.bare_share_percent, 3),
           "max_bare_m": round(cov.max_bare_m, 3),
           "seaward_bare_percent": round(faces.get("seaward slope", float("nan")), 2),
           "crest_bare_percent": round(faces.get("crest", float("nan")), 2),
           "landward_bare_percent": round(faces.get("landward slope", float("nan")), 2),
           **band_shares(cov),
           "out_of_tolerance": len(check.out_of_tolerance), "collisions": len(check.collisions),
           "valid": not check.out_of_tolerance and not check.collisions,
           "stable": "" if settled is None else settled}
    row.update(extra or {})
    return row, cov


def band_shares(cov: CoverageReport) -> dict[str, float]:
    """Bare share (percent) of the slopes in each band of distance from the axis (``BANDS``)."""
    s = cov.samples
    ax = np.abs(s.points[:, 0])
    out = {}
    for lo, hi in BANDS:
        on = (s.face != 1) & (ax >= lo) & (ax < hi) & (s.area > 0)
        share = 100 * s.area[on & cov.bare].sum() / s.area[on].sum()
        out[f"bare_{lo:g}_{hi:g}_percent"] = round(float(share), 1)
    return out


def stable(scene: Scene, placed: list) -> tuple[bool, list]:
    result = settle(scene, placed, seed=0)
    return bool(result.stable), sorted(result.unstable_ids)


def show(row: dict) -> None:
    print(f"{row['stage']:9} +{row['added']:<3} {row['blocks']:4} {row['porosity_percent']:8.2f} "
          f"{row['bare_share_percent']:7.2f} {row['max_bare_m']:6.2f} "
          f"{row['seaward_bare_percent']:7.1f} {row['crest_bare_percent']:6.1f} "
          f"{row['landward_bare_percent']:7.1f} {row['valid']!s:6} {row['stable']!s:6} "
          f"{row.get('where', '')}", flush=True)


class Greedy:
    """Blocks added one by one where they bare least, with lowerings and let-gos reused between steps."""

    def __init__(self, scene: Scene, build: Build, problem: Problem):
        self.scene, self.build, self.problem = scene, build, problem
        block = scene.block
        self.shapes = [(family, Shape.of(block, hanging_of(block, family, yaw)))
                       for family, yaw in spread_yaws(block, families(block), YAWS)]
        self.lowered: dict[tuple[int, int, int], Candidate | None] = {}
        self.rested: dict[tuple[int, int, int], Candidate | None] = {}
        self.tried = 0

    def forget(self, position: np.ndarray) -> None:
        """Drop the lowerings and let-gos the block just placed at ``position`` may change."""
        for key in [k for k in self.lowered if math.hypot(k[0] * GRID - position[0],
                                                          k[1] * GRID - position[1]) < LOWER_RADIUS]:
            del self.lowered[key]
        for key, c in list(self.rested.items()):
            first = self.lowered.get(key)
            if first is None or c is None or min(np.linalg.norm(first.pose.position - position),
                                                 np.linalg.norm(c.pose.position - position)) < SETTLE_RADIUS:
                del self.rested[key]

    def nodes(self, pts: np.ndarray) -> list[tuple[int, int]]:
        lo = np.floor((pts[:, :2].min(axis=0) - REACH) / GRID).astype(int)
        hi = np.ceil((pts[:, :2].max(axis=0) + REACH) / GRID).astype(int)
        ix, iy = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij")
        grid = np.column_stack([ix.ravel(), iy.ravel()])
        d, _ = cKDTree(pts[:, :2]).query(grid * GRID, distance_upper_bound=REACH)
        return [tuple(map(int, g)) for g in grid[np.isfinite(d)]]

    def step(self, cov: CoverageReport) -> tuple[Candidate, str, CoverageReport, dict] | None:
        """The candidate that leaves the least bare area, with its coverage; None if none lowers it."""
        bare = BareArea(cov, self.scene.block)
        pts = bare.points
        ranked = []
        for ix, iy in self.nodes(pts):
            for s, (_, shape) in enumerate(self.shapes):
                key = (ix, iy, s)
                if key not in self.lowered:
                    self.tried += 1
                    self.lowered[key] = self.build.lower(shape, ix * GRID, iy * GRID, loose=True)
                c = self.lowered[key]
                if c is not None:
                    g = bare.covered(c.pose)
                    if g > 0:
                        ranked.append((g, key))
        ranked.sort(reverse=True)
        resting = []
        for _, key in ranked[:SETTLE_TOP]:
            if key not in self.rested:
                self.rested[key] = settle_in(self.problem, self.build, self.lowered[key])
            c = self.rested[key]
            if c is not None:
                resting.append((bare.covered(c.pose), key, c))
        resting.sort(key=lambda t: -t[0])
        best = None
        placed = self.build.placed()
        for _, key, c in resting[:VERIFY_TOP]:
            after = coverage(self.scene, placed + [(-1, self.scene.block, c.pose)])
            if best is None or after.bare_share_percent < best[2].bare_share_percent:
                best = (c, key, after)
        info = {"candidates": len(ranked), "let_go": len(ranked[:SETTLE_TOP]), "resting": len(resting)}
        if best is None or best[2].bare_share_percent >= cov.bare_share_percent - 1e-9:
            return None
        c, key, after = best
        return c, self.shapes[key[2]][0], after, info


def main() -> None:
    layout = read_layout(REFERENCE)
    scene = layout.load_scene()
    block = scene.block
    run = Run("toe_coverage", {"reference": str(REFERENCE.relative_to(ROOT)), "scene": scene.name,
                               "grid_m": GRID, "reach_m": REACH, "yaws_per_hanging": YAWS,
                               "settle_top": SETTLE_TOP, "verify_top": VERIFY_TOP,
                               "max_added": MAX_ADDED, "settle_every": SETTLE_EVERY,
                               "bare_limit_percent": BARE_LIMIT, "remove_top": REMOVE_TOP})
    target, h = scene.target_porosity, block.height
    design_volume = scene.design.volume
    problem = Problem(scene=scene, required=scene.required_blocks, target=target,
                      lattice=lattice_for(block, scene.block_type), families=families(block))
    build = Build(scene)
    for p in layout.blocks:
        build.keep(p.id, p.type, p.pose)

    print("stage     added blocks porosity  bare%  maxbare seaward  crest landward valid  stable", flush=True)
    ok, _ = stable(scene, build.placed())
    row, cov = measure(scene, build.placed(), "reference", 0, ok)
    rows = [row]
    show(row)
    greedy = Greedy(scene, build, problem)
    added: list[int] = []
    met_at: dict[str, Any] | None = None
    stop = "max_added"
    while len(added) < MAX_ADDED:
        if cov.bare_share_percent <= BARE_LIMIT and cov.max_bare_m <= h:
            stop = "coverage met"
            break
        t = time.perf_counter()
        found = greedy.step(cov)
        if found is None:
            stop = "no valid candidate lowers the bare area"
            break
        c, family, cov, info = found
        key = build.place(c)
        added.append(key)
        greedy.forget(c.pose.position)
        settled = None
        if len(added) % SETTLE_EVERY == 0:
            settled, unstable = stable(scene, build.placed())
            info["unstable_keys"] = " ".join(map(str, unstable))
        x, y, z = c.pose.position
        row, cov = measure(scene, build.placed(), "added", len(added), settled, cov, {
            "family": family, "x_m": round(float(x), 3), "y_m": round(float(y), 3), "z_m": round(float(z), 3),
            "inside_share_percent": round(100 * c.inside / block.volume, 1),
            "where": f"{family} at ({x:.2f}, {y:.2f}, {z:.2f})", "step_s": round(time.perf_counter() - t, 2),
            **info})
        rows.append(row)
        show(row)
        if met_at is None and cov.bare_share_percent <= BARE_LIMIT and cov.max_bare_m <= h:
            met_at = row
    if rows[-1]["stable"] == "":
        ok, unstable = stable(scene, build.placed())
        rows[-1]["stable"] = ok
        rows[-1]["unstable_keys"] = " ".join(map(str, unstable))
        print(f"final settle: stable {ok}, unstable keys {unstable}", flush=True)
    print(f"stopped: {stop}; lowerings tried {greedy.tried}", flush=True)

    # The porosity the added blocks cost, and what bringing it back would take.
    inside = build.porosity.filled
    v = block.volume
    added_inside = sum(inside_of(build, k) for k in added)
    excess_target = inside - (1 - target / 100) * design_volume
    excess_window = inside - (1 - (target - 1) / 100) * design_volume
    arithmetic = {
        "stop": stop, "added": len(added), "lowerings_tried": greedy.tried,
        "added_inside_m3": round(added_inside, 3),
        "added_mean_inside_share_percent": round(100 * added_inside / (v * len(added)), 1) if added else None,
        "points_per_whole_block": round(100 * v / design_volume, 3),
        "coverage_met_at_added": met_at["added"] if met_at else None,
        "coverage_met_porosity_percent": met_at["porosity_percent"] if met_at else None,
        "final_porosity_percent": round(build.porosity.percent, 3),
        "whole_blocks_out_for_target": max(0, math.ceil(excess_target / v)),
        "whole_blocks_out_for_window": max(0, math.ceil(excess_window / v)),
    }
    print(arithmetic, flush=True)

    # Take them out in fact: the highest free blocks wholly inside the prism, barring least.
    placed = build.placed()
    carried = {k: set(s) for k, s in build.carried.items()}
    removed = 0
    goal = arithmetic["whole_blocks_out_for_target"] if met_at is not None else 0
    if met_at is None:
        arithmetic["removal_stop"] = "coverage never met: nothing to keep while removing"
    while removed < goal:
        free = [k for k in build.order if k in {p[0] for p in placed} and not carried[k]
                and inside_of(build, k) >= WHOLE * v]
        free.sort(key=lambda k: -build.poses[k].position[2])
        best = None
        for k in free[:REMOVE_TOP]:
            rest = [p for p in placed if p[0] != k]
            after = coverage(scene, rest)
            if best is None or after.bare_share_percent < best[2].bare_share_percent:
                best = (k, rest, after)
        if best is None:
            arithmetic["removal_stop"] = "no free block wholly inside"
            break
        k, rest, after = best
        if after.bare_share_percent > BARE_LIMIT or after.max_bare_m > h:
            arithmetic["removal_stop"] = "the next removal breaks coverage"
            break
        placed, cov = rest, after
        for s in build.supports[k]:
            if s in carried:
                carried[s].discard(k)
        removed += 1
        settled = None
        if removed == goal:
            settled, unstable = stable(scene, placed)
            arithmetic["removed_unstable_keys"] = " ".join(map(str, unstable))
        z = build.poses[k].position[2]
        row, cov = measure(scene, placed, "removed", len(added), settled, cov,
                           {"removed": removed, "where": f"key {k} at z {z:.2f}"})
        rows.append(row)
        show(row)
    if removed and rows[-1]["stable"] == "":
        ok, unstable = stable(scene, placed)
        rows[-1]["stable"] = ok
        arithmetic["removed_unstable_keys"] = " ".join(map(str, unstable))
    arithmetic["removed"] = removed

    # Toe rows laid first, on the empty foundation, beside the reference.
    reference = layout.placed()
    row_rows, laid_by = toe_rows(scene, reference)
    for r in row_rows:
        print(r, flush=True)
        rows.append({"stage": "toe row", **r})
    points = 100 * v / design_volume
    for family, laid in laid_by.items():
        toe = [(1000 * (i + 1) + k, block, pose)
               for i, (row, _) in enumerate(laid) for k, _, pose in row.placed()]
        hit = set().union(*(h for _, h in laid))
        for stage, kept in (("reference + rows", reference),
                            ("rows, hit out", [p for p in reference if p[0] not in hit])):
            ok, _ = stable(scene, kept + toe)
            row, _ = measure(scene, kept + toe, stage, 0, ok, extra={
                "family": family, "row_blocks": len(toe), "reference_blocks_hit": len(hit),
                "where": f"{family} rows"})
            short = scene.required_blocks - len(kept + toe)
            if stage == "rows, hit out" and short > 0:
                # The blocks the count still asks for, each wholly inside: the lowest porosity they can give.
                row["short_of_required"] = short
                low = row["porosity_percent"] - short * points
                row["porosity_with_short_whole_inside_percent"] = round(low, 2)
            rows.append(row)
            show(row)
    if "--optimize" in sys.argv[1:]:
        rows.extend(around_rows(scene, laid_by))
    run.params.update(arithmetic)
    run.csv("toe_coverage", rows)
    run.done()


def around_rows(scene: Scene, laid_by: dict) -> list[dict]:
    """``shoha optimize``'s pipeline (its default limit) laying the rest of the mound around
    each hanging's toe rows, kept where they are (``optimize(keep=...)``, as ``--keep``)."""
    from geometry.layout import Placement
    from optimizer.api import optimize

    out = []
    for family in ("crown", "horizontal"):
        rows_placed = [pose for row, _ in laid_by[family] for _, _, pose in row.placed()]
        keep = [Placement(i, scene.block_type, pose) for i, pose in enumerate(rows_placed)]
        for seed in OPTIMIZE_SEEDS:
            result = optimize(scene, seed=seed, keep=keep)
            cov = result.coverage or {}
            row = {"stage": "optimize around rows", "family": family, "seed": seed,
                   "blocks": result.blocks, "required": result.required_blocks,
                   "porosity_percent": round(result.porosity_percent, 2),
                   "bare_share_percent": round(cov.get("bare_share_percent", float("nan")), 2),
                   "max_bare_m": round(cov.get("max_bare_m") or float("nan"), 3),
                   "collisions": result.collisions, "out_of_tolerance": result.out_of_tolerance,
                   "stable": result.stable, "seconds": round(result.seconds, 1),
                   "row_blocks": len(keep)}
            row["valid"] = row["collisions"] == 0 and row["out_of_tolerance"] == 0 and bool(result.stable)
            out.append(row)
            print(f"around {family} rows, seed {seed}: {row['blocks']}/{row['required']} blocks, "
                  f"{row['porosity_percent']:.2f} %, bare {row['bare_share_percent']:.2f} %, "
                  f"largest bare {row['max_bare_m']:.2f} m, valid {row['valid']}, {row['seconds']} s",
                  flush=True)
    return out


def toe_rows(scene: Scene, placed: list) -> tuple[list[dict], dict]:
    """The outermost ground row of each hanging at each toe, laid alone on the empty foundation.

    For each hanging, ``ROW_YAWS`` yaws are swept outward from the axis
    (``ROW_STEP``) at mid-length on the empty foundation; the yaw whose
    outermost valid block comes nearest the design toe line is kept. A row is
    then laid at that distance from the axis along each toe, each block lowered
    at the first ``ROW_STEP`` along y where it lands on the ground inside the
    zone, touching the last (crane order: along the toe). Returns a row per
    hanging and side (centroid |x|, nearest distance to the toe line, blocks,
    reference blocks it interpenetrates), and each hanging's two rows with the
    reference blocks they interpenetrate.
    """
    block = scene.block
    design = scene.design
    mid = 0.5 * (design.y_start + design.y_end)
    line = np.column_stack([np.full(61, design.bottom_half_width), np.linspace(mid - 3, mid + 3, 61),
                            np.zeros(61)])
    world = world_of(placed)
    rows, laid_by = [], {}
    for family in families(block):
        pick = None
        for yaw in np.arange(ROW_YAWS) * 2 * math.pi / symmetry(block, family) / ROW_YAWS:
            shape = Shape.of(block, hanging_of(block, family, float(yaw)))
            for x in np.arange(scene.tolerance.bottom_half_width, 0.0, -ROW_STEP):
                c = Build(scene).lower(shape, float(x), mid)
                if c is not None:
                    d = float(distance_to_block(line, block, c.pose).min())
                    if pick is None or d < pick[2]:
                        pick = (float(yaw), float(x), d)
                    break
        yaw, x, d = pick
        laid = []
        for side in (1.0, -1.0):
            # The landward toe is the seaward one turned half a turn about the vertical.
            q = hanging_of(block, family, yaw + (0.0 if side > 0 else math.pi))
            shape = Shape.of(block, q)
            row = Build(scene)
            for y in np.arange(scene.tolerance.y_start, scene.tolerance.y_end, ROW_STEP):
                c = row.lower(shape, side * x, float(y))
                if c is not None and c.support == (-1,):
                    row.place(c)
            hit = {k for _, _, pose in row.placed() for k, _ in world.query(block, pose)}
            rows.append({"family": family, "side": "seaward" if side > 0 else "landward",
                         "yaw_deg": round(math.degrees(yaw), 1), "centroid_abs_x_m": round(x, 3),
                         "toe_distance_m": round(d, 3), "row_blocks": len(row),
                         "row_inside_share_percent":
                             round(100 * row.porosity.filled / (len(row) * block.volume), 1),
                         "reference_blocks_hit": len(hit)})
            laid.append((row, hit))
        laid_by[family] = laid
    return rows, laid_by


def inside_of(build: Build, key: int) -> float:
    """A placed block's volume inside the design prism, m^3."""
    return volume_inside(build.block, build.poses[key], build.scene.design.polytope)


if __name__ == "__main__":
    main()
