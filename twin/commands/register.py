"""``twin register CALIBRATION.json DATASET (--first N | --pose-ids FILE | --set NAME) [--tool] [--against GEO.json |
--no-judge] --out NEW.json``: the calibrated robot in a new session: its measurement frame (and tool) re-identified
from a few rows, the robot held; an extended calibration is used only where it predicts the session's registration
rows better than the geometric model it extends (judged by blocks of those rows)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..units import MM_PER_M, rad_to_deg

HELP = "re-identify a calibration's measurement frame (and tool) from a few rows of a new session, robot held"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("calibration", help="calibration.json of the robot (from twin calibrate or twin diagnose)")
    p.add_argument("dataset", help="dataset folder of the new session (poses.csv + dataset.toml)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--first", type=int, default=None, metavar="N",
                   help="use the first N measured rows in measurement order (default 50)")
    g.add_argument("--pose-ids", default=None, metavar="FILE",
                   help="use the rows whose pose_id is listed in FILE (a CSV with a pose_id column, e.g. a JOINTS.csv, "
                        "or one integer per line)")
    g.add_argument("--set", default=None, choices=["calibration", "validation"], dest="set_",
                   help="use the rows of this 'set' of poses.csv")
    p.add_argument("--session", default=None, help="only rows of this value of the 'session' column")
    p.add_argument("--station", default=None, help="only rows of this station")
    p.add_argument("--tool", action="store_true", help="re-identify tool2flange too (6 more parameters)")
    j = p.add_mutually_exclusive_group()
    j.add_argument("--against", default=None, metavar="GEOMETRIC.json",
                   help="judge the calibration against this one (the model it extends) on the session's registration "
                        "rows and write the one that predicts them better (default for an extended calibration: the "
                        "calibration_geometric.json beside it, as twin diagnose writes it)")
    j.add_argument("--no-judge", action="store_true",
                   help="register the calibration as given, without judging it against the model it extends")
    p.add_argument("--out", required=True, help="the registered calibration.json to write")
    p.add_argument("--force", action="store_true",
                   help="register even when the dataset's joints or length unit look wrong (noted in the output)")


def _pose_ids(path: str) -> list[int]:
    """Pose ids from a CSV with a ``pose_id`` column or from one integer per line (``#`` comments, blank lines)."""
    from ..dataset import read_csv_rows

    f = Path(path)
    if not f.is_file():
        raise ValueError(f"--pose-ids {path}: no such file")
    lines = f.read_text().splitlines()
    first = next((ln for ln in lines if ln.strip() and not ln.lstrip().startswith("#")), None)
    if first is None:
        raise ValueError(f"--pose-ids {path}: no pose ids in the file")
    if "pose_id" in [c.strip() for c in first.split(",")]:
        _, rows = read_csv_rows(f, ("pose_id",))
        vals = [(k + 2, r["pose_id"]) for k, r in enumerate(rows)]
    else:
        vals = [(k + 1, ln.strip()) for k, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith("#")]
    out = []
    for line, t in vals:
        try:
            out.append(int(t))
        except (TypeError, ValueError):
            raise ValueError(f"--pose-ids {path}: line {line}: not an integer pose id: {t!r}") from None
    if not out:
        raise ValueError(f"--pose-ids {path}: no pose ids in the file")
    return out


def _fmt(stats: dict, key: str = "position_mm", unit: str = "mm") -> str:
    v = stats.get(key)
    return "-" if not v else f"mean {v['mean']:.4g} / rms {v['rms']:.4g} / max {v['max']:.4g} {unit}"


def _report(label: str, stats: dict) -> list[str]:
    what = f"{stats['n_rows']} rows" + (f", {stats['n_spheres']} points" if "n_spheres" in stats else "")
    lines = [f"{label} ({what}): position {_fmt(stats)}"]
    if "orientation_deg" in stats:
        lines.append(f"{' ' * len(label)}   orientation {_fmt(stats, 'orientation_deg', 'deg')}")
    return lines


def run(args) -> int:
    import numpy as np

    from ..dataset import read_dataset
    from ..estimator import Calibration
    from ..estimator.plausibility import ImplausibleData, check_joints, check_length_unit, forced_reasons
    from ..estimator.register import SESSION_COLUMN, prediction_errors, register, select_rows
    from ..transforms import rotation_angle_between, transform_to_pose6
    from . import warn_forced

    out = Path(args.out)
    if out.is_dir():
        raise ValueError(f"--out {args.out}: is a folder; give the calibration file to write (e.g. {out / 'calibration.json'})")
    if out.resolve() == Path(args.calibration).resolve():
        raise ValueError(f"--out {args.out}: is the input calibration; write the registered one beside it (the robot's "
                         "calibration stays as it was)")
    cal = Calibration.load(args.calibration)
    warn_forced(args.calibration, forced_reasons(cal.details))
    ds = read_dataset(args.dataset)
    notes: list[str] = []
    try:
        notes += check_joints(ds)
        check_length_unit(ds)
    except ImplausibleData as exc:
        if not args.force:
            raise ValueError(f"{args.dataset}: {exc}; nothing registered (--force registers anyway)") from None
        notes.append(f"FORCED: {exc}")

    if args.pose_ids is not None:
        how = f"--pose-ids {args.pose_ids}"
        sel = dict(pose_ids=_pose_ids(args.pose_ids))
    elif args.set_ is not None:
        how = f"--set {args.set_}"
        sel = dict(set_=args.set_)
    else:
        n = 50 if args.first is None else args.first
        how = f"--first {n}"
        sel = dict(first=n)
    scope = "".join(f" --{k} {v}" for k, v in (("session", args.session), ("station", args.station)) if v is not None)
    try:
        rows = select_rows(ds, session=args.session, station=args.station, **sel)
    except ValueError as exc:
        raise ValueError(f"{how}{scope}: {exc}") from None

    if cal.effects:
        # a term of the history (an approach direction) reads its unknown state at the session's first rows: such a
        # row would pull the frame by the term's size, so it registers nothing
        from ..diagnosis.apply import history_unknown_rows
        from ..diagnosis.floor import row_context

        unknown = history_unknown_rows(cal, row_context(ds))[rows]
        if unknown.any() and not unknown.all():
            notes.append(f"{int(unknown.sum())} of the {rows.size} rows ({how}{scope}) lack the history a term of "
                         f"{args.calibration} needs (pose_id {ds.pose_id[rows[unknown]][:10].tolist()}): left out of "
                         "the registration")
            rows = rows[~unknown]
            how = f"{how} less {int(unknown.sum())} row(s) without the history a term needs"
    cal, args_cal, choice = _judged(args, cal, ds, rows, how, scope)
    predict = None
    if cal.effects:
        # an extended calibration: its effects evaluated from the dataset's rows in measurement order (history
        # unknown at the first row and where the 'session' column changes: a new session starts anew)
        from ..diagnosis.apply import dataset_predictor

        predict = dataset_predictor(ds)
        print(f"applied effects: {'; '.join(str(e.get('label', e.get('family', '?'))) for e in cal.effects)} "
              "(rows in measurement order; approach directions unknown until each joint moves in the session)")
    try:
        reg = register(cal, ds, rows, tool=args.tool, predict=predict)
    except ValueError as exc:
        msg = str(exc)
        raise ValueError(f"{how}{scope}: {msg}" if msg.startswith("rows") else msg) from None
    new = reg.calibration
    if choice is not None:
        from dataclasses import replace as _replace

        new = _replace(new, details={**new.details, "session_choice": {
            "chosen": choice.chosen, "calibration": str(args_cal), "cv_position_rms_mm": choice.cv_position_rms_mm,
            "folds": [int(f.size) for f in choice.folds], "dropped": list(choice.dropped), "prune_z": choice.prune_z,
            "note": choice.note}})
    if notes:
        from dataclasses import replace

        new = replace(new, notes=tuple(new.notes) + tuple(notes))
    path = new.save(out)

    sess = f" of session {', '.join(repr(s) for s in reg.session)}" if reg.session else ""
    pid = reg.pose_id
    ids = f"pose_id {pid[0]}..{pid[-1]}" if np.array_equal(pid, np.arange(pid[0], pid[0] + pid.size)) else \
        f"pose_id {', '.join(str(v) for v in pid[:8])}{' ...' if pid.size > 8 else ''}"
    print(f"registered {', '.join(repr(s) for s in reg.stations)} ({'base2meas and tool2flange' if reg.tool else 'base2meas'}) "
          f"on {rows.size} rows ({how}{scope}: {ids}){sess} of {args.dataset}; robot model of {args_cal} held")
    for s in reg.stations:
        v = transform_to_pose6(new.base2meas[s])
        line = (f"  station {s!r} base2meas: x {v[0] * MM_PER_M:.3f} y {v[1] * MM_PER_M:.3f} z {v[2] * MM_PER_M:.3f} mm, rotation vector "
                f"{rad_to_deg(v[3]):.4f} {rad_to_deg(v[4]):.4f} {rad_to_deg(v[5]):.4f} deg")
        if s in cal.stations:
            B0, B1 = cal.base2meas[s], new.base2meas[s]
            line += (f" (moved {np.linalg.norm(B1[:3, 3] - B0[:3, 3]) * MM_PER_M:.3f} mm, "
                     f"{rad_to_deg(float(rotation_angle_between(B0[:3, :3], B1[:3, :3]))):.4f} deg from the calibration's)")
        print(line)
    if reg.tool:
        v = transform_to_pose6(new.tool2flange)
        print(f"  tool2flange: x {v[0] * MM_PER_M:.3f} y {v[1] * MM_PER_M:.3f} z {v[2] * MM_PER_M:.3f} mm, rotation vector "
              f"{rad_to_deg(v[3]):.4f} {rad_to_deg(v[4]):.4f} {rad_to_deg(v[5]):.4f} deg")
    print(f"  Gauss-Newton from the closed-form registration: {reg.iterations} iteration(s), "
          f"{'converged' if reg.converged else 'NOT converged'}; residual scale {reg.residual_scale:.3g}")
    for line in _report("residual on the rows used", reg.residuals):
        print(line)
    # the measured rows of the registered stations (and sessions) that took no part: what the registered model
    # predicts in the new session
    measured = ds.sphere_seen.any(axis=1) | ds.pose_seen
    scope_rows = np.isin(ds.station_ids.astype(str), reg.stations)
    if reg.session is not None:
        scope_rows &= np.isin(np.asarray(ds.extra[SESSION_COLUMN]).astype(str), reg.session)
    others = np.setdiff1d(np.flatnonzero(measured & scope_rows), rows)
    if others.size:
        for line in _report("error on the measured rows not used", prediction_errors(new, ds, others, predict=predict)):
            print(line)
    rest = np.flatnonzero(measured & ~scope_rows)
    if rest.size:
        what = "station(s) or session(s)" if reg.session is not None else "station(s)"
        print(f"  {rest.size} measured row(s) of other {what} not evaluated (not registered)")
    for n in notes:
        print(f"note: {n}")
    if reg.session is not None and len(reg.session) > 1:
        print(f"note: the rows used span sessions {list(reg.session)}: one frame was fitted to all of them; --session "
              "registers one session's")
    if len(new.stations) > 1:
        print(f"note: the calibration holds stations {list(new.stations)}: give JOINTS.csv a 'station' column for "
              "`twin predict` to predict in a station's frame")
    print(f"wrote {path}")
    return 0


def _judged(args, cal, ds, rows, how: str, scope: str):
    """The calibration to register: the given one, or the model it extends where that predicts the session's
    registration rows better (:func:`twin.diagnosis.apply.choose_for_session`). Returns ``(calibration, its path,
    choice or None)``; prints the judgement."""
    from ..estimator import Calibration

    against = args.against
    auto = against is None
    if args.no_judge or (auto and not cal.effects):
        return cal, args.calibration, None
    if auto:
        beside = Path(args.calibration).with_name("calibration_geometric.json")
        if not beside.is_file() or beside.resolve() == Path(args.calibration).resolve():
            print(f"note: {args.calibration} has effects and no calibration_geometric.json beside it: not judged "
                  "against the model it extends (--against GEOMETRIC.json judges it on this session's rows)")
            return cal, args.calibration, None
        against = str(beside)
    other = Calibration.load(against)
    from ..diagnosis.apply import choose_for_session

    names = ("geometric" if not other.effects else "fallback", "extended" if cal.effects else "given")
    try:
        choice = choose_for_session({names[0]: other, names[1]: cal}, ds, rows, tool=args.tool)
    except ValueError as exc:
        if not auto:
            raise ValueError(f"--against {against}: {how}{scope}: {exc}") from None
        print(f"note: not judged against {against} ({exc}); the given calibration is registered")
        return cal, args.calibration, None
    print(f"judged on this session's {rows.size} registration rows ({len(choice.folds)} blocks in measurement order, "
          "each predicted by the others' registration), position RMS: "
          + ", ".join(f"{k} {v:.4g} mm" for k, v in choice.cv_position_rms_mm.items())
          + f" ({names[0]}: {against}; {names[1]}: {args.calibration})")
    if choice.dropped:
        print(f"  {names[1]} (pruned): without the {len(choice.dropped)} term(s) these rows do not bear out (z = "
              f"{choice.prune_z:.2f} against the whole model), in the order dropped: {'; '.join(choice.dropped)}")
    elif choice.prune_z:
        print(f"  every term of the {names[1]} model kept: dropping some did not predict these rows significantly "
              f"better (z = {choice.prune_z:.2f})")
    if choice.chosen == names[0]:
        print(f"  the {names[0]} model is used: the {names[1]} one does not predict this session's rows better "
              "(--no-judge registers it anyway)")
        return other, against, choice
    print(f"  the {choice.chosen} model is used")
    return choice.candidates[choice.chosen], args.calibration, choice
