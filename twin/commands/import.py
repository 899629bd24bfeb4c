"""``twin import CSV [--validation CSV] --urdf URDF --root LINK --end LINK --out DATASET``: a FIGAROH-style
motion-capture campaign (joints under the robot's joint names, K points of one tracked body per row) and the
robot's URDF into a dataset folder (``twin.mocap``)."""

from __future__ import annotations

import argparse


HELP = "import a motion-capture campaign (FIGAROH-style CSV + URDF) as a dataset folder"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("csv", nargs="+", help="mocap CSV(s) of the calibration (training) rows")
    p.add_argument("--validation", action="append", default=[], metavar="CSV",
                   help="mocap CSV of validation rows (another day); repeatable")
    p.add_argument("--urdf", required=True, help="the robot's URDF")
    p.add_argument("--root", required=True, help="root link of the chain (the robot base)")
    p.add_argument("--end", required=True, help="end link of the chain (the flange the markers are fixed to)")
    p.add_argument("--out", required=True, help="dataset folder to write")
    p.add_argument("--marker-unit", choices=["m", "mm"], default="m", help="unit of the x1..zK columns (default m)")
    p.add_argument("--points", default=None, help="marker numbers to keep, e.g. 1 or 1,2,3 (default all)")
    p.add_argument("--rigid-tol-mm", type=float, default=1.0,
                   help="largest spread of a pairwise marker distance over the rows (default 1 mm)")
    p.add_argument("--noise-mm", type=float, default=None, help="instrument noise per coordinate for [noise]")
    p.add_argument("--attribution", default="", help="text kept in the dataset's provenance")


def run(args) -> int:
    from ..mocap import import_mocap

    points = None
    if args.points:
        try:
            points = [int(t) for t in args.points.split(",")]
        except ValueError:
            raise ValueError(f"--points must be comma-separated marker numbers, got {args.points!r}") from None
    files = [(c, "calibration") for c in args.csv] + [(v, "validation") for v in args.validation]
    ds = import_mocap(files, args.urdf, args.root, args.end, args.out, marker_unit=args.marker_unit, points=points,
                      rigid_tol_mm=args.rigid_tol_mm, noise_position_mm=args.noise_mm, attribution=args.attribution)
    n_cal = int((ds.set == "calibration").sum())
    print(f"{ds.n} rows ({n_cal} calibration, {ds.n - n_cal} validation), {ds.robot.n_joints} joints "
          f"({', '.join(ds.robot.joint_names)}), {ds.n_points} marker point(s); wrote {args.out}")
    return 0
