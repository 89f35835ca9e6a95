"""A layout under construction, with every incremental structure over it.

The search strategies grow, change and copy :class:`Build` objects. A build
keeps, for its placed blocks in crane order:

* a :class:`~optimizer.drop.DropWorld`, to lower new blocks until they touch;
* a :class:`~geometry.collision.CollisionWorld` (python-fcl), which confirms
  every placement and every move against the neighbours only;
* an exact :class:`~geometry.porosity.PorosityTracker` (the shared porosity
  module), updated per block;
* the support graph: which blocks each block rests on, so that a block with
  others resting on it is never moved from under them.

Copying a build shares the immutable per-block entries, so a beam of a few
builds costs little more than one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geometry.blocks import Block
from geometry.clip import volume_inside
from geometry.collision import CollisionWorld
from geometry.constants import tol
from geometry.layout import Layout, Placement
from geometry.porosity import PorosityTracker
from geometry.pose import Pose
from geometry.scene import Scene

from .drop import DropWorld, Shape

#: The ground, as a support key.
GROUND = -1


@dataclass(frozen=True)
class Candidate:
    """A block lowered to first contact at one horizontal position.

    Attributes
    ----------
    shape : Shape
        The block in its hanging orientation.
    pose : Pose
        Where it rests.
    support : tuple of int
        What it rests on (``GROUND`` for the foundation).
    inside : float, m^3
        Its volume inside the design prism.
    loose : bool
        Its first contact sticks out of the tolerance zone: it is valid only
        where it comes to rest once let go (``Build.lower(..., loose=True)``),
        and only a physics check may place it.
    """

    shape: Shape
    pose: Pose
    support: tuple[int, ...]
    inside: float
    loose: bool = False


class Build:
    """Placed blocks in crane order, and the structures that score them.

    Parameters
    ----------
    scene : Scene
    """

    def __init__(self, scene: Scene):
        self.scene = scene
        self.block: Block = scene.block
        cell = 2.0 * self.block.bounding_radius
        self.drops = DropWorld(scene.foundation, cell=cell)
        self.collide = CollisionWorld(cell=cell)
        self.porosity = PorosityTracker(scene, "exact")
        self.order: list[int] = []
        self.shapes: dict[int, Shape] = {}
        self.poses: dict[int, Pose] = {}
        self.supports: dict[int, tuple[int, ...]] = {}
        self.carried: dict[int, set[int]] = {}
        self.next_key = 0
        #: Blocks kept where a partial layout had them (``optimize(keep=...)``): by key, their id
        #: and type in that layout. No strategy moves or removes them.
        self.kept: dict[int, tuple[int, str]] = {}
        #: Blocks laid along the toes to cover them (:class:`optimizer.search.toe.ToeRows`), by
        #: key: the samples of the toe's strip where each was laid, and the share of them it
        #: covered there. The annealing moves one only where it covers no less of them, and it
        #: stays one under its new key. A block taken out (:meth:`remove`) leaves it; a settled
        #: build (:meth:`settled`) has new keys and none.
        self.toe_rows: dict[int, tuple[np.ndarray, float]] = {}
        self.zone = scene.tolerance.polytope
        self._design = scene.design.polytope
        # The zone's faces a rising block can only cross further: slopes, crest, ends.
        up = self.zone.normals[:, 2] >= 0.0
        self._ceiling = (self.zone.normals[up], self.zone.offsets[up])

    def __len__(self) -> int:
        return len(self.order)

    def copy(self) -> Build:
        other = Build.__new__(Build)
        other.__dict__.update(self.__dict__)
        other.drops = self.drops.copy()
        other.collide = self.collide.copy()
        other.porosity = self.porosity.copy()
        other.order = list(self.order)
        other.shapes = dict(self.shapes)
        other.poses = dict(self.poses)
        other.supports = dict(self.supports)
        other.carried = {k: set(v) for k, v in self.carried.items()}
        other.kept = dict(self.kept)
        other.toe_rows = dict(self.toe_rows)
        return other

    # --- proposing ---------------------------------------------------------------

    def lower(self, shape: Shape, x: float, y: float, exclude: frozenset[int] = frozenset(),
              loose: bool = False) -> Candidate | None:
        """Lower ``shape`` at (x, y) until it touches; None if it ends out of tolerance.

        The exact first-contact height comes from the drop world; FCL then
        confirms that the resting block penetrates no neighbour. A block only
        rests at or above the ground, so one that already crosses a face of
        the zone's ceiling at ground height is out without a drop (about half
        the drops of a pattern pass on ``mini`` and ``tetrapod``). With
        ``loose``, a first contact out of the zone (on a neighbour's shoulder)
        is returned all the same, marked ``loose``: let go, it may slide into
        the pocket beside.
        """
        normals, offsets = self._ceiling
        ground = self.drops.ground_height(shape, x, y)
        low = Pose([x, y, ground], shape.quaternion).apply(self.block.vertices)
        if not loose and not np.all(low @ normals.T <= offsets + tol.distance):
            return None
        z, support, on_ground = self.drops.drop(shape, x, y, exclude, ground)
        pose = Pose([x, y, z], shape.quaternion)
        world = pose.apply(self.block.vertices)
        # The tolerance zone is convex: the block is inside iff its vertices are.
        out = not self.zone.contains(world).all()
        if out and not loose:
            return None
        if self.collide.query(self.block, pose, exclude=exclude, threshold=-1.0, first=True):
            return None  # pragma: no cover - the exact drop leaves a gap; FCL is the referee
        keys = tuple(support) + ((GROUND,) if on_ground else ())
        return Candidate(shape, pose, keys, volume_inside(self.block, pose, self._design), out)

    def clear_of_ceiling(self, shape: Shape, xy: np.ndarray) -> np.ndarray:
        """Which of the places ``xy`` (n, 2) :meth:`lower` does not refuse without a drop.

        The same first test as :meth:`lower`'s, for many places at once, with the block's
        lowest piece on the foundation's lowest point rather than on the ground under each:
        a block that crosses a face of the zone's ceiling there crosses it wherever it rests,
        no lower. So a place it refuses, :meth:`lower` refuses too (a sweep of the mound skips
        half its drops by it).
        """
        normals, offsets = self._ceiling
        turned = Pose([0.0, 0.0, 0.0], shape.quaternion).apply(self.block.vertices) @ normals.T
        low = self.scene.foundation.lowest - float(shape.lows.min())
        at = np.column_stack([xy, np.full(len(xy), low)]) @ normals.T
        return np.all(at + turned.max(axis=0) <= offsets + tol.distance, axis=1)

    # --- changing ----------------------------------------------------------------

    def place(self, c: Candidate) -> int:
        """Add a candidate as the next block in crane order; returns its key."""
        if c.loose:
            raise ValueError("a loose candidate is placed only where it comes to rest")
        key = self.next_key
        self.next_key += 1
        self.order.append(key)
        self._insert(key, c)
        return key

    def _insert(self, key: int, c: Candidate) -> None:
        self.shapes[key] = c.shape
        self.poses[key] = c.pose
        self.supports[key] = c.support
        self.carried[key] = set()
        for s in c.support:
            if s != GROUND:
                self.carried[s].add(key)
        self.drops.add(key, c.shape, c.pose.position)
        self.collide.add(key, self.block, c.pose)
        self.porosity.add(key, self.block, c.pose)

    def place_at(self, pose: Pose) -> int:
        """Add a block of a layout where it is, resting on what it touches, free to move later."""
        return self.place(self._resting(pose, anyway=True))

    def keep(self, block_id: int, block_type: str, pose: Pose) -> int:
        """Add a block of a partial layout where it is, fixed: first in crane order, never moved.

        It rests on the blocks and the ground it touches; one that touches
        nothing, collides or sticks out of the zone is kept all the same (the
        caller reports it).
        """
        key = self.place_at(pose)
        self.kept[key] = (block_id, block_type)
        return key

    def settled(self, poses: dict[int, Pose]) -> Build:
        """A new build of the same blocks where a settle left them (``poses`` by key).

        Kept blocks stay as they are, first. The others are placed in crane
        order again, each at its settled pose, resting on what it touches;
        a block that now leans on one placed after it waits until that one
        is in (a settle can shift a block onto a later neighbour). Keys are
        new: ``0..n-1`` in the new order. Blocks the settle moved out of the
        zone, or into a neighbour deeper than the contact tolerance, are
        placed all the same: the caller checks them.
        """
        other = Build(self.scene)
        for k in self.order:
            if k in self.kept:
                other.keep(*self.kept[k], self.poses[k])
        waiting = [k for k in self.order if k not in self.kept]
        while waiting:
            later = []
            for k in waiting:
                c = other._resting(poses.get(k, self.poses[k]))
                if c is None:
                    later.append(k)
                else:
                    other.place(c)
            if len(later) == len(waiting):  # nothing it touches is ever placed first: it goes as it is
                for k in later:
                    other.place(other._resting(poses.get(k, self.poses[k]), anyway=True))
                break
            waiting = later
        return other

    def _resting(self, pose: Pose, anyway: bool = False) -> Candidate | None:
        """A block at ``pose`` as a candidate resting on what it touches, or None if it touches
        nothing placed and not the ground (unless ``anyway``)."""
        touching = tuple(sorted(k for k, _ in self.collide.query(self.block, pose, threshold=-1.0)))
        world = pose.apply(self.block.vertices)
        ground = (world[:, 2] - self.scene.foundation.height_at(world[:, :2])).min() <= tol.contact_gap
        support = touching + ((GROUND,) if ground or (anyway and not touching) else ())
        if not support:
            return None
        return Candidate(Shape.of(self.block, pose.quaternion), pose, support,
                         volume_inside(self.block, pose, self._design))

    def remove(self, key: int) -> None:
        """Take a block out; it must carry nothing, and not be a kept one."""
        if key in self.kept:
            raise ValueError(f"block {self.kept[key][0]} is kept: it is not moved")
        if self.carried[key]:
            raise ValueError(f"block {key} carries {sorted(self.carried[key])}")
        self._delete(key)
        self.order.remove(key)
        self.toe_rows.pop(key, None)

    def _delete(self, key: int) -> None:
        for s in self.supports.pop(key):
            if s != GROUND:
                self.carried[s].discard(key)
        del self.carried[key], self.shapes[key], self.poses[key]
        self.drops.remove(key)
        self.collide.remove(key)
        self.porosity.remove(key)

    def replace(self, key: int, c: Candidate) -> None:
        """Move a block that carries nothing to a new resting pose, keeping its place in order.

        The crane order stays valid only if the block still rests on blocks
        placed before it; callers check that with :meth:`order_ok`.
        """
        carried = self.carried[key]
        if carried:
            raise ValueError(f"block {key} carries {sorted(carried)}")
        if key in self.kept:
            raise ValueError(f"block {self.kept[key][0]} is kept: it is not moved")
        self._delete(key)
        self._insert(key, c)

    def order_ok(self, key: int, support: tuple[int, ...]) -> bool:
        """Whether ``key`` may rest on ``support``: all of them placed before it."""
        rank = {k: i for i, k in enumerate(self.order)}
        mine = rank.get(key, len(self.order))
        return all(s == GROUND or rank[s] < mine for s in support)

    # --- reading ---------------------------------------------------------------------

    def free_keys(self) -> list[int]:
        """Blocks with nothing resting on them, and not kept: the ones that may move."""
        return [k for k in self.order if not self.carried[k] and k not in self.kept]

    @property
    def inside_volume(self) -> float:
        return self.porosity.filled

    def placed(self) -> list[tuple[int, Block, Pose]]:
        return [(k, self.block, self.poses[k]) for k in self.order]

    def layout(self, extra: dict | None = None) -> Layout:
        """The build as a layout, in crane order: kept blocks with their own ids, then ids counting on.

        Without kept blocks the ids are 0..n-1. Its ``scene`` is the scene's
        built-in name or absolute file path; :func:`geometry.layout.write_layout`
        callers that know the output folder make it relative (``Scene.reference``).
        """
        next_id = 1 + max((i for i, _ in self.kept.values()), default=-1)
        blocks = []
        for k in self.order:
            if k in self.kept:
                block_id, block_type = self.kept[k]
            else:
                block_id, block_type, next_id = next_id, self.scene.block_type, next_id + 1
            blocks.append(Placement(block_id, block_type, self.poses[k]))
        return Layout(self.scene.reference(), blocks, dict(extra or {}), self.scene.base_dir)

    def heights(self) -> np.ndarray:
        return np.array([self.poses[k].position[2] for k in self.order])


def search_window(scene: Scene) -> tuple[tuple[float, float], tuple[float, float]]:
    """Where a block's centroid may lie and still fill some of the design prism.

    The tolerance zone's base, but no farther from the design prism's base
    than the block's bounding radius: a block beyond that fills none of the
    prism. For a zone of ordinary allowances (a third of H) this is the whole
    zone; for one a user widened by kilometres, the search would otherwise
    spend its time on sites that add nothing. Returns ``((xmin, xmax), (ymin, ymax))``.
    """
    z, d, r = scene.tolerance, scene.design, scene.block.bounding_radius
    half = min(z.bottom_half_width, d.bottom_half_width + r)
    return (-half, half), (max(z.y_start, d.y_start - r), min(z.y_end, d.y_end + r))


def fill_window(scene: Scene) -> tuple[tuple[float, float], tuple[float, float]]:
    """Where a block's centroid can lie with the block inside the tolerance zone.

    Its footprint must fit under the slope at half its height and inside the
    ends: a window narrower than the zone's base, so that random drops are
    not wasted on corners no block fits. Returns ``((xmin, xmax), (ymin, ymax))``;
    where the block is too big for the zone, a range shrinks to the zone's middle
    (drops there are refused as any others are, and the search places nothing).
    """
    z = scene.tolerance
    h = scene.block.height
    (_, x_end), (y_start, y_end) = search_window(scene)
    run = (z.bottom_half_width - z.top_half_width) / z.height
    half = max(0.0, min(x_end, z.bottom_half_width - run * h / 2 - 0.3 * h))
    ys = (max(y_start, z.y_start + 0.45 * h), min(y_end, z.y_end - 0.45 * h))
    if ys[0] > ys[1]:
        ys = ((z.y_start + z.y_end) / 2,) * 2
    return (-half, half), ys
