"""Candidate effect models for diagnosis: what a geometric model lacks, as regressors linear in their parameters.

Every candidate maps (commanded joints in measurement order, auxiliary channels) to a first-order change of
the model, linear in its parameters ``phi``:

* joint effects give a joint-angle correction ``dtheta = G(q, ctx) @ phi`` with ``G`` ``(n, 6, K)``;
* length effects (thermal growth) scale the nominal link lengths: ``dL = L_nominal * (s(ctx) @ phi)``;
* measurement effects (plate geometry) move sphere centres in the tool frame.

The vocabulary (names used in ``diagnosis.json``, ``docs/formats.md``):

==================  =====================================================================================
``compliance``      joint compliance under gravity: ``dtheta_i = c_i tau_i(q)``; the gravity torque is linear in
                    the links' mass moments ``(m_k, m_k c_k)``, so ``c_i m_k`` and ``c_i m_k c_k`` enter
                    linearly and no mass needs to be known (regressor from the nominal kinematics only)
``backlash``        per-joint offset ``b_i`` whose sign follows the direction the joint last moved
``cyclic``          transmission cyclic error: ``A_i sin(k q_i) + B_i cos(k q_i)`` for harmonic orders ``k``
``gear_ratio``      ``dtheta_i = (k_i - 1) q_i``
``coupling``        wrist coupling ``dtheta_6 = c q_5``
``thermal``         all link lengths grow by ``kappa (T - T_ref)`` (``temp_c``), or a drift in time
                    (``t_s``: a cubic in time) when no temperature is recorded
``plate_geometry``  the spheres sit off their nominal plate positions (not a rigid motion of the plate)
==================  =====================================================================================

Nothing here reads truth; the regressors use only commanded joints, the dataset's channels and the nominal
model.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Literal

import numpy as np

from ..kinematics import N_JOINTS, RobotModel, link_frames

__all__ = [
    "EFFECT_VOCABULARY",
    "Candidate",
    "RowContext",
    "approach_signs",
    "gravity_torque_regressor",
    "candidate_catalogue",
]

EFFECT_VOCABULARY = ("compliance", "backlash", "cyclic", "gear_ratio", "coupling", "thermal", "plate_geometry")
GRAVITY = np.array([0.0, 0.0, -9.81])  # [m/s^2] in the robot base frame (base z up)


@dataclass(frozen=True)
class RowContext:
    """What the instrument and the controller recorded, per row in measurement order.

    ``q`` ``(n, 6)`` [rad] commanded joints of *every* row in the order measured (rows without a
    measurement included: the robot still moved there); ``q_start`` ``(6,)`` [rad] where the campaign
    started (``None``: unknown); ``temp_c`` ``(n,)`` [deg C] and ``t_s`` ``(n,)`` [s] or None; ``station``
    ``(n,)`` names or None; ``history_reset`` ``(n,)`` bool: rows whose approach is unknown (the first row
    without a known ``q_start``, a gap in time, a recorded restart), or None.
    """

    q: np.ndarray
    q_start: np.ndarray | None = None
    temp_c: np.ndarray | None = None
    t_s: np.ndarray | None = None
    station: np.ndarray | None = None
    history_reset: np.ndarray | None = None


@dataclass(frozen=True)
class Candidate:
    """One effect model. ``kind`` says how ``regressor(ctx, ref)`` is used:

    * ``"joint"``: ``(n, 6, K)``, the joint-angle correction per unit of each parameter [rad];
    * ``"length"``: ``(n, K)``, the relative growth of every robot link length (``d_i``, ``a_i``) per unit of
      each parameter;
    * ``"plate"``: no regressor: the fit adds per-sphere offsets in the tool frame (``3 x 3`` parameters [m]).

    ``reference(ctx)`` fixes the constants a regressor needs (e.g. the reference temperature) from the data
    the effect is identified on; they are stored with the identified values so that prediction on new rows
    uses the same regressor. ``param_names(ref)`` names the ``K`` columns.
    """

    name: str
    kind: Literal["joint", "length", "plate"]
    names: Callable[[dict], tuple[str, ...]]
    regressor: Callable[[RowContext, dict], np.ndarray] | None
    description: str
    reference: Callable[[RowContext], dict] = lambda ctx: {}

    def param_names(self, ref: dict) -> tuple[str, ...]:
        return self.names(ref)


def approach_signs(q: np.ndarray, q_start: np.ndarray | None = None, unknown: np.ndarray | None = None) -> np.ndarray:
    """Direction ``(n, 6)`` from which each joint reached each row (the sign of its last motion).

    A joint that did not move keeps the sign of its previous motion. Before any motion: with ``unknown``
    ``(n,)`` bool given, rows flagged there (and the first row) start an unknown history and a joint's sign
    is 0 (unknown) until it moves; without it, the move from ``q_start`` (home when None) counts, and +1 if
    the joint has never moved.
    """
    q = np.asarray(q, dtype=float)
    n = len(q)
    if unknown is not None:
        reset = np.asarray(unknown, dtype=bool).copy()
        if reset.shape != (n,):
            raise ValueError(f"unknown must have shape ({n},), got {reset.shape}")
        if n:
            reset[0] = True
        out = np.zeros((n, N_JOINTS))
        last = np.zeros(N_JOINTS)
        for k in range(n):
            if reset[k]:
                last = np.zeros(N_JOINTS)
            else:
                step = np.sign(q[k] - q[k - 1])
                last = np.where(step != 0, step, last)
            out[k] = last
        return out
    start = np.zeros(N_JOINTS) if q_start is None else np.asarray(q_start, dtype=float)
    prev = np.vstack([start[None], q[:-1]])
    step = np.sign(q - prev)
    out = np.empty_like(step)
    last = np.ones(N_JOINTS)
    for k in range(len(q)):
        last = np.where(step[k] != 0, step[k], last)
        out[k] = last
    return out


def _joint_axes(model: RobotModel, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis origins and directions ``(n, 6, 3)`` of the six joints in the base frame."""
    # MDH: joint i turns about z of frame i; DH: about z of frame i-1.
    idx = np.arange(1, 7) if model.convention == "mdh" else np.arange(0, 6)
    sel = frames[:, idx]  # (n, 6, 4, 4)
    return sel[:, :, :3, 3], sel[:, :, :3, 2]


