"""Start-up of the command line -> the ``cli`` section of results/benchmark.json.

Target: ``twin --help`` and an argument error in <= 0.5 s (heavy imports deferred to the
subcommand that needs them). Median of ``--runs`` fresh processes each.

    python experiments/bench_cli.py [--runs 7]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)

import numpy as np

from twin.benchio import update_benchmark_section

TARGET_S = 0.5


def _time(cmd: list[str], runs: int) -> dict:
    wall = []
    for _ in range(runs):
        t = time.perf_counter()
        subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        wall.append(time.perf_counter() - t)
    return {"median_s": float(np.median(wall)), "max_s": float(np.max(wall)), "runs_s": wall}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    exe = shutil.which("twin", path=str(Path(sys.executable).parent)) or "twin"
    data = {
        "target": f"twin --help and an argument error <= {TARGET_S} s",
        "help": _time([exe, "--help"], args.runs),
        "argument_error": _time([exe, "calibrate"], args.runs),
        "load_average_1_5_15": list(os.getloadavg()),
    }
    data["meets_target"] = bool(max(data["help"]["median_s"], data["argument_error"]["median_s"]) <= TARGET_S)
    print(f"twin --help {data['help']['median_s']:.3f} s, argument error {data['argument_error']['median_s']:.3f} s "
          f"(target {TARGET_S} s)")
    if not args.no_write:
        update_benchmark_section("cli", data)
    return 0


if __name__ == "__main__":
    sys.exit(main())
