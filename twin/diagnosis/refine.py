"""Refining a kept term: its continuous constant (a change point's time, a time constant, a move width, a clearance, a
period, an order, a pull's angle) moved from the coarse grid it was found on to the value that explains most, a sign
backlash replaced by the play operator that explains significantly more, a broad term widened to its further
directions when they add evidence.
"""

from __future__ import annotations

from dataclasses import replace as replace_atom

import numpy as np

from ..estimator import distributions as dists
from ..units import MM_PER_M, deg_to_rad, rad_to_deg
from .atoms import (BACKLASH_MOVE_LAWS, BACKLASH_MOVE_REFINED_LAWS, BACKLASH_MOVE_WIDTHS_DEG, HINGE_POINTS, MIN_ROWS,
                    MIN_SIDE, PLAY_HALF_DEG, Atom, hinge_atom, joint_words, play_backlash, sign_backlash, started_at)
from .extend import error_stats, reduced_basis
from .features import Exp, Feature, Heat, Lag, Pow, Step, StepIn
from .problem import Fit, Problem, refit_with
from .scoring import Scored, memo_on_fit, raw_columns, score_atoms, scoring_basis
from .structure import chi2_logsf
from .values import feature_values

__all__ = ["bend_unseen", "prefer_play", "prefer_sign", "recorded_lag", "refine", "refine_gap", "refine_onset",
           "refine_time", "retimeable", "follows_the_air", "is_onset", "onset_atom", "onset_lag", "polish_in_fit",
           "prefer_heat", "widen", "clip_value", "ONSET_POINTS", "ONSET_TAUS", "ONSET_RAMPS"]

ONSET_POINTS = 20  # onsets (or a ramp's middles) tried, on the quantiles 0-95 % of the calibration rows' times
ONSET_TAUS = tuple(2.0 ** np.arange(-6, 3))  # time constants tried, as fractions of the calibration rows' span
ONSET_RAMPS = (0.0, 0.25, 0.5, 1.0)  # the air's ramp durations tried (0: a step), as fractions of that span
ONSET_TRIALS = ONSET_POINTS * len(ONSET_TAUS) * len(ONSET_RAMPS)  # the onset grid's size (its Bonferroni factor)
# where in an interval between recorded rows the recorded air's change is tried (fractions of it; then refined)
GAP_FRACTIONS = tuple(np.linspace(0.0, 1.0, 9))
ONSET_SIDE = 0.05  # rows after an onset, at least this share of them and 3 (a change's: twin.diagnosis.changes.MIN_SIDE)


def prefer_play(prob: Problem, fit: Fit, scored: list[Scored], pool_sizes: dict[str, int]) -> list[Scored]:
    """Each scored sign backlash (the offset follows the direction of the last move) replaced by the backlash as
    a play operator with the half clearance that explains most (``PLAY_HALF_DEG``, then refined), when that
    explains significantly more: beyond ``chi2_1`` at 1 % / the number of clearances tried, on at least 3
    calibration rows where the two differ (rows after a move shorter than the clearance, which does not switch
    the side). Both are the one backlash of that joint, so they compete as one candidate: a joint with a
    clearance and short moves is not left to an unnamed function of its last move."""
    out = []
    for s in scored:
        if s.atom.family != "backlash" or {f.kind for f in s.atom.features} != {"sign"}:
            out.append(s)
            continue
        j = s.atom.features[0].j
        trial = score_atoms(prob, fit, [play_backlash(j, deg_to_rad(hd)) for hd in PLAY_HALF_DEG], pool_sizes,
                            exact_top=len(PLAY_HALF_DEG))
        top = max(trial, key=lambda t: t.dchi2, default=None)
        better = top is not None and (top.dchi2 - s.dchi2) / prob.evidence_scale >= dists.chi2_isf(0.01 / len(PLAY_HALF_DEG), 1)
        if better:
            f_sign = prob.features(s.atom)[prob.rows_cal, 0]
            f_play = prob.features(top.atom)[prob.rows_cal, 0]
            better = int(np.sum(np.abs(np.abs(f_play) - np.abs(f_sign)) > 0.5)) >= 3
        out.append(top if better else s)
    return out


