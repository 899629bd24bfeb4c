"""The verdict of the diagnosis (step 5): whether the residual holds structure, and whether the extended model
replaces the geometric one (the selection of its terms: :mod:`twin.diagnosis.rule`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..units import M_PER_MM
from .confirm import smooth_confirm
from .extend import error_stats
from .problem import Fit, Problem
from .structure import StructureTest

__all__ = ["decide", "adopt"]


def decide(prob: Problem, base: Fit, ext: Fit | None, test0: StructureTest, excess: bool,
           z_min: float) -> tuple[bool, dict | None, list[str]]:
    """Step 5: ``structured`` when the test fired (``excess``) and something in the residual is predictable on the
    confirmation rows: a confirmed term (``ext``), or, without one, the nearest calibration rows in joint space or
    in time (:func:`twin.diagnosis.confirm.smooth_confirm`). An excess that nothing predicts is scatter that
    changes from visit to visit (the robot's repeatability, a per-pose instrument error), however large:
    reported (``unexplained``), not called structure. Returns ``(structured, unexplained, notes)``."""
    notes: list[str] = []
    confirmed = ext is not None
    unexplained = None
    if excess and not confirmed:
        smooth = smooth_confirm(prob, base, z_min)
        w = test0.whitened_rms
        unexplained = {"whitened_rms": w, "excess_sigma_mm": prob.floor.sigma * np.sqrt(max(w * w - 1.0, 0.0)) / M_PER_MM,
                       "predictable": smooth["confirmed"], "by": smooth["by"] if smooth["confirmed"] else None,
                       "smoothers": smooth["smoothers"]}
    structured = bool(excess and (confirmed or unexplained["predictable"]))
    if excess and not structured:
        notes.append(f"the held-out scatter is {test0.whitened_rms:.2f}x the floor (p = {test0.p_value:.2g}), an extra "
                     f"{unexplained['excess_sigma_mm']:.5f} mm per coordinate, but nothing in it is predictable on held-out "
                     f"rows, neither by a term nor from the nearest rows in joint space or time (z = "
                     f"{unexplained['smoothers']['joints']['z']:.2f}, {unexplained['smoothers']['time']['z']:.2f}): random "
                     "scatter beyond the instrument's floor (the robot's repeatability, or an error that changes from visit "
                     "to visit or too finely for these rows); no structure is claimed")
    if structured and not confirmed:
        by = "joint space" if unexplained["by"] == "joints" else "time"
        notes.append(f"the residual is predictable from the nearest rows in {by} (z = "
                     f"{unexplained['smoothers'][unexplained['by']]['z']:.2f} on held-out rows) and no term of the "
                     "catalogue or the dictionary explains it")
    return structured, unexplained, notes


def adopt(prob: Problem, base: Fit, ext: Fit) -> dict[str, Any]:
    """Step 5b: does the extended model replace the geometric one? Only where it predicts the confirmation block (a
    block of time after every row that fitted it, or another session) better: a lower position RMS there, over every
    confirmation row (no row set aside as gross: a posture the extended model mispredicts, one outside the ranges it
    was fitted on, is a posture of the next session too; a glitch of the instrument costs both models alike).
    Otherwise the geometric model stays the one to use and the terms are reported as candidates. Returns
    ``{adopted, confirmation_rms_mm: {geometric, extended}, note}``."""
    gb = error_stats(base.model_val, base.z)["position_mm"]["rms"]
    ge = error_stats(ext.model_val, ext.z)["position_mm"]["rms"]
    adopted = bool(ge < gb)
    note = ("" if adopted else
            f"the extended model does not predict the confirmation block better than the geometric model ({ge:.4g} "
            f"against {gb:.4g} mm RMS): the geometric model is the one to use; its terms are reported as candidates")
    return {"adopted": adopted, "confirmation_rms_mm": {"geometric": gb, "extended": ge}, "note": note}
