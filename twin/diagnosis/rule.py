"""The selection rule of the diagnosis: which terms enter the extended model, in which order, and whether the
extended model replaces the geometric one.

One round (:func:`selection_round`) scores the remaining atoms on the calibration rows (:mod:`twin.diagnosis.scoring`),
takes the best whose evidence passes the threshold of its pool, and keeps it only if it predicts the confirmation
block (a block of time after every calibration row, or another session); :func:`select_terms` repeats rounds,
then swaps a term for a named alternative that explains as much (:func:`_swap_term`, :func:`_named_shapes`),
keeps fewer families where they do as well (:func:`_fewer_families`), keeps no term of another family beside a
named one unless it predicts the confirmation block beyond the family's own shapes (:func:`_no_extra_family`) and
refuses terms of implausible size (:func:`implausible_size`: ``JOINT_MAX``, ``LOAD_MAX``, ``THERMAL_MAX``); where
every candidate of a round fails on the held-out rows, the first term of the arm's load among them is kept with the
change of a joint's compliance its rows hold when each is confirmed given the other
(:func:`twin.diagnosis.pairs.with_change`). :mod:`twin.diagnosis.verdict` states the verdict and whether the
extended model is the model to use. The procedure around it is :mod:`twin.diagnosis.diagnose`; the steps it calls are
in :mod:`twin.diagnosis.scoring`, :mod:`~twin.diagnosis.ordering`, :mod:`~twin.diagnosis.confirm` and
:mod:`~twin.diagnosis.refine`."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from ..estimator.distributions import chi2_isf
from ..units import RAD_PER_DEG
from .atoms import Atom, is_load_change, is_load_term
from .changes import (STRUCTURED_OUTSIDE, change_places, is_change, is_step, is_window, row_times, same_event,
                      scan_changes, selection_short, window_wander)
from .features import BaseMoment, Cos, Heat, Lag, LoadSign, Moment, Play, Pow, Sin, Torque
from .loads import (along_link_weight, fitted_load, link_tilt_atom, load_alternatives, load_candidates, own_link_atom,
                    reads_its_load, refine_load_sign, stiffening_atoms, tilt_angles)
from .confirm import confirm, confirm_configurations, time_only
from .harmonics import with_second_order
from .late import as_event
from .pairs import with_change
from .ordering import alternatives, distinct_terms, order_candidates, payload_rivals, rival_readings, slot
from .problem import Fit, Problem, common_chi2, covariance, held_out_rms, psi_init, refit_with, update_gross
from .pools import heat_alternatives
from .refine import (ONSET_TAUS, bend_unseen, follows_the_air, is_onset, polish_in_fit, prefer_heat, prefer_play,
                     prefer_sign, recorded_lag, refine, refine_gap, refine_time, retimeable, widen)
from .scoring import Scored, score_atoms
from .structure import chi2_logsf, signed_rank_z

__all__ = [
    "CandidateScore",
    "Selection",
    "Round",
    "selection_round",
    "select_terms",
    "implausible_size",
    "backward",
    "retime",
]



LAG_SIGMA = 1.0  # chi2 rise of one standard error of one constant (the recorded lag's, rule.retime)
JOINT_MAX = 0.5 * RAD_PER_DEG  # [rad] largest joint error a named mechanism (backlash, cyclic, compliance, ...) makes
# on the 6R industrial arms (cycloidal and harmonic drives)
# [rad] the same for any other chain (a URDF's: service and mobile manipulators whose wrist and belt stages show up
# to a degree of play; set after the TIAGo wrist's 0.63 deg backlash, confirmed on its other day, exceeded 0.5 deg)
JOINT_MAX_CHAIN = 1.0 * RAD_PER_DEG
# [rad] largest variation over the rows of a deflection under a known load (compliance or a support's tilt under the
# chain's own weight, from its mass properties): 17 mm at 1 m, visible by eye
LOAD_MAX = 1.0 * RAD_PER_DEG
SPAN_TOL = 1e-6  # [relative] a term's columns within this of another's span: the rows cannot tell the two apart
THERMAL_MAX = 1e-3  # [relative] largest thermal growth over a campaign: 43 K of aluminium (23 ppm/K)


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
    z_configurations: float = float("nan")  # [configurations] the check between the sampled values (nan: not made)


@dataclass
class Selection:
    """The outcome of :func:`select_terms`: the extended fit (its ``chosen`` atoms), every candidate scored, the
    alternatives of the kept terms, each kept term's calibration ``Delta chi2`` when it entered, and notes."""

    fit: Fit
    scores: list[CandidateScore] = field(default_factory=list)
    alternatives: list[dict] = field(default_factory=list)
    entry_chi2: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def _heat(atom: Atom) -> bool:
    """Whether ``atom`` is a thermal term of the motors' heat (:class:`~twin.diagnosis.features.Heat` features)."""
    return atom.family == "thermal" and any(isinstance(f, Heat) for f in atom.features)


def _recorded_reading(atom: Atom, scored: list[Scored]) -> list[Atom]:
    """The scored thermal atom of ``atom``'s links against the recorded temperature through a lag (the most significant
    on the grid; none without a record): a link's temperature that follows the air's records what the motors' heat,
    a constructed channel with a warm-up beside it, would only imitate by its smooth rise."""
    lagged = [c for c in scored if c.atom.family == "thermal" and c.atom.target == atom.target
              and len(c.atom.features) == 1 and isinstance(c.atom.features[0], Lag) and c.atom.features[0].ch == "temp_c"]
    return [min(lagged, key=lambda c: c.logp_adj).atom] if lagged else []


@dataclass
class Round:
    """One forward round: the accepted candidate (or None), the candidates tried with their decisions, every
    atom scored, the keys rejected, whether a named atom was rejected for an unphysical size, and the tries that
    failed on the held-out rows (each as tried: atoms of one label, a load-signed backlash's directions, differ)."""

    accepted: Scored | None
    scores: list[CandidateScore]
    scored: list[Scored]
    rejected: list[str]
    unphysical: bool
    failed: list[Scored] = field(default_factory=list)


