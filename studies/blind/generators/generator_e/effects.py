"""Effects, parameterised independently. Each returns modifications of the true measurement chain:

    P = M_post(t) . base2meas[s] . B_pre(q) . flange2base(params + dparams, q_cmd + dq) . tool2flange . (s_tool + ds)
    P <- meas_map(P)  (instrument effects, in the camera frame)

Internal units: mm, rad, s.
"""
from __future__ import annotations

import numpy as np

import kin

DEG = kin.DEG


class Mods:
    def __init__(self, n):
        self.dq = np.zeros((n, 6))
        self.dparams = {}
        self.base_pre = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
        self.meas_post = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
        self.dsph = np.zeros((n, 3, 3))
        self.maps = []

    def add(self, o: "Mods"):
        self.dq += o.dq
        for k, v in o.dparams.items():
            self.dparams[k] = self.dparams.get(k, 0) + v
        self.base_pre = self.base_pre @ o.base_pre
        self.meas_post = o.meas_post @ self.meas_post
        self.dsph += o.dsph
        self.maps += o.maps


def _rot_about(pivot, rv):
    """(n,4,4) rotations by rotation vectors rv (n,3) about a fixed point pivot (3,)."""
    n = len(rv)
    R = kin.rotvec_to_R_batch(rv)
    T = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    T[:, :3, :3] = R
    T[:, :3, 3] = pivot - np.einsum("nij,j->ni", R, pivot)
    return T


def lagged(temp_fn, t_rows, tau_s, t0=0.0):
    """First-order lag of temp_fn, starting at equilibrium at t0; integrated exactly on a 1 s grid."""
    tmax = float(np.max(t_rows)) + 2
    grid = np.arange(t0, tmax + 1.0, 1.0)
    Tin = temp_fn(grid)
    out = np.empty_like(Tin)
    out[0] = Tin[0]
    k = 1 - np.exp(-1.0 / tau_s)
    for i in range(1, len(grid)):
        out[i] = out[i - 1] + k * (Tin[i - 1] - out[i - 1])
    return np.interp(t_rows, grid, out)


class Effect:
    family = "?"
    place = "?"

    def __init__(self, **kw):
        self.kw = kw

    def mods(self, ctx) -> Mods:
        raise NotImplementedError

    def key(self) -> dict:
        raise NotImplementedError


# ------------------------------------------------------------------ catalogue-type effects
class JointCompliance(Effect):
    """delta q_j = tau_j(q) / k_j, tau from a link-mass + payload gravity model of the true arm."""

    def mods(self, ctx):
        m = Mods(ctx.n)
        tau = kin.gravity_torques(ctx.params, ctx.q, ctx.robot, ctx.T_tool, self.kw["payload_kg"], self.kw["payload_com_mm"])
        for j, k in self.kw["stiffness"].items():
            m.dq[:, j - 1] = tau[:, j - 1] / k
        return m

    def key(self):
        js = sorted(self.kw["stiffness"])
        return dict(
            family="compliance",
            description=f"gravity-driven joint compliance of joints {js} with a {self.kw['payload_kg']} kg payload "
            f"at {self.kw['payload_com_mm']} mm in the plate frame",
            formula="q_actual_j = q_cmd_j + tau_j(q_cmd)/k_j; tau_j = z_j . sum_{links>=j, payload} (c_k - o_j) x m_k g; "
            + ", ".join(f"k{j} = {self.kw['stiffness'][j]:.4g} N m/rad" for j in js)
            + f"; link masses {self.kw.get('masses_note', 'crude link-mass model')}",
            joints=js, links=[], place="joint", channel="gravity torque of joints " + ",".join(map(str, js)),
        )


class Backlash(Effect):
    """q_actual = q_cmd - h * s, s = sign of the last non-zero commanded motion of the joint (initial s0)."""

    def mods(self, ctx):
        j = self.kw["joint"] - 1
        h = self.kw["half_deg"] * DEG
        s = float(self.kw.get("initial_sign", 1))
        qs = np.concatenate([[ctx.q_home[j]], ctx.q[:, j]])
        sig = np.empty(ctx.n)
        for i in range(ctx.n):
            d = qs[i + 1] - qs[i]
            if abs(d) > 1e-9:
                s = 1.0 if d > 0 else -1.0
            sig[i] = s
        m = Mods(ctx.n)
        m.dq[:, j] = -h * sig
        return m

    def key(self):
        return dict(
            family="backlash",
            description=f"backlash on joint {self.kw['joint']}: the joint stops short by half the clearance on the side it approached from",
            formula=f"q_actual = q_cmd - h*sign(last commanded motion of joint {self.kw['joint']}); h = {self.kw['half_deg']} deg",
            joints=[self.kw["joint"]], links=[], place="joint", channel=f"approach_sign_j{self.kw['joint']}",
        )


