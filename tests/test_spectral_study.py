"""The spectral-correction study (studies/spectral_correction): its solvers, its problem and its failure rule."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from twin.estimator.problem import pair_residuals  # noqa: E402
from twin.estimator.solvers import gauss_newton, spectral_correction  # noqa: E402
from studies.spectral_correction.spectral import (  # noqa: E402
    FitResult,
    gauss_newton_fit,
    markdown_table,
    run_case,
    simulate_problem,
    solve_step,
    summarise,
)


@pytest.fixture(scope="module")
def wide():
    return simulate_problem(3, 1e-5, scenario="wide")


def test_all_methods_agree_on_a_well_conditioned_problem(wide):
    """Wide design, 0.01 mm noise: every solver (plain, SVD, scaled, spectral, LM) returns the same estimate."""
    recs = run_case(wide)
    ref = next(r for r in recs if r.method == "lstsq").x
    scale = np.max(np.abs(ref - wide.prep.x_nominal))
    for r in recs:
        assert r.converged and not r.failed, r.method
        assert np.max(np.abs(r.x - ref)) < 1e-9 * scale, r.method


def test_spectral_correction_converges_to_the_minimum_norm_least_squares_solution():
    """Rank-deficient H (rank 5 of 8), b = H^T e in the range of N: the iteration from 0 reaches lstsq's
    minimum-norm solution."""
    for seed in range(5):
        rng = np.random.default_rng(seed)
        H = rng.normal(size=(30, 5)) @ rng.normal(size=(5, 8))
        e = rng.normal(size=30)
        s = spectral_correction(H.T @ H, H.T @ e, max_iter=10**9)
        x_ls = np.linalg.lstsq(H, e, rcond=None)[0]
        assert s.converged
        assert np.max(np.abs(s.x - x_ls)) < 1e-9 * np.max(np.abs(x_ls)), seed


def test_the_study_loop_reproduces_the_projects_gauss_newton(wide):
    """Step 1 of the wide problem: the study's Gauss-Newton with the scaled / spectral step ends where the
    project's gauss_newton(linear_solver=...) ends."""
    p = wide

    def fun(y):
        return pair_residuals(p.space, y, p.obs_rot, p.pairs_rot, "rotation_change")

    for solver in ("scaled", "spectral"):
        ours = gauss_newton_fit(fun, p.prep.x_nominal, p.idx1, solver)
        project = gauss_newton(fun, p.prep.x_nominal, p.idx1, linear_solver=solver)
        assert np.max(np.abs(ours.x - project.x)) < 1e-12, solver


def test_the_failure_flag_trips_on_a_solver_that_stops_short(wide):
    """A 'solver' that reports convergence after half a Gauss-Newton step is flagged by the error rule."""

    def half_step(fun, x0, idx):
        res = fun(x0)
        x = x0.copy()
        x[idx] += 0.5 * solve_step("lstsq", res.J[:, idx], res.r).dx
        return FitResult(x, 1, 0, 0, True, True, True, 0.0, 0.0, 1.0, 1.0, 1.0)

    recs = {r.method: r for r in run_case(wide, ["lstsq", ("half", half_step)])}
    assert not recs["lstsq"].failed
    assert recs["half"].failed and recs["half"].failure == "error above threshold"


def test_plain_normal_equations_fail_on_the_papers_singular_parameter_list():
    """The paper's lists as written (columns without effect): plain normal equations are flagged as a solver
    error, SVD least squares is not."""
    p = simulate_problem(0, 1e-5, scenario="paper_list")
    recs = {r.method: r for r in run_case(p, ["lstsq", "normal"])}
    assert recs["normal"].failed and "solver error" in recs["normal"].failure
    assert not recs["lstsq"].failed


def test_capped_spectral_correction_does_not_converge_on_the_ill_conditioned_d2_problem():
    """d2 estimated (cond(H) ~ 1e5): with the project's cap of 1e5 iterations per step the spectral step does
    not converge and the run is flagged; without a cap it matches least squares."""
    p = simulate_problem(0, 1e-5, scenario="with_d2")
    recs = {r.method: r for r in run_case(p, ["lstsq", "spectral", "spectral_unbounded"])}
    assert recs["spectral"].failed and "not converged" in recs["spectral"].failure
    assert not recs["spectral_unbounded"].failed
    assert recs["spectral_unbounded"].distance_prediction_error < 1.01 * recs["lstsq"].distance_prediction_error


def test_summary_table_has_one_row_per_method_and_noise(wide):
    """The Markdown table lists every (noise, method) cell of the records once."""
    recs = run_case(wide, ["lstsq", "scaled"])
    md = markdown_table(summarise(recs))
    assert md.count("| 0.01 | lstsq |") == 1 and md.count("| 0.01 | scaled |") == 1


def test_unknown_names_are_rejected_naming_the_argument():
    """A bad scenario or method name raises ValueError naming it."""
    with pytest.raises(ValueError, match="scenario"):
        simulate_problem(0, 0.0, scenario="tight")
    with pytest.raises(ValueError, match="method"):
        solve_step("cholesky", np.eye(2), np.ones(2))
