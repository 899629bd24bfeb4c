"""World effects of other shapes than the diagnosis' candidates: what a held-out campaign may hold.

Each is written as physics of the world, not as a regressor of the diagnosis: effects on one joint or one link
only, couplings between joints, a hysteresis that follows the size of the last move, a link that grows with a
lagging temperature, a robot base that slips during the campaign, a plate that flexes under gravity.

================  ==========================================================================================
``joint_polynomial``  ``q_act[target] += sum_p c_p ((q[source] - centre) / scale)^p`` (c in deg): a quadratic
                      or cubic in one joint acting on the same or another joint, or a linear coupling
``joint_product``     ``q_act[target] += c (q[a] - c_a) (q[b] - c_b)`` (c in deg per rad^2)
``move_lag``          friction-like lag: ``q_act_j = q_j - b_j tanh(dq_j / w_j)``, ``dq_j`` the last nonzero move of
                      joint j (a small move lags less than a long one; not a constant clearance)
``link_growth``       one link length (``d_i`` or ``a_i``) grows by ``alpha L (T_link - T_ref)``; the casing
                      temperature ``T(t)`` warms up as ``T0 + rise (1 - exp(-t/tau))`` and the link follows it
                      with a first-order lag ``lag_s`` (the recorded ``temp_c`` is the casing's)
``base_shift``        from ``at_s`` on, the robot base sits ``shift_mm`` / ``rotate_deg`` off (a slip, a bump):
                      an effect that changes during the campaign, at the base frame
``plate_flex``        the plate flexes along the flange axis: ``tool2flange`` translation ``+= k g_z e_z`` (``g_z`` the
                      gravity component along the flange axis, ``k`` [mm per g])
``repeatability``     the robot's pose repeatability: every measurement adds seeded random joint offsets
                      ``N(0, sigma_j^2)`` drawn from ``(seed, pose_index)`` (a new draw each time the robot arrives,
                      even at the same command); :func:`repeatability_sigma` sizes ``sigma`` for an ISO 9283 RP
================  ==========================================================================================

Registered in :data:`twin.world.effects_catalogue.EFFECT_TYPES` (names above) so that campaign TOML can
declare them. Millimetres and degrees at the edge, SI inside.
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from ..kinematics import N_JOINTS, RobotModel, link_frames
from ..transforms import pose6_to_transform
from ..units import M_PER_MM, RAD_PER_DEG
from .config import check_keys, table_number
from .config import table_vector as config_vector
from .effects import BaseEffect, EffectContext

__all__ = ["JointPolynomial", "JointProduct", "MoveLag", "LinkGrowth", "BaseShift", "PlateFlex", "Repeatability",
           "flange_repeatability", "repeatability_sigma", "SHAPE_TYPES"]


def _keys(t: Mapping[str, Any], allowed: set[str], where: str) -> None:
    check_keys(t, allowed | {"name", "type"}, where)


def _number(t: Mapping[str, Any], key: str, default: float | None, where: str, *, positive: bool = False) -> float:
    if default is None and key not in t:
        raise ValueError(f"{where}: missing {key!r}")
    return table_number(t, key, 0.0 if default is None else default, where, positive=positive)


def _joint(v: Any, what: str) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= int(v) <= N_JOINTS:
        raise ValueError(f"{what} must be a joint number 1..{N_JOINTS}, got {v!r}")
    return int(v)


def table_vector(t: Mapping[str, Any], key: str, n: int, where: str, default=None) -> np.ndarray:
    v = t.get(key, default)
    if np.ndim(v) == 0 and v is not None and n > 1:
        v = [v] * n
    return config_vector(v, n, f"{where}.{key}")


class JointPolynomial(BaseEffect):
    """``q_act[target] += sum_p c_p ((q[source] - centre) / scale)^p``, ``c_p`` [rad] for ``p = 1, 2, ...``."""

    name = "joint_polynomial"

    def __init__(self, target_joint: int, source_joint: int, coefficients_rad: Sequence[float],
                 centre_rad: float = 0.0, scale_rad: float = 1.0):
        self.target = _joint(target_joint, "joint_polynomial target_joint")
        self.source = _joint(source_joint, "joint_polynomial source_joint")
        c = np.asarray(coefficients_rad, dtype=float).reshape(-1)
        if c.size == 0 or not np.all(np.isfinite(c)):
            raise ValueError(f"joint_polynomial coefficients must be finite numbers, got {coefficients_rad!r}")
        if not (math.isfinite(scale_rad) and scale_rad > 0):
            raise ValueError(f"joint_polynomial scale must be positive, got {scale_rad!r}")
        self.coefficients = c
        self.centre = float(centre_rad)
        self.scale = float(scale_rad)

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> "JointPolynomial":
        where = "world.effects (joint_polynomial)"
        _keys(t, {"target_joint", "source_joint", "coefficients_deg", "centre_deg", "scale_deg"}, where)
        if "coefficients_deg" not in t:
            raise ValueError(f"{where}: missing 'coefficients_deg' (one per power 1, 2, ...)")
        c = np.asarray(t["coefficients_deg"], dtype=float).reshape(-1) * RAD_PER_DEG
        return cls(t.get("target_joint"), t.get("source_joint"), c, _number(t, "centre_deg", 0.0, where) * RAD_PER_DEG,
                   _number(t, "scale_deg", 57.29577951308232, where, positive=True) * RAD_PER_DEG)

    def joints(self, q: np.ndarray, context: EffectContext) -> np.ndarray:
        x = (q[self.source - 1] - self.centre) / self.scale
        out = q.copy()
        out[self.target - 1] += sum(c * x ** (p + 1) for p, c in enumerate(self.coefficients))
        return out

    def params(self) -> dict:
        return {"target_joint": self.target, "source_joint": self.source,
                "coefficients_rad": self.coefficients.tolist(), "centre_rad": self.centre, "scale_rad": self.scale,
                "model": "q_act[target] += sum_p c_p ((q[source] - centre) / scale)^p"}


class JointProduct(BaseEffect):
    """``q_act[target] += c (q[a] - c_a) (q[b] - c_b)`` with ``c`` [rad per rad^2]."""

    name = "joint_product"

    def __init__(self, target_joint: int, joints: Sequence[int], coefficient: float, centres_rad=(0.0, 0.0)):
        self.target = _joint(target_joint, "joint_product target_joint")
        if len(joints) != 2:
            raise ValueError(f"joint_product joints must be two joint numbers, got {joints!r}")
        self.a, self.b = (_joint(j, "joint_product joints") for j in joints)
        self.coefficient = float(coefficient)
        self.centres = np.asarray(centres_rad, dtype=float).reshape(2)

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> "JointProduct":
        where = "world.effects (joint_product)"
        _keys(t, {"target_joint", "joints", "coefficient_deg_per_rad2", "centres_deg"}, where)
        return cls(t.get("target_joint"), list(t.get("joints", [])),
                   _number(t, "coefficient_deg_per_rad2", None, where) * RAD_PER_DEG,
                   table_vector(t, "centres_deg", 2, where, [0.0, 0.0]) * RAD_PER_DEG)

    def joints(self, q: np.ndarray, context: EffectContext) -> np.ndarray:
        out = q.copy()
        out[self.target - 1] += self.coefficient * (q[self.a - 1] - self.centres[0]) * (q[self.b - 1] - self.centres[1])
        return out

    def params(self) -> dict:
        return {"target_joint": self.target, "joints": [self.a, self.b], "coefficient_rad_per_rad2": self.coefficient,
                "centres_rad": self.centres.tolist(), "model": "q_act[target] += c (q[a] - c_a) (q[b] - c_b)"}


class MoveLag(BaseEffect):
    """Friction-like lag ``q_act_j = q_j - b_j tanh(dq_j / w_j)`` (``b`` [rad] per joint, ``w`` [rad]), ``dq_j``
    the last nonzero move of joint j in the command history (from ``q_start``, home, before the first)."""

    name = "move_lag"

    def __init__(self, lag_rad: Sequence[float] | np.ndarray, width_rad: float = 0.05):
        self.lag = np.asarray(lag_rad, dtype=float).reshape(N_JOINTS)
        if not np.all(np.isfinite(self.lag)):
            raise ValueError(f"move_lag lag must be {N_JOINTS} finite numbers, got {lag_rad!r}")
        if not (math.isfinite(width_rad) and width_rad > 0):
            raise ValueError(f"move_lag width must be positive, got {width_rad!r}")
        self.width = float(width_rad)

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> "MoveLag":
        where = "world.effects (move_lag)"
        _keys(t, {"lag_deg", "width_deg"}, where)
        return cls(table_vector(t, "lag_deg", N_JOINTS, where) * RAD_PER_DEG, _number(t, "width_deg", 3.0, where, positive=True) * RAD_PER_DEG)

    def joints(self, q: np.ndarray, context: EffectContext) -> np.ndarray:
        seq = context.command_sequence()
        if seq is None:
            raise ValueError("move_lag needs the command history (EffectContext.q_cmd_history)")
        d = np.diff(seq, axis=0)
        last = np.zeros(N_JOINTS)
        for j in range(N_JOINTS):
            nz = np.flatnonzero(np.abs(d[:, j]) > 1e-12)
            if nz.size:
                last[j] = d[nz[-1], j]
        return q - self.lag * np.tanh(last / self.width)

    def params(self) -> dict:
        return {"lag_rad": self.lag.tolist(), "width_rad": self.width,
                "model": "q_act = q - b tanh(last move / w)"}


class LinkGrowth(BaseEffect):
    """One link length grows with a lagging temperature (module docstring)."""

    name = "link_growth"

    def __init__(self, link: str, alpha_per_k: float = 2.3e-5, temp_start_c: float = 20.0, temp_rise_k: float = 10.0,
                 tau_s: float = 1800.0, lag_s: float = 0.0, temp_ref_c: float = 20.0):
        if not (isinstance(link, str) and link[:1] in ("d", "a") and link[1:].isdigit()
                and 1 <= int(link[1:]) <= N_JOINTS):
            raise ValueError(f"link_growth link must be d1..d6 or a1..a6, got {link!r}")
        for k, v in {"tau_s": tau_s}.items():
            if not v > 0:
                raise ValueError(f"link_growth {k} must be positive, got {v!r}")
        if lag_s < 0:
            raise ValueError(f"link_growth lag_s must be >= 0, got {lag_s!r}")
        self.link, self.alpha, self.t0, self.rise, self.tau, self.lag, self.tref = (
            link, float(alpha_per_k), float(temp_start_c), float(temp_rise_k), float(tau_s), float(lag_s), float(temp_ref_c))

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> "LinkGrowth":
        where = "world.effects (link_growth)"
        _keys(t, {"link", "alpha_per_k", "temp_start_c", "temp_rise_k", "tau_s", "lag_s", "temp_ref_c"}, where)
        return cls(str(t.get("link", "")), _number(t, "alpha_per_k", 2.3e-5, where),
                   _number(t, "temp_start_c", 20.0, where), _number(t, "temp_rise_k", 10.0, where),
                   _number(t, "tau_s", 1800.0, where, positive=True), _number(t, "lag_s", 0.0, where),
                   _number(t, "temp_ref_c", 20.0, where))

    def temperature_c(self, t_s: float) -> float:
        """The casing temperature [°C] the instrument records (the world's temperature)."""
        return self.t0 + self.rise * (1.0 - math.exp(-float(t_s) / self.tau))

    def link_temperature_c(self, t_s: float) -> float:
        """The link's own temperature: the casing's through a first-order lag ``lag_s`` (closed form)."""
        t = float(t_s)
        if self.lag <= 0:
            return self.temperature_c(t)
        a, b = 1.0 / self.tau, 1.0 / self.lag
        if abs(a - b) < 1e-12:
            resp = 1.0 - math.exp(-a * t) * (1.0 + a * t)
        else:
            resp = 1.0 - (b * math.exp(-a * t) - a * math.exp(-b * t)) / (b - a)
        return self.t0 + self.rise * resp

    def geometry(self, robot: RobotModel, context: EffectContext) -> RobotModel:
        i = robot.layout.indices([self.link])
        p = robot.params.copy()
        p[i] *= 1.0 + self.alpha * (self.link_temperature_c(context.t_s) - self.tref)
        return robot.with_params(p)

    def params(self) -> dict:
        return {"link": self.link, "alpha_per_k": self.alpha, "temp_start_c": self.t0, "temp_rise_k": self.rise,
                "tau_s": self.tau, "lag_s": self.lag, "temp_ref_c": self.tref,
                "model": "L *= 1 + alpha (T_link(t) - T_ref); T_link = casing T through a first-order lag"}


class BaseShift(BaseEffect):
    """From ``at_s`` on, the robot base is displaced by ``shift`` [m] and ``rotate`` (rotation vector) [rad]."""

    name = "base_shift"

    def __init__(self, at_s: float, shift_m: Sequence[float], rotate_rad: Sequence[float] = (0.0, 0.0, 0.0)):
        self.at_s = float(at_s)
        self.delta = pose6_to_transform(np.concatenate([np.asarray(shift_m, float).reshape(3),
                                                        np.asarray(rotate_rad, float).reshape(3)]))
        self._pose6 = np.concatenate([np.asarray(shift_m, float).reshape(3), np.asarray(rotate_rad, float).reshape(3)])

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> "BaseShift":
        where = "world.effects (base_shift)"
        _keys(t, {"at_s", "shift_mm", "rotate_deg"}, where)
        return cls(_number(t, "at_s", None, where), table_vector(t, "shift_mm", 3, where) * M_PER_MM,
                   table_vector(t, "rotate_deg", 3, where, [0.0, 0.0, 0.0]) * RAD_PER_DEG)

    def geometry(self, robot: RobotModel, context: EffectContext) -> RobotModel:
        if context.t_s < self.at_s:
            return robot
        return robot.with_frames(base2meas=robot.base2meas @ self.delta)

    def params(self) -> dict:
        return {"at_s": self.at_s, "shift_m": self._pose6[:3].tolist(), "rotate_rad": self._pose6[3:].tolist(),
                "model": "base2world <- base2world @ delta for t >= at_s"}


class PlateFlex(BaseEffect):
    """The plate flexes under gravity: its origin moves along the flange axis by ``k`` [m per g] times the
    component of gravity along that axis (the robot's kinematics of the commanded pose give it)."""

    name = "plate_flex"

    def __init__(self, k_m: float):
        self.k = float(k_m)

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> "PlateFlex":
        where = "world.effects (plate_flex)"
        _keys(t, {"k_mm_per_g"}, where)
        return cls(_number(t, "k_mm_per_g", None, where) * M_PER_MM)

    def geometry(self, robot: RobotModel, context: EffectContext) -> RobotModel:
        if context.q_cmd is None:
            return robot
        # the flange's orientation in the robot base frame, and gravity (world -z) in the base frame
        R = link_frames(robot, context.q_cmd[None])[0, -1, :3, :3]
        g_base = robot.base2meas[:3, :3].T @ np.array([0.0, 0.0, -1.0])
        g_flange = R.T @ g_base
        T = robot.tool2flange.copy()
        # a plate stiff in its plane bends along the flange axis by the gravity component along it (a pure
        # sag along gravity would be a constant offset in the world, absorbed by any base frame)
        T[:3, 3] = T[:3, 3] + self.k * g_flange[2] * np.array([0.0, 0.0, 1.0])
        return robot.with_frames(tool2flange=T)

    def params(self) -> dict:
        return {"k_m_per_g": self.k, "model": "tool2flange.t += k * (gravity . flange z) * flange z"}


class Repeatability(BaseEffect):
    """The robot's pose repeatability: each measurement's actual joints carry random offsets
    ``N(0, sigma_j^2)`` [rad], drawn from ``np.random.default_rng([seed, pose_index])``: the same pose index gives
    the same draw in any process (a resumed campaign reproduces it), a new arrival at the same command (another
    pose index) a new one. ``sigma`` ``(6,)`` [rad]; :func:`repeatability_sigma` sizes it for a flange RP."""

    name = "repeatability"

    def __init__(self, sigma_rad: Sequence[float] | np.ndarray | float, seed: int = 0):
        sig = np.asarray(sigma_rad, dtype=float).reshape(-1)
        if sig.size == 1:
            sig = np.full(N_JOINTS, float(sig[0]))
        if sig.shape != (N_JOINTS,) or not np.all(np.isfinite(sig)) or np.any(sig < 0):
            raise ValueError(f"repeatability sigma_rad must be {N_JOINTS} non-negative numbers, got {sigma_rad!r}")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"repeatability seed must be a non-negative integer, got {seed!r}")
        self.sigma = sig
        self.seed = int(seed)

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> "Repeatability":
        where = "world.effects (repeatability)"
        _keys(t, {"sigma_deg", "seed"}, where)
        if "sigma_deg" not in t:
            raise ValueError(f"{where}: missing 'sigma_deg'")
        return cls(table_vector(t, "sigma_deg", N_JOINTS, where) * RAD_PER_DEG, t.get("seed", 0))

    def offsets(self, context: EffectContext) -> np.ndarray:
        """The joint offsets ``(6,)`` [rad] of the measurement ``context.pose_index``."""
        rng = np.random.default_rng([self.seed, int(context.pose_index)])
        return rng.normal(size=N_JOINTS) * self.sigma

    def joints(self, q: np.ndarray, context: EffectContext) -> np.ndarray:
        return q + self.offsets(context)

    def params(self) -> dict:
        return {"sigma_rad": self.sigma.tolist(), "seed": self.seed,
                "model": "q_act = q + N(0, sigma^2), drawn from (seed, pose_index)"}


