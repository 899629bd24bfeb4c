"""The chi-square and F tail functions the estimator and the diagnosis use, from ``scipy.special``, and the average
ranks of a rank test.

The same numbers as ``scipy.stats.chi2``, ``scipy.stats.f`` (the functions those distributions call, with their
handling of the support's ends) and ``scipy.stats.rankdata`` (``tests/test_estimator_distributions.py`` compares
them bit for bit), without importing ``scipy.stats``, which costs more than a second of start-up for every ``twin calibrate`` and ``twin
diagnose``.
"""

from __future__ import annotations

import numpy as np
from scipy import special as sc

__all__ = ["chi2_sf", "chi2_logsf", "chi2_isf", "chi2_ppf", "chi2_median", "f_sf", "average_ranks"]


def _support(x, k):
    x, k = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(k, dtype=float))
    return x, k, k > 0


def _out(v: np.ndarray):
    return v[()] if v.ndim == 0 else v


def chi2_sf(x, k):
    """``P(chi2(k) > x)`` (scalars or arrays): 1 for ``x <= 0``, NaN for ``k <= 0``."""
    x, k, ok = _support(x, k)
    out = np.full(x.shape, np.nan)
    good = ok & (x > 0) & (x < np.inf)
    out[ok & (x <= 0)] = 1.0
    out[ok & (x == np.inf)] = 0.0
    out[good] = sc.chdtrc(k[good], x[good])
    return _out(out)


def chi2_logsf(x, k):
    """``log P(chi2(k) > x)``: ``log(sf)`` beyond the median, ``log1p(-cdf)`` below it (as ``scipy.stats``); 0 for
    ``x <= 0``, ``-inf`` where the tail underflows, NaN for ``k <= 0``."""
    if type(x) is np.ndarray and type(k) is np.ndarray and x.ndim == 0 and k.ndim == 0 \
            and x.dtype == np.float64 and k.dtype == np.float64:
        # two 0-d arrays (what the diagnosis passes, thousands of times): the entry's number as the scalar the
        # broadcast below gives, without broadcasting
        return np.float64(_chi2_logsf_entry(x[()], k[()]))
    x, k, ok = _support(x, k)
    if x.size == 1:  # one entry (the diagnosis asks thousands): the branches below without the masks of an array
        return _out(np.full(x.shape, _chi2_logsf_entry(x.reshape(-1)[0], k.reshape(-1)[0])))
    out = np.full(x.shape, -np.inf)
    out[~ok | np.isnan(x)] = np.nan
    out[ok & (x <= 0)] = 0.0
    good = ok & (x > 0) & (x < np.inf)
    xg, kg = x[good], k[good]
    upper = xg > 2 * sc.gammaincinv(kg / 2, 0.5)
    v = np.empty(xg.shape)
    with np.errstate(divide="ignore"):
        v[upper] = np.log(sc.chdtrc(kg[upper], xg[upper]))
        v[~upper] = np.log1p(-sc.chdtr(kg[~upper], xg[~upper]))
    out[good] = v
    return _out(out)


def _chi2_logsf_entry(x: np.float64, k: np.float64) -> np.float64:
    """:func:`chi2_logsf` of one ``x`` and one ``k``: the same scipy functions of the same numbers."""
    if not k > 0 or np.isnan(x):
        return np.float64(np.nan)
    if x <= 0:
        return np.float64(0.0)
    if x == np.inf:
        return np.float64(-np.inf)
    with np.errstate(divide="ignore"):
        if x > 2 * sc.gammaincinv(k / 2, 0.5):
            return np.log(sc.chdtrc(k, x))
        return np.log1p(-sc.chdtr(k, x))


def chi2_isf(q, k):
    """The ``x`` with ``P(chi2(k) > x) = q``: ``inf`` for ``q = 0``, 0 for ``q = 1``, NaN outside."""
    q, k, ok = _support(q, k)
    out = np.full(q.shape, np.nan)
    good = ok & (q > 0) & (q < 1)
    out[ok & (q == 0)] = np.inf
    out[ok & (q == 1)] = 0.0
    out[good] = sc.chdtri(k[good], q[good]) * 1.0 + 0.0
    return _out(out)


def chi2_ppf(p, k):
    """The ``x`` with ``P(chi2(k) <= x) = p``: 0 for ``p = 0``, ``inf`` for ``p = 1``, NaN outside."""
    p, k, ok = _support(p, k)
    out = np.full(p.shape, np.nan)
    good = ok & (p > 0) & (p < 1)
    out[ok & (p == 0)] = 0.0
    out[ok & (p == 1)] = np.inf
    out[good] = 2 * sc.gammaincinv(k[good] / 2, p[good]) * 1.0 + 0.0
    return _out(out)


def chi2_median(k):
    """The median of ``chi2(k)``."""
    return chi2_ppf(0.5, k)


def f_sf(x, d1, d2):
    """``P(F(d1, d2) > x)``: 1 for ``x <= 0``, NaN for ``d1, d2 <= 0``."""
    x, d1, d2 = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (x, d1, d2)))
    ok = (d1 > 0) & (d2 > 0)
    out = np.full(x.shape, np.nan)
    good = ok & (x > 0) & (x < np.inf)
    out[ok & (x <= 0)] = 1.0
    out[ok & (x == np.inf)] = 0.0
    out[good] = sc.fdtrc(d1[good], d2[good], x[good])
    return _out(out)


def average_ranks(a) -> np.ndarray:
    """The ranks ``1..n`` of the entries of ``a`` (flattened), tied entries at the mean of their ranks (``(first +
    last) / 2``, exact in floating point), as ``scipy.stats.rankdata(a)``."""
    a = np.asarray(a, dtype=float).ravel()
    order = np.argsort(a, kind="stable")
    s = a[order]
    new = np.ones(s.size, dtype=bool)
    new[1:] = s[1:] != s[:-1]
    start = np.flatnonzero(new)  # 0-based first position of each run of equal values
    stop = np.append(start[1:], s.size)  # one past its last
    grp = np.cumsum(new) - 1
    out = np.empty(a.size)
    out[order] = 0.5 * (start[grp] + 1 + stop[grp])
    return out
