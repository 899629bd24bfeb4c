"""The catalogue of world effects and the registry that builds them from config tables.

Every effect is a :class:`~twin.world.effects.BaseEffect` with its parameters in SI, a constructor from a
TOML table (``from_table``: millimetres and degrees at the edge, unknown keys refused) and ``params()`` for
the truth file. Effects are *undeclared*: they shape the measurements, and nothing about them reaches the
dataset except what a real instrument would record (``t_s``/``temp_c``, when the campaign says so).

==========================  ===================================================================================
name                        what the world does
==========================  ===================================================================================
``compliance``              joints held by position servos of stiffness ``k_i`` [N m/rad]; the actual joints are
                            the static equilibrium ``k (q_act - q) = tau_g(q_act)`` under gravity, the torque
                            computed by MuJoCo from the twin's own masses (plus an optional payload)
``backlash``                the output trails the motor by the half-clearance ``b_i`` [rad] in the direction
                            the joint last moved: ``q_act = q - s_i b_i``
``cyclic``                  transmission cyclic error ``q_act = q + sum_h A_hi sin(k_hi phi_i + ph_hi)`` with
                            ``phi`` the joint angle or the motor angle ``N_i q_i``
``gear_ratio``              ``q_act_i = k_i q_i``
``coupling``                ``q_act_j += c q_i`` (joint 6 driven by joint 5 by default)
``thermal``                 every link length ``d_i``, ``a_i`` scales by ``1 + alpha (T - T_ref)``; ``T`` a
                            warm-up ``T0 + dT (1 - exp(-t/tau))`` over the campaign's time, or the context's
``sphere_out_of_round``     one sphere of the plate is a slightly ellipsoidal body (rendered as such)
``constant_joint_offset``   ``q_act = q + offsets`` (the trivial example)
``python``                  any user effect or ``f(q, context) -> q`` named as ``"module:attribute"``
==========================  ===================================================================================

A config names an effect under ``[[world.effects]]`` with ``name = "..."`` (``type`` is accepted as a synonym)
and its parameters; :func:`register_effect` adds names. The "bias correction switched off" case of the
sphere images is an instrument option, not a world effect: ``twin.instrument.measure_pair(...,
bias_correction=False)`` (``docs/world.md``).
"""

from __future__ import annotations

import importlib
import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..kinematics import N_JOINTS, RobotModel
from ..units import M_PER_MM, RAD_PER_DEG
from .config import table_number  # the one validator of numbers in world TOML tables
from .effects import BaseEffect, ConstantJointOffset, EffectContext, SceneState, as_effect

__all__ = [
    "ComplianceEquilibrium",
    "solve_compliance_equilibrium",
    "Compliance",
    "Backlash",
    "approach_signs",
    "CyclicError",
    "GearRatio",
    "Coupling",
    "ThermalGrowth",
    "SphereOutOfRound",
    "EFFECT_TYPES",
    "register_effect",
    "effect_from_spec",
    "DEFAULT_STIFFNESS_NM_PER_RAD",
]


#: Servo stiffness per joint [N m/rad]: RV-class reducers on joints 1-3, strain-wave gears on the wrist.
#: With the twin's masses (52 kg arm, 0.96 kg plate) this sags the tool by 0.01-0.5 mm over the joint ranges
#: and by 0.08-0.26 mm over the default stations' visible configurations (``docs/world.md``).
DEFAULT_STIFFNESS_NM_PER_RAD = (2.0e5, 2.5e5, 1.2e5, 2.0e4, 2.0e4, 1.0e4)
#: Gear ratios used for a motor-angle cyclic error when none are given (typical of this class; the IRB 1200's
#: own ratios are not published).
DEFAULT_GEAR_RATIOS = (121.0, 121.0, 101.0, 81.0, 81.0, 51.0)


# ------------------------------------------------------------------------------------------------
# Config-table helpers (mm/deg at the edge, SI out)
# ------------------------------------------------------------------------------------------------

def check_keys(table: Mapping[str, Any], allowed: set[str], where: str) -> None:
    unknown = sorted(set(table) - allowed - {"name", "type"})
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")


