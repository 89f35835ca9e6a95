"""How much of a posed block lies inside a convex prism, exactly.

Porosity (the design prism) and the tolerance check (the tolerance prism)
both ask this question; they ask it here. A block wholly inside, or wholly
outside, is settled by its vertices alone; only a block that straddles a face
is clipped, by manifold3d, against just the planes it crosses.
"""

from __future__ import annotations

import numpy as np

from .blocks import Block
from .constants import tol
from .polytope import ConvexPolytope
from .pose import Pose


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
    is trimmed by each plane some vertex crosses (``Manifold.trim_by_plane``),
    about 0.1 ms per plane for the Shake Block.
    """
    rotation = pose.rotation
    world = block.vertices @ rotation.T + pose.position
    excess = world @ prism.normals.T - prism.offsets  # (n, k), > 0 outside a plane
    worst = excess.max(axis=0)
    crossed = worst > tol.distance
    if not crossed.any():
        return block.volume
    if np.any(excess.min(axis=0) >= -tol.distance):
        return 0.0  # every vertex is on the far side of one plane
    solid = block.manifold.transform(np.hstack([rotation, pose.position[:, None]]))
    for n, d in zip(prism.normals[crossed], prism.offsets[crossed], strict=True):
        # trim_by_plane keeps n' . p >= d'; we keep n . p <= d.
        solid = solid.trim_by_plane(-n, -d)
    return float(solid.volume())
