"""`make run` with the current code against an earlier commit's, back to back: campaign time and CPU time.

On a machine shared with other jobs a campaign's wall time depends on what they take; two codes compared in
turn, each run a fresh campaign in a fresh process, see the same conditions. Each round runs the campaign of
commit REV (its tree extracted from git into a temporary folder, its own experiments/separation.toml, this
environment's packages) and the current one (the same command on this tree), alternately, into temporary output
folders. Per run: the campaign time (``timings_s.total_s`` of its results.json), the command's wall time, the
CPU time (user + system) of the command and its worker processes, and the 1/5/15-minute load average at its
start and end. Writes the ``campaign_comparison`` section of results/benchmark.json: the runs, the medians per
code and their ratios.

    .venv/bin/python experiments/compare_campaign.py --against 9b4e55f [--rounds 2]
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

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def _campaign(tree: Path, out: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    env.setdefault("MUJOCO_GL", "egl")
    load0 = [round(x, 2) for x in os.getloadavg()]
    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "twin.cli", "campaign", "experiments/separation.toml", "--out", str(out),
                    "--restart"], check=True, cwd=tree, env=env, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    r = json.loads((out / "results.json").read_text())
    return {"campaign_total_s": round(r["timings_s"]["total_s"], 2), "command_wall_s": round(wall, 2),
            "command_cpu_s": round((ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime), 1),
            "measurements": r["counts"]["poses"] + r["counts"]["compensated_measurements"],
            "load_average_start": load0, "load_average_end": [round(x, 2) for x in os.getloadavg()]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", required=True, help="the earlier commit")
    ap.add_argument("--rounds", type=int, default=2)
    a = ap.parse_args()
    if a.rounds < 1:
        raise SystemExit(f"--rounds must be >= 1, got {a.rounds}")
    from twin.benchio import alternate_with_commit, update_benchmark_section

    sha, head, runs = alternate_with_commit(a.against, a.rounds, lambda tree, scratch: _campaign(tree, scratch / "out"),
                                            ROOT)
    keys = ("campaign_total_s", "command_wall_s", "command_cpu_s")
    med = {code: {k: float(np.median([r[k] for r in runs if r["code"] == code])) for k in keys}
           for code in (sha, "current")}
    update_benchmark_section("campaign_comparison", {
        "against": sha, "current": head, "rounds": a.rounds, "runs": runs, "median": med,
        "ratio_current_to_against": {k: round(med["current"][k] / med[sha][k], 3) for k in keys},
        "note": "each code's own experiments/separation.toml, fresh campaigns alternating, this environment's "
                "packages; command_cpu_s: user + system time of the command and its worker processes"})
    print(json.dumps(med), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
