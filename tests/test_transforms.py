"""Tests of twin.transforms (rotation vectors, SE(3), Euler angles)."""

import numpy as np
import pytest

from twin.transforms import (
    euler_zyx_from_matrix,
    invert_transform,
    left_jacobian_so3,
    matrix_from_euler_zyx,
    matrix_to_quat_wxyz,
    matrix_to_rotvec,
    pose6_to_transform,
    quat_wxyz_to_matrix,
    rot_x,
    rot_y,
    rot_z,
    rotvec_to_matrix,
    transform_to_pose6,
)


def _random_rotvecs(rng, n):
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    return axis * rng.uniform(0, np.pi, (n, 1))


def test_rotvec_round_trip_including_near_pi():
    """matrix_to_rotvec inverts rotvec_to_matrix for angles in [0, pi], also within 1e-9 of pi."""
    rng = np.random.default_rng(0)
    r = _random_rotvecs(rng, 500)
    r[:5] *= np.pi / np.linalg.norm(r[:5], axis=1, keepdims=True) * (1 - 1e-10)
    r[5] = 0.0
    R = rotvec_to_matrix(r)
    assert np.allclose(np.swapaxes(R, 1, 2) @ R, np.eye(3), atol=1e-12)
    R2 = rotvec_to_matrix(matrix_to_rotvec(R))
    assert np.abs(R2 - R).max() < 1e-9


def test_left_jacobian_matches_finite_differences():
    """exp(r + dr) = exp([J_l(r) dr]x) exp(r) to first order, checked by central differences."""
    rng = np.random.default_rng(1)
    for r in _random_rotvecs(rng, 20):
        J = left_jacobian_so3(r)
        h = 1e-6
        for k in range(3):
            e = np.zeros(3)
            e[k] = h
            w = matrix_to_rotvec(rotvec_to_matrix(r + e) @ rotvec_to_matrix(r - e).T) / (2 * h)
            assert np.allclose(w, J[:, k], atol=1e-8)


def test_transform_inverse_and_pose6_round_trip():
    """invert_transform gives the identity product; pose6 <-> transform round-trips."""
    rng = np.random.default_rng(2)
    p6 = np.concatenate([rng.normal(size=(50, 3)), _random_rotvecs(rng, 50)], axis=1)
    T = pose6_to_transform(p6)
    assert np.allclose(T @ invert_transform(T), np.eye(4), atol=1e-12)
    assert np.allclose(pose6_to_transform(transform_to_pose6(T)), T, atol=1e-12)


def test_euler_zyx_gives_the_matrix_back_at_gimbal_lock():
    """At ry = 90 deg with rounding in the matrix (a URDF origin "1.5708 1.5708 -1.5708" behind a fixed joint) the
    angles give the matrix back."""
    A = rot_x(0.1) @ rot_y(-0.2) @ rot_z(0.3)
    R = A @ np.linalg.inv(A) @ rot_z(-np.pi / 2) @ rot_y(np.pi / 2) @ rot_x(np.pi / 2)
    assert np.abs(matrix_from_euler_zyx(euler_zyx_from_matrix(R)) - R).max() < 1e-12


def test_euler_zyx_round_trip_matches_paper_eq43():
    """euler_zyx_from_matrix (eq. 43 of the separation paper) inverts Rz Ry Rx."""
    rng = np.random.default_rng(3)
    e = np.stack([rng.uniform(-3, 3, 100), rng.uniform(-1.5, 1.5, 100), rng.uniform(-3, 3, 100)], axis=1)
    assert np.allclose(euler_zyx_from_matrix(matrix_from_euler_zyx(e)), e, atol=1e-12)


def test_quaternion_round_trip():
    """wxyz quaternions round-trip through rotation matrices (w >= 0)."""
    rng = np.random.default_rng(4)
    R = rotvec_to_matrix(_random_rotvecs(rng, 100))
    assert np.allclose(quat_wxyz_to_matrix(matrix_to_quat_wxyz(R)), R, atol=1e-12)


def test_kabsch_recovers_rigid_transforms_in_a_batch():
    """The rigid fit of rotated and shifted points returns the rotations and translations that made them."""
    from twin.transforms import kabsch

    rng = np.random.default_rng(3)
    A = rng.normal(size=(4, 10, 3))
    R = rotvec_to_matrix(rng.normal(size=(4, 3)))
    t = rng.normal(size=(4, 3))
    B = np.einsum("bij,bmj->bmi", R, A) + t[:, None]
    Rk, tk = kabsch(A, B)
    np.testing.assert_allclose(Rk, R, atol=1e-12)
    np.testing.assert_allclose(tk, t, atol=1e-12)


def test_kabsch_weights_and_reflection_guard():
    """A zero-weight outlier does not move the fit, and mirrored points still give a rotation (det +1)."""
    from twin.transforms import kabsch

    rng = np.random.default_rng(4)
    A = rng.normal(size=(8, 3))
    R = rotvec_to_matrix(np.array([0.2, 0.5, -0.3]))
    B = A @ R.T
    B[0] += 10.0
    w = np.ones(8)
    w[0] = 0.0
    Rk, tk = kabsch(A, B, w)
    np.testing.assert_allclose(Rk, R, atol=1e-12)
    np.testing.assert_allclose(tk, 0.0, atol=1e-12)
    Rm, _ = kabsch(A, A * np.array([1.0, 1.0, -1.0]))
    assert np.linalg.det(Rm) == pytest.approx(1.0)


def test_kabsch_refuses_mismatched_points():
    """Point sets of different shapes are refused, naming both shapes."""
    from twin.transforms import kabsch

    with pytest.raises(ValueError, match=r"\(5, 3\) and \(4, 3\)"):
        kabsch(np.zeros((5, 3)), np.zeros((4, 3)))
