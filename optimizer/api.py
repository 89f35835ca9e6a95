"""``optimize``: the one public entry point of the placement search.

::

    from optimizer.api import optimize
    result = optimize(load_scene("mini"), seed=1, time_limit=120)
    result.layout         # shoha-layout/1, crane order
    result.to_dict()      # the keys of `shoha optimize --json` (docs/contract.md)

The pipeline, each step a pluggable strategy instance:

1. beam search builds a layout in crane order from the placement pattern;
2. simulated annealing refines it (porosity towards the target, evenness,
   support), and tries to add blocks where the count fell short;
3. optionally (``bound=True``, ``shoha optimize --bound``), CP-SAT solves the
   bottom layer exactly over a discretised candidate set and reports its
   bound beside the heuristic's result (the optimality gap). It changes the
   layout only when nothing rests on the ground layer yet, so on a finished
   layout it is a measurement, and it costs a quarter of a default run: it is
   an explicit step, off by default;
4. a physics settle confirms that the layout stands; unstable blocks are
   repaired (taken out, with whatever rests on them, and placed again) and
   the layout is settled again;
5. if the layout reaches its count and stands but is over its porosity
   window, blocks that stick out of the design prism are moved into pockets
   inside it, and the layout nearer the window is kept if it stands
   (:func:`trim_repair`, ``search.trim``);
6. if the layout is still short of its count, does not stand, or is off its
   porosity window, and the time its search took is left before the
   deadline, steps 1-5 run again on a random stream of their own (up to
   ``ATTEMPTS`` in all), and the best layout is kept;
7. if the best layout reaches its count and porosity but leaves the mound's
   surface bare, and its time is left, one more attempt lays rows along the
   toes first (:func:`covered_attempt`; trimmed as in 5 if it covers better
   but is over the window), and is kept if it covers better; if the layout
   kept then still leaves it bare and that attempt's time is left, one more
   (``COVER_ATTEMPTS``, :func:`covered_attempts`); an attempt with rows kept
   is repaired as in 8 at once, before the next is weighed against it;
8. if the layout kept still leaves the surface bare, blocks that carry
   nothing are moved one by one to where they cover most bare area, within
   the porosity window, and the moves are kept if the layout then stands, or
   else all but the last if that stands (:func:`cover_repair`): in rounds of
   twelve moves at most, each settled, while each round is kept, makes all its
   moves and the time lasts (a layout repaired in 7 made its first round there,
   and goes on from it).

Validity is never loosened: if the required count cannot be reached, the best
valid layout found is returned with the count it reached.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from geometry.checks import CheckReport, check_layout, check_not_crowded
from geometry.coverage import AIM_BARE_PERCENT, AIM_MAX_BARE_H, BARE_FRACTION, CoverageReport
from geometry.errors import InputError
from geometry.layout import Layout, Placement
from geometry.porosity import exact_filled_volume
from geometry.scene import Scene
from settle import Stopped

from .search import cover as search_cover
from .search.anneal import COVER_FACTOR, Annealing
from .search.beam import BeamSearch
from .search.build import GROUND, Build
from .search.cover import cover_moves
from .search.cpsat import BoundStats, CpSat
from .search.fill import PocketFill
from .search.hangings import families
from .search.patterns import InterlockLattice, pattern_for
from .search.physics import confirm, judged, raised_check, settled_layout, settling_by, stands, verdict
from .search.problem import (
    SETTLE_EXPONENT,
    TARGET_POINTS,
    Clock,
    Phase,
    Problem,
    SettleMeter,
    Strategy,
    off_window,
    over,
)
from .search.shapes import ShapeCache
from .search.sites import fit_to_toes, holds_margin, spread_to_count
from .search.toe import ToeRows
from .search.trim import trim_moves

#: The default time limit (s): at least this, ``SECONDS_PER_BLOCK`` a required block above it,
#: and at most ``MAX_DEFAULT_LIMIT`` (issue 24: up to 0.5 s a block, 20 minutes at most).
MIN_DEFAULT_LIMIT = 120.0
SECONDS_PER_BLOCK = 0.5
MAX_DEFAULT_LIMIT = 1200.0


def default_time_limit(scene: Scene) -> float:
    """``shoha optimize``'s limit when none is given: 0.5 s a required block, within [120 s, 20 min]."""
    return min(MAX_DEFAULT_LIMIT, max(MIN_DEFAULT_LIMIT, SECONDS_PER_BLOCK * scene.required_blocks))


#: What the end of a run costs, measured on 2 cores: a settle of 75 Shake Blocks (5 convex
#: pieces) takes about 0.6 s and of 1000 about 11 s, growing as n^1.15
#: (benchmarks/results/settle_speed.csv) and with the pieces; the counts, tolerance,
#: collisions and porosity about 0.2 s for 1005 blocks; the coverage about 2 ms a square
#: metre of slopes and crest (0.24 s for mini's 171 m2, 4.4 s for full's 2310 m2).
SETTLE_SECONDS_75 = 0.6
#: A rough underlayer (a MuJoCo height field) and a wall make a settle slower, by these
#: factors on the estimate above: measured on 2 cores with ``shoha settle``, 1.27 s for
#: mini-rough's 69 blocks, 0.94 s for wall-shake's 72 and 0.73 s for 53 blocks behind a wall
#: on rubble, against 0.35 s for mini's 75 on flat ground. Without them a run on rubble
#: confirmed its layout past the search's reserve and ran out of time for the coverage.
SETTLE_FACTOR_ROUGH = 2.5
SETTLE_FACTOR_WALL = 2.0
CHECK_SECONDS = (0.3, 0.0005)  # a fixed part, and per block
COVERAGE_SECONDS_PER_M2 = 0.002
#: How far past its limit a run may end (a time limit is a promise, kept to within this).
LIMIT_GRACE = 2.0
#: Reserves are this many times the estimate (a loaded machine runs slower), and take at
#: most this share of the limit (a limit too short for the scene places few blocks, whose
#: settle and checks are quick).
RESERVE_MARGIN = 2.0
RESERVE_SHARE = 0.5
#: A settle reserve from the settles timed in the run (:class:`search.problem.SettleMeter`) is
#: this many times what they took, scaled to the count. The estimate above is for flat mounds:
#: ``big-shake``'s 269 blocks, 4.5 m high, took 7.4 s to settle alone on 2 cores against its
#: 2.6 s, and 9-15 s with a third busy process; the confirming settles then did not fit in the
#: reserve, and half the layouts of that run were written as they failed (2026-11-27).
MEASURED_MARGIN = 1.5


def settle_reserve(scene: Scene, blocks: int | None = None, meter: SettleMeter | None = None) -> float:
    """Seconds kept for the settles that confirm a layout of ``blocks`` (the required count by
    default; two kicks, ``physics.verdict``; repairs take what time is left): the estimate with
    its margin, or more where the whole-layout settles timed in this run (``meter``) say so."""
    estimate, timed = _settle_seconds(scene, blocks, meter)
    return 2 * max(RESERVE_MARGIN * estimate, MEASURED_MARGIN * (timed or 0.0))


def verdict_seconds(scene: Scene, blocks: int, meter: SettleMeter | None = None) -> float:
    """What one verdict (two settles) of ``blocks`` should take, with no margin: the estimate,
    or the settles timed in this run where they are slower."""
    estimate, timed = _settle_seconds(scene, blocks, meter)
    return 2 * max(estimate, timed or 0.0)


def _settle_seconds(scene: Scene, blocks: int | None,
                    meter: SettleMeter | None) -> tuple[float, float | None]:
    """One settle of ``blocks`` (the required count by default): the estimate, and what the
    settles timed in this run make of it (None before one is)."""
    n, pieces = blocks or scene.required_blocks, len(scene.block.pieces)
    ground = max(SETTLE_FACTOR_ROUGH if scene.foundation.kind == "rough" else 1.0,
                 SETTLE_FACTOR_WALL if scene.design.wall_x is not None else 1.0)
    estimate = SETTLE_SECONDS_75 * (n / 75) ** SETTLE_EXPONENT * pieces / 5 * ground
    return estimate, meter.seconds(n) if meter is not None else None


def calibrated(problem: Problem, end: float) -> Problem:
    """``problem`` with its deadline brought forward where the settles timed so far say that the
    confirming settles, due by ``end``, need more time than it leaves (never before
    ``problem.meter.earliest``)."""
    deadline = max(problem.meter.earliest, end - settle_reserve(problem.scene, meter=problem.meter))
    return problem if deadline >= problem.deadline else replace(problem, deadline=deadline)


def check_reserve(scene: Scene, blocks: int | None = None) -> float:
    """Seconds kept for the final checks of ``blocks`` (the required count by default): counts,
    tolerance, collisions and porosity."""
    return RESERVE_MARGIN * (CHECK_SECONDS[0] + CHECK_SECONDS[1] * (blocks or scene.required_blocks))


def kept_reserves(scene: Scene, time_limit: float, blocks: int, settle_layout: bool = True
                  ) -> tuple[float, float, float]:
    """The seconds a run keeps from its search for the final checks, the confirming settles and
    the coverage of ``blocks``: each whole where together they take at most ``RESERVE_SHARE``
    of the limit. Beyond that, the checks first, then the settles (whether the layout stands),
    and the coverage last: it is measured up to the limit all the same, and left out (the result
    says so) where it does not fit.

    (The capped reserve once went to the checks and the coverage first: the search then ran to
    the moment the confirming settle had to end, and a 153-block mound under a 5 s limit was
    written unsettled and unmeasured at 2.5 s, where its settle took 0.2 s.)"""
    most = RESERVE_SHARE * time_limit
    check = min(check_reserve(scene, blocks), most)
    settle = min(settle_reserve(scene, blocks) if settle_layout else 0.0, most - check)
    return check, settle, min(coverage_reserve(scene), most - check - settle)


def coverage_reserve(scene: Scene) -> float:
    """Seconds the coverage of the final layout takes, with the margin (it grows with the surface)."""
    d = scene.design
    run = np.hypot(d.bottom_half_width - d.top_half_width, d.height)
    slopes = run if d.wall_x is not None else 2 * run
    return RESERVE_MARGIN * COVERAGE_SECONDS_PER_M2 * (slopes + 2 * d.top_half_width) * d.length


#: Times the pocket fill may go on from a confirmed layout short of its count, and the
#: confirmations' cost (of the last one, less the time it spent laying sites again:
#: ``Confirmation.relay_seconds``) kept free for the one after it. The one after it is stopped at
#: the confirmations' end whatever is kept (``physics.confirm``), so this is a guess at its length
#: with a quarter to spare, not what holds the limit. (Until stop 80 it was twice the last one:
#: ``big-shake`` ended two runs with two blocks short and 56-59 s of 134.5 unused, its
#: confirmations taking 28-35 s; docs/coverage-study.md, stop 80.)
REFILLS = 3
REFILL_SETTLES = 1.25

