"""How much of a posed block lies inside a convex prism, exactly.

Porosity (the design prism) and the tolerance check (the tolerance prism)
both ask this question; they ask it here. A block wholly inside, or wholly
outside, is settled by its vertices alone; only a block that straddles a face
is clipped, against just the planes it crosses: its surface triangles are cut
by those planes and the volume summed by the divergence theorem, or, where
that does not apply, the solid is trimmed by manifold3d. :func:`volumes_inside`
does the same for a whole layout, cutting every straddling block in one
vectorised pass.
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence

import manifold3d as m3
import numpy as np

from .blocks import Block
from .constants import tol
from .polytope import ConvexPolytope
from .pose import Pose

_FACE_PRODUCTS: weakref.WeakKeyDictionary[Block, tuple[np.ndarray, np.ndarray]] = weakref.WeakKeyDictionary()


def volume_inside(block: Block, pose: Pose, prism: ConvexPolytope) -> float:
    """Volume of ``block`` at ``pose`` that lies inside ``prism``, m^3.

    Parameters
    ----------
    block : Block
    pose : Pose
        Block frame to world frame.
    prism : ConvexPolytope, world frame

    Notes
    -----
    A convex prism contains a solid exactly when it contains its vertices, so
    the common cases cost one ``(n, 3) @ (3, k)`` product. A straddling block
    is cut by each plane some vertex crosses, as :func:`volumes_inside`
    explains (about 0.05 ms for the Shake Block's 140 triangles and one
    plane, 0.1 ms for two: see :func:`_clipped_triple_sum`); where the
    crossed planes share no point, it is trimmed by ``Manifold.trim_by_plane``
    instead (about 0.3 ms).
    """
    world = block.vertices @ pose.rotation.T + pose.position
    excess = world @ prism.normals.T - prism.offsets  # (n, k), > 0 outside a plane
    crossed = excess.max(axis=0) > tol.distance
    if not crossed.any():
        return block.volume
    if np.any(excess.min(axis=0) >= -tol.distance):
        return 0.0  # every vertex is on the far side of one plane
    normals, offsets = prism.normals[crossed], prism.offsets[crossed]
    apex = _common_point(normals, offsets)
    if apex is None:
        return _trimmed_volume(block, pose, normals, offsets)
    if len(normals) == 1:
        return _cut_by_one_plane(block, pose, excess[:, np.flatnonzero(crossed)[0]], apex)
    # One block: clip its triangles by every crossed plane but the last, plane by plane (the batch's
    # bookkeeping costs more here); the last plane's cut is summed without building its triangles.
    tri = world[block.faces] - apex
    owner = np.zeros(len(tri), dtype=np.int64)
    for n in normals[:-1]:
        tri, owner = _clip_triangles(tri, owner, tri @ n)
    return _clipped_triple_sum(_triple(tri), tri @ normals[-1]) / 6.0


def volume_below(block: Block, pose: Pose, normal: np.ndarray, offset: float) -> float:
    """Volume of ``block`` at ``pose`` on the side ``normal . p <= offset`` of a plane, m^3 (exact).

    As :func:`volume_inside` cuts a block that crosses one plane of its prism:
    no triangle is built.
    """
    distance = block.vertices @ (pose.rotation.T @ normal) + (float(pose.position @ normal) - offset)
    if distance.max() <= 0.0:
        return block.volume
    if distance.min() >= 0.0:
        return 0.0
    return _cut_by_one_plane(block, pose, distance, normal * (offset / float(normal @ normal)))


def _cut_by_one_plane(block: Block, pose: Pose, distance: np.ndarray, apex: np.ndarray) -> float:
    """Volume of the posed block on the inner side of one plane through ``apex`` (world frame), m^3.

    ``distance`` (n,) holds the block's vertices' signed distances to the
    plane. Each surface triangle's product from the apex comes from the block
    frame's (:func:`_face_products`), and the plane's cut from the distances
    (:func:`_clipped_triple_sum`).
    """
    det, normal = _face_products(block)
    triple = det + normal @ (pose.rotation.T @ (pose.position - apex))
    return _clipped_triple_sum(triple, distance[block.faces]) / 6.0


def volumes_inside(placed: Sequence[tuple[int, Block, Pose]], prism: ConvexPolytope) -> np.ndarray:
    """:func:`volume_inside` of each ``(id, Block, Pose)``, (n,) float, m^3.

    Notes
    -----
    By the divergence theorem a solid's volume is ``1/3`` of the integral of
    ``(p - o) . n`` over its boundary, for any point ``o``. A block cut by
    some of the prism's planes is bounded by the part of its surface inside
    them, plus a cap on each crossed plane; with ``o`` on every crossed plane,
    ``(p - o) . n`` vanishes on the caps. So its volume is the sum of the
    signed tetrahedra from ``o`` to its surface triangles clipped by those
    planes, and the caps are never built. Every straddling block is clipped in
    one pass over the prism's planes, each block with its own ``o``.
    """
    out = np.empty(len(placed))
    straddling: list[int] = []
    cut: list[tuple[np.ndarray, Block, Pose, np.ndarray]] = []  # world vertices, block, pose, crossed
    same_block: dict[int, list[int]] = {}
    for i, (_, block, _) in enumerate(placed):
        same_block.setdefault(id(block), []).append(i)
    for members in same_block.values():
        # The vertex test of every block of one type at once: (b, n, 3) vertices, (b, n, k) excess.
        block = placed[members[0]][1]
        poses = [placed[i][2] for i in members]
        world = np.einsum("bij,nj->bni", np.stack([pose.rotation for pose in poses]), block.vertices)
        world += np.stack([pose.position for pose in poses])[:, None, :]
        excess = world @ prism.normals.T - prism.offsets  # > 0 outside a plane
        crossed = excess.max(axis=1) > tol.distance
        beyond = np.any(excess.min(axis=1) >= -tol.distance, axis=1)  # all vertices past one plane
        for n, i in enumerate(members):
            if not crossed[n].any():
                out[i] = block.volume
            elif beyond[n]:
                out[i] = 0.0
            else:
                straddling.append(i)
                cut.append((world[n], block, poses[n], crossed[n]))
    if cut:
        out[straddling] = _cut_volumes(cut, prism)
    return out


def _cut_volumes(cut: list[tuple[np.ndarray, Block, Pose, np.ndarray]], prism: ConvexPolytope) -> np.ndarray:
    """Volumes inside ``prism`` of straddling blocks, (len(cut),) m^3.

    ``cut`` holds each block's world vertices, block, pose, and the (k,) bool
    mask of the prism planes it crosses. See :func:`volumes_inside`.
    """
    out = np.empty(len(cut))
    apexes: dict[bytes, np.ndarray | None] = {}
    clip, rows, apex_rows = [], [], []
    for n, (world, block, pose, crossed) in enumerate(cut):
        key = crossed.tobytes()
        if key not in apexes:
            apexes[key] = _common_point(prism.normals[crossed], prism.offsets[crossed])
        if apexes[key] is None:
            # The crossed planes share no point (say, top and bottom): manifold3d trims it.
            out[n] = _trimmed_volume(block, pose, prism.normals[crossed], prism.offsets[crossed])
        else:
            clip.append((world, block, crossed))
            rows.append(n)
            apex_rows.append(apexes[key])
    if not clip:
        return out
    owner = np.repeat(np.arange(len(clip)), [len(block.faces) for _, block, _ in clip])
    # Triangles (m, 3, 3) with each block's point o at the origin: its crossed planes pass through it.
    tri = np.concatenate([world[block.faces] - apex
                          for (world, block, _), apex in zip(clip, apex_rows, strict=True)])
    crosses = np.array([crossed for _, _, crossed in clip])  # (blocks, k)
    # Most triangles lie inside every plane their block crosses, or wholly past one of them:
    # they are kept or dropped as they are, and only the rest are clipped.
    beyond = (tri @ prism.normals.T > 0.0) & crosses[owner][:, None, :]  # (m, 3, k)
    kept = ~beyond.any(axis=(1, 2))
    straddle = ~kept & ~beyond.all(axis=1).any(axis=1)
    volumes = np.bincount(owner[kept], weights=_triple(tri[kept]), minlength=len(clip)).astype(float)
    tri, owner = tri[straddle], owner[straddle]
    for j, normal in enumerate(prism.normals):
        if not crosses[:, j].any():
            continue
        s = tri @ normal
        s[~crosses[owner, j]] = -1.0  # a block that does not cross this plane keeps its triangles
        tri, owner = _clip_triangles(tri, owner, s)
    out[rows] = (volumes + np.bincount(owner, weights=_triple(tri), minlength=len(clip))) / 6.0
    return out


def _triple(tri: np.ndarray) -> np.ndarray:
    """``a . (b x c)`` of triangles ``(m, 3, 3)``: six times the signed tetrahedra from the origin.

    Written out: ``np.linalg.det`` costs several times more on 3 x 3 stacks.
    """
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    return (a[:, 0] * (b[:, 1] * c[:, 2] - b[:, 2] * c[:, 1])
            + a[:, 1] * (b[:, 2] * c[:, 0] - b[:, 0] * c[:, 2])
            + a[:, 2] * (b[:, 0] * c[:, 1] - b[:, 1] * c[:, 0]))


def _face_products(block: Block) -> tuple[np.ndarray, np.ndarray]:
    """Each surface triangle's ``a . (b x c)`` and ``(b - a) x (c - a)``, block frame: (m,) and (m, 3).

    Posed by ``R`` and moved by ``u``, a triangle's product is
    ``(Ra + u) . ((Rb + u) x (Rc + u)) = a . (b x c) + (R^T u) . ((b - a) x (c - a))``
    (the terms with ``u`` twice vanish, and ``R`` keeps cross products), so
    one matrix-vector product gives every posed triangle's.
    """
    products = _FACE_PRODUCTS.get(block)
    if products is None:
        a, b, c = (block.vertices[block.faces[:, i]] for i in range(3))
        products = _triple(np.stack([a, b, c], axis=1)), np.cross(b - a, c - a)
        _FACE_PRODUCTS[block] = products
    return products


def _clipped_triple_sum(triple: np.ndarray, s: np.ndarray) -> float:
    """Sum of ``a . (b x c)`` over the parts of triangles where ``s`` (m, 3) is <= 0.

    ``triple`` (m,) holds each whole triangle's product, and ``s`` its
    vertices' signed distances to a plane through the origin. The part of a
    triangle ``abc`` cut off at its lone vertex ``a`` (the one on its side of
    the plane) is ``a p q``, with ``p = a + t_b (b - a)`` and ``q = a + t_c (c - a)``
    on the plane, ``t = s_a / (s_a - s_other)``; expanding the product, every
    term but one has ``a`` twice, so ``a . (p x q) = t_b t_c a . (b x c)``. A
    lone vertex inside keeps that share of the triangle's product, a lone
    vertex outside loses it: no clipped triangle need be built.
    """
    inside = s <= 0.0
    count = inside.sum(axis=1)
    share = (count == 3).astype(float)
    rows = np.flatnonzero((count == 1) | (count == 2))
    if len(rows):
        one = count[rows] == 1
        lone = np.where(one, inside[rows].argmax(axis=1), inside[rows].argmin(axis=1))
        d = s[rows[:, None], (lone[:, None] + np.arange(3)) % 3]  # the lone vertex's distance first
        cut = d[:, 0] * d[:, 0] / ((d[:, 0] - d[:, 1]) * (d[:, 0] - d[:, 2]))
        share[rows] = np.where(one, cut, 1.0 - cut)
    return float(triple @ share)


def _common_point(normals: np.ndarray, offsets: np.ndarray) -> np.ndarray | None:
    """A point on every plane ``normals @ p = offsets``, or None if they share none."""
    if len(normals) == 1:
        return normals[0] * offsets[0]  # the foot of the origin
    if len(normals) == 2:
        # The point of the planes' common line nearest the origin, as lstsq would find it, in closed form.
        (n1, n2), (d1, d2) = normals, offsets
        c = float(n1 @ n2)
        if 1.0 - c * c < 1e-12:
            return None  # parallel planes
        return ((d1 - d2 * c) * n1 + (d2 - d1 * c) * n2) / (1.0 - c * c)
    point = np.linalg.lstsq(normals, offsets, rcond=None)[0]
    if np.abs(normals @ point - offsets).max() > tol.distance:
        return None
    return point


def _trimmed_volume(block: Block, pose: Pose, normals: np.ndarray, offsets: np.ndarray) -> float:
    """Volume of the posed block's solid on the inner side of every plane, by manifold3d."""
    return solid_volume_inside(block.posed_solid(pose), normals, offsets)


