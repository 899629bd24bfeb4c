"""This generator's own physical effect models. Each effect has one amplitude `amp` (scaled by the campaign so
that what a geometric calibration leaves of it is a chosen multiple of the noise) and fixed shape parameters.

Every effect returns a kin.Mods for the whole measurement sequence (dataset rows then test rows), computed
from the session context: commanded joints in measurement order, which rows follow a move, time, true air
temperature, station.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kin import DEG, Mods, about_point, gravity_joint_torques, link_frames, com_positions, pose6_to_T, rotvec_to_R, G


@dataclass
class Ctx:
    robot: object  # true robot
    q: np.ndarray  # (n,6) commanded [rad]
    moved: np.ndarray  # (n,) bool: row follows a motion (False: re-measured without moving)
    t: np.ndarray  # (n,) s, true time of each row
    temp_air: np.ndarray  # (n,) degC, true air temperature
    temp_fn: object  # callable T_air(t)
    station: np.ndarray  # (n,) int
    q_start: np.ndarray  # (6,) rad: where the robot was before the first row


def steps(ctx: Ctx) -> np.ndarray:
    """Commanded joint step that brought the robot to each row [rad] (repeats inherit their visit's step)."""
    n = ctx.q.shape[0]
    out = np.zeros((n, 6))
    prev = ctx.q_start
    last = np.zeros(6)
    for r in range(n):
        if ctx.moved[r]:
            last = ctx.q[r] - prev
            prev = ctx.q[r]
        out[r] = last
    return out


class Effect:
    family = None  # vocabulary name or None
    place = "joint"
    channel = ""
    joints: list = []
    links: list = []
    unit = ""
    a0 = 1.0  # amplitude used for the first evaluation (only its shape matters)

    def mods(self, ctx: Ctx, amp: float) -> Mods:
        raise NotImplementedError

    def describe(self, amp: float) -> dict:
        raise NotImplementedError


# ============================================================================== catalogue families
class GravityCompliance(Effect):
    """Joint deflection under the gravity torque of the links and a payload: dq_j = tau_j(q) / K_j.

    amp = 1 / K_ref [rad / (N m)]; K_j = K_ref * rel_j for the compliant joints, infinite elsewhere."""

    family = "compliance"
    place = "joint"
    channel = "gravity torque (configuration-dependent)"

    def __init__(self, joints, rel_stiffness, payload_kg, payload_com_mm):
        self.joints = list(joints)
        self.rel = dict(zip(joints, rel_stiffness))
        self.payload_kg = payload_kg
        self.payload_com = list(payload_com_mm)
        self.a0 = 1e-6

    def mods(self, ctx, amp):
        tau = gravity_joint_torques(ctx.robot, ctx.q, self.payload_kg, self.payload_com)
        m = Mods(ctx.q.shape[0])
        for j in self.joints:
            m.dq[:, j - 1] = tau[:, j - 1] * amp / self.rel[j]
        return m

    def describe(self, amp):
        K = {f"K{j}_nm_per_rad": float(self.rel[j] / amp) for j in self.joints}
        return dict(
            description=f"joints {self.joints} yield elastically under the gravity torque of the arm's links and a "
            f"{self.payload_kg:.2f} kg payload at {self.payload_com} mm in the flange frame",
            formula="q_actual_j = q_cmd_j + tau_j(q)/K_j, tau_j = z_j . sum_{k>=j} (c_k - o_j) x m_k g "
            "(own link masses/COMs, see README)",
            parameters=dict(**K, payload_kg=self.payload_kg, payload_com_mm=self.payload_com),
        )


class Backlash(Effect):
    """Gear clearance: the output trails the commanded motion by h_j on the side it approached from.

    With `transition_deg` the clearance is taken up smoothly: after a step D (signed) the offset relaxes to
    -sign(D) h with exp(-|D|/transition): y <- -s h + (y + s h) exp(-|D|/d0). amp = h of the first joint [rad]."""

    family = "backlash"
    place = "joint"
    channel = "direction of the last motion of the joint"

    def __init__(self, joints, rel_h, transition_deg=None, initial_sign=None):
        self.joints = list(joints)
        self.rel = dict(zip(joints, rel_h))
        self.d0 = None if transition_deg is None else transition_deg * DEG
        self.initial_sign = initial_sign or [1] * len(joints)
        self.a0 = 0.005 * DEG

    def mods(self, ctx, amp):
        n = ctx.q.shape[0]
        m = Mods(n)
        for jj, j in enumerate(self.joints):
            h = amp * self.rel[j]
            y = -self.initial_sign[jj] * h
            prev = ctx.q_start[j - 1]
            for r in range(n):
                if ctx.moved[r]:
                    D = ctx.q[r, j - 1] - prev
                    prev = ctx.q[r, j - 1]
                    if D != 0:
                        s = np.sign(D)
                        if self.d0 is None:
                            y = -s * h
                        else:
                            y = -s * h + (y + s * h) * np.exp(-abs(D) / self.d0)
                m.dq[r, j - 1] = y
        return m

    def describe(self, amp):
        p = {f"half_clearance_j{j}_deg": float(amp * self.rel[j] / DEG) for j in self.joints}
        shape = "sharp (full offset after any motion)" if self.d0 is None else (
            f"smooth take-up over the first degree (exp(-|step|/{self.d0 / DEG:.2f} deg))")
        return dict(
            description=f"backlash on joints {self.joints}: the joint lags behind the commanded direction by the "
            f"half clearance; {shape}; initial side sign {self.initial_sign}",
            formula="y_j <- -s*h_j + (y_j + s*h_j)*exp(-|step_j|/d0), s = sign(step_j), on rows after a motion; "
            "q_actual_j = q_cmd_j + y_j" + (" (d0 -> 0: y_j = -s*h_j)" if self.d0 is None else ""),
            parameters=dict(**p, transition_deg=None if self.d0 is None else self.d0 / DEG,
                            initial_sign=self.initial_sign),
        )


class Harmonic(Effect):
    """Transmission cyclic error: dq_j = A sin(k * q_j + phase) (k per joint turn; motor side: k = ratio*m)."""

    family = "cyclic"
    place = "joint"

    def __init__(self, joint, order, phase_deg, side="joint"):
        self.joints = [joint]
        self.order = order
        self.phase = phase_deg * DEG
        self.side = side
        self.channel = f"sin/cos({order} q{joint})"
        self.a0 = 0.003 * DEG

    def mods(self, ctx, amp):
        m = Mods(ctx.q.shape[0])
        j = self.joints[0] - 1
        m.dq[:, j] = amp * np.sin(self.order * ctx.q[:, j] + self.phase)
        return m

    def describe(self, amp):
        side = "joint-side (output gear)" if self.side == "joint" else "motor-side (once per motor turn)"
        return dict(
            description=f"{side} cyclic transmission error of joint {self.joints[0]}, order {self.order} per joint turn",
            formula=f"q_actual_{self.joints[0]} = q_cmd + A*sin({self.order}*q_cmd + phase)",
            parameters=dict(amplitude_deg=float(amp / DEG), order=self.order, phase_deg=float(self.phase / DEG)),
        )


class GearRatio(Effect):
    family = "gear_ratio"
    place = "joint"

    def __init__(self, joint):
        self.joints = [joint]
        self.channel = f"q{joint}"
        self.a0 = 1e-4

    def mods(self, ctx, amp):
        m = Mods(ctx.q.shape[0])
        j = self.joints[0] - 1
        m.dq[:, j] = amp * ctx.q[:, j]
        return m

    def describe(self, amp):
        return dict(
            description=f"joint {self.joints[0]} turns (1+eps) times the commanded angle (wrong transmission ratio)",
            formula=f"q_actual_{self.joints[0]} = (1 + eps) q_cmd_{self.joints[0]}",
            parameters=dict(eps=float(amp), ratio_error_ppm=float(amp * 1e6)),
        )


class Coupling(Effect):
    family = "coupling"
    place = "joint"

    def __init__(self, driven, driving):
        self.joints = [driven, driving]
        self.driven, self.driving = driven, driving
        self.channel = f"q{driving} -> theta{driven}"
        self.a0 = 1e-4

    def mods(self, ctx, amp):
        m = Mods(ctx.q.shape[0])
        m.dq[:, self.driven - 1] = amp * ctx.q[:, self.driving - 1]
        return m

    def describe(self, amp):
        return dict(
            description=f"wrist coupling: joint {self.driven} is dragged by the motion of joint {self.driving} "
            "(the drive of the one passes through the other)",
            formula=f"q_actual_{self.driven} = q_cmd_{self.driven} + c * q_cmd_{self.driving}",
            parameters=dict(c=float(amp)),
        )


class ThermalLink(Effect):
    """One link length grows with its temperature: L = L0 (1 + alpha (T_link - T_ref)).

    source 'air': T_link = recorded air temperature (true); 'lag': dT_link/dt = (T_air - T_link)/tau,
    T_link(start) = T_air(start) - offset. amp = alpha [1/K]."""

    family = "thermal"
    place = "length"

    def __init__(self, param, joint, T_ref=20.0, source="air", tau_s=None, start_offset_k=0.0):
        self.param, self.joint = param, joint
        self.links = [joint]
        self.joints = []
        self.T_ref = T_ref
        self.source = source
        self.tau = tau_s
        self.offset = start_offset_k
        self.channel = "temp_c" if source == "air" else "temp_c (lagged) / t_s"
        self.a0 = 2e-5

    def link_temp(self, ctx):
        if self.source == "air":
            return ctx.temp_air.copy()
        t0 = ctx.t[0] - 1.0
        grid = np.arange(t0, ctx.t[-1] + 5.0, 2.0)
        Ta = ctx.temp_fn(grid)
        Tl = np.empty_like(grid)
        Tl[0] = Ta[0] - self.offset
        f = np.exp(-2.0 / self.tau)
        for i in range(1, grid.size):
            Tl[i] = Ta[i - 1] + (Tl[i - 1] - Ta[i - 1]) * f
        return np.interp(ctx.t, grid, Tl)

    def mods(self, ctx, amp):
        m = Mods(ctx.q.shape[0])
        L0 = getattr(ctx.robot, self.param)[self.joint - 1]
        self._Tl = self.link_temp(ctx)
        m.dpar[self.param][:, self.joint - 1] = L0 * amp * (self._Tl - self.T_ref)
        return m

    def describe(self, amp):
        lag = "" if self.source == "air" else (
            f"; the link's temperature lags the air temperature with time constant {self.tau:.0f} s, starting "
            f"{self.offset:.2f} K below it")
        return dict(
            description=f"link parameter {self.param}{self.joint} grows with temperature{lag}",
            formula=f"{self.param}{self.joint} = L0 * (1 + alpha*(T_link - {self.T_ref})), " + (
                "T_link = air temperature" if self.source == "air" else
                "dT_link/dt = (T_air - T_link)/tau"),
            parameters=dict(alpha_per_k=float(amp), T_ref_c=self.T_ref, tau_s=self.tau,
                            start_offset_k=self.offset if self.source != "air" else None),
        )


class SphereDisplaced(Effect):
    family = "plate_geometry"
    place = "plate"

    def __init__(self, sphere, direction):
        self.sphere = sphere
        self.dir = np.asarray(direction, float) / np.linalg.norm(direction)
        self.channel = f"sphere p{sphere} (constant in the plate frame)"
        self.a0 = 0.05

    def mods(self, ctx, amp):
        m = Mods(ctx.q.shape[0])
        m.plate[:, self.sphere] = amp * self.dir
        return m

    def describe(self, amp):
        return dict(
            description=f"sphere p{self.sphere} sits off its nominal place on the plate (bonding error)",
            formula="p_k_true(plate) = p_k_nominal + v",
            parameters=dict(displacement_mm=(amp * self.dir).tolist(), magnitude_mm=float(amp)),
        )


# ============================================================================== outside the vocabulary
class HoseHinge(Effect):
    """A cable/hose dress goes taut once the joint passes q0 and pulls it back, quadratically."""

    family = None
    place = "joint"

    def __init__(self, joint, q0_deg, side=+1):
        self.joints = [joint]
        self.q0 = q0_deg * DEG
        self.side = side
        self.channel = f"q{joint} beyond {q0_deg:+.0f} deg (one-sided)"
        self.a0 = 0.01

    def mods(self, ctx, amp):
        m = Mods(ctx.q.shape[0])
        j = self.joints[0] - 1
        x = np.maximum(0.0, self.side * (ctx.q[:, j] - self.q0))
        m.dq[:, j] = -self.side * amp * x ** 2
        return m

    def describe(self, amp):
        return dict(
            description=f"hose/cable dress on joint {self.joints[0]} goes taut past {self.q0 / DEG:+.0f} deg "
            "and pulls the joint back, growing with the square of the overtravel",
            formula=f"q_actual = q_cmd - side*c*max(0, side*(q_cmd - q0))^2 [rad], side={self.side}",
            parameters=dict(c_per_rad=float(amp), q0_deg=self.q0 / DEG, side=self.side),
        )


class BaseTiltGravityMoment(Effect):
    """The pedestal/floor is compliant: the base rotates about horizontal axes in proportion to the arm's
    gravity moment about the base origin: omega = (M_x, M_y, 0) / K_floor. amp = 1/K_floor [rad/(N m)]."""

    family = None
    place = "base"
    channel = "gravity moment of the whole arm about the base"

    def __init__(self, payload_kg, payload_com_mm):
        self.payload_kg = payload_kg
        self.payload_com = list(payload_com_mm)
        self.a0 = 1e-7

    def mods(self, ctx, amp):
        frames = link_frames(ctx.robot, ctx.q)
        coms, mass = com_positions(ctx.robot, frames, self.payload_kg, self.payload_com)
        M = np.zeros((ctx.q.shape[0], 3))
        for k in range(coms.shape[1]):
            M += np.cross(coms[:, k] * 1e-3, mass[k] * G[None])
        w = np.zeros_like(M)
        w[:, :2] = M[:, :2] * amp
        m = Mods(ctx.q.shape[0])
        m.base = about_point(rotvec_to_R(w), np.zeros(3))
        return m

    def describe(self, amp):
        return dict(
            description="the robot's pedestal tilts on a compliant floor under the gravity moment of the arm and "
            f"a {self.payload_kg:.2f} kg payload about the base origin",
            formula="base_true = Rot(omega) base, omega = (M_x, M_y, 0)/K_floor, M = sum_k c_k x m_k g (base frame)",
            parameters=dict(K_floor_nm_per_rad=float(1 / amp), payload_kg=self.payload_kg,
                            payload_com_mm=self.payload_com),
        )


class ForearmBending(Effect):
    """The forearm (elbow -> wrist centre) is a cantilever: the transverse gravity load of the wrist, the tool
    and half the forearm's own weight bends it, moving and tilting everything beyond. amp = 1/EI [1/(N m^2)]."""

    family = None
    place = "length"
    channel = "gravity load transverse to the forearm"

    def __init__(self, payload_kg):
        self.links = [3, 4]
        self.payload_kg = payload_kg
        self.a0 = 1e-5

    def mods(self, ctx, amp):
        rob = ctx.robot
        frames = link_frames(rob, ctx.q)
        n = ctx.q.shape[0]
        tip = (np.linalg.inv(frames[2][0]) @ frames[3][0])[:3, 3]  # wrist-centre origin in frame 3 [mm]
        L = np.linalg.norm(tip) * 1e-3
        u = tip / np.linalg.norm(tip)
        R03 = frames[2][:, :3, :3]
        g3 = np.einsum("nji,j->ni", R03, G)  # gravity in frame 3
        m_tip = rob.masses[3:].sum() + self.payload_kg
        w = 0.5 * rob.masses[2] / L  # kg per m of the forearm's own weight (half of link 3)

        def perp(v):
            return v - np.einsum("ni,i->n", v, u)[:, None] * u[None]

        F = perp(m_tip * g3)  # N
        q_dist = perp(w * g3)  # N/m
        defl = (F * L ** 3 / 3 + q_dist * L ** 4 / 8) * amp * 1e3  # mm
        slope = (np.cross(u[None], F) * L ** 2 / 2 + np.cross(u[None], q_dist) * L ** 3 / 6) * amp  # rad
        R = rotvec_to_R(slope)
        T = about_point(R, tip)
        T[:, :3, 3] += defl
        m = Mods(n)
        m.post[2] = T
        return m

    def describe(self, amp):
        return dict(
            description="the forearm bends as a cantilever under the transverse gravity load of the wrist, the "
            f"{self.payload_kg:.2f} kg payload and its own weight: the wrist centre moves and tilts",
            formula="delta = F_perp L^3/(3EI) + w_perp L^4/(8EI), slope = u x (F_perp L^2/(2EI) + w_perp L^3/(6EI)), "
            "applied at the wrist centre in frame 3",
            parameters=dict(EI_nm2=float(1 / amp), payload_kg=self.payload_kg),
        )


class CameraMountDrift(Effect):
    """The camera bracket warms after power-on: the measurement frame drifts as D(t) = exp(f(t) * xi),
    f = 1 - exp(-(t + t_on)/tau), xi = (v [mm], w [rad]) fixed direction. amp scales xi."""

    family = None
    place = "measurement"
    channel = "t_s (camera warm-up)"

    def __init__(self, v_dir_mm, w_dir_rad, tau_s, t_on_s):
        self.v = np.asarray(v_dir_mm, float)
        self.w = np.asarray(w_dir_rad, float)
        self.tau, self.t_on = tau_s, t_on_s
        self.a0 = 1.0

    def mods(self, ctx, amp):
        f = 1 - np.exp(-(ctx.t + self.t_on) / self.tau)
        xi = amp * f[:, None] * np.concatenate([self.v, self.w])[None]
        m = Mods(ctx.q.shape[0])
        m.meas = np.stack([pose6_to_T(x) for x in xi])
        return m

    def describe(self, amp):
        return dict(
            description="the camera mount drifts while it warms up after power-on (translation and rotation of "
            "the measurement frame, exponential in time)",
            formula="base2meas_true(t) = D(f(t)) base2meas, f = 1 - exp(-(t_s + t_on)/tau), D = pose6(f*(v, w))",
            parameters=dict(v_final_mm=(amp * self.v).tolist(), w_final_deg=(amp * self.w / DEG).tolist(),
                            tau_s=self.tau, t_on_s=self.t_on),
        )


class BaseBump(Effect):
    """Someone bumps the robot at t_b: the base shifts and turns slightly and stays there."""

    family = None
    place = "base"

    def __init__(self, t_bump, v_dir_mm, w_dir_rad, pivot_mm=(0, 0, 0)):
        self.t_b = t_bump
        self.v = np.asarray(v_dir_mm, float)
        self.w = np.asarray(w_dir_rad, float)
        self.pivot = np.asarray(pivot_mm, float)
        self.channel = f"step at t_s = {t_bump:.0f} s"
        self.a0 = 1.0

    def mods(self, ctx, amp):
        n = ctx.q.shape[0]
        step = (ctx.t >= self.t_b).astype(float)
        R = rotvec_to_R(amp * step[:, None] * self.w[None])
        T = about_point(R, self.pivot)
        T[:, :3, 3] += amp * step[:, None] * self.v[None]
        m = Mods(n)
        m.base = T
        return m

    def describe(self, amp):
        return dict(
            description="the robot base was knocked during the session: a sudden small shift and turn that stays",
            formula="base_true = base for t < t_b, Rot(w) about pivot + v afterwards",
            parameters=dict(t_bump_s=self.t_b, v_mm=(amp * self.v).tolist(), w_deg=(amp * self.w / DEG).tolist(),
                            pivot_mm=self.pivot.tolist()),
        )


class MoveSizeOffset(Effect):
    """Unsettled servo wind-up: after a move the joint stays off by h*tanh(step/s0), step the signed size of the
    last commanded move of that joint (repeats without moving keep it)."""

    family = None
    place = "joint"

    def __init__(self, joint, s0_deg):
        self.joints = [joint]
        self.s0 = s0_deg * DEG
        self.channel = f"signed size of the last move of q{joint}"
        self.a0 = 0.005 * DEG

    def mods(self, ctx, amp):
        st = steps(ctx)
        m = Mods(ctx.q.shape[0])
        j = self.joints[0] - 1
        m.dq[:, j] = amp * np.tanh(st[:, j] / self.s0)
        return m

    def describe(self, amp):
        return dict(
            description=f"joint {self.joints[0]} settles short/long in proportion to the size of its last move, "
            f"saturating for moves beyond ~{self.s0 / DEG:.0f} deg",
            formula=f"q_actual = q_cmd + h*tanh(step_{self.joints[0]}/s0)",
            parameters=dict(h_deg=float(amp / DEG), s0_deg=self.s0 / DEG),
        )


class BearingWobble(Effect):
    """Raceway waviness of joint 1's bearing: axis 1 tilts by eps in a direction turning k times per
    revolution: pre-rotation Rot(eps (cos(k q1 + ph), sin(k q1 + ph), 0)) about (0, 0, z_p)."""

    family = None
    place = "joint"

    def __init__(self, order, phase_deg, pivot_z_mm):
        self.joints = [1]
        self.order = order
        self.ph = phase_deg * DEG
        self.zp = pivot_z_mm
        self.channel = f"tilt of axis 1 with ({order} q1)"
        self.a0 = 0.002 * DEG

    def mods(self, ctx, amp):
        a = self.order * ctx.q[:, 0] + self.ph
        w = amp * np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)
        m = Mods(ctx.q.shape[0])
        m.pre[0] = about_point(rotvec_to_R(w), np.array([0, 0, self.zp]))
        return m

    def describe(self, amp):
        return dict(
            description=f"joint 1's axis wobbles: its tilt (not its angle) varies {self.order} times per turn, "
            "from raceway waviness of the base bearing",
            formula="frame1 = Rot(eps*(cos(k q1+ph), sin(k q1+ph), 0)) about (0,0,z_p) applied in the base frame "
            "before joint 1",
            parameters=dict(eps_deg=float(amp / DEG), order=self.order, phase_deg=self.ph / DEG,
                            pivot_z_mm=self.zp),
        )