def _per_joint(v: Any, what: str, *, rows: bool = False, positive=False, nonneg=False) -> np.ndarray:
    """A scalar or ``N_JOINTS`` numbers -> ``(6,)``; with ``rows`` also a list of such rows -> ``(H, 6)``."""
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a number or {N_JOINTS} numbers, got {v!r}") from None
    if a.ndim == 0:
        a = np.full(N_JOINTS, float(a))
    ok = a.shape == (N_JOINTS,) or (rows and a.ndim == 2 and a.shape[1] == N_JOINTS and len(a) > 0)
    if not ok:
        raise ValueError(f"{what} must be a number or {N_JOINTS} numbers{' (or rows of them)' if rows else ''}, "
                         f"got {v!r}")
    if not np.all(np.isfinite(a)) or (positive and np.any(a <= 0)) or (nonneg and np.any(a < 0)):
        what_kind = "positive" if positive else "non-negative" if nonneg else "finite"
        raise ValueError(f"{what} must be {what_kind}, got {v!r}")
    return a


def _joint_number(v: Any, what: str) -> int:
    try:
        j = int(v)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a joint number 1..{N_JOINTS}, got {v!r}") from None
    if j != v or not 1 <= j <= N_JOINTS:
        raise ValueError(f"{what} must be a joint number 1..{N_JOINTS}, got {v!r}")
    return j


# ------------------------------------------------------------------------------------------------
# Compliance: MuJoCo statics
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ComplianceEquilibrium:
    """Result of :func:`solve_compliance_equilibrium`: ``q_actual`` ``(6,)`` [rad], the iterations used, the
    last step ``max |q_{n+1} - q_n|`` [rad] and the trace of steps (one per iteration)."""

    q_actual: np.ndarray
    iterations: int
    last_step_rad: float
    trace: tuple[float, ...]


def solve_compliance_equilibrium(
    q_cmd: np.ndarray,
    stiffness: np.ndarray,
    gravity_torque: Callable[[np.ndarray], np.ndarray],
    *,
    tol: float = 1e-12,
    max_iter: int = 100,
    callback: Callable[[int, np.ndarray, float], None] | None = None,
) -> ComplianceEquilibrium:
    """Static equilibrium of joints held by position servos of finite stiffness under gravity.

    A servo commanded to ``q_cmd`` exerts ``-K (q - q_cmd)`` (``K = diag(k_i)`` [N m/rad]); gravity exerts
    ``tau(q)`` [N m] (the torque gravity applies to each joint at rest, ``(6,)``). At rest they balance::

        K (q - q_cmd) = tau(q)

    solved by the fixed point ``q_{n+1} = q_cmd + K^{-1} tau(q_n)`` from ``q_0 = q_cmd``. It contracts with
    rate ``||K^{-1} d tau/dq||`` (about 1e-3 for the defaults: gravity stiffness of ~100 N m/rad against
    servos of ~1e5 N m/rad), so a handful of iterations reach ``max |q_{n+1} - q_n| <= tol`` [rad]. A servo
    too soft for its load (rate >= 1: no stable equilibrium near the command) is refused with a
    ``ValueError``. ``callback(n, q_n, step)`` sees every iterate.
    """
    q0 = np.asarray(q_cmd, dtype=float).reshape(-1)
    if q0.shape != (N_JOINTS,) or not np.all(np.isfinite(q0)):
        raise ValueError(f"q_cmd must be {N_JOINTS} finite joint angles [rad], got {q_cmd!r}")
    k = np.asarray(stiffness, dtype=float).reshape(-1)
    if k.shape != (N_JOINTS,) or not np.all(np.isfinite(k)) or np.any(k <= 0):
        raise ValueError(f"stiffness must be {N_JOINTS} positive numbers [N m/rad], got {stiffness!r}")
    if not (tol > 0) or max_iter < 1:
        raise ValueError(f"tol must be positive and max_iter >= 1, got tol={tol!r}, max_iter={max_iter!r}")
    q = q0.copy()
    trace: list[float] = []
    for n in range(1, max_iter + 1):
        tau = np.asarray(gravity_torque(q), dtype=float).reshape(-1)
        if tau.shape != (N_JOINTS,) or not np.all(np.isfinite(tau)):
            raise ValueError(f"gravity_torque returned {tau!r}; expected {N_JOINTS} finite torques [N m]")
        q_next = q0 + tau / k
        step = float(np.max(np.abs(q_next - q)))
        trace.append(step)
        q = q_next
        if callback is not None:
            callback(n, q.copy(), step)
        if step <= tol:
            return ComplianceEquilibrium(q, n, step, tuple(trace))
        if n >= 4 and trace[-1] >= trace[-2] >= trace[-3]:
            break  # not contracting: the servos are too soft for the load
    raise ValueError(
        f"compliance: no static equilibrium near q_cmd={q0.tolist()} (steps {trace[-3:]} rad): "
        f"stiffness {k.tolist()} N m/rad is too low for the gravity load"
    )


