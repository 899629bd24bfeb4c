"""Benchmark of the test suite as CI runs it: the wall time of ``make test``'s pytest command, several runs.

Runs ``pytest -q -n JOBS --dist worksteal`` (the command of ``make test`` after its install step) ``--runs`` times and
writes the ``suite`` section of ``results/benchmark.json``: each run's wall time, CPU time (user + system of pytest and
every process it waited for: what the suite costs, less sensitive to other jobs than the wall time), test counts,
load average at its start and end and its slowest tests (``SLOWEST``, with the phase and seconds pytest's
``--durations`` reports), the range (min, median, max) over the runs, and the time of ``make install`` on the already
synced environment. The target: pytest within 300 s on an idle 2-core machine, so that a machine twice as slow keeps
``make test`` under CI's 10 minutes.

Two-core machines differ by twice or more, so a wall time alone does not say whether the suite grew or the machine
is slower. With ``--reference REV`` each run of the suite alternates with a run of the suite of the commit ``REV``
(its files by ``git archive``, run with this environment) on the same machine; the section then also records that
commit's own recorded run (its ``results/benchmark.json``), the ratio of its wall time here to its recorded one (the
machine's and the environment's speed against the machine that recorded it) and each run's wall time divided by
that ratio: the suite's time at the recording machine's speed. The reference's tests that fail here (golden files
made with other package versions) fail fast, so the ratio leans low and the scaled time high.

    .venv/bin/python experiments/bench_suite.py [--runs 3] [--jobs 2] [--reference REV]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import subprocess
import sys
import time
from pathlib import Path

from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)

import numpy as np

from twin.benchio import alternate_with_commit, update_benchmark_section

ROOT = Path(__file__).resolve().parent.parent
TARGET_S = 300.0
SLOWEST = 20  # the slowest tests (setup, call or teardown phases) recorded per run


def _counts(out: str) -> dict[str, int]:
    tail = out.strip().splitlines()[-1] if out.strip() else ""
    return {k: int(v) for v, k in re.findall(r"(\d+) (passed|failed|xfailed|xpassed|skipped|errors?)", tail)}


def _failed(out: str) -> list[str]:
    """The test ids of pytest's short summary's ``FAILED`` and ``ERROR`` lines."""
    return re.findall(r"^(?:FAILED|ERROR) (\S+)", out, flags=re.M)


def _slowest(out: str) -> list[dict]:
    """The ``--durations`` block of pytest's output: ``[{"test", "phase", "s"}]``, slowest first."""
    block = out.split("slowest", 1)[1] if "slowest" in out else ""
    return [{"test": t, "phase": ph, "s": float(sec)}
            for sec, ph, t in re.findall(r"^([0-9.]+)s (setup|call|teardown)\s+(\S+)", block, flags=re.M)]


def _pytest_run(tree: Path, jobs: int, env: dict) -> dict:
    """One run of the suite of the code in ``tree`` (pytest on ``jobs`` workers; a tree other than this checkout with
    its ``twin`` first on the path, this one as ``make test`` runs it): wall and CPU seconds, exit code, counts, the
    failed tests, load averages and the slowest tests."""
    venv = tree / ".venv"
    if not venv.exists() and (ROOT / ".venv").is_dir():
        venv.symlink_to(ROOT / ".venv")  # an archived tree's tests that call the environment's tools find them
    load0 = [round(x, 2) for x in os.getloadavg()]
    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "pytest", "-q", "-n", str(jobs), "--dist", "worksteal", "-p",
                        "no:cacheprovider", f"--durations={SLOWEST}"],
                       cwd=tree, capture_output=True, text=True,
                       env=env if tree == ROOT else {**env, "PYTHONPATH": str(tree)})
    wall = time.perf_counter() - t
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    return {"wall_s": round(wall, 1), "cpu_s": round(cpu, 1), "exit_code": p.returncode, "counts": _counts(p.stdout),
            "failed": _failed(p.stdout), "load_average_start": load0, "load_average_end": [round(x, 2) for x in os.getloadavg()],
            "slowest": _slowest(p.stdout)}