def selection_round(prob: Problem, fit: Fit, remaining: list[Atom], sizes: dict[str, int], rnd: int, *,
                    alpha_select: float, z_min: float, tries: int = 3, lead: frozenset = frozenset(),
                    callback: Callable[[CandidateScore], None] | None = None) -> Round:
    """One forward round: score the remaining atoms against ``fit`` (a sign backlash competing as the play
    operator when that explains significantly more), order them (:func:`order_candidates`), and try up to
    ``tries`` in that order: the first that is significant on the calibration rows, confirmed on the
    confirmation rows and of a physical size is accepted (a window the wander test turns down where the rows
    outside it hold a change the model lacks, :func:`twin.diagnosis.changes.window_wander`, sends the round on to
    the next ``tries`` significant changes and no other term; one turned down against a wander of the cell ends the
    round as any candidate not significant does); then the strongest of each pool none of those came from.
    The significant atoms whose keys are in ``lead`` (the same payload's change at another joint) are tried first;
    where every try failed, a payload's change at the joints the tries did not change (:func:`payload_rivals`)."""
    scored = prefer_sign(prob, fit, prefer_play(prob, fit, score_atoms(prob, fit, remaining, sizes), sizes), sizes)
    out = Round(None, [], scored, [], False)
    if not scored:
        return out
    order, same = distinct_terms(prob, order_candidates(scored))
    led = [s for s in order if s.atom.key in lead and s.logp_adj < np.log(alpha_select)]
    order = led + [s for s in order if s not in led]
    first = rival_readings(order, order[:len(led) + tries], np.log(alpha_select))
    # then the strongest of each pool none of the first came from: a family of broad terms (the cell's oscillations
    # in time, which follow any stretch of the campaign on the rows that fit) must not keep a named term or a change
    # from being tried at all
    seen = {c.atom.pool for c in first}
    more = []
    for c in order[tries:]:
        if c.atom.pool not in seen and c.logp_adj < np.log(alpha_select):
            seen.add(c.atom.pool)
            more.append(c)
    queue = first + more
    n_first = len(first)
    for k, s in enumerate(queue):
        if k == len(queue) - 1:
            # every try failed so far: the payload's change at the joints none of them changes (ordering.payload_rivals)
            queue += payload_rivals(order, queue, np.log(alpha_select))
        alike = same.get(s.atom.key, [])
        logp_adj = s.logp_adj
        structured_outside = False
        if is_window(s.atom) and logp_adj < np.log(alpha_select):
            # a change and back measured against the scatter the rows outside it show along its place (a wander)
            logp_w, outside_ms = window_wander(prob, fit, s, sizes)
            logp_adj = min(0.0, max(logp_adj, logp_w))
            structured_outside = outside_ms > STRUCTURED_OUTSIDE
        if logp_adj >= np.log(alpha_select):
            out.scores.append(CandidateScore(rnd, s.atom.label, s.basis.shape[1], s.dchi2, float(np.exp(logp_adj)),
                                             float("nan"), "not significant on the calibration rows"))
            if structured_outside:
                # a window turned down against rows outside it that hold a change the model lacks (not a wander):
                # the round goes on to that change, the significant changes in the order not yet tried (as its
                # first tries), and to no other term
                del queue[k + 1:]
                queue += [c for c in order if is_change(c.atom) and c not in queue
                          and c.logp_adj < np.log(alpha_select)][:tries]
                n_first = len(queue)
                continue
            if k < n_first:
                break
            continue
        if retimeable(s.atom):
            # a thermal term's time constants (the air's onset and ramp, the links' lag, the motors' heat) are the
            # effect's, not the grid's: judged at their best values (an onset's evidence then pays for the onsets,
            # ramps and lags tried: refine_onset)
            # the motors' heat: the joints whose travel heats the links chosen at the best time constant of each
            # and a recorded temperature's lag is the heat's rival on the same links: each at its best time constant
            s = prefer_heat(prob, fit, s, heat_alternatives(prob.ctx, s.atom) + _recorded_reading(s.atom, scored),
                            sizes) if _heat(s.atom) else refine(prob, fit, s, sizes)
            if is_onset(s.atom) and s.logp_adj >= np.log(alpha_select):
                out.scores.append(CandidateScore(rnd, s.atom.label, s.basis.shape[1], s.dchi2,
                                                 float(np.exp(s.logp_adj)), float("nan"),
                                                 "not significant on the calibration rows after the onsets tried"))
                out.rejected += [s.atom.key] + alike
                continue
        c = confirm(prob, fit, s, z_min)
        if c.local and time_only(s.atom) and not is_onset(s.atom):
            # a term of time is judged against the nearest rows in time at its best constant (a step's time, a
            # period), not at the coarse grid value it was found at: a slip between two grid times is a step
            refined = refine(prob, fit, s, sizes)
            if refined is not s:
                c_refined = confirm(prob, fit, refined, z_min)
                if not c_refined.local:
                    s, c = refined, c_refined
        if c.z > z_min and c.z_without_best_row > z_min and not (c.better or c.local) and with_second_order(
                prob, fit, s, remaining, sizes, alpha=alpha_select):
            c = replace(c, better=True)  # a harmonic whose joint holds a second order: judged with it
        implausible = _implausible(prob, s)
        ok = c.holds(z_min) and implausible is None
        # [configurations] a term of joint angles also holds between the sampled values (folds of them left out)
        cc = confirm_configurations(prob, fit, s, scored, sizes) if ok else None
        held_in_time, ok = ok, ok and (cc is None or cc.passed)
        # failed on the held-out rows: z, z without the best row, or the error there (not a wander, not its size)
        held_out_failed = not (c.z > z_min and c.z_without_best_row > z_min and c.better)
        sc = CandidateScore(rnd, s.atom.label, s.basis.shape[1], s.dchi2, float(np.exp(logp_adj)), c.z,
                            "kept" if ok else cc.decision if held_in_time else
                            ("not confirmed on held-out rows" if not (c.z > z_min) else
                             "held-out gain rests on one row" if not (c.z_without_best_row > z_min) else
                             "held-out error not reduced" if held_out_failed else
                             "the nearest rows in time predict the held-out rows as well (a wander, "
                             "not a term of time)" if c.local else implausible),
                            float("nan") if cc is None else cc.z)
        out.scores.append(sc)
        if held_out_failed:
            out.failed.append(s)
        if callback:
            callback(sc)
        if ok:
            out.accepted = s
            break
        out.rejected += [s.atom.key] + alike
        out.unphysical |= implausible is not None
    return out


