"""Spectral correction measured: the separation paper's linear solver (eq. 33-36) beside plain and
column-scaled least squares and Levenberg-Marquardt, on the paper's separation steps.

The identification problem is the separation method as ``twin.estimator.paper_methods.identify_separation``
implements it, rebuilt here so that the linear solver of each Gauss-Newton step can be swapped:

* step 1: the angle parameters of eq. 21 from the orientation changes of motion pairs (``rotation_change``:
  the rotation of the motion seen in the plate frame);
* step 2: the length parameters of eq. 22 and the theta2/theta3 split from the distances the three spheres
  move (eq. 28-30), the step-1 angles and ``theta2 + theta3`` held.

Residuals are the paper's: unweighted, SI units (metres, radians), both steps (``weighting="paper"``; note
that ``identify_separation`` itself whitens its step-1 orientation residuals by a sigma derived from the
sphere noise, here they are plain radians as in the paper). The plate is pinned to the flange (nominal tool)
and d2 is held at nominal (the paper's parameter set).

Linear solvers of one Gauss-Newton step ``H dx = e`` (``H`` the Jacobian, ``e`` the residual):

* ``normal``: the plain normal equations ``(H^T H) dx = H^T e`` (eq. 32), ``numpy.linalg.solve``, no scaling;
* ``lstsq``: ``numpy.linalg.lstsq(H, e)`` (SVD, minimum-norm), no scaling: the reference solution;
* ``scaled``: the project's column scaling, ``A = H D`` with ``D = diag(1 / |H_k|)``, Cholesky of ``A^T A``
  (falling back to ``lstsq(A, e)`` when Cholesky fails, as ``twin.estimator.solvers.gauss_newton`` does);
* ``spectral``: the paper's spectral-correction iteration (:func:`twin.estimator.solvers.spectral_correction`)
  with the project's cap of 100 000 iterations per step (``spectral_iterations``);
* ``spectral_unbounded``: the same with a cap of 1e15 (the closed form makes any count free; a literal
  implementation iterating eq. 35 could not afford it): what the iteration converges to;
* ``lm``: the project's Levenberg-Marquardt (:func:`twin.estimator.lm.levenberg_marquardt`, the TM-MDH
  paper's damping on the unscaled normal equations) on the whole nonlinear fit of each step.

The first four run inside one undamped Gauss-Newton loop (every step taken, as the paper's iteration and the
project's ``gauss_newton(linear_solver="spectral")`` do). Scenarios: ``wide`` (motion-pair ends drawn over the
joint ranges), ``narrow`` (all configurations within a small box around one posture: an ill-conditioned
design), ``with_d2`` (the wide design with d2 estimated as eq. 22 lists it: d2 and d3 act along axes that are
parallel in the nominal model and only the small beta2 tells them apart, so ``H`` is full rank but ill-conditioned)
and ``paper_list`` (the paper's parameter lists as written, eq. 21 and 22 with d2: columns without any effect
stay in as well, so ``H^T H`` is singular).

Simulation (evaluation side, like the campaign's ``truth_noise`` mode): the true model is the nominal IRB-1200
plus the separation paper's Tables 2 and 4 deviations; the measured sphere centres are the true ones plus
N(0, sigma^2) per coordinate. Only the evaluation functions here compare estimates with the truth.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from scipy import linalg as sla

from twin.estimator.core import Prepared, prepare
from twin.estimator.identifiability import Identifiability, analyse_jacobian, preference_order
from twin.estimator.lm import LMSettings, levenberg_marquardt
from twin.estimator.paper_methods import EQ21_ANGLES, EQ22_LENGTHS
from twin.estimator.problem import Observations, ParamSpace, Residuals, make_pairs, pair_residuals
from twin.estimator.simulate import random_configurations, simulate_dataset
from twin.estimator.solvers import spectral_correction
from twin.presets import preset_deviation
from twin.robots import get_robot
from twin.transforms import pose6_to_transform
from twin.units import M_PER_MM, MM_PER_M, UM_PER_M, RAD_PER_DEG

__all__ = [
    "LINEAR_METHODS",
    "METHODS",
    "SCENARIOS",
    "UNITS",
    "UNBOUNDED_ITERATIONS",
    "NARROW_POSTURE_DEG",
    "conditioning",
    "StepSolution",
    "solve_step",
    "FitResult",
    "gauss_newton_fit",
    "lm_fit",
    "SeparationProblem",
    "simulate_problem",
    "RunRecord",
    "run_method",
    "run_case",
    "study",
    "summarise",
    "markdown_table",
    "plot_study",
]

LINEAR_METHODS = ("normal", "lstsq", "scaled", "spectral", "spectral_unbounded")
METHODS = LINEAR_METHODS + ("lm",)
UNBOUNDED_ITERATIONS = 10**15
SCENARIOS = ("wide", "narrow", "with_d2", "paper_list")
UNITS = ("si", "mm")
NARROW_POSTURE_DEG = (0.0, 10.0, 10.0, 0.0, 40.0, 0.0)  # centre of the narrow design


# ------------------------------------------------------------------------------------------------
# One linear step
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class StepSolution:
    """One linear solve: the step ``dx`` ``(p,)`` [SI], inner iterations (spectral correction; 1 otherwise) and
    whether they met their tolerance (``inner_converged``), ``ok`` (False when the solver failed: singular
    matrix or non-finite step; an inner iteration stopped by its cap is not a failure of the step)."""

    dx: np.ndarray
    inner_iterations: int
    inner_converged: bool
    ok: bool
    message: str = ""


def solve_step(method: str, H: np.ndarray, e: np.ndarray, *, spectral_iterations: int = 100_000) -> StepSolution:
    """Solve the Gauss-Newton step ``H dx ~ e`` (``H`` ``(m, p)``, ``e`` ``(m,)``) with ``method`` (one of
    :data:`LINEAR_METHODS`)."""
    H = np.asarray(H, dtype=float)
    e = np.asarray(e, dtype=float)
    if H.ndim != 2 or e.shape != (H.shape[0],):
        raise ValueError(f"H must be (m, p) and e (m,), got {H.shape} and {e.shape}")
    n_it, inner_ok = 1, True
    try:
        if method == "normal":
            dx = np.linalg.solve(H.T @ H, H.T @ e)
        elif method == "lstsq":
            dx = np.linalg.lstsq(H, e, rcond=None)[0]
        elif method == "scaled":
            nrm = np.linalg.norm(H, axis=0)
            D = 1.0 / np.where(nrm > 0, nrm, 1.0)
            A = H * D
            try:
                c = sla.cho_factor(A.T @ A, check_finite=False)
                dx = D * sla.cho_solve(c, A.T @ e, check_finite=False)
            except (np.linalg.LinAlgError, sla.LinAlgError):  # as gauss_newton does: least squares on A
                dx = D * np.linalg.lstsq(A, e, rcond=None)[0]
        elif method in ("spectral", "spectral_unbounded"):
            cap = spectral_iterations if method == "spectral" else UNBOUNDED_ITERATIONS
            s = spectral_correction(H.T @ H, H.T @ e, max_iter=cap)
            dx, n_it, inner_ok = s.x, s.iterations, s.converged
        else:
            raise ValueError(f"method must be one of {LINEAR_METHODS}, got {method!r}")
    except (np.linalg.LinAlgError, sla.LinAlgError) as exc:
        return StepSolution(np.full(H.shape[1], np.nan), n_it, False, False, f"{type(exc).__name__}: {exc}")
    if not np.all(np.isfinite(dx)):
        return StepSolution(dx, n_it, inner_ok, False, "non-finite step")
    return StepSolution(dx, int(n_it), bool(inner_ok), True)


# ------------------------------------------------------------------------------------------------
# Nonlinear fits
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class FitResult:
    """A nonlinear fit of one step: ``x`` ``(P,)``, outer ``iterations``, total and largest per-step inner
    (spectral) iterations, ``converged``, ``ok`` (no solver failure), final ``cost`` (sum of squared
    residuals), residual RMS, and the conditioning at the start point: ``cond_raw`` = cond(H),
    ``cond_scaled`` = cond(H D), ``cond_shifted`` = cond(H^T H + I) (the matrix eq. 35 inverts)."""

    x: np.ndarray
    iterations: int
    inner_iterations: int
    inner_max: int
    inner_converged: bool
    converged: bool
    ok: bool
    cost: float
    residual_rms: float
    cond_raw: float
    cond_scaled: float
    cond_shifted: float
    message: str = ""


def conditioning(H: np.ndarray) -> tuple[float, float, float]:
    """``(cond(H), cond(H D), cond(H^T H + I))`` of a Jacobian ``(m, p)`` (``D`` the column scaling); ``inf``
    when the smallest singular value is below ``1e-15`` of the largest (numerically singular)."""
    s = np.linalg.svd(H, compute_uv=False)
    nrm = np.linalg.norm(H, axis=0)
    sd = np.linalg.svd(H / np.where(nrm > 0, nrm, 1.0), compute_uv=False)
    c = lambda v: float(v[0] / v[-1]) if v[-1] > 1e-15 * v[0] else float("inf")
    return c(s), c(sd), float((s[0] ** 2 + 1.0) / (s[-1] ** 2 + 1.0))


def gauss_newton_fit(
    fun: Callable[[np.ndarray], Residuals],
    x0: np.ndarray,
    idx: np.ndarray,
    method: str,
    *,
    max_iter: int = 50,
    xtol: float = 1e-11,
    rtol: float = 1e-12,
    spectral_iterations: int = 100_000,
) -> FitResult:
    """Undamped Gauss-Newton over the parameters ``idx`` with the linear solver ``method``; every step taken.
    Converged when the largest step is below ``xtol`` [SI], when the cost changes by less than ``rtol`` of itself,
    or when the step changes the linearised residual by less than ``rtol`` of the start residual's norm (round-off
    level: a noise-free fit of an ill-conditioned problem ends there)."""
    x = np.array(x0, dtype=float)
    idx = np.asarray(idx, dtype=int)
    res = fun(x)
    cost = float(res.r @ res.r)
    r0 = float(np.sqrt(cost))
    conds = conditioning(res.J[:, idx])
    inner_tot = inner_max = 0
    inner_ok = True
    converged, ok, msg, it = False, True, "", 0
    for it in range(1, max_iter + 1):
        st = solve_step(method, res.J[:, idx], res.r, spectral_iterations=spectral_iterations)
        inner_tot += st.inner_iterations
        inner_max = max(inner_max, st.inner_iterations)
        inner_ok &= st.inner_converged
        if not st.ok:
            ok, msg = False, st.message
            break
        lin = float(np.linalg.norm(res.J[:, idx] @ st.dx))
        x = x.copy()
        x[idx] += st.dx
        res = fun(x)
        cost_new = float(res.r @ res.r)
        if not np.isfinite(cost_new):
            ok, msg = False, "non-finite cost"
            break
        small = (float(np.max(np.abs(st.dx))) < xtol or abs(cost - cost_new) <= rtol * max(cost, 1e-300)
                 or lin <= rtol * r0)
        cost = cost_new
        if small:
            converged = True
            break
    rms = float(np.sqrt(cost / max(res.r.size, 1)))
    return FitResult(x, it, inner_tot, inner_max, inner_ok, converged and ok, ok, cost, rms, *conds, msg)


class _Batch:
    """A residual function as the batch problem :func:`twin.estimator.lm.levenberg_marquardt` takes."""

    def __init__(self, fun: Callable[[np.ndarray], Residuals], size: int) -> None:
        self.fun = fun
        self.size = size

    def __call__(self, X, part="full", jacobian=True):
        rs, Js = [], []
        for x in np.atleast_2d(X):
            res = self.fun(x)
            rs.append(res.r)
            Js.append(res.J.T)
        return np.stack(rs), np.stack(Js)


def lm_fit(fun: Callable[[np.ndarray], Residuals], x0: np.ndarray, idx: np.ndarray, *, max_iter: int = 50,
           xtol: float = 1e-11) -> FitResult:
    """The project's Levenberg-Marquardt (defaults of :class:`twin.estimator.lm.LMSettings`: ``mu0 = 1e-3``,
    factor 10, every step taken) over ``idx``; converged when its largest step falls below ``xtol`` [SI]."""
    x0 = np.array(x0, dtype=float)
    free = np.zeros(x0.size, dtype=bool)
    free[np.asarray(idx, dtype=int)] = True
    res0 = fun(x0)
    conds = conditioning(res0.J[:, free])
    r = levenberg_marquardt(_Batch(fun, x0.size), x0[None], free, settings=LMSettings(max_iter=max_iter, tol_step=xtol))
    x = r.X[0]
    res = fun(x)
    cost = float(res.r @ res.r)
    ok = bool(np.all(np.isfinite(x)) and np.isfinite(cost))
    return FitResult(x, int(r.iterations[0]), 0, 0, True, bool(r.stopped_early[0]) and ok, ok, cost,
                     float(np.sqrt(cost / max(res.r.size, 1))), *conds, "" if ok else "non-finite")


# ------------------------------------------------------------------------------------------------
# The problem (simulation: evaluation side)
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class SeparationProblem:
    """One simulated separation problem. Estimator side: ``prep``, the observations and pairs, the free index
    sets of the two steps. Evaluation side only: ``x_true`` and the noise-free validation observations."""

    scenario: str
    seed: int
    noise_position: float  # [m]
    prep: Prepared
    obs: Observations  # unweighted SI sphere observations
    obs_rot: Observations  # plate poses, unweighted SI
    pairs: np.ndarray
    pairs_rot: np.ndarray
    idx1: np.ndarray  # step-1 free parameters
    idx2: np.ndarray  # step-2 free parameters (theta2 stands for the split)
    ida1: Identifiability
    ida2: Identifiability
    evaluated: tuple[str, ...]  # parameters whose error is reported (identifiable, in no combination)
    x_true: np.ndarray = field(repr=False)
    val_obs: Observations = field(repr=False)
    val_obs_rot: Observations = field(repr=False)
    val_pairs: np.ndarray = field(repr=False)
    val_pairs_rot: np.ndarray = field(repr=False)

    @property
    def space(self) -> ParamSpace:
        return self.prep.space


def _configs(nom, n: int, rng: np.random.Generator, scenario: str, span: float) -> np.ndarray:
    if scenario == "narrow":
        centre = np.array(NARROW_POSTURE_DEG) * RAD_PER_DEG
        return centre + rng.uniform(-span, span, (n, 6))
    return random_configurations(nom, n, rng)


def _step2_fun(space: ParamSpace, obs: Observations, pairs: np.ndarray, s23: float):
    i2, i3 = space.index("theta2"), space.index("theta3")

    def fun2(y):
        y = y.copy()
        y[i3] = s23 - y[i2]  # theta2 + theta3 stays at the step-1 sum
        res = pair_residuals(space, y, obs, pairs, "distance")
        J = res.J.copy()
        J[:, i2] = J[:, i2] - J[:, i3]
        J[:, i3] = 0.0
        return Residuals(r=res.r, J=J, row=res.row, block=res.block)

    return fun2


def simulate_problem(
    seed: int,
    noise_position: float,
    *,
    scenario: str = "wide",
    n_pairs: int = 25,
    narrow_span_deg: float = 5.0,
    preset: str = "separation_tables_2_4",
    n_validation_pairs: int = 50,
) -> SeparationProblem:
    """Simulate one problem: ``n_pairs`` motion pairs of the IRB-1200 carrying ``preset``'s deviations, sphere
    centres plus N(0, ``noise_position``^2) [m] per coordinate, in the frame of a camera-like station.
    ``scenario`` in :data:`SCENARIOS` (``narrow``: every joint within +-``narrow_span_deg`` of
    :data:`NARROW_POSTURE_DEG`)."""
    if scenario not in SCENARIOS:
        raise ValueError(f"scenario must be one of {SCENARIOS}, got {scenario!r}")
    if noise_position < 0:
        raise ValueError(f"noise_position must be >= 0, got {noise_position!r}")
    if n_pairs < 12:
        raise ValueError(f"n_pairs must be >= 12 (step 2 has 10+ unknowns), got {n_pairs!r}")
    nom = get_robot("irb1200")
    dev = preset_deviation(preset)
    truth = nom.perturbed(np.array([dev.get(k, 0.0) for k in nom.layout.names]))
    rng = np.random.default_rng(seed)
    base2meas = pose6_to_transform([0.5, 0.0, 1.1, 0.2, -1.3, 0.1])
    n = 2 * n_pairs
    q = _configs(nom, n, rng, scenario, narrow_span_deg * RAD_PER_DEG)
    ds, _ = simulate_dataset(truth, q, robot_spec="irb1200", base2meas={"0": base2meas}, rng=rng,
                             noise_position=noise_position, pair=np.repeat(np.arange(n_pairs), 2),
                             set_=np.array(["calibration"] * n, dtype=object))
    # estimator side: the data and the nominal model only
    prep = prepare(ds, noise_position=max(noise_position, 1e-6))
    space = prep.space
    obs = prep.obs_cal.with_sigma(1.0, 1.0)
    obs_rot = obs.as_poses().with_sigma(1.0, 1.0)
    pairs, _ = make_pairs(obs)
    pairs_rot, _ = make_pairs(obs_rot)
    x0 = prep.x_nominal
    names1 = list(EQ21_ANGLES)
    r1 = pair_residuals(space, x0, obs_rot, pairs_rot, "rotation_change")
    ida1 = analyse_jacobian(r1.J, space.names, candidates=names1, order=preference_order(names1, "frames"))
    held = () if scenario in ("paper_list", "with_d2") else ("d2",)
    names2 = [m for m in EQ22_LENGTHS if m != "theta3" and m not in held]
    r2 = _step2_fun(space, obs, pairs, x0[space.index("theta2")] + x0[space.index("theta3")])(x0)
    ida2 = analyse_jacobian(r2.J, space.names, candidates=names2, order=preference_order(names2))
    drop1 = () if scenario == "paper_list" else ida1.dropped
    drop2 = {"paper_list": (), "with_d2": tuple(m for m in ida2.dropped if m not in ("d2", "d3"))}.get(scenario, ida2.dropped)
    idx1 = np.array([space.index(m) for m in names1 if m not in drop1])
    idx2 = np.array([space.index(m) for m in names2 if m not in drop2])
    # errors on every estimated parameter (theta3 from the split) except those without any effect on the data
    no_effect = {m for c in ida1.combinations + ida2.combinations if c.kind == "no_effect" for m in c.names}
    est = {space.names[i] for i in np.r_[idx1, idx2]} | {"theta3"}
    evaluated = tuple(m for m in space.names if m in est and m not in no_effect)
    # evaluation side: truth and noise-free validation pairs
    x_true = space.from_model(truth, {"0": base2meas})
    qv = random_configurations(nom, 2 * n_validation_pairs, np.random.default_rng(10_000 + seed))
    dsv, _ = simulate_dataset(truth, qv, robot_spec="irb1200", base2meas={"0": base2meas},
                              pair=np.repeat(np.arange(n_validation_pairs), 2))
    pv = prepare(dsv, noise_position=1e-6, validation_fraction=0.0)
    val_obs = pv.obs.with_sigma(1.0, 1.0)
    val_obs_rot = val_obs.as_poses().with_sigma(1.0, 1.0)
    return SeparationProblem(
        scenario=scenario, seed=int(seed), noise_position=float(noise_position), prep=prep, obs=obs, obs_rot=obs_rot,
        pairs=pairs, pairs_rot=pairs_rot, idx1=idx1, idx2=idx2, ida1=ida1, ida2=ida2, evaluated=evaluated,
        x_true=x_true, val_obs=val_obs, val_obs_rot=val_obs_rot, val_pairs=make_pairs(val_obs)[0],
        val_pairs_rot=make_pairs(val_obs_rot)[0],
    )


# ------------------------------------------------------------------------------------------------
# Runs and their evaluation
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class RunRecord:
    """One method on one problem. Counts and conditioning are per step (1: angles, 2: lengths); errors are
    RMS over the evaluated parameters ([m] lengths, [rad] angles); prediction errors are RMS on the noise-free
    validation pairs (distance [m], rotation change [rad]); ``failed`` per :func:`run_case`'s rule."""

    scenario: str
    noise_position: float
    seed: int
    method: str
    iterations: tuple[int, int]
    inner_iterations: tuple[int, int]
    inner_max: tuple[int, int]
    inner_converged: bool
    converged: bool
    ok: bool
    cond_raw: tuple[float, float]
    cond_scaled: tuple[float, float]
    cond_shifted: tuple[float, float]
    residual_rms: tuple[float, float]
    length_error: float
    angle_error: float
    distance_prediction_error: float
    rotation_prediction_error: float
    failed: bool = False
    failure: str = ""
    units: str = "si"
    x: np.ndarray | None = field(default=None, repr=False, compare=False)  # the estimate (P,) [SI]

    def as_dict(self) -> dict:
        """The record without the estimate, tuples as lists (for JSON)."""
        d = {k: getattr(self, k) for k in self.__dataclass_fields__ if k != "x"}
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in d.items()}


