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
