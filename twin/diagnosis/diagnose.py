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
7. ``structured``: the test fires and something in the residual is predictable on held-out rows: an atom is
   confirmed, or (no atom) the mean residual of the nearest calibration rows in joint space or in time predicts
   the held-out residual (``_smooth_confirm``). An excess that nothing predicts is scatter that changes from
   visit to visit (the robot's repeatability, a per-pose instrument error): reported in a note, not structure.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np

from ..dataset import Dataset
from ..estimator.calibration import Calibration
from ..estimator.core import Prepared, prepare
from ..estimator.methods import build_calibration, identify_best
from ..estimator.problem import kabsch
from ..transforms import matrix_to_rotvec
from .atoms import Atom, approach_unknown, catalogue_atoms, generic_atoms
from .candidates import EFFECT_VOCABULARY
from .extend import ExtendedModel, reduced_basis
from .floor import DiagnosisError, NoiseFloor, history_resets, noise_floor, row_context
from .select import (StructureTest, _alternatives, _refine, _widen, _backward, _confirm, _smooth_confirm, _covariance, _Fit, _order, _Problem,
                     _psi_init, _raw_columns, _row_rms, _score_atoms, _update_gross)

__all__ = [
    "virtual_spheres",
    "CandidateScore",
    "DiagnosisResult",
    "EffectFit",
    "diagnose",
    "fit_with_effects",
    # re-exported: the floor and the test are part of what diagnose returns
    "NoiseFloor",
    "StructureTest",
    "DiagnosisError",
    "noise_floor",
    "history_resets",
    "row_context",
]

_MM = 1e-3
_DEG = np.pi / 180.0
DEFAULT_HOLDOUT = 0.3  # held-out fraction without a 'set' column (and no holdout given)
THERMAL_MAX = 1e-3  # [relative] largest thermal growth over a campaign: 43 K of aluminium (23 ppm/K)
JOINT_MAX = 0.5 * np.pi / 180  # [rad] largest joint error a named mechanism (backlash, cyclic, compliance, ...) makes
MINOR_RMS = 0.3  # an atom whose unique effect is below this RMS (in units of the floor) is reported as minor


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
    data cannot tell apart from a chosen one; ``rows``: rows flagged (gross, unknown history); ``unexplained``:
    when the test fired and no term was confirmed, the excess (whitened RMS, extra sigma per coordinate [mm]),
    the neighbour smoothers' held-out ``z`` and whether they predict it (else None)."""

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
    unexplained: dict[str, Any] | None = None


def _unmask(r: np.ndarray, model: ExtendedModel) -> np.ndarray:
    """Whitened sphere residuals back to ``(n, 3, 3)`` [m] (order of ``absolute_residuals``)."""
    obs = model.obs
    shape = (3, 3, obs.n)
    mask = np.broadcast_to(obs.seen.T[:, None, :], shape)
    tmp = np.zeros(shape)
    tmp[mask] = model.unwhiten(r)
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
    diff = _unmask(res.r, model)  # measured - predicted (n, 3, 3) [m], zero where not seen
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
    generic: bool = True,
    q_start: np.ndarray | None = None,
    callback: Callable[[CandidateScore], None] | None = None,
) -> DiagnosisResult:
    """Diagnose ``dataset`` (see the module docstring for the procedure and its statistics).

    ``holdout``: without a ``set`` column, hold out this seeded random fraction for validation (default
    ``DEFAULT_HOLDOUT``, 30 %, said so in the notes).
    ``calibration``: a geometric calibration to start from (refitted on this dataset's calibration rows).
    ``max_effects``: most atoms kept. ``alpha_select``: family-wise false-selection rate per round (each pool
    Bonferroni-adjusted). ``z_min``: held-out confirmation threshold (terms and the neighbour smoothers).
    ``generic``: also search the unnamed dictionary. ``q_start``: where the robot stood before the first row,
    when known (otherwise the first row's approach is unknown).
    """
    if not isinstance(dataset, Dataset):
        raise ValueError(f"dataset must be a twin.dataset.Dataset, got {type(dataset).__name__}")
    if not (0 < alpha < 0.5):
        raise ValueError(f"alpha must be in (0, 0.5), got {alpha!r}")
    if not (0 < alpha_select < 0.5):
        raise ValueError(f"alpha_select must be in (0, 0.5), got {alpha_select!r}")
    if not (isinstance(max_effects, (int, np.integer)) and max_effects >= 0):
        raise ValueError(f"max_effects must be a non-negative integer, got {max_effects!r}")
    virtual = not dataset.has_spheres
    if virtual:
        # a 6-DOF instrument (a tracker's probe): its poses read as three points of the tool frame
        dataset, note_virtual = virtual_spheres(dataset)
    default_holdout = dataset.set is None and holdout is None
    if dataset.set is None:
        if holdout is None:
            # as the estimator does without a 'set' column (docs/formats.md): a seeded random fraction, said so
            holdout = DEFAULT_HOLDOUT
        if not (0.05 <= holdout <= 0.8):
            raise ValueError(f"holdout must be in [0.05, 0.8], got {holdout!r}")
    elif not np.any(dataset.set == "validation"):
        raise DiagnosisError("diagnosis needs held-out rows: the 'set' column has no 'validation' rows")
    floor = noise_floor(dataset, plate=not virtual)
    notes: list[str] = [f"noise floor {floor.sigma / _MM:.5f} mm per coordinate from {floor.source}"]
    if virtual:
        notes.append(note_virtual)
    if default_holdout:
        notes.append(f"no 'set' column: held out a seeded random {100 * holdout:.0f} % of the rows for validation "
                     f"(seed {seed}; --holdout and --seed choose another split)")
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
            pool += generic_atoms(prep.nominal, ctx, pnames, length_names, cat, points=None if virtual else dataset.spheres,
                                  plate_spheres=dataset.plate.spheres_flange)
        if virtual:
            pool = [a for a in pool if a.place != "plate"]  # the points are the tool frame's: no sphere to move
        sizes = {k: max(1, sum(a.pool == k for a in pool)) for k in ("catalogue", "scan", "generic")}
        rejected: set[str] = set()
        entry_chi2: dict[str, float] = {}
        rnd, kept = 0, 0
        while kept < max_effects and rnd < 4 * max_effects:
            rnd += 1
            remaining = [a for a in pool if a.key not in rejected and a.key not in {c.key for c, _ in chosen}]
            scored = _score_atoms(prob, fit, remaining, sizes)
            if not scored:
                break
            order = _order(scored)
            accepted = None
            unphysical = False
            for s in order[:3]:
                logp_adj = s.logp_adj
                if logp_adj >= np.log(alpha_select):
                    scores.append(CandidateScore(rnd, s.atom.label, s.basis.shape[1], s.dchi2, float(np.exp(logp_adj)), float("nan"),
                                                 "not significant on the calibration rows"))
                    break
                z, zm, better = _confirm(prob, fit, s, z_min)
                implausible = _implausible(prob, s)
                ok = z > z_min and zm > z_min and better and implausible is None
                sc = CandidateScore(rnd, s.atom.label, s.basis.shape[1], s.dchi2, float(np.exp(logp_adj)), z,
                                    "kept" if ok else ("not confirmed on held-out rows" if not (z > z_min) else
                                                       "held-out gain rests on one row" if not (zm > z_min) else
                                                       "held-out error not reduced" if not better else implausible))
                scores.append(sc)
                if callback:
                    callback(sc)
                if ok:
                    accepted = s
                    break
                rejected.add(s.atom.key)
                unphysical |= implausible is not None
            if accepted is None:
                if unphysical:
                    continue  # named atoms of an unphysical size are out: the next round scores the rest
                break
            refined = _refine(prob, fit, accepted, sizes)
            accepted = _widen(prob, fit, refined if _implausible(prob, refined) is None else accepted, alpha_select)
            kept += 1
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
            fit, swapped, alts = _named_shapes(prob, fit, pool, sizes, alpha_select)
            notes += swapped
            alternatives = [d for d in alternatives if d["of"] in {a.label for a, _ in fit.chosen}] + alts
            _update_gross(prob, fit)
            fit = prob.fit(fit.z[: prep.space.size], fit.chosen, _psi_init(fit, fit.chosen))
            test = prob.test(fit)
        chosen = fit.chosen
        base_fit = prob.fit(base_fit.z[: prep.space.size], [])
        test0 = prob.test(base_fit)
        before = _error_stats(base_fit.model_val, base_fit.z, prob.keep_val)

    confirmed = bool(chosen)
    # without a confirmed term, structure must still be predictable: from the nearest calibration rows in joint
    # space or in time. An excess that nothing predicts is scatter that changes from visit to visit (the robot's
    # repeatability, a per-pose instrument error), however large: reported, not called structure.
    unexplained = None
    if excess and not confirmed:
        smooth = _smooth_confirm(prob, base_fit, z_min)
        w = test0.whitened_rms
        unexplained = {"whitened_rms": w, "excess_sigma_mm": floor.sigma * np.sqrt(max(w * w - 1.0, 0.0)) / _MM,
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
    # a named shape of one joint variable (a harmonic, a ratio, a coupling) kept beside a non-minor unnamed
    # function of the same variable at the same joint is part of one shape the catalogue does not name (a
    # one-sided pull of a cable past some angle took a quadratic and a 1st harmonic of q5 on a blind campaign)
    merged = _merged_into_unnamed(atoms_json)
    for a, u in merged:
        notes.append(f"'{a['label']}' is reported with '{u['label']}' as one function of "
                     f"{', '.join(sorted(_joint_channels(a)))} on joint {a['target'][5:]} that the catalogue does not "
                     f"name (not as {a['family']})")
    unnamed_shape = {id(a) for a, _ in merged}
    effects = tuple(dict.fromkeys(a["family"] for a in atoms_json
                                  if a["family"] != "unnamed" and not a["minor"] and id(a) not in unnamed_shape))
    minor = [a["label"] for a in atoms_json if a["minor"]]
    if minor:
        notes.append(f"minor terms kept in the model but not named as effects (each explained less than {MINOR_RMS} "
                     f"of the floor, RMS per residual, when it entered): {'; '.join(minor)}")
    unnamed = tuple(a for a in atoms_json if a["family"] == "unnamed" and not a["minor"])
    instrument = [a["label"] for a in atoms_json if a["place"] in ("scale", "field") or a["target"] == "base"]
    if instrument:
        notes.append("terms on the measurement side (scale, field or frame of the measurements) describe the instrument or "
                     f"the cell, not the robot: {'; '.join(instrument)}")
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
        unexplained=unexplained,
    )


