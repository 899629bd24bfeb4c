"""Physical effects. Each effect has a dimensionless `scale` (set by the sizing step) multiplying its
amplitude; `params()` reports the physical values at that scale; `key()` the key.json entry.

Kinds (where the effect enters the chain p_meas = M(base2meas @ Dbase @ Lflange @ flange2base(q+dq, geom+dgeom)
@ J @ tool2flange @ Dtool @ (s + ds))):
  joint  -> dq (n,6) [rad] added to the commanded joints
  length -> dgeom (n,25) added to the true MDH vector (mm / rad)
  lag    -> translation (n,3) [mm] of the flange in the base frame (Lflange)
  base   -> Dbase (n,4,4): p_base' = Dbase p_base
  tool   -> Dtool (n,4,4): tool2flange' = tool2flange @ Dtool
  plate  -> ds (n,3,3) [mm] sphere centres in the plate frame
  meas   -> P' = M(P) on the measured centres in the station frame
"""
from __future__ import annotations

import numpy as np

import kin
from kin import DEG
from robots import masses

G = 9.81
PLATE_LOAD_OFFSET_MM = np.array([0.0, 0.0, 45.0])   # payload centre of mass in the flange frame


def gravity(ctx, payload_kg):
    """Gravity torques about the six joint axes [N m] (n,6) and the overturning moment about the base
    origin [N m] (n,3), from lumped masses on the nominal arm at the commanded joints."""
    fr = ctx.frames_nom
    m = masses(ctx.robot)
    o = [f[:, :3, 3] for f in fr]
    F = fr[-1]
    pts = [0.5 * (o[2] + o[3]), 0.5 * (o[3] + o[4]), o[5], kin.apply(F, PLATE_LOAD_OFFSET_MM[None, None, :])[:, 0]]
    mass = [np.full(ctx.n, m["upper_arm"]), np.full(ctx.n, m["forearm"]), np.full(ctx.n, m["wrist"]),
            m["plate"] + np.asarray(payload_kg, float) * np.ones(ctx.n)]
    link_of_body = [2, 3, 5, 6]   # a body on link i loads joints 1..i
    tau = np.zeros((ctx.n, 6))
    for j in range(1, 7):
        z = fr[j][:, :3, 2]
        oj = o[j]
        for p, mm, lb in zip(pts, mass, link_of_body):
            if j <= lb:
                f = np.zeros((ctx.n, 3)); f[:, 2] = -mm * G
                tau[:, j - 1] += np.sum(z * np.cross((p - oj) * 1e-3, f), 1)
    M = np.zeros((ctx.n, 3))
    for p, mm in zip(pts, mass):
        f = np.zeros((ctx.n, 3)); f[:, 2] = -mm * G
        M += np.cross(p * 1e-3, f)
    return tau, M


class Effect:
    family = None
    kind = None
    place = None
    links: list = []
    joints: list = []

    def __init__(self):
        self.scale = 1.0

    def key(self):
        return dict(family=self.family, description=self.description(), formula=self.formula(),
                    joints=list(self.joints), links=list(self.links), place=self.place, channel=self.channel(),
                    params=self.params())


# ---------------------------------------------------------------- catalogue families