def _recorded_run(rev: str) -> dict:
    """The first suite run that commit ``rev``'s own ``results/benchmark.json`` records, with its date."""
    got = subprocess.run(["git", "show", f"{rev}:results/benchmark.json"], cwd=ROOT, capture_output=True, text=True)
    if got.returncode != 0:
        raise SystemExit(f"--reference {rev}: no results/benchmark.json at that commit ({got.stderr.strip()})")
    text = got.stdout
    suite = json.loads(text).get("suite")
    if not suite or not suite.get("runs"):
        raise SystemExit(f"--reference {rev}: its results/benchmark.json records no suite run")
    run = suite["runs"][0]
    return {"wall_s": run["wall_s"], "cpu_s": run.get("cpu_s"), "counts": run.get("counts"),
            "load_average_start": run.get("load_average_start"),
            "date": (suite.get("machine") or {}).get("date")}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--jobs", type=int, default=2, help="pytest-xdist workers (make test: one per core)")
    ap.add_argument("--reference", default=None,
                    help="a commit whose suite runs alternately with this one's, to scale the times to its machine")
    a = ap.parse_args()
    if a.runs < 1:
        raise SystemExit(f"--runs must be >= 1, got {a.runs}")
    recorded = None if a.reference is None else _recorded_run(a.reference)
    env = {**os.environ, "MUJOCO_GL": "egl", "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    t = time.perf_counter()
    subprocess.run(["make", "install"], cwd=ROOT, check=True, capture_output=True, env=env)
    install_s = time.perf_counter() - t
    reference = None
    if a.reference is None:
        runs = []
        for _ in range(a.runs):
            runs.append(_pytest_run(ROOT, a.jobs, env))
            print({k: v for k, v in runs[-1].items() if k != "slowest"}, flush=True)
    else:
        sha, _, both = alternate_with_commit(a.reference, a.runs, lambda tree, _scratch: _pytest_run(tree, a.jobs, env),
                                             ROOT)
        runs = [{k: v for k, v in r.items() if k != "code"} for r in both if r["code"] == "current"]
        here = [{k: v for k, v in r.items() if k not in ("code", "slowest")} for r in both if r["code"] == sha]
        ratio = float(np.median([r["wall_s"] for r in here])) / recorded["wall_s"]
        reference = {"commit": sha, "recorded": recorded, "runs_here": here, "wall_ratio_here_to_recorded": round(ratio, 3)}
        for r in runs:
            r["wall_s_at_reference_speed"] = round(r["wall_s"] / ratio, 1)
    walls = [r["wall_s"] for r in runs]
    data = {
        "command": f"pytest -q -n {a.jobs} --dist worksteal --durations={SLOWEST} (make test after make install)"
                   + (f"; alternated with the suite of {reference['commit']}" if reference else ""),
        "jobs": a.jobs,
        "runs": runs,
        "wall_s_range": [min(walls), float(np.median(walls)), max(walls)],
        "make_install_synced_s": round(install_s, 1),
        "target_s": TARGET_S,
        "target": "pytest <= 300 s wall on an idle 2-core machine (a machine twice as slow keeps make test under CI's "
                  "10 minutes)",
        "note": "wall_s_range: min, median, max of the runs; cpu_s: user + system seconds of pytest and its workers; "
                "load averages (1, 5, 15 min) at each run's start and end; "
                f"slowest: each run's {SLOWEST} slowest test phases (wall seconds, on the run's load)"
                + ("; reference: the suite of an earlier commit run here alternately (runs_here) against the run its "
                   "own benchmark recorded (recorded), the median ratio of their wall times (this machine and "
                   "environment against the recording one), and each run's wall_s_at_reference_speed = wall_s / "
                   "ratio" if reference else ""),
    }
    if reference:
        data["reference"] = reference
    update_benchmark_section("suite", data)
    return 0 if all(r["exit_code"] == 0 for r in runs) else 1


if __name__ == "__main__":
    sys.exit(main())
