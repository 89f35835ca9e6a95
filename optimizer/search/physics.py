"""Physics in the loop, modelling no more than is needed.

* During the main search, a block lowered onto the foundation, flat or
  rough, is kept as lowered: on a flat one it stands on one of its rest
  poses; on rubble it touches a bump or two and would rock a little before it
  rests, and the whole settle below judges that, with its neighbours in place.
  A block that comes down on other blocks first touches at one point and may
  tip, slide or rock before it rests, as a block does when the crane lets it
  go. So each such candidate is let go (:func:`settle_in`): settled on its
  own, its neighbours held fixed as static bodies (``movable={new}``). If it
  stays where it was lowered, it is kept there; if it moves, it is kept where
  it comes to rest, provided it rests there whole, inside the tolerance zone
  and pressing into no block. This costs 5-30 ms a candidate.
* The final layout is settled (``settle.settle``, MuJoCo for 3D scenes). If
  some blocks move or turn too far, they are taken out together with every
  block resting on them, and placed again by the beam search.
* While repairing, every candidate is let go, on the ground or not.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Collection
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from geometry.blocks import Block
from geometry.clip import volume_inside
from geometry.collision import collisions
from geometry.constants import tol
from geometry.polytope import ConvexPolytope
from geometry.pose import Pose
from geometry.scene import Scene
from settle import SettleResult, Stopped, Thresholds, settle

from .beam import BeamSearch
from .build import GROUND, Build, Candidate
from .drop import Shape
from .problem import Phase, Problem

#: How far around a block let go its neighbours are taken in, held fixed, in bounding radii.
LET_GO_REACH = 2.5
#: Simulated seconds a candidate is let go for (it stops early once at rest).
LOCAL_SECONDS = 2.0
#: A candidate that moves less than this when let go stays where it was
#: lowered. The neighbours are held still, so the check cannot see them shift
#: under the new block; it asks for half the final verdict's movement.
LOCAL_THRESHOLDS = Thresholds(displacement_fraction=0.025, rotation_deg=2.5)
#: Repair rounds before the verdict is taken as it is.
ROUNDS = 3
#: The seed of the settle that ``shoha settle`` and ``shoha score`` run by default. A layout
#: the confirmation calls stable has stood from its own random kick and from this one, so a
#: user's own check of it says the same.
VERDICT_SEED = 0
#: Seconds past its end a confirmation's settle may run before it is stopped: the final checks
#: have their own reserve after the end, and the time limit 2 s of grace.
SETTLE_GRACE = 1.0
#: How far (m) past the zone's face a block is set back inside it by :func:`within`.
NUDGE_SLACK = 1e-6


def raised_check(problem: Problem, build: Build, candidate: Candidate) -> Candidate | None:
    """:func:`settle_in` for candidates that rest on other blocks; one on the foundation
    alone, flat or rough, is kept as lowered.

    On rubble, a ground block was first seated (let go alone, then lowered
    again on its site turned as it came to rest) and then let go among its
    neighbours. Turned onto the bumps, it left the pattern's next layer no
    room: on ``mini-rough`` seeds 1-3 the first beam placed 67, 70 and 67
    of 75 in 51-56 s, and two in three of the blocks let go on top of others did not
    come to rest (976 of 1477 on seed 1). Kept as lowered, the same beam placed
    75 in 35-37 s, with a third not coming to rest (566 of 1599), and each
    layout stood once settled whole (a block or none laid again). On
    ``tetrapod-big`` seed 1: 65 of 75 against 61; on ``wall-shake`` over
    ``mini-rough``'s rubble: 58 of 72 against 52 (docs/coverage-study.md).
    """
    if candidate.support == (GROUND,) and not candidate.loose:
        return candidate
    return settle_in(problem, build, candidate)


def settle_in(problem: Problem, build: Build, candidate: Candidate) -> Candidate | None:
    """The candidate where it comes to rest when let go among fixed neighbours, or None.

    Returns the candidate itself if it stays within :data:`LOCAL_THRESHOLDS`
    of where it was lowered (and is not ``loose``: where it was lowered is
    out of the zone); otherwise the block at rest where it ends, if it
    comes to rest within :data:`LOCAL_SECONDS`, whole inside the tolerance
    zone (set back inside where it rests a hair into a wall: :func:`within`),
    pressing no block deeper than ``tol.contact_depth``, and resting on
    something; otherwise None.
    """
    key = -2  # not a key any build uses
    block = build.block
    near = build.collide.neighbours(candidate.pose.position, LET_GO_REACH * block.bounding_radius)
    placed = [(k, block, build.poses[k]) for k in near] + [(key, block, candidate.pose)]
    result = let_go(problem.scene, placed, key)
    if result is None:
        return None
    if result.stable:
        return None if candidate.loose else candidate
    if not result.at_rest:
        return None
    pose = within(build.zone, block, result.poses[key])
    world = pose.apply(block.vertices)
    if not build.zone.contains(world).all():
        return None
    if build.collide.query(block, pose, threshold=tol.contact_depth, first=True):
        return None
    touching = sorted(k for k, _ in build.collide.query(block, pose, threshold=-1.0))
    clearance = world[:, 2] - problem.scene.foundation.height_at(world[:, :2])
    support = tuple(touching) + ((GROUND,) if clearance.min() <= tol.contact_gap else ())
    if not support:
        return None
    return Candidate(Shape.of(block, pose.quaternion), pose, support,
                     volume_inside(block, pose, problem.scene.design.polytope))


def let_go(scene: Scene, placed: list, key: int) -> SettleResult | None:
    """The short settle of block ``key`` let go among fixed ``placed`` (judged by
    :data:`LOCAL_THRESHOLDS`); None where the engine diverged (the candidate is refused, as one
    that does not come to rest is). The live service's hints are let go the same way."""
    result = settle(scene, placed, seconds=LOCAL_SECONDS, seed=0, movable={key},
                    thresholds=LOCAL_THRESHOLDS)
    return None if result.diverged else result


