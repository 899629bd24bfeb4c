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

A change too close to the campaign's end for steps 2-3 (fewer than ``n_locate + rows_to_confirm(z_min)`` rows after
it) is an *end change* (:func:`end_change`): judged on every row as a change and back that has not ended, against
the scatter the rows before it show along its place, whether or not the held-out block held structure.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..estimator.core import prepare
from ..estimator import distributions as dists
from ..estimator.distributions import chi2_isf
from .changes import (MIN_ROWS, MIN_SIDE, ChangePlace, as_step, as_window, change_at, change_pool_sizes, is_change,
                      is_step, is_window, place_scatter, row_times, same_event, scan_changes, started_at)
from .atoms import Atom, is_load_change
from .features import Gated, Heat, Lag, Window
from .problem import (Fit, Problem, common_chi2, held_out_rms, psi_init, refit_with, runs_of_length,
                      update_gross)
from .confirm import confirm
from .refine import ONSET_POINTS, ONSET_RAMPS, ONSET_TAUS, is_onset, onset_lag, refine, refine_onset
from .scoring import Scored, score_atoms
from .structure import chi2_logsf

__all__ = ["LateChange", "EndChange", "late_change", "end_change", "late_templates", "late_term", "end_term", "end_steps",
           "begun_steps", "glitches", "gross_runs", "rows_to_confirm", "own_weight", "payload_event", "as_event",
           "payload_at", "step_as_return"]


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
    """The problem whose calibration rows are ``prob_all``'s calibration rows before ``t_cut`` (time channel) and whose
    confirmation rows are the rest of them (the dataset's other rows, a report block after them, in neither)."""
    _, tv = row_times(setup.ctx)
    ds = setup.dataset
    inside = np.zeros(ds.n, bool)
    inside[prob_all.rows_cal] = True
    sets = np.where(inside, np.where(tv < t_cut, "calibration", "validation"), "none").astype(object)
    ds_cut = replace(ds, set=sets)
    prep = prepare(ds_cut, noise_position=setup.floor.sigma, validation_fraction=0.0)
    prob = Problem(prep, setup.floor, setup.ctx, setup.problem.free_geo, threads=setup.problem.threads_asked)
    prob.evidence_scale = prob_all.evidence_scale
    prob.cross_session = prob_all.cross_session
    return prob


def _rows_after(n: int, z_min: float) -> tuple[int, int]:
    """The rows after a change found after the rows that fit (of ``n``) that locate it (the fewest rows after a step
    the scan needs, plus one) and those that locate and confirm it (with :func:`rows_to_confirm`)."""
    n_locate = max(MIN_ROWS, int(np.ceil(MIN_SIDE * n))) + 1
    return n_locate, n_locate + rows_to_confirm(z_min)


def _cut(t_rows: np.ndarray, later: np.ndarray, z_min: float) -> tuple[float | None, int]:
    """Where a change found after the rows that fit is cut (``t_rows`` every calibration row's time, sorted; ``later``
    those after the change): the time of the row that leaves enough rows before it to locate the change, and the
    rows it takes to locate and confirm it (None when fewer follow the change)."""
    n_locate, need = _rows_after(len(t_rows), z_min)
    return (float(later[n_locate]) if len(later) >= need else None), need

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
    t_cut, need = _cut(t_rows, later, z_min)
    if t_cut is None:
        return None, (f"a change after the rows that fit ({found[0].label}) has {len(later)} rows after it, fewer than "
                      f"the {need} it takes to locate it on some and confirm it on others: not kept")
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
    s, note = as_event(prob, fit0, scored[0], cands, places, sizes, t_rows, alpha=alpha)
    got, words = _confirmed(prob, fit0, use_all, s, t_cut, ch, z_min, "a change after the rows that fit")
    return got, words + note


@dataclass(frozen=True)
class EndChange:
    """A change whose new state the campaign's last rows hold (:func:`end_change`): its atom and reduced basis
    ``(K, r)``, the rows after its start, its evidence ``dchi2`` on every row, the scatter of the rows before it along
    its place it was measured against (:func:`place_scatter`, 1 at the floor) and its ``log10`` p-value after the
    Bonferroni ``factor``."""

    atom: object
    basis: np.ndarray
    n_after: int
    dchi2: float
    scatter: float
    log10_p: float
    factor: int

    def judged(self) -> dict:
        """How it was judged, for ``diagnosis.json`` ``changes``."""
        return {"rows_after": self.n_after, "delta_chi2": self.dchi2, "scatter_before": self.scatter,
                "log10_p": self.log10_p, "bonferroni_factor": self.factor}


