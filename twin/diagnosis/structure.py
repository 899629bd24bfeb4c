"""The statistics the selection reads: the structure test of whitened residuals against the noise floor (``chi2`` with a
stated floor, ``F`` with an estimated one), gross rows, the ``chi2`` tail in logs and the signed-rank score.

Everything works on whitened residuals of :class:`~twin.diagnosis.extend.ExtendedModel` (per-axis noise of the
measurement frame, :class:`~twin.diagnosis.floor.NoiseFloor`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..estimator import distributions as dists
from .floor import NoiseFloor

__all__ = ["StructureTest", "structure_test", "fit_block_test", "row_rms", "gross_rows", "chi2_logsf", "signed_rank_z"]


@dataclass(frozen=True)
class StructureTest:
    """``T`` (quadratic form of the validation residuals), its ``m`` degrees of freedom, ``p_value``, and the
    RMS of the whitened residuals (1 for noise alone)."""

    statistic: float
    dof: int
    p_value: float
    whitened_rms: float
    distribution: str


def structure_test(r: np.ndarray, Jv: np.ndarray, Jc: np.ndarray, floor: NoiseFloor) -> StructureTest:
    """``T = r^T (I + Jv C Jv^T)^-1 r`` with ``C = (Jc^T Jc)^-1`` (whitened units)."""
    m = r.size
    H = Jc.T @ Jc
    # Woodbury with C = H^-1: (I + Jv C Jv^T)^-1 = I - Jv (H + Jv^T Jv)^-1 Jv^T
    M = H + Jv.T @ Jv
    y = Jv.T @ r
    T = float(r @ r - y @ np.linalg.lstsq(M, y, rcond=None)[0]) if M.size else float(r @ r)
    if np.isinf(floor.dof):
        p = float(dists.chi2_sf(T, m))
        dist = f"chi2({m})"
    else:
        p = float(dists.f_sf(T / m, m, floor.dof))
        dist = f"F({m}, {int(floor.dof)})"
    return StructureTest(T, m, p, float(np.sqrt(np.mean(r**2))), dist)


def fit_block_test(r: np.ndarray, n_free: int, floor: NoiseFloor) -> StructureTest:
    """The whitened residual ``r`` of a fit on the rows that fit it (gross rows left out) against the floor:
    ``T = r^T r`` with ``m - p`` degrees of freedom (``p = n_free`` parameters), ``chi2(m - p)`` with a stated
    floor, ``(T / (m - p)) ~ F(m - p, nu)`` with an estimated one. A structure inside the block that fits (a change
    in its middle) shows here even where the held-out block after it holds only one state of it."""
    m = max(r.size - int(n_free), 1)
    T = float(r @ r)
    if np.isinf(floor.dof):
        p, dist = float(dists.chi2_sf(T, m)), f"chi2({m})"
    else:
        p, dist = float(dists.f_sf(T / m, m, floor.dof)), f"F({m}, {int(floor.dof)})"
    return StructureTest(T, m, p, float(np.sqrt(np.mean(r**2))) if r.size else 0.0, dist)


def row_rms(r: np.ndarray, row: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The RMS ``(n,)`` of the residuals ``r`` of each of ``n`` rows (``row``: the row of each residual) and their
    count per row (0 and 0 for a row without residuals)."""
    ss = np.bincount(row, weights=r**2, minlength=n)
    cnt = np.bincount(row, minlength=n)
    return np.sqrt(ss / np.maximum(cnt, 1)), cnt


def gross_rows(r: np.ndarray, row: np.ndarray, n: int, *, max_fraction: float = 0.02) -> np.ndarray:
    """Rows ``(n,)`` bool whose whitened misfit is beyond both the floor's ``1e-6/n`` quantile and
    ``median + 8 MAD`` of the rows; none when more than ``max(2, max_fraction n)`` rows are (that is
    structure, not a few gross rows)."""
    e, cnt = row_rms(r, row, n)
    has = cnt > 0
    if has.sum() < 5:
        return np.zeros(n, dtype=bool)
    k = np.maximum(cnt, 1)
    thr_floor = np.sqrt(dists.chi2_isf(1e-6 / max(n, 1), k) / k)
    med = float(np.median(e[has]))
    mad = 1.4826 * float(np.median(np.abs(e[has] - med)))
    bad = has & (e > thr_floor) & (e > med + 8 * max(mad, 0.05 * med))
    if bad.sum() > max(2, int(max_fraction * has.sum())):
        return np.zeros(n, dtype=bool)
    return bad


def chi2_logsf(x, k):
    """``log P(chi2(k) > x)`` (scalars or arrays), finite where scipy's underflows to ``-inf`` (large ``x``: the
    leading term of the upper incomplete gamma function, :func:`_upper_tail_term`)."""
    x, k = np.asarray(x, float), np.asarray(k, float)
    if x.ndim == 0 and k.ndim == 0:  # two scalars (most calls): the branch below's number, without reshaping
        vv, xv = dists.chi2_logsf(x, k), x[()]
        if not np.isfinite(vv) and np.isfinite(xv) and xv > 0:
            vv = _upper_tail_term(xv, k[()])
        return float(vv)
    v = dists.chi2_logsf(x, k)
    if np.size(v) == 1:  # one entry: without the masks of an array
        xv, kv, vv = x.reshape(-1)[0], k.reshape(-1)[0], np.reshape(v, -1)[0]
        if not np.isfinite(vv) and np.isfinite(xv) and xv > 0:
            vv = _upper_tail_term(xv, kv)
        return float(vv) if np.ndim(v) == 0 else np.full(np.shape(v), vv, dtype=float)
    v = np.asarray(v, float)
    bad = ~np.isfinite(v) & np.isfinite(x) & (x > 0)
    if np.any(bad):
        xb, kb = np.broadcast_to(x, v.shape)[bad], np.broadcast_to(k, v.shape)[bad]
        v = v.copy()
        v[bad] = _upper_tail_term(xb, kb)
    return v


def _upper_tail_term(x, k):
    """``-x/2 + (k/2 - 1) log(x/2) - lgamma(k/2)``: the log of the leading term of the chi-square tail."""
    from scipy.special import gammaln

    return -x / 2 + (k / 2 - 1) * np.log(x / 2) - gammaln(k / 2)


def signed_rank_z(c: np.ndarray) -> float:
    """Wilcoxon's signed-rank statistic of ``c`` ``(n,)`` as a normal score: ``(W+ - n (n + 1) / 4) / sqrt(n (n + 1)
    (2 n + 1) / 24)``, ``W+`` the sum of the ranks of ``|c|`` over the positive entries (zeros dropped, ties at their
    mean rank). ~N(0, 1) when the entries are independent and symmetric about zero; 0 for fewer than two."""
    c = np.asarray(c, float)
    c = c[c != 0]
    n = c.size
    if n < 2:
        return 0.0
    w = float(dists.average_ranks(np.abs(c))[c > 0].sum())
    return (w - n * (n + 1) / 4.0) / np.sqrt(n * (n + 1) * (2 * n + 1) / 24.0)
