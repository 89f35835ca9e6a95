"""What a search is asked, and what each of its phases hands on.

A strategy is an ``abc.ABC`` subclass with one abstract method, passed in as
an instance (``optimize(scene, strategies=[BeamSearch(), Annealing()])``),
in optuna's sampler model (STYLE.md). The only table that maps strategy names
to classes is at the CLI edge (``optimizer/cli/optimize.py``). Every strategy
passes the same contract suite (``tests/test_strategies.py``).

Phases talk through types, not dicts: a strategy returns a :class:`Phase`,
its build with typed :class:`Stats`, and the next strategy receives it. The
:class:`Problem` is frozen: no phase changes what is asked (a repair that
needs its own deadline asks a copy, ``dataclasses.replace``).
"""

from __future__ import annotations

import abc
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from geometry.coverage import CoverageReport, Placed, TimeUp, coverage
from geometry.scene import Scene

from .build import Build
from .patterns import InterlockLattice

#: How far (percentage points) a full layout's porosity may be from the scene's target and
#: still meet it (issue 4: within 1); ``shoha optimize`` says when it missed by more.
TARGET_POINTS = 1.0


def over(problem: Problem, build: Build) -> float:
    """How many points the build's porosity lies above its window (0 within it or below)."""
    return max(0.0, build.porosity.percent - problem.target - TARGET_POINTS)


def off_window(problem: Problem, build: Build) -> float:
    """How many points the build's porosity lies outside its window, either side (0 within it)."""
    return max(0.0, abs(build.porosity.percent - problem.target) - TARGET_POINTS)

#: A clock: seconds, monotonic. ``time.monotonic`` unless a test injects one.
Clock = Callable[[], float]


#: How a settle's cost grows with the blocks in it (benchmarks/results/settle_speed.csv: 75 to
#: 1000 Shake Blocks on 2 cores, log-log slope 1.15).
SETTLE_EXPONENT = 1.15