#: Share of the time limit, and most seconds, that tuning a new block's pattern may take.
TUNE_SHARE = 0.25
TUNE_MAX_SECONDS = 60.0
#: The share of the limit that choosing how far to spread the pattern may take (``spread_to_count``).
SPREAD_SHARE = 0.05

#: The steps of a run that draw random numbers, each numbered and with a stream of its own
#: (:func:`streams`): the attempts, each one's trim, the attempts with toe rows and their trims,
#: and the covering moves of an attempt kept (of an attempt with rows, numbered as those are).
STEPS = ("attempt", "trim", "rows", "rows trim", "cover", "rows cover")

#: ``stream(step, number)``: the random stream of one step of a run (:func:`streams`).
Streams = Callable[[str, int], np.random.Generator]


def streams(seed: int) -> Streams:
    """The random streams of a run with ``seed``: one for each numbered step (``STEPS``).

    Each step draws from its own stream, spawned from the seed, not from one stream that the
    steps before it have drawn on. So a step made or left out for want of time, or a step that
    ran longer and drew more, does not change what the steps after it draw. On one stream
    (until 2026-12-06), ``mini-mesh`` seed 1 tuned its pattern quicker in one run than in
    another; the time saved let covering moves be tried on its first attempt, they moved
    nothing, but their draws changed the attempt with toe rows that followed, and the layout
    came out at 57.01 %, over the window, where it had been 4.70 % bare within it."""
    def stream(step: str, number: int) -> np.random.Generator:
        return np.random.default_rng(np.random.SeedSequence([seed, STEPS.index(step), number]))
    return stream


@dataclass
class OptimizeResult:
    """What ``optimize`` found, and how it checks.

    Attributes
    ----------
    layout : Layout
        Blocks in crane order, ids ``0..n-1`` (with ``keep``: the kept blocks
        first with their own ids, then ids counting on from the largest).
    porosity_percent : float
        Exact porosity of the design prism.
    blocks, required_blocks : int
    collisions : int
        Interpenetrating pairs (FCL, deeper than the contact tolerance).
    out_of_tolerance : int
        Blocks with volume outside the tolerance zone.
    stable : bool or None
        Physics verdict (None when settle was skipped).
    seconds : float
    phases : list of dict
        Per strategy: name, seconds, blocks and porosity after it, and its stats.
    gap : dict
        The CP-SAT bound beside the heuristic's result, where the bound step ran.
    outside_design_prism_m3 : float
        Block volume outside the design prism (in the tolerance zone, where
        the layout is valid): what porosity loses to blocks that stick out.
        The blocks' volume less what fills the prism, so with blocks one inside
        another (kept ones) their overlap counts too.
        Not ``shoha check``'s ``outside_volume_m3``, which is a block's volume
        outside the tolerance zone.
    coverage : dict or None
        ``shoha check``'s coverage object (bare share, largest bare distance,
        where it is); None when the time limit left no room to measure it.
    time_limit_s : float
        The limit the run had (the default one unless given).
    cover_attempt : str or None
        Where the layout misses a coverage aim, what came of the attempt with
        toe rows first (:func:`covered_attempt`) and of the blocks moved to
        bare areas (:func:`cover_repair`), in words for :meth:`summary`.
    searched : int or None
        Blocks the search placed before the settle that confirmed them.
    shortfall : str or None
        Short of the count, why the search stopped, in words for
        :meth:`summary` (:func:`shortfall`); None where that is not known.
    coverage_left_out : bool
        The run did not measure the coverage: the time limit left no room for it.
    outside_budget_m3 : float or None
        The most block volume the required count may hold outside the design
        prism with the porosity within its window (:func:`outside_budget`),
        for :meth:`summary`; None where not known.
    kept : dict or None
        With ``keep``: how many blocks were kept, and the ids of those among
        them that collide, stick out of the tolerance zone or fail the settle
        (they stay all the same; a layout with any is not valid).
    """

    layout: Layout
    porosity_percent: float
    blocks: int
    required_blocks: int
    target_porosity_percent: float
    collisions: int
    out_of_tolerance: int
    stable: bool | None
    seconds: float
    settle: dict[str, Any] = field(default_factory=dict)
    phases: list[dict[str, Any]] = field(default_factory=list)
    gap: dict[str, Any] = field(default_factory=dict)
    outside_design_prism_m3: float = 0.0
    path: str | None = None
    coverage: dict[str, Any] | None = None
    kept: dict[str, Any] | None = None
    time_limit_s: float | None = None
    cover_attempt: str | None = None
    searched: int | None = None
    shortfall: str | None = None
    coverage_left_out: bool = False
    outside_budget_m3: float | None = None

    @property
    def valid(self) -> bool:
        return (self.blocks == self.required_blocks and self.collisions == 0
                and self.out_of_tolerance == 0 and self.stable is not False
                and self.settle.get("skipped") != "time")

    def summary(self) -> str:
        """The result in plain words."""
        if self.blocks < self.required_blocks:
            head = (f"{self.required_blocks} required, {self.blocks} fit: "
                    f"porosity {self.porosity_percent:.1f}%")
        else:
            head = (f"{self.blocks} blocks, porosity {self.porosity_percent:.2f}% "
                    f"(target {self.target_porosity_percent:g}%)")
        verdict = {True: "stable", False: "NOT stable", None: "not settled"}[self.stable]
        text = (f"{head}; {self.collisions} collisions, {self.out_of_tolerance} out of tolerance, "
                f"{verdict}; {self.seconds:.1f} s")
        if self.coverage is not None:
            c = self.coverage
            text += f"; bare {c['bare_share_percent']:.1f}%"
            if c["max_bare_m"] is not None:
                text += f", farthest {c['max_bare_m']:.2f} m from a block"
        if (self.searched is not None and self.blocks < min(self.searched, self.required_blocks)
                and self.stable is not False):
            # Why the count can end below what the search showed on the way.
            text += (f"\nthe search placed {self.searched} blocks; the confirming settle took out those "
                     f"that did not stand, with what rested on them, and {self.blocks} stood in the end")
        text += self._not_standing()
        if self.settle.get("skipped") == "time":
            text += ("\nthe layout was not settled: one settle of it would not fit in the time limit, "
                     "so whether it stands is not known; a longer --time-limit settles it")
        if self.shortfall:
            text += f"\n{self.shortfall}"
        text += self._over_budget()
        if self.coverage is not None:
            text += self._not_covered()
        elif self.coverage_left_out:
            text += "\nthe coverage was not measured: the time limit left no room for it"
        off = self.porosity_percent - self.target_porosity_percent
        if self.blocks >= self.required_blocks and abs(off) > TARGET_POINTS:
            text += (f"\nporosity is {abs(off):.2f} points {'above' if off > 0 else 'below'} the target")
            if off > 0 and self.outside_design_prism_m3 > 0:
                # The blocks' volume less what fills the prism: with blocks one inside another
                # (kept ones) the overlaps are in it too, and none need be in the zone.
                faulty = self.collisions or self.out_of_tolerance
                where = ("outside the design prism or inside other blocks" if faulty
                         else "outside the design prism, in the tolerance zone")
                text += f": {self.outside_design_prism_m3:.1f} m³ of the blocks lies {where}"
        if self.kept is not None:
            k = self.kept
            faults = [f"{len(k[key])} {words}: {_ids(k[key])}"
                      for key, words in (("colliding", "collide"), ("out_of_tolerance", "stick out"),
                                         ("unstable", "do not stand")) if k[key]]
            text += (f"\nkept {k['blocks']} blocks where they were"
                     + (f"; of those, {'; '.join(faults)}" if faults else ""))
        return text

    def _over_budget(self) -> str:
        """Where a layout short of its count already holds more of its volume outside the design
        prism than the whole count may within the porosity window (:func:`outside_budget`): a line
        that says so. Blocks added never take volume from the prism's outside, so no layout that
        keeps these blocks where they are reaches both the count and the porosity. (Every tetrapod
        scene that ends short of its count does: ``tetrapod-big``'s 65 of 75 hold 18.9-20.2 m³
        outside, where all 75 may hold 14.0.) Not where blocks collide: the figure then counts their
        overlaps too, and the words "outside the design prism" would not be right. A budget below
        zero (a scene whose own ``required_blocks`` is under what its target asks) says instead
        that the count cannot reach the porosity at all."""
        if self.outside_budget_m3 is None or self.blocks >= self.required_blocks:
            return ""
        if self.outside_budget_m3 < 0:
            return (f"\neven all {self.required_blocks} blocks wholly inside the design prism would "
                    f"leave its porosity more than {TARGET_POINTS:g} point over the target: the "
                    "required count is too small for the target porosity")
        if self.collisions or self.outside_design_prism_m3 <= self.outside_budget_m3:
            return ""
        # Enough digits that the two figures read apart (0.5 and 0.5 once read as a contradiction).
        held, budget = self.outside_design_prism_m3, self.outside_budget_m3
        digits = next((d for d in range(1, 7) if round(held, d) != round(budget, d)), 6)
        return (f"\nthe {self.blocks} blocks placed already hold {held:.{digits}f} m³ "
                f"outside the design prism, where all {self.required_blocks} may hold at most "
                f"{budget:.{digits}f} m³ with the porosity within {TARGET_POINTS:g} point of "
                "its target: no layout that keeps these blocks where they are reaches both the count "
                "and the porosity")

    def _not_standing(self) -> str:
        """Where the settle's verdict fails on blocks not kept: a line that says why they are in.

        The confirming settle takes out what does not stand while a settle of what is left
        fits in the limit (``search.physics.confirm``), so the layout written fails it only
        where the time ran out first, or where the engine named no block."""
        if self.stable is not False:
            return ""
        kept = len(self.kept["unstable"]) if self.kept is not None else 0
        failed = len(self.settle.get("unstable", [])) - kept
        if failed > 0:
            return (f"\n{failed} {'block' if failed == 1 else 'blocks'} did not stand when the layout was "
                    "settled, and the time limit left no room to take them out and settle what is left "
                    "again: a longer --time-limit may give a layout that stands")
        if kept:
            return ""  # the kept blocks' own line names them
        return "\nthe settle did not confirm that the layout stands (the physics engine named no block)"

    def _not_covered(self) -> str:
        """A line on the coverage aims the layout misses, and why, or nothing if it meets them."""
        c = self.coverage
        assert c is not None
        h = c["bare_distance_m"] / BARE_FRACTION
        misses = []
        if c["bare_share_percent"] > AIM_BARE_PERCENT:
            misses.append(f"{c['bare_share_percent']:.1f}% of the slopes and crest lies over H/2 = "
                          f"{c['bare_distance_m']:.2f} m from a block (aim: at most {AIM_BARE_PERCENT:g}%)")
        if c["max_bare_m"] is not None and c["max_bare_m"] > AIM_MAX_BARE_H * h:
            x, y, z = c["worst_point"]
            misses.append(f"the point ({x:.1f}, {y:.1f}, {z:.1f}) lies {c['max_bare_m']:.2f} m from one "
                          f"(aim: within H = {AIM_MAX_BARE_H * h:.2f} m)")
        if not misses:
            return ""
        return "\nthe mound is not covered: " + "; ".join(misses) + (
            f"; {self.cover_attempt}" if self.cover_attempt else "") + (
            " (how much no block inside the tolerance zone can reach: shoha scene info SCENE --floor)")

    def to_dict(self) -> dict[str, Any]:
        return {
            "porosity_percent": self.porosity_percent,
            "blocks": self.blocks,
            "required_blocks": self.required_blocks,
            "target_porosity_percent": self.target_porosity_percent,
            "collisions": self.collisions,
            "out_of_tolerance": self.out_of_tolerance,
            "stable": self.stable,
            "seconds": self.seconds,
            "time_limit_s": self.time_limit_s,
            "path": self.path,
            "valid": self.valid,
            "outside_design_prism_m3": self.outside_design_prism_m3,
            "coverage": self.coverage,
            "kept": self.kept,
            "settle": self.settle,
            "phases": self.phases,
            "gap": self.gap,
        }


