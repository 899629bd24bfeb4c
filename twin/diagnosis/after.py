"""Step 9 of the diagnosis (:func:`after_blocks`): what every row of the campaign holds after the blocks that chose
the model (a change after the rows that fit, the air's temperature changing there, a kept change that ends, a change
and back, a payload's event at every loaded joint, a state the campaign's last rows hold), on the chosen model refitted
on those rows.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..estimator.distributions import chi2_isf
from .atoms import Atom
from .changes import is_change
from .features import Lag
from .late import (begun_steps, end_change, end_steps, end_term, glitches, gross_runs, late_change, late_templates,
                   late_term, own_weight, payload_at, payload_event, step_as_return)
from .problem import Fit, Problem, common_chi2, refit_with, update_gross
from .refine import is_onset
from .rule import retime

__all__ = ["AfterBlocks", "after_blocks"]


@dataclass(frozen=True)
class AfterBlocks:
    """What :func:`after_blocks` found on a problem's rows: the fit with it, and per term found (in the order added)
    ``(atom, how, late, entry_chi2)`` (``how``: ``"late"``, ``"end"``, ``"glitch"``, ``"event"`` or ``"load"``;
    ``late``: the :class:`~twin.diagnosis.late.LateChange` of a term confirmed after a cut, the
    :class:`~twin.diagnosis.late.EndChange` of a change in the campaign's last rows, else None), notes, and whether a
    term it was given took another end there (``changed``: the state later rows read changed)."""

    fit: Fit
    found: tuple
    notes: tuple
    changed: bool = False  # a term the rows brought was given another end (its state on later rows changed)


def _air_explains(prob: Problem, src: Fit, step, air, alpha: float) -> bool:
    """Whether the change of the air ``air`` (a thermal term, its constants :func:`retime`d) explains every row of
    ``prob`` as well as the ``step`` found after the rows that fit, with fewer parameters: its chi2 beyond the step's by
    less than ``chi2`` at ``alpha`` with a degree of freedom per parameter the step has more (columns and constants: the
    step's time; the recorded temperature's lag, or without a record the air's onset, ramp and lag; at least one for
    the recorded temperature, whose record times the change). Without a record, an air that takes as many parameters
    as the step or more does not explain it."""
    recorded = any(isinstance(f, Lag) for f in air.atom.features)
    extra = step.basis.shape[1] + 1 - air.basis.shape[1] - (1 if recorded else 3)
    if extra < 1 and not recorded:
        return False
    chosen = list(src.chosen)
    with_step = refit_with(prob, src, chosen + [(step.atom, step.basis)])
    with_air = retime(prob, refit_with(prob, src, chosen + [(air.atom, air.basis)]))
    return with_air.chi2 - with_step.chi2 < prob.evidence_scale * chi2_isf(alpha, max(1, extra))


def _payload_instead(prob: Problem, src: Fit, air, places: list, alpha: float) -> tuple[Fit, list, str] | None:
    """A payload's event in place of a change of the air after the rows that fit that no temperature record times
    (``air``: its onset confirmed on later rows): both read a change of the arm at that time, the event
    (:func:`~twin.diagnosis.late.payload_at`) kept where it explains every row better (a chi2 lower than the air's,
    its lag :func:`retime`d, by ``chi2`` at ``alpha`` of the columns it has beyond the air's columns and its three
    constants, onset, ramp and lag: none where it has no more). Returns the fit with the event, its terms
    and a note, None where the air stays."""
    got = payload_at(prob, src, air.atom, places, alpha=alpha)
    if got is None:
        return None
    fit, terms = got
    with_air = retime(prob, refit_with(prob, src, list(src.chosen) + [(air.atom, air.basis)]))
    # columns the event has beyond the air's columns and constants must earn their place
    k_event = sum(B.shape[1] for a, B in fit.chosen[len(src.chosen):])
    extra = k_event - air.basis.shape[1] - 3
    margin = prob.evidence_scale * chi2_isf(alpha, extra) if extra > 0 else 0.0
    if not fit.chi2 < with_air.chi2 - margin:
        return None
    return fit, terms, (f"not kept: {air.atom.label}; a payload's event at that time explains every row better "
                        f"({'; '.join(a.label for a, _ in terms)}: chi2 {fit.chi2:.1f} against {with_air.chi2:.1f})")


def _late_beside_glitches(prob: Problem, src: Fit, found: list, alpha: float) -> tuple[Fit, list, list[str]]:
    """``src`` without each term of ``found`` kept after the rows that fit (``"late"``: a step, a change of the air)
    where every row is explained as well without it beside the glitches kept since (its chi2 within ``chi2`` at
    ``alpha`` with a degree of freedom per column and per constant: a step's time; the air's onset, ramp and lag, or
    the recorded air's lag); the entries of ``found`` left and notes."""
    notes = []
    for entry in [f for f in found if f[1] == "late"]:
        chosen = [c for c in src.chosen if c[0].key != entry[0].key]
        if len(chosen) == len(src.chosen):
            continue
        without = refit_with(prob, src, chosen)
        cols = next(b.shape[1] for a, b in src.chosen if a.key == entry[0].key)
        constants = 3 if is_onset(entry[0]) else 1
        if without.chi2 - src.chi2 < prob.evidence_scale * chi2_isf(alpha, cols + constants):
            notes.append(f"not kept: {entry[0].label}; the glitches kept beside it explain every row as well "
                         f"(chi2 {without.chi2:.1f} against {src.chi2:.1f})")
            src, found = without, [f for f in found if f is not entry]
    return src, found, notes


def after_blocks(setup, prob_x: Problem, src: Fit, pool: list[Atom], places: list, *, late: bool, alpha: float,
                 z_min: float, recorded: list[Atom] | None = None) -> AfterBlocks:
    """Step 9, on the rows of ``prob_x`` (every row of the campaign; or every row before the report block) from the
    chosen model refitted on them (``src``): a change after the rows that fit, located before a cut and confirmed after
    it (:func:`~twin.diagnosis.late.late_change`; else the air's temperature,
    :func:`~twin.diagnosis.late.late_term`, its lag then :func:`retime`d) when ``late`` (the model left the confirmation
    block beyond the floor); then, when the rows hold more than the floor (or a run of gross rows), a kept change that
    ends (:func:`~twin.diagnosis.late.end_steps`), a change and back of a joint's zero or of its compliance (a payload
    hung on and taken off, :func:`~twin.diagnosis.late.glitches`); a payload's change kept so far as one event at
    every loaded joint (:func:`~twin.diagnosis.late.payload_event`); whatever the rows hold, the recorded temperature
    leaving its range in the campaign's last rows (:func:`~twin.diagnosis.late.end_term`, on ``late_templates(pool)``
    or, where no selection ran, the ``recorded`` temperature's templates; its lag then :func:`retime`d) and a change
    whose new state the campaign's last rows hold, too close to the end for a cut
    (:func:`~twin.diagnosis.late.end_change`: or a kept step's end there); and the arm's own weight at a joint a
    payload's change shows compliant
    (:func:`~twin.diagnosis.late.own_weight`). A change of the air after the rows that fit is not kept where a kept
    change that ends explains every row as well, nor, where no temperature is recorded, where a payload's event at
    its time explains every row better (:func:`_payload_instead`, once the glitches were judged beside it). A result
    that fits every row worse than ``src`` by more than ``chi2`` at ``alpha`` of its terms is a failed refit: ``src``
    is returned, nothing found."""
    found, notes = [], []
    given = src
    if late and pool:
        got, note = late_change(setup, prob_x, src, places, alpha=alpha, z_min=z_min)
        notes.append(note)
        # the air's temperature changing after the rows that fit (a door opened late in the campaign), tried beside a
        # step too: the links growing after a step of the air are a step of the rows' geometry as well
        air, note = late_term(setup, prob_x, src, late_templates(pool), alpha=alpha, z_min=z_min)
        if note:
            notes.append(note)
        if got is None:
            got = air
        elif air is not None and _air_explains(prob_x, src, got, air, alpha):
            notes.append(f"not kept: {got.atom.label}; the air's change explains every row as well with fewer "
                         f"parameters ({air.atom.label})")
            got = air
        if got is not None:
            with_got = refit_with(prob_x, src, list(src.chosen) + [(got.atom, got.basis)])
            if not is_change(got.atom):
                with_got = retime(prob_x, with_got)
                # a kept change that ends (a payload taken off) is preferred over a change of the air after the rows
                # that fit where it explains every row as well: the kept term with one more constant, its end
                ended, ends = end_steps(setup, prob_x, src, alpha=alpha)
                if ends and ended.chi2 - with_got.chi2 < prob_x.evidence_scale * chi2_isf(alpha, 1):
                    notes.append(f"not kept: {got.atom.label}; a kept change that ends explains every row as well "
                                 f"(chi2 {ended.chi2:.1f} against {with_got.chi2:.1f})")
                    got = None
            elif any(is_change(a) and (a.place, a.target) == (got.atom.place, got.atom.target) for a, _ in src.chosen):
                # a step at the place of a kept change: the kept change ending there (a change and back, its size back
                # to the state before it) is preferred where it explains every row as well, one constant fewer
                ended, ends = end_steps(setup, prob_x, src, alpha=alpha)
                if ends and ended.chi2 - with_got.chi2 < prob_x.evidence_scale * chi2_isf(alpha, 1):
                    notes.append(f"not kept: {got.atom.label}; the kept change at its place ending explains every row "
                                 f"as well (chi2 {ended.chi2:.1f} against {with_got.chi2:.1f})")
                    notes += ends
                    src, got = ended, None
            if got is not None:
                # a change of the recorded air is minor or not by what it explains on every row: the record times
                # it, and the rows before the cut that located it may hold little of it (its start late among them,
                # the links' lag); an onset placed without a record, by what the rows that placed it hold
                recorded = any(isinstance(f, Lag) for f in got.atom.features)
                entry = max(got.dchi2, src.chi2 - with_got.chi2) if recorded and not is_change(got.atom) else got.dchi2
                src = with_got
                # the term as the fit holds it (its constants retimed there): what later judges it finds it by
                found.append((with_got.chosen[-1][0], "late", got, entry))
                if is_change(got.atom):
                    # a zero's step after the rows that fit that is a glitch's return: the window ending there
                    src, win, note = step_as_return(setup, prob_x, src, found[-1][0], alpha=alpha)
                    if note:
                        notes.append(note)
                        found[-1] = (win, "glitch", None, entry)
    src0 = src
    beyond = bool((pool and prob_x.test_fit_block(src).p_value < alpha) or gross_runs(setup, prob_x).any())
    if beyond:
        # what every row holds beyond the floor: a kept change that ends, a change and back at a joint's zero (an
        # unconfirmed window of a frame or a load follows a wander of the cell: late.glitches)
        src, notes_end = end_steps(setup, prob_x, src, alpha=alpha)
        # a kept step that ends a change begun among the rows before it (a payload hung on and taken off later)
        src, notes_begun = begun_steps(setup, prob_x, src, alpha=alpha)
        notes_end += notes_begun
        # a joint's zero, and a joint's compliance under gravity: a payload hung on and taken off again
        zeros = [p for p in places if p.place == "joint"]
        src, wins, notes_win = glitches(setup, prob_x, src, zeros, places, alpha=alpha, z_min=z_min)
        notes += notes_end + notes_win
        found += [(a, "glitch", None, dchi2) for a, dchi2 in wins]
        if wins:
            # a term found after the rows that fit, before the glitches were: judged again beside them (a glitch's
            # return read as a step at another place or as the air's change), dropped where every row is explained
            # as well without it (its columns and its constants)
            src, found, notes_back = _late_beside_glitches(prob_x, src, found, alpha)
            notes += notes_back
    if setup.ctx.temp_c is None:
        # an unrecorded change of the air kept after the rows that fit (beside the glitches): a payload's event at
        # that time in its place where it explains every row better
        for entry in [f for f in found if f[1] == "late" and is_onset(f[0])]:
            keep = [c for c in src.chosen if c[0].key != entry[0].key]
            event = _payload_instead(prob_x, refit_with(prob_x, src, keep), entry[2], places, alpha)
            if event is not None:
                src, terms, note = event
                notes.append(note)
                found = [f for f in found if f is not entry] + [(a, "event", None, dchi2) for a, dchi2 in terms]
    # a payload's change found so far is one event at every loaded joint before the last rows are scanned: a joint it
    # loads is not left to read as a change in the last rows
    src, events, notes_ev, renamed = payload_event(prob_x, src, places, alpha=alpha)
    notes += notes_ev
    found = [(renamed.get(f[0].key, f[0]),) + tuple(f[1:]) for f in found]
    found += [(a, "event", None, dchi2) for a, dchi2 in events]
    # the recorded temperature leaving its range in the last rows, too close to the end for a cut: its growth
    templates = late_templates(pool) if pool else list(recorded or [])
    if templates:
        src, end, note = end_term(setup, prob_x, src, templates, alpha=alpha, z_min=z_min)
        if end is not None:
            src = retime(prob_x, src)
            notes.append(note)
            found.append((end.atom, "end", end, end.dchi2))
    # a change whose new state the last rows hold, too close to the end to be confirmed on later rows (or a kept
    # change's end there)
    src, end, note = end_change(setup, prob_x, src, places, alpha=alpha, z_min=z_min)
    if note:
        notes.append(note)
    if end is not None:
        found.append((end.atom, "end", end, end.dchi2))
    # a payload is one event at every joint below the flange: one timing, every loaded joint
    src, more, notes_ev, renamed = payload_event(prob_x, src, places, alpha=alpha)
    notes += notes_ev
    found = [(renamed.get(f[0].key, f[0]),) + tuple(f[1:]) for f in found]
    found += [(a, "event", None, dchi2) for a, dchi2 in more]
    events += more
    if beyond or events:
        src, loads, notes_load = own_weight(prob_x, src, pool, alpha=alpha)
        notes += notes_load
        found += [(a, "load", None, dchi2) for a, dchi2 in loads]
    if -common_chi2(given, src) > prob_x.evidence_scale * chi2_isf(alpha, len(src.chosen)):
        # what step 9 adds or reshapes nests the model it was given (a term more, a change's end, one timing within
        # its chi2): a model fitting every row worse than that by more than chi2 at alpha of its terms is a refit
        # that failed, never the model a user takes
        update_gross(prob_x, given)
        return AfterBlocks(given, (), tuple(notes) + (
            f"not kept after the blocks: {'; '.join(a.label for a, *_ in found) or 'a reshaped change'} (every row's "
            f"chi2 {src.chi2:.1f} against {given.chi2:.1f} for the model without them: a refit that failed)",))
    changed = [a.label for a, _ in src.chosen[:len(src0.chosen)]] != [a.label for a, _ in src0.chosen]
    return AfterBlocks(src, tuple(found), tuple(notes), changed)