class Cyclic(Effect):
    def mods(self, ctx):
        j = self.kw["joint"] - 1
        m = Mods(ctx.n)
        for (order, amp, ph) in self.kw["harmonics"]:
            m.dq[:, j] += amp * DEG * np.sin(order * ctx.q[:, j] + ph * DEG)
        return m

    def key(self):
        j = self.kw["joint"]
        hs = self.kw["harmonics"]
        return dict(
            family="cyclic",
            description=f"cyclic transmission error of joint {j} (orders {[h[0] for h in hs]} per joint revolution)",
            formula=" + ".join(f"{a} deg * sin({o} q{j} + {p} deg)" for o, a, p in hs) + f" added to q{j}",
            joints=[j], links=[], place="joint", channel=" ".join(f"sin/cos({o} q{j})" for o, _, _ in hs),
        )


class GearRatio(Effect):
    def mods(self, ctx):
        j = self.kw["joint"] - 1
        m = Mods(ctx.n)
        m.dq[:, j] = self.kw["eps"] * ctx.q[:, j]
        return m

    def key(self):
        j = self.kw["joint"]
        return dict(
            family="gear_ratio",
            description=f"gear-ratio (scale) error of joint {j}",
            formula=f"q_actual = q_cmd * (1 + {self.kw['eps']:.3g}) (about the encoder zero)",
            joints=[j], links=[], place="joint", channel=f"q{j}",
        )


class Coupling(Effect):
    def mods(self, ctx):
        m = Mods(ctx.n)
        m.dq[:, self.kw["driven"] - 1] = self.kw["c"] * ctx.q[:, self.kw["driver"] - 1]
        return m

    def key(self):
        a, b = self.kw["driver"], self.kw["driven"]
        return dict(
            family="coupling",
            description=f"mechanical coupling: joint {b} turns with joint {a} (wrist transmission cross-coupling)",
            formula=f"q{b}_actual = q{b}_cmd + {self.kw['c']:.4g} * q{a}_cmd",
            joints=[a, b], links=[], place="joint", channel=f"q{a}",
        )


class Thermal(Effect):
    """Link lengths grow with the lagged temperature: L -> L (1 + alpha (T_link - T_ref))."""

    def mods(self, ctx):
        Tl = lagged(ctx.temp_fn, ctx.t, self.kw["tau_s"])
        dT = Tl - self.kw["T_ref"]
        m = Mods(ctx.n)
        for name in self.kw["links"]:
            kind, idx = name[0], int(name[1]) - 1
            L = ctx.params[kind][idx]
            arr = m.dparams.setdefault(kind, np.zeros((ctx.n, 6)))
            arr[:, idx] += self.kw["alpha"] * L * dT
        return m

    def key(self):
        return dict(
            family="thermal",
            description=f"thermal growth of links {self.kw['links']} following the recorded temperature with a first-order lag",
            formula=f"L = L_true (1 + {self.kw['alpha']:.3g}/K * (T_link - {self.kw['T_ref']} C)); "
            f"dT_link/dt = (T(t) - T_link)/{self.kw['tau_s']} s, T_link(0) = T(0); T(t) = the temperature the instrument records (temp_c, without its 0.03 K sensor noise)",
            joints=[], links=list(self.kw["links"]), place="length", channel=f"temp_c lagged {self.kw['tau_s']} s",
        )


class PlateSphere(Effect):
    def mods(self, ctx):
        m = Mods(ctx.n)
        m.dsph[:, self.kw["sphere"]] = np.asarray(self.kw["delta_mm"])
        return m

    def key(self):
        return dict(
            family="plate_geometry",
            description=f"sphere p{self.kw['sphere']} sits off its nominal place on the plate (re-glued)",
            formula=f"s_tool[{self.kw['sphere']}] += {list(self.kw['delta_mm'])} mm (plate frame)",
            joints=[], links=[], place="plate", channel="plate", 
        )


