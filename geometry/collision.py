"""Which blocks interpenetrate, and by how much (python-fcl).

Each block is a set of convex pieces, each an ``fcl.Convex``. The broadphase
is ours, not FCL's: python-fcl's manager calls back with fresh wrapper objects
that cannot be traced to their block, so blocks are hashed into a uniform grid
of cells by centre, and pairs are pruned by bounding sphere and then by piece
bounding box before FCL's narrow phase (GJK/EPA) runs on piece pairs.

The world is incremental: the optimizer adds, moves and removes one block at
a time and queries only that block against its neighbours.
"""

from __future__ import annotations

import weakref
from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import fcl
import numpy as np

from .blocks import Block
from .constants import tol
from .pose import Pose


@dataclass(frozen=True)
class Collision:
    """Two blocks that interpenetrate by ``depth`` metres (``a < b``)."""

    a: int
    b: int
    depth: float


_GEOMETRY: weakref.WeakKeyDictionary[Block, list[fcl.Convex]] = weakref.WeakKeyDictionary()


def _fcl_pieces(block: Block) -> list[fcl.Convex]:
    """FCL shapes of a block's pieces, built once per block object."""
    shapes = _GEOMETRY.get(block)
    if shapes is None:
        shapes = []
        for piece in block.pieces:
            faces = np.hstack([np.full((len(piece.faces), 1), 3), piece.faces]).ravel()
            shapes.append(fcl.Convex(np.ascontiguousarray(piece.vertices), len(piece.faces), faces))
        _GEOMETRY[block] = shapes
    return shapes


class _Entry:
    __slots__ = ("block", "pose", "objects", "boxes", "centre", "radius", "cell")

    def __init__(self, block: Block, pose: Pose, cell: tuple[int, int, int]):
        self.block = block
        self.cell = cell
        self.objects = [fcl.CollisionObject(g) for g in _fcl_pieces(block)]
        self.radius = block.bounding_radius
        self.set_pose(pose)

    def set_pose(self, pose: Pose) -> None:
        self.pose = pose
        rotation = pose.rotation
        tf = fcl.Transform(rotation, pose.position)
        boxes = np.empty((len(self.objects), 2, 3))
        for i, (obj, piece) in enumerate(zip(self.objects, self.block.pieces, strict=True)):
            obj.setTransform(tf)
            w = piece.vertices @ rotation.T
            boxes[i, 0] = w.min(axis=0)
            boxes[i, 1] = w.max(axis=0)
        boxes += pose.position
        self.boxes = boxes
        self.centre = pose.position


class CollisionWorld:
    """Posed blocks, queried for interpenetration.

    Parameters
    ----------
    cell : float, metres
        Broadphase cell size; about two block bounding radii is best.
    """

    def __init__(self, cell: float = 2.0):
        self.cell = float(cell)
        self._entries: dict[int, _Entry] = {}
        self._grid: dict[tuple[int, int, int], set[int]] = defaultdict(set)
        self._max_radius = 0.0

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, key: int) -> bool:
        return key in self._entries

    def copy(self) -> CollisionWorld:
        """An independent world sharing the (immutable once placed) block entries.

        Search branches copy worlds; :meth:`move` replaces an entry rather
        than changing it, so a shared entry is never changed under a copy.
        """
        other = CollisionWorld(self.cell)
        other._entries = dict(self._entries)
        other._grid = defaultdict(set, {c: set(k) for c, k in self._grid.items() if k})
        other._max_radius = self._max_radius
        return other

    def _cell_of(self, p: np.ndarray) -> tuple[int, int, int]:
        c = np.floor(p / self.cell).astype(int)
        return int(c[0]), int(c[1]), int(c[2])

    def add(self, key: int, block: Block, pose: Pose) -> None:
        cell = self._cell_of(pose.position)
        self._entries[key] = _Entry(block, pose, cell)
        self._grid[cell].add(key)
        self._max_radius = max(self._max_radius, block.bounding_radius)

    def move(self, key: int, pose: Pose) -> None:
        block = self._entries[key].block
        self.remove(key)
        self.add(key, block, pose)

    def remove(self, key: int) -> None:
        e = self._entries.pop(key)
        self._grid[e.cell].discard(key)

    def pose(self, key: int) -> Pose:
        return self._entries[key].pose

    def block(self, key: int) -> Block:
        return self._entries[key].block

    def keys(self) -> list[int]:
        return list(self._entries)

    def neighbours(self, centre: np.ndarray, radius: float, exclude: Iterable[int] = ()) -> list[int]:
        """Keys of blocks whose bounding spheres reach within ``radius`` of ``centre``."""
        reach = radius + self._max_radius
        lo = self._cell_of(np.asarray(centre) - reach)
        hi = self._cell_of(np.asarray(centre) + reach)
        skip = set(exclude)
        out = []
        for i in range(lo[0], hi[0] + 1):
            for j in range(lo[1], hi[1] + 1):
                for k in range(lo[2], hi[2] + 1):
                    for key in self._grid.get((i, j, k), ()):
                        if key in skip:
                            continue
                        e = self._entries[key]
                        if np.sum((e.centre - centre) ** 2) <= (radius + e.radius) ** 2:
                            out.append(key)
        return out

    def query(
        self,
        block: Block,
        pose: Pose,
        exclude: Iterable[int] = (),
        threshold: float = tol.contact_depth,
        first: bool = False,
    ) -> list[tuple[int, float]]:
        """Blocks that ``block`` at ``pose`` penetrates by more than ``threshold``.

        Parameters
        ----------
        exclude : keys to ignore (the block itself, when it is in the world).
        threshold : float, metres
            Penetration at or below this is contact. A negative threshold
            reports any touching pair, with FCL's boolean test only.
        first : bool
            Stop at the first hit (the annealer only needs to know whether).

        Returns
        -------
        list of (key, depth m), depth the deepest over piece pairs.
        """
        probe = _Entry(block, pose, (0, 0, 0))
        hits = []
        for key in self.neighbours(pose.position, block.bounding_radius, exclude):
            depth = _pair_depth(probe, self._entries[key], threshold)
            if depth is not None:
                hits.append((key, depth))
                if first:
                    break
        return hits

    def pairs(self, threshold: float = tol.contact_depth) -> list[Collision]:
        """Every pair of blocks in the world interpenetrating by more than ``threshold``."""
        out = []
        for key, e in self._entries.items():
            for other in self.neighbours(e.centre, e.radius):
                if other <= key:
                    continue
                depth = _pair_depth(e, self._entries[other], threshold)
                if depth is not None:
                    out.append(Collision(key, other, depth))
        out.sort(key=lambda c: (c.a, c.b))
        return out