class Compliance(Effect):
    family, kind, place = "compliance", "joint", "joint"

    def __init__(self, rng, ctx, joints=(2, 3), payload=(0.0, 0.0), soften=0.0):
        super().__init__()
        self.joints = list(joints)
        self.payload = payload
        self.soften = soften
        # relative compliances (joint 3 stiffer per unit torque than joint 2 is not assumed)
        self.c = {j: rng.uniform(0.6, 1.4) for j in joints}
        pay = np.where(np.arange(ctx.n) >= (ctx.restart_idx if ctx.restart_idx is not None else ctx.n),
                       payload[1], payload[0])
        self.tau, _ = gravity(ctx, pay)
        self.tau_ref = {j: float(np.max(np.abs(self.tau[:ctx.n_data, j - 1]))) for j in joints}

    def _k(self, j):   # stiffness [N m / rad] at this scale
        return 1.0 / (self.scale * self.c[j] * 2e-6)

    def joint(self, ctx):
        dq = np.zeros((ctx.n, 6))
        for j in self.joints:
            tau = self.tau[:, j - 1]
            x = tau / self._k(j)
            if self.soften:
                x = x * (1 + self.soften * (tau / self.tau_ref[j]) ** 2)
            dq[:, j - 1] = x
        return dq

    def params(self):
        d = {f"stiffness_j{j}_nm_per_rad": self._k(j) for j in self.joints}
        d.update({f"max_abs_gravity_torque_j{j}_nm": self.tau_ref[j] for j in self.joints})
        d["payload_kg_before_after_restart"] = list(self.payload)
        if self.soften:
            d["softening_beta"] = self.soften
        return d

    def description(self):
        s = f"joints {self.joints} deflect under the gravity torque of the arm and its load (linear springs"
        if self.soften:
            s = f"joints {self.joints} deflect under gravity torque through a softening (progressive) spring"
        if self.payload[1] != self.payload[0]:
            s += f"; {self.payload[1] - self.payload[0]:.1f} kg added to the flange load at the recorded restart"
        return s + ")" if not self.soften else s

    def formula(self):
        f = "dq_j = tau_j(q, m_load) / K_j, tau_j = z_j . sum_b (r_b - o_j) x m_b g (lumped masses: upper arm, forearm, wrist, plate+load)"
        if self.soften:
            f += "; softening: dq_j = tau_j/K_j * (1 + beta (tau_j/tau_ref_j)^2)"
        return f

    def channel(self):
        s = "gravity torque (configuration)"
        if self.payload[1] != self.payload[0]:
            s += "; load step at the status=restart row"
        return s


class Backlash(Effect):
    family, kind, place = "backlash", "joint", "joint"

    def __init__(self, rng, ctx, joint=5):
        super().__init__()
        self.joints = [joint]
        self.h_unit = 0.01 * DEG

    def joint(self, ctx):
        j = self.joints[0] - 1
        h = self.h_unit * self.scale
        u = ctx.path[:, j]
        o = np.empty_like(u)
        cur = u[0] - h
        for i, x in enumerate(u):
            cur = min(max(cur, x - h), x + h)
            o[i] = cur
        dq = np.zeros((ctx.n, 6))
        dq[:, j] = (o - u)[ctx.row_path_idx]
        return dq

    def params(self):
        return dict(half_clearance_deg=self.h_unit * self.scale / DEG, dead_band_deg=2 * self.h_unit * self.scale / DEG)

    def description(self):
        return f"lost motion (dead band) in the gear of joint {self.joints[0]}: the output lags the command by half the clearance, on the side it was approached from; reversals inside the band do not move it"

    def formula(self):
        return "play operator: o_k = clip(o_{k-1}, u_k - h, u_k + h) over every commanded waypoint; dq = o - u (= -h sign(last move) after moves > 2h)"

    def channel(self):
        return f"approach direction of joint {self.joints[0]} (history of commanded moves)"


class Cyclic(Effect):
    family, kind, place = "cyclic", "joint", "joint"

    def __init__(self, rng, ctx, terms=((3, 2), (4, 1))):
        super().__init__()
        self.terms = [(j, n, rng.uniform(0.6, 1.4), rng.uniform(0, 2 * np.pi)) for j, n in terms]
        self.joints = sorted({j for j, _ in terms})
        self.unit = 0.01 * DEG

    def joint(self, ctx):
        dq = np.zeros((ctx.n, 6))
        for j, n, a, ph in self.terms:
            dq[:, j - 1] += self.scale * self.unit * a * np.sin(n * ctx.q[:, j - 1] + ph)
        return dq

    def params(self):
        return dict(terms=[dict(joint=j, order=n, amplitude_deg=self.scale * self.unit * a / DEG, phase_rad=ph)
                           for j, n, a, ph in self.terms])

    def description(self):
        return "periodic transmission error: " + ", ".join(f"joint {j} order {n}" for j, n, _, _ in self.terms)

    def formula(self):
        return "dq_j = A sin(n q_j + phi) per term (q_j commanded joint angle [rad])"

    def channel(self):
        return ", ".join(f"sin/cos({n} q{j})" for j, n, _, _ in self.terms)


