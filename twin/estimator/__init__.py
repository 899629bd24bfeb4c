"""The estimator: error models, identification methods, identifiability, uncertainty, compensation.

Works on datasets (``twin.dataset``) only; never imports the world or the instrument. Stable API (see
``docs/estimator.md``)::

    cal = calibrate(dataset, method="best")          # -> Calibration (also: distance, fullpose, separation, lm, clm)
    cal.save("out/calibration.json"); cal = Calibration.load("out/calibration.json")
    pred = predict(cal, q, station=None)             # sphere centres + plate pose with standard deviations
    q_cmd = compensate(cal, targets_tool2base, q_ref)  # corrected joint commands (iterative IK)
    ida = identifiability(dataset, part="full")      # identifiable parameters and named couplings
    cal.model(station) / cal.robot / cal.base2meas   # identified RobotModel(s)
"""

from __future__ import annotations

import numpy as np

from ..kinematics import UnreachableError
from .calibration import CALIBRATION_SCHEMA_VERSION, Calibration, Prediction, parameter_table
from .compensation import CompensationResult, compensate, compensation, compensation_position
from .identifiability import Combination, Identifiability, analyse_jacobian, preference_order
from .methods import METHODS, calibrate, identifiability, identify_best
from . import paper_methods  # noqa: E402,F401  (registers the papers' methods in METHODS)
from .simulate import random_configurations, simulate_dataset

__all__ = [
    "CALIBRATION_SCHEMA_VERSION",
    "Calibration",
    "Combination",
    "CompensationResult",
    "Identifiability",
    "METHODS",
    "Prediction",
    "UnreachableError",
    "analyse_jacobian",
    "calibrate",
    "compensate",
    "compensation",
    "compensation_position",
    "identifiability",
    "identify_best",
    "parameter_table",
    "predict",
    "preference_order",
    "random_configurations",
    "simulate_dataset",
]


def predict(calibration: Calibration, q: np.ndarray, station: np.ndarray | None = None) -> Prediction:
    """Predicted sphere centres and plate poses for joints ``q`` ``(n, 6)`` [rad] (see
    :meth:`Calibration.predict`)."""
    return calibration.predict(q, station)
