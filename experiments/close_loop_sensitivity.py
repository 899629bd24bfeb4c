"""Detection rate of `twin diagnose` against effect size: the world's own effects, camera-visible poses,
the instrument's noise level, no rendering (the rendered experiment is experiments/close_loop.py).

For every catalogue effect the world implements, the effect's magnitude is scaled so that what it leaves
after a perfect geometric-only calibration (noise-free data, same poses) is 1, 2, 3, 4, 6 times the noise;
for each size and seed a new plan and noise draw are diagnosed. Recorded per cell: detection rate
(structured), naming rate (effects == the injected one), and the extended model's validation error over the
oracle's (geometry + the true effect shape identified on the same rows). Plus the false-alarm rate with no
effect.

    python experiments/close_loop_sensitivity.py --seeds 10 --out results/close_loop_sensitivity.json
"""

from __future__ import annotations

import argparse
import copy
import json
import time
from pathlib import Path

import twin  # noqa: F401  (sets MUJOCO_GL and single-threaded BLAS before numpy/mujoco load)
import numpy as np

from twin.diagnosis import diagnose
from twin.evaluation.closeloop import effect_size, oracle_fit, plan_poses, synthetic_dataset
from twin.world import World, load_world_config
from twin.world.effects_catalogue import effect_from_spec

# the base spec of each effect and how its magnitude scales with a factor m (size is ~linear in m)
BASE = {
    "compliance": ({"name": "compliance", "stiffness_nm_per_rad": [2e5, 2.5e5, 1.2e5, 2e4, 2e4, 1e4]},
                   lambda s, m: {**s, "stiffness_nm_per_rad": [k / m for k in s["stiffness_nm_per_rad"]]}),
    "backlash": ({"name": "backlash", "half_clearance_deg": 0.005},
                 lambda s, m: {**s, "half_clearance_deg": s["half_clearance_deg"] * m}),
    "cyclic": ({"name": "cyclic", "amplitude_deg": 0.005}, lambda s, m: {**s, "amplitude_deg": s["amplitude_deg"] * m}),
    "gear_ratio": ({"name": "gear_ratio", "ratio": [1.0001, 1.0002, 1.0002, 1.0001, 1.0001, 1.0001]},
                   lambda s, m: {**s, "ratio": [1 + (r - 1) * m for r in s["ratio"]]}),
    "coupling": ({"name": "coupling", "coefficient": 0.001}, lambda s, m: {**s, "coefficient": s["coefficient"] * m}),
    "thermal": ({"name": "thermal", "temp_rise_k": 8.0}, lambda s, m: {**s, "temp_rise_k": s["temp_rise_k"] * m}),
}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--clean-seeds", type=int, default=40)
    ap.add_argument("--sizes", default="1,2,3,4,6")
    ap.add_argument("--sigma-mm", type=float, default=0.002, help="sphere-centre noise per coordinate [mm]")
    ap.add_argument("--per-station", type=int, default=50)
    ap.add_argument("--effects", default=",".join(BASE))
    ap.add_argument("--world", default="experiments/world_default.toml")
    ap.add_argument("--out", default="results/close_loop_sensitivity.json")
    args = ap.parse_args()
    sigma = args.sigma_mm * 1e-3
    sizes = [float(s) for s in args.sizes.split(",")]
    world = World.from_config(load_world_config(args.world))
    t0 = time.time()
    out = {
        "command": "python experiments/close_loop_sensitivity.py " + " ".join(
            f"--{k.replace('_', '-')} {v}" for k, v in vars(args).items()),
        "sigma_mm": args.sigma_mm,
        "per_station": args.per_station,
        "definition": "size = validation RMS per coordinate left by the default estimator on noise-free data with the "
                      "effect (a perfect geometric-only calibration), in noise sigmas; detected = structured; "
                      "named = effects equals the injected effect; ratio = extended model's validation RMS over the "
                      "oracle fit's (geometry + the true effect shape, same rows)",
        "effects": {},
    }
    # Plans depend on the stations and the seed, not on the effect (an operator plans with commanded poses):
    # one plan per seed, shared by every effect and size (planning visible configurations is the slow part).
    world.effects = []
    plans = {seed: plan_poses(world, args.per_station, seed=seed) for seed in range(args.seeds + 1)}
    # false alarms: the seeds' plans with independent noise draws
    alarms = 0
    for k in range(args.clean_seeds):
        plan = plans[1 + k % args.seeds]
        ds, _ = synthetic_dataset(world, plan, sigma=sigma, seed=2000 + k)
        alarms += bool(diagnose(ds).structured)
    out["false_alarm"] = {"seeds": args.clean_seeds, "alarms": alarms, "rate": alarms / max(args.clean_seeds, 1)}
    print(f"false alarms: {alarms}/{args.clean_seeds}", flush=True)
    for name in args.effects.split(","):
        spec0, scale = BASE[name]
        rec = "thermal" == name
        world.effects = [effect_from_spec(spec0)]
        plan0 = plans[0]
        s0 = effect_size(world, plan0, sigma, record_temp=rec)
        cells = []
        for target in sizes:
            m = target / s0
            spec = scale(copy.deepcopy(spec0), m)
            world.effects = [effect_from_spec(spec)]
            actual = effect_size(world, plan0, sigma, record_temp=rec)
            det = named = 0
            ratios = []
            found = []
            for seed in range(args.seeds):
                plan = plans[seed + 1]
                ds, caps = synthetic_dataset(world, plan, sigma=sigma, seed=100 + seed, record_temp=rec)
                res = diagnose(ds)
                det += bool(res.structured)
                named += res.effects == (name,)
                found.append(list(res.effects))
                if res.effects == (name,):
                    ratios.append(res.after["position_mm"]["rms"] / oracle_fit(ds, caps).after["position_mm"]["rms"])
            cell = {
                "target_size": target, "size": actual, "magnitude_factor": m, "spec": spec,
                "seeds": args.seeds, "detected": det / args.seeds, "named": named / args.seeds,
                "effects_per_seed": found,
                "ratio_to_oracle": {"median": float(np.median(ratios)) if ratios else None,
                                    "max": float(np.max(ratios)) if ratios else None},
            }
            cells.append(cell)
            print(f"{name:11s} size {actual:5.2f}: detected {det}/{args.seeds}, named {named}/{args.seeds}, "
                  f"ratio median {cell['ratio_to_oracle']['median']}", flush=True)
        out["effects"][name] = {"default_size": s0, "default_spec": spec0, "cells": cells}
    out["seconds"] = time.time() - t0
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=2) + "\n")
    _plot(out, Path(args.out).with_suffix(".png"))
    return 0


def _plot(out: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    for name, e in out["effects"].items():
        x = [c["size"] for c in e["cells"]]
        ax[0].plot(x, [c["detected"] for c in e["cells"]], "o-", label=name)
        ax[1].plot(x, [c["named"] for c in e["cells"]], "o-", label=name)
    for a, t in zip(ax, ("detected (structured)", "named correctly")):
        a.axvline(3.0, color="k", lw=0.8, ls="--")
        a.axhline(0.95, color="grey", lw=0.8, ls=":")
        a.set_xlabel("effect size after a perfect geometric calibration [noise sigmas]")
        a.set_ylabel(t)
        a.set_ylim(-0.05, 1.05)
    ax[0].legend(fontsize=8)
    fa = out["false_alarm"]
    fig.suptitle(f"diagnosis sensitivity (noise {out['sigma_mm']} mm per coordinate; false alarms "
                 f"{fa['alarms']}/{fa['seeds']} with no effect)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
