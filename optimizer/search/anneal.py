"""Simulated annealing: refine a full layout one block at a time.

Moves, each applied to a block that carries no other block (so nothing is
ever pulled from under a block), which is then lowered again from above as a
crane would and becomes the last block of the crane order (always a valid
order, since nothing rests on it):

``jitter``     shift the block a little horizontally;
``yaw``        turn it about the vertical;
``hanging``    hang it in another family (crown, level, horizontal), any yaw;
``relocate``   take it out and set it down somewhere else;
``insert``     (only while the layout is short of the required count) add a block.

Relocated and inserted blocks go, half the time, to a jittered site of the
placement pattern the beam search used (its pockets fit the pattern's own
hangings), otherwise anywhere in the zone a block can fit.

A block of the toe rows (``Build.toe_rows``, laid by
``optimizer.search.toe.ToeRows``) moves only where it covers no less of the
toe's strip where it was laid (:func:`holds_toe`): moved further in, it holds
more inside the prism, and the toe it was laid to cover is bare again. In the
attempt that aims to cover, the annealing makes up to ``COVER_FACTOR`` times
its moves (:meth:`Annealing.covering`): the moves past its own count go on
only while the best layout is short of its count or outside its porosity
window, at the temperature its own count cooled to (:func:`temperature`).

A move whose block would end out of tolerance or interpenetrate another
(FCL) is rejected outright, never penalised. Otherwise it is accepted by the
Metropolis rule at temperature T. The energy (``optimizer.objective``) is
updated per move: porosity through the exact tracker (one block's clipped
volume), slice spread through centroid bins, support from the block's own
support list. A move that would put a block on other blocks is also settled
locally (``optimizer.search.physics.raised_check``) before it is kept.

Temperature schedule: T0 is calibrated so that the average uphill move of a
trial sample is accepted with probability 1/2; T falls geometrically to
T0/100 over the iterations (in the covering annealing, over its own count,
and stays there after it; until stop 74 it fell over all of them, and a run
stopped at its own count had cooled only to about 0.63 T0). The
iteration count is fixed, so a seed gives one result; the deadline, and in
the covering annealing the window, only stop the run early.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from geometry.constants import tol
from geometry.porosity import exact_filled_volume
from geometry.pose import axis_angle_quat, quat_multiply

from .build import GROUND, Build, Candidate, fill_window
from .hangings import free, hanging_of
from .objective import Energy
from .problem import Phase, Problem, Stats, Strategy, off_window
from .shapes import ShapeCache
from .sites import pattern_sites
from .toe import strip_share

if TYPE_CHECKING:
    from geometry.scene import Scene

MOVES = ("jitter", "yaw", "hanging", "relocate")
#: How many times the moves the annealing makes in the attempt that aims to cover
#: (:meth:`Annealing.covering`). Set on ``mini-mesh`` seeds 2-3 (docs/coverage-study.md, stop 72).
COVER_FACTOR = 10


def temperature(t0: float, it: int, cooled: int) -> float:
    """The temperature of move ``it``: from ``t0`` down to ``t0 / 100``, geometrically, over the
    first ``cooled`` moves, and held there after them.

    Parameters
    ----------
    t0 : float
        The starting temperature, energy units (:class:`optimizer.objective.Energy`).
    it : int
        The move, from 0.
    cooled : int
        The moves over which it falls: the annealing's own count.
    """
    t_end = t0 / 100.0  # as the plain annealing has always reckoned it, to the last bit
    return t0 * (t_end / t0) ** (min(it, cooled - 1) / max(1, cooled - 1))


def holds_toe(scene: Scene, build: Build, key: int, c: Candidate) -> bool:
    """Whether a block of the toe rows (``Build.toe_rows``), moved to ``c``, covers no less of the
    toe's strip where it was laid than it did there."""
    points, share = build.toe_rows[key]
    return strip_share(scene, points, c.pose) >= share


def weak_blocks(build: Build) -> int:
    """Blocks resting on fewer than three blocks and not on the ground."""
    return sum(1 for s in build.supports.values() if GROUND not in s and len(s) < 3)


def energy_of(problem: Problem, build: Build) -> float:
    """The energy of a build computed from scratch (the reference for the incremental one)."""
    e = Energy(problem.scene, problem.required, problem.target)
    for k in build.order:
        e.add(build.poses[k].position)
    filled = exact_filled_volume(problem.scene.design.polytope, build.placed(), assume_disjoint=True)
    porosity = 100.0 * (problem.scene.design_volume - filled) / problem.scene.design_volume
    return e.total(len(build), porosity, weak_blocks(build))


