"""Benchmark of the instrument: 3D sphere-centre error, plate orientation error and time per pair.

Protocol: the twin (MuJoCo, full 2592 x 1944 resolution, Gaussian sensor noise of 2 grey levels) renders
its ChArUco board views; the instrument calibrates the rig from them; the twin renders plate poses from all
its stations (plate 500-1000 mm from the cameras, spread over the field of view); the instrument measures
them. Truth comes from the world's API (this is an experiment: it may read truth). Every figure is given
with and without the perspective-bias (cone) correction and with the estimated and the exact calibration,
so the error budget is visible:

* ``raw``: error in the true left-camera frame;
* ``aligned``: after one rigid transform common to all poses and stations. An estimated rig defines its
  measurement frame only up to a small rotation (a principal-point error of 0.3 px turns it by 0.002 deg,
  0.03 mm at 700 mm); the estimator's ``base2meas`` absorbs exactly this, so ``aligned`` is what the
  calibration of the robot sees.

Three more rows separate the instrument from the renderer: ``what_if_msaa4`` (the same with MuJoCo's 4x
multisampling, offsamples = 4), ``what_if_supersampled_2x2`` (the twin renders 2x2 samples per pixel,
averaged like a real sensor's pixel integrates light, then the same noise) and ``analytic`` (the same poses
and board views drawn by the analytic ray tracer of ``twin.instrument.synthetic``: exact, anti-aliased
sphere outlines).

The main ``world`` row renders with the twin's target windows (``--window-supersample``, default 3: 3 x 3
samples per pixel in windows along the sphere outlines and around the board's corners, over a frame at one
sample per 4 x 4 pixels (``--frame-subsample``), what ``make run`` renders);
``world_full_frame`` is the same scene at one sample per pixel everywhere.
``--render-supersample N`` renders the main ``world`` row with the twin's own ``render.supersample = N``
(N x N samples per pixel, distortion on the sampling grid, block means, then noise).

Usage: ``python experiments/bench_instrument.py [--per-station 15] [--render-supersample 2] [--no-msaa] [--no-analytic]``
"""

from __future__ import annotations

import argparse
import os
import time

import cv2
import numpy as np

from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)
from twin.benchio import update_benchmark_section
from twin.camera import CameraIntrinsics
from twin.instrument import (
    BoardSpec,
    StereoCalibration,
    calibrate_stereo,
    measure_pair,
    paper_frame_from_spheres,
    plate_pose_from_spheres,
)
from twin.instrument.synthetic import add_sensor_noise, render_board, render_spheres
from twin.transforms import matrix_to_rotvec, rotation_angle_between
from twin.units import MM_PER_M, UM_PER_M, rad_to_deg
from twin.world import World

TARGETS = {
    "sphere_rms_mm": 0.010,
    "sphere_max_mm": 0.030,
    "orientation_mean_deg": 0.005,
    "orientation_max_deg": 0.015,
    "time_per_pair_ms": 100.0,
    "prototype_with_exact_intrinsics": {"corrected_rms_mm": 0.004, "uncorrected_rms_mm": 0.031},
}


