"""Benchmark of the end-to-end pipeline (`make run`): wall time per phase, per-pose costs, recording size.

    python experiments/bench_campaign.py                      # runs experiments/separation.toml afresh 3 times
    python experiments/bench_campaign.py --runs 1 --from results/separation/results.json   # records an existing run

Writes the `campaign` section of results/benchmark.json (twin.benchio.update_benchmark_section), with the
machine's load average and the package versions, since the figure depends on both, each run's campaign time and
their range (the README quotes the range over at least 3 runs), each run's CPU time over all its processes (the
command and its workers: on a machine shared with other jobs the wall time depends on what they take, the CPU
time much less), and the instrument's
sphere-centre and plate-orientation errors over the run's measured dataset poses (`instrument_on_dataset`).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path
import csv

from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)

import numpy as np

from twin.benchio import update_benchmark_section
from twin.dataset import Plate
from twin.estimator.problem import kabsch
from twin.instrument import plate_pose_from_spheres
from twin.transforms import rotation_angle_between
from twin.units import M_PER_MM, MM_PER_M, rad_to_deg


def instrument_errors(run_dir: Path) -> dict:
    """The instrument's errors over a campaign's measured dataset poses (estimated stereo calibration): measured
    sphere centres (``dataset/poses.csv`` [mm]) against the world's truth (``truth.json``), raw and after one
    rigid alignment of the measurement frame over all poses (what ``base2meas`` absorbs, as in the instrument
    benchmark); plate orientation from the nominal plate fitted to the measured centres [deg]."""
    truth = json.loads((run_dir / "truth.json").read_text())
    by_id = {int(p["pose_id"]): p for p in truth["poses"]}
    plate = Plate(float(truth["plate"]["sphere_diameter_m"]), np.array(truth["plate"]["nominal_spheres_flange_m"]))
    meas, sph, tool = [], [], []
    with open(run_dir / "dataset" / "poses.csv") as f:
        for row in csv.DictReader(f):
            if any(row[f"p{k}_{a}"] == "" for k in range(3) for a in "xyz") or int(row["pose_id"]) not in by_id:
                continue
            meas.append(np.array([[float(row[f"p{k}_{a}"]) for a in "xyz"] for k in range(3)]) * M_PER_MM)
            t = by_id[int(row["pose_id"])]
            sph.append(np.array(t["spheres_meas_m"]))
            tool.append(np.array(t["tool2meas"]))
    X, Y = np.concatenate(meas), np.concatenate(sph)
    R, t = kabsch(X, Y)  # R X + t ~ Y
    err_raw = np.linalg.norm(X - Y, axis=1) * MM_PER_M
    err_al = np.linalg.norm(X @ R.T + t - Y, axis=1) * MM_PER_M
    ori = [rad_to_deg(rotation_angle_between(R @ plate_pose_from_spheres(m, plate).tool2meas[:3, :3], T[:3, :3]))
           for m, T in zip(meas, tool)]

    def stats(v) -> dict:
        v = np.asarray(v)
        return {"rms": float(np.sqrt(np.mean(v**2))), "mean": float(np.mean(v)), "max": float(np.max(v))}

    return {"poses": len(meas), "sphere_error_mm": {"raw": stats(err_raw), "aligned": stats(err_al)},
            "plate_orientation_error_deg_aligned": stats(ori),
            "targets": {"sphere_rms_mm": 0.005, "sphere_max_mm": 0.015, "orientation_mean_deg": 0.003}}


def _where(path: Path) -> str:
    """``path`` relative to the repository, or a note that it lies outside (no machine path in a results file)."""
    root = Path(__file__).resolve().parents[1]
    try:
        return str(path.resolve().relative_to(root))
    except ValueError:
        return "a folder outside the repository (not kept)"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", default="experiments/separation.toml")
    p.add_argument("--out", default="results/runs/bench_campaign", help="campaign folder (git-ignored)")
    p.add_argument("--runs", type=int, default=3, help="fresh runs of the campaign (each renders everything)")
    p.add_argument("--from", dest="from_", default=None, help="record this results.json instead of running")
    a = p.parse_args()
    if a.runs < 1:
        raise SystemExit(f"--runs must be >= 1, got {a.runs}")
    load_before = os.getloadavg()
    runs = []
    wall = None
    if a.from_:
        res_path = Path(a.from_)
        r = json.loads(res_path.read_text())
        runs.append({"campaign_total_s": r["timings_s"]["total_s"], "command_wall_s": None,
                     "load_average_start": r.get("machine", {}).get("load_average_start"),
                     "load_average_end": r.get("machine", {}).get("load_average_end")})
    else:
        res_path = Path(a.out) / "results.json"
        for _ in range(a.runs):
            load0 = [round(x, 2) for x in os.getloadavg()]
            ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            t = time.perf_counter()
            subprocess.run([sys.executable, "-m", "twin.cli", "campaign", a.config, "--out", a.out, "--restart"],
                           check=True)
            wall = time.perf_counter() - t
            ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
            r = json.loads(res_path.read_text())
            runs.append({"campaign_total_s": round(r["timings_s"]["total_s"], 2), "command_wall_s": round(wall, 2),
                         "command_cpu_s": round(cpu, 1),
                         "load_average_start": load0, "load_average_end": [round(x, 2) for x in os.getloadavg()]})
            print(runs[-1], flush=True)
    r = json.loads(res_path.read_text())
    totals = [x["campaign_total_s"] for x in runs]
    n_meas = r["counts"]["poses"] + r["counts"]["compensated_measurements"]
    sums = r["worker_time_sums_s"]
    data = {
        "config": r["config"].get("name"),
        "results": _where(res_path),
        "command_wall_s": wall,
        "campaign_total_s": r["timings_s"]["total_s"],
        "runs": runs,
        "campaign_total_s_range": [min(totals), float(np.median(totals)), max(totals)],
        "command_cpu_s_median": (float(np.median([x["command_cpu_s"] for x in runs])) if all(
            x.get("command_cpu_s") is not None for x in runs) else None),
        "phases_s": r["timings_s"],
        "measurements": n_meas,
        "per_measurement_s": {k: v / n_meas for k, v in sums.items()},
        "recording_mb": r.get("recording_mb"),
        "recording_mb_per_100_poses": (r["recording_mb"] / r["counts"]["poses"] * 100) if r.get("recording_mb") else None,
        "load_average_1_5_15": r.get("machine", {}).get("load_average_start", list(load_before)),
        "load_average_end": r.get("machine", {}).get("load_average_end"),
        "target": "make run <= 80 s of campaign time on the 2-core machine; recording < 200 MB per 100 poses",
        "note": "campaign_total_s_range: min, median, max of the runs' campaign time; command_cpu_s: user + system "
                "time of the command and its worker processes; phases and per-measurement costs are of the last run",
        "instrument_on_dataset": instrument_errors(res_path.parent),
    }
    update_benchmark_section("campaign", data)
    print(json.dumps(data, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