def held_up(problem: Problem, build: Build, candidate: Candidate, gone: Collection[int] = ()) -> bool:
    """Whether a candidate at rest (:func:`settle_in`) stays so when the blocks it rests on are
    let go with it: the candidate and its supports (never kept ones) free, the blocks around
    them held fixed, judged by the whole settle's thresholds.

    :func:`settle_in` holds every neighbour still, so it cannot see a support tip under the new
    block. The repairs' moves are all lost when the settle that confirms them fails, and on
    ``mini`` seed 4 (the attempt with rows) four covering moves that met both coverage aims
    fell so: the last block moved rested on one that tipped 12 degrees under it, and it slid
    1.5 m down the slope. Let go with its supports it fell the same way, in 0.04 s of
    settling; the other two blocks moved did not (2026-12-07, stop 75). A candidate on the
    foundation alone is held up. Kept blocks are let go as the whole settle lets them go
    (:func:`judged`: not those inside another). ``gone``: blocks the move takes out, left out
    of the check. The blocks resting on a support are held fixed, so they neither load it nor
    let it go: the check is cheap, not whole.
    """
    held = set(gone)
    supports = {k for k in candidate.support if k != GROUND and k not in held and not kept_inside(build, k)}
    if not supports:
        return True
    key = -2  # not a key any build uses
    block = build.block
    reach = LET_GO_REACH * block.bounding_radius
    around = set(build.collide.neighbours(candidate.pose.position, reach, exclude=held))
    for k in supports:
        around.update(build.collide.neighbours(build.poses[k].position, reach, exclude=held))
    placed = [(k, block, build.poses[k]) for k in sorted(around)] + [(key, block, candidate.pose)]
    result = settle(problem.scene, placed, seconds=LOCAL_SECONDS, seed=0, movable={key, *supports})
    return bool(result.stable) and not result.diverged


def local_check(problem: Problem, build: Build, candidate: Candidate) -> Candidate | None:
    """:func:`settle_in` for any candidate, on the ground or not (the repair's check)."""
    return settle_in(problem, build, candidate)


