"""Own forward kinematics (Craig modified DH + beta on joint 2), written from docs/conventions.md only.

Units inside this generator: millimetres for lengths, radians for angles, seconds, degC, kg, N.
Transforms are named A2B (p_B = A2B @ p_A) and batched as (n, 4, 4) arrays.

Joint i transform (mdh):  RotX(alpha_i) TransX(a_i) TransZ(d_i) RotZ(theta_i + q_i) RotY(beta_i)
Tool pose:  tool2meas = base2meas @ flange2base(q) @ tool2flange
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

DEG = np.pi / 180.0


# ---------------------------------------------------------------------------------------------- transforms
def eye(n: int) -> np.ndarray:
    return np.broadcast_to(np.eye(4), (n, 4, 4)).copy()


def rot_x(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, float)
    T = eye(a.size)
    c, s = np.cos(a), np.sin(a)
    T[:, 1, 1], T[:, 1, 2], T[:, 2, 1], T[:, 2, 2] = c, -s, s, c
    return T


def rot_y(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, float)
    T = eye(a.size)
    c, s = np.cos(a), np.sin(a)
    T[:, 0, 0], T[:, 0, 2], T[:, 2, 0], T[:, 2, 2] = c, s, -s, c
    return T


def rot_z(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, float)
    T = eye(a.size)
    c, s = np.cos(a), np.sin(a)
    T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = c, -s, s, c
    return T


def trans(v: np.ndarray) -> np.ndarray:
    v = np.atleast_2d(np.asarray(v, float))
    T = eye(v.shape[0])
    T[:, :3, 3] = v
    return T


def rotvec_to_R(rv: np.ndarray) -> np.ndarray:
    """Rodrigues, batched: (n, 3) rotation vectors [rad] -> (n, 3, 3)."""
    rv = np.atleast_2d(np.asarray(rv, float))
    th = np.linalg.norm(rv, axis=1)
    small = th < 1e-12
    k = np.where(small[:, None], 0.0, rv / np.where(small, 1.0, th)[:, None])
    K = np.zeros((rv.shape[0], 3, 3))
    K[:, 0, 1], K[:, 0, 2] = -k[:, 2], k[:, 1]
    K[:, 1, 0], K[:, 1, 2] = k[:, 2], -k[:, 0]
    K[:, 2, 0], K[:, 2, 1] = -k[:, 1], k[:, 0]
    s, c = np.sin(th)[:, None, None], np.cos(th)[:, None, None]
    R = np.eye(3)[None] + s * K + (1 - c) * (K @ K)
    # second order for tiny angles (keeps derivatives exact near zero)
    Ks = np.zeros_like(K)
    Ks[:, 0, 1], Ks[:, 0, 2] = -rv[:, 2], rv[:, 1]
    Ks[:, 1, 0], Ks[:, 1, 2] = rv[:, 2], -rv[:, 0]
    Ks[:, 2, 0], Ks[:, 2, 1] = -rv[:, 1], rv[:, 0]
    R_small = np.eye(3)[None] + Ks + 0.5 * Ks @ Ks
    return np.where(small[:, None, None], R_small, R)


def R_to_rotvec(R: np.ndarray) -> np.ndarray:
    R = np.atleast_3d(R) if R.ndim == 2 else R
    if R.ndim == 2:
        R = R[None]
    tr = np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1, 1)
    th = np.arccos(tr)
    w = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], axis=1)
    s = np.sin(th)
    fac = np.where(th < 1e-9, 0.5, th / (2 * np.where(np.abs(s) < 1e-15, 1.0, s)))
    return w * fac[:, None]


def pose6_to_T(p6) -> np.ndarray:
    """(x, y, z [mm], rx, ry, rz [rad]) -> (4, 4)."""
    p6 = np.asarray(p6, float)
    T = np.eye(4)
    T[:3, :3] = rotvec_to_R(p6[None, 3:])[0]
    T[:3, 3] = p6[:3]
    return T


def T_to_pose6(T: np.ndarray) -> np.ndarray:
    return np.concatenate([T[:3, 3], R_to_rotvec(T[None, :3, :3])[0]])


def inv_T(T: np.ndarray) -> np.ndarray:
    out = np.zeros_like(T)
    R = T[..., :3, :3]
    out[..., :3, :3] = np.swapaxes(R, -1, -2)
    out[..., :3, 3] = -np.einsum("...ji,...j->...i", R, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def about_point(R: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(n,3,3) rotation about the point(s) c (n,3) or (3,) as (n,4,4)."""
    n = R.shape[0]
    c = np.broadcast_to(np.asarray(c, float), (n, 3))
    T = eye(n)
    T[:, :3, :3] = R
    T[:, :3, 3] = c - np.einsum("nij,nj->ni", R, c)
    return T


