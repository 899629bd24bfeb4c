"""Shared set-up of the TM-MDH paper reproductions (its section 4): the BRTIRUS0707A (Table 3) with the
presets of Tables 4-5, nominal base2meas and tool2flange = identity (section 4.1), 100 random poses inside the
joint limits, 6-DOF pose measurements. Evaluation-side code: it owns the truth and compares it with the
estimates; the estimator only ever sees the datasets built here."""

from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from twin.estimator.core import prepare  # noqa: E402
from twin.estimator.lm import LMSettings, PoseBatch, cross_identification, levenberg_marquardt  # noqa: E402
from twin.estimator.simulate import random_configurations, simulate_dataset  # noqa: E402
from twin.kinematics import RobotModel  # noqa: E402
from twin.presets import preset_deviation  # noqa: E402
from twin.robots import brtirus0707a  # noqa: E402
from twin.transforms import matrix_to_rotvec, rotvec_to_matrix  # noqa: E402

RESULTS = ROOT / "results"
MM = 1e-3


def targets() -> dict:
    """The TM-MDH paper's targets (validated, with its ``[[unscored]]`` flags: twin.evaluation.targets)."""
    from twin.evaluation.targets import DEFAULT_TMMDH_TARGETS, read_targets

    return read_targets(DEFAULT_TMMDH_TARGETS)


def truth_model() -> RobotModel:
    nom = brtirus0707a()
    return nom.perturbed(preset_deviation("tmmdh_tables_4_5"), name="brtirus0707a-true")


def poses(n: int, seed: int) -> np.ndarray:
    return random_configurations(brtirus0707a(), n, np.random.default_rng(seed))


def dataset(q: np.ndarray, *, noise=(0.0, 0.0), seed: int = 0, sets=None, declare=True):
    """Pose dataset measured on the truth; nominal station base2meas = identity in dataset.toml (the paper's
    T_m0 nominal). Returns (dataset, noise-free truth dict)."""
    truth = truth_model()
    rng = np.random.default_rng(seed)
    ds, true = simulate_dataset(truth, q, robot_spec="brtirus0707a", kind="pose", base2meas={"0": truth.base2meas},
                                noise_position=noise[0], noise_orientation=noise[1], rng=rng,
                                set_=np.array(sets if sets is not None else ["calibration"] * len(q), dtype=object),
                                declare_noise=declare)
    return replace(ds, stations_base2meas={"0": np.eye(4)}), true


def euler_from_rotvec(r: np.ndarray) -> np.ndarray:
    """(alpha about z, beta about y, gamma about x) of R = Rz(alpha) Ry(beta) Rx(gamma) (the paper's eq. 3)."""
    from twin.transforms import euler_zyx_from_matrix

    e = euler_zyx_from_matrix(rotvec_to_matrix(np.asarray(r, float)))  # (rx=gamma, ry=beta, rz=alpha)
    return np.array([e[2], e[1], e[0]])


def deviations_table(x: np.ndarray, x_nom: np.ndarray, names) -> dict:
    """Deviations in the paper's units: theta/alpha/beta rad, d/a mm, base/tool xyz mm + (alpha, beta, gamma)."""
    idx = {n: k for k, n in enumerate(names)}
    out = {}
    for fam, scale in (("theta", 1.0), ("d", 1 / MM), ("a", 1 / MM), ("alpha", 1.0)):
        out[fam] = [float((x[idx[f"{fam}{j}"]] - x_nom[idx[f"{fam}{j}"]]) * scale) for j in range(1, 7)]
    out["beta2"] = float(x[idx["beta2"]] - x_nom[idx["beta2"]])
    for fr in ("base", "tool"):
        v = np.array([x[idx[f"{fr}_{c}"]] for c in ("x", "y", "z", "rx", "ry", "rz")])
        out[fr] = [float(t / MM) for t in v[:3]] + [float(t) for t in euler_from_rotvec(v[3:])]
    return out


