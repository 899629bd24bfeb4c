"""Effects of batch C: each builds the per-row changes (kin.Mods) for an amplitude `amp`; the generator scales
`amp` so that what a geometric calibration leaves of the effect is a chosen multiple of the noise. Every effect
is linear in `amp` to first order. Millimetres, radians, seconds inside."""

from __future__ import annotations

import numpy as np

import kin

DEG = np.pi / 180.0
DN_DT = 9.3e-7  # |dn/dT| of air near 20 degC, 1/K


class Effect:
    family = None  # vocabulary name or None
    place = ""
    joints: list = []
    links: list = []
    amp = 1.0

    def mods(self, ctx, amp):
        raise NotImplementedError

    def describe(self):
        """(description, formula, channel) with the scaled values filled in."""
        raise NotImplementedError


def _lag(x, t, tau, x0=None):
    """First-order lag of a sampled signal x(t) with time constant tau (exact for piecewise-linear x)."""
    y = np.empty_like(x)
    y[0] = x[0] if x0 is None else x0
    for k in range(1, len(x)):
        a = np.exp(-(t[k] - t[k - 1]) / tau)
        y[k] = a * y[k - 1] + (1 - a) * 0.5 * (x[k] + x[k - 1])
    return y


# ----------------------------------------------------------------------------------------------- catalogue

class Compliance(Effect):
    family = "compliance"
    place = "joint"

    def __init__(self, rng, joints, payload_kg, payload_com, weights=None, label="gravity"):
        self.joints = list(joints)
        self.payload_kg = payload_kg
        self.payload_com = np.asarray(payload_com, float)
        self.weights = np.ones(len(joints)) if weights is None else np.asarray(weights, float)
        self.label = label
        self.phys_amp = 4.0 if min(self.joints) >= 4 else 1.6  # k ~ 25e3 N m/rad (wrist), ~ 60e3 N m/rad (axes 2-3)

    def _tau(self, ctx):
        masses = kin.default_masses(ctx.robot, self.payload_kg, self.payload_com)
        return kin.gravity_torques(ctx.kp_nom, ctx.q, masses) / 1000.0  # N m

    def mods(self, ctx, amp):
        m = kin.Mods(ctx.n)
        tau = self._tau(ctx)
        for j, w in zip(self.joints, self.weights):
            m.dq[:, j - 1] = amp * 1e-5 * w * tau[:, j - 1]  # amp*1e-5*w [rad/(N m)] = 1/k
        self.tau_rms = np.sqrt(np.mean(tau**2, axis=0))
        return m

    def describe(self):
        ks = {f"k{j}_nm_per_rad": float(round(1.0 / (self.amp * 1e-5 * w), -2)) for j, w in zip(self.joints, self.weights)}
        jj = ",".join(map(str, self.joints))
        desc = (
            f"joints {jj} deflect under the gravity torque of the arm and a {self.payload_kg:.1f} kg tool mass "
            f"centred at {np.round(self.payload_com, 0).tolist()} mm in the flange frame (lumped link masses, "
            f"stiffness {ks})"
        )
        form = "q_actual_j = q_cmd_j + tau_g,j(q_cmd) / k_j, tau_g from lumped masses of a 7 kg arm + payload"
        return desc, form, f"gravity torque at joints {jj}"