class GearRatio(Effect):
    family, kind, place = "gear_ratio", "joint", "joint"

    def __init__(self, rng, ctx, joints=(3, 6)):
        super().__init__()
        self.joints = list(joints)
        self.eps = {j: rng.choice([-1, 1]) * rng.uniform(0.5, 1.5) for j in joints}
        self.unit = 1e-4

    def joint(self, ctx):
        dq = np.zeros((ctx.n, 6))
        for j in self.joints:
            dq[:, j - 1] = self.scale * self.unit * self.eps[j] * ctx.q[:, j - 1]
        return dq

    def params(self):
        return {f"ratio_error_j{j}_ppm": self.scale * self.unit * self.eps[j] * 1e6 for j in self.joints}

    def description(self):
        return f"the reduction ratio of joints {self.joints} differs from the controller's value (joint angle scaled)"

    def formula(self):
        return "dq_j = eps_j q_j (q_j commanded, from the encoder zero)"

    def channel(self):
        return ", ".join(f"q{j}" for j in self.joints)


class Coupling(Effect):
    family, kind, place = "coupling", "joint", "joint"

    def __init__(self, rng, ctx, driven=6, driver=5):
        super().__init__()
        self.driven, self.driver = driven, driver
        self.joints = [driven, driver]
        self.k = rng.choice([-1, 1]) * 1e-4

    def joint(self, ctx):
        dq = np.zeros((ctx.n, 6))
        dq[:, self.driven - 1] = self.scale * self.k * ctx.q[:, self.driver - 1]
        return dq

    def params(self):
        return dict(coupling_ratio=self.scale * self.k, driven_joint=self.driven, driver_joint=self.driver)

    def description(self):
        return f"wrist coupling: joint {self.driven} turns with joint {self.driver}'s motion (the controller's coupling compensation ratio is off)"

    def formula(self):
        return f"dq{self.driven} = kappa q{self.driver}"

    def channel(self):
        return f"q{self.driver} -> joint {self.driven}"


class ThermalTemp(Effect):
    family, kind, place = "thermal", "length", "length"

    def __init__(self, rng, ctx, links=("d1", "a3")):
        super().__init__()
        self.links = list(links)
        self.rel = {l: rng.uniform(0.6, 1.4) for l in links}
        self.T0 = 20.0
        self.unit = 1e-5   # per K at scale 1 (10 ppm/K)

    def length(self, ctx):
        dv = np.zeros((ctx.n, 25))
        for l in self.links:
            i = kin.PARAM_NAMES.index(l)
            L = ctx.pv_nom[i]
            dv[:, i] = self.scale * self.unit * self.rel[l] * L * (ctx.T - self.T0)
        return dv

    def params(self):
        return {f"expansion_{l}_ppm_per_K": self.scale * self.unit * self.rel[l] * 1e6 for l in self.links} | {"T_ref_c": self.T0}

    def description(self):
        return f"links {self.links} grow with the robot temperature (recorded as temp_c)"

    def formula(self):
        return "dL = alpha_L L_nominal (T - T_ref)"

    def channel(self):
        return "temp_c"


class ThermalWarmup(Effect):
    family, kind, place = "thermal", "length", "length"

    def __init__(self, rng, ctx, links=("a3", "d4")):
        super().__init__()
        self.links = list(links)
        self.rel = {l: rng.uniform(0.6, 1.4) for l in links}
        self.tau = rng.uniform(1200, 2400)
        self.unit = 0.01   # mm at scale 1
        self.t0 = float(ctx.t[0])

    def length(self, ctx):
        dv = np.zeros((ctx.n, 25))
        for l in self.links:
            i = kin.PARAM_NAMES.index(l)
            dv[:, i] = self.scale * self.unit * self.rel[l] * (1 - np.exp(-(ctx.t - ctx.t[0]) / self.tau))
        return dv

    def params(self):
        return {f"growth_{l}_mm_final": self.scale * self.unit * self.rel[l] for l in self.links} | {"tau_s": self.tau, "t_start_s": self.t0}

    def description(self):
        return f"links {self.links} grow as the robot warms up after the start (no temperature recorded)"

    def formula(self):
        return "dL = G_L (1 - exp(-(t - t_first)/tau))"

    def channel(self):
        return "t_s"


class PlateSphere(Effect):
    family, kind, place = "plate_geometry", "plate", "plate"

    def __init__(self, rng, ctx, sphere=1, size_mm=0.05):
        super().__init__()
        self.sphere = sphere
        v = rng.normal(size=3)
        self.v = v / np.linalg.norm(v) * size_mm

    def plate(self, ctx, tool2base):
        ds = np.zeros((ctx.n, 3, 3))
        ds[:, self.sphere, :] = self.scale * self.v
        return ds

    def params(self):
        return dict(sphere=self.sphere, displacement_mm=list(self.scale * self.v),
                    size_mm=float(np.linalg.norm(self.scale * self.v)))

    def description(self):
        return f"sphere p{self.sphere} sits off its nominal position on the plate"

    def formula(self):
        return "s_k' = s_k + delta (constant, plate frame)"

    def channel(self):
        return "constant"


