"""Own kinematics for the held-out generator (batch C). Millimetres and radians inside.

Craig modified DH with beta on joint 2, as in docs/conventions.md:
    T_{i-1,i} = RotX(alpha_i) TransX(a_i) TransZ(d_i) RotZ(theta_i + q_i) RotY(beta_i)
Kinematic parameter vector (25): theta1..6, d1..6, a1..6, alpha1..6, beta2.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

DEG = np.pi / 180.0
KP_NAMES = (
    [f"theta{i}" for i in range(1, 7)]
    + [f"d{i}" for i in range(1, 7)]
    + [f"a{i}" for i in range(1, 7)]
    + [f"alpha{i}" for i in range(1, 7)]
    + ["beta2"]
)
I_TH, I_D, I_A, I_AL, I_BE = 0, 6, 12, 18, 24


class Robot:
    """Nominal MDH robot (angles stored in rad, lengths in mm)."""

    def __init__(self, name, theta_deg, d_mm, a_mm, alpha_deg, qmin_deg, qmax_deg, by_name=True):
        self.name = name
        self.theta_deg = list(map(float, theta_deg))
        self.d_mm = list(map(float, d_mm))
        self.a_mm = list(map(float, a_mm))
        self.alpha_deg = list(map(float, alpha_deg))
        self.qmin_deg = np.array(qmin_deg, float)
        self.qmax_deg = np.array(qmax_deg, float)
        self.by_name = by_name
        self.kp = np.r_[np.radians(self.theta_deg), self.d_mm, self.a_mm, np.radians(self.alpha_deg), 0.0]

    @property
    def qmin(self):
        return np.radians(self.qmin_deg)

    @property
    def qmax(self):
        return np.radians(self.qmax_deg)


def irb1200():
    return Robot(
        "irb1200",
        [0, -90, 0, 0, 0, 0],
        [399.1, 0, 0, 351, 0, 82],
        [0, 0, 350, 42, 0, 0],
        [0, -90, 0, -90, 90, -90],
        [-170, -100, -200, -270, -130, -360],
        [170, 130, 70, 270, 130, 360],
        by_name=True,
    )


INLINE = {
    "A": dict(name="cell2_arm", theta=[0, -90, 0, 0, 0, 0], d=[430.0, 0, 0, 420.0, 0, 90.0], a=[0, 30.0, 400.0, 35.0, 0, 0],
              alpha=[0, -90, 0, -90, 90, -90], qmin=[-165, -110, -210, -200, -125, -350], qmax=[165, 140, 65, 200, 125, 350]),
    "B": dict(name="lab_r7", theta=[0, -90, 0, 0, 0, 0], d=[352.0, 0, 0, 380.0, 0, 75.0], a=[0, 70.0, 360.0, 20.0, 0, 0],
              alpha=[0, -90, 0, -90, 90, -90], qmin=[-170, -100, -200, -190, -120, -400], qmax=[170, 135, 70, 190, 120, 400]),
    "C": dict(name="m10_line4", theta=[0, -90, 0, 0, 0, 0], d=[450.0, 0, 0, 300.0, 0, 95.0], a=[0, 50.0, 320.0, 0.0, 0, 0],
              alpha=[0, -90, 0, -90, 90, -90], qmin=[-160, -95, -190, -180, -120, -300], qmax=[160, 125, 75, 180, 120, 300]),
}


def inline_robot(key):
    t = INLINE[key]
    return Robot(t["name"], t["theta"], t["d"], t["a"], t["alpha"], t["qmin"], t["qmax"], by_name=False)


# ----------------------------------------------------------------------------------------------- transforms

def pose6(v):
    """(..., 6) [mm, rad] translation + rotation vector -> (..., 4, 4)."""
    v = np.asarray(v, float)
    shp = v.shape[:-1]
    flat = v.reshape(-1, 6)
    T = np.tile(np.eye(4), (flat.shape[0], 1, 1))
    T[:, :3, :3] = Rotation.from_rotvec(flat[:, 3:]).as_matrix()
    T[:, :3, 3] = flat[:, :3]
    return T.reshape(shp + (4, 4))


def inv_T(T):
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    out = np.zeros_like(T)
    Rt = np.swapaxes(R, -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


def apply_T(T, p):
    """T (..., 4, 4) applied to points p (..., k, 3) -> (..., k, 3)."""
    return np.einsum("...ij,...kj->...ki", T[..., :3, :3], p) + T[..., None, :3, 3]


def rot_about_axis_through(axis, angle, point):
    """4x4 (N) rotation by angle (N,) about a unit axis through a point."""
    angle = np.atleast_1d(angle)
    R = Rotation.from_rotvec(np.outer(angle, axis)).as_matrix()
    T = np.tile(np.eye(4), (len(angle), 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = point - R @ point
    return T


# ----------------------------------------------------------------------------------------------- forward kinematics

def _link(al, a, d, th, be):
    # Rx(al) Rz(th) in closed form: each entry of the product has one non-zero term, so it equals the matrix product
    # bit for bit; Ry(be) multiplies only where some be is non-zero (else it is the identity)
    n = th.shape[0]
    ca, sa = np.cos(al), np.sin(al)
    ct, st = np.cos(th), np.sin(th)
    R = np.zeros((n, 3, 3))
    R[:, 0, 0] = ct
    R[:, 0, 1] = -st
    R[:, 1, 0] = ca * st
    R[:, 1, 1] = ca * ct
    R[:, 1, 2] = -sa
    R[:, 2, 0] = sa * st
    R[:, 2, 1] = sa * ct
    R[:, 2, 2] = ca
    if np.any(be != 0):
        cb, sb = np.cos(be), np.sin(be)
        Ry = np.zeros((n, 3, 3))
        Ry[:, 0, 0] = cb
        Ry[:, 0, 2] = sb
        Ry[:, 1, 1] = 1
        Ry[:, 2, 0] = -sb
        Ry[:, 2, 2] = cb
        R = R @ Ry
    T = np.zeros((n, 4, 4))
    T[:, :3, :3] = R
    T[:, 0, 3] = a
    T[:, 1, 3] = -sa * d
    T[:, 2, 3] = ca * d
    T[:, 3, 3] = 1
    return T


def fk_frames(kp, q):
    """Frames 1..6 in the base frame: list of six (N, 4, 4). kp (25,) or (N, 25); q (N, 6) [rad]."""
    q = np.atleast_2d(q)
    n = q.shape[0]
    kp = np.broadcast_to(np.asarray(kp, float), (n, 25))
    T = np.tile(np.eye(4), (n, 1, 1))
    out = []
    for i in range(6):
        be = kp[:, I_BE] if i == 1 else np.zeros(n)
        T = T @ _link(kp[:, I_AL + i], kp[:, I_A + i], kp[:, I_D + i], kp[:, I_TH + i] + q[:, i], be)
        out.append(T)
    return out


def fk(kp, q):
    return fk_frames(kp, q)[-1]


# ----------------------------------------------------------------------------------------------- true geometry

class Geometry:
    """True (or nominal) geometry: kinematic parameters, tool2flange, sphere centres in the tool frame,
    base2meas of every station."""

    def __init__(self, kp, tool2flange, spheres_tool, base2meas):
        self.kp = np.array(kp, float)
        self.tool = np.array(tool2flange, float)
        self.spheres = np.array(spheres_tool, float)
        self.base2meas = [np.array(B, float) for B in base2meas]

    def copy(self):
        return Geometry(self.kp.copy(), self.tool.copy(), self.spheres.copy(), [B.copy() for B in self.base2meas])


class Mods:
    """What effects change, per row (N rows)."""

    def __init__(self, n):
        self.n = n
        self.dq = np.zeros((n, 6))  # joint offsets added to the commanded angles [rad]
        self.dkp = np.zeros((n, 25))  # kinematic parameter changes
        self.tool = None  # (N,4,4): tool2flange_row = tool @ tool2flange (in the flange frame)
        self.plate = np.zeros((n, 3, 3))  # sphere centre offsets in the tool frame [mm]
        self.base = None  # (N,4,4): p_base' = base @ p_base (robot base moved in the cell)
        self.meas = None  # (N,4,4): base2meas_row = meas @ base2meas (instrument moved)
        self.fields = []  # functions p_meas (N,3,3) -> p_meas' (instrument field errors)

    def compose(self, other):
        m = Mods(self.n)
        m.dq = self.dq + other.dq
        m.dkp = self.dkp + other.dkp
        m.plate = self.plate + other.plate
        for name in ("tool", "base", "meas"):
            a, b = getattr(self, name), getattr(other, name)
            setattr(m, name, a if b is None else (b if a is None else a @ b))
        m.fields = self.fields + other.fields
        return m


def centres(geom: Geometry, q, st, mods: Mods | None = None, flange_delta=None):
    """True sphere centres (N, 3, 3) [mm] in the measurement frame of each row's station.

    q (N, 6) commanded joints [rad]; st (N,) station index; flange_delta (N,4,4): a rigid displacement of the
    flange (robot repeatability), applied in the flange frame."""
    q = np.atleast_2d(q)
    n = q.shape[0]
    if mods is None:
        mods = Mods(n)
    F = fk(geom.kp[None, :] + mods.dkp, q + mods.dq)
    if flange_delta is not None:
        F = F @ flange_delta
    tool = np.broadcast_to(geom.tool, (n, 4, 4))
    if mods.tool is not None:
        tool = mods.tool @ tool
    s = geom.spheres[None] + mods.plate
    p = apply_T(F @ tool, s)
    if mods.base is not None:
        p = apply_T(mods.base, p)
    B = np.stack([geom.base2meas[int(k)] for k in st])
    if mods.meas is not None:
        B = mods.meas @ B
    p = apply_T(B, p)
    for f in mods.fields:
        p = f(p)
    return p


def geometric_jacobian(geom: Geometry, q, st, n_stations):
    """d centres / d (25 kinematic + 6 tool + 6 per station base2meas) by central differences.
    Returns (N*9, P). Any parameterisation spanning each 6-DOF frame's tangent space is equivalent here."""
    q = np.atleast_2d(q)
    cols = []

    def ev(g):
        return centres(g, q, st).reshape(-1)

    for i in range(25):
        h = 1e-3 if I_D <= i < I_AL else 1e-6
        gp, gm = geom.copy(), geom.copy()
        gp.kp[i] += h
        gm.kp[i] -= h
        cols.append((ev(gp) - ev(gm)) / (2 * h))
    for i in range(6):
        h = 1e-3 if i < 3 else 1e-6
        v = np.zeros(6)
        v[i] = h
        gp, gm = geom.copy(), geom.copy()
        gp.tool = geom.tool @ pose6(v)
        gm.tool = geom.tool @ pose6(-v)
        cols.append((ev(gp) - ev(gm)) / (2 * h))
    for s in range(n_stations):
        for i in range(6):
            h = 1e-3 if i < 3 else 1e-6
            v = np.zeros(6)
            v[i] = h
            gp, gm = geom.copy(), geom.copy()
            gp.base2meas[s] = pose6(v) @ geom.base2meas[s]
            gm.base2meas[s] = pose6(-v) @ geom.base2meas[s]
            cols.append((ev(gp) - ev(gm)) / (2 * h))
    return np.stack(cols, axis=1)