def select_terms(prob: Problem, fit: Fit, pool: list[Atom], sizes: dict[str, int], *, max_effects: int = 16,
                 alpha_select: float = 0.01, z_min: float = 3.0,
                 callback: Callable[[CandidateScore], None] | None = None) -> Selection:
    """Step 4: forward rounds (:func:`selection_round`) from the geometric ``fit``: an accepted atom is refined
    (its continuous constant), widened (its further directions when they add evidence), added and the model
    refitted; a round whose every try failed on the held-out rows keeps the first term of the arm's load among them
    with the change of a joint's compliance its rows hold where each is confirmed given the other
    (:func:`twin.diagnosis.pairs.with_change`; the change is the next round's); then the backward pass, the
    catalogue's shapes of one joint variable (:func:`_named_shapes`), fewer families (:func:`_fewer_families`) and no
    extra term beside a named family (:func:`_no_extra_family`)."""
    sel = Selection(fit)
    chosen: list = []
    rejected: set[str] = set()
    taken: set[str] = set()
    rnd, kept = 0, 0
    P = prob.prep.space.size
    places = change_places(prob.prep.nominal, [a for a in pool if a.pool == "catalogue"], prob.ctx.q) \
        if "change" in sizes else []
    pending: Atom | None = None  # a change kept with the last round's term (pairs.with_change), added this round
    while kept < max_effects and rnd < 4 * max_effects:
        rnd += 1
        remaining = [a for a in pool if a.key not in rejected and slot(a) not in taken]
        lead: dict[str, Atom] = {}
        forced = None
        if pending is not None:
            got = score_atoms(prob, fit, [pending], sizes)
            forced = Round(got[0] if got else None, [CandidateScore(
                rnd, g.atom.label, g.basis.shape[1], g.dchi2, float(np.exp(g.logp_adj)), float("nan"),
                "kept with the term before it (each confirmed given the other)") for g in got], got, [], False)
            pending = None
        elif places:
            # the best row of every place for a change, against the current fit (changes.scan_changes; windows from
            # MIN_ROWS rows where the grid is fine, changes.selection_short: a glitch of a few rows read by a window
            # of more takes a load's shapes to fit the extra row)
            remaining += [a for a in scan_changes(prob, fit, places, short=selection_short(prob.obs_cal.n))
                          if a.key not in rejected and slot(a) not in taken]
            # a payload's change kept: the same change (its start and end) at every other joint's compliance is tried
            # first (one event loads every joint below the flange at once: its timing is the kept change's)
            lead = {c.key: c for a, _ in chosen if is_load_change(a) for c in same_event(a, places)
                    if c.key not in rejected and slot(c) not in taken}
            have = {a.key for a in remaining}
            remaining += [c for k, c in lead.items() if k not in have]
        r = forced or selection_round(prob, fit, remaining, sizes, rnd, alpha_select=alpha_select, z_min=z_min,
                                      lead=frozenset(lead), callback=callback)
        sel.scores += r.scores
        rejected.update(r.rejected)
        if r.accepted is None and r.unphysical:
            continue  # named atoms of an unphysical size are out: the next round scores the rest
        if r.accepted is None:
            # every try failed on the held-out rows: a load term of them with the load's change (pairs)
            pair = with_change(prob, fit, r.failed, places, sizes, alpha_select=alpha_select, z_min=z_min,
                               admit=lambda a: a.key not in rejected and slot(a) not in taken) if places else None
            if pair is None:
                break
            term = pair.term
            sc = CandidateScore(rnd, term.atom.label, term.basis.shape[1], term.dchi2, float(np.exp(term.logp_adj)),
                                pair.z_term, f"kept with a change its rows hold (each confirmed given the other, z "
                                             f"{pair.z_term:.2f} and {pair.z_change:.2f})")
            sel.scores.append(sc)
            if callback:
                callback(sc)
            r, pending = replace(r, accepted=term), pair.change
        accepted = r.accepted
        if places and accepted.atom.place == "joint" and is_step(accepted.atom) and not is_load_change(accepted.atom):
            # a step of a joint's zero where a payload's change at that joint (with the same change at every loaded
            # joint) explains more than its extra columns: one event, a payload hung on or taken off (late.as_event)
            event, note = as_event(prob, fit, accepted, [a for a in remaining if is_change(a)], places, sizes,
                                   np.sort(row_times(prob.ctx)[1][prob.rows_cal]), alpha=alpha_select)
            if note and _admitted(prob, fit, event, z_min):
                sel.notes.append(f"{accepted.atom.label}{note}")
                taken.add(slot(accepted.atom))
                accepted = event
        taken.add(slot(accepted.atom))  # the grid value it was found at is taken with it
        refined = refine_load_sign(prob, fit, accepted if retimeable(accepted.atom) else refine(prob, fit, accepted, sizes),
                                   sizes)
        accepted = widen(prob, fit, refined if _implausible(prob, refined) is None else accepted, alpha_select)
        taken.add(slot(accepted.atom))
        kept += 1
        sel.alternatives += alternatives(accepted, r.scored)
        chosen.append((accepted.atom, accepted.basis))
        sel.entry_chi2[accepted.atom.key] = accepted.dchi2
        fit = prob.fit(fit.z[:P], chosen, psi_init(fit, chosen))
        update_gross(prob, fit)
        if accepted.atom.family == "compliance":
            # a linear compliance of unknown masses fitted its torque: its stiffening with that torque joins the pool
            load = fitted_load(fit, int(accepted.atom.target[5:]))
            if load is not None:
                have = {a.key for a in pool}
                pool = pool + [a for a in stiffening_atoms(prob.prep.nominal, prob.ctx, int(accepted.atom.target[5:]),
                                                           load) if a.key not in have]
        if any(isinstance(f, Play) for f in accepted.atom.features):
            # a clearance is placed on the whole model refitted (the linearised evidence is biased by its size),
            # under the gross rows of that model (the rows before its joint first moves, whose side of the clearance
            # is unknown, are left out of the fit: update_gross)
            fit = polish_in_fit(prob, fit, len(chosen) - 1, "h")
            chosen = list(fit.chosen)
            update_gross(prob, fit)
    if chosen:
        fit, dropped = backward(prob, fit, alpha_select, sizes)
        for a in dropped:
            sel.notes.append(f"dropped in the backward pass (redundant once the others are in): {a.label}")
        fit, swapped, alts = _named_shapes(prob, fit, pool, sizes, alpha_select)
        sel.notes += swapped
        fit, merged, alts2 = _fewer_families(prob, fit, pool, sizes, alpha_select, z_min)
        sel.notes += merged
        fit, loaded, alts4 = _load_for_harmonics(prob, fit, pool, sizes, alpha_select, z_min)
        sel.notes += loaded
        fit, lawed, alts3 = _no_extra_family(prob, fit, pool, sizes, alpha_select, z_min)
        sel.notes += lawed
        alts = alts + alts2 + alts4 + alts3 + load_alternatives(prob, fit, pool, sizes, alpha_select)
        sel.alternatives = [d for d in sel.alternatives if d["of"] in {a.label for a, _ in fit.chosen}] + alts
        update_gross(prob, fit)
        fit = prob.fit(fit.z[:P], fit.chosen, psi_init(fit, fit.chosen))
    sel.fit = fit
    return sel


def backward(prob: Problem, fit: Fit, alpha_select: float, sizes: dict) -> tuple[Fit, list[Atom]]:
    """Drop atoms whose removal costs no significant calibration evidence (one pass, weakest first)."""
    dropped: list[Atom] = []
    changed = True
    while changed and len(fit.chosen) > 1:
        changed = False
        rc = fit.model_cal.residuals(fit.z)
        sw = np.sqrt(prob.w_cal[rc.row])
        C = covariance(rc.J[:, fit.free] * sw[:, None])
        pos = {int(f): k for k, f in enumerate(fit.free)}
        worst = None
        for k, (a, B) in enumerate(fit.chosen):
            idx = [pos[i] for i in range(fit.model_cal.offsets[k], fit.model_cal.offsets[k + 1])]
            psi = fit.z[fit.model_cal.offsets[k]:fit.model_cal.offsets[k + 1]]
            Ck = C[np.ix_(idx, idx)]
            d = float(psi @ np.linalg.lstsq(Ck, psi, rcond=None)[0])  # chi2 cost of removing it (Wald)
            lp = chi2_logsf(d / prob.evidence_scale, len(idx)) + np.log(sizes[a.pool])
            if lp >= np.log(alpha_select) and (worst is None or lp > worst[0]):
                worst = (lp, k)
        if worst is not None:
            k = worst[1]
            dropped.append(fit.chosen[k][0])
            chosen = [c for i, c in enumerate(fit.chosen) if i != k]
            fit = prob.fit(fit.z[: prob.prep.space.size], chosen, psi_init(fit, chosen))
            changed = True
    return fit, dropped


def implausible_size(prob: Problem, atom: Atom, phi: np.ndarray) -> str | None:
    """Why the named ``atom`` with the values ``phi`` ``(K,)`` (SI per unit of its features) has a size that is not
    physical for its family (:func:`_implausible`'s rules), or None."""
    from types import SimpleNamespace

    phi = np.asarray(phi, dtype=float)
    return _implausible(prob, SimpleNamespace(atom=atom, basis=np.eye(phi.size), psi=phi))


