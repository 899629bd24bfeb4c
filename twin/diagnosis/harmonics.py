"""A harmonic of two orders: a joint's cyclic error with two stages (two orders per joint turn) confirmed as a pair.

A harmonic scored alone against rows that hold two orders of one joint follows the held-out rows (its signed-rank
score passes) but its values, fitted on the calibration rows where the two orders mix, need not lower their error: the
order left out distorts the one fitted. :func:`with_second_order` says whether the harmonic with the strongest further
order of its joint, fitted beside it, lowers the held-out error; the second order then enters on its own evidence in
the next round.
"""

from __future__ import annotations

import numpy as np

from .atoms import Atom
from .features import Cos, Sin
from .problem import Fit, Problem, held_out_rms, psi_init
from .scoring import Scored, score_atoms

__all__ = ["is_harmonic", "with_second_order"]


def is_harmonic(atom: Atom) -> bool:
    """Whether ``atom`` is a cyclic term of one joint angle (sines and cosines of one order)."""
    return atom.family == "cyclic" and bool(atom.features) and all(isinstance(f, (Sin, Cos)) for f in atom.features)


def with_second_order(prob: Problem, fit: Fit, s: Scored, remaining: list[Atom], sizes: dict[str, int], *,
                      alpha: float) -> bool:
    """Whether the harmonic ``s`` and the strongest further order of its joint (among ``remaining``, scored against
    the fit with ``s``; significant at ``alpha`` after its pool's size) fitted together on the calibration rows predict
    the confirmation rows with a lower position RMS than ``fit`` does. The fits leave the problem's gross rows as they
    are."""
    if not is_harmonic(s.atom):
        return False
    others = [a for a in remaining if is_harmonic(a) and a.target == s.atom.target and a.key != s.atom.key]
    if not others:
        return False
    P = prob.prep.space.size
    chosen = list(fit.chosen) + [(s.atom, s.basis)]
    with_s = prob.fit(fit.z[:P], chosen, psi_init(fit, chosen))
    second = [t for t in score_atoms(prob, with_s, others, sizes) if t.logp_adj < np.log(alpha)]
    if not second:
        return False
    t = min(second, key=lambda c: c.logp_adj)
    both = chosen + [(t.atom, t.basis)]
    pair = prob.fit(with_s.z[:P], both, psi_init(with_s, both))
    return held_out_rms(prob, pair) < held_out_rms(prob, fit)
