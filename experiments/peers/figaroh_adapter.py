"""FIGAROH (PyPI ``figaroh``): Pinocchio model from a URDF, ``full_params`` calibration (a 6-DOF placement
error per joint), identifiable base parameters by QR, unknown base and tool frames, scipy Levenberg-Marquardt.

Driven as its examples do (``figaroh-examples``: ``ur10``, ``tiago``, ``tiago_pro``): a unified YAML config
(``tasks.calibration`` with ``kinematics``, ``measurements``, ``data``), the measured data as the CSV its loader
reads (``x1 y1 z1 phix1 phiy1 phiz1`` -- position [m] and roll-pitch-yaw [rad] of the marker in the measurement
frame -- and one column per active joint [rad]), a ``BaseCalibration`` subclass whose ``cost_function`` is the
SE(3) log-map residual passed through ``apply_measurement_weighting``, ``calib_config["known_baseframe"] =
calib_config["known_tipframe"] = False`` (both frames unknown: FIGAROH adds ``base_*`` and ``pEE*``/``phiEE*``
parameters and starts them from its own closed-form estimate), then ``initialize()`` and ``solve()``.

Best settings (stated in the benchmark output):
* ``calibration_level: full_params`` (every joint placement free; QR keeps the identifiable combinations, then
  the parameters absorbed by the frames are dropped on the data);
* residual weights ``1 / sigma`` from the true noise of the data (``measurement_std``), position error in the
  world (measurement) frame: the examples' fixed weights (UR10: 1 and 0.5) or no weights gave larger
  validation errors on this problem (checked in development);
* ``solve(method="lm", max_iterations=3)`` (its default; the outlier threshold of 5 cm never triggers here).

Position-only use (variant ``position``) keeps fewer parameters than the data identify: its structural QR on
position rows, then the data-level elimination of frame-absorbed parameters (which drops ``d_phix_joint2`` and
``d_pz_joint6`` here) leave 24 of the 27 identifiable directions, and the fit stays far above the noise (in
development: weighted residual RMS ~33 sigma, 0.65 mm on validation at 100 poses).

The URDF is written from our nominal model by :mod:`experiments.peers.urdf` (root ``base_link`` = robot base,
``tool`` = flange with the nominal identity tool frame).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from twin.kinematics import RobotModel

from .common import PeerResult, PeerUnavailable, run_quietly, timed
from .urdf import write_urdf

__all__ = ["NAME", "VARIANTS", "available", "calibrate", "config_yaml"]

NAME = "FIGAROH"
VARIANTS = ("pose", "pose-example-weights", "position")

SETTINGS = {
    "model": "URDF of the nominal IRB-1200 (Pinocchio); calibration_level full_params; base and tool frames unknown",
    "residual": "SE(3) log map, position in the measurement frame, weighted by 1/sigma of the data's noise",
    "solver": "BaseCalibration.solve(method='lm', max_iterations=3): scipy least_squares LM with outlier pass",
}


def available() -> bool:
    try:
        import figaroh  # noqa: F401
        import pinocchio  # noqa: F401
    except ImportError:
        return False
    return True


def config_yaml(data_file: str, n_samples: int, position_only: bool = False) -> str:
    """The unified FIGAROH configuration of the benchmark (one marker = the tool frame on ``joint6``)."""
    dof = "[true, true, true, false, false, false]" if position_only else "[true, true, true, true, true, true]"
    return f"""schema_version: "2.0"
robot:
  name: irb1200
  properties:
    joints:
      active_joints: [joint1, joint2, joint3, joint4, joint5, joint6]