def prefer_sign(prob: Problem, fit: Fit, scored: list[Scored], pool_sizes: dict[str, int]) -> list[Scored]:
    """The backlashes growing with the size of the last move (``lastmove``) of a joint left out of ``scored`` where a
    simpler reading explains nearly as much: the joint's sign (or play) backlash, scored beside them, or the step
    into the row in proportion (a joint still settling from the move it just made: the same numbers wherever the
    joint moves into every row; it differs from the last move only on the rows that did not move). The size of the
    move must add evidence beyond ``chi2_1`` at 1 % / the number of laws and widths tried
    (``BACKLASH_MOVE_WIDTHS_DEG``, ``BACKLASH_MOVE_LAWS``) over each. Both backlashes are the one backlash of the
    joint; a sign followed by the size of a few moves' noise mispredicts every short move after the campaign. Against
    the sign the size is also judged nested: scored on the model refitted with the joint's sign backlash, it must add
    that evidence beyond it (two readings of one strong backlash differ by a linearised score's small error of it,
    which a difference of their scores takes for evidence), and the model with it must predict the confirmation rows
    better than the model with the sign.

    Where the joint moves into every row, the step and a size law in proportion to the move are the same numbers; which
    one the rows hold is told by the other joints: an arm still settling from its moves lags on every joint it moved
    (the step into the row of another joint adds evidence beyond this joint's, at 1 % / the other joints), a backlash
    is one joint's. On an arm that settles, the size must also add that evidence nested, scored on the model refitted
    with the joint's step (a linear lag whose gain follows the pose leaks into a curved law's score at high
    signal-to-noise), and with the steps of the other joints that settle (their lag, not yet in the model, leaks into
    it too); where the joint alone follows its move, the size is kept wherever the step does not explain
    significantly more (by the bar above) and the joint's step leaves the round: the catalogue's reading of those
    numbers, a backlash that grows with the move up to a size and predicts the longer moves after the campaign."""
    sizes = [s for s in scored if s.atom.family == "backlash" and s.atom.features[0].kind == "lastmove"]
    if not sizes:
        return scored
    rival: dict[str, float] = {}
    sign: dict[str, Scored] = {}
    for s in scored:
        if s.atom.family == "backlash" and {f.kind for f in s.atom.features} <= {"sign", "play"}:
            rival[s.atom.target] = max(rival.get(s.atom.target, -np.inf), s.dchi2)
            if s.dchi2 >= max((x.dchi2 for x in sign.values() if x.atom.target == s.atom.target), default=-np.inf):
                sign[s.atom.target] = s
    targets = sorted({s.atom.target for s in sizes})
    steps = [Atom("unnamed", "joint", t, (StepIn(j=int(t[5:])),), f"step into the row j{t[5:]}",
                  f"unnamed: joint {t[5:]} angle varies with step into the row j{t[5:]}", "generic", (int(t[5:]),))
             for t in targets]
    # the joint's sign backlash, scored here where the round's pool no longer holds it (rejected in an earlier round:
    # its size law is the same backlash and no better reading of it)
    signs = [sign_backlash(int(t[5:])) for t in targets if t not in sign]
    step_of: dict[str, Scored] = {}
    for s in score_atoms(prob, fit, steps + signs, pool_sizes, exact_top=len(steps) + len(signs)):
        if s.atom.features[0].kind == "stepin":
            step_of[s.atom.target] = s
        else:
            rival[s.atom.target] = max(rival.get(s.atom.target, -np.inf), s.dchi2)
    bar = dists.chi2_isf(0.01 / (len(BACKLASH_MOVE_WIDTHS_DEG) * len(BACKLASH_MOVE_LAWS)), 1) * prob.evidence_scale
    keep: dict[str, Scored] = {}
    alone: set[str] = set()  # joints whose step leaves the round: their size law reads it
    for t in targets:
        top = max((s for s in sizes if s.atom.target == t), key=lambda s: s.dchi2)
        if top.logp_adj >= np.log(0.01):
            continue  # not significant: it competes as scored (it will not be tried)
        # at its best law and width, not the grid's (the linear step is the wide limit of both laws)
        top = refine(prob, fit, top, pool_sizes)
        if top.dchi2 - rival.get(t, -np.inf) < bar or _beyond_sign(prob, fit, top, sign.get(t), pool_sizes) < bar:
            continue
        step = step_of.get(t)
        if step is None:
            keep[t] = top
        elif (settling := _settling(prob, fit, step, top, pool_sizes)) is not None:
            if top.dchi2 - step.dchi2 >= bar and _beyond(prob, fit, top, [step] + settling, pool_sizes) >= bar:
                keep[t] = top
        elif step.dchi2 - top.dchi2 < bar:
            keep[t] = top
            alone.add(t)
    out = []
    for s in scored:
        if s.atom.family == "backlash" and s.atom.features[0].kind == "lastmove":
            if s.atom.target in keep:
                out.append(keep.pop(s.atom.target))  # the refined one, in the place of the joint's grid atoms
            continue
        if s.atom.target in alone and len(s.atom.features) == 1 and isinstance(s.atom.features[0], StepIn) \
                and f"theta{s.atom.features[0].j}" == s.atom.target:
            continue
        out.append(s)
    return out


@memo_on_fit
def _settling(prob: Problem, fit: Fit, step: Scored, size: Scored, pool_sizes: dict[str, int]) -> list[Scored] | None:
    """The other joints of an arm that settles from its moves beyond the joint of ``step`` (its step into the row) and
    ``size`` (its backlash growing with the last move), or None where that joint alone follows its moves: another
    joint's step into the row on that joint's angle already in ``fit``, and each one that adds evidence beyond
    ``chi2_1`` at 1 % / the other joints to ``fit`` refitted with the better of the two readings (returned)."""
    j = int(step.atom.target[5:])
    n = prob.ctx.q.shape[1]
    others = [Atom("unnamed", "joint", f"theta{k}", (StepIn(j=k),), f"step into the row j{k}",
                   f"unnamed: joint {k} angle varies with step into the row j{k}", "generic", (k,))
              for k in range(1, n + 1) if k != j]
    held = {a.key for a, _ in fit.chosen}
    before = any(a.key in held for a in others)
    others = [a for a in others if a.key not in held]
    if not others:
        return [] if before else None
    best = max((step, size), key=lambda s: s.dchi2)
    gross = (prob.w_cal, prob.keep_val, prob.history_out)
    try:
        with_best = refit_with(prob, fit, list(fit.chosen) + [(best.atom, best.basis)])
        got = score_atoms(prob, with_best, others, pool_sizes, exact_top=len(others))
    finally:
        prob.w_cal, prob.keep_val, prob.history_out = gross
    bar = dists.chi2_isf(0.01 / len(others), 1) * prob.evidence_scale
    more = [g for g in got if g.dchi2 >= bar]
    return more if more or before else None


@memo_on_fit
def _beyond(prob: Problem, fit: Fit, size: Scored, others: list[Scored], pool_sizes: dict[str, int]) -> float:
    """The evidence ``size`` adds to ``fit`` refitted with ``others``."""
    gross = (prob.w_cal, prob.keep_val, prob.history_out)
    try:
        with_others = refit_with(prob, fit, list(fit.chosen) + [(o.atom, o.basis) for o in others])
        got = score_atoms(prob, with_others, [size.atom], pool_sizes, exact_top=1)
    finally:
        prob.w_cal, prob.keep_val, prob.history_out = gross
    return got[0].dchi2 if got else 0.0


