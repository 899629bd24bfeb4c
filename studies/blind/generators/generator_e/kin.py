"""Kinematics written blind from docs/conventions.md: Craig modified DH with beta on joint 2.

Internal units: millimetres and radians. Joint i transform (frame i-1 -> frame i):
    RotX(alpha_i) TransX(a_i) TransZ(d_i) RotZ(theta_i + q_i) RotY(beta_i)
"""
from __future__ import annotations

import numpy as np

DEG = np.pi / 180.0

# ---------------------------------------------------------------- robot tables (nominal)
# each robot: alpha_deg, a_mm, d_mm, theta_deg (per joint, Craig's alpha_{i-1}, a_{i-1} as in conventions.md),
# limits, and a crude mass model used only by gravity-driven effects.
ROBOTS = {
    "irb1200": dict(
        inline=False,
        alpha_deg=[0, -90, 0, -90, 90, -90], a_mm=[0, 0, 350, 42, 0, 0], d_mm=[399.1, 0, 0, 351, 0, 82],
        theta_deg=[0, -90, 0, 0, 0, 0],
        q_min=[-170, -100, -200, -270, -130, -360], q_max=[170, 130, 70, 270, 130, 360],
        masses_kg=[14.0, 8.0, 6.0, 3.0, 1.5, 0.6],
    ),
    # two arms made up for this exam (6R, spherical wrist, beta on joint 2)
    "cx900": dict(
        inline=True,
        alpha_deg=[0, -90, 0, -90, 90, -90], a_mm=[0, 40, 420, 30, 0, 0], d_mm=[450, 0, 0, 400, 0, 95],
        theta_deg=[0, -90, 0, 0, 0, 0],
        q_min=[-165, -90, -190, -240, -125, -350], q_max=[165, 140, 75, 240, 125, 350],
        masses_kg=[22.0, 12.0, 8.0, 4.0, 2.0, 0.8],
    ),
    "lr560": dict(
        inline=True,
        alpha_deg=[0, -90, 0, -90, 90, -90], a_mm=[0, 25, 300, 35, 0, 0], d_mm=[330, 0, 0, 310, 0, 75],
        theta_deg=[0, -90, 0, 0, 0, 0],
        q_min=[-170, -95, -180, -190, -120, -400], q_max=[170, 135, 70, 190, 120, 400],
        masses_kg=[10.0, 6.0, 4.5, 2.2, 1.0, 0.4],
    ),
}


def nominal_params(robot: str) -> dict:
    r = ROBOTS[robot]
    return dict(
        theta=np.array(r["theta_deg"], float) * DEG,
        d=np.array(r["d_mm"], float),
        a=np.array(r["a_mm"], float),
        alpha=np.array(r["alpha_deg"], float) * DEG,
        beta=np.zeros(6),
    )


def copy_params(p: dict) -> dict:
    return {k: np.array(v, float, copy=True) for k, v in p.items()}


PARAM_NAMES = [f"{k}{i}" for k in ("theta", "d", "a", "alpha") for i in range(1, 7)] + ["beta2"]


# ---------------------------------------------------------------- rotations / transforms
def rotvec_to_R(rv) -> np.ndarray:
    rv = np.asarray(rv, float)
    th = np.linalg.norm(rv)
    if th < 1e-15:
        K = np.array([[0, -rv[2], rv[1]], [rv[2], 0, -rv[0]], [-rv[1], rv[0], 0]])
        return np.eye(3) + K
    k = rv / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


def rotvec_to_R_batch(rv: np.ndarray) -> np.ndarray:
    """(n,3) -> (n,3,3)."""
    rv = np.asarray(rv, float)
    th = np.linalg.norm(rv, axis=1)
    safe = np.where(th < 1e-15, 1.0, th)
    k = rv / safe[:, None]
    K = np.zeros((len(rv), 3, 3))
    K[:, 0, 1], K[:, 0, 2] = -k[:, 2], k[:, 1]
    K[:, 1, 0], K[:, 1, 2] = k[:, 2], -k[:, 0]
    K[:, 2, 0], K[:, 2, 1] = -k[:, 1], k[:, 0]
    s = np.where(th < 1e-15, th, np.sin(th))[:, None, None]
    c = np.where(th < 1e-15, th**2 / 2, 1 - np.cos(th))[:, None, None]
    return np.eye(3)[None] + s * K + c * (K @ K)


def make_T(R=None, t=None) -> np.ndarray:
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if t is not None:
        T[:3, 3] = t
    return T


