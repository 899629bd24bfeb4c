"""Benchmark of the world's image formation: seconds per full-resolution stereo pair with sensor noise,
next to MuJoCo's bare ``Renderer.update_scene`` + ``Renderer.render()`` for the same scene and cameras, with
one sample per pixel, with ``render.supersample = 2`` (2 x 2 samples per pixel) and with
``render.window_supersample = 4`` (1 sample per pixel, 4 x 4 in windows along the sphere outlines and over the
board), and the instrument's ``measure_pair`` on each rendered pair (render + measure against the bare render).

Writes the ``world`` section of ``results/benchmark.json``. Bare and full renders are interleaved so that
load from other processes on the machine hits both alike; figures are medians (and minima, the least
disturbed runs), with the 1-minute load average recorded. Ratios are to the bare render of the output size
(what one sample per pixel costs MuJoCo); for supersampling the bare render of the sampling grid (2x the
width and height) is timed as well.

    .venv/bin/python experiments/bench_world.py [--repeats 10] [--board-views 6]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)
import mujoco
from twin.benchio import update_benchmark_section
from twin.instrument import StereoCalibration, measure_pair
from twin.world import World


def _stats(x: list[float]) -> dict:
    return {"median": round(float(np.median(x)), 4), "min": round(float(np.min(x)), 4), "all": [round(v, 4) for v in x]}


def _bench(world: World, q: np.ndarray, repeats: int, bare_scales: tuple[int, ...] = (1,)) -> dict:
    """World.render_pair against MuJoCo's bare renderer at ``bare_scales`` times the image size, interleaved;
    plus the instrument's measure_pair on the rendered pair (exact calibration: only its time is used here)."""
    world.capture(q, 0, record=False)  # warm-up: creates the world's renderer, uploads textures
    w, h = world.image_size
    renderers = {s: mujoco.Renderer(world.model, s * h, s * w) for s in bare_scales}  # MuJoCo's own renderer
    world.place(q, 0)
    for r in renderers.values():
        world.render_bare(r)  # warm-up
    bare: dict[int, list[float]] = {s: [] for s in bare_scales}
    full, measure = [], []
    il, ir = world.true_intrinsics()
    cal = StereoCalibration(il, ir, world.true_left2right(), 0.0, 0.0, 0.0)
    for _ in range(repeats):
        for s, r in renderers.items():
            t = time.perf_counter()
            world.render_bare(r)
            bare[s].append(time.perf_counter() - t)
        t = time.perf_counter()
        left, right = world.render_pair(q, 0)
        full.append(time.perf_counter() - t)
        t = time.perf_counter()
        measure_pair(left, right, cal, world.nominal_plate)
        measure.append(time.perf_counter() - t)
    world.truth_poses.clear()
    for r in renderers.values():
        r.close()
    r = world.config.render
    out = {"supersample": r.supersample, "window_supersample": r.window_supersample, "pair_s": _stats(full),
           "measure_pair_s": _stats(measure)}
    for s in bare_scales:
        out[f"bare_pair_s_{s}x"] = _stats(bare[s])
    b1 = bare[1]
    out["ratio_to_bare_1x"] = round(float(np.median(full) / np.median(b1)), 3)
    out["ratio_of_min_to_bare_1x"] = round(float(np.min(full) / np.min(b1)), 3)
    both = np.array(full) + np.array(measure)
    out["render_plus_measure_ratio_to_bare_1x"] = round(float(np.median(both) / np.median(b1)), 3)
    return out


def _board_pair_s(world: World, n: int) -> float:
    t = time.perf_counter()
    views = world.render_board_views(n, seed=0)
    return round((time.perf_counter() - t) / len(views), 4)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--board-views", type=int, default=6)
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
    out["board_view_pair_s"] = _board_pair_s(w, args.board_views)
    w.close()

    t = time.perf_counter()
    w = World.from_config({**base, "render": {"supersample": 2}})  # the default camera, 2 x 2 samples per pixel
    out["build_world_s_supersample_2"] = round(time.perf_counter() - t, 3)
    out["supersample_2"] = _bench(w, q, args.repeats, bare_scales=(1, 2))
    out["board_view_pair_s_supersample_2"] = _board_pair_s(w, args.board_views)
    w.close()

    t = time.perf_counter()
    w = World.from_config({**base, "render": {"window_supersample": 4}})  # the default camera, 4 x 4 in windows
    out["build_world_s_windows_4"] = round(time.perf_counter() - t, 3)
    out["windows_4"] = _bench(w, q, args.repeats)
    out["board_view_pair_s_windows_4"] = _board_pair_s(w, args.board_views)
    w.close()
    t = time.perf_counter()
    # make run's setting: 4 x 4 in the windows over a frame at one sample per 2 x 2 pixels
    w = World.from_config({**base, "render": {"window_supersample": 4, "frame_subsample": 2}})
    out["build_world_s_windows_4_frame_2"] = round(time.perf_counter() - t, 3)
    out["windows_4_frame_2"] = _bench(w, q, args.repeats)
    out["board_view_pair_s_windows_4_frame_2"] = _board_pair_s(w, args.board_views)
    w.close()
    d1, d2 = out["noise_and_distortion"], out["supersample_2"]
    out["windows_4_over_1"] = {"median": round(out["windows_4"]["pair_s"]["median"] / d1["pair_s"]["median"], 3),
                               "min": round(out["windows_4"]["pair_s"]["min"] / d1["pair_s"]["min"], 3)}
    out["target_render_plus_measure_ratio_windows"] = 1.0
    out["supersample_2_over_1"] = {"median": round(d2["pair_s"]["median"] / d1["pair_s"]["median"], 3),
                                   "min": round(d2["pair_s"]["min"] / d1["pair_s"]["min"], 3)}
    out["load_average_1min_at_end"] = round(os.getloadavg()[0], 2)
    out["note"] = ("pair_s: World.render_pair (kinematics, render both cameras, grey, distortion remap in float32, "
                   "with supersampling 2x2 block means, Gaussian noise, 8-bit rounding, truth of the pose); "
                   "bare_pair_s_Nx: Renderer.update_scene + Renderer.render() for both cameras of the same scene at N "
                   "times the image width and height; ratio_to_bare_1x: pair_s over the bare render of the output size; "
                   "measure_pair_s: the instrument on that pair; render_plus_measure_ratio_to_bare_1x: "
                   "(pair_s + measure_pair_s) over the bare render, medians; windows_4: 4 x 4 samples per pixel in "
                   "the target windows; windows_4_frame_2: the same over a frame rendered at one sample per 2 x 2 "
                   "pixels (make run's setting)")
    path = update_benchmark_section("world", out)
    for k in ("noise_only", "noise_and_distortion", "supersample_2", "windows_4", "windows_4_frame_2"):
        d = out[k]
        extra = f", bare 2x {d['bare_pair_s_2x']['median']:.3f} s" if "bare_pair_s_2x" in d else ""
        print(f"{k}: {d['pair_s']['median']:.3f} s/pair vs bare {d['bare_pair_s_1x']['median']:.3f} s/pair "
              f"(ratio {d['ratio_to_bare_1x']:.2f}; of minima {d['ratio_of_min_to_bare_1x']:.2f}){extra}")
    print(f"supersample 2 / 1: {out['supersample_2_over_1']}; board view pair {out['board_view_pair_s']:.3f} s "
          f"(supersample 2: {out['board_view_pair_s_supersample_2']:.3f} s); written to {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
