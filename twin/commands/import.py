"""``twin import``: files people have into a dataset folder (``twin.importers``).

* ``twin import --map MAP.toml [CSV[:key=value,...] ...] --out DATASET``: any laser-tracker or motion-capture CSV
  read through a column map (``twin.importers.columns``); the CSVs are the map's ``[[files]]`` unless given here,
  each with its own ``set``, ``session``, ``station``, ``time=row``, ``order``; ``--calibration CAL.json`` places the
  measurement on the flange with a calibration's tool (a session whose rows cannot: an ISO cube of one orientation).
* ``twin import CSV [--validation CSV] --urdf URDF --root LINK --end LINK --out DATASET``: a FIGAROH-style
  motion-capture campaign (joints under the robot's joint names, K points of one tracked body per row) and the
  robot's URDF (``twin.importers.mocap``).
"""

from __future__ import annotations

import argparse


HELP = "import CSVs as a dataset folder: through a column map (--map), or a FIGAROH-style mocap CSV + URDF"

_MOCAP_ONLY = ("urdf", "root", "end", "marker_unit", "points", "rigid_tol_mm", "noise_mm")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("csv", nargs="*",
                   help="CSV(s): with --map, PATH[:set=calibration|validation|last:F|first:N,session=S,station=S,time=row,"
                        "order=file|time] (default: the map's [[files]]); without, mocap CSV(s) of the calibration rows")
    p.add_argument("--map", default=None, metavar="MAP.toml",
                   help="column map: CSV dialect, robot, joint columns and units, points or a 6-DOF pose, time, "
                        "temperature, set, session, station, nominal frames (docs/formats.md)")
    p.add_argument("--validation", action="append", default=[], metavar="CSV",
                   help="CSV of validation rows (another day); repeatable")
    p.add_argument("--urdf", default=None, help="mocap: the robot's URDF")
    p.add_argument("--root", default=None, help="mocap: root link of the chain (the robot base)")
    p.add_argument("--end", default=None, help="mocap: end link of the chain (the flange the markers are fixed to)")
    p.add_argument("--out", required=True,
                   help="dataset folder to write; refused when it already holds a dataset (dataset.toml or poses.csv) "
                        "unless --force")
    p.add_argument("--force", action="store_true",
                   help="write into an --out folder that already holds a dataset: its dataset.toml and poses.csv (and "
                        "the robot file copied beside them) are replaced; no other file in it is touched")
    p.add_argument("--marker-unit", choices=["m", "mm"], default=None, help="mocap: unit of the x1..zK columns (default m)")
    p.add_argument("--points", default=None, help="mocap: marker numbers to keep, e.g. 1 or 1,2,3 (default all)")
    p.add_argument("--rigid-tol-mm", type=float, default=None,
                   help="mocap: largest spread of a pairwise marker distance over the rows (default 1 mm)")
    p.add_argument("--noise-mm", type=float, default=None, help="mocap: instrument noise per coordinate for [noise]")
    p.add_argument("--attribution", default="", help="text kept in the dataset's provenance")
    p.add_argument("--calibration", default=None, metavar="CAL.json",
                   help="with --map: the robot's calibration, whose tool (a pose's tool2flange, or the marker points on "
                        "the flange) places this session's measurement on the flange instead of a fit (a session of "
                        "one tool orientation, e.g. an ISO cube, cannot place it itself)")