class Compliance(BaseEffect):
    """Joint compliance under gravity, by MuJoCo statics.

    Each joint is held by a position servo of stiffness ``stiffness[i]`` [N m/rad] (``(6,)``; default
    :data:`DEFAULT_STIFFNESS_NM_PER_RAD`). The actual configuration is the static equilibrium
    ``k (q_act - q) = tau_g(q_act)`` (:func:`solve_compliance_equilibrium`, to ``tol`` [rad]) where ``tau_g`` is
    the torque gravity exerts on each joint, computed by MuJoCo from the twin's own body masses and inertias
    (:meth:`twin.world.World.gravity_torque`: the 52 kg arm, flange, plate and spheres) plus an optional
    ``payload_kg`` [kg] point mass at ``payload_com_tool`` ``(3,)`` [m] in the plate (tool) frame. Gravity is
    the MuJoCo model's (``model.opt.gravity``). Needs ``context.world``. Place it last among the joint
    effects: the servos hold the motors where the transmission effects put them, and gravity bends the
    output from there.
    """

    name = "compliance"

    def __init__(self, stiffness: Sequence[float] | np.ndarray = DEFAULT_STIFFNESS_NM_PER_RAD,
                 payload_kg: float = 0.0, payload_com_tool: Sequence[float] | np.ndarray = (0.0, 0.0, 0.0),
                 *, tol: float = 1e-12, max_iter: int = 100):
        self.stiffness = _per_joint(stiffness, "compliance stiffness [N m/rad]", positive=True)
        self.payload_kg = float(payload_kg)
        if not (math.isfinite(self.payload_kg) and self.payload_kg >= 0):
            raise ValueError(f"compliance payload_kg must be a non-negative mass [kg], got {payload_kg!r}")
        c = np.asarray(payload_com_tool, dtype=float).reshape(-1)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise ValueError(f"compliance payload_com_tool must be 3 finite numbers [m], got {payload_com_tool!r}")
        self.payload_com_tool = c
        self.tol, self.max_iter = float(tol), int(max_iter)

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> "Compliance":
        where = "world.effects (compliance)"
        check_keys(t, {"stiffness_nm_per_rad", "payload_kg", "payload_com_mm"}, where)
        com = t.get("payload_com_mm", (0.0, 0.0, 0.0))
        try:
            com = np.asarray(com, dtype=float).reshape(3) * M_PER_MM
        except (TypeError, ValueError):
            raise ValueError(f"{where}.payload_com_mm must be 3 numbers [mm], got {com!r}") from None
        return cls(
            _per_joint(t.get("stiffness_nm_per_rad", DEFAULT_STIFFNESS_NM_PER_RAD), f"{where}.stiffness_nm_per_rad",
                       positive=True),
            table_number(t, "payload_kg", 0.0, where, nonneg=True),
            com,
        )

    def _torque_fn(self, context: EffectContext) -> Callable[[np.ndarray], np.ndarray]:
        world = context.world
        if world is None or not hasattr(world, "gravity_torque"):
            raise ValueError("compliance needs context.world (a twin.world.World computing gravity torques with "
                             "MuJoCo); got none")
        return lambda q: world.gravity_torque(q, payload_kg=self.payload_kg, payload_com_tool=self.payload_com_tool)

    def equilibrium(self, q: np.ndarray, context: EffectContext) -> ComplianceEquilibrium:
        """The full solver result for input joints ``q`` ``(6,)`` [rad]."""
        return solve_compliance_equilibrium(q, self.stiffness, self._torque_fn(context), tol=self.tol,
                                            max_iter=self.max_iter)

    def joints(self, q: np.ndarray, context: EffectContext) -> np.ndarray:
        return self.equilibrium(q, context).q_actual

    def params(self) -> dict:
        return {
            "stiffness_nm_per_rad": self.stiffness.tolist(),
            "payload_kg": self.payload_kg,
            "payload_com_tool_m": self.payload_com_tool.tolist(),
            "tolerance_rad": self.tol,
            "model": "k (q_act - q) = tau_gravity(q_act); tau by MuJoCo (mj_rne at rest) from the twin's masses",
        }


# ------------------------------------------------------------------------------------------------
# Backlash
# ------------------------------------------------------------------------------------------------

