"""The effect families: each draws its instance (``draw``: where, which shape, when), turns the drawn parameters into
changes of the true measurement chain (``apply``, deterministic: the key's ``params`` give the effect back) and
says what it is in words (``words``).

The chain of row i (station s, commanded joints q_i)::

    P_ik = Meas_i . base2meas[s] . Base_i . flange2base(true geometry with lengths x Scale_i, q_i + dq_i)
           . tool2flange . Tool_i . p_k

``dq`` ``(N, 6)`` [rad] adds to the commanded joints; ``length_scale`` ``(N, 2, 6)`` multiplies each ``d`` and ``a``;
``tool`` ``(N, 4, 4)`` acts in the flange frame after the true tool2flange (the plate or the reflector moved on the
flange); ``meas`` ``(N, 4, 4)`` is left-multiplied on base2meas (the instrument moved); ``base`` ``(N, 4, 4)`` turns
the whole robot in its base frame.

Every family's size is one number, ``params["scale"]``, that multiplies the whole effect to first order: the
campaign sets it so that the part of the effect the geometry cannot take has the drawn ratio to the noise
(``campaign.py``). Joint 1 carries no gravity torque (the base stands upright), so the load families act on joints
2-6 where their torque is large enough to matter (``TAU_MIN``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from twin.units import DEG_PER_RAD, MM_PER_M, M_PER_MM, RAD_PER_DEG

from . import kin

__all__ = [
    "Redraw", "Ctx", "Effect", "Family", "FAMILIES", "lag", "air_profile", "window_tail", "heat_state", "payload_on",
    "tilt_compliance", "thermal_link_temperature", "frame_change_transform"
]


class Redraw(Exception):
    """The drawn instance cannot act on this campaign (a joint without load, a range without a period): draw
    again."""


@dataclass
class Ctx:
    """One campaign's rows (the dataset's, then the later rows), arrays over the N rows."""

    robot: object
    params: dict  # the true geometry
    Q: np.ndarray  # (N, 6) commanded joints [rad]
    F: np.ndarray  # (N, 7, 4, 4) true frames at the commanded joints
    t: np.ndarray  # (N,) [s]
    station: np.ndarray  # (N,) station index
    n_data: int
    bodies: tuple  # the true bodies (the robot's and the instrument's nest)
    base2meas: np.ndarray  # (S, 4, 4)
    points_tool: np.ndarray  # (K, 3) [m]
    air_c: np.ndarray | None = None  # (N,) the cell's air temperature [deg C], when a family drives it

    @property
    def N(self) -> int:
        return len(self.Q)

    @property
    def moves(self) -> np.ndarray:
        """Each row's commanded move from the row before ``(N, 6)`` [rad] (row 0: none)."""
        d = np.zeros_like(self.Q)
        d[1:] = np.diff(self.Q, axis=0)
        return d

    def torques(self, extra=()) -> np.ndarray:
        return kin.gravity_torques(self.robot.convention, self.F, tuple(self.bodies) + tuple(extra))


@dataclass
class Effect:
    dq: np.ndarray | None = None
    length_scale: np.ndarray | None = None
    tool: np.ndarray | None = None
    meas: np.ndarray | None = None
    base: np.ndarray | None = None

    @property
    def max_dq(self) -> float:
        return 0.0 if self.dq is None else float(np.max(np.abs(self.dq)))


MICRO = 1e6  # [ppm] per unit of strain or ratio, [urad] per [rad]
JOINT_DQ_MAX = 0.1 * RAD_PER_DEG  # [rad]: a joint offset larger than this is no plausible gear or compliance effect
TAU_MIN = 0.3  # [N m]: the RMS gravity torque below which a joint's load does not set a flank or a deflection
K_MIN = {1: 2e4, 2: 2e4, 3: 2e4, 4: 2e3, 5: 2e3, 6: 2e3}  # [N m/rad]: the softest plausible joint stiffness


def _uni(rng, lo, hi):
    return float(rng.uniform(lo, hi))


def _logu(rng, lo, hi):
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _row(rng, n, lo, hi) -> int:
    return int(np.clip(round(rng.uniform(lo, hi) * n), 3, n - 3))


def _last_move_sign(moves: np.ndarray, j: int, initial: float) -> tuple[np.ndarray, np.ndarray]:
    """Sign and size [rad] of joint ``j``'s last move that changed it, for every row (before any: ``initial``,
    size 0)."""
    s, size = np.empty(len(moves)), np.zeros(len(moves))
    cur, cur_size = float(initial), 0.0
    for i, d in enumerate(moves[:, j]):
        if abs(d) > 1e-9:
            cur, cur_size = float(np.sign(d)), abs(float(d))
        s[i], size[i] = cur, cur_size
    return s, size


def window_tail(n: int) -> int:
    """The fewest rows that follow a window's end in the campaign (5 % of them, at least 8): the rows that show the
    state came back."""
    return max(8, int(np.ceil(0.05 * n)))


def _rows_text(ctx: Ctx, r: int) -> str:
    return f"row {r + 1} (t_s {ctx.t[r]:.1f})"


# ------------------------------------------------------------------------------------------ gravity compliance