def _run_map(args) -> int:
    from ..importers.columns import import_columns, parse_file_argument, read_column_map

    given = [k.replace("_", "-") for k in _MOCAP_ONLY if getattr(args, k) is not None]
    if given:
        raise ValueError(f"--map: the robot, units and frames come from the map; --{', --'.join(given)} belong to the "
                         "mocap import (without --map)")
    cmap = read_column_map(args.map)
    inputs = [parse_file_argument(c)[0] for c in args.csv + args.validation]
    check_out_folder(args.out, args.force, inputs + ([] if args.csv else [str(f.path) for f in cmap.files]),
                     robot_file=cmap.urdf)
    tool = None
    if args.calibration is not None:
        tool = _calibration_tool(args.calibration, cmap.base.kind)
    files = [parse_file_argument(c) for c in args.csv]
    for v in args.validation:
        path, over = parse_file_argument(v)
        if over.get("set", "validation") != "validation":
            raise ValueError(f"--validation {v}: set={over['set']} contradicts --validation")
        files.append((path, {**over, "set": "validation"}))
    rep = import_columns(cmap, args.out, files=files or None, attribution=args.attribution, tool=tool)
    ds = rep.dataset
    kind = "a 6-DOF pose" if ds.has_poses else f"{ds.n_points} point(s)"
    if ds.set is None:
        sets = "no set column"
    else:
        n_cal = int((ds.set == "calibration").sum())
        sets = f"{n_cal} calibration, {ds.n - n_cal} validation"
    print(f"{ds.n} rows ({sets}) from {len(rep.files)} file(s), "
          f"{ds.robot.n_joints} joints ({', '.join(ds.robot.joint_names)}), {kind} per row; wrote {args.out}")
    for f in rep.files:
        split = "" if ds.set is None else f" ({f['calibration']} calibration, {f['validation']} validation)"
        print(f"  {f['path']}: {f['rows']} rows{split}, "
              f"session {', '.join(f['session'])}" + (f", station {', '.join(f['station'])}" if f["station"] else "")
              + f", {f['time']}")
    for sid, st in rep.stations.items():
        o = "" if st["orientation_rms_deg"] is None else f", {st['orientation_rms_deg']:.3g} deg"
        print(f"  station {sid}: {st['rows']} rows; the nominal robot fits to {st['position_rms_mm']:.3g} mm{o} RMS "
              f"(base2meas {st['base2meas']})")
        warning = _nominal_miss_warning(ds, sid, st["position_rms_mm"])
        if warning:
            print(f"  WARNING: station {sid}: {warning}")
    for n in rep.notes:
        print(f"  note: {n}")
    spec = ds.robot_spec
    if isinstance(spec, dict) and spec.get("convention") in ("dh", "mdh") and not {"q_min_deg", "q_max_deg"} <= set(spec):
        print("  note: the robot table gives no q_min_deg / q_max_deg: every joint's limits are taken as -180..180 deg "
              "(twin predict and twin compensate refuse joints beyond them; give the robot's limits in the map)")
    return 0


def _nominal_miss_warning(ds, sid: str, rms_mm: float) -> str:
    """Words when the nominal robot misses the station's rows by :data:`~twin.estimator.plausibility.MAX_MISS_FRACTION`
    or more of how far its measured positions move (their RMS distance from their centroid), the bound past which
    ``twin calibrate`` refuses a fitted model; empty otherwise."""
    from ..estimator.plausibility import MAX_MISS_FRACTION, position_spread
    from ..units import MM_PER_M

    rows = ds.station_ids.astype(str) == str(sid)
    pts = ds.pose[rows, :3, 3][ds.pose_seen[rows]] if ds.has_poses else ds.spheres[rows][ds.sphere_seen[rows]]
    if pts.shape[0] < 3:
        return ""
    spread_mm = position_spread(pts) * MM_PER_M
    if not rms_mm >= MAX_MISS_FRACTION * spread_mm:
        return ""
    return (f"the nominal robot misses its rows by {rms_mm:.3g} mm RMS, {rms_mm / spread_mm:.0%} of the {spread_mm:.4g} mm "
            "they move: no robot's own errors are that large; check the map's joint columns (their order) and units "
            "(joints.unit), the measurement's unit, rotation_unit and euler, and the robot (twin calibrate refuses "
            "such data)")


