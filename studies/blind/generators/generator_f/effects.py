"""The effects: each turns a campaign context into changes of the true measurement chain and a key entry.

The chain of row i (station s, commanded joints q_i):

    P_ik = Meas_i . base2meas[s] . Base_i . flange2base(true geometry, q_i + dq_i) . tool2flange . Tool_i . s_k

``dq`` (n, 6) [rad] adds to the commanded joints; ``tool`` (n, 4, 4) acts in the flange frame after the true
tool2flange (the plate moved on the flange); ``meas`` (n, 4, 4) is left-multiplied on base2meas (the camera moved);
``base`` (n, 4, 4) is left-multiplied on flange2base (the whole robot turned about its base origin). Each spec value
given as a 2-tuple is drawn uniformly from it, a list is a choice, anything else is taken as is.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

import kin

FAMILY_OF = {  # kind -> key family (a catalogue name, or a description of what lies outside the catalogue)
    "zero_glitch": "joint_zero_glitch", "zero_step": "joint_zero_step", "tool_knock": "tool_step",
    "camera_bump": "measurement_frame_step", "payload": "compliance", "compliance": "compliance",
    "load_backlash": "backlash", "base_tilt": "tilt", "cyclic": "cyclic",
}
CATALOGUE = {"compliance", "backlash", "cyclic", "gear_ratio", "coupling", "thermal", "plate_geometry", "tilt"}


def draw(rng, v):
    if isinstance(v, tuple) and len(v) == 2 and all(isinstance(x, (int, float)) for x in v):
        if all(isinstance(x, int) for x in v):
            return int(rng.integers(v[0], v[1] + 1))
        return float(rng.uniform(*v))
    if isinstance(v, list):
        return v[int(rng.integers(len(v)))]
    return v


@dataclass
class Ctx:
    """One campaign's rows (dataset rows first, then the test rows), all arrays over the N rows."""
    Q: np.ndarray  # (N, 6) commanded joints [rad]
    F: np.ndarray  # (N, 7, 4, 4) true frames at the commanded joints
    t: np.ndarray  # (N,) time [s]
    station: np.ndarray  # (N,) station index
    pose_id: np.ndarray  # (N,)
    n_data: int
    stations: list
    bodies: list
    session_start_rows: list = field(default_factory=list)  # rows where a new session starts

    @property
    def N(self):
        return len(self.Q)


@dataclass
class Effect:
    key: dict
    dq: np.ndarray | None = None
    tool: np.ndarray | None = None
    meas: np.ndarray | None = None
    base: np.ndarray | None = None


def _change_row(rng, ctx, spec):
    """The dataset row where a change happens: ``at`` a fraction of the dataset rows (or ``session`` k: the first
    row of the k-th session start)."""
    if "session" in spec:
        return ctx.session_start_rows[spec["session"]]
    return int(round(draw(rng, spec["at"]) * ctx.n_data))


def _moment(ctx, r):
    return {"row": int(r) + 1, "pose_id": int(ctx.pose_id[r]), "t_s": round(float(ctx.t[r]), 1)}


def _eye(n):
    return np.broadcast_to(np.eye(4), (n, 4, 4)).copy()


def _rigid(rot_vec, pivot, trans):
    """Rotation ``rot_vec`` about ``pivot`` followed by a translation ``trans`` (all in one frame)."""
    T = np.eye(4)
    R = kin.rotvec_to_matrix(rot_vec)
    T[:3, :3] = R
    T[:3, 3] = pivot - R @ pivot + trans
    return T


def _unit(rng):
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def make(kind, spec, rng, ctx):
    return globals()["_" + kind](spec, rng, ctx)