def converged_position_rms(pb: PoseBatch, X: np.ndarray, true_p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """RMS position [m] and orientation [rad] errors of the parameter vectors X (B, P) on the noise-free poses."""
    sp = pb.space
    ev = sp.chain.evaluate(X[:, : sp.n_rt], pb.obs.q, base6=X[:, sp.n_rt:], jacobian=False)
    ep = np.sqrt(np.mean(np.sum((ev.p - true_p[None, :, :3, 3]) ** 2, axis=-1), axis=1))
    er = matrix_to_rotvec(true_p[None, :, :3, :3] @ np.swapaxes(ev.R, -1, -2))
    eo = np.sqrt(np.mean(np.sum(er**2, axis=-1), axis=1))
    return ep, eo


def data_position_rms(pb: PoseBatch, X: np.ndarray) -> np.ndarray:
    """RMS position residual [m] of the parameter vectors X (B, P) against the *measured* poses of ``pb``: what
    an estimator may look at (the stop rule), unlike :func:`converged_position_rms`, which reads the truth
    (evaluation)."""
    sp = pb.space
    ev = sp.chain.evaluate(X[:, : sp.n_rt], pb.obs.q, base6=X[:, sp.n_rt:], jacobian=False)
    return np.sqrt(np.mean(np.sum((ev.p - pb.obs.pose_p[None]) ** 2, axis=-1), axis=1))


def clm_stop_rule(pb: PoseBatch, tol_m: float = 1e-6):
    """C-LM stops when the fit reproduces the measured positions to ``tol_m`` [m] RMS (data only)."""
    return lambda X: data_position_rms(pb, X) <= tol_m


def convergence_grid(n: int = 63, lim: float = 3.1) -> np.ndarray:
    return np.linspace(-lim, lim, n)


LM_SETTINGS = LMSettings(max_iter=100, tol_step=1e-12, accept="always")
CLM_STAGE = LMSettings(max_iter=10, tol_step=1e-12, accept="always")
CLM_CYCLES = 20
CONVERGED_M = 1e-6


def convergence_study(n_grid: int = 63, chunk: int = 256, methods=("lm", "clm"), progress=print) -> dict:
    """The Table 8 / Figure 6 study: starts = nominal + (Delta theta1, Delta alpha2) on the grid, all 37
    parameters free, unweighted SI residuals (the paper's), noise-free poses of the 100 calibration poses."""
    q = poses(100, seed=1)
    ds, true = dataset(q)
    prep = prepare(ds, use_given_bases=True)
    sp = prep.space
    obs = prep.obs_cal.with_sigma(1.0, 1.0)
    pb = PoseBatch(sp, obs)
    g = convergence_grid(n_grid)
    T1, A2 = np.meshgrid(g, g, indexing="ij")
    X0 = np.repeat(prep.x_nominal[None], T1.size, axis=0)
    X0[:, sp.index("theta1")] += T1.ravel()
    X0[:, sp.index("alpha2")] += A2.ravel()
    free = np.ones(sp.size, dtype=bool)
    angle = ~sp.is_length
    out = {"grid_rad": g.tolist(), "n_starts": int(T1.size)}
    for method in methods:
        t0 = time.perf_counter()
        Xs, its, cyc = [], [], []
        for c0 in range(0, T1.size, chunk):
            Xc = X0[c0:c0 + chunk]
            if method == "lm":
                r = levenberg_marquardt(pb, Xc, free, settings=LM_SETTINGS)
            else:
                # the stop rule reads the measurements only (the data are noise-free here: a converged fit
                # reproduces them); the truth is read below, for the table, by evaluation
                stop = clm_stop_rule(pb, CONVERGED_M)
                r = cross_identification(pb, pb, Xc, free, angle, n_cycles=CLM_CYCLES, settings_orientation=CLM_STAGE,
                                         settings_full=CLM_STAGE, stop=stop)
            Xs.append(r.X)
            its.append(r.iterations)
            cyc.append(r.cycles)
            if progress:
                progress(f"{method}: {min(c0 + chunk, T1.size)}/{T1.size} starts, {time.perf_counter() - t0:.1f} s")
        elapsed = time.perf_counter() - t0
        X = np.concatenate(Xs)
        ep, eo = converged_position_rms(pb, X, true["pose"])
        conv = ep <= CONVERGED_M
        out[method] = {
            "converged_percent": float(100 * conv.mean()),
            "time_total_s": elapsed,
            "time_per_run_s": elapsed / T1.size,
            "iterations_median": float(np.median(np.concatenate(its))),
            "iterations_max": int(np.max(np.concatenate(its))),
            # compact maps: log10 of the RMS errors to 3 decimals, converged as 0/1
            "log10_position_rms_m": np.round(np.log10(np.maximum(ep, 1e-300)), 3).reshape(T1.shape).tolist(),
            "log10_orientation_rms_rad": np.round(np.log10(np.maximum(eo, 1e-300)), 3).reshape(T1.shape).tolist(),
            "converged": conv.astype(int).reshape(T1.shape).tolist(),
        }
        if method == "clm":
            out[method]["cycles_median"] = float(np.median(np.concatenate(cyc)))
    return out
