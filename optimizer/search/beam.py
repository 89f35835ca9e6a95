"""Beam search: sequential placement in crane order.

Blocks are placed one at a time, each lowered along -z until it first
touches, so the order is always one a crane can follow: bottom up, never a
block under one already placed. At each step every partial layout in the
beam proposes candidates:

* the next few pending sites of the placement pattern (the interlocking
  lattice, crowns first then level blocks), each as drawn and with a few
  jittered variants (position and yaw);
* when no pattern site fits, random "fill" drops over the part of the zone
  where a block can fit, in any allowed hanging, which find pockets the
  pattern does not cover. Fill drops are not offered beside pattern sites:
  they would take the pockets later sites of the pattern need.

A candidate is scored by the documented heuristic::

    gain = inside / V_block                 volume it adds inside the design prism
           - 0.3 * (z - z_ground) / H        resting high (a later layer) costs a little
           + 0.1 * min(supports, 3) / 3      resting on several blocks helps

and the beam keeps the ``width`` partial layouts of highest total gain. A
partial layout ends when it holds the required count or nothing more fits.
The pattern's origin is chosen first, by a quick pass of pattern sites only
for origins on line scans across one lattice cell (:func:`rank_origins`).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from geometry.coverage import default_spacing

from .build import GROUND, Build, Candidate, fill_window
from .drop import Shape
from .hangings import free, hanging_of
from .problem import TARGET_POINTS, Phase, Problem, Stats, Strategy
from .shapes import ShapeCache
from .sites import fitted_origins, laid_sites, pattern_sites, rank_by_coverage, rank_origins

HEIGHT_COST = 0.3
SUPPORT_GAIN = 0.1
#: Candidates a beam step may let go (a physics run each), per partial layout it keeps.
ACCEPT_CHECKS = 3
#: Beam budget (s) from which origins are ranked in full: ``shoha optimize``'s
#: default 120 s limit gives the beam about 80 s.
RANK_SECONDS = 60.0
#: With :meth:`BeamSearch.covering`, how many origins (the best by volume at each offset across
#: the crest) are ranked again by coverage, and the share of the beam's time that may take.
#: Set once, not tuned.
COVER_RANK = 8
COVER_RANK_SHARE = 0.1
#: Where the problem has an anchor (``Problem.anchor``), the first attempt ranks its origins by
#: coverage too (:func:`rank_by_coverage`), with the surface sampled this many times coarser
#: than the coverage's own cell: on ``big-shake`` 0.3 s an origin, not 0.7 s, within 0.1 points
#: of its bare share on eight origins (four times coarser: 0.2 s, up to 1.1 points off).
ANCHOR_RANK_COARSER = 2
#: The share of the beam's time that fitting the pattern's later passes to the section may take
#: (``sites.fitted_origins``), for the best origins whose pattern falls short of the count. Set
#: once, not tuned.
FIT_SHARE = 0.1
#: With :meth:`BeamSearch.against_wall`, a pattern block that stands less than this many block
#: heights from a wall is set down against it: the coverage's own distance (H/2), so no strip of
#: crest that wide is left between the pattern and the wall. On ``wall-shake`` the top row stood
#: 0.5-0.6 m off the wall, and the crest beside it was 70-85 % bare. (0.3 and 0.8 measured too:
#: docs/coverage-study.md.)
WALL_GAP_H = 0.5
#: Steps (m) in which the block is tried nearer the wall; it must rest no higher there than
#: where the pattern set it, to within ``WALL_RISE`` (m).
WALL_STEP = 0.05
WALL_RISE = 0.01


@dataclass(frozen=True)
class BeamStats(Stats):
    """What a beam search did.

    Attributes
    ----------
    candidates : int
        Candidates lowered and scored, over every restart.
    restarts : int
        Searches run, from as many pattern origins.
    origin : (float, float)
        The pattern origin of the build returned.
    """

    candidates: int
    restarts: int
    origin: tuple[float, float]


def gain(problem: Problem, c: Candidate) -> float:
    """How much a candidate is worth: its volume in the design prism, in blocks, less its
    rise above the ground in block heights (``HEIGHT_COST``), plus up to ``SUPPORT_GAIN``
    for resting on the ground or on three blocks."""
    h = problem.scene.block.height
    rise = max(0.0, c.pose.position[2] - (-c.shape.lows.min()))
    supports = len([s for s in c.support if s != GROUND]) + (3 if GROUND in c.support else 0)
    return (c.inside / problem.scene.block.volume - HEIGHT_COST * rise / h
            + SUPPORT_GAIN * min(supports, 3) / 3)


def set_against_wall(problem: Problem, build: Build, c: Candidate,
                     lower: Callable[[Problem, Build, Shape, float, float], Candidate | None]) -> Candidate:
    """``c`` set down against the scene's wall, if it stands less than ``WALL_GAP_H`` from it.

    The block, as hung, is lowered again at the same y, ``WALL_STEP`` apart from
    half a step off the wall outwards; the first place where it rests no higher
    than ``c`` (to within ``WALL_RISE``) is taken. Otherwise, and with no wall,
    ``c`` itself. The wall is on the landward (-x) side, as scenes have it. The
    beam offers the moved candidate in place of the site as drawn: if it does not
    come to rest, the site is offered jittered next, not as drawn.
    """
    wall = problem.scene.tolerance.wall_x
    if wall is None:
        return c
    x, y, z = c.pose.position
    gap = float(x + c.shape.xy_boxes[:, 0, 0].min() - wall)  # the footprint the drop already has
    if not WALL_STEP < gap < WALL_GAP_H * problem.scene.block.height:
        return c
    for left in np.arange(WALL_STEP / 2, gap, WALL_STEP):
        d = lower(problem, build, c.shape, float(x - gap + left), float(y))
        if d is not None and d.pose.position[2] <= z + WALL_RISE:
            return d
    return c


@dataclass
class _Beam:
    build: Build
    score: float
    used: frozenset[int]
    done: bool = False
    idle: int = 0  # consecutive steps with no candidate
    tries: tuple[tuple[int, int], ...] = ()  # (site, times its candidate did not come to rest)

    def tried(self, site: int) -> int:
        return dict(self.tries).get(site, 0)


class BeamSearch(Strategy):
    """Sequential placement with a beam of partial layouts.

    Parameters
    ----------
    width : int
        Partial layouts kept per step.
    lookahead : int
        Pending pattern sites offered per step.
    jitter : int
        Jittered variants per pattern site.
    fill : int
        Random fill drops per step while pattern sites remain (four times as
        many once they are used up).
    jitter_xy : float, metres
    jitter_yaw : float, radians
    origins : int
        Random pattern origins probed before the search.
    scans : int
        Line scans of origins after the probes, along and across the crest
        in turn (:func:`rank_origins`).
    scan_origins : int
        Origins on a scan along the crest (half as many across it), for
        scenes of up to 100 blocks and a planned beam budget of at least
        ``RANK_SECONDS``; fewer for larger scenes (``* 100 / required``) and
        shorter planned budgets (``* planned / RANK_SECONDS``), at least 4. The budget
        planned is ``share`` of the run's span (:meth:`Problem.budget`), not
        of the time left: the count follows from the scene and the time
        limit, not from the machine's speed or the steps before, so that a
        seed gives one layout. (Until stop 69 it was a share of the time
        left, and an attempt made after a slow step ranked fewer origins.)
        The ranking stops at 70 % of the beam's time left (15 % where the
        planned budget is short of ``RANK_SECONDS``), so that a slow machine
        keeps time for the search; only then does the machine's speed change
        the layout. The share is chosen by the planned budget too: an attempt
        made late in a run, with less time left, ranks as many origins, and
        if the ranking takes most of its time its search has what is left
        (with 15 % of a short time left, the cap would cut the ranking, and
        the machine's speed would pick the origins). On 2 cores ``tetrapod``'s 50
        trials take 24 to 44 s of the beam's 82 s at the default 120 s limit
        (the same machine on different days); a 40 % cap cut them (48 in one
        run), and runs of one seed gave different layouts. At 70 % (57 s) the
        first search, 17 s, still fits after the slowest ranking seen.
    patience : int
        Fruitless rounds of fill drops before a partial layout is finished.
    accept : callable, optional
        ``accept(problem, build, candidate) -> Candidate | None``: the
        candidate as it comes to rest, or None if it does not
        (``optimizer.search.physics.raised_check``: a block that rests on
        blocks is let go among its fixed neighbours; one on the foundation
        alone, flat or rough, is kept as lowered).
    origin : (float, float), optional
        Pattern origin; by default several are ranked by a quick pass of the
        pattern's sites alone, and the search restarts from the best ones.
    restarts : int
        Most searches from the best-ranked origins, for scenes of up to 100
        blocks; fewer for larger scenes (``restarts * 100 / required``). The
        next origin is searched only while no search has placed the required
        count in a layout that stands (``judge``) with its porosity within
        ``TARGET_POINTS`` of the target. Running every restart made
        the work outgrow the default limit on a slow day: on 2 cores on
        2026-11-23 ``mini``'s four took until 79 s of the beam's 82 s and
        ``tetrapod``'s were cut at the third, so the deadline, that is the
        machine's speed, picked the layout. What the later restarts bought
        was small where measured: 0.02 points on ``mini`` seed 1 (56.517 %
        after the fourth, 56.539 % after the first), none on ``tetrapod``
        seed 2 (its first two gave 53.1816 %).
    share : float
        Fraction of the time left that the beam may use.
    judge : callable, optional
        ``judge(problem, build) -> bool``: whether a finished build stands
        (``optimizer.search.physics.stands``); restarts that stand rank first.
    """

    name = "beam"

    def __init__(self, width: int = 4, lookahead: int = 3, jitter: int = 2, fill: int = 4,
                 jitter_xy: float = 0.12, jitter_yaw: float = math.radians(6.0), origins: int = 10,
                 scans: int = 3, scan_origins: int = 16, patience: int = 4,
                 accept: Callable[[Problem, Build, Candidate], Candidate | None] | None = None,
                 origin: tuple[float, float] | None = None, restarts: int = 4, share: float = 0.75,
                 judge: Callable[[Problem, Build], bool] | None = None):
        self.width = width
        self.lookahead = lookahead
        self.jitter = jitter
        self.fill = fill
        self.jitter_xy = jitter_xy
        self.jitter_yaw = jitter_yaw
        self.origins = origins
        self.scans = scans
        self.scan_origins = scan_origins
        self.patience = patience
        self.accept = accept
        self.origin = origin
        self.restarts = restarts
        self.share = share
        self.judge = judge
        self.around_all = False
        self.to_wall = False
        self.cover_rank = 0

    def against_wall(self) -> BeamSearch:
        """The same search, with the pattern's blocks that stand within ``WALL_GAP_H`` of a wall
        set down against it (:func:`set_against_wall`), for the attempt that aims to cover."""
        other = copy.copy(self)
        other.to_wall = True
        return other

    def around_laid(self) -> BeamSearch:
        """The same search, leaving out the pattern sites that any block of its start is in the
        way of, not only kept ones (:func:`optimizer.search.sites.laid_sites`): the pattern laid
        around blocks placed before it, such as the toe rows."""
        other = copy.copy(self)
        other.around_all = True
        return other

    def covering(self, origins: int = COVER_RANK) -> BeamSearch:
        """The same search, searched first from up to ``origins`` origins (the best by volume
        at each offset across the crest) ranked by how well their pattern alone covers the
        mound (:func:`rank_by_coverage`), for the attempt that aims to cover."""
        other = copy.copy(self)
        other.cover_rank = origins
        return other

    # --- candidates ------------------------------------------------------------

    def _lower(self, problem: Problem, build: Build, shape: Shape, x: float, y: float) -> Candidate | None:
        # Whether it comes to rest is asked later, of the candidates the beam keeps (_search).
        return build.lower(shape, x, y)

    def _proposals(self, problem: Problem, beam: _Beam, sites: list, shapes: ShapeCache,
                   rng: np.random.Generator) -> tuple[list[tuple[float, Candidate, int | None]], set[int]]:
        """Candidates for one partial layout, and the pending sites where nothing fits (dead)."""
        out = []
        dead: set[int] = set()
        pending = [i for i in range(len(sites)) if i not in beam.used][: self.lookahead]
        for i in pending:
            fam, yaw, x, y = sites[i]
            # A site is offered as drawn first; once its candidate did not come to rest, jittered.
            c = (self._lower(problem, beam.build, shapes.hung(fam, yaw), x, y)
                 if not beam.tried(i) else None)
            if c is not None:
                if self.to_wall:
                    c = set_against_wall(problem, beam.build, c, self._lower)
                out.append((gain(problem, c), c, i))
                continue
            fitted = False
            # The lattice is tuned to its limit: jitter a site only where it does not fit as
            # drawn (the slopes and ends), or it would jam the pockets of later sites.
            for _ in range(self.jitter):
                vx, vy = x + rng.normal(0, self.jitter_xy), y + rng.normal(0, self.jitter_xy)
                vyaw = yaw + rng.normal(0, self.jitter_yaw)
                c = self._lower(problem, beam.build, shapes.hung(fam, vyaw), vx, vy)
                if c is not None:
                    out.append((gain(problem, c), c, i))
                    fitted = True
            if not fitted:
                dead.add(i)
        if out or len(dead) < len(pending):
            return out, dead  # the pattern first: fill drops would take the pockets its later sites need
        if pending:
            return out, dead  # all pending sites died: move on along the pattern before filling
        xr, yr = fill_window(problem.scene)
        for _ in range(4 * self.fill):
            fam = problem.families[int(rng.integers(len(problem.families)))]
            yaw = float(rng.uniform(0, 2 * np.pi))
            q = free(rng) if fam == "free" else hanging_of(shapes.block, fam, yaw)
            x, y = rng.uniform(xr[0], xr[1]), rng.uniform(yr[0], yr[1])
            c = self._lower(problem, beam.build, shapes.get(q), float(x), float(y))
            if c is not None:
                out.append((gain(problem, c), c, None))
        return out, dead

    # --- search ---------------------------------------------------------------------

    def run(self, problem: Problem, previous: Phase | None, rng: np.random.Generator) -> Phase:
        start = previous.build.copy() if previous is not None else Build(problem.scene)
        if len(start) >= problem.required:
            # A start that holds the count already (``--keep`` with a whole layout) is done: ranking
            # origins for it took 1.6 s of a 2 s limit around 84 kept blocks one inside another.
            return Phase(start, BeamStats(0, 0, None), previous.origin if previous is not None else None)
        shapes = ShapeCache(problem.scene.block)
        t0 = problem.now()
        # The beam's share of the time left; the rest is for the strategies after it.
        end = t0 + self.share * max(0.0, problem.time_left())
        if self.origin is not None:
            origins = [self.origin]
        else:
            # Fewer trials for long scenes and short limits: how many follows from the run's
            # span (Problem.budget), not from the time left, so that an attempt made after a
            # slow step ranks as many. Under a short limit the search itself needs the time:
            # the ranking keeps to 15 % of the beam's time. Otherwise the cap is a guard for
            # slow machines, not a limit that binds (see scan_origins).
            budget, planned = end - t0, problem.budget(self.share)
            n = max(4, round(self.scan_origins * min(1.0, 100 / max(problem.required, 1))
                             * min(1.0, planned / RANK_SECONDS)))
            cap = t0 + (0.7 if planned >= RANK_SECONDS else 0.15) * budget
            counts: dict[tuple[float, ...], int] = {}  # the quick passes' blocks, laid once
            # With an anchor the count and the anchor rank first, then the volume, which does not
            # see the crest: on big-shake the anchor's origin along it left 16.8 or 29-30 % bare
            # (stop 80). Its origins are ranked again by coverage, sampled ANCHOR_RANK_COARSER
            # times coarser: the attempt needs its time for the count. Either ranking by coverage
            # takes the anchor's passes as the ranking above laid them.
            anchored = problem.anchor is not None and not self.cover_rank
            passes: dict[tuple[float, ...], Build] | None = {} if problem.anchor is not None else None
            origins = rank_origins(problem, shapes, rng, start, self.origins, cap, self.scans, n,
                                   self._laid(start), counts, passes)
            origins = fitted_origins(problem, shapes, start, origins, problem.now() + FIT_SHARE * budget,
                                     self._laid(start), counts=counts)
            if self.cover_rank or anchored:
                spacing = ANCHOR_RANK_COARSER * default_spacing(problem.scene) if anchored else None
                origins = rank_by_coverage(problem, shapes, start, origins, self.cover_rank or COVER_RANK,
                                           problem.now() + COVER_RANK_SHARE * budget, self._laid(start),
                                           passes, spacing)
            passes = None  # not held through the search
        best: tuple | None = None
        tried = 0
        runs = 0
        # Restarts pay off where the pattern's origin decides much (a short scene's ends);
        # a long scene gets fewer, fixed by its size so a seed does the same work anywhere.
        restarts = max(1, min(self.restarts, round(self.restarts * 100 / max(problem.required, 1))))
        for n, origin in enumerate(origins[:restarts]):
            # Restarts follow from results, not from the clock: the same seed does the same
            # work on any machine, and only a deadline that binds cuts it short.
            # best[0] starts (-count, not stands, porosity off): a full layout that stands, with
            # its porosity within TARGET_POINTS of the target, ends the restarts.
            if n and (problem.now() > end or best[0][:3] <= (-problem.required, False, TARGET_POINTS)):
                break
            result, count = self._search(problem, start, origin, shapes, rng, end)
            tried += count
            runs += 1
            # The verdict ranks restarts and ends them. A first search that ends past the beam's
            # time has neither to do: 900 kept blocks of ``full`` took 6.5 s to judge after a
            # search of a 2 s limit that had placed nothing.
            judge = self.judge is not None and (n > 0 or problem.now() <= end)
            stands = self.judge(problem, result) if judge else True
            key = (-len(result), not stands, abs(result.porosity.percent - problem.target), n)
            if best is None or key < best[0]:
                best = (key, result, origin)
            problem.tell(self.name, best[1], f"restart {n + 1}: {len(result)} placed")
        assert best is not None
        _, result, origin = best
        return Phase(result, BeamStats(tried, runs, origin), origin)

    def _laid(self, start: Build) -> list[int]:
        """The blocks of ``start`` whose sites the pattern leaves out: kept ones, or all."""
        return list(start.order) if self.around_all else list(start.kept)

    def _search(self, problem: Problem, start: Build, origin: tuple[float, float], shapes: ShapeCache,
                rng: np.random.Generator, end: float) -> tuple[Build, int]:
        """One beam search from one pattern origin; returns the best build and candidates tried."""
        sites = pattern_sites(problem, origin)
        # A start that holds the count already (``--keep`` with a whole layout) is done.
        beams = [_Beam(start, 0.0, laid_sites(problem, start, sites, self._laid(start)),
                       len(start) >= problem.required)]
        tried = 0
        while any(not b.done for b in beams) and problem.now() < end:
            expanded: list[tuple[float, int, _Beam, Candidate | None, int | None]] = []
            for bi, beam in enumerate(beams):
                if beam.done:
                    expanded.append((beam.score, bi, beam, None, None))
                    continue
                props, dead = self._proposals(problem, beam, sites, shapes, rng)
                tried += len(props)
                if dead:
                    beam = _Beam(beam.build, beam.score, beam.used | dead, beam.done, beam.idle)
                if not props:
                    # Nothing fits. Dead sites are consumed above; once no site remains,
                    # a few more rounds of fill drops before the layout is finished.
                    idle = 0 if dead else beam.idle + 1
                    expanded.append((beam.score, bi, _Beam(beam.build, beam.score, beam.used,
                                                           idle >= self.patience, idle), None, None))
                    continue
                for gain, c, site in props:
                    expanded.append((beam.score + gain, bi, beam, c, site))
            # Keep the best distinct expansions (ties broken by order: deterministic). Whether a
            # candidate comes to rest costs a physics run, so it is asked only of those the beam
            # would keep, best first; one that does not is counted against its site.
            expanded.sort(key=lambda e: (-e[0], e[1]))
            nxt: list[_Beam] = []
            seen: set[tuple] = set()
            refused: dict[int, dict[int, int]] = {}
            checks = 0
            for score, bi, beam, c, site in expanded:
                if len(nxt) >= self.width or checks >= ACCEPT_CHECKS * self.width:
                    break
                if c is None:
                    key = ("keep", id(beam.build), len(beam.used), beam.idle)
                    if key in seen:
                        continue
                    seen.add(key)
                    nxt.append(beam)
                    continue
                key = (id(beam), tuple(np.round(c.pose.position, 3)))
                if key in seen:
                    continue
                seen.add(key)
                if self.accept is not None:
                    checks += 1
                    rested = self.accept(problem, beam.build, c)
                    if rested is None:
                        if site is not None:
                            counts = refused.setdefault(bi, {})
                            counts[site] = counts.get(site, 0) + 1
                        continue
                    c = rested
                b = beam.build.copy()
                b.place(c)
                used = beam.used | ({site} if site is not None else set())
                nxt.append(_Beam(b, score, used, len(b) >= problem.required, 0,
                                 _count(beam, refused.get(bi, {}), 1 + self.jitter)[1]))
            # A beam whose candidates did not come to rest goes on, with those sites counted (and
            # retired once offered as drawn and jittered), so that it moves on along the pattern.
            for bi, counts in sorted(refused.items()):
                if len(nxt) >= self.width:
                    break
                beam = beams[bi]
                dead, tries = _count(beam, counts, 1 + self.jitter)
                nxt.append(_Beam(beam.build, beam.score, beam.used | dead, beam.done, beam.idle, tries))
            if not nxt:
                break  # nothing was kept and nothing was refused: no beam can go on
            beams = nxt
            lead = max(beams, key=lambda b: (len(b.build), b.score))
            problem.tell(self.name, lead.build, f"{len(lead.build)} placed")
        final = max(beams, key=lambda b: (len(b.build), b.build.inside_volume))
        return final.build, tried


def _count(beam: _Beam, refused: dict[int, int], limit: int) -> tuple[frozenset[int], tuple]:
    """Add ``refused`` to a beam's tries: the sites now tried ``limit`` times, and the new tries."""
    tries = dict(beam.tries)
    for site, n in refused.items():
        tries[site] = tries.get(site, 0) + n
    dead = frozenset(s for s, n in tries.items() if n >= limit)
    return dead, tuple(sorted((s, n) for s, n in tries.items() if s not in dead))