# ---------------------------------------------------------------------------------------------- robots
@dataclass
class Robot:
    name: str
    theta: np.ndarray  # (6,) rad offsets
    d: np.ndarray  # (6,) mm
    a: np.ndarray  # (6,) mm
    alpha: np.ndarray  # (6,) rad
    beta2: float  # rad, on joint 2
    q_min: np.ndarray  # rad
    q_max: np.ndarray  # rad
    named: bool = True  # known to the tool by name (else written inline)
    # gravity model (own guesses; used by gravity-driven effects only)
    masses: np.ndarray = field(default_factory=lambda: np.zeros(6))  # kg, link i carried by joint i
    com_frac: np.ndarray = field(default_factory=lambda: np.zeros(6))  # COM at frac * origin of frame i+1
    com_off: np.ndarray = field(default_factory=lambda: np.zeros((6, 3)))  # + this offset [mm], frame i

    def copy(self, **kw) -> "Robot":
        r = replace(self, **kw)
        for k in ("theta", "d", "a", "alpha", "q_min", "q_max", "masses", "com_frac", "com_off"):
            setattr(r, k, np.array(getattr(r, k), float).copy())
        return r

    def toml_table(self) -> str:
        f = lambda v: "[" + ", ".join(f"{x:.6g}" for x in v) + "]"
        return (
            "[robot]\n"
            f'name = "{self.name}"\n'
            'convention = "mdh"\n'
            "beta_joints = [2]\n"
            f"theta_deg = {f(np.round(self.theta / DEG, 9))}\n"
            f"d_mm = {f(self.d)}\n"
            f"a_mm = {f(self.a)}\n"
            f"alpha_deg = {f(np.round(self.alpha / DEG, 9))}\n"
            f"beta_deg = [{self.beta2 / DEG:.6g}]\n"
            f"q_min_deg = {f(np.round(self.q_min / DEG, 6))}\n"
            f"q_max_deg = {f(np.round(self.q_max / DEG, 6))}\n"
        )


def _robot(name, table, limits, masses, com_frac, com_off, named):
    t = np.asarray(table, float)  # rows: alpha deg, a mm, d mm, theta deg
    lim = np.asarray(limits, float) * DEG
    return Robot(
        name=name,
        theta=t[:, 3] * DEG,
        d=t[:, 2].copy(),
        a=t[:, 1].copy(),
        alpha=t[:, 0] * DEG,
        beta2=0.0,
        q_min=lim[:, 0],
        q_max=lim[:, 1],
        named=named,
        masses=np.asarray(masses, float),
        com_frac=np.asarray(com_frac, float),
        com_off=np.asarray(com_off, float),
    )


def irb1200() -> Robot:
    """Nominal table copied from twin/robots.py (allowed); masses/COMs are this generator's own guesses."""
    return _robot(
        "irb1200",
        [[0, 0, 399.1, 0], [-90, 0, 0, -90], [0, 350, 0, 0], [-90, 42, 351, 0], [90, 0, 0, 0], [-90, 0, 82, 0]],
        [[-170, 170], [-100, 130], [-200, 70], [-270, 270], [-130, 130], [-360, 360]],
        masses=[14.0, 8.5, 6.0, 2.2, 1.0, 0.35],
        com_frac=[0.0, 0.5, 0.45, 0.0, 0.0, 0.0],
        com_off=[[0, 0, -120], [0, 0, 25], [10, 0, -5], [0, 0, -70], [0, -8, 0], [0, 0, -6]],
        named=True,
    )