class Backlash(Effect):
    phys_amp = 0.9
    family = "backlash"
    place = "joint"

    def __init__(self, rng, joints, weights, angle_dependent=False):
        self.joints = list(joints)
        self.weights = np.asarray(weights, float)
        self.angle_dependent = angle_dependent
        self.kappa = float(rng.uniform(0.6, 0.85)) if angle_dependent else 0.0
        self.phi = float(rng.uniform(-np.pi, np.pi))

    def mods(self, ctx, amp):
        m = kin.Mods(ctx.n)
        for j, w in zip(self.joints, self.weights):
            size = amp * 1e-4 * w * (1 + self.kappa * np.cos(ctx.q[:, j - 1] - self.phi))
            m.dq[:, j - 1] = -size * ctx.dirs[:, j - 1]
        return m

    def describe(self):
        b = {f"b{j}_deg": float(round(self.amp * 1e-4 * w / DEG, 5)) for j, w in zip(self.joints, self.weights)}
        jj = ",".join(map(str, self.joints))
        if self.angle_dependent:
            desc = (
                f"lost motion in joint(s) {jj}: the joint stops short of the command by a half-clearance that "
                f"varies around the gear (eccentric gear mounting): b(q) = b0 (1 + {self.kappa:.2f} cos(q - "
                f"{self.phi / DEG:.0f} deg)), b0 = {b}; sign from the direction the joint last moved"
            )
            form = "q_actual_j = q_cmd_j - b0_j (1 + kappa cos(q_cmd_j - phi)) s_j, s_j = sign of the last nonzero move of joint j"
        else:
            desc = f"lost motion in joint(s) {jj}: constant half-clearance {b}, sign from the direction the joint last moved"
            form = "q_actual_j = q_cmd_j - b_j s_j, s_j = sign of the last nonzero move of joint j (from home at start)"
        return desc, form, f"direction of the last motion of joint(s) {jj}"


class Cyclic(Effect):
    phys_amp = 2.0
    family = "cyclic"
    place = "joint"

    def __init__(self, rng, terms):
        """terms: list of (joint, order, relative amplitude); phases drawn here."""
        self.terms = [(j, o, r, float(rng.uniform(-np.pi, np.pi))) for j, o, r in terms]
        self.joints = sorted({t[0] for t in terms})

    def mods(self, ctx, amp):
        m = kin.Mods(ctx.n)
        for j, o, r, ph in self.terms:
            m.dq[:, j - 1] += amp * 1e-4 * r * np.sin(o * ctx.q[:, j - 1] + ph)
        return m

    def describe(self):
        parts = [
            f"{self.amp * 1e-4 * r / DEG:.5f} deg * sin({o:g} q{j} + {ph / DEG:.0f} deg)" for j, o, r, ph in self.terms
        ]
        desc = "periodic transmission error: dq = " + " + ".join(parts)
        form = "q_actual_j = q_cmd_j + sum A sin(order * q_cmd_j + phase)"
        ch = ", ".join(f"sin/cos({o:g} q{j})" for j, o, r, ph in self.terms)
        return desc, form, ch


class GearRatio(Effect):
    phys_amp = 5.0
    family = "gear_ratio"
    place = "joint"

    def __init__(self, rng, joints, weights):
        self.joints = list(joints)
        self.weights = np.asarray(weights, float)

    def mods(self, ctx, amp):
        m = kin.Mods(ctx.n)
        for j, w in zip(self.joints, self.weights):
            m.dq[:, j - 1] = amp * 1e-4 * w * ctx.q[:, j - 1]
        return m

    def describe(self):
        e = {f"eps{j}": float(f"{self.amp * 1e-4 * w:.3e}") for j, w in zip(self.joints, self.weights)}
        jj = ",".join(map(str, self.joints))
        return (
            f"transmission ratio of joint(s) {jj} off its nominal value: relative scale errors {e}",
            "q_actual_j = (1 + eps_j) q_cmd_j",
            f"q{jj.replace(',', ', q')}",
        )


class Coupling(Effect):
    phys_amp = 3.0
    family = "coupling"
    place = "joint"

    def __init__(self, rng, driver, driven):
        self.driver, self.driven = driver, driven
        self.joints = [driver, driven]

    def mods(self, ctx, amp):
        m = kin.Mods(ctx.n)
        m.dq[:, self.driven - 1] = amp * 1e-4 * ctx.q[:, self.driver - 1]
        return m

    def describe(self):
        c = self.amp * 1e-4
        return (
            f"the drive of joint {self.driven} passes through joint {self.driver}; the controller's coupling "
            f"compensation factor is off by {c:.3e}: joint {self.driven} turns by {c:.3e} x q{self.driver}",
            f"q_actual_{self.driven} = q_cmd_{self.driven} + c q_cmd_{self.driver}",
            f"q{self.driver} -> joint {self.driven}",
        )


