"""The rig as placed: stations and camera mounts deviate from the nominal rig by seeded placement errors."""

import json

import numpy as np
import pytest

from twin.runner.campaign import run_campaign
from twin.runner.config import parse_campaign_config
from twin.dataset import read_dataset
from twin.camera import mujoco_to_opencv_cam2world
from twin.transforms import rotation_angle_between
from twin.world import World
from twin.world.rig import camera2rig, station_rig2world

from _campaign_helpers import SMALL_TOML

BASE = {"preset": "separation_tables_2_4", "seed": 3, "render": {"scale": 0.25}}


STATIONS = [{"name": "front", "target_mm": [500, 0, 550], "elevation_deg": 5},
            {"name": "left", "target_mm": [420, 220, 450], "azimuth_deg": 35, "elevation_deg": 10}]
ZERO = {"placement_sigma_mm": 0, "placement_sigma_deg": 0, "camera_mount_sigma_mm": 0, "camera_mount_sigma_deg": 0}


def _offsets(tol: dict | None, seeds=(3,), stations=STATIONS) -> tuple[np.ndarray, np.ndarray]:
    """Translation [m] and rotation [rad] ``(seeds, stations, 2)`` of each true camera (both cameras of every
    station of a world per seed) from where the nominal rig puts it, in the lab frame."""
    rig = {} if tol is None else dict(tol)
    dt = np.zeros((len(seeds), len(stations), 2))
    dr = np.zeros_like(dt)
    for i, seed in enumerate(seeds):
        w = World.from_config({"world": {**BASE, "seed": seed, "rig": rig, "stations": stations}})
        try:
            for k, st in enumerate(w.config.stations):
                rig2world = station_rig2world(st, w.config.rig)
                for c, (c2r, true_c2w) in enumerate(zip(camera2rig(w.config.rig), w.true_cam2world(k))):  # OpenCV axes
                    T = rig2world @ c2r
                    nominal = mujoco_to_opencv_cam2world(T[:3, 3], T[:3, :3].reshape(9))
                    dt[i, k, c] = np.linalg.norm(true_c2w[:3, 3] - nominal[:3, 3])
                    dr[i, k, c] = rotation_angle_between(true_c2w[:3, :3], nominal[:3, :3])
        finally:
            w.close()
    return dt, dr


def _chi2_band(dof: int) -> tuple[float, float]:
    from scipy.stats import chi2

    return float(chi2.ppf(0.0005, dof)), float(chi2.ppf(0.9995, dof))


SEEDS = tuple(range(10))
FAN = [{"name": f"s{k}", "target_mm": [500, 0, 550], "azimuth_deg": -60 + 15 * k, "elevation_deg": 5} for k in range(9)]


def test_default_rig_tolerances_are_the_documented_ones():
    """By default a station is placed within 3 mm / 0.2 deg and a camera mounted within 0.2 mm / 0.05 deg (1 sigma
    per axis), as docs/world.md states."""
    w = World.from_config({"world": BASE})
    try:
        rc = w.config.rig
        assert (rc.placement_sigma, np.degrees(rc.placement_sigma_rot)) == pytest.approx((3e-3, 0.2))
        assert (rc.camera_mount_sigma, np.degrees(rc.camera_mount_sigma_rot)) == pytest.approx((0.2e-3, 0.05))
    finally:
        w.close()


@pytest.mark.parametrize("source", ["station_translation", "station_rotation", "mount_translation", "mount_rotation"])
def test_each_placement_error_has_its_stated_size(source):
    """Each placement error alone (the others zero), over 10 seeds: the cameras' offsets from the nominal rig are
    the stated per-axis Gaussian. Oracle (independent of the world's code): a station's translation error moves
    both of its cameras by |t| with |t|^2 / sigma^2 ~ chi2(3), its rotation turns both by |w| with |w|^2 / sigma^2
    ~ chi2(3); a camera's mount error moves or turns that camera alike at every station. The sum over the
    independent draws lies in its chi-square distribution's central 99.9 % (a correct world passes for 999 seed sets
    in 1000; with these seeds a sigma 25 % too large fails each of the four)."""
    key, sigma, angle = {"station_translation": ("placement_sigma_mm", 3e-3, False),
                         "station_rotation": ("placement_sigma_deg", np.radians(0.2), True),
                         "mount_translation": ("camera_mount_sigma_mm", 0.2e-3, False),
                         "mount_rotation": ("camera_mount_sigma_deg", np.radians(0.05), True)}[source]
    tol = {**ZERO, key: sigma * 1e3 if not angle else np.degrees(sigma)}
    # 90 station draws (10 seeds x 9 stations), or 60 camera draws (30 seeds x 2 cameras)
    dt, dr = _offsets(tol, SEEDS, FAN) if source.startswith("station") else _offsets(tol, tuple(range(30)), STATIONS)
    x = dr if angle else dt
    other = dt if angle else dr
    if source.startswith("station"):
        np.testing.assert_allclose(x[..., 0], x[..., 1], rtol=1e-9)  # both cameras of a station move alike
        draws = x[..., 0]  # one draw per station and seed
    else:
        np.testing.assert_allclose(x, x[:, :1, :].repeat(x.shape[1], axis=1), rtol=1e-9)  # alike at every station
        draws = x[:, 0, :]  # one draw per camera and seed
    lo, hi = _chi2_band(3 * draws.size)
    s = float(np.sum((draws / sigma) ** 2))
    assert lo < s < hi, (source, s, lo, hi)
    if angle and source == "mount_rotation":
        assert other.max() < 1e-12  # a camera turned on its mount stays where it was
    elif not angle:
        assert other.max() < 1e-12  # a translation turns nothing