def default_strategies(bound: bool = False) -> list[Strategy]:
    """Beam search, a pocket fill where it fell short, then annealing; with ``bound``, then the
    CP-SAT bound on the ground layer."""
    out: list[Strategy] = [BeamSearch(accept=raised_check, judge=stands), PocketFill(accept=raised_check),
                           Annealing(accept=raised_check)]
    return out + [CpSat()] if bound else out


def optimize(
    scene: Scene,
    seed: int = 0,
    time_limit: float | None = None,
    strategies: Sequence[Strategy] | None = None,
    lattice: InterlockLattice | None = None,
    settle_layout: bool = True,
    report: Callable[[str, Build, str], None] | None = None,
    bound: bool = False,
    clock: Clock = time.monotonic,
    keep: Sequence[Placement] | None = None,
    started: float | None = None,
    cover: bool = True,
) -> OptimizeResult:
    """Find a reference layout for ``scene``.

    Parameters
    ----------
    scene : Scene
    seed : int
        All randomness comes from streams spawned from the seed, one for each
        step (:func:`streams`); the same
        seed gives the same layout, byte for byte, as long as ``time_limit``
        neither cuts the strategies' fixed work short nor decides whether
        another attempt fits (``ATTEMPTS``), nor whether a trim is made again
        (``TRIM_TRIES``).
    time_limit : float, seconds, optional
        Wall-clock budget of the whole run, checks included: it is kept to
        within 2 s. The best valid layout found so far is returned when it
        runs out. By default :func:`default_time_limit`.
    strategies : sequence of Strategy, optional
        Run in order, each improving the previous one's build; by default
        :func:`default_strategies`.
    lattice : InterlockLattice, optional
        Placement pattern; the block type's tuned lattice by default.
    settle_layout : bool
        Confirm (and repair) with a physics settle; and where the best attempt
        reaches its count over its porosity window, move blocks that stick
        out of the design prism into pockets inside it (:func:`trim_repair`).
    report : callable, optional
        ``report(phase, build, message)`` for a progress display.
    bound : bool
        Add the CP-SAT bound step to the default strategies (ignored when
        ``strategies`` is given).
    clock : callable
        The clock the time limit is read on; tests inject one.
    keep : sequence of Placement
        A partial layout to complete (``shoha optimize --keep``): its blocks
        stay exactly where they are, first in crane order, and the search
        places the rest around and on them. Each must be of the scene's block
        type. Given, even empty, the result reports them (``kept``).
    started : float, optional
        The ``clock`` reading when the caller's job began, if before this
        call: ``shoha optimize`` passes the time before it read the scene and
        cut a user's mesh into pieces, so that the limit covers them too and
        ``seconds`` is what the user waited.
    cover : bool
        When the best attempt reaches its count and porosity but leaves the
        mound's surface bare (``geometry.coverage``'s aims), and its time is
        left, try once more with rows along the toes laid first
        (:func:`covered_attempt`); keep that layout if it reaches the count and
        porosity too and covers better (not with ``keep``), and if the layout
        kept still leaves it bare and that attempt's time is left, once more
        (:func:`covered_attempts`). With ``settle_layout``, move blocks that
        carry nothing to bare areas (:func:`cover_repair`; kept blocks never
        move): an attempt with rows as soon as it is kept, else the layout kept;
        and, to weigh an attempt with rows that covers no better, the layout
        kept and then that attempt (:func:`covered_attempt`).
    """
    if scene.kind != "3d":
        raise InputError(f"{scene.source or scene.name}: a {scene.kind} scene is a 2D slice for physics "
                         "checks; shoha optimize places blocks in 3D scenes")
    start = clock() if started is None else min(started, clock())
    kept_given, keep = keep is not None, tuple(keep or ())
    check_keep(scene, keep)
    time_limit = default_time_limit(scene) if time_limit is None else float(time_limit)
    stream = streams(seed)
    spread = lattice is None and not keep  # a pattern given is laid as given; kept blocks set their own
    beyond = beyond_reach(scene)  # why no layout reaches the count, where a bound shows it
    nowhere = beyond is not None and beyond.startswith(NO_BLOCK_FITS)  # no search, no pattern tuned
    tune_phase = None
    if lattice is None:
        # A block with no tuned pattern is tuned now, within a share of the limit, and cached.
        t0 = clock()
        tune_seconds = 0.0 if nowhere else min(TUNE_SHARE * time_limit, TUNE_MAX_SECONDS)
        lattice, tuning = pattern_for(scene.block, scene.block_type, tune_seconds, clock)
        if tuning.source != "built in":
            tune_phase = {"strategy": "tune", "attempt": 1, "seconds": clock() - t0, **asdict(tuning),
                          "area_per_block_m2": lattice.area_per_block, "blocks": 0,
                          "porosity_percent": 100.0}
    # The search ends early enough for the confirming settle and the final checks, of the kept
    # blocks too (5000 kept ones, far apart, took 31 s of a 10 s limit when only the count was).
    n = max(scene.required_blocks, len(keep))
    reserve = sum(kept_reserves(scene, time_limit, n, settle_layout))
    problem = Problem(
        scene=scene,
        required=scene.required_blocks,
        target=scene.target_porosity,
        lattice=lattice,
        families=families(scene.block),
        deadline=start + time_limit - reserve,
        span=time_limit - reserve,
        report=report,
        clock=clock,
        meter=SettleMeter(earliest=start + (1.0 - RESERVE_SHARE) * time_limit),
    )
    strategies_run = list(strategies) if strategies is not None else default_strategies(bound)
    if nowhere:
        strategies_run = []  # no block fits anywhere in the zone: the summary says why (shortfall)
    spread_phase = None
    if spread and any(isinstance(s, BeamSearch) for s in strategies_run):
        # A pattern denser than the target fills a tall mound's count with its top empty: spread.
        t0 = clock()
        shapes = ShapeCache(scene.block)
        factor, held = spread_to_count(problem, shapes, min(t0 + SPREAD_SHARE * time_limit, problem.deadline))
        if factor != 1.0:
            problem = replace(problem, lattice=problem.lattice.scaled(factor))
        width = problem.lattice.w
        # Wider columns only where the pattern was seen to hold the count with the spread's margin.
        problem = fit_to_toes(problem, shapes, problem.deadline, stretch=holds_margin(problem, held))
        spread_phase = {"strategy": "spread", "attempt": 1, "seconds": clock() - t0, "factor": factor,
                        "holds": held, "blocks": 0, "porosity_percent": 100.0,
                        "across": problem.lattice.w / width, "anchor": problem.anchor}

    def end_for(blocks: int) -> float:
        """When the confirming settles must end, for a layout of ``blocks``: what its final
        checks and coverage leave of the limit (:func:`kept_reserves` of so many blocks)."""
        kept_checks, _, kept_measure = kept_reserves(scene, time_limit, blocks, settle_layout)
        return start + time_limit - kept_checks - kept_measure

    end = end_for(n)
    kept = kept_in_time(scene, keep, start, time_limit, clock) if keep else None
    tried: list[_Attempt] = []
    for attempt in range(1, ATTEMPTS + 1):
        tried.append(_attempt(problem, strategies_run, scene, kept, stream("attempt", attempt), settle_layout,
                              end, attempt, end_for=end_for))
        if settle_layout:
            problem = calibrated(problem, end)
            # A layout at its count over its porosity window: blocks that stick out moved in,
            # before another attempt is weighed (a trim that brings it in saves one).
            tried[-1], trim = trim_repair(problem, tried[-1], stream("trim", attempt), attempt, end)
            if trim is not None:
                tried[-1].phases.append(trim)
        if not tried[-1].another(problem, clock()):
            break
    chosen = max(range(len(tried)), key=lambda i: tried[i].key(problem))  # the first of equals
    cover_note = "the attempt with toe rows first is not made with --keep" if cover and keep else None
    if cover and not keep:
        chosen, cover_note = covered_attempts(problem, strategies_run, tried, chosen, stream, settle_layout,
                                              end)
    best, moves = tried[chosen], None
    if cover and settle_layout:
        # The attempts keep their own figures (the attempts phase); the repaired layout is written.
        best, moves = repair_once(problem, best, stream("cover", chosen + 1), chosen + 1, end, rounds=None)
    if moves and moves["moved"] and moves["stood"]:
        n = moves["moved"]
        undone = moves.get("undone", 0)
        undone = ("" if not undone else " (the last move undone: with it the layout fell)" if undone == 1
                  else f" ({undone} moves undone, the last of a round each: with them the layout fell)")
        moved = (f"moving {n} {'block that' if n == 1 else 'blocks that'} carried nothing to bare areas "
                 f"took the bare share from {moves['bare_before_percent']:.1f}% to "
                 f"{moves['bare_share_percent']:.1f}%{undone}")
        cover_note = f"{cover_note}; {moved}" if cover_note else moved
    build, gap, settle_info, stable = best.build, best.gap, best.settle, best.stable
    tried[chosen] = best
    phases = [p for p in (tune_phase, spread_phase) if p] + [p for t in tried for p in t.phases]
    if len(tried) > 1:
        own = [t.unmoved or t for t in tried]
        phases.append({"strategy": "attempts", "attempts": len(tried), "chosen": chosen + 1,
                       "blocks": [len(t.build) for t in own],
                       "porosity_percent": [t.build.porosity.percent for t in own],
                       **({"bare_share_percent": [t.coverage.bare_share_percent if t.coverage else None
                                                  for t in own]}
                          if any(t.coverage for t in own) else {})})
    layout = build.layout({"generator": {"tool": "shoha optimize", "seed": seed,
                                         **({"kept": len(keep)} if keep else {})}})
    # The coverage is measured if the time left allows it (a scene far too long for its limit
    # may not); without it the result says so.
    left = start + time_limit - clock()
    known = best.coverage  # measured already to choose the attempt (covered_attempt)
    fits = left >= check_reserve(scene, len(layout.blocks)) + coverage_reserve(scene)
    report_ = check_layout(scene, layout.placed(), with_coverage=False)
    report_.coverage = known
    if known is None and clock() + coverage_reserve(scene) / RESERVE_MARGIN <= start + time_limit:
        # Where its estimate fits, the measure may run a second past the limit: the estimate
        # holds for blocks like the built-in ones, and long slender blocks take far longer.
        # Where only the estimate without its margin fits, it is tried up to the limit: the
        # margin is for a loaded machine, and a 150-block layout whose reserve was 1.8 s was
        # measured in 0.3 s. (Not with less: its sampling is not stopped until it measures.)
        report_.coverage = problem.coverage(layout.placed(),
                                            until=start + time_limit + (1.0 if fits else 0.0))
    return OptimizeResult(
        layout=layout,
        porosity_percent=report_.porosity_percent,
        blocks=report_.blocks,
        required_blocks=scene.required_blocks,
        target_porosity_percent=scene.target_porosity,
        collisions=len(report_.collisions),
        out_of_tolerance=len(report_.out_of_tolerance),
        stable=stable,
        seconds=clock() - start,
        settle=settle_info,
        phases=phases,
        gap=gap,
        outside_design_prism_m3=max(0.0, outside_prism(scene, report_.blocks, report_.porosity_percent)),
        coverage=report_.coverage.to_dict() if report_.coverage is not None else None,
        time_limit_s=time_limit,
        kept=kept_report(keep, report_, [layout.blocks[i].id for i in settle_info.get("unstable", [])])
        if kept_given else None,
        cover_attempt=cover_note,
        searched=best.searched,
        shortfall=shortfall(best.phases, problem.required, len(build), time_limit, bool(keep),
                            one_layer=single_layer(build), beyond=beyond),
        coverage_left_out=report_.coverage is None,
        outside_budget_m3=outside_budget(scene),
    )