class ThermalAmbient(Effect):
    phys_amp = 2.3
    family = "thermal"
    place = "length"

    def __init__(self, rng, links, tau_s, t_ref=20.0):
        self.link_idx = links  # list of (name, kp index)
        self.links = [n for n, _ in links]
        self.tau = tau_s
        self.t_ref = t_ref

    def mods(self, ctx, amp):
        m = kin.Mods(ctx.n)
        T_link = _lag(ctx.temp, ctx.t, self.tau, x0=ctx.temp[0] - 0.3)
        self.T_link = T_link
        for name, i in self.link_idx:
            L = ctx.kp_nom[i]
            m.dkp[:, i] = amp * 1e-5 * L * (T_link - self.t_ref)
        return m

    def describe(self):
        a = self.amp * 1e-5
        return (
            f"links {', '.join(self.links)} grow with the arm's temperature, which follows the cell air "
            f"temperature with a {self.tau:.0f} s lag; growth coefficient {a:.2e} /K (reference {self.t_ref} degC)",
            "L(t) = L_nom (1 + alpha (T_link(t) - T_ref)), T_link = first-order lag of the air temperature",
            f"temp_c lagged {self.tau:.0f} s",
        )


class ThermalMotors(Effect):
    phys_amp = 5.0
    """Links warmed by the motors themselves: holding current from servo-on plus heat per radian moved."""

    family = "thermal"
    place = "length"

    def __init__(self, rng, tau_u, tau_f, alpha=23e-6):
        self.links = ["a3", "d4"]
        self.tau_u, self.tau_f = tau_u, tau_f
        self.alpha = alpha
        self.hold_share = float(rng.uniform(0.35, 0.55))
        self.fore_share = float(rng.uniform(0.6, 0.9))

    def _dT(self, t, moves, tau):
        # dT/dt = (P(t) - dT) / tau with P = hold + motion heat; exact discrete update per row
        y = np.zeros(len(t))
        prev_t, cur = 0.0, 0.0
        hold = self.hold_share
        for k in range(len(t)):
            a = np.exp(-(t[k] - prev_t) / tau)
            cur = a * cur + (1 - a) * hold + moves[k] * (1 - self.hold_share) / tau * 40.0
            y[k] = cur
            prev_t = t[k]
        return y

    def mods(self, ctx, amp):
        m = kin.Mods(ctx.n)
        mv_u = np.abs(ctx.step[:, 1]) + np.abs(ctx.step[:, 2])
        mv_f = np.abs(ctx.step[:, 2]) + np.abs(ctx.step[:, 3]) + np.abs(ctx.step[:, 4]) + np.abs(ctx.step[:, 5])
        su = self._dT(ctx.t, mv_u, self.tau_u)
        sf = self._dT(ctx.t, mv_f, self.tau_f)
        self.dTu = amp * su / np.max(su[ctx.data_rows])  # amp = peak rise of the upper arm over the dataset [K]
        self.dTf = amp * self.fore_share * sf / np.max(sf[ctx.data_rows])
        m.dkp[:, kin.I_A + 2] = self.alpha * ctx.kp_nom[kin.I_A + 2] * self.dTu
        m.dkp[:, kin.I_D + 3] = self.alpha * ctx.kp_nom[kin.I_D + 3] * self.dTf
        return m

    def describe(self):
        return (
            "the upper arm (a3) and forearm (d4) warm up from the robot's own motors after servo-on (t_s = 0 at "
            "servo-on): a holding-current share plus heat proportional to the joint travel of each move "
            f"(joints 2-3 heat the upper arm, 3-6 the forearm); time constants {self.tau_u:.0f} s and "
            f"{self.tau_f:.0f} s; linear expansion {self.alpha:.1e} /K; peak link temperature rise "
            f"{np.max(self.dTu):.2f} K (upper arm), {np.max(self.dTf):.2f} K (forearm); the recorded temp_c "
            "is the cell air and does not show it",
            "dT_link' = (P_hold + c |dq| per move - dT_link) / tau; L = L_nom (1 + alpha dT_link)",
            "commanded joint travel history (motor heating), time since servo-on",
        )