@memo_on_fit
def _beyond_sign(prob: Problem, fit: Fit, size: Scored, sign: Scored | None, pool_sizes: dict[str, int]) -> float:
    """The evidence ``size`` (a backlash growing with the last move) adds to ``fit`` refitted with the joint's sign
    backlash ``sign``; 0 when the model with ``size`` in place of ``sign`` does not predict the confirmation rows
    better than the model with ``sign`` (inf without a sign backlash)."""
    if sign is None:
        return np.inf
    gross = (prob.w_cal, prob.keep_val, prob.history_out)  # each reading's own gross rows, for this comparison only
    try:
        with_sign = refit_with(prob, fit, list(fit.chosen) + [(sign.atom, sign.basis)])
        got = score_atoms(prob, with_sign, [size.atom], pool_sizes, exact_top=1)
        with_size = refit_with(prob, fit, list(fit.chosen) + [(size.atom, size.basis)])
    finally:
        prob.w_cal, prob.keep_val, prob.history_out = gross
    held = [error_stats(f.model_val, f.z, gross[1])["position_mm"]["rms"] for f in (with_size, with_sign)]
    return got[0].dchi2 if got and held[0] < held[1] else 0.0


@memo_on_fit
def refine(prob: Problem, fit: Fit, s: Scored, pool_sizes: dict[str, int]) -> Scored:
    """An atom with a continuous constant found on a coarse grid, moved to the value that explains most: a change
    point to the row time between its grid neighbours (the step's time is a parameter of the effect, not of the
    grid); a time constant (``exp``, ``lag``), a move width (``lastmove``), a clearance (``play``) or a period
    in time (``sin``/``cos`` of ``t_s``) over a log grid around it, zoomed twice, then to the maximum of the
    evidence within the last grid step (bounded scalar search: a play's clearance must be right to a fraction of
    a per cent, or the rows after short moves are mispredicted by that fraction of the clearance). Other atoms
    come back as they are."""
    kinds = {f.kind for f in s.atom.features}
    if kinds == {"lastmove"} and s.atom.family == "backlash":
        # a backlash growing with the size of the last move (saturating smoothly, in proportion up to a size, or taken
        # up at a rate in proportion to what is left)
        # each law (saturating smoothly, in proportion up to a size) at its own best width, the one that explains
        # more; the first-order take-up, a law beyond the pool's grid, only where it explains more than both by
        # chi2_1 at 1 % (one more hypothesis: near the sign's limit the three differ by a few rows' noise)
        others = [_with_law(s.atom, law) for law in BACKLASH_MOVE_REFINED_LAWS if law != s.atom.features[0].law]
        got = [_refine_constant(prob, fit, c, pool_sizes)
               for c in [s] + score_atoms(prob, fit, others, pool_sizes, exact_top=len(others))]
        grid = [t for t in got if t.atom.features[0].law in BACKLASH_MOVE_LAWS] or got
        top = max(grid, key=lambda t: t.dchi2)
        extra = max((t for t in got if t.atom.features[0].law not in BACKLASH_MOVE_LAWS), key=lambda t: t.dchi2,
                    default=None)
        if extra is not None and extra.dchi2 - top.dchi2 >= dists.chi2_isf(0.01, 1) * prob.evidence_scale:
            top = extra
        return _seen_saturation(prob, fit, top, pool_sizes)
    return _refine_constant(prob, fit, s, pool_sizes)


def _seen_saturation(prob: Problem, fit: Fit, s: Scored, pool_sizes: dict[str, int]) -> Scored:
    """A backlash growing with the size of the last move ``s`` at its best law and width, or the backlash in proportion
    to every move the calibration rows saw (``clip`` at the largest of them) where ``s`` does not explain more by
    ``chi2_1`` at 1 %: a saturation the rows do not show is not placed (where the moves stay short of it, the widths
    that bend the law within the moves seen and those beyond them explain alike, and a bend placed within them
    mispredicts every longer move after the campaign)."""
    j = s.atom.features[0].j
    step = prob.features(Atom("unnamed", "joint", s.atom.target, (StepIn(j=j),), "", "", "generic", (j,)))
    seen = float(np.max(np.abs(step[:, 0]), initial=0.0))
    if seen <= 0.0:
        return s
    got = score_atoms(prob, fit, [_with_constant(_with_law(s.atom, "clip"), "w", seen)], pool_sizes, exact_top=1)
    if got and s.dchi2 - got[0].dchi2 < dists.chi2_isf(0.01, 1) * prob.evidence_scale:
        return got[0]
    return s


# each law's name in a lastmove atom's channel (expsat(x): sign(x) (1 - exp(-|x|)))
LAW_WORDS = {None: "tanh(", "clip": "clip(", "exp": "expsat("}


def _with_law(atom: Atom, law: str | None) -> Atom:
    """A backlash growing with the size of the last move (``lastmove`` features) with the law ``law`` (``None``:
    ``tanh``, ``"clip"``, ``"exp"``: :class:`~twin.diagnosis.features.LastMove`); channel and label to match."""
    old, new = LAW_WORDS[atom.features[0].law], LAW_WORDS[law]
    return replace_atom(atom, features=tuple(replace_atom(g, law=law) for g in atom.features),
                        channel=atom.channel.replace(old, new), label=atom.label.replace(old, new))