def _implausible(prob: Problem, s) -> str | None:
    """Why a named (catalogue) atom's fitted size is not physical for its family, or None: thermal growth of more
    than ``THERMAL_MAX`` over the rows (a short link's huge growth stands for something else: on a blind
    campaign 3,500 ppm of a4 took the place of a joint offset jumping at restarts), a joint error beyond
    ``JOINT_MAX`` (``JOINT_MAX_CHAIN`` on a ``"urdf"`` chain), a deflection under the chain's own weight varying by
    more than ``LOAD_MAX``. Unnamed atoms make no physical claim and are not checked."""
    a = s.atom
    if a.pool == "generic" or is_change(a):
        return None  # a change of the robot or the cell has no physical bound of a mechanism
    if any(isinstance(f, (Torque, Moment, BaseMoment)) for f in a.features):
        # a deflection under the load the chain's masses give: its variation over the rows (the constant part is
        # the geometry's), per axis for a tilt
        F = prob.features(a)[prob.rows_cal]
        phi = s.basis @ s.psi
        eff = tilt_angles(a.features, F, phi) if a.place == "param" else (F @ phi)[:, None]
        dev = float(np.max(np.abs(eff - eff.mean(axis=0)))) if eff.size else 0.0
        if dev > LOAD_MAX:
            return (f"implausible for {a.family} under the chain's own weight: {dev / RAD_PER_DEG:.3f} deg of variation over the "
                    f"rows (more than {LOAD_MAX / RAD_PER_DEG:.1f} deg)")
        return None
    eff = prob.features(a)[prob.rows_cal] @ (s.basis @ s.psi) if a.place in ("length", "joint") else None
    if eff is None or eff.size == 0:
        return None
    if a.place == "length" and float(np.ptp(eff)) > THERMAL_MAX:
        return (f"implausible for thermal growth: {np.ptp(eff) * 1e6:.0f} ppm over the rows (more than "
                f"{THERMAL_MAX * 1e6:.0f} ppm, 43 K of aluminium)")
    if a.place == "length" and is_onset(a) and float(np.sum(np.abs(s.basis @ s.psi))) > THERMAL_MAX:
        # the air's change settles to its full size after the rows: the size it settles to
        return (f"implausible for thermal growth: {np.sum(np.abs(s.basis @ s.psi)) * 1e6:.0f} ppm once the air's change "
                f"has settled (more than {THERMAL_MAX * 1e6:.0f} ppm, 43 K of aluminium)")
    cap = JOINT_MAX if prob.prep.nominal.convention != "urdf" else JOINT_MAX_CHAIN
    if a.place == "joint" and float(np.max(np.abs(eff))) > cap:
        return f"implausible for {a.family}: {np.max(np.abs(eff)) / RAD_PER_DEG:.3f} deg (more than {cap / RAD_PER_DEG:.1f} deg)"
    return None


def _single_joint_variable(a: Atom) -> str | None:
    """The one joint variable (``"q4"``) a joint atom's features are functions of (pow/sin/cos), else None."""
    if a.place != "joint" or not all(isinstance(f, (Pow, Sin, Cos)) for f in a.features):
        return None
    chans = {f.ch for f in a.features}  # pow/sin/cos features name one channel each
    ch = chans.pop() if len(chans) == 1 else ""
    return ch if ch.startswith("q") else None


def _swap_term(prob: Problem, fit: Fit, a: Atom, cands: list[Atom], sizes: dict, alpha_select: float,
               admit: Callable[[Fit, Scored], bool] | None = None) -> tuple[Fit, float, float] | None:
    """The model ``fit`` with its term ``a`` replaced by the candidates ``cands`` that are significant on the fit
    without it (``logp_adj < alpha_select``) and pass ``admit(fit_without_a, scored)``, refitted and through the
    backward pass: ``(alternative, e_alt, e_now)`` with the confirmation rows' position RMS [mm] of the
    alternative and of ``fit``; None when no candidate enters."""
    if not cands:
        return None
    P = prob.prep.space.size
    keep = [(c, B) for c, B in fit.chosen if c is not a]
    base = prob.fit(fit.z[:P], keep, psi_init(fit, keep))
    scored = score_atoms(prob, base, cands, sizes, exact_top=len(cands))
    new = [(sc.atom, sc.basis) for sc in scored
           if sc.logp_adj < np.log(alpha_select) and (admit is None or admit(base, sc))]
    if not new:
        return None
    alt = prob.fit(base.z[:P], keep + new, psi_init(base, keep + new))
    alt, _ = backward(prob, alt, alpha_select, sizes)
    e_alt = held_out_rms(prob, alt)
    e_now = held_out_rms(prob, fit)
    return alt, e_alt, e_now


def _swap_load(prob: Problem, fit: Fit, a: Atom, pool: list[Atom], targets: set[str], sizes: dict,
               alpha_select: float, z_min: float, *, bare: bool = False) -> tuple[Fit, float, float] | None:
    """The model ``fit`` with its term ``a`` replaced by the load family of the joints ``targets``
    (:func:`twin.diagnosis.loads.load_candidates`), grown by the forward pass' rules, at most two terms (a support
    tilts about two axes), its linear terms first (:func:`_grow_own`), and through the backward pass: ``(alternative,
    e_alt, e_now)`` with the confirmation rows' position RMS [mm] of the alternative and of ``fit``; None when no term of the family enters, unless ``bare``
    (then the alternative is ``fit`` without ``a``: the family's terms it holds read the load alone)."""
    P = prob.prep.space.size
    keep = [(c, B) for c, B in fit.chosen if c is not a]
    base = prob.fit(fit.z[:P], keep, psi_init(fit, keep))
    cur = _grow_own(prob, base, lambda f, have: load_candidates(prob, f, pool, targets, have), sizes, alpha_select,
                    z_min, 2, linear_first=True)
    if len(cur.chosen) == len(keep) and not bare:
        return None
    alt, _ = backward(prob, cur, alpha_select, sizes)
    e_alt = held_out_rms(prob, alt)
    e_now = held_out_rms(prob, fit)
    return alt, e_alt, e_now


def _own_variables(a: Atom) -> set[str]:
    """The joint variables of an unnamed term of a joint's angle in joint variables only, its own among them."""
    chans = {c for f in a.features for c in np.atleast_1d(getattr(f, "ch", None)).tolist()}
    ok = a.place == "joint" and all(isinstance(c, str) and c.startswith("q") for c in chans)
    return chans if ok and "q" + a.target[5:] in chans else set()


def _named_shapes(prob: Problem, fit: Fit, pool: list[Atom], sizes: dict,
                  alpha_select: float) -> tuple[Fit, list[str], list[dict]]:
    """Where the greedy forward pass built a function of one joint variable at a joint from an unnamed term and
    named ones (a quadratic before the harmonics it stands for), try the catalogue's shapes of that variable
    alone (harmonics 1-3, the gear ratio, the scanned orders already kept) in place of the unnamed term: when
    they predict the confirmation rows as well (within 2 %) with no more parameters at that joint than the unnamed
    shape and the named terms kept with it, the named explanation is kept, and the unnamed shape it
    replaced is reported as the alternative the data cannot tell from it (over a joint's range a few harmonics
    follow any smooth shape: the name is the simpler reading, not a proof). An unnamed term of a joint's angle in
    its own variable (with another joint's, or alone) and no named one beside it: the gear ratio and the wrist
    couplings of those variables at that joint, on the same terms (a ratio error beside another effect is read by a
    product that takes a little of both). Returns the fit, notes and those alternatives."""
    notes: list[str] = []
    alts: list[dict] = []
    for a, _ in list(fit.chosen):
        var = _single_joint_variable(a)
        if a.pool != "generic" or a not in [c for c, _ in fit.chosen]:
            continue
        target = a.target
        named_here = var is not None and any(
            c.pool != "generic" and c.target == target and _single_joint_variable(c) == var for c, _ in fit.chosen)
        # a shape of one variable beside a named term of it: every catalogue shape of that variable; otherwise a term
        # in its own joint's variable: the ratio and the couplings of its variables
        own = set() if named_here else _own_variables(a)
        if not named_here and not own:
            continue
        scope = own or {var}
        have = {c.key for c, _ in fit.chosen if c is not a}
        cands = [c for c in pool if c.pool == "catalogue" and c.target == target and _single_joint_variable(c) in scope
                 and c.key not in have and (not own or c.family in ("gear_ratio", "coupling"))]
        swap = _swap_term(prob, fit, a, cands, sizes, alpha_select)
        if swap is None:
            continue
        alt, e_alt, e_now = swap
        # no more parameters at that joint than the unnamed shape and the named ones kept with it (a one-sided
        # pull past an angle is a quadratic; three harmonics follow it as well with twice the parameters)
        n_now = sum(B.shape[1] for c, B in fit.chosen
                    if c.target == target and (_single_joint_variable(c) in scope or c is a))
        n_alt = sum(B.shape[1] for c, B in alt.chosen if c.target == target and _single_joint_variable(c) in scope)
        if e_alt <= 1.02 * e_now and n_alt <= n_now:
            notes.append(f"'{a.label}' replaced by the catalogue's shapes of {', '.join(sorted(scope))} on joint "
                         f"{target[5:]} ({'; '.join(c.label for c, _ in alt.chosen if c.target == target)}): they "
                         f"predict the held-out rows as well ({e_alt:.5f} vs {e_now:.5f} mm RMS)")
            for c, _ in alt.chosen:
                if c.target == target and c.pool != "generic":
                    alts.append({"of": c.label, "alternative": f"{a.label} (with the named terms it was kept with)",
                                 "family": "unnamed", "channel": a.channel, "target": target,
                                 "delta_chi2": float("nan"), "delta_chi2_chosen": float("nan"),
                                 "share_reproduced": float("nan"), "held_out_rms_mm": [e_alt, e_now]})
            fit = alt
    return fit, notes, alts