SolverFn = Callable[[Callable[[np.ndarray], Residuals], np.ndarray, np.ndarray], FitResult]


def _fitter(method: str, max_iter: int, spectral_iterations: int) -> SolverFn:
    if method == "lm":
        return lambda f, x0, idx: lm_fit(f, x0, idx, max_iter=max_iter)
    if method in LINEAR_METHODS:
        return lambda f, x0, idx: gauss_newton_fit(f, x0, idx, method, max_iter=max_iter,
                                                   spectral_iterations=spectral_iterations)
    raise ValueError(f"method must be one of {METHODS}, got {method!r}")


def _rms(v: np.ndarray) -> float:
    v = np.asarray(v, dtype=float)
    return float(np.sqrt(np.mean(v**2))) if v.size else float("nan")


def _fit_in_units(fit: SolverFn, fun, x0: np.ndarray, idx: np.ndarray, col: np.ndarray, row: float) -> FitResult:
    """``fit`` run on the problem in other units: parameters ``u = x / col``, residuals ``row * r``; the result
    (``x``, residual RMS) converted back to SI, its iteration counts and condition numbers those of the units."""
    from dataclasses import replace

    if row == 1.0 and np.all(col == 1.0):
        return fit(fun, x0, idx)

    def fun_u(u):
        res = fun(col * u)
        return Residuals(r=row * res.r, J=row * res.J * col, row=res.row, block=res.block)

    f = fit(fun_u, x0 / col, idx)
    return replace(f, x=col * f.x, residual_rms=f.residual_rms / row, cost=f.cost / row**2)


