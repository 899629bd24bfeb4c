"""``twin plan``: choose N measurement configurations that the cameras see and that identify the robot well,
and compare the plan's predicted calibration accuracy with random choice."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..units import M_PER_MM, MM_PER_M, deg_to_rad


HELP = "choose measurement configurations the cameras can see that identify the parameters well (D-optimal)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    src = p.add_argument_group("robot, cameras and stations (a campaign config, or the pieces)")
    src.add_argument("--campaign", default=None, help="campaign/world config TOML: robot, rig and [[world.stations]]")
    src.add_argument("--robot", default=None, help="robot name (e.g. irb1200) when no campaign/dataset gives it")
    src.add_argument("--dataset", default=None, help="dataset folder: robot, plate and stations' base2meas from its dataset.toml")
    src.add_argument("--camera", default=None,
                     help="stereo_calibration.json of the instrument, or a hand-written stereo_camera JSON (docs/estimator.md)")
    src.add_argument("--station", action="append", default=[], metavar="NAME=x_mm,y_mm,z_mm,rx_rad,ry_rad,rz_rad",
                     help="a station's approximate base2meas (repeat for several stations)")
    p.add_argument("--n", type=int, required=True, help="number of configurations to choose")
    p.add_argument("--out", required=True, help="JOINTS.csv to write (pose_id, q1..q6 [deg], station)")
    p.add_argument("--pool", type=int, default=600, help="visible candidates per station (default 600)")
    p.add_argument("--noise-mm", type=float, default=0.01, help="sphere-centre noise for the accuracy prediction")
    p.add_argument("--random", type=int, default=30, help="random plans to compare with (default 30)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--margin-px", type=float, default=20.0)
    p.add_argument("--max-tilt-deg", type=float, default=55.0)
    p.add_argument("--link-radius-mm", type=float, default=45.0)
    p.add_argument("--depth-mm", default=None, help="min,max distance of the plate from the left camera")
    p.add_argument("--report", default=None, help="also write the plan's numbers to this JSON file")


def _station_arg(text: str) -> tuple:
    import numpy as np

    from ..transforms import pose6_to_transform

    try:
        name, vals = text.split("=", 1)
        v = np.array([float(x) for x in vals.split(",")])
    except ValueError:
        raise ValueError(f"--station must be NAME=x_mm,y_mm,z_mm,rx_rad,ry_rad,rz_rad, got {text!r}") from None
    if v.shape != (6,) or not np.all(np.isfinite(v)):
        raise ValueError(f"--station {text!r}: need six finite numbers")
    return name, pose6_to_transform(np.r_[v[:3] * M_PER_MM, v[3:]])


def from_campaign(path: str):
    """Nominal robot, nominal stereo camera (no distortion, centred) and each station's nominal base2meas from a
    world config (stations are placed relative to the nominal robot base, which is the lab frame)."""
    from ..camera import CameraIntrinsics, mujoco_to_opencv_cam2world
    from ..estimator.planning import StereoCamera
    from ..transforms import invert_transform
    from ..world.config import load_world_config, nominal_robot_from_spec
    from ..world.rig import camera2rig, station_rig2world

    cfg = load_world_config(path)
    robot = nominal_robot_from_spec(cfg.robot)
    rig = cfg.rig
    f = rig.focal_px
    intr = CameraIntrinsics(f, f, rig.width_px / 2 - 0.5, rig.height_px / 2 - 0.5, rig.width_px, rig.height_px)
    left_mj, right_mj = camera2rig(rig)
    stations = {}
    left2right = None
    for st in cfg.stations:
        R2W = station_rig2world(st, rig)
        cams = []
        for cm in (left_mj, right_mj):
            T = R2W @ cm
            cams.append(mujoco_to_opencv_cam2world(T[:3, 3], T[:3, :3].reshape(-1)))
        stations[st.name] = invert_transform(cams[0])
        left2right = invert_transform(cams[1]) @ cams[0]
    return robot, StereoCamera(intr, intr, left2right), stations


def run(args) -> int:
    import numpy as np

    from ..dataset import Joints, default_plate, read_dataset, robot_from_spec, write_joints_csv
    from ..files import read_json
    from ..estimator.planning import PlanOptions, StereoCamera, plan_measurements

    robot = camera = None
    stations: dict[str, np.ndarray] = {}
    plate = default_plate()
    if args.campaign:
        robot, camera, stations = from_campaign(args.campaign)
    if args.dataset:
        ds = read_dataset(args.dataset)
        robot = ds.robot
        plate = ds.plate
        stations.update(ds.stations_base2meas)
    if args.robot:
        robot = robot_from_spec(args.robot, where="--robot")
    if args.camera:
        camera = StereoCamera.from_json_dict(read_json(args.camera), where=args.camera)
    for s in args.station:
        name, T = _station_arg(s)
        stations[name] = T
    if robot is None:
        raise ValueError("no robot: give --campaign, --dataset or --robot")
    if camera is None:
        raise ValueError("no camera model: give --campaign or --camera")
    if not stations:
        raise ValueError("no station: give --campaign, a --dataset whose dataset.toml has [stations], or --station")
    depth = None
    if args.depth_mm:
        try:
            a, b = (float(x) * M_PER_MM for x in args.depth_mm.split(","))
        except ValueError:
            raise ValueError(f"--depth-mm must be min,max in mm, got {args.depth_mm!r}") from None
        depth = (a, b)
    opts = PlanOptions(margin_px=args.margin_px, max_tilt=deg_to_rad(args.max_tilt_deg),
                       link_radius=args.link_radius_mm * M_PER_MM, depth=depth)
    res = plan_measurements(robot, stations, camera, plate, args.n, pool_per_station=args.pool,
                            noise_position=args.noise_mm * M_PER_MM, n_random=args.random, seed=args.seed,
                            options=opts, progress=print)
    write_joints_csv(args.out, Joints(pose_id=np.arange(len(res.q)), q=res.q, station=res.station), robot=robot)
    fr = res.floor_random
    finite = fr[np.isfinite(fr)]
    print(f"{len(res.identifiable)} identifiable parameters ({len(res.dropped)} not: {', '.join(res.dropped)})")
    print(f"chosen per station: " + ", ".join(f"{s}: {int(np.sum(res.station == s))}" for s in stations))
    print(f"predicted RMS error of the calibrated sphere predictions over the visible workspace at "
          f"{args.noise_mm:g} mm noise: plan {res.floor_plan * MM_PER_M:.4g} mm; random {args.n} "
          + (f"median {np.median(finite) * MM_PER_M:.4g} mm, best {finite.min() * MM_PER_M:.4g} mm" if finite.size else "")
          + (f", {int(np.sum(~np.isfinite(fr)))} of {fr.size} random plans cannot identify the parameters" if np.any(~np.isfinite(fr)) else ""))
    print(f"wrote {args.out}")
    if args.report:
        Path(args.report).write_text(json.dumps({
            "n": args.n, "pool": res.pool, "identifiable": list(res.identifiable), "dropped": list(res.dropped),
            "floor_plan_mm": res.floor_plan * MM_PER_M, "floor_random_mm": [float(x) * MM_PER_M if np.isfinite(x) else None for x in fr],
            "design": res.design,
        }, indent=2) + "\n")
    return 0
