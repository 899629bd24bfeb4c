"""The separation paper's accuracy statistics as pure functions (SI in, SI out).

Definitions (``docs/conventions.md``, separation paper sections 2.1.4 and 3.1):

* **Moved-distance error** of a motion (eq. 28, 30; Figures 10b, 11b, 15): the error of the distance a
  point of the plate moved, ``| |p_end - p_start|_measured - |p_end - p_start|_commanded |`` [m].
* **Angle error** of a motion (eq. 25, 43; Figures 10a, 11a, 13): the Euclidean norm of the difference
  between the measured and the commanded *change* of the ZYX Euler angles
  (``R = Rz(rz) Ry(ry) Rx(rx)``, :func:`twin.transforms.euler_zyx_from_matrix`),
  ``| (E(R_end) - E(R_start))_measured - (E(R_end) - E(R_start))_commanded |`` [rad]. Every difference
  of angles is wrapped into (-pi, pi] so a change across +-180 deg is not counted as a full turn.
* **Absolute pose errors** (our extra columns): the position distance [m] and the geodesic rotation
  angle [rad] between an actual and a target pose.
* **Summary** of a set of errors: ``max``, ``mean``, ``rms`` and ``std``. The paper's "mean square
  error" is smaller than its mean in most of its figures, which an RMS never is: it behaves as a sample
  standard deviation, so we report ``std`` (``ddof = 1``) under that name and ``rms`` beside it.
* **Improvement** [%]: ``100 (before - after) / before`` of the *mean*; this reproduces every percentage
  the paper prints (80.7 and 87.8 % in section 3.1, 86.2 and 66.9 % in section 3.2).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Iterable

import numpy as np

from ..kinematics import wrap_angle
from ..transforms import euler_zyx_from_matrix, rotation_angle_between

__all__ = [
    "Summary",
    "summarize",
    "improvement_percent",
    "moved_distance_error",
    "euler_change",
    "euler_change_error",
    "absolute_pose_errors",
    "flatten_numbers",
    "aggregate",
]


def _points(name: str, p) -> np.ndarray:
    a = np.asarray(p, dtype=float)
    if a.ndim == 1:
        a = a[None]
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3) [m], got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains non-finite values in rows {np.flatnonzero(~np.isfinite(a).all(1))[:10].tolist()}")
    return a


def _rotations(name: str, R) -> np.ndarray:
    a = np.asarray(R, dtype=float)
    if a.ndim == 2:
        a = a[None]
    if a.ndim != 3 or a.shape[1:] != (3, 3):
        raise ValueError(f"{name} must have shape (n, 3, 3), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains non-finite values")
    return a


def _same_n(**arrays: np.ndarray) -> int:
    ns = {k: v.shape[0] for k, v in arrays.items()}
    if len(set(ns.values())) != 1:
        raise ValueError(f"inputs must have the same number of rows, got {ns}")
    return next(iter(ns.values()))


@dataclass(frozen=True)
class Summary:
    """Summary statistics of one set of non-negative errors (same unit as the input)."""

    n: int
    max: float
    mean: float
    rms: float
    std: float

    def scaled(self, factor: float) -> "Summary":
        """Same statistics in another unit (e.g. ``twin.units.MM_PER_M`` for m -> mm)."""
        return Summary(self.n, self.max * factor, self.mean * factor, self.rms * factor, self.std * factor)

    def to_dict(self) -> dict:
        return asdict(self)


def summarize(errors) -> Summary:
    """``max``, ``mean``, ``rms`` and sample ``std`` (``ddof=1``; the paper's "mean square error").

    ``errors`` ``(n,)``, finite, ``n >= 1`` (``std`` is 0 for a single value). Raises ``ValueError`` on an
    empty or non-finite input rather than returning NaN.
    """
    e = np.asarray(errors, dtype=float).reshape(-1)
    if e.size == 0:
        raise ValueError("errors is empty: nothing to summarize")
    if not np.all(np.isfinite(e)):
        raise ValueError(f"errors contains non-finite values at {np.flatnonzero(~np.isfinite(e))[:10].tolist()}")
    std = float(np.std(e, ddof=1)) if e.size > 1 else 0.0
    return Summary(int(e.size), float(np.max(e)), float(np.mean(e)), float(np.sqrt(np.mean(e * e))), std)


def improvement_percent(before: float, after: float) -> float:
    """``100 (before - after) / before`` [%]; ``before`` must be positive."""
    if not (np.isfinite(before) and before > 0):
        raise ValueError(f"before must be a positive number, got {before!r}")
    if not np.isfinite(after):
        raise ValueError(f"after must be finite, got {after!r}")
    return float(100.0 * (before - after) / before)


def moved_distance_error(p_start_meas, p_end_meas, p_start_cmd, p_end_cmd) -> np.ndarray:
    """Error of the moved distance ``(n,)`` [m] of motions ``start -> end``.

    ``| |p_end - p_start|_meas - |p_end - p_start|_cmd |`` for points ``(n, 3)`` [m]. The measured points may
    be in any frame (a distance does not depend on it) as long as start and end share it.
    """
    a = _points("p_start_meas", p_start_meas)
    b = _points("p_end_meas", p_end_meas)
    c = _points("p_start_cmd", p_start_cmd)
    d = _points("p_end_cmd", p_end_cmd)
    _same_n(p_start_meas=a, p_end_meas=b, p_start_cmd=c, p_end_cmd=d)
    return np.abs(np.linalg.norm(b - a, axis=1) - np.linalg.norm(d - c, axis=1))


def euler_change(R_start, R_end) -> np.ndarray:
    """Change of the ZYX Euler angles ``(n, 3)`` [rad] (``rx, ry, rz``) from ``R_start`` to ``R_end``, wrapped."""
    a = _rotations("R_start", R_start)
    b = _rotations("R_end", R_end)
    _same_n(R_start=a, R_end=b)
    return wrap_angle(euler_zyx_from_matrix(b) - euler_zyx_from_matrix(a))


def euler_change_error(R_start_meas, R_end_meas, R_start_cmd, R_end_cmd) -> np.ndarray:
    """The paper's angle error ``(n,)`` [rad] (eq. 25): ``| dE_meas - dE_cmd |`` of ZYX Euler-angle changes.

    All rotations ``(n, 3, 3)`` must be expressed in the same frame (the robot base, as in eq. 42).
    """
    dm = euler_change(R_start_meas, R_end_meas)
    dc = euler_change(R_start_cmd, R_end_cmd)
    _same_n(measured=dm, commanded=dc)
    return np.linalg.norm(wrap_angle(dm - dc), axis=1)


def absolute_pose_errors(T_actual, T_target) -> tuple[np.ndarray, np.ndarray]:
    """Position distance ``(n,)`` [m] and geodesic rotation angle ``(n,)`` [rad] between poses ``(n, 4, 4)``."""
    A = np.asarray(T_actual, dtype=float)
    B = np.asarray(T_target, dtype=float)
    if A.ndim == 2:
        A = A[None]
    if B.ndim == 2:
        B = B[None]
    for name, X in (("T_actual", A), ("T_target", B)):
        if X.ndim != 3 or X.shape[1:] != (4, 4):
            raise ValueError(f"{name} must have shape (n, 4, 4), got {X.shape}")
        if not np.all(np.isfinite(X)):
            raise ValueError(f"{name} contains non-finite values")
    _same_n(T_actual=A, T_target=B)
    pos = np.linalg.norm(A[:, :3, 3] - B[:, :3, 3], axis=1)
    rot = rotation_angle_between(A[:, :3, :3], B[:, :3, :3])
    return pos, rot


def flatten_numbers(d: Any, prefix: str = "") -> dict[str, float]:
    """Numeric leaves of nested dicts as ``{"a.b.c": value}`` (booleans and strings skipped)."""
    out: dict[str, float] = {}
    if isinstance(d, dict):
        for k, v in d.items():
            out.update(flatten_numbers(v, f"{prefix}.{k}" if prefix else str(k)))
    elif isinstance(d, (int, float, np.integer, np.floating)) and not isinstance(d, bool):
        out[prefix] = float(d)
    return out


def aggregate(results: Iterable[dict]) -> dict[str, dict[str, float]]:
    """Mean and spread of every numeric statistic over repeats: ``{path: {n, mean, std, min, max}}``.

    A statistic missing from some repeats is aggregated over those that have it (``n`` says how many).
    """
    flat = [flatten_numbers(r) for r in results]
    if not flat:
        raise ValueError("results is empty: nothing to aggregate")
    keys = sorted(set().union(*flat))
    out: dict[str, dict[str, float]] = {}
    for k in keys:
        v = np.array([f[k] for f in flat if k in f and np.isfinite(f[k])], dtype=float)
        if v.size == 0:
            continue
        out[k] = {
            "n": int(v.size),
            "mean": float(v.mean()),
            "std": float(v.std(ddof=1)) if v.size > 1 else 0.0,
            "min": float(v.min()),
            "max": float(v.max()),
        }
    return out