# ------------------------------------------------------------------------------------------------
# Reports
# ------------------------------------------------------------------------------------------------

VIRTUAL_ARM = 0.1  # [m] distance of the virtual points from the tool origin when poses are read as points


def virtual_spheres(ds: Dataset) -> tuple[Dataset, str]:
    """A pose dataset (``x y z rx ry rz``) as three points of the tool frame ``VIRTUAL_ARM`` along its x, y
    and z axes, measured where the pose puts them: every sphere-centre atom then applies (the plate's own atoms
    do not: the points are the tool frame's). The noise per point coordinate is ``sqrt(sigma_p^2 + (2/3)
    (L sigma_r)^2)`` from ``[noise]`` (a point inherits the rotation noise across its arm). Returns the dataset and
    a note."""
    from ..dataset import Plate

    if not ds.has_poses:
        raise DiagnosisError("diagnosis needs sphere centres (p0_x..p2_z) or poses (x y z rx ry rz); this dataset has "
                             "neither")
    L = VIRTUAL_ARM
    pts = np.eye(3) * L  # (3 points, xyz) in the tool frame
    R, t = ds.pose[:, :3, :3], ds.pose[:, :3, 3]
    spheres = np.einsum("nij,sj->nsi", R, pts) + t[:, None, :]
    seen = np.repeat(ds.pose_seen[:, None], 3, axis=1)
    spheres[~seen] = np.nan
    noise = None
    if ds.noise_position is not None:
        sr = ds.noise_orientation or 0.0
        noise = float(np.sqrt(ds.noise_position**2 + (2.0 / 3.0) * (L * sr) ** 2))
    out = replace(ds, spheres=spheres, sphere_seen=seen, pose_seen=np.zeros(ds.n, bool),
                  plate=Plate(ds.plate.sphere_diameter, pts), noise_position=noise)
    return out, (f"poses read as three points of the tool frame {L / _MM:.0f} mm along its axes (virtual spheres); "
                 "the plate's own terms and the plate-distance floor do not apply")