def outside_budget(scene: Scene) -> float:
    """The most volume (m³) the required count of blocks may hold outside the design prism with
    the porosity no more than ``TARGET_POINTS`` over its target: what they hold in all, less what
    must fill the prism. With the count set by the target (``ceil((1 - target / 100) V_design /
    V_block)``, the target in percent), that is little: 1.8 blocks of ``tetrapod-big``'s 75, 2.4 %
    of their volume. Below zero where a scene's own count is under what its target asks."""
    return outside_prism(scene, scene.required_blocks, scene.target_porosity + TARGET_POINTS)


def outside_prism(scene: Scene, blocks: int, porosity_percent: float) -> float:
    """The volume (m³) ``blocks`` of the scene's block hold outside the design prism at that
    porosity: their volume less what fills the prism (with blocks one inside another, their
    overlap counts too)."""
    return blocks * scene.block.volume - (1.0 - porosity_percent / 100.0) * scene.design_volume


def single_layer(build: Build) -> tuple[float, float] | None:
    """Where every block of ``build`` rests on the foundation (one layer: each may touch its
    neighbours too), how high the tolerance zone's crest is over the design's base, and the
    block's height; else None."""
    if not len(build) or any(GROUND not in build.supports[k] for k in build.order):
        return None
    scene = build.scene
    return scene.tolerance.z_top - scene.design.z_bottom, scene.block.height


#: How many times the tolerance zone's volume the required blocks' own must exceed for
#: :func:`beyond_reach` to call the count out of reach: valid blocks overlap only in contacts
#: at most ``tol.contact_depth`` deep, a sliver of their volume.
ZONE_OVERFILL = 2.0
#: How :func:`fits_nowhere`'s words begin.
NO_BLOCK_FITS = "no block fits in the tolerance zone"


def fits_nowhere(scene: Scene) -> str | None:
    """Why no block of ``scene`` fits in its tolerance zone, where a bound shows it; else None:
    the block, turned any way, is at least as thick as the widest ball inside its convex hull,
    and the zone is less high than that. (A 0.3 m mound of 1.66 m Shake Blocks searched its
    whole limit, and said a longer one might place more: stop 77's probe.) ``optimize`` then
    runs no search."""
    zone = scene.tolerance
    high = zone.z_top - zone.z_bottom
    thick = 2.0 * inscribed_radius(scene.block.vertices)
    if thick > high:
        return (f"{NO_BLOCK_FITS}: turned any way, the block is at least {thick:.2f} m "
                f"thick (the widest ball inside its convex hull), and the zone is {high:.2f} m high")
    return None


def beyond_reach(scene: Scene) -> str | None:
    """Why no layout of ``scene`` can reach its count, where a bound shows it; else None: no
    block fits at all (:func:`fits_nowhere`), or the required blocks' volume is over
    ``ZONE_OVERFILL`` times the zone's (100 000 blocks of 1.7 m³ asked of a 160 m³ zone)."""
    nowhere = fits_nowhere(scene)
    if nowhere is not None:
        return nowhere
    zone = scene.tolerance
    need = scene.required_blocks * scene.block.volume
    if need > ZONE_OVERFILL * zone.volume:
        return (f"no layout holds {scene.required_blocks} blocks: they are {need:.4g} m³ of concrete, and "
                f"the tolerance zone they must lie in is {zone.volume:.4g} m³")
    return None


def inscribed_radius(points: np.ndarray) -> float:
    """Radius of the largest ball inside the convex hull of ``points`` (its Chebyshev ball, a
    linear programme over the hull's faces)."""
    from scipy.optimize import linprog
    from scipy.spatial import ConvexHull

    try:
        eq = ConvexHull(points).equations  # n . x + d <= 0 inside, |n| = 1
    except Exception:  # qhull refuses a flat or degenerate set: no ball, and no claim made
        return 0.0
    res = linprog(c=[0.0, 0.0, 0.0, -1.0], A_ub=np.column_stack([eq[:, :3], np.ones(len(eq))]),
                  b_ub=-eq[:, 3], bounds=[(None, None)] * 3 + [(0.0, None)])
    return float(res.x[3]) if res.success else 0.0


def shortfall(phases: list[dict[str, Any]], required: int, blocks: int, time_limit: float,
              kept: bool, one_layer: tuple[float, float] | None = None, beyond: str | None = None
              ) -> str | None:
    """Why an attempt's search stopped short of the count, from its last pocket fill (its
    ``ended``): no room found, or no time left. Where no fill ran (``--strategy`` without it),
    what the strategies that ran can place. None if it reached the count.

    With ``one_layer`` (:func:`single_layer`: every block on the foundation), no room found says
    that no second layer found room under the zone's crest either, with its height and the
    block's: on a mound under two blocks high (``benchmarks/scenes/shake-low-gentle.toml``, a
    2.95 m zone and 1.66 m blocks) the pattern's second layer, nested 0.8 H, stands 4 cm out
    of the zone, and no block lowered onto the first rests inside it (docs/coverage-study.md).

    ``beyond`` (:func:`beyond_reach`): why no layout reaches the count; it is said in place of
    the search's own reason, which then never says a longer limit may place more."""
    if blocks >= required:
        return None
    if beyond is not None:
        return beyond
    ended = [p for p in phases if "ended" in p]
    if not ended:
        return _without_fill(phases)
    last = ended[-1]
    if last["ended"] == "room":
        return (f"no room was found for more{' around the kept blocks' if kept else ''}: the last "
                f"pocket fill lowered {last['drops']} blocks at random over the mound, in every "
                f"hanging, and let the {last['checks']} most promising go; it stopped after "
                f"{last['fruitless']} rounds in a row in which none came to rest inside the "
                "tolerance zone" + ("" if one_layer is None else
                                    f"; all {blocks} blocks stand on the foundation, one layer, and "
                                    f"the zone's crest is {one_layer[0]:.2f} m over its base "
                                    f"against a block {one_layer[1]:.2f} m tall: a second layer "
                                    "of this block found no room under it"))
    if last["ended"] == "time":
        return (f"the search's time ran out (the limit of {time_limit:g} s, less what the settle and "
                "checks keep): a longer --time-limit may place more")
    return None


def _without_fill(phases: list[dict[str, Any]]) -> str | None:
    """The shortfall where no pocket fill ran: CP-SAT's ground layer, or the strategies' names."""
    names = list(dict.fromkeys(p["strategy"] for p in phases if p["strategy"] != "attempts"))
    if not names:
        return None
    solved = [p for p in phases if p["strategy"] == "cpsat" and not p.get("skipped")]
    if names == ["cpsat"] and solved:
        last = solved[-1]
        return (f"CP-SAT lays the ground layer only: the best choice among its {last['candidates']} "
                f"candidate poses on the foundation holds {last['placed']} blocks"
                f"{' (proved optimal among them)' if last.get('optimal') else ''}; with beam and fill "
                "in --strategy, blocks are laid on top as well")
    return (f"the strategies run ({', '.join(names)}) placed no more; the pocket fill "
            "(fill in --strategy, as by default) adds blocks where they settle, and says why it stops")


#: Searches a run may make: when one ends short of the required count (or with a layout that
#: does not stand) with the time its search took still left before the deadline
#: (:meth:`_Attempt.another`), the pipeline runs again
#: from the start on a stream of its own (:func:`streams`), and the best layout of all is kept. The first
#: attempt is the whole run wherever the count is reached.
ATTEMPTS = 3


