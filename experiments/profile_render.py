"""Where `make run`'s time goes: a profile of one stereo pair at its render setting.

`make run` spends most of its campaign time rendering stereo pairs (section `campaign` of
results/benchmark.json: the phases). This profiles ``World.render_pair`` at make run's setting
(``window_supersample = 4``, ``frame_subsample = 2``) over ``--pairs`` visible configurations with cProfile and
writes the ``render_profile`` section: seconds per pair, and the share of the pair's time of each function that
takes >= 1 % of it (own time, the GL read-back standing for the GL work it waits for).

    .venv/bin/python experiments/profile_render.py [--pairs 12]
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import time

from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)
from twin.benchio import update_benchmark_section
from twin.world import World

SETTING = {"window_supersample": 4, "frame_subsample": 2}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=12)
    a = ap.parse_args()
    if a.pairs < 1:
        raise SystemExit(f"--pairs must be >= 1, got {a.pairs}")
    load0 = [round(x, 2) for x in os.getloadavg()]
    w = World.from_config({"preset": "separation_tables_2_4", "seed": 1, "render": SETTING})
    qs = w.visible_configurations(0, a.pairs, seed=0)
    w.render_pair(qs[0], 0)  # warm-up: renderer, textures
    prof = cProfile.Profile()
    t = time.perf_counter()
    prof.enable()
    for q in qs:
        w.render_pair(q, 0)
    prof.disable()
    total = time.perf_counter() - t
    w.close()
    st = pstats.Stats(prof)
    rows = []
    for (fname, line, func), (_, ncalls, tt, _, _) in st.stats.items():
        share = tt / total
        if share >= 0.01:
            where = os.path.basename(fname) if fname.startswith(("/", ".")) else fname
            rows.append({"function": f"{where}:{line}({func})" if line else func, "calls_per_pair": ncalls / a.pairs,
                         "own_s_per_pair": round(tt / a.pairs, 4), "share": round(share, 3)})
    rows.sort(key=lambda r: -r["share"])
    update_benchmark_section("render_profile", {
        "setting": SETTING, "pairs": a.pairs, "pair_s": round(total / a.pairs, 4), "functions": rows,
        "load_average_at_start": load0,
        "note": "cProfile own time per function over the pairs, share of the profiled wall time; the GL read-back "
                "(mjr_readPixels) waits for llvmpipe's rasterisation of the drawn scene"})
    for r in rows:
        print(f"{r['share']:6.1%}  {r['own_s_per_pair']:.4f} s  {r['function']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