def end_change(setup, prob_all: Problem, use_all: Fit, places: list[ChangePlace], *, alpha: float,
               z_min: float) -> tuple[Fit, EndChange | None, str]:
    """A change whose new state the campaign's last rows hold (an *end change*: a joint's zero re-latched, a plate
    slipping, the instrument bumped, a payload hung on or taken off a few rows before the end), too close to the end
    for :func:`late_change` to locate it on some rows and confirm it on others (fewer than its ``n_locate +
    rows_to_confirm(z_min)`` rows after it). Judged as a change and back that has not ended (:func:`glitches` judges
    those): the step scan of :func:`twin.diagnosis.changes.scan_changes` on every row against the models to use, at
    the steps with ``MIN_ROWS`` to that many rows after them, by its rules (the rows after the step fitted by it to
    the scatter of the others, significant without any one of them with at least half its evidence, the residual it
    leaves white in time), gross rows among those last rows seen by it (a row 17x the noise off is gross without
    the change that explains it); then its evidence measured against the scatter the rows before it show along its
    place (:func:`place_scatter` over each of the place's columns, the model with the change: a wander of the cell
    holds over a few rows and moves the last ones together), significant after the window pool's Bonferroni factor
    over every row and place (a window whose end is the campaign's). Strongest first; a step of a joint's zero read as
    a payload's change where the payload's event explains more (:func:`as_event`). At the place of a kept step, that
    step ending there (a change and back: a payload taken off again, a glitch's return) is preferred where it explains
    every row as well (its chi2 within ``chi2_1`` at ``alpha`` of both changes': one constant fewer). Returns the fit
    (with the change, or with the kept step ended, or as given), the change (or None) and a note."""
    ch, tv = row_times(setup.ctx)
    t_rows = np.sort(tv[prob_all.rows_cal])
    n = len(t_rows)
    _, need = _rows_after(n, z_min)
    if n < 2 * need:
        return use_all, None, ""
    factor = change_pool_sizes(n, places, short=MIN_ROWS)["change_window"]
    sizes = {"change": factor, "change_window": factor}
    w0 = prob_all.w_cal
    tail = tv[prob_all.rows_cal] >= t_rows[n - need + 1]
    w_tail = np.maximum(w0, (tail & ~prob_all.history_out).astype(float))  # not the rows a term lacks the history of
    prob_all.w_cal = w_tail
    result = use_all, None, ""
    try:
        cands = scan_changes(prob_all, use_all, places, windows=False, alpha=alpha, last=(MIN_ROWS, need - 1),
                             sizes=sizes)
        for a in cands:
            prob_all.w_cal = w_tail
            got = score_atoms(prob_all, use_all, [a], sizes, exact_top=1)
            if not got:
                continue
            with_it = refit_with(prob_all, use_all, list(use_all.chosen) + [(got[0].atom, got[0].basis)])
            s2 = place_scatter(prob_all, with_it, a, every_column=True)
            logp = chi2_logsf(got[0].dchi2 / prob_all.evidence_scale / s2, got[0].basis.shape[1]) + np.log(factor)
            if logp >= np.log(alpha):
                continue
            at = float(a.features[0].at)
            k = int(np.sum(t_rows > at))
            words = (f"({k} rows after it, fewer than the {need} it takes to locate it on some and confirm it on "
                     f"others; Delta chi2 {got[0].dchi2 / prob_all.evidence_scale:.1f} against the scatter {s2:.2f} "
                     f"of the rows before it, p = 10^{logp / np.log(10.0):.1f} after the factor {factor})")
            ended = _ended_at(prob_all, use_all, a, at)
            if ended is not None and ended.chi2 - with_it.chi2 < prob_all.evidence_scale * chi2_isf(alpha, 1):
                result = ended, None, (f"a change in the campaign's last rows {words} is the end of a kept change at "
                                       f"its place: {[c.label for c, _ in ended.chosen if is_window(c)][-1]} (chi2 "
                                       f"{ended.chi2:.1f} against {with_it.chi2:.1f} with both)")
                break
            prob_all.w_cal = w_tail
            s, note = as_event(prob_all, use_all, got[0], cands, places, sizes, t_rows, alpha=alpha)
            k = int(np.sum(t_rows > float(s.atom.features[0].at)))
            end = EndChange(s.atom, s.basis, k, float(s.dchi2), float(s2), float(logp / np.log(10.0)), int(factor))
            result = use_all, end, f"a change in the campaign's last rows: {s.atom.label} {words}" + note
            break
    finally:
        prob_all.w_cal = w0
    fit, end, note = result
    if end is not None or fit is not use_all:
        # fitted with the last rows it holds (gross without it), whose weights the refit then sets anew
        prob_all.w_cal = w_tail
        chosen = list(fit.chosen) + ([(end.atom, end.basis)] if end is not None else [])
        fit = refit_with(prob_all, fit, chosen)
    return fit, end, note


def _ended_at(prob: Problem, fit: Fit, atom, at: float) -> Fit | None:
    """``fit`` with the kept step at ``atom``'s place (``place``, ``target``; starting before ``at``) that fits every
    row best when it ends at ``at`` (a window), or None when no kept step is there."""
    best = None
    for k, (c, _) in enumerate(fit.chosen):
        if not (is_step(c) and (c.place, c.target) == (atom.place, atom.target) and float(c.features[0].at) < at):
            continue
        chosen = list(fit.chosen)
        chosen[k] = (as_window(c, at), chosen[k][1])
        trial = refit_with(prob, fit, chosen)
        if best is None or trial.chi2 < best.chi2:
            best = trial
    return best


EVENT_ROWS = 3  # rows either side of the candidates' starts where a payload's event is located as a whole


