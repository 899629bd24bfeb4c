"""Changes after the block that fits: a step that happens in the held-out block of time.

The terms are chosen on the rows that fit and judged on the later held-out block; a change that happens inside that
block (a tool knocked, a tripod bumped, a payload taken off late in the campaign) is in no fit, and the models to use,
refitted on every row with the chosen terms, keep the state before it: every later row, and the next session, then
carry the change as error. This step looks for such a change and keeps it only on rows it was not located or fitted
on, sequentially in time:

1. **Where.** When the model in use leaves the held-out block beyond the floor, the step scan of
   :func:`twin.diagnosis.changes.scan_changes` (steps only; its Bonferroni factor over places and rows) runs on every
   row of the campaign against the model in use refitted on every row; a step is a candidate only where the
   selection's scan could not place it (after the last rows that fit, less than ``max(MIN_ROWS, MIN_SIDE n)`` of
   them after it).
2. **Located and fitted before a cut.** The cut is the fewest rows after the candidate's start that the scan needs
   to place a step (``max(MIN_ROWS, MIN_SIDE n) + 1``): the model in use is refitted on the rows before the cut, and
   the scan runs again on them alone; its best step after the last rows that fit is the change. The rows after the
   cut must be enough for the confirmation to reach ``z_min`` without its most favourable row (:func:`rows_to_confirm`).
3. **Confirmed after the cut.** The rows after the cut are its held-out block: the per-row gains' signed-rank score
   (:func:`twin.diagnosis.confirm.confirm`) above ``z_min``, also without the most favourable row, the held-out error
   lower, and no better predicted by the state of the rows just before them (a wander, not a change).

A confirmed change joins the models to use (refitted on every row with it): rows after it and a new session read
the state after it. Its figures are those of step 3: the RMS position error on the rows after the cut without and
with it, both models fitted on the rows before the cut.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..estimator.core import prepare
from .changes import MIN_ROWS, MIN_SIDE, ChangePlace, change_pool_sizes, row_times, scan_changes
from .features import Lag
from .problem import Fit, Problem, psi_init, refit_with
from .confirm import confirm
from .extend import error_stats
from .refine import ONSET_POINTS, ONSET_RAMPS, ONSET_TAUS, is_onset, onset_lag, refine, refine_onset
from .scoring import Scored, score_atoms
from .structure import chi2_logsf

__all__ = ["LateChange", "late_change", "late_templates", "late_term", "rows_to_confirm"]


def rows_to_confirm(z_min: float) -> int:
    """The fewest rows whose signed-rank score can exceed ``z_min`` without the most favourable one: ``n - 1``
    rows all in favour give ``z = sqrt(3 k (k + 1) / (2 (2 k + 1)))``, ``k = n - 1`` (13 rows for ``z_min = 3``)."""
    k = 1
    while np.sqrt(3.0 * k * (k + 1) / (2.0 * (2 * k + 1))) <= z_min:
        k += 1
    return k + 1


@dataclass(frozen=True)
class LateChange:
    """A change confirmed after the block that fits: its atom and reduced basis ``(K, r)``, the cut (time channel
    value: rows at or after it confirmed it), the confirmation's scores, the rows on each side of the cut and the RMS
    position error [mm] on the rows after the cut without and with it (models fitted before the cut), and its entry
    evidence ``dchi2`` on the rows before the cut."""

    atom: object
    basis: np.ndarray
    cut: float
    z: float
    z_without_best_row: float
    n_before: int
    n_after: int
    rms_without_mm: float
    rms_with_mm: float
    dchi2: float


def _prob_before(setup, prob_all: Problem, t_cut: float) -> Problem:
    """The problem whose calibration rows are the campaign's rows before ``t_cut`` (time channel) and whose
    confirmation rows are the rest."""
    _, tv = row_times(setup.ctx)
    ds = setup.dataset
    sets = np.where(tv < t_cut, "calibration", "validation").astype(object)
    ds_cut = replace(ds, set=sets)
    prep = prepare(ds_cut, noise_position=setup.floor.sigma, validation_fraction=0.0)
    prob = Problem(prep, setup.floor, setup.ctx, setup.problem.free_geo, threads=setup.problem.threads_asked)
    prob.evidence_scale = prob_all.evidence_scale
    prob.cross_session = prob_all.cross_session
    return prob


def _rms_mm(fit: Fit, prob: Problem) -> float:
    return float(error_stats(fit.model_val, fit.z, prob.keep_val)["position_mm"]["rms"])


def late_change(setup, prob_all: Problem, use_all: Fit, places: list[ChangePlace], *, alpha: float,
                z_min: float) -> tuple[LateChange | None, str]:
    """Steps 1-3 of the module docstring. ``use_all``: the model in use refitted on every row (``prob_all``).
    Returns the confirmed change (or ``None``) and a note saying what was tried."""
    ch, tv = row_times(setup.ctx)
    # the selection's scan takes steps with at least `side` rows of the block that fits after them: later ones are this
    # step's
    t_fit = np.sort(tv[setup.problem.rows_cal])
    side = max(MIN_ROWS, int(np.ceil(MIN_SIDE * len(t_fit))))
    t_fit_end = float(t_fit[max(len(t_fit) - side, 0)])
    t_rows = np.sort(tv[prob_all.rows_cal])
    found = [a for a in scan_changes(prob_all, use_all, places, windows=False, alpha=alpha)
             if float(a.features[0].at) > t_fit_end]
    if not found:
        return None, "no change after the rows that fit (step scan on every row)"
    at = float(found[0].features[0].at)
    later = t_rows[t_rows > at]
    n_locate = max(MIN_ROWS, int(np.ceil(MIN_SIDE * len(t_rows)))) + 1
    need = n_locate + rows_to_confirm(z_min)
    if len(later) < need:
        return None, (f"a change after the rows that fit ({found[0].label}) has {len(later)} rows after it, fewer than "
                      f"the {need} it takes to locate it on some and confirm it on others: not kept")
    t_cut = float(later[n_locate])
    prob = _prob_before(setup, prob_all, t_cut)
    fit0 = refit_with(prob, use_all, use_all.chosen)
    cands = [a for a in scan_changes(prob, fit0, places, windows=False, alpha=alpha)
             if float(a.features[0].at) > t_fit_end]
    if not cands:
        return None, (f"a change after the rows that fit ({found[0].label}) is not found again on the rows before "
                      f"{ch} {t_cut:.6g} alone: not kept")
    sizes = change_pool_sizes(prob.obs_cal.n, places)
    scored = score_atoms(prob, fit0, cands[:1], sizes, exact_top=1)
    if not scored:
        return None, f"a change after the rows that fit ({cands[0].label}) could not be scored: not kept"
    s = scored[0]
    c = confirm(prob, fit0, s, z_min)
    ok = c.z > z_min and c.z_without_best_row > z_min and c.better and not c.local
    P = prob.prep.space.size
    chosen = list(use_all.chosen) + [(s.atom, s.basis)]
    fit1 = prob.fit(fit0.z[:P], chosen, psi_init(fit0, use_all.chosen) + [s.psi])
    got = LateChange(s.atom, s.basis, t_cut, float(c.z), float(c.z_without_best_row), int(prob.obs_cal.n),
                     int(prob.obs_val.n), _rms_mm(fit0, prob), _rms_mm(fit1, prob), float(s.dchi2))
    words = (f"{s.atom.label}: located and fitted on the {got.n_before} rows before {ch} {t_cut:.6g}, on the "
             f"{got.n_after} rows after it RMS {got.rms_without_mm:.4f} -> {got.rms_with_mm:.4f} mm (z {c.z:.1f}, "
             f"{c.z_without_best_row:.1f} without the best row)")
    if not ok:
        return None, "a change after the rows that fit not confirmed on the rows after the cut: " + words
    return got, "a change after the rows that fit, confirmed on later rows: " + words


def late_templates(pool: list) -> list:
    """The thermal terms a change of the air after the rows that fit may take, one per place (all links, each link):
    against the recorded temperature through a lag, or, without a record, a step or a ramp of the air at an onset
    through the links' lag (:func:`twin.diagnosis.refine.is_onset`)."""
    out, seen = [], set()
    for a in pool:
        if a.family != "thermal" or a.target in seen:
            continue
        if is_onset(a) or (len(a.features) == 1 and isinstance(a.features[0], Lag) and a.features[0].ch == "temp_c"):
            out.append(a)
            seen.add(a.target)
    return out