def _replaced(kept: Atom, replaced: Atom, e_alt: float, e_now: float) -> dict:
    """The ``alternatives`` entry of a term ``replaced`` by ``kept`` because the model with ``kept`` predicts the held-out
    rows as well (``e_alt`` against ``e_now`` [mm] RMS); the evidence columns do not apply (nan)."""
    return {"of": kept.label, "alternative": replaced.label, "family": replaced.family, "channel": replaced.channel,
            "target": replaced.target, "delta_chi2": float("nan"), "delta_chi2_chosen": float("nan"),
            "share_reproduced": float("nan"), "held_out_rms_mm": [e_alt, e_now]}

def _fewer_families(prob: Problem, fit: Fit, pool: list[Atom], sizes: dict, alpha_select: float,
                    z_min: float) -> tuple[Fit, list[str], list[dict]]:
    """Where a catalogue family is named by one term only, at one joint (or a support's tilt, at the joints it bends:
    :func:`_places`), and another named family has terms of that joint in the pool, try that family's terms of the
    joint in its place, each held to the forward pass' rules
    (significant, confirmed on the held-out rows, of a physical size): when they predict the confirmation rows as
    well (within 2 %), the model with fewer families is kept and the term it replaced is reported as the
    alternative the data cannot tell from it (a harmonic of a wrist joint follows part of the gravity torque on
    that joint over a plan's range: one cause is the simpler reading). Returns the fit, notes and alternatives."""
    notes: list[str] = []
    alts: list[dict] = []

    def admitted(base: Fit, sc: Scored) -> bool:
        if _implausible(prob, sc) is not None:
            return False
        c = confirm(prob, base, sc, z_min)
        return c.holds(z_min)

    for a, _ in list(fit.chosen):
        named = [c for c, _ in fit.chosen if c.pool == "catalogue"]
        support = a.family == "tilt" and a.target != "tilt0"
        # a support's tilt beside a payload's change: the payload's change reads the compliance of joints the tilt
        # bends carrying a load, and the arm's own weight goes through the same compliance on every row (a support
        # that tilted under the arm's moment would tilt under the payload's too, which no kept change reads)
        payload = a.family == "tilt" and any(is_load_change(c) for c, _ in fit.chosen)
        support = support or payload
        if a.pool != "catalogue" or not (a.place == "joint" or support) or a not in [c for c, _ in fit.chosen]:
            continue
        if sum(c.family == a.family for c in named) != 1:
            continue
        others = {c.family for c in named} - {a.family} | ({"compliance"} if payload else set())
        have = {c.key for c, _ in fit.chosen if c is not a}
        # a joint's term: the other families' terms of that joint; a support's tilt (the link a joint turns tilting
        # about two axes, one of them parallel to a neighbouring joint's): the compliance of the joints it bends
        if support and "compliance" not in others:
            continue
        at = _places(prob, a) if support else {a.target}
        cands = [c for c in pool if c.pool == "catalogue" and c.family in others and c.place == "joint"
                 and c.target in at and c.key not in have and (not support or c.family == "compliance")]
        swap = _swap_term(prob, fit, a, cands, sizes, alpha_select, admitted) if not support \
            else _swap_load(prob, fit, a, pool, {t for t in at if t.startswith("theta")}, sizes, alpha_select, z_min,
                            bare=payload)
        if swap is None:
            continue
        alt, e_alt, e_now = swap
        if {c.family for c, _ in alt.chosen if c.pool == "catalogue"} & {a.family}:
            continue
        new = [c for c, _ in alt.chosen if c.key not in {k.key for k, _ in fit.chosen}]
        if payload and not new:
            # the compliance the model holds reads the load alone
            new = [c for c, _ in alt.chosen if c.family == "compliance"]
        if not new:
            continue  # nothing of the other family survived the backward pass: the term stays
        # beside a payload's change the tilt is the reading physics does not support: it stays only where it
        # predicts the confirmation rows better row by row (signed-rank z beyond z_min)
        if e_alt <= 1.02 * e_now or (payload and _better_rows(prob, alt, fit) <= z_min):
            notes.append(f"'{a.label}' replaced by {'; '.join(c.label for c in new)} (a family already named): "
                         f"they predict the held-out rows as well ({e_alt:.5f} vs {e_now:.5f} mm RMS)")
            alts += [_replaced(c, a, e_alt, e_now) for c in new]
            fit = alt
    return fit, notes, alts


def _places(prob: Problem, a: Atom) -> set[str]:
    """The joints (``theta<j>``) and supports (``tilt<i>``) a kept term acts at: a joint term its joint; a support's
    tilt the support and the joints about whose axes it turns (the base's: the shoulder's and the elbow's, whose
    torques follow its moment; link ``i``'s support: joints ``i - 1`` to ``i + 1``); any other term none."""
    if a.place == "joint":
        return {a.target}
    if a.family == "tilt":
        i, N = int(a.target[4:]), prob.prep.nominal.n_joints
        joints = {"theta2", "theta3"} if i == 0 else {f"theta{j}" for j in (i - 1, i, i + 1) if 1 <= j <= N}
        return joints | {a.target}
    return set()


def _own_candidates(prob: Problem, fit: Fit, pool: list[Atom], a: Atom, targets: set[str],
                    have: set[str]) -> list[Atom]:
    """The family of the kept term ``a``'s own terms at ``targets`` not in ``have``, its richer shapes first in
    line: for a joint's load (a compliance, a backlash signed by the load) the joints' compliance shapes, the weight
    of the link each moves and the stiffening of each linear compliance ``fit`` holds
    (:func:`twin.diagnosis.loads.load_candidates`); for a support's tilt its own atoms and (the base's) the weight of the shoulder's and the elbow's links; for any other
    family the pool's terms of that family at those joints (a backlash's other laws, a harmonic's other orders)."""
    if a.family == "tilt":
        cands = [c for c in pool if c.family == "tilt" and c.target == a.target and c.key not in have]
        if a.target == "tilt0":
            cands += [c for c in (link_tilt_atom(prob.prep.nominal, prob.ctx.q, k) for k in (2, 3))
                      if c is not None and c.key not in have]
        return cands
    if is_load_term(a):
        return load_candidates(prob, fit, pool, targets, have)
    return [c for c in pool if c.pool != "generic" and c.family == a.family and c.place == "joint"
            and c.target in targets and c.key not in have and not is_change(c)]