def settling_by(problem: Problem, end: float) -> Problem:
    """``problem`` with its whole-layout settles stopped ``SETTLE_GRACE`` past ``end``
    (:class:`settle.Stopped`, which the caller catches)."""
    return replace(problem, settle_until=end + SETTLE_GRACE)


def stands(problem: Problem, build: Build) -> bool:
    """Whether a whole build passes the settle verdict (used to rank beam restarts); False if the
    settle runs ``SETTLE_GRACE`` past the search's deadline (117 kept rods: 5.8 s of a 2 s limit)."""
    try:
        return bool(whole_settle(settling_by(problem, problem.deadline), build.placed(), seed=0).stable)
    except Stopped:
        return False


def whole_settle(problem: Problem, placed: list, **options) -> SettleResult:
    """``settle`` of a whole layout, timed on the problem's clock into ``problem.meter``: what
    the settles that confirm a layout cost on this machine now."""
    t0 = problem.now()
    try:
        return _settled_by(problem, placed, **options)
    finally:
        # A stopped settle's time too, as the least it costs: the estimates then see how slow it is.
        problem.meter.record(len(placed), problem.now() - t0, problem.required)


def _settled_by(problem: Problem, placed: list, called_off: Callable[[], bool] | None = None,
                **options) -> SettleResult:
    """``settle`` of a whole layout, stopped at ``problem.settle_until`` or once ``called_off``
    says so (:class:`settle.Stopped` either way); not timed."""
    until = problem.settle_until
    if until is None and called_off is None:
        stop = None
    else:
        def stop() -> bool:
            return (until is not None and problem.now() > until) or (called_off is not None and called_off())
    return settle(problem.scene, placed, stop=stop, **options)


def carried_closure(build: Build, keys: set[int]) -> set[int]:
    """``keys`` and every block resting on them, directly or not."""
    out = set(keys)
    stack = list(keys)
    while stack:
        for k in build.carried[stack.pop()]:
            if k not in out:
                out.add(k)
                stack.append(k)
    return out


@dataclass(frozen=True)
class Confirmation:
    """The settle that confirms a layout, after any repairs.

    Attributes
    ----------
    stable : bool
        The last settle's verdict on the build returned.
    max_displacement_m, max_rotation_deg : float
        Of that settle.
    unstable : list of int
        Crane-order indices of the blocks that failed it (empty when stable).
    adopted : int
        Times the layout was taken where a settle left it: where a failed
        settle left it (before any repair of that round), and where the last
        one left it once it stands.
    rounds : int
        Repair rounds run.
    repaired : int
        Blocks taken out over those rounds (each with what rested on it).
    seconds : float
    relay_seconds : float
        Of ``seconds``, the time spent laying again the sites of blocks a settle left
        out of the zone (not in :meth:`to_dict`): a confirmation lays them again only
        where its time allows, so the refill need not keep that time free for the next.
    stopped : bool
        A settle ran ``SETTLE_GRACE`` past the confirmation's end and was stopped
        (:func:`confirm`): the build is as it was given, and nothing is known of it (not in
        :meth:`to_dict`).
    """

    stable: bool
    max_displacement_m: float
    max_rotation_deg: float
    unstable: list[int]
    adopted: int
    rounds: int
    repaired: int
    seconds: float
    relay_seconds: float = 0.0
    stopped: bool = False

    def to_dict(self) -> dict:
        return {"stable": self.stable, "max_displacement_m": self.max_displacement_m,
                "max_rotation_deg": self.max_rotation_deg, "unstable": list(self.unstable),
                "adopted": self.adopted, "rounds": self.rounds, "repaired": self.repaired,
                "seconds": self.seconds}