@dataclass
class SettleMeter:
    """The whole-layout settles timed during a run, for what its confirming settles will cost.

    Only settles of at least half the required count are recorded (a few blocks' settle is
    mostly fixed cost, and says little about the whole layout's). The slowest rate seen is
    kept: the confirming settles come at the end, and a machine busy once may be busy again.

    The confirming settles are verdicts (``search.physics.verdict``: two settles, side by side
    where a core is idle), and a verdict is timed as two settles of half its time. Once one
    is, the verdicts' rate is the one used: a lone settle (a beam restart's ``stands``) takes
    as long as a whole verdict side by side, and counted as half of one it held back the
    covering moves on ``big-shake`` seed 1 with 40 s of the run left.

    Attributes
    ----------
    rate : float or None
        Seconds a settle took, over ``blocks ** SETTLE_EXPONENT``; None until one is recorded.
    verdict_rate : float or None
        The same, of the verdicts' settles only.
    earliest : float
        The earliest clock value a search's deadline may be brought forward to (reserves
        take at most a share of the limit, ``optimizer.api.RESERVE_SHARE``).
    """

    rate: float | None = None
    verdict_rate: float | None = None
    earliest: float = -np.inf

    def record(self, blocks: int, seconds: float, required: int, verdict: bool = False) -> None:
        """A whole-layout settle of ``blocks`` took ``seconds`` (a verdict's: half the verdict's time)."""
        if blocks >= max(1, required // 2):
            rate = seconds / blocks ** SETTLE_EXPONENT
            self.rate = rate if self.rate is None else max(self.rate, rate)
            if verdict:
                self.verdict_rate = rate if self.verdict_rate is None else max(self.verdict_rate, rate)

    def seconds(self, blocks: int) -> float | None:
        """What one settle of ``blocks`` would take at the slowest rate seen (of the verdicts,
        once one is timed), or None."""
        rate = self.verdict_rate if self.verdict_rate is not None else self.rate
        return None if rate is None else rate * blocks ** SETTLE_EXPONENT


@dataclass(frozen=True)
class Problem:
    """What to build.

    Attributes
    ----------
    scene : Scene
    required : int
        Blocks to place (the scene's required count).
    target : float, percent
        Target porosity.
    lattice : InterlockLattice
        The placement pattern the candidates start from.
    families : tuple of str
        Hangings the search may use (``hangings.families`` of the block, and
        "free"); the built-in tetrapod-like blocks' three by default.
    deadline : float
        Clock value by which a strategy must return.
    report : callable, optional
        ``report(phase, build, message)``: progress for the CLI's display.
    clock : callable
        The clock every deadline is read on (``time.monotonic``); tests
        inject one to check the deadline logic without timing anything.
    meter : SettleMeter
        Whole-layout settles timed so far (shared by the copies ``dataclasses.replace`` makes).
    settle_until : float, optional
        Clock value past which a whole-layout settle is stopped (:class:`settle.Stopped`):
        set by the confirming settles, which must end within the time limit.
    span : float, seconds, optional
        How long the whole search may take: from the run's start to its first ``deadline``,
        fixed when the run begins (``optimizer.api.optimize``: the time limit less what the
        checks and settles keep). The beam plans how many pattern origins it ranks from a
        share of it, not of the time left (:meth:`budget`), so that an attempt made after a
        slow step does the same work; only a deadline that binds cuts it short. None: the
        time left. A problem given a short deadline of its own for a step inside the run (the
        confirming settle's repair, ``physics._repaired``) clears it.
    anchor : float, optional
        An origin across the crest (x) that stands a column of the pattern's first hanging
        where that hanging rests outermost at each toe (:func:`sites.fit_to_toes`); the
        origins ranked for the pattern include some from it. None: no such origin.
    """

    scene: Scene
    required: int
    target: float
    lattice: InterlockLattice
    families: tuple[str, ...] = ("crown", "level", "horizontal")
    deadline: float = field(default_factory=lambda: time.monotonic() + 60.0)
    report: Callable[[str, Build, str], None] | None = None
    clock: Clock = time.monotonic
    meter: SettleMeter = field(default_factory=SettleMeter, compare=False)
    settle_until: float | None = None
    span: float | None = None
    anchor: float | None = None

    def now(self) -> float:
        return self.clock()

    def time_left(self) -> float:
        return self.deadline - self.clock()

    def budget(self, share: float) -> float:
        """Seconds of work a step may plan for: ``share`` of ``span``, or of the time left
        where no span is set. Not a deadline: the step still stops at ``deadline``."""
        return share * max(0.0, self.time_left() if self.span is None else self.span)

    def coverage(self, placed: Placed, until: float | None = None,
                 spacing: float | None = None) -> CoverageReport | None:
        """The coverage of ``placed`` (:func:`geometry.coverage.coverage`, sampled every
        ``spacing`` where given), or None if it is not measured by the deadline (``until`` where
        given: a measure after the settles that the search's deadline leaves room for)."""
        try:
            return coverage(self.scene, placed, spacing=spacing,
                            deadline=self.deadline if until is None else until, clock=self.clock)
        except TimeUp:
            return None

    def tell(self, phase: str, build: Build, message: str = "") -> None:
        if self.report is not None:
            self.report(phase, build, message)


@dataclass(frozen=True)
class Stats:
    """Figures about one phase's run. Strategies subclass it with their own fields."""

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for name in self.__dataclass_fields__:
            value = getattr(self, name)
            out[name] = list(value) if isinstance(value, tuple) else value
        return out


@dataclass(frozen=True)
class Phase:
    """What a strategy hands on: its build, its figures, and the pattern origin in use.

    Attributes
    ----------
    build : Build
    stats : Stats
    origin : (float, float) or None
        The pattern origin the layout was laid from, for the strategies after
        it (annealing relocates blocks to the pattern's sites); None before a
        pattern was chosen.
    """

    build: Build
    stats: Stats = field(default_factory=Stats)
    origin: tuple[float, float] | None = None


class Strategy(abc.ABC):
    """A way to produce or improve a build.

    Subclasses implement :meth:`run`. They take randomness only from the
    generator they are given, and return by ``problem.deadline``.
    """

    #: Name shown in progress and results.
    name: str = "strategy"

    @abc.abstractmethod
    def run(self, problem: Problem, previous: Phase | None, rng: np.random.Generator) -> Phase:
        """Return a phase for ``problem``, starting from ``previous`` (None: from nothing).

        The returned build is valid: no interpenetration (FCL), every block
        inside the tolerance zone and resting on what it was lowered onto, in
        an order a crane can follow. It may hold fewer blocks than required.
        The input build is never changed.
        """
