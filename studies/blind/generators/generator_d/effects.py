"""Effects that act on the true cell, each with its own physical formula (mm, rad, s, degC inside).

Every effect has a scalar `scale` multiplying its amplitude parameter(s); the campaign builder sets it so that
the effect alone contributes a drawn RMS at the spheres. Hooks (all optional):
  dq(ctx)                  -> (n, 6) joint offsets added to the commanded joints [rad]
  params(ctx, P)           -> per-row geometry (dict of (n, 6) arrays)
  tool(ctx, T, S)          -> per-row tool2flange (n,4,4) and sphere centres in the tool frame (n,3,3)
  base(ctx, B)             -> per-row base2meas (n,4,4)
  meas(ctx, pts, aux)      -> measured-frame sphere centres (n,3,3) (instrument effects)
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from kin import DEG, apply_T, copy_params, link_frames

G = 9.81


def rigid(rotvec, trans):
    """(n,4,4) from (n,3) rotation vectors [rad] and (n,3) translations [mm]."""
    rotvec = np.atleast_2d(rotvec)
    trans = np.atleast_2d(trans)
    n = max(len(rotvec), len(trans))
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.from_rotvec(np.array(np.broadcast_to(rotvec, (n, 3)))).as_matrix()
    T[:, :3, 3] = np.broadcast_to(trans, (n, 3))
    return T


def about_point(T, pivot):
    """rigid motion T applied about a pivot point (both in the same frame)."""
    P = np.eye(4)
    P[:3, 3] = pivot
    Pi = np.eye(4)
    Pi[:3, 3] = -pivot
    return P[None] @ T @ Pi[None]


class Effect:
    family = "unnamed"  # catalogue family or 'unnamed'
    place = "joint"
    channel = ""
    joints: list = []
    links: list = []
    label = ""

    def __init__(self):
        self.scale = 1.0

    def dq(self, ctx):
        return None

    def params(self, ctx, P):
        return P

    def tool(self, ctx, T, S):
        return T, S

    def base(self, ctx, B):
        return B

    def meas(self, ctx, pts, aux):
        return pts

    def description(self) -> str:
        return self.label

    def formula(self) -> str:
        return ""


# ----------------------------------------------------------------------------------------------------------
# mass model shared by the gravity / cable effects: lumped masses in link frames (mm, kg)
MASSES = [
    # (frame index, kg, centre in that frame [mm])
    (2, 6.5, np.array([170.0, 0.0, 25.0])),  # upper arm, along a3 in frame 2
    (3, 4.0, np.array([30.0, 60.0, 0.0])),  # elbow housing with wrist motors (frame 3)
    (4, 1.6, np.array([0.0, 0.0, -120.0])),  # forearm tube (frame 4, behind the wrist centre)
    (5, 0.9, np.array([0.0, 0.0, 0.0])),  # wrist
    (6, 0.45, np.array([0.0, 0.0, 30.0])),  # flange, adapter and the sphere plate
]


def gravity_torques(frames, extra=()):
    """(n, 6) gravity torque about each joint axis [N m] (sign: torque on the outboard chain)."""
    n = frames.shape[0]
    g = np.array([0.0, 0.0, -G])
    tau = np.zeros((n, 6))
    bodies = list(MASSES) + list(extra)
    for fi, m, c in bodies:
        cb = apply_T(frames[:, fi], c[None, None].repeat(n, 0))[:, 0] / 1000.0  # m
        F = m * g
        for j in range(fi):  # joint j+1 (frame j+1) carries bodies on frames >= j+1
            o = frames[:, j + 1, :3, 3] / 1000.0
            z = frames[:, j + 1, :3, 2]
            tau[:, j] += np.einsum("ni,ni->n", z, np.cross(cb - o, F))
    return tau


class Compliance(Effect):
    family = "compliance"
    place = "joint"
    channel = "gravity torque about joints 2, 3, 5 (configuration)"

    def __init__(self, rng, payload_kg=0.0):
        super().__init__()
        # nominal torsional stiffness [N m / rad]; divided by `scale`
        self.k = np.array([np.inf, 1.6e5, 9.0e4, np.inf, 2.2e4, np.inf]) * rng.uniform(0.8, 1.25, 6)
        self.payload = payload_kg
        self.payload_com = np.array([rng.uniform(-20, 20), rng.uniform(-20, 20), rng.uniform(40, 90)])
        self.joints = [2, 3, 5]
        self.links = [2, 3, 5]

    def dq(self, ctx):
        fr = link_frames(ctx["P"], ctx["q"])
        extra = [(6, self.payload, self.payload_com)] if self.payload > 0 else []
        tau = gravity_torques(fr, extra)
        return self.scale * tau / self.k

    def stiffness(self):
        return self.k / self.scale

    def description(self):
        k = self.stiffness()
        s = f"joint compliance under gravity: joints 2, 3, 5 deflect by tau_j/k_j, k = {k[1]:.3g}, {k[2]:.3g}, {k[4]:.3g} N m/rad"
        if self.payload > 0:
            s += f"; extra payload {self.payload:.2f} kg at {np.round(self.payload_com, 1).tolist()} mm in the flange frame"
        return s

    def formula(self):
        return ("q_act_j = q_cmd_j + tau_j(q_cmd)/k_j, tau_j = z_j . sum_b (c_b - o_j) x (m_b g) over lumped link masses "
                "(upper arm 6.5 kg, elbow 4.0, forearm 1.6, wrist 0.9, plate 0.45 kg" + (" + payload" if self.payload else "") + ")")


class Backlash(Effect):
    family = "backlash"
    place = "joint"

    def __init__(self, rng, joints=(1,), half_deg=(0.012,)):
        super().__init__()
        self.joints = list(joints)
        self.links = list(joints)
        self.h = np.array(half_deg) * DEG
        self.channel = "approach direction of joint " + ", ".join(str(j) for j in joints)

    def dq(self, ctx):
        out = np.zeros_like(ctx["q"])
        for j, h in zip(self.joints, self.h):
            out[:, j - 1] = self.scale * h * ctx["approach"][:, j - 1]
        return out

    def description(self):
        return "backlash (lost motion): half clearance " + ", ".join(
            f"{h * self.scale / DEG:.4f} deg on joint {j}" for j, h in zip(self.joints, self.h)) + \
            "; the joint lags on the side it approached from; the robot starts from home q = (0, 0, 0, 0, 30, 0) deg"

    def formula(self):
        return "q_act_j = q_cmd_j + b_j * s_j, s_j = sign of the last non-zero move of joint j (from home before the first row)"


class Cyclic(Effect):
    family = "cyclic"
    place = "joint"

    def __init__(self, rng, joint=2, orders=(2,), amps_deg=(0.008,)):
        super().__init__()
        self.joints = [joint]
        self.links = [joint]
        self.orders = list(orders)
        self.amps = np.array(amps_deg) * DEG
        self.phases = rng.uniform(-np.pi, np.pi, len(orders))
        self.channel = ", ".join(f"sin/cos({o} q{joint})" for o in orders)

    def dq(self, ctx):
        out = np.zeros_like(ctx["q"])
        qj = ctx["q"][:, self.joints[0] - 1]
        for o, a, ph in zip(self.orders, self.amps, self.phases):
            out[:, self.joints[0] - 1] += self.scale * a * np.sin(o * qj + ph)
        return out

    def description(self):
        return f"cyclic transmission error of joint {self.joints[0]}: " + ", ".join(
            f"order {o}: {a * self.scale / DEG:.4f} deg, phase {ph / DEG:.1f} deg" for o, a, ph in zip(self.orders, self.amps, self.phases))

    def formula(self):
        j = self.joints[0]
        return f"q_act_{j} = q_cmd_{j} + sum_h A_h sin(n_h q_cmd_{j} + phi_h)"


class GearRatio(Effect):
    family = "gear_ratio"
    place = "joint"

    def __init__(self, rng, joints=(3,), eps=(3e-4,)):
        super().__init__()
        self.joints = list(joints)
        self.links = list(joints)
        self.eps = np.array(eps)
        self.channel = ", ".join(f"q{j}" for j in joints)

    def dq(self, ctx):
        out = np.zeros_like(ctx["q"])
        for j, e in zip(self.joints, self.eps):
            out[:, j - 1] = self.scale * e * ctx["q"][:, j - 1]
        return out

    def description(self):
        return "gear ratio error: joint reading scaled, " + ", ".join(
            f"q{j} x (1 {'+' if e * self.scale >= 0 else '-'} {abs(e * self.scale):.2e})" for j, e in zip(self.joints, self.eps))

    def formula(self):
        return "q_act_j = (1 + eps_j) q_cmd_j (about the joint's zero)"


class Coupling(Effect):
    family = "coupling"
    place = "joint"

    def __init__(self, rng, driving=4, driven=5, c=1e-3):
        super().__init__()
        self.driving, self.driven, self.c = driving, driven, c
        self.joints = [driving, driven]
        self.links = [driven]
        self.channel = f"q{driving} -> q{driven}"

    def dq(self, ctx):
        out = np.zeros_like(ctx["q"])
        out[:, self.driven - 1] = self.scale * self.c * ctx["q"][:, self.driving - 1]
        return out

    def description(self):
        return f"joint coupling: joint {self.driven} turns by {self.c * self.scale:.2e} x q{self.driving} (uncompensated wrist gear train)"

    def formula(self):
        return f"q_act_{self.driven} = q_cmd_{self.driven} + c q_cmd_{self.driving}"


class Thermal(Effect):
    family = "thermal"
    place = "length"

    def __init__(self, rng, alpha=2.3e-5, links=("d1", "a3", "a4", "d4", "d6"), source="T_robot"):
        super().__init__()
        self.alpha = alpha
        self.links = list(links)
        self.joints = []
        self.source = source
        self.channel = "temperature of the arm (temp_c, lagging the duty)"

    def params(self, ctx, P):
        n = ctx["q"].shape[0]
        dT = ctx[self.source] - ctx["T_ref"]
        Q = copy_params(P)
        for k in ("a", "d"):
            Q[k] = np.tile(np.asarray(P[k], float), (n, 1))
        for name in self.links:
            k, i = name[0], int(name[1]) - 1
            Q[k][:, i] = Q[k][:, i] * (1.0 + self.scale * self.alpha * dT)
        return Q

    def description(self):
        return (f"thermal growth of the links {', '.join(self.links)}: L = L0 (1 + alpha (T - T_ref)), alpha = "
                f"{self.alpha * self.scale:.3g} /K, T the arm temperature")

    def formula(self):
        return "L_i(t) = L_i (1 + alpha (T_arm(t) - T_ref)), T_arm: first-order response to the duty (heats while running, cools in pauses)"


class PlateGeometry(Effect):
    family = "plate_geometry"
    place = "plate"

    def __init__(self, rng, sphere=1, delta_mm=(0.15, -0.1, 0.08)):
        super().__init__()
        self.sphere = sphere
        self.delta = np.array(delta_mm, float)
        self.joints = []
        self.links = [f"sphere{sphere}"]
        self.channel = "constant (plate frame)"

    def tool(self, ctx, T, S):
        S = S.copy()
        S[:, self.sphere] += self.scale * self.delta
        return T, S

    def description(self):
        d = self.delta * self.scale
        return f"plate geometry: sphere p{self.sphere} sits {np.round(d, 4).tolist()} mm off its nominal place (plate frame), not seated in its cup"

    def formula(self):
        return f"s_{self.sphere} = s_{self.sphere},nominal + delta (in the plate frame); the other spheres unchanged"


# ---------------------------------------------------------------- outside the catalogue ----------------------

class CableDrag(Effect):
    """A process cable hanging from a boom pulls the forearm once it is stretched beyond its slack length."""
    place = "joint"
    channel = "configuration: stretch of a cable from a fixed anchor to the forearm (hinge)"

    def __init__(self, rng, anchor=None, slack_quantile=0.45):
        super().__init__()
        self.anchor = anchor if anchor is not None else np.array([rng.uniform(-300, 0), rng.uniform(-450, 450), rng.uniform(1300, 1700)])
        self.attach = np.array([0.0, -60.0, -200.0])  # frame 4: on top of the forearm behind the wrist
        self.kc = 4.0  # N/mm of stretch (elastic cable + balancer spring); times scale
        self.k = np.array([3.0e5, 1.6e5, 9.0e4, 1e12, 1e12, 1e12])
        self.q_slack = slack_quantile
        self.L0 = None
        self.joints = [1, 2, 3]
        self.links = [1, 2, 3]

    def _geom(self, ctx):
        fr = link_frames(ctx["P"], ctx["q"])
        n = fr.shape[0]
        P = apply_T(fr[:, 4], self.attach[None, None].repeat(n, 0))[:, 0]
        L = np.linalg.norm(self.anchor - P, axis=1)
        return fr, P, L

    def dq(self, ctx):
        fr, P, L = self._geom(ctx)
        if self.L0 is None:
            self.L0 = float(np.quantile(L[: ctx["n_data"]], self.q_slack))
        stretch = np.maximum(0.0, L - self.L0)
        u = (self.anchor - P) / L[:, None]
        F = (self.scale * self.kc * stretch)[:, None] * u  # N
        out = np.zeros_like(ctx["q"])
        for j in range(3):
            o = fr[:, j + 1, :3, 3]
            z = fr[:, j + 1, :3, 2]
            tau = np.einsum("ni,ni->n", z, np.cross((P - o) / 1000.0, F))
            out[:, j] = tau / self.k[j]
        return out

    def description(self):
        return (f"process cable from a boom anchor at {np.round(self.anchor, 0).tolist()} mm (base frame) to the forearm; "
                f"beyond its slack length {self.L0:.0f} mm it pulls with {self.kc * self.scale:.2f} N/mm, deflecting joints 1-3 "
                "through their stiffness (3e5, 1.6e5, 9e4 N m/rad)")

    def formula(self):
        return ("F = k_c max(0, |A - P(q)| - L0) (A - P)/|A - P|, P = attachment on the forearm (frame 4); "
                "q_act_j = q_cmd_j + z_j.((P - o_j) x F)/k_j, j = 1..3")


class CameraCreep(Effect):
    """The tripod head of the rig sags slowly after it was set up: a rotation about a pivot below the cameras."""
    place = "measurement"
    channel = "t_s (1 - exp(-t/tau) + slow linear creep)"

    def __init__(self, rng, stations=(0,)):
        super().__init__()
        self.tau = rng.uniform(1200, 3600)
        self.rate = rng.uniform(0.2, 0.6)  # linear part relative to the saturating part per tau
        ax = np.array([1.0, rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2)])
        self.axis = ax / np.linalg.norm(ax)
        self.theta = 0.01 * DEG
        self.pivot = np.array([125.0, 180.0, -40.0])  # tripod head below the rig centre, left camera frame
        self.stations = list(stations)
        self.joints, self.links = [], ["base2meas"]

    def shape(self, t):
        return (1 - np.exp(-t / self.tau)) + self.rate * t / self.tau

    def base(self, ctx, B):
        ang = self.scale * self.theta * self.shape(ctx["t"])
        M = rigid(ang[:, None] * self.axis[None], np.zeros(3))
        M = about_point(M, self.pivot)
        B = B.copy()
        sel = np.isin(ctx["station"], self.stations)
        B[sel] = M[sel] @ B[sel]
        return B

    def description(self):
        return (f"camera tripod head creeps after set-up: the rig turns about a pivot {self.pivot.tolist()} mm (left camera frame), "
                f"axis {np.round(self.axis, 3).tolist()}, angle {self.theta * self.scale / DEG:.4f} deg x shape(t)")

    def formula(self):
        return f"base2meas(t) = Rot(axis, A (1 - exp(-t/{self.tau:.0f} s) + {self.rate:.2f} t/{self.tau:.0f} s)) about the pivot . base2meas(0)"


class Settling(Effect):
    """Residual ringing of the arm: the capture comes a fixed dwell after arrival, before the first mode died out."""
    place = "joint"
    channel = "previous move: joint steps q_k - q_(k-1)"

    def __init__(self, rng):
        super().__init__()
        self.f = rng.uniform(6, 11)  # Hz
        self.zeta = rng.uniform(0.03, 0.07)
        self.dwell = rng.uniform(0.35, 0.6)  # s
        w = 2 * np.pi * self.f
        self.factor = np.exp(-self.zeta * w * self.dwell) * np.cos(w * np.sqrt(1 - self.zeta ** 2) * self.dwell)
        self.weights = np.array([1.0, 1.0, 0.8, 0.3, 0.3, 0.2]) * 2e-3
        self.joints, self.links = [1, 2, 3, 4, 5, 6], [1, 2, 3]

    def dq(self, ctx):
        return -self.scale * self.factor * self.weights[None] * ctx["dq_prev"]

    def description(self):
        return (f"unsettled arm at capture: the first mode ({self.f:.1f} Hz, zeta {self.zeta:.3f}) excited by each move "
                f"is still ringing {self.dwell:.2f} s after arrival; joint lag proportional to the last joint step")

    def formula(self):
        return ("q_act_j = q_cmd_j - s w_j exp(-zeta omega t_d) cos(omega_d t_d) (q_cmd_j[k] - q_cmd_j[k-1]), "
                f"w = {np.round(self.weights * self.scale, 6).tolist()}")


class HolderOcclusion(Effect):
    """The sphere's holder post hides part of the silhouette when the plate is tilted: the fitted centre moves away."""
    place = "measurement"
    channel = "plate tilt to the line of sight (n - (n.v)v)"

    def __init__(self, rng):
        super().__init__()
        self.k = 0.1  # mm per unit sin(tilt)
        self.joints, self.links = [], ["measurement"]

    def meas(self, ctx, pts, aux):
        n = aux["normal"][:, None, :]  # plate normal in meas
        v = pts / np.linalg.norm(pts, axis=2, keepdims=True)
        perp = n - np.sum(n * v, axis=2, keepdims=True) * v
        return pts + self.scale * self.k * perp

    def description(self):
        return (f"sphere holders occlude the silhouette's plate side when the plate is tilted: each measured centre "
                f"shifts by {self.k * self.scale:.3f} mm x the plate normal's component across the line of sight")

    def formula(self):
        return "m_i = p_i + k (n - (n.v_i) v_i), n = plate normal, v_i = unit line of sight of sphere i (left camera)"