def _refine_constant(prob: Problem, fit: Fit, s: Scored, pool_sizes: dict[str, int]) -> Scored:
    """:func:`refine` of one atom (its law as given)."""
    kinds = {f.kind for f in s.atom.features}
    if "step" in kinds:
        return _refine_step(prob, fit, s, pool_sizes)
    if is_onset(s.atom):
        return refine_onset(prob, fit, s, pool_sizes)
    if _time_linear(s.atom):
        # a drift of the links linear in time is the air's ramp that the rows did not see end, through no lag: the
        # onset's shapes hold it (and, seen to end, its end)
        t = np.asarray(prob.ctx.t_s, float)[prob.rows_cal]
        got = score_atoms(prob, fit, [_as_onset(s.atom, float(np.min(t)), float(np.ptp(t)))], pool_sizes, exact_top=1)
        top = refine_onset(prob, fit, got[0], pool_sizes) if got else s
        return top if top.dchi2 > s.dchi2 else s
    if _temp_linear(s.atom) and prob.ctx.t_s is not None:
        # the links follow the recorded temperature through a lag, of any length, zero included
        span = float(np.ptp(np.asarray(prob.ctx.t_s, float)[prob.rows_cal]))
        trial = [_temp_lagged(s.atom, fc * span) for fc in ONSET_TAUS] if span > 0 else []
        top = max(score_atoms(prob, fit, trial, pool_sizes, exact_top=len(trial)), key=lambda x: x.dchi2, default=None)
        if top is None or top.dchi2 <= s.dchi2:
            return s
        s = top
        kinds = {f.kind for f in s.atom.features}
    if kinds == {"hinge"}:
        return _refine_hinge(prob, fit, s, pool_sizes)
    if s.atom.pool == "scan" and kinds <= {"sin", "cos"}:
        # an order off the whole cycles per joint turn only where terms are confirmed on another session
        return _refine_order(prob, fit, s, pool_sizes) if prob.cross_session else s
    timely = all(getattr(f, "ch", None) in ("t_s", "row") for f in s.atom.features)
    if any(_has(f, "tau") for f in s.atom.features):  # exp, lag, heat, settle, a field warming up
        key = "tau"
    elif "lastmove" in kinds or "play" in kinds:
        key = "w" if "lastmove" in kinds else "h"
    elif kinds <= {"sin", "cos"} and timely:
        key = "k"
    else:
        key = None
    if key is None:
        return s
    span_max = 4.0 if key != "k" else 1.25  # a period is sharp: zoom within +-25 % of the grid's
    best = s
    v0 = _constant(s.atom.features, key)
    for span in (span_max, span_max ** 0.25):
        vals = [v0 * span ** x for x in np.linspace(-1, 1, 9) if x != 0]
        trial = [_with_constant(best.atom, key, v) for v in vals]
        scored = score_atoms(prob, fit, trial, pool_sizes, exact_top=len(trial))
        top = max(scored, key=lambda t: t.dchi2, default=None)
        if top is not None and top.dchi2 > best.dchi2:
            best = top
        v0 = _constant(best.atom.features, key)
    return _polish(prob, fit, best, key, span_max ** (0.25 * 0.25), pool_sizes)


def polish_in_fit(prob: Problem, fit: Fit, k: int, key: str, ratio: float = 1.05) -> Fit:
    """The kept atom ``k`` of ``fit`` with its constant ``key`` moved to the minimum of the calibration chi2 of the
    whole model refitted (Gauss-Newton, the joint terms applied exactly), within a factor ``ratio`` of its value
    (bounded Brent search on its log, to 1e-4 of it). The linearised evidence that placed it is biased at the
    noise level when the effect is large (a 0.3 deg clearance moves the plate ~4 mm: its second-order term is
    ~10 um), and a clearance must be right to a fraction of a per cent."""
    from scipy.optimize import minimize_scalar

    atom, B = fit.chosen[k]
    v0 = _constant(atom.features, key)
    x = fit.z[: prob.prep.space.size]
    best = [fit]

    def cost(u: float) -> float:
        chosen = list(fit.chosen)
        chosen[k] = (_with_constant(atom, key, v0 * np.exp(u)), B)
        f = prob.fit(x, chosen, _psi_like(fit, chosen))
        if f.chi2 < best[0].chi2:
            best[0] = f
        return f.chi2

    minimize_scalar(cost, bounds=(-np.log(ratio), np.log(ratio)), method="bounded", options={"xatol": 1e-4})
    return best[0]


def _psi_like(fit: Fit, chosen: list) -> list[np.ndarray]:
    """Start values: the fit's reduced coordinates position by position (a term whose constant changed keeps
    its coefficients)."""
    return [fit.z[fit.model_cal.offsets[k]:fit.model_cal.offsets[k + 1]].copy() for k in range(len(chosen))]


def _polish(prob: Problem, fit: Fit, s: Scored, key: str, ratio: float, pool_sizes: dict[str, int],
            make=None) -> Scored:
    """``s`` with its constant ``key`` moved to the maximum of the calibration evidence within a factor ``ratio``
    of its value (bounded Brent search on the log of the constant, to 1e-4 of it); ``make(atom, v)`` builds the
    atom with the constant ``v`` (default: :func:`_with_constant`)."""
    from scipy.optimize import minimize_scalar

    make = make or (lambda atom, v: _with_constant(atom, key, v))
    v0 = _constant(s.atom.features, key)
    best = [s]

    def cost(u: float) -> float:
        got = score_atoms(prob, fit, [make(s.atom, v0 * np.exp(u))], pool_sizes, exact_top=1)
        if not got:
            return 0.0
        if got[0].dchi2 > best[0].dchi2:
            best[0] = got[0]
        return -got[0].dchi2

    minimize_scalar(cost, bounds=(-np.log(ratio), np.log(ratio)), method="bounded", options={"xatol": 1e-4})
    return best[0]


