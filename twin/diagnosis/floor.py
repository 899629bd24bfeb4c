"""The noise floor a user can measure, and the rows whose history is unknown.

* **Repeats**: the same commanded joints measured twice or more in a row; their pooled spread per axis of the
  measurement frame is the sensor noise.
* **The plate's rigid geometry**: the three inter-sphere distances are constant, so their spread over the
  campaign is the instrument's pose-to-pose error. For independent centre errors with standard deviations
  ``(sigma_x, sigma_y, sigma_z)`` in the measurement frame, a distance along the unit vector ``u`` varies as
  ``var(d) = 2 sum_c u_c^2 sigma_c^2``; regressing the squared deviations of the distances on ``2 u_c^2``
  over every row and pair gives the per-axis error (a stereo instrument is worse in depth, ``z``, than
  across). Rows more than 5 MAD off are left out.
* **Stated**: ``dataset.toml [noise] position_mm`` (an artifact measurement, isotropic).

The floor per axis is the largest estimate available; its scalar ``sigma`` is their RMS. Never the world's truth.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..dataset import Dataset
from .candidates import RowContext

__all__ = ["DiagnosisError", "NoiseFloor", "noise_floor", "history_resets", "row_context"]

_MM = 1e-3


class DiagnosisError(ValueError):
    """The dataset lacks what diagnosis needs; the message says what to add."""


@dataclass(frozen=True)
class NoiseFloor:
    """Measurement noise ``sigma`` [m] per sphere coordinate (RMS over the axes), per axis of the measurement
    frame ``axis_sigma`` ``(3,)`` [m] (None: isotropic), its degrees of freedom (``inf`` when stated), where
    it came from, how many repeat groups there were, and every estimate available (``components``:
    ``repeats``, ``plate``, ``stated`` -> ``{sigma_mm, axis_sigma_mm, dof, source}``)."""

    sigma: float
    dof: float
    source: str
    groups: int
    components: dict = field(default_factory=dict)
    axis_sigma: np.ndarray | None = None


def _repeat_floor(ds: Dataset) -> tuple[np.ndarray, int, int]:
    """Pooled variance of consecutive repeats per axis: ``(sum of squares (3,), dof per axis, groups)``."""
    st = ds.station_ids
    qr = np.round(ds.q, 9)
    ss, dof, groups, k, n = np.zeros(3), 0, 0, 0, ds.n
    while k < n:
        j = k + 1
        while j < n and np.array_equal(qr[j], qr[k]) and st[j] == st[k]:
            j += 1
        if j - k >= 2:
            block = ds.spheres[k:j]
            seen = ds.sphere_seen[k:j]
            for s in range(3):
                rows = seen[:, s]
                if rows.sum() >= 2:
                    v = block[rows, s]
                    ss += np.sum((v - v.mean(axis=0)) ** 2, axis=0)
                    dof += int(rows.sum()) - 1
            groups += 1
        k = j
    return ss, dof, groups


def _plate_floor(ds: Dataset) -> tuple[np.ndarray, float] | None:
    """Per-axis centre error ``(3,)`` [m] from the spread of the three inter-sphere distances over the
    campaign (module docstring), and its degrees of freedom; None with fewer than 10 complete rows."""
    from scipy.optimize import nnls

    full = ds.sphere_seen.all(axis=1)
    if full.sum() < 10:
        return None
    P = ds.spheres[full]
    X, Y, var_iso = [], [], []
    for a, b in ((0, 1), (0, 2), (1, 2)):
        v = P[:, a] - P[:, b]
        d = np.linalg.norm(v, axis=1)
        dev = d - np.median(d)
        mad = 1.4826 * float(np.median(np.abs(dev)))
        keep = np.abs(dev) <= 5 * max(mad, 1e-12)  # a few gross or mislabelled rows do not set the floor
        u = v[keep] / d[keep, None]
        dk = d[keep] - d[keep].mean()
        X.append(2 * u**2)
        Y.append(dk**2)
        var_iso.append(float(np.var(d[keep], ddof=1)) / 2 if keep.sum() > 2 else mad**2 / 2)
    X, Y = np.concatenate(X), np.concatenate(Y)
    s2, _ = nnls(X, Y)
    iso = float(np.mean(var_iso))
    # an axis the distances barely point along is not measured: it gets at least the isotropic figure
    lever = X.mean(axis=0) / 2
    s2 = np.where((lever < 0.01) | (s2 <= 0), np.maximum(s2, iso), s2)
    # three distances of one row share their spheres: about two independent values per row
    return np.sqrt(s2), float(2 * (full.sum() - 1))


def noise_floor(ds: Dataset, *, stated_ok: bool = True) -> NoiseFloor:
    """The sphere-coordinate noise floor (see the module docstring): per axis the largest of the repeats'
    spread, the plate-geometry spread and the stated figure, with the smallest degrees of freedom of the
    estimates that set it."""
    if not ds.has_spheres:
        if ds.noise_position is not None and stated_ok:
            return NoiseFloor(ds.noise_position, float("inf"), "dataset.toml [noise] position_mm (stated)", 0,
                              {"stated": {"sigma_mm": ds.noise_position / _MM, "dof": None}})
        raise DiagnosisError("diagnosis of pose data needs [noise] position_mm/orientation_rad in dataset.toml")
    comps: dict[str, tuple[np.ndarray, float, str]] = {}
    ss, dof, groups = _repeat_floor(ds)
    if 3 * dof >= 30:
        comps["repeats"] = (np.sqrt(ss / dof), float(3 * dof), f"{groups} groups of consecutive repeats")
    pl = _plate_floor(ds)
    if pl is not None:
        comps["plate"] = (pl[0], pl[1], f"spread of the plate's inter-sphere distances over {int(pl[1] / 2 + 1)} rows")
    if stated_ok and ds.noise_position is not None:
        comps["stated"] = (np.full(3, float(ds.noise_position)), float("inf"), "dataset.toml [noise] position_mm (stated)")
    if not comps:
        raise DiagnosisError(
            "diagnosis needs the measurement noise floor: repeat some configurations (measure the same commanded "
            "joints twice in a row, at least ~10 repeats), measure rows with all three spheres (their distances "
            "give the instrument's error), or state the instrument's noise in dataset.toml ([noise] position_mm)"
            + (f"; found only {groups} repeat groups ({3 * dof} degrees of freedom)" if groups else "")
        )
    names = list(comps)
    A = np.stack([comps[k][0] for k in names])  # (k, 3)
    axis = A.max(axis=0)
    setters = sorted({names[i] for i in A.argmax(axis=0)})
    nu = min(comps[k][1] for k in setters)
    sigma = float(np.sqrt(np.mean(axis**2)))

    def fmt(v):
        return "(" + ", ".join(f"{x / _MM:.5f}" for x in v) + ") mm"

    others = "; ".join(f"{k}: {fmt(v[0])}" for k, v in comps.items() if k not in setters)
    source = " and ".join(comps[k][2] for k in setters) + f", per axis x, y, z {fmt(axis)}" + (
        f" (the largest; {others})" if others else "")
    return NoiseFloor(sigma, nu, source, groups,
                      {k: {"sigma_mm": float(np.sqrt(np.mean(v[0] ** 2))) / _MM, "axis_sigma_mm": (v[0] / _MM).tolist(),
                           "dof": None if np.isinf(v[1]) else v[1], "source": v[2]} for k, v in comps.items()},
                      axis_sigma=axis)


def history_resets(ds: Dataset, *, gap_factor: float = 20.0) -> np.ndarray:
    """Rows ``(n,)`` bool whose approach history is unknown: the first row, a row after a gap in ``t_s``
    longer than ``gap_factor`` times the median step, and rows whose ``status`` says restart/home/power."""
    n = ds.n
    out = np.zeros(n, dtype=bool)
    if n:
        out[0] = True
    if ds.t_s is not None and n > 2:
        dt = np.diff(ds.t_s)
        med = float(np.median(dt[dt > 0])) if np.any(dt > 0) else 0.0
        if med > 0:
            out[1:] |= dt > gap_factor * med
    if ds.status is not None:
        st = np.char.lower(np.asarray(ds.status, dtype=str))
        out |= np.char.find(st, "restart") >= 0
        out |= np.char.find(st, "power") >= 0
        out |= np.char.find(st, "homed") >= 0
    return out


def row_context(ds: Dataset, q_start: np.ndarray | None = None) -> RowContext:
    """Every row of the dataset in measurement order, with its auxiliary channels and unknown-history rows
    (``q_start``: where the robot stood before the first row, when known)."""
    reset = history_resets(ds)
    if q_start is not None:
        reset[0] = False
    return RowContext(
        q=ds.q.copy(),
        q_start=None if q_start is None else np.asarray(q_start, dtype=float),
        temp_c=None if ds.temp_c is None else ds.temp_c.copy(),
        t_s=None if ds.t_s is None else ds.t_s.copy(),
        station=ds.station_ids.copy() if ds.station is not None else None,
        history_reset=reset,
    )