def verdict(problem: Problem, placed: list, rng: np.random.Generator,
            movable: list[int] | None = None, side_by_side: bool | None = None) -> SettleResult:
    """A settle from a random kick; if that stands, the settle from ``VERDICT_SEED``'s kick too.

    Its result is the first that fails, or the random kick's when both stand
    (the poses a layout is adopted at). A layout on the edge of standing can
    pass one kick and fail another: only one that passes both is called
    stable.

    Where a core is idle (:func:`_spare_core`, or where ``side_by_side`` says so), the two
    settles run side by side (:func:`_side_by_side`); the answer is the same as one
    after the other. The verdict is timed into ``problem.meter`` as its settles, each
    at its share of the verdict's time.
    """
    seed = int(rng.integers(2**31))
    t0 = problem.now()
    ran = 2  # the settles the verdict's time is shared among (two side by side, called off or not)
    try:
        if side_by_side if side_by_side is not None else _spare_core():
            return _side_by_side(problem, placed, seed, movable)
        ran = 1
        result = _settled_by(problem, placed, seed=seed, movable=movable)
        if not _needs_second(result):
            return result
        ran = 2
        return _answer(result, _settled_by(problem, placed, seed=VERDICT_SEED, movable=movable))
    finally:
        # A stopped verdict's time too, as the least it costs (as ``whole_settle``).
        problem.meter.record(len(placed), (problem.now() - t0) / ran, problem.required, verdict=True)


def _spare_core() -> bool:
    """Whether a core is idle for a verdict's second settle: this process may run on two or
    more, and fewer threads than that are running on the machine now, this one among them
    (``/proc/loadavg``'s count of running threads, the least of three looks; elsewhere, the
    1-minute load average under the cores less half).

    Where every core is busy, the second settle only takes its core from other work: in
    ``generality.py``'s two runs at once on 2 cores, each verdict's second thread slowed the
    other run's search, and ``big-shake`` seeds 1 and 2 came out 263 and 229 of 269 (2026-12-07).
    The 1-minute average alone is too slow for that: a minute after both runs begin it is still
    under 1.5.
    """
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    if cores < 2:
        return False
    running = _running_threads()
    if running is not None:
        return running < cores
    try:
        return os.getloadavg()[0] < cores - 0.5
    except OSError:  # no load average on this platform
        return True


def _running_threads(looks: int = 3) -> int | None:
    """The threads running on the machine now, the least of ``looks`` reads of /proc/loadavg
    (a shell started for an instant is not a busy core); None where there is no such file."""
    try:
        counts = [int(Path("/proc/loadavg").read_text().split()[3].split("/")[0]) for _ in range(looks)]
    except (OSError, IndexError, ValueError):
        return None
    return min(counts)


def _side_by_side(problem: Problem, placed: list, seed: int, movable: list[int] | None) -> SettleResult:
    """:func:`verdict`'s two settles at once: the ``VERDICT_SEED`` kick in a worker thread while
    the random kick runs here. MuJoCo lets go of Python's lock while it steps, so on two free
    cores a verdict takes about one settle's time, not two: on ``big-shake``'s 266 blocks, 9.8 s
    against 22.5 s in turn (2026-12-07). Where the random kick fails, the other is called off:
    its answer is not needed. Either way the verdict took what a whole one takes side by side,
    and :func:`verdict` counts two settles for it: a failed kick's 14.5 s, counted as one settle, had
    the next verdict estimated at 29 s, and kept the covering moves on ``big-shake`` from the
    40 s the run had left.
    """
    first_failed = threading.Event()
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="shoha-verdict") as pool:
        second = pool.submit(_settled_by, problem, placed, called_off=first_failed.is_set,
                             seed=VERDICT_SEED, movable=movable)
        try:
            result = _settled_by(problem, placed, seed=seed, movable=movable)
        except BaseException:
            first_failed.set()
            second.exception()  # ended, whatever it raised
            raise
        if not _needs_second(result):
            first_failed.set()
            second.exception()
            return result
        again = second.result()
    return _answer(result, again)


def _needs_second(result: SettleResult) -> bool:
    """Whether the random kick's settle leaves the verdict to the second: it stood, or the
    engine diverged (another kick may let it answer)."""
    return bool(result.stable or result.diverged)


