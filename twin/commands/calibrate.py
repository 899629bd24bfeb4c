"""``twin calibrate DATASET --method M --out DIR``: identify the robot of a dataset, write calibration.json."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..units import M_PER_MM, MM_PER_M, RAD_PER_MRAD


HELP = "identify the robot of a measured dataset (writes DIR/calibration.json)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", help="dataset folder (poses.csv + dataset.toml)")
    p.add_argument("--method", default="best", choices=["best", "distance", "fullpose", "separation", "separation_paper", "lm", "clm", "lm_paper", "clm_paper"],
                   help="identification method (default: best, ours)")
    p.add_argument("--out", required=True, help="output folder for calibration.json")
    p.add_argument("--error-model", choices=["tmmdh", "structural"], default=None,
                   help="tmmdh: robot + tool + base per station (default); structural: robot only, frames held")
    p.add_argument("--gauge", choices=["frames", "structure"], default=None,
                   help="which member of a coupled set is kept (best only; default frames)")
    p.add_argument("--level", choices=["full", "offsets", "frames"], default=None,
                   help="best only: which robot parameters are estimated besides base and tool: full (every "
                        "geometric parameter, default), offsets (joint offsets only), frames (none)")
    p.add_argument("--selection", choices=["ordered", "figaroh"], default=None,
                   help="best, full level of a URDF chain: which identifiable parameters are estimated: ordered (every "
                        "one, default) or figaroh (FIGAROH's full-parameter set reproduced: its structural QR, the first "
                        "six base parameters replaced by the base frame, weakly excited directions dropped)")
    p.add_argument("--prior-mm", type=float, default=None,
                   help="best only: Gaussian prior sd [mm] on every robot length's deviation from nominal (MAP fit)")
    p.add_argument("--prior-mrad", type=float, default=None,
                   help="best only: Gaussian prior sd [mrad] on every robot angle's deviation (joint offsets excluded)")
    p.add_argument("--prior-offset-mrad", type=float, default=None,
                   help="best only: Gaussian prior sd [mrad] on the joint offsets (mm for a prismatic joint)")
    p.add_argument("--measurement", choices=["auto", "spheres", "pose"], default="auto")
    p.add_argument("--solver", choices=["spectral", "scaled"], default=None,
                   help="distance/fullpose/separation: the paper's spectral correction (default) or scaled GN")
    p.add_argument("--angle-residual", choices=["relative", "euler"], default=None, help="separation only")
    p.add_argument("--no-robust", action="store_true", help="best: plain least squares (no outlier rule)")
    p.add_argument("--noise-position-mm", type=float, default=None, help="override dataset.toml [noise]")
    p.add_argument("--noise-orientation-rad", type=float, default=None, help="override dataset.toml [noise]")
    p.add_argument("--validation-fraction", type=float, default=0.2,
                   help="held-out fraction when the dataset has no 'set' column (seeded)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--use-given-bases", action="store_true",
                   help="start from dataset.toml's station base2meas instead of registering them")
    p.add_argument("--quiet", action="store_true")
    p.add_argument("--force", action="store_true",
                   help="write the calibration even when the data cannot be right (marked 'forced' in the JSON)")


def _options(args) -> dict:
    opts = {}
    if args.error_model is not None:
        if args.method not in ("best", "lm", "clm", "lm_paper", "clm_paper"):
            raise ValueError(f"--error-model applies to best, lm and clm, not {args.method!r}")
        opts["error_model"] = args.error_model
    if args.gauge is not None:
        if args.method != "best":
            raise ValueError("--gauge applies to --method best only")
        opts["gauge"] = args.gauge
    if args.level is not None:
        if args.method != "best":
            raise ValueError("--level applies to --method best only")
        opts["level"] = args.level
    if args.selection is not None:
        if args.method != "best":
            raise ValueError("--selection applies to --method best only")
        opts["selection"] = args.selection
    prior = {k: v * scale for k, v, scale in (("length", args.prior_mm, M_PER_MM), ("angle", args.prior_mrad, RAD_PER_MRAD),
                                              ("offset", args.prior_offset_mrad, RAD_PER_MRAD)) if v is not None}
    if prior:
        if args.method != "best":
            raise ValueError("--prior-mm / --prior-mrad / --prior-offset-mrad apply to --method best only")
        opts["prior"] = prior
    if args.solver is not None:
        if args.method not in ("distance", "fullpose", "separation", "separation_paper"):
            raise ValueError(f"--solver applies to distance, fullpose and separation, not {args.method!r}")
        opts["solver"] = args.solver
    if args.angle_residual is not None:
        if args.method != "separation":
            raise ValueError("--angle-residual applies to --method separation only")
        opts["angle_residual"] = args.angle_residual
    if args.no_robust:
        if args.method != "best":
            raise ValueError("--no-robust applies to --method best only")
        opts["robust"] = False
    return opts


def report(cal, path: Path) -> str:
    """A short text report of a calibration."""
    r = cal.rows
    ida = cal.identifiability
    res = cal.residuals
    lines = [
        f"method {cal.method} on {cal.measurement} data; {len(cal.stations)} station(s); "
        f"{len(r.get('calibration_used', []))} calibration rows used, {len(r.get('calibration_rejected', []))} rejected, "
        f"{len(r.get('validation', []))} validation rows",
    ]
    if ida:
        lines.append(
            f"identifiable: {ida['rank']} of {ida['n_parameters']} parameters; condition number {ida['condition_number']:.3g}, "
            f"O1 {ida['O1']:.3g}, O3 {ida['O3']:.3g}, O4 {ida['O4']:.3g} (column-scaled Jacobian)"
        )
        for c in ida.get("combinations", []):
            lines.append(f"  not identifiable: {c['text']}  ({c['dropped']} {'held at nominal' if c['dropped'] in set(n for n, s in zip(cal.names, cal.status) if s == 'fixed') else 'estimated only in combination'})")
        if ida.get("data_dependent_dropped"):
            lines.append(f"  WARNING: rank deficiency from these configurations: {', '.join(ida['data_dependent_dropped'])}")
    for rej in r.get("calibration_rejected", [])[:10]:
        lines.append(f"  rejected pose_id {rej['pose_id']}: {rej['reason']}")
    nz = cal.noise
    if "position_mm" in nz:
        s = f"noise: position {nz['position_mm']:.4g} mm ({nz.get('position_source', '')})"
        if "orientation_rad" in nz:
            s += f", orientation {nz['orientation_rad']:.4g} rad ({nz.get('orientation_source', '')})"
        if "residual_scale" in nz:
            s += f"; residual scale {nz['residual_scale']:.3f}"
        lines.append(s)

    def fmt(d, key="position_mm", unit="mm"):
        v = d.get(key)
        return "-" if not v else f"mean {v['mean']:.4g} / rms {v['rms']:.4g} / max {v['max']:.4g} {unit}"

    if res.get("validation", {}).get("n_rows"):
        lines.append(f"validation before: {fmt(res['before_calibration']['validation'])}")
        lines.append(f"validation after:  {fmt(res['validation'])}")
        # worse than the nominal robot and than twice the rms the noise and the parameters' uncertainty explain
        b, a = (d.get("position_mm") or {} for d in (res["before_calibration"]["validation"], res["validation"]))
        expected = ((res.get("predicted_validation") or {}).get("expected_residual_rms") or {}).get("position_mm", 0.0)
        if a.get("rms") is not None and b.get("rms") is not None and a["rms"] > max(b["rms"], 2.0 * expected):
            lines.append(f"  WARNING: the calibrated model misses the validation rows by more than the nominal robot does "
                         f"(rms {a['rms']:.4g} mm after, {b['rms']:.4g} mm before): too few or too alike calibration rows "
                         "for the parameters identified; measure more varied poses before using it")
        if "orientation_deg" in res["validation"]:
            lines.append(f"  orientation before: {fmt(res['before_calibration']['validation'], 'orientation_deg', 'deg')}")
            lines.append(f"  orientation after:  {fmt(res['validation'], 'orientation_deg', 'deg')}")
        pv = res.get("predicted_validation")
        if pv:
            lines.append(
                f"  expected rms {pv['expected_residual_rms']['position_mm']:.4g} mm (noise + Cramer-Rao floor; model error "
                f"floor {pv['model_error_rms']['position_mm']:.4g} mm)"
            )
    for n in cal.notes:
        lines.append(f"note: {n}")
    lines.append(f"wrote {path}")
    return "\n".join(lines)


def run(args) -> int:
    from ..dataset import read_dataset
    from ..estimator import calibrate
    from dataclasses import replace

    import numpy as np

    from ..estimator.plausibility import (ImplausibleData, check_fit_miss, check_joints, check_length_unit,
                                          check_plate_rows, fit_beyond_noise, fit_miss, plate_noise)
    from ..estimator.mixture import SPLIT_MIN_REJECTED, SPLIT_MIN_SCALE, split_rows

    ds = read_dataset(args.dataset)
    forced: list[str] = []

    def refuse(exc: ImplausibleData) -> None:
        if not args.force:
            raise ValueError(f"{args.dataset}: {exc}; no calibration written (--force writes it anyway, marked)")
        forced.append(str(exc))

    notes: list[str] = []
    plate = None
    try:
        notes += check_joints(ds)
        if ds.has_spheres:
            plate = check_plate_rows(ds)
            ds = plate.dataset
        check_length_unit(ds)
    except ImplausibleData as exc:
        refuse(exc)
    if plate is not None and (plate.relabelled or plate.flagged):
        notes.append(f"plate check: {len(plate.relabelled)} row(s) relabelled (pose_id {list(plate.relabelled)[:10]}), "
                     f"{len(plate.flagged)} row(s) left out (pose_id {list(plate.flagged)[:10]})")
    cal = calibrate(
        ds,
        method=args.method,
        measurement=args.measurement,
        noise_position=None if args.noise_position_mm is None else args.noise_position_mm * M_PER_MM,
        noise_orientation=args.noise_orientation_rad,
        validation_fraction=args.validation_fraction,
        seed=args.seed,
        use_given_bases=args.use_given_bases,
        **_options(args),
    )
    scale = cal.noise.get("residual_scale")
    fit_rms = (cal.residuals.get("calibration") or {}).get("position_mm", {}).get("rms")
    beyond = {"detected": False}
    miss = None
    try:
        miss = fit_miss(cal, ds)
        check_fit_miss(miss)
        beyond = fit_beyond_noise(
            None if scale is None else float(scale),
            None if fit_rms is None or cal.measurement != "spheres" else float(fit_rms) * M_PER_MM / np.sqrt(3),
            plate_noise(ds) if cal.measurement == "spheres" else None, dataset=str(args.dataset))
    except ImplausibleData as exc:
        refuse(exc)
    if miss is not None:
        beyond = {**beyond, "miss_rms_mm": miss["miss_rms_m"] * MM_PER_M, "motion_spread_mm": miss["spread_m"] * MM_PER_M,
                  "miss_fraction_of_motion": miss["fraction"]}
    n_rejected = len((cal.rows or {}).get("calibration_rejected", []))
    n_rows = n_rejected + len((cal.rows or {}).get("calibration_used", []))
    far = beyond.get("detected") and max(beyond.get("residual_scale") or 0.0,
                                         beyond.get("plate_ratio") or 0.0) >= SPLIT_MIN_SCALE
    if far or n_rejected >= SPLIT_MIN_REJECTED * max(n_rows, 1):
        # far beyond the noise, or many rows rejected: rows of two robots (or stations) mixed fit two models each
        # to the noise (a robust fit rejects a minority robot's rows)
        noise_m = None if cal.noise.get("position_source") == "given" or cal.measurement != "spheres" else plate_noise(ds)
        split = split_rows(cal, ds, noise_m=noise_m)
        beyond = {**beyond, "two_groups": split.summary()}
    details = dict(cal.details)
    details["plausibility"] = {"plate": None if plate is None else plate.summary(), "joints": notes,
                               "forced": forced}
    details["beyond_geometry"] = beyond
    extra = [beyond["text"]] if beyond.get("detected") else []
    if beyond.get("two_groups", {}).get("found"):
        extra.append(beyond["two_groups"]["text"])
    cal = replace(cal, details=details, notes=tuple(cal.notes) + tuple(notes) + tuple(extra)
                  + tuple(f"FORCED: {f}" for f in forced))
    out = Path(args.out)
    path = cal.save(out / "calibration.json")
    if not args.quiet:
        print(report(cal, path))
    elif notes or forced or extra:
        for n in notes + extra + [f"FORCED: {f}" for f in forced]:
            print(f"note: {n}")
    return 0
