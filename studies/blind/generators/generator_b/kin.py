"""Own forward kinematics (Craig modified DH + beta on joint 2), numpy only.

Units inside this module: millimetres and radians. Parameter vectors per robot:
theta(6), d(6), a(6), alpha(6), beta2 (scalar).
Joint i transform (frame i-1 -> i): RotX(alpha_i) TransX(a_i) TransZ(d_i) RotZ(theta_i + q_i) RotY(beta_i).
"""
from __future__ import annotations

import numpy as np

DEG = np.pi / 180.0

# nominal IRB 1200-7/0.7 (docs/conventions.md): alpha deg, a mm, d mm, theta deg
IRB1200 = dict(
    name="irb1200",
    alpha=np.array([0.0, -90.0, 0.0, -90.0, 90.0, -90.0]) * DEG,
    a=np.array([0.0, 0.0, 350.0, 42.0, 0.0, 0.0]),
    d=np.array([399.1, 0.0, 0.0, 351.0, 0.0, 82.0]),
    theta=np.array([0.0, -90.0, 0.0, 0.0, 0.0, 0.0]) * DEG,
    beta2=0.0,
    qmin=np.array([-170, -100, -200, -270, -130, -360], float),
    qmax=np.array([170, 130, 70, 270, 130, 360], float),
)

PARAM_NAMES = ([f"theta{i}" for i in range(1, 7)] + [f"d{i}" for i in range(1, 7)]
               + [f"a{i}" for i in range(1, 7)] + [f"alpha{i}" for i in range(1, 7)] + ["beta2"])


def pack(p: dict) -> np.ndarray:
    """25-vector theta, d, a, alpha, beta2 (rad / mm)."""
    return np.concatenate([p["theta"], p["d"], p["a"], p["alpha"], [p["beta2"]]])


def unpack(v: np.ndarray) -> dict:
    v = np.asarray(v)
    return dict(theta=v[..., 0:6], d=v[..., 6:12], a=v[..., 12:18], alpha=v[..., 18:24], beta2=v[..., 24])


def rotx(t):
    t = np.asarray(t, float)
    c, s = np.cos(t), np.sin(t)
    M = np.zeros(t.shape + (4, 4))
    M[..., 0, 0] = 1; M[..., 1, 1] = c; M[..., 1, 2] = -s; M[..., 2, 1] = s; M[..., 2, 2] = c; M[..., 3, 3] = 1
    return M


def roty(t):
    t = np.asarray(t, float)
    c, s = np.cos(t), np.sin(t)
    M = np.zeros(t.shape + (4, 4))
    M[..., 0, 0] = c; M[..., 0, 2] = s; M[..., 1, 1] = 1; M[..., 2, 0] = -s; M[..., 2, 2] = c; M[..., 3, 3] = 1
    return M


def rotz(t):
    t = np.asarray(t, float)
    c, s = np.cos(t), np.sin(t)
    M = np.zeros(t.shape + (4, 4))
    M[..., 0, 0] = c; M[..., 0, 1] = -s; M[..., 1, 0] = s; M[..., 1, 1] = c; M[..., 2, 2] = 1; M[..., 3, 3] = 1
    return M


def trans(x, y, z):
    x, y, z = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float), np.asarray(z, float))
    M = np.zeros(x.shape + (4, 4))
    M[..., 0, 0] = M[..., 1, 1] = M[..., 2, 2] = M[..., 3, 3] = 1
    M[..., 0, 3] = x; M[..., 1, 3] = y; M[..., 2, 3] = z
    return M


def rotvec_to_R(r):
    """Rodrigues, r (..., 3) [rad] -> (..., 3, 3)."""
    r = np.asarray(r, float)
    th = np.linalg.norm(r, axis=-1)[..., None, None]
    K = np.zeros(r.shape[:-1] + (3, 3))
    K[..., 0, 1] = -r[..., 2]; K[..., 0, 2] = r[..., 1]; K[..., 1, 0] = r[..., 2]
    K[..., 1, 2] = -r[..., 0]; K[..., 2, 0] = -r[..., 1]; K[..., 2, 1] = r[..., 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        A = np.where(th > 1e-12, np.sin(th) / np.where(th > 0, th, 1), 1.0 - th**2 / 6)
        B = np.where(th > 1e-12, (1 - np.cos(th)) / np.where(th > 0, th, 1) ** 2, 0.5 - th**2 / 24)
    I = np.broadcast_to(np.eye(3), K.shape)
    return I + A * K + B * (K @ K)


def R_to_rotvec(R):
    R = np.asarray(R, float)
    c = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1, 1)
    th = np.arccos(c)
    w = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    s = np.sin(th)
    f = np.where(s > 1e-12, th / (2 * np.where(s > 1e-12, s, 1)), 0.5)
    return w * f[..., None]


def sixdof(x):
    """(x, y, z [mm], rx, ry, rz [rad]) -> 4x4 (broadcast over leading dims)."""
    x = np.asarray(x, float)
    M = np.zeros(x.shape[:-1] + (4, 4))
    M[..., :3, :3] = rotvec_to_R(x[..., 3:6])
    M[..., :3, 3] = x[..., 0:3]
    M[..., 3, 3] = 1
    return M


def to_sixdof(M):
    return np.concatenate([M[..., :3, 3], R_to_rotvec(M[..., :3, :3])], -1)


def inv(M):
    R = M[..., :3, :3]
    t = M[..., :3, 3]
    out = np.zeros_like(M)
    out[..., :3, :3] = np.swapaxes(R, -1, -2)
    out[..., :3, 3] = -np.einsum("...ji,...j->...i", R, t)
    out[..., 3, 3] = 1
    return out


def link_frames(q, pv):
    """q (n, 6) [rad]; pv (25,) or (n, 25). Returns list of 7 (n,4,4): frame_i 2 base for i = 0..6."""
    q = np.atleast_2d(q)
    n = q.shape[0]
    pv = np.broadcast_to(np.asarray(pv, float), (n, 25))
    p = unpack(pv)
    T = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    frames = [T.copy()]
    for i in range(6):
        A = rotx(p["alpha"][:, i]) @ trans(p["a"][:, i], 0 * q[:, i], p["d"][:, i]) @ rotz(p["theta"][:, i] + q[:, i])
        if i == 1:
            A = A @ roty(p["beta2"])
        T = T @ A
        frames.append(T)
    return frames


def flange2base(q, pv):
    return link_frames(q, pv)[-1]


def apply(M, pts):
    """M (..., 4, 4), pts (..., k, 3) -> (..., k, 3)."""
    return np.einsum("...ij,...kj->...ki", M[..., :3, :3], pts) + M[..., None, :3, 3]