def as_event(prob: Problem, fit0: Fit, s: Scored, cands: list, places: list[ChangePlace], sizes: dict,
             t_rows: np.ndarray, *, alpha: float) -> tuple[Scored, str]:
    """The change ``s`` (a step of a joint's zero or of a frame, scored against ``fit0`` on ``prob``'s rows), or a
    change of a joint's compliance the scan found (``cands``: at the same joint for a zero's step; for a frame's, at
    any joint, starting within :data:`EVENT_ROWS` rows of it) read as one event: a payload hangs at the flange and
    changes the gravity torque of every joint below it at once (:func:`payload_event`), so the event is that joint's
    change with the same change at every other joint's payload place (:func:`~twin.diagnosis.changes.same_event`)
    added while significant after the factor of the places tried. Each such change leads an event in turn; the one
    that leaves the rows the lowest chi2 is the event, a payload's shapes leading where they do within ``chi2_1`` at
    ``alpha`` of it (a point mass at the flange, the physical event, over a stiffness changed under the arm's own
    weight when the rows cannot tell them apart). The event replaces the zero's step where its
    ``Delta chi2`` beyond the step's exceeds ``chi2`` of its extra columns at ``alpha`` (``k_event - k_step`` degrees
    of freedom, at least one); its start is then the row (``t_rows``: the rows' times, sorted), within
    :data:`EVENT_ROWS` of the two candidates' starts, at which the whole event fits the rows best (each joint's start
    alone is located less surely than all of them together). Returns the change to confirm and a note (empty when
    ``s`` stands)."""
    a = s.atom
    if not (is_step(a) and not is_load_change(a)):
        return s, ""
    w_entry = prob.w_cal
    i_a = np.searchsorted(t_rows, float(a.features[0].at))
    alts = [c for c in cands if is_load_change(c) and is_step(c)
            and (c.target == a.target if a.place == "joint"
                 else abs(np.searchsorted(t_rows, float(c.features[0].at)) - i_a) <= EVENT_ROWS)]
    if not alts:
        return s, ""
    got, tried = None, []
    for c in alts:
        # each candidate lead (a payload's shapes, or the arm's own at a joint whose stiffness changed) as a whole
        # event: the one that leaves every row the lowest chi2
        first = score_atoms(prob, fit0, [c], sizes, exact_top=1)
        if not first:
            continue
        fit = refit_with(prob, fit0, list(fit0.chosen) + [(first[0].atom, first[0].basis)])
        fit, added = _while_significant(prob, fit, same_event(first[0].atom, places), alpha=alpha)
        tried.append((first[0], fit, added))
        if got is None or fit.chi2 < got[1].chi2:
            got = (first[0], fit, added)
    if got is None:
        return s, ""
    lead, fit, added = got
    # a payload is a point mass at the flange: its own shapes lead the event where they explain every row as well
    # (a chi2 within chi2_1 at alpha of the best lead's)
    pay = [g for g in tried if _payload_place(g[0].atom, places)]
    if pay and min(pay, key=lambda g: g[1].chi2)[1].chi2 - fit.chi2 < prob.evidence_scale * chi2_isf(alpha, 1):
        lead, fit, added = min(pay, key=lambda g: g[1].chi2)
    k_event = lead.basis.shape[1] + sum(g.basis.shape[1] for g, _, _ in added)
    gain = (fit0.chi2 - fit.chi2 - s.dchi2) / prob.evidence_scale
    extra = max(k_event - s.basis.shape[1], 1)
    # scored again against fit0 (a Scored reads its columns from the last scoring of the problem)
    if gain <= chi2_isf(alpha, extra):
        again = score_atoms(prob, fit0, [a], sizes, exact_top=1)
        # a step with no columns left against fit0 on these rows stands as it was scored
        return (again[0] if again else s), ""
    members = list(fit.chosen[len(fit0.chosen):])
    ats = sorted((float(a.features[0].at), float(lead.atom.features[0].at)))
    i0, i1 = np.searchsorted(t_rows, ats[0]), np.searchsorted(t_rows, ats[1])
    # the starts compared on the same rows' weights (the gross rows of the event at the scan's start): a start that
    # made rows gross would drop their misfit from its chi2
    w_event = prob.w_cal.copy()
    P = prob.prep.space.size
    best_chi2, best_at = fit.chi2, float(lead.atom.features[0].at)
    try:
        for t in t_rows[max(i0 - EVENT_ROWS, 1):i1 + EVENT_ROWS + 1]:
            chosen = list(fit.chosen[:len(fit0.chosen)]) + [(started_at(c, t), B) for c, B in members]
            prob.w_cal = w_event
            trial = prob.fit(fit.z[:P], chosen, psi_init(fit, chosen))
            if trial.chi2 < best_chi2:
                best_chi2, best_at = trial.chi2, float(t)
    finally:
        prob.w_cal = w_entry
    moved = score_atoms(prob, fit0, [started_at(lead.atom, best_at)], sizes, exact_top=1)
    lead = moved[0] if moved else score_atoms(prob, fit0, [lead.atom], sizes, exact_top=1)[0]
    return lead, (f"; read as a payload's change ({lead.atom.label} with the same change at every loaded joint "
                  f"beside it: Delta chi2 {gain:.1f} beyond {a.label} for {extra} more columns)")


def _payload_place(atom, places: list[ChangePlace]) -> bool:
    """Whether ``atom`` is a change at a joint's payload place of ``places`` (a point mass at the flange)."""
    shapes = tuple(getattr(f, "f", None) for f in atom.features)
    return any(pl.payload and pl.target == atom.target and tuple(pl.inner) == shapes for pl in places)