def flange_repeatability(robot: RobotModel, q: np.ndarray, sigma_rad: Sequence[float] | np.ndarray, *,
                         draws: int = 200, seed: int = 0) -> float:
    """ISO 9283 pose repeatability RP [m] of the flange origin, ``mean(l) + 3 std(l)`` with ``l`` the distance of
    each arrival from the barycentre of its pose, over ``draws`` arrivals at each configuration ``q`` ``(n, 6)``
    [rad] with joint offsets ``N(0, sigma^2)`` [rad]; the mean RP over the configurations."""
    q = np.asarray(q, dtype=float).reshape(-1, N_JOINTS)
    sig = np.broadcast_to(np.asarray(sigma_rad, dtype=float), (N_JOINTS,))
    if draws < 2:
        raise ValueError(f"draws must be at least 2, got {draws}")
    rng = np.random.default_rng(seed)
    rp = []
    for qk in q:
        qs = qk + rng.normal(size=(draws, N_JOINTS)) * sig
        p = link_frames(robot, qs)[:, -1, :3, 3]
        d = np.linalg.norm(p - p.mean(axis=0), axis=1)
        rp.append(float(d.mean() + 3.0 * d.std()))
    return float(np.mean(rp))


def repeatability_sigma(robot: RobotModel, q: np.ndarray, rp_m: float, *, draws: int = 200, seed: int = 0) -> float:
    """The joint sigma [rad] (the same for every joint) whose :func:`flange_repeatability` over ``q`` is ``rp_m``
    [m] (RP is linear in a small sigma)."""
    if not (math.isfinite(rp_m) and rp_m >= 0):
        raise ValueError(f"rp_m must be a non-negative length [m], got {rp_m!r}")
    unit = 1e-5
    return rp_m / flange_repeatability(robot, q, np.full(N_JOINTS, unit), draws=draws, seed=seed) * unit


SHAPE_TYPES = {cls.name: cls.from_table for cls in (JointPolynomial, JointProduct, MoveLag, LinkGrowth, BaseShift,
                                                     PlateFlex, Repeatability)}
