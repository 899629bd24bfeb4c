"""Close the loop through rendered images: world (with an undeclared effect) -> images -> instrument ->
dataset -> `twin diagnose` -> evaluation beside the truth.

    python experiments/close_loop.py experiments/close_loop.toml --out results/close_loop

Writes ``OUT/dataset/`` (what the diagnosis saw), ``OUT/truth.json``, ``OUT/diagnosis/`` (diagnosis.json, the
two calibrations, plots) and ``OUT/close_loop.json``: geometric-only error, extended-model error, the oracle
(the true effect known exactly, from the world's centres with and without it, and the geometry re-identified on
the same measured rows) and the true model's error (the instrument's error only), side by side, with every term
diagnosis kept. The dataset records ``t_s`` and ``temp_c`` whatever the effect; its noise floor is what the
diagnosis measures itself (repeats, plate distances): nothing stated from the world's truth.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import time
import tomllib
from pathlib import Path

import twin  # noqa: F401  (MUJOCO_GL, single-threaded BLAS)
import numpy as np

from twin.dataset import DatasetWriter, PoseRow, default_plate, read_dataset, write_dataset_toml
from twin.diagnosis import diagnose, write_diagnosis
from twin.evaluation.closeloop import effect_delta, effect_size, oracle_delta_fit, plan_poses, true_model_error
from twin.instrument import BoardSpec, StereoCalibration, calibrate_stereo, measure_pair
from twin.world import World, WorldConfig
from twin.world.effects import EffectContext

_MM = 1e-3


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("config")
    ap.add_argument("--out", required=True)
    ap.add_argument("--quick", action="store_true", help="half resolution, 20 configurations per station")
    ap.add_argument("--reuse-dataset", action="store_true",
                    help="diagnose OUT/dataset again (rendered before with the same config) instead of rendering")
    args = ap.parse_args()
    cfg = tomllib.loads(Path(args.config).read_text())
    cl = cfg.get("close_loop", {})
    if args.quick:
        cfg.setdefault("world", {}).setdefault("render", {})["scale"] = 0.5
        cl["per_station"] = 20
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    timings = {}
    t = time.time()
    world = World.from_config(WorldConfig.from_dict(cfg))
    timings["world_build_s"] = time.time() - t

    # 1. the rig, calibrated from board views (the instrument never sees the world's cameras)
    t = time.time()
    calib_path = out / "stereo_calibration.json"
    if calib_path.exists():
        calib = StereoCalibration.load(calib_path)
    else:
        views = world.render_board_views(int(cl.get("board_views", 24)))
        calib = calibrate_stereo(views, BoardSpec.from_table(world.rig_info()["board"]))
        calib.save(calib_path)
    timings["stereo_calibration_s"] = time.time() - t

    # 2. the plan and the measurements, in order (the effects see the command history)
    plan = plan_poses(world, int(cl.get("per_station", 50)), repeats_every=int(cl.get("repeats_every", 4)),
                      seed=int(cl.get("seed", 1)))
    plate = default_plate()
    ds_dir = out / "dataset"
    if "instrument_noise_mm" in cl:
        raise ValueError(f"{args.config}: [close_loop] instrument_noise_mm is not allowed: a floor measured against the "
                         "world's truth; diagnosis measures its own (repeats, the plate's distances)")
    if not args.reuse_dataset:
        write_dataset_toml(ds_dir, "irb1200", plate, noise_position=None,
                           provenance=(f"experiments/close_loop.py {args.config}: the IRB-1200 twin rendered, measured "
                                       "by twin.instrument; effects undeclared"))
    world.reset_history()
    caps = []
    t = time.time()
    n_flagged = 0
    if args.reuse_dataset and (ds_dir / "poses.csv").exists():
        # the truth of the same plan without rendering (the world's effects see the same command history)
        caps = world.true_sequence(plan.q, list(plan.stations), t_s=plan.t_s)
        n_flagged = int((~read_dataset(ds_dir).sphere_seen.all(axis=1)).sum())
    else:
        with DatasetWriter(ds_dir, optional=["set", "station", "t_s", "temp_c", "status"]) as w:
            for k, (q, st) in enumerate(zip(plan.q, plan.stations)):
                # the pose's time stamp reaches the effects (warm-up, change points); the world fills the history
                cap = world.capture(q, int(st), EffectContext(t_s=float(plan.t_s[k]), station=int(st)), pose_id=k,
                                    noise_seed=k)
                m = measure_pair(cap.left, cap.right, calib, plate, bias_correction=bool(cl.get("bias_correction", True)))
                n_flagged += not m.complete
                w.write(PoseRow(k, q, list(m.centres), set=str(plan.sets[k]), station=world.station_names[int(st)],
                                t_s=float(plan.t_s[k]), temp_c=float(cap.temp_c), status=m.status))
                caps.append(dataclasses.replace(cap, left=None, right=None))  # keep the truth, drop the pixels
        timings["render_and_measure_s"] = time.time() - t
    world.write_truth(out / "truth.json")

    # 3. diagnosis: reads the dataset only
    ds = read_dataset(ds_dir)
    t = time.time()
    res = diagnose(ds)
    timings["diagnose_s"] = time.time() - t
    paths = write_diagnosis(res, out / "diagnosis")
    # the verdict and its plots are small: committed beside close_loop.json (the folder is git-ignored)
    for key in ("diagnosis", "residual_vs_joints", "residual_vs_history"):
        if key in paths:
            shutil.copyfile(paths[key], out / paths[key].name)

    # 4. evaluation: truth beside the diagnosis
    sigma = res.noise.sigma
    oracle = oracle_delta_fit(ds, effect_delta(world, plan))
    truth_only = true_model_error(ds, caps)
    size = effect_size(world, plan, sigma)
    summary = {
        "config": args.config,
        "rows": int(ds.n),
        "rows_with_a_missing_sphere": int(n_flagged),
        "noise_floor_mm": sigma / _MM,
        "noise_floor_source": res.noise.source,
        "noise_floor_components": res.noise.components,
        "effect": [e for e in cfg.get("world", {}).get("effects", [])],
        "effect_size_sigmas": size,
        "structured": res.structured,
        "p_value": res.p_value,
        "effects_named": list(res.effects),
        "terms": [a["text"] for a in res.atoms],
        "unnamed": [{"channel": a["channel"], "target": a["target"], "text": a["text"]} for a in res.unnamed],
        "alternatives": list(res.alternatives),
        "explained_fraction": res.explained_fraction,
        "validation_error_mm": {
            "geometric_only": res.before["position_mm"],
            "extended": res.after["position_mm"],
            "oracle_fit": oracle.after["position_mm"],
            "true_model": truth_only["position_mm"],
        },
        "validation_orientation_deg": {
            "geometric_only": res.before.get("orientation_deg"),
            "extended": res.after.get("orientation_deg"),
            "oracle_fit": oracle.after.get("orientation_deg"),
        },
        "ratio_extended_to_oracle": res.after["position_mm"]["rms"] / oracle.after["position_mm"]["rms"],
        "ratio_extended_to_true_model": res.after["position_mm"]["rms"] / truth_only["position_mm"]["rms"],
        "oracle_definition": "the true effect known exactly (the world's centres with minus without the effects) "
                             "and the geometry re-identified on the same measured calibration rows",
        "timings_s": timings,
        "command": f"python experiments/close_loop.py {args.config} --out {args.out}" + (" --quick" if args.quick else ""),
    }
    (out / "close_loop.json").write_text(json.dumps(summary, indent=2, default=float) + "\n")
    _plot(summary, out / "close_loop.png")
    v = summary["validation_error_mm"]
    print(f"noise floor {sigma / _MM:.4f} mm/coord; effect size {size:.2f} sigma; structured={res.structured} "
          f"(p={res.p_value:.2g}); effects={list(res.effects)}")
    for a in res.atoms:
        print(f"  term: {a['text']}")
    print("validation sphere error [mm]   mean     rms      max")
    for k in ("geometric_only", "extended", "oracle_fit", "true_model"):
        print(f"  {k:<26} {v[k]['mean']:.5f}  {v[k]['rms']:.5f}  {v[k]['max']:.5f}")
    return 0


def _plot(s: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    v = s["validation_error_mm"]
    keys = ["geometric_only", "extended", "oracle_fit", "true_model"]
    fig, ax = plt.subplots(figsize=(7, 4))
    x = np.arange(len(keys))
    for i, stat in enumerate(("mean", "rms", "max")):
        ax.bar(x + (i - 1) * 0.25, [v[k][stat] for k in keys], 0.25, label=stat)
    named = s["effects_named"] + [f"unnamed: {u['channel']} on {u['target']}" for u in s["unnamed"]]
    ax.set_xticks(x, ["geometric only", "extended\n(" + ",\n".join(named) + ")", "oracle", "true model"], fontsize=7)
    ax.set_ylabel("validation sphere-centre error [mm]")
    ax.set_title(f"close the loop: effect size {s['effect_size_sigmas']:.1f} sigma, structured={s['structured']}")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