def approach_signs(sequence: np.ndarray, initial_sign: np.ndarray | float = 1.0, move_tol: float = 1e-9) -> np.ndarray:
    """Direction ``(6,)`` in {-1, +1} from which each joint reached the last row of ``sequence`` ``(m, 6)``.

    ``sequence`` runs from the start configuration through every command in measurement order to the current
    one. Each joint takes the sign of its last move larger than ``move_tol`` [rad]; a joint that did not move
    keeps the sign it had; one that never moved has ``initial_sign``.
    """
    seq = np.asarray(sequence, dtype=float)
    s = np.broadcast_to(np.asarray(initial_sign, dtype=float), (N_JOINTS,)).copy()
    if len(seq) < 2:
        return s
    steps = np.diff(seq, axis=0)
    moved = np.abs(steps) > move_tol
    for i in range(N_JOINTS):
        idx = np.flatnonzero(moved[:, i])
        if len(idx):
            s[i] = np.sign(steps[idx[-1], i])
    return s


class Backlash(BaseEffect):
    """Gear clearance: the joint's output trails its motor by the half-clearance ``b_i`` [rad] (``(6,)``,
    non-negative) in the direction the joint last moved::

        q_act_i = q_i - s_i b_i,   s_i = sign of joint i's last move (approach direction)

    ``s`` comes from the context alone (:func:`approach_signs` over ``q_start``, ``q_cmd_history`` and this
    command): a joint that did not move keeps its previous sign; the first pose approaches from the campaign's
    start configuration (``context.q_start``, home = zeros by default); a joint that never moved has
    ``initial_sign`` (+1, as the diagnosis assumes). Moves below ``move_tol`` [rad] do not count. No hidden
    state: a campaign resumed in another process gives the same values when it passes the same plan
    (:func:`twin.world.effects.contexts_for_sequence`). A context that has a previous command but no history
    is refused (the sign of a joint that did not move would be unknown).

    In the diagnosis' model ``dtheta_i = s_i b'_i`` the same effect reads ``b' = -b``
    (``params()['offset_by_approach_sign_rad']``).
    """

    name = "backlash"

    def __init__(self, half_clearance: Sequence[float] | np.ndarray | float = 0.005 * RAD_PER_DEG,
                 initial_sign: Sequence[float] | np.ndarray | float = 1.0, move_tol: float = 1e-9):
        self.half_clearance = _per_joint(half_clearance, "backlash half_clearance [rad]", nonneg=True)
        s = _per_joint(initial_sign, "backlash initial_sign")
        if not np.all(np.isin(s, (-1.0, 1.0))):
            raise ValueError(f"backlash initial_sign must be +1 or -1 per joint, got {initial_sign!r}")
        self.initial_sign = s
        if not (move_tol > 0):
            raise ValueError(f"backlash move_tol must be positive [rad], got {move_tol!r}")
        self.move_tol = float(move_tol)

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> "Backlash":
        where = "world.effects (backlash)"
        check_keys(t, {"half_clearance_deg", "initial_sign"}, where)
        return cls(_per_joint(t.get("half_clearance_deg", 0.005), f"{where}.half_clearance_deg", nonneg=True) * RAD_PER_DEG,
                   t.get("initial_sign", 1.0))

    def signs(self, context: EffectContext) -> np.ndarray:
        """Approach direction ``(6,)`` of this measurement (see the class docstring)."""
        if context.q_cmd is None:
            raise ValueError("backlash needs context.q_cmd (apply_joint_effects fills it)")
        seq = context.command_sequence()
        if seq is None:
            raise ValueError("backlash needs the command history: the context has q_cmd_prev but no q_cmd_history "
                             "(pass every command measured since the campaign start, e.g. contexts_for_sequence)")
        return approach_signs(seq, self.initial_sign, self.move_tol)

    def joints(self, q: np.ndarray, context: EffectContext) -> np.ndarray:
        return q - self.signs(context) * self.half_clearance

    def params(self) -> dict:
        return {
            "half_clearance_rad": self.half_clearance.tolist(),
            "offset_by_approach_sign_rad": (-self.half_clearance).tolist(),
            "initial_sign": self.initial_sign.tolist(),
            "move_tol_rad": self.move_tol,
            "model": "q_act = q - s b, s = sign of each joint's last move (start: q_start, home = 0)",
        }


# ------------------------------------------------------------------------------------------------
# Transmission errors
# ------------------------------------------------------------------------------------------------