def arm_b() -> Robot:
    """A smaller 6R arm with a shoulder offset (inline [robot] table)."""
    return _robot(
        "heldout_arm_b",
        [[0, 0, 330.0, 0], [-90, 25.0, 0, -90], [0, 300.0, 0, 0], [-90, 30.0, 295.0, 0], [90, 0, 0, 0], [-90, 0, 75.0, 0]],
        [[-165, 165], [-95, 135], [-190, 75], [-240, 240], [-125, 125], [-350, 350]],
        masses=[11.0, 6.5, 4.5, 1.8, 0.8, 0.3],
        com_frac=[0.0, 0.5, 0.45, 0.0, 0.0, 0.0],
        com_off=[[0, 0, -100], [0, 0, 20], [8, 0, -4], [0, 0, -60], [0, -6, 0], [0, 0, -5]],
        named=False,
    )


def arm_c() -> Robot:
    """A larger 6R arm: longer upper arm and forearm, 60 mm shoulder offset (inline [robot] table)."""
    return _robot(
        "heldout_arm_c",
        [[0, 0, 450.0, 0], [-90, 60.0, 0, -90], [0, 400.0, 0, 0], [-90, 20.0, 420.0, 0], [90, 0, 0, 0], [-90, 0, 95.0, 0]],
        [[-170, 170], [-90, 150], [-210, 70], [-200, 200], [-125, 125], [-360, 360]],
        masses=[20.0, 12.0, 8.0, 3.0, 1.2, 0.45],
        com_frac=[0.0, 0.5, 0.45, 0.0, 0.0, 0.0],
        com_off=[[0, 0, -150], [0, 0, 30], [12, 0, -5], [0, 0, -90], [0, -9, 0], [0, 0, -7]],
        named=False,
    )


ROBOTS = {"irb1200": irb1200, "arm_b": arm_b, "arm_c": arm_c}


# ---------------------------------------------------------------------------------------------- modifications
class Mods:
    """Everything an effect may change, per row. Composed left-to-right in the order effects are added."""

    def __init__(self, n: int):
        self.n = n
        self.dq = np.zeros((n, 6))  # added to the commanded joints [rad]
        self.dpar = {k: np.zeros((n, 6)) for k in ("theta", "d", "a", "alpha")}
        self.dbeta2 = np.zeros(n)
        self.pre: list = [None] * 6  # (n,4,4) left of joint i's transform (in frame i-1)
        self.post: list = [None] * 6  # (n,4,4) right of joint i's transform (in frame i)
        self.base = None  # (n,4,4): p_base_true = base @ p_chain (robot base moved in its own frame)
        self.meas = None  # (n,4,4): left of base2meas (measurement frame moved)
        self.flange = None  # (n,4,4): right of flange2base (rigid motion of the plate at the flange)
        self.plate = np.zeros((n, 3, 3))  # sphere displacements in the tool frame [mm]
        self.point_fns: list = []  # f(points_meas (n,3,3)) -> points (instrument effects)

    @staticmethod
    def _mul(A, B):
        if A is None:
            return B
        if B is None:
            return A
        return A @ B

    def add(self, o: "Mods") -> "Mods":
        self.dq += o.dq
        for k in self.dpar:
            self.dpar[k] += o.dpar[k]
        self.dbeta2 += o.dbeta2
        for i in range(6):
            self.pre[i] = self._mul(self.pre[i], o.pre[i])
            self.post[i] = self._mul(self.post[i], o.post[i])
        self.base = self._mul(o.base, self.base)
        self.meas = self._mul(o.meas, self.meas)
        self.flange = self._mul(self.flange, o.flange)
        self.plate = self.plate + o.plate
        self.point_fns = self.point_fns + o.point_fns
        return self

    def subset(self, idx) -> "Mods":
        m = Mods(len(np.arange(self.n)[idx]))
        m.dq = self.dq[idx]
        m.dpar = {k: v[idx] for k, v in self.dpar.items()}
        m.dbeta2 = self.dbeta2[idx]
        m.pre = [None if x is None else x[idx] for x in self.pre]
        m.post = [None if x is None else x[idx] for x in self.post]
        m.base = None if self.base is None else self.base[idx]
        m.meas = None if self.meas is None else self.meas[idx]
        m.flange = None if self.flange is None else self.flange[idx]
        m.plate = self.plate[idx]
        m.point_fns = list(self.point_fns)  # point functions act on points only (row-independent)
        return m


