"""The MuJoCo backend: 3D rigid bodies with soft contacts (docs/settle.md).

Every free block is a MuJoCo body with a free joint. Its collision geoms are
exactly the block's convex pieces (``Block.pieces``) as mesh geoms, and its
mass and inertia are the real block's, set explicitly rather than inferred
from the geoms. A block held fixed is a body without a joint, welded to the
world. The foundation is a static box whose top is z = 0, or a height field
for a rough underlayer, never an infinite plane: MuJoCo's plane-mesh collider
keeps at most 3 contact points, so a flat face resting on a plane ratchets
and creeps (mujoco#3524); the box goes through the general convex collider,
which gives a full contact patch. A wall-backed section's wall is another
static box.

Quaternions are scalar first ``[w, x, y, z]`` in MuJoCo as in shoha, so poses
go in and out without conversion.

Contact and time-step choices, each with its reason (and in docs/settle.md):

``condim = 3``
    Normal force plus two-dimensional sliding friction. Friction is what
    rejects the perturbations finite precision injects into a stack at rest;
    with ``condim = 1`` a packed stack that is stable on paper topples
    (mujoco#366). Torsion and rolling resistance (``condim`` 4, 6) are left
    out: a block touching over a face gets several contact points from
    multi-point CCD, and those resist twisting and rolling as a real face does.
``friction = 0.6``
    Coulomb friction of precast concrete on concrete and on rubble, at the
    low end of the 0.6-0.8 design values: a verdict of "stable" then errs on
    the safe side. All geoms have the same value, so MuJoCo's rule for mixing
    two geoms' friction (the maximum) gives 0.6 for every pair.
``cone = elliptic, impratio = 10``
    The pyramidal cone approximates the friction cone by a pyramid: a block
    sliding diagonally to the pyramid's edges meets up to 1/sqrt(2) less
    friction, which shifts the sliding threshold on an incline. The elliptic
    cone is the Coulomb cone. ``impratio = 10`` makes friction ten times
    stiffer than the normal direction, which cuts the slow creep of MuJoCo's
    regularised friction under a load inside the cone (mujoco#3328) to
    tenths of a millimetre in 2 s.
``solref = (12 ms, 1)``
    The contact behaves as a critically damped spring-damper (ratio 1: no
    bounce, concrete blocks do not rebound) with a 12 ms time constant. Stiff
    contacts reject the perturbations of a stack (mujoco#366, where the
    default 20 ms lets a packed stack topple), but MuJoCo's stiffest, 2 time
    steps, makes a sliding block chatter: it loses and regains contact every
    few steps and twists by degrees (measured: 9 deg in 2 s at 2 ms steps
    and 4 ms, 0.7 deg at 4 ms and 8 ms). At 3 steps (12 ms at 4 ms) it slides
    cleanly, within 1 % of the analytic distance. The constant is fixed, not
    tied to the step, so that halving the step changes the integration only.
    Positive solref keeps contacts mass-invariant: a 4 t block and a 1 kg
    one sink in alike.
``solimp = (0.9, 0.99, 1 mm, 0.5, 2)``
    Impedance 0.9 at first touch, rising to 0.99 over 1 mm of penetration.
    With the time constant above, a 4 t block resting on another sinks in by
    about 0.1 mm, far below ``tol.contact_depth``. Trainee saves start with a
    few millimetres of overlap; the critically damped spring pushes an
    overlap ``p`` out at about ``p / (2 tau)`` at most (0.2 m/s for 5 mm)
    and leaves it at rest where the blocks touch, without launching it
    (tested).
``timestep = 4 ms``
    The blocks are metres across and fall at a few m/s at most, so a step
    moves them by centimetres at worst against pieces 0.3 m and more thick;
    the slowest dynamics (toppling, ~sqrt(H/g) = 0.4 s) get a hundred steps.
    The tipping boundary of a Shake Block on one leg comes out within 0.25
    deg of the geometry's at 4, 2 and 1 ms alike, and no tested verdict
    changes when the step is halved. A step costs the same at any size, so
    4 ms settles a 75-block pile twice as fast as 2 ms (docs/settle.md).
Sleeping
    MuJoCo's island sleeping is on: an island of touching blocks whose every
    velocity stays below ``tol.rest_speed / 2`` for 10 steps stops being
    simulated, and wakes when an awake block touches it. Every block is held
    awake for the first ``tol.rest_time``, so that a block that starts from
    rest and only slowly gathers speed (on an incline just past its friction
    angle) is not put to sleep before it has had the chance to move.
Multi-point CCD
    On (MuJoCo's default): face-face contacts between convex pieces get up to
    4 points instead of 1, so a leg end resting on the ground is a patch, not
    a pivot.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager

import mujoco
import numpy as np

from geometry.blocks import Block
from geometry.constants import GRAVITY, tol
from geometry.pose import Pose
from geometry.scene import Scene

from .base import Diverged, Progress, Run, SettleBackend, SettleBody
from .section import foundation_profile

#: Thickness of the static foundation box below z = 0, and of the solid part
#: of a rough height field below its lowest point, metres. Thick enough that
#: no block, falling at a few m/s, tunnels through in one step.
FOUNDATION_THICKNESS = 2.0

#: Margin by which the foundation extends past the scene's foundation extent
#: and past every block, metres. A block that slides this far is unstable
#: long before it could fall off the edge.
FOUNDATION_MARGIN = 10.0

#: MuJoCo arena bytes per free block. Measured at 16-18 kB per block on poured
#: piles of 75 to 1000 shake-4t blocks (data.maxuse_arena); four times that leaves
#: room for a collapsing pile's extra contacts.
ARENA_PER_BLOCK = 64 * 1024


class MujocoBackend(SettleBackend):
    """3D settle with MuJoCo (see the module docstring for every choice).

    Parameters
    ----------
    timestep : float, seconds
    friction : float
        Coulomb friction coefficient of every contact.
    solref : (2,) float, optional
        MuJoCo contact reference (time constant s, damping ratio); default
        ``(2 timestep, 1)``.
    solimp : (5,) float
        MuJoCo contact impedance (dmin, dmax, width m, midpoint, power).
    impratio : float
        Ratio of frictional to normal constraint impedance.
    sleep : bool
        Use MuJoCo's island sleeping.
    multiccd : bool
        Multi-point contacts between convex geoms.
    check_every : int
        Steps between checks for rest, progress and divergence.
    """

    name = "mujoco"

    def __init__(
        self,
        timestep: float = 0.004,
        friction: float = 0.6,
        solref: tuple[float, float] | None = None,
        solimp: tuple[float, float, float, float, float] = (0.9, 0.99, 1e-3, 0.5, 2.0),
        impratio: float = 10.0,
        sleep: bool = True,
        multiccd: bool = True,
        check_every: int = 10,
    ):
        self._set_step(timestep, friction, check_every)
        self.solref = tuple(solref) if solref is not None else (0.012, 1.0)
        self.solimp = tuple(solimp)
        self.impratio = float(impratio)
        self.sleep = bool(sleep)
        self.multiccd = bool(multiccd)

    # --- model ---------------------------------------------------------------

    def build(self, scene: Scene, bodies: Sequence[SettleBody]) -> mujoco.MjModel:
        """The MuJoCo model of ``bodies`` on ``scene``'s foundation.

        Free bodies come first in body order, in the order given, so that
        ``qpos`` is ``(n_free, 7)`` and ``qvel`` ``(n_free, 6)``.
        """
        spec = mujoco.MjSpec()
        spec.modelname = "shoha-settle"
        opt = spec.option
        opt.timestep = self.timestep
        opt.gravity = [0.0, 0.0, -GRAVITY]
        opt.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
        opt.impratio = self.impratio
        # A diverged simulation must raise, not silently restart from qpos0.
        opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_AUTORESET
        if not self.multiccd:
            opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_MULTICCD
        if self.sleep:
            opt.enableflags |= mujoco.mjtEnableBit.mjENBL_SLEEP
            opt.sleep_tolerance = tol.rest_speed / 2
        n_free = sum(b.movable for b in bodies)
        spec.memory = max(16 << 20, ARENA_PER_BLOCK * n_free)

        meshes: dict[int, list[str]] = {}
        for body in bodies:
            if id(body.block) not in meshes:
                meshes[id(body.block)] = self._add_meshes(spec, body.block, len(meshes))
        self._add_foundation(spec, scene, bodies)
        self._add_wall(spec, scene)
        # Free bodies first, so that their joints' qpos and qvel are
        # contiguous, in the order of free_order().
        free = [bodies[i] for i in free_order(bodies)]
        for body in free + [b for b in bodies if not b.movable]:
            self._add_body(spec, body, meshes[id(body.block)])
        return spec.compile()

    def _contact(self, geom: mujoco.MjsGeom) -> None:
        geom.condim = 3
        geom.friction = [self.friction, 0.0, 0.0]
        geom.solref = list(self.solref)
        geom.solimp = list(self.solimp)

    @staticmethod
    def _add_meshes(spec: mujoco.MjSpec, block: Block, index: int) -> list[str]:
        names = []
        for i, piece in enumerate(block.pieces):
            mesh = spec.add_mesh()
            mesh.name = f"block{index}_piece{i}"
            mesh.uservert = piece.vertices.ravel().tolist()
            mesh.userface = piece.faces.ravel().tolist()
            names.append(mesh.name)
        return names

    def _add_body(self, spec: mujoco.MjSpec, body: SettleBody, meshes: list[str]) -> None:
        b = spec.worldbody.add_body()
        b.name = f"block{body.id}"
        b.pos = body.pose.position.tolist()
        b.quat = body.pose.quaternion.tolist()  # MuJoCo is scalar first too
        if body.movable:
            b.add_freejoint()
        # The real block's mass and inertia about its centroid (the body
        # origin), not MuJoCo's estimate from the geoms. ipos must be set:
        # left unset, the compiler puts the centre of mass at the body's pos.
        i = body.block.inertia
        b.mass = body.block.mass
        b.fullinertia = [i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2]]
        b.ipos = [0.0, 0.0, 0.0]
        b.explicitinertial = True
        for name in meshes:
            g = b.add_geom()
            g.type = mujoco.mjtGeom.mjGEOM_MESH
            g.meshname = name
            self._contact(g)

    def _add_foundation(self, spec: mujoco.MjSpec, scene: Scene, bodies: Sequence[SettleBody]) -> None:
        f = scene.foundation
        x0, x1, y0, y1 = f.extent
        if bodies:
            xy = np.array([b.pose.position[:2] for b in bodies])
            r = max(b.block.bounding_radius for b in bodies)
            x0, y0 = min(x0, xy[:, 0].min() - r), min(y0, xy[:, 1].min() - r)
            x1, y1 = max(x1, xy[:, 0].max() + r), max(y1, xy[:, 1].max() + r)
        if f.kind == "rough":
            # The box then lies under the height field, its top at the
            # underlayer's lowest level, and is the ground beyond its edges.
            self._add_height_field(spec, scene)
        g = spec.worldbody.add_geom()
        g.name = "foundation"
        g.type = mujoco.mjtGeom.mjGEOM_BOX
        m = FOUNDATION_MARGIN
        g.size = [(x1 - x0) / 2 + m, (y1 - y0) / 2 + m, FOUNDATION_THICKNESS / 2]
        top = -f.amplitude if f.kind == "rough" else 0.0
        g.pos = [(x0 + x1) / 2, (y0 + y1) / 2, top - FOUNDATION_THICKNESS / 2]
        self._contact(g)

    def _add_wall(self, spec: mujoco.MjSpec, scene: Scene) -> None:
        """A wall-backed section's wall (``Scene.wall_box``): a static box, as fixed as the foundation."""
        box = scene.wall_box
        if box is None:
            return
        g = spec.worldbody.add_geom()
        g.name = "wall"
        g.type = mujoco.mjtGeom.mjGEOM_BOX
        g.size = ((box[1] - box[0]) / 2).tolist()
        g.pos = ((box[0] + box[1]) / 2).tolist()
        self._contact(g)

    def _add_height_field(self, spec: mujoco.MjSpec, scene: Scene) -> None:
        """The rough underlayer as a MuJoCo height field.

        MuJoCo splits each grid cell into two triangles where the foundation
        interpolates bilinearly; the two agree at the nodes and differ inside
        a cell by a fraction of the amplitude. A section scene's foundation is
        extruded along y like its blocks (``section.foundation_profile``).
        """
        xs, ys, h = scene.foundation.grid
        if scene.kind == "section":
            h = np.repeat(foundation_profile(scene)[1][:, None], len(ys), axis=1)
        lo, hi = float(h.min()), float(h.max())
        span = max(hi - lo, tol.distance)
        field = spec.add_hfield()
        field.name = "underlayer"
        # MuJoCo's rows run along y and columns along x; it rescales the
        # elevations to [0, 1] and multiplies them by size[2].
        field.nrow, field.ncol = len(ys), len(xs)
        field.userdata = ((h.T - lo) / span).ravel().tolist()
        field.size = [(xs[-1] - xs[0]) / 2, (ys[-1] - ys[0]) / 2, span, FOUNDATION_THICKNESS]
        g = spec.worldbody.add_geom()
        g.name = "underlayer"
        g.type = mujoco.mjtGeom.mjGEOM_HFIELD
        g.hfieldname = field.name
        g.pos = [(xs[0] + xs[-1]) / 2, (ys[0] + ys[-1]) / 2, lo]
        self._contact(g)

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
        model = self.build(scene, bodies)
        data = mujoco.MjData(model)
        free = [bodies[i] for i in free_order(bodies)]
        q, v = data.qpos.reshape(-1, 7), data.qvel.reshape(-1, 6)
        for k, b in enumerate(free):
            # Free joint velocity: linear in the world frame, angular in the
            # body frame.
            v[k, :3] = b.velocity
            v[k, 3:] = b.pose.rotation.T @ b.angular_velocity
        if self.sleep:
            # Hold every block awake for the first rest_time (module docstring).
            data.tree_asleep[:] = -(1 + math.ceil(tol.rest_time / self.timestep))
        done = [0]

        def advance(n: int) -> None:
            # MuJoCo prints its warnings ("Too many contacts...") on stderr, where a --json
            # run's one-line summary is read; they are read from ``data.warning`` instead
            # (``_check_health``: no answer, diverged). The handler is set only while MuJoCo
            # steps (in any thread: ``_quieted``): one left set at exit made nanobind report
            # leaks on stderr.
            with _quieted():
                try:
                    mujoco.mj_step(model, data, nstep=n)
                except mujoco.FatalError as exc:  # its stack overflowed: blocks one inside another
                    raise Diverged(f"MuJoCo stopped at step {done[0]}: {exc}") from exc
            done[0] += n
            self._check_health(data, done[0])

        steps, at_rest, peak = self._run(
            advance, lambda: (q[:, :3], q[:, 3:], v[:, :3], v[:, 3:]),
            np.array([b.block.bounding_radius for b in free]), seconds, early_stop, progress, stop)
        poses = {b.id: Pose(q[k, :3], q[k, 3:]) for k, b in enumerate(free)}
        return Run(poses, steps * self.timestep, steps, at_rest, peak)

    @staticmethod
    def _check_health(data: mujoco.MjData, steps: int) -> None:
        w = mujoco.mjtWarning
        full = data.warning[w.mjWARN_CONTACTFULL].number + data.warning[w.mjWARN_CNSTRFULL].number
        if full:
            # Contacts beyond the arena sized for blocks that touch (ARENA_PER_BLOCK): blocks lie
            # one inside another, as no layout that passes the checks does. No answer.
            raise Diverged(f"MuJoCo ran out of contact memory at step {steps} (blocks inside one another)")
        if data.warning[w.mjWARN_BADQACC].number or not np.isfinite(data.qpos).all():
            raise Diverged(f"MuJoCo diverged at step {steps} (non-finite accelerations)")


