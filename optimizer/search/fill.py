"""Pocket fill: where the pattern leaves a layout short, blocks go where they settle.

The beam search lays the placement pattern; around blocks off any pattern (a
kept trainee's layout, ``optimize(keep=...)``), on a rough underlayer, or
where a mesh block's tuned pattern fits the section badly, the pattern's sites
run out before the count is reached. This step then adds one block at a time,
the way a crane operator fills the pockets that are left:

1. draw ``draws`` drops at random over the fill window, each in a random
   hanging at a random yaw, and lower each until it touches. A drop whose
   first contact sticks out of the zone (on a neighbour's shoulder) is kept
   as a *loose* candidate;
2. rank them by the beam's :func:`optimizer.search.beam.gain` (volume in the
   design prism, low, well supported);
3. let the best go, one after the other, among their fixed neighbours
   (``accept``, :func:`optimizer.search.physics.raised_check`): the first that
   comes to rest inside the zone is placed where it rests. A loose candidate
   is valid only if it slid into a pocket. (``raised_check`` keeps a drop on
   the bare foundation, flat or rough, where it touched; the settle of the
   whole layout judges it.)

A round in which none of the first ``checks`` comes to rest is fruitless; the
next draws twice as many. ``patience`` fruitless rounds in a row end the step.

Measured with seed 1 on 2 cores: keeping the first 30 blocks of a random
layout (``optimizer.search.scatter``) on ``mini``, the beam reached 47 blocks
and this step 55; on ``mini`` with a rough underlayer, 66 and 70. The
layout's confirming settle then took out what did not stand in the whole
layout (47 and 63 stayed): blocks that come to rest among fixed neighbours
do not all stand once every block is free. The step is kept for the count it
adds before that settle, which the repair starts from.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .beam import gain
from .build import Build, Candidate, fill_window
from .hangings import free, hanging_of, spread_yaws
from .physics import settle_in
from .problem import Phase, Problem, Stats, Strategy
from .shapes import ShapeCache


@dataclass(frozen=True)
class FillStats(Stats):
    """Figures of a pocket fill.

    Attributes
    ----------
    placed : int
        Blocks it added.
    drops : int
        Blocks lowered.
    checks : int
        Candidates let go (a physics run each).
    fruitless : int
        Rounds in a row, at its end, in which no candidate came to rest.
    ended : str
        Why it stopped: ``"count"`` (reached), ``"room"`` (``patience``
        fruitless rounds, the last not cut short by the clock, and with ``sweep`` a sweep
        of every node whose best candidates did not come to rest) or ``"time"``.
    swept : int
        Blocks the sweep lowered (0 without one); they are not in ``drops``. The sweep's
        candidates let go are in ``checks``, and the blocks it placed in ``placed``.
    """

    placed: int = 0
    drops: int = 0
    checks: int = 0
    fruitless: int = 0
    ended: str = ""
    swept: int = 0


#: The sweep's grid (:func:`sweep`): its step, as a share of the block height (0.2 m for the
#: Shake Block), and the yaws of each hanging over its symmetry's period. Set on the one case
#: studied (``benchmarks/studies/room_sweep.py``, ``wall-rough`` seed 1), where they found the
#: places random drops had missed.
SWEEP_STEP = 0.12
SWEEP_YAWS = 12
#: Nodes whose places are tested against the zone's ceiling at once.
SWEEP_CHUNK = 1024
#: The share of the time left a sweep may take; the rest is for letting its candidates go.
SWEEP_SHARE = 0.8
#: How near a place a sweep lowers first, in bounding radii: after a block is placed there, and
#: where the settle took blocks out. A block within one radius of the place touches what stood
#: there, and may rest on or beside what is one more radius away. Set by that reasoning, not tuned.
NEAR_REACH = 2.0


class PocketFill(Strategy):
    """Add blocks one at a time where they settle, until the count or the time is reached.

    Parameters
    ----------
    draws : int
        Drops lowered per round (doubled after each fruitless round).
    checks : int
        Best candidates let go per round before it counts as fruitless.
    patience : int
        Fruitless rounds in a row that end the step.
    accept : callable
        ``accept(problem, build, candidate) -> Candidate | None``, as the beam
        search's; it must handle loose candidates
        (:func:`optimizer.search.physics.raised_check` does).
    sweep : bool
        Where the random rounds find no room, go on with :func:`sweep`: every node of a grid
        over the fill window, in every hanging. It is thorough and slow (34 s for 72 Shake
        Blocks on one core), so ``optimize`` asks for it only in the refills after a
        confirming settle, where a layout that reached its count has lost a block or two.
    first : array of (x, y), optional
        With ``sweep``: where to sweep first, the nodes within ``NEAR_REACH`` bounding radii
        of these points (where the settle took blocks out: there was room there), and then,
        while the count is short, the rest of the window.
    """

    name = "fill"

    def __init__(self, accept: Callable[[Problem, Build, Candidate], Candidate | None],
                 draws: int = 200, checks: int = 30, patience: int = 4, sweep: bool = False,
                 first: np.ndarray | None = None):
        self.accept = accept
        self.draws = draws
        self.checks = checks
        self.patience = patience
        self.sweep = sweep
        self.first = None if first is None or not len(first) else np.asarray(first, float).reshape(-1, 2)

    def sweeping(self, first: np.ndarray | None = None) -> PocketFill:
        """The same fill, going on with a sweep where its random rounds find no room (first
        near the points ``first``, where given)."""
        return PocketFill(self.accept, self.draws, self.checks, self.patience, sweep=True, first=first)

    def run(self, problem: Problem, previous: Phase | None, rng: np.random.Generator) -> Phase:
        build = previous.build.copy() if previous is not None else Build(problem.scene)
        origin = previous.origin if previous is not None else None
        shapes = ShapeCache(problem.scene.block)
        xr, yr = fill_window(problem.scene)
        placed = drops = checks = fruitless = 0
        cut = False  # whether the last round was cut short by the clock
        while len(build) < problem.required and fruitless < self.patience and problem.time_left() > 0:
            cands = []
            cut = False
            # The drops may take half the time left: the other half is for letting them go.
            stop = problem.now() + 0.5 * problem.time_left()
            for _ in range(self.draws * 2 ** fruitless):
                if problem.now() > stop:
                    cut = True
                    break
                c = random_drop(problem, build, shapes, rng, (xr, yr))
                drops += 1
                if c is not None:
                    cands.append((-gain(problem, c), len(cands), c))
            cands.sort(key=lambda t: t[:2])
            rested = None
            for _, _, c in cands[: self.checks]:
                if problem.time_left() <= 0:
                    cut = True
                    break
                checks += 1
                rested = self.accept(problem, build, c)
                if rested is not None:
                    break
            if rested is None:
                fruitless += 1
                continue
            build.place(rested)
            placed += 1
            fruitless = 0
            problem.tell(self.name, build, f"{len(build)} placed")
        swept = 0
        if self.sweep and len(build) < problem.required and fruitless >= self.patience and not cut:
            added, swept, checked, cut = self._swept(problem, build, shapes, rng)
            placed += added
            checks += checked
        # A fruitless round the clock cut short says nothing of the room: that is the time.
        ended = ("count" if len(build) >= problem.required
                 else "room" if fruitless >= self.patience and not cut else "time")
        return Phase(build, FillStats(placed, drops, checks, fruitless, ended, swept), origin)

    def _swept(self, problem: Problem, build: Build, shapes: ShapeCache, rng: np.random.Generator
               ) -> tuple[int, int, int, bool]:
        """Blocks placed from sweeps of ``build`` (changed in place), one at a time, the best by
        :func:`optimizer.search.beam.gain` that comes to rest first. After each, only the
        places near it are swept again, and the others lowered again; those let go that did
        not come to rest are not let go again. With ``first``, the nodes near those points are
        swept first, and the others only while the count is still short. Returns the blocks
        placed, the drops, the candidates let go, and whether it ended short of sweeping every
        node or on the clock.

        Every candidate is let go among its neighbours (:func:`physics.settle_in`), on the bare
        foundation too, whatever ``accept`` does: the places a sweep finds are few, and on
        ``wall-rough`` seed 1 the best of them by gain was a block on the rubble at the toe,
        which, kept where it touched, tipped over in the settle of the whole layout."""
        window = fill_window(problem.scene)
        placed = checks = drops = 0
        whole = True
        # Near where the settle took blocks out first, then, while the count is short, the rest
        # of the window; or the whole window at once.
        parts = [False] if self.first is None else [False, True]
        around = None if self.first is None else (self.first, near_reach(problem))
        # The first part's candidates not let go go on to the second, and those let go that did
        # not come to rest are not let go again there.
        left: list[Candidate] = []
        failed: set[tuple] = set()
        for beyond in parts:
            if len(build) >= problem.required or problem.time_left() <= 0:
                break
            added, more, took, done, left = self._swept_part(problem, build, shapes, rng, window,
                                                             around, beyond, left, failed)
            placed, drops, checks, whole = placed + added, drops + more, checks + took, whole and done
        return placed, drops, checks, not whole or problem.time_left() <= 0

    def _swept_part(self, problem: Problem, build: Build, shapes: ShapeCache, rng: np.random.Generator,
                    window, around, beyond: bool, left: list[Candidate], failed: set[tuple]
                    ) -> tuple[int, int, int, bool, list[Candidate]]:
        """:meth:`_swept` over one part of the window (all of it where ``around`` is None), with
        ``left`` (candidates not let go before) and without those ``failed`` (let go before, not
        come to rest; added to as it goes): the blocks placed, the drops, the candidates let go,
        whether every node was swept, and the candidates it did not let go."""
        # The sweep may take most of the time left (on wall-rough seed 1 it took 36 s of the
        # refill's 45), the rest is for letting its candidates go: the few it finds.
        found, drops, whole = sweep(problem, build, shapes, window, rng, around=around,
                                    stop=problem.now() + SWEEP_SHARE * problem.time_left(), beyond=beyond)
        found = left + ([c for c in found if _key(c) not in failed] if failed else found)
        placed = checks = 0
        while found and len(build) < problem.required and problem.time_left() > 0:
            found.sort(key=lambda c: -gain(problem, c))
            rested, tried = None, 0
            for c in found[: self.checks]:
                if problem.time_left() <= 0:
                    break
                checks += 1
                tried += 1
                rested = settle_in(problem, build, c)
                if rested is not None:
                    break
                failed.add(_key(c))
            if rested is None:
                return placed, drops, checks, whole, found[tried:]
            build.place(rested)
            placed += 1
            problem.tell(self.name, build, f"{len(build)} placed (sweep)")
            # Only drops within reach of the new block change: those are lowered again. The
            # ones let go before it did not come to rest, and are not let go again.
            at, reach = rested.pose.position[:2], near_reach(problem)
            far = [c for c in found[tried:] if np.hypot(*(c.pose.position[:2] - at)) > reach]
            near, more, done = sweep(problem, build, shapes, window, rng, around=(at, reach))
            found, drops, whole = far + near, drops + more, whole and done
        return placed, drops, checks, whole, found


def near_reach(problem: Problem) -> float:
    """``NEAR_REACH`` in metres, for the scene's block."""
    return NEAR_REACH * problem.scene.block.bounding_radius