class CameraBump(Effect):
    """The rig was knocked during a pause: a step in base2meas from then on."""
    place = "measurement"
    channel = "step in t_s at the end of a pause"

    def __init__(self, rng, t_bump):
        super().__init__()
        self.t_bump = t_bump
        r = rng.normal(size=3)
        self.rot = r / np.linalg.norm(r) * 0.012 * DEG
        tr = rng.normal(size=3)
        self.tr = tr / np.linalg.norm(tr) * 0.06
        self.pivot = np.array([125.0, 200.0, -20.0])
        self.joints, self.links = [], ["base2meas"]

    def base(self, ctx, B):
        M = about_point(rigid(self.scale * self.rot, self.scale * self.tr), self.pivot)[0]
        B = B.copy()
        sel = ctx["t"] >= self.t_bump
        B[sel] = M[None] @ B[sel]
        return B

    def description(self):
        return (f"rig knocked during the pause: from t = {self.t_bump:.0f} s the station pose is off by "
                f"{np.linalg.norm(self.rot) * self.scale / DEG:.4f} deg about a pivot below the rig and {np.linalg.norm(self.tr) * self.scale:.3f} mm")

    def formula(self):
        return "base2meas(t) = B base2meas for t >= t_bump (B a small rigid motion about the tripod pivot)"


