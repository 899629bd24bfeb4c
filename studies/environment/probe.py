"""Render probe run inside one environment: hashes and times of ``make run``'s render setting.

Prints one JSON line: the MuJoCo version, a sha256 over the rendered stereo pairs of fixed configurations,
and the seconds per ``World.render_pair`` (``window_supersample = 4``, ``frame_subsample = 2``, as make run).
Called by ``mujoco_versions.py`` once per environment and round; not meant to be run alone.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time

from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)
import mujoco
from twin.world import World


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=6)
    args = ap.parse_args()
    w = World.from_config({"preset": "separation_tables_2_4", "seed": 1,
                           "render": {"window_supersample": 4, "frame_subsample": 2}})
    qs = w.visible_configurations(0, args.pairs, seed=3)
    w.render_pair(qs[0], 0)  # warm-up: renderer, textures
    h = hashlib.sha256()
    times = []
    for q in qs:
        t = time.perf_counter()
        left, right = w.render_pair(q, 0)
        times.append(time.perf_counter() - t)
        h.update(left.tobytes())
        h.update(right.tobytes())
    w.close()
    print(json.dumps({"mujoco": mujoco.__version__, "images_sha256": h.hexdigest(), "pair_s": times}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