def _compliance_law(tau: np.ndarray, shape: str, p: dict) -> np.ndarray:
    """The deflection law's shape of the torque (before its compliance): linear, stiffening (softer near zero
    torque, ``tau / sqrt(1 + (tau / tau_s)^2)``), two stiffnesses (``tau`` up to ``tau_b``, beyond it
    ``ratio`` times as compliant)."""
    if shape == "linear":
        return tau
    if shape == "stiffening":
        return tau / np.sqrt(1.0 + (tau / p["tau_s_nm"]) ** 2)
    if shape == "two_stiffness":
        tb, r = p["tau_b_nm"], p["ratio"]
        a = np.abs(tau)
        return np.sign(tau) * np.where(a < tb, a, tb + r * (a - tb))
    raise ValueError(f"unknown compliance shape {shape!r}")


def _eligible_load_joints(ctx: Ctx, tau=None) -> list[int]:
    tau = ctx.torques() if tau is None else tau
    rms = np.sqrt(np.mean(tau[: ctx.n_data] ** 2, axis=0))
    return [j for j in range(2, 7) if rms[j - 1] >= TAU_MIN]


def compliance_draw(rng, ctx: Ctx) -> dict:
    tau = ctx.torques()
    js = _eligible_load_joints(ctx, tau)
    two = len(js) >= 2 and rng.uniform() < 0.4
    joints = sorted(rng.choice(js, 2 if two else 1, replace=False).tolist())
    shape = ["linear", "stiffening", "two_stiffness"][int(rng.integers(3))]
    per = {}
    for j in joints:
        tmax = float(np.max(np.abs(tau[: ctx.n_data, j - 1])))
        law = {"shape": shape}
        if shape == "stiffening":
            law["tau_s_nm"] = round(_uni(rng, 0.2, 0.8) * tmax, 4)
        elif shape == "two_stiffness":
            law["tau_b_nm"] = round(_uni(rng, 0.2, 0.7) * tmax, 4)
            law["ratio"] = round(_uni(rng, 0.2, 0.6), 4)
        # compliance [rad/(N m)] per unit scale: each joint's RMS deflection equal, times a drawn weight
        rms = float(np.sqrt(np.mean(_compliance_law(tau[: ctx.n_data, j - 1], shape, law) ** 2)))
        law["c_rad_per_nm"] = _uni(rng, 0.5, 1.5) * 1e-5 / rms
        per[str(j)] = law
    return {"joints": joints, "shape": shape, "per_joint": per, "scale": 1.0}


def compliance_apply(p: dict, ctx: Ctx, tau=None) -> Effect:
    tau = ctx.torques() if tau is None else tau
    dq = np.zeros((ctx.N, 6))
    for js, law in p["per_joint"].items():
        j = int(js)
        dq[:, j - 1] = p["scale"] * law["c_rad_per_nm"] * _compliance_law(tau[:, j - 1], law["shape"], law)
    return Effect(dq=dq)


def compliance_plausible(p: dict, ctx: Ctx, e: Effect) -> str:
    for js, law in p["per_joint"].items():
        k = 1.0 / (p["scale"] * law["c_rad_per_nm"])
        if k < K_MIN[int(js)]:
            return f"joint {js} stiffness {k:.3g} N m/rad below {K_MIN[int(js)]:.3g}"
    return ""


def compliance_words(p: dict, ctx: Ctx) -> dict:
    parts = []
    for js, law in p["per_joint"].items():
        k = 1.0 / (p["scale"] * law["c_rad_per_nm"])
        extra = {"stiffening": f", stiffening (tau_s {law.get('tau_s_nm', 0):.2f} N m)",
                 "two_stiffness": f", {1 / law.get('ratio', 1):.2f}x stiffer beyond {law.get('tau_b_nm', 0):.2f} N m"}
        parts.append(f"joint {js} k = {k:.4g} N m/rad{extra.get(law['shape'], '')}")
    return {"description": "joint compliance under the arm's own gravity torque: " + "; ".join(parts),
            "formula": "q_j += c_j f(tau_j(q)); f = tau (linear), tau / sqrt(1 + (tau/tau_s)^2) (stiffening), "
                       "tau up to tau_b then tau_b + ratio (tau - tau_b) (two stiffnesses)",
            "joints": [int(j) for j in p["per_joint"]], "links": [], "place": "joint", "channel": "gravity torque"}


# ------------------------------------------------------------------------------------------ a carried payload


def payload_draw(rng, ctx: Ctx) -> dict:
    js = _eligible_load_joints(ctx)
    big = [j for j in (2, 3) if j in js]
    choice = rng.uniform()
    if choice < 0.5 and len(big) == 2:
        joints = big
    elif choice < 0.75 and len(big) == 2 and 5 in js:
        joints = big + [5]
    else:
        joints = [int(rng.choice(big or js))]
    m = _uni(rng, 0.3, 1.0) * ctx.robot.payload_kg
    com = [_uni(rng, -30, 30), _uni(rng, -30, 30), _uni(rng, 30, 150)]
    timing = ["on", "off", "window"][int(rng.integers(3))]
    n = ctx.n_data
    if timing == "window":
        s = _row(rng, n, 0.05, 0.75)
        e = int(min(n - window_tail(n), s + max(5, round(_uni(rng, 0.1, 0.5) * n))))
        if e - s < 5:
            raise Redraw("no room for a window")
    else:
        s, e = _row(rng, n, 0.05, 0.95), None
    tau_arm = ctx.torques()
    per = {}
    for j in joints:
        rms = float(np.sqrt(np.mean(tau_arm[:n, j - 1] ** 2)))
        per[str(j)] = {"c_rad_per_nm": _uni(rng, 0.5, 1.5) * 1e-5 / rms}
    return {"joints": joints, "per_joint": per, "mass_kg": round(m, 4), "com_flange_mm": [round(x, 2) for x in com],
            "timing": timing, "row": s, "end_row": e, "scale": 1.0}