class PlateSphere(Effect):
    phys_amp = 10.0
    family = "plate_geometry"
    place = "plate"

    def __init__(self, rng, sphere):
        self.sphere = sphere
        u = rng.normal(size=3)
        self.u = u / np.linalg.norm(u)

    def mods(self, ctx, amp):
        m = kin.Mods(ctx.n)
        m.plate[:, self.sphere, :] = amp * 0.01 * self.u
        return m

    def describe(self):
        v = np.round(self.amp * 0.01 * self.u, 4).tolist()
        return (
            f"sphere p{self.sphere} sits {np.linalg.norm(v):.4f} mm off its nominal centre on the plate, "
            f"offset {v} mm in the plate frame (re-glued stem)",
            "s_k,true = s_k,nominal + delta (one sphere)",
            f"sphere {self.sphere}",
        )


# ----------------------------------------------------------------------------------------------- outside the vocabulary

class TripodSettle(Effect):
    phys_amp = 10.0
    place = "measurement"

    def __init__(self, rng, n_stations):
        self.tau = float(rng.uniform(700, 1500))
        # pivot: feet of the tripod, ~1.1-1.4 m below the instrument (OpenCV y points down), axis ~ camera x
        self.pivots = [np.array([rng.uniform(-150, 150), rng.uniform(1100, 1400), rng.uniform(-100, 250)]) for _ in range(n_stations)]
        ax = [np.array([1.0, rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3)]) for _ in range(n_stations)]
        self.axes = [a / np.linalg.norm(a) for a in ax]
        self.signs = [float(rng.choice([-1, 1])) for _ in range(n_stations)]

    def mods(self, ctx, amp):
        m = kin.Mods(ctx.n)
        m.meas = np.tile(np.eye(4), (ctx.n, 1, 1))
        for s in range(ctx.n_stations):
            rows = ctx.st == s
            if not rows.any():
                continue
            ang = self.signs[s] * amp * 1e-5 * (1 - np.exp(-(ctx.t[rows] - ctx.setup_t[s]) / self.tau))
            m.meas[rows] = kin.rot_about_axis_through(self.axes[s], ang, self.pivots[s])
        return m

    def describe(self):
        a = self.amp * 1e-5
        return (
            "the instrument's tripod settles after each set-up (a foot sinking into the floor mat): the "
            f"instrument tilts about an axis through the feet ~1.2 m below it by up to {a / DEG * 3600:.1f} arcsec, "
            f"exponentially with time constant {self.tau:.0f} s from the station's set-up time",
            "base2meas(t) = Rot(axis through foot pivot, theta_inf (1 - exp(-(t - t_setup)/tau))) base2meas",
            "t_s since the station was set up",
        )


class BarWarmup(Effect):
    phys_amp = 50.0
    place = "measurement"

    def __init__(self, rng, baseline_mm=250.0):
        self.tau = float(rng.uniform(1200, 2400))
        self.B = baseline_mm
        self.t_on = float(rng.uniform(-300, -60))  # instrument switched on before t_s = 0

    def mods(self, ctx, amp):
        m = kin.Mods(ctx.n)
        dphi = amp * 1e-6 * (1 - np.exp(-(ctx.t - self.t_on) / self.tau))

        def f(p, dphi=dphi):
            r = np.linalg.norm(p, axis=2, keepdims=True)
            return p * (1 - r * dphi[:, None, None] / self.B)

        m.fields.append(f)
        return m

    def describe(self):
        return (
            "the stereo bar warms up after switch-on and bends: the cameras' convergence drifts by up to "
            f"{self.amp * 1e-6 * 1e6:.1f} urad (time constant {self.tau:.0f} s), so every point slides along its "
            f"line of sight by -r^2 dphi / B (baseline {self.B:.0f} mm)",
            "p' = p (1 - |p| dphi(t) / B), dphi(t) = dphi_inf (1 - exp(-(t - t_on)/tau))",
            "t_s and distance from the instrument",
        )


