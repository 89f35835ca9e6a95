"""Toe rows: a row of blocks laid first along each toe, where later blocks cannot reach.

A mound whose count fills it to the crest leaves its toes bare: the pattern's
outermost blocks stand a cell's width in from the design toe line, and a block
lowered there later lands on the slope blocks, out of the zone
(docs/coverage-study.md). Rows along the toes have to be laid first. ``optimize``
lays them in one more attempt when the layout it would keep reaches the count
and the porosity but leaves the mound uncovered, and keeps that attempt only if
it reaches them too and covers better (``optimizer.api.covered_attempt``).

For each toe (the seaward one only behind a wall):

1. at mid-length, each hanging of the block at ``yaws`` yaws over its
   symmetry's period is lowered as far out towards the toe as it rests
   inside the zone (bisection, to ``RESOLUTION`` of H);
2. the hanging kept is the one whose block covers the most of the toe's strip,
   the slope from the toe line up to H / 2 along it, over one block's width of
   row and its gap (:func:`strip_covered`), of those that hold at least
   ``1 - INSIDE_SLACK`` of the most any holds inside the design prism (the
   most inside where they cover as much); if none of those covers any of it,
   the nearest to the toe line of all the hangings (as before). The strip a
   block covers changes sharply with its yaw (on ``mini`` a crown hanging
   covers 82 % at 0 degrees and 74 % at 2.5), so the yaws are ``yaws`` a
   period, and around the ``REFINED`` best of them ``REFINE_STEPS - 1`` more on
   each side, short of the next (each yaw is lowered at once). (Until 2026-12-07 the
   hanging was the one with the most inside of those within H / 2 of the toe
   line at the block's middle, at 12 yaws: on ``mini`` a crown turned 100
   degrees that covers 69 % of the strip. The rows then left the strip between
   their blocks bare, 3 % of the mound's surface: docs/coverage-study.md, stop 71);
3. the row is laid from one end of the zone to the other: past each block,
   the next is lowered every ``ROW_STEP`` of H along the row over half a
   block, each as far out as it rests on the ground inside the zone, and the
   outermost is laid. (Until 2026-11-26 the first place on the ground was
   laid: beside the block before it lands further in, where it clears that
   block, and the rows of ``mini`` stood 0.3-0.4 m in from the outer line,
   beyond H/2 of the toe line.)

The steps are shares of the block height. ``INSIDE_SLACK`` was set on ``mini`` alone
(docs/coverage-study.md, stop 71, gives what the choice is without it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from geometry.coverage import BARE_FRACTION, distance_to_block

from .build import GROUND, Build, Candidate, search_window
from .drop import Shape
from .hangings import spread_yaws, symmetry
from .problem import Phase, Problem, Stats, Strategy
from .shapes import ShapeCache

if TYPE_CHECKING:
    from geometry.pose import Pose
    from geometry.scene import Scene

#: The rows' hanging is chosen among those whose block holds inside the design prism no less
#: than this share below the most any hanging holds. On ``mini`` the horizontal hanging covers
#: as much of the toe's strip as the crown (82 %) with 15 % less of the block inside, and rows
#: in it cost the count (docs/coverage-study.md, stop 36); the crown that covers most holds
#: 1 % less than the crown that holds most. Set on ``mini`` alone.
INSIDE_SLACK = 0.05
#: How many of the first pass's best (ranked as the choice ranks them) are looked at more
#: finely, and in how many steps on each side, up to the first pass's next yaw.
REFINED = 4
REFINE_STEPS = 6
#: Points across the row (one block's width and a gap) and up the strip at which it is sampled.
STRIP_ALONG = 41
STRIP_UP = 4
#: How finely the outermost place is found, as a share of the block height.
RESOLUTION = 0.01
#: Steps along the row from one block to the next, as a share of the block height.
ROW_STEP = 0.03
#: Places the row is laid from, evenly from the zone's start to where the first block's end is
#: ``START_PAST`` of its width past the design prism's end, inwards: the best row is kept.
STARTS = 4
START_PAST = 0.1


@dataclass(frozen=True)
class ToeStats(Stats):
    """Figures of the toe rows.

    Attributes
    ----------
    placed : int
        Blocks laid in the rows.
    hangings : tuple of str
        The hanging and yaw (degrees) of each side's row.
    reach_m : tuple of float
        How near each row's block at mid-length comes to the design toe line.
    strip_covered : tuple of float
        The share of the toe's strip that block covers (:func:`strip_covered`).
    """

    placed: int = 0
    hangings: tuple[str, ...] = ()
    reach_m: tuple[float, ...] = ()
    strip_covered: tuple[float, ...] = ()


class ToeRows(Strategy):
    """Lay a row of blocks along each toe (the seaward one only behind a wall).

    Parameters
    ----------
    yaws : int
        Yaws tried per hanging, over one period of its symmetry, before the finer look
        around the best (``REFINED``).
    """

    name = "toe"

    def __init__(self, yaws: int = 24):
        self.yaws = yaws

    def run(self, problem: Problem, previous: Phase | None, rng: np.random.Generator) -> Phase:
        build = previous.build.copy() if previous is not None else Build(problem.scene)
        origin = previous.origin if previous is not None else None
        shapes = ShapeCache(problem.scene.block)
        design = problem.scene.design
        sides = (1.0,) if design.wall_x is not None else (1.0, -1.0)
        placed, names, reach, strip = 0, [], [], []
        for side in sides:
            if problem.time_left() <= 0:
                break
            chosen = self._hanging(problem, build, shapes, side)
            if chosen is None:
                continue
            fam, yaw, dist, cover = chosen
            names.append(f"{fam} {np.degrees(yaw):.0f}")
            reach.append(dist)
            strip.append(cover)
            build, laid = self._best_row(problem, build, shapes, side, fam, yaw)
            placed += laid
            for key in build.order[len(build.order) - laid:]:  # the row, last in crane order
                # What the block covers where it was laid: the annealing keeps it so (holds_toe).
                pose = build.poses[key]
                points = strip_points(problem.scene, build.shapes[key], float(pose.position[1]), side)
                build.toe_rows[key] = (points, strip_share(problem.scene, points, pose))
        return Phase(build, ToeStats(placed, tuple(names), tuple(reach), tuple(strip)), origin)

    # --- which hanging ---------------------------------------------------------------

    def _hanging(self, problem: Problem, build: Build, shapes: ShapeCache,
                 side: float) -> tuple[str, float, float, float] | None:
        """The (hanging, yaw, distance to the toe line, share of the toe's strip covered) a row
        should be laid in, or None if none fits."""
        scene = problem.scene
        block, design = scene.block, scene.design
        y = 0.5 * (design.y_start + design.y_end)
        toe = np.array([[side * design.bottom_half_width, y, design.z_bottom]])

        def measured(fam: str, yaw: float) -> tuple[float, float, float, str, float] | None:
            shape = shapes.hung(fam, yaw)
            c = outermost(problem, build, shape, side, y)
            if c is None:
                return None
            dist = float(distance_to_block(toe, block, c.pose)[0])
            return strip_covered(scene, shape, c, side), c.inside, dist, fam, yaw

        seen: dict[tuple[str, float], tuple[float, float, float, str, float] | None] = {}

        def tried(fam: str, yaw: float) -> tuple[float, float, float, str, float] | None:
            # Two neighbouring yaws among the best look at the same yaws between them.
            key = (fam, round(yaw, 9))
            if key not in seen:
                seen[key] = measured(fam, yaw)
            return seen[key]

        found = []
        for fam, yaw in spread_yaws(block, problem.families, self.yaws):
            if problem.time_left() <= 0:
                break
            found.append(tried(fam, yaw))
        found = [f for f in found if f is not None]
        if not found:
            return None
        for _, _, _, fam, yaw in sorted(_fit(found), key=_covering, reverse=True)[:REFINED]:
            period = 2 * np.pi / symmetry(block, fam)
            step = period / self.yaws / REFINE_STEPS
            for k in (*range(-REFINE_STEPS + 1, 0), *range(1, REFINE_STEPS)):
                if problem.time_left() <= 0:
                    break
                found.append(tried(fam, (yaw + k * step) % period))
        found = [f for f in found if f is not None]
        cover, _, dist, fam, yaw = max(_fit(found), key=_covering)
        if cover <= 0.0:
            cover, _, dist, fam, yaw = min(found, key=lambda f: f[2])  # none covers it: the nearest of all
        return fam, yaw, dist, cover

    # --- the row ---------------------------------------------------------------------------

    def _best_row(self, problem: Problem, build: Build, shapes: ShapeCache, side: float, fam: str,
                  yaw: float) -> tuple[Build, int]:
        """The row laid from each of ``STARTS`` places at the mound's start, on copies of ``build``:
        the one with the most blocks, then the least volume outside the design prism. Returns
        the build with it, and how many blocks it has."""
        scene = problem.scene
        shape = shapes.hung(fam, yaw)
        width = _row_width(shape)
        first = search_window(scene)[1][0]
        flush = max(first, scene.design.y_start + (0.5 + START_PAST) * width)
        best = None
        for start in np.linspace(first, flush, STARTS):
            if best is not None and problem.time_left() <= 0:
                break
            trial = build.copy()
            laid = self._row(problem, trial, shape, width, side, float(start))
            outside = laid * scene.block.volume - (trial.inside_volume - build.inside_volume)
            if best is None or (-laid, outside) < best[0]:
                best = ((-laid, outside), trial, laid)
        return best[1], best[2]

    def _row(self, problem: Problem, build: Build, shape: Shape, width: float, side: float,
             y: float) -> int:
        """Lay the row from ``y`` to the zone's end; returns how many blocks it placed."""
        y_end = search_window(problem.scene)[1][1]
        h = problem.scene.block.height
        step = ROW_STEP * h
        placed = 0
        while y <= y_end and len(build) < problem.required and problem.time_left() > 0:
            # The outermost place on the ground within half a block along the row: the first
            # place beside the block before is often further in, where it clears that block.
            c = None
            for at in np.arange(y, min(y + 0.5 * width, y_end) + 0.5 * step, step):
                if problem.time_left() <= 0:
                    break
                here = outermost(problem, build, shape, side, float(at))
                if here is not None and GROUND in here.support and (
                        c is None or side * here.pose.position[0] > side * c.pose.position[0] + step):
                    c = here
            # A row block rests on the ground where it touched, as every block on the bare
            # foundation does in the search (``physics.raised_check``), on rubble too: on
            # ``mini-rough`` (seeds 2 and 3) letting row blocks on rubble go instead did not make
            # the attempt with rows stand whole (70 and 74 of 75 stood, against 66 and 69).
            if c is None or GROUND not in c.support:
                y += 0.5 * width if c is None else step
                continue
            build.place(c)
            placed += 1
            problem.tell(self.name, build, f"{len(build)} placed")
            # The next block cannot stand nearer than this one's half width along the row.
            y = float(c.pose.position[1]) + 0.5 * width + ROW_STEP * h
        return placed


def outermost(problem: Problem, build: Build, shape: Shape, side: float, y: float
              ) -> Candidate | None:
    """The block lowered at ``y`` as far out towards the ``side`` toe as it rests inside the zone."""
    h = problem.scene.block.height
    lo, hi = 0.0, search_window(problem.scene)[0][1]
    inner = build.lower(shape, side * lo, y)
    # From the axis outwards, the first place it fits (a mound's core may be taken already).
    step = 0.25 * h
    while inner is None and lo < hi:
        lo += step
        inner = build.lower(shape, side * lo, y)
    if inner is None:
        return None
    # Then bisect between the last place it fits and the zone's edge.
    best = inner
    while hi - lo > RESOLUTION * h:
        mid = 0.5 * (lo + hi)
        c = build.lower(shape, side * mid, y)
        if c is None:
            hi = mid
        else:
            lo, best = mid, c
    return best


def _fit(found: list[tuple[float, float, float, str, float]]) -> list[tuple[float, float, float, str, float]]:
    """The hangings (strip covered, inside, ...) that hold within ``INSIDE_SLACK`` of the most inside."""
    most = max(f[1] for f in found)
    return [f for f in found if f[1] >= (1.0 - INSIDE_SLACK) * most]


def _covering(f: tuple[float, float, float, str, float]) -> tuple[float, float]:
    """A hanging's rank for the rows: the strip it covers, then how much it holds inside."""
    return f[0], f[1]


def _row_width(shape: Shape) -> float:
    """How far a block in ``shape`` reaches along the row (y), metres."""
    return float(shape.xy_boxes[:, 1, 1].max() - shape.xy_boxes[:, 0, 1].min())


def strip_covered(scene: Scene, shape: Shape, candidate: Candidate, side: float) -> float:
    """The share of the toe's strip within H / 2 of ``candidate``: the design slope from the
    ``side`` toe line up to H / 2 along it, ``STRIP_UP`` lines of ``STRIP_ALONG`` points, over
    the block's width along the row and the gap (``ROW_STEP`` of H) a row leaves to the next."""
    points = strip_points(scene, shape, float(candidate.pose.position[1]), side)
    return strip_share(scene, points, candidate.pose)


def strip_points(scene: Scene, shape: Shape, y: float, side: float) -> np.ndarray:
    """The samples of :func:`strip_covered` for a block of ``shape`` at ``y`` along the row."""
    block, design = scene.block, scene.design
    half = BARE_FRACTION * block.height
    across = 0.5 * _row_width(shape) + 0.5 * ROW_STEP * block.height
    ys = np.linspace(y - across, y + across, STRIP_ALONG)
    slope = float(np.hypot(design.bottom_half_width - design.top_half_width, design.height))
    z = design.z_bottom + np.linspace(0.0, min(half, slope), STRIP_UP) * design.height / slope
    x = side * design.half_width(z)
    return np.column_stack([np.repeat(x, STRIP_ALONG), np.tile(ys, STRIP_UP), np.repeat(z, STRIP_ALONG)])


def strip_share(scene: Scene, points: np.ndarray, pose: Pose) -> float:
    """The share of ``points`` within H / 2 of a block at ``pose``."""
    block = scene.block
    return float((distance_to_block(points, block, pose) <= BARE_FRACTION * block.height).mean())
