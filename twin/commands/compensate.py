"""``twin compensate CALIBRATION.json TARGETS.csv --out JOINTS.csv``: corrected joint commands for tool poses, or for
positions of the calibration's measured point (a reflector) with the tool's orientation at the reference joints held; the
JOINTS.csv carries ``miss_mm`` and ``miss_deg``, how far each command lands from its target on the calibrated model."""

from __future__ import annotations

import argparse

from ..units import DEG_PER_RAD, M_PER_MM, MM_PER_M, deg_to_rad


POSITION_FIRST_M_PER_RAD = 1e-4  # [m/rad] the orientation's weight against a position-only target's position

HELP = "corrected joint commands that reach target tool poses (or a marker point's positions) on the calibrated robot"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("calibration", help="calibration.json")
    p.add_argument("targets", help="TARGETS.csv (pose_id, x, y, z [mm], qw, qx, qy, qz: the tool in the robot base frame; "
                                   "without qw..qz: positions of the calibration's measured point (its first marker, or "
                                   "a probe's origin), the tool's orientation at the reference joints held)")
    p.add_argument("--out", required=True, help="JOINTS.csv to write (with miss_mm, miss_deg: how far from each target "
                                                "the corrected command lands on the calibrated model)")
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
    from ..estimator.compensation import compensation_position, point_frame
    from ..estimator.files import read_targets
    from ..kinematics import UnreachableError, tool2base
    from ..estimator.plausibility import ImplausibleData, check_targets, forced_reasons
    from ..transforms import make_transform
    from . import check_joints_file, warn_forced

    cal = Calibration.load(args.calibration)
    tg = read_targets(args.targets)
    pid = tg.pose_id
    position_only = tg.rotation is None
    warn_forced(args.calibration, forced_reasons(cal.details))
    rot = np.broadcast_to(np.eye(3), (len(pid), 3, 3)) if position_only else tg.rotation
    P = point_frame(cal)
    # a position-only target is of the measured point (point_frame), a pose target of the tool
    reach = cal.robot.with_frames(tool2flange=cal.robot.tool2flange @ P) if position_only else cal.robot
    try:
        check_targets(np.stack([make_transform(R, p) for R, p in zip(rot, tg.position)]), pid, reach,
                      where="TARGETS.csv")
    except ImplausibleData as exc:
        raise ValueError(f"{args.targets}: {exc}; nothing written") from None
    nj = cal.nominal.n_joints
    if args.reference:
        ref = read_joints_csv(args.reference, robot=cal.nominal)
        by_id = {int(p): k for k, p in enumerate(ref.pose_id)}
        missing = [int(p) for p in pid if int(p) not in by_id]
        if missing:
            raise ValueError(f"{args.reference}: no reference row for pose_id {missing[:10]}")
        check_joints_file(args.reference, ref.q, ref.pose_id, cal.nominal, args.force, "used")
        q_ref = ref.q[[by_id[int(p)] for p in pid]]
    else:
        what = "six" if nj == 6 else f"{nj} ({', '.join(cal.nominal.joint_names)}; mm for a prismatic joint)"
        try:
            v = np.zeros(nj) if args.q_ref_deg is None else np.array([float(t) for t in args.q_ref_deg.split(",")])
        except ValueError:
            raise ValueError(f"--q-ref-deg must be {what} comma-separated numbers, got {args.q_ref_deg!r}") from None
        if v.shape != (nj,) or not np.all(np.isfinite(v)):
            raise ValueError(f"--q-ref-deg must be {what} finite numbers, got {args.q_ref_deg!r}")
        q_ref = np.where(cal.nominal.is_prismatic, v * M_PER_MM, deg_to_rad(v))
        q_ref = np.broadcast_to(q_ref, (len(pid), nj))
    try:
        if position_only and cal.effects:
            # the geometric answer first (position, the orientation held as far as the chain can); its tool pose is
            # then the target of the extended model, so that it is one the chain reaches
            geo = compensation_position(cal, tg.position, q_ref)
            T = tool2base(cal.robot.with_frames(base2meas=np.eye(4)), geo.q)
            T[:, :3, 3] = tg.position - np.einsum("nij,j->ni", T[:, :3, :3], point_frame(cal)[:3, 3])
            # the position first where the chain cannot hold the orientation as well
            res = _compensate_with_effects(cal, T, geo.q, pid, args.context, weight_rotation=POSITION_FIRST_M_PER_RAD)
        elif position_only:
            res = compensation_position(cal, tg.position, q_ref)
        elif cal.effects:
            res = _compensate_with_effects(cal, tg.tool2base, q_ref, pid, args.context)
        else:
            res = compensation(cal, tg.tool2base, q_ref)
    except UnreachableError as exc:
        hint = ""
        if not position_only and nj < 6:
            hint = (f"; a chain of {nj} joints reaches a position, not every pose: give TARGETS.csv without qw, qx, qy, "
                    "qz (positions of the marker point)")
        raise ValueError(f"{args.targets}: {exc} (indices count data rows from 0){hint}") from None
    miss_mm, miss_deg = res.position_error * MM_PER_M, res.rotation_error * DEG_PER_RAD
    write_joints_csv(args.out, Joints(pose_id=pid, q=res.q), robot=cal.nominal,
                     extra={"miss_mm": miss_mm, "miss_deg": miss_deg})
    rev = ~cal.nominal.is_prismatic
    dq = (np.abs(res.q - res.q_nominal)[:, rev] * DEG_PER_RAD).max() if rev.any() else 0.0
    what = ("positions of the measured point, the tool's orientation at the reference joints held" if position_only
            else "tool poses")
    print(f"compensated {len(pid)} targets ({what}; largest change from the nominal inverse {dq:.4g} deg); on the "
          f"calibrated model they land within {miss_mm.max():.2g} mm"
          + (f" and {miss_deg.max():.2g} deg of the held orientation" if position_only else f", {miss_deg.max():.2g} deg")
          + f" (columns miss_mm, miss_deg); wrote {args.out}")
    return 0


def _compensate_with_effects(cal, T, q_ref, pid, context_path, weight_rotation: float = 1.0):
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
    from ..dataset import temperature_gaps

    gaps = temperature_gaps(temp, np.asarray(pid)) if "temp_c" in need else ""
    if gaps:
        raise ValueError(f"{context_path}: the calibration's effects depend on 'temp_c': {gaps}")
    ctx = RowContext(q=np.zeros((len(pid), cal.nominal.n_joints)), q_start=np.zeros(cal.nominal.n_joints),
                     temp_c=temp, t_s=t_s)
    print(f"applied effects: {'; '.join(e.get('label', e.get('family', '?')) for e in cal.effects)} "
          "(commands in file order, start at home)")
    return compensate_extended(cal, T, q_ref, ctx, weight_rotation=weight_rotation)