# ---------------------------------------------------------------- outside any catalogue name

class MeasScaleTemp(Effect):
    kind, place = "meas", "measurement"

    def __init__(self, rng, ctx):
        super().__init__()
        self.unit = 1e-6
        self.T0 = 20.0

    def meas(self, ctx, P, tool2meas):
        f = 1 + self.scale * self.unit * (ctx.T - self.T0)
        return P * f[:, None, None]

    def params(self):
        return dict(scale_ppm_per_K=self.scale * self.unit * 1e6, T_ref_c=self.T0)

    def description(self):
        return "the instrument's length scale drifts with the temperature (its own frame, about its origin)"

    def formula(self):
        return "p_meas' = (1 + kappa (T - T_ref)) p_meas"

    def channel(self):
        return "temp_c"


class DepthBias(Effect):
    kind, place = "meas", "measurement"

    def __init__(self, rng, ctx):
        super().__init__()
        self.unit = 0.01
        self.r0 = {}

    def meas(self, ctx, P, tool2meas):
        r = np.linalg.norm(P, axis=2)
        r0 = np.zeros(ctx.n)
        for s in np.unique(ctx.station):
            r0[ctx.station == s] = ctx.station_distance[s]
        u = P / r[..., None]
        b = self.scale * self.unit * ((r - r0[:, None]) / 100.0) ** 2
        return P + b[..., None] * u

    def params(self):
        return dict(coefficient_mm_per_100mm2=self.scale * self.unit, reference="each station's nominal distance")

    def description(self):
        return "the instrument's range reading is biased quadratically with the distance from its nominal working distance (along each line of sight)"

    def formula(self):
        return "p' = p + b ((|p| - r0)/100 mm)^2 p/|p|"

    def channel(self):
        return "distance from the instrument"


class RehomeJump(Effect):
    kind, place = "joint", "joint"

    def __init__(self, rng, ctx, joint=4):
        super().__init__()
        self.joints = [joint]
        self.sign = rng.choice([-1, 1])
        self.unit = 0.01 * DEG
        self.idx = ctx.restart_idx

    def joint(self, ctx):
        dq = np.zeros((ctx.n, 6))
        dq[self.idx:, self.joints[0] - 1] = self.sign * self.scale * self.unit
        return dq

    def params(self):
        return dict(jump_deg=self.sign * self.scale * self.unit / DEG, from_row_index=int(self.idx))

    def description(self):
        return f"joint {self.joints[0]}'s zero moves after the recorded restart (encoder re-homed)"

    def formula(self):
        return "dq_j = delta for rows at and after the status=restart row, 0 before"

    def channel(self):
        return "step at the status=restart row"


class ElbowWindup(Effect):
    kind, place = "joint", "joint"

    def __init__(self, rng, ctx):
        super().__init__()
        self.joints = [3]
        self.k = rng.choice([-1, 1]) * 1e-4

    def joint(self, ctx):
        d2 = np.zeros(len(ctx.path))
        d2[1:] = np.diff(ctx.path[:, 1])
        dq = np.zeros((ctx.n, 6))
        dq[:, 2] = self.scale * self.k * d2[ctx.row_path_idx]
        return dq

    def params(self):
        return dict(kappa_rad_per_rad=self.scale * self.k)

    def description(self):
        return "the elbow (joint 3) is left wound up by the cable harness in proportion to joint 2's last move (signed size)"

    def formula(self):
        return "dq3 = kappa (q2_k - q2_previous waypoint)"

    def channel(self):
        return "signed size of joint 2's last move (history)"