def run_method(problem: SeparationProblem, method: str | SolverFn, *, max_iter: int = 50,
               spectral_iterations: int = 100_000, name: str | None = None, units: str = "si") -> RunRecord:
    """Both separation steps with one solver (a name of :data:`METHODS`, or a fit function
    ``(fun, x0, idx) -> FitResult``), then the evaluation against the truth (``failed`` left False).

    ``units``: the units the solver sees, ``"si"`` (residuals and parameters in m and rad, the project's) or
    ``"mm"`` (lengths in mm, angles in rad; step 2's distance residuals in mm). Column-scaled least squares
    and SVD least squares are unaffected; the plain normal equations, LM's ``mu I`` and spectral correction's
    ``+ I`` are not invariant to the choice."""
    if units not in UNITS:
        raise ValueError(f"units must be one of {UNITS}, got {units!r}")
    fit = method if callable(method) else _fitter(method, max_iter, spectral_iterations)
    label = name or (method if isinstance(method, str) else getattr(method, "__name__", "custom"))
    p, space = problem, problem.space
    col = np.where(space.is_length, M_PER_MM, 1.0) if units == "mm" else np.ones(space.size)
    row2 = MM_PER_M if units == "mm" else 1.0
    x0 = p.prep.x_nominal.copy()
    f1 = _fit_in_units(fit, lambda y: pair_residuals(space, y, p.obs_rot, p.pairs_rot, "rotation_change"), x0,
                       p.idx1, col, 1.0)
    i2, i3 = space.index("theta2"), space.index("theta3")
    x1 = f1.x
    s23 = x1[i2] + x1[i3]
    f2 = _fit_in_units(fit, _step2_fun(space, p.obs, p.pairs, s23), x1, p.idx2, col, row2)
    x = f2.x.copy()
    x[i3] = s23 - x[i2]
    ev = np.array([space.index(m) for m in p.evaluated])
    err = x[ev] - p.x_true[ev]
    is_len = space.is_length[ev]
    if np.all(np.isfinite(x)):
        rd = pair_residuals(space, x, p.val_obs, p.val_pairs, "distance", jacobian=False).r
        rr = pair_residuals(space, x, p.val_obs_rot, p.val_pairs_rot, "rotation_change", jacobian=False).r
        dpe = _rms(rd / np.sqrt(2.0))  # the residuals are divided by sqrt(2) sigma with sigma = 1
        rpe = _rms(np.linalg.norm(rr.reshape(3, -1), axis=0) / np.sqrt(2.0))
    else:
        dpe = rpe = float("nan")
    return RunRecord(
        scenario=p.scenario, noise_position=p.noise_position, seed=p.seed, method=label,
        iterations=(f1.iterations, f2.iterations), inner_iterations=(f1.inner_iterations, f2.inner_iterations),
        inner_max=(f1.inner_max, f2.inner_max), inner_converged=f1.inner_converged and f2.inner_converged,
        converged=f1.converged and f2.converged, ok=f1.ok and f2.ok,
        cond_raw=(f1.cond_raw, f2.cond_raw), cond_scaled=(f1.cond_scaled, f2.cond_scaled),
        cond_shifted=(f1.cond_shifted, f2.cond_shifted),
        residual_rms=(f1.residual_rms * np.sqrt(2.0), f2.residual_rms * np.sqrt(2.0)),
        length_error=_rms(err[is_len]), angle_error=_rms(err[~is_len]),
        distance_prediction_error=dpe, rotation_prediction_error=rpe,
        failure="; ".join(m for m in (f1.message, f2.message) if m), x=x, units=units,
    )


