"""Where in the workspace a diagnosis' residual is large and which way it points (pure numpy, no ``rerun``).

:func:`diagnosis_workspace` puts a diagnosis' held-out rows into one measurement frame: the calibrated robot's
skeleton (:func:`skeleton_points`) at each drawn row's commanded joints, the measured points, and the residual
vectors (measured minus predicted) of the geometric model (before) and of the extended model (after), with the
colour scale (:func:`size_colours`, 0 to ``colour_max_mm``) and the arrow scale factor the recording draws them at.
:func:`twin.evaluation.recording.record_diagnosis` logs it (layout in ``docs/diagnosis.md``).

The frame is the measurement frame of one station (the calibration's first station among the rows); rows measured
from another station are mapped into it through the calibrated frames,
``meas_s2meas_ref = base2meas_ref @ inv(base2meas_s)``. The skeleton is drawn on at most ``max_robot_rows`` rows
(evenly spaced in measurement order) so that a recording of a large campaign stays small; the points and their
residual sizes are kept for every held-out row (the workspace map).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal, Mapping

import numpy as np

from ..estimator.calibration import Calibration
from ..kinematics import RobotModel, link_frames
from ..transforms import invert_transform
from ..units import MM_PER_M

__all__ = [
    "MAX_ROBOT_ROWS",
    "ARROW_LENGTH_SHARE",
    "COLOUR_STOPS",
    "DiagnosisWorkspace",
    "skeleton_points",
    "diagnosis_workspace",
    "nice_ceil",
    "nice_floor",
    "size_colours",
    "view_eye",
]

MAX_ROBOT_ROWS = 400
"""Most held-out rows at which the recording draws the robot and the residual arrows."""

ARROW_LENGTH_SHARE = 0.15
"""The 95th percentile of the residual sizes is drawn at about this share of the workspace's extent (the arrow
scale factor is the 1-2-5 number at or below the one that does it exactly)."""

COLOUR_STOPS: tuple[tuple[float, str, tuple[int, int, int]], ...] = (
    (0.0, "blue", (40, 90, 230)),
    (0.25, "cyan", (30, 190, 230)),
    (0.5, "green", (60, 200, 90)),
    (0.75, "yellow", (245, 210, 40)),
    (1.0, "red", (230, 40, 40)),
)
"""The colour map of residual sizes: (share of ``colour_max_mm``, name, RGB); linear between stops, red beyond."""


def nice_ceil(x: float) -> float:
    """The smallest number of the 1-2-5 sequence (``{1, 2, 5} * 10**k``) at or above ``x > 0``."""
    if not (np.isfinite(x) and x > 0):
        raise ValueError(f"x must be a positive finite number, got {x!r}")
    k = math.floor(math.log10(x))
    for m in (1.0, 2.0, 5.0, 10.0):
        v = m * 10.0**k
        if v >= x * (1 - 1e-12):
            return float(v)
    return float(10.0 ** (k + 1))


def nice_floor(x: float) -> float:
    """The largest number of the 1-2-5 sequence (``{1, 2, 5} * 10**k``) at or below ``x > 0``."""
    if not (np.isfinite(x) and x > 0):
        raise ValueError(f"x must be a positive finite number, got {x!r}")
    k = math.floor(math.log10(x))
    for m in (10.0, 5.0, 2.0, 1.0):
        v = m * 10.0**k
        if v <= x * (1 + 1e-12):
            return float(v)
    return float(10.0**k)


def size_colours(size_mm: np.ndarray, colour_max_mm: float) -> np.ndarray:
    """RGB ``(..., 3)`` uint8 of residual sizes ``size_mm`` [mm] on :data:`COLOUR_STOPS` from 0 to
    ``colour_max_mm`` (sizes beyond it are red; NaN, a point not seen, is grey)."""
    if not (np.isfinite(colour_max_mm) and colour_max_mm > 0):
        raise ValueError(f"colour_max_mm must be a positive number, got {colour_max_mm!r}")
    s = np.asarray(size_mm, dtype=float)
    t = np.clip(np.nan_to_num(s / colour_max_mm, nan=0.0), 0.0, 1.0)
    at = np.array([c[0] for c in COLOUR_STOPS])
    rgb = np.array([c[2] for c in COLOUR_STOPS], dtype=float)
    out = np.stack([np.interp(t, at, rgb[:, c]) for c in range(3)], axis=-1)
    out[~np.isfinite(s)] = 128.0
    return np.round(out).astype(np.uint8)


def skeleton_points(model: RobotModel, q: np.ndarray, frame: Literal["base", "meas"] = "meas") -> np.ndarray:
    """The robot as a skeleton: the origins of its frames 0..N ``(n, N+1, 3)`` [m] (the base, each joint's frame,
    the flange last) at joints ``q`` ``(n, N)`` [rad; m for a prismatic joint], in the model's measurement frame
    (``model.base2meas``) or its base frame; any serial chain of :mod:`twin.kinematics` (DH tables, URDF chains)."""
    if frame not in ("base", "meas"):
        raise ValueError(f"frame must be 'base' or 'meas', got {frame!r}")
    return link_frames(model, q, frame=frame)[:, :, :3, 3]


@dataclass(frozen=True)
class DiagnosisWorkspace:
    """A diagnosis' held-out rows in one measurement frame (``station``'s), SI inside.

    ``rows`` ``(n,)``: the rows' dataset rows (``series["dataset_row"]``); ``measured_m`` ``(n, K, 3)`` [m] (NaN
    where a point was not seen); ``residual_m`` ``{"before", "after"}`` ``(n, K, 3)`` [m], measured minus predicted
    (geometric model, extended model); ``size_mm`` the same ``(n, K)`` as lengths [mm]; ``drawn`` ``(d,)``: the
    rows (indices into ``rows``) at which the robot and the arrows are drawn, ``skeleton_m`` ``(d, N+1, 3)`` [m]
    the calibrated robot's frame origins there (:func:`skeleton_points`); ``colour_max_mm`` [mm]: the top of the
    colour map (:func:`size_colours`); ``arrow_scale``: the factor the residual vectors are drawn at;
    ``extent_m`` [m]: the diagonal of the box around the points and skeletons; ``up``: the robot base's z axis in
    the frame ``(3,)``; ``base2frame`` ``(4, 4)``: the robot base in the frame; ``notes``: how the frame and the
    drawn rows were chosen."""

    station: str
    rows: np.ndarray
    measured_m: np.ndarray
    residual_m: Mapping[str, np.ndarray]
    size_mm: Mapping[str, np.ndarray]
    drawn: np.ndarray
    skeleton_m: np.ndarray
    colour_max_mm: float
    arrow_scale: float
    extent_m: float
    up: np.ndarray
    base2frame: np.ndarray
    notes: tuple[str, ...] = ()


def _drawn_rows(n: int, cap: int) -> np.ndarray:
    """``min(n, cap)`` row indices evenly spaced over ``0..n-1`` (the first and the last included)."""
    if n <= cap:
        return np.arange(n)
    return np.unique(np.round(np.linspace(0, n - 1, cap)).astype(int))


def diagnosis_workspace(series: Mapping[str, Any], calibration: Calibration, *,
                        max_robot_rows: int = MAX_ROBOT_ROWS) -> DiagnosisWorkspace:
    """The held-out rows of a diagnosis (``series``: :attr:`twin.diagnosis.DiagnosisResult.series`, which carries
    ``q``, ``station``, ``measured_m`` and ``residual_vector_m_before``/``_after``) in one measurement frame, with
    the robot of ``calibration`` (the calibrated geometric model; each station's ``base2meas``) drawn on at most
    ``max_robot_rows`` of them (module docstring). ``ValueError`` naming the key or argument at fault."""
    if not (isinstance(max_robot_rows, (int, np.integer)) and max_robot_rows >= 1):
        raise ValueError(f"max_robot_rows must be a positive integer, got {max_robot_rows!r}")
    keys = ("dataset_row", "q", "station", "measured_m", "residual_vector_m_before", "residual_vector_m_after")
    for key in keys:
        if series.get(key) is None:
            raise ValueError(f"series lacks {key!r} (has {sorted(series)}): pass DiagnosisResult.series")
    rows = np.asarray(series["dataset_row"], dtype=np.int64)
    n = rows.size
    if n == 0:
        raise ValueError("series['dataset_row'] is empty: the workspace needs held-out rows")
    q = np.asarray(series["q"], dtype=float)
    N = calibration.nominal.n_joints
    if q.shape != (n, N) or not np.all(np.isfinite(q)):
        raise ValueError(f"series['q'] must be finite with shape ({n}, {N}) [rad; m], got {q.shape}")
    station = np.asarray(series["station"], dtype=object)
    if station.shape != (n,):
        raise ValueError(f"series['station'] must have shape ({n},), got {station.shape}")
    station = np.array([str(s) for s in station], dtype=object)
    unknown = sorted(set(station) - set(calibration.stations))
    if unknown:
        raise ValueError(f"series['station'] names stations the calibration does not know: {unknown} "
                         f"(known: {list(calibration.stations)})")
    meas = np.asarray(series["measured_m"], dtype=float)
    if meas.ndim != 3 or meas.shape[0] != n or meas.shape[2] != 3:
        raise ValueError(f"series['measured_m'] must have shape ({n}, K, 3), got {meas.shape}")
    seen = np.all(np.isfinite(meas), axis=2)
    res = {}
    for tag in ("before", "after"):
        v = np.asarray(series[f"residual_vector_m_{tag}"], dtype=float)
        if v.shape != meas.shape:
            raise ValueError(f"series['residual_vector_m_{tag}'] must have shape {meas.shape}, got {v.shape}")
        if not np.array_equal(np.all(np.isfinite(v), axis=2), seen):
            raise ValueError(f"series['residual_vector_m_{tag}'] must be finite exactly where series['measured_m'] is")
        res[tag] = v
    if not seen.any():
        raise ValueError("series['measured_m'] holds no measured point")

    ref = next(s for s in calibration.stations if s in set(station))
    bases = calibration.base2meas
    notes = []
    out_meas, out_res = meas.copy(), {t: v.copy() for t, v in res.items()}
    for s in sorted(set(station) - {ref}):
        T = bases[ref] @ invert_transform(bases[s])
        sel = station == s
        out_meas[sel] = np.einsum("ij,nkj->nki", T[:3, :3], meas[sel]) + T[:3, 3]
        for t in res:
            out_res[t][sel] = np.einsum("ij,nkj->nki", T[:3, :3], res[t][sel])
        notes.append(f"{int(sel.sum())} row(s) of station {s!r} mapped into the measurement frame of station {ref!r} "
                     "through the calibrated base2meas of both")
    drawn = _drawn_rows(n, int(max_robot_rows))
    if drawn.size < n:
        notes.append(f"the robot and the residual arrows are drawn on {drawn.size} of the {n} held-out rows (evenly "
                     f"spaced in measurement order); the map holds every row's points")
    model = calibration.model(ref)
    skel = skeleton_points(model, q[drawn])
    size = {t: np.linalg.norm(v, axis=2) * MM_PER_M for t, v in out_res.items()}
    pooled = np.concatenate([size["before"][seen], size["after"][seen]])
    p95 = float(np.percentile(pooled, 95))
    colour_max = nice_ceil(p95) if p95 > 0 else 1.0
    box = np.concatenate([out_meas[seen], skel.reshape(-1, 3)])
    extent = float(np.linalg.norm(box.max(axis=0) - box.min(axis=0)))
    scale = nice_floor(max(1.0, ARROW_LENGTH_SHARE * extent * MM_PER_M / p95)) if p95 > 0 else 1.0
    base2frame = model.base2meas
    return DiagnosisWorkspace(station=ref, rows=rows, measured_m=out_meas, residual_m=out_res, size_mm=size,
                              drawn=drawn, skeleton_m=skel, colour_max_mm=colour_max, arrow_scale=scale,
                              extent_m=extent, up=base2frame[:3, 2].copy(), base2frame=base2frame, notes=tuple(notes))


def view_eye(ws: DiagnosisWorkspace) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 3-D view's eye for the workspace: ``(position, look_target, eye_up)`` in its frame [m]: looking at the
    centre of the box around the points and skeletons, from in front of the robot's base (its +x, -y side, above),
    at one extent, with the base's z axis up."""
    seen = np.all(np.isfinite(ws.measured_m), axis=2)
    box = np.concatenate([ws.measured_m[seen], ws.skeleton_m.reshape(-1, 3)])
    target = 0.5 * (box.min(axis=0) + box.max(axis=0))
    d = ws.base2frame[:3, :3] @ np.array([1.0, -1.0, 0.6])
    position = target + max(ws.extent_m, 1e-3) * d / np.linalg.norm(d)
    return position, target, ws.up / np.linalg.norm(ws.up)