class CyclicError(BaseEffect):
    """Transmission cyclic error, per joint and harmonic ``h``::

        q_act_i = q_i + sum_h A_hi sin(k_hi phi_i + ph_hi)

    ``amplitude`` ``A`` [rad], ``order`` ``k`` (cycles per revolution of ``phi``, positive) and ``phase``
    ``ph`` [rad]: a number, ``(6,)`` or ``(H, 6)`` (broadcast to a common ``(H, 6)``). ``angle`` chooses
    ``phi``:

    * ``"joint"``: ``phi_i = q_i``, the joint angle as it enters this effect (the commanded angle when the
      effect comes first): an error periodic in the joint angle, e.g. an eccentric output bearing;
    * ``"motor"``: ``phi_i = N_i q_i`` with the gear ratio ``N_i`` (``gear_ratio`` ``(6,)``, default
      :data:`DEFAULT_GEAR_RATIOS`): an error of the motor-side stages, ``N_i k`` cycles per joint turn
      (a few degrees of joint angle per cycle); its phase includes the motor's unknown zero.
    """

    name = "cyclic"

    def __init__(self, amplitude: Any = 0.005 * RAD_PER_DEG, order: Any = 2.0, phase: Any = 0.0, angle: str = "joint",
                 gear_ratio: Sequence[float] | np.ndarray | None = None):
        A = _per_joint(amplitude, "cyclic amplitude [rad]", rows=True)
        k = _per_joint(order, "cyclic order", rows=True, positive=True)
        ph = _per_joint(phase, "cyclic phase [rad]", rows=True)
        try:
            A, k, ph = (np.array(x, dtype=float) for x in np.broadcast_arrays(np.atleast_2d(A), np.atleast_2d(k),
                                                                             np.atleast_2d(ph)))
        except ValueError:
            raise ValueError(f"cyclic amplitude/order/phase rows do not match: {np.shape(amplitude)}, "
                             f"{np.shape(order)}, {np.shape(phase)}") from None
        if angle not in ("joint", "motor"):
            raise ValueError(f"cyclic angle must be 'joint' or 'motor', got {angle!r}")
        self.amplitude, self.order, self.phase, self.angle = A, k, ph, angle
        N = _per_joint(DEFAULT_GEAR_RATIOS if gear_ratio is None else gear_ratio, "cyclic gear_ratio", positive=True)
        self.gear_ratio = N

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> "CyclicError":
        where = "world.effects (cyclic)"
        check_keys(t, {"amplitude_deg", "order", "phase_deg", "angle", "gear_ratio"}, where)
        return cls(
            _per_joint(t.get("amplitude_deg", 0.005), f"{where}.amplitude_deg", rows=True) * RAD_PER_DEG,
            _per_joint(t.get("order", 2.0), f"{where}.order", rows=True, positive=True),
            _per_joint(t.get("phase_deg", 0.0), f"{where}.phase_deg", rows=True) * RAD_PER_DEG,
            str(t.get("angle", "joint")),
            t.get("gear_ratio"),
        )

    def phi(self, q: np.ndarray) -> np.ndarray:
        """The angle the error is periodic in ``(6,)`` [rad]."""
        return q if self.angle == "joint" else self.gear_ratio * q

    def joints(self, q: np.ndarray, context: EffectContext) -> np.ndarray:
        return q + np.sum(self.amplitude * np.sin(self.order * self.phi(q)[None, :] + self.phase), axis=0)

    def params(self) -> dict:
        out = {
            "amplitude_rad": self.amplitude.tolist(),
            "order": self.order.tolist(),
            "phase_rad": self.phase.tolist(),
            "angle": self.angle,
            "model": "q_act = q + sum_h A sin(k phi + phase); phi = q (joint) or N q (motor)",
        }
        if self.angle == "motor":
            out["gear_ratio"] = self.gear_ratio.tolist()
        return out


class GearRatio(BaseEffect):
    """Gear-ratio error: ``q_act_i = k_i q_i`` (``ratio`` ``k`` ``(6,)``, dimensionless, near 1)."""

    name = "gear_ratio"

    def __init__(self, ratio: Sequence[float] | np.ndarray = (1.0001, 1.0002, 1.0002, 1.0001, 1.0001, 1.0001)):
        self.ratio = _per_joint(ratio, "gear_ratio ratio", positive=True)

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> "GearRatio":
        where = "world.effects (gear_ratio)"
        check_keys(t, {"ratio"}, where)
        if "ratio" not in t:
            return cls()
        return cls(_per_joint(t["ratio"], f"{where}.ratio", positive=True))

    def joints(self, q: np.ndarray, context: EffectContext) -> np.ndarray:
        return self.ratio * q

    def params(self) -> dict:
        return {"ratio": self.ratio.tolist(), "model": "q_act_i = k_i q_i"}