def left_after_geometric(J, e, fit_rows, eval_rows):
    """Part of an effect e (N, 3, 3) a geometric calibration cannot absorb: least-squares fit of the linearised
    geometric model on fit_rows, residual on eval_rows. Returns (residual (N,3,3), rms per coordinate on eval)."""
    n = e.shape[0]
    Jr = J.reshape(n, 9, -1)
    A = Jr[fit_rows].reshape(-1, J.shape[1])
    b = e[fit_rows].reshape(-1)
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0] = 1
    x, *_ = np.linalg.lstsq(A / scale, b, rcond=1e-10)
    x = x / scale
    r = e - (Jr @ x).reshape(n, 3, 3)
    rms = float(np.sqrt(np.mean(r[eval_rows] ** 2)))
    return r, rms


# ----------------------------------------------------------------------------------------------- gravity torques

def gravity_torques(robot_kp, q, masses):
    """Torque of gravity about each joint axis [N mm], (N, 6).

    masses: list of (link index 1..6, point in that link's frame [mm], mass [kg]); a mass on link k loads joints
    1..k. Gravity is -z of the robot base, 9.81 m/s^2."""
    frames = fk_frames(robot_kp, q)
    n = q.shape[0]
    g = np.array([0.0, 0.0, -9.81])
    tau = np.zeros((n, 6))
    for link, point, m in masses:
        T = frames[link - 1]
        pw = T[:, :3, :3] @ np.asarray(point, float) + T[:, :3, 3]
        F = m * g
        for j in range(link):
            o = frames[j][:, :3, 3]
            z = frames[j][:, :3, 2]
            tau[:, j] += np.einsum("ni,ni->n", np.cross(pw - o, F), z)
    return tau