def _key(c: Candidate) -> tuple:
    """A candidate's pose, to tell whether a sweep lowered it before."""
    return tuple(np.round(np.concatenate([c.pose.position, c.pose.quaternion]), 6))


def sweep(problem: Problem, build: Build, shapes: ShapeCache,
          window: tuple[tuple[float, float], tuple[float, float]], rng: np.random.Generator,
          around: tuple[np.ndarray, float] | None = None, stop: float | None = None,
          beyond: bool = False) -> tuple[list[Candidate], int, bool]:
    """Every drop of a grid over ``window``, ``SWEEP_STEP`` of H apart, in each hanging at
    ``SWEEP_YAWS`` yaws over its symmetry's period, that is valid as lowered (not loose);
    with ``around`` (a point, or an array of them, and a distance), only the nodes within
    that distance of one of them, or with ``beyond`` only the others.

    Random drops miss narrow pockets: on a ``wall-rough`` layout one block short after its
    settle, 3000 of them found no room, where this grid found 6 places that come to rest and
    3 where the layout then stands (``benchmarks/studies/room_sweep.py``). The nodes are
    taken in a random order, so a sweep the clock cuts short has covered the window evenly.
    Places the block crosses the zone's ceiling at even if it rests on the foundation's lowest
    point are not lowered (:meth:`Build.clear_of_ceiling`). Lowering stops at ``stop``
    (``problem.now()``; the deadline by default). Returns the candidates, the drops lowered,
    and whether every node was lowered at.
    """
    stop = problem.deadline if stop is None else stop
    (x0, x1), (y0, y1) = window
    step = SWEEP_STEP * problem.scene.block.height
    xs, ys = np.arange(x0, x1 + 1e-9, step), np.arange(y0, y1 + 1e-9, step)
    nodes = np.array(np.meshgrid(xs, ys, indexing="ij")).reshape(2, -1).T
    if around is not None:
        points = np.asarray(around[0], float).reshape(-1, 2)
        near = (np.linalg.norm(nodes[:, None, :] - points[None, :, :], axis=2) <= around[1]).any(axis=1)
        nodes = nodes[~near if beyond else near]
    nodes = nodes[rng.permutation(len(nodes))]
    hung = [shapes.hung(f, yaw) for f, yaw in spread_yaws(shapes.block, problem.families, SWEEP_YAWS)]
    return lowered(problem, build, hung, nodes, stop)


