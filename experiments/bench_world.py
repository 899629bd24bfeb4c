"""Benchmark of the world's image formation: seconds per full-resolution stereo pair with sensor noise,
next to MuJoCo's bare ``Renderer.update_scene`` + ``Renderer.render()`` for the same scene and cameras.

Writes the ``world`` section of ``results/benchmark.json``. Bare and full renders are interleaved so that
load from other processes on the machine hits both alike; figures are medians (and minima, the least
disturbed runs), with the 1-minute load average recorded.

    .venv/bin/python experiments/bench_world.py [--repeats 10]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

import twin  # noqa: F401  (MUJOCO_GL=egl before mujoco)
import mujoco
from twin.benchio import update_benchmark_section
from twin.world import World


def _bench(world: World, q: np.ndarray, repeats: int) -> dict:
    world.capture(q, 0, record=False)  # warm-up: creates the world's renderer, uploads textures
    w, h = world.image_size
    r = mujoco.Renderer(world.model, h, w)  # MuJoCo's own renderer on the same model and data
    world._place(q, 0)
    r.update_scene(world.data, camera=world._cam_ids[0], scene_option=world._opt_pairs)
    r.render()  # warm-up
    bare, full = [], []
    for _ in range(repeats):
        t = time.perf_counter()
        for cam in world._cam_ids:
            r.update_scene(world.data, camera=cam, scene_option=world._opt_pairs)
            r.render()
        bare.append(time.perf_counter() - t)
        t = time.perf_counter()
        world.render_pair(q, 0)
        full.append(time.perf_counter() - t)
    world.truth_poses.clear()
    r.close()
    b, f = float(np.median(bare)), float(np.median(full))
    bm, fm = float(np.min(bare)), float(np.min(full))
    return {"bare_pair_s": round(b, 4), "pair_s": round(f, 4), "ratio": round(f / b, 3),
            "bare_pair_s_min": round(bm, 4), "pair_s_min": round(fm, 4), "ratio_of_min": round(fm / bm, 3),
            "bare_pair_s_all": [round(x, 4) for x in bare], "pair_s_all": [round(x, 4) for x in full]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=10)
    args = ap.parse_args()
    base = {"preset": "separation_tables_2_4", "seed": 1}
    out: dict = {"image_size_px": [2592, 1944], "target_ratio": 1.5, "repeats": args.repeats,
                 "load_average_1min_at_start": round(os.getloadavg()[0], 2)}
    t = time.perf_counter()
    w = World.from_config({**base, "render": {"noise_sigma": 2.0, "distortion": [0, 0, 0, 0, 0], "principal_offset_px": [0, 0]}})
    out["build_world_s_ideal_camera"] = round(time.perf_counter() - t, 3)
    q = w.visible_configurations(0, 1, seed=0)[0]
    out["noise_only"] = _bench(w, q, args.repeats)
    w.close()
    t = time.perf_counter()
    w = World.from_config(base)  # default: noise + lens distortion + principal-point offsets (float remap)
    out["build_world_s_default"] = round(time.perf_counter() - t, 3)
    out["noise_and_distortion"] = _bench(w, q, args.repeats)
    t = time.perf_counter()
    views = w.render_board_views(6, seed=0)
    out["board_view_pair_s"] = round((time.perf_counter() - t) / len(views), 4)
    w.close()
    out["load_average_1min_at_end"] = round(os.getloadavg()[0], 2)
    out["note"] = ("pair_s: World.render_pair (kinematics, render both cameras, grey, distortion remap in float32, "
                   "Gaussian noise, 8-bit rounding, truth of the pose); bare_pair_s: Renderer.update_scene + "
                   "Renderer.render() for both cameras of the same scene")
    path = update_benchmark_section("world", out)
    for k in ("noise_only", "noise_and_distortion"):
        d = out[k]
        print(f"{k}: {d['pair_s']:.3f} s/pair vs bare {d['bare_pair_s']:.3f} s/pair (ratio {d['ratio']:.2f}; "
              f"minima {d['pair_s_min']:.3f} vs {d['bare_pair_s_min']:.3f}, ratio {d['ratio_of_min']:.2f})")
    print(f"board view pair: {out['board_view_pair_s']:.3f} s; written to {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