def _fit_template(prob: Problem, fit: Fit, a, after: float, sizes: dict) -> tuple[Scored | None, int]:
    """The thermal template ``a`` at its best constants on ``prob``'s calibration rows against ``fit`` (an onset no
    earlier than ``after`` [s]; a lag of the recorded temperature over every time constant of the onset grid, then
    refined) and the number of constants' values tried."""
    got = score_atoms(prob, fit, [a], sizes, exact_top=1)
    if not got:
        return None, 1
    if is_onset(a):
        s = refine_onset(prob, fit, got[0], sizes, after=after)
        return (None if s is got[0] else s), ONSET_POINTS * len(ONSET_TAUS) * len(ONSET_RAMPS)
    t = np.asarray(prob.ctx.t_s, float)[prob.rows_cal]
    trial = [onset_lag(a, fc * float(np.ptp(t))) for fc in ONSET_TAUS]
    s = max(got + score_atoms(prob, fit, trial, sizes, exact_top=len(trial)), key=lambda x: x.dchi2)
    return refine(prob, fit, s, sizes), len(ONSET_TAUS)


def _start(setup, a, t_fit_end: float) -> float | None:
    """When the late change of the template ``a`` starts: an onset's time; for a lag of the recorded temperature, the
    first row after ``t_fit_end`` whose temperature leaves the range of the rows before it by more than that range's
    width (None when it never does)."""
    if is_onset(a):
        return float(a.features[0].t0)
    _, tv = row_times(setup.ctx)
    temp = np.asarray(setup.ctx.temp_c, float)
    before = tv <= t_fit_end
    lo, hi = float(np.min(temp[before])), float(np.max(temp[before]))
    w = hi - lo
    out = (~before) & ((temp < lo - w) | (temp > hi + w))
    return float(np.min(tv[out])) if np.any(out) else None


