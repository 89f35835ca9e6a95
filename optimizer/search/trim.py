"""Porosity trim: blocks that stick out of the design prism moved into pockets inside it.

With the count fixed, a layout's porosity is the share of the design prism its
blocks leave empty, so it is over its window only by what the blocks hold
outside the prism: over the crest, out of the slopes, at the toes. Rows laid
along the toes to cover them hold much of their volume there: on ``mini``
with the Shake Block as a user's mesh, the attempt with toe rows first held
4.9 m³ outside the prism against 2.5 m³ without the rows (2.3 m³ of it in the
rows), and came to 57.3 % against a window that ends at 57 %
(docs/coverage-study.md, "The porosity of the attempt with toe rows").

Each move takes one block that carries nothing out, of those holding the most
volume outside the prism, and lowers it again where it holds more inside:
``draws`` random drops over the fill window, in any hanging, ranked by the
volume they hold inside, the best let go among their fixed neighbours
(``accept``; a drop on the bare foundation is kept where it touched) until
one comes to rest inside the zone with more inside than the block held
before and stays so when the blocks it rests on are let go with it
(``physics.held_up``). The move is kept if ``keep`` accepts the new build (a
coverage that must stay better than another attempt's). Moves go on, one at a
time, until the porosity is within ``TARGET_POINTS`` of the target, or
``PATIENCE`` rounds in a row find no move (each round draws anew), or the
time is up. The caller settles the whole layout again.

The constants were set on three untrimmed ``mini-rough`` layouts (seeds 1-3,
57.22-57.30 %), trimmed with 4 to 6 seeds each: with 3 blocks a round and
one round, 2 of 14 trims ended within the window; with 4 blocks and 3
rounds, 9 of 14, in at most 28 s, 7 of them standing when the whole layout
was settled again (docs/coverage-study.md). Blocks on the bare rubble were
then seated, which the search no longer does (stop 52); the constants were
not set again.

How many moves, blocks, drops and checks there are is fixed, so a seed gives
one result; the deadline only stops it early.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass

import numpy as np

from .build import Build, Candidate, fill_window
from .fill import random_drop
from .physics import held_up
from .problem import Problem, over
from .shapes import ShapeCache

#: Moves at most.
MOVES = 8
#: Blocks tried for each move: the free ones with the most volume outside the prism.
BLOCKS_TRIED = 4
#: Drops lowered for each block tried.
DRAWS = 300
#: Candidates let go for each block tried, the most inside first.
CHECKS = 12
#: Rounds in a row, each of ``BLOCKS_TRIED`` blocks, in which no move is found before the trim ends.
PATIENCE = 3
#: A move must add at least this share of a block's volume inside the prism.
MIN_GAIN = 0.02


@dataclass
class TrimStats:
    """What the trim did: moves kept, candidates let go, and the porosity before and after."""

    moved: int = 0
    tried: int = 0
    porosity_before_percent: float | None = None
    porosity_percent: float | None = None

    def to_dict(self) -> dict:
        return asdict(self)


Accept = Callable[[Problem, Build, Candidate], Candidate | None]
Keep = Callable[[Build], bool]


def trim_moves(problem: Problem, build: Build, accept: Accept, rng: np.random.Generator,
               keeps: Sequence[Keep] = ()) -> tuple[Build, TrimStats]:
    """Move free blocks from outside the prism to pockets inside while the porosity is over
    its window; returns a new build (``build`` is not changed).

    ``keeps`` are the caller's rules, strictest first: the moves go on under each in turn
    while the porosity is still over its window once the one before has found no more
    (none: every move is kept)."""
    stats = TrimStats(porosity_before_percent=build.porosity.percent, porosity_percent=build.porosity.percent)
    build = build.copy()
    for keep in keeps or [None]:
        build = _moves(problem, build, accept, rng, keep, stats)
    return build, stats


def _moves(problem: Problem, build: Build, accept: Accept, rng: np.random.Generator, keep: Keep | None,
           stats: TrimStats) -> Build:
    """The moves under one of the caller's rules (:func:`trim_moves`): the build after them."""
    block = problem.scene.block
    shapes = ShapeCache(block)
    window = fill_window(problem.scene)
    fruitless = 0
    refused: set[int] = set()  # blocks whose move ``keep`` refused: not tried again
    while stats.moved < MOVES and fruitless < PATIENCE:
        if over(problem, build) <= 0 or problem.time_left() <= 0:
            break
        outside = {k: block.volume - build.porosity.contribution(k) for k in build.free_keys()
                   if k not in refused}
        moved = None
        for key in sorted(outside, key=lambda k: -outside[k])[:BLOCKS_TRIED]:
            if outside[key] < MIN_GAIN * block.volume or problem.time_left() <= 0:
                break
            trial = build.copy()
            trial.remove(key)
            need = block.volume - outside[key] + MIN_GAIN * block.volume
            cands = []
            for _ in range(DRAWS):
                if problem.time_left() <= 0:
                    break
                c = random_drop(problem, trial, shapes, rng, window)
                # A loose drop (first contact out of the zone) may slide into a pocket, deeper in.
                if c is not None and (c.inside >= need or c.loose):
                    cands.append((-c.inside, len(cands), c))
            cands.sort(key=lambda t: t[:2])
            for _, _, c in cands[:CHECKS]:
                if problem.time_left() <= 0:
                    break
                stats.tried += 1
                rested = accept(problem, trial, c)
                if rested is None or rested.inside < need or not held_up(problem, trial, rested):
                    continue
                trial.place(rested)
                if keep is None or keep(trial):
                    moved = trial
                else:
                    refused.add(key)
                break
            if moved is not None:
                break
        if moved is None:
            fruitless += 1  # new drops may find what these did not
            continue
        fruitless = 0
        build = moved
        stats.moved += 1
        stats.porosity_percent = build.porosity.percent
        problem.tell("trim", build, f"{stats.moved} moved, porosity {build.porosity.percent:.2f}%")
    return build