_REQUEST_DEPTH = fcl.CollisionRequest(num_max_contacts=1, enable_contact=True)
_REQUEST_BOOL = fcl.CollisionRequest(num_max_contacts=1, enable_contact=False)


def _pair_depth(a: _Entry, b: _Entry, threshold: float) -> float | None:
    """Deepest penetration over piece pairs if it exceeds ``threshold``, else None."""
    # Piece bounding boxes that overlap, all pairs in one vectorised test.
    overlap = np.all(
        (a.boxes[:, None, 0] <= b.boxes[None, :, 1]) & (b.boxes[None, :, 0] <= a.boxes[:, None, 1]), axis=2
    )
    deepest = None
    for i, j in zip(*np.nonzero(overlap), strict=True):
        oa, ob = a.objects[i], b.objects[j]
        if threshold < 0:
            if fcl.collide(oa, ob, _REQUEST_BOOL, fcl.CollisionResult()):
                return 0.0
            continue
        result = fcl.CollisionResult()
        if fcl.collide(oa, ob, _REQUEST_DEPTH, result):
            depth = max(c.penetration_depth for c in result.contacts)
            if depth > threshold and (deepest is None or depth > deepest):
                deepest = depth
    return deepest


def world_of(placed: Sequence[tuple[int, Block, Pose]]) -> CollisionWorld:
    """A collision world holding ``(id, Block, Pose)`` blocks."""
    radius = max((b.bounding_radius for _, b, _ in placed), default=1.0)
    world = CollisionWorld(cell=2.0 * radius)
    for key, block, pose in placed:
        world.add(key, block, pose)
    return world


def collisions(
    placed: Sequence[tuple[int, Block, Pose]], threshold: float = tol.contact_depth
) -> list[Collision]:
    """Interpenetrating pairs of a layout, deeper than ``threshold`` metres."""
    return world_of(placed).pairs(threshold)


def overlap_groups(placed: Sequence[tuple[int, Block, Pose]]) -> list[list[int]]:
    """Groups (indices into ``placed``) of two or more blocks that touch or overlap.

    Connected components of the "pieces intersect" graph; the exact porosity
    method unions each group instead of summing its members.
    """
    index = {key: i for i, (key, _, _) in enumerate(placed)}
    parent = list(range(len(placed)))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for c in collisions(placed, threshold=-1.0):
        ra, rb = find(index[c.a]), find(index[c.b])
        if ra != rb:
            parent[ra] = rb
    groups: dict[int, list[int]] = defaultdict(list)
    for i in range(len(placed)):
        groups[find(i)].append(i)
    return [g for g in groups.values() if len(g) > 1]