def _quiet(text: str) -> None:
    """MuJoCo's warning handler while it steps: nothing printed (see ``simulate``)."""


_stepping_lock = threading.Lock()
_stepping = 0


@contextmanager
def _quieted() -> Iterator[None]:
    """:func:`_quiet` as MuJoCo's warning handler while any thread steps a settle.

    The handler is one for the process. Two settles step at once (a verdict's two kicks,
    ``optimizer.search.physics.verdict``; the live service's threads), and the first to end
    its steps must not unset it under the other: it is set by the first to begin and unset by
    the last to end.
    """
    global _stepping
    with _stepping_lock:
        if _stepping == 0:
            mujoco.set_mju_user_warning(_quiet)
        _stepping += 1
    try:
        yield
    finally:
        with _stepping_lock:
            _stepping -= 1
            if _stepping == 0:
                mujoco.set_mju_user_warning(None)


def free_order(bodies: Sequence[SettleBody]) -> list[int]:
    """Indices of the free bodies, in the order that keeps MuJoCo's solver sparse.

    MuJoCo's Newton solver factorises ``M + J' D J`` by sparse Cholesky in
    the order of the degrees of freedom, without reordering. Two blocks in
    contact couple their dofs; in the order the blocks were placed the
    couplings are scattered and the factor fills in towards a dense matrix,
    whose cost grows with the cube of the block count. Sorted along the
    principal axis of their centres (the crest, for a breakwater), touching
    blocks lie close in the order, and the factor stays within a band about
    one cross-section of blocks wide, so its cost grows linearly along the
    crest. Measured on a poured 300-block pile: 403 ms per step in the
    placement order, 27 ms with scipy's reverse Cuthill-McKee (which starts
    from a block of least degree, often mid-pile, and sweeps in rings), and
    18 ms sorted along the principal axis.
    """
    index = [i for i, b in enumerate(bodies) if b.movable]
    if len(index) < 3:
        return index
    centres = np.array([bodies[i].pose.position for i in index])
    centres -= centres.mean(axis=0)
    axis = np.linalg.svd(centres, full_matrices=False)[2][0]
    # Stable sort: ties keep the given order, so the result is deterministic.
    return [index[i] for i in np.argsort(centres @ axis, kind="stable")]
