"""The UR10 study, second part: what of series A's extended model carries over to series B, and why the ratio on B
stays above 0.8.

Run from the repository root, after ``run.py`` (it reads ``work/``: the imported series and series A's diagnosis)::

    .venv/bin/python studies/ur10_laser_tracker/transfer.py

Writes ``results/transfer.json`` (with its ``provenance``) and ``results/transfer.md``:

1. the registration's share: series A's models to use with B's tracker registered on B's first 50 rows (the new
   session's figure) and on all of B's rows (an analysis bound: 6 parameters from every row, the same rows scored;
   no prediction);
2. term sets with their values fitted on series A's calibration rows alone (``fit_with_effects``, no selection),
   B's tracker registered on its first 50 rows, scored on B's blocks: series A's terms, the same without its
   measurement-scale and base-tilt terms, the terms series B's own ``twin diagnose`` keeps (chosen on B's first
   70 % of rows and confirmed on its next rows: only B's last 90 rows, its report block, are untouched by that
   choice), and the terms both diagnoses keep;
3. series A's terms less one, fitted on A and judged on B as in 2;
4. each of series A's terms fitted on series A alone and on series B alone (their calibration rows), and on halves
   of series A (in time; in q3): a periodic error of a joint's drive keeps its amplitude and phase from one session
   to the next and within one.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

from twin.runtime import set_process_defaults

set_process_defaults()  # one BLAS thread before numpy loads (twin.runtime)

import numpy as np  # noqa: E402

from twin.benchio import atomic_write_text, provenance  # noqa: E402
from twin.dataset import read_dataset  # noqa: E402
from twin.diagnosis import diagnose, write_diagnosis  # noqa: E402
from twin.diagnosis.apply import block_errors, dataset_predictor, effect_atoms  # noqa: E402
from twin.diagnosis import fit_with_effects  # noqa: E402
from twin.estimator import Calibration  # noqa: E402
from twin.estimator.register import register  # noqa: E402
from twin.units import rad_to_deg  # noqa: E402

HERE = Path(__file__).resolve().parent
FIRST = 50  # rows of B that register its tracker (the "at most 50")


def _rms(e: dict) -> float:
    return e["position_mm"]["rms"]


def _scored(geo: Calibration, ext: Calibration, ds, rows: np.ndarray, blocks: dict, tool: bool = False) -> dict:
    """Both models with B's tracker (and the probe's frame with ``tool``) registered on ``rows``, on ``blocks``."""
    pred = dataset_predictor(ds)
    g = register(geo, ds, rows, tool=tool).calibration
    e = register(ext, ds, rows, tool=tool, predict=pred if ext.effects else None).calibration
    return {k: {"n_rows": v["n_rows"], "geometric_rms_mm": _rms(v["geometric"]), "extended_rms_mm": _rms(v["extended"]),
                "rms_ratio": v["rms_ratio"]} for k, v in block_errors(g, e, ds, blocks).items()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.parse_args()
    work = HERE / "work"
    need = [work / "series_A", work / "series_B", work / "diagnosis_A" / "calibration.json"]
    missing = [str(p.relative_to(HERE)) for p in need if not p.exists()]
    if missing:
        print(f"missing {missing}: run studies/ur10_laser_tracker/run.py first", file=sys.stderr)
        return 2
    ds_a, ds_b = read_dataset(work / "series_A"), read_dataset(work / "series_B")
    n = ds_b.n
    geo_a = Calibration.load(work / "diagnosis_A" / "calibration_geometric.json")
    ext_a = Calibration.load(work / "diagnosis_A" / "calibration.json")
    first, every = np.arange(FIRST), np.arange(n)
    n_val = int(np.sum(np.asarray(ds_b.set) == "validation"))
    blocks = {f"B's other {n - FIRST} rows": np.arange(FIRST, n),
              f"B's last {n_val} rows (its own diagnosis' held-out rows)": np.arange(n - n_val, n)}

    out: dict = {"provenance": provenance(), "registered_on_first_rows": FIRST}
    out["registration"] = {
        f"B's first {FIRST} rows (the new session)": _scored(geo_a, ext_a, ds_b, first, {"scored": np.arange(FIRST, n)}),
        f"B's first {FIRST} rows, probe's frame too": _scored(geo_a, ext_a, ds_b, first, {"scored": np.arange(FIRST, n)},
                                                            tool=True),
        "all of B's rows (analysis bound; the same rows scored)": _scored(geo_a, ext_a, ds_b, every, {"scored": every}),
        "all of B's rows, probe's frame too (analysis bound)": _scored(geo_a, ext_a, ds_b, every, {"scored": every},
                                                                     tool=True),
    }

    res_b = diagnose(ds_b)
    write_diagnosis(res_b, work / "diagnosis_B", plots=False)
    report_b = np.flatnonzero(np.isin(ds_b.pose_id, res_b.held_out["report_pose_ids"]))
    if report_b.size:
        blocks[f"B's report block ({report_b.size} rows, untouched by B's choice of terms)"] = report_b
    atoms_a = [a for a, _ in effect_atoms(ext_a)]
    atoms_b = [a for a, _ in effect_atoms(res_b.calibration)] if res_b.calibration.effects else []
    labels_b = {a.label for a in atoms_b}
    sets = {
        "series A's terms": atoms_a,
        "series A's terms without its measurement-scale and base-tilt terms":
            [a for a in atoms_a if not (a.family == "tilt" or a.target.startswith("meas_"))],
        "the terms series B's own diagnosis keeps": atoms_b,
        "the terms both diagnoses keep": [a for a in atoms_a if a.label in labels_b],
    }
    out["term_sets"] = {}
    for name, atoms in sets.items():
        if not atoms:
            out["term_sets"][name] = {"terms": [], "note": "no term"}
            continue
        fit = fit_with_effects(ds_a, atoms)
        out["term_sets"][name] = {
            "terms": [a.label for a in atoms],
            "series_A_report_rms_mm": {"geometric": _rms(fit.before), "extended": _rms(fit.after)},
            "series_B": _scored(fit.calibration_geometric, fit.calibration, ds_b, first, blocks),
        }
    # series A's terms less one: what each costs or gains in the next session
    other = {"B's other rows": np.arange(FIRST, n)}
    out["series_A_terms_less_one"] = []
    for k, a in enumerate(atoms_a):
        fit = fit_with_effects(ds_a, atoms_a[:k] + atoms_a[k + 1:])
        out["series_A_terms_less_one"].append({
            "without": a.label, "series_A_report_extended_rms_mm": _rms(fit.after),
            "series_B_other_rows": _scored(fit.calibration_geometric, fit.calibration, ds_b, first, other)[
                "B's other rows"]})
    # each of series A's terms fitted on each series alone (a cyclic term of the robot keeps its amplitude and phase),
    # and on halves of series A: its first and second half in time, its rows below and above the median of q3
    q3 = ds_a.q[:, 2]
    half = np.arange(ds_a.n) < ds_a.n // 2
    def part(mask):  # a part of series A, its own last 30 % in time held out
        return fit_with_effects(replace(ds_a.subset(mask), set=None), atoms_a, holdout=0.3)

    fit_a_on = {"A": fit_with_effects(ds_a, atoms_a), "B": fit_with_effects(ds_b, atoms_a),
                "A, first half in time": part(half), "A, second half in time": part(~half),
                "A, q3 below its median": part(q3 < np.median(q3)), "A, q3 above its median": part(q3 >= np.median(q3))}
    values = {k: effect_atoms(f.calibration) for k, f in fit_a_on.items()}
    out["series_A_terms_per_series"] = []
    out["whitened_rms_with_series_A_terms"] = {k: float(fit_a_on[k].test_after.whitened_rms) for k in ("A", "B")}
    for i, (a, phi_a) in enumerate(values["A"]):
        row = {"term": a.label, "family": a.family}
        if a.family == "cyclic" and phi_a.size == 2:
            for k in values:
                phi = values[k][i][1]
                size = fit_a_on[k].effect_parameters.get(a.label, {}).get("size", {})
                row[k] = {"amplitude_deg": float(rad_to_deg(np.hypot(phi[0], phi[1]))),
                          "amplitude_sd_deg": size.get("amplitude_sd"),
                          "phase_deg": float(rad_to_deg(np.arctan2(phi[1], phi[0])))}
            dphi = lambda k1, k2: float((row[k2]["phase_deg"] - row[k1]["phase_deg"] + 180.0) % 360.0 - 180.0)  # noqa: E731
            row["phase_difference_deg"] = dphi("A", "B")
            row["phase_difference_within_A_deg"] = {
                "time halves": dphi("A, first half in time", "A, second half in time"),
                "q3 halves": dphi("A, q3 below its median", "A, q3 above its median")}
        else:
            row.update({k: {"values": values[k][i][1].tolist()} for k in values})
        out["series_A_terms_per_series"].append(row)
    (HERE / "results").mkdir(exist_ok=True)
    atomic_write_text(HERE / "results" / "transfer.json", json.dumps(out, indent=1) + "\n")

    lines = ["# UR10: what of series A's extended model carries over to series B", "",
             "RMS of the probe's 3-D position error [mm], geometric / extended (ratio).", "",
             "## The registration's share (series A's models to use)", "",
             "| B's tracker registered on | rows scored | geometric | extended | ratio |", "|---|---|---|---|---|"]
    for k, v in out["registration"].items():
        s = v["scored"]
        lines.append(f"| {k} | {s['n_rows']} | {s['geometric_rms_mm']:.3f} | {s['extended_rms_mm']:.3f} | "
                     f"{s['rms_ratio']:.3f} |")
    names = list(blocks)
    lines += ["", f"## Term sets fitted on series A's calibration rows alone, B's tracker registered on its first {FIRST} rows",
              "", "| terms | series A's report block | " + " | ".join(names) + " |",
              "|---|---|" + "---|" * len(names)]
    for k, v in out["term_sets"].items():
        if "series_B" not in v:
            lines.append(f"| {k} | - |" + " - |" * len(names))
            continue
        ra = v["series_A_report_rms_mm"]
        cells = [f"{v['series_B'][b]['geometric_rms_mm']:.3f} / {v['series_B'][b]['extended_rms_mm']:.3f} "
                 f"({v['series_B'][b]['rms_ratio']:.3f})" for b in names]
        lines.append(f"| {k} ({len(v['terms'])}) | {ra['geometric']:.3f} / {ra['extended']:.3f} | " + " | ".join(cells)
                     + " |")
    sds = [r[k]["amplitude_sd_deg"] for r in out["series_A_terms_per_series"] if "phase_difference_deg" in r
           for k in ("A", "B") if r[k]["amplitude_sd_deg"] is not None]
    scaled = {k: [r[k]["amplitude_sd_deg"] * out["whitened_rms_with_series_A_terms"][k]
                  for r in out["series_A_terms_per_series"] if "phase_difference_deg" in r
                  and r[k]["amplitude_sd_deg"] is not None] or [float("nan")] for k in ("A", "B")}
    lines += ["", "## Series A's terms fitted on each series alone (its calibration rows; values in SI per unit of the "
              "term's features)", "",
              f"Formal standard deviations of the amplitudes {min(sds):.5f}-{max(sds):.5f} deg (from the stated noise); "
              "scaled by the whitened residual RMS with these terms ("
              + ", ".join(f"{v:.1f} on {k}" for k, v in out["whitened_rms_with_series_A_terms"].items()) + "): "
              + ", ".join(f"up to {max(scaled[k]):.4f} deg on {k}" for k in ("A", "B")) + "."
              if sds else "", "", "| term | series A (amplitude +- its scaled standard deviation) | series B | phase difference [deg] | "
              "within A: time halves / q3 halves [deg] |",
              "|---|---|---|---|---|"]
    for r in out["series_A_terms_per_series"]:
        if "phase_difference_deg" in r:
            def cell(k):
                d, sd = r[k], r[k]["amplitude_sd_deg"]
                pm = f" +- {sd * out['whitened_rms_with_series_A_terms'][k]:.4f}" if sd is not None else ""
                return f"{d['amplitude_deg']:.4f}{pm} deg at {d['phase_deg']:.0f} deg"

            w = r["phase_difference_within_A_deg"]
            lines.append(f"| {r['term']} | {cell('A')} | {cell('B')} | {r['phase_difference_deg']:.0f} | "
                         f"{w['time halves']:.0f} / {w['q3 halves']:.0f} |")
        else:
            cell = lambda d: ", ".join(f"{v:.3g}" for v in d["values"])  # noqa: E731
            lines.append(f"| {r['term']} | {cell(r['A'])} | {cell(r['B'])} | - | - |")
    full = out["term_sets"]["series A's terms"]
    lines += ["", f"## Series A's terms less one (fitted on series A's calibration rows; B's tracker registered on its "
              f"first {FIRST} rows)", "",
              "| without | series A's report block, extended | B's other rows, extended | ratio to geometric |",
              "|---|---|---|---|",
              f"| (none) | {full['series_A_report_rms_mm']['extended']:.3f} | "
              f"{full['series_B'][names[0]]['extended_rms_mm']:.3f} | {full['series_B'][names[0]]['rms_ratio']:.3f} |"]
    for r in out["series_A_terms_less_one"]:
        b = r["series_B_other_rows"]
        lines.append(f"| {r['without']} | {r['series_A_report_extended_rms_mm']:.3f} | {b['extended_rms_mm']:.3f} | "
                     f"{b['rms_ratio']:.3f} |")
    lines += ["", "Terms of series B's own diagnosis: " + "; ".join(out["term_sets"]["the terms series B's own diagnosis keeps"]["terms"])]
    atomic_write_text(HERE / "results" / "transfer.md", "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