def _admitted(prob: Problem, fit: Fit, sc: Scored, z_min: float) -> bool:
    """The forward pass' rules for a term scored against ``fit``: of a physical size and confirmed on the
    confirmation rows (``z`` beyond ``z_min`` with and without its best row, a lower error there, not a wander the
    nearest rows in time predict as well)."""
    if _implausible(prob, sc) is not None:
        return False
    c = confirm(prob, fit, sc, z_min)
    return c.holds(z_min)


def _row_errors(prob: Problem, fit: Fit) -> np.ndarray:
    """Each confirmation row's squared (whitened) error under ``fit`` ``(n_val,)``; nan for a row left out."""
    rv = fit.model_val.residuals(fit.z, jacobian=False)
    n = fit.model_val.obs.n
    err = np.bincount(rv.row, weights=rv.r ** 2, minlength=n)
    seen = np.bincount(rv.row, minlength=n) > 0
    return np.where(seen & prob.keep_val, err, np.nan)


def _better_rows(prob: Problem, fit: Fit, other: Fit) -> float:
    """Wilcoxon's signed-rank score (a normal score) of how much better ``other`` predicts the confirmation rows than
    ``fit``, row by row (each row's squared error under ``fit`` minus under ``other``): beyond ``z_min`` the rows
    say ``other`` predicts better, whatever the size of their errors."""
    d = _row_errors(prob, fit) - _row_errors(prob, other)
    return signed_rank_z(d[np.isfinite(d)])


def _first_admitted(prob: Problem, fit: Fit, cands: list[Atom], sizes: dict, alpha_select: float, z_min: float, *,
                    top: int | None = None, reshape=None):
    """The strongest of ``cands`` against ``fit`` (by ``Delta chi2``, among those significant after their pool's
    factor at ``alpha_select``; the first ``top`` of them) that the forward pass' rules admit (:func:`_admitted`),
    each first passed through ``reshape`` when given; None when none is."""
    scored = sorted((sc for sc in score_atoms(prob, fit, cands, sizes, exact_top=len(cands))
                     if sc.logp_adj < np.log(alpha_select)), key=lambda sc: -sc.dchi2)
    for sc in scored[:top]:
        sc = reshape(sc) if reshape is not None else sc
        if _admitted(prob, fit, sc, z_min):
            return sc
    return None


def _nested(prob: Problem, fit: Fit, extra: list[Atom], sizes: dict, alpha_select: float,
            z_min: float) -> tuple[Fit, list[Atom]]:
    """``fit`` with those of the terms ``extra`` that predict the confirmation rows beyond it, added back one at a time
    by the forward pass' rules (significant on the calibration rows, confirmed on the held-out ones against the model
    without them, of a physical size), the strongest first. Returns the fit and the terms added back."""
    P = prob.prep.space.size
    back: list[Atom] = []
    left = list(extra)
    while left:
        got = _first_admitted(prob, fit, left, sizes, alpha_select, z_min)
        if got is None:
            break
        chosen = list(fit.chosen) + [(got.atom, got.basis)]
        fit = prob.fit(fit.z[:P], chosen, psi_init(fit, chosen))
        back.append(got.atom)
        left = [c for c in left if c.key != got.atom.key]
    return fit, back


def _grow_own(prob: Problem, cur: Fit, candidates: Callable[[Fit, set[str]], list[Atom]], sizes: dict,
              alpha_select: float, z_min: float, rounds: int, *, linear_first: bool = False) -> Fit:
    """``cur`` with a family's own terms (``candidates(fit, keys_kept)``) added one at a time by the forward pass'
    rules (:func:`_first_admitted`: the strongest of the first three admitted, a law refined within its family), at
    most ``rounds`` of them. ``linear_first``: a joint's linear load terms (its torque shapes, the weight of the link
    it moves) enter before any law read on their fitted sum (a stiffening): the law bends the joint's whole torque,
    not the part of it placed first. A law along a direction of a link's weight
    (:func:`twin.diagnosis.loads.along_link_weight`) is tried only where no law of the fitted torque is admitted: the
    fitted torque is the rows' own reading of the load, the directions the reading where its zero is lost to the
    joint's."""
    P = prob.prep.space.size
    for _ in range(rounds):
        have = {c.key for c, _ in cur.chosen}
        cands = candidates(cur, have)
        if not cands:
            break

        def own_shape(sc, cur=cur):
            # the family's own shape: a law refined past the family's range (a compliance's stiffening into a
            # backlash's narrow flank) is another family's term, judged with the terms taken out
            refined = refine_load_sign(prob, cur, sc, sizes)
            return refined if refined.atom.family == sc.atom.family else sc

        linear = [c for c in cands if not any(isinstance(f, LoadSign) for f in c.features)] if linear_first else []
        best = _first_admitted(prob, cur, linear, sizes, alpha_select, z_min, top=3) if linear else None
        rest = [c for c in cands if c not in linear]
        for tier in ([c for c in rest if not along_link_weight(c)], [c for c in rest if along_link_weight(c)]):
            if best is None and tier:
                best = _first_admitted(prob, cur, tier, sizes, alpha_select, z_min, top=3, reshape=own_shape)
        if best is None:
            break
        chosen = list(cur.chosen) + [(best.atom, best.basis)]
        cur = prob.fit(cur.z[:P], chosen, psi_init(cur, chosen))
    return cur


