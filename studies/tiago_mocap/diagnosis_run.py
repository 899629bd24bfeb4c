"""The diagnosis of the TIAGo campaign, validated on the other day (``run.py`` calls it; alone:
``.venv/bin/python studies/tiago_mocap/diagnosis_run.py``).

Three parts, each trained on one day and judged on the other, in both directions (2021-11-30 -> 2021-11-26, the
study's protocol, and 2021-11-26 -> 2021-11-30):

1. ``twin diagnose`` itself (:func:`twin.diagnosis.diagnose`, the library's defaults; and with the catalogue's
   named terms only): its structure test, floor, kept terms and before/after on its report rows (held out, used for
   nothing else), and its geometric and extended calibrations scored on every row of the other day;
2. the physical account: every physical candidate of the catalogue for this chain (compliance under the load the
   URDF masses give, the tilt of each joint's support and of the base under the moment it carries, backlash of every
   joint, the prismatic torso's travel scale), each fitted alone with the geometry
   (:func:`twin.diagnosis.fit_with_effects`) on one day and scored on the other. A term is *confirmed on the other
   day* when, in both directions, it lowers the other day's RMSE and its fitted coefficients keep their signs;
3. the physical model: the confirmed terms together, fitted on one day and scored on the other (both directions),
   on the default geometry and on FIGAROH's parameter selection; what each term explains (the model without it);
   and a Rerun recording of the real campaign (git-ignored): the robot from the URDF, measured and predicted points,
   the error per posture before and after.

The selection of part 3 is made on the other day's errors (as the diagnosis' confirmation rows are): its validation
figures are not those of an untouched held-out set; the diagnosis' report rows (part 1) are.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
import tomllib
from pathlib import Path

from twin.runtime import set_process_defaults  # noqa: E402
from twin.units import MM_PER_M  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
sys.path.insert(0, str(HERE))

from protocol import by_group, split_validation, stats  # noqa: E402

DIRECTIONS = ("2021-11-30 -> 2021-11-26", "2021-11-26 -> 2021-11-30")


def import_days(tmp: Path, cfg: dict) -> dict:
    """The campaign imported four ways: ``(direction, variant)`` with ``variant`` ``"points"`` (the hand's four points)
    or ``"marker1"``; the training day's file first (measurement order)."""
    from twin.dataset import read_dataset
    from twin.importers.mocap import import_mocap

    p = cfg["protocol"]
    data = ROOT / "data" / "tiago_mocap"
    fwd = [(data / p["training"], "calibration"), (data / p["validation"], "validation")]
    rev = [(data / p["validation"], "calibration"), (data / p["training"], "validation")]
    out = {}
    for d, files in zip(DIRECTIONS, (fwd, rev)):
        for variant, pts in (("points", None), ("marker1", [1])):
            folder = tmp / f"{len(out)}"
            import_mocap(files, data / p["urdf"], p["root_link"], p["end_link"], folder, points=pts)
            out[(d, variant)] = read_dataset(folder)
    return out


def groups_of(ds, p: dict) -> np.ndarray:
    cal = ds.set == "calibration"
    return split_validation(ds.q[cal], ds.q[~cal], p["replay_tolerance"], p["range_margin"])[0]


def predicted(cal, ds) -> np.ndarray:
    """Points ``(n, K, 3)`` [m] a (possibly extended) calibration predicts for every row of ``ds``."""
    from twin.diagnosis import row_context
    from twin.diagnosis.apply import predict_extended

    return predict_extended(cal, row_context(ds), ds.station_ids).spheres


def scores(cal, ds, group) -> dict:
    """Errors on the other day's rows by FIGAROH's groups: ``marker1`` (point 1) and ``points`` (all points), and the
    training RMSE on point 1."""
    e = np.linalg.norm(predicted(cal, ds) - ds.spheres, axis=-1) * MM_PER_M
    v = ds.set == "validation"
    return {"marker1": by_group(e[v][:, :1], group), "points": by_group(e[v], group),
            "training_marker1": stats(e[~v][:, :1])}


def run_diagnose(ds, group, *, generic: bool, geometry: dict | None) -> dict:
    from twin.diagnosis import diagnose

    t0 = time.perf_counter()
    res = diagnose(ds, generic=generic, geometry=geometry)
    dt = time.perf_counter() - t0
    tb = res.test_before
    return {
        "seconds": dt, "structured": res.structured, "p_value": res.p_value,
        "test": {"statistic": tb.statistic, "dof": tb.dof, "distribution": tb.distribution, "whitened_rms": tb.whitened_rms},
        "noise_floor_mm": res.noise.sigma * MM_PER_M, "noise_floor_source": res.noise.source,
        "terms": [{"label": a["label"], "family": a["family"], "text": a["text"], "minor": a["minor"]} for a in res.atoms],
        "effects": list(res.effects), "alternatives": [{"of": a["of"], "alternative": a["alternative"]} for a in res.alternatives],
        "explained_fraction": res.explained_fraction, "notes": list(res.notes), "model_in_use": res.model_in_use,
        "candidate_terms": [a["text"] for a in res.candidate_terms],
        "geometry_chosen": next((n for n in res.notes if n.startswith("geometric parameter set chosen")), None),
        "report_rows": {"n": res.held_out.get("n_report_rows"), "before": res.before["position_mm"],
                        "after": res.after["position_mm"]},
        # the models fitted on the training day alone (calibration.json is refitted on both days: not for scoring here)
        "other_day": {"geometric": scores(res.calibrations_blocked["geometric"], ds, group),
                      "extended": scores(res.calibrations_blocked["extended"], ds, group)},
    }, res


def physical_candidates(ds) -> list:
    """The catalogue's physical candidates for this chain (labels are the diagnosis' own)."""
    from twin.diagnosis import catalogue_atoms, row_context
    from twin.diagnosis.diagnose import link_lengths

    cat = catalogue_atoms(ds.robot, row_context(ds), link_lengths(ds.robot), n_points=ds.spheres.shape[1])
    keep = []
    for a in cat:
        kinds = {f.kind for f in a.features}
        prismatic = a.place == "joint" and ds.robot.joint_kinds[int(a.target[5:]) - 1] == "prismatic"
        if (a.family == "compliance" and kinds == {"torque"}) or a.family == "tilt" or \
                (a.family == "backlash" and kinds == {"sign"}) or (a.family == "gear_ratio" and prismatic):
            keep.append(a)
    return keep


def fit_terms(ds, group, labels, geometry=None) -> dict:
    """The geometry extended by the named catalogue terms, fitted on ``ds``'s training day; scored on its other day."""
    from twin.diagnosis import fit_with_effects

    by = {a.label: a for a in physical_candidates(ds)}
    f = fit_with_effects(ds, [by[k] for k in labels], geometry=geometry)
    coef = {k: [float(x) for x in v["values"]] for k, v in f.effect_parameters.items()}
    return {"coefficients_si": coef, "geometric": scores(f.calibration_geometric, ds, group),
            "extended": scores(f.calibration, ds, group), "calibration": f.calibration,
            "calibration_geometric": f.calibration_geometric}


def account(days: dict, groups: dict) -> list[dict]:
    """Each physical candidate alone, both directions (four points, the default geometry): the diagnosis' own test
    of a term against the geometric fit (:func:`twin.diagnosis.scoring.score_atoms`, :func:`~twin.diagnosis.confirm.confirm`,
    :func:`twin.diagnosis.diagnose.implausible_size`: significant on the training day, confirmed on the other day's
    confirmation rows with ``z > 3`` also without the most favourable row and a lower held-out error, of a physical
    size), and the other day's marker-1 RMSE with the term. *Confirmed on the other day*: it passes in both
    directions."""
    from twin.diagnosis.diagnose import atom_pool, evidence_scale, fit_geometry, implausible_size, prepare_diagnosis
    from twin.diagnosis.confirm import confirm
    from twin.diagnosis.scoring import score_atoms

    tests = {}
    for d in DIRECTIONS:
        setup = prepare_diagnosis(days[(d, "points")])
        prob = setup.problem
        base = fit_geometry(prob, setup.x0)
        evidence_scale(prob, base)
        pool, sizes = atom_pool(setup, generic=True)
        labels = {a.label for a in physical_candidates(days[(d, "points")])}
        for a in pool:
            if a.label not in labels:
                continue
            got = score_atoms(prob, base, [a], sizes, exact_top=1)
            if not got:
                tests[(d, a.label)] = {"significant": False, "z": None, "better": None, "implausible": None}
                continue
            s = got[0]
            c = confirm(prob, base, s, 3.0)
            tests[(d, a.label)] = {"p_adjusted": float(np.exp(s.logp_adj)), "significant": bool(s.logp_adj < np.log(0.01)),
                                   "z": c.z, "z_without_best_row": c.z_without_best_row, "better": bool(c.better),
                                   "implausible": implausible_size(prob, a, s.basis @ s.psi)}
    out = []
    for lab in [a.label for a in physical_candidates(days[(DIRECTIONS[0], "points")])]:
        row = {"term": lab, "directions": {}}
        ok = []
        for d in DIRECTIONS:
            r = fit_terms(days[(d, "points")], groups[d], [lab])
            t = tests.get((d, lab), {"significant": False})
            passed = bool(t.get("significant") and t.get("z") is not None and t["z"] > 3 and t["z_without_best_row"] > 3
                          and t["better"] and t["implausible"] is None)
            ok.append(passed)
            row["directions"][d] = {"coefficients_si": r["coefficients_si"][lab], "test": t, "kept_by_the_rule": passed,
                                    "geometric_marker1_rmse": r["geometric"]["marker1"]["all"]["rmse"],
                                    "extended_marker1_rmse": r["extended"]["marker1"]["all"]["rmse"],
                                    "extended_marker1": r["extended"]["marker1"]}
        row["confirmed_on_the_other_day"] = all(ok)
        row["rule"] = ("the diagnosis' test of a term, alone against the geometric fit, passed in both directions: "
                       "significant on the training day, z > 3 on the other day's confirmation rows (also without the "
                       "most favourable row), a lower error there, a physical size")
        out.append(row)
    return out


def physical_model(days: dict, groups: dict, labels: list[str]) -> dict:
    """The confirmed terms together, both directions, on the default geometry (four points; point 1 scored) and on
    FIGAROH's selection (marker 1); what each term explains (the model without it, default geometry, forward)."""
    out = {"terms": labels, "fits": {}}
    for name, variant, geometry in (("four points, default geometry", "points", None),
                                    ("marker 1, FIGAROH's parameter selection", "marker1", {"selection": "figaroh"})):
        for d in DIRECTIONS:
            r = fit_terms(days[(d, variant)], groups[d], labels, geometry)
            out["fits"][f"{name}; {d}"] = {k: v for k, v in r.items() if not k.startswith("calibration")}
            if d == DIRECTIONS[0]:
                out.setdefault("calibrations", {})[name] = r
    drop = {}
    d0 = DIRECTIONS[0]
    for lab in labels:
        rest = [x for x in labels if x != lab]
        r = fit_terms(days[(d0, "points")], groups[d0], rest) if rest else None
        drop[lab] = None if r is None else r["extended"]["marker1"]["all"]["rmse"]
    out["without_each_term_marker1_rmse"] = drop
    return out


def record(path: Path, ds, group, geo_cal, ext_cal, summary: str) -> Path:
    """The real campaign as a Rerun recording through the one module that imports rerun."""
    from twin.evaluation.recording import record_measured_campaign
    from twin.kinematics import link_frames

    model = ext_cal.model(ext_cal.space.stations[0])
    origins = link_frames(model, ds.q, frame="meas")[:, :, :3, 3]
    meas = np.where(ds.sphere_seen[..., None], ds.spheres, np.nan)
    val = ds.set == "validation"
    g = np.full(ds.n, "training", dtype=object)
    g[val] = group
    return record_measured_campaign(path, joint_origins_m=origins, measured_m=meas,
                                    predicted_m={"geometric": predicted(geo_cal, ds), "extended": predicted(ext_cal, ds)},
                                    posture_ids=ds.pose_id, groups=[str(x) for x in g], summary_markdown=summary)


def _f(s: dict | None) -> str:
    return "-" if not s or s.get("rmse") is None else f"{s['rmse']:.2f} / {s['max']:.1f}"


def markdown(res: dict) -> str:
    d0, d1 = DIRECTIONS
    L = ["# The diagnosis of the TIAGo campaign, validated on the other day", "",
         "RMSE / max of the 3-D error of point 1 [mm] on the other day's rows, split as FIGAROH splits them.", "",
         "## 1. twin diagnose", "",
         "The held-out rows are the other day: its earlier rows confirm the terms, its last fifth reports (a block of "
         "time used for nothing else). `geometry` default: the parameter set chosen on the confirmation block "
         "(blocked cross-validation).", "",
         "| data | trained -> scored | dictionary | geometry | floor [mm] | structure test | kept terms | model to use | "
         "report rows before -> after | other day: geometric | other day: model to use |",
         "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in res["diagnose"]:
        t = "; ".join(x["label"] + (" (minor)" if x["minor"] else "") for x in r["terms"]) or "none"
        if r.get("candidate_terms"):
            t += " (candidates, not adopted: " + "; ".join(r["candidate_terms"]) + ")"
        geo = r["geometry"] if r["geometry"] != "default" else (
            "chosen: " + r["geometry_chosen"].rsplit(": ", 1)[-1] if r.get("geometry_chosen") else "default")
        L.append(f"| {r['data']} | {r['direction']} | {'yes' if r['generic'] else 'catalogue only'} | {geo} | "
                 f"{r['noise_floor_mm']:.3f} | p = {r['p_value']:.2g} ({r['test']['distribution']}, whitened RMS "
                 f"{r['test']['whitened_rms']:.2f}) | {t} | {r.get('model_in_use', 'extended')} | "
                 f"{r['report_rows']['before']['rms']:.2f} -> "
                 f"{r['report_rows']['after']['rms']:.2f} ({r['report_rows']['n']} rows) | "
                 f"{_f(r['other_day']['geometric']['marker1']['all'])} | {_f(r['other_day']['extended']['marker1']['all'])} |")
    L += ["", "## 2. Each physical candidate alone (four points, default geometry)", "",
          "Coefficients in SI per unit of the term's load (rad/Nm, rad/N, rad, or relative); marker-1 RMSE [mm] of "
          "the other day, geometric -> with the term; the diagnosis' test of the term alone (z on the other day's "
          "confirmation rows; why it fails).", "",
          f"| term | {d0}: coefficient | RMSE | test | {d1}: coefficient | RMSE | test | confirmed on the other day |",
          "|---|---|---|---|---|---|---|---|"]

    def test(x):
        t = x["test"]
        if not t.get("significant"):
            return "not significant"
        why = "" if x["kept_by_the_rule"] else (" " + (t["implausible"] or ("held-out error not lower" if not t["better"]
                                                                             else "z below 3")))
        return f"z {t['z']:.1f} / {t['z_without_best_row']:.1f}{why}"

    for r in res["account"]:
        a, b = r["directions"][d0], r["directions"][d1]
        c = lambda x: ", ".join(f"{v:.3g}" for v in x["coefficients_si"])  # noqa: E731
        L.append(f"| {r['term']} | {c(a)} | {a['geometric_marker1_rmse']:.2f} -> {a['extended_marker1_rmse']:.2f} | "
                 f"{test(a)} | {c(b)} | {b['geometric_marker1_rmse']:.2f} -> {b['extended_marker1_rmse']:.2f} | {test(b)} | "
                 f"{'yes' if r['confirmed_on_the_other_day'] else 'no'} |")
    pm = res["physical_model"]
    L += ["", "## 3. The confirmed terms together", "", "Terms: " + "; ".join(pm["terms"]), "",
          "| geometry; trained -> scored | geometric: all | replayed | new in range | outside | extended: all | replayed | "
          "new in range | outside |", "|---|---|---|---|---|---|---|---|---|"]
    for k, r in pm["fits"].items():
        g, e = r["geometric"]["marker1"], r["extended"]["marker1"]
        L.append(f"| {k} | " + " | ".join(_f(g[x]) for x in ("all", "replayed", "new_in_range", "outside")) + " | "
                 + " | ".join(_f(e[x]) for x in ("all", "replayed", "new_in_range", "outside")) + " |")
    L += ["", "Without each term (default geometry, " + d0 + "), marker-1 RMSE of the other day: "
          + "; ".join(f"without {k}: {v:.2f}" for k, v in pm["without_each_term_marker1_rmse"].items() if v is not None)]
    L += ["", res["summary"]]
    return "\n".join(L) + "\n"


def main(argv: list[str] | None = None, recording: bool = True) -> dict:
    from twin.benchio import provenance

    load = os.getloadavg()
    cfg = tomllib.loads((HERE / "config.toml").read_text())
    p = cfg["protocol"]
    with tempfile.TemporaryDirectory() as tmp:
        days = import_days(Path(tmp), cfg)
    groups = {d: groups_of(days[(d, "points")], p) for d in DIRECTIONS}
    runs = []
    for d in DIRECTIONS:
        for data, variant, geometry in (("four points", "points", None), ("marker 1", "marker1", None),
                                        ("marker 1, FIGAROH's selection", "marker1", {"selection": "figaroh"})):
            for generic in (True, False):
                r, _ = run_diagnose(days[(d, variant)], groups[d], generic=generic, geometry=geometry)
                runs.append({"data": data, "direction": d, "generic": generic, "geometry": geometry or "default", **r})
    acc = account(days, groups)
    confirmed = [r["term"] for r in acc if r["confirmed_on_the_other_day"]]
    pm = physical_model(days, groups, confirmed) if confirmed else {"terms": [], "fits": {}}
    # the day-to-day bound: FIGAROH's best geometric level and ours on the same data
    base = pm["fits"].get(f"marker 1, FIGAROH's parameter selection; {DIRECTIONS[0]}") if confirmed else None
    summary = ""
    if base:
        g, e = base["geometric"]["marker1"]["all"]["rmse"], base["extended"]["marker1"]["all"]["rmse"]
        summary = (f"Marker 1, FIGAROH's parameter selection (our best geometric model on the other day, "
                   f"{g:.2f} mm): with the confirmed terms {e:.2f} mm ({100 * (e / g - 1):+.0f} %).")
    out = {"question": "What does the diagnosis find in the real TIAGo residual, confirmed on the other day?",
           "command": ".venv/bin/python studies/tiago_mocap/diagnosis_run.py",
           "directions": list(DIRECTIONS), "diagnose": runs, "account": acc,
           "physical_model": {k: v for k, v in pm.items() if k != "calibrations"}, "summary": summary,
           "provenance": provenance(load)}
    res_dir = HERE / "results"
    res_dir.mkdir(exist_ok=True)
    (res_dir / "diagnosis.json").write_text(json.dumps(out, indent=1, default=float) + "\n")
    (res_dir / "diagnosis.md").write_text(markdown(out))
    if recording and confirmed:
        c = pm["calibrations"]["four points, default geometry"]
        ds = days[(DIRECTIONS[0], "points")]
        record(res_dir / "tiago_mocap.rrd", ds, groups[DIRECTIONS[0]], c["calibration_geometric"], c["calibration"],
               markdown(out))
    out["_calibrations"] = pm.get("calibrations")
    return out


if __name__ == "__main__":
    r = main()
    print((HERE / "results" / "diagnosis.md").read_text())
