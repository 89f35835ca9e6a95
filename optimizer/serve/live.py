"""A layout kept checked as its blocks come and go, one block at a time.

``shoha serve`` answers after every block a trainee lays, so nothing here
recomputes the whole layout: each change costs the changed block and its
neighbours. The answers are still exactly ``shoha check``'s and ``shoha
porosity --method exact``'s on the same blocks, computed by the same functions:

* **Out of tolerance**: :func:`geometry.tolerance.outside_volume` of the
  changed block, as ``geometry.tolerance.out_of_tolerance`` does for each block.
* **Collisions**: a :class:`geometry.collision.CollisionWorld` finds the
  blocks the changed one touches, and the depth of each such pair is asked
  of FCL with the pair's earlier block first, as ``shoha check``'s
  whole-layout search asks it.
* **Porosity** (exact): ``shoha porosity`` sums each block's volume inside the
  design prism and, where blocks touch, unions each touching group with
  manifold3d. A group of a settled pile can hold tens of blocks, too many to
  union on every request. Instead the filled volume ``V(U)`` of the union ``U``
  of all blocks, clipped to the prism, is kept, and a block ``k`` changes it by
  inclusion and exclusion::

      V(U) = V(U without k) + V(k) - V(k ∩ (union of the blocks k touches))

  since ``k`` meets no block it does not touch. ``V(k)`` is
  :func:`geometry.clip.volume_inside`; the intersection with the (few) touched
  blocks is the union of ``k``'s intersection with each of them (a manifold3d
  boolean per pair, kept until either block of the pair moves), clipped to
  the prism like ``geometry.porosity``'s unions. Taking a block out subtracts
  the same terms with its neighbours as they stand then, so the running sum
  stays the volume of the union: each step is exact to manifold3d's rounding
  (about 1e-13 m³), far below the 1e-6 percentage points the state promises.
  "Touches" is FCL's answer for the pair asked earlier block first, as
  ``geometry.collision.overlap_groups`` asks it.
* **Above the crest** (``protruding``): the block's volume above the design
  crest's plane ``z = height``, cut by :func:`geometry.clip.volume_below`, for
  blocks that reach above it.

World frame, metres and cubic metres throughout.
"""

from __future__ import annotations

from dataclasses import dataclass

import manifold3d as m3
import numpy as np

from geometry.blocks import Block
from geometry.checks import crowding, overlapping
from geometry.clip import solid_volume_inside, volume_below, volume_inside
from geometry.collision import CollisionWorld
from geometry.constants import tol
from geometry.pose import Pose
from geometry.scene import Scene
from geometry.tolerance import outside_volume

from .bodies import BodyError


@dataclass(frozen=True)
class Placed:
    """One block of a live layout and what its checks found.

    Attributes
    ----------
    id : int
    type : str
        Block type name, as in layout files.
    block : Block
    pose : Pose
        Block frame to world frame.
    time_s : float or None, seconds
        When it was laid, counted from the start of the session, where the
        client said.
    inside_m3 : float
        Its volume inside the design prism.
    outside_tolerance_m3 : float
        Its volume outside the tolerance zone (``shoha check``'s ``outside_volume_m3``).
    above_crest_m3 : float
        Its volume above the plane of the design crest.
    """

    id: int
    type: str
    block: Block
    pose: Pose
    time_s: float | None
    inside_m3: float
    outside_tolerance_m3: float
    above_crest_m3: float


_UP = np.array([0.0, 0.0, 1.0])


def _pair(a: int, b: int) -> tuple[int, int]:
    return (a, b) if a < b else (b, a)


