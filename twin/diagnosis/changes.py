"""Change points: a step (or a step and back, a window) at an unknown row in one channel of the model.

A *change* acts at one *place* from one row of the campaign on (a step) or between two rows (a window): a joint
offset (``theta<j>``), the tool frame, the measurement (base) frame (each row's station), or a joint's compliance
(its leading gravity-torque shapes, :func:`twin.diagnosis.pools.catalogue_atoms`: a payload put on or taken off).
Its column is the place's column times ``1[row >= s]`` (a window: ``1[s <= row < e]``), rows in time order (``t_s``
when recorded, else the measurement order).

**The scan.** After a fit with whitened residual ``r`` orthogonal to an orthonormal basis ``Q`` (``m x P``) of the
model's columns, a place whose columns on row ``i`` are ``g_i`` (``p`` columns: the place's columns times its
features) explains, with a step at row ``s``,

    ``Delta chi2(s) = b_s^T (C_s - A_s^T A_s)^+ b_s``,  ``A_s = sum_{i>=s} Q_i^T g_i``, ``b_s = sum_{i>=s} g_i^T r_i``,
    ``C_s = sum_{i>=s} g_i^T g_i``

(the columns scaled to unit norm, directions below 1 % of a unit column dropped, as every atom is scored:
:func:`twin.diagnosis.scoring.score_atoms`). Suffix sums give every ``s`` at once, ``O(n p^2 P)``; a window
``[s, e)`` takes the difference of two of them. The best row of each place is one candidate of the selection
(family ``change``), its evidence ``p = chi2_sf(Delta chi2, rank)`` times the number of places and row positions
tried (its pool: a step at every row of every place, ``change``; a window at every pair of rows, ``change_window``,
on a grid of at most ``WINDOW_GRID`` boundaries, refined to the rows around the best pair). A change then faces
what every term faces: held-out confirmation on the later block of time, the backward pass.

A change is reported in ``diagnosis.json`` ``changes`` (not among the ``effects``) with the row and time it starts
(and ends), its place and its size. In prediction the step is a term of time: rows after it, and a new session,
read the state after it (:func:`twin.diagnosis.values.feature_values`, ``step`` and ``window``).
"""

from __future__ import annotations

import re
import threading
from dataclasses import dataclass

import numpy as np

from ..estimator.distributions import f_sf
from ..runtime import thread_map
from ..units import MM_PER_M, rad_to_deg
from .atoms import MIN_ROWS, MIN_SIDE, Atom, change_from, joint_words, started_at
from .candidates import RowContext, gravity_torque_regressor
from .confirm import row_blocks
from .features import Const, Gated, Step, Window, feature_from_dict
from .loads import payload_shapes
from .problem import psi_init
from .scoring import memo_on_fit, row_aggregates, score_atoms, scoring_basis
from .structure import chi2_logsf

__all__ = ["CHANGE_POOLS", "MIN_ROWS", "WINDOW_GRID", "ChangePlace", "change_places", "change_pool_sizes",
           "scan_changes", "describe_changes", "is_change", "is_step", "is_window", "as_window", "as_step", "row_times",
           "same_event", "started_at", "change_at", "place_scatter", "window_wander",
           "STRUCTURED_OUTSIDE", "selection_short"]

WINDOW_MIN_ROWS = 5  # rows inside a window by default (the selection and the glitch scan take MIN_ROWS, short=)
UNIFORM_P = 1e-3  # the rows a change acts on may not keep a scatter larger than the others' beyond this p
WINDOW_GRID = 60  # most boundary positions the window scan takes (every k-th row beyond, then refined)
SHORT_START_SHARE = 8  # a short window of w rows is tried from every max(1, w // this)-th row
CHANGE_POOLS = ("change", "change_window")


@dataclass(frozen=True)
class ChangePlace:
    """Where a change may act: ``place``/``target`` as an atom's, the features the change multiplies (``None``: a
    constant offset of the place), the words and joints."""

    place: str
    target: str
    inner: tuple | None
    words: str
    joints: tuple[int, ...] = ()
    payload: bool = False  # a joint's compliance under a point mass at the flange (one event at every joint below it)


def is_change(atom) -> bool:
    """Whether an atom (or its JSON) is a change (family ``change``)."""
    fam = atom["family"] if isinstance(atom, dict) else atom.family
    return fam == "change"


def change_places(model, catalogue: list[Atom], q: np.ndarray | None = None) -> list[ChangePlace]:
    """Every joint offset, the tool frame, the measurement (base) frame, and each joint's compliance where the
    catalogue has one under gravity, twice: under the arm's own weight (the catalogue's leading gravity-torque shapes
    of that joint: a brake released, a stiffness changed) and, with the rows' joints ``q`` ``(n, N)``, under a payload
    put on or taken off (:func:`twin.diagnosis.loads.payload_shapes`: a point mass at the flange)."""
    out = [ChangePlace("joint", f"theta{j}", None, f"joint {joint_words(model, j)} offset", (j,))
           for j in range(1, model.n_joints + 1)]
    Y = None if q is None else gravity_torque_regressor(model, q)
    out += [ChangePlace("param", "tool", None, "tool (plate) frame"),
            ChangePlace("param", "base", None, "base (measurement) frame")]
    for a in catalogue:
        if a.family == "compliance" and a.channel == f"gravity torque of {a.target.replace('theta', 'joint ')}":
            j = int(a.target[5:])
            out.append(ChangePlace("joint", a.target, tuple(a.features),
                                   f"joint {joint_words(model, j)} compliance (under gravity)", a.joints))
            shapes = () if q is None else payload_shapes(model, q, j, Y)
            if shapes:
                words = f"joint {joint_words(model, j)} compliance (a payload)"
                out.append(ChangePlace("joint", a.target, shapes, words, a.joints, payload=True))
    return out


def is_step(atom: Atom) -> bool:
    """Whether ``atom`` is a change from a row on (a step, or a gated shape without an end)."""
    f0 = atom.features[0] if atom.features else None
    return is_change(atom) and (isinstance(f0, Step) or (isinstance(f0, Gated) and f0.until is None))


def is_window(atom: Atom) -> bool:
    """Whether ``atom`` is a change and back (a window, or a gated shape with an end)."""
    f0 = atom.features[0] if atom.features else None
    return is_change(atom) and (isinstance(f0, Window) or (isinstance(f0, Gated) and f0.until is not None))


