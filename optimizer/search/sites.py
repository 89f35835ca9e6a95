"""The placement pattern laid over a scene: its sites, a quick pass, and its best origins.

The beam search, annealing and the CP-SAT bound all draw blocks from the
pattern's sites (:func:`pattern_sites`); which origin the pattern is laid from
decides how many rows fit between the slopes and the ends, so origins are
ranked first by a quick pass of the pattern alone (:func:`rank_origins`).
"""

from __future__ import annotations

import math
from collections.abc import Collection
from dataclasses import replace

import numpy as np
from scipy.spatial import cKDTree

from geometry.coverage import AIM_BARE_PERCENT

from .build import Build, search_window
from .problem import Problem
from .shapes import ShapeCache
from .toe import outermost


def rank_origins(problem: Problem, shapes: ShapeCache, rng: np.random.Generator, start: Build,
                 probes: int, stop: float, scans: int = 0, n: int = 16,
                 laid: Collection[int] | None = None,
                 counts: dict[tuple[float, ...], int] | None = None,
                 passes: dict[tuple[float, ...], Build] | None = None) -> list[tuple[float, float]]:
    """Pattern origins, best first: by the volume their sites alone place in the design prism.

    First ``probes`` origins, (0, 0) and seeded random ones over one lattice cell;
    a build with kept blocks adds first the origins that lay the pattern through
    them (:func:`kept_origins`), and a problem with an anchor (``Problem.anchor``,
    :func:`fit_to_toes`) the :data:`ANCHORED` origins from it, after (0, 0). With an
    anchor, the pass that places more of the count ranks first, then an origin from the
    anchor, then the volume (:func:`anchored_first`). Then ``scans`` line scans, taken in turn along
    the crest (y) and across it (x), each through the best origin so far: ``n``
    origins along the crest, or ``n / 2`` across it, spaced evenly over one
    lattice period with a seeded offset. The count a pattern places is a step
    function of its origin, nearly a sum of one step in x (how many rows fit
    between the slopes) and one in y (how many fit between the ends): on
    ``tetrapod`` it ranges from 60 to 81 blocks, and the steps that reach 81 are
    about 0.3 m wide in x and 0.16 m in y, against scan spacings of 0.23 m and
    0.13 m at ``n = 16``: a scan cannot step over them, where random probes often
    miss them. The sites that the ``laid`` blocks of ``start`` are in the way of
    are left out (:func:`laid_sites`; kept ones by default). Trials stop at
    ``stop`` (``problem.now()``). A trial the deadline cuts short is dropped,
    unless it is the only one: then the origin it drew is all there is to rank
    (a budget too short for one pass over a long scene). Where ``counts`` is given, the
    blocks each pass that ended before ``stop`` holds are entered in it, by origin, for
    :func:`fitted_origins`; where ``passes`` is given, the passes from the anchor themselves,
    for :func:`rank_by_coverage` (4.5 MB a pass of ``big-shake``'s 269 blocks: not all of them).
    """
    lat = problem.lattice
    period = np.array([lat.w, lat.p])
    trials = kept_origins(problem, start, stop=stop) + [(0.0, 0.0)] + anchored_origins(problem) + [
        (float(rng.uniform(0, lat.w)), float(rng.uniform(0, lat.p))) for _ in range(probes - 1)]
    scored: list[tuple] = []  # (*anchored_first, -volume, trial, origin)

    def trial(origin: tuple[float, float]) -> None:
        build = pattern_pass(problem, shapes, start, origin, stop, laid)
        whole = problem.now() <= stop
        if counts is not None and whole:
            counts[origin] = len(build)
        if passes is not None and whole and from_anchor(problem, origin):
            passes[origin] = build
        if not scored or whole:
            first = anchored_first(problem, build, origin)
            scored.append((*first, -build.inside_volume, len(scored), origin))

    for origin in trials:
        if scored and problem.now() > stop:
            break
        trial(origin)
    for scan in range(scans):
        best = np.array(min(scored)[-1])
        axis = 1 - scan % 2  # along the crest first: its steps are the narrower
        m = n if axis == 1 else max(2, n // 2)  # the steps across are twice as wide
        offset = rng.uniform(0.0, 1.0)
        for i in range(m):
            if problem.now() > stop:
                break
            best[axis] = (i + offset) / m * period[axis]
            trial((float(best[0]), float(best[1])))
    scored.sort()
    return [s[-1] for s in scored]


#: How far the pattern's spacing across the crest may be changed so that its columns stand at
#: both toes (:func:`fit_to_toes`), as a share of it.
TOE_FIT = 0.03
#: Origins from the anchor (:attr:`Problem.anchor`) among the trials that rank origins, evenly
#: along the crest over one period.
ANCHORED = 4


def anchored_origins(problem: Problem) -> list[tuple[float, float]]:
    """The origins from ``problem.anchor`` ranked with the rest, or none where it has none."""
    if problem.anchor is None:
        return []
    return [(problem.anchor, i / ANCHORED * problem.lattice.p) for i in range(ANCHORED)]


def from_anchor(problem: Problem, origin: tuple[float, ...]) -> bool:
    """Whether ``origin`` is one of the anchor's: its x is the anchor (``Problem.anchor``), as the
    scans along the crest keep it exactly."""
    return problem.anchor is not None and origin[0] == problem.anchor


def anchored_first(problem: Problem, build: Build, origin: tuple[float, float]) -> tuple[int, ...]:
    """The first keys of an origin's rank where the problem has an anchor: the pass that places
    more of the count first, then an origin from the anchor; none where it has no anchor.

    By volume alone the anchor's origins come after others that hold a little more inside and
    leave the toes bare: on ``big-shake`` seed 1 the beam was laid from x = 0.51, where the
    anchor puts the columns at x = 0.00 (stop 80).
    """
    if problem.anchor is None:
        return ()
    return -min(len(build), problem.required), int(not from_anchor(problem, origin))


def fit_to_toes(problem: Problem, shapes: ShapeCache, stop: float, stretch: bool = True) -> Problem:
    """``problem`` with its pattern fitted across the crest to the mound's toes, where it fits.

    The pattern's columns stand ``w`` apart across the crest. A translation moves the outermost
    column at one toe out and the one at the other in, so that the two gaps between them and
    where a block can rest outermost add up to about one spacing whatever the origin: on
    ``big-shake`` the toes of every layout were bare (docs/coverage-study.md, stop 79). Here
    the first hanging of the pattern is lowered onto the empty foundation at mid-length as far
    out towards each side as it rests inside the zone (:func:`toe.outermost`), and the spacing
    is changed to the nearest that puts a whole number of columns between the two places,
    where that is within :data:`TOE_FIT` of it; ``anchor`` is then the origin across the crest
    that stands a column at each. The spacing along the crest and the later passes are as they
    were. A wider spacing holds fewer blocks, so it is taken only with ``stretch``: where the
    pattern is known to hold the count with a margin (``optimize`` asks the spread's choice). On
    held-out ``tetra-gentle``, short of its count, a spacing 2.3 % wider took seed 1 from 51 to 46
    of 60 (stop 80). Unchanged where no such spacing is that near, or ``stop``
    (``problem.now()``) comes first.
    """
    lat = problem.lattice
    scene = problem.scene
    shape = shapes.hung(lat.family_a, lat.yaw_a)
    empty = Build(scene)
    _, (y0, y1) = search_window(scene)
    y = 0.5 * (y0 + y1)
    found = []
    for side in (1.0, -1.0):
        if problem.now() > stop:
            return problem
        c = outermost(problem, empty, shape, side, y)
        if c is None:
            return problem
        found.append(float(c.pose.position[0]))
    span = found[0] - found[1]
    columns = round(span / lat.w)
    if columns < 1 or abs(span / columns / lat.w - 1.0) > TOE_FIT or (span / columns > lat.w and not stretch):
        return problem
    fitted = replace(lat, w=span / columns)
    return replace(problem, lattice=fitted, anchor=found[1])


def rank_by_coverage(problem: Problem, shapes: ShapeCache, start: Build, origins: list[tuple[float, float]],
                     n: int, stop: float, laid: Collection[int] | None = None,
                     passes: dict[tuple[float, ...], Build] | None = None,
                     spacing: float | None = None) -> list[tuple[float, float]]:
    """``origins`` (ranked by volume, best first) with ``n`` of them put first, ranked by how
    their pattern alone covers: the pass that places more of the count first, then the one
    that covers better (:meth:`geometry.coverage.CoverageReport.better_than`), then the
    volume's order.

    Which rows of the pattern stand nearest the crest's edges and the toes depends on the
    origin across the crest (x), so the ``n`` are the best by volume of each x, and of each
    origin along the crest (y) from the anchor (``Problem.anchor``), where x is fixed. On ``mini``
    with toe rows laid (seed 1), the best origins by volume shared one x and left 8.5 to
    11.8 % of the surface bare after the beam search; passes from other x within 0.2 points
    of porosity left 4.0 to 11.1 % bare. Passes stop at ``stop``: origins not reached by
    then keep their order, after the ranked ones (a pass cut short ranks by what it placed).
    A pass already laid in ``passes`` (:func:`rank_origins`) is not laid again; the coverage
    is sampled every ``spacing`` where given (:func:`geometry.coverage.coverage`).
    """
    firsts: dict[tuple[float, ...], int] = {}
    for i, origin in enumerate(origins):  # an origin may go on with its later passes' shifts
        x = round(origin[0], 3)
        # The anchor fixes x: its origins differ along the crest, each a candidate of its own.
        key = (x, round(origin[1], 3)) if from_anchor(problem, origin) else (x,)
        firsts.setdefault(key, i)
    chosen = sorted(firsts.values())[:n]
    scored = []
    for i in chosen:
        if problem.now() > stop:
            break
        b = (passes or {}).get(origins[i])
        if b is None:
            b = pattern_pass(problem, shapes, start, origins[i], stop, laid)
        report = problem.coverage(b.placed(), spacing=spacing)
        if report is None:
            break
        scored.append((-min(len(b), problem.required), -report.aims_met(), report.bare_share_percent, i))
    first = [i for *_, i in sorted(scored)]
    ranked = set(first)
    return [origins[i] for i in first] + [o for i, o in enumerate(origins) if i not in ranked]


def pattern_pass(problem: Problem, shapes: ShapeCache, start: Build, origin: tuple[float, float],
                 stop: float = float("inf"), laid: Collection[int] | None = None) -> Build:
    """``start`` with the pattern's sites from ``origin`` lowered in crane order, as drawn,
    up to the required count or until ``stop`` (``problem.now()``): the quick pass
    that ranks an origin. The sites the ``laid`` blocks of ``start`` are in the way
    of are skipped (:func:`laid_sites`; kept ones by default)."""
    b = start.copy()
    lay_sites(problem, shapes, start, b, pattern_sites(problem, origin), stop, laid, problem.required)
    return b


def lay_sites(problem: Problem, shapes: ShapeCache, start: Build, onto: Build,
              sites: list[tuple[str, float, float, float]], stop: float,
              laid: Collection[int] | None = None, most: float = float("inf")) -> int | None:
    """Lower ``sites`` in order onto ``onto``, placing each that lands, until ``onto`` holds
    ``most`` blocks; the sites the ``laid`` blocks of ``start`` are in the way of are skipped
    (:func:`laid_sites`). Returns the blocks placed, or None where ``stop``
    (``problem.now()``) came first."""
    taken = laid_sites(problem, start, sites, laid)
    placed = 0
    for i, (fam, yaw, x, y) in enumerate(sites):
        if len(onto) >= most:
            break
        if problem.now() > stop:
            return None
        if i in taken:
            continue
        c = onto.lower(shapes.hung(fam, yaw), x, y)
        if c is not None:
            onto.place(c)
            placed += 1
    return placed


def pattern_passes(problem: Problem) -> int:
    """How many passes (layers) the pattern lays: a nested layer adds about 0.8 H of height,
    so the zone's height sets it (two for ``mini``'s 3.55 m zone and 1.66 m blocks, more for
    taller mounds). The zone counts no higher than a block's bounding radius over the
    design's crest, as ``search_window`` bounds it across: a block above fills none of the
    prism. A crest allowance of kilometres made thousands of passes, and ``optimize`` ran
    out of memory before its first time check."""
    scene = problem.scene
    z = scene.tolerance
    top = min(z.z_top, scene.design.z_top + scene.block.bounding_radius)
    return max(2, int(np.floor((top - z.z_bottom) / (0.8 * scene.block.height))))


def pass_sites(problem: Problem, origin: tuple[float, ...], n: int) -> list[tuple[str, float, float, float]]:
    """The sites of the pattern's pass ``n`` (0 for the first) from ``origin``, in crane order.

    An origin is ``(x, y)``, the first pass's; it may go on with a shift ``(dx, dy)`` for each
    later pass, from where that pass nests by default (:func:`fit_layers`)."""
    xr, yr = search_window(problem.scene)
    lat = problem.lattice
    if n % 2 == 0:
        layer, at = lat, (origin[0], origin[1])
    else:
        layer, at = lat.second_layer((origin[0], origin[1]))
    if n and len(origin) >= 2 * n + 2:
        at = (at[0] + origin[2 * n], at[1] + origin[2 * n + 1])
    return layer.sites(xr, yr, at)


def pattern_sites(problem: Problem, origin: tuple[float, ...]) -> list[tuple[str, float, float, float]]:
    """Pattern sites in crane order: the lattice, then the layer laid on it, and so on.

    Each pass lands on the one before where it left no room below: the next
    layer, nested into the pockets of the one under it. The second pass is
    the lattice's tuned upper layer where it has one (tetrapods), otherwise
    the lattice shifted by half a cell; later passes alternate the two, each
    shifted as its origin says (:func:`pass_sites`). The zone's height sets
    the number of passes (:func:`pattern_passes`).
    """
    sites = []
    for n in range(pattern_passes(problem)):
        sites += pass_sites(problem, origin, n)
    return sites


#: Shifts tried for each later pass of the pattern (:func:`fit_layers`): this many across the
#: crest over one period (x), then this many along it (y), each including the nested default.
LAYER_SHIFTS = (6, 3)
#: Origins, the best by volume, whose later passes are fitted (:func:`fitted_origins`).
FITTED = 4


def fit_layers(problem: Problem, shapes: ShapeCache, start: Build, origin: tuple[float, ...],
               stop: float, laid: Collection[int] | None = None) -> tuple[float, ...]:
    """``origin`` with each later pass of the pattern shifted to where it lays the most blocks.

    A layer nests into the pockets of the one under it wherever the mound is
    wide; where its section narrows (a slope, a wall), where its rows fall
    decides how many of them stay inside the zone. Pass by pass, on the passes
    before it as laid, shifts across the crest (``LAYER_SHIFTS[0]`` over one
    period) and then along it at the best across are each laid in full, no
    count to stop them; a shift is kept only if it lays strictly more than the
    nested default. What that holds, against the pattern nested as tuned, is measured
    by ``benchmarks/studies/pattern_capacity.py`` (docs/benchmarks.md, "Later layers
    fitted to the section").
    Trials stop at ``stop`` (``problem.now()``), within a pass too: a pass cut short is
    not weighed, and the shifts found by then are kept.
    """
    lat = problem.lattice
    b = start.copy()

    def lay(onto: Build, sites: list) -> int | None:
        return lay_sites(problem, shapes, start, onto, sites, stop, laid)

    def trial(below: Build, shifts: list[float], n: int,
              shift: tuple[float, float]) -> tuple[int | None, Build]:
        """Pass ``n`` shifted by ``shift``, laid on ``below`` (the passes before, shifted by ``shifts``)."""
        t = below.copy()
        return lay(t, pass_sites(problem, (origin[0], origin[1], *shifts, *shift), n)), t

    if lay(b, pass_sites(problem, origin, 0)) is None:
        return origin
    shifts: list[float] = []
    across, along = LAYER_SHIFTS
    for n in range(1, pattern_passes(problem)):
        best_count, best_build = trial(b, shifts, n, (0.0, 0.0))
        if best_count is None:
            break
        best = (0.0, 0.0)
        tries = [(i / across * lat.w, None) for i in range(1, across)] + [(None, j / along * lat.p)
                                                                            for j in range(1, along)]
        for dx, dy in tries:
            shift = (best[0], dy) if dx is None else (dx, 0.0)
            k, t = trial(b, shifts, n, shift)
            if k is None:
                break
            if k > best_count:
                best_count, best_build, best = k, t, shift
        shifts += best
        b = best_build
    while shifts and shifts[-2:] == [0.0, 0.0]:
        shifts = shifts[:-2]
    return (origin[0], origin[1], *shifts)


def fitted_origins(problem: Problem, shapes: ShapeCache, start: Build, origins: list[tuple[float, ...]],
                   stop: float, laid: Collection[int] | None = None,
                   n: int = FITTED, counts: dict[tuple[float, ...], int] | None = None
                   ) -> list[tuple[float, ...]]:
    """``origins`` (ranked, best first) with the first ``n`` whose pattern falls short of the
    required count fitted layer by layer (:func:`fit_layers`), where that lays more of it.

    Where any is fitted, those tried are ranked by the count their quick pass places, and
    equal counts keep their order; the rest follow in theirs. Where none is, ``origins`` come
    back as they were. An origin whose pattern holds the count is left as it is: where the
    pattern has room to spare its layers stay nested as tuned. Trials stop at ``stop``.
    ``counts`` are the blocks quick passes already laid hold, by origin (:func:`rank_origins`):
    those passes are not laid again.
    """
    scored, changed = [], False
    for i, origin in enumerate(origins[:n]):
        if problem.now() > stop:
            break
        count = (counts or {}).get(origin)
        if count is None:
            count = len(pattern_pass(problem, shapes, start, origin, stop, laid))
        if count < problem.required:
            shifted = fit_layers(problem, shapes, start, origin, stop, laid)
            if len(shifted) > 2 and problem.now() <= stop:
                more = len(pattern_pass(problem, shapes, start, shifted, stop, laid))
                if more > count and problem.now() <= stop:  # a pass cut short is not weighed
                    origin, count, changed = shifted, more, True
        scored.append((-count, i, origin))
    if not changed:
        return origins
    scored.sort(key=lambda s: s[:2])
    return [o for *_, o in scored] + origins[len(scored):]


#: A block already laid within this share of the lattice's smaller period of a site, across, stands
#: on that site (the pattern's own blocks are on their sites to within the beam's jitter).
SITE_MATCH = 0.2
#: Sites this many bounding radii of a block already laid off the pattern are left out.
OFF_PATTERN = 1.0
#: Kept blocks that propose origins (each proposes two), evenly over the crane order: the rest
#: only count.
PROPOSERS = 32
#: A kept block within this share of the lattice's smaller period of a site stands on it
#: exactly (a site as drawn, before any jitter or settle), when origins are counted.
EXACT_MATCH = 0.05


def kept_origins(problem: Problem, build: Build, most: int = 3, stop: float | None = None
                 ) -> list[tuple[float, float]]:
    """Origins that lay the pattern through the most kept blocks (``Build.keep``), best first.

    A partial layout laid from the pattern (a reference cut short) is
    completed along its own rows: each kept block proposes the origin that
    puts a site of either family under it, and an origin counts the kept
    blocks it puts a site under, within ``EXACT_MATCH`` first and then
    within ``SITE_MATCH``. Origins under fewer than two are left out
    (kept blocks off any pattern, such as a trainee's, propose none).

    The sites are dense enough that ``SITE_MATCH`` alone does not tell the
    pattern's origin from others: the first 30 blocks of a ``mini`` reference
    (14 in toe rows, off the pattern) lay under 22 sites of their own origin
    and under 24 to 26 of three others, whose quick passes placed 58 to 60
    blocks against 75 (2026-11-27). Within ``EXACT_MATCH``, 17 lay under
    their own and under one other, and under at most 4 of the rest.
    """
    lat = problem.lattice
    kept = np.array([build.poses[k].position[:2] for k in build.kept]).reshape(-1, 2)
    if len(kept) < 2:
        return []
    proposals = []
    # Proposers evenly over the crane order: the first blocks may be rows off the pattern.
    for x, y in kept[np.unique(np.linspace(0, len(kept) - 1, min(PROPOSERS, len(kept))).astype(int))]:
        for du, dv in ((0.0, 0.0), (lat.u, lat.v)):
            j = np.floor((x - du) / lat.w)
            proposals.append((x - du - j * lat.w, (y - dv - j * lat.q) % lat.p))
    # Counted until ``stop`` (``problem.now()``), the first always: 3005 kept blocks took 2.9 s
    # here under a 2 s limit.
    counted = []
    for i, o in enumerate(proposals):
        if counted and stop is not None and problem.now() > stop:
            break
        counted.append((tuple(-n for n in _under(problem, o, kept)), i, o))
    counted.sort()
    out: list[tuple[float, float]] = []
    for minus, _, o in counted:
        if -minus[0] < 2 or len(out) == most:
            break
        if all(np.hypot(o[0] - p[0], o[1] - p[1]) > SITE_MATCH * min(lat.w, lat.p) for p in out):
            out.append((float(o[0]), float(o[1])))
    return out


def _under(problem: Problem, origin: tuple[float, float], kept: np.ndarray) -> tuple[int, int]:
    """How many of ``kept`` (x, y) stand on a site of the pattern laid from ``origin``: within
    ``EXACT_MATCH``, and within ``SITE_MATCH``."""
    sites = np.array([(x, y) for _, _, x, y in pattern_sites(problem, origin)]).reshape(-1, 2)
    if not len(sites):
        return 0, 0
    d, _ = cKDTree(sites).query(kept)
    period = min(problem.lattice.w, problem.lattice.p)
    return int((d <= EXACT_MATCH * period).sum()), int((d <= SITE_MATCH * period).sum())


def laid_sites(problem: Problem, build: Build, sites: list[tuple[str, float, float, float]],
               keys: Collection[int] | None = None) -> frozenset[int]:
    """Indices of ``sites`` that blocks already laid stand on or are in the way of.

    The blocks are ``keys`` of ``build``: by default its kept ones
    (``Build.keep``); the attempt with toe rows first passes every block of
    its start, the rows (``BeamSearch.around_laid``). Each, in crane order,
    takes the first free site within ``SITE_MATCH`` of it across. One off the
    pattern (a trainee's, a toe row's) takes every site within ``OFF_PATTERN``
    bounding radii of it: a block lowered there would land on its shoulder,
    and the pockets around it are left to the fill drops, which go where
    blocks settle. Offered anyway, the sites beside the toe rows were
    jittered into the pockets and jammed the ones after them: around
    ``mini``'s crown toe rows (seeds 1-3) the beam and the fill laid 72, 75
    and 71 of 75 blocks with them offered, 75 on each seed without. A
    settle's repair (``physics.confirm``) leaves its blocks out of this: they
    are the pattern's own, and the sites of the blocks it took out are to be
    laid again.
    """
    keys = list(build.kept if keys is None else keys)
    if not keys or not sites:
        return frozenset()
    tree = cKDTree(np.array([(x, y) for _, _, x, y in sites]))
    reach = SITE_MATCH * min(problem.lattice.w, problem.lattice.p)
    taken: set[int] = set()
    for k in keys:
        xy = build.poses[k].position[:2]
        free = [i for i in sorted(tree.query_ball_point(xy, reach)) if i not in taken]
        if free:
            taken.add(free[0])
        else:
            taken.update(tree.query_ball_point(xy, OFF_PATTERN * build.block.bounding_radius))
    return frozenset(taken)


#: How far above the required count the pattern must still hold once spread (its quick pass,
#: laid up to that many): a tuned constant. On ``big-shake`` the pattern spread by 1.05 holds 309 (269
#: required, 15 % over) and the search reached the count; spread by 1.10 it holds 279 (4 % over)
#: and the search, which lets blocks go, placed 264 (docs/coverage-study.md, "Spreading the
#: pattern").
SPREAD_MARGIN = 0.15
#: The spreads tried, in plan, smallest first; and the origins each is laid from, until one
#: holds the count with the margin (a pattern's count steps with its origin).
SPREADS = (1.02, 1.04, 1.06, 1.08, 1.10, 1.15, 1.20, 1.25, 1.30)
SPREAD_ORIGINS = 4


def holds_margin(problem: Problem, held: int | None) -> bool:
    """Whether a pattern that ``spread_to_count`` saw hold ``held`` blocks holds the count with
    ``SPREAD_MARGIN`` over it (None: not measured)."""
    return held is not None and held >= problem.required * (1.0 + SPREAD_MARGIN)


def spread_to_count(problem: Problem, shapes: ShapeCache, stop: float) -> tuple[float, int | None]:
    """How far to spread the pattern in plan so that the count fills the mound to its top.

    The patterns are denser than the target porosity asks, so on a tall mound the count is
    reached with the top layer empty and the crest bare (``big-shake``: two layers, and
    nothing in the upper 1.5 m). Spread, the same count covers more of the mound. Where the
    count laid as the pattern is (from the origin 0, 0) leaves more of the crest bare than the
    coverage's aim (``AIM_BARE_PERCENT``), the largest
    of :data:`SPREADS` whose pattern still holds ``SPREAD_MARGIN`` more than the count is
    chosen (its quick pass, :func:`pattern_pass`, laid up to that many, from each of
    ``SPREAD_ORIGINS`` origins until one holds it); 1.0 where the unspread one holds no more
    than that, or where
    ``stop`` (``problem.now()``) comes before the choice is made, even after a spread that holds
    the margin was found: a choice cut short says that the spread's search would be short of
    time too. Returns the factor and what the pattern so spread holds, up to the count with the
    margin (the unspread one's where the factor is 1.0; None where it was not measured: the count
    reaches the crest, or no time).
    """
    need = problem.required * (1.0 + SPREAD_MARGIN)
    empty = Build(problem.scene)
    # Only where the count, laid as the pattern is, leaves more of the crest bare than the
    # coverage's aim: elsewhere the count fills the mound already (on ``mini-mesh`` the pattern
    # holds 87 of 75 and covers the crest, and a spread of 1.02 only moved the search's origins).
    counted = pattern_pass(problem, shapes, empty, (0.0, 0.0), stop)
    report = problem.coverage(counted.placed()) if problem.now() <= stop else None
    if report is None or report.by_face().get("crest", 0.0) <= AIM_BARE_PERCENT:  # none: no crest
        return 1.0, None
    # Each pass lays up to the count with the margin, and the origins are tried until one holds it:
    # the choice asks only whether a spread holds that many, and a pass lays its sites in the
    # same order whatever its count. (Laid until nothing fitted, from every origin, the choice
    # on ``big-shake`` took 4.8-6.7 s of its 6.7 s share on our 2-core machine, and the share
    # cut it short in two of six runs.)
    enough = replace(problem, required=math.ceil(need))
    # Fixed shares of a cell, not drawn: the run's random stream is the same with or without it.
    origins = [(0.0, 0.0), (0.5, 0.5), (0.25, 0.75), (0.75, 0.25)][:SPREAD_ORIGINS]

    def holds(factor: float) -> int | None:
        lat = problem.lattice.scaled(factor) if factor != 1.0 else problem.lattice
        p = replace(enough, lattice=lat)
        most = 0
        for u, v in origins:
            b = pattern_pass(p, shapes, empty, (u * lat.w, v * lat.p), stop)
            if problem.now() > stop:
                return None
            most = max(most, len(b))
            if most >= enough.required:
                break
        return most

    base = holds(1.0)
    if not holds_margin(problem, base):
        return 1.0, base
    chosen, held = 1.0, base
    for factor in SPREADS:
        n = holds(factor)
        if n is None:
            # Cut short by its time: the machine is too slow for the spread pattern's longer
            # search as well, and a smaller spread is not chosen. (big-shake on a slow 2-core
            # machine, stops 58 and 60: spread, 231-266 of 269, or 269 that did not stand, in six
            # runs; unspread, 269 and valid in every run.) Since the passes stop at the margin
            # (stop 70) the choice does less work, and this guard cuts only on a machine about
            # twice as slow as ours, where before it cut on ours on a slow day (4.8-6.7 s of
            # its 6.7 s). Now the choice takes 3.0-3.5 s here, and the spread search reached
            # 269, standing, on every seed. Between the two machines is not measured.
            return 1.0, base
        if not holds_margin(problem, n):
            break
        chosen, held = factor, n
    return chosen, held