class AdapterSag(Effect):
    """The plate sits on a slender adapter that bends under the plate's weight depending on the flange attitude."""
    place = "tool"
    channel = "gravity direction in the flange frame (flange orientation)"

    def __init__(self, rng, length_mm=60.0):
        super().__init__()
        self.delta = 0.05  # mm tip deflection for a horizontal adapter
        self.L = length_mm
        self.joints, self.links = [], ["tool"]

    def tool(self, ctx, T, S):
        R = ctx["flange_R"]  # (n,3,3) flange2base rotation at the actual joints
        g = np.einsum("nji,j->ni", R, np.array([0.0, 0.0, -1.0]))  # unit gravity in the flange frame
        gp = g.copy()
        gp[:, 2] = 0.0
        d = self.scale * self.delta
        trans = d * gp
        rot = 1.5 * d / self.L * np.cross(np.array([0.0, 0.0, 1.0])[None], gp)
        Bend = rigid(rot, trans)
        return Bend @ T, S

    def description(self):
        return (f"plate adapter ({self.L:.0f} mm) bends under gravity: tip deflection {self.delta * self.scale:.3f} mm and "
                f"slope 1.5 delta/L for a horizontal adapter, scaled by the gravity component across the flange axis")

    def formula(self):
        return "tool2flange(q) = [Rot(1.5 (delta/L) z x g_perp), delta g_perp] tool2flange, g_perp = lateral part of gravity in the flange frame"


