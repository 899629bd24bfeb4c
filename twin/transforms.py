"""Rigid-transform helpers (pure numpy, batched).

Naming follows the ``A2B`` scheme: ``flange2base`` maps flange-frame points into the base frame,
``p_base = flange2base @ p_flange``. Rotation vectors are axis * angle [rad]; quaternions carry their
order in the name (``quat_wxyz``). Every function accepts a leading batch shape.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "skew",
    "rotvec_to_matrix",
    "matrix_to_rotvec",
    "left_jacobian_so3",
    "make_transform",
    "pose6_to_transform",
    "transform_to_pose6",
    "invert_transform",
    "rot_x",
    "rot_y",
    "rot_z",
    "euler_zyx_from_matrix",
    "matrix_from_euler_zyx",
    "quat_wxyz_to_matrix",
    "matrix_to_quat_wxyz",
    "rotation_angle_between",
    "kabsch",
]

_EPS = 1e-12
_GIMBAL_COS = 1e-6  # cos(ry) below which euler_zyx_from_matrix reads rx from R's second row


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix ``[v]x`` of vectors ``(..., 3)`` -> ``(..., 3, 3)``."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def rotvec_to_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: rotation vectors ``(..., 3)`` [rad] -> rotation matrices ``(..., 3, 3)``."""
    r = np.asarray(rotvec, dtype=float)
    theta = np.linalg.norm(r, axis=-1)[..., None, None]
    K = skew(r)
    small = theta < 1e-8
    th = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(th) / th)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(th)) / th**2)
    eye = np.broadcast_to(np.eye(3), K.shape)
    return eye + a * K + b * (K @ K)


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` -> rotation vectors ``(..., 3)`` [rad], angle in [0, pi]."""
    R = np.asarray(R, dtype=float)
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    w = np.stack(
        [R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], axis=-1
    )
    # atan2 of (sin, cos) stays accurate near 0 and pi, where arccos alone loses half the digits.
    sin = np.clip(0.5 * np.linalg.norm(w, axis=-1), 0.0, 1.0)
    angle = np.arctan2(sin, cos)
    out = np.empty(R.shape[:-2] + (3,))
    # Regular case: axis from the antisymmetric part.
    regular = sin > 1e-6
    scale = np.where(regular, angle / np.where(regular, 2.0 * sin, 1.0), 0.5 + angle**2 / 12.0)
    out[...] = w * scale[..., None]
    # Near pi the antisymmetric part vanishes: take the axis from the symmetric part.
    near_pi = (~regular) & (angle > 1.0)
    if np.any(near_pi):
        Rp = R[near_pi]
        B = (Rp + np.swapaxes(Rp, -1, -2)) / 2.0 - np.eye(3) * ((np.trace(Rp, axis1=-2, axis2=-1) - 1) / 2)[..., None, None]
        # B = (1 - cos) a a^T ; pick the column of largest norm.
        idx = np.argmax(np.einsum("...ii->...i", B), axis=-1)
        axis = np.take_along_axis(B, idx[..., None, None].repeat(3, axis=-2), axis=-1)[..., 0]
        axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
        wp = w[near_pi]
        sign = np.where(np.einsum("...i,...i->...", axis, wp) < 0, -1.0, 1.0)
        out[near_pi] = axis * (angle[near_pi] * sign)[..., None]
    return out


def left_jacobian_so3(rotvec: np.ndarray) -> np.ndarray:
    """Left Jacobian of SO(3): ``exp(r + dr) = exp([J_l(r) dr]x) exp(r)`` to first order.

    ``J_l(r) = I + (1 - cos t)/t^2 [r]x + (t - sin t)/t^3 [r]x^2`` with ``t = |r|``.
    """
    r = np.asarray(rotvec, dtype=float)
    t = np.linalg.norm(r, axis=-1)[..., None, None]
    K = skew(r)
    small = t < 1e-6
    ts = np.where(small, 1.0, t)
    a = np.where(small, 0.5 - t**2 / 24.0, (1.0 - np.cos(ts)) / ts**2)
    b = np.where(small, 1.0 / 6.0 - t**2 / 120.0, (ts - np.sin(ts)) / ts**3)
    eye = np.broadcast_to(np.eye(3), K.shape)
    return eye + a * K + b * (K @ K)


def make_transform(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Homogeneous transforms ``(..., 4, 4)`` from rotations ``(..., 3, 3)`` and translations ``(..., 3)``."""
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float)
    shape = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = np.zeros(shape + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def pose6_to_transform(pose6: np.ndarray) -> np.ndarray:
    """``(x, y, z, rx, ry, rz)`` (translation [m], rotation vector [rad]) ``(..., 6)`` -> ``(..., 4, 4)``."""
    p = np.asarray(pose6, dtype=float)
    return make_transform(rotvec_to_matrix(p[..., 3:6]), p[..., 0:3])


def transform_to_pose6(T: np.ndarray) -> np.ndarray:
    """Inverse of :func:`pose6_to_transform`: ``(..., 4, 4)`` -> ``(..., 6)``."""
    T = np.asarray(T, dtype=float)
    return np.concatenate([T[..., :3, 3], matrix_to_rotvec(T[..., :3, :3])], axis=-1)


def invert_transform(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms ``(..., 4, 4)``: ``A2B -> B2A``."""
    T = np.asarray(T, dtype=float)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return make_transform(Rt, -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3]))


def rot_x(angle: np.ndarray) -> np.ndarray:
    """Rotation matrices about x for angles ``(...)`` [rad] -> ``(..., 3, 3)``."""
    c, s = np.cos(angle), np.sin(angle)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([o, z, z, z, c, -s, z, s, c], axis=-1).reshape(np.shape(c) + (3, 3))


def rot_y(angle: np.ndarray) -> np.ndarray:
    """Rotation matrices about y for angles ``(...)`` [rad] -> ``(..., 3, 3)``."""
    c, s = np.cos(angle), np.sin(angle)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([c, z, s, z, o, z, -s, z, c], axis=-1).reshape(np.shape(c) + (3, 3))


def rot_z(angle: np.ndarray) -> np.ndarray:
    """Rotation matrices about z for angles ``(...)`` [rad] -> ``(..., 3, 3)``."""
    c, s = np.cos(angle), np.sin(angle)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([c, -s, z, s, c, z, z, z, o], axis=-1).reshape(np.shape(c) + (3, 3))


def euler_zyx_from_matrix(R: np.ndarray) -> np.ndarray:
    """The separation paper's eq. 43: ``R = Rz(c) Ry(b) Rx(a)`` -> ``(a, b, c)`` = (rx, ry, rz) [rad], ``(..., 3)``.

    At (or near) ``b = +-pi/2`` only ``a -+ c`` is defined and ``R``'s third row carries no ``a``: there ``a`` is read
    from the second row of ``Rz(-c) R = Ry(b) Rx(a)``, ``(0, cos a, -sin a)``, so that the angles give ``R`` back
    (a URDF origin with ``rpy = "0 1.5707963 0"``)."""
    R = np.asarray(R, dtype=float)
    cos_b = np.hypot(R[..., 2, 1], R[..., 2, 2])
    rx = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    ry = np.arctan2(-R[..., 2, 0], cos_b)
    rz = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    near = cos_b < _GIMBAL_COS
    if np.any(near):
        c, s = np.cos(rz), np.sin(rz)
        rx = np.where(near, np.arctan2(s * R[..., 0, 2] - c * R[..., 1, 2], c * R[..., 1, 1] - s * R[..., 0, 1]), rx)
    return np.stack([rx, ry, rz], axis=-1)


def matrix_from_euler_zyx(rxyz: np.ndarray) -> np.ndarray:
    """``(rx, ry, rz)`` [rad] ``(..., 3)`` -> ``Rz(rz) Ry(ry) Rx(rx)`` ``(..., 3, 3)``."""
    e = np.asarray(rxyz, dtype=float)
    return rot_z(e[..., 2]) @ rot_y(e[..., 1]) @ rot_x(e[..., 0])


def quat_wxyz_to_matrix(quat_wxyz: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(..., 4)`` in (w, x, y, z) order -> rotation matrices ``(..., 3, 3)``."""
    q = np.asarray(quat_wxyz, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
            2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
            2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
        ],
        axis=-1,
    ).reshape(q.shape[:-1] + (3, 3))


def matrix_to_quat_wxyz(R: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` -> unit quaternions ``(..., 4)`` (w, x, y, z), w >= 0."""
    r = matrix_to_rotvec(R)
    angle = np.linalg.norm(r, axis=-1, keepdims=True)
    axis = r / np.where(angle < _EPS, 1.0, angle)
    q = np.concatenate([np.cos(angle / 2), axis * np.sin(angle / 2)], axis=-1)
    return np.where(q[..., :1] < 0, -q, q)


def rotation_angle_between(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Geodesic angle [rad] between rotation matrices ``(..., 3, 3)``: ``|log(Ra^T Rb)|``."""
    M = np.swapaxes(np.asarray(Ra), -1, -2) @ np.asarray(Rb)
    return np.linalg.norm(matrix_to_rotvec(M), axis=-1)


