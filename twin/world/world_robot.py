"""The world's robot: commanded joints -> actual joints through the effects, the command history, gravity statics.

A part of :class:`twin.world.World` (it uses the model, data and effects the world builds).
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from ..kinematics import N_JOINTS, RobotModel
from ..transforms import matrix_to_quat_wxyz
from . import mjcf
from .effects import EffectContext, apply_geometry_effects, apply_joint_effects

__all__ = ["WorldRobot"]


class WorldRobot:
    """Commanded -> actual joints of :class:`twin.world.World`: history, effects and gravity torques."""

    def temperature_c(self, t_s: float) -> float | None:
        """The robot's true temperature [°C] at ``t_s`` [s] when an effect defines it (the first effect with a
        ``temperature_c(t_s)`` that is not ``None``, e.g. ``thermal`` in warm-up mode), else ``None``."""
        for e in self.effects:
            f = getattr(e, "temperature_c", None)
            if callable(f):
                T = f(t_s)
                if T is not None:
                    return float(T)
        return None

    def reset_history(self, q_start: np.ndarray | None = None) -> None:
        """Start a new campaign: forget the commands executed so far; the robot starts at ``q_start`` ``(6,)``
        [rad] (``None``: home, all zeros). History-dependent effects (backlash) take the first approach from it."""
        self._history = []
        self._prev = None
        if q_start is not None:
            q_start = np.asarray(q_start, dtype=float).reshape(-1)
            if q_start.shape != (N_JOINTS,) or not np.all(np.isfinite(q_start)):
                raise ValueError(f"q_start must be {N_JOINTS} finite joint angles [rad], got {q_start!r}")
        self._q_start = None if q_start is None else q_start.copy()

    @property
    def command_history(self) -> np.ndarray:
        """Commands ``(k, 6)`` [rad] executed by :meth:`capture` since :meth:`reset_history`, in order."""
        return np.array(self._history).reshape(-1, N_JOINTS)

    def _context(self, context: EffectContext | None, station: int, q_cmd: np.ndarray) -> EffectContext:
        """The context of one measurement, completed from the world's own record where the caller left gaps.

        No context, or one without ``q_cmd_prev`` and ``q_cmd_history``: the history is the commands this
        world executed since :meth:`reset_history`. A context with ``q_cmd_prev`` but no history is left as is
        (history-dependent effects refuse it). A world with a temperature profile sets ``temp_c``.
        """
        ctx = context if context is not None else EffectContext(pose_index=len(self._history), station=station)
        fill: dict[str, Any] = {}
        if ctx.world is None:
            fill["world"] = self
        if ctx.q_cmd is None:
            fill["q_cmd"] = q_cmd
        if ctx.q_cmd_prev is None and ctx.q_cmd_history is None:
            fill["q_cmd_history"] = self.command_history
            if ctx.q_actual_prev is None and self._prev is not None:
                fill["q_actual_prev"] = self._prev[1].copy()
        if ctx.q_start is None and self._q_start is not None:
            fill["q_start"] = self._q_start
        T = self.temperature_c(ctx.t_s)
        if T is not None:
            fill["temp_c"] = T
        return ctx.with_(**fill) if fill else ctx

    def _check_q(self, q_cmd: np.ndarray) -> np.ndarray:
        q = np.asarray(q_cmd, dtype=float).reshape(-1)
        if q.shape != (N_JOINTS,) or not np.all(np.isfinite(q)):
            raise ValueError(f"q_cmd must be {N_JOINTS} finite joint angles [rad], got {q_cmd!r}")
        return q

    def _evaluate(self, q_cmd: np.ndarray, ctx: EffectContext) -> tuple[RobotModel, np.ndarray]:
        """Geometry effects (applied to the MuJoCo model; the caller restores), then joint effects."""
        robot = apply_geometry_effects(self.effects, self.true_robot, ctx)
        self._apply_geometry(robot)
        return robot, apply_joint_effects(self.effects, q_cmd, ctx)

    def actual_joints(self, q_cmd: np.ndarray, context: EffectContext | None = None) -> np.ndarray:
        """Actual joints ``(6,)`` [rad] for commanded ``q_cmd`` ``(6,)`` [rad]: the joint effects in order (on the
        geometry of this measurement). Pure given the context: it does not advance the world's history."""
        q_cmd = self._check_q(q_cmd)
        ctx = self._context(context, context.station if context else 0, q_cmd)
        try:
            return self._evaluate(q_cmd, ctx)[1]
        finally:
            self._apply_geometry(self.true_robot)

    def gravity_torque(self, q_actual: np.ndarray, *, payload_kg: float = 0.0,
                       payload_com_tool: np.ndarray | None = None) -> np.ndarray:
        """Torque ``(6,)`` [N m] that gravity exerts on each joint of the robot at rest at ``q_actual`` [rad].

        Computed by MuJoCo from the twin's own bodies (masses, centres of mass: the arm, flange, plate, posts
        and spheres; gravity ``model.opt.gravity``) on the current geometry: ``-qfrc_bias`` at zero velocity.
        ``mj_rne`` needs the body poses (``mj_kinematics``), the composite inertias and motion axes
        (``mj_comPos``) and the body velocities (``mj_comVel``, zero here, so no Coriolis term enters);
        ``mj_forward`` would add actuation and constraint stages this does not need. An optional point
        payload ``payload_kg`` [kg] at ``payload_com_tool`` ``(3,)`` [m] (plate frame) adds ``J_p^T m g`` with
        its point Jacobian from ``mj_jac``.
        """
        q = np.asarray(q_actual, dtype=float).reshape(-1)
        if q.shape != (N_JOINTS,) or not np.all(np.isfinite(q)):
            raise ValueError(f"q_actual must be {N_JOINTS} finite joint angles [rad], got {q_actual!r}")
        m, d = self.model, self._statics
        d.qpos[self._qadr] = q
        d.qvel[:] = 0.0
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_comVel(m, d)
        bias = np.zeros(m.nv)
        mujoco.mj_rne(m, d, 0, bias)
        tau = -bias[self._dofadr]
        if payload_kg:
            if not (np.isfinite(payload_kg) and payload_kg > 0):
                raise ValueError(f"payload_kg must be a non-negative mass [kg], got {payload_kg!r}")
            c = np.zeros(3) if payload_com_tool is None else np.asarray(payload_com_tool, dtype=float).reshape(3)
            R = d.xmat[self._plate_body].reshape(3, 3)
            point = d.xpos[self._plate_body] + R @ c
            jacp = np.zeros((3, m.nv))
            mujoco.mj_jac(m, d, jacp, None, point, self._plate_body)
            tau = tau + (jacp.T @ (payload_kg * m.opt.gravity))[self._dofadr]
        return tau

    def _apply_geometry(self, robot: RobotModel) -> None:
        """Move the MuJoCo bodies and hinges to ``robot``'s geometry (same structure as the true robot)."""
        if robot is self._geometry_robot:
            return
        jg = self._true_jg if robot is self.true_robot else mjcf.joint_geometry(robot)
        m = self.model
        frames = [robot.base2meas] + [j.body2parent for j in jg] + [robot.tool2flange]
        for b, T in zip(self._robot_bodies, frames):
            m.body_pos[b] = T[:3, 3]
            m.body_quat[b] = matrix_to_quat_wxyz(T[:3, :3])
        for j, g in zip(self._jnt_ids, jg):
            m.jnt_pos[j] = g.anchor
            m.jnt_axis[j] = g.axis
        self._geometry_robot = robot