def as_window(atom: Atom, until: float) -> Atom:
    """The change ``atom`` (a step, :func:`is_step`, or a window) ending at ``until`` (its time channel's value): a
    step and back, a window; channel and label to match, in the window pool."""
    f0 = atom.features[0]
    ch, at = f0.ch, float(f0.at)
    if isinstance(f0, (Step, Window)):
        feats = tuple(Window(ch=f.ch, at=f.at, until=float(until)) for f in atom.features)
    else:
        feats = tuple(Gated(f=f.f, ch=f.ch, at=f.at, until=float(until)) for f in atom.features)
    chan = f"change({at:.6g} <= {ch} < {until:.6g})"
    label = re.sub(r"from \S+ \S+ (on|until \S+)$", f"from {ch} {at:.6g} until {until:.6g}", atom.label)
    return Atom(atom.family, atom.place, atom.target, feats, chan, label, "change_window", atom.joints, dict(atom.meta))


def as_step(atom: Atom) -> Atom:
    """The change ``atom`` (a step or a window) from its start on, without an end: a step, in the step pool."""
    return change_from(atom, float(atom.features[0].at), "change")


def row_times(ctx: RowContext) -> tuple[str, np.ndarray]:
    """The time channel of the rows (``t_s`` when it varies, else the row order) and its values ``(n,)``."""
    if ctx.t_s is not None and np.ptp(ctx.t_s) > 0:
        return "t_s", np.asarray(ctx.t_s, float)
    return "row", np.arange(len(ctx.q), dtype=float)


def _steps(n: int) -> np.ndarray:
    """The positions ``s`` (time-ordered rows ``>= s`` change) with ``max(MIN_ROWS, MIN_SIDE n)`` rows on each side."""
    side = max(MIN_ROWS, int(np.ceil(MIN_SIDE * n)))
    return np.arange(side, n - side + 1)


def _grid(n: int) -> np.ndarray:
    s = _steps(n)
    stride = max(1, int(np.ceil(len(s) / WINDOW_GRID)))
    return s[::stride]


def _pairs(g: np.ndarray, min_rows: int = WINDOW_MIN_ROWS) -> tuple[np.ndarray, np.ndarray]:
    a, b = np.meshgrid(g, g, indexing="ij")
    ok = b - a >= min_rows
    return a[ok], b[ok]


