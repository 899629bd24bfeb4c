"""Which Python the environment is built on, by measurement: the CPU the same work takes, and whether its results are
the same bits, under each candidate interpreter.

For each interpreter a throwaway virtual environment is built with uv from the lock's own pins (``uv export``) and
this checkout installed editable; each runs the same test modules (pytest, one process) in alternating rounds, so
that machine load hits all alike, then the same drawn instances once (``studies.drawn.run``, one worker); the CPU
seconds (user + system) of each run are recorded, and the drawn instances' results, without their timings, compared
across interpreters (``drawn_results_identical``). Written: ``studies/environment/results/interpreters.json``.

    .venv/bin/python studies/environment/interpreters.py --pythons /usr/bin/python3 OTHER_PYTHON [--rounds 2]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)

from twin.benchio import provenance  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
UV = ROOT / ".tools" / "bin" / "uv"
TESTS = ["tests/test_diagnosis_changes.py", "tests/test_diagnosis_atoms.py"]
DRAWN = ["--families", "payload,thermal,backlash_load,compliance,zero_glitch,clean", "--seeds", "1100-1101"]
# the keys of a drawn run's results that hold its timings, machine and command, left out of the comparison
TIMING_KEYS = frozenset({"cpu_s", "cpu_s_job", "cpu_s_jobs", "wall_s", "seconds", "provenance", "command"})

_DESCRIBE = ("import json, sys, sysconfig; print(json.dumps({'version': sys.version.split()[0], "
             "'implementation': sys.implementation.name, 'prefix_is_system': sysconfig.get_config_var('prefix') == '/usr'}))")


def _env_for(python: str, scratch: Path, k: int) -> Path:
    """A virtual environment on ``python`` with the lock's pins (``scratch/req.txt``) and this checkout (editable);
    returns its python."""
    venv = scratch / f"env{k}"
    subprocess.run([str(UV), "venv", "-q", "--python", python, str(venv)], check=True)
    env = {**os.environ, "VIRTUAL_ENV": str(venv)}
    subprocess.run([str(UV), "pip", "install", "-q", "-r", str(scratch / "req.txt")], check=True, env=env)
    subprocess.run([str(UV), "pip", "install", "-q", "--no-deps", "-e", str(ROOT)], check=True, env=env)
    return venv / "bin" / "python"


def _cpu_of(cmd: list[str], env: dict) -> float:
    """Run ``cmd`` in the repository; the CPU seconds (user + system) it and its children took."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(cmd, cwd=ROOT, env=env, check=True, capture_output=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def _without_timings(x):
    if isinstance(x, dict):
        return {k: _without_timings(v) for k, v in x.items() if k not in TIMING_KEYS}
    if isinstance(x, list):
        return [_without_timings(v) for v in x]
    return x


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pythons", nargs="+", required=True, help="interpreters to compare (paths or names)")
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()
    if len(args.pythons) < 2:
        raise SystemExit(f"--pythons needs at least two interpreters, got {args.pythons}")
    if args.rounds < 1:
        raise SystemExit(f"--rounds must be >= 1, got {args.rounds}")
    load0 = os.getloadavg()
    env = {**os.environ, "MUJOCO_GL": "egl", "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
           "PYTHONPATH": str(ROOT)}
    out: dict = {"tests": TESTS, "drawn": " ".join(DRAWN) + " --workers 1", "rounds": args.rounds, "interpreters": []}
    for p in args.pythons:
        if shutil.which(p) is None:
            raise SystemExit(f"--pythons: {p!r} is not an interpreter found on this machine")
    with tempfile.TemporaryDirectory() as tmp:
        req = subprocess.run([str(UV), "export", "--frozen", "--all-extras", "--no-hashes", "--no-emit-project"],
                             cwd=ROOT, check=True, capture_output=True, text=True).stdout
        (Path(tmp) / "req.txt").write_text(req)
        pys = [_env_for(p, Path(tmp), k) for k, p in enumerate(args.pythons)]
        runs: list[dict] = []
        for py in pys:
            desc = json.loads(subprocess.run([str(py), "-c", _DESCRIBE], check=True, capture_output=True,
                                             text=True).stdout)
            runs.append({**desc, "tests_cpu_s": [], "drawn_cpu_s": []})
        drawn_results = []
        for r in range(args.rounds):
            for py, rec in zip(pys, runs):
                rec["tests_cpu_s"].append(round(_cpu_of([str(py), "-m", "pytest", "-q", "-p", "no:cacheprovider",
                                                         *TESTS], env), 2))
        for k, (py, rec) in enumerate(zip(pys, runs)):
            dest = Path(tmp) / f"drawn{k}"
            rec["drawn_cpu_s"].append(round(_cpu_of([str(py), "-m", "studies.drawn.run", *DRAWN, "--workers", "1",
                                                     "--out", str(dest)], env), 2))
            drawn_results.append(_without_timings(json.loads((dest / "results.json").read_text())))
    for rec in runs:
        rec["tests_cpu_s_median"] = round(statistics.median(rec["tests_cpu_s"]), 2)
    base = runs[0]["tests_cpu_s_median"]
    for rec in runs:
        rec["tests_cpu_relative_to_first"] = round(rec["tests_cpu_s_median"] / base, 3)
    out["interpreters"] = runs
    out["drawn_results_identical"] = all(d == drawn_results[0] for d in drawn_results[1:])
    out["provenance"] = provenance(load0)
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / "interpreters.json").write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps({r["version"] + (" (system)" if r["prefix_is_system"] else ""): r["tests_cpu_s_median"]
                      for r in runs}), "drawn results identical:", out["drawn_results_identical"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
