"""robotkinecal (PyPI ``robotkinecal``): product-of-exponentials calibration (Li et al. 2016, adjoint error
model), 4 parameters per joint screw + the zero-configuration end-effector pose.

Driven as its README's "custom robot from a URDF" example intends: the robot is a Robotics Toolbox model read
from a URDF (ours, written by :mod:`experiments.peers.urdf`), then
``SerialRobotKineCal(robot, ee_name="tool")``, ``set_observations(joints, observations)`` and ``solve()``
(its defaults: at most 100 iterations, step 1.0, stop when the twist-error norm changes by less than 1e-4).
Observations are ``spatialmath.SE3`` poses (variant ``pose``) or 3-vectors (variant ``position``), both
documented.

Where it cannot use the data as given:
* it has no base frame: observations are taken in the model's base frame. The screws are free, so a model
  expressed in a measurement frame fits as well; we write the URDF with a ``meas`` root placed by the same
  closed-form registration the other peers without an initialisation get
  (:func:`experiments.peers.common.register_base_and_tool`), and the tool point from it;
* it weighs position [m] and orientation [rad] errors alike (no measurement weights): with 0.02 mm / 0.002 rad
  the orientation rows dominate the fit, and its spatial twist error mixes orientation into position through
  the 2 m lever of the measurement frame;
* ``B_Matrix`` draws random directions from NumPy's global generator: we seed it (``np.random.seed(0)``) so
  runs repeat.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from twin.kinematics import RobotModel

from .common import PeerResult, PeerUnavailable, register_base_and_tool, run_quietly, timed
from .urdf import write_urdf

__all__ = ["NAME", "available", "calibrate"]

NAME = "robotkinecal"

SETTINGS = {
    "model": "Robotics Toolbox robot from our URDF (nominal joints, meas root at the registered base frame)",
    "solver": "SerialRobotKineCal.solve() defaults (max_iterations=100, step_size=1.0, tolerance 1e-4)",
    "weights": "none (the library has no measurement weights)",
}


def available() -> bool:
    try:
        import robotkinecal  # noqa: F401
    except ImportError:
        return False
    return True


def _load_robot(path: str):
    import warnings

    import roboticstoolbox as rtb

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Robot.URDF is deprecated in RTB 1.5; the README uses it
        return rtb.Robot.URDF(path)


def calibrate(
    nominal: RobotModel, q_cal: np.ndarray, tool2meas_cal: np.ndarray, q_val: np.ndarray, variant: str = "pose"
) -> PeerResult:
    """Calibrate with pose (``variant="pose"``) or position (``"position"``) observations; predict validation."""
    if variant not in ("pose", "position"):
        raise ValueError(f"variant must be 'pose' or 'position', got {variant!r}")
    try:
        from robotkinecal import SerialRobotKineCal
        from spatialmath import SE3
    except ImportError as e:
        raise PeerUnavailable(f"robotkinecal is not installed ({e}); pip install .[peers]") from e
    q_cal = np.asarray(q_cal, dtype=float)
    T = np.asarray(tool2meas_cal, dtype=float)
    if variant == "pose":
        obs = [SE3(Ti, check=False) for Ti in T]
        used = "positions and orientations (unweighted); base frame via the registered URDF root"
    else:
        obs = [Ti[:3, 3].copy() for Ti in T]
        used = "positions only; base frame via the registered URDF root"
    joints = [qi for qi in q_cal]
    tmp = tempfile.TemporaryDirectory()

    def fit():
        base2meas, tool_point = register_base_and_tool(nominal, q_cal, T[:, :3, 3])
        start = nominal.with_frames(tool2flange=_translation(tool_point))
        path = write_urdf(Path(tmp.name) / "irb1200.urdf", start, base2meas=base2meas)
        robot = _load_robot(path)
        np.random.seed(0)
        cal = SerialRobotKineCal(robot, ee_name="tool", verbose=False)
        cal.set_observations(joints, obs)
        result = cal.solve()
        return cal, result

    try:
        with run_quietly() as log:
            seconds, (cal, result) = timed(fit)
    except Exception as e:
        tmp.cleanup()
        return PeerResult(NAME, variant, None, None, None, SETTINGS, used, error=f"{type(e).__name__}: {e}")
    tmp.cleanup()
    pred = [cal.forward_kinematics(cal.N_JOINTS + 1, qv).A for qv in np.asarray(q_val, dtype=float)]
    pred = np.array(pred)
    status = "converged" if result.has_converged else ("diverging" if result.is_diverging else "max iterations")
    notes = [f"{result.nb_iterations_executed} iterations, {status}"]
    warn = [ln for ln in log.getvalue().splitlines() if "WARNING" in ln]
    if warn:
        notes.append(warn[0])
    error = None if result.has_converged else f"did not converge ({status})"
    return PeerResult(
        NAME, variant, pred[:, :3, 3], pred[:, :3, :3] if variant == "pose" else None, seconds, SETTINGS, used,
        error=error, notes=tuple(notes),
    )


def _translation(t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = t
    return T
