"""FIGAROH (pip ``figaroh``, with Pinocchio; the ``peers`` extra) run on the same files as ours: its own
``BaseCalibration`` with its unified config, marker 1 only, position only, base and tool estimated, at
``joint_offset`` and ``full_params``. Returns its per-posture validation errors from its own forward kinematics.

FIGAROH 1.0.2 leaves two frame flags to the robot-specific subclasses of its examples repository (which this
project does not read): ``known_baseframe`` and ``known_tipframe`` are set here to False (base and tool
estimated, as its reference run states)."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from twin.units import MM_PER_M

CONFIG = """robot:
  name: tiago
tasks:
  calibration:
    enabled: true
    type: kinematic_calibration
    parameters:
      calibration_level: {level}
      include_non_geometric: false
      outlier_threshold: 0.05
    kinematics:
      base_frame: universe
      tool_frame: {end_link}
      free_flying_base: false
    joints:
      active_joints: [{joints}]
    measurements:
      markers:
        - reference_joint: {last_joint}
          measurable_dof: [true, true, true, false, false, false]
      poses:
        base_pose: null
        tool_pose: null
    data:
      source_file: {training}
      validation_data_file: {validation}
      number_of_samples: {n_training}
"""


def available() -> str | None:
    """None when FIGAROH and Pinocchio import, else the reason they do not."""
    try:
        import figaroh  # noqa: F401
        import pinocchio  # noqa: F401
    except Exception as exc:  # any import failure means: quote instead
        return f"{type(exc).__name__}: {exc}"
    return None


def run_figaroh(urdf: Path, training: Path, validation: Path, end_link: str, joints: list[str], level: str) -> dict:
    """Calibrate with FIGAROH at ``level`` (``joint_offset`` / ``full_params``); per-posture errors [mm]."""
    import logging
    import warnings

    import pinocchio as pin
    from figaroh.calibration.base_calibration import BaseCalibration
    from figaroh.calibration.calibration_tools import calc_updated_fkm

    logging.getLogger("figaroh").setLevel(logging.ERROR)

    class Calibration(BaseCalibration):
        def cost_function(self, var):
            pee = calc_updated_fkm(self.model, self.data, var, self.q_measured, self.calib_config)
            return self.apply_measurement_weighting(self._compute_logmap_residuals(self.PEE_measured, pee))

    n_training = sum(1 for _ in open(training)) - 1
    model = pin.buildModelFromUrdf(str(urdf))
    robot = pin.RobotWrapper(model)
    with tempfile.TemporaryDirectory() as tmp:
        cfg = Path(tmp) / "calibration.yaml"
        cfg.write_text(CONFIG.format(level=level, end_link=end_link, joints=", ".join(joints), last_joint=joints[-1],
                                     training=training.resolve(), validation=validation.resolve(),
                                     n_training=n_training))
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cal = Calibration(robot, str(cfg))
            cal.calib_config["known_baseframe"] = False
            cal.calib_config["known_tipframe"] = False
            cal.initialize()
            result = cal.solve(enable_logging=False)
        seconds = time.perf_counter() - t0

        def errors(q, pee):
            conf = dict(cal.calib_config, NbSample=len(q))
            est = calc_updated_fkm(cal.model, cal.data, result.x, q, conf)
            res = cal._compute_logmap_residuals(pee, est, n_samples=len(q))
            return np.linalg.norm(np.asarray(res).reshape(3, len(q)), axis=0) * MM_PER_M

        e_val = errors(cal._q_val, cal._PEE_val)
        e_train = errors(cal.q_measured, cal.PEE_measured)
    return {"level": level, "parameters": list(cal.calib_config["param_name"]), "n_parameters": len(result.x),
            "values": [float(v) for v in result.x], "validation_errors_mm": e_val.tolist(),
            "training_errors_mm": e_train.tolist(), "seconds": seconds,
            "reported_rmse_mm": float(cal.evaluation_metrics["rmse"]) * MM_PER_M}
