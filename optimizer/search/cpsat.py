"""CP-SAT: exact selection of the ground layer over a discretised candidate set.

The whole layout is no exact problem CP-SAT can take (blocks rest on blocks
whose poses are themselves chosen), but the ground layer is: every candidate
rests on the foundation, so its pose is known before any choice is made.

Candidates
    The placement pattern's ground sites from a few origins, each as drawn
    and with jittered variants (position and yaw), lowered to the
    foundation; those out of the tolerance zone are dropped.
Model (OR-Tools CP-SAT)
    * one boolean per candidate;
    * no overlap: ``x_i + x_j <= 1`` for each pair that interpenetrates (FCL);
    * support: every candidate rests on the foundation by construction, so it
      needs no other block; a candidate that a chosen one would stop short of
      the ground (it could not be lowered past it) must be placed first, and
      a pair that would each stop the other is excluded like an overlap;
    * block count: at most the required number;
    * objective: maximise the block volume inside the design prism (the
      exact porosity of the layer), in units of 1e-6 m^3.
Result
    The optimal ground layer for the candidate set, or the best found within
    the time limit with CP-SAT's bound on the optimum. The candidate set
    includes the heuristic's own ground blocks, so the bound, set beside the
    volume the heuristic's ground layer reaches, is the optimality gap the
    CLI reports: how much more design-prism volume the best ground layer of
    the set could hold.
"""

from __future__ import annotations

import heapq
from collections import defaultdict
from dataclasses import dataclass

import numpy as np

from geometry.clip import volume_inside
from geometry.collision import CollisionWorld
from geometry.constants import tol
from geometry.pose import Pose

from .build import GROUND, Build, search_window
from .drop import DropWorld, Shape
from .problem import Phase, Problem, Stats, Strategy
from .shapes import ShapeCache
from .sites import rank_origins

#: Objective units per cubic metre.
SCALE = 1_000_000


@dataclass(frozen=True)
class BoundStats(Stats):
    """CP-SAT's bound on the ground layer, set beside the heuristic's (the optimality gap).

    Attributes
    ----------
    skipped : bool
        No time was left to solve: every other figure is zero.
    slab_m : float
        Length of crest solved (the whole scene, or a slab at one end).
    candidates, conflicts : int
        Size of the model.
    heuristic_m3 : float
        Design-prism volume of the input build's ground blocks in the slab.
    objective_m3, bound_m3 : float
        CP-SAT's best selection and its proven bound on the optimum.
    gap_percent : float
        How far the bound lies above the heuristic, percent of the bound.
    solver_gap_percent : float
        How far the bound lies above the best of the two.
    optimal : bool
        CP-SAT proved its selection optimal.
    placed : int
        Blocks of the solved layer laid (only on a build with nothing above its ground layer).
    seconds : float
        The step's cost: wall-clock seconds of candidates, model and solve.
    """

    skipped: bool = False
    slab_m: float = 0.0
    candidates: int = 0
    conflicts: int = 0
    heuristic_m3: float = 0.0
    objective_m3: float = 0.0
    bound_m3: float = 0.0
    gap_percent: float = 0.0
    solver_gap_percent: float = 0.0
    optimal: bool = False
    placed: int = 0
    seconds: float = 0.0


