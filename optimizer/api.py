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
   the layout is settled again.

Validity is never loosened: if the required count cannot be reached, the best
valid layout found is returned with the count it reached.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from geometry.checks import check_layout
from geometry.errors import InputError
from geometry.layout import Layout
from geometry.scene import Scene

from .search.anneal import Annealing
from .search.beam import BeamSearch
from .search.build import Build
from .search.cpsat import BoundStats, CpSat
from .search.hangings import families
from .search.patterns import InterlockLattice, lattice_for
from .search.physics import confirm, raised_check, stands
from .search.problem import Clock, Phase, Problem, Strategy

#: The default time limit (s): at least this, ``SECONDS_PER_BLOCK`` a required block above it,
#: and at most ``MAX_DEFAULT_LIMIT`` (issue 24: up to 0.5 s a block, 20 minutes at most).
MIN_DEFAULT_LIMIT = 120.0
SECONDS_PER_BLOCK = 0.5
MAX_DEFAULT_LIMIT = 1200.0


def default_time_limit(scene: Scene) -> float:
    """``shoha optimize``'s limit when none is given: 0.5 s a required block, within [120 s, 20 min]."""
    return min(MAX_DEFAULT_LIMIT, max(MIN_DEFAULT_LIMIT, SECONDS_PER_BLOCK * scene.required_blocks))


#: Share of the time limit, and most seconds, that tuning a new block's pattern may take.
TUNE_SHARE = 0.25
TUNE_MAX_SECONDS = 60.0

#: How far (percentage points) a reference layout's porosity may be from the
#: scene's target before ``shoha optimize`` says it missed (issue 4: within 1).
TARGET_POINTS = 1.0


@dataclass
class OptimizeResult:
    """What ``optimize`` found, and how it checks.

    Attributes
    ----------
    layout : Layout
        Blocks in crane order, ids ``0..n-1``.
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
        Not ``shoha check``'s ``outside_volume_m3``, which is a block's volume
        outside the tolerance zone.
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

    @property
    def valid(self) -> bool:
        return (self.blocks == self.required_blocks and self.collisions == 0
                and self.out_of_tolerance == 0 and self.stable is not False)

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
        off = self.porosity_percent - self.target_porosity_percent
        if self.blocks >= self.required_blocks and abs(off) > TARGET_POINTS:
            text += (f"\nporosity is {abs(off):.2f} points {'above' if off > 0 else 'below'} the target")
            if off > 0 and self.outside_design_prism_m3 > 0:
                text += (f": {self.outside_design_prism_m3:.1f} m³ of the blocks lies outside the design "
                         "prism, in the tolerance zone")
        return text

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
            "path": self.path,
            "valid": self.valid,
            "outside_design_prism_m3": self.outside_design_prism_m3,
            "settle": self.settle,
            "phases": self.phases,
            "gap": self.gap,
        }


def default_strategies(bound: bool = False) -> list[Strategy]:
    """Beam search, then annealing; with ``bound``, then the CP-SAT bound on the ground layer."""
    out: list[Strategy] = [BeamSearch(accept=raised_check, judge=stands), Annealing(accept=raised_check)]
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
) -> OptimizeResult:
    """Find a reference layout for ``scene``.

    Parameters
    ----------
    scene : Scene
    seed : int
        All randomness comes from ``numpy.random.default_rng(seed)``; the same
        seed gives the same layout, byte for byte, as long as ``time_limit``
        does not cut the strategies' fixed work short.
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
        Confirm (and repair) with a physics settle.
    report : callable, optional
        ``report(phase, build, message)`` for a progress display.
    bound : bool
        Add the CP-SAT bound step to the default strategies (ignored when
        ``strategies`` is given).
    clock : callable
        The clock the time limit is read on; tests inject one.
    """
    if scene.kind != "3d":
        raise InputError(f"{scene.name}: a {scene.kind} scene is a 2D slice for physics checks; "
                         "shoha optimize places blocks in 3D scenes")
    start = clock()
    time_limit = default_time_limit(scene) if time_limit is None else float(time_limit)
    rng = np.random.default_rng(seed)
    if lattice is None:
        # A block with no tuned pattern is tuned now, within a share of the limit, and cached.
        lattice = lattice_for(scene.block, scene.block_type, min(TUNE_SHARE * time_limit, TUNE_MAX_SECONDS),
                              clock)
    # Keep a share of the budget for the physics confirmation and the final checks.
    reserve = min(0.15 * time_limit, 10.0) if settle_layout else 0.0
    problem = Problem(
        scene=scene,
        required=scene.required_blocks,
        target=scene.target_porosity,
        lattice=lattice,
        families=families(scene.block),
        deadline=start + time_limit - reserve,
        report=report,
        clock=clock,
    )
    phase: Phase | None = None
    phases = []
    gap: dict[str, Any] = {}
    for strategy in strategies if strategies is not None else default_strategies(bound):
        t0 = clock()
        phase = strategy.run(problem, phase, rng)
        phases.append({"strategy": strategy.name, "seconds": clock() - t0, "blocks": len(phase.build),
                       "porosity_percent": phase.build.porosity.percent, **phase.stats.to_dict()})
        if isinstance(phase.stats, BoundStats) and not phase.stats.skipped:
            s = phase.stats
            gap = {"layer": "ground", "slab_m": s.slab_m, "heuristic_m3": s.heuristic_m3,
                   "objective_m3": s.objective_m3, "bound_m3": s.bound_m3, "gap_percent": s.gap_percent,
                   "optimal": s.optimal, "candidates": s.candidates, "seconds": s.seconds}
    build = phase.build if phase is not None else Build(scene)
    settle_info: dict[str, Any] = {}
    stable: bool | None = None
    if settle_layout:
        # Leave time for the final checks (about 3 ms a block, measured on mini and full).
        end = start + time_limit - (0.5 + 0.003 * scene.required_blocks)
        build, confirmation = confirm(problem, build, rng, phase.origin if phase else None, end)
        settle_info = confirmation.to_dict()
        stable = confirmation.stable
    layout = build.layout({"generator": {"tool": "shoha optimize", "seed": seed}})
    report_ = check_layout(scene, layout.placed())
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
        outside_design_prism_m3=max(0.0, report_.blocks * scene.block.volume
                              - (1 - report_.porosity_percent / 100) * scene.design_volume),
    )
