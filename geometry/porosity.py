"""Porosity of the design prism: the one module every part of shoha calls.

Porosity is the share of the design trapezoidal prism that no block fills,
eq. (1) of the reference paper::

    Phi = (V_B - V_b) / V_B * 100 %

Three methods (docs/contract.md, ``shoha porosity --method``):

``exact``
    Solid geometry. Each block contributes its volume clipped to the design
    prism (:func:`geometry.clip.volume_inside`): a block wholly inside costs no
    boolean at all. Blocks that touch or overlap (trainee saves) are grouped,
    and each group's union is clipped instead, with manifold3d, so the result
    stays exact.
``voxel``
    Eq. (2) of the paper with the voxel-centre rule: a voxel belongs to the
    prism, or to a block, when its centre does.
``voxel-any``
    The paper's own rule (Unity's ``Physics.OverlapBox``): the prism's voxels
    are those wholly inside it, and a voxel is occupied when any part of it
    touches a block. It over-counts occupied voxels, which is the low bias of
    the paper's Table V.

The grid is the paper's: the bounding box of the design prism cut into
``divisions`` (GridDivisionCount) voxels along each axis, or cut into cubes of
a given voxel size.

The voxel methods never loop over the grid. Each convex piece of each block
is crossed with the vertical lines through the voxel centres under its
footprint (:func:`geometry.polytope.column_intervals`), which gives every
column's occupied run of voxels at once; a voxel touches a piece exactly when
its centre lies in the piece's Minkowski sum with the voxel box. Only the
voxels near each block are written.

:class:`PorosityTracker` adds, moves and removes one block at a time without
recomputing the others; the optimizer lives on it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import manifold3d as m3
import numpy as np

from .blocks import Block
from .clip import solid_volume_inside, volume_inside, volumes_inside
from .collision import overlap_groups
from .constants import MAX_VOXELS, tol
from .errors import InputError
from .polytope import ConvexPolytope, column_intervals
from .pose import Pose
from .scene import Scene

METHODS = ("exact", "voxel", "voxel-any")

Placed = Sequence[tuple[int, Block, Pose]]


@dataclass(frozen=True)
class PorosityResult:
    """A porosity and how it was computed.

    Attributes
    ----------
    percent : float
        Porosity of the design prism, in [0, 100].
    method : str
    divisions : int or None
        GridDivisionCount, for voxel methods given by divisions.
    voxel_size : (3,) float or None, metres
        Voxel edge lengths, for voxel methods.
    blocks : int
    design_volume : float, m^3
        V_B. For voxel methods, the prism's voxel count is ``prism_voxels``.
    filled : float
        V_b in m^3 (exact) or the occupied voxel count n_b (voxel methods).
    prism_voxels : int or None
        n_B, for voxel methods.
    seconds : float
        Compute time.
    """

    percent: float
    method: str
    divisions: int | None
    voxel_size: tuple[float, float, float] | None
    blocks: int
    design_volume: float
    filled: float
    prism_voxels: int | None
    seconds: float


def porosity(
    scene: Scene,
    placed: Placed,
    method: str = "exact",
    divisions: int | None = None,
    voxel_size: float | None = None,
) -> PorosityResult:
    """Porosity of the design prism holding ``placed`` blocks.

    Parameters
    ----------
    scene : Scene
    placed : sequence of (id, Block, Pose)
    method : {"exact", "voxel", "voxel-any"}
    divisions : int, optional
        GridDivisionCount per axis of the prism's bounding box (voxel methods;
        default 100).
    voxel_size : float, optional, metres
        Cubic voxels of this edge instead of ``divisions``.
    """
    start = time.perf_counter()
    if method == "exact":
        filled = exact_filled_volume(scene.design.polytope, placed)
        v_b = scene.design_volume
        percent = 100.0 * (v_b - filled) / v_b
        return PorosityResult(_clip_percent(percent), method, None, None, len(placed), v_b,
                              filled, None, time.perf_counter() - start)
    grid = VoxelGrid.for_scene(scene, method, divisions, voxel_size)
    occupied = np.zeros(grid.shape, dtype=bool)
    for _, block, pose in placed:
        cells = grid.block_cells(block, pose)
        if cells is not None:
            occupied[cells[0]] |= cells[1]
    n_b = int(np.count_nonzero(occupied & grid.prism_mask))
    n_big_b = grid.prism_count
    percent = 100.0 * (n_big_b - n_b) / n_big_b
    return PorosityResult(
        _clip_percent(percent), method, grid.divisions, tuple(map(float, grid.size)), len(placed),
        scene.design_volume, float(n_b), n_big_b, time.perf_counter() - start,
    )


def _clip_percent(p: float) -> float:
    # Clipping noise of ~1e-12 m^3 must not report 100.0000000001 %.
    return float(min(100.0, max(0.0, p)))


# --- exact ---------------------------------------------------------------------


def exact_filled_volume(prism: ConvexPolytope, placed: Placed, assume_disjoint: bool = False) -> float:
    """V_b: block volume inside a convex prism, m^3, exact.

    Parameters
    ----------
    prism : ConvexPolytope, world frame
        The design prism (``scene.design.polytope``).
    placed : sequence of (id, Block, Pose)
    assume_disjoint : bool
        Skip the overlap search, for callers that already know no two blocks
        overlap (the optimizer rejects collisions before it asks).
    """
    contrib = volumes_inside(placed, prism)  # every straddling block cut in one vectorised pass
    total = float(sum(contrib))
    if assume_disjoint or len(placed) < 2:
        return total
    for group in overlap_groups(placed):
        total -= sum(contrib[i] for i in group)
        total += _union_volume_inside([placed[i] for i in group], prism)
    return total


def _union_volume_inside(members: Placed, prism: ConvexPolytope) -> float:
    """Volume of the union of posed blocks, clipped to a convex prism."""
    solids = [b.posed_solid(p) for _, b, p in members]
    return solid_volume_inside(m3.Manifold.batch_boolean(solids, m3.OpType.Add), prism.normals, prism.offsets)


# --- voxels ----------------------------------------------------------------------


class VoxelGrid:
    """A voxel grid over the design prism's bounding box.

    Attributes
    ----------
    origin : (3,) float, metres, world frame
        Lower corner of voxel (0, 0, 0).
    size : (3,) float, metres
        Voxel edge lengths along x, y, z (the paper's voxels are not cubes:
        its bounding box is cut into the same count along every axis).
    shape : (3,) int
    rule : {"center", "any"}
    prism_mask : (nx, ny, nz) bool
        Voxels that belong to the prism under ``rule``.
    """

    def __init__(self, origin: np.ndarray, size: np.ndarray, shape: tuple[int, int, int],
                 prism: ConvexPolytope, rule: str, divisions: int | None):
        self.origin = np.asarray(origin, dtype=float)
        self.size = np.asarray(size, dtype=float)
        self.shape = tuple(int(n) for n in shape)
        self.rule = rule
        self.divisions = divisions
        self.centres = [self.origin[a] + (np.arange(self.shape[a]) + 0.5) * self.size[a] for a in range(3)]
        if rule == "any":
            # The paper keeps the voxels wholly inside the prism.
            normals, offsets = prism.eroded_box_planes(self.size / 2)
        else:
            normals, offsets = prism.normals, prism.offsets
        xy = np.stack(np.meshgrid(self.centres[0], self.centres[1], indexing="ij"), -1).reshape(-1, 2)
        lo, hi = column_intervals(normals, offsets, xy)
        k0, k1 = self._k_range(lo, hi)
        k = np.arange(self.shape[2])
        self.prism_mask = ((k >= k0[:, None]) & (k <= k1[:, None])).reshape(self.shape)
        self.prism_count = int(np.count_nonzero(self.prism_mask))
        if self.prism_count == 0:
            raise InputError("voxel grid: no voxel lies in the design prism; "
                             "use more divisions or a smaller voxel size")

    @classmethod
    def for_scene(cls, scene: Scene, method: str, divisions: int | None = None,
                  voxel_size: float | None = None) -> VoxelGrid:
        """The grid ``method`` uses on ``scene``'s design prism."""
        if method not in ("voxel", "voxel-any"):
            raise InputError(f"unknown voxel method {method!r}: use voxel or voxel-any")
        bounds = scene.design.bounds
        extent = bounds[1] - bounds[0]
        if voxel_size is not None:
            if divisions is not None:
                raise InputError("give divisions or a voxel size, not both")
            if not (np.isfinite(voxel_size) and voxel_size > 0):
                raise InputError(f"voxel size must be a positive number of metres, not {voxel_size}")
            # Counted in floats first: at 1e-19 m the counts overflow int64 and their product
            # came out negative, past the size check.
            counts = np.maximum(1.0, np.ceil(extent / voxel_size - tol.relative))
            if math.prod(float(c) for c in counts) > MAX_VOXELS:
                grid = " x ".join(f"{c:.3g}" for c in counts)
                raise InputError(f"voxel size {voxel_size:g} m makes a grid of {grid} voxels, "
                                 f"more than {MAX_VOXELS:.3g}")
            shape = counts.astype(np.int64)
            size = np.full(3, float(voxel_size))
        else:
            divisions = 100 if divisions is None else divisions
            if not isinstance(divisions, (int, np.integer)) or divisions < 1:
                raise InputError(f"divisions must be a positive integer, not {divisions!r}")
            shape = np.full(3, int(divisions), dtype=np.int64)
            size = extent / divisions
        if float(np.prod(shape.astype(float))) > MAX_VOXELS:
            raise InputError(
                f"voxel grid of {' x '.join(map(str, shape))} voxels is more than {MAX_VOXELS:.3g}"
            )
        rule = "any" if method == "voxel-any" else "center"
        return cls(bounds[0], size, tuple(shape), scene.design.polytope, rule, divisions)

    @property
    def voxel_volume(self) -> float:
        return float(np.prod(self.size))

    def _k_range(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Voxel index range ``k0..k1`` whose centres lie in ``[lo, hi]`` along z."""
        oz, dz, nz = self.origin[2], self.size[2], self.shape[2]
        with np.errstate(invalid="ignore"):
            k0 = np.ceil((lo - oz) / dz - 0.5 - tol.distance)
            k1 = np.floor((hi - oz) / dz - 0.5 + tol.distance)
        # Clipping maps -inf and +inf to the grid's ends; a NaN bound (a column no
        # plane bounds sensibly) leaves its column empty. The NaN check is one pass,
        # and the repair runs only where there is one.
        bad = np.isnan(k0) | np.isnan(k1)
        np.clip(k0, 0, nz, out=k0)
        np.clip(k1, -1, nz - 1, out=k1)
        if bad.any():
            k0[bad], k1[bad] = nz, -1
        return k0.astype(np.int64), k1.astype(np.int64)

    def _index_range(self, axis: int, lo: float, hi: float) -> tuple[int, int]:
        """Half-open index range of voxels whose centres lie in ``[lo, hi]`` on an axis.

        Plain floats, not NumPy scalars: this runs for every piece of every
        block a tracker moves. A range off the grid (or NaN) is ``(n, 0)``,
        empty and neutral when ranges are merged by min and max.
        """
        o, d, n = float(self.origin[axis]), float(self.size[axis]), self.shape[axis]
        a, b = (lo - o) / d - 0.5, (hi - o) / d - 0.5
        if not (a <= n and b >= -1.0):
            return n, 0
        return max(math.ceil(max(a, -1.0)), 0), min(math.floor(min(b, float(n))) + 1, n)

    def block_cells(self, block: Block, pose: Pose) -> tuple[tuple[slice, slice, slice], np.ndarray] | None:
        """The voxels a posed block occupies under this grid's rule.

        Returns
        -------
        (slices, mask) or None
            ``mask`` is a bool array over ``grid[slices]``, the block's
            neighbourhood; None if the block misses the grid.
        """
        rotation, t = pose.rotation, pose.position
        # Each piece as (planes, bounding box): under the "any" rule, the piece's
        # Minkowski sum with a voxel (the centres of the voxels that touch it).
        half = self.size / 2 if self.rule == "any" else None
        pieces = [(n, d, lo.tolist(), hi.tolist()) for n, d, lo, hi in block.stack.planes(rotation, t, half)]
        ranges = [[self._index_range(a, lo[a], hi[a]) for a in range(3)] for _, _, lo, hi in pieces]
        r = np.array(ranges)  # (pieces, 3, 2)
        b0, b1 = r[:, :, 0].min(axis=0), r[:, :, 1].max(axis=0)
        if np.any(b1 <= b0):
            return None
        ni, nj, nk = (int(n) for n in b1 - b0)
        cols, los, his = [], [], []
        for (normals, offsets, _, _), pr in zip(pieces, r, strict=True):
            (i0, i1), (j0, j1), _ = pr
            if i1 <= i0 or j1 <= j0:
                continue
            ii = np.repeat(np.arange(i0, i1), j1 - j0)
            jj = np.tile(np.arange(j0, j1), i1 - i0)
            lo, hi = column_intervals(normals, offsets,
                                      np.column_stack([self.centres[0][ii], self.centres[1][jj]]))
            cols.append((ii - b0[0]) * nj + (jj - b0[1]))
            los.append(lo)
            his.append(hi)
        if not cols:
            return None
        # One pass for every piece's columns: each column's run k0..k1 goes into a
        # difference array along z (+1 at k0, -1 after k1), summed by bincount, which
        # adds up a column that several pieces share.
        k0, k1 = self._k_range(np.concatenate(los), np.concatenate(his))
        col = np.concatenate(cols)
        hit = k1 >= k0
        col, k0, k1 = col[hit] * (nk + 1), k0[hit] - b0[2], k1[hit] - b0[2]
        size = ni * nj * (nk + 1)
        diff = (np.bincount(col + np.clip(k0, 0, nk), minlength=size)
                - np.bincount(col + np.clip(k1 + 1, 0, nk), minlength=size))
        mask = np.cumsum(diff.reshape(ni, nj, nk + 1), axis=2)[:, :, :nk] > 0
        slices = (slice(b0[0], b1[0]), slice(b0[1], b1[1]), slice(b0[2], b1[2]))
        return slices, mask


# --- incremental -----------------------------------------------------------------------


class PorosityTracker:
    """Porosity kept up to date as blocks are added, moved and removed.

    Each change costs one block's work, not the layout's. With ``exact`` the
    tracker sums clipped block volumes and so assumes that no two blocks
    overlap, which the optimizer guarantees by rejecting collisions first;
    the voxel methods count voxel occupancy and allow overlaps.

    Parameters
    ----------
    scene : Scene
    method : {"exact", "voxel", "voxel-any"}
    divisions, voxel_size : see :func:`porosity`.
    """

    def __init__(self, scene: Scene, method: str = "exact", divisions: int | None = None,
                 voxel_size: float | None = None):
        if method not in METHODS:
            raise InputError(f"unknown porosity method {method!r}: use {', '.join(METHODS)}")
        self.scene = scene
        self.method = method
        self._prism = scene.design.polytope
        self._blocks: dict[int, tuple[Block, Pose, object]] = {}
        self.filled = 0.0
        if method == "exact":
            self.grid = None
            self._total = scene.design_volume
        else:
            self.grid = VoxelGrid.for_scene(scene, method, divisions, voxel_size)
            self._count = np.zeros(self.grid.shape, dtype=np.uint16)
            self._total = float(self.grid.prism_count)

    def __len__(self) -> int:
        return len(self._blocks)

    def __contains__(self, key: int) -> bool:
        return key in self._blocks

    @property
    def percent(self) -> float:
        """Current porosity, percent."""
        return _clip_percent(100.0 * (self._total - self.filled) / self._total)

    def percent_with(self, filled: float) -> float:
        """Porosity if the filled amount were ``filled``."""
        return _clip_percent(100.0 * (self._total - filled) / self._total)

    def gain(self, block: Block, pose: Pose) -> float:
        """How much ``block`` at ``pose`` would add to the filled amount, without adding it.

        m^3 for ``exact``; newly occupied prism voxels for the voxel methods.
        """
        if self.grid is None:
            return volume_inside(block, pose, self._prism)
        cells = self.grid.block_cells(block, pose)
        if cells is None:
            return 0.0
        sl, mask = cells
        return float(np.count_nonzero(mask & (self._count[sl] == 0) & self.grid.prism_mask[sl]))

    def add(self, key: int, block: Block, pose: Pose) -> float:
        """Add a block; returns the new porosity, percent."""
        if key in self._blocks:
            raise KeyError(f"block {key} is already tracked")
        if self.grid is None:
            v = volume_inside(block, pose, self._prism)
            self.filled += v
            self._blocks[key] = (block, pose, v)
            return self.percent
        cells = self.grid.block_cells(block, pose)
        if cells is not None:
            sl, mask = cells
            region = self._count[sl]
            self.filled += float(np.count_nonzero(mask & (region == 0) & self.grid.prism_mask[sl]))
            region += mask
        self._blocks[key] = (block, pose, cells)
        return self.percent

    def remove(self, key: int) -> float:
        """Remove a block; returns the new porosity, percent."""
        block, pose, state = self._blocks.pop(key)
        if self.grid is None:
            self.filled -= state
            if not self._blocks:
                self.filled = 0.0  # drop accumulated rounding with the last block
            return self.percent
        if state is not None:
            sl, mask = state
            region = self._count[sl]
            region -= mask
            self.filled -= float(np.count_nonzero(mask & (region == 0) & self.grid.prism_mask[sl]))
        return self.percent

    def move(self, key: int, pose: Pose) -> float:
        """Move a block to ``pose``; returns the new porosity, percent."""
        block = self._blocks[key][0]
        self.remove(key)
        return self.add(key, block, pose)

    def pose(self, key: int) -> Pose:
        return self._blocks[key][1]

    def occupied(self) -> np.ndarray:
        """Voxel methods: the prism's voxels that some block fills, a bool array over ``grid``."""
        if self.grid is None:
            raise NotImplementedError("the exact method keeps no voxels; use a voxel method")
        return (self._count > 0) & self.grid.prism_mask

    def contribution(self, key: int) -> float:
        """What a tracked block adds to ``filled`` now (exact method: its clipped volume, m^3)."""
        if self.grid is not None:
            raise NotImplementedError("a voxel block's share depends on its neighbours; use remove()")
        return float(self._blocks[key][2])

    def copy(self) -> PorosityTracker:
        """An independent tracker in the same state (search branches copy it)."""
        other = PorosityTracker.__new__(PorosityTracker)
        other.__dict__.update(self.__dict__)
        other._blocks = dict(self._blocks)
        if self.grid is not None:
            other._count = self._count.copy()
        return other
