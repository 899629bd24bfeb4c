"""Regression bands: run a campaign config for N seeds and record each statistic's mean and spread.

    python studies/separation_paper/regression_bands.py studies/separation_paper/separation_ci.toml --seeds 20 --section separation_ci
    python studies/separation_paper/regression_bands.py experiments/separation.toml --seeds 20 --section separation

Writes (replaces) one section of studies/separation_paper/results/regression.json, with this command in it. Runs the seeds on local
processes (--workers) or a Dask cluster (--dask ADDRESS); per-seed campaigns go to --work (resumable).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))

from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)

from twin.benchio import command_line, provenance  # noqa: E402
from twin.evaluation.regression import bands_from_repeats, update_regression_file  # noqa: E402
from twin.runner.campaign import run_repeats  # noqa: E402
from twin.runner.config import load_campaign_config  # noqa: E402
from twin.runner.executor import open_executor  # noqa: E402

BANDS = HERE / "results" / "regression.json"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("config")
    p.add_argument("--seeds", type=int, default=20, help="number of seeds (the config's seed and the next ones)")
    p.add_argument("--section", required=True, help="section name in studies/separation_paper/results/regression.json")
    p.add_argument("--quick", action="store_true")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--dask", default=None)
    p.add_argument("--work", default=str(HERE / "work"), help="folder for the per-seed campaigns (default: the study's work/)")
    p.add_argument("--out", default=str(BANDS), help="regression file (default: the study's results/regression.json)")
    a = p.parse_args()
    load_start = os.getloadavg()
    cfg = load_campaign_config(a.config, quick=a.quick)
    seeds = [cfg.seed + k for k in range(a.seeds)]
    kind = "dask" if a.dask else "process"
    with open_executor(kind, a.workers, a.dask) as ex:
        rep = run_repeats(cfg, Path(a.work) / a.section, seeds, ex,
                          progress=lambda ph, d, n: print(f"{ph}: {d}/{n}", flush=True))
    command = command_line("python", sys.argv)
    data = bands_from_repeats(rep, command, a.config)
    data["provenance"] = provenance(load_start)
    path = update_regression_file(a.section, data, a.out)
    print(f"wrote section {a.section!r} of {path}")
    for claim, e in rep["orderings"].items():
        print(f"  {claim}: holds in {e['holds']}/{e['n']} seeds")
    for claim, e in data["orderings_literal"].items():
        print(f"  {claim} (paper-literal separation): holds in {e['holds']}/{e['n']} seeds")
    return 0


if __name__ == "__main__":
    sys.exit(main())