def _zero_glitch(spec, rng, ctx):
    """A joint's zero slips by delta for a window of rows and comes back (a resolver count lost, re-referenced)."""
    j = draw(rng, spec["joint"])
    delta = draw(rng, spec["delta_deg"]) * rng.choice([-1, 1])
    r0 = _change_row(rng, ctx, spec)
    r1 = min(r0 + draw(rng, spec["length"]), ctx.n_data - 1)
    dq = np.zeros((ctx.N, 6))
    dq[r0:r1, j - 1] = delta * kin.DEG
    a, b = _moment(ctx, r0), _moment(ctx, r1)
    key = dict(
        family=FAMILY_OF["zero_glitch"],
        description=f"joint {j}'s zero slips by {delta:+.4f} deg for {r1 - r0} consecutive rows (pose_id "
                    f"{a['pose_id']}..{int(ctx.pose_id[r1 - 1])}, t_s {a['t_s']}..{round(float(ctx.t[r1 - 1]), 1)}) and "
                    f"comes back: an encoder count lost and found again at the next reference; rows after the window, "
                    f"test rows included, are in the original state",
        formula=f"q{j}_actual = q{j}_cmd + {delta:+.5f} deg for dataset rows {r0 + 1}..{r1} (1-based), else q{j}_cmd",
        joints=[j], links=[f"theta{j}"], place="joint", channel=f"window of rows {r0 + 1}..{r1} (t_s {a['t_s']}..{b['t_s']})",
        params=dict(joint=j, delta_deg=round(delta, 6)),
        changes=[dict(a, what="zero slips", size_deg=round(delta, 6)), dict(b, what="zero back", size_deg=round(-delta, 6))],
    )
    return Effect(key, dq=dq)


def _zero_step(spec, rng, ctx):
    """A joint's zero steps at one row and stays (re-latched to a neighbouring reference mark)."""
    j = draw(rng, spec["joint"])
    delta = draw(rng, spec["delta_deg"]) * rng.choice([-1, 1])
    r0 = _change_row(rng, ctx, spec)
    dq = np.zeros((ctx.N, 6))
    dq[r0:, j - 1] = delta * kin.DEG
    a = _moment(ctx, r0)
    key = dict(
        family=FAMILY_OF["zero_step"],
        description=f"joint {j}'s zero steps by {delta:+.4f} deg at pose_id {a['pose_id']} (t_s {a['t_s']}) and stays "
                    f"(the test rows too)",
        formula=f"q{j}_actual = q{j}_cmd + {delta:+.5f} deg * [row >= {r0 + 1}]",
        joints=[j], links=[f"theta{j}"], place="joint", channel=f"step at row {r0 + 1} (t_s {a['t_s']})",
        params=dict(joint=j, delta_deg=round(delta, 6)), changes=[dict(a, what="zero steps", size_deg=round(delta, 6))],
    )
    return Effect(key, dq=dq)


def _tool_knock(spec, rng, ctx):
    """The plate is knocked on the flange: a rigid step of tool2flange (a turn about a contact point on the plate's
    rim, the clamping screws slipping, plus a small slide), from one row on."""
    r0 = _change_row(rng, ctx, spec)
    ang = draw(rng, spec["rot_deg"]) * kin.DEG
    slide = draw(rng, spec["slide_mm"]) * 1e-3
    phi = rng.uniform(0, 2 * np.pi)
    pivot = np.array([0.045 * np.cos(phi), 0.045 * np.sin(phi), 0.006])  # a contact on the plate's rim [m]
    axis = _unit(rng)
    axis[2] *= 2.0  # mostly a turn about the flange axis and a rock on the rim
    axis /= np.linalg.norm(axis)
    sd = _unit(rng) * slide
    sd[2] *= 0.3
    K = _rigid(axis * ang, pivot, sd)
    tool = _eye(ctx.N)
    tool[r0:] = K
    a = _moment(ctx, r0)
    disp = np.linalg.norm((K[:3, :3] @ kin.SPHERES_FLANGE.T).T + K[:3, 3] - kin.SPHERES_FLANGE, axis=1)
    key = dict(
        family=FAMILY_OF["tool_knock"],
        description=f"the sphere plate is knocked on the flange at pose_id {a['pose_id']} (t_s {a['t_s']}): a rigid "
                    f"step of tool2flange, {ang / kin.DEG:.4f} deg about a contact on the rim plus a {slide * 1e3:.4f} mm "
                    f"slide (spheres moved {disp.min() * 1e3:.4f}..{disp.max() * 1e3:.4f} mm on the flange); stays",
        formula="tool2flange_i = tool2flange . K for rows >= the knock; K = Trans(c) Rot(w) Trans(-c) then Trans(s) in "
                f"the flange frame, c = {np.round(pivot * 1e3, 2).tolist()} mm, w = {np.round(axis * ang, 8).tolist()} "
                f"rad, s = {np.round(sd * 1e3, 5).tolist()} mm",
        joints=[], links=[], place="tool", channel=f"step at row {r0 + 1} (t_s {a['t_s']})",
        params=dict(rot_deg=round(ang / kin.DEG, 6), slide_mm=round(slide * 1e3, 6), pivot_mm=np.round(pivot * 1e3, 3).tolist()),
        changes=[dict(a, what="plate knocked", size_mm=round(float(disp.max() * 1e3), 5))],
    )
    return Effect(key, tool=tool)


