"""The vocabulary of named effects and what every atom reads from the rows: the row context, the approach
directions, and the gravity-torque regressors of the joints and the base (the atoms themselves are in
:mod:`twin.diagnosis.atoms`).

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
``tilt``            the support of a joint (or the robot's base) tilting about two axes of its frame under the
                    gravity moment of everything it carries, from a chain's mass properties (a URDF's inertials):
                    a column, a bearing, a mobile base on its wheels, a pedestal
==================  =====================================================================================

With a chain's mass properties, ``compliance`` also has one-parameter atoms ``dq_i = c_i tau_i(q)`` whose load
``tau_i`` (torque, or force along a prismatic joint) comes from the masses (:func:`gravity_torques`).

Nothing here reads truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..estimator.memo import KeptResults, array_key
from ..kinematics import N_JOINTS, RobotModel, link_frames

__all__ = [
    "EFFECT_VOCABULARY",
    "RowContext",
    "approach_signs",
    "gravity_torque_regressor",
    "has_masses",
    "joint_frames",
    "gravity_torques",
    "carried_moments",
    "base_moment_regressor",
]

EFFECT_VOCABULARY = ("compliance", "backlash", "cyclic", "gear_ratio", "coupling", "thermal", "plate_geometry", "tilt")
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
    """Direction ``(n, N)`` from which each joint reached each row (the sign of its last motion).

    A joint that did not move keeps the sign of its previous motion. Before any motion: with ``unknown``
    ``(n,)`` bool given, rows flagged there (and the first row) start an unknown history and a joint's sign
    is 0 (unknown) until it moves; without it, the move from ``q_start`` (home when None) counts, and +1 if
    the joint has never moved.
    """
    q = np.asarray(q, dtype=float)
    n = len(q)
    N = q.shape[1] if q.ndim == 2 else N_JOINTS
    if unknown is not None:
        reset = np.asarray(unknown, dtype=bool).copy()
        if reset.shape != (n,):
            raise ValueError(f"unknown must have shape ({n},), got {reset.shape}")
        if n:
            reset[0] = True
        out = np.zeros((n, N))
        last = np.zeros(N)
        for k in range(n):
            if reset[k]:
                last = np.zeros(N)
            else:
                step = np.sign(q[k] - q[k - 1])
                last = np.where(step != 0, step, last)
            out[k] = last
        return out
    start = np.zeros(N) if q_start is None else np.asarray(q_start, dtype=float)
    prev = np.vstack([start[None], q[:-1]])
    step = np.sign(q - prev)
    out = np.empty_like(step)
    last = np.ones(N)
    for k in range(len(q)):
        last = np.where(step[k] != 0, step[k], last)
        out[k] = last
    return out


def _joint_axes(model: RobotModel, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis origins and directions ``(n, N, 3)`` of the N joints of a DH/MDH chain in the base frame."""
    # MDH: joint i turns about z of frame i; DH: about z of frame i-1.
    N = frames.shape[1] - 1
    idx = np.arange(1, N + 1) if model.convention == "mdh" else np.arange(0, N)
    sel = frames[:, idx]  # (n, 6, 4, 4)
    return sel[:, :, :3, 3], sel[:, :, :3, 2]


def joint_frames(model: RobotModel, q: np.ndarray) -> np.ndarray:
    """The frame of every joint of a ``"urdf"`` chain in the base frame ``(n, N, 4, 4)``: its child frame, where
    the URDF's mass properties of what it moves are given (the chain's constant end transform taken off the last
    joint's frame, which :func:`twin.kinematics.link_frames` ends at the flange)."""
    if model.convention != "urdf":
        raise ValueError(f"joint_frames: model {model.name!r} is not a 'urdf' chain")
    F = link_frames(model, q)[:, 1:].copy()
    E = np.asarray(model.structure.end_origin, dtype=float).reshape(4, 4)
    F[:, -1] = F[:, -1] @ np.linalg.inv(E)
    return F