def _no_extra_family(prob: Problem, fit: Fit, pool: list[Atom], sizes: dict, alpha_select: float,
                     z_min: float) -> tuple[Fit, list[str], list[dict]]:
    """No extra term where the named family explains the rows. For each kept named term (in the order they entered:
    the family that explains most first), the terms of another family, or unnamed, acting where it acts (its joint;
    for a support's tilt the support and the joints whose torques follow its moment; a joint's load also the base's
    tilt, and a support's tilt the loads of those joints) are taken out, the family's own richer shapes tried in
    their place, each held to the forward pass' rules (:func:`_own_candidates`: a joint's load its compliance
    shapes, the weight of the link it moves, the stiffening of its fitted torque; a tilt its own atoms; a harmonic
    its other orders), and the terms taken out added back only where they predict the confirmation rows beyond that
    model, judged nested (:func:`_nested`: significant on the calibration rows and confirmed on the held-out rows
    against the model without them); all of them stay where together they predict the confirmation rows better row
    by row (:func:`_better_rows` beyond ``z_min``). The family alone is tried first: when it predicts the
    confirmation rows within 2 % of the model with the extra terms, nothing is added in their place. The terms not
    added back are reported as the alternatives the data cannot tell from the family's reading. Last, a harmonic or a
    ratio still kept beside the family whose every column a term of the family's own spans over the rows
    (:func:`_spanning`) is replaced by that term: the same prediction on every row, the family's reading. Returns the
    fit, notes and alternatives."""
    notes: list[str] = []
    alts: list[dict] = []
    P = prob.prep.space.size
    done: set[tuple] = set()
    named = [a for a, _ in fit.chosen if a.pool != "generic" and not is_change(a) and _places(prob, a)]
    anchors = [(a, _places(prob, a)) for a in named]
    # a joint's compliance named: another loaded joint whose angle only harmonics, a ratio or unnamed functions hold
    # is tried with the family's terms there too (a load's law is the same family at every joint it bends)
    loaded = {c.target for c in pool if c.family == "compliance" and c.place == "joint" and c.pool != "generic"}
    for a in [a for a in named if a.family == "compliance" and a.place == "joint"]:
        held = {c.target for c, _ in fit.chosen if c.place == "joint" and not is_change(c)
                and (c.pool == "generic" or c.family in ("cyclic", "gear_ratio"))}
        bent = {c.target for c in named if c.family == a.family and c.place == "joint"}
        anchors += [(a, {t}) for t in sorted((held & loaded) - bent)]
    for a, places in anchors:
        if a not in [c for c, _ in fit.chosen]:
            continue
        targets = {t for t in places if t.startswith("theta")}
        # beside a load: harmonics, a ratio, unnamed functions and the other load families; beside any other family
        # the named terms of another (an unnamed function beside a harmonic is the catalogue's shapes' question:
        # _named_shapes)
        others = [c for c, _ in fit.chosen if c is not a and not is_change(c) and c.family != a.family
                  and (_places(prob, c) & places)
                  and ((c.pool == "generic" and is_load_term(a)) or c.family in ("cyclic", "gear_ratio")
                       or (is_load_term(c) and is_load_term(a)))]
        tag = (a.key, frozenset(c.key for c in others))
        if not others or tag in done:
            continue
        done.add(tag)
        keep = [(c, B) for c, B in fit.chosen if c not in others]
        # the family's constants (a load law's direction among the torque shapes) read again without the others,
        # which took part of the load when the law was placed
        cur = retime(prob, prob.fit(fit.z[:P], keep, psi_init(fit, keep)))
        e_now = held_out_rms(prob, fit)
        if held_out_rms(prob, cur) <= 1.02 * e_now:
            rounds = 0  # the family alone predicts as well: nothing in their place
        else:
            rounds = len(others) + 1
        cur = _grow_own(prob, cur, lambda f, have, a=a, t=targets: _own_candidates(prob, f, pool, a, t, have),
                        sizes, alpha_select, z_min, rounds, linear_first=a.family == "compliance")
        alt, _ = backward(prob, cur, alpha_select, sizes)
        if a not in [c for c, _ in alt.chosen] and not any(c.family == a.family for c, _ in alt.chosen):
            continue  # the family itself did not survive without the others: no reading of its own
        alt, back = _nested(prob, alt, others, sizes, alpha_select, z_min)
        if len(back) == len(others):
            continue  # every term taken out predicts beyond the family: all stay as they were
        alt, _ = backward(prob, alt, alpha_select, sizes)
        e_alt = held_out_rms(prob, alt)
        if _better_rows(prob, alt, fit) > z_min:
            continue  # together the terms taken out predict the confirmation rows beyond the family: they stay
        out = [o for o in others if o.key not in {c.key for c, _ in alt.chosen}]
        new = [c for c, _ in alt.chosen if c.key not in {k.key for k, _ in fit.chosen}]
        notes.append(f"{'; '.join(repr(c.label) for c in out)} taken out beside '{a.label}' (the family's own terms in "
                     f"their place: {'; '.join(c.label for c in new) or 'none'}): not confirmed on the held-out rows "
                     f"beyond it ({e_alt:.5f} vs {e_now:.5f} mm RMS)")
        alts += [_replaced(a, o, e_alt, e_now) for o in out]
        fit = alt
    for a, places in anchors:
        # a term of another family kept beside the family whose every column a term of the family's own spans over
        # the rows (a level joint's own link weight is exactly a 1st harmonic of its angle) is read as the family's:
        # the same effect on every row, the rows cannot tell the two readings apart
        if a not in [c for c, _ in fit.chosen]:
            continue
        others = [c for c, _ in fit.chosen if c.family != a.family and c.family in ("cyclic", "gear_ratio")
                  and not is_change(c) and (_places(prob, c) & places)]
        have = {c.key for c, _ in fit.chosen}
        same = _spanning(prob, others, _own_candidates(prob, fit, pool, a, {t for t in places if t.startswith("theta")},
                                                       have))
        if not same:
            continue
        keep = [(c, B) for c, B in fit.chosen if c not in [o for o, _ in same]]
        cur = prob.fit(fit.z[:P], keep, psi_init(fit, keep))
        chosen = list(cur.chosen) + [(sc.atom, sc.basis) for sc in score_atoms(prob, cur, [c for _, c in same], sizes,
                                                                               exact_top=len(same))]
        alt = prob.fit(cur.z[:P], chosen, psi_init(cur, chosen))
        e_now = held_out_rms(prob, fit)
        e_alt = held_out_rms(prob, alt)
        notes.append(f"{'; '.join(repr(o.label) for o, _ in same)} read as {'; '.join(c.label for _, c in same)} "
                     f"beside '{a.label}': the same columns over the rows ({e_alt:.5f} vs {e_now:.5f} mm RMS on the "
                     f"held-out rows)")
        alts += [_replaced(c, o, e_alt, e_now) for o, c in same]
        fit = alt
    return fit, notes, alts


def _spanning(prob: Problem, others: list[Atom], cands: list[Atom]) -> list[tuple[Atom, Atom]]:
    """Pairs ``(o, c)``: a joint's term ``o`` of ``others`` and the first term ``c`` of ``cands`` at that joint, no
    wider than it, whose span holds every column of ``o`` over the rows (with a constant, the joint's zero) within
    ``SPAN_TOL`` of its norm: the same effect on every row, one reading of it. Each candidate once."""
    out: list[tuple[Atom, Atom]] = []
    n = len(prob.ctx.q)
    for o in others:
        if o.place != "joint":
            continue
        Fo = prob.features(o)
        Fo = Fo - Fo.mean(axis=0)
        for c in cands:
            if c in [u for _, u in out] or c.place != "joint" or c.target != o.target or c.K > o.K:
                continue
            Fc = np.column_stack([np.ones(n), prob.features(c)])
            res = Fo - Fc @ np.linalg.lstsq(Fc, Fo, rcond=None)[0]
            if np.all(np.linalg.norm(res, axis=0) <= SPAN_TOL * np.linalg.norm(Fo, axis=0)):
                out.append((o, c))
                break
    return out


