"""Own kinematics of the IRB 1200-7/0.7 (Craig modified DH + beta on joint 2), written from docs/conventions.md.

Units inside this generator: millimetres and radians. Transforms are 4x4 arrays named A2B (p_B = A2B @ p_A).
Joint i transform (frame i-1 -> i): RotX(alpha_i) TransX(a_i) TransZ(d_i) RotZ(theta_i + q_i) RotY(beta_i).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

DEG = np.pi / 180.0

# nominal table (alpha deg, a mm, d mm, theta deg) per joint, from docs/conventions.md / twin/robots.py
NOMINAL_TABLE = np.array(
    [
        [0.0, 0.0, 399.1, 0.0],
        [-90.0, 0.0, 0.0, -90.0],
        [0.0, 350.0, 0.0, 0.0],
        [-90.0, 42.0, 351.0, 0.0],
        [90.0, 0.0, 0.0, 0.0],
        [-90.0, 0.0, 82.0, 0.0],
    ]
)
Q_MIN_DEG = np.array([-170, -100, -200, -270, -130, -360], float)
Q_MAX_DEG = np.array([170, 130, 70, 270, 130, 360], float)

# nominal sphere centres in the flange frame [mm] (dataset.toml [plate])
PLATE_SPHERES_MM = np.array([[60.0, 0.0, 50.0], [-60.0, 0.0, 50.0], [-20.52, 56.38, 50.0]])
SPHERE_DIAMETER_MM = 25.4


def nominal_params() -> dict:
    return {
        "alpha": NOMINAL_TABLE[:, 0] * DEG,
        "a": NOMINAL_TABLE[:, 1].copy(),
        "d": NOMINAL_TABLE[:, 2].copy(),
        "theta": NOMINAL_TABLE[:, 3] * DEG,
        "beta2": 0.0,
    }


def copy_params(p: dict) -> dict:
    return {k: (np.array(v, float).copy() if k != "beta2" else float(v)) for k, v in p.items()}


def param_vector_names() -> list[str]:
    names = []
    for k in ("theta", "d", "a", "alpha"):
        names += [f"{k}{i}" for i in range(1, 7)]
    return names + ["beta2"]


def _rotx(c):
    n = c.shape[0]
    T = np.tile(np.eye(4), (n, 1, 1))
    ca, sa = np.cos(c), np.sin(c)
    T[:, 1, 1] = ca
    T[:, 1, 2] = -sa
    T[:, 2, 1] = sa
    T[:, 2, 2] = ca
    return T


def _rotz(c):
    n = c.shape[0]
    T = np.tile(np.eye(4), (n, 1, 1))
    ca, sa = np.cos(c), np.sin(c)
    T[:, 0, 0] = ca
    T[:, 0, 1] = -sa
    T[:, 1, 0] = sa
    T[:, 1, 1] = ca
    return T


def _roty(c):
    n = c.shape[0]
    T = np.tile(np.eye(4), (n, 1, 1))
    ca, sa = np.cos(c), np.sin(c)
    T[:, 0, 0] = ca
    T[:, 0, 2] = sa
    T[:, 2, 0] = -sa
    T[:, 2, 2] = ca
    return T


def _param_rows(p: dict, n: int, i: int, key: str) -> np.ndarray:
    """parameter of joint i (0-based) for n rows; p[key] may be (6,) or (n, 6) (per-row geometry, thermal)."""
    v = np.asarray(p[key], float)
    if v.ndim == 1:
        return np.full(n, v[i])
    return v[:, i]


def link_frames(p: dict, q: np.ndarray) -> np.ndarray:
    """(n, 7, 4, 4): frame_k2base for k = 0..6 (frame 0 = base, 6 = flange). q (n, 6) [rad]."""
    q = np.atleast_2d(q)
    n = q.shape[0]
    out = np.empty((n, 7, 4, 4))
    T = np.tile(np.eye(4), (n, 1, 1))
    out[:, 0] = T
    beta2 = np.asarray(p["beta2"], float)
    for i in range(6):
        alpha = _param_rows(p, n, i, "alpha")
        a = _param_rows(p, n, i, "a")
        d = _param_rows(p, n, i, "d")
        th = _param_rows(p, n, i, "theta") + q[:, i]
        A = _rotx(alpha)
        A[:, 0, 3] = a  # RotX then TransX: translation along the (unrotated) x axis
        Z = _rotz(th)
        Z[:, 2, 3] = d  # TransZ(d) RotZ(theta) commute
        L = A @ Z
        if i == 1:
            b = np.broadcast_to(beta2, (n,)) if beta2.ndim == 0 else beta2
            L = L @ _roty(np.asarray(b, float))
        T = T @ L
        out[:, i + 1] = T
    return out


def flange2base(p: dict, q: np.ndarray) -> np.ndarray:
    return link_frames(p, q)[:, 6]


def pose6_to_T(x) -> np.ndarray:
    """(x, y, z [mm], rx, ry, rz [rad rotation vector]) -> 4x4."""
    x = np.asarray(x, float)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(x[3:6]).as_matrix()
    T[:3, 3] = x[:3]
    return T


def T_to_pose6(T) -> np.ndarray:
    return np.concatenate([T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_rotvec()])


def inv_T(T):
    Ti = np.zeros_like(T)
    R = T[..., :3, :3]
    Rt = np.swapaxes(R, -1, -2)
    Ti[..., :3, :3] = Rt
    Ti[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    Ti[..., 3, 3] = 1.0
    return Ti


def apply_T(T, pts):
    """T (n,4,4) or (4,4), pts (n,k,3) or (k,3) -> transformed points (n,k,3)."""
    T = np.asarray(T)
    if T.ndim == 2:
        return pts @ T[:3, :3].T + T[:3, 3]
    return np.einsum("nij,nkj->nki", T[:, :3, :3], pts) + T[:, None, :3, 3]


def rotvec_err(R_target, R):
    """log(R_target R^T) as rotation vectors, batched."""
    M = R_target @ np.swapaxes(R, -1, -2)
    return Rotation.from_matrix(M).as_rotvec()


def ik_batch(p: dict, target_f2b: np.ndarray, q_seed: np.ndarray, iters: int = 60, tol_mm: float = 1e-7):
    """Damped Newton IK (numerical Jacobian) for many targets at once. Returns q (n,6) [rad], ok (n,) bool."""
    q = q_seed.copy()
    n = q.shape[0]
    Rt = target_f2b[:, :3, :3]
    pt = target_f2b[:, :3, 3]
    W = np.array([1.0, 1.0, 1.0, 300.0, 300.0, 300.0])  # mm vs rad
    h = 1e-7
    for _ in range(iters):
        T = flange2base(p, q)
        err = np.concatenate([pt - T[:, :3, 3], rotvec_err(Rt, T[:, :3, :3])], axis=1) * W
        if np.all(np.abs(err) < tol_mm):
            break
        J = np.empty((n, 6, 6))
        for j in range(6):
            dq = q.copy()
            dq[:, j] += h
            Tj = flange2base(p, dq)
            ej = np.concatenate([pt - Tj[:, :3, 3], rotvec_err(Rt, Tj[:, :3, :3])], axis=1) * W
            J[:, :, j] = -(ej - err) / h
        lam = 1e-6
        JT = np.swapaxes(J, 1, 2)
        step = np.linalg.solve(JT @ J + lam * np.eye(6), np.einsum("nij,nj->ni", JT, err)[..., None])[..., 0]
        sn = np.linalg.norm(step, axis=1, keepdims=True)
        step = step * np.minimum(1.0, 0.5 / np.maximum(sn, 1e-300))
        q = q + step
    T = flange2base(p, q)
    err = np.concatenate([pt - T[:, :3, 3], rotvec_err(Rt, T[:, :3, :3])], axis=1) * W
    ok = np.all(np.abs(err) < 1e-5, axis=1)
    return q, ok


if __name__ == "__main__":
    T = flange2base(nominal_params(), np.zeros((1, 6)))[0]
    print(np.round(T, 6))