class CpSat(Strategy):
    """Exact ground layer by CP-SAT.

    Parameters
    ----------
    origins : int
        Pattern origins whose ground sites enter the candidate set.
    jitter : int
        Jittered variants per site.
    jitter_xy : float, metres
    jitter_yaw : float, radians
    time_limit : float, seconds
        CP-SAT's own limit (deterministic time, so a seed gives one answer).
    slab : float, metres
        Longest stretch of the crest solved at once. A longer scene is solved
        on a slab at one end, with the blocks beside it held in place; the
        gap then speaks for that slab.
    """

    name = "cpsat"

    def __init__(self, origins: int = 2, jitter: int = 2, jitter_xy: float = 0.12,
                 jitter_yaw: float = np.radians(6.0), time_limit: float = 10.0, slab: float = 24.0):
        self.origins = origins
        self.jitter = jitter
        self.jitter_xy = jitter_xy
        self.jitter_yaw = jitter_yaw
        self.time_limit = time_limit
        self.slab = slab
        self._time_left = float("inf")

    # --- candidates -------------------------------------------------------------------

    def candidates(self, problem: Problem, origins: list[tuple[float, float]], rng: np.random.Generator,
                   y_range: tuple[float, float] | None = None) -> list[tuple[Shape, Pose, float]]:
        """Ground candidates ``(shape, pose, inside volume)``: pattern ground sites and jitter.

        ``y_range`` limits the sites to a slab of the scene (default: all of it).
        """
        scene = problem.scene
        shapes = ShapeCache(scene.block)
        lat = problem.lattice
        ground = DropWorld(scene.foundation)
        xr, window_y = search_window(scene)
        yr = y_range or window_y
        out = []
        for origin in origins:
            for fam, yaw, x, y in lat.sites(xr, yr, origin):
                variants = [(x, y, yaw)] + [
                    (x + rng.normal(0, self.jitter_xy), y + rng.normal(0, self.jitter_xy),
                     yaw + rng.normal(0, self.jitter_yaw)) for _ in range(self.jitter)]
                for vx, vy, vyaw in variants:
                    shape = shapes.hung(fam, vyaw)
                    z = ground.ground_height(shape, vx, vy) + tol.drop_resolution
                    c = self._candidate(problem, shape, Pose([vx, vy, z], shape.quaternion))
                    if c is not None:
                        out.append(c)
        return out

    def _candidate(self, problem: Problem, shape: Shape, pose: Pose) -> tuple[Shape, Pose, float] | None:
        scene = problem.scene
        if not scene.tolerance.polytope.contains(pose.apply(scene.block.vertices)).all():
            return None
        return shape, pose, volume_inside(scene.block, pose, scene.design.polytope)

    def relations(self, problem: Problem, cands: list[tuple[Shape, Pose, float]]
                  ) -> tuple[set[tuple[int, int]], set[tuple[int, int]]]:
        """Conflicting pairs ``(i, j)``, and ordering pairs ``(i, j)``: i must go before j."""
        block = problem.scene.block
        conflicts = overlapping_pairs(block, [pose for _, pose, _ in cands])
        # One drop world of every candidate: each candidate asks, unpruned, how high each
        # neighbour would stop it; a neighbour that stops it short of the ground must go first.
        drops = DropWorld(problem.scene.foundation, cell=2.0 * block.bounding_radius)
        for i, (shape, pose, _) in enumerate(cands):
            drops.add(i, shape, pose.position)
        stops: set[tuple[int, int]] = set()
        for i, (shape, pose, _) in enumerate(cands):
            x, y, z = pose.position
            for j in drops.blockers(shape, x, y, z, frozenset({i})):
                if (min(i, j), max(i, j)) not in conflicts:
                    stops.add((j, i))  # j, in place, stops i
        before: set[tuple[int, int]] = set()
        for j, i in stops:
            if (i, j) in stops:
                conflicts.add((min(i, j), max(i, j)))
            else:
                before.add((i, j))  # j would stop i, so i goes down first
        return conflicts, before

    # --- model ------------------------------------------------------------------------------

    def solve(self, values: list[float], conflicts: set[tuple[int, int]], limit: int, seed: int,
              fixed: frozenset[int] = frozenset()) -> tuple[list[int], float, float, str]:
        """Maximum-volume selection; returns (chosen, objective m^3, bound m^3, status).

        ``fixed`` candidates are chosen by force (blocks in place around a
        slab); they do not count against ``limit``.
        """
        from ortools.sat.python import cp_model

        model = cp_model.CpModel()
        x = [model.new_bool_var(f"c{i}") for i in range(len(values))]
        for i in sorted(fixed):
            model.add(x[i] == 1)
        for i, j in sorted(conflicts):
            model.add_at_most_one([x[i], x[j]])
        model.add(sum(x[i] for i in range(len(values)) if i not in fixed) <= limit)
        weights = [int(round(v * SCALE)) for v in values]
        model.maximize(sum(w * xi for w, xi in zip(weights, x, strict=True)))
        solver = cp_model.CpSolver()
        # Deterministic time and one worker: the same seed gives the same selection.
        solver.parameters.max_deterministic_time = self.time_limit
        # The deadline still rules (binding only when time is nearly out).
        solver.parameters.max_time_in_seconds = max(0.1, self._time_left)
        solver.parameters.num_workers = 1
        solver.parameters.random_seed = seed
        status = solver.solve(model)
        name = solver.status_name(status)
        if status not in (cp_model.OPTIMAL, cp_model.FEASIBLE):
            return [], 0.0, float(sum(sorted(values, reverse=True)[:limit])), name
        chosen = [i for i in range(len(values)) if solver.value(x[i])]
        return chosen, solver.objective_value / SCALE, solver.best_objective_bound / SCALE, name

    def run(self, problem: Problem, previous: Phase | None, rng: np.random.Generator) -> Phase:
        """Solve the ground layer; lay it on an empty build, or bound a finished one.

        The candidate set holds the input build's own ground blocks and the
        pattern's ground sites (with jitter) from the best-ranked origins, so
        the optimum is at least the input's ground layer, and the bound says
        how far above it the best ground layer of this set can be. A build
        with kept blocks (``Build.keep``), or that already has blocks resting
        on its ground layer, is returned
        unchanged (its upper layers stand on that ground layer); the bound is
        recorded in :meth:`stats`.
        """
        t0 = problem.now()
        start = previous.build.copy() if previous is not None else Build(problem.scene)
        origin = previous.origin if previous is not None else None
        if problem.time_left() <= 0:
            return Phase(start, BoundStats(skipped=True), origin)
        shapes = ShapeCache(problem.scene.block)
        zone = problem.scene.tolerance
        # A long scene is solved on a slab at one end (its end and slopes, the hard part):
        # the heuristic's ground blocks just outside the slab stay where they are.
        whole = zone.y_end - zone.y_start <= self.slab
        y0, y1 = zone.y_start, (zone.y_end if whole else zone.y_start + self.slab)
        reach = 2.0 * problem.scene.block.bounding_radius
        ground = [k for k in start.order if start.supports[k] == (GROUND,)]
        upper = len(start) - len(ground)
        own = [k for k in ground if y0 <= start.poses[k].position[1] <= y1]
        border = [k for k in ground if not y0 <= start.poses[k].position[1] <= y1
                  and y0 - reach <= start.poses[k].position[1] <= y1 + reach]
        outside = len(ground) - len(own)
        heuristic = sum(start.porosity.contribution(k) for k in own)
        cands = [(start.shapes[k], start.poses[k], start.porosity.contribution(k)) for k in own]
        cands += [(start.shapes[k], start.poses[k], 0.0) for k in border]
        fixed = frozenset(range(len(own), len(own) + len(border)))
        origins = rank_origins(problem, shapes, rng, Build(problem.scene), max(2, self.origins + 2),
                               problem.now() + 0.1 * max(0.0, problem.time_left()))
        cands += self.candidates(problem, origins[: self.origins], rng, (y0, y1))
        conflicts, before = self.relations(problem, cands)
        limit = max(0, problem.required - upper - outside)
        self._time_left = problem.time_left()
        chosen, objective, bound, status = self.solve([v for _, _, v in cands], conflicts, limit,
                                                      int(rng.integers(2**31)), fixed)
        placed = 0
        if whole and upper == 0 and not start.kept and objective > heuristic + tol.objective_volume:
            # Lay the solved ground layer, blockers first, each lowered to confirm it.
            start = Build(problem.scene)
            for i in _topological(chosen, before):
                shape, pose, _ = cands[i]
                c = start.lower(shape, pose.position[0], pose.position[1])
                if c is not None and c.support == (GROUND,):
                    start.place(c)
                    placed += 1
        best = max(objective, heuristic)
        stats = BoundStats(
            slab_m=float(y1 - y0),
            candidates=len(cands),
            conflicts=len(conflicts),
            heuristic_m3=heuristic,
            objective_m3=objective,
            bound_m3=bound,
            # Clamped at zero: the objective is rounded to 1e-6 m^3 for the integer model.
            gap_percent=max(0.0, 100.0 * (bound - heuristic) / bound) if bound > 0 else 0.0,
            solver_gap_percent=max(0.0, 100.0 * (bound - best) / bound) if bound > 0 else 0.0,
            optimal=status == "OPTIMAL",
            placed=placed,
            seconds=problem.now() - t0,
        )
        return Phase(start, stats, origin)