def _with_order(atom: Atom, k: float) -> Atom:
    """A scanned cyclic atom with its order (cycles per joint turn) set to ``k``; channel and label to match."""
    k0 = atom.features[0].k
    feats = tuple(replace_atom(f, k=float(k)) for f in atom.features)
    ch = atom.features[0].ch
    return replace_atom(atom, features=feats, channel=f"sin/cos({k:.4g} {ch})",
                label=atom.label.replace(f"order {k0:.4g}", f"order {k:.4g}"), meta=dict(atom.meta, order=float(k)))


def _refine_order(prob: Problem, fit: Fit, s: Scored, pool_sizes: dict[str, int]) -> Scored:
    """A scanned cyclic order (half-order grid) moved to the order that explains most within half a grid step
    (a stage's ratio need not be a half-integer), zoomed twice, then polished within the last grid step."""
    best = s
    for half in (0.25, 0.06):
        k0 = best.atom.features[0].k
        trial = [_with_order(best.atom, k) for k in k0 + np.linspace(-half, half, 9) if k > 0 and k != k0]
        scored = score_atoms(prob, fit, trial, pool_sizes, exact_top=len(trial))
        top = max(scored, key=lambda t: t.dchi2, default=None)
        if top is not None and top.dchi2 > best.dchi2:
            best = top
    k0 = best.atom.features[0].k
    return _polish(prob, fit, best, "k", 1.0 + 0.015 / k0, pool_sizes, make=_with_order)


def widen(prob: Problem, fit: Fit, s: Scored, alpha_select: float, max_rank: int = 18) -> Scored:
    """An accepted atom was scored on at most 6 directions (a broad atom must not fit noise); its further
    directions above 1 % of a unit column are kept when together they add significant calibration evidence
    (``chi2_sf(Delta chi2_more - Delta chi2, extra) < alpha_select``): a frame swaying in time moves along its
    six axes with a sine and a cosine, twelve directions."""
    sb = scoring_basis(prob, fit)
    rc, sw, keep, Q = sb.rc, sb.sw, sb.keep, sb.Q
    F = prob.features(s.atom)[prob.rows_cal]
    E = raw_columns(fit.model_cal, s.atom, F, fit.z, rc)[keep] * sw[keep][:, None]
    B = reduced_basis(E, Q=Q, max_rank=max_rank)
    if B.shape[1] <= s.basis.shape[1]:
        return s
    EB = E @ B
    Ep = EB - Q @ (Q.T @ EB)
    psi, *_ = np.linalg.lstsq(Ep, s.r, rcond=None)
    fitted = Ep @ psi
    d = float(fitted @ fitted)
    if chi2_logsf(max(d - s.dchi2, 0.0) / prob.evidence_scale, B.shape[1] - s.basis.shape[1]) >= np.log(alpha_select):
        return s
    return Scored(s.atom, B, psi, d, s.logp_adj, s.r, E=EB, Ep=Ep)


def _has(f: Feature, key: str) -> bool:
    """Whether the feature ``f`` has the constant ``key`` (a field of its kind, set)."""
    return getattr(f, key, None) is not None


def _constant(features, key: str):
    """The constant ``key`` of the first of ``features`` that has it (:func:`_has`)."""
    return next(getattr(f, key) for f in features if _has(f, key))


def _with_constant(atom: Atom, key: str, v: float) -> Atom:
    """``atom`` with the constant ``key`` (``tau`` [s], ``w`` or ``h`` [rad], ``k`` [rad/s]) of its features set to
    ``v``; channel and label renamed to match."""
    old = _constant(atom.features, key)
    feats = tuple(replace_atom(f, **{key: float(v)}) if _has(f, key) else f for f in atom.features)
    if key == "tau":
        o, n = f"{old:.4g}", f"{v:.4g}"
    elif key == "k":
        o, n = f"{2 * np.pi / old:.4g}", f"{2 * np.pi / v:.4g}"
    elif key == "w" and atom.channel.endswith(" mm)"):
        o, n = f"{old * MM_PER_M:.3g} mm", f"{v * MM_PER_M:.3g} mm"  # a prismatic joint's move width
    else:
        o, n = f"{rad_to_deg(old):.3g} deg", f"{rad_to_deg(v):.3g} deg"
    return replace_atom(atom, features=feats, channel=atom.channel.replace(o, n), label=atom.label.replace(o, n))


def _refine_hinge(prob: Problem, fit: Fit, s: Scored, pool_sizes: dict[str, int]) -> Scored:
    """A one-sided pull found past a decile of its joint's range moved to the angle that explains most between the
    neighbouring deciles (bounded Brent search on the angle, to 1e-5 rad)."""
    from scipy.optimize import minimize_scalar

    f0 = s.atom.features[0]
    j = int(f0.ch[1:])
    model = prob.prep.nominal
    prismatic = model.joint_kinds[j - 1] == "prismatic"
    x = prob.ctx.q[:, j - 1]
    grid = np.quantile(x, np.linspace(0, 1, HINGE_POINTS + 2))
    k = int(np.argmin(np.abs(grid - f0.at)))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    best = [s]

    def cost(at: float) -> float:
        got = score_atoms(prob, fit, [hinge_atom(j, at, f0.side, f0.p, f0.h, prismatic=prismatic,
                                                 words=joint_words(model, j))], pool_sizes, exact_top=1)
        if not got:
            return 0.0
        if got[0].dchi2 > best[0].dchi2:
            best[0] = got[0]
        return -got[0].dchi2

    if hi > lo:
        minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 1e-5})
    return best[0]


