"""The pymunk backend: 2D rigid bodies for section scenes (docs/settle.md).

A section scene's blocks are prisms along y that move only in x-z
(:mod:`settle.section`), so the physics is 2D: pymunk (Chipmunk2D) in the
plane (u, v) = (x, z). Each free block is a pymunk body with the block's mass
and its moment of inertia about local y, and one convex polygon per piece,
the piece's x-z outline. A block held fixed is a static body. The foundation
is a static polygon whose top is z = 0, or, over a rough underlayer, a row of
static quadrilaterals following the height field's profile along the middle
of the slice. A wall-backed section's wall is one more static polygon.

Choices, each with its reason:

Friction
    0.6, as in the MuJoCo backend. Chipmunk gives a pair of shapes the
    product of their friction values, so every shape gets ``sqrt(0.6)``: each
    pair, block on block or block on ground, then has exactly 0.6.
    Chipmunk's friction is exact Coulomb (a 2D cone is two lines), so there
    is no cone approximation to correct.
Overlap
    Chipmunk pushes overlapping shapes apart with a bias velocity that it
    throws away after each step (split impulses), not with a spring, so an
    initial overlap is removed (all but 0.9^60 of it per second, Chipmunk's
    default rate) without leaving kinetic energy behind. ``collision_slop``,
    the overlap left alone, is 0.5 mm, as small as the geometry's tolerances.
Time step and iterations
    2 ms and 30 solver iterations: the same step as MuJoCo, and enough
    iterations for the contact impulses of a stack of a dozen blocks to
    converge (Chipmunk's default of 10 lets a tall stack sag).
Sleeping
    Off: the run stops early by the same rest rule as the MuJoCo backend
    (:class:`settle.base.RestMonitor`), and 2D runs are cheap.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
import pymunk

from geometry.constants import GRAVITY
from geometry.errors import InputError
from geometry.scene import Scene

from .base import Diverged, Progress, Run, SettleBackend, SettleBody
from .section import foundation_profile, from_plane, outlines, to_plane

#: Depth of the static foundation below its top, and its margin past the
#: blocks and the scene, metres (as in the MuJoCo backend).
FOUNDATION_THICKNESS = 2.0
FOUNDATION_MARGIN = 10.0


class PymunkBackend(SettleBackend):
    """2D settle of section scenes with pymunk.

    Parameters
    ----------
    timestep : float, seconds
    friction : float
        Coulomb friction coefficient of every contact.
    iterations : int
        Chipmunk solver iterations per step.
    slop : float, metres
        Overlap Chipmunk leaves alone.
    bias : float
        Fraction of an overlap left after one second of correction
        (Chipmunk's ``collision_bias``; its default, 0.9^60).
    check_every : int
        Steps between checks for rest and progress.
    """

    name = "pymunk"

    def __init__(
        self,
        timestep: float = 0.002,
        friction: float = 0.6,
        iterations: int = 30,
        slop: float = 5e-4,
        bias: float = 0.9**60,
        check_every: int = 10,
    ):
        self._set_step(timestep, friction, check_every)
        self.iterations = int(iterations)
        self.slop = float(slop)
        self.bias = float(bias)

    def check(self, scene: Scene, bodies: Sequence[SettleBody]) -> None:
        """Only section scenes, with prism blocks turned about y only."""
        if scene.kind != "section":
            raise InputError(
                f"scene {scene.name}: the pymunk backend is 2D and settles section scenes only, "
                f"not {scene.kind!r} scenes"
            )
        for body in bodies:
            outlines(body.block)
            to_plane(body.pose, f"block {body.id}")

    # --- model ---------------------------------------------------------------

    def build(self, scene: Scene, bodies: Sequence[SettleBody]) -> tuple[pymunk.Space, list[pymunk.Body]]:
        """The pymunk space, and the free bodies in the order given."""
        space = pymunk.Space()
        space.gravity = (0.0, -GRAVITY)
        space.iterations = self.iterations
        space.collision_slop = self.slop
        space.collision_bias = self.bias
        shape_friction = math.sqrt(self.friction)
        self._add_foundation(space, scene, bodies, shape_friction)
        free = []
        for body in bodies:
            (u, v), angle = to_plane(body.pose, f"block {body.id}")
            if body.movable:
                # The block's own mass and moment about local y (the 2D
                # rotation axis), not pymunk's from the outlines' areas.
                b = pymunk.Body(body.block.mass, float(body.block.inertia[1, 1]))
            else:
                b = pymunk.Body(body_type=pymunk.Body.STATIC)
            b.position = (u, v)
            b.angle = angle
            if body.movable:
                b.velocity = (float(body.velocity[0]), float(body.velocity[2]))
                # A turn about +y is clockwise in (u, v) = (x, z).
                b.angular_velocity = -float(body.angular_velocity[1])
                free.append(b)
            shapes = [pymunk.Poly(b, [tuple(p) for p in outline]) for outline in outlines(body.block)]
            for s in shapes:
                s.friction = shape_friction
            space.add(b, *shapes)
        return space, free

    @staticmethod
    def _add_foundation(space: pymunk.Space, scene: Scene, bodies: Sequence[SettleBody],
                        friction: float) -> None:
        f = scene.foundation
        x0, x1 = f.extent[0], f.extent[1]
        for b in bodies:
            r = b.block.bounding_radius
            x0, x1 = min(x0, b.pose.position[0] - r), max(x1, b.pose.position[0] + r)
        x0, x1 = x0 - FOUNDATION_MARGIN, x1 + FOUNDATION_MARGIN
        ground = space.static_body
        if f.kind == "rough":
            # The height field's profile along the middle of the slice, one
            # convex quadrilateral per grid cell.
            xs, zs = foundation_profile(scene)
            bottom = -f.amplitude - FOUNDATION_THICKNESS
            quads = [[(xs[i], bottom), (xs[i + 1], bottom), (xs[i + 1], zs[i + 1]), (xs[i], zs[i])]
                     for i in range(len(xs) - 1)]
            quads.append([(x0, bottom), (xs[0], bottom), (xs[0], zs[0]), (x0, zs[0])])
            quads.append([(xs[-1], bottom), (x1, bottom), (x1, zs[-1]), (xs[-1], zs[-1])])
        else:
            quads = [[(x0, -FOUNDATION_THICKNESS), (x1, -FOUNDATION_THICKNESS), (x1, 0.0), (x0, 0.0)]]
        box = scene.wall_box
        if box is not None:  # a wall-backed section's wall: its x-z outline, as fixed as the ground
            quads.append([(box[0, 0], box[0, 2]), (box[1, 0], box[0, 2]), (box[1, 0], box[1, 2]),
                          (box[0, 0], box[1, 2])])
        for quad in quads:
            s = pymunk.Poly(ground, [(float(a), float(b)) for a, b in quad])
            s.friction = friction
            space.add(s)

    # --- run -------------------------------------------------------------------

    def simulate(
        self,
        scene: Scene,
        bodies: Sequence[SettleBody],
        seconds: float,
        early_stop: bool,
        progress: Progress | None = None,
        stop: Callable[[], bool] | None = None,
    ) -> Run:
        space, free = self.build(scene, bodies)
        moving = [b for b in bodies if b.movable]
        done = [0]

        def advance(n: int) -> None:
            for _ in range(n):
                space.step(self.timestep)
            done[0] += n

        def observe() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
            state = np.array([(*b.velocity, b.angular_velocity, *b.position, b.angle)
                              for b in free]).reshape(-1, 6)
            if not np.isfinite(state).all():
                raise Diverged(f"pymunk diverged at step {done[0]} (non-finite state)")
            zeros = np.zeros(len(free))
            v = np.column_stack([state[:, 0], zeros, state[:, 1]])
            w = np.column_stack([zeros, -state[:, 2], zeros])
            # 3D poses of the 2D state: (x, z) and a turn by -angle about +y.
            p = np.column_stack([state[:, 3], zeros, state[:, 4]])
            half = -state[:, 5] / 2
            q = np.column_stack([np.cos(half), zeros, np.sin(half), zeros])
            return p, q, v, w

        steps, at_rest, peak = self._run(advance, observe,
                                         np.array([b.block.bounding_radius for b in moving]),
                                         seconds, early_stop, progress, stop)
        poses = {
            body.id: from_plane((b.position.x, b.position.y), b.angle, float(body.pose.position[1]))
            for body, b in zip(moving, free, strict=True)
        }
        return Run(poses, steps * self.timestep, steps, at_rest, peak)
