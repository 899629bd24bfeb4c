"""Compensation: corrected joint commands for target poses by iterative inverse kinematics on the
identified model (the separation paper's section 2.4)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..kinematics import (
    IKTraceEntry,
    RobotModel,
    UnreachableError,
    closest_branch,
    inverse_kinematics_closed_form,
    inverse_kinematics_iterative,
    joint_jacobian,
    pose_error,
    tool2base,
    wrap_angle,
)
from ..transforms import invert_transform, make_transform
from .calibration import Calibration

__all__ = ["CompensationResult", "compensation", "compensate", "compensation_position", "point_frame", "measured_pose"]

_POSE_POINTS_TOL_M = 1e-9  # [m] a marker set this close to three points on the tool's axes is a pose read as points
_HOLD_WEIGHT_M_PER_RAD = 0.1  # [m/rad] the held orientation against the position in the first pass of a position target
_KEEP_WEIGHT_M_PER_RAD = 1e-4  # [m/rad] the same in the second pass: the position first, the orientation kept near


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
       for any other chain the nominal model's damped least squares (:func:`_levenberg_marquardt`) from ``q_ref``,
       converged or not (a start: the nominal model may miss a target the identified one reaches).
    2. Newton iteration ``q <- q + J^+ e`` on the identified model's forward kinematics (tool frame, with the
       identified ``tool2flange``) until position and rotation errors are below ``tol_position`` [m] /
       ``tol_rotation`` [rad]; on a chain without the closed form, the rows it leaves are solved again by damped
       least squares from the start, then from the reference joints (near a singular configuration Newton's
       steps overshoot).
    3. A command outside the joint limits (a target that holds a joint at its limit, which Newton's last step
       crossed by a hair): the command clipped to the limits, else damped least squares within them from the start
       and from the reference joints, kept where the pose is still met within 10 x the tolerances.

    Raises :class:`~twin.kinematics.UnreachableError` naming the targets the nominal 6R model cannot reach
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
    q_ref = _reference_joints(q_ref, n, nj)
    flange_nom = T @ invert_transform(nominal.tool2flange)
    try:
        sols = inverse_kinematics_closed_form(nominal, flange_nom)
    except ValueError:
        sols = None
    if sols is not None:
        q0 = closest_branch(sols, q_ref)  # raises UnreachableError naming the targets
    else:
        start = np.clip(q_ref, nominal.q_min, nominal.q_max)
        q0 = _levenberg_marquardt(nominal, T, start, max_iter=max_iter)[0]
    robot = calibration.robot
    ik = inverse_kinematics_iterative(
        robot, T, q0, frame="tool", tol_position=tol_position, tol_rotation=tol_rotation, max_iter=max_iter,
        callback=callback,
    )
    q_ik, ep, er = ik.q, ik.position_error, ik.rotation_error
    bad = np.flatnonzero(~ik.converged)
    if bad.size and sols is None:
        q_ik, ep, er = q_ik.copy(), ep.copy(), er.copy()
        for q_start in (q0, start):  # from the nominal answer, then from the reference joints
            q_lm, ep_lm, er_lm, _ = _levenberg_marquardt(robot, T[bad], q_start[bad], max_iter=max_iter)
            q_ik[bad], ep[bad], er[bad] = q_lm, ep_lm, er_lm
            bad = bad[~((ep_lm <= 10 * tol_position) & (er_lm <= 10 * tol_rotation))]
            if not bad.size:
                break
    # keep the command in the same turn as the nominal start (the iteration moves it by a tiny amount)
    if nominal.is_prismatic.any():
        q = np.where(nominal.is_prismatic, q_ik, q0 + wrap_angle(q_ik - q0))
    else:
        q = q0 + wrap_angle(q_ik - q0)
    if bad.size:
        raise UnreachableError(
            f"targets {bad[:10].tolist()}: the identified model does not reach them (position error "
            f"{ep[bad].max():.3g} m, rotation error {er[bad].max():.3g} rad after {ik.iterations} iterations)"
        )
    out = np.flatnonzero(~robot.within_limits(q, tol=1e-9))
    if out.size:
        q, ep, er = q.copy(), ep.copy(), er.copy()
        out = _within_limits(robot, T, q, ep, er, out, (q0, np.clip(q_ref, nominal.q_min, nominal.q_max)),
                             tol_position, tol_rotation, max_iter)
    if out.size:
        raise UnreachableError(f"targets {out[:10].tolist()}: the corrected joint command leaves the joint limits")
    return CompensationResult(
        q=q, q_nominal=q0, position_error=ep, rotation_error=er,
        iterations=ik.iterations, trace=ik.trace,
    )


def _within_limits(robot: RobotModel, T: np.ndarray, q: np.ndarray, ep: np.ndarray, er: np.ndarray,
                   out: np.ndarray, starts: tuple[np.ndarray, ...], tol_position: float, tol_rotation: float,
                   max_iter: int) -> np.ndarray:
    """The rows ``out`` whose command ``q`` ``(n, N)`` leaves the joint limits, answered within them where the
    identified model reaches the target ``T`` there: the command clipped to the limits (a joint the target holds at
    its limit, which Newton's last step crossed by a hair in a direction the pose barely sees), else damped least
    squares within the limits from each of ``starts`` ``(n, N)``; accepted where the pose error stays within 10 x
    the tolerances. Updates ``q``, ``ep``, ``er`` in place; returns the rows still outside."""
    m = robot.with_frames(base2meas=np.eye(4))
    q_clip = np.clip(q[out], robot.q_min, robot.q_max)
    e = pose_error(T[out], tool2base(m, q_clip))
    tries = [lambda rows, qc=q_clip, e=e: (qc[rows], np.linalg.norm(e[rows, :3], axis=1),
                                          np.linalg.norm(e[rows, 3:], axis=1))]
    tries += [lambda rows, s=s: _levenberg_marquardt(robot, T[out[rows]], s[out[rows]], max_iter=max_iter)[:3]
              for s in starts]
    left = np.arange(out.size)  # positions in ``out`` still outside
    for attempt in tries:
        q_c, ep_c, er_c = attempt(left)
        ok = (ep_c <= 10 * tol_position) & (er_c <= 10 * tol_rotation) & robot.within_limits(q_c, tol=1e-9)
        rows = out[left[ok]]
        q[rows], ep[rows], er[rows] = q_c[ok], ep_c[ok], er_c[ok]
        left = left[~ok]
        if not left.size:
            break
    return out[left]


def compensate(calibration: Calibration, targets_tool2base: np.ndarray, q_ref: np.ndarray) -> np.ndarray:
    """Corrected joint commands ``(n, N)`` for plate targets in the base frame (see :func:`compensation`)."""
    return compensation(calibration, targets_tool2base, q_ref).q


def point_frame(calibration: Calibration) -> np.ndarray:
    """``point2tool`` ``(4, 4)``: the point a position-only target places, as a frame with the tool's orientation: the
    tool origin of a calibration on 6-DOF poses (a tracker's probe; also when ``twin diagnose`` read the poses as
    three points on the tool's axes at one distance), else the first marker point ``p0`` (a laser tracker's one
    reflector)."""
    if measured_pose(calibration):
        return np.eye(4)
    return make_transform(np.eye(3), np.asarray(calibration.spheres_tool, dtype=float)[0])


def measured_pose(calibration: Calibration) -> bool:
    """Whether ``calibration`` was fitted to 6-DOF poses of its tool (a tracker's probe): its measurement is
    ``pose``, or ``twin diagnose`` read the poses as three points on the tool's axes at one distance."""
    pts = np.asarray(calibration.spheres_tool, dtype=float)
    return calibration.measurement == "pose" or bool(
        pts.shape == (3, 3) and pts[0, 0] > 0 and np.abs(pts - pts[0, 0] * np.eye(3)).max() < _POSE_POINTS_TOL_M)


def _levenberg_marquardt(model: RobotModel, T: np.ndarray, q0: np.ndarray, *, weight_rotation: float = 1.0,
                         position_only: bool = False, max_iter: int = 100, max_step: float = 0.2
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Damped least squares on ``model``'s tool frame, row by row: ``min |e_p|^2 + w^2 |e_r|^2`` over the joints
    (``e_p`` the position error [m], ``e_r`` the rotation vector of ``R_target R^T`` [rad], ``w`` =
    ``weight_rotation`` [m/rad]; ``position_only``: ``|e_p|^2`` alone), steps ``(J^T J + mu D + r I) dq = J^T e``
    with ``D`` the diagonal of ``J^T J`` (Marquardt's scaling) and ``r`` 1e-12 of its largest entry, a step kept
    only where it lowers the cost (``mu / 3``, else ``mu x 4``), at most ``max_step`` [rad, m] per joint and cut at
    the joint limits (a joint at a limit the step pushes against held for that step), until the kept steps are
    below 1e-13 or ``max_iter`` rounds. Targets ``T`` ``(n, 4, 4)`` in the base frame. Returns ``(q, |e_p| [m],
    |e_r| [rad], rounds)``."""
    m = model.with_frames(base2meas=np.eye(4))
    q = np.array(q0, dtype=float)
    n, N = q.shape
    w = np.array([1.0, 1.0, 1.0] + [0.0 if position_only else weight_rotation] * 3)

    def resid(qq, rows):
        return pose_error(T[rows], tool2base(m, qq)) * w

    e = resid(q, np.arange(n))
    cost = np.sum(e**2, axis=1)
    mu = np.full(n, 1.0)  # cautious first steps (a start near a singular configuration), Gauss-Newton once they hold
    active = np.ones(n, bool)
    it = 0
    for it in range(1, max_iter + 1):
        if not active.any():
            break
        k = np.flatnonzero(active)
        J = joint_jacobian(m, q[k], frame="base") * w[None, :, None]
        g = np.einsum("nji,nj->ni", J, e[k])
        # a joint at a limit that the step would push beyond it is held there (its column out of this step)
        held = ((q[k] <= model.q_min + 1e-12) & (g < 0)) | ((q[k] >= model.q_max - 1e-12) & (g > 0))
        J = np.where(held[:, None, :], 0.0, J)
        g = np.where(held, 0.0, g)
        H = np.swapaxes(J, 1, 2) @ J
        D = np.einsum("nii->ni", H)
        # Marquardt's scaling, and a ridge of 1e-12 of the largest diagonal: a joint that does not move the target,
        # or the null space of a redundant chain, keeps the system regular
        ridge = 1e-12 * D.max(axis=1) + 1e-300
        A = H + (mu[k, None] * D + ridge[:, None])[:, :, None] * np.eye(N)
        dq = np.linalg.solve(A, g[..., None])[..., 0]
        big = np.abs(dq).max(axis=1, keepdims=True)
        dq = dq * np.minimum(1.0, max_step / np.maximum(big, 1e-300))
        dq = np.clip(q[k] + dq, model.q_min, model.q_max) - q[k]  # within the joint limits
        e_new = resid(q[k] + dq, k)
        c_new = np.sum(e_new**2, axis=1)
        up = c_new < cost[k]
        q[k[up]] += dq[up]
        e[k[up]], cost[k[up]] = e_new[up], c_new[up]
        mu[k] = np.where(up, np.maximum(mu[k] / 3.0, 1e-12), mu[k] * 4.0)
        active[k] = ~((up & (np.abs(dq).max(axis=1) < 1e-13)) | (mu[k] > 1e12) | (cost[k] < 1e-30))
    e = pose_error(T, tool2base(m, q))
    return q, np.linalg.norm(e[:, :3], axis=1), np.linalg.norm(e[:, 3:], axis=1), it


def _position_first(model: RobotModel, p: np.ndarray, R_hold: np.ndarray, q0: np.ndarray, *, max_iter: int
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """The position ``p`` ``(n, 3)`` [m] of ``model``'s tool origin first, the orientation ``R_hold`` ``(n, 3, 3)``
    as near as the chain can: damped least squares with the orientation weighted 0.1 m/rad (near both), then
    1e-4 m/rad (the position first, the orientation kept where the chain allows), then the position alone (the last
    fraction of a nanometre; with six joints or more and the limits away both are met exactly). Returns ``(q,
    position error [m], rotation error [rad], rounds)``."""
    T = make_transform(R_hold, p)
    q, it = np.array(q0, dtype=float), 0
    for w in (_HOLD_WEIGHT_M_PER_RAD, _KEEP_WEIGHT_M_PER_RAD):
        q, _, _, k = _levenberg_marquardt(model, T, q, weight_rotation=w, max_iter=max_iter)
        it += k
    q, ep, er, k = _levenberg_marquardt(model, T, q, position_only=True, max_iter=max_iter)
    return q, ep, er, it + k


def compensation_position(
    calibration: Calibration,
    targets_base: np.ndarray,
    q_ref: np.ndarray,
    *,
    tol_position: float = 1e-9,
    max_iter: int = 100,
) -> CompensationResult:
    """Joint commands that put the calibration's measured point (:func:`point_frame`: a laser tracker's one
    reflector, a pose's origin) at the positions ``targets_base`` ``(n, 3)`` [m] in the robot base frame of the
    calibration, holding the tool orientation the *identified* robot has at the reference joints ``q_ref``
    ``(n, N)`` or ``(N,)`` as far as the chain can (exactly with six joints or more, in what the position leaves
    free with fewer).

    Math (:func:`_position_first`): damped least squares ``min |e_p|^2 + w^2 |e_r|^2`` (``w`` = 0.1 m/rad, then
    1e-4 m/rad), then ``min |e_p|^2`` alone from there, from ``q_ref`` (clipped to the joint limits), first on the
    nominal model (``q_nominal``: an uncalibrated controller's answer), then from there on the identified one;
    ``e_p`` is the point's position error, ``e_r`` the rotation vector of ``R_hold R^T``. Targets left beyond 10 x
    ``tol_position``: ``min |e_p|^2`` alone again from where the stages stopped (a slow approach near a singular
    configuration), from the nominal answer and from ``q_ref`` (a chain that cannot hold the orientation is led
    away from the position by the stages), the nearest answer kept. ``position_error`` [m] is
    what remains of the position on the identified model, ``rotation_error`` [rad] the orientation's departure from
    the held one.

    Raises :class:`~twin.kinematics.UnreachableError` naming the targets whose position the identified model
    does not reach within ``tol_position`` x 10, or whose command leaves the joint limits."""
    p = np.asarray(targets_base, dtype=float)
    if p.ndim == 1:
        p = p[None]
    if p.ndim != 2 or p.shape[1] != 3 or not np.all(np.isfinite(p)):
        raise ValueError(f"targets_base must be finite (n, 3) positions [m], got shape {p.shape}")
    n = p.shape[0]
    nominal = calibration.nominal
    nj = nominal.n_joints
    q_ref = _reference_joints(q_ref, n, nj)
    P = point_frame(calibration)
    robot = calibration.robot.with_frames(tool2flange=calibration.robot.tool2flange @ P)
    nom = nominal.with_frames(tool2flange=nominal.tool2flange @ P)
    start = np.clip(q_ref, nominal.q_min, nominal.q_max)
    R_hold = tool2base(robot.with_frames(base2meas=np.eye(4)), start)[:, :3, :3]
    q0, _, _, _ = _position_first(nom, p, R_hold, start, max_iter=max_iter)
    q, ep, er, it = _position_first(robot, p, R_hold, q0, max_iter=max_iter)
    bad = np.flatnonzero(~(ep <= 10 * tol_position))
    if bad.size:
        # the position alone, on: further from where the stages stopped (a slow approach to a point near a singular
        # configuration), then from the nominal answer and from the reference joints (holding the orientation led
        # a chain that cannot hold it away from the position); the nearest answer per target kept
        q, ep, er = q.copy(), ep.copy(), er.copy()
        T_bad = make_transform(R_hold[bad], p[bad])
        for q_start in (q, q0, start):
            q_lm, ep_lm, er_lm, k = _levenberg_marquardt(robot, T_bad, q_start[bad], position_only=True,
                                                         max_iter=max_iter)
            it += k
            better = ep_lm < ep[bad]
            q[bad[better]], ep[bad[better]], er[bad[better]] = q_lm[better], ep_lm[better], er_lm[better]
            keep = ~(ep[bad] <= 10 * tol_position)
            bad, T_bad = bad[keep], T_bad[keep]
            if not bad.size:
                break
    if nominal.is_prismatic.any():
        q = np.where(nominal.is_prismatic, q, start + wrap_angle(q - start))
    else:
        q = start + wrap_angle(q - start)
    bad = np.flatnonzero(~(ep <= 10 * tol_position))
    if bad.size:
        raise UnreachableError(f"targets {bad[:10].tolist()}: the identified model does not reach their position from "
                               f"the reference joints (left {ep[bad].max():.3g} m from it after {it} iterations)")
    out = np.flatnonzero(~robot.within_limits(q, tol=1e-9))
    if out.size:
        raise UnreachableError(f"targets {out[:10].tolist()}: the corrected joint command leaves the joint limits")
    return CompensationResult(q=q, q_nominal=q0, position_error=ep, rotation_error=er, iterations=it, trace=())


def _reference_joints(q_ref, n: int, nj: int) -> np.ndarray:
    """``q_ref`` ``(nj,)`` or ``(n, nj)`` [rad; m for prismatic joints] as an ``(n, nj)`` array; ``ValueError`` naming
    it when its shape does not broadcast or a value is not finite."""
    try:
        q = np.broadcast_to(np.asarray(q_ref, dtype=float), (n, nj))
    except ValueError:
        raise ValueError(f"q_ref must have shape ({n}, {nj}) or ({nj},), got {np.shape(q_ref)}") from None
    if not np.all(np.isfinite(q)):
        raise ValueError("q_ref must be finite [rad, m for prismatic joints]")
    return q