# ------------------------------------------------------------------ outside the catalogue
class MountDrift(Effect):
    """The camera mount settles/warms: rigid motion of the camera about the tripod head, 1 - exp(-t/tau)."""

    def mods(self, ctx):
        f = 1 - np.exp(-(ctx.t - ctx.t[0]) / self.kw["tau_s"])
        m = Mods(ctx.n)
        rv = f[:, None] * np.asarray(self.kw["rot_rad"])[None]
        T = _rot_about(np.asarray(self.kw["pivot_mm"], float), rv)
        T[:, :3, 3] += f[:, None] * np.asarray(self.kw["trans_mm"])[None]
        m.meas_post = T
        return m

    def key(self):
        return dict(
            family="camera_mount_drift",
            description="the camera tripod/head drifts while it warms and settles (rigid motion of the measurement frame over time)",
            formula=f"p_meas -> R(f rv) (p - c) + c + f*dt, f = 1 - exp(-(t - t0)/{self.kw['tau_s']} s), rv = {self.kw['rot_rad']} rad, "
            f"dt = {self.kw['trans_mm']} mm, c = {self.kw['pivot_mm']} mm (tripod head, camera frame)",
            joints=[], links=[], place="measurement", channel="t_s (1 - exp)",
        )


class LensResidual(Effect):
    def mods(self, ctx):
        k, kd = self.kw["k_lat"], self.kw["k_depth"]

        def f(P):
            u, v = P[..., 0] / P[..., 2], P[..., 1] / P[..., 2]
            r2 = u * u + v * v
            Q = P.copy()
            Q[..., 0] += k * r2 * P[..., 0]
            Q[..., 1] += k * r2 * P[..., 1]
            Q[..., 2] += kd * r2 * P[..., 2]
            return Q

        m = Mods(ctx.n)
        m.maps.append(f)
        return m

    def key(self):
        return dict(
            family="lens_distortion_residual",
            description="the stereo calibration left a radial distortion uncorrected (board views did not cover the image corners)",
            formula=f"u = x/z, v = y/z, r2 = u^2 + v^2; x += {self.kw['k_lat']} r2 x; y += {self.kw['k_lat']} r2 y; z += {self.kw['k_depth']} r2 z (camera frame)",
            joints=[], links=[], place="measurement", channel="field (radial, camera frame)",
        )


class JointStep(Effect):
    def mods(self, ctx):
        m = Mods(ctx.n)
        m.dq[:, self.kw["joint"] - 1] = np.where(ctx.t >= self.kw["t_step"], self.kw["delta_deg"] * DEG, 0.0)
        return m

    def key(self):
        j = self.kw["joint"]
        return dict(
            family="joint_offset_jump",
            description=f"after the controller restart in the pause, joint {j}'s resolver offset re-latched differently (a step in its zero)",
            formula=f"q{j}_actual = q{j}_cmd + {self.kw['delta_deg']} deg for t_s >= {self.kw['t_step']:.1f} s (0 before)",
            joints=[j], links=[f"theta{j}"], place="joint", channel=f"step(t_s >= {self.kw['t_step']:.1f})",
        )


class Pedestal(Effect):
    """The pedestal rocks on a base plate shimmed unevenly: base tilt = K^-1 M, stiffness different along two floor axes."""

    def mods(self, ctx):
        M = kin.base_moment(ctx.params, ctx.q, ctx.robot, ctx.T_tool, self.kw.get("payload_kg", 0.0), self.kw.get("payload_com_mm", [0, 0, 0]))
        ph = self.kw["axis_deg"] * DEG
        u = np.array([np.cos(ph), np.sin(ph), 0.0])
        v = np.array([-np.sin(ph), np.cos(ph), 0.0])
        w = (M @ u / self.kw["K_u"])[:, None] * u + (M @ v / self.kw["K_v"])[:, None] * v
        m = Mods(ctx.n)
        m.base_pre = _rot_about(np.zeros(3), w)
        return m

    def key(self):
        return dict(
            family="pedestal_rocking",
            description="the robot pedestal rocks on its floor plate under the arm's own gravity moment; stiffer along one floor axis than the other",
            formula=f"base tilt rv = (M.u/{self.kw['K_u']:.3g}) u + (M.v/{self.kw['K_v']:.3g}) v [rad, N m/rad], M = gravity moment of all links about the base origin, "
            f"u at {self.kw['axis_deg']} deg from base x in the floor plane; points p_base -> R(rv) p_base",
            joints=[1, 2, 3], links=[], place="base", channel="gravity moment about the base (q1, q2, q3)",
        )


class ServoSettle(Effect):
    def mods(self, ctx):
        prev = np.vstack([ctx.q_home[None], ctx.q[:-1]])
        m = Mods(ctx.n)
        for j in self.kw["joints"]:
            m.dq[:, j - 1] = -self.kw["r"] * (ctx.q[:, j - 1] - prev[:, j - 1])
        return m

    def key(self):
        return dict(
            family="servo_settling",
            description="measurements triggered before the axes had settled: each joint still lags behind by a fraction of its last move",
            formula=f"q_actual_j = q_cmd_j - {self.kw['r']:.3g} * (q_cmd_j - q_cmd_j(previous row)), joints {self.kw['joints']}",
            joints=list(self.kw["joints"]), links=[], place="joint", channel="last move size (history)",
        )