def payload_on(p: dict, N: int) -> np.ndarray:
    """Rows that carry the payload ``(N,)`` (the later rows keep the campaign's last state)."""
    on = np.zeros(N, bool)
    if p["timing"] == "on":
        on[p["row"]:] = True
    elif p["timing"] == "off":
        on[: p["row"]] = True
    else:
        on[p["row"]: p["end_row"]] = True
    return on


def payload_apply(p: dict, ctx: Ctx) -> Effect:
    tau = ctx.torques()
    body = [(6, p["mass_kg"], np.asarray(p["com_flange_mm"]) * M_PER_MM)]
    tau_p = kin.gravity_torques(ctx.robot.convention, ctx.F, body)
    tot = tau + tau_p * payload_on(p, ctx.N)[:, None]
    dq = np.zeros((ctx.N, 6))
    for js, law in p["per_joint"].items():
        j = int(js)
        dq[:, j - 1] = p["scale"] * law["c_rad_per_nm"] * tot[:, j - 1]
    return Effect(dq=dq)


def payload_words(p: dict, ctx: Ctx) -> dict:
    ks = ", ".join(f"joint {j} k = {1 / (p['scale'] * law['c_rad_per_nm']):.4g} N m/rad" for j, law in p["per_joint"].items())
    if p["timing"] == "on":
        when = f"hung on at {_rows_text(ctx, p['row'])} and kept (the later rows too)"
    elif p["timing"] == "off":
        when = f"carried from the start and taken off at {_rows_text(ctx, p['row'])}"
    else:
        when = f"hung on at {_rows_text(ctx, p['row'])} and taken off at {_rows_text(ctx, p['end_row'])}"
    return {"description": f"compliance under gravity ({ks}); a {p['mass_kg']:.2f} kg payload (centre of mass "
                           f"{p['com_flange_mm']} mm, flange frame) {when}",
            "formula": "q_j += c_j (tau_j,arm(q) + L_i tau_j,payload(q)); L_i = 1 on the rows carrying it",
            "joints": [int(j) for j in p["per_joint"]], "links": [], "place": "joint",
            "channel": f"gravity torque, payload {p['timing']}"}


# ------------------------------------------------------------------------------------------ backlash


def backlash_motion_draw(rng, ctx: Ctx) -> dict:
    j = int(rng.integers(1, 7))
    d = ctx.moves[: ctx.n_data, j - 1]
    if min(np.mean(d > 1e-9), np.mean(d < -1e-9)) < 0.15:
        raise Redraw(f"joint {j} moves one way on this plan")
    return {"joint": j, "initial_sign": float(rng.choice([-1.0, 1.0])), "b_rad": 1e-5, "scale": 1.0}


def backlash_motion_apply(p: dict, ctx: Ctx) -> Effect:
    s, _ = _last_move_sign(ctx.moves, p["joint"] - 1, p["initial_sign"])
    dq = np.zeros((ctx.N, 6))
    dq[:, p["joint"] - 1] = p["scale"] * p["b_rad"] * s
    return Effect(dq=dq)


def backlash_motion_words(p: dict, ctx: Ctx) -> dict:
    b = p["scale"] * p["b_rad"] * DEG_PER_RAD
    return {"description": f"joint {p['joint']} backlash signed by the direction of its last move: half clearance "
                           f"{b:.5f} deg (before its first move: {p['initial_sign']:+.0f})",
            "formula": f"q{p['joint']} += b sign(last move of q{p['joint']})", "joints": [p["joint"]], "links": [],
            "place": "joint", "channel": "direction of the last move"}


def backlash_load_draw(rng, ctx: Ctx) -> dict:
    tau = ctx.torques()[: ctx.n_data]
    js = [j for j in _eligible_load_joints(ctx) if min(np.mean(tau[:, j - 1] > 0), np.mean(tau[:, j - 1] < 0)) >= 0.15]
    if not js:
        raise Redraw("no joint's load changes sign on this plan")
    j = int(rng.choice(js))
    smooth = rng.uniform() < 0.5
    w = _uni(rng, 0.05, 0.3) * float(np.sqrt(np.mean(tau[:, j - 1] ** 2))) if smooth else 0.0
    return {"joint": j, "shape": "smooth" if smooth else "sharp", "width_nm": round(w, 5), "b_rad": 1e-5, "scale": 1.0}


def backlash_load_apply(p: dict, ctx: Ctx) -> Effect:
    tau = ctx.torques()[:, p["joint"] - 1]
    f = np.tanh(tau / p["width_nm"]) if p["width_nm"] > 0 else np.sign(tau)
    dq = np.zeros((ctx.N, 6))
    dq[:, p["joint"] - 1] = p["scale"] * p["b_rad"] * f
    return Effect(dq=dq)


