"""A term of the arm's load and the change its rows hold, judged together.

A forward round tries its strongest candidates one at a time, each confirmed on the confirmation rows
(:func:`twin.diagnosis.confirm.confirm`). Where the calibration rows hold two load states of the arm (a payload taken
off in the middle of the campaign) and the confirmation rows one, a term of the arm's load fitted on the mixture
predicts neither state (its size is the rows' average), and the change between the states is not found either:
against the geometric fit alone, the rows on each side of it keep the load term's misfit, which no change fits
uniformly (:func:`twin.diagnosis.changes.scan_changes`). Each needs the other.

:func:`with_change` is tried where every candidate of a round failed on the held-out rows: for each of the first
``PAIR_TRIES`` candidates that failed there (significant on the calibration rows) and are a term of the arm's load
(:func:`twin.diagnosis.atoms.is_load_term`), the model is fitted with it, the change scan runs against that fit, and
a change of a joint's compliance ``c`` (:func:`twin.diagnosis.atoms.is_load_change`: the load's state) that is
significant (its pool's Bonferroni factor) is kept with the candidate ``a`` only when each is confirmed on the
held-out rows given the other:

    ``confirm(fit + a, c)`` and ``confirm(fit + c, a)`` both hold at ``z_min``

(``z``, ``z`` without the most favourable row, the held-out error lower, not a wander the nearest rows in time
predict as well), and ``a`` is significant against ``fit + c``. Neither alone is then what the rows hold, and both
together predict the held-out rows beyond what each predicts given the other.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .atoms import Atom, is_load_change, is_load_term
from .changes import ChangePlace, scan_changes, selection_short
from .confirm import confirm
from .problem import Fit, Problem, psi_init
from .scoring import Scored, score_atoms

__all__ = ["PAIR_TRIES", "Pair", "with_change"]

PAIR_TRIES = 3  # candidates that failed on the held-out rows tried with a change, and changes tried with each


@dataclass(frozen=True)
class Pair:
    """A candidate kept with the change its rows hold: the candidate scored against the round's fit, the change
    (to be scored against the fit that holds the candidate), and each one's held-out ``z`` given the other."""

    term: Scored
    change: Atom
    z_change: float
    z_term: float


def _fit_with(prob: Problem, fit: Fit, s: Scored) -> Fit:
    """``fit`` refitted with the scored atom ``s`` added to its chosen atoms."""
    chosen = list(fit.chosen) + [(s.atom, s.basis)]
    return prob.fit(fit.z[:prob.prep.space.size], chosen, psi_init(fit, chosen))


def with_change(prob: Problem, fit: Fit, failed: list[Scored], places: list[ChangePlace], sizes: dict[str, int], *,
                alpha_select: float, z_min: float, admit=lambda a: True) -> Pair | None:
    """The first term of the arm's load among ``failed`` (candidates of a round, in the order tried, that were
    significant on the calibration rows and failed on the held-out rows) kept with a change of a joint's compliance
    among ``places`` (the module docstring's test), or None.
    ``admit``: whether a change atom may be tried (not rejected, its slot not taken)."""
    log_alpha = np.log(alpha_select)
    for s in [s for s in failed if is_load_term(s.atom)][:PAIR_TRIES]:
        fit_a = _fit_with(prob, fit, s)
        changes = [a for a in scan_changes(prob, fit_a, places, short=selection_short(prob.obs_cal.n))
                   if is_load_change(a) and admit(a)]
        got = sorted(score_atoms(prob, fit_a, changes, sizes), key=lambda g: g.logp_adj)
        for g in got[:PAIR_TRIES]:
            if not g.logp_adj < log_alpha:
                break
            c_change = confirm(prob, fit_a, g, z_min)
            if not c_change.holds(z_min):
                continue
            fit_c = _fit_with(prob, fit, g)
            back = score_atoms(prob, fit_c, [s.atom], sizes)
            if not back or not back[0].logp_adj < log_alpha:
                continue
            c_term = confirm(prob, fit_c, back[0], z_min)
            if c_term.holds(z_min):
                return Pair(s, g.atom, float(c_change.z), float(c_term.z))
    return None
