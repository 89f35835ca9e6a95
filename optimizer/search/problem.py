"""Search strategies: the shared interface, in optuna's sampler model.

A strategy is an ``abc.ABC`` subclass with one abstract method, passed in as
an instance (``optimize(scene, strategies=[BeamSearch(), Annealing()])``).
Its hooks default to doing nothing. The only table that maps strategy names to
classes is at the CLI edge (``optimizer/cli_optimize.py``). Every strategy
passes the same contract suite (``tests/test_strategies.py``).
"""

from __future__ import annotations

import abc
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from geometry.scene import Scene

from .build import Build
from .patterns import InterlockLattice


@dataclass
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
        Hangings the search may use ("crown", "level", "horizontal", "free").
    deadline : float
        ``time.monotonic()`` value by which a strategy must return.
    report : callable, optional
        ``report(phase, build, message)``: progress for the CLI's display.
    origin : (float, float) or None
        The pattern origin the beam search settled on, for later strategies.
    """

    scene: Scene
    required: int
    target: float
    lattice: InterlockLattice
    families: tuple[str, ...] = ("crown", "level", "horizontal")
    deadline: float = field(default_factory=lambda: time.monotonic() + 60.0)
    report: Callable[[str, Build, str], None] | None = None
    origin: tuple[float, float] | None = None

    def time_left(self) -> float:
        return self.deadline - time.monotonic()

    def tell(self, phase: str, build: Build, message: str = "") -> None:
        if self.report is not None:
            self.report(phase, build, message)


class Strategy(abc.ABC):
    """A way to produce or improve a build.

    Subclasses implement :meth:`run`. They take randomness only from the
    generator they are given, and return by ``problem.deadline``.
    """

    #: Name shown in progress and results.
    name: str = "strategy"

    @abc.abstractmethod
    def run(self, problem: Problem, build: Build | None, rng: np.random.Generator) -> Build:
        """Return a build for ``problem``, starting from ``build`` (None: from nothing).

        The returned build is valid: no interpenetration (FCL), every block
        inside the tolerance zone and resting on what it was lowered onto, in
        an order a crane can follow. It may hold fewer blocks than required.
        """

    def stats(self) -> dict[str, float]:
        """Figures about the last run (e.g. a bound), for the result. Default: none."""
        return {}