def backlash_load_words(p: dict, ctx: Ctx) -> dict:
    b = p["scale"] * p["b_rad"] * DEG_PER_RAD
    law = f"tanh(tau / {p['width_nm']:.3f} N m)" if p["width_nm"] > 0 else "sign(tau)"
    return {"description": f"joint {p['joint']} rests on the flank its gravity torque pushes it to: half clearance "
                           f"{b:.5f} deg, {law}, whatever its last move",
            "formula": f"q{p['joint']} += b {law}", "joints": [p["joint"]], "links": [], "place": "joint",
            "channel": "sign of the gravity torque"}


def backlash_size_draw(rng, ctx: Ctx) -> dict:
    p = backlash_motion_draw(rng, ctx)
    shape = "saturating" if rng.uniform() < 0.5 else "proportional"
    d0 = _uni(rng, 3, 40) if shape == "saturating" else _uni(rng, 10, 90)
    return {**p, "shape": shape, "size0_deg": round(d0, 4)}


def backlash_size_apply(p: dict, ctx: Ctx) -> Effect:
    s, size = _last_move_sign(ctx.moves, p["joint"] - 1, p["initial_sign"])
    x = size / (p["size0_deg"] * RAD_PER_DEG)
    g = 1.0 - np.exp(-x) if p["shape"] == "saturating" else np.minimum(1.0, x)
    dq = np.zeros((ctx.N, 6))
    dq[:, p["joint"] - 1] = p["scale"] * p["b_rad"] * s * g
    return Effect(dq=dq)


def backlash_size_words(p: dict, ctx: Ctx) -> dict:
    b = p["scale"] * p["b_rad"] * DEG_PER_RAD
    g = (f"(1 - exp(-|move| / {p['size0_deg']:.2f} deg))" if p["shape"] == "saturating"
         else f"min(1, |move| / {p['size0_deg']:.2f} deg)")
    return {"description": f"joint {p['joint']} backlash whose size follows its last move: up to {b:.5f} deg, "
                           f"signed by the move, times {g}",
            "formula": f"q{p['joint']} += b sign(last move) {g}", "joints": [p["joint"]], "links": [],
            "place": "joint", "channel": "direction and size of the last move"}


# ------------------------------------------------------------------------------------------ a base that tilts


def tilt_draw(rng, ctx: Ctx) -> dict:
    return {"anisotropy": round(_logu(rng, 1.0, 8.0), 4), "axis_deg": round(_uni(rng, 0, 180), 3),
            "c_rad_per_nm": 1e-7, "scale": 1.0}


def tilt_compliance(p: dict) -> np.ndarray:
    phi = p["axis_deg"] * RAD_PER_DEG
    R = np.array([[np.cos(phi), -np.sin(phi)], [np.sin(phi), np.cos(phi)]])
    c1 = p["scale"] * p["c_rad_per_nm"]
    return R @ np.diag([c1, c1 / p["anisotropy"]]) @ R.T


def tilt_apply(p: dict, ctx: Ctx) -> Effect:
    M = kin.base_moment(ctx.F, ctx.bodies)
    w = np.zeros((ctx.N, 3))
    w[:, :2] = M[:, :2] @ tilt_compliance(p).T
    base = np.stack([kin.transform(wi, np.zeros(3)) for wi in w])
    return Effect(base=base)


def tilt_plausible(p: dict, ctx: Ctx, e: Effect) -> str:
    M = kin.base_moment(ctx.F, ctx.bodies)
    tilt = float(np.max(np.linalg.norm(M[:, :2] @ tilt_compliance(p).T, axis=1)))
    return f"tilt {tilt:.3g} rad above 3e-4" if tilt > 3e-4 else ""


def tilt_words(p: dict, ctx: Ctx) -> dict:
    c1 = p["scale"] * p["c_rad_per_nm"]
    return {"description": f"the base turns about horizontal axes through its origin under the arm's gravity moment: "
                           f"{c1 * MICRO:.4f} and {c1 / p['anisotropy'] * MICRO:.4f} urad/(N m) about principal axes at "
                           f"{p['axis_deg']:.1f} deg from base x (anisotropy {p['anisotropy']:.2f})",
            "formula": "flange2base_i = Rot(w_i) flange2base(q_i); w_i = (C [M_x, M_y], 0), C = R(phi) diag(c1, c2) R(phi)^T",
            "joints": [], "links": [], "place": "base", "channel": "gravity moment about the base"}


# ------------------------------------------------------------------------------------------ thermal growth


def lag(t: np.ndarray, u: np.ndarray, tau: float) -> np.ndarray:
    """First-order lag ``dy/dt = (u - y) / tau`` of ``u`` sampled at ``t`` (linear between samples), ``y(t_0) =
    u(t_0)``; exact for a piecewise-linear input."""
    y = np.empty_like(u)
    y[0] = u[0]
    for i in range(1, len(t)):
        h = t[i] - t[i - 1]
        a = np.exp(-h / tau)
        s = (u[i] - u[i - 1]) / h if h > 0 else 0.0
        # y' = (u0 + s (t - t0) - y) / tau: y(h) = u1 - s tau + (y0 - u0 + s tau) a
        y[i] = u[i] - s * tau + (y[i - 1] - u[i - 1] + s * tau) * a
    return y


def _links(rng, ctx: Ctx) -> list[str]:
    names = list(ctx.robot.length_names)
    if rng.uniform() < 0.5:
        return names
    long = [L for L in names if abs(ctx.robot.params[L[0]][int(L[1:]) - 1]) > 0.1]
    return [str(rng.choice(long))]