def _short_pairs(n: int, min_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """Windows shorter than two of the grid's strides (a glitch of a few rows falls between the grid's boundaries):
    ``min_rows`` to ``2 stride - 1`` rows, a window of ``w`` rows from every ``max(1, w // SHORT_START_SHARE)``-th
    start of :func:`_steps` (every start while ``w < 2 SHORT_START_SHARE``: every scan of up to 533 rows). A longer
    short window tried only every few rows is one whose ends the scan's refinement (``stride`` rows around the best
    pair, :func:`scan_changes`) moves to the rows; tried at every row their count grows with the square of the rows
    (3.8 million per place on 12,000 rows, 0.43 million so)."""
    s = _steps(n)
    stride = max(1, int(np.ceil(len(s) / WINDOW_GRID)))
    if len(s) == 0 or 2 * stride <= min_rows:
        return np.zeros(0, int), np.zeros(0, int)
    a, w = np.meshgrid(s, np.arange(min_rows, 2 * stride), indexing="ij")
    b = a + w
    ok = (b <= s[-1]) & ((a - s[0]) % np.maximum(1, w // SHORT_START_SHARE) == 0)
    return a[ok], b[ok]


def selection_short(n_cal: int) -> int | None:
    """The shortest window the selection scans at every row (``short`` of :func:`scan_changes` and
    :func:`change_pool_sizes`): ``MIN_ROWS`` where the short windows between the grid's boundaries are at most
    ``2 WINDOW_MIN_ROWS - 1`` rows wide (a glitch of a few rows), else None (the grid alone: on a campaign of thousands
    of rows the short windows at every row are thousands of times the grid's pairs per place and per round; the
    glitch scan after the blocks tries them once, :func:`twin.diagnosis.late.glitches`)."""
    s = _steps(n_cal)
    stride = max(1, int(np.ceil(len(s) / WINDOW_GRID)))
    return MIN_ROWS if 2 * stride - 1 <= 2 * WINDOW_MIN_ROWS - 1 else None


def change_pool_sizes(n_cal: int, places: list[ChangePlace], *, short: int | None = None) -> dict[str, int]:
    """The Bonferroni factor of each change pool: places times row positions (steps) or pairs of them (windows; with
    ``short``, also the short windows of at least that many rows, :func:`_short_pairs`, :func:`scan_changes`)."""
    n_short = len(_short_pairs(n_cal, short)[0]) if short else 0
    return {"change": max(1, len(places) * len(_steps(n_cal))),
            "change_window": max(1, len(places) * (len(_pairs(_grid(n_cal), short or WINDOW_MIN_ROWS)[0]) + n_short))}


def _atom(pl: ChangePlace, ch: str, at: float, until: float | None) -> Atom:
    """The change at place ``pl`` from ``at`` on (until ``until``) on the time channel ``ch``."""
    if until is None:
        gate = {"ch": ch, "at": float(at)}
        chan = f"change({ch} >= {at:.6g})"
        when = f"from {ch} {at:.6g} on"
    else:
        gate = {"ch": ch, "at": float(at), "until": float(until)}
        chan = f"change({at:.6g} <= {ch} < {until:.6g})"
        when = f"from {ch} {at:.6g} until {until:.6g}"
    if pl.inner is None:
        feats = ((Step if until is None else Window)(**gate),)
    else:
        feats = tuple(Gated(f=f, **gate) for f in pl.inner)
    return Atom("change", pl.place, pl.target, feats, chan, f"change of the {pl.words} {when}",
                "change" if until is None else "change_window", pl.joints)


def change_at(pl: ChangePlace, ch: str, at: float) -> Atom:
    """The change at place ``pl`` from ``at`` on (a step) on the time channel ``ch``."""
    return _atom(pl, ch, at, None)


EIG_MIN = 1e-4  # directions of a unit-scaled projected Gram matrix below this eigenvalue are dropped (1 % of a column)


def _cholesky(G: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cholesky factors ``L`` ``(k, p, p)`` of a stack of symmetric matrices, column by column over the whole stack,
    and whether each is positive definite ``(k,)`` (its factor is then exact; else its entries are meaningless)."""
    k, p, _ = G.shape
    L = np.zeros_like(G)
    ok = np.ones(k, bool)
    for j in range(p):
        s = G[:, j, j] - np.sum(L[:, j, :j] ** 2, axis=1)
        ok &= s > 0
        d = np.sqrt(np.where(s > 0, s, 1.0))
        L[:, j, j] = d
        if j + 1 < p:
            L[:, j + 1:, j] = (G[:, j + 1:, j] - np.einsum("kia,ka->ki", L[:, j + 1:, :j], L[:, j, :j])) / d[:, None]
    return L, ok


def _gains(C: np.ndarray, A: np.ndarray, b: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """``Delta chi2`` and rank ``(k,)`` of stacked candidates: ``C`` ``(k, p, p)``, ``A`` ``(k, P, p)``, ``b``
    ``(k, p)`` (columns scaled to unit norm, directions below 1 % of a unit column dropped: eigenvalues of the
    projected Gram matrix ``G`` at most ``EIG_MIN``): :func:`_gains_gram` with ``A^T A``."""
    return _gains_gram(C, np.matmul(np.swapaxes(A, 1, 2), A), b, scale)


def _window_gains(Cc: np.ndarray, Ac: np.ndarray, bc: np.ndarray, ia: np.ndarray, ib: np.ndarray, ok: np.ndarray,
                  scale: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_gains` of the windows ``ia[i]..ib[j]`` where ``ok[i, j]`` (``(na, nb)``; results in ``np.nonzero(ok)``
    order) from the prefix sums ``Cc`` ``(n+1, p, p)``, ``Ac`` ``(n+1, P, p)``, ``bc`` ``(n+1, p)``. With ``X =
    Ac - Ac[ref]`` (a start in the middle of ``ia``: the window's ``A = X_e - X_s``, ``X_s`` small),
    ``A^T A = X_e^T X_e + X_s^T X_s - X_s^T X_e - (X_s^T X_e)^T``: one Gram per index and one product of the two
    index sets instead of a ``P x p`` matrix per window."""
    ref = Ac[ia[len(ia) // 2]]
    Xa, Xb = Ac[ia] - ref, Ac[ib] - ref  # (na, P, p), (nb, P, p)
    Ma = np.matmul(np.swapaxes(Xa, 1, 2), Xa)
    Mb = np.matmul(np.swapaxes(Xb, 1, 2), Xb)
    I, J = np.nonzero(ok)
    p = Xa.shape[2]
    AtA = Ma[I] + Mb[J]
    step = max(1, int(4e6 // max(1, p * p * len(ib))))  # starts per cross product (~32 MB at most)
    for lo in range(0, len(ia), step):
        K = np.tensordot(Xa[lo:lo + step], Xb, axes=([1], [1]))  # (k, p, nb, p): X_s^T X_e
        sel = (I >= lo) & (I < lo + step)
        cross = K[I[sel] - lo, :, J[sel], :]  # (m, p, p)
        AtA[sel] -= cross + np.swapaxes(cross, 1, 2)
    return _gains_gram(Cc[ib[J]] - Cc[ia[I]], AtA, bc[ib[J]] - bc[ia[I]], scale)


def _gains_gram(C: np.ndarray, AtA: np.ndarray, b: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """``Delta chi2`` and rank ``(k,)`` of stacked candidates from ``C`` ``(k, p, p)``, ``A^T A`` ``(k, p, p)`` and
    ``b`` ``(k, p)``: the projected Gram matrix ``G = D (C - A^T A) D`` (``D``: the columns scaled to unit norm).

    Where every eigenvalue of ``G`` is above ``EIG_MIN`` (``G - EIG_MIN I`` has a Cholesky factor) nothing is dropped
    and the gain is ``|L^-1 D b|^2`` with ``G = L L^T``; the others take the eigen-decomposition."""
    d = np.sqrt(np.maximum(np.diagonal(C, axis1=1, axis2=2), 0.0))
    has = d > 1e-12
    D = np.where(has, 1.0 / np.where(has, d, 1.0), 0.0)
    G = (C - AtA) * D[:, :, None] * D[:, None, :]
    bD = b * D
    p = G.shape[1]
    if p == 1:
        lam = G[:, 0, :]
        ok = (lam > EIG_MIN) & has
        gain = np.where(ok[:, 0], bD[:, 0] ** 2 / np.where(ok[:, 0], lam[:, 0], 1.0), 0.0) / scale
        return gain, ok.sum(axis=1)
    gain, rank = np.zeros(len(G)), np.zeros(len(G), int)
    _, full = _cholesky(G - EIG_MIN * np.eye(p))
    full &= np.all(has, axis=1)
    if np.any(full):
        L, _ = _cholesky(G[full])
        y = np.zeros((int(full.sum()), p))
        r = bD[full]
        for j in range(p):
            y[:, j] = (r[:, j] - np.einsum("ka,ka->k", L[:, j, :j], y[:, :j])) / L[:, j, j]
        gain[full], rank[full] = np.sum(y * y, axis=1) / scale, p
    rest = ~full
    if np.any(rest):
        lam, V = np.linalg.eigh(G[rest])
        ok = (lam > EIG_MIN) & np.any(has[rest], axis=1)[:, None]
        proj = np.einsum("kij,ki->kj", V, bD[rest])
        gain[rest] = np.sum(np.where(ok, proj**2 / np.where(ok, lam, 1.0), 0.0), axis=1) / scale
        rank[rest] = ok.sum(axis=1)
    return gain, rank


def _uniform(rss: np.ndarray, m: np.ndarray, gain: np.ndarray, rank: np.ndarray, rss_all: float, m_all: float,
             scale: float) -> np.ndarray:
    """Whether the rows a change acts on are fitted by it to the scatter of the other rows ``(k,)``: the residual
    left on them, ``(RSS_in - Delta chi2) / (m_in - rank)``, against ``RSS_out / m_out`` of the rows outside, not
    larger at ``p < UNIFORM_P`` (``F`` test). A burst of noisy rows, or a gross row, is fitted by no change: a
    change is the same offset on every row it acts on."""
    d1 = np.maximum(m - rank, 1.0)
    d2 = np.maximum(m_all - m, 1.0)
    left = np.maximum(rss - gain * scale, 0.0) / d1
    out = np.maximum(rss_all - rss, 1e-300) / d2
    x = left / out
    ok = np.ones(x.shape, bool)
    # P(F(d1, d2) > 1) is above 0.3 for every d1, d2 >= 1: only ratios beyond 1 can fail
    big = x > 1.0
    ok[big] = f_sf(x[big], d1[big], d2[big]) >= UNIFORM_P
    return ok


def _stands_out(rss_in: float, m_in: float, gain: float, rank: int, rss_all: float, m_all: float, scale: float,
                logp_max: float) -> bool:
    """Whether a change's evidence stands out of the scatter the rows outside it keep: ``Delta chi2 / s^2`` with
    ``s^2 = max(1, RSS_out / m_out)`` (per residual, in the floor's units) still significant (``log p <
    logp_max``). Under scatter beyond the floor that moves over a few rows (a cell wandering in time), a window's
    mean over a stretch of them is as large as that scatter allows, not a change."""
    s2 = max(1.0, (rss_all - rss_in) / max(m_all - m_in, 1.0) / scale)
    return bool(chi2_logsf(gain / s2, max(int(rank), 1)) < logp_max)


def _holds_without_any_row(Ci, Ai, bi, lo: int, hi: int, scale: float, logp_max: float) -> bool:
    """Whether the change on the time-ordered rows ``lo..hi-1`` (per-row blocks ``Ci``, ``Ai``, ``bi``) stays
    significant (``log p < logp_max``) without any one of its rows, with at least ``LOO_SHARE`` of its evidence: no single row
    elects a change (a gross row is fitted by a window around it)."""
    C, A, b = Ci[lo:hi].sum(0), Ai[lo:hi].sum(0), bi[lo:hi].sum(0)
    full, _ = _gains(C[None], A[None], b[None], scale)
    gain, rank = _gains(C[None] - Ci[lo:hi], A[None] - Ai[lo:hi], b[None] - bi[lo:hi], scale)
    lp = np.where(rank > 0, chi2_logsf(gain, np.maximum(rank, 1)), 0.0)
    return bool(np.max(lp) < logp_max and np.min(gain) >= LOO_SHARE * full[0])


LOO_SHARE = 0.5  # a change keeps at least this share of its evidence without any one of its rows
WHITE_Z = 3.0  # the residual a change leaves must not be correlated from row to row beyond this normal score
TOP = 5  # positions of a place tried, best first, for one that holds without any one of its rows
REFINE_ROUNDS = 4  # a window's ends refined around the pair they moved to at most this many times


def _window_at(agg: tuple, s: int, e: int, rr: np.ndarray, mm: np.ndarray, n: int, scale: float,
               lp_max: float) -> float | None:
    """``log p`` of the window ``[s, e)`` (rows in time order) at the place whose per-row aggregates and prefix sums
    ``agg`` holds, where the scan's rules keep it (:func:`_uniform`, :func:`_stands_out`,
    :func:`_holds_without_any_row`; ``rr``, ``mm``: the prefix sums of the residual's squares and counts), else None."""
    Ci, Ai, bi, Cc, Ac, bc = agg
    gain, rank = _gains(Cc[[e]] - Cc[[s]], Ac[[e]] - Ac[[s]], bc[[e]] - bc[[s]], scale)
    ok = (rank > 0) & _uniform(rr[[e]] - rr[[s]], mm[[e]] - mm[[s]], gain, rank, rr[n], mm[n], scale)
    if not ok[0]:
        return None
    lp = float(chi2_logsf(gain, rank.astype(float))[0])
    if lp < 0 and _stands_out(rr[e] - rr[s], mm[e] - mm[s], gain[0], rank[0], rr[n], mm[n], scale, lp_max) \
            and _holds_without_any_row(Ci, Ai, bi, s, e, scale, lp_max):
        return lp
    return None


def _logp(gain: np.ndarray, rank: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """``log chi2_sf(gain, rank)`` ``(k,)`` of the positions ``ok``, computed for the ``TOP`` largest gains of each
    rank only (the others, and those not ``ok``, read 0: never among the best)."""
    lp = np.zeros(len(gain))
    for r in np.unique(rank[ok]):
        idx = np.flatnonzero(ok & (rank == r))
        idx = idx[np.argsort(-gain[idx])[:TOP]]
        lp[idx] = chi2_logsf(gain[idx], float(r))
    return lp


@memo_on_fit
def scan_changes(prob, fit, places: list[ChangePlace], *, windows: bool = True, alpha: float = 0.01,
                 short: int | None = None, last: tuple[int, int] | None = None,
                 sizes: dict[str, int] | None = None) -> list[Atom]:
    """The best step and the best window of every place against ``fit`` (the module docstring's scan over the
    calibration rows in time order) among the positions whose rows the change fits uniformly (:func:`_uniform`): one
    candidate atom each (the selection applies the Bonferroni factor, :func:`change_pool_sizes`). ``short``: windows
    of at least this many rows (default ``WINDOW_MIN_ROWS``), and those shorter than two of the grid's strides tried
    from every row, the longer of them from every few rows (a glitch of a few rows, :func:`_short_pairs`). ``last``:
    steps only, with ``last[0]`` to ``last[1]`` rows after them (a change in the campaign's last rows,
    :func:`twin.diagnosis.late.end_change`) instead of :func:`_steps`' positions. ``sizes``: the Bonferroni factors
    the scan's own rules apply (default :func:`change_pool_sizes`)."""
    if last is not None and windows:
        raise ValueError(f"last={last!r} scans steps only: windows must be False")
    min_rows = short or WINDOW_MIN_ROWS
    sb = scoring_basis(prob, fit)
    rows, r = sb.rows, sb.r
    n = prob.obs_cal.n
    if n < 2 * MIN_ROWS + 1:
        return []
    ch, tv = row_times(prob.ctx)
    t_cal = tv[prob.rows_cal]
    order = np.argsort(t_cal, kind="stable")
    ts = t_cal[order]
    steps = _steps(n) if last is None else np.arange(max(n - last[1], 1), n - last[0] + 1)
    steps = steps[ts[steps] > ts[steps - 1]]  # a change between two rows measured at different times
    g = _grid(n)
    g = g[ts[g] > ts[g - 1]]
    # per-row residual sums of squares and residual counts, in time order (the uniformity check)
    rr = np.concatenate([[0.0], np.cumsum(np.bincount(rows, weights=r * r, minlength=n)[order])])
    mm = np.concatenate([[0.0], np.cumsum(np.bincount(rows, minlength=n)[order].astype(float))])
    sizes = sizes or change_pool_sizes(n, places, short=short)

    aggregates, best_windows = {}, {}

    def place_scan(pl: ChangePlace) -> list[tuple[float, Atom]]:
        out = []
        tmpl = Atom("change", pl.place, pl.target, (Const(),), "", "", "change")
        W, QB, Br = row_aggregates(prob, fit, sb, tmpl)  # (n, c, c), (n, p, c), (n, c)
        c = W.shape[1]
        if pl.inner is None:
            F = np.ones((n, 1))
        else:
            F = prob.features(Atom("change", pl.place, pl.target, pl.inner, "", "", "change"))[prob.rows_cal]
        K = F.shape[1]
        p = K * c
        Ci = np.einsum("nk,nl,nab->nkalb", F, F, W).reshape(n, p, p)[order]
        Ai = np.einsum("nk,nqa->nqka", F, QB).reshape(n, QB.shape[1], p)[order]
        bi = np.einsum("nk,na->nka", F, Br).reshape(n, p)[order]
        Cc = np.concatenate([np.zeros((1, p, p)), np.cumsum(Ci, axis=0)])
        Ac = np.concatenate([np.zeros((1, QB.shape[1], p)), np.cumsum(Ai, axis=0)])
        bc = np.concatenate([np.zeros((1, p)), np.cumsum(bi, axis=0)])
        aggregates[pl] = (Ci, Ai, bi, Cc, Ac, bc)
        if len(steps):
            gain, rank = _gains(Cc[n] - Cc[steps], Ac[n] - Ac[steps], bc[n] - bc[steps], prob.evidence_scale)
            ok = (rank > 0) & _uniform(rr[n] - rr[steps], mm[n] - mm[steps], gain, rank, rr[n], mm[n],
                                       prob.evidence_scale)
            lp = _logp(gain, rank, ok)
            lp_max = np.log(alpha) - np.log(sizes["change"])
            for k in np.argsort(lp)[:TOP]:
                s = steps[k]
                if ok[k] and lp[k] < 0 and _stands_out(rr[n] - rr[s], mm[n] - mm[s], gain[k], rank[k], rr[n], mm[n],
                                                       prob.evidence_scale, lp_max) \
                        and _holds_without_any_row(Ci, Ai, bi, s, n, prob.evidence_scale, lp_max):
                    out.append((float(lp[k]), _atom(pl, ch, 0.5 * (ts[s - 1] + ts[s]), None)))
                    break
        if not windows or len(g) < 2:
            return out
        a, b = _pairs(g, min_rows)
        if short:
            sa_, sb_ = _short_pairs(n, min_rows)
            inside = (ts[sa_] > ts[sa_ - 1]) & (ts[sb_] > ts[sb_ - 1])
            a, b = np.concatenate([a, sa_[inside]]), np.concatenate([b, sb_[inside]])
        lp_all = np.zeros(len(a))
        gain_all, rank_all = np.zeros(len(a)), np.zeros(len(a), int)
        for lo in range(0, len(a), 4000):
            sa, sb_ = a[lo:lo + 4000], b[lo:lo + 4000]
            gain, rank = _gains(Cc[sb_] - Cc[sa], Ac[sb_] - Ac[sa], bc[sb_] - bc[sa], prob.evidence_scale)
            ok = (rank > 0) & _uniform(rr[sb_] - rr[sa], mm[sb_] - mm[sa], gain, rank, rr[n], mm[n],
                                       prob.evidence_scale)
            lp_all[lo:lo + 4000] = _logp(gain, rank, ok)
            gain_all[lo:lo + 4000], rank_all[lo:lo + 4000] = gain, rank
        best = None
        lp_max = np.log(alpha) - np.log(sizes["change_window"])
        for k in np.argsort(lp_all)[:TOP]:
            s, e = int(a[k]), int(b[k])
            if lp_all[k] < 0 and _stands_out(rr[e] - rr[s], mm[e] - mm[s], gain_all[k], rank_all[k], rr[n], mm[n],
                                             prob.evidence_scale, lp_max) \
                    and _holds_without_any_row(Ci, Ai, bi, s, e, prob.evidence_scale, lp_max):
                best = (float(lp_all[k]), int(a[k]), int(b[k]))
                break
        if best is None:
            return out
        stride = max(1, int(np.ceil(len(_steps(n)) / WINDOW_GRID)))
        lo_, hi_ = int(_steps(n)[0]), int(_steps(n)[-1])
        for _ in range(REFINE_ROUNDS if stride > 1 else 0):
            # the best pair refined to the rows around it, again around the pair it moved to while it moves (a short
            # window's ends, tried from every row or every few, may lie a stride or more inside a longer window's)
            sa = np.arange(max(best[1] - stride, lo_), min(best[1] + stride, hi_) + 1)
            sb2 = np.arange(max(best[2] - stride, lo_), min(best[2] + stride, hi_) + 1)
            A2, B2 = np.meshgrid(sa, sb2, indexing="ij")
            pair = (B2 - A2 >= min_rows) & (ts[A2] > ts[A2 - 1]) & (ts[B2] > ts[B2 - 1])
            A2, B2 = A2[pair], B2[pair]
            if not len(A2):
                break
            gain, rank = _window_gains(Cc, Ac, bc, sa, sb2, pair, prob.evidence_scale)
            ok = (rank > 0) & _uniform(rr[B2] - rr[A2], mm[B2] - mm[A2], gain, rank, rr[n], mm[n],
                                       prob.evidence_scale)
            lp = _logp(gain, rank, ok)
            k = int(np.argmin(lp))
            s, e = int(A2[k]), int(B2[k])
            if not (lp[k] < best[0] and _stands_out(rr[e] - rr[s], mm[e] - mm[s], gain[k], rank[k], rr[n], mm[n],
                                                    prob.evidence_scale, lp_max)
                    and _holds_without_any_row(Ci, Ai, bi, s, e, prob.evidence_scale, lp_max)):
                break
            best = (float(lp[k]), s, e)
        best_windows[pl] = best
        return out

    out = [c for got in thread_map(place_scan, places, prob.threads) for c in got]
    if windows:
        # a joint's zero and its compliance share the rows a window of either holds: each is judged on the rows the
        # other placed (the grid's pairs around a short window may not fit one of them uniformly, and a broader
        # place's columns then take the rows alone)
        for pl in places:
            if pl not in aggregates:
                continue
            best = best_windows.get(pl)
            for q, other in best_windows.items():
                if q is pl or (q.place, q.target) != (pl.place, pl.target) or other is None:
                    continue
                got = _window_at(aggregates[pl], other[1], other[2], rr, mm, n, prob.evidence_scale,
                                 np.log(alpha) - np.log(sizes["change_window"]))
                if got is not None and (best is None or got < best[0]):
                    best = (got, other[1], other[2])
            best_windows[pl] = best
        for pl, best in best_windows.items():
            if best is not None:
                _, s, e = best
                out.append((best[0], _atom(pl, ch, 0.5 * (ts[s - 1] + ts[s]), 0.5 * (ts[e - 1] + ts[e]))))
    cands = [a for _, a in sorted(out, key=lambda t: t[0])]
    white = _WhiteTest(prob, fit, sizes, order, places)
    return [a for a, ok in zip(cands, thread_map(white, cands, prob.threads)) if ok]


def same_event(atom: Atom, places: list[ChangePlace]) -> list[Atom]:
    """When ``atom`` is a change of a joint's compliance (a payload put on or taken off): the same change (its start and
    end) at every other joint's payload place of ``places`` (a payload hangs at the flange and loads every joint below
    it at once). Else none."""
    f0 = atom.features[0]
    if not isinstance(f0, Gated) or atom.place != "joint":
        return []
    return [_atom(pl, f0.ch, f0.at, f0.until) for pl in places if pl.payload and pl.target != atom.target]


def _payload_companions(atom: Atom, places: list[ChangePlace]) -> tuple[list[Atom], list[Atom]]:
    """When ``atom`` is a change of a joint's compliance (a payload put on or taken off): the same change (its rows)
    at every other joint's compliance of ``places``, and each of those joints' compliance under its gravity-torque
    shapes and under the payload's shapes on every row (the second list: the same for every change of ``places``).
    A payload hangs at the flange and gravity loads every joint below it at once (the torque shapes at each of them
    change together), on top of the arm's own weight, which the joints carry on every row (``q_j += c_j
    (tau_j,arm + L_i tau_j,payload)``); a payload taken off was carried on every row before (``L_i = 1`` there): its
    shapes on every row hold that loaded state, the change its removal. Else two empty lists."""
    f0 = atom.features[0]
    if not isinstance(f0, Gated) or atom.place != "joint":
        return [], []
    loads = [pl for pl in places if pl.inner is not None and pl.place == "joint"]
    same = [_atom(pl, f0.ch, f0.at, f0.until) for pl in loads if pl.target != atom.target]
    return same, [Atom("compliance", pl.place, pl.target, pl.inner, f"gravity torque of {pl.target}", pl.words,
                       "change", pl.joints) for pl in loads]


def _orthonormal(X: np.ndarray) -> np.ndarray:
    """An orthonormal basis ``(m, k)`` of the columns of ``X`` ``(m, c)``: its left singular vectors whose singular
    value is above ``eps max(m, c)`` times the largest (the rank least squares takes, ``numpy.linalg.lstsq``)."""
    if X.shape[1] == 0:
        return X
    U, S, _ = np.linalg.svd(X, full_matrices=False)
    return U[:, S > S[0] * np.finfo(float).eps * max(X.shape)] if S[0] > 0 else U[:, :0]


def _off(U: np.ndarray, X: np.ndarray) -> np.ndarray:
    """``X - U U^T X``: ``X`` ``(m,)`` or ``(m, c)`` projected off the orthonormal columns ``U`` ``(m, k)``."""
    return X - U @ (U.T @ X) if U.shape[1] else X


class _WhiteTest:
    """Whether the residual a change leaves is white in time (:meth:`__call__`), for the changes of one scan against
    one fit: the lag-1 correlation of consecutive rows' whitened residual vectors (time order, rows of the same
    commanded joints not paired: a repeat shares its visit's error), ``rho = sum r_i . r_{i+1} / sqrt(sum |r_i|^2
    sum |r_{i+1}|^2)``, not beyond ``WHITE_Z / sqrt(pairs)``. A change leaves the rows independent; scatter that
    wanders over a few rows stays correlated after any change fitted to a stretch of it, whose evidence against the
    (white) floor then says nothing. A payload's change (:func:`_payload_companions`) is fitted with its companions
    for this test: a payload changes every joint's load at once, and one joint's change alone leaves the others'
    steps in the rows. A residual still correlated is tested once more with every identifiable direction of the
    model's columns refitted beside the change (:func:`_geometry_span`, when the geometric parameter selection left
    some out), when those directions alone leave it correlated: a selection chosen on rows the change dominated
    leaves a misfit that follows the configurations along the campaign's path, which the left-out parameters take
    and a wander does not.

    The residual after columns ``[X, Y]`` is the residual after ``X - P_Y X`` of ``r - P_Y r`` (``P_Y``: the
    projection on ``Y``'s span), so what every change of the scan shares (the time order's pairs, the companions on
    every row, the geometry's span and the residual beyond it) is projected off once."""

    def __init__(self, prob, fit, sizes: dict, order: np.ndarray, places: list[ChangePlace]):
        self.prob, self.fit, self.sizes, self.order, self.places = prob, fit, sizes, order, places
        self.sb = scoring_basis(prob, fit)
        q = np.round(prob.ctx.q[prob.rows_cal][order], 9)
        self.pair = ~np.all(q[1:] == q[:-1], axis=1) & (prob.w_cal[order][1:] > 0) & (prob.w_cal[order][:-1] > 0)
        self._shared: dict = {}
        self._lock = threading.RLock()  # the shared parts are computed once, whichever thread asks first

    def _z(self, e_kept: np.ndarray) -> float | None:
        e = np.zeros(len(self.sb.keep))
        e[self.sb.keep] = e_kept
        return _lag1_z(self.fit, e, self.order, self.pair)

    def _once(self, key: tuple, make):
        """``make()`` computed once per scan under ``key``, whichever thread asks first."""
        with self._lock:
            if key not in self._shared:
                self._shared[key] = make()
            return self._shared[key]

    def _every_row(self, every_row: list[Atom]) -> np.ndarray:
        """The reduced columns ``Ep`` ``(m_kept, k)`` of the companions on every row."""
        def make() -> np.ndarray:
            more = score_atoms(self.prob, self.fit, every_row, self.sizes, exact_top=len(every_row)) if every_row \
                else []
            return np.hstack([m.Ep for m in more]) if more else np.zeros((len(self.sb.r), 0))
        return self._once(("rows", tuple(a.key for a in every_row)), make)

    def _rows_basis(self, every_row: list[Atom]) -> tuple[np.ndarray, np.ndarray]:
        """An orthonormal basis of the companions on every row and the residual ``r`` beyond it."""
        def make() -> tuple[np.ndarray, np.ndarray]:
            U1 = _orthonormal(self._every_row(every_row))
            return U1, _off(U1, self.sb.r)
        return self._once(("rows_basis", tuple(a.key for a in every_row)), make)

    def _geometry(self) -> tuple[np.ndarray, np.ndarray, float | None]:
        """The geometry's span ``U``, the raw residual beyond it and that residual's normal score."""
        def make() -> tuple:
            U = _geometry_span(self.sb, self.fit)
            rU = _off(U, (self.sb.rc.r * self.sb.sw)[self.sb.keep])
            return U, rU, self._z(rU)
        return self._once(("geometry",), make)

    def _every_row_off_geometry(self, every_row: list[Atom]) -> np.ndarray:
        """The companions on every row (:meth:`_every_row`) projected off the geometry's span."""
        return self._once(("rows_off_geometry", tuple(a.key for a in every_row)),
                          lambda: _off(self._geometry()[0], self._every_row(every_row)))

    def __call__(self, atom: Atom) -> bool:
        prob, fit, sizes, sb = self.prob, self.fit, self.sizes, self.sb
        got = score_atoms(prob, fit, [atom], sizes, exact_top=1)
        if not got:
            return False
        same, every_row = _payload_companions(atom, self.places)
        more = score_atoms(prob, fit, same, sizes, exact_top=len(same)) if same else []
        if same or every_row:
            U1, r1 = self._rows_basis(every_row)
            X = _off(U1, np.hstack([got[0].Ep] + [m.Ep for m in more]))
            e = r1 - X @ np.linalg.lstsq(X, r1, rcond=None)[0]
        else:
            fitted = got[0].E @ got[0].psi  # Scored.fitted, projected off Q as a vector
            e = got[0].r - (fitted - sb.Q @ (sb.Q.T @ fitted))
        z = self._z(e)
        if z is None or z <= WHITE_Z:
            return True
        U, rU, z_geometry = self._geometry()
        if U.shape[1] <= sb.Q.shape[1]:
            return False
        # the correlation left may be the geometry the selection left out (a parameter set chosen on rows the change
        # dominated): the change still leaves the rows white when every identifiable geometric direction refits with
        # it, and that geometry alone leaves them correlated (else the change takes nothing the geometry would not)
        if z_geometry is None or z_geometry <= WHITE_Z:
            return False
        X = np.hstack([_off(U, np.hstack([got[0].E] + [m.Ep for m in more])), self._every_row_off_geometry(every_row)])
        z = self._z(rU - X @ np.linalg.lstsq(X, rU, rcond=None)[0])
        return z is None or z <= WHITE_Z


def _lag1_z(fit, e: np.ndarray, order: np.ndarray, pair: np.ndarray) -> float | None:
    """The normal score ``rho sqrt(pairs)`` of the lag-1 correlation of consecutive rows' residual vectors (the
    per-row blocks of ``e`` in time ``order``, the pairs ``pair`` of consecutive rows), None with fewer than 10 pairs
    or no residual."""
    R = row_blocks(fit.model_cal, e)[order]
    R[~np.isfinite(R)] = 0.0
    a, b = R[:-1][pair], R[1:][pair]
    den = float(np.sqrt(np.sum(a * a) * np.sum(b * b)))
    if den <= 0 or pair.sum() < 10:
        return None
    return float(np.sum(a * b)) / den * float(np.sqrt(pair.sum()))


# a geometric direction counts as identifiable when its singular value, of the unit-norm columns, is above this
# fraction of the largest (the estimator's identifiability tolerance)
GEOMETRY_RCOND = 1e-6


def _geometry_span(sb, fit) -> np.ndarray:
    """An orthonormal basis ``(m_kept, k)`` of every identifiable direction of the model's columns on the kept rows
    (the free ones and those the parameter selection left out), cached on the fit."""
    got = fit.cache.get("geometry_span")
    if got is None or got[0] is not sb:
        A = (sb.rc.J * sb.sw[:, None])[sb.keep]
        norms = np.linalg.norm(A, axis=0)
        A = A[:, norms > 0] / norms[norms > 0]
        U, S, _ = np.linalg.svd(A, full_matrices=False)
        got = fit.cache["geometry_span"] = (sb, U[:, S > S[0] * GEOMETRY_RCOND] if S.size else U[:, :0])
    return got[1]


def place_scatter(prob, fit, window: Atom, *, every_column: bool = False) -> float:
    """The variance, in the floor's units, of the mean residual along the ``window``'s place over a stretch of rows,
    from the rows outside it: each row's evidence for an offset of the place, ``z_i = g_i . r_i / sqrt(|g_i|^2 -
    |Q^T g_i|^2)``, their mean square ``s^2`` (at least 1) and their correlation from one row to the next in time
    ``rho`` (clipped to [0, 0.9]): ``s^2 (1 + rho) / (1 - rho)``, the variance of a long stretch's mean of an AR(1)
    process. A wander of the cell moves whole rows together, shows along a joint's direction more than the floor
    says and holds over a few rows; a window's evidence is measured against it (1 for white rows at the floor).
    ``g_i`` is the place's first column (a joint's offset, the direction a compliance's change turns it); with
    ``every_column``, each of the place's columns (a frame's six directions, per station), the largest figure."""
    return _scatter_figure(_scatter_parts(prob, fit, window, every_column))


def _scatter_figure(parts: list[tuple[float, float]]) -> float:
    """:func:`place_scatter`'s figure from :func:`_scatter_parts`: the largest ``max(1, s^2) (1 + rho) / (1 - rho)``,
    at least 1."""
    return max([1.0] + [max(1.0, s2) * (1.0 + rho) / (1.0 - rho) for s2, rho in parts])


def _scatter_parts(prob, fit, window: Atom, every_column: bool) -> list[tuple[float, float]]:
    """Per column of the ``window``'s place (:func:`place_scatter`), the rows outside it: the mean square ``s^2`` of
    their evidence for an offset of the place (in the floor's units) and its correlation ``rho`` from one row to the
    next in time (clipped to [0, 0.9]); a column with fewer than 10 such rows gives none."""
    sb = scoring_basis(prob, fit)
    W, QB, Br = row_aggregates(prob, fit, sb, window)
    inside = prob.features(window)[prob.rows_cal, 0] != 0
    _, tv = row_times(prob.ctx)
    order = np.argsort(tv[prob.rows_cal], kind="stable")
    out = []
    for j in range(W.shape[1] if every_column else 1):
        den = W[:, j, j] - np.einsum("np,np->n", QB[:, :, j], QB[:, :, j])
        ok = (~inside) & (den > 1e-12 * max(float(np.max(W[:, j, j])), 1e-300)) & (prob.w_cal > 0)
        if np.sum(ok) < 10:
            continue
        z = np.where(ok, Br[:, j] / np.sqrt(np.where(ok, den, 1.0)), 0.0) / np.sqrt(prob.evidence_scale)
        s2 = float(np.mean(z[ok] ** 2))
        zo, oko = z[order], ok[order]
        pair = oko[1:] & oko[:-1]
        a, b = zo[:-1][pair], zo[1:][pair]
        den2 = float(np.sqrt(np.sum(a * a) * np.sum(b * b)))
        rho = float(np.clip(np.sum(a * b) / den2, 0.0, 0.9)) if den2 > 0 else 0.0
        out.append((s2, rho))
    return out


# the mean square evidence along a window's place of the rows outside it (the floor's units) beyond which they hold a
# change the model lacks, not a wander of the cell: the drawn clean campaigns' wanders (0.25-0.6x the noise, rho up
# to 0.85) give 1.2-2.9; the rows outside a window of payload_905's change begun at a wrong row give 66
STRUCTURED_OUTSIDE = 10.0


@memo_on_fit
def window_wander(prob, fit, s, sizes: dict) -> tuple[float, float]:
    """The pool-adjusted log p-value of a scored window ``s`` (a change and back) with its evidence measured against
    the scatter the rows outside it show along its place (:func:`place_scatter`: 1 for white rows at the floor, the
    long-run variance of an AR(1) where the noise wanders over a few rows), and the largest mean square of those rows'
    evidence on a column of the place (the floor's units). A window fitted to a stretch of a wander gains the wander's
    excursion there, which the rows outside show as often. A frame's window is read on each of its columns (a wander
    moves the cell along any of them). The scatter is read on the model with the window: without it the rows inside
    pull the fit (the joint's offset, the load's shapes) and the rows outside carry that pull, a structure of their
    own (read so, a 40-row window of joint 2's zero was not kept on one seed of two of
    ``tests/test_diagnosis_changes.py``). A mean square beyond ``STRUCTURED_OUTSIDE`` says that the rows outside
    hold a change the model lacks, not that they wander."""
    frame = s.atom.place == "param" and s.atom.target in ("tool", "base")
    chosen = list(fit.chosen) + [(s.atom, s.basis)]
    # fitted under the problem's gross rows as they are (the scored atom's columns are of those rows)
    with_it = prob.fit(fit.z[: prob.prep.space.size], chosen, psi_init(fit, chosen))
    parts = _scatter_parts(prob, with_it, s.atom, frame)
    logp = chi2_logsf(s.dchi2 / prob.evidence_scale / _scatter_figure(parts), s.basis.shape[1]) + \
        np.log(sizes[s.atom.pool])
    return logp, max([0.0] + [q for q, _ in parts])


def describe_changes(atoms_json: list[dict], ctx: RowContext, pose_id: np.ndarray) -> list[dict]:
    """The ``changes`` of ``diagnosis.json``: per kept change, its ``kind`` (``step`` or ``window``), ``place`` and
    ``target``, the row where it starts (``row``: index in the dataset, ``pose_id``, ``t_s`` when recorded) and, for
    a window, where it ends (the first row back in the former state), its ``size`` (the term's value in words'
    units: deg for a joint offset, the frame's change in mm and deg, a compliance change's RMS effect) and the
    label."""
    ch, tv = row_times(ctx)
    order = np.argsort(tv, kind="stable")
    out = []
    for a in atoms_json:
        if not is_change(a):
            continue
        f0 = feature_from_dict(a["features"][0])
        at, until = float(f0.at), getattr(f0, "until", None)

        def first(v):
            later = order[tv[order] >= v]
            return int(later[0]) if len(later) else None

        row = first(at)
        d = {"kind": "step" if until is None else "window", "place": a["place"], "target": a["target"],
             "label": a["label"], "minor": bool(a.get("minor", False)), "row": row,
             "pose_id": None if row is None else int(pose_id[row]),
             "t_s": None if (row is None or ctx.t_s is None) else float(ctx.t_s[row])}
        if until is not None:
            end = first(float(until))
            d.update({"end_row": end, "end_pose_id": None if end is None else int(pose_id[end]),
                      "end_t_s": None if (end is None or ctx.t_s is None) else float(ctx.t_s[end])})
        v = np.asarray(a["values"], float)
        if a["place"] == "param" and a["target"] in ("tool", "base"):
            d["size"] = {"translation_mm": (v[:3] * MM_PER_M).tolist(), "rotation_deg": rad_to_deg(v[3:]).tolist()}
        elif a["place"] == "joint" and isinstance(f0, (Step, Window)):
            d["size"] = {"offset_deg": float(rad_to_deg(v[0])), "sd_deg": float(rad_to_deg(a["sd"][0]))}
        else:
            d["size"] = dict(a["size"])
        out.append(d)
    return out
