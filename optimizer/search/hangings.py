"""How a crane hangs a block: the orientation families of a slung block.

The reference paper's simulator offers three hangings (Table IV, Fig. 8):
crown, horizontal and level. It shows them but does not define them; shoha
defines them as the three ways a tetrapod-like block can hang with a symmetry
axis vertical, which are the three ways the slings can be rigged:

``crown`` (冠吊り)
    One sling on one leg: that leg points straight up and the block stands on
    its other three legs. This is the block frame itself (leg 0 along +z).
``level``
    Slings on three legs, pulled level: those three legs point up and out at
    the same height, and the fourth hangs straight down, so the block lands
    upright on one leg's end face. The block frame turned over (leg 0 to -z).
``horizontal``
    Slings on two legs, held horizontal: the block hangs by an edge, two legs
    up and two down, the axis through the midpoints of opposite edges vertical.

Each family has a free yaw about the vertical, the crane's slewing of the
hook. The ``free`` family, an option, is any orientation at all.

For blocks that are not tetrapod-like (``box:``, ``mesh:``) the same rotations
are applied to the block frame: as given, upside down, and on its side.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from geometry.blocks import LEG_DIRECTIONS
from geometry.pose import axis_angle_quat, quat_multiply
from geometry.samples import random_quaternion

FAMILIES = ("crown", "level", "horizontal")


def _turn(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The shortest rotation taking direction ``a`` to ``b``, as ``[w, x, y, z]`` (scipy).

    Not for opposite directions, where no rotation is shortest.
    """
    r, _ = Rotation.align_vectors(np.asarray(b, float)[None], np.asarray(a, float)[None])
    return r.as_quat(scalar_first=True)


_EDGE = LEG_DIRECTIONS[0] + LEG_DIRECTIONS[1]  # midpoint direction of the edge joining legs 0 and 1

#: Base orientation of each family, before yaw (scalar-first quaternions). Level
#: hanging is the block frame turned over: half a turn about its x axis takes leg
#: 0 from +z to -z. (Any half turn about a horizontal axis does; the axis fixes
#: the yaw the tuned lattices were found at.)
BASE = {
    "crown": np.array([1.0, 0.0, 0.0, 0.0]),
    "level": axis_angle_quat([1.0, 0.0, 0.0], np.pi),
    "horizontal": _turn(_EDGE, np.array([0.0, 0.0, 1.0])),
}


def hanging(family: str, yaw: float) -> np.ndarray:
    """Orientation ``[w, x, y, z]`` of a block hung in ``family``, turned by ``yaw`` radians."""
    return quat_multiply(axis_angle_quat([0.0, 0.0, 1.0], yaw), BASE[family])


def tilted(q: np.ndarray, tilt: float, azimuth: float) -> np.ndarray:
    """``q`` tipped by ``tilt`` radians about the horizontal axis at ``azimuth``.

    A slung block swings a little before it is set down; small tilts let the
    search nest blocks the way settling after release does.
    """
    axis = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
    return quat_multiply(axis_angle_quat(axis, tilt), q)


def free(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random orientation (the optional ``free`` family)."""
    return random_quaternion(rng)