def _growth_scale(ctx: Ctx, links: list[str], strain: np.ndarray) -> np.ndarray:
    S = np.ones((ctx.N, 2, 6))
    for L in links:
        S[:, 0 if L[0] == "d" else 1, int(L[1:]) - 1] += strain
    return S


def air_profile(p: dict, t: np.ndarray, t0: float, span: float) -> np.ndarray:
    """The air's temperature change the thermal family drives [K] ``(N,)``: a ramp from ``ramp_start`` over
    ``ramp_s`` or a step at ``step_at`` (times relative to the campaign's first row)."""
    x = t - t0
    if p["profile"] == "ramp":
        return p["delta_k"] * np.clip((x - p["ramp_start_s"]) / p["ramp_s"], 0.0, 1.0)
    return p["delta_k"] * (x >= p["step_at_s"])


def thermal_draw(rng, ctx: Ctx) -> dict:
    span = float(ctx.t[ctx.n_data - 1] - ctx.t[0])
    profile = "ramp" if rng.uniform() < 0.5 else "step"
    p = {"profile": profile, "delta_k": round(float(rng.choice([-1, 1, 1])) * _uni(rng, 1.5, 8.0), 4),
         "tau_s": round(_logu(rng, 0.02, 1.5) * span, 2), "links": _links(rng, ctx),
         "temp_column": bool(rng.uniform() < 0.6), "alpha_per_k": 1e-5, "scale": 1.0}
    if profile == "ramp":
        p["ramp_start_s"] = round(_uni(rng, -0.2, 0.6) * span, 2)
        p["ramp_s"] = round(_uni(rng, 0.2, 1.5) * span, 2)
    else:
        p["step_at_s"] = round(_uni(rng, 0.05, 0.9) * span, 2)
    return p


def thermal_link_temperature(p: dict, ctx: Ctx) -> np.ndarray:
    """The links' temperature change [K] ``(N,)``: the air's (its wander ``ctx.air_c`` and the drawn profile) through
    the lag, on a fine time grid (the air linear between rows)."""
    t0, span = float(ctx.t[0]), float(ctx.t[ctx.n_data - 1] - ctx.t[0])
    grid = np.union1d(ctx.t, np.linspace(ctx.t[0], ctx.t[-1], 4000))
    if p["profile"] == "step":  # the step's two sides, one microsecond apart
        ts = t0 + p["step_at_s"]
        grid = np.union1d(grid, [ts - 1e-6, ts])
    wander = 0.0 if ctx.air_c is None else np.interp(grid, ctx.t, ctx.air_c - ctx.air_c[0])
    y = lag(grid, air_profile(p, grid, t0, span) + wander, p["tau_s"])
    return np.interp(ctx.t, grid, y)


def thermal_apply(p: dict, ctx: Ctx) -> Effect:
    strain = p["scale"] * p["alpha_per_k"] * thermal_link_temperature(p, ctx)
    return Effect(length_scale=_growth_scale(ctx, p["links"], strain))


def thermal_plausible(p: dict, ctx: Ctx, e: Effect) -> str:
    a = p["scale"] * p["alpha_per_k"]
    return f"expansion coefficient {a:.3g}/K above 5e-5" if a > 5e-5 else ""


def thermal_words(p: dict, ctx: Ctx) -> dict:
    a = p["scale"] * p["alpha_per_k"]
    when = (f"a ramp of {p['delta_k']:+.2f} K from {p['ramp_start_s']:.0f} s over {p['ramp_s']:.0f} s"
            if p["profile"] == "ramp" else f"a step of {p['delta_k']:+.2f} K at {p['step_at_s']:.0f} s")
    col = "written in temp_c" if p["temp_column"] else "not recorded (t_s only)"
    return {"description": f"links {', '.join(p['links'])} grow {a * MICRO:.2f} ppm/K with their temperature, which "
                           f"follows the air's ({when}; {col}) through a lag of {p['tau_s']:.0f} s",
            "formula": "L_i = L (1 + alpha T_link(t_i)); dT_link/dt = (T_air - T_link) / tau",
            "joints": [], "links": list(p["links"]), "place": "length",
            "channel": "temp_c lagged" if p["temp_column"] else "t_s"}


def heat_state(p: dict, ctx: Ctx) -> np.ndarray:
    """The motors' heat ``(N,)``: each move's travel of the heating joints [rad] comes in at its row and leaks out
    with ``tau``; normalised to 1 at its mean over the dataset rows."""
    travel = np.sum(np.abs(ctx.moves[:, np.asarray(p["heat_joints"]) - 1]), axis=1)
    H = np.zeros(ctx.N)
    for i in range(1, ctx.N):
        H[i] = H[i - 1] * np.exp(-(ctx.t[i] - ctx.t[i - 1]) / p["tau_s"]) + travel[i]
    return H / max(float(np.mean(H[: ctx.n_data])), 1e-12)


def motion_heat_draw(rng, ctx: Ctx) -> dict:
    span = float(ctx.t[ctx.n_data - 1] - ctx.t[0])
    u = rng.uniform()
    heat = [1, 2, 3] if u < 0.4 else [4, 5, 6] if u < 0.6 else [int(rng.integers(1, 7))]
    return {"heat_joints": heat, "tau_s": round(_logu(rng, 0.05, 1.0) * span, 2), "links": _links(rng, ctx),
            "strain_per_heat": 1e-5, "scale": 1.0}