def _judge(rec: RunRecord, ref: RunRecord | None, factor: float, floor_length: float, floor_angle: float) -> RunRecord:
    from dataclasses import replace

    why = []
    if not rec.ok:
        why.append("solver error")
    elif not rec.converged:
        why.append("not converged")
    errs = (rec.length_error, rec.angle_error, rec.distance_prediction_error, rec.rotation_prediction_error)
    if not all(np.isfinite(errs)):
        why.append("non-finite estimate")
    elif ref is not None and ref is not rec:
        refs = (ref.length_error, ref.angle_error, ref.distance_prediction_error, ref.rotation_prediction_error)
        floors = (floor_length, floor_angle, floor_length, floor_angle)
        if any(e > factor * r + f for e, r, f in zip(errs, refs, floors)):
            why.append("error above threshold")
    return replace(rec, failed=bool(why), failure="; ".join(why))


def run_case(problem: SeparationProblem, methods: Sequence[str | tuple[str, SolverFn]] = METHODS, *,
             max_iter: int = 50, spectral_iterations: int = 100_000, fail_factor: float = 2.0,
             fail_floor_length: float = 1e-7, fail_floor_angle: float = 1e-7, units: str = "si") -> list[RunRecord]:
    """Every method on one problem, judged. A run fails on a solver error (singular matrix, non-finite step),
    when it does not converge in ``max_iter`` outer iterations (either step), or when one of its errors (length
    and angle parameter errors, distance and rotation prediction errors) exceeds ``fail_factor`` times that of
    the reference solver ``lstsq`` on the same data plus ``fail_floor_length`` [m] / ``fail_floor_angle`` [rad]
    (the reference itself fails only by the first two rules). ``methods``: names, or ``(name, fit function)``
    pairs. ``units``: see :func:`run_method`."""
    recs = {}
    for m in methods:
        name, fn = (m, m) if isinstance(m, str) else m
        recs[name] = run_method(problem, fn, max_iter=max_iter, spectral_iterations=spectral_iterations, name=name,
                                units=units)
    ref = recs.get("lstsq") or run_method(problem, "lstsq", max_iter=max_iter, units=units)
    return [_judge(r, ref, fail_factor, fail_floor_length, fail_floor_angle) for r in recs.values()]


