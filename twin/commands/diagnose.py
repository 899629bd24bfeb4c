"""``twin diagnose DATASET [--calibration C.json] --out DIR``."""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace

from ..units import MM_PER_M

HELP = "find structure beyond the noise in held-out residuals, trace it to an effect, extend the model, report before/after"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", help="dataset folder (poses.csv + dataset.toml); the held-out rows are a block of time after the "
                   "rows that fit: its 'set' column's validation rows when they are the end of the campaign or whole "
                   "sessions, else the same share at the end (without a 'set' column or validation rows: the last "
                   "30 %%; --holdout: its fraction at the end)")
    p.add_argument("--out", required=True, help="output folder: diagnosis.json, calibration.json, calibration_geometric.json, plots, diagnosis.rrd")
    p.add_argument("--calibration", help="a calibration.json of this robot: checked against the dataset's robot and named in the notes; "
                        "the geometry is identified anew from the nominal model (its values are not used)")
    p.add_argument("--alpha", type=float, default=0.01, help="false-alarm rate of the structure test (default 0.01)")
    p.add_argument("--holdout", type=float, default=None,
                   help="hold out this fraction at the end of the campaign, whatever the 'set' column says (default: "
                        "the 'set' column's validation rows when they are the end of the campaign or whole sessions, "
                        "their share at the end when they interleave; 0.3 without a 'set' column or validation rows)")
    p.add_argument("--seed", type=int, default=0, help="seed of the estimator's random draws")
    p.add_argument("--max-effects", type=int, default=16, help="most terms (atoms) kept in the extended model (default 16)")
    p.add_argument("--catalogue-only", action="store_true",
                   help="select among the catalogue's named terms only (no unnamed dictionary)")
    p.add_argument("--selection", choices=["ordered", "figaroh"], default=None,
                   help="the geometric model's parameters on a URDF chain (as twin calibrate --selection)")
    p.add_argument("--threads", type=int, default=None,
                   help="threads the scoring may use (default: every core this process may run on); the result is the "
                        "same with any number")
    p.add_argument("--force", action="store_true",
                   help="write a diagnosis of too few rows (refused without it: rows that fit give fewer than twice as "
                        "many coordinates as the geometric model's parameters); "
                        "its diagnosis.json then says in its notes that it is not meaningful")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    p.add_argument("--no-recording", action="store_true",
                   help="skip the Rerun recording DIR/diagnosis.rrd (open it with: rerun DIR/diagnosis.rrd)")


# the rows that fit must give this many times as many coordinates as the geometric model has parameters
MIN_EQUATIONS_PER_PARAMETER = 2


def too_few_rows(geo, n_rows: int) -> str:
    """Words when the diagnosis rests on too few rows, empty otherwise: the rows that fit the geometric model ``geo``
    (a :class:`~twin.estimator.Calibration`) give fewer than :data:`MIN_EQUATIONS_PER_PARAMETER` times as many
    coordinates as the parameters a varied campaign identifies (whether or not their configurations leave some of
    them unidentified: a fit of 36 coordinates for 30 parameters leaves 6 degrees of freedom for the noise floor and
    every term). A rank deficiency on many rows (a joint never moved) is a matter of configurations, not of the
    count, and stays a warning."""
    ida = geo.identifiability or {}
    dep = ida.get("data_dependent_dropped") or []
    n_fit = len((geo.rows or {}).get("calibration_used", []))
    if n_fit == 0 or "n_parameters" not in ida or "n_equations" not in ida:
        return ""
    n_par = int(ida["n_parameters"]) - len(ida.get("structural_dropped") or [])
    n_eq = int(ida["n_equations"])
    need = MIN_EQUATIONS_PER_PARAMETER * n_par
    if n_eq >= need:
        return ""
    per_row = n_eq / n_fit
    min_fit = math.ceil(need / per_row)
    what = (f"cannot identify {', '.join(dep)} of its {n_par} parameters" if dep else
            f"fit its {n_par} parameters with {n_eq - n_par} degrees of freedom to spare")
    return (f"too few rows for a diagnosis: {n_rows} rows, {n_fit} of them fit the geometric model; their {n_eq} "
            f"coordinates {what}, and a diagnosis needs at least "
            f"{MIN_EQUATIONS_PER_PARAMETER} coordinates per parameter on the rows that fit: at least {min_fit} rows that "
            f"fit (about {math.ceil(min_fit * n_rows / n_fit)} rows in all with this split) of varied configurations")


