"""The placement pattern laid over a scene: its sites, a quick pass, and its best origins.

The beam search, annealing and the CP-SAT bound all draw blocks from the
pattern's sites (:func:`pattern_sites`); which origin the pattern is laid from
decides how many rows fit between the slopes and the ends, so origins are
ranked first by a quick pass of the pattern alone (:func:`rank_origins`).
"""

from __future__ import annotations

import numpy as np

from .build import Build
from .problem import Problem
from .shapes import ShapeCache


def rank_origins(problem: Problem, shapes: ShapeCache, rng: np.random.Generator, start: Build,
                 probes: int, stop: float, scans: int = 0, n: int = 16) -> list[tuple[float, float]]:
    """Pattern origins, best first: by the volume their sites alone place in the design prism.

    First ``probes`` origins, (0, 0) and seeded random ones over one lattice
    cell. Then ``scans`` line scans, taken in turn along the crest (y) and
    across it (x), each through the best origin so far: ``n`` origins along
    the crest, or ``n / 2`` across it, spaced evenly over one lattice period
    with a seeded offset. The count a pattern places is a step function of
    its origin, nearly a sum of one step in x (how many rows fit between the
    slopes) and one in y (how many fit between the ends): on ``tetrapod`` it
    ranges from 60 to 81 blocks, and the steps that reach 81 are about 0.3 m
    wide in x and 0.16 m in y, against scan spacings of 0.23 m and 0.13 m at
    ``n = 16``: a scan cannot step over them, where random probes often
    miss them. Trials stop at ``stop`` (``problem.now()``). A trial the
    deadline cuts short is dropped, unless it is the only one: then the
    origin it drew is all there is to rank (a budget too short for one pass
    over a long scene).
    """
    lat = problem.lattice
    period = np.array([lat.w, lat.p])
    trials = [(0.0, 0.0)] + [(float(rng.uniform(0, lat.w)), float(rng.uniform(0, lat.p)))
                             for _ in range(probes - 1)]
    scored: list[tuple[float, int, tuple[float, float]]] = []

    def trial(origin: tuple[float, float]) -> None:
        volume = pattern_pass(problem, shapes, start, origin, stop).inside_volume
        if not scored or problem.now() <= stop:
            scored.append((-volume, len(scored), origin))

    for origin in trials:
        if scored and problem.now() > stop:
            break
        trial(origin)
    for scan in range(scans):
        best = np.array(min(scored)[2])
        axis = 1 - scan % 2  # along the crest first: its steps are the narrower
        m = n if axis == 1 else max(2, n // 2)  # the steps across are twice as wide
        offset = rng.uniform(0.0, 1.0)
        for i in range(m):
            if problem.now() > stop:
                break
            best[axis] = (i + offset) / m * period[axis]
            trial((float(best[0]), float(best[1])))
    scored.sort()
    return [o for _, _, o in scored]


def pattern_pass(problem: Problem, shapes: ShapeCache, start: Build, origin: tuple[float, float],
                 stop: float = float("inf")) -> Build:
    """``start`` with the pattern's sites from ``origin`` lowered in crane order, as drawn,
    up to the required count or until ``stop`` (``problem.now()``): the quick pass
    that ranks an origin."""
    b = start.copy()
    for fam, yaw, x, y in pattern_sites(problem, origin):
        if len(b) >= problem.required or problem.now() > stop:
            break
        c = b.lower(shapes.hung(fam, yaw), x, y)
        if c is not None:
            b.place(c)
    return b


def pattern_sites(problem: Problem, origin: tuple[float, float]) -> list[tuple[str, float, float, float]]:
    """Pattern sites in crane order: the lattice, then the layer laid on it, and so on.

    Each pass lands on the one before where it left no room below: the next
    layer, nested into the pockets of the one under it. The second pass is
    the lattice's tuned upper layer where it has one (tetrapods), otherwise
    the lattice shifted by half a cell; later passes alternate the two. A
    nested layer adds about 0.8 H of height, so the zone's height sets the
    number of passes (two for ``mini``'s 3.55 m zone and 1.66 m blocks, more
    for taller mounds).
    """
    z = problem.scene.tolerance
    xr, yr = (-z.bottom_half_width, z.bottom_half_width), (z.y_start, z.y_end)
    lat = problem.lattice
    passes = max(2, int(np.floor((z.z_top - z.z_bottom) / (0.8 * problem.scene.block.height))))
    upper, shifted = lat.second_layer(origin)
    sites = []
    for n in range(passes):
        sites += lat.sites(xr, yr, origin) if n % 2 == 0 else upper.sites(xr, yr, shifted)
    return sites
