"""TM-MDH paper, Tables 10-11 under three readings of its orientation noise "0.002 rad":
per rotation-vector component, as the RMS norm of the rotation vector, and on each Z-Y-X Euler angle
(studies/tmmdh/tmmdh_common.dataset, twin.estimator.simulate.orientation_noise). Position noise 0.02 mm per
coordinate throughout. The paper's method (C-LM with its bounded damping, unweighted residuals in mm and rad,
31 parameters: ``clm_paper``) and our default estimator; flange-pose errors in the robot base frame on 100 test
poses, ours beside the paper's Tables 10-11. Writes studies/tmmdh/results/tmmdh_tables_10_11_noise.{json,md}.

    python studies/tmmdh/tmmdh_tables_10_11_noise.py [--seeds 20]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)

import tmmdh_common as tc  # noqa: E402

from twin.benchio import provenance  # noqa: E402
from tmmdh_tables_9_11 import NOISE, PAPER_EXCLUDED, pose_errors, error_stats  # noqa: E402

import numpy as np  # noqa: E402

from twin.estimator.core import prepare  # noqa: E402
from twin.estimator.methods import identify_best  # noqa: E402
from twin.estimator.paper_methods import identify_clm_paper  # noqa: E402
from twin.estimator.simulate import ORIENTATION_NOISE_READINGS  # noqa: E402

METHODS = {
    "clm_paper": lambda prep: identify_clm_paper(prep, error_model="tmmdh", exclude=PAPER_EXCLUDED),
    "ours": lambda prep: identify_best(prep, gauge="structure"),
}


def run(reading: str, seed: int) -> dict:
    q = tc.poses(100, seed=seed)
    q_test = tc.poses(100, seed=1000 + seed)
    ds, _ = tc.dataset(q, noise=NOISE, seed=seed, orientation_reading=reading)
    prep = prepare(ds, use_given_bases=True)
    truth = tc.truth_model()
    out = {"before": pose_errors(prep.nominal.with_frames(base2meas=np.eye(4), tool2flange=np.eye(4)), truth, q_test)}
    for k, f in METHODS.items():
        out[k] = pose_errors(prep.space.model(f(prep).x, prep.nominal, station=0), truth, q_test)
    return {k: v["flange_in_base"] for k, v in out.items()}


def main() -> int:
    load_start = os.getloadavg()
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    args = ap.parse_args()
    tg = tc.targets()
    t0 = time.perf_counter()
    res = {"noise": {"position_m_per_coordinate": NOISE[0], "orientation_rad": NOISE[1]}, "seeds": args.seeds,
           "readings": {}}
    for reading in ORIENTATION_NOISE_READINGS:
        per = [run(reading, s) for s in range(1, args.seeds + 1)]
        res["readings"][reading] = {
            k: {"seed_1": {"position_mm": error_stats(per[0][k]["position_mm"]), "orientation_rad": error_stats(per[0][k]["orientation_rad"])},
                "mean_over_seeds": {"position_mm_mean": float(np.mean([np.mean(p[k]["position_mm"]) for p in per])),
                                    "orientation_rad_mean": float(np.mean([np.mean(p[k]["orientation_rad"]) for p in per])),
                                    "orientation_rad_mean_seed_range": [float(f([np.mean(p[k]["orientation_rad"]) for p in per]))
                                                                        for f in (np.min, np.max)]}}
            for k in per[0]}
        print(reading, {k: v["mean_over_seeds"] for k, v in res["readings"][reading].items()}, flush=True)
    res["time_s"] = time.perf_counter() - t0
    res["paper"] = {"table10_mm": tg["table10_mm"], "table11_rad": tg["table11_rad"]}
    tc.RESULTS.mkdir(exist_ok=True)
    (tc.RESULTS / "tmmdh_tables_10_11_noise.json").write_text(json.dumps({**res, "provenance": provenance(load_start)}, indent=2) + "\n")
    p10, p11 = tg["table10_mm"]["tmmdh"], tg["table11_rad"]["tmmdh"]
    desc = {"rotvec": "0.002 rad per rotation-vector component (RMS angle 0.0035 rad)",
            "norm": "0.002 rad RMS norm of the rotation vector (0.00115 rad per component)",
            "euler": "0.002 rad on each Z-Y-X Euler angle"}
    L = ["# TM-MDH paper, Tables 10-11: three readings of the orientation noise", "",
         "BRTIRUS0707A, Tables 4-5 presets, 100 calibration and 100 test poses, position noise 0.02 mm per coordinate; "
         "`clm_paper`: the paper's C-LM (bounded damping, unweighted residuals in mm and rad, 31 parameters: z, alpha, x', "
         "z', alpha', gamma' held); `ours`: the default estimator (noise-weighted, structure gauge), told the per-component "
         f"orientation sigma of each reading. Flange pose in the robot base frame; seed 1 and the mean over {args.seeds} seeds. "
         f"Run time {res['time_s']:.0f} s.", "",
         "| orientation noise | model | position mean [mm] (seed 1) | max | min | mean over seeds | orientation mean [rad] (seed 1) "
         "| max | min | mean over seeds | range of the per-seed means |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for reading, rr in res["readings"].items():
        for k, v in rr.items():
            p, o, m = v["seed_1"]["position_mm"], v["seed_1"]["orientation_rad"], v["mean_over_seeds"]
            L.append(f"| {desc[reading]} | {k} | {p['mean']:.4g} | {p['max']:.4g} | {p['min']:.4g} | {m['position_mm_mean']:.4g} "
                     f"| {o['mean']:.3g} | {o['max']:.3g} | {o['min']:.3g} | {m['orientation_rad_mean']:.3g} "
                     f"| {m['orientation_rad_mean_seed_range'][0]:.3g} - {m['orientation_rad_mean_seed_range'][1]:.3g} |")
    L.append(f"| paper (TM-MDH, C-LM) | - | {p10['mean']} | {p10['max']} | {p10['min']} | - | {p11['mean']} | {p11['max']} | {p11['min']} | - | - |")
    best = min(res["readings"], key=lambda r: res["readings"][r]["clm_paper"]["mean_over_seeds"]["orientation_rad_mean"])
    bo = res["readings"][best]["clm_paper"]["mean_over_seeds"]["orientation_rad_mean"]
    L += ["", f"Closest reading for the paper's method: `{best}`, orientation mean {bo:.3g} rad over seeds against the paper's "
          f"{p11['mean']} rad (ratio {bo / p11['mean']:.2f})."]
    near = {r: v[k]["mean_over_seeds"]["orientation_rad_mean"] for r, v in res["readings"].items() for k in ("clm_paper",)}
    rat = [v["clm_paper"]["seed_1"]["orientation_rad"]["max"] / v["clm_paper"]["seed_1"]["orientation_rad"]["mean"]
           for v in res["readings"].values()]
    if all(v > 1.5 * p11["mean"] for v in near.values()):
        L.append(f"None of the three readings brings the paper's method near its {p11['mean']} rad on average "
                 f"(means over seeds: " + ", ".join(f"{r} {v:.3g}" for r, v in near.items()) + " rad); single seeds reach "
                 "down to the lower ends of the ranges above. Our default estimator comes closest under the `norm` reading "
                 f"({res['readings']['norm']['ours']['mean_over_seeds']['orientation_rad_mean']:.3g} rad). The paper's "
                 f"max/mean ratio over test poses ({p11['max'] / p11['mean']:.1f}) is also far from that of its method here "
                 f"(seed 1: {min(rat):.2f} - {max(rat):.2f}).")
    (tc.RESULTS / "tmmdh_tables_10_11_noise.md").write_text("\n".join(L) + "\n")
    print("\n".join(L))
    return 0


if __name__ == "__main__":
    sys.exit(main())