def test_zero_tolerances_place_the_rig_as_configured():
    """With all placement tolerances at zero the true cameras are the nominal ones."""
    dt, dr = _offsets(ZERO)
    assert dt.max() < 1e-12 and dr.max() < 1e-9


def test_rig_tolerances_are_validated():
    """A negative or implausibly large placement tolerance is a ValueError naming the key."""
    for key, bad in (("placement_sigma_mm", -1.0), ("placement_sigma_deg", 10.0), ("camera_mount_sigma_mm", "x")):
        with pytest.raises(ValueError, match=key):
            World.from_config({"world": {**BASE, "rig": {key: bad}}})


def test_estimator_reaches_its_floor_with_the_rig_placed_with_error(tmp_path):
    """With the rig placed with error (nominal station frames off by mm and tenths of a degree), the default
    estimator compensates as well as with an exactly placed rig (same seed, paper's measurement noise)."""
    import tomllib

    after = {}
    for name, tol in (("exact", {"placement_sigma_mm": 0, "placement_sigma_deg": 0, "camera_mount_sigma_mm": 0,
                                  "camera_mount_sigma_deg": 0}), ("placed", {})):
        raw = tomllib.loads(SMALL_TOML)
        raw["methods"] = ["default"]
        raw["world"]["rig"].update(tol)
        run = run_campaign(parse_campaign_config(raw), tmp_path / name)
        stated = read_dataset(tmp_path / name / "dataset").stations_base2meas
        truth = json.loads((tmp_path / name / "truth.json").read_text())["stations"]
        off_mm = max(np.linalg.norm(np.array(t["base2meas"])[:3, 3] - stated[t["name"]][:3, 3]) * 1e3 for t in truth)
        assert (off_mm > 0.5) if name == "placed" else (off_mm < 1e-6), off_mm  # the dataset states the nominal rig
        m = run.results["methods"]["default"]["measured"]
        after[name] = (m["angle_deg"]["after"]["mean"], m["position_mm"]["after"]["mean"])
    # the measurement noise sets the floor: both runs see the same noise draws on (nearly) the same poses
    assert after["placed"][0] <= 1.3 * after["exact"][0] and after["placed"][1] <= 1.3 * after["exact"][1], after


def test_camera_pipeline_makes_its_remap_tables_at_first_use_and_exactly_distortion_maps(monkeypatch):
    """A camera pipeline builds without making its remap tables; its first use makes distortion_maps' tables on its
    grid, bit for bit, once (None for the ideal camera)."""
    import twin.world.render as render
    from twin.camera import CameraIntrinsics
    from twin.world.rig import distortion_maps, render_focal_px

    made = []
    monkeypatch.setattr(render, "distortion_maps", lambda *a: made.append(a) or distortion_maps(*a))
    intr = CameraIntrinsics(330.0, 331.0, 162.0, 118.5, 320, 240, (-0.08, 0.02, 1e-4, -2e-4, 0.0))
    pipe = render.CameraPipeline.build("left", intr, supersample=2)
    assert made == [] and not pipe.ideal
    ref = distortion_maps(render.sampling_intrinsics(intr, 2), 2 * render_focal_px(intr))
    assert all(np.array_equal(m, r) and m.dtype == r.dtype for m, r in zip(pipe.maps, ref))
    assert pipe.maps is pipe.maps and len(made) == 1
    ideal = render.CameraPipeline.build("right", CameraIntrinsics.ideal(320, 240, 40.0))
    assert ideal.ideal and ideal.maps is None