def _camera_bump(spec, rng, ctx):
    """The tripod is bumped: the rig turns about the tripod head (below and behind the left camera) and slides a
    little, from one row on, for the rows of the station in use."""
    r0 = _change_row(rng, ctx, spec)
    s = int(ctx.station[r0])
    ang = draw(rng, spec["rot_deg"]) * kin.DEG
    slide = draw(rng, spec["slide_mm"]) * 1e-3
    pivot = np.array([0.125, 0.11, -0.05])  # tripod head in the left camera frame (y down) [m]
    w = rng.normal(size=3) * np.array([1.0, 1.6, 0.5])  # mostly a pan (about the camera's vertical y), then a tilt
    w /= np.linalg.norm(w)
    sd = _unit(rng) * slide
    D = _rigid(w * ang, pivot, sd)  # the new camera frame in the old one: cam2base_new = cam2base . D
    Dinv = kin.inv(D)
    meas = _eye(ctx.N)
    sel = (np.arange(ctx.N) >= r0) & (ctx.station == s)
    meas[sel] = Dinv
    a = _moment(ctx, r0)
    key = dict(
        family=FAMILY_OF["camera_bump"],
        description=f"the camera tripod of station {s} is bumped at pose_id {a['pose_id']} (t_s {a['t_s']}): the rig "
                    f"turns {ang / kin.DEG:.4f} deg about the tripod head and slides {slide * 1e3:.4f} mm; a rigid step of "
                    f"that station's base2meas, which stays (the test rows too)",
        formula="base2meas_i = inv(D) . base2meas for rows of station %d from the bump on; D = Trans(c) Rot(w) Trans(-c) "
                "then Trans(s) in the camera frame, c = %s mm, w = %s rad, s = %s mm"
                % (s, np.round(pivot * 1e3, 1).tolist(), np.round(w * ang, 9).tolist(), np.round(sd * 1e3, 5).tolist()),
        joints=[], links=[], place="measurement", channel=f"step at row {r0 + 1} (t_s {a['t_s']}), station {s}",
        params=dict(station=s, rot_deg=round(ang / kin.DEG, 6), slide_mm=round(slide * 1e3, 6)),
        changes=[dict(a, what="tripod bumped", size_deg=round(ang / kin.DEG, 6), size_mm=round(slide * 1e3, 6))],
    )
    return Effect(key, meas=meas)


def _stiffness(rng, spec):
    return {int(j): draw(rng, v) for j, v in spec["k_nm_per_rad"].items()}


def _compliance_dq(ctx, k, extra_rows=None, extra=()):
    tau = kin.gravity_torques(ctx.F, ctx.bodies)
    if extra_rows is not None:
        tau_p = kin.gravity_torques(ctx.F, [], extra)
        tau = tau + tau_p * extra_rows[:, None]
    dq = np.zeros((ctx.N, 6))
    for j, kj in k.items():
        dq[:, j - 1] = tau[:, j - 1] / kj
    return dq, tau