@dataclass
class _Attempt:
    """One run of the strategies and the confirming settle: its layout, the seconds it took, and
    its coverage once measured (only where the coverage attempt has to judge it)."""

    build: Build
    phases: list[dict[str, Any]]
    gap: dict[str, Any]
    settle: dict[str, Any]
    stable: bool | None
    seconds: float = 0.0
    coverage: CoverageReport | None = None
    searched: int | None = None  # blocks before the confirming settle
    search_seconds: float = 0.0  # the strategies' time, before the confirming settle
    unmoved: _Attempt | None = None  # before the covering repair moved blocks (for the attempts phase)
    more_cover: bool = False  # its last round of covering moves made every move a round may
    _written: tuple[Build, float] | None = field(default=None, init=False, repr=False, compare=False)

    def reached(self, problem: Problem) -> bool:
        return len(self.build) >= problem.required and self.stable is not False

    def another(self, problem: Problem, now: float) -> bool:
        """Whether to search again after this attempt: it is short of its count, does not
        stand, or (trimmed) its porosity is still off its window; and its search fits again
        between ``now`` and the search's deadline. Its search only: the deadline keeps a
        reserve for the confirming settle, and the refills that follow a short search are not
        needed by one that reaches the count. (Counting them, a first attempt on
        ``wall-shake`` that ended short had its refills use the time a second one needed, on
        a loaded machine.)"""
        # The time first: on_target measures the layout's union (about 0.2 s for 1000 blocks).
        return now + self.search_seconds <= problem.deadline and not self.on_target(problem)

    def on_target(self, problem: Problem) -> bool:
        """Reached, and its porosity as written within ``TARGET_POINTS`` of the target."""
        return self.reached(problem) and off_window(self.as_written(problem), self.build) == 0.0

    def key(self, problem: Problem) -> tuple[bool, int, float]:
        """Better is larger: standing, then more blocks (up to the count), then porosity nearer
        the target: as written where the count is reached (short of it, as counted: the count
        decides, and the union is not measured)."""
        if not len(self.build):
            return self.stable is not False, 0, -np.inf
        count = min(len(self.build), problem.required)
        porosity = self.written_percent(problem) if count == problem.required else self.build.porosity.percent
        return self.stable is not False, count, -abs(porosity - problem.target)

    def written_gap(self, scene: Scene) -> float:
        """:func:`counted_below` of this attempt's layout, measured once for each layout
        (``dataclasses.replace`` of an attempt measures its own again)."""
        if self._written is None or self._written[0] is not self.build:
            self._written = (self.build, counted_below(scene, self.build))
        return self._written[1]

    def as_written(self, problem: Problem) -> Problem:
        """:func:`as_written` of this attempt's layout, from :meth:`written_gap`."""
        return replace(problem, target=problem.target - self.written_gap(problem.scene))

    def written_percent(self, problem: Problem) -> float:
        """The porosity of this attempt's layout as written (the blocks' union), percent."""
        return self.build.porosity.percent + self.written_gap(problem.scene)


def taken_out(before: Build, after: Build) -> np.ndarray:
    """Where (x, y) the blocks of ``before`` stood that ``after`` (its confirmed layout) has no
    block near: those a confirming settle took out. A settle moves the blocks it keeps by
    centimetres, so a block of ``after`` within half a bounding radius is the same block."""
    if not len(before):
        return np.empty((0, 2))
    at = np.array([before.poses[k].position for k in before.order])
    if not len(after):
        return at[:, :2]
    near = cKDTree(np.array([after.poses[k].position for k in after.order]))
    d, _ = near.query(at, distance_upper_bound=0.5 * before.block.bounding_radius)
    return at[~np.isfinite(d), :2]


def _attempt(problem: Problem, strategies: Sequence[Strategy], scene: Scene, kept: Build | None,
             rng: np.random.Generator, settle_layout: bool, end: float, attempt: int,
             all_or_nothing: bool = False, end_for: Callable[[int], float] | None = None) -> _Attempt:
    """The strategies in order from an empty (or kept) build, then the settle that confirms it.

    ``end_for(blocks)``, where given, is when the confirmation of a layout of so many blocks
    must end: a search far short of a large count leaves the checks of the count unneeded.
    (10 645 tetrapods of 0.35 t under a 5 s limit: checks for them all kept half the limit,
    and the 32 blocks placed were written as they failed, with 2.4 s of the limit left.)

    With ``all_or_nothing`` (the coverage attempt, kept only if it reaches the count), a build
    the strategies leave short of the count is returned as they left it, not confirmed. The
    settle's repair can add blocks, but not a search's shortfall: on ``full`` it brought the
    705 of 1005 the search left to 736.
    """
    clock = problem.clock
    start = clock()
    phase = Phase(kept.copy()) if kept is not None else None
    phases = []
    gap: dict[str, Any] = {}
    for strategy in strategies:
        if settle_layout:
            problem = calibrated(problem, end)  # a settle timed in the search may need more room
        t0 = clock()
        phase = strategy.run(problem, phase, rng)
        phases.append({"strategy": strategy.name, "attempt": attempt, "seconds": clock() - t0,
                       "blocks": len(phase.build), "porosity_percent": phase.build.porosity.percent,
                       **phase.stats.to_dict()})
        if isinstance(phase.stats, BoundStats) and not phase.stats.skipped:
            s = phase.stats
            gap = {"layer": "ground", "slab_m": s.slab_m, "heuristic_m3": s.heuristic_m3,
                   "objective_m3": s.objective_m3, "bound_m3": s.bound_m3, "gap_percent": s.gap_percent,
                   "optimal": s.optimal, "candidates": s.candidates, "seconds": s.seconds}
    build = phase.build if phase is not None else Build(scene)
    origin = phase.origin if phase else None
    search_seconds = clock() - start
    if not settle_layout or (all_or_nothing and len(build) < problem.required):
        return _Attempt(build, phases, gap, {}, None, search_seconds, search_seconds=search_seconds)
    if end_for is not None:
        end = max(end, end_for(len(build)))
    if clock() + verdict_seconds(scene, len(build), problem.meter) > end + LIMIT_GRACE:
        # Not even one verdict fits in the limit (a limit far too short for the kept blocks):
        # the layout is not settled, and says so, rather than overrun the limit.
        return _Attempt(build, phases, gap, {"skipped": "time"}, None, search_seconds,
                        search_seconds=search_seconds)
    searched = len(build)
    before = build
    build, confirmation = confirm(problem, build, rng, origin, end, whole=all_or_nothing)
    if confirmation.stopped:
        # Its settle ran past the end and was stopped: the layout is written as searched, and says
        # it is not settled, as where not even one settle fits.
        return _Attempt(build, phases, gap, {"skipped": "time"}, None, clock() - start,
                        searched=searched, search_seconds=search_seconds)
    # Short of the count, the pocket fill (if it is among the strategies) goes on from the
    # confirmed layout while a fill and one more confirmation fit: the settle has let blocks
    # come to rest lower, and what did not stand is out.
    fill = next((s for s in strategies if isinstance(s, PocketFill)), None)
    for _ in range(REFILLS if fill is not None else 0):
        reserve = settle_reserve(scene, meter=problem.meter)
        deadline = end - max(reserve, REFILL_SETTLES * (confirmation.seconds - confirmation.relay_seconds))
        if len(build) >= problem.required or not confirmation.stable or clock() >= deadline:
            break
        t0 = clock()
        # Where the search reached its count and the settle took blocks out, there was room for
        # them: the fill goes on with a sweep of the mound where its random drops find none,
        # first where those blocks were.
        refill = fill.sweeping(first=taken_out(before, build)) if searched >= problem.required else fill
        filled = refill.run(replace(problem, deadline=deadline), Phase(build, origin=origin), rng)
        more = filled.build
        gained = len(more) > len(build)
        if gained:
            again, check = confirm(problem, more, rng, origin, end)
            gained = len(again) > len(build) and check.stable
        # Every refill tried is a phase, the ones that gained nothing too: their time is spent.
        phases.append({"strategy": "refill", "attempt": attempt, "seconds": clock() - t0,
                       "blocks": len(again) if gained else len(build),
                       "porosity_percent": (again if gained else build).porosity.percent,
                       "added": len(again) - len(build) if gained else 0, **filled.stats.to_dict()})
        if not gained:
            break
        before, build, confirmation = more, again, check
        searched = max(searched, len(more))
    return _Attempt(build, phases, gap, confirmation.to_dict(), confirmation.stable, clock() - start,
                    searched=searched, search_seconds=search_seconds)


#: Attempts with toe rows first at most (:func:`covered_attempts`): one, and one more where its
#: time is left after it. Tried at 4 (e9e7f04, stop 67), once each step had a stream of its own:
#: no tuned run kept a third, and on the held-out ``brick-rough`` (seeds 2 and 3) a fourth
#: attempt covered a little better than the layout without rows before its covering moves, was
#: kept, and its moves did not stand: 45.3 and 49.0 % bare, where the layout without rows,
#: repaired, had come to 39.0 and 39.1 %. The time also went from the moves at the end.
COVER_ATTEMPTS = 2


def covered_attempts(problem: Problem, strategies: Sequence[Strategy], tried: list[_Attempt], chosen: int,
                     stream: Streams, settle_layout: bool, end: float) -> tuple[int, str | None]:
    """:func:`covered_attempt`, and again while the layout kept still misses a coverage aim and
    the last attempt's time is left, up to ``COVER_ATTEMPTS`` in all. An attempt kept is
    repaired (:func:`cover_repair`) before the next is weighed, which it then has to beat.

    Each draws its pattern origins anew from a stream of its own (``stream("rows", n)``, its trim
    and covering moves from ``"rows trim"`` and ``"rows cover"``), and around the rows one origin
    reaches the count where another does not. Without it the time left after one attempt was
    spent on nothing: in a trial of another toe-row hanging (not kept), ``mini`` seed 2 was done
    at 49 s of its 120 with 6.2 % bare (2026-11-27). Returns the
    index of the attempt to keep, and the words of the attempt kept (else of the last one
    made), with how many were made where more than one.
    """
    made, note, kept_note, took, without = 0, None, None, None, None
    plain = tried[chosen]
    while made < COVER_ATTEMPTS:
        before, was, t0, moved_before = len(tried), chosen, problem.now(), _cover_seconds(tried)
        chosen, words = covered_attempt(problem, strategies, tried, chosen, stream, settle_layout, end,
                                        needs=took, without=without, number=made + 1)
        # Its trim too, not the covering moves it made to weigh it (the next attempt makes its own).
        took = problem.now() - t0 - (_cover_seconds(tried) - moved_before)
        if len(tried) == before:  # none made: covered, or no time left for one
            if not made:
                note = words
            break
        made += 1
        note = words
        if chosen != was:
            kept_note = words
            if settle_layout:
                # Repaired at once (cover_repair), before another attempt is weighed: one that misses
                # an aim narrowly is often covered by a move or two, where another attempt takes
                # as long as this one (mini seed 3: 5.99 -> 4.90 % bare in one move of 6 s, against
                # 57 s for an attempt that then came to 57.09 %, over the window).
                tried[chosen], _ = repair_once(problem, tried[chosen], stream("rows cover", made), chosen + 1,
                                               end)
        # A second attempt kept says how bare the layout without rows was, not the first one with rows.
        without = plain.coverage.bare_share_percent if plain.coverage is not None else None
    note = kept_note if kept_note is not None else note
    if made > 1 and note is not None:
        note = f"{made} attempts with toe rows first were made: {note}"
    return chosen, note


def _cover_seconds(tried: list[_Attempt]) -> float:
    """Seconds the attempts' covering moves (their ``cover`` phases) have taken."""
    return sum(p["seconds"] for t in tried for p in t.phases if p["strategy"] == "cover")