def alternative_evidence(d: dict) -> str:
    """What tells an alternative reading ``d`` (an entry of ``diagnosis.json`` ``alternatives``) from the kept term, in
    words: the calibration evidence ``Delta chi2`` of each where both were scored on the same fit, else the
    confirmation rows' RMS of the model with either (``held_out_rms_mm``: the alternative's, the kept model's), and
    ``Delta chi2`` of the alternative alone where only it has one. Never a number that is not one."""
    def finite(v) -> bool:
        return isinstance(v, (int, float)) and math.isfinite(v)

    alt, kept = d.get("delta_chi2"), d.get("delta_chi2_chosen")
    if finite(alt) and finite(kept):
        return f"delta chi2 {alt:.0f} vs {kept:.0f}"
    words = []
    rms = d.get("held_out_rms_mm")
    if isinstance(rms, (list, tuple)) and len(rms) == 2 and all(finite(v) for v in rms):
        words.append(f"confirmation rows {rms[0]:.4g} mm RMS with it vs {rms[1]:.4g} mm as kept")
    if finite(alt):
        words.append(f"delta chi2 {alt:.0f} against the model without the kept term")
    return "; ".join(words) or "no evidence recorded"


def without_temperature_gaps(ds):
    """The dataset ``ds`` without its rows whose ``temp_c`` is empty (the diagnosis reads every row's temperature)
    and the note naming them (empty, and ``ds`` itself, when no row lacks one). A ``temp_c`` column empty in every
    row is dropped instead (the diagnosis then has no temperature). The commanded motion to a left-out row is not
    in the history of the rows after it: their approach directions are read from the row before it."""
    import numpy as np

    from ..dataset import temperature_gaps

    gaps = temperature_gaps(ds.temp_c, ds.pose_id)
    if not gaps:
        return ds, ""
    missing = np.isnan(np.asarray(ds.temp_c, dtype=float))
    if missing.all():
        return replace(ds, temp_c=None), (f"{gaps}: diagnosed without a temperature (no thermal terms)")
    return ds.subset(~missing), (f"{gaps}: those rows are left out of the diagnosis (it reads every row's "
                                 f"temperature); {int((~missing).sum())} rows diagnosed; the rows after a left-out "
                                 "row read their approach direction from the row before it")


