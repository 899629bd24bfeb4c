"""Benchmark of the test suite as CI runs it: the wall time of ``make test``'s pytest command, several runs.

Runs ``pytest -q -n JOBS --dist worksteal`` (the command of ``make test`` after its install step) ``--runs`` times and
writes the ``suite`` section of ``results/benchmark.json``: each run's wall time, test counts and load average at its
start and end, the range (min, median, max) over the runs, and the time of ``make install`` on the already synced
environment. The target: the whole of ``make test`` under 10 minutes on the 2-core machine.

    .venv/bin/python experiments/bench_suite.py [--runs 3] [--jobs 2]
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from pathlib import Path

from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)

import numpy as np

from twin.benchio import update_benchmark_section

ROOT = Path(__file__).resolve().parent.parent
TARGET_S = 600.0


def _counts(out: str) -> dict[str, int]:
    tail = out.strip().splitlines()[-1] if out.strip() else ""
    return {k: int(v) for v, k in re.findall(r"(\d+) (passed|failed|xfailed|xpassed|skipped|errors?)", tail)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--jobs", type=int, default=2, help="pytest-xdist workers (make test: one per core)")
    a = ap.parse_args()
    if a.runs < 1:
        raise SystemExit(f"--runs must be >= 1, got {a.runs}")
    env = {**os.environ, "MUJOCO_GL": "egl", "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    t = time.perf_counter()
    subprocess.run(["make", "install"], cwd=ROOT, check=True, capture_output=True, env=env)
    install_s = time.perf_counter() - t
    runs = []
    for _ in range(a.runs):
        load0 = [round(x, 2) for x in os.getloadavg()]
        t = time.perf_counter()
        p = subprocess.run([sys.executable, "-m", "pytest", "-q", "-n", str(a.jobs), "--dist", "worksteal", "-p",
                            "no:cacheprovider"],
                           cwd=ROOT, capture_output=True, text=True, env=env)
        wall = time.perf_counter() - t
        runs.append({"wall_s": round(wall, 1), "exit_code": p.returncode, "counts": _counts(p.stdout),
                     "load_average_start": load0, "load_average_end": [round(x, 2) for x in os.getloadavg()]})
        print(runs[-1], flush=True)
    walls = [r["wall_s"] for r in runs]
    data = {
        "command": f"pytest -q -n {a.jobs} --dist worksteal (make test after make install)",
        "jobs": a.jobs,
        "runs": runs,
        "wall_s_range": [min(walls), float(np.median(walls)), max(walls)],
        "make_install_synced_s": round(install_s, 1),
        "target_s": TARGET_S,
        "target": "make test (install + suite) <= 10 min wall on the 2-core machine",
        "note": "wall_s_range: min, median, max of the runs; load averages (1, 5, 15 min) at each run's start and end",
    }
    update_benchmark_section("suite", data)
    return 0 if all(r["exit_code"] == 0 for r in runs) else 1


if __name__ == "__main__":
    sys.exit(main())