def lowered(problem: Problem, build: Build, hung: list, nodes: np.ndarray, stop: float,
            exclude: frozenset[int] = frozenset()) -> tuple[list[Candidate], int, bool]:
    """Each shape of ``hung`` lowered at each of ``nodes`` (n, 2), in that order, with the blocks
    ``exclude`` left out (:meth:`Build.lower`): the candidates valid as lowered (not loose), the
    drops lowered, and whether every node was lowered at before ``stop`` (``problem.now()``).
    Places :meth:`Build.clear_of_ceiling` refuses are not lowered: :meth:`Build.lower` would
    refuse them too."""
    found: list[Candidate] = []
    drops = 0
    if not hung or not len(nodes):  # only free turns: no hanging to lower
        return found, drops, True
    # In chunks, so that a mound kilometres long is tested as the clock allows, not all at once.
    for chunk in np.array_split(nodes, max(1, len(nodes) // SWEEP_CHUNK)):
        if problem.now() > stop:
            return found, drops, False
        clear = np.column_stack([build.clear_of_ceiling(shape, chunk) for shape in hung])
        for (x, y), row in zip(chunk, clear, strict=True):
            if problem.now() > stop:
                return found, drops, False
            for shape, ok in zip(hung, row, strict=True):
                if not ok:
                    continue
                drops += 1
                c = build.lower(shape, float(x), float(y), exclude=exclude)
                if c is not None:
                    found.append(c)
    return found, drops, True


def random_drop(problem: Problem, build: Build, shapes: ShapeCache, rng: np.random.Generator,
                window: tuple[tuple[float, float], tuple[float, float]]) -> Candidate | None:
    """A block in a random allowed hanging at a random yaw, lowered at a random point of
    ``window`` (``fill_window``) until it touches; loose where its first contact is out of the zone."""
    fam = problem.families[int(rng.integers(len(problem.families)))]
    q = free(rng) if fam == "free" else hanging_of(shapes.block, fam, float(rng.uniform(0, 2 * np.pi)))
    xr, yr = window
    return build.lower(shapes.get(q), float(rng.uniform(*xr)), float(rng.uniform(*yr)), loose=True)
