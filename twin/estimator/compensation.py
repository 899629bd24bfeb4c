"""Compensation: corrected joint commands for target poses by iterative inverse kinematics on the
identified model (the separation paper's section 2.4)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..kinematics import (
    IKTraceEntry,
    UnreachableError,
    closest_branch,
    inverse_kinematics_closed_form,
    inverse_kinematics_iterative,
    wrap_angle,
)
from ..transforms import invert_transform
from .calibration import Calibration

__all__ = ["CompensationResult", "compensation", "compensate"]


@dataclass(frozen=True)
class CompensationResult:
    """``q`` ``(n, N)`` commands [rad, m for prismatic joints]; ``q_nominal`` the nominal model's answer (what an
    uncalibrated controller would command); ``position_error`` [m] / ``rotation_error`` [rad] of the calibrated model at
    ``q`` against the targets; ``iterations``; the IK trace."""

    q: np.ndarray
    q_nominal: np.ndarray
    position_error: np.ndarray
    rotation_error: np.ndarray
    iterations: int
    trace: tuple[IKTraceEntry, ...]


def compensation(
    calibration: Calibration,
    targets_tool2base: np.ndarray,
    q_ref: np.ndarray,
    *,
    tol_position: float = 1e-9,
    tol_rotation: float = 1e-9,
    max_iter: int = 100,
    callback: Callable[[IKTraceEntry], None] | None = None,
) -> CompensationResult:
    """Joint commands that put the plate at ``targets_tool2base`` ``(n, 4, 4)`` (plate frame in the robot base
    frame of the calibration) on the *identified* robot.

    1. Start: for a 6R arm with a spherical wrist, the nominal model's closed-form inverse (target through the
       nominal ``tool2flange``), the branch nearest ``q_ref`` ``(n, N)`` or ``(N,)`` inside the joint limits;
       for any other chain the nominal model's iterative inverse from ``q_ref`` (a redundant chain takes
       minimum-norm steps, so it stays near the reference).
    2. Newton iteration ``q <- q + J^+ e`` on the identified model's forward kinematics (tool frame, with the
       identified ``tool2flange``) until position and rotation errors are below ``tol_position`` [m] /
       ``tol_rotation`` [rad].

    Raises :class:`~twin.kinematics.UnreachableError` naming the targets the nominal model cannot reach
    within the limits, that the iteration does not bring within tolerance, or whose corrected command leaves
    the joint limits.
    """
    T = np.asarray(targets_tool2base, dtype=float)
    if T.ndim == 2:
        T = T[None]
    if T.ndim != 3 or T.shape[1:] != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"targets_tool2base must be finite (n, 4, 4) transforms, got shape {T.shape}")
    R = T[:, :3, :3]
    if np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max() > 1e-6:
        raise ValueError("targets_tool2base: rotation parts are not orthonormal")
    n = T.shape[0]
    nominal = calibration.nominal
    nj = nominal.n_joints
    try:
        q_ref = np.broadcast_to(np.asarray(q_ref, dtype=float), (n, nj))
    except ValueError:
        raise ValueError(f"q_ref must have shape ({n}, {nj}) or ({nj},), got {np.shape(q_ref)}") from None
    if not np.all(np.isfinite(q_ref)):
        raise ValueError("q_ref must be finite [rad, m for prismatic joints]")
    flange_nom = T @ invert_transform(nominal.tool2flange)
    try:
        sols = inverse_kinematics_closed_form(nominal, flange_nom)
    except ValueError:
        sols = None
    if sols is not None:
        q0 = closest_branch(sols, q_ref)  # raises UnreachableError naming the targets
    else:
        start = np.clip(q_ref, nominal.q_min, nominal.q_max)
        ik0 = inverse_kinematics_iterative(nominal, T, start, frame="tool", tol_position=tol_position,
                                           tol_rotation=tol_rotation, max_iter=max_iter)
        bad0 = np.flatnonzero(~ik0.converged)
        if bad0.size:
            raise UnreachableError(f"targets {bad0[:10].tolist()}: the nominal model does not reach them from the "
                                   f"reference joints (position error {ik0.position_error[bad0].max():.3g} m)")
        q0 = ik0.q
    robot = calibration.robot
    ik = inverse_kinematics_iterative(
        robot, T, q0, frame="tool", tol_position=tol_position, tol_rotation=tol_rotation, max_iter=max_iter,
        callback=callback,
    )
    # keep the command in the same turn as the nominal start (the iteration moves it by a tiny amount)
    if nominal.is_prismatic.any():
        q = np.where(nominal.is_prismatic, ik.q, q0 + wrap_angle(ik.q - q0))
    else:
        q = q0 + wrap_angle(ik.q - q0)
    bad = np.flatnonzero(~ik.converged)
    if bad.size:
        raise UnreachableError(
            f"targets {bad[:10].tolist()}: the identified model does not reach them (position error "
            f"{ik.position_error[bad].max():.3g} m, rotation error {ik.rotation_error[bad].max():.3g} rad after "
            f"{ik.iterations} iterations)"
        )
    out = np.flatnonzero(~robot.within_limits(q, tol=1e-9))
    if out.size:
        raise UnreachableError(f"targets {out[:10].tolist()}: the corrected joint command leaves the joint limits")
    return CompensationResult(
        q=q, q_nominal=q0, position_error=ik.position_error, rotation_error=ik.rotation_error,
        iterations=ik.iterations, trace=ik.trace,
    )


def compensate(calibration: Calibration, targets_tool2base: np.ndarray, q_ref: np.ndarray) -> np.ndarray:
    """Corrected joint commands ``(n, N)`` for plate targets in the base frame (see :func:`compensation`)."""
    return compensation(calibration, targets_tool2base, q_ref).q