class PlateSlip(Effect):
    """The plate's clamp slips a little about the flange axis at every wrist move; the slip accumulates."""
    place = "tool"
    channel = "cumulative |q6 motion| (history)"

    def __init__(self, rng):
        super().__init__()
        self.c = 2e-5  # rad of plate rotation per rad of joint-6 travel
        self.sign = rng.choice([-1.0, 1.0])
        self.joints, self.links = [6], ["tool"]

    def tool(self, ctx, T, S):
        phi = self.sign * self.scale * self.c * ctx["cum_q6"]
        R = rigid(phi[:, None] * np.array([0.0, 0.0, 1.0])[None], np.zeros(3))
        return R @ T, S

    def description(self):
        return (f"plate clamp slips about the flange axis: {self.c * self.scale:.2e} rad per rad of joint-6 travel, "
                f"accumulating over the campaign (sign {int(self.sign):+d})")

    def formula(self):
        return "tool2flange[k] = RotZ(c sum_{i<=k} |q6[i] - q6[i-1]|) tool2flange[0]"


class VergenceDrift(Effect):
    """The rig's bar bends with the air temperature (HVAC cycling): the vergence changes, the depth scale drifts."""
    place = "measurement"
    channel = "t_s (air-conditioning cycle), depth-proportional"

    def __init__(self, rng, baseline=250.0):
        super().__init__()
        self.gamma = 0.0015 * DEG  # rad per K
        self.B = baseline
        self.joints, self.links = [], ["measurement"]

    def meas(self, ctx, pts, aux):
        k = self.scale * self.gamma * (ctx["T_air"] - ctx["T_air_cal"])
        z = pts[..., 2:3]
        return pts + k[:, None, None] * (z / self.B) * pts

    def description(self):
        return (f"stereo bar bends with the air temperature: vergence error {self.gamma * self.scale / DEG * 1000:.2f} mdeg/K, "
                "depth error z^2/B per rad; the air temperature cycles with the air conditioning (not recorded)")

    def formula(self):
        return "m = p (1 + gamma (T_air(t) - T_cal) z / B), T_air(t) = T0 + a sin(2 pi t / P + phi) + drift"


class LensDecentering(Effect):
    """Residual decentering distortion of the left lens not captured by the rig calibration."""
    place = "measurement"
    channel = "place in the image (x/z, y/z)"

    def __init__(self, rng):
        super().__init__()
        ang = rng.uniform(0, 2 * np.pi)
        self.p = np.array([np.cos(ang), np.sin(ang)]) * 6e-4
        self.joints, self.links = [], ["measurement"]

    def meas(self, ctx, pts, aux):
        x = pts[..., 0] / pts[..., 2]
        y = pts[..., 1] / pts[..., 2]
        r2 = x * x + y * y
        p1, p2 = self.p * self.scale
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        out = pts.copy()
        out[..., 0] += pts[..., 2] * dx
        out[..., 1] += pts[..., 2] * dy
        return out

    def description(self):
        p = self.p * self.scale
        return f"residual decentering distortion of the left lens: p1 = {p[0]:.2e}, p2 = {p[1]:.2e} (normalized coordinates)"

    def formula(self):
        return "X += Z (2 p1 x y + p2 (r^2 + 2 x^2)), Y += Z (p1 (r^2 + 2 y^2) + 2 p2 x y), x = X/Z, y = Y/Z"