def _compliance(spec, rng, ctx):
    """Joint compliance under the arm's own weight: dq_j = tau_j(q) / k_j."""
    k = _stiffness(rng, spec)
    dq, tau = _compliance_dq(ctx, k)
    js = sorted(k)
    key = dict(
        family="compliance",
        description="joints " + ", ".join(f"{j} (k = {k[j]:.4g} N m/rad, torque {tau[:ctx.n_data, j - 1].min():.1f}.."
                                            f"{tau[:ctx.n_data, j - 1].max():.1f} N m)" for j in js)
                    + " deflect under the arm's own gravity torque",
        formula="q_j,actual = q_j,cmd + tau_j(q_cmd) / k_j; tau_j = z_j . sum_b (c_b - o_j) x m_b g over the bodies "
                "beyond joint j (mass model in the notes)",
        joints=js, links=[], place="joint", channel="gravity torque tau_j(q)",
        params=dict(k_nm_per_rad={str(j): round(k[j], 1) for j in js}), changes=[],
    )
    return Effect(key, dq=dq)


def _payload(spec, rng, ctx):
    """Joint compliance under gravity, and a payload mounted on the flange (or taken off) at one row: the gravity
    torques, hence the deflections, change from that row on."""
    k = _stiffness(rng, spec)
    r0 = _change_row(rng, ctx, spec)
    m = draw(rng, spec["mass_kg"])
    c = np.array([draw(rng, v) for v in spec["com_mm"]]) * 1e-3
    removed = bool(spec.get("removed", False))
    on = np.zeros(ctx.N)
    if removed:
        on[:r0] = 1.0
    else:
        on[r0:] = 1.0
    dq, tau = _compliance_dq(ctx, k, on, [(6, m, c)])
    js = sorted(k)
    a = _moment(ctx, r0)
    verb = "taken off" if removed else "mounted"
    where = f"at session start {spec['session']}" if "session" in spec else "in the middle of a session"
    key = dict(
        family="compliance",
        description=f"joints {js} deflect under gravity (k = " + ", ".join(f"{k[j]:.4g}" for j in js) + " N m/rad); a "
                    f"{m:.2f} kg payload (centre of mass {np.round(c * 1e3, 1).tolist()} mm in the flange frame) is {verb} "
                    f"{where} at pose_id {a['pose_id']} (t_s {a['t_s']}); the torques change from that row on and "
                    f"stay changed in the test rows",
        formula="q_j,actual = q_j,cmd + (tau_j,arm(q) + L_i tau_j,payload(q)) / k_j; L_i = %s" % (
            f"[row < {r0 + 1}]" if removed else f"[row >= {r0 + 1}]"),
        joints=js, links=[], place="joint",
        channel=f"gravity torque, payload {verb} at row {r0 + 1} (t_s {a['t_s']})",
        params=dict(k_nm_per_rad={str(j): round(k[j], 1) for j in js}, payload_kg=round(m, 4),
                    payload_com_flange_mm=np.round(c * 1e3, 2).tolist(), removed=removed),
        changes=[dict(a, what=f"payload {verb}", size_kg=round(m, 4))],
    )
    return Effect(key, dq=dq)


def _load_backlash(spec, rng, ctx):
    """Backlash whose flank follows the load: the link rests on the flank its gravity torque pushes it against,
    dq_j = +b_j sign(tau_j) (tau_j the torque gravity exerts about +z_j; optionally a smooth tanh(tau/w) over a
    contact width w), whatever direction the joint last moved."""
    js = list(spec["joints"])
    b = {j: draw(rng, spec["b_deg"][j]) * kin.DEG for j in js}
    width = draw(rng, spec.get("width_nm", 0.0))
    tau = kin.gravity_torques(ctx.F, ctx.bodies)
    dq = np.zeros((ctx.N, 6))
    parts = []
    for j in js:
        tj = tau[:, j - 1]
        dq[:, j - 1] = b[j] * (np.tanh(tj / width) if width > 0 else np.sign(tj))
        d = tj[:ctx.n_data]
        flips = int(np.sum(np.sign(d[1:]) != np.sign(d[:-1])))
        parts.append(f"joint {j}: half clearance {b[j] / kin.DEG:.4f} deg, gravity torque {d.min():.2f}..{d.max():.2f} "
                     f"N m, positive on {np.mean(d > 0):.0%} of the dataset rows, {flips} sign changes between "
                     f"consecutive rows")
    key = dict(
        family="backlash",
        description="load-signed backlash: each gear rests on the flank its gravity torque pushes the link against "
                    "(positive torque about +z_j: the link sits +b_j ahead of the motor side, on the positive flank), "
                    "independent of the direction of the last move; the offset flips where the torque changes sign. "
                    + "; ".join(parts),
        formula="q_j,actual = q_j,cmd + b_j * " + (f"tanh(tau_j(q) / {width:.3f} N m)" if width > 0 else "sign(tau_j(q))")
                + "; tau_j = z_j . sum_b (c_b - o_j) x m_b g over the bodies beyond joint j",
        joints=js, links=[], place="joint", channel="sign of the gravity torque tau_j(q)",
        params=dict(half_clearance_deg={str(j): round(b[j] / kin.DEG, 6) for j in js}, width_nm=round(width, 4)),
        changes=[],
    )
    return Effect(key, dq=dq)


