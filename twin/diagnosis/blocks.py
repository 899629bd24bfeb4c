"""Which rows fit a model, which confirm its terms, which report its error: blocks of time, never interleaved.

A calibration is for the robot's next session. Rows held out *between* the rows that fit a model share the
campaign's slow drifts, its warm-up and the shapes of its one pose pattern with them, so a term that describes only
this campaign passes any test on them (measured on a real UR5: -45 % on interleaved report rows, +134 % on the
next session). So the held-out rows are always a block of time that follows the rows that fit:

* the dataset's ``set`` column is used as it is when its ``validation`` rows already follow every calibration row
  (the end of the campaign) or are whole sessions (``session`` column: each session all calibration or all
  validation);
* otherwise (no ``set`` column, or validation rows interleaved with calibration rows in time) the held-out rows
  are the end of the campaign: whole sessions at the end when the ``session`` column gives a boundary near the
  held-out fraction, else the last fraction of the rows in measurement order (a visit, consecutive rows at the
  same commanded joints and station, is never split). The fraction is the ``set`` column's own share of
  validation rows, or ``holdout`` (default :data:`HOLDOUT_DEFAULT`, 30 %).
* A station (an instrument placement) whose every row is held out has no frame the fit could know: its first
  rows (:data:`REGISTER_ROWS`) register it and join the calibration rows, as a user re-registers a moved tracker.

The held-out rows are then split in two contiguous blocks (:func:`confirm_and_report`): the *confirmation* block
(earlier: the structure test and every check that chooses a term) and the *report* block (the last whole
held-out session when there are several, else the last :data:`REPORT_FRACTION` (a fifth) of the held-out visits;
before and after are measured there and nothing else). Rows are in measurement order (``docs/formats.md``): that order is the
time axis, ``t_s`` or not.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..dataset import Dataset

__all__ = ["HOLDOUT_DEFAULT", "REPORT_FRACTION", "REPORT_MIN_VISITS", "REGISTER_ROWS", "HeldOutSets", "visits",
           "sessions", "held_out_sets", "confirm_and_report"]

HOLDOUT_DEFAULT = 0.3  # held-out fraction at the end of the campaign without a set column
REPORT_FRACTION = 0.2  # the last fifth of the held-out visits report (the rest confirm: they need the power)
REPORT_MIN_VISITS = 20  # fewer held-out visits: no separate report block (before/after on the confirmation rows)
REGISTER_ROWS = (10, 50)  # rows that register a station seen only in the held-out block: 10 % of its rows, in these bounds


@dataclass(frozen=True)
class HeldOutSets:
    """``set`` ``(n,)``: ``calibration``/``validation`` per dataset row, the rule that chose it in words, the
    ``source`` (``"set column"``, ``"end of the campaign"``, ``"whole sessions"``) and, per station registered from
    held-out rows, the pose ids that moved to the calibration rows to register it."""

    set: np.ndarray
    rule: str
    source: str
    registration: dict[str, list[int]]


def visits(ds: Dataset) -> np.ndarray:
    """Visit number ``(n,)`` of every row: a visit is a run of consecutive rows with the same commanded joints and
    station (a repeat shares its visit's error, so a visit stays in one block)."""
    q = np.round(np.asarray(ds.q, float), 9)
    st = np.asarray(ds.station_ids).astype(str)
    new = np.ones(ds.n, bool)
    if ds.n:
        new[1:] = np.any(q[1:] != q[:-1], axis=1) | (st[1:] != st[:-1])
    return np.cumsum(new) - 1


def sessions(ds: Dataset) -> np.ndarray:
    """Session number ``(n,)`` of every row: the runs of the ``session`` column in measurement order (0 for every row
    without one)."""
    raw = ds.extra.get("session")
    if raw is None or ds.n == 0:
        return np.zeros(ds.n, int)
    v = np.asarray(raw).astype(str)
    new = np.zeros(ds.n, bool)
    new[1:] = v[1:] != v[:-1]
    return np.cumsum(new)


def _blocked(is_val: np.ndarray, sess: np.ndarray) -> str | None:
    """How the validation rows ``is_val`` ``(n,)`` are blocked, or None when they interleave with calibration rows."""
    if not is_val.any() or is_val.all():
        return None
    if is_val[int(np.argmax(is_val)):].all():
        return "end of the campaign"
    whole = all(len(set(is_val[sess == s].tolist())) == 1 for s in np.unique(sess))
    if whole and len(np.unique(sess)) > 1:
        return "whole sessions"
    return None


def _suffix(ds: Dataset, frac: float, vis: np.ndarray, sess: np.ndarray) -> tuple[np.ndarray, str]:
    """The last ``frac`` of the rows as held out: whole sessions when a session boundary holds out between half and
    twice the fraction (nearest to it, leaving a session to fit), else the rows from the first whole visit at or
    after ``(1 - frac) n``."""
    n = ds.n
    starts = [int(i) for i in np.flatnonzero(np.diff(sess) != 0) + 1]
    best = None
    for b in starts:
        share = (n - b) / n
        if 0.5 * frac <= share <= min(2.0 * frac, 0.8) and (best is None or abs(share - frac) < abs((n - best) / n - frac)):
            best = b
    if best is not None:
        out = np.zeros(n, bool)
        out[best:] = True
        return out, "whole sessions"
    cut = int(np.ceil((1.0 - frac) * n))
    cut = min(max(cut, 1), n - 1)
    # the first row of the visit that is under way at the cut goes with the held-out block only if the visit starts there
    while 0 < cut < n and vis[cut] == vis[cut - 1]:
        cut += 1
    out = np.zeros(n, bool)
    out[cut:] = True
    return out, "end of the campaign"


def held_out_sets(ds: Dataset, holdout: float | None = None) -> HeldOutSets:
    """The calibration and validation rows of ``ds`` as blocks of time (module docstring). ``holdout``: the held-out
    fraction at the end, whatever the ``set`` column says (default: the ``set`` column's validation rows when they
    are blocked, their share at the end when they interleave, :data:`HOLDOUT_DEFAULT` without a ``set`` column or
    validation rows)."""
    if holdout is not None and not (0.05 <= holdout <= 0.8):
        raise ValueError(f"holdout must be in [0.05, 0.8], got {holdout!r}")
    n = ds.n
    sess = sessions(ds)
    vis = visits(ds)
    has_val = ds.set is not None and bool(np.any(ds.set == "validation"))
    if has_val and holdout is None:
        is_val = np.asarray(ds.set) == "validation"
        how = _blocked(is_val, sess)
        if how is not None:
            rule = (f"the dataset's 'set' column: its {int(is_val.sum())} validation rows are "
                    + ("the end of the campaign" if how == "end of the campaign" else "whole sessions")
                    + ", after every calibration row in time or in sessions of their own")
            source = "set column"
        else:
            frac = float(is_val.mean()) if holdout is None else float(holdout)
            is_val, how = _suffix(ds, frac, vis, sess)
            rule = (f"the dataset's 'set' column interleaves its validation rows with the calibration rows in time: "
                    f"held out instead the same share ({100 * frac:.0f} %) at the "
                    + ("end of the campaign" if how == "end of the campaign" else "end, as whole sessions")
                    + f" ({int(is_val.sum())} rows)")
            source = how
    else:
        frac = HOLDOUT_DEFAULT if holdout is None else float(holdout)
        is_val, how = _suffix(ds, frac, vis, sess)
        why = ("no set column: " if ds.set is None else
               f"the holdout given ({frac:g}) replaces the 'set' column's validation rows: " if has_val else
               "the 'set' column has no validation rows: ")
        rule = (f"{why}held out the last {100 * frac:.0f} % of the rows in "
                f"measurement order" + (" as whole sessions" if how == "whole sessions" else "")
                + f" ({int(is_val.sum())} rows)")
        source = how
    # a station seen only in held-out rows: its first rows register its frame
    st = np.asarray(ds.station_ids).astype(str)
    registration: dict[str, list[int]] = {}
    for s in dict.fromkeys(st.tolist()):
        rows = np.flatnonzero(st == s)
        if is_val[rows].all():
            m = int(np.clip(round(0.1 * rows.size), *REGISTER_ROWS))
            m = min(m, max(rows.size - 1, 0))
            if m == 0:
                continue
            take = rows[vis[rows] <= vis[rows[m - 1]]]  # whole visits
            if take.size >= rows.size:
                take = rows[:m]
            if take.size:
                is_val[take] = False
                registration[s] = [int(p) for p in np.asarray(ds.pose_id)[take]]
    if registration:
        rule += ("; " + ", ".join(f"station {s} is measured only in the held-out rows: its first {len(p)} rows register "
                                  f"its frame (fitted with the calibration rows)" for s, p in registration.items()))
    out = np.where(is_val, "validation", "calibration").astype(object)
    return HeldOutSets(out, rule, source, registration)


def confirm_and_report(ds: Dataset, held_rows: np.ndarray, unknown: np.ndarray, *,
                       fraction: float = REPORT_FRACTION, min_visits: int = REPORT_MIN_VISITS
                       ) -> tuple[np.ndarray, np.ndarray | None, str]:
    """Split the held-out rows ``held_rows`` ``(m,)`` (dataset row indices, in measurement order) in two contiguous
    blocks: returns boolean masks ``(m,)`` of the confirmation and the report rows (``None`` when there are fewer
    than ``min_visits`` held-out visits) and the rule in words. The report block is the last held-out session when
    the held-out rows span several and it leaves at least ``min_visits`` visits on each side, else the last
    ``fraction`` of the held-out visits. Report rows whose approach history is unknown (``unknown`` ``(n,)``: the
    first rows of a session) go to the confirmation block: no model predicts a history-dependent term there."""
    held_rows = np.asarray(held_rows, int)
    vis = visits(ds)[held_rows]
    sess = sessions(ds)[held_rows]
    uniq = list(dict.fromkeys(vis.tolist()))
    if len(uniq) < min_visits:
        return np.ones(held_rows.size, bool), None, (
            f"fewer than {min_visits} held-out visits ({len(uniq)}): before/after are on the rows that also confirmed "
            "the terms (no separate report block)")
    is_rep = None
    if len(np.unique(sess)) > 1:
        last = sess == sess[-1]
        n_last = len(set(vis[last].tolist()))
        if n_last >= min_visits and len(uniq) - n_last >= min_visits:
            is_rep = last
            rule = ("the last held-out session in time reports before/after; the held-out sessions before it confirm "
                    "the terms")
    if is_rep is None:
        n_rep = int(np.ceil(fraction * len(uniq)))
        rep_visits = set(uniq[-n_rep:])
        is_rep = np.isin(vis, list(rep_visits))
        rule = (f"the last {100 * fraction:.0f} % of the held-out visits in measurement order report before/after "
                "(a block of time after every row that chose or fitted the model); the earlier held-out rows confirm "
                "the terms")
    is_rep = is_rep & ~np.asarray(unknown, bool)[held_rows]
    rule += "; rows with an unknown approach history go to the confirmation block"
    return ~is_rep, is_rep, rule
