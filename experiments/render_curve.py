"""What the target windows' sampling buys and costs: time per stereo pair against the instrument's accuracy, for
window supersampling and frame subsampling around make run's setting.

For each setting (``window_supersample`` S, ``frame_subsample`` k; everything else make run's world,
experiments/separation.toml), ``--per-station`` visible configurations at each station (seed 11, the same for
every setting) are rendered ``--noise`` times each with different noise seeds (the same for every setting) and
measured by the instrument with the world's *true* cameras (so that only image formation differs between
settings): per pair the process CPU time (every thread) and wall time of ``World.capture``, and the 3-D error
of each measured sphere centre against the truth (RMS, median and max [mm]; the RMS of a few hundred centres
moves by ~10 % from one set of noise seeds to another: a few hard spheres dominate it). Writes the
``render_curve`` section of results/benchmark.json with the load average. The
estimated stereo calibration adds its own error on top (the campaign's ``instrument_on_dataset``).

    .venv/bin/python experiments/render_curve.py [--per-station 15] [--noise 2]
"""

from __future__ import annotations

import argparse
import os
import time
import tomllib
from pathlib import Path

from twin.runtime import set_process_defaults  # noqa: E402
from twin.units import MM_PER_M  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
SETTINGS = [(4, 2), (4, 4), (3, 2), (3, 4), (2, 4), (1, 1)]  # (window_supersample, frame_subsample); (1, 1): no windows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-station", type=int, default=15)
    ap.add_argument("--noise", type=int, default=2, help="noise realizations per configuration")
    a = ap.parse_args()
    if a.per_station < 1 or a.noise < 1:
        raise SystemExit(f"--per-station and --noise must be >= 1, got {a.per_station}, {a.noise}")
    from twin.benchio import update_benchmark_section
    from twin.instrument import StereoCalibration, measure_pair
    from twin.world import World

    raw = tomllib.loads((ROOT / "experiments" / "separation.toml").read_text())
    base = dict(raw["world"])
    base.setdefault("seed", raw["seed"])
    make_run = base.get("render", {})
    load0 = [round(x, 2) for x in os.getloadavg()]
    rows = []
    qs = None
    for ws, k in SETTINGS:
        render = {**make_run, "window_supersample": ws if ws > 1 else 0, "frame_subsample": k}
        w = World.from_config({"world": {**base, "render": render}})
        if qs is None:
            qs = [(st, q) for st in range(len(w.station_names))
                  for q in w.visible_configurations(st, a.per_station, seed=11)]
        il, ir = w.true_intrinsics()
        cal = StereoCalibration(il, ir, w.true_left2right(), 0.0, 0.0, 0.0)
        w.capture(qs[0][1], qs[0][0], record=False, noise_seed=0)  # warm-up: renderer, textures
        cpu = wall = 0.0
        err = []
        n = 0
        for r in range(a.noise):
            for i, (st, q) in enumerate(qs):
                c0, t0 = time.process_time(), time.perf_counter()
                cap = w.capture(q, st, record=False, noise_seed=1000 * (r + 1) + i)
                cpu += time.process_time() - c0
                wall += time.perf_counter() - t0
                n += 1
                m = measure_pair(cap.left, cap.right, cal, w.nominal_plate)
                err += [np.linalg.norm(np.asarray(c) - p) * MM_PER_M for c, p in zip(m.centres, cap.spheres_meas)
                        if c is not None]
        w.close()
        e = np.array(err)
        rows.append({"window_supersample": ws if ws > 1 else 0, "frame_subsample": k, "pairs": n,
                     "make_run": render == make_run, "pair_cpu_s": round(cpu / n, 4),
                     "pair_wall_s": round(wall / n, 4), "spheres": int(e.size),
                     "sphere_error_mm": {"rms": round(float(np.sqrt(np.mean(e**2))), 5),
                                         "median": round(float(np.median(e)), 5), "max": round(float(e.max()), 4)}})
        print(rows[-1], flush=True)
    update_benchmark_section("render_curve", {
        "settings": rows, "per_station": a.per_station, "noise_realizations": a.noise, "load_average_at_start": load0,
        "load_average_at_end": [round(x, 2) for x in os.getloadavg()],
        "note": "sphere_error_mm: 3-D error of the instrument's sphere centres against the truth with the world's "
                "true cameras (image formation only); pair times of World.capture (CPU: every thread); "
                "window_supersample 0: no windows, the whole frame at one sample per pixel"})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
