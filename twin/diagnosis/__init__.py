"""Diagnosis: residual structure -> candidate effects -> extended model -> before/after.

Reads only datasets (``twin.dataset``) and calibrations (``twin.estimator``); never the world. API::

    res = diagnose(dataset, alpha=0.01)          # -> DiagnosisResult
    write_diagnosis(res, "out/")                 # diagnosis.json, calibration.json, calibration_geometric.json, PNGs
    q_eff = apply_joint_effects(effects, q, ctx) # what an extended calibration does to commanded joints
"""

from .atoms import Atom
from .pools import catalogue_atoms, generic_atoms
from .candidates import EFFECT_VOCABULARY, RowContext, approach_signs, gravity_torque_regressor
from .diagnose import (
    CandidateScore,
    DiagnosisError,
    DiagnosisResult,
    NoiseFloor,
    StructureTest,
    diagnose,
    history_resets,
    noise_floor,
    row_context,
    split_held_out,
)
from .effect_fit import EffectFit, fit_with_effects
from .report import DIAGNOSIS_SCHEMA_VERSION, diagnosis_dict, read_diagnosis, write_diagnosis

__all__ = [
    "Atom",
    "catalogue_atoms",
    "generic_atoms",
    "history_resets",
    "EFFECT_VOCABULARY",
    "CandidateScore",
    "DIAGNOSIS_SCHEMA_VERSION",
    "DiagnosisError",
    "DiagnosisResult",
    "NoiseFloor",
    "RowContext",
    "StructureTest",
    "approach_signs",
    "EffectFit",
    "diagnose",
    "fit_with_effects",
    "diagnosis_dict",
    "gravity_torque_regressor",
    "noise_floor",
    "read_diagnosis",
    "row_context",
    "split_held_out",
    "write_diagnosis",
]
