"""Gauss-Newton's stopping rules (twin.estimator.solvers.gauss_newton)."""

import numpy as np

from twin.estimator.problem import Residuals
from twin.estimator.solvers import gauss_newton


def _exponential(seed=0, n=60):
    """Residuals ``y - a exp(b t)`` ``(n,)`` of noisy data and their prediction Jacobian, and a start ``x0``."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 2.0, n)
    y = 1.7 * np.exp(-0.8 * t) + rng.normal(0.0, 0.01, n)
    calls = []

    def fun(x):
        calls.append(1)
        f = x[0] * np.exp(x[1] * t)
        J = np.column_stack([np.exp(x[1] * t), x[0] * t * np.exp(x[1] * t)])
        return Residuals((y - f) / 0.01, J / 0.01, np.arange(n), np.zeros(n, int))

    return fun, np.array([1.0, -0.3]), calls


def test_a_flat_cost_stops_at_the_same_minimum_with_fewer_evaluations():
    """With ``ftol`` the fit stops once a step changes the cost by less than that share of it: the same minimum
    (parameters within 1e-9 relative, cost within 1e-10) in fewer function evaluations than without it."""
    fun, x0, calls = _exponential()
    plain = gauss_newton(fun, x0, np.arange(2), xtol=1e-15, rtol=0.0)
    n_plain = len(calls)
    calls.clear()
    flat = gauss_newton(fun, x0, np.arange(2), xtol=1e-15, rtol=0.0, ftol=1e-10)
    assert flat.converged and plain.converged
    assert np.allclose(flat.x, plain.x, rtol=1e-9, atol=0)
    assert abs(flat.cost - plain.cost) <= 1e-10 * plain.cost
    assert len(calls) < n_plain


def test_ftol_zero_leaves_the_iterations_unchanged():
    """``ftol = 0`` (the default) is the solver without the rule: the same iterates, bit for bit."""
    fun, x0, _ = _exponential(seed=1)
    a = gauss_newton(fun, x0, np.arange(2))
    b = gauss_newton(fun, x0, np.arange(2), ftol=0.0)
    assert np.array_equal(a.x, b.x) and a.iterations == b.iterations
