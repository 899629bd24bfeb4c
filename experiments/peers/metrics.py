"""Validation figures of a prediction against the noise-free truth, and small timing helpers."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from twin.transforms import rotation_angle_between
from twin.units import MM_PER_M, rad_to_deg

__all__ = ["ValidationErrors", "validation_errors", "median_time"]


@dataclass(frozen=True)
class ValidationErrors:
    """Position errors [mm] (mean, RMS, max of the per-pose distance) and orientation errors [deg]
    (RMS and max of the per-pose geodesic angle; ``None`` when the method predicts no orientation)."""

    position_mean_mm: float
    position_rms_mm: float
    position_max_mm: float
    orientation_rms_deg: float | None
    orientation_max_deg: float | None

    def as_dict(self) -> dict:
        return {
            "position_mm": {"mean": self.position_mean_mm, "rms": self.position_rms_mm, "max": self.position_max_mm},
            "orientation_deg": None
            if self.orientation_rms_deg is None
            else {"rms": self.orientation_rms_deg, "max": self.orientation_max_deg},
        }


def validation_errors(
    true_tool2meas: np.ndarray, positions: np.ndarray, rotations: np.ndarray | None = None
) -> ValidationErrors:
    """Errors of predicted positions ``(m, 3)`` [m] (and rotations ``(m, 3, 3)``) against true poses ``(m, 4, 4)``."""
    true_tool2meas = np.asarray(true_tool2meas, dtype=float)
    positions = np.asarray(positions, dtype=float)
    if positions.shape != (true_tool2meas.shape[0], 3):
        raise ValueError(f"positions must have shape ({true_tool2meas.shape[0]}, 3), got {positions.shape}")
    if not np.all(np.isfinite(positions)):
        raise ValueError("positions contain non-finite values")
    d = np.linalg.norm(positions - true_tool2meas[:, :3, 3], axis=1) * MM_PER_M
    o_rms = o_max = None
    if rotations is not None:
        rotations = np.asarray(rotations, dtype=float)
        if rotations.shape != (true_tool2meas.shape[0], 3, 3):
            raise ValueError(f"rotations must have shape ({true_tool2meas.shape[0]}, 3, 3), got {rotations.shape}")
        ang = rad_to_deg(rotation_angle_between(true_tool2meas[:, :3, :3], rotations))
        o_rms, o_max = float(np.sqrt(np.mean(ang**2))), float(ang.max())
    return ValidationErrors(
        position_mean_mm=float(d.mean()),
        position_rms_mm=float(np.sqrt(np.mean(d**2))),
        position_max_mm=float(d.max()),
        orientation_rms_deg=o_rms,
        orientation_max_deg=o_max,
    )


def median_time(fn: Callable[[], object], repeats: int) -> tuple[float, list[float], object]:
    """Run ``fn`` ``repeats`` times; (median wall time [s], all times, the last result)."""
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), times, out