def _confirmed(prob: Problem, fit0: Fit, use_all: Fit, s, t_cut: float, ch: str, z_min: float,
               what: str) -> tuple[LateChange | None, str]:
    """The change ``s`` (scored on ``prob``'s rows before the cut ``t_cut`` on channel ``ch``, against ``fit0``) judged
    on the rows after the cut: the :class:`LateChange` when confirmed there (else None) and a note on ``what`` it is."""
    c = confirm(prob, fit0, s, z_min)
    ok = c.holds(z_min)
    P = prob.prep.space.size
    fit1 = prob.fit(fit0.z[:P], list(use_all.chosen) + [(s.atom, s.basis)], psi_init(fit0, use_all.chosen) + [s.psi])
    got = LateChange(s.atom, s.basis, t_cut, float(c.z), float(c.z_without_best_row), int(prob.obs_cal.n),
                     int(prob.obs_val.n), held_out_rms(prob, fit0), held_out_rms(prob, fit1), float(s.dchi2))
    words = (f"{s.atom.label}: located and fitted on the {got.n_before} rows before {ch} {t_cut:.6g}, on the "
             f"{got.n_after} rows after it RMS {got.rms_without_mm:.4f} -> {got.rms_with_mm:.4f} mm (z {c.z:.1f}, "
             f"{c.z_without_best_row:.1f} without the best row)")
    if not ok:
        return None, f"{what} not confirmed on the rows after the cut: " + words
    return got, f"{what}, confirmed on later rows: " + words

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
    already have a thermal term of the air are not tried (one whose growth follows the motors' heat alone is: the
    links' temperature sums both sources). Returns the confirmed term (or ``None``) and a note."""
    ch, tv = row_times(setup.ctx)
    # the links' temperature sums its sources: a place whose growth follows the motors' heat alone may still follow
    # the air
    have = {a.target for a, _ in use_all.chosen if a.family == "thermal"
            and not any(isinstance(f, Heat) for f in a.features)}
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
    t_cut, need = _cut(t_rows, later, z_min)
    if t_cut is None:
        return None, (f"a change after the rows that fit ({s_all.atom.label}) has {len(later)} rows after its start, "
                      f"fewer than the {need} it takes to locate it on some and confirm it on others: not kept")
    prob = _prob_before(setup, prob_all, t_cut)
    fit0 = refit_with(prob, use_all, use_all.chosen)
    s, _ = _fit_template(prob, fit0, s_all.atom, t_fit_end, sizes)
    if s is None:
        return None, f"a change after the rows that fit ({s_all.atom.label}) could not be fitted before the cut: not kept"
    return _confirmed(prob, fit0, use_all, s, t_cut, ch, z_min,
                      "a change of the air's temperature after the rows that fit")


def end_term(setup, prob_all: Problem, use_all: Fit, templates: list, *, alpha: float,
             z_min: float) -> tuple[Fit, EndChange | None, str]:
    """The recorded temperature leaving, in the campaign's last rows, the range every row before them saw (by more than
    that range's width), too close to the end for :func:`late_term` to locate its growth on some rows and confirm it on
    others (the last ``need - 1`` rows of :func:`_rows_after`): growth against it through the links' lag (a template
    of :func:`late_templates` on ``temp_c``, its lag over the onset grid then refined) on every row, those last rows
    at full weight (a row the change puts 20x the noise off is gross without the term that explains it), significant
    after the factor of places and time constants tried, and so without any one of the rows after the temperature
    left its range. The record is a measured cause: its excursion times the change, the rows read its size. Places
    that already have a thermal term are not tried. Returns the fit (with the term, or as given), the term as an
    :class:`EndChange` (or None) and a note."""
    ch, tv = row_times(setup.ctx)
    have = {a.target for a, _ in use_all.chosen if a.family == "thermal"}
    templates = [a for a in templates if a.target not in have and len(a.features) == 1
                 and isinstance(a.features[0], Lag) and a.features[0].ch == "temp_c"]
    if ch != "t_s" or not templates or setup.ctx.temp_c is None:
        return use_all, None, ""
    t_rows = np.sort(tv[prob_all.rows_cal])
    n = len(t_rows)
    _, need = _rows_after(n, z_min)
    if n < 2 * need:
        return use_all, None, ""
    t_before = float(t_rows[n - need])
    start = _start(setup, templates[0], t_before)
    if start is None:
        return use_all, None, ""
    t_cal = tv[prob_all.rows_cal]
    after = t_cal >= start
    w0 = prob_all.w_cal
    w_tail = np.maximum(w0, ((t_cal > t_before) & ~prob_all.history_out).astype(float))
    prob_all.w_cal = w_tail
    sizes = {a.pool: 1 for a in templates}
    best, factor, kept = None, 1, False
    try:
        for a in templates:
            s, tried = _fit_template(prob_all, use_all, a, t_before, sizes)
            factor = len(templates) * tried
            if s is None:
                continue
            logp = chi2_logsf(s.dchi2 / prob_all.evidence_scale, s.basis.shape[1]) + np.log(factor)
            if logp < np.log(alpha) and (best is None or s.dchi2 > best[0].dchi2):
                best = (s, logp)
        if best is None:
            return use_all, None, ""
        s, logp = best
        for i in np.flatnonzero(after):
            # without any one of the rows after the excursion's start
            prob_all.w_cal = w_tail.copy()
            prob_all.w_cal[i] = 0.0
            got = score_atoms(prob_all, use_all, [s.atom], sizes, exact_top=1)
            if not got or chi2_logsf(got[0].dchi2 / prob_all.evidence_scale, s.basis.shape[1]) + np.log(factor) \
                    >= np.log(alpha):
                return use_all, None, (f"the recorded temperature leaves its range in the campaign's last rows "
                                       f"({s.atom.label}): not significant without one of its {int(np.sum(after))} "
                                       f"rows")
        # fitted with the last rows it holds, whose weights the refit then sets anew
        prob_all.w_cal = w_tail
        fit = refit_with(prob_all, use_all, list(use_all.chosen) + [(s.atom, s.basis)])
        kept = True
    finally:
        if not kept:
            prob_all.w_cal = w0
    k = int(np.sum(after))
    end = EndChange(s.atom, s.basis, k, float(s.dchi2), 1.0, float(logp / np.log(10.0)), int(factor))
    return fit, end, (f"the recorded temperature leaving its range in the campaign's last rows: {s.atom.label} ({k} "
                      f"rows after {ch} {start:.6g}, fewer than the {need} it takes to locate it on some and confirm it "
                      f"on others; Delta chi2 {s.dchi2 / prob_all.evidence_scale:.1f} on every row, p = "
                      f"10^{logp / np.log(10.0):.1f} after the factor {factor}, without any one of those rows too)")


def _swap_for_best(prob_all: Problem, use_all: Fit, k: int, readings: list[Atom], sizes: dict, *,
                   alpha: float) -> tuple[Fit, Scored, float] | None:
    """The kept term ``k`` of ``use_all`` and its other ``readings`` (the same change with another start or end),
    scored against the fit without it on ``prob_all``'s rows: the reading that explains most replaces it where its
    ``Delta chi2`` exceeds the term's by more than ``chi2_1`` at ``alpha`` over the readings tried. Returns the fit
    with it, the reading and that gain (in units of the evidence scale), or None (the term stands)."""
    a = use_all.chosen[k][0]
    without = refit_with(prob_all, use_all, [c for i, c in enumerate(use_all.chosen) if i != k])
    got = score_atoms(prob_all, without, [a] + readings, sizes, exact_top=len(readings) + 1)
    kept = next((g for g in got if g.atom is a), None)
    wins = [g for g in got if g.atom is not a]
    if kept is None or not wins:
        return None
    best = max(wins, key=lambda g: g.dchi2)
    gain = (best.dchi2 - kept.dchi2) / prob_all.evidence_scale
    if gain <= dists.chi2_isf(alpha / len(readings), 1):
        return None
    chosen = list(use_all.chosen)
    chosen[k] = (best.atom, best.basis)
    return refit_with(prob_all, use_all, chosen), best, gain


def end_steps(setup, prob_all: Problem, use_all: Fit, *, alpha: float) -> tuple[Fit, list[str]]:
    """Each kept change of the models to use ends, on every row, where the rows after it return to the state before
    it: a step is a window that has not ended, and a window's end is a constant of the term like its start (the block
    that chose it may have ended before the change did). The end is placed between two rows with at least
    ``max(MIN_ROWS, MIN_SIDE n)`` rows after it (a state held by a handful of rows at an end is no state); the change
    with its new end replaces it (the same coefficients) where that lowers the chi2 of every row beyond ``chi2_1`` at
    ``alpha`` over the ends tried. A glitch whose return comes too late in the campaign for the rows after a cut to
    confirm it (:func:`late_change`) is still a return to a state the campaign held. Returns the fit and a note per
    change ended."""
    ch, tv = row_times(setup.ctx)
    t_rows = np.sort(tv[prob_all.rows_cal])
    n = len(t_rows)
    side = max(MIN_ROWS, int(np.ceil(MIN_SIDE * n)))
    notes = []
    for k in range(len(use_all.chosen)):
        a, _ = use_all.chosen[k]
        if not (is_step(a) or is_window(a)):
            continue
        at = float(a.features[0].at)
        first = int(np.searchsorted(t_rows, at))
        ends = [0.5 * (t_rows[i - 1] + t_rows[i]) for i in range(first + MIN_ROWS, n - side + 1)
                if t_rows[i] > t_rows[i - 1]]
        if not ends:
            continue
        swapped = _swap_for_best(prob_all, use_all, k, [as_window(a, e) for e in ends],
                                 {"change": 1, "change_window": 1}, alpha=alpha)
        if swapped is None:
            continue
        use_all, best, gain = swapped
        notes.append(f"a change ends on every row: {best.atom.label} (the rows after its end back in the state before it: "
                     f"chi2 {gain:.1f} lower than with the end the first block gave it, {len(ends)} ends tried)")
    return use_all, notes


def begun_steps(setup, prob_all: Problem, use_all: Fit, *, alpha: float) -> tuple[Fit, list[str]]:
    """Each kept step of the models to use (a change from a row on) is, on every row, the end of a change the rows
    before it held from an earlier row on: a step back to the state of the rows before that start (a payload hung on
    within the rows and taken off later reads, to a model of one state before the step, as a step where it came off;
    the rows before it came on hold the state after). The start is placed between two rows with at least
    ``max(MIN_ROWS, MIN_SIDE n)`` rows before it and ``MIN_ROWS`` rows before the step; the window from it until the
    step replaces the step (its sign the fit's) where that lowers the chi2 of every row beyond ``chi2_1`` at ``alpha``
    over the starts tried (a window from the first row is the step itself where the geometry or a term of every row
    holds the state before it). Not where another kept change is at its place: that change sets the state of the rows
    before the step. The mirror of :func:`end_steps`. Returns the fit and a note per step turned into a window."""
    ch, tv = row_times(setup.ctx)
    t_rows = np.sort(tv[prob_all.rows_cal])
    n = len(t_rows)
    side = max(MIN_ROWS, int(np.ceil(MIN_SIDE * n)))
    notes = []
    for k in range(len(use_all.chosen)):
        a, _ = use_all.chosen[k]
        if not is_step(a) or any(is_change(c) and (c.place, c.target) == (a.place, a.target)
                                 for i, (c, _) in enumerate(use_all.chosen) if i != k):
            continue  # another change at its place sets the state of the rows before it
        at = float(a.features[0].at)
        last = int(np.searchsorted(t_rows, at))
        starts = [0.5 * (t_rows[i - 1] + t_rows[i]) for i in range(side, last - MIN_ROWS + 1)
                  if t_rows[i] > t_rows[i - 1]]
        if not starts:
            continue
        swapped = _swap_for_best(prob_all, use_all, k, [as_window(started_at(a, t0), at) for t0 in starts],
                                 {a.pool: 1, "change_window": 1}, alpha=alpha)
        if swapped is None:
            continue
        use_all, best, gain = swapped
        notes.append(f"a step ends a change the rows before it held: {best.atom.label} (the rows before its start in "
                     f"the state after the step: chi2 {gain:.1f} lower than the step alone, {len(starts)} starts tried)")
    return use_all, notes


def glitches(setup, prob_all: Problem, use_all: Fit, places: list[ChangePlace], every_place: list[ChangePlace], *,
             alpha: float, most: int = 3, z_min: float | None = None) -> tuple[Fit, list, list[str]]:
    """A change and back at one of ``places`` (a glitch: a joint's zero off for a few rows, an encoder's count lost
    and found again) anywhere in the campaign, on every row against the models to use: the window scan of
    :func:`twin.diagnosis.changes.scan_changes` (its rules: the rows in the window fitted by it to the scatter of the
    others, significant without any one of its rows, the residual it leaves white in time), significant after the
    window pool's Bonferroni factor over every row and ``every_place`` a change may take, its evidence measured
    against the scatter the rows outside it show along its place (:func:`place_scatter`), and better than the best
    step of any place (a window over most of the rows is the complement of a step). A glitch that is over predicts nothing of the later rows by
    itself: no later block can confirm it, and none is asked to; it takes the rows it holds out of the fit of
    everything else (a zero off on 40 rows pulls the joint's offset of a fit on every row by a fraction of it, and
    every later row with it). At most ``most``, strongest first, none at a place a kept change or joint term holds
    (a window there is that term's misfit on a few rows). Returns the
    fit with them, the windows (atom, calibration Delta chi2) and notes. ``places`` may hold a joint's compliance
    (its gravity-torque shapes: a payload hung on and taken off again); its window's scatter is measured on the
    model with it (the rows inside pull a fit on every row along the load's shapes, and the rows outside carry that
    pull), and only a kept change of that compliance excludes it. A window whose return leaves fewer of the campaign's
    last rows than it takes to locate and confirm a change there (``z_min``: :func:`_rows_after`) is kept only where
    it explains the rows better than the same change not ending, (Delta chi2_window - Delta chi2_step) / (e s2) >
    chi2_1^-1(1 - alpha), against the same scatter s2 (e: the problem's evidence scale): a load hung on late and kept
    on is not read as returning in the last rows."""
    sizes = change_pool_sizes(prob_all.obs_cal.n, every_place, short=MIN_ROWS)
    found, notes = [], []
    for _ in range(most):
        # a run of gross rows in time is a glitch's candidate too (a zero off by much on a few rows): the scan sees them,
        # and judges them as any window (one offset fitting every row of it to the floor)
        w_gross = prob_all.w_cal.copy()
        prob_all.w_cal = np.maximum(w_gross, gross_runs(setup, prob_all))
        cands = scan_changes(prob_all, use_all, every_place, windows=True, alpha=alpha, short=MIN_ROWS)
        # a place a kept change or a kept joint term holds is not a glitch's (a window there is that term's misfit)
        # (a joint's zero: a kept change or joint term there; a payload's window at a joint's compliance: a kept change
        # of that compliance, the load's own term being the state outside the window)
        kept = [a for a, _ in use_all.chosen if is_change(a) or a.place == "joint"]
        at = {(p.place, p.target, p.inner is None) for p in places}
        pick = None
        for a in cands:
            zero = isinstance(a.features[0], Window)
            if not is_window(a) or (a.place, a.target, zero) not in at:
                continue
            if any(is_step(c) for c in cands[:cands.index(a)]):
                continue  # a step explains more (a window over most of the rows is a step's complement): no return
            if any((c.place, c.target) == (a.place, a.target) and (zero or is_change(c)) for c in kept):
                continue
            got = score_atoms(prob_all, use_all, [a], sizes, exact_top=1)
            if not got:
                continue
            # the scatter the rows outside show: a payload's window measured against the model with it (the rows
            # inside pull a fit on every row along the load's shapes, and the rows outside then carry that pull)
            s2 = place_scatter(prob_all, use_all if zero else
                                refit_with(prob_all, use_all, list(use_all.chosen) + [(got[0].atom, got[0].basis)]), a)
            logp = chi2_logsf(got[0].dchi2 / prob_all.evidence_scale / s2, got[0].basis.shape[1]) \
                + np.log(sizes[a.pool])
            if logp < np.log(alpha) and z_min is not None:
                # a return held by too few of the campaign's last rows to locate and confirm it: kept only where it
                # explains every row better than the same change not ending (one constant more), against the scatter
                _, tv = row_times(setup.ctx)
                t_rows = np.sort(tv[prob_all.rows_cal])
                k_after = int(np.sum(t_rows >= float(a.features[0].until)))
                if k_after < _rows_after(len(t_rows), z_min)[1]:
                    st = score_atoms(prob_all, use_all, [as_step(a)], sizes, exact_top=1)
                    if st and (got[0].dchi2 - st[0].dchi2) / prob_all.evidence_scale / s2 <= chi2_isf(alpha, 1):
                        continue
            if logp < np.log(alpha):
                pick = got[0] if zero else _load_or_zero(prob_all, use_all, got[0], places, sizes, alpha)
                break
        if pick is None:
            prob_all.w_cal = w_gross
            break
        # fitted with the rows it holds (gross without it), whose weights the refit then sets anew
        chosen = list(use_all.chosen) + [(pick.atom, pick.basis)]
        use_all = refit_with(prob_all, use_all, chosen)
        found.append((pick.atom, float(pick.dchi2)))
        notes.append(f"a change and back on every row: {pick.atom.label} (p = {np.exp(pick.logp_adj):.2g} after the "
                     f"window pool's factor {sizes['change_window']})")
    return use_all, found, notes


def step_as_return(setup, prob_all: Problem, use_all: Fit, step, *, alpha: float) -> tuple[Fit, object, str]:
    """A kept step of a joint's zero (``step``, found after the rows that fit) read as the return of a change and back:
    the window of that zero ending at the step's start, from any row with ``MIN_ROWS`` rows before it and inside it,
    in place of the step where its ``Delta chi2`` (against ``use_all`` without the step, on ``prob_all``'s rows)
    exceeds the step's by more than ``chi2_1`` at ``alpha`` over the starts tried (one constant more: its start,
    chosen among them). A glitch whose start the rows that fit hold too few rows of to place and whose return comes
    after them is one window, not a step: the step leaves the rows before the glitch in the glitch's state. Returns
    the fit, the kept term and a note (empty: the step stands)."""
    if not (is_step(step) and step.place == "joint" and not isinstance(step.features[0], Gated)):
        return use_all, step, ""
    _, tv = row_times(setup.ctx)
    t_rows = np.sort(tv[prob_all.rows_cal])
    at = float(step.features[0].at)
    i_at = int(np.searchsorted(t_rows, at))
    starts = [0.5 * (t_rows[i - 1] + t_rows[i]) for i in range(MIN_ROWS, i_at - MIN_ROWS + 1)
              if t_rows[i] > t_rows[i - 1]]
    if not starts:
        return use_all, step, ""
    without = refit_with(prob_all, use_all, [c for c in use_all.chosen if c[0].key != step.key])
    sizes = {"change": 1, "change_window": len(starts)}
    wins = [as_window(started_at(step, t), at) for t in starts]
    got = score_atoms(prob_all, without, [step] + wins, sizes, exact_top=len(wins) + 1)
    by = {g.atom.key: g for g in got}
    if step.key not in by:
        return use_all, step, ""
    best = max((g for g in got if g.atom.key != step.key), key=lambda g: g.dchi2, default=None)
    if best is None or best.dchi2 - by[step.key].dchi2 <= prob_all.evidence_scale * chi2_isf(alpha / len(starts), 1):
        return use_all, step, ""
    trial = refit_with(prob_all, without, list(without.chosen) + [(best.atom, best.basis)])
    if common_chi2(use_all, trial) <= 0:
        return use_all, step, ""
    return trial, best.atom, (f"the step read as a change and back: {best.atom.label} (Delta chi2 {best.dchi2:.1f} "
                              f"against the step's {by[step.key].dchi2:.1f} on every row)")


def _load_or_zero(prob: Problem, fit: Fit, load: Scored, places: list[ChangePlace], sizes: dict,
                  alpha: float) -> Scored:
    """The window of a joint's compliance ``load`` (its gravity-torque shapes, ``r`` columns) or, in its place, the
    window of that joint's zero on the same rows: a load's shapes predict each row by its torque, a zero the same
    shift on every row of the window, and over rows whose torques barely differ the load's shapes fit a zero's shift,
    not identified. The zero's window is kept unless the load's explains more than ``chi2`` of its ``r - 1`` extra
    columns at ``alpha`` beyond it (both scored against ``fit`` on ``prob``'s calibration rows)."""
    zero_pl = [p for p in places if p.place == "joint" and p.target == load.atom.target and p.inner is None]
    extra = load.basis.shape[1] - 1
    if not zero_pl or extra < 1:
        return load
    f0 = load.atom.features[0]
    got = score_atoms(prob, fit, [as_window(change_at(zero_pl[0], f0.ch, float(f0.at)), float(f0.until))], sizes,
                      exact_top=1)
    if not got or load.dchi2 - got[0].dchi2 > prob.evidence_scale * chi2_isf(alpha, extra):
        return load
    return got[0]


def gross_runs(setup, prob: Problem) -> np.ndarray:
    """``(n,)`` 1 on the calibration rows at weight 0 as gross (not those a kept term lacks the history of) that are
    ``MIN_ROWS`` or more in a row in time order (a glitch's shortest window), else 0."""
    _, tv = row_times(setup.ctx)
    order = np.argsort(tv[prob.rows_cal], kind="stable")
    g = ((prob.w_cal == 0) & ~prob.history_out)[order]
    out = np.zeros(len(g))
    out[order] = runs_of_length(g, MIN_ROWS, len(g))
    return out


def _while_significant(prob: Problem, fit: Fit, cands: list, *, alpha: float) -> tuple[Fit, list]:
    """The strongest of ``cands`` joins ``fit`` while significant on ``prob``'s calibration rows after the factor of the
    candidates left (``chi2`` of its columns at ``alpha`` over their number); each one tried leaves the candidates.
    A term more nests the model: a refit that does not lower the rows' chi2 (counted on the rows both fits keep,
    :func:`~twin.diagnosis.problem.common_chi2`) failed (columns that cancel each other on a few rows, a refit that
    diverged), and the term does not join. Returns the fit and, per term added, ``(scored, p adjusted, candidates
    counted)``."""
    added = []
    while cands:
        got = score_atoms(prob, fit, cands, {a.pool: 1 for a in cands}, exact_top=len(cands))
        logp = [chi2_logsf(g.dchi2 / prob.evidence_scale, g.basis.shape[1]) + np.log(len(cands)) for g in got]
        if not got or min(logp) >= np.log(alpha):
            break
        k = int(np.argmin(logp))
        g = got[k]
        trial = refit_with(prob, fit, list(fit.chosen) + [(g.atom, g.basis)])
        if common_chi2(fit, trial) > 0:
            fit = trial
            added.append((g, float(np.exp(logp[k])), len(cands)))
        else:
            update_gross(prob, fit)
        cands = [a for a in cands if a.key != g.atom.key]
    return fit, added


def own_weight(prob_all: Problem, use_all: Fit, pool: list, *, alpha: float) -> tuple[Fit, list, list[str]]:
    """A joint whose compliance changes with a payload (a kept change of its gravity-torque shapes, a step or a
    window) carries the arm's own weight on every row through the same compliance
    (``q_j += c_j (tau_j,arm + L_i tau_j,payload)``): where the model has no compliance of that joint under the arm's
    own weight (the block that chose the terms rejected it while a payload it did not hold loaded the later rows),
    the catalogue's term joins on every row when significant there, after the factor of the joints tried (``chi2``
    of its rank at ``alpha``), strongest first. Returns the fit with them, the terms (atom, ``Delta chi2``) and
    notes."""
    loaded = {a.target for a, _ in use_all.chosen if is_load_change(a)}
    have = {a.target for a, _ in use_all.chosen if a.family == "compliance"}
    cands = [a for a in pool if a.family == "compliance" and a.target in loaded - have
             and a.channel == f"gravity torque of {a.target.replace('theta', 'joint ')}"]
    use_all, added = _while_significant(prob_all, use_all, cands, alpha=alpha)
    notes = [f"on every row, beside a payload's change of the same joint: {g.atom.label} (the arm's own weight on "
             f"every row; p = {p:.2g} after the factor {n} of the joints tried)" for g, p, n in added]
    return use_all, [(g.atom, float(g.dchi2)) for g, _, _ in added], notes


def payload_event(prob_all: Problem, use_all: Fit, places: list[ChangePlace], *,
                  alpha: float) -> tuple[Fit, list, list[str]]:
    """A payload hangs at the flange: hung on or taken off, it changes the gravity torque of every joint below it at
    once, each joint deflecting through its own compliance (``q_j += c_j L_i tau_j,payload``, ``L_i`` one timing for
    all). So every kept change of a joint's compliance (:func:`is_load_change`) is one event: first, the changes of
    one start take one end, the one (among their own ends, or none) that gives every row the lowest chi2 (a joint
    whose return the rows showed less clearly keeps the state the others show); then each other compliance place of
    ``places`` takes the same change (the same start and end, :func:`twin.diagnosis.changes.same_event`) when
    significant on every row after the factor of the places tried (``chi2`` of its rank at ``alpha``), strongest
    first. Last, a payload's steps whose state before them the rows read as the payload's (carried from the first row
    and taken off) become that window (:func:`_carried_from_start`). Returns the fit, the changes added (atom,
    ``Delta chi2``), notes and the windows that replaced kept steps (the step's key -> the window)."""
    notes: list[str] = []
    starts = sorted({float(a.features[0].at) for a, _ in use_all.chosen if is_load_change(a)})
    for at in starts:
        idx = [k for k, (a, _) in enumerate(use_all.chosen) if is_load_change(a) and float(a.features[0].at) == at]
        ends = list(dict.fromkeys(a.features[0].until for k, (a, _) in enumerate(use_all.chosen) if k in idx))
        if len(ends) < 2:
            continue
        best, moved = None, 0
        for e in ends:
            chosen = [(_with_end(c, e) if k in idx else c, B) for k, (c, B) in enumerate(use_all.chosen)]
            trial = refit_with(prob_all, use_all, chosen)
            if best is None or trial.chi2 < best.chi2:
                best, moved = trial, sum(use_all.chosen[k][0].features[0].until != e for k in idx)
        # one timing is a constraint (an end per change moved): kept where every row's chi2 rises by less than chi2 at
        # alpha of the ends it moves; the rows reject it beyond (the changes are not one event)
        if not -common_chi2(use_all, best) < prob_all.evidence_scale * chi2_isf(alpha, max(1, moved)):
            update_gross(prob_all, use_all)
            notes.append(f"not one timing: the changes of the joints' compliance from {at:.6g} keep their own ends "
                         f"(one end: chi2 {best.chi2:.1f} against {use_all.chi2:.1f})")
            continue
        use_all = best
        notes.append(f"one payload, one timing: the changes of the joints' compliance from {at:.6g} take one end "
                     f"({[a.label for k, (a, _) in enumerate(use_all.chosen) if k in idx][0]}; {len(ends)} ends "
                     "compared on every row)")
    events = {(float(a.features[0].at), a.features[0].until): a for a, _ in use_all.chosen if is_load_change(a)}
    held = {(a.target, float(a.features[0].at), a.features[0].until) for a, _ in use_all.chosen if is_load_change(a)}
    cands = [c for a in events.values() for c in same_event(a, places)
             if (c.target, float(c.features[0].at), c.features[0].until) not in held]
    use_all, added = _while_significant(prob_all, use_all, cands, alpha=alpha)
    notes += [f"the same payload at another joint: {g.atom.label} (one event loads every joint below the flange; "
              f"p = {p:.2g} on every row after the factor {n} of the places tried)" for g, p, n in added]
    use_all, renamed, flipped = _carried_from_start(prob_all, use_all, alpha=alpha)
    notes += flipped
    return use_all, [(renamed.get(g.atom.key, g.atom), float(g.dchi2)) for g, _, _ in added], notes, renamed


def _carried_from_start(prob_all: Problem, use_all: Fit, *, alpha: float) -> tuple[Fit, dict, list[str]]:
    """A payload's change from a row on (kept steps of the joints' compliance with one start) is a payload hung on
    there, or one carried from the campaign's first row and taken off there: the same columns on the other side of
    the start (a window from the first row until it). Without the payload's state on every row (the arm's own weight
    holds the joints there), the side that carries the payload's shapes is the one the rows say: the window replaces
    the steps where it fits every row better by more than ``chi2_1`` at ``alpha`` (as many constants, compared on the
    same rows' weights; where the joint's other terms span the payload's shapes, both read alike and the step
    stays). The rows after the campaign and a new session then read the state after the change: the payload off.
    Returns the fit, the windows that replaced steps (the step's key -> the window) and notes."""
    renamed: dict = {}
    _, tv = row_times(prob_all.ctx)
    t_first = float(np.min(tv[prob_all.rows_cal]))
    notes = []
    P = prob_all.prep.space.size
    starts = sorted({float(a.features[0].at) for a, _ in use_all.chosen if is_load_change(a) and is_step(a)})
    for at in starts:
        idx = [k for k, (a, _) in enumerate(use_all.chosen)
               if is_load_change(a) and is_step(a) and float(a.features[0].at) == at]
        chosen = [(as_window(started_at(c, t_first), at) if k in idx else c, B)
                  for k, (c, B) in enumerate(use_all.chosen)]
        trial = prob_all.fit(use_all.z[:P], chosen, psi_init(use_all, chosen))
        if trial.chi2 < use_all.chi2 - prob_all.evidence_scale * chi2_isf(alpha, 1):
            notes.append(f"a payload carried from the first row and taken off at {at:.6g}, not hung on there: "
                         f"{[c.label for k, (c, _) in enumerate(chosen) if k in idx][0]} (chi2 {trial.chi2:.1f} "
                         f"against {use_all.chi2:.1f} as a step)")
            renamed.update({use_all.chosen[k][0].key: chosen[k][0] for k in idx})
            use_all = refit_with(prob_all, use_all, chosen)
    return use_all, renamed, notes


def _with_end(atom, until):
    """The change ``atom`` ending at ``until`` (None: without an end, a step)."""
    if atom.features[0].until == until:
        return atom
    return as_step(atom) if until is None else as_window(atom, until)


def payload_at(prob_all: Problem, use_all: Fit, onset, places: list[ChangePlace], *,
               alpha: float) -> tuple[Fit, list] | None:
    """A payload's event read where the rows after the rows that fit show a change of the air that no temperature
    record times (``onset``: a thermal term of an onset, :func:`~twin.diagnosis.refine.is_onset`, with its step or
    ramp and the links' lag): the change of a joint's compliance (under the arm's own weight or a payload's,
    :func:`is_load_change`) from a row between ``EVENT_ROWS`` rows before the air's change and ``EVENT_ROWS`` rows
    after its ramp and lag, the strongest on every row, with the same change at every other loaded joint while
    significant there (:func:`payload_event`'s rule). Both read a change of the arm in the campaign's last part; the
    caller keeps the one that explains every row better. Returns the fit with the event and its terms (atom,
    ``Delta chi2``), None when no such change takes a column."""
    ch, tv = row_times(prob_all.ctx)
    if ch != "t_s":
        return None
    f0 = onset.features[0]
    t_rows = np.sort(tv[prob_all.rows_cal])
    lo = max(int(np.searchsorted(t_rows, float(f0.t0))) - EVENT_ROWS, 1)
    hi = int(np.searchsorted(t_rows, float(f0.t0) + float(f0.ramp or 0.0) + float(f0.tau))) + EVENT_ROWS
    loads = [pl for pl in places if pl.place == "joint" and pl.inner is not None]
    cands = [change_at(pl, ch, float(t)) for t in t_rows[lo:hi + 1] for pl in loads]
    if not cands:
        return None
    sizes = {a.pool: 1 for a in cands}
    got = score_atoms(prob_all, use_all, cands, sizes, exact_top=len(cands))
    if not got:
        return None
    lead = max(got, key=lambda g: g.dchi2)
    fit = refit_with(prob_all, use_all, list(use_all.chosen) + [(lead.atom, lead.basis)])
    fit, added = _while_significant(prob_all, fit, same_event(lead.atom, places), alpha=alpha)
    return fit, [(lead.atom, float(lead.dchi2))] + [(g.atom, float(g.dchi2)) for g, _, _ in added]