def solid_volume_inside(solid: m3.Manifold, normals: np.ndarray, offsets: np.ndarray) -> float:
    """Volume of a manifold3d solid on the inner side (``n . p <= d``) of every plane, m^3.

    The solid is trimmed only by the planes its bounding box crosses: the
    others leave it whole. The exact porosity's unions of touching blocks and
    the live layout's shared parts are both measured here.
    """
    box = np.array(solid.bounding_box()).reshape(2, 3)
    corners = box[_CORNERS, [0, 1, 2]]  # (8, 3)
    crossed = (corners @ normals.T - offsets).max(axis=0) > 0.0
    for n, d in zip(normals[crossed], offsets[crossed], strict=True):
        solid = solid.trim_by_plane(-n, -d)  # trim_by_plane keeps n' . p >= d'; we keep n . p <= d
    return float(solid.volume())


#: Row (0: min, 1: max) of each coordinate at the eight corners of a box.
_CORNERS = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])


def _clip_triangles(tri: np.ndarray, owner: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The parts of triangles ``(m, 3, 3)`` where the signed distance ``s`` (m, 3) is <= 0.

    A triangle with one vertex inside becomes one triangle, with two inside a
    quadrilateral, split in two; ``owner`` (m,) follows each piece. Vertices
    are cycled, never swapped, so every triangle keeps its orientation.
    """
    inside = s <= 0.0
    count = inside.sum(axis=1)
    whole = count == 3
    rows = np.flatnonzero((count == 1) | (count == 2))
    if len(rows) == 0:
        return tri[whole], owner[whole]
    one = count[rows] == 1
    # Cycle the odd vertex first: the one inside (one vertex in), else the one outside.
    odd = np.where(one, inside[rows].argmax(axis=1), inside[rows].argmin(axis=1))
    order = (odd[:, None] + np.arange(3)) % 3
    t, d = tri[rows[:, None], order], s[rows[:, None], order]
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    # Where edges a-b and a-c cross the plane (d_a has the other sign than d_b, d_c).
    p = a + (b - a) * (d[:, 0] / (d[:, 0] - d[:, 1]))[:, None]
    q = a + (c - a) * (d[:, 0] / (d[:, 0] - d[:, 2]))[:, None]
    two = ~one
    cut_owner = owner[rows]
    return (
        np.concatenate([tri[whole], np.stack([a, p, q], axis=1)[one], np.stack([p, b, c], axis=1)[two],
                        np.stack([p, c, q], axis=1)[two]]),
        np.concatenate([owner[whole], cut_owner[one], cut_owner[two], cut_owner[two]]),
    )