def _implausible(prob: _Problem, s) -> str | None:
    """Why a named (catalogue) atom's fitted size is not physical for its family, or None: thermal growth of more
    than ``THERMAL_MAX`` over the rows (a short link's huge growth stands for something else: on a blind
    campaign 3,500 ppm of a4 took the place of a joint offset jumping at restarts), a joint error beyond
    ``JOINT_MAX``. Unnamed atoms make no physical claim and are not checked."""
    a = s.atom
    if a.pool == "generic":
        return None
    eff = prob.features(a)[prob.rows_cal] @ (s.basis @ s.psi) if a.place in ("length", "joint") else None
    if eff is None or eff.size == 0:
        return None
    if a.place == "length" and float(np.ptp(eff)) > THERMAL_MAX:
        return (f"implausible for thermal growth: {np.ptp(eff) * 1e6:.0f} ppm over the rows (more than "
                f"{THERMAL_MAX * 1e6:.0f} ppm, 43 K of aluminium)")
    if a.place == "joint" and float(np.max(np.abs(eff))) > JOINT_MAX:
        return f"implausible for {a.family}: {np.max(np.abs(eff)) / _DEG:.3f} deg (more than {JOINT_MAX / _DEG:.1f} deg)"
    return None


def _single_joint_variable(a: Atom) -> str | None:
    """The one joint variable (``"q4"``) a joint atom's features are functions of (pow/sin/cos), else None."""
    if a.place != "joint" or not {f.get("kind") for f in a.features} <= {"pow", "sin", "cos"}:
        return None
    chans = {f["ch"] for f in a.features}  # pow/sin/cos features name one channel each
    ch = chans.pop() if len(chans) == 1 else ""
    return ch if ch.startswith("q") else None


