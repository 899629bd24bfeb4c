"""pybotics (PyPI ``pybotics``): MDH chain + world and tool frames, fitted to measured *positions*.

Driven as its calibration example intends (``examples/calibration.ipynb``): a ``Robot`` built from MDH
parameters, an ``OptimizationHandler`` with masks choosing what to fit, and
``scipy.optimize.least_squares(pybotics.optimization.optimize_accuracy, ...)``, whose residual is the distance
between measured and modelled tool positions, one per pose. Lengths in millimetres, as in its examples.

Best settings (stated in the benchmark output):
* every MDH parameter that position data can identify is free: all of joints 2..6 except ``d`` of joint 3
  (parallel to joint 2: only d2 + d3 is seen) and ``theta``/``d`` of joint 6 (absorbed by the tool point);
  joint 1's four parameters are absorbed by the world frame and stay nominal;
* the world frame (6) and the tool position (3) are free; the tool orientation cannot be seen by one point;
* the world frame and tool point start from a closed-form registration of the nominal model to the measured
  positions (:func:`experiments.peers.common.register_base_and_tool`) -- pybotics has no initialisation of its
  own and starts at the identity otherwise, 2 m and 170 deg away from the truth;
* ``least_squares`` with the example's settings (its defaults: ``trf``, no scaling). Its per-pose *distance*
  residual converges slowly once the model error dominates: in development (100 poses, seed 1,
  0.02 mm / 0.002 rad) the defaults stopped on ``xtol`` after 23 evaluations (5.4 s) at 0.364 mm RMS on
  validation; ``method="lm", x_scale="jac"`` reached 0.311 mm after 300 evaluations (87 s) and 0.3105 mm after
  600 (192 s). We keep the example's call: 15 % better accuracy for 15-35x the time changes no conclusion
  (both stay more than 30x above the floor, from the missing beta).

What it cannot use: the measured orientations (position-only fit) and the beta tilt of the parallel pair 2-3
(pure MDH: a tilt about the common normal of two parallel axes is not representable without a huge ``d``),
so a 0.1 deg beta2 error stays in its model.
"""

from __future__ import annotations

from copy import deepcopy

import numpy as np
from scipy.optimize import least_squares

from twin.kinematics import RobotModel
from twin.units import MM_PER_M

from .common import PeerResult, PeerUnavailable, register_base_and_tool, run_quietly, timed

__all__ = ["NAME", "available", "mdh_table_mm", "build_robot", "calibrate"]

NAME = "pybotics"


def available() -> bool:
    try:
        import pybotics  # noqa: F401
    except ImportError:
        return False
    return True


def mdh_table_mm(model: RobotModel) -> np.ndarray:
    """pybotics' MDH link rows ``(6, 4)``: (alpha [rad], a [mm], theta [rad], d [mm]) -- Craig MDH, as ours.

    Raises ``ValueError`` when the model carries a non-zero beta (pybotics has no such parameter)."""
    if model.convention != "mdh":
        raise ValueError(f"model convention must be 'mdh' for pybotics, got {model.convention!r}")
    if np.any(model.beta != 0):
        raise ValueError(f"pybotics cannot represent beta != 0, got beta = {model.beta.tolist()}")
    return np.column_stack([model.alpha, model.a * MM_PER_M, model.theta, model.d * MM_PER_M])


def build_robot(model: RobotModel, base2meas: np.ndarray, tool_point: np.ndarray):
    """A ``pybotics.robot.Robot`` of ``model``'s joints with the given world frame and tool point [m]."""
    try:
        from pybotics.kinematic_chain import MDHKinematicChain
        from pybotics.robot import Robot
        from pybotics.tool import Tool
    except ImportError as e:  # pragma: no cover - depends on the extra
        raise PeerUnavailable(f"pybotics is not installed ({e}); pip install .[peers]") from e
    kc = MDHKinematicChain(mdh_table_mm(model))
    tool = Tool()
    tool.position = np.asarray(tool_point, dtype=float) * MM_PER_M
    world = np.array(base2meas, dtype=float)
    world[:3, 3] *= MM_PER_M
    robot = Robot(kc, tool=tool, world_frame=world)
    robot.joint_limits = np.vstack([model.q_min, model.q_max])
    return robot


def _mask() -> np.ndarray:
    m = np.ones((6, 4), dtype=bool)  # columns: alpha, a, theta, d
    m[0, :] = False  # joint 1: absorbed by the world frame
    m[2, 3] = False  # d3: parallel to joint 2
    m[5, 2] = m[5, 3] = False  # theta6, d6: absorbed by the tool point
    return m.ravel()


SETTINGS = {
    "residual": "pybotics.optimization.optimize_accuracy (distance per pose) [mm]",
    "solver": "scipy.optimize.least_squares defaults (trf), as in the pybotics calibration example",
    "free": "MDH joints 2-6 minus d3, theta6, d6 (17); world frame (6); tool position (3)",
    "start": "nominal MDH; world frame and tool point from a closed-form registration to the measured positions",
}


def calibrate(nominal: RobotModel, q_cal: np.ndarray, tool2meas_cal: np.ndarray, q_val: np.ndarray) -> PeerResult:
    """Fit pybotics to the calibration positions and predict the validation tool positions."""
    try:
        from pybotics.optimization import OptimizationHandler, optimize_accuracy
    except ImportError as e:
        raise PeerUnavailable(f"pybotics is not installed ({e}); pip install .[peers]") from e
    positions_mm = np.asarray(tool2meas_cal)[:, :3, 3] * MM_PER_M
    q_cal = np.asarray(q_cal, dtype=float)

    def fit():
        base2meas, tool_point = register_base_and_tool(nominal, q_cal, positions_mm / MM_PER_M)
        robot = build_robot(nominal, base2meas, tool_point)
        handler = OptimizationHandler(
            robot,
            kinematic_chain_mask=_mask().tolist(),
            tool_mask=[True, True, True, False, False, False],
            world_mask=True,
        )
        res = least_squares(
            optimize_accuracy,
            handler.generate_optimization_vector(),
            args=(handler, q_cal, positions_mm),
        )
        handler.apply_optimization_vector(res.x)
        return handler, res

    try:
        with run_quietly():
            seconds, (handler, res) = timed(fit)
    except Exception as e:  # the peer failing is a result, not a crash of the benchmark
        return PeerResult(NAME, "position", None, None, None, SETTINGS, "positions", error=f"{type(e).__name__}: {e}")
    fitted = deepcopy(handler.robot)
    pred = np.array([fitted.fk(q)[:3, 3] for q in np.asarray(q_val, dtype=float)]) / MM_PER_M
    notes = (f"least_squares: {res.message} ({res.nfev} evaluations)",)
    error = None if res.success else f"least_squares did not converge: {res.message}"
    return PeerResult(
        NAME, "position", pred, None, seconds, SETTINGS,
        "positions only (orientations unused: position-only fit); base frame via the world frame",
        error=error, notes=notes,
    )