class TripodBump(Effect):
    def mods(self, ctx):
        on = (ctx.t >= self.kw["t_step"]).astype(float)
        rv = on[:, None] * np.asarray(self.kw["rot_rad"])[None]
        T = _rot_about(np.asarray(self.kw["pivot_mm"], float), rv)
        T[:, :3, 3] += on[:, None] * np.asarray(self.kw["trans_mm"])[None]
        m = Mods(ctx.n)
        m.meas_post = T
        return m

    def key(self):
        return dict(
            family="tripod_bump",
            description="the operator knocked the camera tripod during the pause; the camera sits slightly differently afterwards",
            formula=f"for t_s >= {self.kw['t_step']:.1f}: p_meas -> R(rv)(p - c) + c + dt, rv = {self.kw['rot_rad']} rad, dt = {self.kw['trans_mm']} mm, c = {self.kw['pivot_mm']} mm",
            joints=[], links=[], place="measurement", channel=f"step(t_s >= {self.kw['t_step']:.1f})",
        )


class FocalDrift(Effect):
    """Camera warm-up changes both cameras' focal length by eps(t): a stereo pair then scales depth only."""

    def mods(self, ctx):
        eps = self.kw["coef_per_K"] * self.kw["dT_K"] * (1 - np.exp(-(ctx.t - ctx.t[0]) / self.kw["tau_s"]))

        def f(P):
            Q = P.copy()
            Q[..., 2] = P[..., 2] / (1 + eps[:, None])
            return Q

        m = Mods(ctx.n)
        m.maps.append(f)
        return m

    def key(self):
        return dict(
            family="camera_warmup_focal",
            description="camera electronics warm the lenses: focal lengths grow by eps(t); triangulated depth shrinks by 1/(1+eps), x and y unchanged",
            formula=f"z_meas = z / (1 + eps(t)), eps = {self.kw['coef_per_K']:.3g}/K * {self.kw['dT_K']} K * (1 - exp(-(t - t0)/{self.kw['tau_s']} s))",
            joints=[], links=[], place="measurement", channel="t_s x depth",
        )


class OutlineBias(Effect):
    """Uncorrected perspective bias of the sphere outlines (both images magnified by (R/z)^2 about the principal point)."""

    def mods(self, ctx):
        R = self.kw["radius_mm"]

        def f(P):
            Q = P.copy()
            Q[..., 2] = P[..., 2] / (1 + (R / P[..., 2]) ** 2)
            return Q

        m = Mods(ctx.n)
        m.maps.append(f)
        return m

    def key(self):
        return dict(
            family="sphere_outline_bias",
            description="the instrument's software takes the centre of each sphere's elliptical outline as the centre's image (no perspective-bias correction); for a near-parallel stereo pair that biases depth",
            formula=f"z_meas = z / (1 + (R/z)^2), R = {self.kw['radius_mm']} mm (camera frame, x and y unchanged)",
            joints=[], links=[], place="measurement", channel="depth (1/z)",
        )


class HoseHinge(Effect):
    def mods(self, ctx):
        j = self.kw["joint"] - 1
        x = np.maximum(0.0, ctx.q[:, j] - self.kw["q0_deg"] * DEG)
        m = Mods(ctx.n)
        m.dq[:, j] = -self.kw["c"] * x**2
        return m

    def key(self):
        j = self.kw["joint"]
        return dict(
            family="dress_pack_tension",
            description=f"the dress pack (cables and air hose) goes taut when joint {j} passes {self.kw['q0_deg']} deg and pulls it back through the gearbox's compliance",
            formula=f"q{j}_actual = q{j}_cmd - {self.kw['c']:.3g} * max(0, q{j}_cmd - {self.kw['q0_deg']} deg)^2 [rad]",
            joints=[j], links=[], place="joint", channel=f"hinge(q{j} > {self.kw['q0_deg']} deg)^2",
        )


CATALOGUE = {
    "compliance": JointCompliance, "backlash": Backlash, "cyclic": Cyclic, "gear_ratio": GearRatio,
    "coupling": Coupling, "thermal": Thermal, "plate": PlateSphere,
    "mount_drift": MountDrift, "lens": LensResidual, "joint_step": JointStep, "pedestal": Pedestal,
    "settle": ServoSettle, "bump": TripodBump, "focal": FocalDrift, "outline": OutlineBias, "hose": HoseHinge,
}


def build(spec):
    kind, kw = spec
    return CATALOGUE[kind](**kw)