tasks:
  calibration:
    enabled: true
    type: kinematic_calibration
    parameters:
      calibration_level: full_params
      include_non_geometric: false
    kinematics:
      base_frame: universe
      tool_frame: tool
    measurements:
      markers:
        - name: tool
          reference_joint: joint6
          measurable_dof: {dof}
      poses:
        base_pose: [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
        tool_pose: [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    data:
      source_file: {data_file}
      number_of_samples: {n_samples}
"""


def _write_csv(path: Path, q: np.ndarray, T: np.ndarray, position_only: bool) -> None:
    import pinocchio as pin

    cols = ["x1", "y1", "z1"] + ([] if position_only else ["phix1", "phiy1", "phiz1"])
    cols += [f"joint{i}" for i in range(1, 7)]
    rows = []
    for qi, Ti in zip(q, T):
        vals = list(Ti[:3, 3])
        if not position_only:
            vals += list(pin.rpy.matrixToRpy(Ti[:3, :3]))
        vals += list(qi)
        rows.append(",".join(repr(float(v)) for v in vals))
    path.write_text(",".join(cols) + "\n" + "\n".join(rows) + "\n")


def _calibration_class(example_weights: bool = False):
    from figaroh.calibration.base_calibration import BaseCalibration
    from figaroh.calibration.calibration_tools import calc_updated_fkm

    class IRB1200Calibration(BaseCalibration):
        """The robot-specific subclass FIGAROH asks for: the cost function (log-map residuals, weighted by
        ``1/sigma`` from ``measurement_std``, or by the UR10 example's fixed 1.0 / 0.5)."""

        def cost_function(self, var: np.ndarray) -> np.ndarray:
            PEEe = calc_updated_fkm(self.model, self.data, var, self.q_measured, self.calib_config)
            raw = self._compute_logmap_residuals(self.PEE_measured, PEEe, position_frame="world")
            if example_weights:
                return self.apply_measurement_weighting(raw, pos_weight=1.0, orient_weight=0.5)
            return self.apply_measurement_weighting(raw)

    return IRB1200Calibration


class _Robot:
    """The (model, data, q0) triple FIGAROH's classes take (as in its ``tiago_pro`` example)."""

    def __init__(self, model):
        import pinocchio as pin

        self.model = model
        self.data = model.createData()
        self.q0 = pin.neutral(model)


def _predict(calib, q_val: np.ndarray, position_only: bool) -> tuple[np.ndarray, np.ndarray | None]:
    import pinocchio as pin
    from figaroh.calibration.calibration_tools import calc_updated_fkm

    cfg = dict(calib.calib_config, NbSample=len(q_val))
    q_full = np.tile(calib.calib_config["q0"], (len(q_val), 1))
    q_full[:, calib.calib_config["config_idx"]] = q_val
    pee = calc_updated_fkm(calib.model, calib.data, calib.var_, q_full, cfg)
    pee = pee.reshape(3 if position_only else 6, len(q_val))
    pos = pee[:3].T.copy()
    if position_only:
        return pos, None
    R = np.array([pin.rpy.rpyToMatrix(pee[3:, i]) for i in range(len(q_val))])
    return pos, R


def calibrate(
    nominal: RobotModel,
    q_cal: np.ndarray,
    tool2meas_cal: np.ndarray,
    q_val: np.ndarray,
    position_sigma: float,
    orientation_sigma: float,
    variant: str = "pose",
) -> PeerResult:
    """Calibrate FIGAROH on the calibration rows and predict validation.

    ``variant``: ``"pose"`` (the best settings above), ``"pose-example-weights"`` (the UR10 example's cost
    function: weights 1.0 on position [m] and 0.5 on orientation [rad]) or ``"position"`` (positions only,
    weighted 1/sigma)."""
    if variant not in VARIANTS:
        raise ValueError(f"variant must be one of {VARIANTS}, got {variant!r}")
    if not available():
        raise PeerUnavailable("figaroh / pinocchio are not installed; pip install .[peers]")
    import pinocchio as pin

    position_only = variant == "position"
    q_cal = np.asarray(q_cal, dtype=float)
    tmp = tempfile.TemporaryDirectory()
    folder = Path(tmp.name)
    urdf = write_urdf(folder / "irb1200.urdf", nominal.with_frames(np.eye(4), np.eye(4)), name="irb1200")
    data_file = folder / "calibration.csv"
    _write_csv(data_file, q_cal, np.asarray(tool2meas_cal, dtype=float), position_only)
    config = folder / "irb1200_config.yaml"
    config.write_text(config_yaml(str(data_file), len(q_cal), position_only))
    cls = _calibration_class(example_weights=variant == "pose-example-weights")
    if position_only:
        used = "positions only; base and tool frames estimated (base_*, pEE*)"
    elif variant == "pose":
        used = "positions and orientations (weighted 1/sigma); base and tool frames estimated (base_*, pEE*, phiEE*)"
    else:
        used = "positions and orientations (UR10-example weights 1.0 / 0.5); base and tool frames estimated"

    def fit():
        robot = _Robot(pin.buildModelFromUrdf(urdf))
        calib = cls(robot, str(config))
        calib.calib_config["known_baseframe"] = False
        calib.calib_config["known_tipframe"] = False
        calib.calib_config["measurement_std"] = {"position": position_sigma, "orientation": orientation_sigma}
        calib.initialize()
        result = calib.solve(method="lm", max_iterations=3, enable_logging=False)
        return calib, result

    try:
        with run_quietly():
            seconds, (calib, result) = timed(fit)
        pos, R = _predict(calib, np.asarray(q_val, dtype=float), position_only)
    except Exception as e:
        tmp.cleanup()
        return PeerResult(NAME, variant, None, None, None, SETTINGS, used, error=f"{type(e).__name__}: {e}")
    tmp.cleanup()
    n_params = len(calib.calib_config["param_name"])
    notes = (
        f"{n_params} parameters after QR selection; least_squares: {result.message} ({result.nfev} evaluations)",
        f"status {calib.STATUS}",
    )
    error = None if calib.STATUS == "CALIBRATED" else f"FIGAROH status {calib.STATUS}: {result.message}"
    return PeerResult(NAME, variant, pos, R, seconds, SETTINGS, used, error=error, notes=notes)
