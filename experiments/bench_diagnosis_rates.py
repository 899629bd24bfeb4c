"""Benchmark of the diagnosis' pass rates: every seed of the costly rate tests, against the rate each one states.

A rate test claims an outcome on at least k of n seeds (``tests/_diagnosis_helpers.py``, ``tally``). The suite runs
two seeds of the costly ones as a regression (``rate_seeds``); this benchmark runs the test files that use
``rate_seeds`` with every seed (``TWIN_FULL_RATES=1``), where each test asserts its stated rate, and writes the
``diagnosis_rates`` section of ``results/benchmark.json``: per test its rule, what all the seeds gave, whether the rule
holds, the seeds the suite runs and whether they pass there, the seeds that miss; the pytest outcome (a failed test is
listed), the wall time and the load averages.

    .venv/bin/python experiments/bench_diagnosis_rates.py [--jobs 2]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)

from twin.benchio import update_benchmark_section  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
TESTS = ROOT / "tests"


def rate_files() -> list[str]:
    """The test files with costly rate tests (those that call ``rate_seeds`` or run more cases under
    ``FULL_RATES``), relative to the repository."""
    return sorted(str(p.relative_to(ROOT)) for p in TESTS.glob("test_*.py")
                  if "rate_seeds(" in p.read_text() or "FULL_RATES" in p.read_text())


def _holds(rule: list, got) -> bool:
    if rule[0] == "median<=":
        return got <= rule[1]
    k, of = rule
    return got[1] == of and got[0] >= k


def _suite_passes(rule: list, seeds: list[dict], name: str) -> bool:
    """Whether the suite's seeds pass the rule as the suite applies it (``tally`` on fewer seeds than the rate's)."""
    vals = [s[name] for s in seeds]
    if rule[0] == "median<=":
        vals = sorted(vals)
        m = len(vals)
        return (vals[m // 2] if m % 2 else 0.5 * (vals[m // 2 - 1] + vals[m // 2])) <= rule[1]
    k, of = rule
    return sum(bool(v) for v in vals) >= len(vals) - (of - k) * len(vals) // of


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2, help="pytest-xdist workers")
    a = ap.parse_args()
    if a.jobs < 1:
        raise SystemExit(f"--jobs must be >= 1, got {a.jobs}")
    files = rate_files()
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "MUJOCO_GL": "egl", "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
               "TWIN_FULL_RATES": "1", "TWIN_RATES_DIR": tmp}
        cmd = [sys.executable, "-m", "pytest", "-q", "-n", str(a.jobs), "--dist", "worksteal", "-p", "no:cacheprovider",
               "-rfE", *files]
        load0 = [round(x, 2) for x in os.getloadavg()]
        t = time.perf_counter()
        p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, env=env)
        wall = time.perf_counter() - t
        load1 = [round(x, 2) for x in os.getloadavg()]
        records = [json.loads(line) for f in sorted(Path(tmp).glob("*.jsonl")) for line in f.read_text().splitlines()]
    tail = p.stdout.strip().splitlines()[-1] if p.stdout.strip() else ""
    counts = {k: int(v) for v, k in re.findall(r"(\d+) (passed|failed|xfailed|xpassed|skipped|errors?)", tail)}
    failed = sorted(set(re.findall(r"^(?:FAILED|ERROR) (\S+)", p.stdout, flags=re.M)))
    tests = {}
    for r in sorted(records, key=lambda r: r["test"]):
        ns = [rule[1] for rule in r["need"].values() if rule[0] != "median<="]
        bools = [k for k, rule in r["need"].items() if rule[0] != "median<="]
        holds = all(_holds(r["need"][k], r["got"][k]) for k in r["need"])
        picked = r["suite_seeds"]  # the seeds the suite runs where they are fewer (else every one, as here)
        suite = [s for s in r["seeds"] if s.get("seed", s.get("case")) in picked] if picked else r["seeds"]
        tests[r["test"]] = {
            "rule": {k: (f"median <= {v[1]}" if v[0] == "median<=" else f">= {v[0]}/{v[1]}")
                     for k, v in r["need"].items()},
            "got": {k: (round(v, 4) if isinstance(v, float) else f"{v[0]}/{v[1]}") for k, v in r["got"].items()},
            "holds": holds,
            "all_seeds_run": not ns or len(r["seeds"]) == max(ns),
            "suite_seeds": [s.get("seed", s.get("case")) for s in suite],
            "suite_seeds_pass": all(_suite_passes(r["need"][k], suite, k) for k in r["need"]),
            "misses": [{"seed": s.get("seed", s.get("case")), "false": [k for k in bools if not s[k]]}
                       for s in r["seeds"] if not all(s[k] for k in bools)],
        }
    data = {
        "command": "TWIN_FULL_RATES=1 pytest -q -n {} --dist worksteal {}".format(a.jobs, " ".join(files)),
        "jobs": a.jobs,
        "wall_s": round(wall, 1),
        "exit_code": p.returncode,
        "counts": counts,
        "failed": failed,
        "load_average_start": load0,
        "load_average_end": load1,
        "n_rate_tests": len(tests),
        "n_rates_hold": sum(t["holds"] for t in tests.values()),
        "tests": tests,
        "note": "per test: its rule over every seed ('>= k/n' seeds true, or a median bound), what the seeds gave, "
                "whether the rule holds; suite_seeds: the seeds the suite runs as a regression (every one must pass "
                "there); misses: the seeds where an outcome counted by a rate is false; xfail tests are recorded as "
                "they ran; load averages (1, 5, 15 min) at start and end",
    }
    update_benchmark_section("diagnosis_rates", data)
    print(f"{data['n_rates_hold']}/{len(tests)} rates hold; pytest exit {p.returncode}: {tail}")
    for f in failed:
        print("FAILED", f)
    return 0 if p.returncode == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