def inv_T(T: np.ndarray) -> np.ndarray:
    Ti = np.zeros_like(T)
    R = T[..., :3, :3]
    Rt = np.swapaxes(R, -1, -2)
    Ti[..., :3, :3] = Rt
    Ti[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    Ti[..., 3, 3] = 1.0
    return Ti


def T_from_xyzrv(x) -> np.ndarray:
    return make_T(rotvec_to_R(x[3:]), x[:3])


# ---------------------------------------------------------------- forward kinematics
def fk_frames(params: dict, q: np.ndarray) -> np.ndarray:
    """All frames T_0i, i = 0..6, shape (n, 7, 4, 4); params values may be (6,) or (n, 6) per row."""
    q = np.atleast_2d(q)
    n = q.shape[0]
    P = {k: np.broadcast_to(np.asarray(v, float), (n, 6)) for k, v in params.items()}
    out = np.zeros((n, 7, 4, 4))
    out[:, 0] = np.eye(4)
    T = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    for i in range(6):
        al, a, d, th, be = P["alpha"][:, i], P["a"][:, i], P["d"][:, i], P["theta"][:, i] + q[:, i], P["beta"][:, i]
        ca, sa = np.cos(al), np.sin(al)
        # A = RotX(alpha) TransX(a) TransZ(d)
        A = np.zeros((n, 4, 4))
        A[:, 0, 0] = 1
        A[:, 1, 1], A[:, 1, 2] = ca, -sa
        A[:, 2, 1], A[:, 2, 2] = sa, ca
        A[:, 0, 3] = a
        A[:, 1, 3] = -sa * d
        A[:, 2, 3] = ca * d
        A[:, 3, 3] = 1
        ct, st = np.cos(th), np.sin(th)
        Z = np.zeros((n, 4, 4))
        Z[:, 0, 0], Z[:, 0, 1], Z[:, 1, 0], Z[:, 1, 1] = ct, -st, st, ct
        Z[:, 2, 2] = Z[:, 3, 3] = 1
        cb, sb = np.cos(be), np.sin(be)
        Y = np.zeros((n, 4, 4))
        Y[:, 0, 0], Y[:, 0, 2], Y[:, 2, 0], Y[:, 2, 2] = cb, sb, -sb, cb
        Y[:, 1, 1] = Y[:, 3, 3] = 1
        T = T @ A @ Z @ Y
        out[:, i + 1] = T
    return out


def flange2base(params: dict, q: np.ndarray) -> np.ndarray:
    return fk_frames(params, q)[:, 6]


def spheres_meas(params, q, base2meas, tool2flange, spheres_tool) -> np.ndarray:
    """(n,3,3) sphere centres in the measurement frame [mm]; base2meas (4,4) or (n,4,4)."""
    T = np.asarray(base2meas) @ flange2base(params, q) @ tool2flange
    return np.einsum("nij,kj->nki", T[:, :3, :3], spheres_tool) + T[:, None, :3, 3]


def perturb_geometry(robot: str, rng) -> dict:
    """True geometry: every one of the 25 MDH parameters deviates from nominal."""
    p = nominal_params(robot)
    clip = lambda x, c: np.clip(x, -c, c)
    p["theta"] = p["theta"] + clip(rng.normal(0, 0.025, 6), 0.07) * DEG
    p["alpha"] = p["alpha"] + clip(rng.normal(0, 0.02, 6), 0.06) * DEG
    p["d"] = p["d"] + clip(rng.normal(0, 0.25, 6), 0.7)
    p["a"] = p["a"] + clip(rng.normal(0, 0.25, 6), 0.7)
    p["beta"][1] = clip(rng.normal(0, 0.02), 0.06) * DEG
    return p


def params_to_list(p: dict) -> dict:
    out = {}
    for k in ("theta", "d", "a", "alpha"):
        for i in range(6):
            v = p[k][i]
            out[f"{k}{i+1}" + ("_deg" if k in ("theta", "alpha") else "_mm")] = float(v / DEG if k in ("theta", "alpha") else v)
    out["beta2_deg"] = float(p["beta"][1] / DEG)
    return out


# ---------------------------------------------------------------- gravity (for compliance-like effects)
G_BASE = np.array([0.0, 0.0, -9.81])


def link_coms(frames: np.ndarray, T_tool: np.ndarray, payload_tool_mm) -> np.ndarray:
    """Crude centres of mass in the base frame [mm]: links 1..6 and the payload; (n, 7, 3)."""
    o = frames[:, :, :3, 3]
    n = frames.shape[0]
    c = np.zeros((n, 7, 3))
    c[:, 0] = 0.5 * (o[:, 0] + o[:, 2])            # link 1 (turret)
    c[:, 1] = 0.5 * (o[:, 2] + o[:, 3])            # link 2 (upper arm)
    c[:, 2] = o[:, 3] + 0.3 * (o[:, 4] - o[:, 3])  # link 3 (elbow housing)
    c[:, 3] = o[:, 3] + 0.75 * (o[:, 4] - o[:, 3]) # link 4 (forearm tube)
    c[:, 4] = o[:, 5]                              # link 5 (wrist)
    c[:, 5] = 0.5 * (o[:, 5] + o[:, 6])            # link 6 + plate
    p = np.asarray(payload_tool_mm, float)
    Tt = frames[:, 6] @ T_tool
    c[:, 6] = np.einsum("nij,j->ni", Tt[:, :3, :3], p) + Tt[:, :3, 3]
    return c


def gravity_torques(params, q, robot, T_tool, payload_kg, payload_tool_mm) -> np.ndarray:
    """Gravity torque about each joint axis [N m], (n, 6); positive = tends to increase q."""
    fr = fk_frames(params, q)
    c = link_coms(fr, T_tool, payload_tool_mm) * 1e-3
    m = np.array(list(ROBOTS[robot]["masses_kg"]) + [payload_kg])
    tau = np.zeros((q.shape[0], 6))
    for j in range(6):
        z = fr[:, j + 1, :3, 2]
        o = fr[:, j + 1, :3, 3] * 1e-3
        tot = np.zeros((q.shape[0], 3))
        for k in range(j, 7):
            tot += np.cross(c[:, k] - o, m[k] * G_BASE)
        tau[:, j] = np.einsum("ni,ni->n", z, tot)
    return tau


def base_moment(params, q, robot, T_tool, payload_kg, payload_tool_mm) -> np.ndarray:
    """Gravity moment of the whole arm about the base origin [N m], (n, 3), base frame."""
    fr = fk_frames(params, q)
    c = link_coms(fr, T_tool, payload_tool_mm) * 1e-3
    m = np.array(list(ROBOTS[robot]["masses_kg"]) + [payload_kg])
    return sum(np.cross(c[:, k], m[k] * G_BASE) for k in range(7))
