"""Diagnosis: is there structure beyond the noise floor, which effect explains it, how much does adding it help.

Reads only a dataset (and optionally an existing geometric calibration). The procedure:

1. **Noise floor.** From repeated measurements of the same configuration taken one after the other (rows
   with identical commanded joints and station, consecutive in measurement order): the pooled variance of
   the sphere coordinates about their group means, with ``nu = sum (n_g - 1) * coordinates`` degrees of
   freedom. Without repeats, the instrument's stated noise (``dataset.toml [noise] position_mm``), taken as
   exact. Without either, diagnosis refuses (it cannot tell structure from noise).
2. **Geometric fit** on the calibration rows (the estimator's default, with the noise fixed to the floor so
   that the effect cannot hide in an inflated noise estimate; gross outliers still rejected).
3. **Test** on the validation rows: ``T = r^T (I + J C J^T)^-1 r`` with ``r`` the whitened validation residuals
   and ``C`` the (whitened) parameter covariance, i.e. the residuals' own covariance under a correct model.
   With the floor known ``T ~ chi2(m)``; with the floor estimated from ``nu`` repeat degrees of freedom
   ``(T/m) ~ F(m, nu)``. ``structured`` when ``p < alpha`` (default 0.01: a 1 % false-alarm rate).
4. **Trace** (only when structured): greedy forward selection over the candidates
   (:mod:`twin.diagnosis.candidates`) on the calibration rows by the Bayesian information criterion with
   known noise, ``BIC = chi2 + k ln m`` (``k`` the candidate's reduced dimension), requiring
   ``Delta BIC < -bic_margin``; after each addition the validation test is repeated with the extended model.
   The effects *explain* the residual when the extended model passes the test; when no combination of up to
   ``max_effects`` candidates does, ``effects`` is empty (the residual is structured by something outside the
   catalogue) and the best attempt is still reported.
5. **Before/after**: validation error statistics of the geometric and of the extended model.
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
from ..estimator.problem import Observations, absolute_residuals, kabsch, predict_points
from ..estimator.solvers import gauss_newton
from ..transforms import matrix_to_rotvec
from .candidates import EFFECT_VOCABULARY, Candidate, RowContext, candidate_catalogue
from .extend import EffectTerm, ExtendedModel, reduced_basis, term_regressor

__all__ = [
    "NoiseFloor",
    "StructureTest",
    "CandidateScore",
    "DiagnosisResult",
    "DiagnosisError",
    "noise_floor",
    "row_context",
    "diagnose",
]

_MM = 1e-3
_DEG = np.pi / 180.0


class DiagnosisError(ValueError):
    """The dataset lacks what diagnosis needs; the message says what to add."""


@dataclass(frozen=True)
class NoiseFloor:
    """Measurement noise per sphere coordinate ``sigma`` [m], its degrees of freedom (``inf`` when stated by
    the instrument), where it came from, and how many repeat groups gave it."""

    sigma: float
    dof: float
    source: str
    groups: int


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
    """One candidate tried in a selection round: reduced dimension, calibration chi2 and Delta BIC against
    the current model, validation test with it added."""

    round: int
    name: str
    dim: int
    chi2_cal: float
    delta_bic: float
    validation: StructureTest | None
    note: str = ""


@dataclass(frozen=True, eq=False)
class DiagnosisResult:
    """What diagnosis found. ``before``/``after``: validation error statistics
    ``{position_mm: {mean, rms, max}, orientation_deg: {mean, rms, max}}``; ``effect_parameters``: per
    chosen effect, names, values (SI) and standard deviations; ``series``: per validation row the variables
    most telling for each candidate and the residual norms before/after (for plots and the recording)."""

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


# ------------------------------------------------------------------------------------------------
# Noise floor
# ------------------------------------------------------------------------------------------------

def noise_floor(ds: Dataset, *, stated_ok: bool = True) -> NoiseFloor:
    """The sphere-coordinate noise from consecutive repeats (see the module docstring)."""
    if not ds.has_spheres:
        if ds.noise_position is not None and stated_ok:
            return NoiseFloor(ds.noise_position, float("inf"), "dataset.toml [noise] position_mm (stated)", 0)
        raise DiagnosisError("diagnosis of pose data needs [noise] position_mm/orientation_rad in dataset.toml")
    st = ds.station_ids
    qr = np.round(ds.q, 9)
    ss = 0.0
    dof = 0
    groups = 0
    k = 0
    n = ds.n
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
    if dof >= 30:
        return NoiseFloor(float(np.sqrt(ss / dof)), float(dof), f"{groups} groups of consecutive repeats", groups)
    if ds.noise_position is not None and stated_ok:
        note = f" ({groups} repeat groups were too few)" if groups else ""
        return NoiseFloor(ds.noise_position, float("inf"), "dataset.toml [noise] position_mm (stated)" + note, groups)
    raise DiagnosisError(
        "diagnosis needs the measurement noise floor: repeat some configurations (measure the same commanded "
        "joints twice in a row, at least ~10 repeats) or state the instrument's noise in dataset.toml "
        "([noise] position_mm)"
        + (f"; found only {groups} repeat groups ({dof} degrees of freedom)" if groups else "")
    )


def row_context(ds: Dataset, q_start: np.ndarray | None = None) -> RowContext:
    """Every row of the dataset in measurement order, with its auxiliary channels."""
    return RowContext(
        q=ds.q.copy(),
        q_start=np.zeros(6) if q_start is None else np.asarray(q_start, dtype=float),
        temp_c=None if ds.temp_c is None else ds.temp_c.copy(),
        t_s=None if ds.t_s is None else ds.t_s.copy(),
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
    T = float(r @ r - y @ np.linalg.solve(M, y)) if M.size else float(r @ r)
    if np.isinf(floor.dof):
        p = float(stats.chi2.sf(T, m))
        dist = f"chi2({m})"
    else:
        p = float(stats.f.sf(T / m, m, floor.dof))
        dist = f"F({m}, {int(floor.dof)})"
    return StructureTest(T, m, p, float(np.sqrt(np.mean(r**2))), dist)


def _error_stats(model: ExtendedModel, z: np.ndarray) -> dict[str, Any]:
    """Validation error statistics: 3-D sphere-centre error [mm], and the plate orientation error [deg]
    between rigid fits of the plate to the measured and to the predicted spheres (rows with all three)."""
    _, phis = model.split(z)
    obs = model.effective_obs(phis)
    res = model.residuals(z, jacobian=False)
    diff = _unmask(res, obs)  # measured - predicted (n, 3, 3) [m], zero where not seen
    e3 = np.linalg.norm(diff, axis=-1)[obs.seen]
    out: dict[str, Any] = {"n_rows": int(obs.n), "position_mm": _stats(e3 / _MM)}
    full = obs.seen.all(axis=1)
    if full.any():
        meas = obs.spheres[full]
        pred = meas - diff[full]
        A = np.broadcast_to(model.obs.spheres_tool, meas.shape)
        Rm, _ = kabsch(A, meas)
        Rp, _ = kabsch(A, pred)
        ang = np.linalg.norm(matrix_to_rotvec(Rm @ np.swapaxes(Rp, 1, 2)), axis=-1)
        out["orientation_deg"] = _stats(ang / _DEG)
    return out


def _unmask(res, obs: Observations) -> np.ndarray:
    """Whitened sphere residuals back to ``(n, 3, 3)`` [m] (order of ``absolute_residuals``)."""
    shape = (3, 3, obs.n)
    mask = np.broadcast_to(obs.seen.T[:, None, :], shape)
    tmp = np.zeros(shape)
    tmp[mask] = res.r * obs.sigma_position
    return np.transpose(tmp, (2, 0, 1))


def _stats(e: np.ndarray) -> dict[str, float]:
    return {"mean": float(np.mean(e)), "rms": float(np.sqrt(np.mean(e**2))), "max": float(np.max(e))}


# ------------------------------------------------------------------------------------------------
# The procedure
# ------------------------------------------------------------------------------------------------

@dataclass
class _Fit:
    terms: list[EffectTerm]
    z: np.ndarray
    free: np.ndarray
    chi2: float
    model_cal: ExtendedModel
    model_val: ExtendedModel


def _build_terms(chosen, prep: Prepared, ctx: RowContext, x: np.ndarray, free_geo: np.ndarray) -> tuple[list, list]:
    """Effect terms (calibration rows, validation rows) for the chosen candidates with their references."""
    rows_cal = prep.rows[prep.cal]
    rows_val = prep.rows[prep.val]
    terms_cal, terms_val = [], []
    for cand, ref, basis in chosen:
        Gc = term_regressor(cand, ref, ctx, rows_cal)
        Gv = term_regressor(cand, ref, ctx, rows_val)
        terms_cal.append(EffectTerm(cand, ref, Gc, basis))
        terms_val.append(EffectTerm(cand, ref, Gv, basis))
    return terms_cal, terms_val


def _fit(prep: Prepared, obs_cal: Observations, obs_val: Observations, x0: np.ndarray, free_geo: np.ndarray,
         chosen: list, ctx: RowContext, z0_effects: list[np.ndarray] | None = None, inlier=None) -> _Fit:
    terms_cal, terms_val = _build_terms(chosen, prep, ctx, x0, free_geo)
    mc = ExtendedModel(prep.space, obs_cal, terms_cal)
    mv = ExtendedModel(prep.space, obs_val, terms_val)
    z0 = np.concatenate([x0] + [np.zeros(t.r) for t in terms_cal])
    free = np.concatenate([free_geo, np.arange(prep.space.size, mc.size)]).astype(int)
    w = None if inlier is None else inlier.astype(float)
    # 1e-11 (SI) per step is far below any effect or geometric parameter that matters here
    gn = gauss_newton(lambda z: mc.residuals(z), z0, free, row_weights=w, max_iter=30, xtol=1e-11, stage="extended")
    res = mc.residuals(gn.x, jacobian=False)
    rr = res.r if inlier is None else res.r[inlier[res.row]]
    return _Fit(terms_cal, gn.x, free, float(rr @ rr), mc, mv)


def _validation_test(fit: _Fit, floor: NoiseFloor, inlier: np.ndarray | None) -> StructureTest:
    rv = fit.model_val.residuals(fit.z)
    rc = fit.model_cal.residuals(fit.z)
    Jc = rc.J[:, fit.free]
    if inlier is not None:
        Jc = Jc[inlier[rc.row]]
    return _structure_test(rv.r, rv.J[:, fit.free], Jc, floor)


def diagnose(
    dataset: Dataset,
    *,
    calibration: Calibration | None = None,
    alpha: float = 0.01,
    holdout: float | None = None,
    seed: int = 0,
    max_effects: int = 3,
    bic_margin: float = 10.0,
    candidates: list[Candidate] | None = None,
    q_start: np.ndarray | None = None,
    callback: Callable[[CandidateScore], None] | None = None,
) -> DiagnosisResult:
    """Diagnose ``dataset`` (see the module docstring for the procedure and the test).

    ``holdout``: without a ``set`` column, hold out this seeded random fraction for validation (without
    either, diagnosis refuses: it needs held-out rows). ``calibration``: a geometric calibration to start
    from (its parameters are the start of the fit; the fit is redone on this dataset's calibration rows).
    ``candidates``: the catalogue to try (default :func:`candidate_catalogue` of the dataset's robot).
    ``q_start``: where the robot stood before the first row (for approach directions), default home (0).
    """
    if not isinstance(dataset, Dataset):
        raise ValueError(f"dataset must be a twin.dataset.Dataset, got {type(dataset).__name__}")
    if not (0 < alpha < 0.5):
        raise ValueError(f"alpha must be in (0, 0.5), got {alpha!r}")
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
    sig = floor.sigma
    obs_cal = prep.obs_cal.with_sigma(sig)
    obs_val = prep.obs_val.with_sigma(sig)
    inlier = ident.inlier
    free_geo = np.flatnonzero(np.array(ident.status) == "identified")
    ctx = row_context(dataset, q_start)

    base_fit = _fit(prep, obs_cal, obs_val, ident.x, free_geo, [], ctx, inlier=inlier)
    test0 = _validation_test(base_fit, floor, inlier)
    before = _error_stats(base_fit.model_val, base_fit.z)
    structured = test0.p_value < alpha
    scores: list[CandidateScore] = []
    chosen: list = []
    fit = base_fit
    test = test0
    explained = not structured
    catalogue = candidates if candidates is not None else candidate_catalogue(prep.nominal)
    m_cal = int(base_fit.model_cal.residuals(base_fit.z, jacobian=False).r.size)
    if structured:
        remaining = [c for c in catalogue if _applicable(c, dataset)]
        for rnd in range(1, max_effects + 1):
            best = None
            rc = fit.model_cal.residuals(fit.z)
            A = rc.J[:, fit.free]
            for cand in remaining:
                try:
                    ref = cand.reference(ctx)
                    basis = _candidate_basis(cand, ref, prep, obs_cal, ctx, fit, A)
                except ValueError as exc:
                    scores.append(CandidateScore(rnd, cand.name, 0, float("nan"), float("nan"), None, str(exc)))
                    continue
                if basis.shape[1] == 0:
                    scores.append(CandidateScore(rnd, cand.name, 0, fit.chi2, 0.0, None,
                                                 "no direction beyond what the geometry absorbs"))
                    continue
                trial = _fit(prep, obs_cal, obs_val, fit.z[: prep.space.size], free_geo,
                             chosen + [(cand, ref, basis)], ctx, inlier=inlier)
                dbic = (trial.chi2 - fit.chi2) + basis.shape[1] * np.log(m_cal)
                vt = _validation_test(trial, floor, inlier)
                sc = CandidateScore(rnd, cand.name, int(basis.shape[1]), trial.chi2, float(dbic), vt)
                scores.append(sc)
                if callback:
                    callback(sc)
                if dbic < -bic_margin and (best is None or dbic < best[0]):
                    best = (dbic, cand, ref, basis, trial, vt)
            if best is None:
                break
            _, cand, ref, basis, fit, test = best
            chosen.append((cand, ref, basis))
            remaining = [c for c in remaining if c.name != cand.name]
            if test.p_value >= alpha:
                explained = True
                break
    effects = tuple(c.name for c, _, _ in chosen) if explained else ()
    if structured and not explained:
        notes.append(
            "the residual is structured and no combination of the catalogue's effects explains it"
            + (f" (best attempt: {', '.join(c.name for c, _, _ in chosen)})" if chosen else "")
        )
    use_fit = fit if explained else base_fit
    after = _error_stats(use_fit.model_val, use_fit.z) if effects else before
    effect_params, effects_json = _effect_parameters(use_fit if effects else base_fit, inlier) if effects else ({}, [])
    extended = replace(
        geo,
        method="best+effects" if effects else geo.method,
        x=use_fit.z[: prep.space.size] if effects else geo.x,
        effects=tuple(effects_json),
    )
    series = _series(base_fit, use_fit, prep, ctx)
    return DiagnosisResult(
        structured=bool(structured),
        p_value=float(test0.p_value),
        alpha=alpha,
        test_before=test0,
        test_after=test if chosen else None,
        effects=effects,
        effect_parameters=effect_params,
        explained=bool(explained),
        before=before,
        after=after,
        noise=floor,
        scores=tuple(scores),
        calibration_geometric=geo,
        calibration=extended,
        series=series,
        notes=tuple(notes),
    )


def _applicable(c: Candidate, ds: Dataset) -> bool:
    if c.name == "thermal":
        return ds.temp_c is not None or ds.t_s is not None
    return True


def _candidate_basis(cand, ref, prep, obs_cal, ctx, fit: _Fit, A: np.ndarray) -> np.ndarray:
    """Whitened columns of the full candidate at the current fit, reduced against the current columns."""
    rows_cal = prep.rows[prep.cal]
    G = term_regressor(cand, ref, ctx, rows_cal)
    K = len(cand.param_names(ref)) if cand.kind != "plate" else 9
    probe = EffectTerm(cand, ref, G, np.eye(K))
    mc = ExtendedModel(prep.space, obs_cal, fit.model_cal.terms + [probe])
    z = np.concatenate([fit.z, np.zeros(K)])
    J = mc.residuals(z).J
    E = J[:, fit.model_cal.size:]
    return reduced_basis(E, A)


def _effect_parameters(fit: _Fit, inlier) -> tuple[dict[str, Any], list[dict]]:
    """Full parameters ``phi = B psi`` of each chosen effect with standard deviations from the covariance."""
    rc = fit.model_cal.residuals(fit.z)
    J = rc.J[:, fit.free]
    if inlier is not None:
        J = J[inlier[rc.row]]
    C = np.linalg.pinv(J.T @ J, rcond=1e-12)
    pos = {int(f): k for k, f in enumerate(fit.free)}
    _, phis = fit.model_cal.split(fit.z)
    out: dict[str, Any] = {}
    js: list[dict] = []
    for k, (t, phi) in enumerate(zip(fit.terms, phis)):
        idx = [pos[i] for i in range(fit.model_cal.offsets[k], fit.model_cal.offsets[k + 1])]
        Cpsi = C[np.ix_(idx, idx)]
        Cphi = t.basis @ Cpsi @ t.basis.T
        sd = np.sqrt(np.clip(np.diag(Cphi), 0, None))
        names = list(t.candidate.param_names(t.reference)) if t.kind != "plate" else [
            f"dp{s}_{c}" for s in range(3) for c in "xyz"]
        entry = {
            "name": t.name,
            "kind": t.kind,
            "description": t.candidate.description,
            "param_names": names,
            "values": phi.tolist(),
            "sd": sd.tolist(),
            "reference": t.reference,
            "reduced_dimension": int(t.r),
            "units": _units(t),
        }
        if t.kind == "joint":
            # what the effect does, in words a user reads: the RMS joint deflection it implies on these rows
            d = np.einsum("nik,k->ni", t.G, phi)
            entry["joint_rms_deg"] = (np.sqrt(np.mean(d**2, axis=0)) / _DEG).tolist()
        out[t.name] = {"param_names": names, "values": phi.tolist(), "sd": sd.tolist(),
                       "reduced_dimension": int(t.r), **({"joint_rms_deg": entry["joint_rms_deg"]} if "joint_rms_deg" in entry else {})}
        js.append(entry)
    return out, js


def _units(t: EffectTerm) -> str:
    if t.kind == "joint":
        return "rad per unit of the regressor (compliance: rad per N m per kg or kg m; backlash, cyclic: rad; gear_ratio, coupling: rad/rad)"
    if t.kind == "length":
        return "relative growth per K (temp_c) or per normalised time (t_s)"
    return "m (sphere offsets in the plate frame)"


def _series(base: _Fit, ext: _Fit, prep: Prepared, ctx: RowContext) -> dict[str, np.ndarray]:
    """Per validation row: residual norms before/after [mm] and the most telling variables."""
    from .candidates import approach_signs

    rows_val = prep.rows[prep.val]
    out: dict[str, np.ndarray] = {"dataset_row": rows_val, "pose_id": prep.dataset.pose_id[rows_val]}
    for tag, f in (("before", base), ("after", ext)):
        r = f.model_val.residuals(f.z, jacobian=False)
        e = np.sqrt(np.bincount(r.row, weights=r.r**2, minlength=f.model_val.obs.n))
        cnt = np.maximum(np.bincount(r.row, minlength=f.model_val.obs.n), 1)
        out[f"residual_rms_mm_{tag}"] = e / np.sqrt(cnt) * f.model_val.obs.sigma_position / _MM
    out["q_deg"] = ctx.q[rows_val] / _DEG
    out["approach_sign"] = approach_signs(ctx.q, ctx.q_start)[rows_val]
    if ctx.temp_c is not None:
        out["temp_c"] = ctx.temp_c[rows_val]
    if ctx.t_s is not None:
        out["t_s"] = ctx.t_s[rows_val]
    return out


# Vocabulary check at import: every catalogue name is documented.
assert set(EFFECT_VOCABULARY) == {"compliance", "backlash", "cyclic", "gear_ratio", "coupling", "thermal", "plate_geometry"}
