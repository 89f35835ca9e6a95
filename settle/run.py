"""The physics settle's one entry point, :func:`settle`, and the choice of backend.

>>> settle(scene, placed)                                   # doctest: +SKIP
>>> settle(scene, placed, backend=MujocoBackend(timestep=1e-3))  # doctest: +SKIP

With ``backend=None`` the scene's kind picks it: MuJoCo for ``"3d"`` scenes,
pymunk for ``"section"`` scenes (docs/settle.md). The interface the backends
implement, and the verdict, are in :mod:`settle.base`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Collection, Sequence

import numpy as np

from geometry.blocks import Block
from geometry.errors import InputError
from geometry.pose import Pose, rotation_between
from geometry.scene import Scene

from .base import (
    DEFAULT_SECONDS,
    KICK_SPEED,
    MAX_SECONDS,
    BlockSettle,
    Diverged,
    Progress,
    Run,
    SettleBackend,
    SettleBody,
    SettleResult,
    Thresholds,
)
from .mujoco_backend import MujocoBackend
from .pymunk_backend import PymunkBackend


def default_backend(scene: Scene) -> SettleBackend:
    """The backend a scene's kind calls for: MuJoCo for ``3d``, pymunk for ``section``."""
    return PymunkBackend() if scene.kind == "section" else MujocoBackend()


def settle(
    scene: Scene,
    placed: Sequence[tuple[int, Block, Pose]],
    seconds: float = DEFAULT_SECONDS,
    seed: int | np.random.Generator = 0,
    backend: SettleBackend | None = None,
    movable: Collection[int] | None = None,
    thresholds: Thresholds | None = None,
    early_stop: bool = True,
    progress: Progress | None = None,
    stop: Callable[[], bool] | None = None,
) -> SettleResult:
    """Settle blocks under gravity and judge whether they stand.

    Parameters
    ----------
    scene : Scene
        Its foundation is the ground the blocks stand on.
    placed : sequence of (id, Block, Pose)
        The blocks and their initial poses (``Layout.placed()``).
    seconds : float
        Simulated time, seconds (0 < seconds <= 60).
    seed : int or numpy.random.Generator
        Seeds the small initial kick of each free block (``KICK_SPEED``).
        The same seed gives a bit-identical result.
    backend : SettleBackend, optional
        The physics engine; by default the one the scene's kind calls for.
    movable : collection of int, optional
        Ids of the blocks that are free bodies; the others are held fixed.
        All blocks are free by default.
    thresholds : Thresholds, optional
        The stability thresholds; issue 3's by default.
    early_stop : bool
        Stop once every free block has come to rest (see ``tol.rest_time``).
    progress : callable, optional
        Called now and then with (simulated seconds, ``seconds``).
    stop : callable, optional
        Asked every few steps; once it says True the settle raises
        :class:`settle.base.Stopped` (a caller's deadline: the optimizer's
        confirming settles of slender meshes ran 5 s past its time limit).

    Returns
    -------
    SettleResult
        Where the engine diverged (:class:`Diverged`), one with ``diverged``
        set: not stable, each free block where it started and not stable.

    Raises
    ------
    InputError
        For bad arguments: duplicate ids, unknown ids in ``movable``, a time
        out of range, or blocks the backend cannot model.
    """
    start = time.perf_counter()
    thresholds = thresholds if thresholds is not None else Thresholds()
    if not isinstance(seconds, (int, float)) or not 0 < seconds <= MAX_SECONDS:
        raise InputError(f"settle time must be in (0, {MAX_SECONDS:g}] seconds, not {seconds!r}")
    ids = [int(k) for k, _, _ in placed]
    if len(set(ids)) != len(ids):
        raise InputError("settle: block ids must be unique")
    free = set(ids) if movable is None else {int(k) for k in movable}
    unknown = sorted(free - set(ids))
    if unknown:
        raise InputError(f"settle: movable block {unknown[0]} is not in the layout")
    backend = backend if backend is not None else default_backend(scene)
    if not isinstance(backend, SettleBackend):
        raise InputError(f"settle: backend must be a SettleBackend instance, not {type(backend).__name__}")

    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    bodies = []
    for key, block, pose in placed:
        v = w = np.zeros(3)
        if key in free:
            # A random direction for the centroid and for the spin, each at
            # KICK_SPEED (for the spin, at the block's outermost point).
            v, w = _unit(rng.normal(size=3)), _unit(rng.normal(size=3))
            v, w = KICK_SPEED * v, KICK_SPEED / block.bounding_radius * w
        bodies.append(SettleBody(int(key), block, pose, key in free, v, w))
    backend.check(scene, bodies)

    diverged = False
    try:
        run = (backend.simulate(scene, bodies, float(seconds), early_stop, progress, stop)
               if any(b.movable for b in bodies) else Run({}, 0.0, 0, True))
    except Diverged:
        # A wedge the engine's contacts could not resolve: no answer, so nothing is known to stand.
        run, diverged = Run({}, 0.0, 0, False), True

    records = []
    for body in bodies:
        final = run.poses.get(body.id, body.pose) if body.movable else body.pose
        displacement = float(np.linalg.norm(final.position - body.pose.position))
        rotation = float(np.degrees(rotation_between(body.pose.quaternion, final.quaternion)))
        ok = (displacement <= thresholds.displacement_limit(body.block)
              and rotation <= thresholds.rotation_deg and not (diverged and body.movable))
        records.append(BlockSettle(body.id, final, displacement, rotation, bool(ok), body.movable))
    return SettleResult(
        stable=all(r.stable for r in records),
        blocks=records,
        max_displacement_m=max((r.displacement_m for r in records), default=0.0),
        max_rotation_deg=max((r.rotation_deg for r in records), default=0.0),
        seconds=time.perf_counter() - start,
        simulated_seconds=run.simulated_seconds,
        steps=run.steps,
        at_rest=run.at_rest,
        peak_speed=run.peak_speed,
        backend=backend.name,
        thresholds=thresholds,
        diverged=diverged,
    )


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)
