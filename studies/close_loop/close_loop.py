"""Close the loop through rendered images: world (with an undeclared effect) -> images -> instrument ->
dataset -> `twin diagnose` -> evaluation beside the truth.

    python studies/close_loop/close_loop.py studies/close_loop/close_loop.toml --out studies/close_loop/results/close_loop

The runner's measure stage (``twin.runner.measure``: the world renders, the instrument measures, each pose
stored in the work folder under OUT as it is measured, so a rerun resumes) on the close-loop plan (``twin.evaluation.closeloop.plan_poses``:
configurations the cameras see, station by station, every ``repeats_every``-th measured twice), then the public
``twin.diagnosis.diagnose`` on the dataset. Writes ``OUT/dataset/`` (what the diagnosis saw), ``OUT/truth.json``,
``OUT/diagnosis/`` (diagnosis.json, the two calibrations, plots) and ``OUT/close_loop.json``: geometric-only
error, extended-model error, the oracle (the true effect known exactly, from the world's centres with and without
it, and the geometry re-identified on the same measured rows) and the true model's error (the instrument's error
only), side by side, with every term diagnosis kept. The dataset records ``t_s`` and ``temp_c`` whatever the
effect; its noise floor is what the diagnosis measures itself (repeats, plate distances): nothing stated from the
world's truth.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)
import numpy as np  # noqa: E402

from twin.benchio import command_line, provenance  # noqa: E402
from twin.dataset import default_plate, read_dataset, write_dataset_toml  # noqa: E402
from twin.diagnosis import diagnose, write_diagnosis  # noqa: E402
from twin.evaluation.closeloop import effect_delta, effect_size, oracle_delta_fit, plan_poses, true_model_error  # noqa: E402
from twin.runner.executor import SerialExecutor, open_executor  # noqa: E402
from twin.runner.measure import (BACKENDS, BackendSpec, InstrumentSetup, PoseTask, get_backend, measure_tasks,  # noqa: E402
                                 write_measured_dataset)
from twin.runner.store import PoseStore  # noqa: E402
from twin.units import M_PER_MM  # noqa: E402
from twin.world.effects import contexts_for_sequence  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("config")
    ap.add_argument("--out", required=True)
    ap.add_argument("--quick", action="store_true", help="half resolution, 20 configurations per station")
    ap.add_argument("--workers", type=int, default=1, help="local processes rendering and measuring (default 1)")
    args = ap.parse_args()
    load_start = os.getloadavg()
    cfg = tomllib.loads(Path(args.config).read_text())
    cl = cfg.get("close_loop", {})
    if "instrument_noise_mm" in cl:
        raise ValueError(f"{args.config}: [close_loop] instrument_noise_mm is not allowed: a floor measured against the "
                         "world's truth; diagnosis measures its own (repeats, the plate's distances)")
    if args.quick:
        cfg.setdefault("world", {}).setdefault("render", {})["scale"] = 0.5
        cl["per_station"] = 20
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    timings = {}
    plate = default_plate()

    # 1. the instrument: the rig calibrated from board views (the instrument never sees the world's cameras)
    t = time.time()
    setup = InstrumentSetup(world=cfg["world"], mode="images", board_views=int(cl.get("board_views", 24)),
                            bias_correction=bool(cl.get("bias_correction", True)), plate=plate)
    spec = BackendSpec(BACKENDS["images"], setup, work_dir=str(out / "work"))
    backend = get_backend(spec)
    backend.prepare()
    world = backend.world
    timings["stereo_calibration_s"] = time.time() - t

    # 2. the plan and the measurements, in order (the effects see the command history, the pose's time stamp)
    plan = plan_poses(world, int(cl.get("per_station", 50)), repeats_every=int(cl.get("repeats_every", 4)),
                      seed=int(cl.get("seed", 1)))
    ctx = contexts_for_sequence(plan.q, t_s=plan.t_s, stations=list(plan.stations))
    names = [world.station_names[int(s)] for s in plan.stations]
    tasks = [PoseTask(f"m/{k:05d}", k, plan.q[k], names[k], k, context=ctx[k]) for k in range(len(plan.q))]
    store = PoseStore(out / "work" / "poses")
    t = time.time()
    with (open_executor("process", args.workers) if args.workers > 1 else SerialExecutor()) as ex:
        measure_tasks(ex, spec, tasks, store)
    timings["render_and_measure_s"] = time.time() - t
    results = [store.read(task.key) for task in tasks]
    ds_dir = out / "dataset"
    write_dataset_toml(ds_dir, "irb1200", plate, noise_position=None,
                       provenance=(f"studies/close_loop/close_loop.py {args.config}: the IRB-1200 twin rendered, "
                                   "measured by twin.instrument; effects undeclared"))
    write_measured_dataset(ds_dir, results, plan.q, set=plan.sets, station=names, t_s=plan.t_s,
                           temp_c=[float(r.truth["temp_c"]) for r in results])
    from twin.world.truth import write_truth

    write_truth(out / "truth.json", backend.truth_record(results))
    n_flagged = sum(1 for r in results if any(s is None for s in r.spheres))

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
    truth_only = true_model_error(ds, np.stack([np.asarray(r.truth["spheres_meas"], dtype=float) for r in results]))
    size = effect_size(world, plan, sigma)
    summary = {
        "config": args.config,
        "rows": int(ds.n),
        "rows_with_a_missing_sphere": int(n_flagged),
        "noise_floor_mm": sigma / M_PER_MM,
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
        "command": command_line("python studies/close_loop/close_loop.py",
                                [args.config, "--out", args.out] + (["--quick"] if args.quick else [])),
        "provenance": provenance(load_start),
    }
    (out / "close_loop.json").write_text(json.dumps(summary, indent=2, default=float) + "\n")
    _plot(summary, out / "close_loop.png")
    v = summary["validation_error_mm"]
    print(f"noise floor {sigma / M_PER_MM:.4f} mm/coord; effect size {size:.2f} sigma; structured={res.structured} "
          f"(p={res.p_value:.2g}); effects={list(res.effects)}")
    for a in res.atoms:
        print(f"  term: {a['text']}")
    print("validation sphere error [mm]   mean     rms      max")
    for k in ("geometric_only", "extended", "oracle_fit", "true_model"):
        print(f"  {k:<26} {v[k]['mean']:.5f}  {v[k]['rms']:.5f}  {v[k]['max']:.5f}")
    return 0


def _plot(s: dict, path: Path) -> None:
    from twin.evaluation.report import pyplot

    plt = pyplot()
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