def gravity_torque_regressor(model: RobotModel, q: np.ndarray, g: np.ndarray = GRAVITY) -> np.ndarray:
    """Gravity torques as a linear map of the links' mass moments: ``(n, 6, 6, 4)``.

    ``tau_i(q) = sum_{k >= i} Y[:, i, k] @ (m_k, h_k)`` with ``h_k = m_k c_k`` the first mass moment of link
    ``k`` in its own frame ``k``. For a link ``k`` moved by joint ``i`` (axis through ``o_i`` along ``z_i``),
    ``tau = z_i . ((p_ck - o_i) x m_k g)`` and ``m_k p_ck = m_k o_k + R_k h_k`` give
    ``Y[:, i, k] = (z_i . ((o_k - o_i) x g), R_k^T (g x z_i))``.
    """
    frames = link_frames(model, q)
    o_axis, z_axis = _joint_axes(model, frames)
    n = frames.shape[0]
    Y = np.zeros((n, N_JOINTS, N_JOINTS, 4))
    for i in range(N_JOINTS):
        gxz = np.cross(g, z_axis[:, i])  # (n, 3)
        for k in range(i, N_JOINTS):
            o_k = frames[:, k + 1, :3, 3]
            R_k = frames[:, k + 1, :3, :3]
            Y[:, i, k, 0] = np.einsum("ni,ni->n", z_axis[:, i], np.cross(o_k - o_axis[:, i], g))
            Y[:, i, k, 1:] = np.einsum("nji,nj->ni", R_k, gxz)
    return Y


def _compliance_regressor(model: RobotModel) -> Callable[[RowContext, dict], np.ndarray]:
    def G(ctx: RowContext, ref: dict) -> np.ndarray:
        Y = gravity_torque_regressor(model, ctx.q)  # (n, 6, 6, 4)
        n = Y.shape[0]
        cols = []
        for i in range(N_JOINTS):
            for k in range(i, N_JOINTS):
                for c in range(4):
                    col = np.zeros((n, N_JOINTS))
                    col[:, i] = Y[:, i, k, c]
                    cols.append(col)
        return np.stack(cols, axis=-1)

    return G


def _compliance_names() -> tuple[str, ...]:
    out = []
    for i in range(1, 7):
        for k in range(i, 7):
            out += [f"c{i}*m{k}", f"c{i}*h{k}x", f"c{i}*h{k}y", f"c{i}*h{k}z"]
    return tuple(out)


