"""Kinematics of an IRB-1200-like arm (Craig modified DH, docs/conventions.md), its mass model and gravity loads.

Units inside: metres, radians, kilograms, newtons. Transforms are 4x4, named A2B (p_B = A2B @ p_A).
MDH joint i: RotX(alpha_i) TransX(a_i) TransZ(d_i) RotZ(theta_i + q_i) RotY(beta_i) (beta only on joint 2).
"""
from __future__ import annotations

import numpy as np

DEG = np.pi / 180.0
G = np.array([0.0, 0.0, -9.81])  # gravity in the base frame [m/s^2] (the base stands upright)

# nominal IRB 1200-7/0.7 (docs/conventions.md), SI
NOMINAL = {
    "alpha": np.array([0.0, -90.0, 0.0, -90.0, 90.0, -90.0]) * DEG,
    "a": np.array([0.0, 0.0, 350.0, 42.0, 0.0, 0.0]) * 1e-3,
    "d": np.array([399.1, 0.0, 0.0, 351.0, 0.0, 82.0]) * 1e-3,
    "theta": np.array([0.0, -90.0, 0.0, 0.0, 0.0, 0.0]) * DEG,
    "beta": np.zeros(6),
}
Q_MIN_DEG = np.array([-170.0, -100.0, -200.0, -270.0, -130.0, -360.0])
Q_MAX_DEG = np.array([170.0, 130.0, 70.0, 270.0, 130.0, 360.0])

# the plate: nominal sphere centres in the flange frame [m] (docs/formats.md, dataset.toml example)
SPHERES_FLANGE = np.array([[60.0, 0.0, 50.0], [-60.0, 0.0, 50.0], [-20.52, 56.38, 50.0]]) * 1e-3
PLATE_CENTRE = SPHERES_FLANGE.mean(axis=0)

# Made-up mass model of an IRB-1200-like arm (about 52 kg with the plate). Each body is carried by the joint whose
# MDH frame it is written in: (frame index 1..6, mass [kg], centre of mass in that frame [m]). Frame 2's x axis runs
# along the upper arm to joint 3; frame 3's +y runs along the forearm (axis 4) with the 42 mm offset along x3; frame
# 4 sits at the wrist centre with z4 along the forearm (the forearm tube lies behind it, -z4); frame 5's +y points
# along the flange axis; frame 6 is the flange.
BODIES = [
    (1, 13.0, np.array([-0.030, 0.010, -0.110])),  # turning column and shoulder motors
    (2, 9.5, np.array([0.160, 0.004, 0.045])),  # upper arm, its centre of mass offset towards the motor side
    (3, 5.5, np.array([0.020, -0.035, 0.012])),  # elbow housing with the axis-4 motor behind the elbow
    (4, 3.2, np.array([0.000, 0.003, -0.165])),  # forearm tube
    (5, 1.3, np.array([0.000, 0.022, 0.002])),  # wrist housing
    (6, 0.55, np.array([-0.004, 0.012, 0.028])),  # flange, plate holder and the three-sphere plate
]
ROBOT_MASS = sum(b[1] for b in BODIES)