def covered_attempt(problem: Problem, strategies: Sequence[Strategy], tried: list[_Attempt], chosen: int,
                    stream: Streams, settle_layout: bool, end: float,
                    needs: float | None = None, without: float | None = None, number: int = 1
                    ) -> tuple[int, str | None]:
    """One more attempt, with rows along the toes first, where the chosen one leaves the mound bare.

    Only when the chosen attempt reaches its count and porosity and misses
    a coverage aim (``CoverageReport.aims_met``), the strategies include the
    beam search, and the time the chosen attempt took is left before the
    deadline. The rows (:class:`ToeRows`) come first; then
    the same strategies, the beam ranking its pattern origins around the
    rows and leaving out the sites they are in the way of
    (:meth:`BeamSearch.around_laid`), searching first from the origins whose
    pattern covers best (:meth:`BeamSearch.covering`), and setting the pattern's blocks
    beside a wall down against it (:meth:`BeamSearch.against_wall`); the
    pocket fill takes the pockets beside the rows; the annealing makes up to
    ten times its moves (those past its own while outside the porosity
    window) and moves a row block only where it covers no less of its toe
    (:meth:`Annealing.covering`). Searched from the chosen attempt's origin
    without the fill (until 2026-11-26), the attempt fell short of the count
    on ``mini`` (55-67 of 75). The rows hold much of their volume outside
    the design prism, and the attempt often came to 57.1-57.6 %, over the
    window: one that reaches its count, stands and covers better is then
    trimmed (:func:`trim_repair`), each move kept first only while it meets
    as many coverage aims as before, then while it stays better covered.
    ``needs`` is the time the attempt is expected to take (at least the
    chosen attempt's, with its longer annealing, :func:`longer_annealing`;
    :func:`covered_attempts` gives the last one's), and
    ``without`` the bare share (percent) of the layout without rows, where
    the chosen one has them. ``number`` counts the attempts with rows: the
    attempt draws from ``stream("rows", number)``, its trim from
    ``stream("rows trim", number)`` (:func:`streams`).
    Appends the attempt to ``tried`` and returns the index of the one to
    keep, the new one if it reaches its count and porosity too and covers
    better, with what came of it in words (None where the layout covers).
    One that covers no better is weighed against the chosen one repaired
    (:func:`repair_once`, ``stream("cover", chosen + 1)``, as at the end of the run), and, if
    it still covers no better, once repaired itself (``stream("rows cover", number)``); each
    repaired attempt replaces its own in ``tried``. Neither is repaired where the chosen one
    meets both aims.
    """
    clock = problem.clock
    best = tried[chosen]
    if any(isinstance(s, ToeRows) for s in strategies):
        return chosen, "its toe rows were laid first (--strategy toe), and are not laid again"
    if not best.on_target(problem):
        return chosen, "toe rows are tried only once a layout reaches its count and porosity"
    if not any(isinstance(s, BeamSearch) for s in strategies):
        return chosen, "toe rows are tried only where the beam search lays the pattern around them"
    scene = problem.scene
    if clock() + coverage_reserve(scene) > problem.deadline:
        return chosen, "no time was left for an attempt with toe rows first"
    if best.coverage is None:  # known already where an attempt before measured it
        best.coverage = problem.coverage(best.build.placed())
    if best.coverage is None:
        return chosen, "no time was left to measure the coverage"
    if best.coverage.aims_met() == 2:
        return chosen, None
    needs = max(best.seconds + longer_annealing(best), needs or 0.0)
    if clock() + needs > problem.deadline:
        return chosen, f"no time was left for an attempt with toe rows first (about {needs:.0f} s)"
    again = rows_first(strategies)
    tried.append(_attempt(problem, again, scene, None, stream("rows", number), settle_layout, end,
                          len(tried) + 1, all_or_nothing=True))
    new = tried[-1]
    what = "an attempt with toe rows first"
    if (new.searched or 0) >= problem.required > len(new.build):
        return chosen, (f"{what} placed the count, but {len(new.build)} of {problem.required} blocks "
                        "stood, so it was not kept")
    if len(new.build) < problem.required:
        return chosen, f"{what} placed {len(new.build)} of {problem.required} blocks, so it was not kept"
    if not new.reached(problem):
        return chosen, f"{what} did not stand, so it was not kept"
    trimmed_note = ""
    if over(new.as_written(problem), new.build) > 0:
        trimmed_note = "; no time was left to move blocks into the design prism"
        if clock() + coverage_reserve(scene) <= problem.deadline:
            # The rows hold much of their volume outside the prism: blocks that stick out are moved
            # into pockets while the layout stays better covered than the one it would replace.
            new.coverage = problem.coverage(new.build.placed())
            if new.coverage is not None:
                trimmed_note = f" and covered no better ({new.coverage.bare_share_percent:.1f}% bare)"
        if new.coverage is not None and new.coverage.better_than(best.coverage):
            reports: list[tuple[Build, CoverageReport]] = []

            def better(aims: int) -> Callable[[Build], bool]:
                def keep(build: Build) -> bool:
                    report = problem.coverage(build.placed())
                    if report is None or not report.better_than(best.coverage) or report.aims_met() < aims:
                        return False
                    reports.append((build, report))
                    return True
                return keep

            # The trim moves blocks that stick out of the prism, at the toes and the crest's edges
            # too: on ``mini`` (seed 1) its first move left a toe bare, the layout's farthest bare
            # point went from 1.50 to 1.78 m, over H, and what the rows had won was lost.
            aims = new.coverage.aims_met()
            keeps = [better(aims), better(0)] if aims else [better(0)]
            trimmed, phase = trim_repair(problem, new, stream("rows trim", number), len(tried), end, keeps)
            if phase is not None:
                new.phases.append(phase)
            adopted = trimmed is not new
            if adopted:
                # The report of the very layout kept: a second trim, from the first, may have been
                # measured and not kept. Taken where its settle left it, the layout was never
                # measured: it is now (None where no time was left, which is said below).
                again = next((r for b, r in reversed(reports) if b is trimmed.build), None)
                if again is None:
                    again = problem.coverage(trimmed.build.placed(), until=end)
                tried[-1] = new = replace(trimmed, coverage=again)
            trimmed_note = _trim_words(phase, adopted)
    if not new.on_target(problem):
        return chosen, (f"{what} came to {new.written_percent(problem):.2f}% porosity{trimmed_note}, "
                        "so it was not kept")
    if new.coverage is None:
        # Up to ``end``, not the search's deadline: the attempt's confirming settle, or its trim's,
        # may have run past that, and a layout on target was then dropped unmeasured.
        if clock() + coverage_reserve(scene) <= end:
            new.coverage = problem.coverage(new.build.placed(), until=end)
        if new.coverage is None:
            return chosen, f"{what} reached the count, but no time was left to measure its coverage"
    without_rows = best.coverage.bare_share_percent if without is None else without
    if not new.coverage.better_than(best.coverage) and settle_layout:  # best misses an aim (above)
        # Weighed as they would be written, each repaired. The covering moves gain more on a
        # layout with rows: on ``wall-shake`` seed 3 the attempt with rows, at 9.8 % bare, was
        # dropped against the first attempt's 7.9 %, which its moves then took to 5.6 %; its own
        # took it to 4.3 %. The one it would replace first, as the end of the run would
        # (``repair_once``: not twice): a repair that found no time then leaves that layout as
        # it was before this change, and the new one is weighed against the one written.
        best, _ = repair_once(problem, best, stream("cover", chosen + 1), chosen + 1, end)
        tried[chosen] = best
        if not new.coverage.better_than(best.coverage) and best.coverage.aims_met() < 2:
            new, _ = repair_once(problem, new, stream("rows cover", number), len(tried), end)
            tried[-1] = new
    if not new.coverage.better_than(best.coverage):
        moved = "" if new.unmoved is None else " once blocks were moved to bare areas"
        return chosen, f"{what} covered no better ({new.coverage.bare_share_percent:.1f}% bare{moved})"
    return len(tried) - 1, (f"the layout is that of {what}{trimmed_note}; "
                            f"without them {without_rows:.1f}% was bare")


def rows_first(strategies: Sequence[Strategy]) -> list[Strategy]:
    """``strategies`` after rows along the toes (:class:`ToeRows`), as an attempt with toe rows
    runs them (:func:`covered_attempt`): the beam lays its pattern around the rows, from the
    origins that cover best, and against a wall; the annealing makes its longer run and keeps
    each row block's cover of its toe. ``shoha optimize --strategy toe,...`` runs its first
    attempt so: a mound with time for one attempt only (``big-shake``, 269 blocks in 134.5 s)
    never makes the attempt with rows, and its toes stay bare."""
    return [ToeRows()] + [
        s.around_laid().against_wall().covering() if isinstance(s, BeamSearch)
        else s.covering() if isinstance(s, Annealing) else s
        for s in strategies if not isinstance(s, ToeRows)]


def longer_annealing(attempt: _Attempt) -> float:
    """Seconds the attempt with rows may anneal longer than ``attempt`` did: (``COVER_FACTOR`` − 1)
    times its annealing's, where it made none of the rows' own (:meth:`Annealing.covering`).
    Left out of the time an attempt with rows needs, that was 0.4-1.0 s where the attempt with
    rows annealed 4.8-9.6 s (stop 72): it began with less room than it took."""
    if any(p["strategy"] == "toe" for p in attempt.phases):
        return 0.0
    return (COVER_FACTOR - 1) * sum(p["seconds"] for p in attempt.phases if p["strategy"] == "anneal")


def _trim_words(phase: dict[str, Any] | None, kept: bool) -> str:
    """What the trim of the attempt with rows came to (``kept``: the trimmed layout replaced
    it), for :func:`covered_attempt`'s words."""
    if phase is None:
        return "; no time was left to move blocks into the design prism"
    if kept:
        where = ", and it stood where its settle left it" if phase.get("adopted") else ""
        return (f" ({phase['moved']} of its blocks moved into the design prism took it from "
                f"{phase['porosity_before_percent']:.2f}%{where})")
    # Made again (TRIM_TRIES), the phase's figures are the last trim's: the ones before did not stand.
    twice = phase.get("tries", 1) > 1
    again = "; its first trim did not stand, and in a second" if twice else ";"
    if not phase["moved"]:
        return f"{again} no block that carries nothing came to rest in a pocket holding more of it inside"
    fell = ""
    if phase["stood"] is False:
        fell = ", but then it did not stand" + (" either" if twice else "")
    elif phase["stood"] is None:
        fell = ", with no time left to settle it"
    return (f"{again} {phase['moved']} of its blocks moved into the design prism took it to "
            f"{phase['porosity_percent']:.2f}%{fell}")