class Coupling(BaseEffect):
    """Wrist coupling: ``q_act[driven] = q[driven] + c q[driving]`` (joints numbered 1..6; default joint 6
    driven by joint 5, ``c`` dimensionless)."""

    name = "coupling"

    def __init__(self, coefficient: float = 1e-3, driving_joint: int = 5, driven_joint: int = 6):
        c = float(coefficient)
        if not math.isfinite(c):
            raise ValueError(f"coupling coefficient must be finite, got {coefficient!r}")
        self.coefficient = c
        self.driving_joint = _joint_number(driving_joint, "coupling driving_joint")
        self.driven_joint = _joint_number(driven_joint, "coupling driven_joint")
        if self.driving_joint == self.driven_joint:
            raise ValueError(f"coupling: driving and driven joint must differ, got {driving_joint}")

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> "Coupling":
        where = "world.effects (coupling)"
        check_keys(t, {"coefficient", "driving_joint", "driven_joint"}, where)
        return cls(table_number(t, "coefficient", 1e-3, where), t.get("driving_joint", 5), t.get("driven_joint", 6))

    def joints(self, q: np.ndarray, context: EffectContext) -> np.ndarray:
        out = q.copy()
        out[self.driven_joint - 1] += self.coefficient * q[self.driving_joint - 1]
        return out

    def params(self) -> dict:
        return {"coefficient": self.coefficient, "driving_joint": self.driving_joint,
                "driven_joint": self.driven_joint,
                "model": f"q_act{self.driven_joint} = q{self.driven_joint} + c q{self.driving_joint}"}


# ------------------------------------------------------------------------------------------------
# Thermal growth
# ------------------------------------------------------------------------------------------------

class ThermalGrowth(BaseEffect):
    """Thermal growth of the arm: every link length ``d_i``, ``a_i`` (the true values) scales by
    ``1 + alpha (T - T_ref)`` (``alpha`` [1/K], default 2.3e-5, cast aluminium; ``temp_ref_c`` [°C] the
    temperature at which the true geometry holds).

    The temperature ``T`` [°C]:

    * ``source = "profile"`` (default): a warm-up over the campaign's time,
      ``T(t) = temp_start_c + temp_rise_k (1 - exp(-t / tau_s))`` with ``t = context.t_s`` [s]; the world
      reports it as the pose's temperature (``Capture.temp_c``, which the instrument may or may not record);
    * ``source = "context"``: ``context.temp_c`` (e.g. replaying a recorded temperature log).

    ``include_tool`` also scales the plate's mounting offsets (``tool_x, tool_y, tool_z``); off by default:
    the heat comes from the motors and gears, the plate (and its spheres, never scaled) stays near ambient.
    The base mount (``base2world``) does not grow. Acts through the ``geometry`` hook: the true model per pose.
    """

    name = "thermal"

    def __init__(self, alpha_per_k: float = 2.3e-5, temp_ref_c: float = 20.0, *, source: str = "profile",
                 temp_start_c: float = 20.0, temp_rise_k: float = 8.0, tau_s: float = 1800.0,
                 include_tool: bool = False):
        vals = {"alpha_per_k": alpha_per_k, "temp_ref_c": temp_ref_c, "temp_start_c": temp_start_c,
                "temp_rise_k": temp_rise_k, "tau_s": tau_s}
        for k, v in vals.items():
            if not math.isfinite(float(v)):
                raise ValueError(f"thermal {k} must be finite, got {v!r}")
        if not float(tau_s) > 0:
            raise ValueError(f"thermal tau_s must be positive [s], got {tau_s!r}")
        if source not in ("profile", "context"):
            raise ValueError(f"thermal source must be 'profile' or 'context', got {source!r}")
        self.alpha_per_k = float(alpha_per_k)
        self.temp_ref_c = float(temp_ref_c)
        self.source = source
        self.temp_start_c = float(temp_start_c)
        self.temp_rise_k = float(temp_rise_k)
        self.tau_s = float(tau_s)
        self.include_tool = bool(include_tool)

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> "ThermalGrowth":
        where = "world.effects (thermal)"
        check_keys(t, {"alpha_per_k", "temp_ref_c", "source", "temp_start_c", "temp_rise_k", "tau_s",
                        "include_tool"}, where)
        inc = t.get("include_tool", False)
        if not isinstance(inc, bool):
            raise ValueError(f"{where}.include_tool must be true or false, got {inc!r}")
        return cls(
            table_number(t, "alpha_per_k", 2.3e-5, where), table_number(t, "temp_ref_c", 20.0, where),
            source=str(t.get("source", "profile")), temp_start_c=table_number(t, "temp_start_c", 20.0, where),
            temp_rise_k=table_number(t, "temp_rise_k", 8.0, where), tau_s=table_number(t, "tau_s", 1800.0, where, positive=True),
            include_tool=inc,
        )

    def temperature_c(self, t_s: float) -> float | None:
        """The profile's temperature [°C] at ``t_s`` [s] (``None`` when the temperature comes from the context)."""
        if self.source != "profile":
            return None
        return self.temp_start_c + self.temp_rise_k * (1.0 - math.exp(-float(t_s) / self.tau_s))

    def scale(self, context: EffectContext) -> float:
        """Length factor ``1 + alpha (T - T_ref)`` of this measurement."""
        T = self.temperature_c(context.t_s) if self.source == "profile" else context.temp_c
        return 1.0 + self.alpha_per_k * (T - self.temp_ref_c)

    def length_names(self, robot: RobotModel) -> list[str]:
        names = [f"{f}{i}" for f in ("d", "a") for i in range(1, N_JOINTS + 1)]
        return names + (["tool_x", "tool_y", "tool_z"] if self.include_tool else [])

    def geometry(self, robot: RobotModel, context: EffectContext) -> RobotModel:
        idx = robot.layout.indices(self.length_names(robot))
        p = robot.params.copy()
        p[idx] *= self.scale(context)
        return robot.with_params(p)

    def params(self) -> dict:
        out = {"alpha_per_k": self.alpha_per_k, "temp_ref_c": self.temp_ref_c, "source": self.source,
               "include_tool": self.include_tool,
               "model": "d_i, a_i *= 1 + alpha (T - T_ref)"}
        if self.source == "profile":
            out.update(temp_start_c=self.temp_start_c, temp_rise_k=self.temp_rise_k, tau_s=self.tau_s,
                       profile="T(t) = temp_start_c + temp_rise_k (1 - exp(-t / tau_s))")
        return out