class LensDistortion(Effect):
    phys_amp = 5.0
    place = "measurement"

    def __init__(self, rng, gamma=None):
        self.gamma = float(rng.uniform(0.5, 1.2)) if gamma is None else gamma
        self.sign = float(rng.choice([-1, 1]))

    def mods(self, ctx, amp):
        m = kin.Mods(ctx.n)
        k = self.sign * amp * 1e-4

        def f(p, k=k):
            rho2 = (p[..., 0] ** 2 + p[..., 1] ** 2) / p[..., 2] ** 2
            d = np.stack([p[..., 0], p[..., 1], -self.gamma * p[..., 2]], axis=-1) * (k * rho2)[..., None]
            return p + d

        m.fields.append(f)
        return m

    def describe(self):
        k = self.sign * self.amp * 1e-4
        return (
            "radial lens distortion left over by the instrument's own calibration: points are displaced "
            f"radially by k rho^2 (k = {k:.2e}, rho = image radius in normalised coordinates) and the "
            f"triangulated depth by -{self.gamma:.2f} k rho^2 z",
            "x' = x (1 + k rho^2), y' = y (1 + k rho^2), z' = z (1 - g k rho^2), rho^2 = (x^2 + y^2)/z^2",
            "position in the instrument's field of view",
        )


class TripodBump(Effect):
    phys_amp = 15.0
    place = "measurement"

    def __init__(self, rng, t_frac=None, station=-1):
        self.t_frac = float(rng.uniform(0.35, 0.65)) if t_frac is None else t_frac
        self.station = station
        ax = rng.normal(size=3)
        self.axis = ax / np.linalg.norm(ax)
        self.head = np.array([0.0, rng.uniform(150, 300), rng.uniform(-150, 0)])  # tripod head, below the camera
        self.trans = rng.normal(0, 0.5, 3)

    def mods(self, ctx, amp):
        m = kin.Mods(ctx.n)
        s_idx = self.station % ctx.n_stations
        rows = np.flatnonzero(ctx.data_rows & (ctx.st == s_idx))
        k = rows[int(self.t_frac * (len(rows) - 1))]
        self.t_bump = float(0.5 * (ctx.t[k] + ctx.t[k + 1]))
        after = (ctx.t >= self.t_bump) & (ctx.st == s_idx)
        T = np.tile(np.eye(4), (ctx.n, 1, 1))
        R = kin.rot_about_axis_through(self.axis, np.array([amp * 1e-5]), self.head)[0]
        R[:3, 3] += amp * 1e-2 * self.trans
        T[after] = R
        m.meas = T
        return m

    def describe(self):
        return (
            f"someone knocked the instrument's tripod at t_s = {self.t_bump:.0f} s: the instrument turned by "
            f"{self.amp * 1e-5 / DEG * 3600:.1f} arcsec about an axis through the tripod head and shifted by "
            f"{np.round(self.amp * 1e-2 * self.trans, 4).tolist()} mm; it stayed there",
            "base2meas(t) = D base2meas for t >= t_bump, D a fixed small rigid motion",
            "t_s (a step)",
        )