def _named_shapes(prob: _Problem, fit: _Fit, pool: list[Atom], sizes: dict,
                  alpha_select: float) -> tuple[_Fit, list[str], list[dict]]:
    """Where the greedy forward pass built a function of one joint variable at a joint from an unnamed term and
    named ones (a quadratic before the harmonics it stands for), try the catalogue's shapes of that variable
    alone (harmonics 1-3, the gear ratio, the scanned orders already kept) in place of the unnamed term: when
    they predict the held-out rows as well (within 2 %), the named explanation is kept, and the unnamed shape it
    replaced is reported as the alternative the data cannot tell from it (over a joint's range a few harmonics
    follow any smooth shape: the name is the simpler reading, not a proof). Returns the fit, notes and those
    alternatives."""
    notes: list[str] = []
    alts: list[dict] = []
    for a, _ in list(fit.chosen):
        var = _single_joint_variable(a)
        if a.pool != "generic" or var is None or a not in [c for c, _ in fit.chosen]:
            continue
        target = a.target
        named_here = [c for c, _ in fit.chosen if c.pool != "generic" and c.target == target and _single_joint_variable(c) == var]
        if not named_here:
            continue
        keep = [(c, B) for c, B in fit.chosen if c is not a]
        base = prob.fit(fit.z[: prob.prep.space.size], keep, _psi_init(fit, keep))
        have = {c.key for c, _ in keep}
        cands = [c for c in pool if c.pool == "catalogue" and c.target == target and _single_joint_variable(c) == var
                 and c.key not in have]
        scored = _score_atoms(prob, base, cands, sizes, exact_top=len(cands)) if cands else []
        trial = keep + [(s.atom, s.basis) for s in scored if s.logp_adj < np.log(alpha_select)]
        if len(trial) == len(keep):
            continue
        alt = prob.fit(base.z[: prob.prep.space.size], trial, _psi_init(base, trial))
        alt, _ = _backward(prob, alt, alpha_select, sizes)
        e_alt = _error_stats(alt.model_val, alt.z, prob.keep_val)["position_mm"]["rms"]
        e_now = _error_stats(fit.model_val, fit.z, prob.keep_val)["position_mm"]["rms"]
        if e_alt <= 1.02 * e_now:
            notes.append(f"'{a.label}' replaced by the catalogue's shapes of {var} on joint {target[5:]} "
                         f"({'; '.join(c.label for c, _ in alt.chosen if c.target == target)}): they predict the "
                         f"held-out rows as well ({e_alt:.5f} vs {e_now:.5f} mm RMS)")
            for c, _ in alt.chosen:
                if c.target == target and c.pool != "generic":
                    alts.append({"of": c.label, "alternative": f"{a.label} (with the named terms it was kept with)",
                                 "family": "unnamed", "channel": a.channel, "target": target,
                                 "delta_chi2": float("nan"), "delta_chi2_chosen": float("nan"),
                                 "share_reproduced": float("nan"), "held_out_rms_mm": [e_alt, e_now]})
            fit = alt
    return fit, notes, alts


