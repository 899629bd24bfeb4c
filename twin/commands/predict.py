"""``twin predict CALIBRATION.json JOINTS.csv --out PRED.csv``: predicted sphere centres and plate poses."""

from __future__ import annotations

import argparse


HELP = "predict sphere centres and plate poses (with standard deviations) for joint rows"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("calibration", help="calibration.json")
    p.add_argument("joints", help="JOINTS.csv (pose_id, the robot's joints (q1..q6) [deg, mm], optional station)")
    p.add_argument("--out", required=True, help="PRED.csv to write")
    p.add_argument("--force", action="store_true",
                   help="predict even for joints outside the robot's limits or that look like radians")


def run(args) -> int:
    import sys

    import numpy as np

    from ..dataset import read_joints_csv
    from ..estimator import Calibration
    from ..estimator.files import write_pred_csv
    from ..estimator.plausibility import forced_reasons
    from . import check_joints_file, warn_forced

    cal = Calibration.load(args.calibration)
    j = read_joints_csv(args.joints, robot=cal.nominal)
    warn_forced(args.calibration, forced_reasons(cal.details))
    check_joints_file(args.joints, j.q, j.pose_id, cal.nominal, args.force, "predicted")
    if cal.effects:
        # an extended calibration (from twin diagnose): apply its effects to the rows in this order
        from ..diagnosis.apply import predict_extended
        from ..diagnosis.floor import joints_context

        # where the robot stood before the first row is not in the file: history-dependent terms (backlash)
        # read 0 until each joint has moved (as the diagnosis read its rows), and again where the session changes
        ctx = joints_context(j)
        pred = predict_extended(cal, ctx, j.station)
        print(f"applied effects: {'; '.join(e.get('label', e.get('family', '?')) for e in cal.effects)} "
              "(rows in file order; approach directions unknown until each joint moves)")
        from ..diagnosis.apply import history_unknown_rows

        from ..diagnosis.apply import row_states

        for line in row_states(cal, ctx):
            print(f"state: {line}")
        lack = j.pose_id[history_unknown_rows(cal, ctx)]
        if lack.size:
            print(f"warning: {lack.size} row(s) lack the history an order-dependent term needs (the joint had not moved "
                  f"since the first row of the file or a restart); that term reads 0 there: pose_id {lack[:20].tolist()}"
                  + (" ..." if lack.size > 20 else ""))
    else:
        pred = cal.predict(j.q, j.station)
    if j.station is not None:  # a station the calibration does not know (a typing error?): its rows in the base frame
        st = np.asarray(j.station, dtype=object).astype(str)
        unknown = sorted(set(st.tolist()) - set(cal.stations))
        if unknown:
            counts = ", ".join(f"{s or '(empty)'!r}: {int(np.sum(st == s))} row(s)" for s in unknown[:5])
            more = " ..." if len(unknown) > 5 else ""
            print(f"warning: {args.joints}: station(s) the calibration does not know ({counts}{more}; it knows "
                  f"{', '.join(map(repr, cal.stations))}): those rows are predicted in the robot base frame",
                  file=sys.stderr)
    write_pred_csv(args.out, j.pose_id, pred, station=j.station)
    frames = sorted(set(pred.frame.tolist()))
    print(f"predicted {len(j.pose_id)} rows in the {' and '.join(frames)} frame(s); wrote {args.out}")
    return 0