def _refine_step(prob: Problem, fit: Fit, s: Scored, pool_sizes: dict[str, int]) -> Scored:
    """A change point found on the coarse grid (deciles of the channel) moved to the row time between its grid
    neighbours that explains most: the step's time is a parameter of the effect, not of the grid. Only times that
    leave the change scan's ``max(MIN_ROWS, MIN_SIDE n)`` fitting rows (weight > 0) on each side are tried (a state
    a handful of rows hold at an end is no state); a change keeps its label's time with it
    (:func:`~twin.diagnosis.atoms.started_at`); steps at several times (one at every session start) stay."""
    steps = [f for f in s.atom.features if isinstance(f, Step)]
    f0 = steps[0]
    if any(f.at != f0.at or f.ch != f0.ch for f in steps):
        return s
    ch = f0.ch
    values = np.unique(feature_values((Pow(ch=ch, p=1, c=0.0, h=1.0),), prob.ctx,
                                      prob.prep.nominal)[:, 0])
    grid = np.quantile(values, np.linspace(0, 1, 11))
    k = int(np.argmin(np.abs(grid - f0.at)))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    fitting = feature_values((Pow(ch=ch, p=1, c=0.0, h=1.0),), prob.ctx, prob.prep.nominal)[prob.rows_cal, 0]
    fitting = np.sort(fitting[prob.w_cal > 0])
    side = max(MIN_ROWS, int(np.ceil(MIN_SIDE * len(fitting))))
    before = np.searchsorted(fitting, values, side="left")  # fitting rows before each candidate time
    cands = [v for v, nb in zip(values, before)
             if lo < v < hi and v != f0.at and nb >= side and len(fitting) - nb >= side]
    trial = []
    for v in cands:
        if s.atom.family == "change":
            trial.append(started_at(s.atom, float(v)))
            continue
        feats = tuple(replace_atom(f, at=float(v)) if isinstance(f, Step) else f for f in s.atom.features)
        label = s.atom.label.replace(s.atom.channel, f"step({ch} >= {v:.6g})")
        trial.append(replace_atom(s.atom, features=feats, channel=f"step({ch} >= {v:.6g})", label=label))
    scored = score_atoms(prob, fit, trial, pool_sizes, exact_top=len(trial)) if trial else []
    best = max(scored, key=lambda t: t.dchi2, default=None)
    return best if best is not None and best.dchi2 > s.dchi2 else s


def _time_linear(atom: Atom) -> bool:
    """Whether ``atom`` is thermal growth linear in ``t_s``."""
    return atom.family == "thermal" and len(atom.features) == 1 and isinstance(atom.features[0], Pow) \
        and atom.features[0].ch == "t_s" and atom.features[0].p == 1


def _as_onset(atom: Atom, t0: float, span: float) -> Atom:
    """The thermal ``atom`` linear in ``t_s`` (:func:`_time_linear`) as the air's ramp from ``t0`` over ``span`` [s]
    through a short lag (the start of :func:`refine_onset`)."""
    return onset_atom(replace_atom(atom, features=(Exp(ch="t_s", t0=t0, tau=span),)), t0, 1e-3 * span, span)


def bend_unseen(prob: Problem, atom: Atom) -> bool:
    """Whether ``atom`` is a backlash growing with the size of the last move read in proportion up to the campaign's
    longest move of its joint (:func:`_seen_saturation`: the rows that chose it showed no bend): its law is then
    undetermined by those rows and read again on every row a model is refitted on
    (:func:`twin.diagnosis.rule.retime`); a law whose bend those rows showed keeps the law and width they chose."""
    f = atom.features[0]
    if atom.family != "backlash" or f.kind != "lastmove" or f.law != "clip":
        return False
    step = prob.features(Atom("unnamed", "joint", atom.target, (StepIn(j=f.j),), "", "", "generic", (f.j,)))
    seen = float(np.max(np.abs(step[:, 0]), initial=0.0))
    return seen > 0.0 and f.w >= seen * (1.0 - 1e-9)


def retimeable(atom: Atom) -> bool:
    """Whether ``atom`` is a thermal term with a time constant, or one a lag or an onset generalises (growth linear in
    ``temp_c`` or in ``t_s``): what :func:`refine_time` moves."""
    return atom.family == "thermal" and (any(_has(f, "tau") for f in atom.features) or _temp_linear(atom)
                                         or _time_linear(atom))


def follows_the_air(atom: Atom) -> bool:
    """Whether ``atom`` is a thermal term of the air's temperature (recorded, through a lag; or without a record, its
    change at an onset, a drift in time): a change of the air may come late in a campaign, after the rows that chose
    the term, unlike the motors' heat, which every move brings from the first on."""
    return retimeable(atom) and not any(isinstance(f, Heat) for f in atom.features)


@memo_on_fit
def refine_time(prob: Problem, fit: Fit, s: Scored, pool_sizes: dict[str, int]) -> Scored:
    """A kept thermal term's time constants (:func:`retimeable`) at the maximum of the evidence on ``prob``'s
    calibration rows, searched over their whole range: a lag or the motion heat's time constant over the onset grid
    ``ONSET_TAUS`` first (a constant the first block could not see may lie far from its value), then :func:`refine`;
    an onset over :func:`refine_onset`'s grid."""
    a = s.atom
    if not (is_onset(a) or _temp_linear(a) or _time_linear(a)):
        span = float(np.ptp(np.asarray(prob.ctx.t_s, float)[prob.rows_cal]))
        trial = [_with_constant(a, "tau", fc * span) for fc in ONSET_TAUS] if span > 0 else []
        s = max([s] + score_atoms(prob, fit, trial, pool_sizes, exact_top=len(trial)), key=lambda x: x.dchi2)
    return refine(prob, fit, s, pool_sizes)