def _answer(result: SettleResult, again: SettleResult) -> SettleResult:
    """The verdict of the two kicks, the second run because the first stood or diverged: the
    second's where it fails or the first diverged, else the first's (the poses adopted)."""
    return again if not again.stable or result.diverged else result


def judged(build: Build) -> list[int] | None:
    """The blocks a settle of ``build`` lets move (``settle``'s ``movable``; None: every one).

    Kept blocks one inside another are held: they stay and are reported as
    colliding, whatever a settle says, and letting them go costs what their
    overlaps cost the engine. 84 kept copies of one block at one pose took a
    settle of 1.8-3.8 s, and ``--time-limit 2`` ran to 5.9 s; held, 0.01 s.
    """
    held = {k for k in build.kept if kept_inside(build, k)}
    return [k for k in build.order if k not in held] if held else None


def kept_inside(build: Build, key: int) -> bool:
    """Whether block ``key`` is a kept one inside another: held where it is by every settle."""
    return key in build.kept and bool(
        build.collide.query(build.block, build.poses[key], exclude=(key,), first=True))


def settled_layout(problem: Problem, build: Build, result: SettleResult, rng: np.random.Generator
                   ) -> tuple[Build, SettleResult]:
    """The build where a settle left it, less the blocks that ended invalid; and its own settle.

    Kept blocks are held where they are (a settle that moved them is run again
    with them fixed). A block the settle left pressed into the zone's face by
    no more than the contact tolerance is set back inside it (:func:`within`).
    A block that ended out of the tolerance zone, or pressed into a neighbour
    deeper than the contact tolerance, is taken out with what rests on it.
    """
    free = [k for k in build.order if k not in build.kept]
    if build.kept:
        result = whole_settle(problem, build.placed(), seed=int(rng.integers(2**31)), movable=free)
    poses = {k: within(build.zone, build.block, pose) if k not in build.kept else pose
             for k, pose in result.poses.items()}
    after = build.settled(poses)
    bad = {k for k in after.order if k not in after.kept
           and not after.zone.contains(after.poses[k].apply(after.block.vertices)).all()}
    bad |= {k for c in collisions(after.placed()) for k in (c.a, c.b) if k not in after.kept}
    for k in sorted(carried_closure(after, bad) - set(after.kept), key=after.order.index, reverse=True):
        after.remove(k)
    return after, verdict(problem, after.placed(), rng, movable=judged(after))


def within(zone: ConvexPolytope, block: Block, pose: Pose) -> Pose:
    """``pose`` moved back inside ``zone`` where a settle left the block out of it by no more than
    the contact tolerance (``tol.contact_depth``); else as it is.

    A block settled against a wall, or onto the zone's face, presses into it as into any body
    the engine's soft contacts hold it against (0.02-0.15 mm on ``tetra-wall-steep``): out of
    the zone by that much, it was taken out with every block resting on it. Each face it is
    out of pushes it back along the face's inward normal, twice over for a corner; if it is
    still out then, it is left where it was.
    """
    moved = pose
    for _ in range(2):
        worst = (moved.apply(block.vertices) @ zone.normals.T - zone.offsets).max(axis=0)
        out = worst > tol.distance  # as ``ConvexPolytope.contains`` has it
        if not out.any():
            return moved
        if worst.max() > tol.contact_depth:
            break
        shift = -(zone.normals[out] * (worst[out] + NUDGE_SLACK)[:, None]).sum(axis=0)
        moved = Pose(moved.position + shift, moved.quaternion)
    return pose


def _repaired(problem: Problem, build: Build, origin: tuple[float, float] | None, deadline: float,
              rng: np.random.Generator) -> Build:
    """``build`` with the pattern's free sites laid again by a narrow beam under the local check,
    until ``deadline`` (a ``problem.now()`` value) at the latest. The repair plans its work from
    the time it has (no ``span``), not from the whole run's."""
    beam = BeamSearch(width=2, accept=local_check, origin=origin, restarts=1, share=0.5)
    return beam.run(replace(problem, deadline=deadline, span=None), Phase(build, origin=origin), rng).build