def _load_for_harmonics(prob: Problem, fit: Fit, pool: list[Atom], sizes: dict, alpha_select: float,
                        z_min: float) -> tuple[Fit, list[str], list[dict]]:
    """A joint's load read in place of several harmonics. Where the arm's weight loads a joint, no load term is kept
    there, and harmonics of its own angle are kept there with further terms of that joint (other orders, unnamed
    functions), the joint's load family is tried in their place (:func:`twin.diagnosis.loads.load_candidates`: its
    torque shapes, the weight of the link it moves, the stiffening of its fitted torque), each term held to the forward pass' rules, and
    the terms taken out added back only where they predict the confirmation rows beyond it (:func:`_nested`). A
    joint whose axis lies level turns its own link's first mass moment into exactly a first harmonic of its angle, and
    a stiffening of that torque into its odd harmonics: one cause read as several. The load is kept when it replaces
    every harmonic there and predicts the confirmation rows as well (within 2 %) and the terms it replaced do not
    predict them better row by row (:func:`_better_rows`). One harmonic alone stays (the data cannot tell it from the
    link's weight; the harmonic is the reading with no assumption on the load). Returns the fit, notes and
    alternatives."""
    notes: list[str] = []
    alts: list[dict] = []
    P = prob.prep.space.size
    model = prob.prep.nominal
    loaded = sorted({c.target for c in pool if c.family == "compliance" and c.place == "joint" and c.pool != "generic"})
    for t in loaded:
        if any(is_load_term(c) and t in _places(prob, c) for c, _ in fit.chosen):
            continue
        if own_link_atom(model, prob.ctx.q, int(t[5:])) is None:
            continue
        var = f"q{t[5:]}"
        harmonics = [c for c, _ in fit.chosen if c.family == "cyclic" and c.target == t
                     and _single_joint_variable(c) == var]
        others = [c for c, _ in fit.chosen if c.place == "joint" and c.target == t and not is_change(c)
                  and (c.pool == "generic" or c.family in ("cyclic", "gear_ratio"))]
        if not harmonics or len(others) < 2:
            continue
        keep = [(c, B) for c, B in fit.chosen if c not in others]
        cur = prob.fit(fit.z[:P], keep, psi_init(fit, keep))
        cur = _grow_own(prob, cur, lambda f, have, t=t: load_candidates(prob, f, pool, {t}, have), sizes,
                        alpha_select, z_min, len(others) + 1, linear_first=True)
        alt, _ = backward(prob, cur, alpha_select, sizes)
        if not any(c.family == "compliance" and c.target == t for c, _ in alt.chosen):
            continue  # no load of the joint's own survived: no reading of the load
        alt, back = _nested(prob, alt, others, sizes, alpha_select, z_min)
        if any(c.family == "cyclic" for c in back):
            continue  # a harmonic predicts beyond the load: the harmonics stay as they were
        alt, _ = backward(prob, alt, alpha_select, sizes)
        if not any(c.family == "compliance" and c.target == t for c, _ in alt.chosen):
            continue
        e_now = held_out_rms(prob, fit)
        e_alt = held_out_rms(prob, alt)
        if e_alt > 1.02 * e_now or _better_rows(prob, alt, fit) > z_min:
            continue
        out = [o for o in others if o.key not in {c.key for c, _ in alt.chosen}]
        new = [c for c, _ in alt.chosen if c.key not in {k.key for k, _ in fit.chosen}]
        notes.append(f"{'; '.join(repr(c.label) for c in out)} read as the load of joint {t[5:]} "
                     f"({'; '.join(c.label for c in new)}): it predicts the held-out rows as well "
                     f"({e_alt:.5f} vs {e_now:.5f} mm RMS)")
        alts += [_replaced(c, o, e_alt, e_now) for o in out for c in new[:1]]
        fit = alt
    return fit, notes, alts


def retime(prob: Problem, fit: Fit) -> Fit:
    """``fit`` with the constants its terms were given on the rows that chose them refined again on ``prob``'s rows, the
    model refitted after each: they are values of a term, like its coefficients. The constants: the time constants
    of the thermal terms (a lag of the recorded temperature; without a record the air's onset, ramp and lag:
    :func:`twin.diagnosis.refine.follows_the_air`, :func:`twin.diagnosis.refine.refine_time`; the motors' heat, its
    time constant and the motors whose travel heats the links: :func:`twin.diagnosis.refine.prefer_heat`) and the
    direction of a load-signed backlash's load in its torque shapes (:func:`twin.diagnosis.loads.refine_load_sign`)
    and the law and width of a backlash growing with the last move that the rows that chose it read in proportion,
    no bend shown (:func:`twin.diagnosis.refine.bend_unseen`, refined by :func:`twin.diagnosis.refine.refine`), each
    term against the others refitted without it. A term keeps the constants it has unless the new ones lower the
    chi2 of every row significantly (beyond ``chi2`` at 1 % with a degree of freedom per constant moved and per
    column added; a load law's counted on every row but those both fits set aside as gross:
    :func:`twin.diagnosis.problem.common_chi2`; a lag of the recorded temperature beyond ``LAG_SIGMA``, one standard
    error of one constant, its record's changes placed within the intervals between rows where that explains more by
    ``chi2_1`` at 1 %: :func:`twin.diagnosis.refine.refine_gap`), stay within the onset grid's range (a time
    constant at most ``max(ONSET_TAUS)`` times the rows' span: a longer one is a drift that extrapolates as a
    polynomial) and leave the term of a plausible size (:func:`implausible_size`). The models to use, chosen on the
    first block of a campaign and refitted on every row: an air step after that block fixes the lag the block could
    not see; the heat's time constant and motors are read on the whole campaign's moves; the flank a load pushes a
    gear to is read on every row; a backlash growing with the last move that the first block read in proportion is
    read on every row (the held-out rows' longer moves may show the bend)."""
    span = float(np.ptp(np.asarray(prob.ctx.t_s, float)[prob.rows_cal])) if prob.ctx.t_s is not None else 0.0
    for k in range(len(fit.chosen)):
        atom, _ = fit.chosen[k]
        load = reads_its_load(atom)
        heat = _heat(atom) and prob.ctx.t_s is not None
        size = bend_unseen(prob, atom)
        if not (follows_the_air(atom) or load or heat or size):
            continue
        others = [c for i, c in enumerate(fit.chosen) if i != k]
        without = refit_with(prob, fit, others)
        sizes = {atom.pool: 1}
        got = score_atoms(prob, without, [atom], sizes, exact_top=1)
        if not got:
            continue
        if load:
            new = refine_load_sign(prob, without, got[0], sizes)
        elif heat:
            new = prefer_heat(prob, without, got[0], heat_alternatives(prob.ctx, atom), sizes)
        elif size:
            new = refine(prob, without, got[0], sizes)
        else:
            new = refine_time(prob, without, got[0], sizes)
            if recorded_lag(atom) and atom.features[0].gap is None:
                # the record's changes placed within the intervals between rows where that explains more than linear
                # between them by chi2_1 at 1 % (a constant more)
                gapped = refine_gap(prob, without, new, sizes)
                if gapped.dchi2 - new.dchi2 > prob.evidence_scale * chi2_isf(0.01, 1):
                    new = gapped
        if new.atom is atom:
            continue
        taus = [f.tau for f in new.atom.features if getattr(f, "tau", None) is not None]
        if not (load or size) and (not taus or max(taus) > max(ONSET_TAUS) * span):
            continue
        chosen = list(fit.chosen)
        chosen[k] = (new.atom, new.basis)
        trial = refit_with(prob, fit, chosen)
        psi = trial.z[trial.model_cal.offsets[k]:trial.model_cal.offsets[k + 1]]
        moved = 2 if load else 3 if is_onset(new.atom) else 1
        if heat and new.atom.channel.split(" lagged ")[0] != atom.channel.split(" lagged ")[0]:
            moved += 1 + max(new.basis.shape[1] - fit.chosen[k][1].shape[1], 0)  # other motors, more columns
        # a load law's rows read alike in both: a row on the wrong flank is off by twice the backlash, which the
        # fit that put it there sets aside as gross
        gain = (common_chi2(fit, trial) if load else fit.chi2 - trial.chi2) / prob.evidence_scale
        # the recorded air's lag, one constant of a measured cause, is estimated as its coefficients are: it moves to
        # every row's maximum of the likelihood where its reading lies beyond one standard error of it (the rows pin
        # it elsewhere); within it the rows hold both alike and the reading confirmed on the rows after it stays
        need = LAG_SIGMA if recorded_lag(new.atom) else chi2_isf(0.01, moved)
        if gain > need and implausible_size(prob, new.atom, new.basis @ psi) is None:
            fit = trial
    return fit