def overlapping_pairs(block, poses: list[Pose]) -> set[tuple[int, int]]:
    """Pairs ``(i, j)``, ``i < j``, of ``poses`` of ``block`` that interpenetrate (FCL)."""
    world = CollisionWorld(cell=2.0 * block.bounding_radius)
    for i, pose in enumerate(poses):
        world.add(i, block, pose)
    return {(min(c.a, c.b), max(c.a, c.b)) for c in world.pairs(threshold=0.0)}


def _topological(nodes: list[int], before: set[tuple[int, int]]) -> list[int]:
    """Nodes ordered so that every ``(a, b)`` in ``before`` has a first; ties by index."""
    chosen = set(nodes)
    succ: dict[int, list[int]] = defaultdict(list)
    indeg = {n: 0 for n in nodes}
    for a, b in before:
        if a in chosen and b in chosen:
            succ[a].append(b)
            indeg[b] += 1
    ready = [n for n in nodes if indeg[n] == 0]
    heapq.heapify(ready)
    out = []
    while ready:
        n = heapq.heappop(ready)
        out.append(n)
        for m in succ[n]:
            indeg[m] -= 1
            if indeg[m] == 0:
                heapq.heappush(ready, m)
    # A cycle (three or more blocks each stopping the next) leaves nodes out; they are skipped.
    return out