def study(
    noise_levels: Sequence[float] = (0.0, 5e-6, 1e-5, 2e-5, 5e-5),
    seeds: Sequence[int] = tuple(range(20)),
    scenarios: Sequence[str] = SCENARIOS,
    methods: Sequence[str] = METHODS,
    *,
    n_pairs: int = 25,
    narrow_span_deg: float = 5.0,
    max_iter: int = 50,
    spectral_iterations: int = 100_000,
    units: str = "si",
    progress: Callable[[str], None] | None = None,
) -> list[RunRecord]:
    """Every scenario x noise level [m] x seed x method: the judged run records (``units``: see
    :func:`run_method`)."""
    out: list[RunRecord] = []
    for sc in scenarios:
        for noise in noise_levels:
            for s in seeds:
                prob = simulate_problem(s, noise, scenario=sc, n_pairs=n_pairs, narrow_span_deg=narrow_span_deg)
                out += run_case(prob, methods, max_iter=max_iter, spectral_iterations=spectral_iterations, units=units)
            if progress:
                progress(f"{sc} noise {noise * MM_PER_M:g} mm: {len(seeds)} seeds")
    return out


# ------------------------------------------------------------------------------------------------
# Summary, table, figure
# ------------------------------------------------------------------------------------------------

def _pct(v, q):
    """Percentile ignoring NaN; infinite values (singular matrices) count as larger than any other."""
    v = np.asarray(v, dtype=float)
    v = v[~np.isnan(v)]
    if not v.size:
        return float("nan")
    p = float(np.percentile(np.where(np.isinf(v), 1e308, v), q))
    return float("inf") if p > 1e307 else p


