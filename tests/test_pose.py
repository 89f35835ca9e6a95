"""Poses and quaternions (scalar first everywhere)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from geometry.pose import (
    Pose,
    axis_angle_quat,
    matrix_to_quat,
    quat_multiply,
    quat_to_matrix,
    rotation_between,
)

unit = st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda v: np.linalg.norm(v) > 0.1)


@given(unit)
def test_quaternion_matrix_agrees_with_scipy(v):
    q = np.array(v) / np.linalg.norm(v)
    # scipy is scalar-last: [x, y, z, w].
    expected = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()
    np.testing.assert_allclose(quat_to_matrix(q), expected, atol=1e-12)


@given(unit)
def test_matrix_to_quaternion_round_trip(v):
    q = np.array(v) / np.linalg.norm(v)
    back = matrix_to_quat(quat_to_matrix(q))
    assert min(np.abs(back - q).max(), np.abs(back + q).max()) < 1e-9


@settings(max_examples=50)
@given(unit, unit)
def test_compose_is_matrix_product(a, b):
    qa, qb = np.array(a) / np.linalg.norm(a), np.array(b) / np.linalg.norm(b)
    pa, pb = Pose([1, 2, 3], qa), Pose([-0.5, 0.1, 4], qb)
    np.testing.assert_allclose(pa.compose(pb).matrix, pa.matrix @ pb.matrix, atol=1e-12)
    np.testing.assert_allclose(quat_to_matrix(quat_multiply(qa, qb)), quat_to_matrix(qa) @ quat_to_matrix(qb),
                               atol=1e-12)


@settings(max_examples=200)
@given(unit, unit, st.floats(-12, 0))
def test_rotation_between_is_scipys_angle_small_ones_too(a, b, small):
    """The settle's rotation figure is scipy's ``magnitude`` of ``q1 * q0^-1``, in plain
    floats: for any pair, for a pair a hair apart (where ``arccos`` would lose half the
    digits), and for a quaternion against its own negative (the same orientation)."""
    qa, qb = np.array(a) / np.linalg.norm(a), np.array(b) / np.linalg.norm(b)
    near = qa + 10.0 ** small * qb
    near /= np.linalg.norm(near)
    for q0, q1 in [(qa, qb), (qa, near), (qa, -qa)]:
        expected = (Rotation.from_quat(q1, scalar_first=True)
                    * Rotation.from_quat(q0, scalar_first=True).inv()).magnitude()
        assert abs(rotation_between(q0, q1) - expected) <= 1e-14 + 1e-12 * expected


def test_apply_and_inverse():
    p = Pose([1.0, -2.0, 0.5], axis_angle_quat([0, 0, 1], np.pi / 2))
    pts = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    np.testing.assert_allclose(p.apply(pts), [[1, -1, 0.5], [0, -2, 0.5]], atol=1e-12)
    np.testing.assert_allclose(p.inverse_apply(p.apply(pts)), pts, atol=1e-12)


def test_unit_quaternion_is_stored_bit_for_bit():
    q = [0.7071067811865476, 0.0, 0.0, 0.7071067811865476]
    assert list(Pose([0, 0, 0], q).quaternion) == q
