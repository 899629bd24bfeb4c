"""The order in which scored candidates are tried (:func:`order_candidates`: evidence first, a named term before an
unnamed one that does not beat it clearly, small terms before a broad one that only collects them, the smallest
nested shape first), the distinct terms a round tries (:func:`distinct_terms`, :func:`rival_readings`, a joint's one
backlash :func:`slot`) and the alternatives the data cannot tell from a kept term (:func:`alternatives`).
"""

from __future__ import annotations

import numpy as np

from .atoms import Atom, is_load_change
from .problem import Problem
from .scoring import Scored

__all__ = ["CATALOGUE_MARGIN", "CATALOGUE_SHARE", "order_candidates", "alternatives", "slot", "distinct_terms",
           "rival_readings", "payload_rivals"]


CATALOGUE_MARGIN = 10.0  # [natural log of p] an unnamed term is preferred to a named one only beyond this
CATALOGUE_SHARE = 0.05  # ... or beyond this share of the named term's evidence when both act at the same place
# (or the named term's columns lie within the unnamed one's)


def order_candidates(scored: list[Scored], broad_dim: int = 4) -> list[Scored]:
    """Atoms in the order to try: by pool-adjusted evidence, except that a broad atom (``>= broad_dim``
    reduced parameters: compliance, a whole frame) goes behind the small atoms when small atoms together
    explain more within the same number of parameters (a broad atom collects a little of several effects;
    it must not pre-empt the small atoms that each hold one of them)."""
    order = _prefer_nested(sorted(scored, key=lambda s: s.logp_adj))
    if order and order[0].atom.pool == "generic":
        # the dictionary holds supersets of catalogue terms (a polynomial in q_j on theta_j contains the
        # gear-ratio direction): an unnamed term must beat the best named one clearly, not by fitting noise
        named = [s for s in order if s.atom.pool != "generic"]
        top = order[0]
        # "the same place": the same target, or a named atom whose columns lie within the unnamed one's (a joint-1
        # backlash is a rotation about base z, inside the base frame's six directions with the same sign)
        # the first such named atom in the order (the test is lazy: each _nested builds the atom's columns)
        first_same = next((s for s in named if (s.atom.place, s.atom.target) == (top.atom.place, top.atom.target)
                           or _nested(s, top)), None)
        same = first_same is not None
        cand = first_same if same else (named[0] if named else None)
        # at high signal-to-noise, effects not yet modelled leak a few per cent into any broader atom: the
        # margin grows with the evidence (5 % of it) for a named atom acting at the same place
        margin = max(CATALOGUE_MARGIN, CATALOGUE_SHARE * abs(cand.logp_adj)) if same else CATALOGUE_MARGIN
        if cand is not None and _settling_rival(top, cand):
            # a joint still settling from the step into the row and a backlash growing with its last move differ only
            # on the rows that did not move (the step is zero there, the last move is not): the one the rows follow
            # better leads, without a margin
            margin = top.logp_adj - cand.logp_adj if cand.dchi2 >= top.dchi2 else 0.0
        if cand is not None and cand.logp_adj < top.logp_adj + margin:
            order = [cand] + [s for s in order if s is not cand]
        elif same and named[0] is not cand and named[0].logp_adj < top.logp_adj + CATALOGUE_MARGIN:
            # the named atom at the same place is far behind, but a named atom elsewhere is not: it leads
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


def _settling_rival(unnamed: Scored, named: Scored) -> bool:
    """Whether ``unnamed`` is the step into the row of a joint acting on that joint's angle and ``named`` a backlash of
    the same joint growing with the size of its last move."""
    a, b = unnamed.atom, named.atom
    return (a.place == b.place == "joint" and a.target == b.target and len(a.features) == len(b.features) == 1
            and a.features[0].kind == "stepin" and b.features[0].kind == "lastmove" and b.family == "backlash")


def _nested(small: Scored, big: Scored, share: float = 0.99) -> bool:
    """Whether ``small``'s projected columns lie (to ``share`` of their norm) within ``big``'s span."""
    if small.basis.shape[1] >= big.basis.shape[1] or small.r.shape != big.r.shape:
        return False
    # big's span is orthogonal to the current model, so its product with small's projected columns Ep is its product
    # with small's columns E (E - Ep lies in the model's span): no projection of small's columns is needed
    tot = small.ep_norm2()
    return tot > 0 and float(np.sum((big.span().T @ small.reduced_columns()) ** 2)) >= share * tot


