"""The TIAGo study page quotes only committed results: its table rows are rows of results/table.md, and the
figures its sentences quote are in results.json / effects.json."""

from __future__ import annotations

import json
import re
from pathlib import Path

STUDY = Path(__file__).resolve().parent.parent / "studies" / "tiago_mocap"


def _results():
    return json.loads((STUDY / "results" / "results.json").read_text())


def test_study_table_rows_are_rows_of_the_results_table():
    """Every table row of the study README appears verbatim in results/table.md."""
    readme = (STUDY / "README.md").read_text().splitlines()
    table = set((STUDY / "results" / "table.md").read_text().splitlines())
    rows = [ln for ln in readme if ln.startswith("| ") and not ln.startswith("| data ")]
    assert len(rows) >= 10
    assert [r for r in rows if r not in table] == []


def test_quoted_joint_offset_figures_match_the_results():
    """The joint-offset sentence (2.88, 4.23 / 12.0, -49.82 mrad for us and FIGAROH run here) is the results'."""
    res = _results()
    ours = next(r for r in res["rows"] if r["variant"] == "marker 1 only" and r["model"] == "joint offsets"
                and "tool" not in r)
    fig = next(r for r in res["rows"] if r.get("tool", "").startswith("FIGAROH joint"))
    text = (STUDY / "README.md").read_text()
    for r in (ours, fig):
        for v in (f"{r['training']['rmse']:.2f}", f"{r['validation']['all']['rmse']:.2f} / {r['validation']['all']['max']:.1f}"):
            assert v in text
    assert f"{ours['joint_offsets_mrad_or_mm']['arm_5_joint.offset']:.2f} mrad" in text
    assert ours["parameters"] == fig["parameters"] == 14


def test_quoted_repeatability_and_effects_figures_match_the_results():
    """The day-to-day repeatability and the prototype's best figures quoted in the README are the results'."""
    res = _results()
    text = (STUDY / "README.md").read_text()
    rep = res["repeatability"]
    assert f"{rep['as_measured']['rmse']:.2f} mm RMS" in text and f"{rep['after_rigid_motion']['rmse']:.2f} mm" in text
    eff = json.loads((STUDY / "results" / "effects.json").read_text())["rows"]
    best = next(r for r in eff if r["variant"].startswith("four") and r["level"] == "full"
                and r["effects"] == ["compliance", "tilt"])
    base = next(r for r in eff if r["variant"].startswith("four") and r["level"] == "full" and r["effects"] == ["none"])
    v = best["validation"]
    assert re.search(rf"from {base['validation']['all']['rmse']:.2f}\s+to {v['all']['rmse']:.2f} mm", text)
    assert f"{v['new_in_range']['rmse']:.2f}" in text and f"{v['outside']['rmse']:.2f}" in text


def test_quoted_coefficient_ranges_match_the_results():
    """The ranges of the compliance and tilt coefficients quoted in the README are those of every fit."""
    eff = json.loads((STUDY / "results" / "effects.json").read_text())
    fits = eff["rows"] + eff["swapped_days"]
    text = (STUDY / "README.md").read_text()
    arm3 = [r["effect_parameters"]["c_arm_3_joint"] * 1e3 for r in fits if "c_arm_3_joint" in r["effect_parameters"]]
    tilt = [r["effect_parameters"][k] * 1e3 for r in fits for k in ("k_tilt_x", "k_tilt_y") if k in r["effect_parameters"]]
    assert len(arm3) == 12 and min(arm3) > 0
    assert f"({min(arm3):.2f}\n  to {max(arm3):.2f} mrad/Nm)" in text or f"({min(arm3):.2f} to {max(arm3):.2f} mrad/Nm)" in text
    assert f"from {min(tilt):.2f} to {max(tilt):.2f} mrad/Nm" in text


def test_quoted_diagnosis_figures_match_the_diagnosis_results():
    """The diagnosis sentences' figures (report rows before -> after, the other day's RMSE, the physical model's fits
    both directions and without each term, the confirmed terms) are those of results/diagnosis.json."""
    d = json.loads((STUDY / "results" / "diagnosis.json").read_text())
    text = " ".join((STUDY / "README.md").read_text().split())
    d0 = d["directions"][0]
    runs = {(r["data"], r["direction"], r["generic"]): r for r in d["diagnose"]}
    m1 = runs[("marker 1", d0, True)]
    cat4 = runs[("four points", d0, False)]
    gen4 = runs[("four points", d0, True)]
    for r in (m1, cat4, gen4):
        assert f"from {r['report_rows']['before']['rms']:.2f} to {r['report_rows']['after']['rms']:.2f}" in text or \
            f"{r['report_rows']['before']['rms']:.2f} to {r['report_rows']['after']['rms']:.2f}" in text
    for r in (m1, cat4, gen4):
        g, e = r["other_day"]["geometric"]["marker1"]["all"]["rmse"], r["other_day"]["extended"]["marker1"]["all"]["rmse"]
        assert f"{g:.2f} to {e:.2f}" in text
    assert [t["label"] for t in m1["terms"]] == ["joint 7 (arm_6_joint) backlash (offset signed by the direction of its last move)"]
    assert "keeps the wrist's **arm_6 backlash** (its offset signed by the direction of its last move)" in " ".join(text.split())
    confirmed = [r["term"] for r in d["account"] if r["confirmed_on_the_other_day"]]
    assert sorted(confirmed) == sorted(d["physical_model"]["terms"]) and len(confirmed) == 3
    fits = d["physical_model"]["fits"]
    for k, f in fits.items():
        g, e = f["geometric"]["marker1"]["all"]["rmse"], f["extended"]["marker1"]["all"]["rmse"]
        assert f"{g:.2f} to {e:.2f}" in text, k
    for v in d["physical_model"]["without_each_term_marker1_rmse"].values():
        assert f"{v:.2f}" in text


def test_quoted_parameter_selection_figures_match_the_results():
    """The FIGAROH-selection sentence (30 parameters, its validation figures, the training-day CV of both selections)
    is the results'."""
    res = _results()
    text = " ".join((STUDY / "README.md").read_text().split())
    row = next(r for r in res["rows"] if r["variant"] == "marker 1 only" and r["model"].endswith("FIGAROH's parameter selection"))
    assert row["parameters"] == 30 and f"{row['validation']['all']['rmse']:.2f} / {row['validation']['all']['max']:.1f}" in text
    for variant, v in res["parameter_selection_cv"].items():
        for sel in ("ordered", "figaroh"):
            assert f"{v[sel]['cv_6fold_rmse_mm']:.2f} / {v[sel]['cv_leave_one_out_rmse_mm']:.2f}" in text, (variant, sel)