def motion_heat_apply(p: dict, ctx: Ctx) -> Effect:
    strain = p["scale"] * p["strain_per_heat"] * heat_state(p, ctx)
    return Effect(length_scale=_growth_scale(ctx, p["links"], strain))


def motion_heat_plausible(p: dict, ctx: Ctx, e: Effect) -> str:
    s = float(np.max(np.abs(e.length_scale - 1.0)))
    return f"strain {s:.3g} above 4e-4" if s > 4e-4 else ""


def motion_heat_words(p: dict, ctx: Ctx) -> dict:
    return {"description": f"links {', '.join(p['links'])} grow with the heat of joints {p['heat_joints']}' motors: "
                           f"each move's travel heats, the heat leaks out with tau {p['tau_s']:.0f} s; strain "
                           f"{p['scale'] * p['strain_per_heat'] * MICRO:.2f} ppm at the campaign's mean heat",
            "formula": "L_i = L (1 + s H_i / mean H); H_i = H_{i-1} exp(-dt / tau) + sum_j |move_j|",
            "joints": list(p["heat_joints"]), "links": list(p["links"]), "place": "length",
            "channel": "the motors' recent travel"}


# ------------------------------------------------------------------------------------------ joint zero changes


def zero_step_draw(rng, ctx: Ctx) -> dict:
    return {"joint": int(rng.integers(1, 7)), "row": _row(rng, ctx.n_data, 0.05, 0.97),
            "sign": float(rng.choice([-1.0, 1.0])), "delta_rad": 1e-5, "scale": 1.0}


def zero_step_apply(p: dict, ctx: Ctx) -> Effect:
    dq = np.zeros((ctx.N, 6))
    dq[p["row"]:, p["joint"] - 1] = p["sign"] * p["scale"] * p["delta_rad"]
    return Effect(dq=dq)


def zero_step_words(p: dict, ctx: Ctx) -> dict:
    d = p["sign"] * p["scale"] * p["delta_rad"] * DEG_PER_RAD
    return {"description": f"joint {p['joint']}'s zero re-latched: a step of {d:+.5f} deg at "
                           f"{_rows_text(ctx, p['row'])}, kept (the later rows too)",
            "formula": f"q{p['joint']} += {d:+.6f} deg on rows >= {p['row'] + 1}", "joints": [p["joint"]],
            "links": [f"theta{p['joint']}"], "place": "joint", "channel": f"step at row {p['row'] + 1}"}


def zero_glitch_draw(rng, ctx: Ctx) -> dict:
    n = ctx.n_data
    s = _row(rng, n, 0.05, 0.9)
    length = int(min(round(_logu(rng, 3, 0.4 * n)), n - window_tail(n) - s))
    if length < 3:
        raise Redraw("no room for a window")
    return {"joint": int(rng.integers(1, 7)), "row": s, "end_row": s + length, "sign": float(rng.choice([-1.0, 1.0])),
            "delta_rad": 1e-5, "scale": 1.0}


def zero_glitch_apply(p: dict, ctx: Ctx) -> Effect:
    dq = np.zeros((ctx.N, 6))
    dq[p["row"]: p["end_row"], p["joint"] - 1] = p["sign"] * p["scale"] * p["delta_rad"]
    return Effect(dq=dq)


def zero_glitch_words(p: dict, ctx: Ctx) -> dict:
    d = p["sign"] * p["scale"] * p["delta_rad"] * DEG_PER_RAD
    return {"description": f"joint {p['joint']}'s zero off by {d:+.5f} deg from {_rows_text(ctx, p['row'])} to "
                           f"{_rows_text(ctx, p['end_row'] - 1)} ({p['end_row'] - p['row']} rows), then back",
            "formula": f"q{p['joint']} += {d:+.6f} deg on rows {p['row'] + 1}..{p['end_row']}",
            "joints": [p["joint"]], "links": [f"theta{p['joint']}"], "place": "joint",
            "channel": f"window of rows {p['row'] + 1}..{p['end_row']}"}


# ------------------------------------------------------------------------------------------ the joint's own laws


def cyclic_draw(rng, ctx: Ctx) -> dict:
    j = int(rng.integers(1, 7))
    span = float(np.ptp(ctx.Q[: ctx.n_data, j - 1]))
    orders = [k for k in range(1, 13) if k * span >= 1.5 * 2 * np.pi]
    if not orders:
        raise Redraw(f"joint {j}'s range shows no period")
    two = rng.uniform() < 0.5 and len(orders) >= 2
    ks = sorted(int(k) for k in rng.choice(orders[:5], 2 if two else 1, replace=False))
    amps = [1.0] + ([_uni(rng, 0.3, 1.0)] if two else [])
    return {"joint": j, "orders": ks, "amplitudes": [round(a, 4) for a in amps],
            "phases_rad": [round(_uni(rng, 0, 2 * np.pi), 5) for _ in ks], "a_rad": 1e-5, "scale": 1.0}


def cyclic_apply(p: dict, ctx: Ctx) -> Effect:
    q = ctx.Q[:, p["joint"] - 1]
    dq = np.zeros((ctx.N, 6))
    dq[:, p["joint"] - 1] = p["scale"] * p["a_rad"] * sum(
        a * np.sin(k * q + ph) for k, a, ph in zip(p["orders"], p["amplitudes"], p["phases_rad"]))
    return Effect(dq=dq)