class LiveLayout:
    """The blocks of one session, with their checks kept up to date.

    Blocks keep the order they were first laid in (installation order); a
    block laid again under the same id is moved where it is in that order.

    Parameters
    ----------
    scene : Scene
    """

    def __init__(self, scene: Scene):
        self.scene = scene
        self._prism = scene.design.polytope
        self._zone = scene.tolerance
        self._crest = float(scene.design.z_top)
        self._design_volume = scene.design_volume  # a shoelace sum each time it is asked for
        self._world = CollisionWorld(cell=2.0 * scene.block.bounding_radius)
        self._blocks: dict[int, Placed] = {}
        #: Each block's posed solid, kept so that manifold3d transforms it once, not at each move.
        self._solids: dict[int, m3.Manifold] = {}
        self._touching: dict[int, set[int]] = {}
        self._collisions: dict[tuple[int, int], float] = {}
        self._filled = 0.0
        #: Each block's place in the installation order; a moved block keeps its place.
        self._seq: dict[int, int] = {}
        self._next_seq = 0
        #: Each touching pair's intersection (None where it is empty), kept until either block moves.
        self._parts: dict[tuple[int, int], m3.Manifold | None] = {}
        #: V(k ∩ union of the blocks k touches) inside the prism, while none of them has changed.
        self._shared_now: dict[int, float] = {}
        #: Each touching pair's intersection volume (0 where it is empty), m^3.
        self._part_m3: dict[tuple[int, int], float] = {}

    # --- reading --------------------------------------------------------------

    def __len__(self) -> int:
        return len(self._blocks)

    def __contains__(self, key: int) -> bool:
        return key in self._blocks

    def __iter__(self):
        return iter(self._blocks.values())

    def get(self, key: int) -> Placed | None:
        return self._blocks.get(key)

    def near(self, centre: np.ndarray, radius: float) -> list[tuple[int, Block, Pose]]:
        """``(id, Block, Pose)`` of the blocks whose bounding spheres reach within ``radius`` of
        ``centre``."""
        blocks = self._blocks
        return [(k, blocks[k].block, blocks[k].pose) for k in self._world.neighbours(centre, radius)]

    def placed(self) -> list[tuple[int, Block, Pose]]:
        """``(id, Block, Pose)`` of every block, in installation order."""
        return [(p.id, p.block, p.pose) for p in self._blocks.values()]

    @property
    def filled_m3(self) -> float:
        """Block volume inside the design prism, overlaps counted once, m^3."""
        return self._filled if self._blocks else 0.0

    @property
    def porosity_percent(self) -> float:
        """Exact porosity of the design prism, percent in [0, 100] (eq. 1 of the reference paper)."""
        v = self._design_volume
        return float(min(100.0, max(0.0, 100.0 * (v - self.filled_m3) / v)))

    def out_of_tolerance(self) -> list[tuple[int, float]]:
        """``(id, volume outside the tolerance zone m^3)`` of blocks out of it, in installation order."""
        return [(p.id, p.outside_tolerance_m3) for p in self._blocks.values()
                if p.outside_tolerance_m3 > tol.volume]

    def protruding(self) -> list[int]:
        """Ids of blocks with volume above the design crest, in installation order."""
        return [p.id for p in self._blocks.values() if p.above_crest_m3 > tol.volume]

    def collisions(self) -> list[tuple[int, int, float]]:
        """``(a, b, depth m)`` of interpenetrating pairs, ``a < b``, sorted."""
        return [(a, b, d) for (a, b), d in sorted(self._collisions.items())]

    def collides(self, block: Block, pose: Pose) -> bool:
        """Whether ``block`` at ``pose`` would collide with a laid block (``shoha check``'s 5 mm rule)."""
        return bool(self._world.query(block, pose, first=True))

    def touching(self, key: int) -> set[int]:
        """Ids of the blocks that block ``key`` touches or overlaps."""
        return set(self._touching.get(key, ()))

    # --- changing -------------------------------------------------------------

    def put(self, key: int, type_name: str, block: Block, pose: Pose, time_s: float | None = None) -> None:
        """Lay block ``key`` at ``pose``, or move it there if it is laid already.

        A BodyError (422), with nothing changed, where more blocks would reach it than could
        without overlapping (:func:`geometry.checks.crowding`), or where it, or a block it
        touches, would overlap the blocks it touches by more than its own volume
        (:func:`geometry.checks.overlapping`): each block's intersections with the blocks it
        touches are unioned, and that union of blocks heaped in one place held the service
        for seconds a block (4999 copies of one pose, for minutes). Every block laid is so
        kept within the rule, whatever the order: a layout the service holds is taken in
        again as a whole save, in any order.
        """
        others = self._world.neighbours(pose.position, block.bounding_radius, exclude=(key,))
        if (wrong := crowding(block, key, len(others))) is not None:
            raise BodyError(422, wrong)
        seq = self._seq.get(key, self._next_seq)
        found = self._contacts(block, pose, seq, others)
        solid = block.posed_solid(pose)
        cut = {other: solid ^ self._solids[other] for other in found}
        parts = {other: None if part.is_empty() else part for other, part in cut.items()}
        volumes = {other: 0.0 if part is None else float(part.volume()) for other, part in parts.items()}
        if (wrong := overlapping(block, key, sum(volumes.values()))) is not None:
            raise BodyError(422, wrong)
        for other, v in volumes.items():
            theirs = self._overlap(other) - self._part_m3.get(_pair(key, other), 0.0) + v
            if (wrong := overlapping(self._blocks[other].block, other, theirs)) is not None:
                raise BodyError(422, f"with block {key} laid there, {wrong}")
        # Checked: from here on the block is laid.
        if key in self._blocks:
            self._take_out(key, keep_slot=True)
        else:
            self._seq[key] = seq
            self._next_seq += 1
        inside = volume_inside(block, pose, self._prism)
        outside = outside_volume(block, pose, self._zone)
        above = self._above_crest(block, pose)
        self._world.add(key, block, pose)
        for other, depth in found.items():
            if depth > tol.contact_depth:
                self._collisions[_pair(key, other)] = depth
        for other, part in parts.items():
            self._parts[_pair(key, other)] = part
            self._part_m3[_pair(key, other)] = volumes[other]
        touching = set(found)
        # A block wholly inside the convex prism has every part of it inside.
        shared = self._inside([p for p in parts.values() if p is not None], trim=inside < block.volume)
        self._filled += inside - shared
        for other in touching:
            self._shared_now.pop(other, None)
        self._shared_now[key] = shared
        self._blocks[key] = Placed(key, type_name, block, pose, time_s, inside, outside, above)
        self._solids[key] = solid
        self._touching[key] = touching
        for other in touching:
            self._touching[other].add(key)

    def remove(self, key: int) -> None:
        """Take block ``key`` out; a KeyError if it is not laid."""
        self._take_out(key, keep_slot=False)

    def _take_out(self, key: int, keep_slot: bool) -> None:
        p = self._blocks[key]
        touching = self._touching.pop(key)
        self._world.remove(key)
        for other in touching:
            self._touching[other].discard(key)
            self._collisions.pop(_pair(key, other), None)
            del self._part_m3[_pair(key, other)]
        parts = [self._parts.pop(_pair(key, other)) for other in touching]
        shared = self._shared_now.pop(key, None)
        if shared is None:
            kept = [part for part in parts if part is not None]
            shared = self._inside(kept, trim=p.inside_m3 < p.block.volume)
        self._filled -= p.inside_m3 - shared
        for other in touching:
            self._shared_now.pop(other, None)
        if keep_slot:
            # A placeholder keeps the block's place in the installation order; put() replaces it.
            self._blocks[key] = p
        else:
            del self._blocks[key]
            del self._solids[key]
            del self._seq[key]
        if not self._blocks:
            self._filled = 0.0  # drop accumulated rounding with the last block

    # --- the checks ---------------------------------------------------------

    def _overlap(self, key: int) -> float:
        """Block ``key``'s intersection volumes with the blocks it touches, summed, m^3
        (:func:`geometry.checks.overlapping` keeps it within the block's own volume)."""
        return sum(self._part_m3[_pair(key, other)] for other in self._touching[key])

    def _inside(self, parts: list[m3.Manifold], trim: bool = True) -> float:
        """Volume of the union of ``parts`` inside the design prism, m^3 (of the union, if not ``trim``).

        ``parts`` are a block's intersections with each block it touches:
        k ∩ (j1 ∪ j2 ...) is (k ∩ j1) ∪ (k ∩ j2) ..., and each pair's
        intersection is small, and cheaper to take (0.07 ms for two posed
        Shake Blocks) than k against the union of all of them.
        """
        if not parts:
            return 0.0
        common = parts[0] if len(parts) == 1 else m3.Manifold.batch_boolean(parts, m3.OpType.Add)
        if not trim:
            return float(common.volume())
        # Trimmed by the prism's planes as geometry.porosity trims its unions of touching blocks.
        return solid_volume_inside(common, self._prism.normals, self._prism.offsets)

    def _above_crest(self, block: Block, pose: Pose) -> float:
        """Volume of the posed block above the design crest's plane, m^3."""
        top = float((block.vertices @ pose.rotation[2] + pose.position[2]).max())
        if top <= self._crest + tol.distance:
            return 0.0
        return max(0.0, block.volume - volume_below(block, pose, _UP, self._crest))

    def _contacts(self, block: Block, pose: Pose, seq: int, others: list[int]) -> dict[int, float]:
        """The blocks of ``others`` that ``block`` at ``pose``, ``seq``-th in the installation
        order, touches: ``{id: depth m}``.

        Touches and collisions are found as ``shoha check`` and the exact
        porosity find them. FCL's answer for a pair depends on which block is
        asked first (its depth by up to 2 mm between Shake Blocks), and they ask
        each pair with its earlier block first; so does this, once per pair,
        in one narrow phase that finds both the touch and the depth.
        """
        return self._world.contacts(block, pose, others, [self._seq[other] > seq for other in others])