def _chain_axes(model: RobotModel, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Origins and unit axes ``(n, N, 3)`` of a ``"urdf"`` chain's joints in the base frame from their frames
    ``F`` (:func:`joint_frames`; a joint turns about, or slides along, its axis through its frame's origin)."""
    axes = np.array([j.axis for j in model.structure.joints], dtype=float)  # (N, 3) in the joint frames
    return F[:, :, :3, 3], np.einsum("nkij,kj->nki", F[:, :, :3, :3], axes)


def has_masses(model: RobotModel) -> bool:
    """Whether ``model`` is a ``"urdf"`` chain whose joints carry the mass properties of what they move."""
    return model.convention == "urdf" and any(j.inertial for j in model.structure.joints)


def _masses(model: RobotModel, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Masses ``(N,)`` [kg] and centres of mass ``(n, N, 3)`` [m, base frame] of what each joint moves up to the
    next (its ``JointSpec.inertial``, given in its frame ``F``)."""
    N = model.n_joints
    mass = np.zeros(N)
    com = np.zeros((F.shape[0], N, 3))
    for i, j in enumerate(model.structure.joints):
        if j.inertial:
            mass[i] = float(j.inertial["mass"])
            com[:, i] = np.einsum("nij,j->ni", F[:, i, :3, :3], np.asarray(j.inertial["com"], float)) + F[:, i, :3, 3]
    return mass, com


def gravity_torques(model: RobotModel, q: np.ndarray, g: np.ndarray = GRAVITY) -> np.ndarray:
    """Gravity load ``(n, N)`` of every joint of a ``"urdf"`` chain from its mass properties: the torque [N m]
    about a revolute joint's axis, the force [N] along a prismatic one's. Recursive sum over the bodies each
    joint carries: ``tau_i = a_i . sum_{k >= i} (c_k - o_i) x m_k g`` (revolute), ``a_i . sum_{k >= i} m_k g``
    (prismatic), with ``o_i``, ``a_i`` the joint's origin and axis and ``c_k``, ``m_k`` the centre of mass and
    mass of what joint ``k`` moves up to the next joint (:attr:`twin.kinematics.JointSpec.inertial`)."""
    if not has_masses(model):
        raise ValueError(f"gravity_torques: model {model.name!r} carries no mass properties (a URDF chain with "
                         "<inertial> elements)")
    q = np.atleast_2d(np.asarray(q, dtype=float))
    F = joint_frames(model, q)
    o, a = _chain_axes(model, F)
    mass, com = _masses(model, F)
    N = model.n_joints
    # from the last joint down: the weight carried and its first moment about the base origin
    W = np.zeros((q.shape[0], 3))
    S = np.zeros((q.shape[0], 3))
    tau = np.zeros((q.shape[0], N))
    for i in range(N - 1, -1, -1):
        W = W + mass[i] * g
        S = S + mass[i] * np.cross(com[:, i], g)
        if model.joint_kinds[i] == "prismatic":
            tau[:, i] = np.einsum("ni,ni->n", a[:, i], W)
        else:
            tau[:, i] = np.einsum("ni,ni->n", a[:, i], S - np.cross(o[:, i], W))
    return tau


def carried_moments(model: RobotModel, q: np.ndarray, joint: int, g: np.ndarray = GRAVITY) -> np.ndarray:
    """The gravity moment ``(n, 3)`` [N m] of everything joint ``joint`` (1-based) of a ``"urdf"`` chain moves,
    about the joint's origin, in the joint's origin frame (its parent frame placed by the joint's origin, before
    its motion); ``joint = 0``: of everything the chain moves, about the base origin, in the base frame. What
    bends the support of that joint (or tilts the base: a mobile base on its wheels, a pedestal)."""
    if not has_masses(model):
        raise ValueError(f"carried_moments: model {model.name!r} carries no mass properties")
    N = model.n_joints
    if not 0 <= joint <= N:
        raise ValueError(f"carried_moments: joint must be in 0..{N}, got {joint!r}")
    q = np.atleast_2d(np.asarray(q, dtype=float))
    F = joint_frames(model, q)
    mass, com = _masses(model, F)
    if joint == 0:
        o = np.zeros((q.shape[0], 3))
        R = np.broadcast_to(np.eye(3), (q.shape[0], 3, 3))
    else:
        parent = np.broadcast_to(np.eye(4), (q.shape[0], 4, 4)) if joint == 1 else F[:, joint - 2]
        before = parent @ model.structure.joints[joint - 1].origin
        o, R = before[:, :3, 3], before[:, :3, :3]
    k0 = max(joint - 1, 0)
    M = np.zeros((q.shape[0], 3))
    for k in range(k0, N):
        M += np.cross(com[:, k] - o, mass[k] * g)
    return np.einsum("nji,nj->ni", R, M)


# the latest regressors, given again for the same model and rows (the pools, the load terms, the change places and the
# feature values each ask for it on the same rows): 4 of them, at most 16 MB
_REGRESSORS = KeptResults(4, 1 << 24)


def gravity_torque_regressor(model: RobotModel, q: np.ndarray, g: np.ndarray = GRAVITY) -> np.ndarray:
    """Gravity torques as a linear map of the links' mass moments: ``(n, N, N, 4)``.

    ``tau_i(q) = sum_{k >= i} Y[:, i, k] @ (m_k, h_k)`` with ``h_k = m_k c_k`` the first mass moment of link
    ``k`` in its own frame ``k``. For a link ``k`` moved by joint ``i`` (axis through ``o_i`` along ``z_i``),
    ``tau = z_i . ((p_ck - o_i) x m_k g)`` and ``m_k p_ck = m_k o_k + R_k h_k`` give
    ``Y[:, i, k] = (z_i . ((o_k - o_i) x g), R_k^T (g x z_i))``; for a prismatic joint ``i`` (a ``"urdf"`` chain)
    the force along its axis, ``Y[:, i, k] = (z_i . g, 0, 0, 0)``. Link frames: a DH/MDH chain's frames 1..N; a
    ``"urdf"`` chain's joint frames (:func:`joint_frames`). The latest few are kept and given again for the same
    model and the same ``q`` and ``g`` to the bit (read-only).
    """
    key = (id(model), array_key(q), array_key(g))
    return _REGRESSORS.get_or_compute(key, lambda: _gravity_torque_regressor(model, q, g), (model,))


def _gravity_torque_regressor(model: RobotModel, q: np.ndarray, g: np.ndarray) -> np.ndarray:
    """:func:`gravity_torque_regressor` computed."""
    if model.convention == "urdf":
        F = joint_frames(model, q)
        o_axis, z_axis = _chain_axes(model, F)
        frames = np.concatenate([np.broadcast_to(np.eye(4), (F.shape[0], 1, 4, 4)), F], axis=1)
        prismatic = model.is_prismatic
    else:
        frames = link_frames(model, q)
        o_axis, z_axis = _joint_axes(model, frames)
        prismatic = np.zeros(model.n_joints, bool)
    n, N = frames.shape[0], frames.shape[1] - 1
    Y = np.zeros((n, N, N, 4))
    for i in range(N):
        if prismatic[i]:
            Y[:, i, i:, 0] = (z_axis[:, i] @ g)[:, None]
            continue
        gxz = np.cross(g, z_axis[:, i])  # (n, 3)
        for k in range(i, N):
            o_k = frames[:, k + 1, :3, 3]
            R_k = frames[:, k + 1, :3, :3]
            Y[:, i, k, 0] = np.einsum("ni,ni->n", z_axis[:, i], np.cross(o_k - o_axis[:, i], g))
            Y[:, i, k, 1:] = np.einsum("nji,nj->ni", R_k, gxz)
    return Y


def base_moment_regressor(model: RobotModel, q: np.ndarray, g: np.ndarray = GRAVITY) -> np.ndarray:
    """The arm's gravity moment about the base's ``x`` and ``y`` axes through its origin as a linear map of the links'
    mass moments: ``(n, 2, N, 4)``, ``M_a(q) = sum_k Y[:, a, k] @ (m_k, h_k)`` with ``h_k = m_k c_k`` in link frame
    ``k`` (the frames of :func:`gravity_torque_regressor`):
    ``Y[:, a, k] = (e_a . (o_k x g), R_k^T (g x e_a))``."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if model.convention == "urdf":
        F = joint_frames(model, q)
    else:
        F = link_frames(model, q)[:, 1:model.n_joints + 1]
    n, N = F.shape[0], F.shape[1]
    Y = np.zeros((n, 2, N, 4))
    for a in (0, 1):
        e = np.zeros(3)
        e[a] = 1.0
        gxe = np.cross(g, e)
        for k in range(N):
            o, R = F[:, k, :3, 3], F[:, k, :3, :3]
            Y[:, a, k, 0] = np.cross(o, g) @ e
            Y[:, a, k, 1:] = np.einsum("nji,j->ni", R, gxe)
    return Y