def cyclic_words(p: dict, ctx: Ctx) -> dict:
    A = p["scale"] * p["a_rad"] * DEG_PER_RAD
    terms = " + ".join(f"{A * a:.5f} sin({k} q + {ph:.3f})" for k, a, ph in zip(p["orders"], p["amplitudes"], p["phases_rad"]))
    return {"description": f"joint {p['joint']}'s transmission error, orders {p['orders']} per joint turn: {terms} deg",
            "formula": f"q{p['joint']} += sum_k A_k sin(k q{p['joint']} + phi_k)", "joints": [p["joint"]], "links": [],
            "place": "joint", "channel": f"sin/cos(k q{p['joint']})"}


def gear_ratio_draw(rng, ctx: Ctx) -> dict:
    return {"joint": int(rng.integers(1, 7)), "sign": float(rng.choice([-1.0, 1.0])), "eps": 1e-5, "scale": 1.0}


def gear_ratio_apply(p: dict, ctx: Ctx) -> Effect:
    dq = np.zeros((ctx.N, 6))
    dq[:, p["joint"] - 1] = p["sign"] * p["scale"] * p["eps"] * ctx.Q[:, p["joint"] - 1]
    return Effect(dq=dq)


def gear_ratio_plausible(p: dict, ctx: Ctx, e: Effect) -> str:
    return f"ratio error {p['scale'] * p['eps']:.3g} above 1e-3" if p["scale"] * p["eps"] > 1e-3 else ""


def gear_ratio_words(p: dict, ctx: Ctx) -> dict:
    eps = p["sign"] * p["scale"] * p["eps"]
    return {"description": f"joint {p['joint']}'s gear ratio off by {eps * MICRO:+.1f} ppm: q_actual = (1 + eps) q",
            "formula": f"q{p['joint']} += {eps:+.4g} q{p['joint']}", "joints": [p["joint"]], "links": [],
            "place": "joint", "channel": f"q{p['joint']}"}


WRIST_PAIRS = ((5, 4), (6, 4), (6, 5))  # (driven, driving): a wrist drive passes through the joints before it


def coupling_draw(rng, ctx: Ctx) -> dict:
    driven, driving = WRIST_PAIRS[int(rng.integers(len(WRIST_PAIRS)))]
    return {"driven": driven, "driving": driving, "sign": float(rng.choice([-1.0, 1.0])), "c": 1e-5, "scale": 1.0}


def coupling_apply(p: dict, ctx: Ctx) -> Effect:
    dq = np.zeros((ctx.N, 6))
    dq[:, p["driven"] - 1] = p["sign"] * p["scale"] * p["c"] * ctx.Q[:, p["driving"] - 1]
    return Effect(dq=dq)


def coupling_plausible(p: dict, ctx: Ctx, e: Effect) -> str:
    return f"coupling {p['scale'] * p['c']:.3g} above 2e-3" if p["scale"] * p["c"] > 2e-3 else ""


def coupling_words(p: dict, ctx: Ctx) -> dict:
    c = p["sign"] * p["scale"] * p["c"]
    return {"description": f"joint {p['driven']} turns with joint {p['driving']}: {c * MICRO:+.1f} urad per rad (a "
                           f"wrist drive's coupling ratio off)",
            "formula": f"q{p['driven']} += {c:+.4g} q{p['driving']}", "joints": [p["driving"], p["driven"]],
            "links": [], "place": "joint", "channel": f"q{p['driving']}"}


# ------------------------------------------------------------------------------------------ frames that move


def frame_change_draw(rng, ctx: Ctx) -> dict:
    kind = ["knock", "bump", "slip"][int(rng.integers(3))]
    u = rng.normal(size=3)
    u /= np.linalg.norm(u)
    p = {"kind": kind, "row": _row(rng, ctx.n_data, 0.05, 0.97), "scale": 1.0}
    if kind == "knock":  # a turn about a contact on the plate's rim, mostly about the flange axis, and a slide
        phi = _uni(rng, 0, 2 * np.pi)
        p["pivot_mm"] = [45.0 * np.cos(phi), 45.0 * np.sin(phi), 6.0]
        w = rng.normal(size=3) * np.array([1.0, 1.0, 2.0])
        p["rot_unit_rad"] = list(w / np.linalg.norm(w) * 1e-4)
        p["slide_unit_mm"] = list(u * _uni(rng, 0.2, 1.0) * 5e-3)
    elif kind == "slip":  # the plate (or the nest) slides along the flange face
        phi = _uni(rng, 0, 2 * np.pi)
        p["pivot_mm"] = [0.0, 0.0, 0.0]
        p["rot_unit_rad"] = [0.0, 0.0, 0.0]
        p["slide_unit_mm"] = [5e-3 * np.cos(phi), 5e-3 * np.sin(phi), 0.0]
    else:  # the instrument's stand bumped: a turn about its head (below and behind it) and a slide
        p["station"] = int(ctx.station[p["row"]])
        p["pivot_mm"] = [0.0, 150.0, -100.0]
        w = rng.normal(size=3) * np.array([1.0, 1.6, 0.5])
        p["rot_unit_rad"] = list(w / np.linalg.norm(w) * 1e-5)
        p["slide_unit_mm"] = list(u * _uni(rng, 0.2, 1.0) * 5e-3)
    return p


