"""Time stereo pairs of a campaign config's world: the ``World`` API any version of twin has, so that the same
pairs can be timed with the code of another commit (``experiments/profile_render.py --against REV`` runs this
file with that commit's tree first on the import path).

Prints one JSON line: seconds per pair of process CPU time (every thread: llvmpipe's rasteriser threads
included) and of wall time, over ``--pairs`` visible configurations spread over the config's stations (seed 0,
the first pair rendered once beforehand: renderer start-up and textures), the 1/5/15-minute load average at the
start and the end, and the config's render table.

    .venv/bin/python experiments/time_pairs.py experiments/separation.toml [--pairs 12]
"""

from __future__ import annotations

import argparse
import json
import os
import time
import tomllib
from pathlib import Path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("config", type=Path, help="campaign config (TOML): its [world] table and seed")
    ap.add_argument("--pairs", type=int, default=12)
    a = ap.parse_args()
    if a.pairs < 1:
        raise SystemExit(f"--pairs must be >= 1, got {a.pairs}")
    if not a.config.is_file():
        raise SystemExit(f"config {a.config} is not a file")
    # twin.runtime.PROCESS_DEFAULTS, spelled out: an earlier commit's twin may lack that module
    for var, value in (("MUJOCO_GL", "egl"), ("OPENBLAS_NUM_THREADS", "1"), ("OMP_NUM_THREADS", "1"),
                       ("MKL_NUM_THREADS", "1")):
        os.environ.setdefault(var, value)  # before numpy or mujoco load
    from twin.world import World

    raw = tomllib.loads(a.config.read_text())
    world = dict(raw["world"])
    world.setdefault("seed", raw.get("seed", 0))
    load0 = [round(x, 2) for x in os.getloadavg()]
    w = World.from_config({"world": world})
    n_st = len(w.station_names)
    qs = [(k, q) for k in range(n_st) for q in w.visible_configurations(k, -(-a.pairs // n_st), seed=0)][:a.pairs]
    w.capture(qs[0][1], qs[0][0], record=False, noise_seed=0)
    c0, t0 = time.process_time(), time.perf_counter()
    for i, (k, q) in enumerate(qs):
        w.capture(q, k, record=False, noise_seed=1000 + i)
    cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    w.close()
    print(json.dumps({"pairs": len(qs), "pair_cpu_s": round(cpu / len(qs), 4), "pair_wall_s": round(wall / len(qs), 4),
                      "load_average_start": load0, "load_average_end": [round(x, 2) for x in os.getloadavg()],
                      "render": world.get("render", {})}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