# ------------------------------------------------------------------------------------------------
# Sphere images
# ------------------------------------------------------------------------------------------------

class SphereOutOfRound(BaseEffect):
    """One sphere of the plate slightly out of round: sphere ``sphere`` (0..2) becomes an ellipsoid whose
    semi-axes along the plate's x, y, z are the radius plus ``semi_axis_delta`` ``(3,)`` [m]. It is rendered
    as that ellipsoid (MuJoCo draws the same fine mesh, scaled); its true centre is unchanged, so what moves
    is the instrument's estimate of it, by an amount that depends on the viewing direction."""

    name = "sphere_out_of_round"

    def __init__(self, sphere: int = 0, semi_axis_delta: Sequence[float] | np.ndarray = (3e-5, 0.0, -3e-5)):
        if isinstance(sphere, bool) or sphere not in (0, 1, 2):
            raise ValueError(f"sphere_out_of_round sphere must be 0, 1 or 2, got {sphere!r}")
        d = np.asarray(semi_axis_delta, dtype=float).reshape(-1)
        if d.shape != (3,) or not np.all(np.isfinite(d)):
            raise ValueError(f"sphere_out_of_round semi_axis_delta must be 3 finite numbers [m], got {semi_axis_delta!r}")
        self.sphere = int(sphere)
        self.semi_axis_delta = d

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> "SphereOutOfRound":
        where = "world.effects (sphere_out_of_round)"
        check_keys(t, {"sphere", "semi_axis_delta_mm"}, where)
        try:
            d = np.asarray(t.get("semi_axis_delta_mm", (0.03, 0.0, -0.03)), dtype=float).reshape(3) * M_PER_MM
        except (TypeError, ValueError):
            raise ValueError(f"{where}.semi_axis_delta_mm must be 3 numbers [mm], got {t.get('semi_axis_delta_mm')!r}") from None
        sphere = t.get("sphere", 0)
        if not isinstance(sphere, int) or isinstance(sphere, bool):
            raise ValueError(f"{where}.sphere must be 0, 1 or 2, got {sphere!r}")
        return cls(sphere, d)

    def scene(self, state: SceneState, context: EffectContext) -> SceneState:
        a = state.sphere_semi_axes.copy()
        a[self.sphere] = a[self.sphere] + self.semi_axis_delta
        if np.any(a[self.sphere] <= 0.5 * state.sphere_semi_axes[self.sphere]):
            raise ValueError(f"sphere_out_of_round: semi_axis_delta {self.semi_axis_delta.tolist()} m shrinks sphere "
                             f"{self.sphere} by half or more")
        return state.with_(sphere_semi_axes=a)

    def params(self) -> dict:
        return {"sphere": self.sphere, "semi_axis_delta_m": self.semi_axis_delta.tolist(),
                "axes": "plate (tool) frame x, y, z"}