def _joint_channels(a: dict) -> set[str]:
    """Joint variables a term's features are functions of (only pow/sin/cos features of joint angles; empty
    when any feature is of another kind: gravity, approach, time)."""
    chans = set()
    for f in a["features"]:
        ch = f.get("ch")
        if f.get("kind") not in ("pow", "sin", "cos") or not (isinstance(ch, str) and ch.startswith("q")):
            return set()
        chans.add(ch)
    return chans


def _merged_into_unnamed(atoms_json: list[dict]) -> list[tuple[dict, dict]]:
    """``(named, unnamed)`` pairs of non-minor joint terms at the same joint whose named term is a function of
    joint variables all of which the unnamed one also uses."""
    out = []
    for a in atoms_json:
        if a["family"] == "unnamed" or a["minor"] or a["place"] != "joint":
            continue
        ca = _joint_channels(a)
        if not ca:
            continue
        for u in atoms_json:
            if u["family"] == "unnamed" and not u["minor"] and u["place"] == "joint" and u["target"] == a["target"] \
                    and ca <= _joint_channels(u):
                out.append((a, u))
                break
    return out


def _place_unit(a: Atom) -> tuple[str, float]:
    """Display unit of an atom's effect on its place, and the factor from SI."""
    if a.place == "joint":
        return "deg", 1 / _DEG
    if a.place in ("length", "scale"):
        return "ppm", 1e6
    if a.place in ("plate", "field") or a.target == "base_along":
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
        if a.place == "param" and a.target == "base_along":
            size = {"rms": float(abs(phi[0])) / _MM, "sd": float(sd[0]) / _MM, "unit": "mm"}
            words = f"{phi[0] / _MM:+.5f} +- {sd[0] / _MM:.5f} mm along the direction of its last move"
        elif a.place == "param" and a.target in ("tool", "base"):
            eff = F @ phi.reshape(len(a.features), 6)  # (n, 6)
            size = {"rms_mm": (np.sqrt(np.mean(eff[:, :3] ** 2)) / _MM).item(),
                    "rms_deg": (np.sqrt(np.mean(eff[:, 3:] ** 2)) / _DEG).item()}
            words = f"{size['rms_mm']:.4f} mm / {size['rms_deg']:.5f} deg RMS over the rows"
        elif a.place == "field":
            obs = prob.obs_cal
            G = (fit.model_cal.field_grid(a) * F[prob.rows_cal][:, None, :, None])[obs.seen]  # (m, K, 3) at the points
            disp = np.einsum("mkc,k->mc", G, phi)  # (m, 3)
            rms = float(np.sqrt(np.mean(np.sum(disp**2, axis=1))))
            grad = np.einsum("mkc,mc->k", G, disp) / (len(disp) * max(rms, 1e-300))
            sd_rms = float(np.sqrt(max(grad @ Cphi @ grad, 0.0)))
            size = {"rms": rms / _MM, "sd": sd_rms / _MM, "unit": "mm"}
            words = f"{rms / _MM:.5f} +- {sd_rms / _MM:.5f} mm RMS displacement over the measured points"
        elif a.varying_plate:
            eff = F @ phi.reshape(len(a.features), 3)  # (n, 3) offset per row in the plate frame
            rms = float(np.sqrt(np.mean(np.sum(eff**2, axis=1))))
            size = {"rms": rms / _MM, "sd": float(np.sqrt(np.sum(sd**2))) / _MM, "unit": "mm"}
            words = f"{rms / _MM:.5f} mm RMS over the rows (offset in the plate frame)"
        elif a.place == "plate":
            size = {"offset_mm": (phi / _MM).tolist(), "sd_mm": (sd / _MM).tolist()}
            words = "offset (" + ", ".join(f"{v / _MM:+.4f} +- {e / _MM:.4f}" for v, e in zip(phi, sd)) + ") mm"
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
        elif len(phi) == 1 and a.place not in ("plate", "field"):
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
        e, _ = _row_rms(f.model_val.unwhiten(r.r), r.row, f.model_val.obs.n)
        out[f"residual_rms_mm_{tag}"] = e / _MM
    # each term of the extended model on the held-out rows, in its place's display unit
    _, phis = ext.model_val.split(ext.z)
    terms = {}
    for t, phi in zip(ext.model_val.terms, phis):
        unit, fac = _place_unit(t.atom)
        if t.atom.place == "param" and t.atom.target in ("tool", "base"):
            v = np.linalg.norm((t.F @ phi.reshape(len(t.atom.features), 6))[:, :3], axis=1) / _MM
            unit = "mm (translation)"
        elif t.atom.place == "plate":
            v = np.linalg.norm(t.F @ phi.reshape(len(t.atom.features), 3), axis=1) / _MM
        elif t.atom.target == "base_along":
            v = np.linalg.norm(t.F, axis=1) * phi[0] / _MM
        elif t.atom.place == "field":
            obs = ext.model_val.obs
            disp = np.linalg.norm(np.einsum("nskc,k->nsc", ext.model_val.field_grid(t.atom) * t.F[:, None, :, None], phi),
                                  axis=2)
            v = np.sqrt(np.sum(disp**2, axis=1) / np.maximum(obs.seen.sum(1), 1)) / _MM
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
    a catalogue family's name: every atom of that family (per joint, per link)."""
    if not isinstance(dataset, Dataset):
        raise ValueError(f"dataset must be a twin.dataset.Dataset, got {type(dataset).__name__}")
    if dataset.set is None and holdout is None:
        raise DiagnosisError("fit_with_effects needs held-out rows: a 'set' column or holdout=FRACTION")
    floor = noise_floor(dataset)
    prep = prepare(dataset, noise_position=floor.sigma, validation_fraction=holdout or 0.0, seed=seed)
    ident = identify_best(prep, alpha=1e-6)
    ctx = row_context(dataset, q_start)
    # a catalogue family given by name stands for all its atoms
    bad = [a for a in atoms if not isinstance(a, (Atom, str))]
    if bad:
        raise ValueError(f"atoms must be twin.diagnosis.atoms.Atom or catalogue family names, got {bad[0]!r}")
    fams = {a for a in atoms if isinstance(a, str)}
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
