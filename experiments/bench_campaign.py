"""Benchmark of the end-to-end pipeline (`make run`): wall time per phase, per-pose costs, recording size.

    python experiments/bench_campaign.py                      # runs experiments/separation.toml afresh (~5 min)
    python experiments/bench_campaign.py --from results/separation/results.json   # records an existing run

Writes the `campaign` section of results/benchmark.json (twin.benchio.update_benchmark_section), with the
machine's load average, since the figure depends on what else the 2 cores are doing.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from twin.benchio import update_benchmark_section


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", default="experiments/separation.toml")
    p.add_argument("--out", default="/scratch/bench_campaign")
    p.add_argument("--from", dest="from_", default=None, help="record this results.json instead of running")
    a = p.parse_args()
    load_before = os.getloadavg()
    if a.from_:
        res_path = Path(a.from_)
        wall = None
    else:
        t = time.perf_counter()
        subprocess.run([sys.executable, "-m", "twin.cli", "campaign", a.config, "--out", a.out, "--restart"], check=True)
        wall = time.perf_counter() - t
        res_path = Path(a.out) / "results.json"
    r = json.loads(res_path.read_text())
    n_meas = r["counts"]["poses"] + r["counts"]["compensated_measurements"]
    sums = r["worker_time_sums_s"]
    data = {
        "config": r["config"].get("name"),
        "results": str(res_path),
        "command_wall_s": wall,
        "campaign_total_s": r["timings_s"]["total_s"],
        "phases_s": r["timings_s"],
        "measurements": n_meas,
        "per_measurement_s": {k: v / n_meas for k, v in sums.items()},
        "recording_mb": r.get("recording_mb"),
        "recording_mb_per_100_poses": (r["recording_mb"] / r["counts"]["poses"] * 100) if r.get("recording_mb") else None,
        "load_average_1_5_15": r.get("machine", {}).get("load_average_start", list(load_before)),
        "load_average_end": r.get("machine", {}).get("load_average_end"),
        "target": "make run <= 300 s on 2 cores; recording < 200 MB per 100 poses",
    }
    update_benchmark_section("campaign", data)
    print(json.dumps(data, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