class BaseSink(Effect):
    kind, place = "base", "base"

    def __init__(self, rng, ctx):
        super().__init__()
        a = rng.uniform(0, 2 * np.pi)
        self.w = np.array([np.cos(a), np.sin(a), 0.0]) * 2e-5   # rad per hour at scale 1
        self.vz = 0.01                                        # mm per hour at scale 1

    def base(self, ctx):
        h = (ctx.t - ctx.t[0]) / 3600.0
        x = np.zeros((ctx.n, 6))
        x[:, 2] = -self.scale * self.vz * h
        x[:, 3:] = self.scale * self.w[None, :] * h[:, None]
        return kin.sixdof(x)

    def params(self):
        return dict(sink_mm_per_h=self.scale * self.vz, tilt_rotvec_rad_per_h=list(self.scale * self.w))

    def description(self):
        return "the robot's base settles: it sinks and tilts slowly, linearly in time"

    def formula(self):
        return "p_base' = Trans(0,0,-v h) Rot(w h) p_base, h = hours since the first row"

    def channel(self):
        return "t_s"


class HVAC(Effect):
    kind, place = "meas", "measurement"

    def __init__(self, rng, ctx):
        super().__init__()
        v = rng.normal(size=3); v[1] *= 2
        self.A = v / np.linalg.norm(v) * 0.01
        self.w = rng.normal(size=3) * 1e-5
        self.P = rng.uniform(600, 1200)
        self.ph = rng.uniform(0, 2 * np.pi)

    def meas(self, ctx, P, tool2meas):
        s = np.sin(2 * np.pi * ctx.t / self.P + self.ph)
        R = kin.rotvec_to_R(self.scale * self.w[None, :] * s[:, None])
        return np.einsum("nij,nkj->nki", R, P) + (self.scale * self.A[None, :] * s[:, None])[:, None, :]

    def params(self):
        return dict(translation_amplitude_mm=list(self.scale * self.A), rotation_amplitude_rad=list(self.scale * self.w),
                    period_s=self.P, phase_rad=self.ph)

    def description(self):
        return "the instrument's stand sways with the air-conditioning cycle (periodic in time)"

    def formula(self):
        return "p' = R(w sin(2 pi t/P + phi)) p + A sin(2 pi t/P + phi), in the station frame"

    def channel(self):
        return "t_s (periodic)"


class ToolSlip(Effect):
    kind, place = "tool", "tool"

    def __init__(self, rng, ctx):
        super().__init__()
        self.idx = int(rng.integers(int(0.4 * ctx.n_data), int(0.65 * ctx.n_data)))
        a = rng.uniform(0, 2 * np.pi)
        self.x = np.array([0.005 * np.cos(a), 0.005 * np.sin(a), 0.0, 0.0, 0.0, rng.choice([-1, 1]) * 0.01 * DEG])

    def tool(self, ctx):
        x = np.zeros((ctx.n, 6))
        x[self.idx:] = self.scale * self.x
        return kin.sixdof(x)

    def params(self):
        return dict(from_row_index=self.idx, shift_mm=list(self.scale * self.x[:3]), turn_deg_about_flange_z=float(self.scale * self.x[5] / DEG))

    def description(self):
        return "the plate slips once on the flange (turns about the flange axis and shifts), at an unrecorded moment"

    def formula(self):
        return "tool2flange' = tool2flange @ Sixdof(delta) for rows from the slip on"

    def channel(self):
        return "hidden change point in time"


class CartesianLag(Effect):
    kind, place = "lag", "base"

    def __init__(self, rng, ctx):
        super().__init__()
        self.unit = 0.01
        pc = ctx.path_plate_centre
        d = np.zeros_like(pc)
        d[1:] = np.diff(pc, axis=0)
        nrm = np.linalg.norm(d, axis=1)
        self.u = np.where(nrm[:, None] > 1.0, d / np.maximum(nrm, 1e-9)[:, None], 0.0)

    def lag(self, ctx):
        return -self.scale * self.unit * self.u[ctx.row_path_idx]

    def params(self):
        return dict(lag_mm=self.scale * self.unit)

    def description(self):
        return "the flange has not fully arrived: it stays short of the target along the Cartesian direction of its last move"

    def formula(self):
        return "p_base' = p_base - lambda u, u = unit vector of the last move of the plate centre (base frame)"

    def channel(self):
        return "Cartesian direction of the last move (history)"


