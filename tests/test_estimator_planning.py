"""Measurement planning: visibility rules, D-optimal selection against random choice, the camera file, the CLI."""

import json

import numpy as np
import pytest
from scipy.optimize import minimize

from twin.camera import CameraIntrinsics
from twin.cli import main
from twin.dataset import default_plate, read_joints_csv
from twin.robots import irb1200
from twin.transforms import make_transform, pose6_to_transform
from twin.estimator.planning import (
    PlanOptions,
    StereoCamera,
    _seg_seg_distance,
    candidate_pool,
    plan_measurements,
    visibility,
)


def _camera():
    """Left camera looking along its +z; right camera 250 mm to its right, turned towards it so that the
    optical axes cross 700 mm in front of the left camera."""
    f = 7272.7
    intr = CameraIntrinsics(f, f, 1295.5, 971.5, 2592, 1944)
    phi = np.arctan2(0.25, 0.7)
    c, s = np.cos(phi), np.sin(phi)
    right2left_R = np.array([[c, 0, -s], [0, 1, 0], [s, 0, c]])  # right's +z is (-s, 0, c) in the left frame
    T = np.eye(4)
    T[:3, :3] = right2left_R.T
    T[:3, 3] = -right2left_R.T @ np.array([0.25, 0.0, 0.0])
    return StereoCamera(intr, intr, T)


def _station():
    """A camera 700 mm in front of the point (500, 0, 550) mm of the IRB-1200's base frame, looking back at it
    (OpenCV axes: z towards the robot, y down)."""
    target = np.array([0.5, 0.0, 0.55])
    cam_pos = target + np.array([0.7, 0.0, 0.0])
    z = -np.array([1.0, 0, 0])
    y = np.array([0, 0, -1.0])
    x = np.cross(y, z)
    cam2base = make_transform(np.stack([x, y, z], axis=1), cam_pos)
    return np.linalg.inv(cam2base)


def test_segment_distance_matches_brute_force():
    """Closest distance between segments equals a dense brute-force search."""
    rng = np.random.default_rng(0)
    for _ in range(30):
        p0, p1, q0, q1 = rng.normal(size=(4, 3))
        t = np.linspace(0, 1, 401)
        P = p0 + t[:, None] * (p1 - p0)
        Q = q0 + t[:, None] * (q1 - q0)
        D = np.linalg.norm(P[:, None] - Q[None], axis=-1)
        i, j = np.unravel_index(np.argmin(D), D.shape)
        # polish the grid minimum with a bounded local search (the distance is convex in (s, t))
        fun = lambda st: np.linalg.norm(p0 + st[0] * (p1 - p0) - q0 - st[1] * (q1 - q0))
        best = minimize(fun, [t[i], t[j]], bounds=[(0, 1), (0, 1)], method="L-BFGS-B", options={"ftol": 1e-15, "gtol": 1e-12}).fun
        d = _seg_seg_distance(p0, p1, q0, q1)
        assert abs(d - best) < 1e-7


def test_visibility_flags_out_of_image_and_facing_away():
    """Pool configurations are visible; out of the image, too much tilt and occlusion are flagged in order."""
    model, B, cam, plate = irb1200(), _station(), _camera(), default_plate()
    rng = np.random.default_rng(1)
    q = candidate_pool(model, B, cam, plate, 20, rng)
    assert q.shape[0] >= 10
    vis, why = visibility(model, q, B, cam, plate)
    assert vis.all()
    q_away = q[:1].copy()
    q_away[0, 0] += 0.6  # swing the arm sideways: out of the narrow field of view
    assert visibility(model, q_away, B, cam, plate)[1][0] == "image"
    # no plate normal points at both cameras exactly: with a (near) zero tilt allowance it fails the tilt rule
    assert visibility(model, q[:1], B, cam, plate, PlanOptions(max_tilt=np.deg2rad(1e-3)))[1][0] == "tilt"
    # a link between the cameras and the plate: a huge capsule radius makes every line of sight occluded
    assert visibility(model, q[:1], B, cam, plate, PlanOptions(link_radius=0.5))[1][0] == "occluded"


def test_plan_beats_random_choice_and_stays_visible():
    """The D-optimal plan's predicted RMS sphere error is below every random plan's of the same size; every
    chosen configuration passes the visibility rules."""
    model, B, cam, plate = irb1200(), _station(), _camera(), default_plate()
    res = plan_measurements(model, {"front": B}, cam, plate, 40, pool_per_station=250, n_random=15, seed=2)
    assert res.q.shape == (40, 6) and set(res.station) == {"front"}
    assert visibility(model, res.q, B, cam, plate)[0].all()
    finite = res.floor_random[np.isfinite(res.floor_random)]
    assert res.floor_plan < finite.min()
    assert len(res.identifiable) == 30 and set(res.dropped) == {"theta1", "alpha1", "a1", "d1", "theta6", "d6", "d2"}
    assert res.design["plan"]["logdet_scaled"] > res.design["random_median_logdet_scaled"]


def test_stereo_camera_reads_the_instruments_calibration_file(tmp_path):
    """The instrument's stereo_calibration.json (its own writer) is read as the plan's camera model."""
    from twin.instrument.calibration import StereoCalibration

    cam = _camera()
    sc = StereoCalibration(cam.left, cam.right, cam.left2right, 0.1, 0.1, 0.1)
    p = sc.save(tmp_path / "stereo_calibration.json")
    back = StereoCamera.from_json_dict(json.loads(p.read_text()))
    assert np.allclose(back.left2right, cam.left2right, atol=1e-12) and back.left.fx == cam.left.fx
    d = json.loads(p.read_text())
    d["kind"] = "something"
    with pytest.raises(ValueError, match="kind"):
        StereoCamera.from_json_dict(d)


def test_plan_command_from_a_camera_file_and_a_station(tmp_path, capsys):
    """twin plan with a hand-written stereo_camera JSON and one --station writes a JOINTS.csv with stations."""
    cam = _camera()
    d = {
        "kind": "stereo_camera", "image_width": 2592, "image_height": 1944,
        "left": {"fx_px": cam.left.fx, "fy_px": cam.left.fy, "cx_px": cam.left.cx, "cy_px": cam.left.cy},
        "right": {"fx_px": cam.right.fx, "fy_px": cam.right.fy, "cx_px": cam.right.cx, "cy_px": cam.right.cy},
        "left2right": {"R": cam.left2right[:3, :3].tolist(), "t_mm": (cam.left2right[:3, 3] * 1e3).tolist()},
    }
    (tmp_path / "cam.json").write_text(json.dumps(d))
    from twin.transforms import transform_to_pose6

    v = transform_to_pose6(_station())
    st = "front=" + ",".join(f"{x:.9f}" for x in np.r_[v[:3] * 1e3, v[3:]])
    assert main(["plan", "--robot", "irb1200", "--camera", str(tmp_path / "cam.json"), "--station", st, "--n", "30",
                 "--pool", "150", "--random", "5", "--out", str(tmp_path / "plan.csv")]) == 0
    j = read_joints_csv(tmp_path / "plan.csv")
    assert j.q.shape == (30, 6) and set(j.station) == {"front"}
    assert "predicted RMS error" in capsys.readouterr().out
    assert main(["plan", "--robot", "irb1200", "--n", "5", "--out", str(tmp_path / "x.csv")]) == 2
