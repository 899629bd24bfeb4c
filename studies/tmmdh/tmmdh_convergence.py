"""TM-MDH paper, Table 8 and Figure 6: convergence of LM and C-LM from 63 x 63 initial values of
(Delta theta1, Delta alpha2) in [-3.1, 3.1] rad, all 37 parameters free, noise-free data of the 100 calibration
poses. A run has converged when its parameters reproduce the noise-free poses to 1 um RMS (position). Our
default estimator takes no start value (nominal model + closed-form registration of the base), so its map is
flat by construction; it is run once and its error drawn over the whole grid. Writes
studies/tmmdh/results/tmmdh_convergence.json and studies/tmmdh/results/tmmdh_convergence_{lm,clm,best}.png.

Caps: LM at most 100 iterations (stop when the largest step < 1e-12); C-LM at most 20 cycles of two LM stages of
at most 10 iterations each, a run leaving the loop once converged or when a cycle no longer lowers its cost.

    python studies/tmmdh/tmmdh_convergence.py [--grid 63]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small batched matrices: threads only contend
sys.path.insert(0, str(Path(__file__).resolve().parent))
from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)

import tmmdh_common as tc  # noqa: E402

from twin.benchio import provenance  # noqa: E402

import numpy as np  # noqa: E402


def run_best() -> dict:
    from twin.estimator.core import prepare
    from twin.estimator.methods import identify_best
    from twin.estimator.lm import PoseBatch

    q = tc.poses(100, seed=1)
    ds, true = tc.dataset(q)
    t0 = time.perf_counter()
    prep = prepare(ds, noise_position=2e-5, noise_orientation=2e-3)
    ident = identify_best(prep)
    el = time.perf_counter() - t0
    pb = PoseBatch(prep.space, prep.obs_cal.with_sigma(1.0, 1.0))
    ep, eo = tc.converged_position_rms(pb, ident.x[None], true["pose"])
    return {"position_rms_m": float(ep[0]), "orientation_rms_rad": float(eo[0]), "time_s": el,
            "converged": bool(ep[0] <= tc.CONVERGED_M),
            "start_value": "none: nominal robot and tool, base2meas by closed-form registration (dataset.toml's "
                           "identity is not used), identifiability-fixed gauge"}


def plot(grid, Z, title, path, vmin=-13, vmax=-1):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.2, 4.4), dpi=120)
    im = ax.imshow(np.log10(np.maximum(Z, 1e-16)).T, origin="lower", extent=[grid[0], grid[-1], grid[0], grid[-1]],
                   vmin=vmin, vmax=vmax, cmap="viridis", aspect="equal")
    ax.set_xlabel("initial Delta theta1 [rad]")
    ax.set_ylabel("initial Delta alpha2 [rad]")
    ax.set_title(title, fontsize=9)
    cb = fig.colorbar(im, ax=ax)
    cb.set_label("log10 RMS position error [m] (converged: <= -6)")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main() -> int:
    load_start = os.getloadavg()
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grid", type=int, default=63)
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args()
    t0 = time.perf_counter()
    res = tc.convergence_study(n_grid=args.grid, progress=None if args.quiet else print)
    res["study_time_s"] = time.perf_counter() - t0
    res["best"] = run_best()
    tg = tc.targets()["table8"]
    res["paper_table8"] = tg
    res["caps"] = {"lm_max_iter": tc.LM_SETTINGS.max_iter, "clm_cycles": tc.CLM_CYCLES,
                   "clm_stage_max_iter": tc.CLM_STAGE.max_iter, "converged_if_position_rms_m_le": tc.CONVERGED_M,
                   "accept": tc.LM_SETTINGS.accept}
    grid = np.array(res["grid_rad"])
    tc.RESULTS.mkdir(exist_ok=True)
    for m in ("lm", "clm"):
        Z = 10.0 ** np.array(res[m]["log10_position_rms_m"])
        plot(grid, Z, f"{m.upper()}: {res[m]['converged_percent']:.2f} % converged (paper {tg[m]['convergence_percent']} %)",
             tc.RESULTS / f"tmmdh_convergence_{m}.png")
    Zb = np.full((grid.size, grid.size), res["best"]["position_rms_m"])
    plot(grid, Zb, "our default: no start value, flat map (one run)", tc.RESULTS / "tmmdh_convergence_best.png")
    (tc.RESULTS / "tmmdh_convergence.json").write_text(json.dumps({**res, "provenance": provenance(load_start)}) + "\n")
    lm, clm, b = res["lm"], res["clm"], res["best"]
    md = [
        "# TM-MDH paper, Table 8 and Figure 6: convergence from 63 x 63 initial values", "",
        "Starts: nominal + (Delta theta1, Delta alpha2) on a 63 x 63 grid over [-3.1, 3.1] rad; all 37 parameters free; "
        "the 100 noise-free calibration poses; unweighted SI residuals; converged = the parameters reproduce the "
        "noise-free poses to 1 um RMS (position). Caps: LM at most 100 iterations (stop when the largest step < 1e-12); "
        "C-LM at most 20 cycles of two LM stages of at most 10 iterations, leaving the loop once converged or when a "
        "cycle no longer lowers its cost. Every step is taken (the paper's Step 3).", "",
        "| method | converged (ours) | paper | run time per start (ours) | paper | median iterations |",
        "|---|---|---|---|---|---|",
        f"| LM | {lm['converged_percent']:.2f} % | {tg['lm']['convergence_percent']} % | {1e3 * lm['time_per_run_s']:.1f} ms | "
        f"{tg['lm']['run_time_s']} s | {lm['iterations_median']:.0f} |",
        f"| C-LM | {clm['converged_percent']:.2f} % | {tg['clm']['convergence_percent']} % | {1e3 * clm['time_per_run_s']:.1f} ms | "
        f"{tg['clm']['run_time_s']} s | {clm['iterations_median']:.0f} |",
        f"| ours (default) | 100 % (no start value) | - | {1e3 * b['time_s']:.1f} ms (one run) | - | - |", "",
        f"Whole study (both methods, {res['n_starts']} starts each): {res['study_time_s']:.0f} s on this machine "
        "(batched: all starts of a chunk iterate together).", "",
        "Maps: `tmmdh_convergence_lm.png`, `tmmdh_convergence_clm.png` (log10 RMS position error after the run), "
        "`tmmdh_convergence_best.png` (our default: flat).", "",
        "Reading: both LM and C-LM converge inside the diamond |Delta theta1| + |Delta alpha2| < pi and fail outside it. "
        "There the initial orientation error of some poses exceeds pi, and the rotation-vector residual log(R_meas "
        "R_model^T) wraps to the short way round: the iteration is then pulled towards a wrong minimum. Our C-LM matches "
        "the paper's ratio; our LM converges far more often than the paper's (it shares C-LM's basin here), which we "
        "attribute to our exact analytic Jacobian of the full nonlinear model against the paper's first-order "
        "differential error model (and its Euler-angle base/tool parameters); we cannot check the paper's "
        "implementation.", "",
        f"Our default estimator does not use a start value: it starts from the nominal robot and tool and registers the "
        f"base in closed form, so every cell of its map is the same run: position RMS {b['position_rms_m']:.2g} m, "
        f"orientation RMS {b['orientation_rms_rad']:.2g} rad on the noise-free poses.", "",
    ]
    (tc.RESULTS / "tmmdh_convergence.md").write_text("\n".join(md))
    summary = {
        m: {k: res[m][k] for k in ("converged_percent", "time_total_s", "time_per_run_s", "iterations_median", "iterations_max")}
        for m in ("lm", "clm")
    }
    print(json.dumps({"summary": summary, "best": res["best"], "paper": tg, "study_time_s": res["study_time_s"]}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