def default_masses(robot: Robot, payload_kg=1.0, payload_com_flange=(0.0, 0.0, 40.0)):
    """A plausible lumped-mass model of a 7-10 kg class arm (link frames as in fk_frames)."""
    a3 = robot.a_mm[2]
    a4 = robot.a_mm[3]
    d4 = robot.d_mm[3]
    return [
        (2, (a3 * 0.5, 0.0, 0.0), 6.0),  # upper arm tube, between axes 2 and 3
        (3, (a4 * 0.5, 0.15 * d4, 0.0), 5.5),  # elbow housing with the wrist motors (frame 3, y3 toward the wrist)
        (4, (0.0, 0.0, -0.45 * d4), 3.0),  # forearm tube (frame 4 sits at the wrist centre, z4 along the forearm)
        (5, (0.0, 0.0, 0.0), 1.2),  # wrist
        (6, tuple(payload_com_flange), payload_kg),  # adapter + plate (+ payload)
    ]


# ----------------------------------------------------------------------------------------------- batched IK

def ik_batch(kp, targets, q0, qmin, qmax, iters=60):
    """Damped Gauss-Newton on flange2base targets (M, 4, 4) from seeds q0 (M, 6). Returns q (M, 6), ok (M,)."""
    q = np.clip(q0.copy(), qmin, qmax)
    w = 300.0

    def err(qq):
        F = fk(kp, qq)
        dp = F[:, :3, 3] - targets[:, :3, 3]
        dR = Rotation.from_matrix(F[:, :3, :3] @ np.swapaxes(targets[:, :3, :3], 1, 2)).as_rotvec() * w
        return np.concatenate([dp, dR], axis=1)

    lam = 1e-3
    for _ in range(iters):
        e = err(q)
        J = np.zeros((q.shape[0], 6, 6))
        h = 1e-7
        for j in range(6):
            dq = np.zeros(6)
            dq[j] = h
            J[:, :, j] = (err(q + dq) - e) / h
        JTJ = np.einsum("nki,nkj->nij", J, J) + lam * np.eye(6)
        step = np.linalg.solve(JTJ, np.einsum("nki,nk->ni", J, e)[..., None])[..., 0]
        step = np.clip(step, -0.3, 0.3)
        q = np.clip(q - step, qmin, qmax)
    e = err(q)
    ok = (np.linalg.norm(e[:, :3], axis=1) < 1e-5) & (np.linalg.norm(e[:, 3:], axis=1) < 1e-5 * w)
    return q, ok