def recorded_lag(atom: Atom) -> bool:
    """Whether ``atom`` is thermal growth against the recorded temperature through a lag (one
    :class:`~twin.diagnosis.features.Lag` feature)."""
    return atom.family == "thermal" and len(atom.features) == 1 and isinstance(atom.features[0], Lag)


def _with_gap(atom: Atom, gap: float | None) -> Atom:
    """The recorded lag ``atom`` (:func:`recorded_lag`) with the record's changes at the fraction ``gap`` of each
    interval between rows (None: linear between rows); channel and label to match."""
    head = atom.channel.split(", changing at ")[0]
    ch = head if gap is None else f"{head}, changing at {gap:.3g} of each interval between rows"
    return replace_atom(atom, features=(replace_atom(atom.features[0], gap=None if gap is None else float(gap)),),
                        channel=ch, label=atom.label.replace(atom.channel, ch))


def refine_gap(prob: Problem, fit: Fit, s: Scored, pool_sizes: dict[str, int]) -> Scored:
    """A recorded lag ``s`` (:func:`recorded_lag`; others come back as they are) with the time of the record's changes
    within the intervals between its rows read on ``prob``'s calibration rows: a temperature recorded at the rows does
    not say when in a pause or a station change between two rows the air changed (a door opened in a pause), and read
    as linear between them it starts the change up to half the pause off, which the lag absorbs (a lag read several
    times too long or short, extrapolated to every row after the campaign). The fraction of the interval where the
    channel steps (:func:`twin.diagnosis.values.feature_values`: ``gap``) over ``GAP_FRACTIONS``, the three best each at
    its own best lag (:func:`refine`), then both at once (a simplex search on the fraction and the lag's log): the
    reading that explains most, ``s`` itself (linear between rows) included; the caller judges the constant it adds."""
    if not recorded_lag(s.atom):
        return s
    trial = [_with_gap(s.atom, g) for g in GAP_FRACTIONS]
    scored = sorted(score_atoms(prob, fit, trial, pool_sizes, exact_top=len(trial)), key=lambda x: -x.dchi2)
    best = s
    for c in scored[:3]:
        got = _refine_constant(prob, fit, c, pool_sizes)
        if got.dchi2 > best.dchi2:
            best = got
    if best.atom.features[0].gap is None:
        return best
    # the fraction and the lag trade against each other (a change later in a pause, a shorter lag): both at once, a
    # simplex search on (fraction, log lag) from the best reading
    f0 = best.atom.features[0]
    x0 = np.array([f0.gap, np.log(f0.tau)])
    at = best.atom
    return _simplex_best(prob, fit, lambda x: _with_constant(_with_gap(at, float(np.clip(x[0], 0.0, 1.0))), "tau",
                                                             float(np.exp(x[1]))), x0, best, pool_sizes,
                         maxfev=60, simplex=x0 + np.array([[0, 0], [0.06, 0], [0, 0.1]]))


def _simplex_best(prob: Problem, fit: Fit, make, x0: np.ndarray, start: Scored, pool_sizes: dict[str, int], *,
                  maxfev: int, simplex: np.ndarray) -> Scored:
    """The atom ``make(x)`` of largest ``dchi2`` on ``prob``'s calibration rows that a Nelder-Mead search over its
    constants ``x`` (from ``x0``, the initial ``simplex``, at most ``maxfev`` scorings) met, or ``start`` where none
    explained more."""
    from scipy.optimize import minimize

    best = [start]

    def cost(x: np.ndarray) -> float:
        got = score_atoms(prob, fit, [make(x)], pool_sizes, exact_top=1)
        if not got:
            return 0.0
        if got[0].dchi2 > best[0].dchi2:
            best[0] = got[0]
        return -got[0].dchi2

    minimize(cost, x0, method="Nelder-Mead", options={"xatol": 1e-3, "fatol": 1e-3, "maxfev": maxfev,
                                                       "initial_simplex": simplex})
    return best[0]


def prefer_heat(prob: Problem, fit: Fit, s: Scored, alternatives: list[Atom], pool_sizes: dict[str, int]) -> Scored:
    """A thermal term of the motors' heat ``s`` or one of its ``alternatives`` (the same link(s)' growth with the heat
    of other motors: :func:`twin.diagnosis.pools.heat_alternatives`), each at its own best time constant
    (:func:`refine_time`): the most significant on ``prob``'s calibration rows. The joints whose travel heats the links
    are a constant of the effect as its time constant is, and the grid of time constants the pool offers is coarse:
    each reading is judged at its best."""
    out = refine_time(prob, fit, s, pool_sizes)
    for c in score_atoms(prob, fit, alternatives, pool_sizes, exact_top=len(alternatives)):
        got = refine_time(prob, fit, c, pool_sizes)
        if got.logp_adj < out.logp_adj:
            out = got
    return out


def _temp_linear(atom: Atom) -> bool:
    """Whether ``atom`` is thermal growth linear in the recorded temperature, without a lag."""
    return atom.family == "thermal" and len(atom.features) == 1 and isinstance(atom.features[0], Pow) \
        and atom.features[0].ch == "temp_c" and atom.features[0].p == 1


def _temp_lagged(atom: Atom, tau: float) -> Atom:
    """The thermal ``atom`` linear in ``temp_c`` (:func:`_temp_linear`) against ``temp_c`` through a lag of ``tau`` [s]."""
    f = atom.features[0]
    ch = f"temp_c lagged {tau:.4g} s"
    return replace_atom(atom, features=(Lag(ch="temp_c", tau=float(tau), c=f.c, h=f.h),), channel=ch,
                        label=atom.label.replace(f"vs {atom.channel}", f"vs {ch}"))