def rotx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def roty(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def rotz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def rotvec_to_matrix(v):
    """Rotation vector (3,) [rad] -> 3x3 (Rodrigues)."""
    v = np.asarray(v, float)
    th = np.linalg.norm(v)
    if th < 1e-15:
        return np.eye(3)
    k = v / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


def matrix_to_rotvec(R):
    """3x3 rotation -> rotation vector (3,) [rad] (angles below pi)."""
    c = np.clip((np.trace(R) - 1) / 2, -1.0, 1.0)
    th = np.arccos(c)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if th < 1e-12:
        return 0.5 * w
    return th / (2 * np.sin(th)) * w


def T_from_xyzrv(v):
    """(x, y, z [m], rx, ry, rz [rad]) -> 4x4."""
    T = np.eye(4)
    T[:3, :3] = rotvec_to_matrix(v[3:])
    T[:3, 3] = v[:3]
    return T


def xyzrv_from_T(T):
    return np.concatenate([T[:3, 3], matrix_to_rotvec(T[:3, :3])])


def inv(T):
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def _batch_rot(axis, ang):
    """(n,) angles -> (n, 4, 4) rotations about x/y/z."""
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


def frames(params, q):
    """Frames 0..6 in the base frame for joints ``q`` (n, 6) [rad] -> (n, 7, 4, 4)."""
    q = np.atleast_2d(q)
    n = q.shape[0]
    out = np.zeros((n, 7, 4, 4))
    out[:, 0] = np.eye(4)
    T = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    for i in range(6):
        A = np.eye(4)
        A[:3, :3] = rotx(params["alpha"][i])
        A[:3, 3] = A[:3, :3] @ np.array([params["a"][i], 0.0, 0.0]) + A[:3, :3] @ np.array([0.0, 0.0, params["d"][i]])
        Ti = A[None] @ _batch_rot("z", params["theta"][i] + q[:, i])
        if params["beta"][i] != 0.0:
            Ti = Ti @ _batch_rot("y", np.full(n, params["beta"][i]))
        T = T @ Ti
        out[:, i + 1] = T
    return out


def flange2base(params, q):
    """(n, 4, 4) flange poses for joints (n, 6) [rad]."""
    return frames(params, q)[:, 6]


def _cross(a, b):
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def frames1(params, q):
    """Frames 1..6 in the base frame for one q (6,) [rad] -> list of 4x4 (a fast path for the IK)."""
    out = []
    T = np.eye(4)
    for i in range(6):
        ca, sa = np.cos(params["alpha"][i]), np.sin(params["alpha"][i])
        th = params["theta"][i] + q[i]
        ct, st = np.cos(th), np.sin(th)
        a, d = params["a"][i], params["d"][i]
        A = np.array([[ct, -st, 0.0, a], [ca * st, ca * ct, -sa, -sa * d], [sa * st, sa * ct, ca, ca * d],
                      [0.0, 0.0, 0.0, 1.0]])
        if params["beta"][i] != 0.0:
            cb, sb = np.cos(params["beta"][i]), np.sin(params["beta"][i])
            A = A @ np.array([[cb, 0, sb, 0], [0, 1.0, 0, 0], [-sb, 0, cb, 0], [0, 0, 0, 1.0]])
        T = T @ A
        out.append(T)
    return out


def jacobian(params, q, F=None):
    """Geometric Jacobian of the flange (6, 6) at one q (6,): rows 0-2 origin velocity, 3-5 angular velocity (joint
    2's axis read after beta2: an approximation of 1e-4 for the IK steps, whose convergence is checked on the pose)."""
    F = frames1(params, q) if F is None else F
    p = F[5][:3, 3]
    J = np.zeros((6, 6))
    for i in range(6):
        z = F[i][:3, 2]
        J[:3, i] = _cross(z, p - F[i][:3, 3])
        J[3:, i] = z
    return J


def ik(params, target, q0, iters=40, tol=1e-10):
    """Flange pose ``target`` (4x4, base frame) -> joints (6,) [rad] by damped Gauss-Newton from ``q0``; None when
    it does not converge."""
    q = np.array(q0, float)
    lam = 1e-6
    for _ in range(iters):
        F = frames1(params, q)
        T = F[5]
        e = np.concatenate([target[:3, 3] - T[:3, 3], matrix_to_rotvec(target[:3, :3] @ T[:3, :3].T)])
        en = np.linalg.norm(e[:3]) + 0.1 * np.linalg.norm(e[3:])
        if en < tol:
            return q
        J = jacobian(params, q, F)
        dq = np.linalg.solve(J.T @ J + lam * np.eye(6), J.T @ e)
        n = np.linalg.norm(dq)
        if n > 0.3:
            dq *= 0.3 / n
        q = q + dq
    return None


def perturbed(rng, len_sd=0.2e-3, ang_sd=0.02 * DEG, beta_sd=0.015 * DEG):
    """A true geometry: every MDH parameter off nominal (lengths N(0, len_sd) clipped at 3 sd, angles N(0, ang_sd))."""
    p = {k: v.copy() for k, v in NOMINAL.items()}
    p["a"] += np.clip(rng.normal(0, len_sd, 6), -3 * len_sd, 3 * len_sd)
    p["d"] += np.clip(rng.normal(0, len_sd, 6), -3 * len_sd, 3 * len_sd)
    p["theta"] += rng.normal(0, ang_sd, 6)
    p["alpha"] += rng.normal(0, ang_sd, 6)
    p["beta"][1] += rng.normal(0, beta_sd)
    return p


def params_to_dict(p):
    """Parameters in mm / deg for the key (names as in docs/conventions.md)."""
    out = {}
    for k, unit in (("theta", "deg"), ("d", "mm"), ("a", "mm"), ("alpha", "deg")):
        for i in range(6):
            v = p[k][i] / DEG if unit == "deg" else p[k][i] * 1e3
            out[f"{k}{i + 1}_{unit}"] = round(float(v), 9)
    out["beta2_deg"] = round(float(p["beta"][1] / DEG), 9)
    return out


# ---------------------------------------------------------------- gravity loads


def body_positions(F, bodies):
    """Centres of mass in the base frame: (n, B, 3) from frames (n, 7, 4, 4)."""
    return np.stack([F[:, f, :3, :3] @ c + F[:, f, :3, 3] for f, _, c in bodies], axis=1)


def gravity_torques(F, bodies, extra=()):
    """Torque gravity exerts on each joint about its +z axis [N m] (n, 6): tau_j = z_j . sum_b (c_b - o_j) x m_b g
    over the bodies carried by joint j (written in frames >= j). ``extra``: more bodies (frame, mass, com)."""
    allb = list(bodies) + list(extra)
    C = body_positions(F, allb)
    n = F.shape[0]
    tau = np.zeros((n, 6))
    for j in range(6):
        o = F[:, j + 1, :3, 3]
        z = F[:, j + 1, :3, 2]
        for b, (f, m, _) in enumerate(allb):
            if f >= j + 1:
                tau[:, j] += np.einsum("ij,ij->i", z, np.cross(C[:, b] - o, m * G))
    return tau


def base_moment(F, bodies, extra=()):
    """Gravity moment of the whole arm about the base origin [N m] (n, 3) in the base frame: sum_b c_b x m_b g."""
    allb = list(bodies) + list(extra)
    C = body_positions(F, allb)
    return sum(np.cross(C[:, b], m * G) for b, (_, m, _) in enumerate(allb))


def mdh_to_joint_table(p=NOMINAL):
    """The MDH table written as URDF-style joints (docs/conventions.md, "any serial chain"): joint i's origin is
    RotX(alpha_i) TransX(a_i) TransZ(d_i) RotZ(theta_i), i.e. xyz = RotX(alpha) (a, 0, d) and the rotation
    RotX(alpha) RotZ(theta) as rpy with R = Rz(yaw) Ry(pitch) Rx(roll); its frame after the joint is MDH frame i."""
    out = []
    for i in range(6):
        Rx = rotx(p["alpha"][i])
        xyz = Rx @ np.array([p["a"][i], 0.0, p["d"][i]])
        R = Rx @ rotz(p["theta"][i])
        pitch = np.arcsin(np.clip(-R[2, 0], -1, 1))
        if abs(np.cos(pitch)) > 1e-9:
            roll = np.arctan2(R[2, 1], R[2, 2])
            yaw = np.arctan2(R[1, 0], R[0, 0])
        else:  # gimbal: put everything in yaw
            roll = 0.0
            yaw = np.arctan2(-R[0, 1], R[1, 1])
        Rc = rotz(yaw) @ roty(pitch) @ rotx(roll)
        assert np.allclose(Rc, R, atol=1e-12), (i, Rc, R)
        out.append((xyz, np.array([roll, pitch, yaw])))
    return out
