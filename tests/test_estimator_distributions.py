"""The chi-square and F tail functions from scipy.special and the average ranks are scipy.stats' numbers, bit for bit."""

import numpy as np
from scipy import stats

from twin.estimator import distributions as D


def _same(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return a.shape == b.shape and np.array_equal(a, b, equal_nan=True)


def _draws():
    rng = np.random.default_rng(11)
    x = np.concatenate([rng.exponential(40.0, 3000), rng.exponential(2.0, 1000), [0.0, 1e-300, 1e-12, 3e4, 1e6, np.inf]])
    k = np.concatenate([rng.integers(1, 300, x.size - 6).astype(float), [1.0, 2.0, 7.0, 90.0, 3.0, 5.0]])
    return x, k


def test_chi2_tails_and_their_log_are_scipy_stats_numbers():
    """chi2 sf and logsf (arrays and scalars, both sides of the median, the support's ends) equal scipy.stats'."""
    x, k = _draws()
    assert _same(D.chi2_sf(x, k), stats.chi2.sf(x, k))
    assert _same(D.chi2_logsf(x, k), stats.chi2.logsf(x, k))
    for xi, ki in zip(x[::97], k[::97]):
        assert float(D.chi2_sf(xi, ki)) == float(stats.chi2.sf(xi, ki))
        assert float(D.chi2_logsf(xi, ki)) == float(stats.chi2.logsf(xi, ki))
    assert _same(D.chi2_logsf(np.array([1.0, 2.0]), np.array([0.0, -1.0])), stats.chi2.logsf([1.0, 2.0], [0.0, -1.0]))


def test_chi2_quantiles_and_median_are_scipy_stats_numbers():
    """chi2 isf, ppf and median (with q and p at 0 and 1) equal scipy.stats'."""
    rng = np.random.default_rng(12)
    q = np.concatenate([rng.random(2000), 10.0 ** -rng.uniform(1, 300, 500), [0.0, 1.0]])
    k = rng.integers(1, 400, q.size).astype(float)
    assert _same(D.chi2_isf(q, k), stats.chi2.isf(q, k))
    assert _same(D.chi2_ppf(q, k), stats.chi2.ppf(q, k))
    assert _same(D.chi2_median(k), stats.chi2.median(k))
    assert float(D.chi2_isf(0.01 / 7, 1)) == float(stats.chi2.isf(0.01 / 7, 1))


def test_f_tail_is_scipy_stats_number():
    """F sf (scalars, as the tests use it, and arrays) equals scipy.stats'."""
    rng = np.random.default_rng(13)
    x = np.concatenate([rng.exponential(1.5, 2000), [0.0, np.inf]])
    d1 = rng.integers(1, 3000, x.size).astype(float)
    d2 = rng.integers(1, 30000, x.size).astype(float)
    assert _same(D.f_sf(x, d1, d2), stats.f.sf(x, d1, d2))
    for a, b, c in zip(x[::50], d1[::50], d2[::50]):
        assert float(D.f_sf(a, b, c)) == float(stats.f.sf(a, b, c))


def test_average_ranks_are_scipy_stats_rankdata():
    """Average ranks (distinct values, ties of two and more, one entry) equal scipy.stats.rankdata's."""
    rng = np.random.default_rng(14)
    for a in (rng.exponential(1.0, 500), rng.integers(0, 20, 400).astype(float), np.round(rng.random(300), 2),
              np.array([3.0]), np.array([2.0, 2.0, 2.0])):
        assert _same(D.average_ranks(a), stats.rankdata(a))
        assert float(D.average_ranks(a)[a > np.median(a)].sum()) == float(stats.rankdata(a)[a > np.median(a)].sum())