def late_term(setup, prob_all: Problem, use_all: Fit, templates: list, *, alpha: float,
              z_min: float) -> tuple[LateChange | None, str]:
    """A change of the air's temperature after the rows that fit, through the links' lag (thermal growth), judged as
    :func:`late_change` judges a step: the best thermal term of ``templates`` (:func:`late_templates`) on every row
    against the model in use (significant after the factor of places and constants tried), starting after the rows
    that fit (an onset, or the recorded temperature leaving the range those rows saw); located and fitted on the rows
    before a cut (the fewest rows after its start the step scan needs), confirmed on the rows after it. Places that
    already have a thermal term are not tried. Returns the confirmed term (or ``None``) and a note."""
    ch, tv = row_times(setup.ctx)
    have = {a.target for a, _ in use_all.chosen if a.family == "thermal"}
    templates = [a for a in templates if a.target not in have]
    if ch != "t_s" or not templates:
        return None, ""
    t_fit = np.sort(tv[setup.problem.rows_cal])
    side = max(MIN_ROWS, int(np.ceil(MIN_SIDE * len(t_fit))))
    t_fit_end = float(t_fit[max(len(t_fit) - side, 0)])
    sizes = {a.pool: 1 for a in templates}
    found = []
    for a in templates:
        s, tried = _fit_template(prob_all, use_all, a, t_fit_end, sizes)
        if s is None:
            continue
        logp = chi2_logsf(s.dchi2 / prob_all.evidence_scale, s.basis.shape[1]) + np.log(len(templates) * tried)
        start = _start(setup, s.atom, t_fit_end)
        if logp < np.log(alpha) and start is not None and start >= t_fit_end:
            found.append((s.dchi2, s, start))
    if not found:
        return None, "no change of the air's temperature after the rows that fit"
    _, s_all, start = max(found, key=lambda x: x[0])
    t_rows = np.sort(tv[prob_all.rows_cal])
    later = t_rows[t_rows >= start]
    n_locate = max(MIN_ROWS, int(np.ceil(MIN_SIDE * len(t_rows)))) + 1
    need = n_locate + rows_to_confirm(z_min)
    if len(later) < need:
        return None, (f"a change after the rows that fit ({s_all.atom.label}) has {len(later)} rows after its start, "
                      f"fewer than the {need} it takes to locate it on some and confirm it on others: not kept")
    t_cut = float(later[n_locate])
    prob = _prob_before(setup, prob_all, t_cut)
    fit0 = refit_with(prob, use_all, use_all.chosen)
    s, _ = _fit_template(prob, fit0, s_all.atom, t_fit_end, sizes)
    if s is None:
        return None, f"a change after the rows that fit ({s_all.atom.label}) could not be fitted before the cut: not kept"
    c = confirm(prob, fit0, s, z_min)
    ok = c.z > z_min and c.z_without_best_row > z_min and c.better and not c.local
    P = prob.prep.space.size
    fit1 = prob.fit(fit0.z[:P], list(use_all.chosen) + [(s.atom, s.basis)], psi_init(fit0, use_all.chosen) + [s.psi])
    got = LateChange(s.atom, s.basis, t_cut, float(c.z), float(c.z_without_best_row), int(prob.obs_cal.n),
                     int(prob.obs_val.n), _rms_mm(fit0, prob), _rms_mm(fit1, prob), float(s.dchi2))
    words = (f"{s.atom.label}: located and fitted on the {got.n_before} rows before {ch} {t_cut:.6g}, on the "
             f"{got.n_after} rows after it RMS {got.rms_without_mm:.4f} -> {got.rms_with_mm:.4f} mm (z {c.z:.1f}, "
             f"{c.z_without_best_row:.1f} without the best row)")
    if not ok:
        return None, "a change of the air's temperature after the rows that fit not confirmed on the rows after the cut: " + words
    return got, "a change of the air's temperature after the rows that fit, confirmed on later rows: " + words
