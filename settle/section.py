"""Section scenes: blocks that are prisms along y, moving only in x-z.

A scene of kind ``"section"`` is a slice of a breakwater whose blocks are all
extruded along the crest (the world y axis) through the slice. Its physics is
2D (issue 3, "Model no more than the scene needs"):

* every convex piece of the block is a right prism along the block's local y
  axis (a ``box:AxBxC`` block is; ``B`` is its extent along the crest);
* every block's pose turns it about the world y axis only, so that local y
  stays world y;
* a block's 2D shape is the x-z outline of its pieces; its 2D mass and moment
  are the block's mass and its moment of inertia about local y, which for a
  prism are exactly the 3D ones.

This module maps poses and blocks between 3D and the 2D (u, v) = (x, z)
plane. A rotation by ``theta`` about +y maps block (x, z) to world
``(x cos + z sin, -x sin + z cos)``; in the (u, v) plane that is a
counter-clockwise turn by ``-theta``.
"""

from __future__ import annotations

from functools import cache

import numpy as np
from scipy.spatial import ConvexHull

from geometry.blocks import Block
from geometry.constants import tol
from geometry.errors import InputError
from geometry.pose import Pose, axis_angle_quat
from geometry.scene import Scene

#: Relative difference between a piece's volume and (outline area) x (y
#: extent) tolerated for it to count as a prism along y (tol.prism_rtol).
PRISM_RTOL = tol.prism_rtol


@cache
def _outlines(block: Block) -> tuple[np.ndarray, ...]:
    out = []
    for i, piece in enumerate(block.pieces):
        xz = piece.vertices[:, [0, 2]]
        hull = ConvexHull(xz)
        depth = float(np.ptp(piece.vertices[:, 1]))
        # A convex solid holds at most (outline area) x (depth), with equality
        # exactly when it is a prism along y.
        if abs(hull.volume * depth - piece.volume) > PRISM_RTOL * piece.volume:
            raise InputError(
                f"block {block.name}: piece {i} is not a prism along its local y axis, "
                "so it cannot stand in a section scene (use a box:AxBxC block)"
            )
        out.append(np.ascontiguousarray(xz[hull.vertices]))  # counter-clockwise
    return tuple(out)


def outlines(block: Block) -> tuple[np.ndarray, ...]:
    """The x-z outlines of a block's pieces.

    Returns
    -------
    tuple of (k, 2) float, metres, block frame (x, z)
        One counter-clockwise convex polygon per piece.

    Raises
    ------
    InputError
        If a piece is not a prism along local y.
    """
    return _outlines(block)


def plane_angle(pose: Pose, where: str = "block") -> float:
    """The angle ``theta`` (radians) of a pose that turns only about world +y.

    Raises
    ------
    InputError
        If the pose tilts local y out of world y.
    """
    r = pose.rotation
    tilt = float(np.linalg.norm(r[:, 1] - np.array([0.0, 1.0, 0.0])))
    if tilt > tol.plane_angle:
        raise InputError(
            f"{where}: in a section scene a block may turn only about the y axis "
            f"(its local y is off world y by {np.degrees(tilt):.3g} deg)"
        )
    return float(np.arctan2(r[0, 2], r[0, 0]))


def to_plane(pose: Pose, where: str = "block") -> tuple[tuple[float, float], float]:
    """A pose as a 2D position (x, z), metres, and a counter-clockwise angle, radians."""
    theta = plane_angle(pose, where)
    return (float(pose.position[0]), float(pose.position[2])), -theta


def from_plane(position: tuple[float, float], angle: float, y: float) -> Pose:
    """The 3D pose of a 2D position (x, z) and counter-clockwise angle, at crest coordinate ``y``."""
    return Pose([position[0], y, position[1]], axis_angle_quat(np.array([0.0, 1.0, 0.0]), -angle))


def foundation_profile(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """The foundation of a section scene: its profile along the middle of the slice.

    A section scene is extruded along y, its foundation too: both backends
    use the rough underlayer's heights at ``y = length / 2`` for the whole
    slice, so that a layout resting on the profile in 2D rests on it in 3D.

    Returns
    -------
    xs : (n,) float, metres
        The height field's x nodes.
    zs : (n,) float, metres
        The foundation's height there.
    """
    xs = scene.foundation.grid[0]
    y = scene.length / 2
    return xs, scene.foundation.height_at(np.column_stack([xs, np.full(len(xs), y)]))