def cover_repair(problem: Problem, attempt: _Attempt, rng: np.random.Generator, number: int, end: float,
                 rounds: int | None = 1) -> tuple[_Attempt, dict[str, Any] | None]:
    """The attempt with free blocks moved to bare areas (``search.cover``), if it misses a coverage aim.

    Only a layout that reaches its count and porosity and stands is
    repaired, until the moves must end for the settle that confirms them
    (:func:`moves_until`). The moves come in rounds of at most
    ``search.cover.MOVES``, each confirmed on its own (:func:`_cover_round`),
    ``rounds`` at most (None: while the time lasts): a round that was kept, made
    every move it may and leaves an aim missed is followed by another from the
    layout it kept (:func:`more_rounds`). Returns the attempt to keep (a new one;
    ``attempt`` keeps its own layout) and the ``cover`` phase (None where nothing
    was tried), whose figures are the rounds' together.
    """
    t0 = problem.clock()
    kept, phase = _cover_round(problem, attempt, rng, number, end, attempt)
    if phase is None:
        return attempt, None
    phase["rounds"] = 1
    if kept is not attempt:  # else the attempt as it was (its callers ask whether it is the same)
        kept = replace(kept, more_cover=_another_round(kept, attempt, phase))
    kept = more_rounds(problem, kept, phase, rng, number, end, rounds)
    phase["seconds"] = problem.clock() - t0
    return kept, phase


def more_rounds(problem: Problem, kept: _Attempt, phase: dict[str, Any], rng: np.random.Generator,
                number: int, end: float, rounds: int | None = None) -> _Attempt:
    """``kept`` with more rounds of covering moves, while its last round made every move a round
    may (``_Attempt.more_cover``) and there is time, up to ``rounds`` in all (None: no bound);
    ``phase``, the ``cover`` phase of the rounds so far, is brought up to date. One round was all
    until 2026-12-07: ``cube`` and ``full`` stopped at twelve moves with a minute or more of
    their limits left (18-19 and 22-23 % bare). The rounds after the first are made only at the
    end of the run (:func:`repair_once` with ``rounds``): made while the attempts were weighed,
    they took the time the next attempt's own moves needed (held-out ``brick-rough`` seed 2:
    38.7 % bare, where the attempt with rows, moved, had come to 32.5 %)."""
    t0 = problem.clock()
    try:
        while kept.more_cover and (rounds is None or phase["rounds"] < rounds):
            before = replace(kept, more_cover=False)
            kept, last = _cover_round(problem, before, rng, number, end, before)
            if last is None:  # no time for another round
                return before
            phase["rounds"] += 1
            phase["tried"] += last["tried"]
            if kept is before:  # its moves were not kept: the layout is the one before them
                return before
            phase["moved"] += last["moved"]
            phase["undone"] += last["undone"]
            if last.get("adopted"):
                phase["adopted"] = True
            phase.update(blocks=last["blocks"], porosity_percent=last["porosity_percent"],
                         bare_share_percent=last["bare_share_percent"])
            kept = replace(kept, more_cover=_another_round(kept, before, last))
        return kept
    finally:
        phase["seconds"] = phase.get("seconds", 0.0) + problem.clock() - t0


def _another_round(kept: _Attempt, before: _Attempt, last: dict[str, Any]) -> bool:
    """Whether the covering moves may go on from ``kept`` after a round (``last``, its phase)
    made on ``before``: it was kept, it made every move a round may (one with moves to spare
    found no more), and the layout still misses a coverage aim."""
    return kept is not before and last["moved"] + last["undone"] >= search_cover.MOVES \
        and (kept.coverage is None or kept.coverage.aims_met() < 2)


def _cover_round(problem: Problem, attempt: _Attempt, rng: np.random.Generator, number: int, end: float,
                 unmoved: _Attempt) -> tuple[_Attempt, dict[str, Any] | None]:
    """One round of covering moves on ``attempt`` (at most ``search.cover.MOVES``), as
    :func:`cover_repair` describes. The moved layout is settled again
    (:func:`physics.verdict`, within the settle's reserve before ``end``), and written as
    moved, each block where it came to rest when let go among its neighbours; if it does
    not stand, the layout with the last move undone is settled the same way, once; if that
    does not stand either, or there is no time to settle it, the attempt is returned as it
    was. ``unmoved`` is the attempt before this round: its own ``unmoved``, where a round
    before moved it, is the one kept."""
    clock, scene = problem.clock, problem.scene
    if attempt.stable is not True:
        return attempt, None
    reserve = settle_reserve(scene, meter=problem.meter)
    short = moves_until(problem, end, reserve)
    # The time before the window: on_target measures the layout's union.
    if clock() + coverage_reserve(scene) > short.deadline or not attempt.on_target(problem):
        return attempt, None
    t0 = clock()
    if attempt.coverage is None:
        attempt.coverage = problem.coverage(attempt.build.placed())
    if attempt.coverage is None or attempt.coverage.aims_met() == 2:
        return attempt, None
    history: list[tuple[Build, CoverageReport]] = []
    written = attempt.as_written(short)
    moved, after, stats = cover_moves(written, attempt.build, attempt.coverage, history)
    phase = {"strategy": "cover", "attempt": number, "seconds": 0.0, "blocks": len(moved),
             "porosity_percent": moved.porosity.percent, **stats.to_dict(), "stood": None, "undone": 0}
    kept = attempt
    if stats.moved:
        kept = _settled_again(problem, attempt, moved, rng, end, phase, than=attempt.coverage,
                              coverage=after, unmoved=unmoved.unmoved or unmoved)
    if kept is attempt and phase["stood"] is False and stats.moved > 1:
        # Each block moved came to rest when let go among its neighbours, but a move can still
        # fell the whole: the last one is undone, and the layout before it settled the same way
        # (``mini`` seed 3: four moves took it from 6.9 % bare to 5.4 % and fell, the fourth
        # block moved sliding; three stood, at 5.6 %). Once: an attempt with rows is repaired
        # before the next is weighed, which needs the time.
        fewer, less = history[-2]
        kept = _settled_again(problem, attempt, fewer, rng, end, phase, than=attempt.coverage,
                              coverage=less, unmoved=unmoved.unmoved or unmoved)
        if kept is not attempt:
            phase.update(moved=stats.moved - 1, undone=1, blocks=len(fewer),
                         porosity_percent=fewer.porosity.percent, bare_share_percent=less.bare_share_percent)
    if kept is attempt:
        phase.update(blocks=len(attempt.build), porosity_percent=attempt.build.porosity.percent,
                     bare_share_percent=attempt.coverage.bare_share_percent)
    elif phase.get("adopted"):  # written where the settle left it: its own figures
        phase.update(porosity_percent=kept.build.porosity.percent,
                     bare_share_percent=kept.coverage.bare_share_percent)
    phase["seconds"] = clock() - t0
    return kept, phase


def repair_once(problem: Problem, attempt: _Attempt, rng: np.random.Generator, number: int, end: float,
                rounds: int | None = 1) -> tuple[_Attempt, dict[str, Any] | None]:
    """:func:`cover_repair` of an attempt kept, its phase appended to the attempt's, unless
    :func:`covered_attempts` repaired it already (its last phase is then that ``cover`` phase,
    which is returned with it): the moves are not tried twice, but where ``rounds`` allows
    more and its last round made every move it may, more rounds follow (:func:`more_rounds`)."""
    made = next((p for p in attempt.phases[-1:] if p["strategy"] == "cover"), None)
    if made is not None:
        if rounds is None or rounds > made.get("rounds", 1):  # else nothing more to make
            attempt = more_rounds(problem, attempt, made, rng, number, end, rounds)
        return attempt, made
    repaired, phase = cover_repair(problem, attempt, rng, number, end, rounds)
    if phase is not None:
        repaired.phases.append(phase)
    return repaired, phase


#: Trims at most for one attempt (:func:`trim_repair`): one, and one more from the untrimmed
#: layout where the trimmed one did not stand.
TRIM_TRIES = 2


def trim_repair(problem: Problem, attempt: _Attempt, rng: np.random.Generator, number: int, end: float,
                keeps: Sequence[Callable[[Build], bool]] = ()) -> tuple[_Attempt, dict[str, Any] | None]:
    """The attempt with blocks moved from outside the design prism into pockets (``search.trim``),
    where it reaches its count and stands but its porosity is over its window.

    Until the moves must end for the settle that confirms them (:func:`moves_until`); ``keeps`` may
    refuse a move, strictest rule first (:func:`search.trim.trim_moves`; the
    coverage attempt's: meet as many coverage aims as before the trim, and
    then only cover better than the layout it would replace). The trimmed layout, nearer
    the window if not within it, is kept only if it stands when settled again
    (:func:`_settled_again`, which takes it where that settle left it if it stands so). Where
    it does not stand, or stands but is still over its window, and that trim's time is left
    before the trim's own deadline and, with a settle's reserve, before ``end``, the layout
    is trimmed once more with new drops, from the last one kept (the untrimmed one if none
    was), up to ``TRIM_TRIES`` trims. (On ``mini`` seed 1 the attempt with toe rows, at
    57.06 %, was trimmed to 57.00 % and did not stand, and was not kept; trimmed once more on
    the same random stream it stood at 56.97 %; it now stands where its first settle left it.)
    A trim that stood over its window was not trimmed again until each step had a random
    stream of its own (:func:`streams`): tried on one stream (2026-12-06, stop 64), the second
    trim's draws changed the attempts after it, and ``--keep``'s reference start on seed 3
    then ended over its window in every attempt (docs/coverage-study.md).
    Returns the attempt to keep and the ``trim`` phase (None where nothing was tried), which
    says how many trims were made (``tries``); its figures are those of the layout kept, from
    the untrimmed one (``moved`` all the moves kept), else of the last trim.
    """
    clock, scene = problem.clock, problem.scene
    if not attempt.reached(problem) or attempt.stable is not True:
        return attempt, None
    reserve = settle_reserve(scene, meter=problem.meter)
    short = moves_until(problem, end, reserve)
    # The time before the window: as_written measures the layout's union.
    if clock() + reserve / 2 > short.deadline or over(attempt.as_written(problem), attempt.build) <= 0:
        return attempt, None
    short = attempt.as_written(short)
    t0 = clock()
    phase: dict[str, Any] = {"strategy": "trim", "attempt": number, "seconds": 0.0, "tries": 0}
    kept, moved = attempt, 0
    for _ in range(TRIM_TRIES):
        t1 = clock()
        trimmed, stats = trim_moves(short, kept.build, raised_check, rng, keeps)
        took = clock() - t1
        phase["tries"] += 1
        trial: dict[str, Any] = {"stood": None}  # ``adopted`` too, where so kept
        # Nearer the window if not within it: kept if it stands (or stands where its settle left it).
        now = _settled_again(problem, kept, trimmed, rng, end, trial, coverage=None) if stats.moved else kept
        if now is not kept:
            # The phase tells of the layout kept, from the untrimmed one: all the moves kept, and
            # ``adopted`` once any of them was taken where its settle left it.
            moved += stats.moved
            kept = now
            phase.update({**stats.to_dict(), **trial, "blocks": len(kept.build), "moved": moved,
                          "porosity_before_percent": attempt.build.porosity.percent,
                          "porosity_percent": kept.build.porosity.percent})  # where the settle left it
        elif kept is attempt:  # none kept yet: the phase tells of this trim
            phase.update(blocks=len(trimmed), **stats.to_dict(), **trial)
        if (not stats.moved or over(kept.as_written(problem), kept.build) <= 0 or trial["stood"] is None
                or clock() + took > short.deadline
                or clock() + took + settle_reserve(scene, meter=problem.meter) > end):
            break  # nothing moved, within the window, not settled, or no time for another trim
    phase["seconds"] = clock() - t0
    return kept, phase