@dataclass(frozen=True)
class AnnealStats(Stats):
    """What an annealing run did.

    Attributes
    ----------
    iterations : int
        Moves proposed (fewer than asked when the deadline came first, or, in the covering
        annealing, the layout came within its window).
    accepted, rejected : int
        Moves kept, and moves the Metropolis rule, the toe rows' strip (:func:`holds_toe`)
        or the local settle refused.
    infeasible : int
        Moves whose block ended out of tolerance or colliding.
    t0 : float
        The calibrated starting temperature, energy units.
    energy : float
        The best build's energy.
    """

    iterations: int
    accepted: int
    rejected: int
    infeasible: int
    t0: float
    energy: float


class Annealing(Strategy):
    """Metropolis refinement of a layout.

    Parameters
    ----------
    iterations : int
        Proposed moves.
    jitter_xy : float, metres
    jitter_yaw : float, radians
    accept : callable, optional
        ``accept(problem, build, candidate) -> bool``, an extra test for
        each kept move (``optimizer.search.physics.raised_check``).
    """

    name = "anneal"

    def __init__(self, iterations: int = 600, jitter_xy: float = 0.15, jitter_yaw: float = math.radians(10),
                 accept: Callable[[Problem, Build, Candidate], Candidate | None] | None = None):
        self.iterations = iterations
        self.jitter_xy = jitter_xy
        self.jitter_yaw = jitter_yaw
        self.accept = accept
        #: Moves past which the run stops once the best layout reaches its count within its
        #: porosity window (None: it never stops early; :meth:`covering`).
        self.base: int | None = None
        self._sites: list[tuple[str, float, float, float]] = []

    def covering(self) -> Annealing:
        """The same refinement with up to ``COVER_FACTOR`` times the moves, for the attempt that
        aims to cover: its toe rows hold much outside the prism, and, held to their strip
        (:func:`holds_toe`), the moves that bring the rest in are fewer to find.

        The moves past this one's count are made only while the best layout is short of its
        count or outside its porosity window. Within it, more moves only bring the porosity nearer
        its target by moving blocks inward, and leave the surface barer: on ``cube``, whose
        attempts with rows were within the window before they were annealed, 6000 moves took
        them from 47.8 to 47.1 % and from 17.7-19.1 to 19.6-20.8 % bare (2026-12-07, stop 72)."""
        other = copy.copy(self)
        other.iterations = COVER_FACTOR * self.iterations
        other.base = self.iterations
        return other

    # --- moves ---------------------------------------------------------------------------

    def _propose(self, problem: Problem, build: Build, shapes: ShapeCache, rng: np.random.Generator
                 ) -> tuple[str, int | None, Candidate | None]:
        """A move: (kind, moved key or None for insert, candidate or None when it does not fit)."""
        if len(build) < problem.required and rng.random() < 0.5:
            x, y, q = self._spot(problem, rng)
            return "insert", None, build.lower(shapes.get(q), x, y)
        free_keys = build.free_keys()
        if not free_keys:
            return "none", None, None
        key = free_keys[int(rng.integers(len(free_keys)))]
        kind = MOVES[int(rng.integers(len(MOVES)))]
        pose = build.poses[key]
        x, y = pose.position[0], pose.position[1]
        q = pose.quaternion
        if kind == "jitter":
            x, y = x + rng.normal(0, self.jitter_xy), y + rng.normal(0, self.jitter_xy)
        elif kind == "yaw":
            q = quat_multiply(axis_angle_quat([0, 0, 1], rng.normal(0, self.jitter_yaw)), q)
        elif kind == "hanging":
            q = self._orientation(problem, rng)
        else:  # relocate
            x, y, q = self._spot(problem, rng)
        c = build.lower(shapes.get(q), float(x), float(y), exclude=frozenset({key}))
        return kind, key, c

    def _spot(self, problem: Problem, rng: np.random.Generator) -> tuple[float, float, np.ndarray]:
        """Where an inserted or relocated block goes: half the time a jittered pattern site
        (the pockets the pattern leaves fit its own hangings), else anywhere in the zone."""
        if self._sites and rng.random() < 0.5:
            fam, yaw, x, y = self._sites[int(rng.integers(len(self._sites)))]
            return (float(x + rng.normal(0, self.jitter_xy)), float(y + rng.normal(0, self.jitter_xy)),
                    hanging_of(problem.scene.block, fam, float(yaw + rng.normal(0, self.jitter_yaw))))
        window = fill_window(problem.scene)
        x, y = rng.uniform(window[0][0], window[0][1]), rng.uniform(window[1][0], window[1][1])
        return float(x), float(y), self._orientation(problem, rng)

    def _orientation(self, problem: Problem, rng: np.random.Generator) -> np.ndarray:
        fam = problem.families[int(rng.integers(len(problem.families)))]
        if fam == "free":
            return free(rng)
        return hanging_of(problem.scene.block, fam, float(rng.uniform(0, 2 * np.pi)))

    def _delta(self, problem: Problem, build: Build, energy: Energy, key: int | None, c: Candidate,
               weak: int) -> tuple[float, int]:
        """Energy change of a move, and the new weak-block count (nothing is changed)."""
        before = energy.total(len(build), build.porosity.percent, weak)
        filled = build.porosity.filled + c.inside
        count = len(build) + (1 if key is None else 0)
        new_weak = weak + (1 if GROUND not in c.support and len(c.support) < 3 else 0)
        if key is not None:
            filled -= build.porosity.contribution(key)
            s = build.supports[key]
            new_weak -= 1 if GROUND not in s and len(s) < 3 else 0
            energy.remove(build.poses[key].position)
        energy.add(c.pose.position)
        after = energy.total(count, build.porosity.percent_with(filled), new_weak)
        energy.remove(c.pose.position)
        if key is not None:
            energy.add(build.poses[key].position)
        return after - before, new_weak

    def _stands(self, problem: Problem, build: Build, key: int | None, c: Candidate) -> bool:
        """Whether the moved or inserted block stays where it was lowered when let go
        (``accept``; :func:`optimizer.search.physics.raised_check` lets go only a block
        that rests on others, and keeps one on the foundation alone as lowered).

        The moved block's old pose is taken out of the collision world while
        it is let go, so that it does not hold up its own new pose. A move
        whose block would slide elsewhere is refused: the energy change was
        worked out for where it was lowered.
        """
        assert self.accept is not None
        if key is not None:
            build.collide.remove(key)
        try:
            return self.accept(problem, build, c) is c
        finally:
            if key is not None:
                build.collide.add(key, build.block, build.poses[key])

    def _apply(self, build: Build, energy: Energy, key: int | None, c: Candidate) -> None:
        row = None
        if key is not None:
            row = build.toe_rows.get(key)  # read before remove() drops it
            energy.remove(build.poses[key].position)
            build.remove(key)
        new = build.place(c)
        if row is not None:  # a block of the toe rows, moved, is still one
            build.toe_rows[new] = row
        energy.add(c.pose.position)

    # --- search ----------------------------------------------------------------------------

    def run(self, problem: Problem, previous: Phase | None, rng: np.random.Generator) -> Phase:
        build = previous.build.copy() if previous is not None else Build(problem.scene)
        origin = previous.origin if previous is not None else None
        self._sites = pattern_sites(problem, origin) if origin is not None else []
        shapes = ShapeCache(problem.scene.block)
        energy = Energy(problem.scene, problem.required, problem.target)
        for k in build.order:
            energy.add(build.poses[k].position)
        weak = weak_blocks(build)
        current = energy.total(len(build), build.porosity.percent, weak)
        best_e, best = current, build.copy()

        # Calibrate T0: the mean uphill change of a sample of moves is accepted half the time.
        uphill = []
        for _ in range(40):
            if problem.time_left() <= 0:  # a drop of a many-faced block can take 0.1 s
                break
            kind, key, c = self._propose(problem, build, shapes, rng)
            if c is not None:
                d, _ = self._delta(problem, build, energy, key, c, weak)
                if d > 0:
                    uphill.append(d)
        t0 = (float(np.mean(uphill)) if uphill else 1.0) / math.log(2.0)
        accepted = rejected = collided = made = 0
        cooled = self.iterations if self.base is None else self.base
        for it in range(self.iterations):
            if problem.time_left() <= 0 or (self.base is not None and it >= self.base
                                            and len(best) >= problem.required
                                            and off_window(problem, best) == 0.0):
                break
            made += 1
            temp = temperature(t0, it, cooled)
            kind, key, c = self._propose(problem, build, shapes, rng)
            if c is None:
                collided += kind != "none"
                continue
            d, new_weak = self._delta(problem, build, energy, key, c, weak)
            if d > 0 and rng.random() >= math.exp(-d / temp):
                rejected += 1
                continue
            if key in build.toe_rows and not holds_toe(problem.scene, build, key, c):
                rejected += 1
                continue
            if self.accept is not None and not self._stands(problem, build, key, c):
                rejected += 1
                continue
            self._apply(build, energy, key, c)
            weak = new_weak
            current += d
            accepted += 1
            if current < best_e - tol.energy:
                best_e, best = current, build.copy()
            if it % 50 == 0:
                problem.tell(self.name, best, f"T={temp:.3g} E={best_e:.3f}")
        stats = AnnealStats(made, accepted, rejected, collided, t0, best_e)
        return Phase(best, stats, origin)