def link_frames(robot: Robot, q: np.ndarray, mods: Mods | None = None) -> list[np.ndarray]:
    """Frames 1..6 in the base frame, (n,4,4) each. q (n,6) commanded joints [rad]."""
    q = np.atleast_2d(q)
    n = q.shape[0]
    if mods is None:
        mods = Mods(n)
    qa = q + mods.dq
    T = eye(n) if mods.base is None else mods.base.copy()
    out = []
    for i in range(6):
        alpha = robot.alpha[i] + mods.dpar["alpha"][:, i]
        a = robot.a[i] + mods.dpar["a"][:, i]
        d = robot.d[i] + mods.dpar["d"][:, i]
        th = robot.theta[i] + mods.dpar["theta"][:, i] + qa[:, i]
        Ti = rot_x(alpha)
        Ti[:, :3, 3] = 0.0
        # TransX(a) TransZ(d) expressed after RotX(alpha): origin = RotX(alpha) @ (a, 0, d)
        ca, sa = np.cos(alpha), np.sin(alpha)
        Ti[:, 0, 3] = a
        Ti[:, 1, 3] = -sa * d
        Ti[:, 2, 3] = ca * d
        Ti = Ti @ rot_z(th)
        if i == 1:
            Ti = Ti @ rot_y(robot.beta2 + mods.dbeta2)
        if mods.pre[i] is not None:
            Ti = mods.pre[i] @ Ti
        if mods.post[i] is not None:
            Ti = Ti @ mods.post[i]
        T = T @ Ti
        out.append(T)
    return out


def flange2base(robot, q, mods=None):
    return link_frames(robot, q, mods)[-1]


def sphere_points(robot, q, station, base2meas, tool2flange, spheres_tool, mods=None):
    """Sphere centres in each row's measurement frame, (n, 3, 3) [mm].

    station: (n,) int index into base2meas (list of (4,4)); spheres_tool (3,3) rows p0..p2 in the tool frame.
    """
    q = np.atleast_2d(q)
    n = q.shape[0]
    if mods is None:
        mods = Mods(n)
    F = flange2base(robot, q, mods)
    if mods.flange is not None:
        F = F @ mods.flange
    B2M = np.stack([base2meas[s] for s in station])
    if mods.meas is not None:
        B2M = mods.meas @ B2M
    T = B2M @ F @ tool2flange[None]
    S = spheres_tool[None] + mods.plate  # (n,3,3)
    P = np.einsum("nij,nkj->nki", T[:, :3, :3], S) + T[:, None, :3, 3]
    for f in mods.point_fns:
        P = f(P)
    return P


# ---------------------------------------------------------------------------------------------- gravity
G = np.array([0.0, 0.0, -9.81])  # m/s^2 in the base frame (base z is up)