def moves_until(problem: Problem, end: float, reserve: float) -> Problem:
    """``problem`` with its deadline where a repair's moves must end (``trim_repair``,
    ``cover_repair``): in time for the settle that confirms them before ``end``, by ``reserve``
    (what the settles timed so far call for), less half a reserve, since a move's last steps
    can run a little past it. The search's deadline was set from an earlier reserve, which
    the settles timed since may have outgrown: on ``mini`` seed 2 the covering moves ran to
    112.8 s, the settle then needed 6.5 s before 118.6 s, and four moves, made, were dropped
    unsettled (7.5 % bare kept, where they had brought it to 5.6 %)."""
    return replace(problem, deadline=min(problem.deadline, end - reserve) - reserve / 2)


def as_written(problem: Problem, build: Build) -> Problem:
    """``problem`` with its target lowered by :func:`counted_below` of ``build``: its porosity
    window as the layout written measures it. The attempts' gates read it (``on_target``, and
    ``over`` before and within a trim, through ``_Attempt.as_written``, which measures each
    layout's union once: about 0.2 s for 1000 blocks), and so do the repairs' moves
    (``trim_moves``, ``cover_moves``), which may take a layout to the window's edge. Until stop
    74 the gates read the porosity as counted, and a layout over its window only as written
    was not trimmed. The annealing's stop (``Annealing.covering``) still reads it as counted:
    it is asked after every move."""
    return replace(problem, target=problem.target - counted_below(problem.scene, build))


def counted_below(scene: Scene, build: Build) -> float:
    """Points by which the build's porosity as the search counts it (each block's volume inside
    the design prism on its own, ``Build.porosity``) lies below the porosity of the layout
    written (of the blocks' union, :func:`geometry.porosity.exact_filled_volume`); 0 where no
    blocks overlap. A settle leaves touching blocks overlapping by a hair: on cubes stacked face
    to face that came to 0.0003 points, and the covering moves took the held-out ``cube-small``
    seed 1 to 47.9998 % as counted, within its window, and 48.0001 % as written, over it
    (2026-12-07, stop 73). Shake Blocks overlap by about 1e-7 points."""
    union = exact_filled_volume(scene.design.polytope, build.placed())
    return max(0.0, 100.0 * (build.porosity.filled - union) / scene.design_volume)


def _settled_again(problem: Problem, attempt: _Attempt, build: Build, rng: np.random.Generator, end: float,
                   phase: dict[str, Any], than: CoverageReport | None = None, **changes: Any) -> _Attempt:
    """``attempt`` with ``build`` (and ``changes``) if that stands when settled again
    (:func:`physics.verdict`) within a settle's reserve before ``end``; else ``attempt``.

    Where it does not stand and another settle's reserve is left, it is taken where that
    settle left it (:func:`physics.settled_layout`, as :func:`physics.confirm` takes every
    layout that fails): kept if every block is still in it, valid, it stands then, and its
    porosity is no further off its window (either side) than ``build``'s. Not where the
    build has kept blocks (``--keep``): holding them takes one more settle. Blocks that crept or slid have
    come to rest, and a layout often stands so: on ``mini-rough`` (seed 1, the attempt with
    toe rows) a trim that failed at 57.25 % stood so at 57.15 % with all 75 blocks. Its
    coverage, if ``changes`` has one, is measured again (the blocks have moved), and must be
    better than ``than`` where given (the covering moves' gain not lost where the blocks came
    to rest); ``phase["adopted"]`` says it was so taken. Records in ``phase["stood"]`` whether
    it stood (None if there was no time)."""
    clock = problem.clock
    if clock() + settle_reserve(problem.scene, meter=problem.meter) > end:
        return attempt
    t1 = clock()
    try:
        result = verdict(settling_by(problem, end), build.placed(), rng, movable=judged(build))
    except Stopped:
        return attempt  # it ran past the end: not known to stand (``stood`` stays None)
    phase["stood"] = bool(result.stable)
    # Not with kept blocks: settled_layout then settles once more to hold them, past the reserve.
    if not result.stable and not result.diverged and not build.kept and \
            clock() + settle_reserve(problem.scene, meter=problem.meter) <= end:
        try:
            after, again = settled_layout(settling_by(problem, end), build, result, rng)
        except Stopped:
            return attempt  # not known to stand where the settle left it
        def nearer() -> bool:  # the unions measured only where the rest holds
            return off_window(as_written(problem, after), after) <= off_window(as_written(problem, build),
                                                                               build) + 1e-9
        if len(after) == len(build) and again.stable and nearer():
            measure = changes.get("coverage") is not None
            # Measured up to ``end``, not the search's deadline: the moves and two settles may
            # have passed that, and the moves were then dropped for want of a measure.
            cover = problem.coverage(after.placed(), until=end) if measure else None
            if not measure or (cover is not None  # else no time was left to measure it
                               and (than is None or cover.better_than(than))):
                build, result = after, again
                phase.update(stood=True, adopted=True)
                if measure:
                    changes["coverage"] = cover
    if not result.stable:
        return attempt
    settle = {**attempt.settle, "stable": True, "max_displacement_m": result.max_displacement_m,
              "max_rotation_deg": result.max_rotation_deg, "unstable": [],
              "seconds": attempt.settle.get("seconds", 0.0) + clock() - t1}
    return replace(attempt, build=build, settle=settle, **changes)


def check_keep(scene: Scene, keep: Sequence[Placement], where: str = "the kept layout") -> None:
    """Raise InputError (naming ``where``) for a partial layout ``optimize`` cannot complete in
    its time: ids repeated, another block type, more blocks than the tolerance zone holds by
    volume, or blocks one inside another by the dozen (:func:`geometry.checks.check_not_crowded`).
    The kept blocks are settled and checked within the limit: 5000 of them, far apart, took
    28 s of a 10 s limit, and 2000 copies of one pose more than 200 s."""
    ids = [p.id for p in keep]
    if len(set(ids)) != len(ids):
        raise InputError(f"{where}: repeats block ids")
    other = next((p for p in keep if p.type != scene.block_type), None)
    if other is not None:
        raise InputError(f"{where}: kept block {other.id} is a {other.type!r}; the scene places "
                         f"{scene.block_type!r} (one block type a scene)")
    room = int(scene.tolerance.volume / scene.block.volume)  # blocks the zone holds at most
    if len(keep) > room:
        raise InputError(f"{where}: {len(keep)} kept blocks, and at most {room} fit in the scene's "
                         f"tolerance zone ({scene.tolerance.volume:.1f} m³) without overlapping")
    check_not_crowded(scene.block, np.array([p.pose.position for p in keep]).reshape(-1, 3), ids, where)


#: Kept blocks taken in between two looks at the clock (:func:`kept_build`).
KEPT_CHUNK = 200
#: Of the 2 s a run may overrun its limit, the part the kept blocks' intake and checks may use.
KEPT_GRACE = 1.0


class KeptTooSlow(Exception):
    """Taking in the kept blocks would end past its time (:func:`kept_build`)."""

    def __init__(self, seconds: float):
        super().__init__(f"{seconds:.1f} s")
        self.seconds = seconds


def kept_build(scene: Scene, keep: Sequence[Placement], clock: Callable[[], float] | None = None,
               by: float | None = None) -> Build:
    """A build holding a partial layout's blocks where they are, in its order (checked by
    :func:`check_keep`).

    With ``by`` (on ``clock``): every ``KEPT_CHUNK`` blocks, where the rest at the pace so far
    would end past ``by``, :class:`KeptTooSlow` is raised with the seconds the whole would take.
    Each block costs most of a millisecond (0.68 ms on the 2-core machine), and 15 920 kept
    blocks under a 5 s limit took 10.9 s before the search began (stop 77's probe).
    """
    build = Build(scene)
    t0 = clock() if clock is not None else 0.0
    for i, p in enumerate(keep):
        if by is not None and clock is not None and i and i % KEPT_CHUNK == 0:
            now = clock()
            rest = (now - t0) / i * (len(keep) - i)
            if now + rest > by:
                raise KeptTooSlow(now - t0 + rest)
        build.keep(p.id, p.type, p.pose)
    return build


def kept_in_time(scene: Scene, keep: Sequence[Placement], start: float, time_limit: float,
                 clock: Callable[[], float]) -> Build:
    """:func:`kept_build` of ``keep``, or an InputError (nothing written) where taking the blocks
    in and checking the layout would end more than ``KEPT_GRACE`` past the limit: the limit is a
    promise, and a run cannot leave out its kept blocks or their checks."""
    # The checks of the kept blocks at least: the search adds blocks only while its time lasts.
    checks = check_reserve(scene, len(keep)) / RESERVE_MARGIN
    by = start + time_limit + KEPT_GRACE - checks
    begun = clock()
    try:
        return kept_build(scene, keep, clock, by)
    except KeptTooSlow as slow:
        need = math.ceil(begun - start + slow.seconds + checks)
        raise InputError(f"the kept layout: its {len(keep)} blocks take about {slow.seconds:.0f} s to take "
                         f"in and {checks:.0f} s to check, more than --time-limit {time_limit:g} allows; "
                         f"give it at least {need} s") from None


#: Ids a summary names before it counts the rest (``--json`` has them all).
LISTED_IDS = 20


def _ids(ids: Sequence[int]) -> str:
    """``ids`` for a summary: the first ``LISTED_IDS``, and how many more (5970 kept blocks out of
    tolerance once filled a screen)."""
    shown = ", ".join(map(str, ids[:LISTED_IDS]))
    more = len(ids) - LISTED_IDS
    return shown if more <= 0 else f"{shown} and {more} more (--json lists them)"


def kept_report(keep: Sequence[Placement], report: CheckReport, unstable: list[int]) -> dict[str, Any]:
    """Which kept blocks collide, stick out or fail the settle (by their ids)."""
    ids = {p.id for p in keep}
    colliding = {i for c in report.collisions for i in (c.a, c.b) if i in ids}
    return {"blocks": len(keep),
            "colliding": sorted(colliding),
            "out_of_tolerance": sorted(i for i, _ in report.out_of_tolerance if i in ids),
            "unstable": sorted(i for i in unstable if i in ids)}
