"""Diagnosis: is there structure beyond the noise floor, what explains it, how much does adding it help.

Reads only a dataset (and optionally an existing geometric calibration). :func:`diagnose` is a sequence of
named steps, each a function of this module (``docs/diagnosis.md`` has the reasoning):

1. :func:`prepare_diagnosis`: the **noise floor** from what a user can measure (repeats, the plate's rigid
   geometry, a stated figure; never the world's truth), the **geometric fit** on the calibration rows, and the
   held-out rows split into two blocks (:func:`split_held_out`): the *confirmation* rows (the structure test
   and every held-out check that chooses a term) and the *report* rows (before/after are measured there and
   nothing else).
2. :func:`fit_geometry`: the geometric model refitted with gross rows down-weighted (a per-row misfit beyond both
   the floor's ``1e-6 / n`` quantile and ``median + 8 MAD`` of the rows, at most 2 % of the rows).
3. The **structure test** on the confirmation rows: ``T = r^T (I + J C J^T)^-1 r`` (whitened; ``C`` the
   parameter covariance), ``chi2(m)`` with a stated floor, ``(T/m) ~ F(m, nu)`` with an estimated one.
4. :func:`select_terms` (only when the test fires): forward selection over *atoms* (:func:`atom_pool`: the named
   catalogue and the unnamed dictionary compete in every round, :func:`selection_round`), each reduced to what
   the geometry cannot absorb, with calibration evidence ``Delta chi2 = |P r|^2``, Bonferroni-adjusted by the
   size of its pool, kept when significant *and* confirmed on the confirmation rows (``z > z_min``, also
   without the most favourable row, and the held-out residual drops); then a backward pass and the catalogue's
   shapes of one joint variable in place of an unnamed one when they predict as well.
5. :func:`decide`: ``structured`` when the test fires and something in the residual is predictable on held-out
   rows: a term is confirmed, or (no term) the nearest calibration rows in joint space or in time predict it.
6. :func:`report_before_after`: the errors and the structure test of the geometric and the extended model on
   the report rows, which took no part in choosing or fitting the model (rows whose approach history is unknown
   are left out: no model can predict a history-dependent term there).
7. :func:`describe_terms` and :func:`name_effects`: every kept term in words, the catalogue families among them.
8. :func:`refit_on_every_row`: the chosen models refitted on every row of the campaign (the models to use).
9. :func:`twin.diagnosis.after.after_blocks`: what every row holds after the blocks (a step after the rows that fit,
   located on the rows up to a cut and confirmed on the rows after it; the air's temperature changing there; a
   change and back of a joint's zero; a change the campaign's last rows hold) joins the models to use
   (``docs/diagnosis.md``, step 7b).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np

from ..dataset import Dataset, Plate, temperature_gaps
from ..estimator.calibration import Calibration
from ..estimator.core import Prepared, prepare, residual_stats
from ..estimator.methods import build_calibration, identify_best
from ..estimator.solvers import gauss_newton
from ..units import M_PER_MM, RAD_PER_DEG
from .atoms import Atom
from .pools import SCAN_ORDERS, catalogue_atoms, generic_atoms, recorded_lag_atoms
from .values import approach_unknown, history_signs
from .blocks import REPORT_FRACTION, REPORT_MIN_VISITS, confirm_and_report, held_out_sets, sessions
from .candidates import EFFECT_VOCABULARY, RowContext
from .changes import (MIN_ROWS, change_places, change_pool_sizes, describe_changes, is_change, is_window, row_times,
                      selection_short)
from .configurations import JointSampling, joint_sampling, offered, sampling_report
from .extend import error_stats
from .loads import reads_its_load
from .floor import AssumedNoise, DiagnosisError, NoiseFloor, history_resets, noise_floor, row_context
from .late import EndChange
from .problem import Fit, Problem, refit_with, update_gross
from .refine import bend_unseen, retimeable
from .structure import StructureTest, gross_rows, row_rms
from .after import AfterBlocks, after_blocks
from .rule import CandidateScore, Selection, implausible_size, retime, select_terms, selection_round
from .verdict import adopt, decide
from .describe import describe_terms, name_effects, place_unit, term_values

__all__ = [
    "virtual_spheres",
    "CandidateScore",
    "DiagnosisResult",
    "HeldOut",
    "Setup",
    "Selection",
    "diagnose",
    "split_held_out",
    "prepare_diagnosis",
    "fit_geometry",
    "atom_pool",
    "campaign_sampling",
    "selection_round",
    "select_terms",
    "decide",
    "adopt",
    "choose_geometry",
    "geometry_candidates",
    "report_before_after",
    "every_row_changes",
    "on_rows",
    "refit_on_every_row",
    "describe_terms",
    "implausible_size",
    "evidence_scale",
    "link_lengths",
    "dictionary_parameters",
    "name_effects",
    "error_stats",
    # re-exported: the floor and the test are part of what diagnose returns
    "NoiseFloor",
    "StructureTest",
    "DiagnosisError",
    "noise_floor",
    "history_resets",
    "row_context",
]



@dataclass(frozen=True, eq=False)
class DiagnosisResult:
    """What diagnosis found. ``before``/``after``: error statistics of the geometric and the extended model on
    the *report* rows (held out, and used for nothing else; ``held_out`` says which rows and why)
    ``{n_rows, position_mm: {mean, rms, max}, orientation_deg: {mean, rms, max}}``; ``p_value``,
    ``test_before``, ``test_after``: the structure test on the *confirmation* rows (they chose the terms);
    ``test_report``: ``{before, after}``, the same test on the report rows; ``explained``,
    ``explained_fraction``: from ``test_report``; ``atoms``: every chosen term (named and unnamed) in words with
    value and standard deviation; ``effects``: the catalogue families among them; ``unnamed``: the chosen terms
    outside the catalogue; ``alternatives``: explanations the data cannot tell apart from a chosen one;
    ``rows``: rows flagged (gross, unknown history) and the two held-out blocks; ``unexplained``: when the test
    fired and no term was confirmed, the excess (whitened RMS, extra sigma per coordinate [mm]), the neighbour
    smoothers' held-out ``z`` and whether they predict it (else None). ``model_in_use``: ``"extended"`` when the
    extended model predicts the confirmation block better than the geometric one (:func:`adopt`), else
    ``"geometric"`` (``calibration`` is then the geometric model, and the terms found are ``candidate_terms``, not
    ``atoms``, their model ``calibration_candidate``); ``adoption``: the comparison behind it (None when no term was
    found). ``calibration`` and ``calibration_geometric`` are the models refitted on every row of the campaign
    (:func:`refit_on_every_row`); ``calibrations_blocked`` (``geometric``, ``extended``) are the same models fitted on
    the calibration rows only: before/after and every block figure are theirs. ``changes``: the kept terms of family
    ``change`` (a step or a window at a row: :func:`twin.diagnosis.changes.describe_changes`), not among ``effects``.
    The terms found after the blocks on every row (:func:`twin.diagnosis.after.after_blocks`: a change after the rows
    that fit, the air's temperature changing there, a change and back of a joint's zero, a change in the campaign's
    last rows) are the last of ``atoms``
    (and of ``changes`` for a change), with ``found``; they are in ``calibration`` (then ``model_in_use`` is
    ``"extended"``); ``calibrations_blocked["extended"]`` holds those found on the rows before the report block (the
    state the report rows read), the kept terms at their calibration rows' values. ``two_groups``: set by `twin
    diagnose` where the model in use leaves 10x the floor or more on the confirmation rows: the rows' split between
    two geometric models (:func:`twin.estimator.mixture.split_rows`, its ``summary``), else None."""

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
    held_out: dict[str, Any] = field(default_factory=dict)
    test_report: dict[str, StructureTest | None] = field(default_factory=dict)
    model_in_use: str = "geometric"
    adoption: dict[str, Any] | None = None
    two_groups: dict[str, Any] | None = None
    candidate_terms: tuple[dict, ...] = ()
    calibration_candidate: Calibration | None = None
    calibrations_blocked: dict[str, Calibration] = field(default_factory=dict)
    changes: tuple[dict, ...] = ()
    sampling: dict[str, Any] = field(default_factory=dict)  # [configurations] each joint's sampling and order bound


@dataclass(frozen=True)
class HeldOut:
    """The held-out rows in two blocks (indices into ``prep.obs``): ``confirmation`` (the structure test and the
    held-out checks that choose the terms) and ``report`` (before/after only; ``None`` when there were too few
    held-out visits for a block of its own, then before/after are on the confirmation rows), and the rule."""

    confirmation: np.ndarray
    report: np.ndarray | None
    rule: str
    sets: str = ""  # how the held-out rows were chosen (:func:`twin.diagnosis.blocks.held_out_sets`)


@dataclass
class Setup:
    """What every step shares: the dataset (virtual spheres for a pose instrument), the floor, the prepared
    rows, the geometric identification and calibration, the row context, the held-out blocks, the selection
    problem (its row weights change as gross rows are found) and the notes so far."""

    dataset: Dataset
    virtual: bool
    floor: NoiseFloor
    prep: Prepared
    x0: np.ndarray
    geometric: Calibration
    ctx: RowContext
    held_out: HeldOut
    problem: Problem
    notes: list[str]


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
    geometry: dict | None = None,
    callback: Callable[[CandidateScore], None] | None = None,
    threads: int = 1,
) -> DiagnosisResult:
    """Diagnose ``dataset`` (see the module docstring for the steps and their statistics).

    ``holdout``: hold out this fraction at the end of the campaign, whatever the ``set`` column says (default: the
    ``set`` column's validation rows, or ``twin.diagnosis.blocks.HOLDOUT_DEFAULT``, 30 %, without a ``set`` column or
    validation rows; :func:`twin.diagnosis.blocks.held_out_sets`: the held-out rows are always a block of time after
    the rows that fit, and the notes say which).
    ``calibration``: a geometric calibration of this robot; checked to be of the dataset's robot and named in the notes,
    its values are not used (the geometry is identified anew from the nominal model on the rows that fit).
    ``max_effects``: most atoms kept. ``alpha_select``: family-wise false-selection rate per round (each pool
    Bonferroni-adjusted). ``z_min``: held-out confirmation threshold (terms and the neighbour smoothers).
    ``generic``: also search the unnamed dictionary. ``q_start``: where the robot stood before the first row,
    when known (otherwise the first row's approach is unknown). ``geometry``: options of the geometric
    identification (:func:`twin.estimator.methods.identify_best`: ``level``, ``selection``; default the estimator's
    own), e.g. ``{"selection": "figaroh"}``. ``threads``: threads the scoring of independent places may use
    (:func:`twin.runtime.thread_map`; the same result with any number; the ``twin diagnose`` command uses every
    core).
    """
    if not (isinstance(threads, (int, np.integer)) and not isinstance(threads, bool) and threads >= 1):
        raise ValueError(f"threads must be a positive integer, got {threads!r}")
    if not (0 < alpha < 0.5):
        raise ValueError(f"alpha must be in (0, 0.5), got {alpha!r}")
    if not (0 < alpha_select < 0.5):
        raise ValueError(f"alpha_select must be in (0, 0.5), got {alpha_select!r}")
    if not (isinstance(max_effects, (int, np.integer)) and max_effects >= 0):
        raise ValueError(f"max_effects must be a non-negative integer, got {max_effects!r}")
    setup = prepare_diagnosis(dataset, calibration=calibration, holdout=holdout, seed=seed, q_start=q_start,
                              geometry=geometry, threads=int(threads))
    prob = setup.problem
    base = fit_geometry(prob, setup.x0)
    test0 = prob.test(base)
    # the selection starts when the held-out block or the block that fits is beyond the floor: a change in the middle
    # of the rows that fit leaves the held-out block after it in one state, which the geometry's frames absorb
    test_fit = prob.test_fit_block(base)
    excess = test0.p_value < alpha or test_fit.p_value < alpha
    if excess and not test0.p_value < alpha:
        setup.notes.append(f"the held-out block is within the floor (p = {test0.p_value:.2g}) but the rows that fit are "
                           f"not (p = {test_fit.p_value:.2g}, {test_fit.distribution}, whitened RMS "
                           f"{test_fit.whitened_rms:.3f}): terms are looked for there and must hold on the held-out block")
    if excess and setup.floor.lower_bound:
        setup.notes.append(evidence_scale(prob, base))
    sel = Selection(base)
    pool: list[Atom] = []
    if excess and max_effects > 0:
        pool, sizes = atom_pool(setup, generic=generic)
        sel = select_terms(prob, base, pool, sizes, max_effects=max_effects, alpha_select=alpha_select, z_min=z_min,
                           callback=callback)
        # the geometric model again, under the gross rows of the final one
        base = prob.fit(base.z[: setup.prep.space.size], [])
        test0 = prob.test(base)
    ext = sel.fit if sel.fit.chosen else None
    adoption, candidate = None, None
    if ext is not None:
        adoption = adopt(prob, base, ext)
        if not adoption["adopted"]:
            candidate, ext = ext, None
    structured, unexplained, notes_v = decide(prob, base, ext if candidate is None else candidate, test0, excess, z_min)
    use = ext if ext is not None else base
    atoms_json, params = describe_terms(prob, use, base.chi2, sel.entry_chi2) if ext is not None else ([], {})
    P = setup.prep.space.size
    geo_blocked = setup.geometric
    ext_blocked = replace(geo_blocked, method="best+effects" if ext is not None else geo_blocked.method,
                          x=use.z[:P] if ext is not None else geo_blocked.x, effects=tuple(atoms_json))
    # the models to use: the chosen terms refitted on every row of the campaign (the choice was made on the blocks;
    # the values take the campaign's whole time), with what every row holds after the blocks (step 9); the report
    # rows are predicted as the rows after the campaign are: by the same models on every row before them
    places = change_places(setup.prep.nominal, [a for a in pool if a.family == "compliance"], setup.ctx.q)
    late_gate = bool(pool) and prob.test(use).p_value < alpha
    # without a selection, the recorded temperature's templates for a change of the air in the campaign's last rows
    recorded = [] if pool else recorded_lag_atoms(setup.prep.nominal, setup.ctx, link_lengths(setup.prep.nominal))

    before_report = np.ones(setup.dataset.n, bool)
    if prob.obs_rep is not None:
        before_report[prob.rows_rep] = False
    refits: dict[bool, tuple] = {}  # the chosen models refitted on every row (False) or every row before the report

    def refit(pre: bool) -> tuple[Fit, Fit | None, Problem]:
        if pre not in refits:
            refits[pre] = refit_on_every_row(setup, base, ext, rows=before_report if pre else None)
        return refits[pre]

    def models(pre: bool):
        geo_x, ext_x, prob_x = refit(pre)
        ab = after_blocks(setup, prob_x, ext_x if ext_x is not None else geo_x, pool, places, late=late_gate,
                          alpha=alpha_select, z_min=z_min, recorded=recorded)
        return geo_x, (ab.fit if ext_x is not None or ab.found else None), prob_x, ab

    def blocked_extended(prob_x: Problem, after: AfterBlocks, fit: Fit) -> None:
        # the report's extended model: ``fit`` on the rows before the report block, what they hold after the blocks
        cal_rep, _, _ = describe_models(setup, prob_x, geo_all, ext_all, atoms_json, after, fit=on_rows(prob_x, fit))
        calibrations_blocked["extended"] = replace(cal_rep, details=ext_blocked.details)

    geo_all, ext_all, prob_all, after_all = models(False)
    rep = report_before_after(prob, base, ext)
    calibrations_blocked = {"geometric": geo_blocked, "extended": ext_blocked}
    fit_rep, prob_pre, use_rep = None, None, use
    thermal = ext is not None and any(retimeable(a) for a, _ in ext.chosen)
    moves = ext is not None and any(bend_unseen(prob, a) for a, _ in ext.chosen)
    if prob.obs_rep is not None and ext is not None and (thermal or moves
                                                         or any(reads_its_load(a) for a, _ in ext.chosen)):
        # a thermal term (the air's temperature, the motors' heat: a state that moves with time), a law of a joint's
        # load whose direction the rows read (the flank each row rests on) or a backlash growing with the last move
        # read in proportion (no bend shown by the rows that chose it): the report rows read the model refitted on
        # every row before them, those constants refined there, as the rows after the campaign read it refitted on
        # every row
        _, ext_pre, prob_pre = refit(True)
        use_rep = on_rows(prob, ext_pre)
        note = report_before_after(prob, base, use_rep)
        what, how = (("thermal terms", "the time constants of the air") if thermal else
                     ("laws of the last move", "their law and width") if moves else
                     ("load laws", "the direction of each joint's load"))
        note["note"] += (f"; the report rows read the model with its {what} refitted on every row before the "
                         f"report block ({how} refined there)")
        rep = note
        rep["held_out"]["report_state"] = f"{what} refitted on every row before the report block"
        blocked_extended(prob_pre, AfterBlocks(ext_pre, (), ()), ext_pre)
    if prob.obs_rep is not None and (after_all.found or after_all.changed):
        # the report rows read the state the rows before them leave (a change found there, with its size as they show
        # it), as the rows after the campaign read the state every row leaves; all else as the calibration rows fitted it
        _, _, prob_pre, after_pre = models(True)
        if not (after_pre.found or after_pre.changed):
            after_pre = AfterBlocks(use_rep, (), ())
        else:
            fit_rep = with_found(prob, prob_pre, use_rep, after_pre.fit)
            rep = report_before_after(prob, base, fit_rep, found=[a.label for a, *_ in after_pre.found])
            blocked_extended(prob_pre, after_pre, fit_rep)
    if prob.obs_rep is not None and ext_all is not None and any(is_change(a) for a, _ in ext_all.chosen):
        # the report rows read the changes where every row places them (a kept step that ends, a change late in the
        # campaign), their sizes as the rows before the report block show them
        if prob_pre is None:
            _, _, prob_pre = refit(True)
        if fit_rep is None:
            after_pre = AfterBlocks(use_rep, (), ())
        got = every_row_changes(prob, prob_pre, fit_rep if fit_rep is not None else use_rep, ext_all, len(use.chosen))
        if got is not None:
            fit_state, extra = got
            how = {a.key: f for f in list(after_all.found) + list(after_pre.found) for a in f[:1]}
            found = tuple(how.get(a.key, (a, "glitch", None, 0.0)) for a, _ in extra)
            note, rep_state = rep["note"], rep["held_out"].get("report_state")
            rep = report_before_after(prob, base, fit_state)
            rep["note"] = note + ("; the report rows read the changes where every row of the campaign places them ("
                                  + "; ".join(a.label for a, _ in fit_state.chosen if is_change(a))
                                  + "), their sizes as the rows before the report block show them")
            rep["held_out"]["report_state"] = (rep_state + "; " if rep_state else "") + "changes timed on every row"
            blocked_extended(prob_pre, AfterBlocks(fit_state, found, ()), fit_state)
    rep["held_out"].update(held_out_rows=setup.held_out.sets, blocks=setup.held_out.rule)
    candidate_terms: tuple = ()
    calibration_candidate = None
    if candidate is not None:
        cand_json, _ = describe_terms(prob, candidate, base.chi2, sel.entry_chi2)
        candidate_terms = tuple(cand_json)
        calibration_candidate = replace(setup.geometric, method="best+effects",
                                        x=candidate.z[: setup.prep.space.size], effects=candidate_terms)
        rep_c = report_before_after(prob, base, candidate)
        adoption["report_rms_mm"] = {"geometric": rep_c["before"]["position_mm"]["rms"],
                                     "extended": rep_c["after"]["position_mm"]["rms"]}
        notes_v.append(adoption["note"])
    frac, explained, notes_r = 0.0, False, []
    if rep["test_after"] is not None:
        tb, ta = rep["test_before"], rep["test_after"]
        explained = bool(structured and ta.p_value >= alpha)
        ex = tb.statistic - tb.dof
        frac = float(np.clip((tb.statistic - ta.statistic) / ex, 0.0, 1.0)) if ex > 0 else 1.0
        if not explained:
            notes_r.append(f"partial explanation: {100 * frac:.0f} % of the held-out excess (report rows) explained; "
                           f"the remainder is still structured (p = {ta.p_value:.2g})")
    rows = _rows_report(prob, setup)
    notes = setup.notes + sel.notes + notes_v + notes_r + [rep["note"]]
    if rows["gross_validation"] or rows["gross_calibration"]:
        notes.append(f"down-weighted gross rows (pose_id): calibration {rows['gross_calibration']}, "
                     f"validation {rows['gross_validation']}")
    notes += list(after_all.notes)
    extended, atoms_out, changes = describe_models(setup, prob_all, geo_all, ext_all, atoms_json, after_all,
                                                   update_minor=True)
    geo = replace(geo_blocked, x=geo_all.z[:P], details={**geo_blocked.details, "refitted_on_every_row": True})
    effects, unnamed, notes_n = name_effects(list(atoms_out))
    notes += notes_n
    structured = structured or bool(after_all.found)
    notes.append(f"calibration.json and calibration_geometric.json are the chosen models refitted on every row of the "
                 f"campaign ({prob_all.obs_cal.n} rows), with what those rows hold after the blocks (a change late in "
                 f"the campaign, a change and back); before/after are those of the models fitted on the {prob.obs_cal.n} "
                 "calibration rows, on report rows they never saw")
    return DiagnosisResult(
        structured=structured,
        p_value=float(test0.p_value),
        alpha=alpha,
        test_before=test0,
        test_after=prob.test(ext) if ext is not None else None,
        effects=effects,
        effect_parameters=params,
        explained=explained,
        before=rep["before"],
        after=rep["after"],
        noise=setup.floor,
        scores=tuple(sel.scores),
        calibration_geometric=geo,
        calibration=extended,
        series=_series(prob, base, use),
        notes=tuple(notes),
        atoms=atoms_out,
        unnamed=unnamed,
        alternatives=tuple(sel.alternatives),
        explained_fraction=frac,
        rows=rows,
        unexplained=unexplained,
        held_out=rep["held_out"],
        test_report={"before": rep["test_before"], "after": rep["test_after"]},
        model_in_use="extended" if ext_all is not None else "geometric",
        adoption=adoption,
        candidate_terms=candidate_terms,
        calibration_candidate=calibration_candidate,
        calibrations_blocked=calibrations_blocked,
        changes=tuple(changes),
        sampling=sampling_report(campaign_sampling(setup)),  # [configurations]
    )


def split_held_out(ds: Dataset, prep: Prepared, ctx: RowContext, *, fraction: float = REPORT_FRACTION,
                   min_visits: int = REPORT_MIN_VISITS) -> HeldOut:
    """The held-out rows ``prep.val`` (a block of time after the calibration rows: :func:`held_out_sets`) in two
    contiguous blocks (:func:`twin.diagnosis.blocks.confirm_and_report`): the earlier held-out rows confirm the
    terms, the last held-out session (when there are several) or the last ``fraction`` of the held-out visits report
    before/after; report rows whose approach history is unknown go to the confirmation block. With fewer than
    ``min_visits`` held-out visits there is no report block (``report`` None)."""
    val = np.asarray(prep.val, int)
    conf, rep, rule = confirm_and_report(ds, prep.rows[val], approach_unknown(ctx), fraction=fraction,
                                         min_visits=min_visits)
    return HeldOut(val[conf], None if rep is None else val[rep], rule)


def prepare_diagnosis(dataset: Dataset, *, calibration: Calibration | None = None, holdout: float | None = None,
                      seed: int = 0, q_start: np.ndarray | None = None, geometry: dict | None = None,
                      threads: int = 1) -> Setup:
    """Step 1: the floor, the rows (split, held-out blocks), the geometric identification and the problem."""
    if not isinstance(dataset, Dataset):
        raise ValueError(f"dataset must be a twin.dataset.Dataset, got {type(dataset).__name__}")
    gaps = temperature_gaps(dataset.temp_c, dataset.pose_id)
    if gaps:
        raise DiagnosisError(f"{gaps}: the diagnosis reads every row's temperature (its thermal terms); give those rows "
                             "their temperature, leave them out, or import without the temperature column")
    virtual = not dataset.has_spheres
    notes: list[str] = []
    if virtual:
        # a 6-DOF instrument (a tracker's probe): its poses read as three points of the tool frame
        dataset, note_virtual, assumed = virtual_spheres(dataset)
    blocks = held_out_sets(dataset, holdout)
    dataset = replace(dataset, set=blocks.set)
    # the virtual points' noise is the diagnosis' assumption (from the stated [noise]), not a stated figure
    floor = noise_floor(dataset, plate=not virtual, stated_ok=not virtual, assumed=assumed if virtual else None)
    notes.append(f"noise floor {floor.sigma / M_PER_MM:.5f} mm per coordinate from {floor.source}")
    if virtual:
        notes.append(note_virtual)
    notes.append(f"held-out rows: {blocks.rule}")
    prep = prepare(dataset, noise_position=floor.sigma, validation_fraction=0.0, seed=seed)
    if prep.val.size == 0:
        raise DiagnosisError("diagnosis needs held-out rows with measurements; none are usable")
    geo_opts = dict(geometry or {})
    bad = sorted(set(geo_opts) - {"level", "selection", "prior"})
    if bad:
        raise ValueError(f"geometry: unknown options {bad}; known: level, selection, prior")
    ctx = row_context(dataset, q_start)
    held = replace(split_held_out(dataset, prep, ctx), sets=blocks.rule)
    notes.append(f"confirmation and report blocks: {held.rule}")
    # the outlier rule needs the scatter a correct model leaves: not against a floor that is only a lower bound of it
    robust = {"robust": False} if floor.lower_bound else {}
    if geo_opts:
        ident = identify_best(prep, alpha=1e-6, **robust, **geo_opts)
        notes.append("geometric model: " + ", ".join(f"{k} {v}" for k, v in sorted(geo_opts.items())))
    else:
        geo_opts, ident, note = choose_geometry(prep, held.confirmation, robust)
        if note:
            notes.append(note)
    if calibration is not None:
        notes.append(f"the given calibration ({calibration.method}) was checked to be of this robot; the geometry is "
                     "identified anew from the nominal model on this dataset's rows that fit (its values are not used)")
    geo = build_calibration(prep, ident, "best", {"diagnosis": True, "noise_floor_mm": floor.sigma / M_PER_MM, **geo_opts})
    free_geo = np.flatnonzero(np.array(ident.status) == "identified")
    prob = Problem(prep, floor, ctx, free_geo, val=held.confirmation, rep=held.report, threads=threads)
    # rows that only register a station's frame do not make their session a fitted one
    sess = sessions(dataset)
    reg = np.isin(dataset.pose_id, [p for v in blocks.registration.values() for p in v])
    cal_rows = prep.rows[prep.cal]
    prob.cross_session = bool(len(np.unique(sess)) > 1 and not (set(sess[prep.rows[held.confirmation]].tolist())
                                                                & set(sess[cal_rows[~reg[cal_rows]]].tolist())))
    return Setup(dataset, virtual, floor, prep, np.asarray(ident.x, float), geo, ctx, held, prob, notes)


def geometry_candidates(model) -> list[dict]:
    """The geometric parameter sets blocked cross-validation chooses among: the estimator's own ordered set and, on a
    ``"urdf"`` chain, FIGAROH's full-parameter selection (:func:`twin.estimator.methods.identify_best`). Each is a set
    of free parameters, as every later fit of the diagnosis takes it (a prior on the deviations would hold in the
    geometric identification only: the terms are fitted by Gauss-Newton over the free parameters without it)."""
    return [{}] + ([{"selection": "figaroh"}] if model.convention == "urdf" else [])


def _geometry_name(opts: dict) -> str:
    return opts.get("selection", "ordered")


def choose_geometry(prep: Prepared, confirmation: np.ndarray, robust: dict) -> tuple[dict, Any, str]:
    """The geometric parameter set that predicts the confirmation block best (blocked cross-validation: each
    candidate of :func:`geometry_candidates` identified on the calibration rows, its position RMS on the
    confirmation rows, a later block of time or another session). Returns the options, the identification and a
    note (empty when there is one candidate)."""
    cands = geometry_candidates(prep.nominal)
    obs_c = prep.obs.subset(np.asarray(confirmation, int))
    best = None
    scores = []
    for opts in cands:
        ident = identify_best(prep, alpha=1e-6, **robust, **opts)
        rms = float(residual_stats(prep.space, np.asarray(ident.x, float), obs_c)["position_mm"]["rms"])
        scores.append((_geometry_name(opts), rms))
        if best is None or rms < best[2]:
            best = (opts, ident, rms)
    if len(cands) == 1:
        return best[0], best[1], ""
    chosen = _geometry_name(best[0])
    return best[0], best[1], ("geometric parameter set chosen on the confirmation block (position RMS there: "
                              + ", ".join(f"{name} {v:.4g} mm" for name, v in scores) + f"): {chosen}")


def evidence_scale(prob: Problem, base: Fit) -> str:
    """When the floor is only a lower bound of the scatter a correct model leaves (a motion-capture system's marker
    noise: the robot's own pose-to-pose scatter is not in it), a term's calibration evidence is measured against
    the geometric fit's residual scatter: ``prob.evidence_scale = max(1, chi2 / (m - p))`` on the kept calibration
    residuals (``Delta chi2 / scale``; the structure test keeps the floor). Returns the note saying so."""
    rc = base.model_cal.residuals(base.z, jacobian=False)
    w = prob.w_cal[rc.row]
    m = float(np.sum(w > 0))
    dof = max(m - base.free.size, 1.0)
    prob.evidence_scale = max(1.0, float(base.chi2) / dof)
    return (f"the floor is a lower bound of the scatter (the marker noise, not the robot's pose-to-pose scatter): a "
            f"term's evidence is measured against the geometric fit's residual scatter, {np.sqrt(prob.evidence_scale):.2f}x "
            "the floor per coordinate")


def fit_geometry(prob: Problem, x0: np.ndarray) -> Fit:
    """Step 2: the geometric model fitted on the calibration rows, refitted once its gross rows are down-weighted
    (calibration: weight 0; confirmation rows: left out of the test)."""
    fit = prob.fit(x0, [])
    update_gross(prob, fit)
    return prob.fit(fit.z[: prob.prep.space.size], [])


def atom_pool(setup: Setup, *, generic: bool = True) -> tuple[list[Atom], dict[str, int]]:
    """The atoms selection draws from (the catalogue, the cyclic scan, and with ``generic`` the dictionary) and
    the size of each pool (its Bonferroni factor)."""
    prep, ctx, ds = setup.prep, setup.ctx, setup.dataset
    length_names = link_lengths(prep.nominal)
    values: dict = {}
    cat = catalogue_atoms(prep.nominal, ctx, length_names, n_points=ds.spheres.shape[1],
                          whole_orders=not setup.problem.cross_session, values=values)
    setup.problem.seed_features(values, ctx, prep.nominal)
    pool = list(cat)
    if generic:
        # change points in time are the change scan's (every row), not a grid of the dictionary's
        pool += generic_atoms(prep.nominal, ctx, dictionary_parameters(prep.nominal), length_names, cat,
                              points=None if setup.virtual else ds.spheres, plate_spheres=ds.plate.spheres_flange,
                              n_change_points=0)
    if setup.virtual:
        pool = [a for a in pool if a.place != "plate"]  # the points are the tool frame's: no sphere to move
    # [configurations] a harmonic above the order its joint's sampling supports is not offered (aliasing)
    bounds = campaign_sampling(setup)
    pool = [a for a in pool if offered(a.features, bounds)]
    # a joint's backlash growing with the last move is one more reading of its backlash, its grid of laws and widths
    # paid for where it is preferred to the sign (twin.diagnosis.refine.prefer_sign): not more hypotheses of the pool
    counted = [a for a in pool if not (a.family == "backlash" and a.features[0].kind == "lastmove")]
    sizes = {k: max(1, sum(a.pool == k for a in counted)) for k in ("catalogue", "scan", "generic", "load")}
    sizes.update(change_pool_sizes(setup.problem.obs_cal.n, change_places(prep.nominal, cat, setup.ctx.q),
                                   short=selection_short(setup.problem.obs_cal.n)))
    return pool, sizes


def campaign_sampling(setup: Setup) -> tuple[JointSampling, ...]:
    """How the calibration rows sampled each joint and the highest harmonic order each supports
    (:func:`twin.diagnosis.configurations.joint_sampling`)."""
    prep = setup.prep
    return joint_sampling(setup.ctx.q[prep.rows[prep.cal]], [k == "revolute" for k in prep.nominal.joint_kinds],
                          max_order_checked=int(SCAN_ORDERS[1]))


def link_lengths(model) -> list[str]:
    """The link lengths thermal atoms may grow: ``d<i>``, ``a<i>`` of a 6R chain; the origin translation of each joint
    of a ``"urdf"`` chain as a whole (``"<joint>.xyz"``)."""
    if model.convention != "urdf":
        return [n for n in model.structure.param_names if n.rstrip("0123456789") in ("d", "a")]
    return [f"{j.name}.xyz" for j in model.structure.joints]


def dictionary_parameters(model) -> list[str]:
    """Structural parameters the unnamed dictionary lets vary (the joint offsets are the joint places): ``d``, ``a``,
    ``alpha``, ``beta`` of a 6R chain; a ``"urdf"`` chain's origin translations and rotations, except the one that
    moves like the joint itself (the rotation about a revolute joint's axis, the translation along a prismatic
    one's, when the axis is a coordinate axis of the joint frame)."""
    st = model.structure
    if model.convention != "urdf":
        return [n for n in st.param_names if n.rstrip("0123456789") in ("d", "a", "alpha", "beta")]
    out = []
    for fam in ("x", "y", "z", "rx", "ry", "rz"):
        for j in st.joints:
            ax = np.abs(np.asarray(j.axis))
            k = int(np.argmax(ax))
            same = ("r" if j.kind == "revolute" else "") + "xyz"[k]
            if fam == same and abs(ax[k] - 1.0) < 1e-12:
                continue
            out.append(f"{j.name}.{fam}")
    return out


def report_before_after(prob: Problem, base: Fit, ext: Fit | None, *, found: list[str] | None = None) -> dict[str, Any]:
    """Step 6: errors and structure tests of the geometric (``base``) and the extended model (``ext``, or the
    geometric one) on the report rows, which took no part in choosing or fitting the model (gross rows of the
    final model left out alike). Without a report block, on the confirmation rows, and ``held_out`` says so.
    ``found``: the terms found after the blocks on the rows before the report block that ``ext`` holds
    (:func:`with_found`), for the note."""
    use = ext if ext is not None else base
    if prob.obs_rep is not None:
        block = "report"
        mb, mu = prob.model([], "rep"), prob.model(use.chosen, "rep")
        r = mu.residuals(use.z, jacobian=False)
        keep = ~gross_rows(r.r, r.row, mu.obs.n)
        rows = prob.rows_rep
    else:
        block = "confirmation"
        mb, mu, keep, rows = base.model_val, use.model_val, prob.keep_val, prob.rows_val
    before = error_stats(mb, base.z, keep)
    after = error_stats(mu, use.z, keep) if ext is not None else before
    tb = prob.test(base, mb, keep)
    ta = prob.test(ext, mu, keep) if ext is not None else None
    pid = prob.prep.dataset.pose_id
    held = {"before_after_on": block, "n_confirmation_rows": int(prob.obs_val.n),
            "n_report_rows": int(keep.sum()), "report_pose_ids": [int(pid[i]) for i in rows[keep]],
            "gross_report_pose_ids": [int(pid[i]) for i in rows[~keep]]}
    note = (f"before/after on {int(keep.sum())} report rows, held out and used for nothing else (the terms were chosen "
            f"on the calibration rows and confirmed on {prob.obs_val.n} other held-out rows)" if block == "report" else
            f"before/after on the {int(keep.sum())} held-out rows that also confirmed the terms (too few held-out "
            "visits for a separate report block): optimistic")
    if found:
        note += (f"; the extended model reads the state the rows before the report block leave: {'; '.join(found)} "
                 "(found on those rows after the blocks, its size as they show it)")
    return {"before": before, "after": after, "test_before": tb, "test_after": ta, "held_out": held, "note": note}


def with_found(prob: Problem, prob_pre: Problem, use: Fit, after: Fit) -> Fit:
    """The model ``use`` (fitted on ``prob``'s calibration rows) with what was found after the blocks on the rows of
    ``prob_pre`` (every row before the report block; ``after``, fitted there: its atoms, the kept ones first, a kept
    step ended there as a window, then the terms found): the kept terms at ``use``'s values, the geometry and the
    terms found fitted on ``prob_pre``'s rows with them held (a glitch in the rows that fit biased the geometry they
    gave; the kept terms keep the values their rows gave them). On ``prob``'s rows."""
    P = prob.prep.space.size
    n = len(use.chosen)
    old = [use.z[use.model_cal.offsets[k]:use.model_cal.offsets[k + 1]] for k in range(n)]
    new = [after.z[after.model_cal.offsets[k]:after.model_cal.offsets[k + 1]] for k in range(n, len(after.chosen))]
    # a kept change takes its end from there; the other kept terms stay as chosen (constants and values)
    chosen = [after.chosen[k] if is_change(use.chosen[k][0]) else use.chosen[k] for k in range(n)] + \
        list(after.chosen[n:])
    # a kept change those rows time anew was sized under the timing they reject: it is sized again there, with the
    # kept terms at its place (the state outside it), as a change found there is
    retimed = {use.chosen[k][0].target for k in range(n) if chosen[k][0].key != use.chosen[k][0].key}
    mc = prob_pre.model(chosen, "cal")
    z0 = np.concatenate([after.z[:P]] + old + new)
    moving = np.concatenate([prob_pre.free_geo] + [np.arange(mc.offsets[k], mc.offsets[k + 1]) for k in range(n)
                                                   if chosen[k][0].target in retimed]
                            + [np.arange(mc.offsets[n], mc.size)]).astype(int)
    gn = gauss_newton(lambda z: mc.residuals(z), z0, moving, row_weights=prob_pre.w_cal, max_iter=30, xtol=1e-11,
                      ftol=1e-10, stage="report")
    free = np.concatenate([prob.free_geo, np.arange(P, mc.size)]).astype(int)
    return Fit(chosen, gn.x, free, float("nan"), prob.model(chosen, "cal"), prob.model(chosen, "val"))


def on_rows(prob: Problem, fit: Fit) -> Fit:
    """``fit``'s terms and values as a model of ``prob``'s rows (its calibration and confirmation models; the chi2
    left unknown)."""
    return Fit(fit.chosen, fit.z, fit.free, float("nan"), prob.model(fit.chosen, "cal"), prob.model(fit.chosen, "val"))


def every_row_changes(prob: Problem, prob_pre: Problem, cur: Fit, every: Fit, n_kept: int
                      ) -> tuple[Fit, list] | None:
    """The report model ``cur`` (on ``prob``'s rows; its first ``n_kept`` terms the kept ones, then those found after
    the blocks on the rows before the report block) with its changes where every row of the campaign places them
    (``every``, the model refitted on every row, its first ``n_kept`` terms the same): a kept change as ``every`` has
    it (a step that ends there, a window), and each change ``every`` found after the blocks of whose rows the rows
    before the report block (``prob_pre``'s calibration rows) include at least ``MIN_ROWS`` (a state a handful of
    rows hold is not sized there), in place of ``cur``'s own changes found after the blocks. Their sizes and the
    geometry are fitted on ``prob_pre``'s rows, the other terms held at ``cur``'s values: a change is located by
    every row, its size by the rows before the report block only. Returns the fit (on
    ``prob``'s rows) and its terms after the kept ones, or None when ``cur`` already holds ``every``'s changes."""
    P = prob.prep.space.size

    def seg(fit: Fit, k: int) -> np.ndarray:
        return fit.z[fit.model_cal.offsets[k]:fit.model_cal.offsets[k + 1]]

    def shown(atom) -> bool:
        F = np.abs(prob_pre.features(atom)[prob_pre.rows_cal]) > 0
        return int(np.sum(np.any(F.reshape(len(F), -1), axis=1))) >= MIN_ROWS

    # a change that holds from the first row on (a payload carried from the start and taken off) makes the state the
    # calibration rows fitted at its joint the changed one: the joint's other terms are sized again with it
    t_first = float(np.min(row_times(prob_pre.ctx)[1][prob_pre.rows_cal]))
    carried = {a.target for a, _ in every.chosen if is_window(a) and float(a.features[0].at) <= t_first}
    terms = []  # (term, value, moving)
    for k in range(n_kept):
        if is_change(cur.chosen[k][0]):
            terms.append((every.chosen[k], seg(every, k), True))
        else:
            terms.append((cur.chosen[k], seg(cur, k), cur.chosen[k][0].target in carried))
    terms += [(cur.chosen[k], seg(cur, k), cur.chosen[k][0].target in carried) for k in range(n_kept, len(cur.chosen))
              if not is_change(cur.chosen[k][0])]
    terms += [(every.chosen[k], seg(every, k), True) for k in range(n_kept, len(every.chosen))
              if is_change(every.chosen[k][0]) and shown(every.chosen[k][0])]
    old = sorted(a.key for a, _ in cur.chosen if is_change(a))
    if sorted(t[0].key for t, _, mv in terms if mv) == old:
        return None
    chosen = [t for t, _, _ in terms]
    mc = prob_pre.model(chosen, "cal")
    z0 = np.concatenate([cur.z[:P]] + [v for _, v, _ in terms])
    moving = np.concatenate([prob_pre.free_geo] + [np.arange(mc.offsets[k], mc.offsets[k + 1])
                                                   for k, (_, _, mv) in enumerate(terms) if mv]).astype(int)
    gn = gauss_newton(lambda z: mc.residuals(z), z0, moving, row_weights=prob_pre.w_cal, max_iter=30, xtol=1e-11,
                      ftol=1e-10, stage="report")
    free = np.concatenate([prob.free_geo, np.arange(P, mc.size)]).astype(int)
    return Fit(chosen, gn.x, free, float("nan"), prob.model(chosen, "cal"), prob.model(chosen, "val")), chosen[n_kept:]


FOUND = {"late": "after the rows that fit (located before a cut, confirmed after it)",
         "glitch": "on every row, a change and back (its own rows and the rows after it; nothing later depends on it)",
         "load": "on every row, the arm's own weight at a joint whose compliance a payload's change shows",
         "event": "on every row, the same payload's change (one timing) at another joint's compliance",
         "end": ("on every row, a change whose new state the campaign's last rows hold (too few rows after it to "
                 "confirm it on later rows: judged against the scatter of the rows before it)")}


def describe_models(setup: Setup, prob_x: Problem, geo_x: Fit, ext_x: Fit | None, atoms_json: list[dict],
                    after, *, update_minor: bool = False,
                    fit: Fit | None = None) -> tuple[Calibration, tuple[dict, ...], list[dict]]:
    """The extended model refitted on ``prob_x``'s rows (``ext_x``; the geometric ``geo_x`` when None) as a calibration,
    its terms (``atoms_json``, the chosen terms described on the calibration rows, then those ``after``
    (:class:`twin.diagnosis.after.AfterBlocks`) found, described on ``prob_x``'s rows, with how each was found) and its
    changes (:func:`describe_changes`, those found after the blocks with their confirmation). A term minor on the
    calibration rows that these rows need (a lag fitted to the first block's wander of the temperature, whose step
    came later) is not minor: with ``update_minor``, ``atoms_json``'s flags are set so. ``fit``: the extended model
    to describe instead of ``ext_x`` (on ``prob_x``'s rows)."""
    P = setup.prep.space.size
    ext_x = fit if fit is not None else ext_x
    base_cal = replace(setup.geometric, x=geo_x.z[:P], details={**setup.geometric.details, "refitted_on_every_row": True})
    if ext_x is None:
        return base_cal, tuple(atoms_json), []
    # a term found after the blocks is minor as a term entering the selection is, by what it explained when it
    # entered
    entries = [{"minor": a["minor"], "entry_chi2": a["entry_chi2"]} for a in atoms_json] + \
        [{"minor": True, "entry_chi2": float(dchi2)} for *_, dchi2 in after.found]
    final, _ = describe_terms(prob_x, ext_x, geo_x.chi2, {a.key: float(dchi2) for a, *_, dchi2 in after.found})
    final = [{**f, **e, "minor": bool(e["minor"] and f["minor"])} for f, e in zip(final, entries)]
    if update_minor:
        for a, f in zip(atoms_json, final):
            a["minor"] = f["minor"]
    extra = final[len(atoms_json):]  # the terms found after the blocks, in the order found
    for f, (_, how, _, _) in zip(extra, after.found):
        f["found"] = FOUND[how]
    late = {f["label"]: (got, how) for f, (_, how, got, _) in zip(extra, after.found)}
    changes = [late_json(*late[c["label"]], c, setup) if c["label"] in late else c
               for c in describe_changes(final, setup.ctx, setup.dataset.pose_id)]
    cal = replace(base_cal, method="best+effects", effects=tuple(final), x=ext_x.z[:P])
    return cal, tuple(atoms_json) + tuple(extra), changes


def late_json(late, how: str, change: dict, setup: Setup) -> dict:
    """The ``changes`` entry of a change found after the blocks (:mod:`twin.diagnosis.late`; ``how`` it was found, a
    key of ``FOUND``): ``change`` as :func:`describe_changes` gives it from its term refitted on every row, with where
    it was found and, for one confirmed after a cut (``late``), its confirmation."""
    d = dict(change)
    if late is None or isinstance(late, EndChange):
        d["found"] = FOUND[how]
        if late is not None:
            d["judged"] = late.judged()
        return d
    ch, _ = row_times(setup.ctx)
    d.update({"found": FOUND["late"],
              "confirmation": {f"cut_{ch}": late.cut, "n_rows_before_cut": late.n_before,
                               "n_rows_after_cut": late.n_after, "z": late.z,
                               "z_without_best_row": late.z_without_best_row,
                               "rms_after_cut_mm": {"without": late.rms_without_mm, "with": late.rms_with_mm}}})
    return d


def refit_on_every_row(setup: Setup, base: Fit, ext: Fit | None, *,
                       rows: np.ndarray | None = None) -> tuple[Fit, Fit | None, Problem]:
    """Step 8: the geometric model and the chosen extended model (its atoms and bases as chosen) refitted on every
    row of the campaign, calibration, confirmation and report rows alike, gross rows down-weighted anew, the time
    constants of its terms of the air refined again (:func:`twin.diagnosis.rule.retime`): the terms were chosen on
    blocks of time; the models a user takes to the next session use the whole campaign (a term of time ends where the
    campaign ends). ``rows`` (a mask of the dataset's rows): on those rows only, the others (the report block) the
    problem's confirmation rows. Returns both fits and their problem."""
    n = setup.dataset.n
    sets = np.full(n, "calibration", dtype=object) if rows is None else \
        np.where(rows, "calibration", "validation").astype(object)
    ds_all = replace(setup.dataset, set=sets)
    prep = prepare(ds_all, noise_position=setup.floor.sigma, validation_fraction=0.0)
    prob = Problem(prep, setup.floor, setup.ctx, setup.problem.free_geo,
                   val=prep.cal[-1:] if rows is None else prep.val, threads=setup.problem.threads_asked)
    prob.evidence_scale = setup.problem.evidence_scale
    prob.cross_session = setup.problem.cross_session
    geo = refit_with(prob, base, [])
    if ext is None:
        return geo, None, prob
    return geo, retime(prob, refit_with(prob, ext, ext.chosen)), prob


# ------------------------------------------------------------------------------------------------
# Reports
# ------------------------------------------------------------------------------------------------

VIRTUAL_ARM = 0.1  # [m] distance of the virtual points from the tool origin when poses are read as points


def virtual_spheres(ds: Dataset) -> tuple[Dataset, str, AssumedNoise | None]:
    """A pose dataset (``x y z rx ry rz``) as three points of the tool frame ``VIRTUAL_ARM`` along its x, y
    and z axes, measured where the pose puts them: every sphere-centre atom then applies (the plate's own atoms
    do not: the points are the tool frame's). The noise the diagnosis assumes per point coordinate is ``sqrt(sigma_p^2
    + (2/3) (L sigma_r)^2)`` from ``[noise]``'s stated ``sigma_p`` and ``sigma_r`` (a point inherits the rotation noise
    across its arm; None without a stated position noise); the dataset's own ``[noise]`` is left as stated. Returns
    the dataset, a note and that assumption."""
    if not ds.has_poses:
        raise DiagnosisError("diagnosis needs sphere centres (p0_x..p2_z) or poses (x y z rx ry rz); this dataset has "
                             "neither")
    L = VIRTUAL_ARM
    pts = np.eye(3) * L  # (3 points, xyz) in the tool frame
    R, t = ds.pose[:, :3, :3], ds.pose[:, :3, 3]
    spheres = np.einsum("nij,sj->nsi", R, pts) + t[:, None, :]
    seen = np.repeat(ds.pose_seen[:, None], 3, axis=1)
    spheres[~seen] = np.nan
    assumed = None
    if ds.noise_position is not None:
        sr = ds.noise_orientation or 0.0
        noise = float(np.sqrt(ds.noise_position**2 + (2.0 / 3.0) * (L * sr) ** 2))
        stated = {"position_mm": ds.noise_position / M_PER_MM, "orientation_rad": ds.noise_orientation}
        assumed = AssumedNoise(noise, "the diagnosis' assumption for the virtual points, sqrt(sigma_p^2 + (2/3) (L "
                               f"sigma_r)^2) with L = {L / M_PER_MM:.0f} mm from dataset.toml [noise] position_mm "
                               f"{stated['position_mm']:.6g} and orientation_rad "
                               f"{0.0 if ds.noise_orientation is None else ds.noise_orientation:.6g} (stated)", stated)
    # the marker set is stated in the flange frame: the virtual points through the nominal tool frame (the frame
    # the poses are measured in), so that the calibration's tool frame stays the measured one
    T = np.asarray(ds.robot.tool2flange, float)
    out = replace(ds, spheres=spheres, sphere_seen=seen, pose_seen=np.zeros(ds.n, bool),
                  plate=Plate(ds.plate.sphere_diameter, pts @ T[:3, :3].T + T[:3, 3]))
    return out, (f"poses read as three points of the tool frame {L / M_PER_MM:.0f} mm along its axes (virtual spheres); "
                 "the plate's own terms and the plate-distance floor do not apply"), assumed


def _rows_report(prob: Problem, setup: Setup) -> dict[str, Any]:
    pid = setup.dataset.pose_id
    prep = setup.prep
    gc = prep.rows[prep.cal][(prob.w_cal == 0) & ~prob.history_out]
    gv = prob.rows_val[~prob.keep_val]
    reset = np.flatnonzero(approach_unknown(prob.ctx))
    rep = [] if prob.rows_rep is None else [int(pid[i]) for i in prob.rows_rep]
    return {"gross_calibration": [int(pid[i]) for i in gc], "gross_validation": [int(pid[i]) for i in gv],
            "unknown_history": [int(pid[i]) for i in reset],
            "unknown_history_rule": "rows where a joint that moves has not moved since the start, a gap in t_s or "
                                    "a recorded restart: history-dependent terms read 0 there",
            "left_out_history": [int(pid[i]) for i in prep.rows[prep.cal][prob.history_out]],
            "left_out_history_rule": "calibration rows whose history a kept term needs and lacks, in runs of 2 rows "
                                     "up to a change's side: left out of the fit (the term reads 0 there, so they "
                                     "would carry its whole size unexplained); a lone such row stays in",
            "rule": "per-row misfit beyond the floor's 1e-6/n quantile and median + 8 MAD (at most 2 % of rows)",
            "confirmation": [int(pid[i]) for i in prob.rows_val], "report": rep,
            "held_out_rule": setup.held_out.rule}


def _point_vectors(m, r_m: np.ndarray) -> np.ndarray:
    """Residuals [m] in ``absolute_residuals`` order (point, coordinate, row) as vectors ``(n, K, 3)``, NaN where a
    point was not seen."""
    out = np.full((m.obs.spheres.shape[1], 3, m.obs.n), np.nan)
    out[np.broadcast_to(m.obs.seen.T[:, None, :], out.shape)] = r_m
    return np.transpose(out, (2, 0, 1))


def _series(prob: Problem, base: Fit, ext: Fit) -> dict[str, np.ndarray]:
    """Per held-out row (confirmation and report rows, in dataset order): residual norms before/after [mm], the
    residual vectors before/after ``(n, K, 3)`` [m] (measured minus predicted) at the measured points ``measured_m``
    [m] (each row's station's measurement frame, NaN where not seen), the station, the commanded joints ``q``
    [rad; m], the block it belongs to, each term of the extended model, and the most telling variables."""
    blocks = [("confirmation", prob.rows_val, base.model_val, ext.model_val)]
    if prob.obs_rep is not None:
        blocks.append(("report", prob.rows_rep, prob.model([], "rep"), prob.model(ext.chosen, "rep")))
    rows_all = np.concatenate([b[1] for b in blocks])
    order = np.argsort(rows_all, kind="stable")
    rows_val = rows_all[order]
    out: dict[str, np.ndarray] = {"dataset_row": rows_val, "pose_id": prob.prep.dataset.pose_id[rows_val],
                                  "block": np.concatenate([[name] * len(r) for name, r, _, _ in blocks])[order]}
    for tag, idx in (("before", 2), ("after", 3)):
        z = base.z if tag == "before" else ext.z
        e_all, v_all = [], []
        for b in blocks:
            m = b[idx]
            r = m.residuals(z, jacobian=False)
            e, _ = row_rms(m.unwhiten(r.r), r.row, m.obs.n)
            e_all.append(e / M_PER_MM)
            v_all.append(_point_vectors(m, m.unwhiten(r.r)))
        out[f"residual_rms_mm_{tag}"] = np.concatenate(e_all)[order]
        out[f"residual_vector_m_{tag}"] = np.concatenate(v_all)[order]
    obs = [b[2].obs for b in blocks]
    out["measured_m"] = np.concatenate([np.where(o.seen[..., None], o.spheres, np.nan) for o in obs])[order]
    out["station"] = np.concatenate([np.asarray(o.station_names, dtype=object)[o.station] for o in obs])[order]
    out["q"] = np.concatenate([o.q for o in obs])[order]
    # each term of the extended model on the held-out rows, in its place's display unit
    terms = {}
    for k in range(len(ext.chosen)):
        vals = []
        for b in blocks:
            m = b[3]
            t = m.terms[k]
            phi = m.split(ext.z)[1][k]
            vals.append(term_values(m, t, phi))
        unit, _ = place_unit(ext.chosen[k][0])
        a = ext.chosen[k][0]
        if a.place == "param" and a.target in ("tool", "base"):
            unit = "mm (translation)"
        terms[a.label] = {"value": np.concatenate(vals)[order], "unit": unit, "channel": a.channel}
    out["terms"] = terms
    ctx = prob.ctx
    # deg, mm for a prismatic joint
    out["q_deg"] = ctx.q[rows_val] / np.where(prob.prep.nominal.is_prismatic, M_PER_MM, RAD_PER_DEG)
    out["approach_sign"] = history_signs(ctx)[rows_val]
    if ctx.temp_c is not None:
        out["temp_c"] = ctx.temp_c[rows_val]
    if ctx.t_s is not None:
        out["t_s"] = ctx.t_s[rows_val]
    return out


# Vocabulary check at import: every catalogue name is documented.
assert set(EFFECT_VOCABULARY) == {"compliance", "backlash", "cyclic", "gear_ratio", "coupling", "thermal", "plate_geometry",
                                  "tilt"}