def com_positions(robot: Robot, frames: list[np.ndarray], payload_kg=0.0, payload_com_mm=(0, 0, 0)):
    """Link centres of mass in the base frame [mm], (n, 7, 3) (links 1..6 + payload), and masses (7,)."""
    n = frames[0].shape[0]
    coms = []
    for i in range(6):
        if i < 5:
            nxt = np.linalg.inv(frames[i][0]) @ frames[i + 1][0]  # origin of frame i+1 in frame i (row 0 ~ nominal)
            o_next = nxt[:3, 3]
        else:
            o_next = np.zeros(3)
        c_local = robot.com_frac[i] * o_next + robot.com_off[i]
        coms.append(np.einsum("nij,j->ni", frames[i][:, :3, :3], c_local) + frames[i][:, :3, 3])
    pc = np.asarray(payload_com_mm, float)
    coms.append(np.einsum("nij,j->ni", frames[5][:, :3, :3], pc) + frames[5][:, :3, 3])
    m = np.concatenate([robot.masses, [payload_kg]])
    return np.stack(coms, axis=1), m


def gravity_joint_torques(robot: Robot, q: np.ndarray, payload_kg=0.0, payload_com_mm=(0, 0, 0)):
    """Gravity torque about each joint axis [N m], (n, 6): tau_j = z_j . sum_{k>=j} (p_k - o_j) x m_k g."""
    frames = link_frames(robot, q)
    coms, m = com_positions(robot, frames, payload_kg, payload_com_mm)
    n = q.shape[0]
    tau = np.zeros((n, 6))
    for j in range(6):
        z = frames[j][:, :3, 2]
        o = frames[j][:, :3, 3]
        tot = np.zeros((n, 3))
        for k in range(j, 7):
            r = (coms[:, k] - o) * 1e-3
            tot += np.cross(r, m[k] * G[None])
        tau[:, j] = np.einsum("ni,ni->n", z, tot)
    return tau


# ---------------------------------------------------------------------------------------------- parameter Jacobian
def param_jacobian(robot, q, station, base2meas, tool2flange, spheres_tool, n_stations):
    """d(sphere coords)/d(geometric parameters) by central differences: columns theta1..6, d1..6, a1..6,
    alpha1..6, beta2, tool(6, in the flange frame), base2meas(6 per station, in the measurement frame).
    Rows: (n*9,). Units mm per (mm | rad)."""
    n = q.shape[0]
    cols = []

    def f(rob=robot, t2f=tool2flange, b2m=base2meas):
        return sphere_points(rob, q, station, b2m, t2f, spheres_tool).reshape(-1)

    for key in ("theta", "d", "a", "alpha"):
        h = 1e-6 if key in ("theta", "alpha") else 1e-3
        for i in range(6):
            rp, rm = robot.copy(), robot.copy()
            getattr(rp, key)[i] += h
            getattr(rm, key)[i] -= h
            cols.append((f(rob=rp) - f(rob=rm)) / (2 * h))
    h = 1e-6
    cols.append((f(rob=robot.copy(beta2=robot.beta2 + h)) - f(rob=robot.copy(beta2=robot.beta2 - h))) / (2 * h))
    for k in range(6):
        h = 1e-3 if k < 3 else 1e-6
        dp = np.zeros(6)
        dp[k] = h
        cols.append((f(t2f=tool2flange @ pose6_to_T(dp)) - f(t2f=tool2flange @ pose6_to_T(-dp))) / (2 * h))
    for s in range(n_stations):
        for k in range(6):
            h = 1e-3 if k < 3 else 1e-6
            dp = np.zeros(6)
            dp[k] = h
            bp = list(base2meas)
            bm = list(base2meas)
            bp[s] = pose6_to_T(dp) @ base2meas[s]
            bm[s] = pose6_to_T(-dp) @ base2meas[s]
            cols.append((f(b2m=bp) - f(b2m=bm)) / (2 * h))
    return np.stack(cols, axis=1)


def residual_after_geometric_fit(J: np.ndarray, e: np.ndarray, weights: np.ndarray | None = None):
    """What a (linearised) geometric calibration leaves of the contribution e (flattened like J's rows)."""
    Jw = J if weights is None else J * weights[:, None]
    ew = e if weights is None else e * weights
    scale = np.linalg.norm(Jw, axis=0)
    scale[scale == 0] = 1.0
    x, *_ = np.linalg.lstsq(Jw / scale, ew, rcond=1e-10)
    r = ew - (Jw / scale) @ x
    return r if weights is None else r / weights
