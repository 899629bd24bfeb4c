"""Benchmark of the diagnosis -> the ``diagnosis`` section of results/benchmark.json.

Target: ``twin diagnose`` on 300 rows in <= 30 s on 2 cores. The dataset: 240 poses of the IRB-1200
(calibration and validation alternating), every 4th pose measured twice in a row (300 rows), 5 um noise per
sphere coordinate, both channels ``t_s`` and ``temp_c`` recorded (every dictionary atom in time and
temperature is tried), and two undeclared effects written here (not with the diagnosis' regressors): a
backlash on joints 2 and 3 (sign of each joint's last move from a start away from home) and a motor-side
cyclic error of order 81 on joint 5 (the generator of ``tests/_diagnosis_helpers.py``: no rendering).

Timed, median of ``--runs`` runs each (after one warm-up run of the library call):

* ``library``: ``twin.diagnosis.diagnose(dataset)`` on the dataset in memory, and the writing phases
  (``write_diagnosis`` with plots, ``record_diagnosis`` with the workspace);
* ``cli``: ``twin diagnose DATASET --out DIR`` end to end in a fresh process (start-up, imports, reading,
  diagnosis, JSON, plots, recording), peak resident memory of that process;
* ``steps``: where one ``diagnose`` spends its time, by its named steps and the scoring inside them (cProfile
  cumulative times of one run: the profiler's overhead included, shares are what matter).

    python experiments/bench_diagnosis.py [--runs 5]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small matrices: BLAS threads only contend on 2 shared cores

import argparse  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import tracemalloc  # noqa: E402
from pathlib import Path  # noqa: E402

from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
import _diagnosis_helpers as H  # noqa: E402  (the synthetic generator of the diagnosis tests)

from twin.benchio import peak_rss_kb, provenance, update_benchmark_section  # noqa: E402
from twin.dataset import read_dataset, write_dataset  # noqa: E402
from twin.diagnosis import diagnose, diagnosis_dict, write_diagnosis  # noqa: E402
from twin.evaluation.recording import record_diagnosis  # noqa: E402
from twin.evaluation.workspace import diagnosis_workspace  # noqa: E402
from twin.units import M_PER_MM, RAD_PER_DEG  # noqa: E402

TARGET_S = 30.0


def _effect(q: np.ndarray, model) -> np.ndarray:
    """Backlash 0.008 deg on joints 2-3 (start away from home) and 0.004 deg at 81 cycles per turn on joint 5."""
    start = np.array([0.5, 0.2, -0.3, 0.1, 0.9, 0.0])
    last = np.sign(q[0] - start)
    sign = np.empty_like(q)
    for k in range(len(q)):
        if k:
            d = np.sign(q[k] - q[k - 1])
            last = np.where(d != 0, d, last)
        sign[k] = last
    out = q + 0.008 * RAD_PER_DEG * sign * np.array([0, 1, 1, 0, 0, 0])
    out[:, 4] += 0.004 * RAD_PER_DEG * np.sin(81 * q[:, 4] + 0.4)
    return out


def _median_timing(f, runs: int) -> dict:
    wall, cpu = [], []
    for _ in range(runs):
        t, c = time.perf_counter(), time.process_time()
        f()
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return {"median_s": float(np.median(wall)), "min_s": float(np.min(wall)), "max_s": float(np.max(wall)),
            "cpu_median_s": float(np.median(cpu)), "runs_s": [float(w) for w in wall]}


STEPS = ("prepare_diagnosis", "fit_geometry", "atom_pool", "select_terms", "selection_round", "score_atoms",
         "_screen", "_score_products", "confirm", "refine", "prefer_play", "backward", "_named_shapes", "decide",
         "report_before_after", "describe_terms", "_series")


def _steps(ds) -> dict:
    """Cumulative seconds of ``diagnose``'s named steps (and the scoring inside them) over one profiled run."""
    import cProfile
    import pstats

    prof = cProfile.Profile()
    prof.enable()
    diagnose(ds)
    prof.disable()
    st = pstats.Stats(prof).stats  # {(file, line, name): (cc, nc, tt, ct, callers)}
    total = max(v[3] for (f, _, n), v in st.items() if n == "diagnose" and f.endswith("diagnose.py"))
    out = {"diagnose_profiled_s": total}
    for name in STEPS:
        hits = [(v[1], v[3]) for (f, _, n), v in st.items() if n == name and "twin/diagnosis" in f.replace("\\", "/")]
        if hits:
            out[name] = {"calls": int(sum(c for c, _ in hits)), "cumulative_s": float(sum(t for _, t in hits)),
                         "share": float(sum(t for _, t in hits) / total)}
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5, help="timed runs of each measurement (>= 5 for the record)")
    ap.add_argument("--n-poses", type=int, default=240, help="poses (every 4th repeated: 240 -> 300 rows)")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--no-write", action="store_true", help="print only, do not update results/benchmark.json")
    args = ap.parse_args()
    if args.runs < 1:
        raise ValueError(f"--runs must be >= 1, got {args.runs}")
    load_start = list(os.getloadavg())
    n = args.n_poses
    m = n + (n + 3) // 4
    rng = np.random.default_rng(args.seed)
    ds, _ = H.make_dataset(seed=args.seed, n=n, effect=_effect, t_s=np.cumsum(rng.uniform(8, 12, m)),
                           temp=21.0 + 0.3 * rng.standard_normal(m))
    work = Path(tempfile.mkdtemp(prefix="bench_diagnosis_"))
    try:
        write_dataset(work / "ds", ds)
        ds = read_dataset(work / "ds")
        n_val = int(np.sum(ds.set == "validation"))

        res = diagnose(ds)  # warm-up (imports, caches) and the verdict recorded with the figures
        lib = _median_timing(lambda: diagnose(ds), args.runs)
        read_t = _median_timing(lambda: read_dataset(work / "ds"), args.runs)
        write_t = _median_timing(lambda: write_diagnosis(res, work / "lib_out", plots=True), args.runs)
        verdict = diagnosis_dict(res)
        rec_t = _median_timing(lambda: record_diagnosis(
            work / "lib_out" / "diagnosis.rrd", res.series, verdict,
            workspace=diagnosis_workspace(res.series, res.calibrations_blocked["geometric"])), args.runs)
        steps = _steps(ds)
        tracemalloc.start()
        diagnose(ds)
        _, traced_peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        rss_self_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0

        twin_exe = shutil.which("twin", path=str(Path(sys.executable).parent)) or "twin"
        cmd = [twin_exe, "diagnose", str(work / "ds"), "--out", str(work / "cli_out")]

        peaks_kb: list[int] = []
        child_cpu: list[float] = []

        def cli():
            # The child's own high-water mark: VmHWM of /proc/PID/status (reset by exec, unlike ru_maxrss of
            # RUSAGE_CHILDREN, which a forked child inherits from this process), polled until it exits.
            ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL)
            hwm = 0
            while proc.poll() is None:
                hwm = max(hwm, peak_rss_kb(proc.pid))
                time.sleep(0.02)
            if proc.returncode != 0:
                raise RuntimeError(f"{' '.join(cmd)} exited with {proc.returncode}")
            ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            peaks_kb.append(hwm)
            child_cpu.append((ru1.ru_utime + ru1.ru_stime) - (ru0.ru_utime + ru0.ru_stime))

        cli_t = _median_timing(cli, args.runs)
        cli_t["cpu_median_s"] = float(np.median(child_cpu))  # the child's CPU time, not this process's
        rss_cli_mb = max(peaks_kb) / 1024.0
        rrd_mb = (work / "cli_out" / "diagnosis.rrd").stat().st_size / 1e6
        cli_files = sorted(p.name for p in (work / "cli_out").iterdir())
    finally:
        shutil.rmtree(work, ignore_errors=True)

    data = {
        "target": f"twin diagnose on a dataset of {ds.n} rows <= {TARGET_S:.0f} s",
        "target_s": TARGET_S,
        "meets_target": bool(cli_t["median_s"] <= TARGET_S and lib["median_s"] <= TARGET_S),
        "dataset": {
            "generator": "tests/_diagnosis_helpers.make_dataset (synthetic sphere centres, no rendering)",
            "robot": "irb1200", "seed": args.seed, "poses": n, "rows": int(ds.n),
            "validation_rows": n_val, "calibration_rows": int(ds.n - n_val),
            "repeats": "every 4th pose measured twice in a row (noise floor)",
            "noise_position_mm": H.SIGMA / M_PER_MM, "channels": ["t_s", "temp_c"],
            "effect": "backlash 0.008 deg on joints 2-3 + cyclic order 81 (0.004 deg) on joint 5, undeclared",
        },
        "verdict": {"structured": res.structured, "p_value": res.p_value, "effects": list(res.effects),
                    "terms": [a["text"] for a in res.atoms],
                    "before_rms_mm": res.before["position_mm"]["rms"], "after_rms_mm": res.after["position_mm"]["rms"],
                    "candidates_scored": len(res.scores)},
        "runs": args.runs,
        "steps": steps,
        "library": {
            "diagnose": lib,
            "read_dataset": read_t,
            "write_diagnosis_with_plots": write_t,
            "record_diagnosis": rec_t,
            "diagnose_traced_peak_mb": traced_peak / 1e6,
            "process_peak_rss_mb": rss_self_mb,
            "process_peak_rss_note": "ru_maxrss of the benchmark process (imports, dataset, all library runs)",
        },
        "cli": {
            "command": "twin diagnose DATASET --out DIR (plots and recording on)",
            "end_to_end": cli_t,
            "peak_rss_mb": rss_cli_mb,
            "peak_rss_method": "VmHWM of /proc/PID/status of the twin process, polled every 20 ms; max over runs",
            "files": cli_files,
            "recording_mb": rrd_mb,
        },
        "provenance": provenance(load_start),
        "load_average_1_5_15": load_start,
        "load_average_end": list(os.getloadavg()),
        "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS"),
        "note": "wall times on a shared 2-core machine (see the load averages); cpu = process time of this process; "
                "diagnose = noise floor, geometric fit, structure test, forward-backward selection over the catalogue "
                "and the dictionary, "
                "before/after statistics; the CLI figure includes interpreter start-up and imports (~1-2 s).",
    }
    print(json.dumps(data, indent=1))
    if not args.no_write:
        p = update_benchmark_section("diagnosis", data)
        print(f"diagnose {lib['median_s']:.2f} s (library, median of {args.runs}); twin diagnose end to end "
              f"{cli_t['median_s']:.2f} s; target {TARGET_S:.0f} s; wrote {p}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