def _adoption_fits(left: float, cost: float) -> bool:
    """Whether the layout a failed settle left may be taken and judged: ``left`` seconds hold
    its verdict, one more of what is left should that fail too (``cost``, a settle, each) and a
    second of slack, as a repair round needs. (Until stop 80 it needed three verdicts, more than
    a repair: with less, the failed blocks were taken out with every block resting on them, and
    on ``big-shake`` seed 2, run beside another, 41 and 69 of 269 went where the layout taken as
    settled stood with 267, as it did when the run was alone.)"""
    return left > 2 * cost + 1.0


def _repair_fits(rounds: int, left: float, cost: float) -> bool:
    """Whether one more repair round fits: rounds are left, and ``left`` seconds hold the
    repair, a verdict of its result (``cost``, a settle, each) and a second of slack."""
    return rounds < ROUNDS and left > 2 * cost + 1.0


def confirm(problem: Problem, build: Build, rng: np.random.Generator,
            origin: tuple[float, float] | None = None, end: float | None = None,
            whole: bool = False) -> tuple[Build, Confirmation]:
    """:func:`_confirm`, its settles stopped ``SETTLE_GRACE`` past ``end`` (else the deadline).

    The rounds time their settles and plan by them, but a layout's first settle has no
    measure to go by: 117 kept rods 4 m long took 7.6 s for 50 steps, and a 2 s limit ran to
    9.2 s. A settle so stopped leaves the last layout that stood, if one did (a stopped
    adoption or repair round does not undo a verdict already given); else ``build`` as it was
    given, unconfirmed: its Confirmation has ``stopped`` set (and is not stable).
    """
    start = problem.now()
    limit = end if end is not None else problem.deadline
    stood: list[tuple[Build, SettleResult]] = []  # the last layout that stood, as _confirm goes
    try:
        return _confirm(settling_by(problem, limit), build, rng, origin, end, whole, stood)
    except Stopped:
        if stood:
            last, result = stood[-1]
            return last, Confirmation(True, result.max_displacement_m, result.max_rotation_deg, [], 0, 0, 0,
                                      problem.now() - start)
        return build, Confirmation(False, 0.0, 0.0, [], 0, 0, 0, problem.now() - start, stopped=True)