def run(args: argparse.Namespace) -> int:
    from ..dataset import read_dataset
    from ..diagnosis import diagnose, read_diagnosis, write_diagnosis
    from ..estimator import Calibration

    from ..estimator.plausibility import ImplausibleData, check_joints, check_plate_rows
    from ..estimator.mixture import SPLIT_MIN_SCALE, split_rows
    from ..runtime import available_cores

    threads = available_cores() if args.threads is None else args.threads
    if threads < 1:
        raise ValueError(f"--threads must be a positive integer, got {args.threads}")
    ds = read_dataset(args.dataset)
    try:
        for n in check_joints(ds):
            print(f"note: {n}", file=sys.stdout)
        plate = check_plate_rows(ds)
    except ImplausibleData as exc:
        raise ValueError(f"{args.dataset}: {exc}; nothing diagnosed") from None
    if plate.relabelled or plate.flagged:
        print(f"note: plate check: {len(plate.relabelled)} row(s) relabelled (pose_id {list(plate.relabelled)[:10]}), "
              f"{len(plate.flagged)} row(s) left out (pose_id {list(plate.flagged)[:10]})", file=sys.stdout)
    ds = plate.dataset
    ds, left_out = without_temperature_gaps(ds)
    cal = Calibration.load(args.calibration) if args.calibration else None
    if cal is not None:
        from ..estimator.register import check_same_robot

        try:
            check_same_robot(cal, ds)
        except ValueError as exc:
            raise ValueError(f"--calibration {args.calibration}: {exc}") from None
    res = diagnose(ds, calibration=cal, alpha=args.alpha, holdout=args.holdout, seed=args.seed,
                   max_effects=args.max_effects, generic=not args.catalogue_only,
                   geometry=None if args.selection is None else {"selection": args.selection}, threads=threads)
    left = res.test_after if res.model_in_use == "extended" and res.test_after is not None else res.test_before
    if left is not None and left.whitened_rms >= SPLIT_MIN_SCALE:
        # the model in use leaves 10x the floor or more: rows of two robots mixed fit two models to the floor; every
        # row is split (the rows the model misses may all be confirmation rows: a second robot's file appended)
        split = split_rows(res.calibration_geometric, ds, noise_m=res.noise.sigma, pose_ids=ds.pose_id)
        res = replace(res, two_groups=split.summary(), notes=tuple(res.notes) + ((split.text,) if split.found else ()))
    few = too_few_rows(res.calibrations_blocked.get("geometric", res.calibration_geometric), ds.n)
    if few and not args.force:
        raise ValueError(f"{args.dataset}: {few}; nothing written (--force writes it, marked as not meaningful)")
    if few:
        res = replace(res, notes=tuple(res.notes) + (f"NOT MEANINGFUL (written with --force): {few}",))
    if left_out:
        res = replace(res, notes=tuple(res.notes) + (left_out,))
    paths = write_diagnosis(res, args.out, plots=not args.no_plots)
    if not args.no_recording:
        # the CLI is where the diagnosis and the evaluation layer (the one Rerun writer) meet; the recording
        # shows exactly what diagnosis.json holds, and the robot of the geometric model fitted on the calibration
        # rows (the model of "before") with the residuals of the held-out rows in the measurement frame
        from ..evaluation.recording import record_diagnosis
        from ..evaluation.workspace import diagnosis_workspace

        ws = diagnosis_workspace(res.series, res.calibrations_blocked.get("geometric", res.calibration_geometric))
        paths["recording"] = record_diagnosis(paths["diagnosis"].with_name("diagnosis.rrd"), res.series,
                                              read_diagnosis(paths["diagnosis"]), workspace=ws)
    b, a = res.before, res.after
    out = sys.stdout
    print(f"noise floor: {res.noise.sigma * MM_PER_M:.5f} mm per coordinate ({res.noise.source})", file=out)
    print(f"structured: {res.structured} (p = {res.p_value:.3g}, alpha = {res.alpha}; {res.test_before.distribution}, "
          f"whitened RMS {res.test_before.whitened_rms:.3f})", file=out)
    print(f"effects: {', '.join(res.effects) if res.effects else 'none'}"
          + (f"; explained {100 * res.explained_fraction:.0f} % of the held-out excess" if res.atoms else ""), file=out)
    for term in res.atoms:
        print(f"  term: {term['text']}" + ("  [minor]" if term.get("minor") else ""), file=out)
    for term in res.candidate_terms:
        print(f"  candidate term (not adopted): {term['text']}", file=out)
    ad = res.adoption
    if ad is not None:
        c = ad["confirmation_rms_mm"]
        print(f"model to use: {res.model_in_use} (confirmation block, a later block of time or another session: "
              f"geometric {c['geometric']:.4g} mm, extended {c['extended']:.4g} mm RMS)", file=out)
    for d in res.alternatives:
        print(f"  alternative to '{d['of']}': {d['alternative']} ({alternative_evidence(d)}; the data cannot tell "
              f"them apart)", file=out)
    for n in res.notes:
        print(f"note: {n}", file=out)
    geo = res.calibrations_blocked.get("geometric", res.calibration_geometric)
    dep = (geo.identifiability or {}).get("data_dependent_dropped")
    if dep:
        print(f"WARNING: rank deficiency from these configurations: {', '.join(dep)} fixed at nominal in the geometric "
              "model of the rows that fit: too few or too alike rows, and every figure below rests on that model; "
              "measure more varied configurations", file=out)
    h = res.held_out
    rows = (f"{h.get('n_report_rows')} report rows, a block of time after every row that chose or fitted the model"
            if h.get("before_after_on") == "report" else "the confirmation rows (too few held-out rows for a report block)")
    print(f"held-out error on {rows}", file=out)
    print("                        before             after", file=out)
    for key, unit in (("position_mm", "mm"), ("orientation_deg", "deg")):
        if key in b:
            for stat in ("mean", "rms", "max"):
                print(f"  {key.split('_')[0]:<11} {stat:<4} {b[key][stat]:>12.5f} {unit:<3}  {a[key][stat]:>12.5f} {unit}", file=out)
    print(f"wrote {paths['diagnosis']}", file=out)
    if "recording" in paths:
        print(f"wrote {paths['recording']} (open with: rerun {paths['recording']})", file=out)
    return 0
