"""The vocabulary of named effects and what every atom reads from the rows: the row context, the approach
directions, and the gravity-torque regressor (the atoms themselves are in :mod:`twin.diagnosis.atoms`).

The vocabulary (families named in ``diagnosis.json``, ``docs/formats.md``):

==================  =====================================================================================
``compliance``      joint compliance under gravity: ``dtheta_i = c_i tau_i(q)``; the gravity torque is linear in
                    the links' mass moments ``(m_k, m_k c_k)`` (regressor from the nominal kinematics only)
``backlash``        per-joint offset whose sign follows the direction the joint last moved
``cyclic``          transmission cyclic error: ``A sin(k q_j) + B cos(k q_j)``
``gear_ratio``      ``dtheta_j = (k_j - 1) q_j``
``coupling``        wrist coupling ``dtheta_6 = c q_5``
``thermal``         link lengths growing with ``temp_c`` (or a cubic in ``t_s``), per link or all together
``plate_geometry``  a sphere off its nominal plate position (not a rigid motion of the plate)
==================  =====================================================================================

Nothing here reads truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..kinematics import N_JOINTS, RobotModel, link_frames

__all__ = [
    "EFFECT_VOCABULARY",
    "RowContext",
    "approach_signs",
    "gravity_torque_regressor",
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
    without a known ``q_start``, a recorded restart), or None; ``session_start`` ``(n,)`` bool: rows that
    start a session (the first, after a long gap in time or a recorded restart), or None; ``pose_id`` ``(n,)``
    the rows' pose ids, or None (a term in the row order numbers a campaign's rows by them).
    """

    q: np.ndarray
    q_start: np.ndarray | None = None
    temp_c: np.ndarray | None = None
    t_s: np.ndarray | None = None
    station: np.ndarray | None = None
    history_reset: np.ndarray | None = None
    session_start: np.ndarray | None = None
    pose_id: np.ndarray | None = None


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
