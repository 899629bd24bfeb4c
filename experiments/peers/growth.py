"""The ``growth`` section: how cost grows with the work.

* **Identification**: our default estimator (``twin.estimator.calibrate(method="best")``) on the benchmark's
  synthetic problem (6-DOF poses, 0.02 mm / 0.002 rad) for 50, 100, 200, 500 and 1000 calibration poses: wall
  time (median of ``repeats`` runs) and peak traced memory (``tracemalloc``, NumPy's buffers included, in a
  separate run so tracing does not slow the timed ones). Linear growth shows as a constant time per pose and a
  log-log slope near 1.
* **Campaign**: ``twin.runner.campaign.run_campaign`` on the separation campaign
  (``experiments/separation.toml``) resized to 100 and 1000 measured poses (half calibration, half validation
  motion pairs, compensation and re-measurement of the validation half, our default method), with the
  ``truth_noise`` backend (the paper's own simulation: no images, so the figure is the runner's own cost; a
  rendered campaign adds the ``pipeline`` section's per-pose cost for every measured pose), recording and
  figures off, two local worker processes as the campaign's default. Each size runs in a fresh interpreter;
  peak memory is its resident-set high-water mark (``VmHWM``), next to the resident set after imports; the
  workers' figure is ``getrusage(RUSAGE_CHILDREN).ru_maxrss``, an upper bound (Linux carries ``ru_maxrss``
  across fork + exec, so a spawned worker reports at least its parent's resident set at spawn time; the same
  made ``RUSAGE_SELF`` report the benchmark process's own 950 MiB in a first run). Poses are streamed to disk one by one (``twin.runner.store``), so memory should stay flat.
* **Monte-Carlo throughput**: ``run_repeats`` (one whole campaign per seed, 80 poses, ``truth_noise``) for the
  same seeds on one in-process worker, two local processes, and a two-worker Dask ``LocalCluster``:
  campaigns per minute, and the sum of the campaigns' own wall times over the executor's wall time (the
  concurrency achieved: about 1 in-process, up to 2 with two workers on two free cores). Worker start-up
  (a fresh interpreter importing the package and building the world) is part of the executors' time. The
  1-minute load average is recorded: on a machine shared with other jobs, two workers cannot go faster than
  the cores left to them.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
import tomllib
import tracemalloc
from pathlib import Path

import numpy as np

__all__ = ["growth_section", "campaign_raw", "identification_growth"]

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "experiments" / "separation.toml"
IDENT_POSES = (50, 100, 200, 500, 1000)
CAMPAIGN_POSES = (100, 1000)


def identification_growth(poses=IDENT_POSES, repeats: int = 5) -> dict:
    """Time and peak memory of our default estimator against the number of calibration poses."""
    from twin.estimator import calibrate

    from .synthetic import NOISE_LEVELS, make_problem, make_split, to_dataset

    problem = make_problem()
    rows = []
    for n in poses:
        ds = to_dataset(problem, make_split(problem, 0, n, NOISE_LEVELS[0]))
        calibrate(ds, method="best")  # warm-up
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            calibrate(ds, method="best")
            times.append(time.perf_counter() - t)
        tracemalloc.start()
        calibrate(ds, method="best")
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        med = float(np.median(times))
        rows.append({"poses": n, "seconds_median": med, "seconds_runs": times, "ms_per_pose": 1e3 * med / n,
                     "peak_mib": peak / 2**20})
    n = np.array([r["poses"] for r in rows], dtype=float)
    t = np.array([r["seconds_median"] for r in rows])
    slope = float(np.polyfit(np.log(n), np.log(t), 1)[0]) if len(rows) > 1 else None
    return {"rows": rows, "loglog_slope": slope, "method": "twin.estimator.calibrate(method='best')",
            "data": "benchmark synthetic IRB-1200, 6-DOF poses, 0.02 mm / 0.002 rad, seed 0"}


def campaign_raw(n_poses: int, workers: int = 2, name: str | None = None) -> dict:
    """The separation campaign resized to ``n_poses`` measured poses, ``truth_noise``, default method only."""
    if n_poses < 8 or n_poses % 4:
        raise ValueError(f"n_poses must be a multiple of 4 and >= 8, got {n_poses}")
    raw = tomllib.loads(CONFIG.read_text())
    raw.pop("quick", None)
    raw["name"] = name or f"growth-{n_poses}"
    raw["methods"] = ["default"]
    raw["measurement"] = {**raw.get("measurement", {}), "mode": "truth_noise"}
    raw["outputs"] = {"recording": False, "figures": False}
    raw["execution"] = {"workers": workers}
    raw["poses"] = [
        {"name": "calibration", "set": "calibration", "kind": "motion_pairs", "count": n_poses // 4},
        {"name": "compensation", "set": "validation", "kind": "motion_pairs", "count": n_poses // 4,
         "evaluate": ["angle"]},
    ]
    return raw


def _status_mib(field: str) -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _rss_mib() -> float:
    """Resident set now [MiB]."""
    return _status_mib("VmRSS")


def _hwm_mib() -> float:
    """Peak resident set of this process [MiB] (the kernel's high-water mark)."""
    return _status_mib("VmHWM")


def _campaign_child(n_poses: int, workers: int) -> None:
    """Entry point of the fresh interpreter that runs one campaign and prints its figures as JSON."""
    import resource

    from twin.runner.campaign import run_campaign
    from twin.runner.config import parse_campaign_config

    cfg = parse_campaign_config(campaign_raw(n_poses, workers))
    base = _rss_mib()
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        run = run_campaign(cfg, Path(tmp) / "campaign", recording=False, figures=False)
        wall = time.perf_counter() - t
        n_files = sum(1 for _ in (Path(tmp) / "campaign" / "work" / "poses").rglob("*.json"))
    print(json.dumps({
        "poses": n_poses,
        "workers": workers,
        "seconds": wall,
        "pose_files_written": n_files,
        "rss_after_imports_mib": base,
        "peak_rss_mib": _hwm_mib(),
        "peak_rss_mib_getrusage": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "peak_rss_largest_worker_mib": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024,
        "timings_s": run.results.get("timings_s", {}),
    }))


def _run_child(code: str, timeout: float) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout, env=env, cwd=ROOT)
    if p.returncode != 0:
        raise RuntimeError(f"child failed ({p.returncode}): {p.stderr.strip()[-2000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def campaign_growth(poses=CAMPAIGN_POSES, workers: int = 2) -> dict:
    rows = []
    for n in poses:
        code = f"from experiments.peers.growth import _campaign_child; _campaign_child({n}, {workers})"
        rows.append(_run_child(code, timeout=3600))
    return {"rows": rows, "backend": "truth_noise (no images)", "config": "experiments/separation.toml resized",
            "methods": ["default"]}


def monte_carlo_throughput(seeds: int = 4, n_poses: int = 40) -> dict:
    """Campaigns per minute for the same seeds on 1 worker, 2 local processes and a 2-worker Dask cluster."""
    from twin.runner.campaign import run_repeats
    from twin.runner.config import parse_campaign_config
    from twin.runner.executor import open_executor

    cfg = parse_campaign_config(campaign_raw(n_poses, workers=1, name="growth-montecarlo"))
    seed_list = list(range(1, seeds + 1))
    out = {"seeds": seed_list, "poses_per_campaign": n_poses, "backend": "truth_noise (no images)", "rows": []}
    runs = [("1 worker (in-process)", "serial", {}), ("2 local processes", "process", {"workers": 2})]
    try:
        from distributed import LocalCluster

        runs.append(("Dask LocalCluster, 2 workers", "dask", {}))
    except ImportError:
        out["dask_missing"] = "dask.distributed is not installed (pip install .[dask])"
        LocalCluster = None  # type: ignore[assignment]
    for label, kind, kw in runs:
        load0 = os.getloadavg()[0]
        with tempfile.TemporaryDirectory() as tmp:
            if kind == "dask":
                cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
                from distributed import Client

                client = Client(cluster)
                try:
                    t = time.perf_counter()
                    with open_executor("dask", address=client) as ex:
                        res = run_repeats(cfg, tmp, seed_list, ex)
                    wall = time.perf_counter() - t
                finally:
                    client.close()
                    cluster.close()
            else:
                t = time.perf_counter()
                with open_executor(kind, **kw) as ex:
                    res = run_repeats(cfg, tmp, seed_list, ex)
                wall = time.perf_counter() - t
            where = sorted({f"{r['worker']['pid']}" + (f"@{r['worker']['dask_worker']}" if r["worker"].get("dask_worker") else "")
                            for r in res["per_seed"]})
        busy = float(sum(r["timings_s"].get("total_s", 0.0) for r in res["per_seed"]))
        out["rows"].append({"executor": label, "seconds": wall, "campaigns_per_minute": 60 * len(seed_list) / wall,
                            "distinct_workers": len(where), "campaign_seconds_sum": busy,
                            "concurrency": busy / wall, "load_average_1min_at_start": load0})
    return out


def growth_section(quick: bool = False, repeats: int = 5) -> dict:
    try:
        import twin.estimator  # noqa: F401
        import twin.runner.campaign  # noqa: F401
    except ImportError as e:
        return {"missing": f"estimator / runner not available ({e}); nothing measured"}
    t0 = time.perf_counter()
    out = {
        "identification": identification_growth((50, 100) if quick else IDENT_POSES, repeats=1 if quick else repeats),
        "campaign": campaign_growth((40,) if quick else CAMPAIGN_POSES),
        "monte_carlo": monte_carlo_throughput(seeds=2 if quick else 6, n_poses=16 if quick else 80),
        "load_average_1min_at_end": os.getloadavg()[0],
    }
    out["wall_seconds"] = time.perf_counter() - t0
    return out