# ------------------------------------------------------------------------------------------------
# User effects by name, and the registry
# ------------------------------------------------------------------------------------------------

def _python_effect(t: Mapping[str, Any]) -> Any:
    """``{name = "python", callable = "pkg.mod:attr", args = {...}}``: ``attr`` is an effect (or a joint function
    ``f(q, context) -> q``) used as is; with ``args`` (or when it is a class) it is called with them (SI) and
    must return one. It is imported in every process that builds the world."""
    where = "world.effects (python)"
    check_keys(t, {"callable", "args"}, where)
    target = t.get("callable")
    if not isinstance(target, str) or ":" not in target:
        raise ValueError(f"{where}.callable must be 'module:attribute', got {target!r}")
    mod_name, _, attr = target.partition(":")
    try:
        obj: Any = importlib.import_module(mod_name)
        for part in attr.split("."):
            obj = getattr(obj, part)
    except (ImportError, AttributeError) as exc:
        raise ValueError(f"{where}.callable {target!r} cannot be imported: {exc}") from None
    args = t.get("args")
    if args is not None and not isinstance(args, Mapping):
        raise ValueError(f"{where}.args must be a table, got {args!r}")
    if args is not None or isinstance(obj, type):
        obj = obj(**dict(args or {}))
    return as_effect(obj)


EFFECT_TYPES: dict[str, Callable[[Mapping[str, Any]], Any]] = {
    "constant_joint_offset": lambda t: (
        check_keys(t, {"offsets_deg"}, "world.effects (constant_joint_offset)"),
        ConstantJointOffset(_per_joint(t["offsets_deg"], "world.effects (constant_joint_offset).offsets_deg") * RAD_PER_DEG),
    )[1],
    "compliance": Compliance.from_table,
    "backlash": Backlash.from_table,
    "cyclic": CyclicError.from_table,
    "gear_ratio": GearRatio.from_table,
    "coupling": Coupling.from_table,
    "thermal": ThermalGrowth.from_table,
    "sphere_out_of_round": SphereOutOfRound.from_table,
    "python": _python_effect,
}
# effects of other shapes than the diagnosis' candidates (twin/world/effects_shapes.py)
from .effects_shapes import SHAPE_TYPES as _SHAPE_TYPES  # noqa: E402

EFFECT_TYPES.update(_SHAPE_TYPES)


def register_effect(name: str, factory: Callable[[Mapping[str, Any]], Any], *, replace: bool = False) -> None:
    """Make ``name`` usable in ``[[world.effects]]``: ``factory(table) -> effect`` (the table as written, with
    its ``name``). Refuses to shadow an existing name unless ``replace``. Register in a module every worker
    imports (or use ``name = "python"``, which needs no registration)."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"effect name must be a non-empty string, got {name!r}")
    if not callable(factory):
        raise ValueError(f"factory must be callable factory(table) -> effect, got {factory!r}")
    if name in EFFECT_TYPES and not replace:
        raise ValueError(f"effect name {name!r} is already registered (pass replace=True to override)")
    EFFECT_TYPES[name] = factory


def effect_from_spec(spec: Mapping[str, Any]) -> Any:
    """An effect from a config table: ``{name = "compliance", stiffness_nm_per_rad = [...]}`` (``type`` is
    accepted for ``name``). Millimetres and degrees at the edge; unknown keys are errors."""
    if not isinstance(spec, Mapping):
        raise ValueError(f"world.effects: each effect must be a table, got {spec!r}")
    name, typ = spec.get("name"), spec.get("type")
    if name is not None and typ is not None and name != typ:
        raise ValueError(f"world.effects: 'name' {name!r} and 'type' {typ!r} disagree")
    t = name if name is not None else typ
    if t not in EFFECT_TYPES:
        raise ValueError(f"world.effects: unknown effect {t!r}; known: {', '.join(sorted(EFFECT_TYPES))}")
    try:
        return EFFECT_TYPES[t](spec)
    except KeyError as exc:
        raise ValueError(f"world.effects ({t}): missing field {exc}") from None
