"""``twin compensate CALIBRATION.json TARGETS.csv --out JOINTS.csv``: corrected joint commands."""

from __future__ import annotations

import argparse

from ..units import M_PER_MM, MM_PER_M, deg_to_rad, rad_to_deg


HELP = "corrected joint commands that reach target plate poses on the calibrated robot"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("calibration", help="calibration.json")
    p.add_argument("targets", help="TARGETS.csv (pose_id, x, y, z [mm], qw, qx, qy, qz: plate in the robot base frame)")
    p.add_argument("--out", required=True, help="JOINTS.csv to write")
    p.add_argument("--reference", default=None,
                   help="JOINTS.csv whose rows (by pose_id) pick the inverse-kinematics branch (default: the branch "
                        "nearest --q-ref-deg)")
    p.add_argument("--q-ref-deg", default=None,
                   help="reference joints [deg; mm for a prismatic joint] when --reference is not given (default: zeros)")
    p.add_argument("--force", action="store_true",
                   help="use --reference joints outside the robot's limits or that look like radians")
    p.add_argument("--context", default=None,
                   help="JOINTS.csv-like file giving temp_c / t_s per pose_id, for an extended calibration with "
                        "thermal growth")


def run(args) -> int:
    import numpy as np

    from ..dataset import Joints, read_joints_csv, write_joints_csv
    from ..estimator import Calibration, compensation
    from ..estimator.files import read_targets_csv
    from ..kinematics import UnreachableError
    from ..estimator.plausibility import ImplausibleData, check_targets, forced_reasons
    from . import check_joints_file, warn_forced

    cal = Calibration.load(args.calibration)
    pid, T = read_targets_csv(args.targets)
    warn_forced(args.calibration, forced_reasons(cal.details))
    try:
        check_targets(T, pid, cal.robot, where="TARGETS.csv")
    except ImplausibleData as exc:
        raise ValueError(f"{args.targets}: {exc}; nothing written") from None
    if args.reference:
        ref = read_joints_csv(args.reference, robot=cal.nominal)
        by_id = {int(p): k for k, p in enumerate(ref.pose_id)}
        missing = [int(p) for p in pid if int(p) not in by_id]
        if missing:
            raise ValueError(f"{args.reference}: no reference row for pose_id {missing[:10]}")
        check_joints_file(args.reference, ref.q, ref.pose_id, cal.nominal, args.force, "used")
        q_ref = ref.q[[by_id[int(p)] for p in pid]]
    else:
        nj = cal.nominal.n_joints
        what = "six" if nj == 6 else f"{nj} ({', '.join(cal.nominal.joint_names)}; mm for a prismatic joint)"
        try:
            v = np.zeros(nj) if args.q_ref_deg is None else np.array([float(t) for t in args.q_ref_deg.split(",")])
        except ValueError:
            raise ValueError(f"--q-ref-deg must be {what} comma-separated numbers, got {args.q_ref_deg!r}") from None
        if v.shape != (nj,) or not np.all(np.isfinite(v)):
            raise ValueError(f"--q-ref-deg must be {what} finite numbers, got {args.q_ref_deg!r}")
        q_ref = np.where(cal.nominal.is_prismatic, v * M_PER_MM, deg_to_rad(v))
    try:
        if cal.effects:
            res = _compensate_with_effects(cal, T, q_ref, pid, args.context)
        else:
            res = compensation(cal, T, q_ref)
    except UnreachableError as exc:
        raise ValueError(f"{args.targets}: {exc} (indices count data rows from 0)") from None
    write_joints_csv(args.out, Joints(pose_id=pid, q=res.q), robot=cal.nominal)
    rev = ~cal.nominal.is_prismatic
    dq = rad_to_deg(np.abs(res.q - res.q_nominal)[:, rev]).max()
    print(f"compensated {len(pid)} targets (largest change from the nominal inverse {dq:.4g} deg; residual "
          f"{res.position_error.max() * MM_PER_M:.2g} mm); wrote {args.out}")
    return 0


def _compensate_with_effects(cal, T, q_ref, pid, context_path):
    """An extended calibration (from twin diagnose): commands in file order, effects included."""
    import numpy as np

    from ..dataset import read_joints_csv
    from ..diagnosis.apply import compensate_extended
    from ..diagnosis.candidates import RowContext

    temp = t_s = None
    if context_path:
        c = read_joints_csv(context_path)
        by_id = {int(p): k for k, p in enumerate(c.pose_id)}
        missing = [int(p) for p in pid if int(p) not in by_id]
        if missing:
            raise ValueError(f"{context_path}: no row for pose_id {missing[:10]}")
        sel = [by_id[int(p)] for p in pid]
        temp = None if c.temp_c is None else c.temp_c[sel]
        t_s = None if c.t_s is None else c.t_s[sel]
    from ..diagnosis.apply import required_channels

    need = required_channels(cal) & {"temp_c", "t_s"}
    have = {"temp_c": temp, "t_s": t_s}
    lacking = sorted(c for c in need if have[c] is None)
    if lacking:
        raise ValueError(f"the calibration's effects depend on {', '.join(lacking)}: give --context with "
                         f"{' and '.join(lacking)} per pose_id")
    ctx = RowContext(q=np.zeros((len(pid), 6)), q_start=np.zeros(6), temp_c=temp, t_s=t_s)
    print(f"applied effects: {'; '.join(e.get('label', e.get('family', '?')) for e in cal.effects)} "
          "(commands in file order, start at home)")
    return compensate_extended(cal, T, q_ref, ctx)
