"""Diagnosis: is there structure beyond the noise floor, what explains it, how much does adding it help.

Reads only a dataset (and optionally an existing geometric calibration). The procedure
(``docs/diagnosis.md`` has the reasoning):

1. **Noise floor** from what a user can measure: consecutive repeats of one configuration (pooled variance:
   the sensor noise) *and* the plate's rigid geometry (the three inter-sphere distances are constant, so
   their spread over the campaign is the instrument's pose-to-pose error: ``var(d) = 2 sigma^2`` for
   independent isotropic centre errors), optionally a stated figure (``dataset.toml [noise] position_mm``,
   an artifact measurement). The floor is the largest of them; never the world's truth.
2. **Geometric fit** on the calibration rows (the estimator's default, noise fixed to the floor).
3. **Rows.** Rows with unknown history (the first row, a gap in ``t_s``, a recorded restart) start an unknown
   approach state: history-dependent terms read 0 there. Gross rows (a per-row misfit beyond both the
   floor's ``1e-6 / n`` quantile and ``median + 8 MAD`` of the rows, at most 2 % of the rows) are
   down-weighted to zero and listed: no single row vetoes or elects an effect.
4. **Test** on the validation rows: ``T = r^T (I + J C J^T)^-1 r`` (whitened; ``C`` the parameter covariance),
   ``chi2(m)`` with a stated floor, ``(T/m) ~ F(m, nu)`` with an estimated one.
5. **Sparse selection** (only when the test fires): forward selection over *atoms*
   (:mod:`twin.diagnosis.atoms`; the named catalogue and the unnamed dictionary compete in every round).
   Each atom is reduced to what the geometry cannot absorb; its calibration evidence is
   ``Delta chi2 = |P r|^2`` (``P`` the projector on its reduced columns, ``r`` the current residual) with
   ``p = chi2_sf(Delta chi2, rank)``, Bonferroni-adjusted by the size of its pool (the generic dictionary is
   ~50x larger than the catalogue, which therefore wins ties). The best atom is kept only if (a)
   ``p_adj < alpha_select`` and (b) its linearised prediction ``u`` on the held-out rows correlates with their
   residual: ``z = r_v . u / (|u| rms(r_v)) > z_min`` (self-normalised, so a floor off by a factor does not
   elect an atom), also without the single most favourable row, and ``|r_v - u| < |r_v|``. Kept atoms are
   refitted with the geometry (Gauss-Newton); a backward pass drops atoms that became redundant. Atoms the
   data cannot separate from a chosen one (>= 90 % of its explained residual, evidence within ``e^5``) are
   reported as alternatives.
6. **Partial explanations** are kept: every confirmed atom stays in the model whether or not the remainder
   passes the test; ``explained_fraction`` is ``(T_before - T_after) / (T_before - m)`` on the held-out rows.
7. ``structured``: the test fires and either an atom is confirmed on held-out rows or the scatter exceeds
   ``floor_tolerance`` times the floor (an excess without anything predictable is reported as a note: the
   floor may be underestimated).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np
from scipy import stats

from ..dataset import Dataset
from ..estimator.calibration import Calibration
from ..estimator.core import Prepared, prepare
from ..estimator.methods import build_calibration, identify_best
from ..estimator.problem import Observations, kabsch
from ..estimator.solvers import gauss_newton
from ..transforms import matrix_to_rotvec
from .atoms import Atom, approach_unknown, catalogue_atoms, feature_values, generic_atoms
from .candidates import EFFECT_VOCABULARY, RowContext
from .extend import AtomTerm, ExtendedModel, reduced_basis

__all__ = [
    "NoiseFloor",
    "StructureTest",
    "CandidateScore",
    "DiagnosisResult",
    "DiagnosisError",
    "EffectFit",
    "noise_floor",
    "history_resets",
    "row_context",
    "diagnose",
    "fit_with_effects",
]

_MM = 1e-3
_DEG = np.pi / 180.0
CATALOGUE_MARGIN = 10.0  # [natural log of p] an unnamed term is preferred to a named one only beyond this
MINOR_RMS = 0.3  # an atom whose unique effect is below this RMS (in units of the floor) is reported as minor


class DiagnosisError(ValueError):
    """The dataset lacks what diagnosis needs; the message says what to add."""


@dataclass(frozen=True)
class NoiseFloor:
    """Measurement noise per sphere coordinate ``sigma`` [m], its degrees of freedom (``inf`` when stated),
    where it came from, how many repeat groups there were, and every estimate available
    (``components``: ``repeats``, ``plate``, ``stated`` -> ``{sigma_mm, dof}``)."""

    sigma: float
    dof: float
    source: str
    groups: int
    components: dict = field(default_factory=dict)


@dataclass(frozen=True)
class StructureTest:
    """``T`` (quadratic form of the validation residuals), its ``m`` degrees of freedom, ``p_value``, and the
    RMS of the whitened residuals (1 for noise alone)."""

    statistic: float
    dof: int
    p_value: float
    whitened_rms: float
    distribution: str


@dataclass(frozen=True)
class CandidateScore:
    """One atom considered in a selection round: reduced dimension, calibration ``Delta chi2``, adjusted
    p-value, held-out ``z``, and what was decided."""

    round: int
    name: str
    dim: int
    delta_chi2: float
    p_adjusted: float
    z_validation: float
    decision: str


@dataclass(frozen=True, eq=False)
class DiagnosisResult:
    """What diagnosis found. ``before``/``after``: validation error statistics
    ``{position_mm: {mean, rms, max}, orientation_deg: {mean, rms, max}}``; ``atoms``: every chosen term
    (named and unnamed) in words with value and standard deviation; ``effects``: the catalogue families
    among them; ``unnamed``: the chosen terms outside the catalogue; ``alternatives``: explanations the
    data cannot tell apart from a chosen one; ``rows``: rows flagged (gross, unknown history)."""

    structured: bool
    p_value: float
    alpha: float
    test_before: StructureTest
    test_after: StructureTest | None
    effects: tuple[str, ...]
    effect_parameters: dict[str, Any]
    explained: bool
    before: dict[str, Any]
    after: dict[str, Any]
    noise: NoiseFloor
    scores: tuple[CandidateScore, ...]
    calibration_geometric: Calibration
    calibration: Calibration
    series: dict[str, np.ndarray] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    atoms: tuple[dict, ...] = ()
    unnamed: tuple[dict, ...] = ()
    alternatives: tuple[dict, ...] = ()
    explained_fraction: float = 0.0
    rows: dict[str, Any] = field(default_factory=dict)


# ------------------------------------------------------------------------------------------------
# Noise floor
# ------------------------------------------------------------------------------------------------

def _repeat_floor(ds: Dataset) -> tuple[float, int, int]:
    """Pooled variance of consecutive repeats: ``(sum of squares, dof, groups)``."""
    st = ds.station_ids
    qr = np.round(ds.q, 9)
    ss, dof, groups, k, n = 0.0, 0, 0, 0, ds.n
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
                    ss += float(np.sum((v - v.mean(axis=0)) ** 2))
                    dof += 3 * (int(rows.sum()) - 1)
            groups += 1
        k = j
    return ss, dof, groups


def _plate_floor(ds: Dataset) -> tuple[float, float] | None:
    """Per-coordinate error from the spread of the three inter-sphere distances over the campaign.

    For independent isotropic centre errors ``sigma``, ``var(|p_a - p_b|) = 2 sigma^2``. Robust spread (MAD)
    per pair, so that a few gross or mislabelled rows do not set the floor. Returns ``(sigma [m], dof)``.
    """
    full = ds.sphere_seen.all(axis=1)
    if full.sum() < 10:
        return None
    P = ds.spheres[full]
    var = []
    for a, b in ((0, 1), (0, 2), (1, 2)):
        d = np.linalg.norm(P[:, a] - P[:, b], axis=1)
        mad = 1.4826 * float(np.median(np.abs(d - np.median(d))))
        # the MAD's efficiency is ~37 %: combine it with the plain variance of the rows within 5 MAD
        keep = np.abs(d - np.median(d)) <= 5 * max(mad, 1e-12)
        var.append(float(np.var(d[keep], ddof=1)) if keep.sum() > 2 else mad**2)
    sigma = float(np.sqrt(np.mean(var) / 2.0))
    # three distances of one row share their spheres: about two independent values per row
    return sigma, float(2 * (full.sum() - 1))


def noise_floor(ds: Dataset, *, stated_ok: bool = True) -> NoiseFloor:
    """The sphere-coordinate noise floor (see the module docstring): the largest of the repeats' spread, the
    plate-geometry spread and the stated figure, with the degrees of freedom of the one chosen."""
    if not ds.has_spheres:
        if ds.noise_position is not None and stated_ok:
            return NoiseFloor(ds.noise_position, float("inf"), "dataset.toml [noise] position_mm (stated)", 0,
                              {"stated": {"sigma_mm": ds.noise_position / _MM, "dof": None}})
        raise DiagnosisError("diagnosis of pose data needs [noise] position_mm/orientation_rad in dataset.toml")
    comps: dict[str, tuple[float, float, str]] = {}
    ss, dof, groups = _repeat_floor(ds)
    if dof >= 30:
        comps["repeats"] = (float(np.sqrt(ss / dof)), float(dof), f"{groups} groups of consecutive repeats")
    pl = _plate_floor(ds)
    if pl is not None:
        comps["plate"] = (pl[0], pl[1], f"spread of the plate's inter-sphere distances over {int(pl[1] / 2 + 1)} rows")
    if stated_ok and ds.noise_position is not None:
        comps["stated"] = (float(ds.noise_position), float("inf"), "dataset.toml [noise] position_mm (stated)")
    if not comps:
        raise DiagnosisError(
            "diagnosis needs the measurement noise floor: repeat some configurations (measure the same commanded "
            "joints twice in a row, at least ~10 repeats), measure rows with all three spheres (their distances "
            "give the instrument's error), or state the instrument's noise in dataset.toml ([noise] position_mm)"
            + (f"; found only {groups} repeat groups ({dof} degrees of freedom)" if groups else "")
        )
    name = max(comps, key=lambda k: comps[k][0])
    sigma, nu, src = comps[name]
    others = "; ".join(f"{k}: {v[0] / _MM:.5f} mm" for k, v in comps.items() if k != name)
    source = src + (f" (the largest; {others})" if others else "")
    return NoiseFloor(sigma, nu, source, groups,
                      {k: {"sigma_mm": v[0] / _MM, "dof": None if np.isinf(v[1]) else v[1], "source": v[2]}
                       for k, v in comps.items()})


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


# ------------------------------------------------------------------------------------------------
# Statistics
# ------------------------------------------------------------------------------------------------

def _structure_test(r: np.ndarray, Jv: np.ndarray, Jc: np.ndarray, floor: NoiseFloor) -> StructureTest:
    """``T = r^T (I + Jv C Jv^T)^-1 r`` with ``C = (Jc^T Jc)^-1`` (whitened units)."""
    m = r.size
    H = Jc.T @ Jc
    # Woodbury with C = H^-1: (I + Jv C Jv^T)^-1 = I - Jv (H + Jv^T Jv)^-1 Jv^T
    M = H + Jv.T @ Jv
    y = Jv.T @ r
    T = float(r @ r - y @ np.linalg.lstsq(M, y, rcond=None)[0]) if M.size else float(r @ r)
    if np.isinf(floor.dof):
        p = float(stats.chi2.sf(T, m))
        dist = f"chi2({m})"
    else:
        p = float(stats.f.sf(T / m, m, floor.dof))
        dist = f"F({m}, {int(floor.dof)})"
    return StructureTest(T, m, p, float(np.sqrt(np.mean(r**2))), dist)


def _row_rms(r: np.ndarray, row: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    ss = np.bincount(row, weights=r**2, minlength=n)
    cnt = np.bincount(row, minlength=n)
    return np.sqrt(ss / np.maximum(cnt, 1)), cnt


def _gross_rows(r: np.ndarray, row: np.ndarray, n: int, *, max_fraction: float = 0.02) -> np.ndarray:
    """Rows ``(n,)`` bool whose whitened misfit is beyond both the floor's ``1e-6/n`` quantile and
    ``median + 8 MAD`` of the rows; none when more than ``max(2, max_fraction n)`` rows are (that is
    structure, not a few gross rows)."""
    e, cnt = _row_rms(r, row, n)
    has = cnt > 0
    if has.sum() < 5:
        return np.zeros(n, dtype=bool)
    k = np.maximum(cnt, 1)
    thr_floor = np.sqrt(stats.chi2.isf(1e-6 / max(n, 1), k) / k)
    med = float(np.median(e[has]))
    mad = 1.4826 * float(np.median(np.abs(e[has] - med)))
    bad = has & (e > thr_floor) & (e > med + 8 * max(mad, 0.05 * med))
    if bad.sum() > max(2, int(max_fraction * has.sum())):
        return np.zeros(n, dtype=bool)
    return bad


def _unmask(r: np.ndarray, obs: Observations) -> np.ndarray:
    """Whitened sphere residuals back to ``(n, 3, 3)`` [m] (order of ``absolute_residuals``)."""
    shape = (3, 3, obs.n)
    mask = np.broadcast_to(obs.seen.T[:, None, :], shape)
    tmp = np.zeros(shape)
    tmp[mask] = r * obs.sigma_position
    return np.transpose(tmp, (2, 0, 1))


def _stats(e: np.ndarray) -> dict[str, float]:
    return {"mean": float(np.mean(e)), "rms": float(np.sqrt(np.mean(e**2))), "max": float(np.max(e))}


def _error_stats(model: ExtendedModel, z: np.ndarray, keep: np.ndarray | None = None) -> dict[str, Any]:
    """Validation error statistics: 3-D sphere-centre error [mm], and the plate orientation error [deg]
    between rigid fits of the plate to the measured and to the predicted spheres (rows with all three);
    ``keep`` ``(n,)``: the rows counted (gross rows left out)."""
    _, phis = model.split(z)
    obs = model.effective_obs(phis)
    res = model.residuals(z, jacobian=False)
    diff = _unmask(res.r, obs)  # measured - predicted (n, 3, 3) [m], zero where not seen
    rows = np.ones(obs.n, bool) if keep is None else keep
    seen = obs.seen & rows[:, None]
    e3 = np.linalg.norm(diff, axis=-1)[seen]
    out: dict[str, Any] = {"n_rows": int(rows.sum()), "position_mm": _stats(e3 / _MM)}
    full = seen.all(axis=1)
    if full.any():
        meas = obs.spheres[full]
        pred = meas - diff[full]
        A = np.broadcast_to(model.obs.spheres_tool, meas.shape)
        Rm, _ = kabsch(A, meas)
        Rp, _ = kabsch(A, pred)
        ang = np.linalg.norm(matrix_to_rotvec(Rm @ np.swapaxes(Rp, 1, 2)), axis=-1)
        out["orientation_deg"] = _stats(ang / _DEG)
    return out


# ------------------------------------------------------------------------------------------------
# Fitting
# ------------------------------------------------------------------------------------------------

@dataclass
class _Fit:
    chosen: list  # [(Atom, basis)]
    z: np.ndarray
    free: np.ndarray
    chi2: float
    model_cal: ExtendedModel
    model_val: ExtendedModel


class _Problem:
    """Everything the selection rounds share: observations, rows, features, weights."""

    def __init__(self, prep: Prepared, floor: NoiseFloor, ctx: RowContext, free_geo: np.ndarray):
        self.prep = prep
        self.obs_cal = prep.obs_cal.with_sigma(floor.sigma)
        self.obs_val = prep.obs_val.with_sigma(floor.sigma)
        self.rows_cal = prep.rows[prep.cal]
        self.rows_val = prep.rows[prep.val]
        self.ctx = ctx
        self.free_geo = free_geo
        self.floor = floor
        self._F: dict[str, np.ndarray] = {}
        self._cache: dict = {}
        self.w_cal = np.ones(self.obs_cal.n)
        self.keep_val = np.ones(self.obs_val.n, dtype=bool)

    def features(self, atom: Atom) -> np.ndarray:
        key = repr(atom.features)
        if "regressor" in atom.meta:  # a given regressor (fit_with_effects with a legacy candidate)
            key = f"regressor:{id(atom)}"
        F = self._F.get(key)
        if F is None and "regressor" in atom.meta:
            G = atom.meta["regressor"](self.ctx)
            F = G.reshape(len(G), -1)
            self._F[key] = F
        elif F is None:
            F = feature_values(atom.features, self.ctx, self.prep.nominal, self._cache)
            self._F[key] = F
        return F

    def fit(self, x0: np.ndarray, chosen: list, z_eff: list | None = None) -> _Fit:
        tc = [AtomTerm(a, self.features(a)[self.rows_cal], B) for a, B in chosen]
        tv = [AtomTerm(a, self.features(a)[self.rows_val], B) for a, B in chosen]
        mc = ExtendedModel(self.prep.space, self.obs_cal, tc)
        mv = ExtendedModel(self.prep.space, self.obs_val, tv)
        z0 = np.concatenate([x0] + ([np.zeros(t.r) for t in tc] if z_eff is None else z_eff))
        free = np.concatenate([self.free_geo, np.arange(self.prep.space.size, mc.size)]).astype(int)
        # 1e-11 (SI) per step is far below any effect or geometric parameter that matters here
        gn = gauss_newton(lambda z: mc.residuals(z), z0, free, row_weights=self.w_cal, max_iter=30, xtol=1e-11,
                          stage="extended")
        res = mc.residuals(gn.x, jacobian=False)
        rr = res.r * np.sqrt(self.w_cal[res.row])
        return _Fit(list(chosen), gn.x, free, float(rr @ rr), mc, mv)

    def test(self, fit: _Fit) -> StructureTest:
        rv = fit.model_val.residuals(fit.z)
        rc = fit.model_cal.residuals(fit.z)
        kv = self.keep_val[rv.row]
        Jc = rc.J[:, fit.free] * np.sqrt(self.w_cal[rc.row])[:, None]
        return _structure_test(rv.r[kv], rv.J[kv][:, fit.free], Jc, self.floor)


def _chi2_logsf(x: float, k: int) -> float:
    """``log P(chi2(k) > x)``, finite where scipy's underflows to ``-inf`` (large ``x``: the leading term of
    the upper incomplete gamma function, ``-x/2 + (k/2 - 1) log(x/2) - lgamma(k/2)``)."""
    v = float(stats.chi2.logsf(x, k))
    if np.isfinite(v):
        return v
    from scipy.special import gammaln

    return float(-x / 2 + (k / 2 - 1) * np.log(x / 2) - gammaln(k / 2))


def _raw_columns(model: ExtendedModel, atom: Atom, F: np.ndarray, z: np.ndarray, res) -> np.ndarray:
    x, phis = model.split(z)
    obs = model.effective_obs(phis)
    return model.columns(AtomTerm(atom, F, np.eye(F.shape[1])), x, obs, res)


@dataclass
class _Scored:
    atom: Atom
    basis: np.ndarray
    Ep: np.ndarray  # projected reduced columns (m_cal_kept, r)
    E: np.ndarray  # reduced columns (m_cal_kept, r)
    psi: np.ndarray
    dchi2: float
    logp_adj: float
    fitted: np.ndarray  # Ep psi
    r: np.ndarray  # the residual it was scored against (projected off the current model)


def _screenable(a: Atom) -> bool:
    """Atoms whose columns are one model column times their features (batch-screened)."""
    if "regressor" in a.meta or len(a.features) > 3:
        return False
    return a.place in ("joint", "length", "scale") or (a.place == "param" and a.target not in ("tool", "base"))


def _screen(prob: _Problem, fit: _Fit, atoms: list[Atom], rc, keep, sw, Q, r, pool_sizes, chunk: int = 600) -> np.ndarray:
    """Pool-adjusted log p-values ``(len(atoms),)`` of single-column-times-feature atoms, batched: columns
    scaled to unit norm, projected off the current model, directions below 1 % of a unit column dropped
    (eigenvalues of the small Gram matrices), ``Delta chi2 = sum (v^T E^T r)^2 / lambda``."""
    from .extend import param_weights

    x = fit.z[: prob.prep.space.size]
    Jg = rc.J[:, : prob.prep.space.size]
    base_cache: dict[tuple, np.ndarray] = {}
    coords = None
    out = np.full(len(atoms), np.inf)
    swk = sw[keep]
    rows = rc.row[keep]
    for c0 in range(0, len(atoms), chunk):
        part = atoms[c0:c0 + chunk]
        cols, owner = [], []
        for i, a in enumerate(part):
            key = (a.place, a.target)
            b = base_cache.get(key)
            if b is None:
                if a.place == "scale":
                    if coords is None:
                        x_, phis = fit.model_cal.split(fit.z)
                        coords = fit.model_cal._coords(fit.model_cal.effective_obs(phis))
                    b = coords
                else:
                    b = (Jg @ param_weights(prob.prep.space, x, a))[:, 0]
                b = b[keep] * swk
                base_cache[key] = b
            F = prob.features(a)[prob.rows_cal][rows]
            cols.append(b[:, None] * F)
            owner += [i] * F.shape[1]
        E = np.concatenate(cols, axis=1)
        nrm = np.linalg.norm(E, axis=0)
        E = E / np.where(nrm > 0, nrm, 1.0)
        Ep = E - Q @ (Q.T @ E)
        owner = np.asarray(owner)
        er = Ep.T @ r
        for i in range(len(part)):
            idx = np.flatnonzero(owner == i)
            if not np.any(nrm[idx] > 0):
                continue
            G = Ep[:, idx].T @ Ep[:, idx]
            lam, V = np.linalg.eigh(G)
            ok = lam > 1e-4  # singular value above 1 % of a unit column
            if not np.any(ok):
                continue
            d = float(np.sum((V[:, ok].T @ er[idx]) ** 2 / lam[ok]))
            out[c0 + i] = _chi2_logsf(d, int(ok.sum())) + np.log(pool_sizes[part[i].pool])
    return out


def _score_atoms(prob: _Problem, fit: _Fit, atoms: list[Atom], pool_sizes: dict[str, int], *,
                 exact_top: int = 40) -> list[_Scored]:
    """Linearised evidence of the atoms against the current fit (see the module docstring). The catalogue
    and the broad atoms are scored exactly; the many small dictionary atoms are screened in batches and only
    the ``exact_top`` strongest of them scored exactly."""
    rc = fit.model_cal.residuals(fit.z)
    sw = np.sqrt(prob.w_cal[rc.row])
    keep = sw > 0
    A = (rc.J[:, fit.free] * sw[:, None])[keep]
    Q, _ = np.linalg.qr(A)
    r = (rc.r * sw)[keep]
    r = r - Q @ (Q.T @ r)
    screen = [a for a in atoms if a.pool != "catalogue" and _screenable(a)]
    exact = [a for a in atoms if not (a.pool != "catalogue" and _screenable(a))]
    if screen:
        lp = _screen(prob, fit, screen, rc, keep, sw, Q, r, pool_sizes)
        exact += [screen[i] for i in np.argsort(lp)[:exact_top] if np.isfinite(lp[i])]
    out = []
    for a in exact:
        F = prob.features(a)[prob.rows_cal]
        if not np.any(F):
            continue
        E = _raw_columns(fit.model_cal, a, F, fit.z, rc)[keep] * sw[keep][:, None]
        B = reduced_basis(E, Q=Q, max_rank=6)
        if B.shape[1] == 0:
            continue
        EB = E @ B
        Ep = EB - Q @ (Q.T @ EB)
        psi, *_ = np.linalg.lstsq(Ep, r, rcond=None)
        fitted = Ep @ psi
        d = float(fitted @ fitted)
        # log of the pool-adjusted p-value (smaller is stronger); chi2.logsf stays finite where sf underflows
        logp = _chi2_logsf(d, B.shape[1]) + np.log(pool_sizes[a.pool])
        out.append(_Scored(a, B, Ep, EB, psi, d, logp, fitted, r))
    return out


def _order(scored: list[_Scored], broad_dim: int = 4) -> list[_Scored]:
    """Atoms in the order to try: by pool-adjusted evidence, except that a broad atom (``>= broad_dim``
    reduced parameters: compliance, a whole frame) goes behind the small atoms when small atoms together
    explain more within the same number of parameters (a broad atom collects a little of several effects;
    it must not pre-empt the small atoms that each hold one of them)."""
    order = sorted(scored, key=lambda s: s.logp_adj)
    if order and order[0].atom.pool == "generic":
        # the dictionary holds supersets of catalogue terms (a polynomial in q_j on theta_j contains the
        # gear-ratio direction): an unnamed term must beat the best named one clearly, not by fitting noise
        named = [s for s in order if s.atom.pool != "generic"]
        if named and named[0].logp_adj < order[0].logp_adj + CATALOGUE_MARGIN:
            order = [named[0]] + [s for s in order if s is not named[0]]
    if not order or order[0].basis.shape[1] < broad_dim:
        return order
    best = order[0]
    # a named broad atom (compliance) answers to the named small atoms; an unnamed one to all
    small = [s for s in order if s.basis.shape[1] < broad_dim
             and (best.atom.pool != "catalogue" or s.atom.pool == "catalogue")]
    gain = _omp_gain(small, best.basis.shape[1])
    if gain >= best.dchi2 and small:
        return small[:1] + [s for s in order if s is not small[0]]
    return order


def _omp_gain(small: list[_Scored], budget: int, pool: int = 60) -> float:
    """Calibration ``Delta chi2`` that small atoms reach together within ``budget`` parameters: greedy
    orthogonal matching pursuit over their projected columns on the residual they were scored against (the
    ``pool`` strongest atoms)."""
    cand = sorted(small, key=lambda s: -s.dchi2)[:pool]
    if not cand:
        return 0.0
    r = cand[0].r
    Qs = [np.linalg.qr(s.Ep)[0] for s in cand]
    taken = np.zeros((len(r), 0))
    used = 0
    gain = 0.0
    avail = list(range(len(cand)))
    while avail:
        best = None
        for i in avail:
            Q = Qs[i] - taken @ (taken.T @ Qs[i])
            Qo, R = np.linalg.qr(Q)
            keep = np.abs(np.diag(R)) > 1e-8
            Qo = Qo[:, keep]
            g = float(np.sum((Qo.T @ r) ** 2))
            if best is None or g > best[0]:
                best = (g, i, Qo)
        g, i, Qo = best
        if used + Qo.shape[1] > budget:
            break
        gain += g
        used += Qo.shape[1]
        r = r - Qo @ (Qo.T @ r)
        taken = np.concatenate([taken, Qo], axis=1)
        avail.remove(i)
    return gain


def _confirm(prob: _Problem, fit: _Fit, s: _Scored, z_min: float) -> tuple[float, float, bool]:
    """Held-out check of a scored atom: ``z``, ``z`` without the most favourable row, and whether the
    held-out residual norm drops."""
    rc = fit.model_cal.residuals(fit.z)
    sw = np.sqrt(prob.w_cal[rc.row])
    keep = sw > 0
    A = (rc.J[:, fit.free] * sw[:, None])[keep]
    # geometry re-adjusts to the atom: beta_A = -A^+ E B psi
    beta_A = -np.linalg.lstsq(A, s.E @ s.psi, rcond=None)[0]
    rv = fit.model_val.residuals(fit.z)
    kv = prob.keep_val[rv.row]
    Fv = prob.features(s.atom)[prob.rows_val]
    Ev = _raw_columns(fit.model_val, s.atom, Fv, fit.z, rv) @ s.basis
    u = (Ev @ s.psi + rv.J[:, fit.free] @ beta_A)[kv]
    r = rv.r[kv]
    nu = float(np.linalg.norm(u))
    if nu <= 0:
        return 0.0, 0.0, False
    srms = float(np.sqrt(np.mean(r**2)))
    contrib = np.bincount(rv.row[kv], weights=r * u, minlength=fit.model_val.obs.n)
    z = float(r @ u) / (nu * srms)
    z_minus = float(r @ u - contrib.max()) / (nu * srms)
    better = float(np.sum((r - u) ** 2)) < float(r @ r)
    return z, z_minus, better


# ------------------------------------------------------------------------------------------------
# The procedure
# ------------------------------------------------------------------------------------------------

def diagnose(
    dataset: Dataset,
    *,
    calibration: Calibration | None = None,
    alpha: float = 0.01,
    holdout: float | None = None,
    seed: int = 0,
    max_effects: int = 16,
    alpha_select: float = 0.01,
    z_min: float = 3.0,
    floor_tolerance: float = 1.5,
    generic: bool = True,
    q_start: np.ndarray | None = None,
    callback: Callable[[CandidateScore], None] | None = None,
    bic_margin: float | None = None,
    candidates: Any = None,
) -> DiagnosisResult:
    """Diagnose ``dataset`` (see the module docstring for the procedure and its statistics).

    ``holdout``: without a ``set`` column, hold out this seeded random fraction for validation.
    ``calibration``: a geometric calibration to start from (refitted on this dataset's calibration rows).
    ``max_effects``: most atoms kept. ``alpha_select``: family-wise false-selection rate per round (each pool
    Bonferroni-adjusted). ``z_min``: held-out confirmation threshold. ``floor_tolerance``: an excess scatter
    below this multiple of the floor, with nothing predictable on held-out rows, is not called structure.
    ``generic``: also search the unnamed dictionary. ``q_start``: where the robot stood before the first row,
    when known (otherwise the first row's approach is unknown). ``bic_margin`` and ``candidates`` are
    accepted for compatibility and ignored.
    """
    if not isinstance(dataset, Dataset):
        raise ValueError(f"dataset must be a twin.dataset.Dataset, got {type(dataset).__name__}")
    if not (0 < alpha < 0.5):
        raise ValueError(f"alpha must be in (0, 0.5), got {alpha!r}")
    if not (0 < alpha_select < 0.5):
        raise ValueError(f"alpha_select must be in (0, 0.5), got {alpha_select!r}")
    if not (isinstance(max_effects, (int, np.integer)) and max_effects >= 0):
        raise ValueError(f"max_effects must be a non-negative integer, got {max_effects!r}")
    if not dataset.has_spheres:
        raise DiagnosisError("diagnosis works on sphere-centre datasets (p0_x..p2_z); this one has none")
    if dataset.set is None:
        if holdout is None:
            raise DiagnosisError(
                "diagnosis needs held-out rows: add a 'set' column with 'calibration' and 'validation' rows, "
                "or pass holdout=FRACTION (CLI: --holdout 0.5) to hold out a seeded random fraction"
            )
        if not (0.05 <= holdout <= 0.8):
            raise ValueError(f"holdout must be in [0.05, 0.8], got {holdout!r}")
    elif not np.any(dataset.set == "validation"):
        raise DiagnosisError("diagnosis needs held-out rows: the 'set' column has no 'validation' rows")
    floor = noise_floor(dataset)
    notes: list[str] = [f"noise floor {floor.sigma / _MM:.5f} mm per coordinate from {floor.source}"]
    prep = prepare(dataset, noise_position=floor.sigma, validation_fraction=holdout or 0.0, seed=seed)
    if prep.val.size == 0:
        raise DiagnosisError("diagnosis needs held-out rows with measurements; none are usable")
    ident = identify_best(prep, alpha=1e-6)
    if calibration is not None:
        notes.append(f"started from the given calibration ({calibration.method}); refitted on this dataset")
    geo = build_calibration(prep, ident, "best", {"diagnosis": True, "noise_floor_mm": floor.sigma / _MM})
    ctx = row_context(dataset, q_start)
    free_geo = np.flatnonzero(np.array(ident.status) == "identified")
    prob = _Problem(prep, floor, ctx, free_geo)

    # gross rows of the geometric fit (calibration: weight 0; validation: left out of test and statistics)
    fit = prob.fit(ident.x, [])
    _update_gross(prob, fit)
    fit = prob.fit(fit.z[: prep.space.size], [])
    base_fit = fit
    test0 = prob.test(base_fit)
    before = _error_stats(base_fit.model_val, base_fit.z, prob.keep_val)
    excess = test0.p_value < alpha

    scores: list[CandidateScore] = []
    alternatives: list[dict] = []
    chosen: list = []
    entry_chi2: dict[str, float] = {}
    test = test0
    if excess and max_effects > 0:
        length_names = [n for n in prep.space.names[: prep.space.n_robot]
                        if n.rstrip("0123456789") in ("d", "a")]
        cat = catalogue_atoms(prep.nominal, ctx, length_names)
        pool = list(cat)
        if generic:
            pnames = [n for n in prep.space.names[: prep.space.n_robot] if n.rstrip("0123456789") in ("d", "a", "alpha", "beta")]
            pool += generic_atoms(prep.nominal, ctx, pnames, length_names, cat)
        sizes = {k: max(1, sum(a.pool == k for a in pool)) for k in ("catalogue", "scan", "generic")}
        rejected: set[str] = set()
        entry_chi2: dict[str, float] = {}
        for rnd in range(1, max_effects + 1):
            remaining = [a for a in pool if a.key not in rejected and a.key not in {c.key for c, _ in chosen}]
            scored = _score_atoms(prob, fit, remaining, sizes)
            if not scored:
                break
            order = _order(scored)
            accepted = None
            for s in order[:3]:
                logp_adj = s.logp_adj
                if logp_adj >= np.log(alpha_select):
                    scores.append(CandidateScore(rnd, s.atom.label, s.basis.shape[1], s.dchi2, float(np.exp(logp_adj)), float("nan"),
                                                 "not significant on the calibration rows"))
                    break
                z, zm, better = _confirm(prob, fit, s, z_min)
                ok = z > z_min and zm > z_min and better
                sc = CandidateScore(rnd, s.atom.label, s.basis.shape[1], s.dchi2, float(np.exp(logp_adj)), z,
                                    "kept" if ok else ("not confirmed on held-out rows" if not (z > z_min) else
                                                       "held-out gain rests on one row" if not (zm > z_min) else
                                                       "held-out error not reduced"))
                scores.append(sc)
                if callback:
                    callback(sc)
                if ok:
                    accepted = s
                    break
                rejected.add(s.atom.key)
            if accepted is None:
                break
            alternatives += _alternatives(accepted, scored)
            chosen.append((accepted.atom, accepted.basis))
            entry_chi2[accepted.atom.key] = accepted.dchi2
            z_eff = _psi_init(fit, chosen)
            fit = prob.fit(fit.z[: prep.space.size], chosen, z_eff)
            _update_gross(prob, fit)
        if chosen:
            fit, dropped = _backward(prob, fit, alpha_select, sizes)
            for a in dropped:
                notes.append(f"dropped in the backward pass (redundant once the others are in): {a.label}")
            alternatives = [d for d in alternatives if d["of"] in {a.label for a, _ in fit.chosen}]
            _update_gross(prob, fit)
            fit = prob.fit(fit.z[: prep.space.size], fit.chosen, _psi_init(fit, fit.chosen))
            test = prob.test(fit)
        chosen = fit.chosen
        base_fit = prob.fit(base_fit.z[: prep.space.size], [])
        test0 = prob.test(base_fit)
        before = _error_stats(base_fit.model_val, base_fit.z, prob.keep_val)

    confirmed = bool(chosen)
    structured = bool(excess and (confirmed or test0.whitened_rms > floor_tolerance))
    if excess and not structured:
        notes.append(f"the held-out scatter is {test0.whitened_rms:.2f}x the floor (p = {test0.p_value:.2g}) but nothing "
                     f"in it is predictable on held-out rows: no structure is claimed (the floor may be underestimated)")
    if structured and not confirmed:
        notes.append("the residual is structured and no term of the catalogue or the dictionary explains it "
                     "on held-out rows")
    explained = bool(structured and confirmed and test.p_value >= alpha)
    frac = 0.0
    if confirmed:
        ex = test0.statistic - test0.dof
        frac = float(np.clip((test0.statistic - test.statistic) / ex, 0.0, 1.0)) if ex > 0 else 1.0
        if not explained:
            notes.append(f"partial explanation: {100 * frac:.0f} % of the held-out excess explained; the remainder is "
                         f"still structured (p = {test.p_value:.2g})")
    use = fit if confirmed else base_fit
    after = _error_stats(use.model_val, use.z, prob.keep_val) if confirmed else before
    atoms_json, params = _atom_report(prob, use, base_fit.chi2, entry_chi2) if confirmed else ([], {})
    # every kept atom stays in the model; the named effects are the families of the atoms that explained at
    # least MINOR_RMS of the floor (RMS per residual) when they entered
    effects = tuple(dict.fromkeys(a["family"] for a in atoms_json if a["family"] != "unnamed" and not a["minor"]))
    minor = [a["label"] for a in atoms_json if a["minor"]]
    if minor:
        notes.append(f"minor terms kept in the model but not named as effects (each explained less than {MINOR_RMS} "
                     f"of the floor, RMS per residual, when it entered): {'; '.join(minor)}")
    unnamed = tuple(a for a in atoms_json if a["family"] == "unnamed" and not a["minor"])
    rows = _rows_report(prob, prep, dataset)
    if rows["gross_validation"] or rows["gross_calibration"]:
        notes.append(f"down-weighted gross rows (pose_id): calibration {rows['gross_calibration']}, "
                     f"validation {rows['gross_validation']}")
    extended = replace(
        geo,
        method="best+effects" if confirmed else geo.method,
        x=use.z[: prep.space.size] if confirmed else geo.x,
        effects=tuple(atoms_json),
    )
    series = _series(base_fit, use, prob)
    return DiagnosisResult(
        structured=structured,
        p_value=float(test0.p_value),
        alpha=alpha,
        test_before=test0,
        test_after=test if confirmed else None,
        effects=effects,
        effect_parameters=params,
        explained=explained,
        before=before,
        after=after,
        noise=floor,
        scores=tuple(scores),
        calibration_geometric=geo,
        calibration=extended,
        series=series,
        notes=tuple(notes),
        atoms=tuple(atoms_json),
        unnamed=unnamed,
        alternatives=tuple(alternatives),
        explained_fraction=frac,
        rows=rows,
    )


def _covariance(J: np.ndarray) -> np.ndarray:
    """``(J^T J)^+`` of whitened columns, column-scaled first (geometric and effect columns differ by many
    orders of magnitude: an unscaled pseudo-inverse truncates the small ones)."""
    d = np.linalg.norm(J, axis=0)
    d = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 0.0)
    Js = J * d
    return d[:, None] * np.linalg.pinv(Js.T @ Js, rcond=1e-12) * d[None, :]


def _update_gross(prob: _Problem, fit: _Fit) -> None:
    rc = fit.model_cal.residuals(fit.z, jacobian=False)
    prob.w_cal = (~_gross_rows(rc.r, rc.row, fit.model_cal.obs.n)).astype(float)
    rv = fit.model_val.residuals(fit.z, jacobian=False)
    prob.keep_val = ~_gross_rows(rv.r, rv.row, fit.model_val.obs.n)


def _psi_init(fit: _Fit, chosen: list) -> list[np.ndarray]:
    """Start values of the reduced coordinates: the current fit's for atoms already in, zero for new ones."""
    prev = {t.atom.key: fit.z[fit.model_cal.offsets[k]:fit.model_cal.offsets[k + 1]]
            for k, t in enumerate(fit.model_cal.terms)}
    return [prev.get(a.key, np.zeros(B.shape[1])) if prev.get(a.key) is not None and prev[a.key].size == B.shape[1]
            else np.zeros(B.shape[1]) for a, B in chosen]


def _backward(prob: _Problem, fit: _Fit, alpha_select: float, sizes: dict) -> tuple[_Fit, list[Atom]]:
    """Drop atoms whose removal costs no significant calibration evidence (one pass, weakest first)."""
    dropped: list[Atom] = []
    changed = True
    while changed and len(fit.chosen) > 1:
        changed = False
        rc = fit.model_cal.residuals(fit.z)
        sw = np.sqrt(prob.w_cal[rc.row])
        C = _covariance(rc.J[:, fit.free] * sw[:, None])
        pos = {int(f): k for k, f in enumerate(fit.free)}
        worst = None
        for k, (a, B) in enumerate(fit.chosen):
            idx = [pos[i] for i in range(fit.model_cal.offsets[k], fit.model_cal.offsets[k + 1])]
            psi = fit.z[fit.model_cal.offsets[k]:fit.model_cal.offsets[k + 1]]
            Ck = C[np.ix_(idx, idx)]
            d = float(psi @ np.linalg.lstsq(Ck, psi, rcond=None)[0])  # chi2 cost of removing it (Wald)
            lp = _chi2_logsf(d, len(idx)) + np.log(sizes[a.pool])
            if lp >= np.log(alpha_select) and (worst is None or lp > worst[0]):
                worst = (lp, k)
        if worst is not None:
            k = worst[1]
            dropped.append(fit.chosen[k][0])
            chosen = [c for i, c in enumerate(fit.chosen) if i != k]
            fit = prob.fit(fit.z[: prob.prep.space.size], chosen, _psi_init(fit, chosen))
            changed = True
    return fit, dropped


def _alternatives(best: _Scored, scored: list[_Scored], *, share: float = 0.9, log_evidence: float = 5.0) -> list[dict]:
    """Atoms the data cannot tell apart from ``best``: they reproduce >= ``share`` of its fitted residual and
    their evidence is within ``e^log_evidence`` of it."""
    f = best.fitted
    nf = float(f @ f)
    out = []
    for s in scored:
        if s is best or nf <= 0 or s.basis.shape[1] > best.basis.shape[1]:
            continue
        if 0.5 * (best.dchi2 - s.dchi2) > log_evidence:
            continue
        Qs, _ = np.linalg.qr(s.Ep)
        cover = float(np.sum((Qs.T @ f) ** 2)) / nf
        if cover >= share:
            out.append({"of": best.atom.label, "alternative": s.atom.label, "family": s.atom.family,
                        "channel": s.atom.channel, "target": s.atom.target,
                        "delta_chi2": s.dchi2, "delta_chi2_chosen": best.dchi2, "share_reproduced": cover})
    out.sort(key=lambda d: -d["delta_chi2"])
    return out[:3]


# ------------------------------------------------------------------------------------------------
# Reports
# ------------------------------------------------------------------------------------------------

def _place_unit(a: Atom) -> tuple[str, float]:
    """Display unit of an atom's effect on its place, and the factor from SI."""
    if a.place == "joint":
        return "deg", 1 / _DEG
    if a.place in ("length", "scale"):
        return "ppm", 1e6
    if a.place == "plate":
        return "mm", 1 / _MM
    t = a.target
    if t in ("tool", "base"):
        return "mm|deg", 1.0
    if t.rstrip("0123456789") in ("d", "a"):
        return "mm", 1 / _MM
    return "deg", 1 / _DEG


def _atom_report(prob: _Problem, fit: _Fit, chi2_base: float | None = None,
                 entry_chi2: dict[str, float] | None = None) -> tuple[list[dict], dict[str, Any]]:
    """Every chosen atom: full parameters ``phi = B psi`` with standard deviations, its effect on its place
    over the calibration rows, words, its unique share of the explained calibration chi2 (Wald
    ``psi^T C_psi^-1 psi`` over ``chi2_base - chi2``), and whether it is minor: its ``Delta chi2`` when it
    entered the forward selection (what it explained beyond the atoms before it) is below ``MINOR_RMS^2``
    per residual (parts shared by two atoms belong to the one that entered first, the stronger)."""
    rc = fit.model_cal.residuals(fit.z)
    sw = np.sqrt(prob.w_cal[rc.row])
    J = rc.J[:, fit.free] * sw[:, None]
    C = _covariance(J)
    pos = {int(f): k for k, f in enumerate(fit.free)}
    _, phis = fit.model_cal.split(fit.z)
    out: list[dict] = []
    params: dict[str, Any] = {}
    for k, (t, phi) in enumerate(zip(fit.model_cal.terms, phis)):
        a = t.atom
        idx = [pos[i] for i in range(fit.model_cal.offsets[k], fit.model_cal.offsets[k + 1])]
        Cpsi = C[np.ix_(idx, idx)]
        Cphi = t.basis @ Cpsi @ t.basis.T
        psi = fit.z[fit.model_cal.offsets[k]:fit.model_cal.offsets[k + 1]]
        wald = float(psi @ np.linalg.lstsq(Cpsi, psi, rcond=None)[0])
        explained = (chi2_base - fit.chi2) if chi2_base is not None else float("nan")
        share = float(wald / explained) if explained > 0 else float("nan")
        sd = np.sqrt(np.clip(np.diag(Cphi), 0, None))
        unit, fac = _place_unit(a)
        F = prob.features(a)
        if a.place == "param" and a.target in ("tool", "base"):
            eff = F @ phi.reshape(len(a.features), 6)  # (n, 6)
            size = {"rms_mm": (np.sqrt(np.mean(eff[:, :3] ** 2)) / _MM).item(),
                    "rms_deg": (np.sqrt(np.mean(eff[:, 3:] ** 2)) / _DEG).item()}
            words = f"{size['rms_mm']:.4f} mm / {size['rms_deg']:.5f} deg RMS over the rows"
        elif a.place == "plate":
            size = {"offset_mm": (phi / _MM).tolist(), "sd_mm": (sd / _MM).tolist()}
            words = "offset (" + ", ".join(f"{v / _MM:+.4f} +- {e / _MM:.4f}" for v, e in zip(phi, sd)) + ") mm"
        elif a.place == "joints":  # a given all-joint regressor (legacy candidate)
            eff = np.einsum("nik,k->ni", F.reshape(len(F), 6, -1), phi)
            size = {"rms_deg": (np.sqrt(np.mean(eff**2, axis=0)) / _DEG).tolist()}
            words = "RMS per joint " + ", ".join(f"{v:.5f}" for v in size["rms_deg"]) + " deg"
        else:
            eff = F @ phi
            g = F.T / max(len(F), 1)
            # sd of the RMS effect (delta method on the mean square): d rms / d phi = F^T eff / (n rms)
            rms = float(np.sqrt(np.mean(eff**2)))
            grad = (g @ eff) / max(rms, 1e-300)
            sd_rms = float(np.sqrt(max(grad @ Cphi @ grad, 0.0)))
            size = {"rms": rms * fac, "sd": sd_rms * fac, "unit": unit}
            if a.family == "cyclic" and len(phi) == 2:
                amp = float(np.hypot(*phi))
                gamp = phi / max(amp, 1e-300)
                sda = float(np.sqrt(max(gamp @ Cphi @ gamp, 0.0)))
                size.update({"amplitude": amp * fac, "amplitude_sd": sda * fac})
                words = f"amplitude {amp * fac:.5f} +- {sda * fac:.5f} {unit}"
            elif len(phi) == 1:
                words = (f"{phi[0] * fac:.5g} +- {sd[0] * fac:.2g} {unit} per unit of {a.channel} "
                         f"({rms * fac:.5f} {unit} RMS over the rows)")
            else:
                words = f"{rms * fac:.5f} +- {sd_rms * fac:.5f} {unit} RMS over the rows"
        # one number in words' units for a table: amplitude (cyclic), the single coefficient, or the RMS effect
        if "amplitude" in size:
            value, value_sd, vunit = size["amplitude"], size["amplitude_sd"], unit
        elif len(phi) == 1 and a.place not in ("plate",):
            value, value_sd, vunit = float(phi[0] * fac), float(sd[0] * fac), f"{unit} per unit of {a.channel}"
        elif "rms" in size:
            value, value_sd, vunit = size["rms"], size["sd"], f"{unit} RMS"
        elif "rms_mm" in size:
            value, value_sd, vunit = size["rms_mm"], None, "mm RMS (translation)"
        else:
            value, value_sd, vunit = float(np.linalg.norm(phi) * fac), None, unit
        entry = {**a.spec(), "pool": a.pool, "values": phi.tolist(), "sd": sd.tolist(), "reduced_dimension": int(t.r),
                 "value": value, "value_sd": value_sd, "value_unit": vunit,
                 "unique_chi2": wald, "unique_share": share, "unique_rms_floor": float(np.sqrt(wald / max(J.shape[0], 1))),
                 "entry_chi2": (entry_chi2 or {}).get(a.key, wald),
                 "minor": bool(np.sqrt((entry_chi2 or {}).get(a.key, wald) / max(J.shape[0], 1)) < MINOR_RMS),
                 "size": size, "text": f"{a.label}: {words}",
                 "unit": "SI per unit of each feature: rad (joint), relative (length, scale), m (plate), m or rad (param)"}
        out.append(entry)
        params[a.label] = {"family": a.family, "values": phi.tolist(), "sd": sd.tolist(), "size": size}
    return out, params


def _rows_report(prob: _Problem, prep: Prepared, ds: Dataset) -> dict[str, Any]:
    pid = ds.pose_id
    gc = prep.rows[prep.cal][prob.w_cal == 0]
    gv = prep.rows[prep.val][~prob.keep_val]
    reset = np.flatnonzero(approach_unknown(prob.ctx))
    return {"gross_calibration": [int(pid[i]) for i in gc], "gross_validation": [int(pid[i]) for i in gv],
            "unknown_history": [int(pid[i]) for i in reset],
            "unknown_history_rule": "rows where a joint that moves has not moved since the start, a gap in t_s or "
                                    "a recorded restart: history-dependent terms read 0 there",
            "rule": "per-row misfit beyond the floor's 1e-6/n quantile and median + 8 MAD (at most 2 % of rows)"}


def _series(base: _Fit, ext: _Fit, prob: _Problem) -> dict[str, np.ndarray]:
    """Per validation row: residual norms before/after [mm] and the most telling variables."""
    from .atoms import _signs

    rows_val = prob.rows_val
    out: dict[str, np.ndarray] = {"dataset_row": rows_val, "pose_id": prob.prep.dataset.pose_id[rows_val]}
    for tag, f in (("before", base), ("after", ext)):
        r = f.model_val.residuals(f.z, jacobian=False)
        e, _ = _row_rms(r.r, r.row, f.model_val.obs.n)
        out[f"residual_rms_mm_{tag}"] = e * f.model_val.obs.sigma_position / _MM
    # each term of the extended model on the held-out rows, in its place's display unit
    _, phis = ext.model_val.split(ext.z)
    terms = {}
    for t, phi in zip(ext.model_val.terms, phis):
        unit, fac = _place_unit(t.atom)
        if t.atom.place == "param" and t.atom.target in ("tool", "base"):
            v = np.linalg.norm((t.F @ phi.reshape(len(t.atom.features), 6))[:, :3], axis=1) / _MM
            unit = "mm (translation)"
        elif t.atom.place == "plate":
            v = np.full(len(t.F), float(np.linalg.norm(phi)) / _MM)
        elif t.atom.place == "joints":
            v = np.linalg.norm(np.einsum("nik,k->ni", t.F.reshape(len(t.F), 6, -1), phi), axis=1) / _DEG
            unit = "deg"
        else:
            v = (t.F @ phi) * fac
        terms[t.atom.label] = {"value": v, "unit": unit, "channel": t.atom.channel}
    out["terms"] = terms
    ctx = prob.ctx
    out["q_deg"] = ctx.q[rows_val] / _DEG
    out["approach_sign"] = _signs(ctx)[rows_val]
    if ctx.temp_c is not None:
        out["temp_c"] = ctx.temp_c[rows_val]
    if ctx.t_s is not None:
        out["t_s"] = ctx.t_s[rows_val]
    return out


# ------------------------------------------------------------------------------------------------
# A given extended model, without selection
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class EffectFit:
    """A given extended model fitted without selection: validation errors of the geometric-only and of the
    extended model (``{n_rows, position_mm: {...}, orientation_deg: {...}}``), the structure test of each,
    and the atom parameters."""

    before: dict[str, Any]
    after: dict[str, Any]
    test_before: StructureTest
    test_after: StructureTest
    effect_parameters: dict[str, Any]
    noise: NoiseFloor


def fit_with_effects(dataset: Dataset, atoms: list, *, holdout: float | None = None, seed: int = 0,
                     q_start: np.ndarray | None = None) -> EffectFit:
    """Fit the geometric model extended by exactly ``atoms`` (no selection; every direction the data separate
    from the geometry kept) on the calibration rows, and report on the validation rows. An entry may also be
    a catalogue family's name (or a legacy ``Candidate``): every atom of that family (per joint, per link)."""
    if not isinstance(dataset, Dataset):
        raise ValueError(f"dataset must be a twin.dataset.Dataset, got {type(dataset).__name__}")
    if dataset.set is None and holdout is None:
        raise DiagnosisError("fit_with_effects needs held-out rows: a 'set' column or holdout=FRACTION")
    floor = noise_floor(dataset)
    prep = prepare(dataset, noise_position=floor.sigma, validation_fraction=holdout or 0.0, seed=seed)
    ident = identify_best(prep, alpha=1e-6)
    ctx = row_context(dataset, q_start)
    # a legacy Candidate with its own regressor: one term of its full regressor
    legacy = []
    for c in atoms:
        if not isinstance(c, (Atom, str)) and getattr(c, "name", None) not in EFFECT_VOCABULARY and getattr(c, "kind", None) in ("joint", "length"):
            ref = c.reference(ctx)
            K = len(c.param_names(ref))
            place, target = ("joints", "all") if c.kind == "joint" else ("length", "all_lengths")
            legacy.append(Atom(c.name, place, target, (), c.name, c.description, "given", (),
                               {"K": K, "regressor": (lambda cx, c=c, ref=ref: c.regressor(cx, ref))}))
    atoms = [a for a in atoms if not any(a is getattr(l, "_src", None) for l in legacy)]
    names_legacy = {l.family for l in legacy}
    atoms = [a for a in atoms if getattr(a, "name", None) not in names_legacy] + legacy
    # a catalogue family given by name (or as a legacy Candidate) stands for all its atoms
    fams = {getattr(a, "name", a) for a in atoms if not isinstance(a, Atom)}
    if fams:
        unknown = fams - set(EFFECT_VOCABULARY)
        if unknown:
            raise ValueError(f"atoms: unknown effect families {sorted(unknown)}; known: {list(EFFECT_VOCABULARY)}")
        lengths = [n for n in prep.space.names[: prep.space.n_robot] if n.rstrip("0123456789") in ("d", "a")]
        cat = [a for a in catalogue_atoms(prep.nominal, ctx, lengths) if a.family in fams and a.target != "all_lengths"]
        atoms = [a for a in atoms if isinstance(a, Atom)] + cat
    prob = _Problem(prep, floor, ctx, np.flatnonzero(np.array(ident.status) == "identified"))
    base = prob.fit(ident.x, [])
    rc = base.model_cal.residuals(base.z)
    Q, _ = np.linalg.qr(rc.J[:, base.free])
    chosen = []
    for a in atoms:
        E = _raw_columns(base.model_cal, a, prob.features(a)[prob.rows_cal], base.z, rc)
        chosen.append((a, reduced_basis(E, Q=Q, rel_tol=1e-6, max_rank=40)))
    fit = prob.fit(ident.x, chosen)
    _, params = _atom_report(prob, fit)
    return EffectFit(
        before=_error_stats(base.model_val, base.z),
        after=_error_stats(fit.model_val, fit.z),
        test_before=prob.test(base),
        test_after=prob.test(fit),
        effect_parameters=params,
        noise=floor,
    )


# Vocabulary check at import: every catalogue name is documented.
assert set(EFFECT_VOCABULARY) == {"compliance", "backlash", "cyclic", "gear_ratio", "coupling", "thermal", "plate_geometry"}