def _base_tilt(spec, rng, ctx):
    """The whole robot tilts on its base under the gravity moment of the arm about the base origin: rotation
    vector w = (C M_xy, 0) about horizontal axes through the base origin, C a 2x2 compliance [rad/(N m)]."""
    c1 = draw(rng, spec["c_urad_per_nm"]) * 1e-6
    ratio = draw(rng, spec.get("anisotropy", 1.0))
    phi = draw(rng, spec.get("axis_deg", (0.0, 180.0))) * kin.DEG
    Rp = np.array([[np.cos(phi), -np.sin(phi)], [np.sin(phi), np.cos(phi)]])
    C = Rp @ np.diag([c1, c1 / ratio]) @ Rp.T
    M = kin.base_moment(ctx.F, ctx.bodies)
    w = np.zeros((ctx.N, 3))
    w[:, :2] = M[:, :2] @ C.T
    base = np.stack([_rigid(wi, np.zeros(3), np.zeros(3)) for wi in w])
    d = M[:ctx.n_data, :2]
    tilt = np.linalg.norm(w[:ctx.n_data], axis=1)
    key = dict(
        family="tilt",
        description=f"the base gives: the whole robot tilts about horizontal axes through the base origin under the "
                    f"arm's gravity moment about the base (M_x {d[:, 0].min():.1f}..{d[:, 0].max():.1f}, M_y "
                    f"{d[:, 1].min():.1f}..{d[:, 1].max():.1f} N m), compliance {c1 * 1e6:.3f} and "
                    f"{c1 / ratio * 1e6:.3f} urad/(N m) along principal axes at {phi / kin.DEG:.1f} deg from base x; tilt "
                    f"{tilt.min() * 1e6:.1f}..{tilt.max() * 1e6:.1f} urad",
        formula="flange2base_i = Rot(w_i) . flange2base(q_i); w_i = (C [M_x, M_y], 0); M = sum_b c_b x m_b g (base "
                "frame, every moving body); C = R(phi) diag(c1, c2) R(phi)^T = %s rad/(N m)" % np.round(C, 12).tolist(),
        joints=[], links=[], place="base", channel="gravity moment of the arm about the base origin",
        params=dict(c_urad_per_nm=[round(c1 * 1e6, 5), round(c1 / ratio * 1e6, 5)], axis_deg=round(phi / kin.DEG, 3)),
        changes=[],
    )
    return Effect(key, base=base)


def _cyclic(spec, rng, ctx):
    """A once- or twice-per-turn error of a joint's gear train: dq_j = A sin(n q_j + phi)."""
    j = draw(rng, spec["joint"])
    A = draw(rng, spec["amp_deg"]) * kin.DEG
    n = draw(rng, spec["order"])
    ph = rng.uniform(0, 2 * np.pi)
    dq = np.zeros((ctx.N, 6))
    dq[:, j - 1] = A * np.sin(n * ctx.Q[:, j - 1] + ph)
    key = dict(
        family="cyclic",
        description=f"joint {j}'s transmission error: {A / kin.DEG:.4f} deg amplitude, {n} per turn of the joint",
        formula=f"q{j}_actual = q{j}_cmd + {A / kin.DEG:.5f} deg * sin({n} q{j}_cmd + {ph:.4f})",
        joints=[j], links=[], place="joint", channel=f"sin/cos({n} q{j})",
        params=dict(joint=j, amp_deg=round(A / kin.DEG, 6), order=n, phase_rad=round(ph, 5)), changes=[],
    )
    return Effect(key, dq=dq)