def summarise(records: Sequence[RunRecord]) -> list[dict]:
    """One row per (scenario, noise, method): medians of the iteration counts and condition numbers (step 1 /
    step 2), median and 95th percentile of the parameter and prediction errors, failure rate and reasons."""
    keys = list(dict.fromkeys((r.units, r.scenario, r.noise_position, r.method) for r in records))
    rows = []
    for units, sc, noise, m in keys:
        rs = [r for r in records if (r.units, r.scenario, r.noise_position, r.method) == (units, sc, noise, m)]
        col = lambda f: [f(r) for r in rs]
        reasons: dict[str, int] = {}
        for r in rs:
            if r.failed:
                reasons[r.failure] = reasons.get(r.failure, 0) + 1
        row = {"units": units, "scenario": sc, "noise_mm": noise * MM_PER_M, "method": m, "runs": len(rs)}
        for s in (0, 1):
            row[f"iterations_step{s + 1}"] = _pct(col(lambda r: r.iterations[s]), 50)
            row[f"inner_iterations_step{s + 1}"] = _pct(col(lambda r: r.inner_iterations[s]), 50)
            row[f"inner_max_step{s + 1}"] = float(np.max(col(lambda r: r.inner_max[s])))
            row[f"cond_raw_step{s + 1}"] = _pct(col(lambda r: r.cond_raw[s]), 50)
            row[f"cond_scaled_step{s + 1}"] = _pct(col(lambda r: r.cond_scaled[s]), 50)
            row[f"cond_shifted_step{s + 1}"] = _pct(col(lambda r: r.cond_shifted[s]), 50)
        row["inner_converged_rate"] = float(np.mean(col(lambda r: r.inner_converged)))
        for name, f, unit in (("length_error_um", lambda r: r.length_error, UM_PER_M),
                              ("angle_error_urad", lambda r: r.angle_error, 1e6),
                              ("distance_prediction_um", lambda r: r.distance_prediction_error, UM_PER_M),
                              ("rotation_prediction_urad", lambda r: r.rotation_prediction_error, 1e6)):
            v = np.array(col(f)) * unit
            row[f"{name}_median"] = _pct(v, 50)
            row[f"{name}_p95"] = _pct(v, 95)
        row["residual_rms_step2_um_median"] = _pct(np.array(col(lambda r: r.residual_rms[1])) * UM_PER_M, 50)
        row["failure_rate"] = float(np.mean(col(lambda r: r.failed)))
        for key, what in (("solver_error_rate", "solver error"), ("not_converged_rate", "not converged"),
                          ("error_above_threshold_rate", "error above threshold")):
            row[key] = float(np.mean(col(lambda r: what in r.failure)))
        row["failure_reasons"] = reasons
        rows.append(row)
    return rows