def kabsch(A: np.ndarray, B: np.ndarray, w: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The rigid fit: ``(R, t)`` minimising ``sum_k w_k |R A_k + t - B_k|^2`` over points ``(..., m, 3)`` [m]
    (batched over the leading shape; ``w`` ``(..., m)``, default 1).

    Kabsch/Umeyama without scale: the weighted centroids ``a``, ``b`` fix ``t = b - R a``; with the SVD of the
    cross-covariance ``H = sum_k w_k (A_k - a)(B_k - b)^T = U S V^T``, ``R = V diag(1, 1, d) U^T`` with
    ``d = sign(det(V U^T))`` (the reflection guard; ``d = 1`` when the points are degenerate).
    """
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    if A.shape != B.shape or A.ndim < 2 or A.shape[-1] != 3:
        raise ValueError(f"A and B must be points of the same shape (..., m, 3), got {A.shape} and {B.shape}")
    if w is None:
        w = np.ones(A.shape[:-1])
    w = np.broadcast_to(np.asarray(w, dtype=float), A.shape[:-1])
    ws = w.sum(axis=-1, keepdims=True)
    ca = np.einsum("...m,...mi->...i", w, A) / ws
    cb = np.einsum("...m,...mi->...i", w, B) / ws
    H = np.einsum("...m,...mi,...mj->...ij", w, A - ca[..., None, :], B - cb[..., None, :])
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, -1, -2) @ np.swapaxes(U, -1, -2)))
    D = np.zeros(H.shape)
    D[..., 0, 0] = 1.0
    D[..., 1, 1] = 1.0
    D[..., 2, 2] = np.where(d == 0, 1.0, d)
    R = np.swapaxes(Vt, -1, -2) @ D @ np.swapaxes(U, -1, -2)
    t = cb - np.einsum("...ij,...j->...i", R, ca)
    return R, t
