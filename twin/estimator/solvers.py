"""Least-squares solvers for identification: scaled Gauss-Newton/Levenberg-Marquardt with robust row
weights (ours), and the separation paper's spectral-correction iteration for the normal equations.

All solvers are pure functions: they take a residual function ``fun(x) -> Residuals`` (whitened residuals
``r`` and the Jacobian ``J`` of the *prediction*, so that ``r(x + dx) ~ r(x) - J dx``), return a frozen
result dataclass with an iteration trace, print nothing and accept a ``callback(entry)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Literal

import numpy as np
from scipy import linalg as sla

from .distributions import chi2_median, chi2_ppf
from .problem import Residuals

__all__ = [
    "TraceEntry",
    "GNResult",
    "gauss_newton",
    "spectral_correction",
    "SpectralResult",
    "row_statistics",
    "robust_scale",
    "cauchy_weights",
    "RobustResult",
    "robust_fit",
    "covariance",
]


@dataclass(frozen=True)
class TraceEntry:
    """One iteration: ``stage`` (solver/phase name), ``iteration``, ``cost`` (sum of squared weighted
    residuals), ``step`` (largest parameter change [SI]), ``damping``."""

    stage: str
    iteration: int
    cost: float
    step: float
    damping: float = 0.0


@dataclass(frozen=True)
class GNResult:
    """Result of :func:`gauss_newton`: ``x`` ``(P,)``, final ``cost``, ``converged``, ``iterations``, the
    residuals at ``x`` and the trace."""

    x: np.ndarray
    cost: float
    converged: bool
    iterations: int
    residuals: Residuals
    trace: tuple[TraceEntry, ...]


def _row_sqrt_weights(res: Residuals, row_weights: np.ndarray | None) -> np.ndarray | None:
    if row_weights is None:
        return None
    return np.sqrt(row_weights[res.row])


def gauss_newton(
    fun: Callable[[np.ndarray], Residuals],
    x0: np.ndarray,
    free: np.ndarray,
    *,
    row_weights: np.ndarray | None = None,
    max_iter: int = 50,
    xtol: float = 1e-13,
    rtol: float = 1e-10,
    ftol: float = 0.0,
    stage: str = "gauss-newton",
    linear_solver: Literal["scaled", "spectral"] = "scaled",
    spectral_iterations: int = 100_000,
    res0: Residuals | None = None,
    callback: Callable[[TraceEntry], None] | None = None,
) -> GNResult:
    """Minimise ``sum_i w_row(i) r_i(x)^2`` over the parameters ``free`` (bool ``(P,)`` or indices).

    ``linear_solver="scaled"`` (ours): Gauss-Newton steps on the column-scaled Jacobian ``A = J D``
    (``D = diag(1/|J_k|)`` at the start), ``(A^T A + lam I) z = A^T r``, ``dx = D z``, solved by Cholesky,
    with Levenberg-Marquardt damping ``lam`` raised only when a step fails to lower the cost. The
    scaling makes the normal equations of millimetre- and milliradian-sized parameters well conditioned
    (their condition number is that of the identifiability analysis).

    ``linear_solver="spectral"`` (the separation paper's eq. 33-36): the unscaled normal equations
    ``(H^T H) dx = H^T e`` are solved by the spectral-correction iteration
    ``dx_n = (H^T H + I)^-1 (H^T e + dx_{n-1})`` (see :func:`spectral_correction`), every step accepted.

    Converged when every parameter moves by less than ``xtol`` [SI] in a step, or (scaled solver) when the
    next Gauss-Newton step would change the residual vector by less than ``rtol * |r| + 1e-15`` (far below
    the noise: the step is then not taken), or (scaled solver, ``ftol > 0``) when a step changes the cost by less
    than ``ftol * cost`` either way (the cost is at its minimum to that relative precision: the step is taken when it
    lowers the cost). ``res0``: residuals already evaluated at ``x0``.
    """
    x = np.array(x0, dtype=float)
    free = np.asarray(free)
    idx = np.flatnonzero(free) if free.dtype == bool else free.astype(int)
    if idx.size == 0:
        res = fun(x)
        sw = _row_sqrt_weights(res, row_weights)
        rr = res.r if sw is None else res.r * sw
        return GNResult(x, float(rr @ rr), True, 0, res, ())
    trace: list[TraceEntry] = []
    res = fun(x) if res0 is None else res0
    sw = _row_sqrt_weights(res, row_weights)
    r = res.r if sw is None else res.r * sw
    cost = float(r @ r)
    D = None
    lam = 0.0
    converged = False
    it = 0
    for it in range(1, max_iter + 1):
        J = res.J[:, idx]  # a copy: scaled in place below
        if sw is not None:
            J *= sw[:, None]
        if linear_solver == "spectral":
            dx_f = spectral_correction(J.T @ J, J.T @ r, max_iter=spectral_iterations).x
            x_new = x.copy()
            x_new[idx] += dx_f
            res_new = fun(x_new)
            r_new = res_new.r if sw is None else res_new.r * sw
            x, res, r = x_new, res_new, r_new
            cost = float(r @ r)
            step = float(np.max(np.abs(dx_f)))
            e = TraceEntry(stage, it, cost, step, 1.0)
            trace.append(e)
            if callback:
                callback(e)
            if step < xtol:
                converged = True
                break
            continue
        if D is None:
            nrm = np.linalg.norm(J, axis=0)
            D = 1.0 / np.where(nrm > 0, nrm, 1.0)
        J *= D
        A = J
        H = A.T @ A
        g = A.T @ r
        while True:
            Hd = H + lam * np.eye(H.shape[0]) if lam > 0 else H
            try:
                c = sla.cho_factor(Hd, check_finite=False)
                z = sla.cho_solve(c, g, check_finite=False)
            except (np.linalg.LinAlgError, ValueError):
                z, *_ = np.linalg.lstsq(A, r, rcond=None) if lam == 0 else (np.linalg.solve(Hd, g),)
            dx_f = D * z
            step = float(np.max(np.abs(dx_f)))
            if lam == 0.0 and (step < xtol or float(np.linalg.norm(A @ z)) <= rtol * np.sqrt(cost) + 1e-15):
                # the Gauss-Newton step would change the (whitened) residuals by a negligible amount: converged
                # here, without spending a function evaluation on it
                cost_new, step = cost, 0.0
                break
            x_new = x.copy()
            x_new[idx] += dx_f
            res_new = fun(x_new)
            r_new = res_new.r if sw is None else res_new.r * sw
            cost_new = float(r_new @ r_new)
            if cost_new <= cost * (1 + 1e-12) or step < xtol:
                break
            if abs(cost_new - cost) <= ftol * cost:
                break
            lam = max(lam * 10.0, 1e-6 * float(np.max(np.diag(H))))
            if lam > 1e8 * float(np.max(np.diag(H))):
                break
        if step == 0.0:
            e = TraceEntry(stage, it, cost, 0.0, lam)
            trace.append(e)
            if callback:
                callback(e)
            converged = True
            break
        accepted = cost_new <= cost * (1 + 1e-12) or step < xtol
        flat = abs(cost_new - cost) <= ftol * cost
        if accepted:
            x, res, r, cost = x_new, res_new, r_new, cost_new
            lam = lam / 10.0 if lam > 1e-12 else 0.0
        e = TraceEntry(stage, it, cost, step, lam)
        trace.append(e)
        if callback:
            callback(e)
        if step < xtol or not accepted or flat:
            converged = step < xtol or accepted or flat
            break
    return GNResult(x=x, cost=cost, converged=converged, iterations=it, residuals=res, trace=tuple(trace))


@dataclass(frozen=True)
class SpectralResult:
    """Result of :func:`spectral_correction`: solution ``x``, ``iterations``, ``converged`` and the
    trace of ``|x_n - x_{n-1}|_inf``."""

    x: np.ndarray
    iterations: int
    converged: bool
    trace: tuple[float, ...]


def spectral_correction(
    N: np.ndarray, b: np.ndarray, *, x0: np.ndarray | None = None, max_iter: int = 100_000, tol: float = 1e-12
) -> SpectralResult:
    """The separation paper's spectral-correction iteration (eq. 33-36) for ``N x = b`` (``N = H^T H``).

    Adding ``x`` to both sides of ``N x = b`` gives ``(N + I) x = b + x``, iterated as
    ``x_n = (N + I)^-1 (b + x_{n-1})`` = ``(a + a^2 + ... + a^n) b + a^n x_0`` with ``a = (N + I)^-1``
    (eq. 36). Each eigen-direction of ``N`` (eigenvalue ``l``) converges with factor ``1/(1 + l)``: fast where
    ``N`` is well determined, slowly where it is ill-conditioned, and not at all in its null space (there the
    iterate keeps its start value).

    The n-th iterate is evaluated in closed form in the eigenbasis of ``N`` (identical to iterating, without
    the loop): ``x_n = x_0 + V diag((1 - (1 + l)^-n) / l) V^T (b - N x_0)`` (``n / (1 + ...)`` limit for
    ``l = 0``: the null-space component stays at ``x_0``). ``n`` is the first power of two (then refined by
    bisection) at which ``|x_n - x_{n-1}|_inf <= tol * max(1, |x_n|_inf)``, or ``max_iter``. The trace holds
    ``|x_n - x_{n-1}|_inf`` at ``n = 1, 2, 4, ...``.
    """
    N = np.asarray(N, dtype=float)
    b = np.asarray(b, dtype=float)
    n = b.shape[0]
    x0 = np.zeros(n) if x0 is None else np.array(x0, dtype=float)
    lam, V = np.linalg.eigh(0.5 * (N + N.T))
    lam = np.clip(lam, 0.0, None)
    c = V.T @ (b - N @ x0)
    lp = np.log1p(lam)

    pos = lam > 0.0

    def gain(k: float) -> np.ndarray:  # (1 - (1+l)^-k) / l; 0 in the exact null space (b lies in range(N))
        with np.errstate(over="ignore", under="ignore"):
            return np.where(pos, -np.expm1(-k * lp) / np.where(pos, lam, 1.0), 0.0)

    def iterate(k: float) -> np.ndarray:
        return x0 + V @ (gain(k) * c)

    def diff(k: float) -> tuple[float, np.ndarray]:
        xk = iterate(k)
        # x_k - x_{k-1} = V diag((1+l)^-k) (c) in the eigenbasis ((1+l)^-(k-1) - (1+l)^-k)/l = (1+l)^-k
        with np.errstate(under="ignore"):
            d = V @ (np.exp(-k * lp) * c)
        return float(np.max(np.abs(d))), xk

    trace = []
    k = 1
    converged = False
    while True:
        d, xk = diff(k)
        trace.append(d)
        if d <= tol * max(1.0, float(np.max(np.abs(xk)))):
            converged = True
            break
        if k >= max_iter:
            break
        k = min(2 * k, max_iter)
    if converged and k > 1:
        lo, hi = k // 2, k  # refine: smallest n in (lo, hi] that meets the tolerance
        while hi - lo > 1:
            mid = (lo + hi) // 2
            d, xm = diff(mid)
            if d <= tol * max(1.0, float(np.max(np.abs(xm)))):
                hi = mid
            else:
                lo = mid
        k = hi
    return SpectralResult(x=iterate(k), iterations=int(k), converged=converged, trace=tuple(trace))


# ------------------------------------------------------------------------------------------------
# Robust fitting
# ------------------------------------------------------------------------------------------------

def row_statistics(res: Residuals, n_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """Per observation row: sum of squared whitened residuals ``t`` ``(n,)`` and their count ``dof``."""
    t = np.bincount(res.row, weights=res.r**2, minlength=n_rows)
    dof = np.bincount(res.row, minlength=n_rows)
    return t, dof


def robust_scale(t: np.ndarray, dof: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Robust noise scale from per-row statistics: median of ``t / median(chi2_dof)`` (square root).

    For rows that follow the model with the stated noise this is ~1; gross errors in a minority of rows
    do not move it.
    """
    ok = dof > 0 if mask is None else (dof > 0) & mask
    if not np.any(ok):
        return 1.0
    med = chi2_median(dof[ok])
    return float(np.sqrt(np.median(t[ok] / med)))


def cauchy_weights(t: np.ndarray, dof: np.ndarray, scale: float, c: float = 2.3849) -> np.ndarray:
    """Cauchy row weights ``1 / (1 + u^2 / c^2)`` of the standardised row residual
    ``u = sqrt(t / dof) / scale`` (``c = 2.385``: 95 % efficiency for Gaussian data)."""
    u2 = t / np.maximum(dof, 1) / max(scale, 1e-300) ** 2
    return np.where(dof > 0, 1.0 / (1.0 + u2 / c**2), 0.0)


@dataclass(frozen=True)
class RobustResult:
    """Result of :func:`robust_fit`: ``x``, per-row ``inlier`` mask, ``row_stat`` (sum of squared
    whitened residuals per row at the end), ``threshold`` per row, ``scale`` (robust residual scale),
    the final Gauss-Newton result on the inliers and the whole trace."""

    x: np.ndarray
    inlier: np.ndarray
    row_stat: np.ndarray
    row_dof: np.ndarray
    threshold: np.ndarray
    scale: float
    used_irls: bool
    final: GNResult
    trace: tuple[TraceEntry, ...]


def robust_fit(
    fun: Callable[[np.ndarray], Residuals],
    x0: np.ndarray,
    free: np.ndarray,
    n_rows: int,
    *,
    alpha: float = 1e-3,
    scale_known: bool = True,
    max_irls: int = 15,
    max_iter: int = 50,
    res0: Residuals | None = None,
    callback: Callable[[TraceEntry], None] | None = None,
) -> RobustResult:
    """Least squares that gross errors cannot spoil, with an explicit outlier rule per row.

    1. Plain scaled Gauss-Newton from ``x0``.
    2. Row statistic ``t_i = sum r^2`` (whitened), robust scale ``s`` (:func:`robust_scale`). A row is an
       outlier when ``t_i > s_eff^2 chi2_{dof_i}^{-1}(1 - alpha / n)`` (Bonferroni: with clean data the
       chance that *any* row is flagged is about ``alpha``), ``s_eff = max(1, s)`` when the noise is known
       (a too-optimistic stated noise cannot flag everything) and ``s`` otherwise.
    3. If a row is flagged: iteratively reweighted least squares with Cauchy weights (scale re-estimated
       each round) from the plain solution, until the weights settle; then the rule of step 2 again.
    4. Final plain Gauss-Newton on the inliers (unit weights), so the estimate and its covariance are
       those of ordinary weighted least squares on clean data (when no row was flagged, step 1 is it).
    """
    trace: list[TraceEntry] = []

    def cb(e):
        trace.append(e)
        if callback:
            callback(e)

    free = np.asarray(free)
    gn = gauss_newton(fun, x0, free, max_iter=max_iter, stage="gauss-newton", res0=res0, callback=cb)

    def classify(res: Residuals, base_mask: np.ndarray | None = None):
        t, dof = row_statistics(res, n_rows)
        s = robust_scale(t, dof, base_mask)
        s_eff = max(1.0, s) if scale_known else s
        n_used = int(np.sum(dof > 0))
        thr = s_eff**2 * chi2_ppf(1.0 - alpha / max(n_used, 1), np.maximum(dof, 1))
        inl = (t <= thr) & (dof > 0)
        return inl, t, dof, thr, s

    inlier, t, dof, thr, s = classify(gn.residuals)
    used_irls = False
    x = gn.x
    if not np.all(inlier[dof > 0]):
        used_irls = True
        w = np.ones(n_rows)
        for k in range(max_irls):
            res = fun(x)
            t, dof = row_statistics(res, n_rows)
            s = robust_scale(t, dof)
            w_new = cauchy_weights(t, dof, s)
            g = gauss_newton(fun, x, free, row_weights=w_new, max_iter=5, stage=f"irls-{k + 1}", callback=cb)
            x = g.x
            if np.max(np.abs(w_new - w)) < 1e-3:
                w = w_new
                break
            w = w_new
        res = fun(x)
        inlier, t, dof, thr, s = classify(res)
    wfinal = inlier.astype(float)
    if used_irls:
        final = gauss_newton(fun, x, free, row_weights=wfinal, max_iter=max_iter, stage="final", callback=cb)
    else:
        final = gn  # no row flagged: the plain fit is the final one
    t, dof = row_statistics(final.residuals, n_rows)
    s_in = robust_scale(t, dof, inlier)
    return RobustResult(
        x=final.x,
        inlier=inlier,
        row_stat=t,
        row_dof=dof,
        threshold=thr,
        scale=s_in,
        used_irls=used_irls,
        final=final,
        trace=tuple(trace),
    )


def covariance(J: np.ndarray, row_weights: np.ndarray | None = None) -> np.ndarray:
    """``(J^T W J)^-1`` for a whitened Jacobian ``(m, p)`` (full column rank), via the column-scaled
    normal equations."""
    if row_weights is not None:
        J = J * np.sqrt(row_weights)[:, None]
    nrm = np.linalg.norm(J, axis=0)
    D = 1.0 / np.where(nrm > 0, nrm, 1.0)
    A = J * D
    H = A.T @ A
    try:
        c = sla.cho_factor(H, check_finite=False)
        Hi = sla.cho_solve(c, np.eye(H.shape[0]), check_finite=False)
    except np.linalg.LinAlgError:
        Hi = np.linalg.pinv(H)
    return Hi * D[:, None] * D[None, :]
