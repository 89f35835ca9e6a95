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

Those three are the built-in tetrapod-like blocks' (``shake-4t``,
``tetrapod``), whose block frame puts leg 0 along +z. Any other block, a
``box:`` or a user's ``mesh:`` in whatever frame its file comes, hangs the
ways its own shape rests: its rest poses (``geometry.blocks.rest_poses``,
faces of its convex hull it stands on without tipping), named ``rest-1``
(the most stable), ``rest-2`` and so on. For a tetrapod-like mesh these are
the same three hangings, found from the shape (crown: three legs down;
level: one leg down; horizontal: two legs down), whatever its frame.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from geometry.blocks import LEG_DIRECTIONS, Block
from geometry.fileio import ascii_digits
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


#: Most rest poses a block's hangings take (the least stable are of little use).
MAX_REST_HANGINGS = 3


def hanging(family: str, yaw: float) -> np.ndarray:
    """Orientation ``[w, x, y, z]`` of a built-in tetrapod-like block in ``family``, turned by ``yaw``."""
    return quat_multiply(axis_angle_quat([0.0, 0.0, 1.0], yaw), BASE[family])


def named(block: Block) -> bool:
    """Whether the block's frame is a built-in tetrapod-like one, with leg 0 along +z."""
    return block.name == "shake-4t" or block.name.startswith("tetrapod")


def families(block: Block) -> tuple[str, ...]:
    """The hangings a block can be set down in: crown, level and horizontal, or its rest poses."""
    if named(block):
        return FAMILIES
    return tuple(f"rest-{i + 1}" for i in range(min(MAX_REST_HANGINGS, len(block.rest_poses))))


def symmetry(block: Block, family: str) -> int:
    """The order of a hanging's symmetry about the vertical: three for the tetrapod-likes' own."""
    if named(block) and family in BASE:
        return 3 if family in ("crown", "level") else 2
    return block.rest_poses[_rest_index(block, family)].symmetry


def spread_yaws(block: Block, families: Sequence[str], per: int) -> list[tuple[str, float]]:
    """(hanging, yaw) pairs: each hanging of ``families`` but ``free`` at ``per`` yaws spread evenly
    over its symmetry period (a turn by the period gives the same shape)."""
    return [(f, float(k * (2 * math.pi / symmetry(block, f)) / per))
            for f in families if f != "free" for k in range(per)]


def _rest_index(block: Block, family: str) -> int:
    number = family[5:]
    if family.startswith("rest-") and ascii_digits(number) and 0 < int(number) <= len(block.rest_poses):
        return int(number) - 1
    raise ValueError(f"{block.name}: no hanging {family!r} (it has {', '.join(families(block))})")


def hanging_of(block: Block, family: str, yaw: float) -> np.ndarray:
    """Orientation ``[w, x, y, z]`` of ``block`` in ``family`` (one of :func:`families`), turned by ``yaw``.

    Raises
    ------
    ValueError
        For a family the block has not.
    """
    if named(block) and family in BASE:
        base = BASE[family]
    else:
        base = block.rest_poses[_rest_index(block, family)].quaternion
    return quat_multiply(axis_angle_quat([0.0, 0.0, 1.0], yaw), base)


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