def _g(v: float, digits: int = 3) -> str:
    if v is None or not np.isfinite(v):
        return "-" if v is None or np.isnan(v) else "inf"
    return f"{v:.{digits}g}"


def markdown_table(rows: Sequence[dict]) -> str:
    """The summary rows as Markdown, one table per (units, scenario)."""
    out = []
    for units, sc in dict.fromkeys((r.get("units", "si"), r["scenario"]) for r in rows):
        what = "m and rad (SI)" if units == "si" else "mm and rad"
        out += [f"### Scenario `{sc}`, solver units {what}", "",
                "| noise [mm] | method | GN its (1/2) | spectral its (1/2) | cond H raw (1/2) | cond H scaled (1/2) "
                "| cond H^T H + I (1/2) | length err med / p95 [um] | angle err med / p95 [urad] "
                "| distance pred. med / p95 [um] | failure rate (solver error / not conv. / error) |",
                "|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in rows:
            if (r.get("units", "si"), r["scenario"]) != (units, sc):
                continue
            sp = (f"{_g(r['inner_iterations_step1'])} / {_g(r['inner_iterations_step2'])}"
                  if r["method"].startswith("spectral") else "-")
            pc = lambda v: f"{v * 100:.0f}"
            fr = (f"{pc(r['failure_rate'])} % ({pc(r['solver_error_rate'])} / {pc(r['not_converged_rate'])} / "
                  f"{pc(r['error_above_threshold_rate'])})")
            out.append(
                f"| {r['noise_mm']:g} | {r['method']} | {_g(r['iterations_step1'])} / {_g(r['iterations_step2'])} | {sp} "
                f"| {_g(r['cond_raw_step1'])} / {_g(r['cond_raw_step2'])} | {_g(r['cond_scaled_step1'])} / "
                f"{_g(r['cond_scaled_step2'])} | {_g(r['cond_shifted_step1'])} / {_g(r['cond_shifted_step2'])} "
                f"| {_g(r['length_error_um_median'])} / {_g(r['length_error_um_p95'])} "
                f"| {_g(r['angle_error_urad_median'])} / {_g(r['angle_error_urad_p95'])} "
                f"| {_g(r['distance_prediction_um_median'])} / {_g(r['distance_prediction_um_p95'])} | {fr} |")
        out.append("")
    return "\n".join(out)


def plot_study(rows: Sequence[dict], path, *, units: str = "si") -> None:
    """Figure of the summary rows in ``units``: one column per scenario; rows: median distance prediction error
    [um] and median length parameter error [um] (bars up to the 95th percentile), failure rate [%], and
    iterations of both steps (GN outer iterations; spectral: inner iterations), against the noise sigma, one
    line per method."""
    from twin.evaluation.report import pyplot, save_figure

    plt = pyplot()
    from matplotlib.ticker import NullFormatter

    rows = [r for r in rows if r.get("units", "si") == units]
    scs = list(dict.fromkeys(r["scenario"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    fig, axes = plt.subplots(4, len(scs), figsize=(4.3 * len(scs), 13), squeeze=False)
    for j, sc in enumerate(scs):
        for k, m in enumerate(methods):
            rs = sorted((r for r in rows if r["scenario"] == sc and r["method"] == m), key=lambda r: r["noise_mm"])
            if not rs:
                continue
            jit = 1 + 0.04 * (k - (len(methods) - 1) / 2)
            x = np.array([r["noise_mm"] for r in rs])
            xp = np.where(x > 0, x, 0.002) * jit
            for i, key in ((0, "distance_prediction_um"), (1, "length_error_um")):
                med = np.array([r[f"{key}_median"] for r in rs])
                p95 = np.array([r[f"{key}_p95"] for r in rs])
                axes[i, j].errorbar(xp, med, yerr=[np.zeros_like(med), np.maximum(p95 - med, 0)], marker="o", ms=3,
                                    label=m, capsize=2)
            axes[2, j].plot(xp, [r["failure_rate"] * 100 for r in rs], marker="o", ms=3, label=m)
            its = [r["inner_iterations_step1"] + r["inner_iterations_step2"] if m.startswith("spectral")
                   else r["iterations_step1"] + r["iterations_step2"] for r in rs]
            axes[3, j].plot(xp, its, marker="o", ms=3, label=m)
        axes[0, j].set_title(f"scenario {sc}")
        axes[0, j].set_ylabel("distance prediction error [um]")
        axes[1, j].set_ylabel("length parameter error RMS [um]")
        axes[2, j].set_ylabel("failure rate [%]")
        axes[3, j].set_ylabel("iterations, both steps (spectral*: inner)")
        noises = sorted({r["noise_mm"] for r in rows})
        ticks = [n if n > 0 else 0.002 for n in noises]
        for i in range(4):
            ax = axes[i, j]
            ax.set_xscale("log")
            if i != 2:
                ax.set_yscale("log")
                ax.yaxis.set_minor_formatter(NullFormatter())
            ax.set_xticks(ticks)
            ax.set_xticklabels([f"{n:g}" for n in noises])
            ax.xaxis.set_minor_formatter(NullFormatter())
            ax.grid(alpha=0.3)
        axes[3, j].set_xlabel("noise sigma per coordinate [mm]")
        axes[0, j].legend(fontsize=7)
    save_figure(plt, fig, path, "Spectral correction (eq. 33-36) vs plain / column-scaled least squares and LM, "
                                 "separation steps, median with bar to p95")