def onset_lag(atom: Atom, tau: float) -> Atom:
    """A thermal ``atom`` against a lag of the recorded temperature with the time constant ``tau`` [s]."""
    return _with_constant(atom, "tau", tau)


def is_onset(atom: Atom) -> bool:
    """Whether ``atom`` is thermal growth against a change of the air's temperature through the links' lag (its
    features all :class:`~twin.diagnosis.features.Exp` in ``t_s``: a warm-up, a step or a ramp at an onset)."""
    return atom.family == "thermal" and bool(atom.features) and all(
        isinstance(f, Exp) and f.ch == "t_s" for f in atom.features)


def clip_value(v: float, lo: float, hi: float) -> float:
    """``np.clip(v, lo, hi)`` of one number without the array machinery, the same number to the bit: ``lo`` where it
    is above ``v`` (or NaN), then ``hi`` where it is below (or NaN), a NaN ``v`` kept; signed zeros as numpy's."""
    if lo != lo or (v == v and lo > v):
        v = lo
    if v == v and (hi != hi or hi < v):
        v = hi
    return v


def onset_atom(atom: Atom, t0: float, tau: float, ramp: float) -> Atom:
    """The thermal ``atom`` (:func:`is_onset`) with its air change at ``t0`` [s], a ramp over ``ramp`` [s] (0: a step)
    and the links' lag ``tau`` [s]; channel and label to match."""
    feats = tuple(replace_atom(f, t0=float(t0), tau=float(tau), ramp=float(ramp) if ramp > 0 else None)
                  for f in atom.features)
    if ramp > 0:
        ch = f"the air's ramp from t_s {t0:.6g} over {ramp:.4g} s, lagged {tau:.4g} s"
    else:
        ch = f"the air's step at t_s {t0:.6g}, lagged {tau:.4g} s"
    head = atom.label.split(" vs ")[0]
    return replace_atom(atom, features=feats, channel=ch, label=f"{head} vs {ch}")


def refine_onset(prob: Problem, fit: Fit, s: Scored, pool_sizes: dict[str, int], *, after: float | None = None) -> Scored:
    """A thermal term against the air's temperature without a record of it (``t_s`` only): the links follow the air
    through a first-order lag ``tau``, and the air changed at an unknown ``t0``, at once (a door opened) or over a
    ramp of ``T`` (:func:`twin.diagnosis.values.lag_response`; a warm-up from the first row is the step at its time).
    The three constants are the effect's, not a grid's: every onset (or ramp's middle) on ``ONSET_POINTS`` quantiles
    of the calibration rows' times, time constant in ``ONSET_TAUS`` and ramp in ``ONSET_RAMPS`` (fractions of their
    span), the maximum of the calibration evidence, then a simplex search from it on ``(t0, log tau, log T)``, within
    bounds that keep a state the rows hold: the onset at most a span before the first row and with at least
    ``max(3, ONSET_SIDE n)`` rows after it (as a change's), the lag and the ramp within ``ONSET_TAUS``' range (a lag
    far longer than the rows is a feature too small to be a change of the air), the lag at most four times the time
    the rows last after the onset (they see a fifth of its response at least: a slower one is a drift they see
    start, which later rows would extrapolate). ``after`` [s]: the onset no earlier
    than this (a change after the rows that fit: ``s`` itself is then no candidate)."""
    t = np.sort(np.asarray(prob.ctx.t_s, float)[prob.rows_cal])
    span = float(t[-1] - t[0])
    side = max(3, int(np.ceil(ONSET_SIDE * len(t))))
    lo = t[0] - span if after is None else float(after)
    hi = float(t[max(len(t) - side, 0)])
    if span <= 0 or hi < lo:
        return s
    tau_lo, tau_hi = min(ONSET_TAUS) * span, max(ONSET_TAUS) * span

    def make(t0: float, tau: float, ramp: float) -> Atom:
        ramp = float(clip_value(ramp, 0.0, tau_hi))
        t0 = float(clip_value(t0, lo, hi))
        # the rows after the onset see at least a fifth of its response (a lag four times longer than they last is
        # a drift they see start, which any later row would extrapolate)
        tau = float(clip_value(tau, tau_lo, max(tau_lo, min(tau_hi, 4.0 * (t[-1] - t0)))))
        return onset_atom(s.atom, t0, tau, ramp if ramp > 1e-3 * span else 0.0)

    middles = np.quantile(t[(t >= lo) & (t <= hi)] if np.any((t >= lo) & (t <= hi)) else [hi],
                          np.linspace(0.0, 1.0, ONSET_POINTS))
    trial = [make(m - 0.5 * fr * span, fc * span, fr * span) for m in middles for fc in ONSET_TAUS for fr in ONSET_RAMPS]
    scored = score_atoms(prob, fit, trial, pool_sizes, exact_top=len(trial))
    first = max(([s] if after is None else []) + scored, key=lambda x: x.dchi2, default=s)
    f0 = first.atom.features[0]
    x0 = np.array([(f0.t0 - t[0]) / span, np.log(f0.tau / span), np.log(max(f0.ramp or 0.0, 1e-3 * span) / span)])
    got = _simplex_best(prob, fit, lambda x: make(t[0] + x[0] * span, float(np.exp(x[1]) * span),
                                                  float(np.exp(x[2]) * span)),
                        x0, first, pool_sizes, maxfev=150, simplex=x0 + np.vstack([np.zeros(3), 0.05 * np.eye(3)]))
    if got is s:
        return s
    # the constants were chosen among ONSET_TRIALS on these rows (as a change's row among the rows): its evidence pays
    # for them
    return Scored(got.atom, got.basis, got.psi, got.dchi2, got.logp_adj + np.log(ONSET_TRIALS), got.r, E=got.E,
                  Ep=got.Ep)