class SpecularBias(Effect):
    """A work lamp near the cell: each sphere's fitted centre is pulled toward its specular highlight."""

    place = "measurement"
    phys_amp = 3.0

    def __init__(self, rng, radius_mm):
        self.R = radius_mm
        # lamp in the instrument frame: beside and above the line of sight, 350-600 mm from the working region
        self.side = float(rng.choice([-1, 1]))
        self.lamp_u = (self.side * rng.uniform(0.5, 0.8), -rng.uniform(0.3, 0.6), rng.uniform(0.55, 0.8))
        self.dist = float(rng.uniform(350, 600))

    def mods(self, ctx, amp):
        m = kin.Mods(ctx.n)
        beta = amp * 0.01
        lamps = []
        for s in range(ctx.n_stations):
            rows = ctx.data_rows & (ctx.st == s)
            c = np.zeros(3)
            if rows.any():
                c = np.mean(ctx.c_nom[rows].reshape(-1, 3), axis=0)
            lamps.append(np.array([c[0], c[1], 0.0]) + np.array(self.lamp_u) * np.array([self.dist, self.dist, c[2] * 0.5]) / np.linalg.norm(self.lamp_u))
        self.lamps = lamps
        L = np.stack([lamps[int(s)] for s in ctx.st])

        def f(p, L=L, beta=beta):
            v = -p / np.linalg.norm(p, axis=2, keepdims=True)
            l = L[:, None, :] - p
            l /= np.linalg.norm(l, axis=2, keepdims=True)
            h = v + l
            h /= np.linalg.norm(h, axis=2, keepdims=True)
            lat = h - np.einsum("nki,nki->nk", h, v)[..., None] * v
            return p + beta * self.R * lat

        m.fields.append(f)
        return m

    def describe(self):
        return (
            "a work lamp beside the instrument makes a specular highlight on each sphere; the sphere-centre fit "
            f"is pulled toward it by {self.amp * 0.01 * 100:.1f} % of the highlight's offset from the centre in the "
            f"image (sphere radius {self.R:.2f} mm); the highlight sits where the sphere normal bisects the "
            "directions to the lamp and to the instrument, so the pull changes across the working volume",
            "p' = p + beta R lateral(h), h = unit(v + l), v = unit(camera - p), l = unit(lamp - p), lateral = component across the line of sight",
            "sphere position relative to the lamp and the instrument",
        )


class RockingBase(Effect):
    phys_amp = 20.0
    place = "base"

    def __init__(self, rng):
        self.psi = float(rng.uniform(-np.pi, np.pi))
        self.edge = float(rng.uniform(150, 200))
        self.sharp = float(rng.uniform(0.15, 0.3))

    def mods(self, ctx, amp):
        m = kin.Mods(ctx.n)
        c = self.edge * np.array([np.cos(self.psi), np.sin(self.psi), 0.0])
        u = np.array([-np.sin(self.psi), np.cos(self.psi), 0.0])
        masses = kin.default_masses(ctx.robot, 1.0, (0, 0, 40)) + [(1, (0.0, 0.0, -0.3 * ctx.kp_nom[kin.I_D]), 8.0)]
        frames = kin.fk_frames(ctx.kp_nom, ctx.q)
        M = np.zeros(ctx.n)
        g = np.array([0, 0, -9.81])
        for link, pt, mass in masses:
            T = frames[link - 1]
            pw = T[:, :3, :3] @ np.asarray(pt, float) + T[:, :3, 3]
            M += np.cross(pw - c, mass * g) @ u
        M /= 1000.0
        ref = ctx.data_rows & ctx.has_meas
        mc = np.median(M[ref])
        w = self.sharp * (np.percentile(M[ref], 75) - np.percentile(M[ref], 25))
        self.M_c, self.M_w = mc, w
        theta = amp * 1e-5 / (1 + np.exp(-(M - mc) / w))
        m.base = kin.rot_about_axis_through(u, theta, c)
        return m

    def describe(self):
        return (
            "an anchor bolt of the robot's pedestal is loose: when the arm's weight moment about the front edge "
            f"(azimuth {self.psi / DEG:.0f} deg, {self.edge:.0f} mm from axis 1) exceeds the bolt preload the "
            f"base rocks onto that edge, by up to {self.amp * 1e-5 / DEG * 3600:.1f} arcsec (smooth step, width "
            f"{self.M_w:.1f} N m around {self.M_c:.1f} N m)",
            "base tilt = theta_max / (1 + exp(-(M(q) - M_c)/w)) about the edge line; M = moment of the arm's "
            "weight about the edge",
            "configuration (overturning moment about a pedestal edge)",
        )


