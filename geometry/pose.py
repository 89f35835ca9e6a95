"""Poses: where a block is and how it is turned.

A pose maps the block frame to the world frame (docs/contract.md, "Units and
frames")::

    p_world = R(quaternion) @ p_block + position

Quaternions are scalar-first ``[w, x, y, z]`` here, in files and in MuJoCo.
This is the one module where a block's pose becomes world coordinates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.spatial.transform import Rotation

from .constants import tol


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion.

    Parameters
    ----------
    q : (4,) or (n, 4) float
        Unit quaternion(s), scalar first ``[w, x, y, z]``.

    Returns
    -------
    (3, 3) or (n, 3, 3) float

    Notes
    -----
    A batch goes to scipy. One quaternion, the optimizer's hot path (every
    candidate pose), is written out in plain floats: ``benchmarks/pose_speed.py``
    measures 3 us against scipy's 20 us, 17 500 calls in a ``mini`` run; and
    scipy's matrix differs from this one in the last bit for most rotations,
    which would change every layout the optimizer writes.
    """
    q = np.asarray(q, dtype=float)
    if q.ndim == 1:
        w, x, y, z = (float(v) for v in q)
        return np.array([
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ])
    if len(q) == 0:
        return np.zeros(q.shape[:-1] + (3, 3))
    return Rotation.from_quat(q.reshape(-1, 4), scalar_first=True).as_matrix().reshape(q.shape[:-1] + (3, 3))


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Unit quaternion ``[w, x, y, z]`` of a rotation matrix, with ``w >= 0`` (scipy's canonical form)."""
    return Rotation.from_matrix(np.asarray(m, dtype=float)).as_quat(canonical=True, scalar_first=True)


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` of scalar-first quaternions (apply b, then a).

    Written out: it turns every hanging of every candidate, and scipy's
    composition costs 63 us against 3 us, 10 000 calls in a ``mini`` run
    (``benchmarks/pose_speed.py``).
    """
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ]
    )


def axis_angle_quat(axis: np.ndarray, angle: float) -> np.ndarray:
    """Quaternion ``[w, x, y, z]`` of a rotation by ``angle`` radians about ``axis``.

    Written out: every candidate's yaw goes through it, and scipy's
    ``from_rotvec`` costs 20 us against 4 us, 10 000 calls in a ``mini`` run
    (``benchmarks/pose_speed.py``).
    """
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis])


def rotation_between(q0: np.ndarray, q1: np.ndarray) -> float:
    """Angle in radians, in [0, pi], of the rotation taking orientation ``q0`` to ``q1``.

    Both are quaternions, scalar first (their lengths cancel). The angle of
    ``q1 * conj(q0)`` is taken by ``atan2`` of its vector and scalar parts, as scipy's
    ``magnitude`` takes it, which keeps full precision for small angles, where
    ``arccos(w)`` loses half the digits. In plain floats: a settle asks it of every block,
    and scipy's ``Rotation`` objects took 160 us a call, 4 % of an ``optimize`` run on
    ``mini-rough`` (2026-11-28).
    """
    a0, b0, c0, d0 = (float(v) for v in q0)
    a1, b1, c1, d1 = (float(v) for v in q1)
    w = a1 * a0 + b1 * b0 + c1 * c0 + d1 * d0
    x = a0 * b1 - a1 * b0 - (c1 * d0 - d1 * c0)
    y = a0 * c1 - a1 * c0 - (d1 * b0 - b1 * d0)
    z = a0 * d1 - a1 * d0 - (b1 * c0 - c1 * b0)
    return 2.0 * math.atan2(math.sqrt(x * x + y * y + z * z), abs(w))


@dataclass(frozen=True, eq=False)
class Pose:
    """A rigid placement of a block frame in the world frame.

    Attributes
    ----------
    position : (3,) float, metres, world frame
        Where the block frame's origin (the block's centroid) lies.
    quaternion : (4,) float, unit, scalar first ``[w, x, y, z]``
        The block frame's orientation.
    """

    position: np.ndarray
    quaternion: np.ndarray

    def __post_init__(self) -> None:
        p = np.array(self.position, dtype=float).reshape(3)
        q = np.array(self.quaternion, dtype=float).reshape(4)
        norm = np.linalg.norm(q)
        # Leave a quaternion that is unit to float precision untouched, so that
        # reading and writing a layout is lossless (dividing by a norm of
        # 1 +- 1 ulp would change its last bits on every round trip).
        if abs(norm - 1.0) > 4 * np.finfo(float).eps:
            q = q / norm
        p.flags.writeable = False
        q.flags.writeable = False
        object.__setattr__(self, "position", p)
        object.__setattr__(self, "quaternion", q)

    @classmethod
    def identity(cls) -> Pose:
        return cls(np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]))

    @classmethod
    def from_matrix(cls, m: np.ndarray) -> Pose:
        """Pose of a 4x4 homogeneous transform."""
        m = np.asarray(m, dtype=float)
        return cls(m[:3, 3], matrix_to_quat(m[:3, :3]))

    @cached_property
    def rotation(self) -> np.ndarray:
        """(3, 3) float rotation matrix, block frame to world frame (read-only)."""
        m = quat_to_matrix(self.quaternion)
        m.flags.writeable = False
        return m

    @property
    def matrix(self) -> np.ndarray:
        """(4, 4) float homogeneous transform, block frame to world frame."""
        m = np.eye(4)
        m[:3, :3] = self.rotation
        m[:3, 3] = self.position
        return m

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Map ``(n, 3)`` points from the block frame to the world frame."""
        return np.asarray(points, dtype=float) @ self.rotation.T + self.position

    def inverse_apply(self, points: np.ndarray) -> np.ndarray:
        """Map ``(n, 3)`` points from the world frame to the block frame."""
        return (np.asarray(points, dtype=float) - self.position) @ self.rotation

    def compose(self, inner: Pose) -> Pose:
        """The pose ``self ∘ inner``: first ``inner``, then ``self``."""
        return Pose(
            self.apply(inner.position[None])[0],
            quat_multiply(self.quaternion, inner.quaternion),
        )

    def translated(self, offset: np.ndarray) -> Pose:
        return Pose(self.position + np.asarray(offset, dtype=float), self.quaternion)

    def close_to(self, other: Pose, atol: float = tol.distance) -> bool:
        """Same placement within ``atol`` (q and -q are the same rotation)."""
        dq = min(
            np.abs(self.quaternion - other.quaternion).max(),
            np.abs(self.quaternion + other.quaternion).max(),
        )
        return bool(np.abs(self.position - other.position).max() <= atol and dq <= atol)

    def __repr__(self) -> str:
        p = ", ".join(f"{v:.4g}" for v in self.position)
        q = ", ".join(f"{v:.4g}" for v in self.quaternion)
        return f"Pose(position=[{p}], quaternion=[{q}])"