def _confirm(problem: Problem, build: Build, rng: np.random.Generator,
             origin: tuple[float, float] | None, end: float | None,
             whole: bool, stood: list[tuple[Build, SettleResult]]) -> tuple[Build, Confirmation]:
    """Settle a build; repair and settle again while blocks fail.

    A layout that stands is returned where the settle left it, if that is
    valid and stands too (the blocks rest on what carries them, not at the
    first contact of their drop). A failed settle is first taken at its
    word: the layout where it left the blocks (:func:`settled_layout`),
    settled again. If that fails too,
    the round takes the failed blocks out, with every block resting on
    them. If a repair and one more settle fit before ``end`` (a
    ``problem.now()`` value; a repair gets at most half the time left
    after reserving one settle), the beam search places blocks again under
    the local check; otherwise the layout stays short of them. The rounds
    end when the settle verdict is stable, so what is returned stands, even
    if it is smaller (a settled empty layout is trivially stable), with two
    exceptions, where the verdict says it fails: the build has kept blocks
    (``Build.keep``) that fail (they stay, and the caller reports them); or
    not even one more verdict on what is left fits before ``end``. The time
    limit is a promise: a settle past ``end`` once took ``full`` 7 s past its
    limit (30 s with a second run beside it).

    With ``whole`` (a caller that keeps the layout only if it stands with
    every block), a failed settle with no time left for a repair ends the
    rounds there too, even if a settle of what is left would fit. And where
    the layout as a failed settle left it stands only without blocks that
    ended out of the zone or in a neighbour, their sites are laid again in
    the same way, as a round, and it is kept with them only if it then
    stands with more. On ``wall-shake``'s attempt with toe rows (seed 1) the
    settle so left 2 of 72 out on 6 of 16 random streams, and the attempt
    was given up; laid again, all 16 stood with 72. Not for other callers:
    the pocket fill goes on from their layouts, and on ``mini-rough`` (seed
    3) the 7 s a fruitless laying again took left no time for the refill
    that reached the count.

    Each layout that stands is appended to ``stood`` as the rounds go: :func:`confirm`
    returns the last of them where a settle after it is stopped.

    Returns the build and its :class:`Confirmation`.
    """
    start = problem.now()
    limit = end if end is not None else problem.deadline
    repaired = rounds = adopted = 0
    relay_seconds = 0.0
    # A smaller layout that stood, kept while its lost blocks' sites are laid again.
    fallback: tuple[Build, SettleResult] | None = None
    while True:
        t = problem.now()
        result = verdict(problem, build.placed(), rng, movable=judged(build))
        cost = problem.now() - t
        if not len(build):
            break
        if result.stable:
            stood.append((build, result))  # what confirm keeps if a settle after this is stopped
            # A layout that stands is written where it stands: each block settled onto what
            # carries it, touching it, rather than at its first contact on the way down
            # (the interlock count sees the difference). Only if that is valid and stands.
            left = limit - problem.now()
            if left > 2 * cost:
                after, again = settled_layout(problem, build, result, rng)
                if len(after) == len(build) and again.stable:
                    build, result = after, again
                    adopted += 1
            break
        # Kept blocks (a partial layout's) are never taken out: if only they fail, the
        # verdict stands as it is and the caller reports them. Where the engine diverged it
        # named no block: the layout stays whole, and is not confirmed.
        failed = carried_closure(build, set(result.unstable_ids)) - set(build.kept)
        if not failed or result.diverged:
            break
        left = limit - problem.now() - cost
        if adopted < ROUNDS and _adoption_fits(left, cost):
            # First the layout where the settle left it: blocks that crept or slid have come
            # to rest, and the layout often stands so, with every block in it.
            adopted += 1
            before = len(build)
            build, result = settled_layout(problem, build, result, rng)
            if result.stable:
                left = limit - problem.now() - cost
                if not whole or len(build) == before or not _repair_fits(rounds, left, cost):
                    break
                # Kept only whole, it stands without the blocks that ended out of the zone: their
                # sites are laid again, and the layout kept as it is unless that stands with more.
                if fallback is None or len(build) > len(fallback[0]):
                    fallback = (build, result)  # the largest that stood
                    stood.append(fallback)
                rounds += 1
                t = problem.now()
                build = _repaired(problem, build, origin, limit - cost, rng)
                relay_seconds += problem.now() - t
                continue
            failed = carried_closure(build, set(result.unstable_ids)) - set(build.kept)
            if not failed:
                break
        left = limit - problem.now() - cost
        repair = _repair_fits(rounds, left, cost)
        if not repair and (whole or left < cost):
            # No repair fits. A layout kept only whole is not kept smaller, and with no time for
            # one more verdict (two settles where what is left stands, as the verdict of a layout
            # that stood is: ``cost`` was one) what is left cannot be confirmed: the rounds end
            # with the failed verdict, within the time.
            break
        rounds += 1
        smaller = build.copy()
        for k in sorted(failed, key=build.order.index, reverse=True):
            smaller.remove(k)
        repaired += len(failed)
        # The repair must leave room for a settle: it is asked with a deadline of its own.
        # Out of rounds, or with no time for a repair, what is left is settled.
        build = _repaired(problem, smaller, origin, limit - cost, rng) if repair else smaller
    if fallback is not None and (not result.stable or len(build) <= len(fallback[0])):
        build, result = fallback
    rank = {k: i for i, k in enumerate(build.order)}
    return build, Confirmation(
        adopted=adopted,
        stable=bool(result.stable),
        max_displacement_m=result.max_displacement_m,
        max_rotation_deg=result.max_rotation_deg,
        unstable=sorted(rank[k] for k in result.unstable_ids if k in rank),
        rounds=rounds,
        repaired=repaired,
        seconds=problem.now() - start,
        relay_seconds=relay_seconds,
    )
