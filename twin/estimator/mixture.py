"""Rows of two robots mixed in one campaign: a split of a campaign's rows between two geometric models.

A campaign whose rows come from two robots of one model (two cells logging to one file, a file appended to the
wrong one) fits one geometric model badly everywhere: each robot's rows sit on their own robot, the model sits
between them, and the residual looks like scatter far beyond the noise that nothing predicts. Two models, each
fitted on its own robot's rows, take it to the noise. This module looks for that split:

* :func:`two_models` (pure, linear): at the one model's parameters the whitened residual of row ``i`` is
  ``r_i ~ J_i (x_true(i) - x)``, so two robots are two regressions, ``r_i = J_i a`` or ``r_i = J_i b``. It finds
  the rows' assignment ``g`` and ``a, b`` minimising ``sum_i min(|r_i - J_i a|^2, |r_i - J_i b|^2)``: starts from
  the sign split of a rank-one model ``r_i = s_i J_i d`` (``s_i = +-1``, alternating ``s`` and ``d``, random ``d``)
  and from the rows' first and second half, each refined by alternating the assignment and the two fits.
* :func:`split_rows` (a calibration and its dataset): the linear split at the calibration's parameters, then each
  group calibrated again on its own (the full non-linear fit, the same noise) and the split judged on those fits:
  found when the two models leave at most :data:`SPLIT_MAX_SCALE` times the noise on their rows and at most a
  fifth of the one model's residual per coordinate. The rows are the calibration's, used and rejected as outliers
  (a minority robot's rows are what a robust fit rejects), or every row of the dataset (a diagnosis: its
  geometric model is fitted on its calibration rows, and a second robot's rows may all come after them). What
  tells the groups apart is named, by the share of the one model's excess a difference in a few parameters alone
  takes (90 %): one parameter of the chain (a joint's offset on some rows: backlash or a zero step), the
  measurement frame (two stations without their ``station`` column, or the first joint's backlash), the tool's
  frame (two tools, or the last joint's backlash), or many parameters (two robots).

Nothing here reads truth; it never refuses data (a robot with errors beyond the geometric model is not wrong
input): it says what the rows look like.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..dataset import Dataset
from ..units import MM_PER_M
from .methods import calibrate
from .problem import absolute_residuals, observations_from_dataset

__all__ = ["TwoModels", "two_models", "RowSplit", "split_rows", "SPLIT_MIN_SCALE", "SPLIT_MIN_REJECTED",
           "SPLIT_MAX_SCALE"]

# the one model's residual scale (or its residual over the instrument's error) from which a split is looked for
SPLIT_MIN_SCALE = 10.0
# the share of the calibration rows rejected as outliers from which a split is looked for
SPLIT_MIN_REJECTED = 0.1
# the two models' residual per coordinate over the noise at which the split explains the rows
SPLIT_MAX_SCALE = 3.0
# the share of the one model's excess a restricted difference (one parameter, the frame) must take to be the cause
_RESTRICTED_SHARE = 0.9


@dataclass(frozen=True, eq=False)
class TwoModels:
    """The best split of ``n`` rows between two linear models.

    ``second`` ``(n,)`` bool: the rows of the second model; ``cost_one`` / ``cost_two``: the sums of squared
    residuals of one model refitted on every row (``min_c |r - J c|^2``: the point the residuals were taken at need
    not be these rows' best) and of the two; ``trace``: the best ``cost_two`` after each start, in order."""

    second: np.ndarray
    cost_one: float
    cost_two: float
    trace: tuple[float, ...]


def _row_cost(e: np.ndarray, row: np.ndarray, n: int) -> np.ndarray:
    return np.bincount(row, weights=e * e, minlength=n)


def _normalised(J: np.ndarray) -> np.ndarray:
    """``J``'s non-zero columns scaled to unit norm (the least squares below are then well conditioned)."""
    norm = np.linalg.norm(J, axis=0)
    return J[:, norm > 0] / norm[norm > 0]


def _one_model_residual(r: np.ndarray, Jn: np.ndarray) -> np.ndarray:
    """``r - J c`` at the best ``c``: one model refitted on every row."""
    return r - Jn @ np.linalg.lstsq(Jn, r, rcond=None)[0]


def two_models(r: np.ndarray, J: np.ndarray, row: np.ndarray, n: int, *, starts: int = 12, seed: int = 0,
               max_iter: int = 50, min_rows: int = 1) -> TwoModels:
    """Split rows between two linear models (module docstring).

    ``r`` ``(m,)`` residuals, ``J`` ``(m, p)`` their derivatives in the parameters, ``row`` ``(m,)`` the row
    (``0..n-1``) of each residual. Minimises ``sum_i min(|r_i - J_i a|^2, |r_i - J_i b|^2)`` over the assignment and
    ``a, b`` ``(p,)``, each group of at least ``min_rows`` rows. Deterministic for a ``seed``."""
    r = np.asarray(r, float)
    J = np.asarray(J, float)
    row = np.asarray(row, int)
    if r.ndim != 1 or J.ndim != 2 or J.shape[0] != r.size or row.shape != r.shape:
        raise ValueError(f"r (m,), J (m, p) and row (m,) must agree, got {r.shape}, {J.shape}, {row.shape}")
    if n < 2 or row.min(initial=0) < 0 or row.max(initial=0) >= n:
        raise ValueError(f"row must index n = {n} rows (n >= 2)")
    if starts < 1 or min_rows < 1 or max_iter < 1:
        raise ValueError(f"starts, min_rows and max_iter must be positive, got {starts}, {min_rows}, {max_iter}")
    Jn = _normalised(J)
    rng = np.random.default_rng(seed)
    e_one = _one_model_residual(r, Jn)
    cost_one = float(e_one @ e_one)

    def fit(rows_mask: np.ndarray) -> np.ndarray:
        sel = rows_mask[row]
        return np.linalg.lstsq(Jn[sel], r[sel], rcond=None)[0]

    def refine(second: np.ndarray) -> tuple[float, np.ndarray] | None:
        for _ in range(max_iter):
            if second.sum() < min_rows or (~second).sum() < min_rows:
                return None
            ca = _row_cost(r - Jn @ fit(~second), row, n)
            cb = _row_cost(r - Jn @ fit(second), row, n)
            new = cb < ca
            if np.array_equal(new, second):
                return float(np.minimum(ca, cb).sum()), second
            second = new
        return float(np.minimum(ca, cb).sum()), second

    inits = [np.arange(n) >= n // 2]
    for _ in range(starts - 1):
        d = rng.normal(size=Jn.shape[1])
        for _ in range(20):
            s = np.sign(np.bincount(row, weights=r * (Jn @ d), minlength=n))
            s[s == 0] = 1.0
            d = np.linalg.lstsq(s[row][:, None] * Jn, r, rcond=None)[0]
        inits.append(s < 0)
    best: tuple[float, np.ndarray] | None = None
    trace = []
    for g in inits:
        out = refine(g.copy())
        if out is not None and (best is None or out[0] < best[0]):
            best = out
        trace.append(float("nan") if best is None else best[0])
    if best is None:
        return TwoModels(np.zeros(n, bool), cost_one, cost_one, tuple(trace))
    return TwoModels(best[1], cost_one, best[0], tuple(trace))


def _restricted_share(r: np.ndarray, J: np.ndarray, row: np.ndarray, second: np.ndarray, cols: np.ndarray,
                      cost_one: float, cost_two: float) -> float:
    """The share of the one model's excess over the two models' that a difference in ``cols`` alone takes: one
    model for every row plus ``J[:, cols] delta`` on the second group's rows."""
    g = second[row].astype(float)[:, None]
    A = np.hstack([J, g * J[:, cols]])
    e = r - A @ np.linalg.lstsq(A, r, rcond=None)[0]
    gain = cost_one - cost_two
    return float((cost_one - e @ e) / gain) if gain > 0 else 0.0


@dataclass(frozen=True, eq=False)
class RowSplit:
    """What :func:`split_rows` found. ``found``: two groups each fitting its own model (module docstring);
    ``kind``: ``"robots"`` (many parameters differ), ``"frames"`` (the measurement frame alone), ``"tool"`` (the
    tool's frame alone), ``"parameter"`` (one parameter of the chain: ``parameter``), or ``""`` when not found;
    ``groups``: the pose_ids of each group;
    ``rms_one_mm`` / ``rms_two_mm``: the residual per coordinate [mm] of the one model and of each group's;
    ``noise_mm``: the noise they are judged against [mm]; ``text``: what it says in words (empty when not found)."""

    found: bool
    kind: str
    groups: tuple[tuple[int, ...], tuple[int, ...]]
    rms_one_mm: float
    rms_two_mm: tuple[float, float]
    noise_mm: float | None
    parameter: str = ""
    text: str = ""
    trace: tuple[float, ...] = ()

    def summary(self) -> dict[str, Any]:
        """A JSON-able dict; a figure not measured (no split to judge) is None."""

        def num(v):
            return None if v is None or not np.isfinite(v) else float(v)

        return {"found": self.found, "kind": self.kind, "groups": [list(g) for g in self.groups],
                "rms_one_mm": num(self.rms_one_mm), "rms_two_mm": [num(v) for v in self.rms_two_mm],
                "noise_mm": num(self.noise_mm),
                "parameter": self.parameter, "text": self.text,
                "rule": (f"two groups of rows each calibrated on its own: found when each leaves at most "
                         f"{SPLIT_MAX_SCALE:g}x the noise and at most a fifth of the one model's residual per "
                         "coordinate")}


def _position_rms(cal, ds: Dataset, meas: str) -> float:
    """The RMS per coordinate [m] of ``cal``'s position residuals on every row of ``ds``: its marker points
    (``meas`` ``"spheres"``), or its poses' positions (``"pose"``)."""
    pred = cal.predict(ds.q, None if ds.station is None else ds.station_ids)
    if meas == "pose":
        e = ds.pose[:, :3, 3] - pred.pose[:, :3, 3]
    else:
        e = (ds.spheres - pred.spheres)[ds.sphere_seen]
    return float(np.sqrt(np.mean(e**2)))


def _ids(pose_id: np.ndarray) -> str:
    ids = [int(p) for p in pose_id]
    return ", ".join(str(p) for p in ids[:8]) + (", ..." if len(ids) > 8 else "")


def split_rows(cal, ds: Dataset, *, noise_m: float | None = None, pose_ids=None, starts: int = 12,
               seed: int = 0) -> RowSplit:
    """Look for two groups of rows in ``ds`` that each fit a geometric model of their own.

    ``cal``: a geometric :class:`~twin.estimator.Calibration` of ``ds``; ``noise_m``: the noise per coordinate
    [m] the groups' fits are judged against (default: the calibration's stated position noise; without one the
    split must still take the residual to a fifth); ``pose_ids``: the rows to split, by pose_id ``(m,)`` (default:
    ``cal``'s calibration rows, used and rejected; a diagnosis passes every row, since the rows its model misses
    may all lie after the rows it was fitted on). Returns a :class:`RowSplit`."""
    if not isinstance(ds, Dataset):
        raise ValueError(f"ds must be a twin.dataset.Dataset, got {type(ds).__name__}")
    if noise_m is not None and not (np.isfinite(noise_m) and noise_m > 0):
        raise ValueError(f"noise_m must be a positive number [m], got {noise_m!r}")
    if pose_ids is None:
        rows = cal.rows or {}
        ids = [int(p) for p in rows.get("calibration_used", [])]
        ids += [int(r["pose_id"]) for r in rows.get("calibration_rejected", [])
                if isinstance(r, dict) and "pose_id" in r]
    else:
        ids = np.asarray(pose_ids).ravel()
        unknown = np.setdiff1d(ids, ds.pose_id)
        if unknown.size:
            raise ValueError(f"pose_ids: {unknown.size} not in the dataset (first {unknown[:5].tolist()})")
    sel = np.flatnonzero(np.isin(ds.pose_id, ids))
    none = RowSplit(False, "", ((), ()), float("nan"), (float("nan"), float("nan")), None)
    if sel.size < 8:
        return none
    sigma_p = (cal.noise or {}).get("position_mm")
    sigma_p = float(sigma_p) / MM_PER_M if sigma_p else 1e-5
    sigma_o = (cal.noise or {}).get("orientation_rad")
    if noise_m is None and (cal.noise or {}).get("position_source") == "given":
        noise_m = sigma_p
    sub = replace(ds.subset(sel), set=None)
    # the calibration's measurement where the dataset has it (a diagnosis fits a pose's virtual points: its poses then)
    meas = cal.measurement if (ds.has_spheres if cal.measurement == "spheres" else ds.has_poses) else (
        "pose" if ds.has_poses else "spheres")
    obs, _, _ = observations_from_dataset(sub, measurement=meas, sigma_position=sigma_p,
                                          sigma_orientation=None if sigma_o is None else float(sigma_o))
    sp = cal.space
    if any(s not in sp.stations for s in obs.station_names):
        return none
    obs = replace(obs, station=np.array([sp.station_index(obs.station_names[k]) for k in obs.station], dtype=int),
                  station_names=sp.stations)
    if obs.kind == "spheres":
        obs = replace(obs, spheres_tool=cal.spheres_tool)
    if obs.n < 16:  # rows without a usable measurement left out: too few for two groups of 8
        return none
    res = absolute_residuals(sp, cal.x, obs)
    free = np.flatnonzero(np.array(cal.status) == "identified")
    J = res.J[:, free]
    per_row = res.r.size / obs.n
    min_rows = max(8, int(np.ceil(2 * free.size / per_row)))
    if obs.n < 2 * min_rows:
        return none
    tm = two_models(res.r, J, res.row, obs.n, starts=starts, seed=seed, min_rows=min_rows)
    if not (tm.second.any() and (~tm.second).any()):
        return none
    groups = (obs.pose_id[~tm.second], obs.pose_id[tm.second])
    # the one model refitted on these rows (linear, at the calibration's parameters): its position residuals
    e_one = _one_model_residual(res.r, _normalised(J))
    rms_one = float(np.sqrt(np.mean(e_one[res.block == 0] ** 2))) * sigma_p
    rms_two = []
    for g in groups:
        part = replace(sub.subset(np.isin(sub.pose_id, g)), set=None)
        try:
            cg = calibrate(part, measurement=meas, noise_position=sigma_p,
                           noise_orientation=None if sigma_o is None else float(sigma_o), validation_fraction=0.0)
        except ValueError:  # a group too small or too alike to calibrate: no split to report
            return none
        rms_two.append(_position_rms(cg, part, meas))
    worst = max(rms_two)
    found = bool(np.isfinite(worst) and worst <= rms_one / 5.0
                 and (noise_m is None or worst <= SPLIT_MAX_SCALE * noise_m))
    kind, name, text = "", "", ""
    if found:
        names = [sp.names[k] for k in free]

        def share(cols) -> float:
            cols = np.asarray(cols, int)
            return (_restricted_share(res.r, J, res.row, tm.second, cols, tm.cost_one, tm.cost_two)
                    if cols.size else 0.0)

        shares = [share([k]) for k in range(free.size)]
        k1 = int(np.argmax(shares))
        base_cols = [k for k, n in enumerate(names) if n.startswith("base_")]
        tool_cols = [k for k, n in enumerate(names) if n.startswith("tool_")]
        if shares[k1] >= _RESTRICTED_SHARE and k1 not in base_cols + tool_cols:
            kind, name = "parameter", names[k1]
            if name.startswith("theta") or name.endswith(".offset"):
                cause = (f"they differ by {name} alone: that joint's zero on some rows and not on others (its backlash, "
                         "the side each row approached from, or a zero step)")
            else:
                cause = f"they differ by {name} alone: that parameter on some rows and not on others"
        elif share(base_cols) >= _RESTRICTED_SHARE:
            kind = "frames"
            cause = ("they differ by the measurement frame alone: rows of two stations without their `station` "
                     "column, or the first joint's offset on some rows (backlash), which moves the rows alike?")
        elif share(tool_cols) >= _RESTRICTED_SHARE:
            kind = "tool"
            cause = ("they differ by the tool's frame alone: two tools or marker sets, or the last joint's offset on "
                     "some rows (backlash), which moves the rows alike?")
        else:
            kind = "robots"
            cause = ("they differ in the robot's own geometry, not in one joint's offset, the measurement frame or the "
                     "tool alone: rows of two robots mixed in one campaign? Calibrate each one's rows on their own")
        text = (f"the rows split into two groups that each fit a geometric model of their own to "
                f"{rms_two[0] * MM_PER_M:.3g} and {rms_two[1] * MM_PER_M:.3g} mm per coordinate (one model: "
                f"{rms_one * MM_PER_M:.3g} mm): {groups[0].size} rows (pose_id {_ids(groups[0])}) and {groups[1].size} "
                f"rows (pose_id {_ids(groups[1])}); {cause}")
    return RowSplit(found, kind, (tuple(int(p) for p in groups[0]), tuple(int(p) for p in groups[1])),
                    rms_one * MM_PER_M, (rms_two[0] * MM_PER_M, rms_two[1] * MM_PER_M),
                    None if noise_m is None else noise_m * MM_PER_M, name, text, tm.trace)