def _calibration_tool(path: str, kind: str):
    """``(frame, source)`` of the tool of the calibration ``path``: its ``tool2flange`` for a pose, its marker points
    on the flange ``(K, 3)`` [m] for points; ``ValueError`` when the calibration measured the other kind."""
    from ..estimator import Calibration
    from ..estimator.compensation import measured_pose

    cal = Calibration.load(path)
    T = cal.tool2flange
    if measured_pose(cal) != (kind == "pose"):
        what = "6-DOF poses of a probe" if measured_pose(cal) else f"{len(cal.spheres_tool)} marker point(s)"
        raise ValueError(f"--calibration {path}: it was fitted to {what}, the map measures "
                         + ("a 6-DOF pose" if kind == "pose" else "points") + ": its tool cannot place them")
    if kind == "pose":
        return T, f"from the calibration {path} (--calibration)"
    pts = cal.spheres_tool @ T[:3, :3].T + T[:3, 3]
    return pts, f"from the calibration {path} (--calibration; its {len(pts)} marker point(s))"


_DATASET_FILES = ("dataset.toml", "poses.csv")


def check_out_folder(out: str, force: bool, inputs: list[str], robot_file=None) -> None:
    """``ValueError`` naming ``out`` when it already holds a dataset (``dataset.toml`` or ``poses.csv``) or a file of
    ``robot_file``'s name with other bytes (the import copies the robot file beside the dataset) and ``force`` is not
    given, or when writing the dataset there would replace one of the ``inputs`` (a measured file the import reads),
    forced or not."""
    from pathlib import Path

    folder = Path(out)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"--out {out}: a file, not a folder")
    written = {(folder / f).resolve() for f in _DATASET_FILES}
    hit = [i for i in inputs if Path(i).resolve() in written]
    if hit:
        raise ValueError(f"--out {out}: the dataset's {', '.join(sorted({Path(h).name for h in hit}))} would replace "
                         f"the input {', '.join(hit)}; write the dataset to another folder")
    present = [f for f in _DATASET_FILES if (folder / f).exists()]
    if present and not force:
        raise ValueError(f"--out {out}: the folder already holds a dataset ({', '.join(present)}); choose a new folder, "
                         "or give --force to replace its dataset.toml and poses.csv (no other file in it is touched)")
    if robot_file is None or force:
        return
    src = Path(robot_file)
    dst = folder / src.name
    if dst.is_file() and src.is_file() and dst.resolve() != src.resolve() and dst.read_bytes() != src.read_bytes():
        raise ValueError(f"--out {out}: it holds a {src.name} other than the robot file {robot_file} the import copies "
                         "there; choose a new folder, or give --force to replace it")


def run(args) -> int:
    if args.calibration is not None and args.map is None:
        raise ValueError("--calibration goes with --map (a column map's session placed with the robot's calibration)")
    if args.map is not None:
        return _run_map(args)
    check_out_folder(args.out, args.force, args.csv + args.validation, robot_file=args.urdf)
    from ..importers.mocap import import_mocap

    missing = [f"--{k}" for k in ("urdf", "root", "end") if getattr(args, k) is None]
    if missing or not args.csv:
        raise ValueError("give --map MAP.toml (a column map), or mocap CSV(s) with --urdf, --root and --end "
                         f"(missing: {', '.join(missing + ([] if args.csv else ['CSV']))})")
    points = None
    if args.points:
        try:
            points = [int(t) for t in args.points.split(",")]
        except ValueError:
            raise ValueError(f"--points must be comma-separated marker numbers, got {args.points!r}") from None
    files = [(c, "calibration") for c in args.csv] + [(v, "validation") for v in args.validation]
    ds = import_mocap(files, args.urdf, args.root, args.end, args.out,
                      marker_unit=args.marker_unit or "m", points=points,
                      rigid_tol_mm=1.0 if args.rigid_tol_mm is None else args.rigid_tol_mm,
                      noise_position_mm=args.noise_mm, attribution=args.attribution)
    n_cal = int((ds.set == "calibration").sum())
    print(f"{ds.n} rows ({n_cal} calibration, {ds.n - n_cal} validation), {ds.robot.n_joints} joints "
          f"({', '.join(ds.robot.joint_names)}), {ds.n_points} marker point(s); wrote {args.out}")
    return 0