def frame_change_transform(p: dict) -> np.ndarray:
    return kin.about(np.asarray(p["rot_unit_rad"]) * p["scale"], np.asarray(p["pivot_mm"]) * M_PER_MM,
                     np.asarray(p["slide_unit_mm"]) * p["scale"] * M_PER_MM)


def frame_change_apply(p: dict, ctx: Ctx) -> Effect:
    D = frame_change_transform(p)
    X = np.broadcast_to(np.eye(4), (ctx.N, 4, 4)).copy()
    rows = np.arange(ctx.N) >= p["row"]
    if p["kind"] == "bump":
        X[rows & (ctx.station == p["station"])] = kin.inv(D)
        return Effect(meas=X)
    X[rows] = D
    return Effect(tool=X)


def frame_change_plausible(p: dict, ctx: Ctx, e: Effect) -> str:
    D = frame_change_transform(p)
    ang = float(np.linalg.norm(kin.matrix_to_rotvec(D[:3, :3])))
    if ang > 0.3 * RAD_PER_DEG or np.linalg.norm(D[:3, 3]) > 0.5 * M_PER_MM * (10 if p["kind"] == "bump" else 1):
        return "a frame change beyond 0.3 deg or 0.5 mm"
    return ""


def frame_change_words(p: dict, ctx: Ctx) -> dict:
    D = frame_change_transform(p)
    ang = float(np.linalg.norm(kin.matrix_to_rotvec(D[:3, :3]))) * DEG_PER_RAD
    what = {"knock": "the plate (tool) is knocked on the flange", "slip": "the plate (tool) slips along the flange face",
            "bump": f"the instrument of station {p.get('station')} is bumped"}[p["kind"]]
    return {"description": f"{what} at {_rows_text(ctx, p['row'])}: a rigid step of {ang:.5f} deg and "
                           f"{np.linalg.norm(D[:3, 3]) * MM_PER_M:.4f} mm, kept (the later rows too)",
            "formula": ("base2meas_i = inv(D) base2meas" if p["kind"] == "bump" else "tool2flange_i = tool2flange D")
                       + f" on rows >= {p['row'] + 1}; D = Trans(c) Rot(w) Trans(-c) Trans(s)",
            "joints": [], "links": [], "place": "measurement" if p["kind"] == "bump" else "tool",
            "channel": f"step at row {p['row'] + 1}"}


# ------------------------------------------------------------------------------------------ the catalogue of families


@dataclass(frozen=True)
class Family:
    """A family: its ``draw``, ``apply``, ``words``, plausibility check (an empty string when plausible), the
    key's category and expected names, and what a right verdict names (``names``: the catalogue family;
    ``change``: the kind and place of the change the diagnosis should report)."""

    name: str
    category: str
    expected: tuple[str, ...]
    draw: object
    apply: object
    words: object
    plausible: object = None
    change: tuple[str, str] | None = None  # (kind, place) of a change the diagnosis should report

    def check(self, p, ctx, e) -> str:
        if e.max_dq > JOINT_DQ_MAX * (3 if self.name in ("zero_step", "zero_glitch") else 1):
            return f"a joint offset of {e.max_dq * DEG_PER_RAD:.3g} deg"
        return self.plausible(p, ctx, e) if self.plausible else ""


FAMILIES = {f.name: f for f in (
    Family("compliance", "catalogue", ("compliance",), compliance_draw, compliance_apply, compliance_words,
           compliance_plausible),
    Family("payload", "catalogue", ("compliance",), payload_draw, payload_apply, payload_words, compliance_plausible),
    Family("backlash_motion", "catalogue", ("backlash",), backlash_motion_draw, backlash_motion_apply,
           backlash_motion_words),
    Family("backlash_load", "catalogue", ("backlash",), backlash_load_draw, backlash_load_apply, backlash_load_words),
    Family("backlash_size", "catalogue", ("backlash",), backlash_size_draw, backlash_size_apply, backlash_size_words),
    Family("tilt", "catalogue", ("tilt",), tilt_draw, tilt_apply, tilt_words, tilt_plausible),
    Family("thermal", "catalogue", ("thermal",), thermal_draw, thermal_apply, thermal_words, thermal_plausible),
    Family("motion_heat", "catalogue", ("thermal",), motion_heat_draw, motion_heat_apply, motion_heat_words,
           motion_heat_plausible),
    Family("zero_step", "outside", (), zero_step_draw, zero_step_apply, zero_step_words, change=("step", "joint")),
    Family("zero_glitch", "outside", (), zero_glitch_draw, zero_glitch_apply, zero_glitch_words,
           change=("window", "joint")),
    Family("cyclic", "catalogue", ("cyclic",), cyclic_draw, cyclic_apply, cyclic_words),
    Family("gear_ratio", "catalogue", ("gear_ratio",), gear_ratio_draw, gear_ratio_apply, gear_ratio_words,
           gear_ratio_plausible),
    Family("coupling", "catalogue", ("coupling",), coupling_draw, coupling_apply, coupling_words, coupling_plausible),
    Family("frame_change", "outside", (), frame_change_draw, frame_change_apply, frame_change_words,
           frame_change_plausible, change=("step", "frame")),
    Family("clean", "clean", (), None, None, None),
)}