def _rigid(X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Best rotation R and translation t with ``R X + t ~ Y`` (Kabsch)."""
    mx, my = X.mean(0), Y.mean(0)
    U, _, Vt = np.linalg.svd((Y - my).T @ (X - mx))
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    return R, my - R @ mx


def _stats(v: np.ndarray, unit_scale: float) -> dict:
    v = np.asarray(v) * unit_scale
    return {"rms": float(np.sqrt(np.mean(v**2))), "mean": float(np.mean(v)), "max": float(np.max(v)), "n": int(v.size)}


def _evaluate(meas: list, truth_sph: list, truth_tool: list, plate) -> dict:
    """Figures for one (calibration, correction) combination over the complete poses."""
    keep = [k for k, m in enumerate(meas) if m is not None]
    X = np.concatenate([meas[k] for k in keep])
    Y = np.concatenate([truth_sph[k] for k in keep])
    R, t = _rigid(X, Y)
    Xa = X @ R.T + t
    out = {
        "poses": len(keep),
        "sphere_error_mm": {"raw": _stats(np.linalg.norm(X - Y, axis=1), MM_PER_M),
                            "aligned": _stats(np.linalg.norm(Xa - Y, axis=1), MM_PER_M)},
        "frame_alignment": {"rotation_deg": float(rad_to_deg(np.linalg.norm(matrix_to_rotvec(R)))),
                            "translation_mm": float(np.linalg.norm(t) * MM_PER_M)},
    }
    # shape only: pairwise sphere distances (free of any frame)
    dist_err = []
    ori_raw, ori_al, paper_raw, paper_al = [], [], [], []
    for k in keep:
        m, s = meas[k], truth_sph[k]
        for i, j in ((0, 1), (0, 2), (1, 2)):
            dist_err.append(abs(np.linalg.norm(m[i] - m[j]) - np.linalg.norm(s[i] - s[j])))
        fit = plate_pose_from_spheres(m, plate)
        ori_raw.append(rotation_angle_between(fit.tool2meas[:3, :3], truth_tool[k][:3, :3]))
        ori_al.append(rotation_angle_between(R @ fit.tool2meas[:3, :3], truth_tool[k][:3, :3]))
        pm, pt = paper_frame_from_spheres(m), paper_frame_from_spheres(s)
        paper_raw.append(rotation_angle_between(pm[:3, :3], pt[:3, :3]))
        paper_al.append(rotation_angle_between(R @ pm[:3, :3], pt[:3, :3]))
    out["distance_error_mm"] = _stats(np.array(dist_err), MM_PER_M)
    out["plate_orientation_error_deg"] = {"raw": _stats(rad_to_deg(ori_raw), 1.0), "aligned": _stats(rad_to_deg(ori_al), 1.0)}
    out["paper_frame_orientation_error_deg"] = {"raw": _stats(rad_to_deg(paper_raw), 1.0),
                                                "aligned": _stats(rad_to_deg(paper_al), 1.0)}
    return out


def _calibration_errors(cal: StereoCalibration, il, ir, l2r) -> dict:
    return {
        "rms_px": cal.rms_px,
        "rms_left_px": cal.rms_left_px,
        "rms_right_px": cal.rms_right_px,
        "views_used": cal.n_views_used,
        "views_rejected": {v.name: v.reason for v in cal.views if not v.used},
        "focal_error_px": [cal.left.fx - il.fx, cal.left.fy - il.fy, cal.right.fx - ir.fx, cal.right.fy - ir.fy],
        "principal_point_error_px": [cal.left.cx - il.cx, cal.left.cy - il.cy, cal.right.cx - ir.cx, cal.right.cy - ir.cy],
        "baseline_error_mm": (cal.baseline - float(np.linalg.norm(l2r[:3, 3]))) * MM_PER_M,
        "left2right_rotation_error_deg": float(rad_to_deg(np.linalg.norm(matrix_to_rotvec(cal.left2right[:3, :3] @ l2r[:3, :3].T)))),
    }


def _measure_all(pairs, truth_sph, truth_tool, calibs: dict, plate, intr_true, l2r, record_time: bool) -> dict:
    """Measure every pair with each calibration; figures per calibration x correction, flags, pixel bias."""
    res: dict = {}
    times_wall, times_cpu = [], []
    for name, cal in calibs.items():
        corr, unc, flags = [], [], {}
        px_c, px_u = [], []
        for (left, right), s in zip(pairs, truth_sph):
            c0 = time.process_time()
            m = measure_pair(left, right, cal, plate)
            c1 = time.process_time()
            if record_time and name == "estimated":
                times_wall.append(m.time_s)
                times_cpu.append(c1 - c0)
            for r in m.reasons:
                if r:
                    flags[r] = flags.get(r, 0) + 1
            corr.append(m.centres_array() if m.complete else None)
            unc.append(np.stack(m.centres_uncorrected) if m.complete else None)
            if m.complete and name == "exact":
                from twin.camera import project_points

                uvl = project_points(s, np.eye(4), intr_true[0])
                uvr = project_points(s, l2r, intr_true[1])
                for k in range(3):
                    px_c += [m.left[k].centre_px - uvl[k], m.right[k].centre_px - uvr[k]]
                    px_u += [m.left[k].centre_px_uncorrected - uvl[k], m.right[k].centre_px_uncorrected - uvr[k]]
        res[name] = {
            "bias_corrected": _evaluate(corr, truth_sph, truth_tool, plate),
            "uncorrected": _evaluate(unc, truth_sph, truth_tool, plate),
            "flags": flags,
        }
        if px_c:
            pc, pu = np.array(px_c), np.array(px_u)
            res[name]["image_centre_error_px"] = {
                "bias_corrected": {"mean_xy": pc.mean(0).tolist(), "rms": float(np.sqrt((pc**2).sum(1).mean()))},
                "uncorrected": {"mean_xy": pu.mean(0).tolist(), "rms": float(np.sqrt((pu**2).sum(1).mean()))},
            }
    if record_time:
        tw, tc = np.array(times_wall) * 1e3, np.array(times_cpu) * 1e3
        res["time_per_pair_ms"] = {
            "wall": {"median": float(np.median(tw)), "p90": float(np.percentile(tw, 90)), "max": float(tw.max())},
            "cpu": {"median": float(np.median(tc)), "p90": float(np.percentile(tc, 90)), "max": float(tc.max())},
            "what": "detection of both images + matching + triangulation + labelling (measure_pair), full resolution",
        }
    return res


def _scaled_back(c: CameraIntrinsics, s: int) -> CameraIntrinsics:
    """Intrinsics of an image area-downsampled ``s`` times (pixel centres at integers)."""
    return CameraIntrinsics(c.fx / s, c.fy / s, (c.cx + 0.5) / s - 0.5, (c.cy + 0.5) / s - 0.5, c.width // s, c.height // s, c.dist)


def run_world(per_station: int, seed: int, msaa: int = 0, supersample: int = 1, depth_range=(0.5, 1.0),
              render_supersample: int = 1, window_supersample: int = 0, frame_subsample: int = 1) -> tuple[dict, dict]:
    """Render with the twin, calibrate from its board views, measure; returns (figures, scene for reuse).

    ``supersample`` > 1 is a what-if: the twin renders a sensor with ``supersample`` times the pixels (same
    optics) without noise, each image is averaged down (``cv2.INTER_AREA``, i.e. every pixel integrates
    ``supersample**2`` samples, like a real sensor integrates light) and then gets the 2 grey levels of
    noise and 8-bit rounding."""
    cfg: dict = {"seed": seed}
    if render_supersample > 1:
        cfg["render"] = {"supersample": render_supersample}  # the twin's own supersampling
    if window_supersample > 0:
        # the twin's target windows: 1 sample per pixel, window_supersample**2 along sphere outlines and boards
        cfg.setdefault("render", {})["window_supersample"] = window_supersample
        if frame_subsample > 1:  # the frame under the windows at one sample per k x k pixels
            cfg["render"]["frame_subsample"] = frame_subsample
    if supersample > 1:
        rig = World.from_config({"seed": seed}).config.rig
        cfg["rig"] = {"width_px": rig.width_px * supersample, "height_px": rig.height_px * supersample,
                      "pixel_um": rig.pixel_size * UM_PER_M / supersample}
        cfg["render"] = {"noise_sigma": 0.0}
    w = World.from_config(cfg)
    rng = np.random.default_rng([seed, 99])

    def img(a: np.ndarray) -> np.ndarray:
        if supersample == 1:
            return a
        d = cv2.resize(a.astype(np.float32), (a.shape[1] // supersample, a.shape[0] // supersample), interpolation=cv2.INTER_AREA)
        return add_sensor_noise(d, 2.0, rng)

    if msaa:
        # what-if: MuJoCo's multisampling of the offscreen buffer; must be set before the first render
        # creates the GL context (the world reads model.vis.quality when it builds its renderer)
        w.model.vis.quality.offsamples = msaa
    t0 = time.perf_counter()
    views = w.render_board_views()
    board = BoardSpec.from_table(w.rig_info()["board"])
    cal = calibrate_stereo([(img(v.left), img(v.right)) for v in views], board, names=[f"{v.index:03d}" for v in views])
    t_cal = time.perf_counter() - t0
    il, ir = (_scaled_back(c, supersample) for c in w.true_intrinsics())
    l2r = w.true_left2right()
    exact = StereoCalibration(il, ir, l2r, 0.0, 0.0, 0.0)
    pairs, sph, tool, stations, depths = [], [], [], [], []
    for st in range(w.n_stations):
        qs = w.visible_configurations(st, per_station * 2, seed=seed + 7, spread_mm=(60, 45, 300))
        n_st = 0
        for q in qs:
            z = w.true_spheres_meas(q, st)[:, 2]
            if not (depth_range[0] <= z.min() and z.max() <= depth_range[1]):
                continue
            cap = w.capture(q, st)
            pairs.append((img(cap.left), img(cap.right)))
            sph.append(cap.spheres_meas)
            tool.append(cap.tool2meas)
            stations.append(st)
            depths.append(float(z.mean()))
            n_st += 1
            if n_st >= per_station:
                break
    figures = _measure_all(pairs, sph, tool, {"estimated": cal, "exact": exact}, w.nominal_plate, (il, ir), l2r, True)
    figures["calibration"] = _calibration_errors(cal, il, ir, l2r)
    figures["calibration"]["time_s"] = t_cal
    figures["scene"] = {
        "poses": len(pairs),
        "stations": {w.station_names[s]: stations.count(s) for s in sorted(set(stations))},
        "depth_mm": {"min": min(depths) * MM_PER_M, "median": float(np.median(depths)) * MM_PER_M, "max": max(depths) * MM_PER_M},
        "image_size": [il.width, il.height],
        "noise_sigma_grey": 2.0,
        "samples_per_pixel": supersample**2 * render_supersample**2,
        "render_supersample": render_supersample,
        "window_supersample": window_supersample,
        "frame_subsample": frame_subsample if window_supersample > 0 else 1,
        "board_views": len(views),
        "offsamples": msaa,
    }
    scene = {"sph": sph, "tool": tool, "intr": (il, ir), "l2r": l2r, "plate": w.nominal_plate,
             "board2meas": [v.board2meas for v in views], "board": board}
    w.close()
    return figures, scene


def run_analytic(scene: dict, seed: int, max_poses: int) -> dict:
    """The same geometry drawn by the analytic ray tracer (exact, anti-aliased outlines), noise 2 levels."""
    rng = np.random.default_rng(seed)
    il, ir = scene["intr"]
    l2r = scene["l2r"]
    cvb = scene["board"].cv_board()
    boards = []
    for b2m in scene["board2meas"]:
        boards.append((add_sensor_noise(render_board(il, b2m, cvb, black=5, white=150, surround=8), 2.0, rng),
                       add_sensor_noise(render_board(ir, l2r @ b2m, cvb, black=5, white=150, surround=8), 2.0, rng)))
    cal = calibrate_stereo(boards, scene["board"])
    pairs = []
    sph = scene["sph"][:max_poses]
    tool = scene["tool"][:max_poses]
    light = (-0.6, -0.4, -0.7)  # towards the upper left and the camera, like the twin's key light
    for s in sph:
        pairs.append((add_sensor_noise(render_spheres(il, np.eye(4), s, 0.0127, background=12, supersample=3, light_dir=light), 2.0, rng),
                      add_sensor_noise(render_spheres(ir, l2r, s, 0.0127, background=12, supersample=3,
                                                      light_dir=l2r[:3, :3].T @ np.array(light)), 2.0, rng)))
    exact = StereoCalibration(il, ir, l2r, 0.0, 0.0, 0.0)
    fig = _measure_all(pairs, sph, tool, {"estimated": cal, "exact": exact}, scene["plate"], (il, ir), l2r, False)
    fig["calibration"] = _calibration_errors(cal, il, ir, l2r)
    fig["scene"] = {"poses": len(pairs), "board_views": len(boards), "renderer": "twin.instrument.synthetic (ray traced, 3x3 supersampled)"}
    return fig


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--per-station", type=int, default=15, help="plate poses per station (4 stations)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--render-supersample", type=int, default=1,
                    help="the twin's render.supersample for the main world row (samples per pixel along each axis)")
    ap.add_argument("--window-supersample", type=int, default=3,
                    help="the twin's render.window_supersample for the main world row (0: no windows); the row "
                         "'world_full_frame' renders the same scene without windows")
    ap.add_argument("--frame-subsample", type=int, default=4,
                    help="with windows: the frame at one sample per k x k pixels (make run's setting: 4)")
    ap.add_argument("--no-msaa", action="store_true", help="skip the 4x multisampling what-if")
    ap.add_argument("--no-supersample", action="store_true", help="skip the 2x2 supersampled-rendering what-if")
    ap.add_argument("--no-analytic", action="store_true", help="skip the analytic-renderer row")
    ap.add_argument("--analytic-poses", type=int, default=30)
    ap.add_argument("--out", default=None, help="benchmark file (default results/benchmark.json)")
    args = ap.parse_args()
    t0 = time.perf_counter()
    load0 = os.getloadavg()
    world, scene = run_world(args.per_station, args.seed, render_supersample=args.render_supersample,
                             window_supersample=args.window_supersample, frame_subsample=args.frame_subsample)
    section = {"protocol": __doc__.split("\n\n")[1].replace("\n", " "), "targets": TARGETS, "world": world}
    if args.window_supersample > 0:
        section["world_full_frame"], _ = run_world(args.per_station, args.seed,
                                                   render_supersample=args.render_supersample)
    if not args.no_msaa:
        section["what_if_msaa4"], _ = run_world(args.per_station, args.seed, msaa=4)
    if not args.no_supersample:
        section["what_if_supersampled_2x2"], _ = run_world(args.per_station, args.seed, supersample=2)
    if not args.no_analytic:
        section["analytic"] = run_analytic(scene, args.seed, args.analytic_poses)
    section["load_average_1min"] = {"start": load0[0], "end": os.getloadavg()[0]}
    section["runtime_s"] = time.perf_counter() - t0
    path = update_benchmark_section("instrument", section, args.out)
    est = world["estimated"]["bias_corrected"]
    print(f"written {path}; estimated calibration, corrected: raw RMS {est['sphere_error_mm']['raw']['rms']:.4f} mm, "
          f"aligned RMS {est['sphere_error_mm']['aligned']['rms']:.4f} mm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