def _prefer_nested(order: list[Scored], alpha_select: float = 0.01) -> list[Scored]:
    """When the leading atom's features contain those of a smaller significant atom at the same place (a product
    group holds the linear terms of its joints; a cubic holds the quadratic and the linear), the smallest such
    atom goes first: what the larger one adds beyond it must then earn its own place in a later round (its
    evidence and held-out confirmation), instead of riding on the part they share."""
    if not order:
        return order
    top = order[0]
    keys = {repr(f) for f in top.atom.features}
    best = None
    for s in order[1:]:
        if (s.atom.place, s.atom.target) != (top.atom.place, top.atom.target) or s.logp_adj >= np.log(alpha_select):
            continue
        sk = {repr(f) for f in s.atom.features}
        if sk < keys and (best is None or len(sk) < len(best.atom.features)
                          or (len(sk) == len(best.atom.features) and s.dchi2 > best.dchi2)):
            best = s
    return order if best is None else [best] + [s for s in order if s is not best]


def _omp_gain(small: list[Scored], budget: int, pool: int = 60) -> float:
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


def alternatives(best: Scored, scored: list[Scored], *, share: float = 0.9, log_evidence: float = 5.0) -> list[dict]:
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


def slot(atom: Atom) -> str:
    """What a kept atom occupies: a joint has one backlash (a sign or a play of some clearance); any other atom
    occupies its own key."""
    return f"backlash:{atom.target}" if atom.family == "backlash" else atom.key


def distinct_terms(prob: Problem, order: list[Scored]) -> tuple[list[Scored], dict[str, list[str]]]:
    """``order`` without the candidates that are an earlier one on the calibration rows (the same family at the same
    place with equal feature values on every calibration row: grid values the rows cannot tell apart, such as the
    directions of a load that give every row the same sign), and the keys each kept candidate stands for. A round
    tries distinct terms; one judged stands for its copies (rejected with it)."""
    kept: list[Scored] = []
    same: dict[str, list[str]] = {}
    by: dict[tuple, list[Scored]] = {}
    for s in order:
        a = s.atom
        k = (a.family, a.place, a.target, float(f"{s.dchi2:.9g}"))
        twin = next((t for t in by.get(k, []) if np.array_equal(prob.features_cal(t.atom), prob.features_cal(a))),
                    None)
        if twin is None:
            by.setdefault(k, []).append(s)
            kept.append(s)
        else:
            same.setdefault(twin.atom.key, []).append(a.key)
    return kept, same


def rival_readings(order: list[Scored], first: list[Scored], logp_max: float) -> list[Scored]:
    """``first`` with, after each backlash in it, the strongest significant other reading (``logp_adj < logp_max``) of
    that joint's backlash in ``order`` (its one slot: the sign of the last move or of the load, a play, the size of the
    last move): a joint's backlash is tried in the readings the rows hold before a term elsewhere takes its rows (one
    reading failing its confirmation says nothing of another)."""
    out: list[Scored] = []
    have = {id(s) for s in first}
    for s in first:
        out.append(s)
        if s.atom.family != "backlash":
            continue
        kinds = {f.kind for f in s.atom.features}
        rival = next((r for r in order if id(r) not in have and r.logp_adj < logp_max and slot(r.atom) == slot(s.atom)
                      and {f.kind for f in r.atom.features} != kinds), None)
        if rival is not None:
            out.append(rival)
            have.add(id(rival))
    return out


def payload_rivals(order: list[Scored], tried: list[Scored], logp_max: float) -> list[Scored]:
    """Where a round tried changes of a joint's compliance (a payload) and none held: the strongest significant change
    (``logp_adj < logp_max``) in ``order`` of the compliance of each joint none of ``tried`` changes, in the order's
    order. A payload at the flange loads every joint below it at once, and the joint whose change the rows that fit
    hold most (a stiff shoulder under a long lever) need not be the one the later rows confirm (a soft wrist)."""
    loaded = {s.atom.target for s in tried if is_load_change(s.atom)}
    if not loaded:
        return []
    out: list[Scored] = []
    have = {id(s) for s in tried}
    for r in order:
        if id(r) not in have and r.logp_adj < logp_max and is_load_change(r.atom) and r.atom.target not in loaded:
            out.append(r)
            loaded.add(r.atom.target)
    return out