def candidate_catalogue(model: RobotModel, *, harmonic_orders: tuple[int, ...] = (1, 2, 3)) -> list[Candidate]:
    """The candidates diagnosis tries, built on the nominal ``model``."""

    def backlash(ctx: RowContext, ref: dict) -> np.ndarray:
        s = approach_signs(ctx.q, ctx.q_start)
        G = np.zeros((len(ctx.q), N_JOINTS, N_JOINTS))
        G[:, np.arange(6), np.arange(6)] = s
        return G

    def cyclic(ctx: RowContext, ref: dict) -> np.ndarray:
        n = len(ctx.q)
        cols = []
        for k in ref["harmonic_orders"]:
            for i in range(N_JOINTS):
                for f in (np.sin, np.cos):
                    col = np.zeros((n, N_JOINTS))
                    col[:, i] = f(k * ctx.q[:, i])
                    cols.append(col)
        return np.stack(cols, axis=-1)

    def gear_ratio(ctx: RowContext, ref: dict) -> np.ndarray:
        G = np.zeros((len(ctx.q), N_JOINTS, N_JOINTS))
        G[:, np.arange(6), np.arange(6)] = ctx.q
        return G

    def coupling(ctx: RowContext, ref: dict) -> np.ndarray:
        G = np.zeros((len(ctx.q), N_JOINTS, 1))
        G[:, 5, 0] = ctx.q[:, 4]
        return G

    def thermal_ref(ctx: RowContext) -> dict:
        if ctx.temp_c is not None:
            return {"channel": "temp_c", "temp_ref_c": float(np.median(ctx.temp_c))}
        if ctx.t_s is not None:
            return {"channel": "t_s", "t0_s": float(np.min(ctx.t_s)), "t_scale_s": float(max(np.ptp(ctx.t_s), 1.0))}
        raise ValueError("thermal: the dataset has neither temp_c nor t_s")

    def thermal(ctx: RowContext, ref: dict) -> np.ndarray:
        if ref["channel"] == "temp_c":
            if ctx.temp_c is None:
                raise ValueError("thermal effect identified against temp_c: the rows need a temp_c column")
            return (ctx.temp_c - ref["temp_ref_c"])[:, None]
        if ctx.t_s is None:
            raise ValueError("thermal effect identified against t_s: the rows need a t_s column")
        # an unknown smooth drift in time: a cubic in normalised time (a warm-up 1 - exp(-t/tau) over the
        # campaign is matched to ~0.3 % of its range)
        t = (ctx.t_s - ref["t0_s"]) / ref["t_scale_s"]
        return np.stack([t, t * t, t * t * t], axis=1)

    def thermal_names(ref: dict) -> tuple[str, ...]:
        return ("kappa_per_K",) if ref.get("channel") == "temp_c" else ("drift_t", "drift_t2", "drift_t3")

    def cyclic_names(ref: dict) -> tuple[str, ...]:
        return tuple(f"{ab}{i}_k{k}" for k in ref["harmonic_orders"] for i in range(1, 7) for ab in ("A", "B"))

    def const(names):
        return lambda ref: tuple(names)

    return [
        Candidate("compliance", "joint", const(_compliance_names()), _compliance_regressor(model),
                  "joint compliance under gravity (compliance x mass moments)"),
        Candidate("backlash", "joint", const(f"b{i}" for i in range(1, 7)), backlash,
                  "backlash: offset b_i signed by the approach direction"),
        Candidate("cyclic", "joint", cyclic_names, cyclic, "transmission cyclic error per joint",
                  reference=lambda ctx: {"harmonic_orders": list(harmonic_orders)}),
        Candidate("gear_ratio", "joint", const(f"k{i}-1" for i in range(1, 7)), gear_ratio,
                  "gear-ratio error: dtheta_i = (k_i - 1) q_i"),
        Candidate("coupling", "joint", const(["c65"]), coupling, "wrist coupling: dtheta_6 = c q_5"),
        Candidate("thermal", "length", thermal_names, thermal,
                  "thermal growth of all link lengths vs temp_c (or drift vs t_s)", reference=thermal_ref),
        Candidate("plate_geometry", "plate", const(f"dp{s}_{c}" for s in range(3) for c in "xyz"), None,
                  "sphere centres off their nominal plate positions"),
    ]
