"""The TIAGo motion-capture study: calibrate a real robot on one day, score on another, beside FIGAROH.

Run from the repository root::

    .venv/bin/python studies/tiago_mocap/run.py

It imports the committed campaign (``data/tiago_mocap``) with ``twin import`` (into a temporary folder), calibrates
it at every parameter level with ``twin.estimator.calibrate``, runs FIGAROH itself on the same files when it is
installed (the ``peers`` extra), and writes ``studies/tiago_mocap/results/results.json`` (with a ``provenance``
block), ``results/table.md`` and the ``real_data`` section of ``results/benchmark.json``; then the prototype of
non-geometric effects (``effects_run.py``: ``results/effects.json``, ``results/effects.md``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
import tomllib
from pathlib import Path

from twin.runtime import set_process_defaults  # noqa: E402
from twin.units import MM_PER_M, MRAD_PER_RAD, rad_to_deg  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
sys.path.insert(0, str(HERE))

from protocol import GROUPS, by_group, split_validation, stats  # noqa: E402

LEVELS = (  # (row name, calibrate options)
    ("base + tool only", {"level": "frames", "robust": False}),
    ("joint offsets", {"level": "offsets", "robust": False}),
    ("full geometric", {"level": "full", "robust": False}),
    ("full geometric, FIGAROH's parameter selection", {"level": "full", "robust": False, "selection": "figaroh"}),
    ("our default (best)", {}),
)
# Gaussian priors on the geometric deviations (MAP) tried by cross-validation on the training day only
PRIORS = ({"length": 5e-3, "angle": 20e-3}, {"length": 2e-3, "angle": 10e-3}, {"length": 1e-3, "angle": 5e-3},
          {"length": 0.5e-3, "angle": 2e-3})
CV_FOLDS = 6


def cv_rmse(ds, opts: dict, folds: int = CV_FOLDS) -> float:
    """RMSE [mm] over the training rows of a ``folds``-fold cross-validation (postures in file order, every
    ``folds``-th to the same fold) of ``calibrate(.., **opts)`` on the training day alone."""
    from dataclasses import replace

    from twin.estimator import calibrate

    tr = ds.subset(np.flatnonzero(ds.set == "calibration"))
    fold = np.arange(tr.n) % folds
    errs = []
    for f in range(folds):
        part = replace(tr, set=np.where(fold == f, "validation", "calibration").astype(object))
        cal = calibrate(part, "best", **opts)
        m = fold == f
        errs.append(point_errors(cal.predict(part.q[m], part.station_ids[m]).spheres, part.spheres[m]).ravel())
    e = np.concatenate(errs)
    return float(np.sqrt(np.mean(e**2)))


def point_errors(pred: np.ndarray, meas: np.ndarray) -> np.ndarray:
    """Per-point 3-D errors ``(n, K)`` [mm]."""
    return np.linalg.norm(pred - meas, axis=-1) * MM_PER_M


def selection_cv(ds) -> dict:
    """Our full-level parameter selection against FIGAROH's, judged on the training day alone: the 6-fold CV of the
    study (every 6th posture in file order) and leave-one-posture-out. The default for chains changes only when
    FIGAROH's wins both on both data variants (this function gives one variant's figures)."""
    out = {}
    for sel in ("ordered", "figaroh"):
        o = {"level": "full", "robust": False, "selection": sel}
        out[sel] = {"cv_6fold_rmse_mm": cv_rmse(ds, o), "cv_leave_one_out_rmse_mm": cv_rmse(ds, o, folds=int(np.sum(ds.set == "calibration")))}
    return out


def nominal_errors(ds) -> np.ndarray:
    """Errors ``(n, K)`` [mm] of the nominal robot and tool with the base registered on the calibration rows (the
    estimator's starting point, 'before calibration')."""
    from twin.estimator.core import prepare
    from twin.estimator.problem import predict_points

    prep = prepare(ds)
    pts, _ = predict_points(prep.space, prep.x_nominal, ds.q, np.zeros(ds.n, int), prep.obs.spheres_tool)
    return point_errors(pts, ds.spheres)


def evaluate(cal, ds, cal_rows, val_rows, group, points) -> dict:
    """Training and validation statistics of a calibration on the points ``points`` (indices)."""
    pred = cal.predict(ds.q, ds.station_ids).spheres
    e = point_errors(pred, ds.spheres)[:, points]
    return {"training": stats(e[cal_rows]), "validation": by_group(e[val_rows], group)}


def identified(cal) -> dict:
    names = [n for n, s in zip(cal.names, cal.status) if s == "identified"]
    return {"n": len(names), "names": names, "not_identifiable": [c.describe() for c in cal.combinations]}


def variant_rows(variant: str, ds, points, group, timings: dict) -> list[dict]:
    from twin.estimator import calibrate

    cal_rows = np.flatnonzero(ds.set == "calibration")
    val_rows = np.flatnonzero(ds.set == "validation")
    e0 = nominal_errors(ds)[:, points]
    rows = [{"variant": variant, "model": "nominal (base registered)", "parameters": 0,
             "training": stats(e0[cal_rows]), "validation": by_group(e0[val_rows], group)}]
    for name, opts in LEVELS:
        t0 = time.perf_counter()
        cal = calibrate(ds, "best", **opts)
        dt = time.perf_counter() - t0
        timings.setdefault(variant, {})[name] = dt
        r = {"variant": variant, "model": name, "options": opts, "parameters": identified(cal)["n"],
             "identified": identified(cal), "rejected_rows": len(cal.rows.get("calibration_rejected", [])),
             "seconds": dt, **evaluate(cal, ds, cal_rows, val_rows, group, points)}
        offs = {n: cal.value(n) * 1e3 for n, s in zip(cal.names, cal.status) if s == "identified" and n.endswith(".offset")}
        r["joint_offsets_mrad_or_mm"] = offs
        rows.append(r)
    # full level with a prior on the geometric deviations, its scale chosen by cross-validation on the training day
    sweep = [{"prior": None, "cv_rmse_mm": cv_rmse(ds, {"level": "full", "robust": False})}]
    for pr in PRIORS:
        sweep.append({"prior": pr, "cv_rmse_mm": cv_rmse(ds, {"level": "full", "robust": False, "prior": pr})})
    best = min(sweep, key=lambda x: x["cv_rmse_mm"])
    for sw in sweep:  # every scale scored on the validation day too, for the record (not used to choose)
        if sw["prior"] is None:
            continue
        cal = calibrate(ds, "best", level="full", robust=False, prior=sw["prior"])
        sw.update(evaluate(cal, ds, cal_rows, val_rows, group, points))
    if best["prior"] is not None:
        opts = {"level": "full", "robust": False, "prior": best["prior"]}
        t0 = time.perf_counter()
        cal = calibrate(ds, "best", **opts)
        dt = time.perf_counter() - t0
        rows.append({"variant": variant, "model": f"full + prior {best['prior']['length'] * MM_PER_M:g} mm / "
                     f"{best['prior']['angle'] * MRAD_PER_RAD:g} mrad (CV on training day)", "options": opts,
                     "parameters": identified(cal)["n"], "identified": identified(cal), "seconds": dt,
                     "prior_sweep": sweep, **evaluate(cal, ds, cal_rows, val_rows, group, points)})
    else:
        rows[-2]["prior_sweep"] = sweep
    return rows


def repeatability(ds, tolerance: float) -> dict:
    """Model-free day-to-day repeatability: each replayed validation posture's measured points against the
    training measurement of the same posture (as measured, and after the best rigid motion between the days)."""
    from twin.estimator.problem import kabsch
    from twin.transforms import matrix_to_rotvec

    cal = ds.set == "calibration"
    T, V = ds.q[cal], ds.q[~cal]
    d = np.abs(V[:, None] - T[None]).max(axis=-1)
    j, rep = d.argmin(axis=1), d.min(axis=1) <= tolerance
    A = ds.spheres[cal][j[rep]]
    B = ds.spheres[~cal][rep]
    e_raw = point_errors(A, B)
    R, t = kabsch(A.reshape(-1, 3), B.reshape(-1, 3))
    e_rigid = np.linalg.norm(A.reshape(-1, 3) @ R.T + t - B.reshape(-1, 3), axis=-1) * MM_PER_M
    return {"postures": int(rep.sum()), "as_measured": stats(e_raw), "after_rigid_motion": stats(e_rigid),
            "rigid_motion": {"translation_mm": (t * MM_PER_M).tolist(), "rotation_deg": float(rad_to_deg(np.linalg.norm(matrix_to_rotvec(R))))}}


def figaroh_rows(cfg: dict, group: np.ndarray, urdf: Path, training: Path, validation: Path, joints) -> tuple[list, str | None]:
    import figaroh_peer

    why = figaroh_peer.available()
    if why is not None:
        return [], why
    rows = []
    for level, name in (("joint_offset", "joint offsets"), ("full_params", "full geometric")):
        import contextlib
        import io

        with contextlib.redirect_stdout(io.StringIO()):  # FIGAROH prints its quality report
            r = figaroh_peer.run_figaroh(urdf, training, validation, cfg["protocol"]["end_link"], list(joints), level)
        e_val = np.asarray(r["validation_errors_mm"])[:, None]
        rows.append({"variant": "marker 1 only", "model": name, "tool": f"FIGAROH {level} (run here)",
                     "parameters": r["n_parameters"], "parameter_names": r["parameters"], "seconds": r["seconds"],
                     "training": stats(r["training_errors_mm"]), "validation": by_group(e_val, group),
                     "figaroh_reported_training_rmse_mm": r["reported_rmse_mm"],
                     "values": dict(zip(r["parameters"], r["values"]))})
    return rows, None


def _fmt(s: dict | None) -> str:
    if not s or s.get("rmse") is None:
        return "-"
    return f"{s['rmse']:.2f} / {s['max']:.1f}"


def table(results: dict) -> str:
    q = results["figaroh_quoted"]
    lines = ["# TIAGo motion capture: train on 2021-11-30, score on 2021-11-26", "",
             "RMSE / max of the 3-D error per point [mm]. Validation postures split as FIGAROH splits them: "
             f"{results['split']['counts']['replayed']} replayed from training, "
             f"{results['split']['counts']['new_in_range']} new inside the training ranges, "
             f"{results['split']['counts']['outside']} outside (definitions in config.toml; the source reports "
             f"{q['counts_replayed'][0]}-{q['counts_replayed'][1]} / {q['counts_new_in_range'][0]}-{q['counts_new_in_range'][1]} / "
             f"{q['counts_outside'][0]}-{q['counts_outside'][1]} for its held-out sessions).", "",
             "| data | model | tool | parameters | training | validation all | replayed | new in range | outside |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in results["rows"]:
        v = r["validation"]
        lines.append(f"| {r['variant']} | {r['model']} | {r.get('tool', 'ours')} | {r['parameters']} | {_fmt(r['training'])} | "
                     f"{_fmt(v['all'])} | {_fmt(v['replayed'])} | {_fmt(v['new_in_range'])} | {_fmt(v['outside'])} |")
    lines.append(f"| marker 1 only | joint offsets | FIGAROH, quoted | {q['joint_offsets_parameters']} | "
                 f"{q['joint_offsets_training_rmse_mm']:.2f} / - | {q['joint_offsets_validation_rmse_mm']:.2f} / "
                 f"{q['joint_offsets_validation_max_mm']:.1f} | - | - | {q['offsets_outside_rmse_mm'][0]:g}-{q['offsets_outside_rmse_mm'][1]:g} / - |")
    lines.append(f"| marker 1 only | full geometric | FIGAROH, quoted | {q['full_parameters']} | - | - | - | "
                 f"{q['full_new_in_range_rmse_mm'][0]:g}-{q['full_new_in_range_rmse_mm'][1]:g} / - | "
                 f"{q['full_outside_rmse_mm'][0]:g}-{q['full_outside_rmse_mm'][1]:g} / - |")
    ours = next(r for r in results["rows"] if r["model"] == "joint offsets" and "tool" not in r)
    a5 = ours["joint_offsets_mrad_or_mm"].get("arm_5_joint.offset")
    fig = next((r for r in results["rows"] if r.get("tool", "").startswith("FIGAROH joint")), None)
    fa5 = None if fig is None else fig["values"].get("offsetRZ_arm_5_joint")
    lines += ["", f"arm_5 offset at the joint-offset level (marker 1): ours {a5:.2f} mrad"
              + ("" if fa5 is None else f", FIGAROH run here {fa5 * MRAD_PER_RAD:.2f} mrad")
              + f", FIGAROH quoted {q['joint_offsets_arm_5_offset_mrad']:g} mrad."]
    rep = results["repeatability"]
    lines += ["", f"Day-to-day repeatability without any model: the {rep['postures']} replayed postures measured on both days "
              f"differ by {_fmt(rep['as_measured'])} mm per point (RMSE / max), {_fmt(rep['after_rigid_motion'])} mm after "
              f"the best rigid motion between the days ({np.linalg.norm(rep['rigid_motion']['translation_mm']):.2f} mm, "
              f"{rep['rigid_motion']['rotation_deg']:.3f} deg)."]
    sel = results.get("parameter_selection_cv")
    if sel:
        parts, wins = [], True
        for variant, v in sel.items():
            o, f = v["ordered"], v["figaroh"]
            parts.append(f"{variant}: ours {o['cv_6fold_rmse_mm']:.2f} / {o['cv_leave_one_out_rmse_mm']:.2f}, FIGAROH's "
                         f"{f['cv_6fold_rmse_mm']:.2f} / {f['cv_leave_one_out_rmse_mm']:.2f}")
            wins &= f["cv_6fold_rmse_mm"] < o["cv_6fold_rmse_mm"] and f["cv_leave_one_out_rmse_mm"] < o["cv_leave_one_out_rmse_mm"]
        lines += ["", "Full-level parameter selection judged on the training day alone (RMSE of the data variant's points [mm], 6-fold CV / "
                  "leave-one-posture-out): " + "; ".join(parts) + ". " +
                  ("FIGAROH's selection wins both on both data variants." if wins else
                   "FIGAROH's selection does not win both on both data variants: our default keeps the ordered selection "
                   "(FIGAROH's is `selection='figaroh'`, `twin calibrate --selection figaroh`).")]
    if results.get("figaroh_unavailable"):
        lines += ["", f"FIGAROH could not run here ({results['figaroh_unavailable']}): its figures are quoted only."]
    return "\n".join(lines) + "\n"


def diagnosis_rows(diag: dict, group: np.ndarray) -> list[dict]:
    """The table rows of the diagnosis (``diagnosis_run.py``): ``twin diagnose``'s extended model on the hand's four
    points and on marker 1 with FIGAROH's selection, and the confirmed physical terms together, each trained on
    2021-11-30 and scored on 2021-11-26 (point 1)."""
    d0 = diag["directions"][0]
    rows = []
    for r in diag["diagnose"]:
        if r["direction"] != d0 or not r["generic"]:
            continue
        variant = "four points, scored on marker 1" if r["data"] == "four points" else "marker 1 only"
        model = "twin diagnose, extended" + ("" if r["geometry"] == "default" else " (FIGAROH's parameter selection)")
        rows.append({"variant": variant, "model": model, "parameters": "+" + str(len(r["terms"])) + " terms",
                     "terms": [t["label"] for t in r["terms"]], "training": r["other_day"]["extended"]["training_marker1"],
                     "validation": r["other_day"]["extended"]["marker1"]})
    pm = diag["physical_model"]
    for k, f in pm.get("fits", {}).items():
        if not k.endswith(d0):
            continue
        variant = "four points, scored on marker 1" if k.startswith("four points") else "marker 1 only"
        geo = "" if k.startswith("four points") else " (FIGAROH's parameter selection)"
        rows.append({"variant": variant, "model": "physical terms confirmed on the other day" + geo,
                     "parameters": "+" + str(len(pm["terms"])) + " terms", "terms": pm["terms"],
                     "training": f["extended"]["training_marker1"], "validation": f["extended"]["marker1"]})
    return rows


def diagnose_benchmark(runs: int = 3) -> dict:
    """``twin diagnose`` on the imported campaign (the user's command: plots and recording included), median of
    ``runs`` runs [s]."""
    import subprocess

    cfg = tomllib.loads((HERE / "config.toml").read_text())
    p = cfg["protocol"]
    data = ROOT / "data" / "tiago_mocap"
    twin = str(Path(sys.executable).with_name("twin"))
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([twin, "import", str(data / p["training"]), "--validation", str(data / p["validation"]),
                        "--urdf", str(data / p["urdf"]), "--root", p["root_link"], "--end", p["end_link"],
                        "--out", str(Path(tmp) / "ds")], check=True, capture_output=True)
        for k in range(runs):
            t0 = time.perf_counter()
            subprocess.run([twin, "diagnose", str(Path(tmp) / "ds"), "--out", str(Path(tmp) / f"d{k}")], check=True,
                           capture_output=True)
            times.append(time.perf_counter() - t0)
    return {"what": "twin diagnose DATASET --out DIR on the imported campaign (defaults; plots and recording included; "
                    "process start included)", "median_s": float(np.median(times)), "runs_s": times, "target_s": 30.0,
            "meets_target": bool(np.median(times) <= 30.0)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(HERE / "results"), help="results folder (default studies/tiago_mocap/results)")
    ap.add_argument("--no-figaroh", action="store_true", help="do not run FIGAROH (its figures are quoted only)")
    ap.add_argument("--no-benchmark", action="store_true", help="do not write the real_data benchmark section")
    ap.add_argument("--prototype", action="store_true",
                    help="also rerun the earlier hand-made prototype of non-geometric effects (effects_run.py)")
    ap.add_argument("--no-recording", action="store_true", help="do not write results/tiago_mocap.rrd")
    args = ap.parse_args(argv)
    load = os.getloadavg()
    from twin.benchio import provenance, update_benchmark_section
    from twin.importers.mocap import import_mocap

    cfg = tomllib.loads((HERE / "config.toml").read_text())
    p = cfg["protocol"]
    data = ROOT / "data" / "tiago_mocap"
    urdf, training, validation = data / p["urdf"], data / p["training"], data / p["validation"]
    files = [(training, "calibration"), (validation, "validation")]
    timings: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        ds4 = import_mocap(files, urdf, p["root_link"], p["end_link"], Path(tmp) / "body4")
        import_s = time.perf_counter() - t0
        ds1 = import_mocap(files, urdf, p["root_link"], p["end_link"], Path(tmp) / "marker1", points=[1])
        from twin.dataset import read_dataset

        ds4, ds1 = read_dataset(Path(tmp) / "body4"), read_dataset(Path(tmp) / "marker1")
    cal = ds4.set == "calibration"
    group, nearest, beyond = split_validation(ds4.q[cal], ds4.q[~cal], p["replay_tolerance"], p["range_margin"])
    rows = variant_rows("marker 1 only", ds1, [0], group, timings)
    rows += variant_rows("four points, scored on marker 1", ds4, [0], group, timings)
    rows += variant_rows("four points", ds4, [0, 1, 2, 3], group, timings)
    fig_rows, why = ([], "not run (--no-figaroh)") if args.no_figaroh else figaroh_rows(
        cfg, group, urdf, training, validation, ds4.robot.joint_names)
    rows += fig_rows
    import diagnosis_run

    diag = diagnosis_run.main(recording=not args.no_recording)
    rows += diagnosis_rows(diag, group)
    results = {
        "question": "Does a calibration of the real TIAGo on one day predict another day's postures as well as FIGAROH's, "
                    "at the same parameter level, and what remains?",
        "command": ".venv/bin/python studies/tiago_mocap/run.py",
        "data": {"training": p["training"], "validation": p["validation"], "urdf": p["urdf"],
                 "provenance": ds4.provenance, "rows": {"training": int(cal.sum()), "validation": int((~cal).sum())}},
        "split": {"definition": {"replay_tolerance": p["replay_tolerance"], "range_margin": p["range_margin"]},
                  "counts": {g: int(np.sum(group == g)) for g in GROUPS}, "group": group.tolist(),
                  "nearest_training_posture": nearest.tolist(), "beyond_training_range": beyond.tolist()},
        "rows": rows,
        "figaroh_unavailable": why,
        "figaroh_quoted": cfg["figaroh_quoted"],
        "repeatability": repeatability(ds4, p["replay_tolerance"]),
        "parameter_selection_cv": {"marker 1 only": selection_cv(ds1), "four points": selection_cv(ds4)},
        "diagnosis": "results/diagnosis.json (diagnosis_run.py)",
        "timings_s": {"import": import_s, "calibrate": timings},
        "provenance": provenance(load),
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(results, indent=1) + "\n")
    (out / "table.md").write_text(table(results))
    if not args.no_benchmark:
        from twin.estimator import calibrate

        runs = []
        for _ in range(3):
            t0 = time.perf_counter()
            calibrate(ds4)
            runs.append(time.perf_counter() - t0)
        update_benchmark_section("real_data", {
            "dataset": "TIAGo motion capture (data/tiago_mocap): 37 training + 62 validation rows, 8 joints, 4 points",
            "calibrate": {"what": "twin.estimator.calibrate(dataset) with the defaults (best, full level, robust)",
                          "median_s": float(np.median(runs)), "runs_s": runs, "target_s": 30.0,
                          "meets_target": bool(np.median(runs) <= 30.0)},
            "diagnose": diagnose_benchmark(),
            "provenance": provenance(load),
        })
    print(table(results))
    if args.prototype:
        import effects_run

        effects_run.main()
    return 0


if __name__ == "__main__":
    sys.exit(main())