class LensDistortionResidual(Effect):
    """The instrument's lens model leaves a radial distortion residual: lateral coordinates scale by
    (1 + k r^2), r^2 = (x^2 + y^2)/z^2 in the camera frame (depth unchanged). amp = k."""

    family = None
    place = "measurement"
    channel = "field angle in the camera image"

    def __init__(self):
        self.a0 = 1e-4

    def mods(self, ctx, amp):
        m = Mods(ctx.q.shape[0])

        def f(P, k=amp):
            r2 = (P[..., 0] ** 2 + P[..., 1] ** 2) / P[..., 2] ** 2
            Q = P.copy()
            Q[..., 0] *= 1 + k * r2
            Q[..., 1] *= 1 + k * r2
            return Q

        m.point_fns.append(f)
        return m

    def describe(self, amp):
        return dict(
            description="uncorrected radial lens distortion of the tracker: points far off the optical axis "
            "are reported too far out (or in) laterally",
            formula="x' = x(1 + k r^2), y' = y(1 + k r^2), z' = z, r^2 = (x^2+y^2)/z^2 (measurement frame)",
            parameters=dict(k=float(amp)),
        )


class JointProduct(Effect):
    """Offset of one joint proportional to the product of two joint angles (about their range centres)."""

    family = None
    place = "joint"

    def __init__(self, target, i, j, ci_deg, cj_deg):
        self.joints = [target, i, j] if target not in (i, j) else sorted({target, i, j})
        self.target, self.i, self.j = target, i, j
        self.ci, self.cj = ci_deg * DEG, cj_deg * DEG
        self.channel = f"(q{i}-{ci_deg:g})*(q{j}-{cj_deg:g})"
        self.a0 = 1e-4

    def mods(self, ctx, amp):
        m = Mods(ctx.q.shape[0])
        m.dq[:, self.target - 1] = amp * (ctx.q[:, self.i - 1] - self.ci) * (ctx.q[:, self.j - 1] - self.cj)
        return m

    def describe(self, amp):
        return dict(
            description=f"joint {self.target} offset grows with the product of q{self.i} and q{self.j} "
            "(elbow cable loop whose pull depends on both)",
            formula=f"q_actual_{self.target} = q_cmd + c (q{self.i}-ci)(q{self.j}-cj) [rad, rad^2]",
            parameters=dict(c_per_rad=float(amp), ci_deg=self.ci / DEG, cj_deg=self.cj / DEG),
        )