class SettleLag(Effect):
    phys_amp = 20.0
    place = "joint"

    def __init__(self, rng, joints, weights):
        self.joints = list(joints)
        self.weights = np.asarray(weights, float)

    def mods(self, ctx, amp):
        m = kin.Mods(ctx.n)
        for j, w in zip(self.joints, self.weights):
            m.dq[:, j - 1] = -amp * 1e-5 * w * ctx.step[:, j - 1]
        return m

    def describe(self):
        lam = {f"lambda{j}": float(f"{self.amp * 1e-5 * w:.2e}") for j, w in zip(self.joints, self.weights)}
        jj = ",".join(map(str, self.joints))
        return (
            f"the capture is triggered by the controller's 'in position' signal before joints {jj} have settled: "
            f"each joint is still short of its target by a fraction of the step it just made {lam} (no step, no "
            "lag: a repeat without motion is settled)",
            "q_actual_j = q_cmd_j - lambda_j (q_cmd_j[k] - q_cmd_j[k-1])",
            f"last joint step of joints {jj}",
        )


class PlateRemount(Effect):
    phys_amp = 2.0
    place = "tool"

    def __init__(self, rng, fracs=None):
        self.fracs = sorted(rng.uniform(0.2, 0.85, 2)) if fracs is None else fracs
        self.v = [np.r_[rng.normal(0, 1, 2), rng.normal(0, 0.2), rng.normal(0, 1e-4, 2), rng.normal(0, 4e-4)] for _ in self.fracs]

    def mods(self, ctx, amp):
        m = kin.Mods(ctx.n)
        td = ctx.t[ctx.data_rows]
        self.times = [float(td[0] + f * (td[-1] - td[0])) for f in self.fracs]
        T = np.tile(np.eye(4), (ctx.n, 1, 1))
        for tm, v in zip(self.times, self.v):
            after = ctx.t >= tm
            T[after] = kin.pose6(amp * 0.01 * v)  # each re-mount replaces the previous seating
        m.tool = T
        return m

    def describe(self):
        segs = [np.round(self.amp * 0.01 * v[:3], 4).tolist() for v in self.v]
        rots = [round(float(self.amp * 0.01 * np.linalg.norm(v[3:])) / DEG * 3600, 1) for v in self.v]
        return (
            "the plate was taken off (sphere cleaning) and put back twice, at t_s = "
            f"{', '.join(f'{t:.0f}' for t in self.times)} s; its locating pins leave play, so it re-seats each time "
            f"at a slightly different place: shifts {segs} mm, turns {rots} arcsec relative to the first seating",
            "tool2flange(t) = D_k tool2flange for t in segment k (D_0 = I)",
            "t_s (steps at the re-mount times)",
        )


class RestartOffset(Effect):
    phys_amp = 8.7
    place = "joint"

    def __init__(self, rng, joint=3):
        self.joints = [joint]
        self.j = joint
        self.w = [1.0, float(rng.choice([-1, 1]) * rng.uniform(0.6, 1.4))]

    def mods(self, ctx, amp):
        m = kin.Mods(ctx.n)
        off = np.zeros(ctx.n)
        self.times = []
        for r, w in zip(ctx.restart_rows, self.w):
            off[r:] += amp * 1e-5 * w
            self.times.append(float(ctx.t[r]))
        m.dq[:, self.j - 1] = off
        return m

    def describe(self):
        steps = [float(round(self.amp * 1e-5 * w / DEG, 5)) for w in self.w]
        return (
            f"after each controller restart the joint-{self.j} resolver count is re-synchronised a few counts off: "
            f"the joint's zero jumps by {steps} deg at the restarts (t_s = "
            f"{', '.join(f'{t:.0f}' for t in self.times)} s)",
            f"q_actual_{self.j} = q_cmd_{self.j} + sum_r delta_r [t >= t_restart_r]",
            "restart events (status rows) / t_s steps",
        )