class LooseSphere(Effect):
    kind, place = "plate", "plate"

    def __init__(self, rng, ctx, sphere=2):
        super().__init__()
        self.sphere = sphere
        self.unit = 0.01

    def plate(self, ctx, tool2base):
        g = np.einsum("nji,j->ni", tool2base[:, :3, :3], np.array([0.0, 0.0, -1.0]))
        gp = g.copy(); gp[:, 2] = 0.0
        m = np.linalg.norm(gp, axis=1)
        d = gp / np.maximum(m, 0.25)[:, None]
        ds = np.zeros((ctx.n, 3, 3))
        ds[:, self.sphere, :] = self.scale * self.unit * d
        return ds

    def params(self):
        return dict(sphere=self.sphere, clearance_radius_mm=self.scale * self.unit)

    def description(self):
        return f"sphere p{self.sphere} is loose in its seat and rolls to the downhill side of its clearance (in the plate plane)"

    def formula(self):
        return "ds = c g_par / max(|g_par|, 0.25), g_par = gravity direction in the plate frame projected on the plate plane"

    def channel(self):
        return "direction of gravity in the plate frame (orientation)"


class BrakeSessions(Effect):
    kind, place = "joint", "joint"

    def __init__(self, rng, ctx, joint=2):
        super().__init__()
        self.joints = [joint]
        ns = int(ctx.session.max()) + 1
        o = rng.normal(size=ns)
        o -= o.mean()
        o /= np.sqrt(np.mean(o ** 2))
        self.o = o
        self.unit = 0.01 * DEG

    def joint(self, ctx):
        dq = np.zeros((ctx.n, 6))
        dq[:, self.joints[0] - 1] = self.scale * self.unit * self.o[ctx.session]
        return dq

    def params(self):
        return dict(offsets_deg_per_session=list(self.scale * self.unit * self.o / DEG),
                    session_rule="a new session starts after every gap > 120 s between rows")

    def description(self):
        return f"joint {self.joints[0]} settles to a new offset each time the brakes engage during a pause (idle > 120 s)"

    def formula(self):
        return "dq_j = o_s, s = index of the brake session (sessions separated by gaps > 120 s in t_s)"

    def channel(self):
        return "pauses in t_s (piecewise constant)"


class Pedestal(Effect):
    kind, place = "base", "base"

    def __init__(self, rng, ctx):
        super().__init__()
        _, self.M = gravity(ctx, 0.0)
        self.unit = 1e-6   # rad per N m at scale 1

    def base(self, ctx):
        x = np.zeros((ctx.n, 6))
        x[:, 3:5] = self.scale * self.unit * self.M[:, 0:2]
        return kin.sixdof(x)

    def params(self):
        return dict(pedestal_compliance_rad_per_nm=self.scale * self.unit,
                    max_overturning_moment_nm=float(np.max(np.linalg.norm(self.M[:, :2], axis=1))))

    def description(self):
        return "the pedestal the robot stands on tilts under the arm's overturning moment (about the base origin on the floor)"

    def formula(self):
        return "p_base' = Rot(c (M_x, M_y, 0)) p_base, M = sum_b r_b x m_b g about the base origin"

    def channel(self):
        return "overturning moment (configuration)"


class GrazingBias(Effect):
    kind, place = "meas", "measurement"

    def __init__(self, rng, ctx):
        super().__init__()
        self.unit = 0.01

    def meas(self, ctx, P, tool2meas):
        n = tool2meas[:, :3, 2]
        u = P / np.linalg.norm(P, axis=2)[..., None]
        nperp = n[:, None, :] - np.sum(n[:, None, :] * u, axis=2)[..., None] * u
        mag = np.linalg.norm(nperp, axis=2)[..., None]
        return P + self.scale * self.unit * mag * nperp

    def params(self):
        return dict(bias_mm_at_grazing=self.scale * self.unit)

    def description(self):
        return "the plate's rim hides part of each sphere at oblique views; the fitted centre moves away from the plate across the line of sight"

    def formula(self):
        return "p' = p + b |n_perp| n_perp, n_perp = plate normal minus its component along the line of sight to the sphere"

    def channel(self):
        return "viewing angle of the plate (orientation relative to the instrument)"


EFFECTS = dict(compliance=Compliance, backlash=Backlash, cyclic=Cyclic, gear_ratio=GearRatio, coupling=Coupling,
               thermal_temp=ThermalTemp, thermal_warmup=ThermalWarmup, plate_sphere=PlateSphere,
               meas_scale_temp=MeasScaleTemp, depth_bias=DepthBias, rehome=RehomeJump, elbow_windup=ElbowWindup,
               base_sink=BaseSink, hvac=HVAC, tool_slip=ToolSlip, cartesian_lag=CartesianLag,
               loose_sphere=LooseSphere, brake_sessions=BrakeSessions, pedestal=Pedestal, grazing=GrazingBias)
