"""Kinematics of the drawn campaigns' robots, written here (the generator shares no code with the estimator or the
diagnosis): Craig modified DH (the IRB 1200) and standard DH (the UR5 and UR10), rows vectorised, link lengths
per row (thermal growth), the bodies' gravity torques about each joint axis and the arm's moment about the base.

SI inside: metres, radians, kilograms, newtons. Transforms are 4x4 and named A2B (``p_B = A2B @ p_A``).

* ``mdh`` joint i: ``RotX(alpha_i) TransX(a_i) TransZ(d_i) RotZ(theta_i + q_i) RotY(beta_i)``; joint i turns
  about the z axis of frame i (the frame after it).
* ``dh`` joint i: ``RotZ(theta_i + q_i) TransZ(d_i) TransX(a_i) RotX(alpha_i) RotY(beta_i)``; joint i turns about
  the z axis of frame i - 1 (the frame before it).

A body ``(frame, mass [kg], centre of mass [m] in that frame)`` is carried by every joint whose moving side holds
that frame: joints ``1..frame``.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "G_BASE", "rotx", "roty", "rotz", "rotvec_to_matrix", "rotvecs_to_matrices", "matrix_to_rotvec", "transform",
    "inv", "about", "frames", "joint_axes", "body_positions", "gravity_torques", "base_moment", "points"
]

G_BASE = np.array([0.0, 0.0, -9.81])  # gravity in the base frame [m/s^2]: the base stands upright


def rotx(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def roty(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def rotz(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def rotvec_to_matrix(v) -> np.ndarray:
    """Rotation vector ``(3,)`` [rad] -> 3x3 (Rodrigues)."""
    v = np.asarray(v, float)
    th = float(np.linalg.norm(v))
    if th < 1e-15:
        return np.eye(3)
    k = v / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


def rotvecs_to_matrices(V: np.ndarray) -> np.ndarray:
    """Rotation vectors ``(n, 3)`` [rad] -> ``(n, 3, 3)``."""
    return np.stack([rotvec_to_matrix(v) for v in np.asarray(V, float)]) if len(V) else np.zeros((0, 3, 3))


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """3x3 rotation (angle below pi) -> rotation vector ``(3,)`` [rad]."""
    c = np.clip((np.trace(R) - 1) / 2, -1.0, 1.0)
    th = np.arccos(c)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if th < 1e-12:
        return 0.5 * w
    return th / (2 * np.sin(th)) * w


def transform(rotvec, trans) -> np.ndarray:
    """4x4 from a rotation vector [rad] and a translation [m]."""
    T = np.eye(4)
    T[:3, :3] = rotvec_to_matrix(rotvec)
    T[:3, 3] = trans
    return T


def inv(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms ``(..., 4, 4)``."""
    R = T[..., :3, :3]
    out = np.zeros_like(T)
    out[..., :3, :3] = np.swapaxes(R, -1, -2)
    out[..., :3, 3] = -np.einsum("...ji,...j->...i", R, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def about(rotvec, pivot, trans=np.zeros(3)) -> np.ndarray:
    """A rotation ``rotvec`` [rad] about the point ``pivot`` [m], then a translation ``trans`` [m] (one frame)."""
    T = np.eye(4)
    R = rotvec_to_matrix(rotvec)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(pivot) - R @ np.asarray(pivot) + np.asarray(trans)
    return T


def _rot(axis: str, ang: np.ndarray) -> np.ndarray:
    """``(n,)`` angles -> ``(n, 4, 4)`` rotations about ``axis``."""
    n = ang.shape[0]
    c, s = np.cos(ang), np.sin(ang)
    T = np.zeros((n, 4, 4))
    T[:, 3, 3] = 1.0
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    k = 3 - i - j
    T[:, k, k] = 1.0
    T[:, i, i] = c
    T[:, j, j] = c
    T[:, i, j] = -s
    T[:, j, i] = s
    return T


def _trans(axis: str, v: np.ndarray) -> np.ndarray:
    n = v.shape[0]
    T = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    T[:, "xyz".index(axis), 3] = v
    return T


def frames(convention: str, params: dict, q: np.ndarray, length_scale: np.ndarray | None = None) -> np.ndarray:
    """Frames 0..6 in the base frame ``(n, 7, 4, 4)`` for joints ``q`` ``(n, 6)`` [rad]. ``params``: ``theta, d, a,
    alpha, beta`` ``(6,)`` each [rad, m]; ``length_scale`` ``(n, 2, 6)``: each row's factor on ``d`` (``[:, 0]``)
    and ``a`` (``[:, 1]``) (thermal growth; 1 when absent)."""
    q = np.atleast_2d(np.asarray(q, float))
    n = q.shape[0]
    out = np.zeros((n, 7, 4, 4))
    out[:, 0] = np.eye(4)
    T = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    for i in range(6):
        d = np.full(n, params["d"][i]) * (1.0 if length_scale is None else length_scale[:, 0, i])
        a = np.full(n, params["a"][i]) * (1.0 if length_scale is None else length_scale[:, 1, i])
        rz = _rot("z", params["theta"][i] + q[:, i])
        rx = _rot("x", np.full(n, params["alpha"][i]))
        if convention == "mdh":
            Ti = rx @ _trans("x", a) @ _trans("z", d) @ rz
        elif convention == "dh":
            Ti = rz @ _trans("z", d) @ _trans("x", a) @ rx
        else:
            raise ValueError(f"convention must be 'mdh' or 'dh', got {convention!r}")
        if params["beta"][i] != 0.0:
            Ti = Ti @ _rot("y", np.full(n, params["beta"][i]))
        T = T @ Ti
        out[:, i + 1] = T
    return out


def joint_axes(convention: str, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each joint's axis in the base frame: origins and unit directions ``(n, 6, 3)`` from frames ``(n, 7, 4, 4)``."""
    idx = np.arange(1, 7) if convention == "mdh" else np.arange(0, 6)
    A = F[:, idx]
    return A[:, :, :3, 3], A[:, :, :3, 2]


def body_positions(F: np.ndarray, bodies) -> np.ndarray:
    """Centres of mass in the base frame ``(n, B, 3)``."""
    return np.stack([F[:, f, :3, :3] @ np.asarray(c) + F[:, f, :3, 3] for f, _, c in bodies], axis=1)


def gravity_torques(convention: str, F: np.ndarray, bodies) -> np.ndarray:
    """Torque gravity exerts about each joint's +axis [N m] ``(n, 6)``: ``tau_j = z_j . sum_b (c_b - o_j) x m_b g``
    over the bodies joint j carries (frames ``>= j``)."""
    C = body_positions(F, bodies)
    o, z = joint_axes(convention, F)
    tau = np.zeros((F.shape[0], 6))
    for j in range(6):
        for b, (f, m, _) in enumerate(bodies):
            if f >= j + 1:
                tau[:, j] += np.einsum("ij,ij->i", z[:, j], np.cross(C[:, b] - o[:, j], m * G_BASE))
    return tau


def base_moment(F: np.ndarray, bodies) -> np.ndarray:
    """Gravity moment of every moving body about the base origin [N m] ``(n, 3)``, base frame:
    ``sum_b c_b x m_b g``."""
    C = body_positions(F, bodies)
    return sum(np.cross(C[:, b], m * G_BASE) for b, (_, m, _) in enumerate(bodies))


def points(F6: np.ndarray, base2meas: np.ndarray, tool2flange: np.ndarray, points_tool: np.ndarray) -> np.ndarray:
    """Marker points in the measurement frame ``(n, K, 3)`` [m]: ``base2meas_i . flange2base_i . tool2flange_i .
    p_k``; each transform ``(n, 4, 4)`` or ``(4, 4)``, ``points_tool`` ``(K, 3)`` [m] in the tool frame."""
    T = np.asarray(base2meas) @ F6 @ np.asarray(tool2flange)
    return np.einsum("nij,kj->nki", T[:, :3, :3], points_tool) + T[:, None, :3, 3]
