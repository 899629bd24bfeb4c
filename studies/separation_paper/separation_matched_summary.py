"""Summary of the matched Figure 10/11 protocol over its 20 band seeds, beside the paper's numbers.

    python studies/separation_paper/separation_matched_summary.py

Reads studies/separation_paper/results/regression.json (section separation_matched, written by
`python studies/separation_paper/regression_bands.py studies/separation_paper/separation_matched.toml --seeds 20 --section separation_matched`)
and the paper's targets (twin/data/paper_targets_separation.toml); writes studies/separation_paper/results/separation_matched/summary.md.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))

from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)

from twin.evaluation.regression import detectable_factor  # noqa: E402
from twin.evaluation.targets import read_targets  # noqa: E402

BANDS = HERE / "results" / "regression.json"
METHODS = ("distance", "full_pose", "separation", "separation_paper", "default")
UNITS = (("angle_deg", "angle [deg]"), ("position_mm", "position [mm]"))


def main() -> int:
    b = json.loads(BANDS.read_text())["separation_matched"]
    st = b["statistics"]
    fig10 = read_targets()["simulation"]["figure10"]
    n = len(b["seeds"])
    L = ["# Separation paper, Figures 10-11, protocol matched (studies/separation_paper/separation_matched.toml, truth_noise mode)", "",
         f"{n} seeds ({b['seeds'][0]}..{b['seeds'][-1]}), from `{b['command']}` ({b['date']}). Mean over the seeds of each "
         "seed's statistic, [min, max] over seeds; `paper` = Figure 10 (separation method, one run; targets file).", ""]
    L += ["## Before compensation (the protocol match)", "", "| statistic | ours (20-seed mean) [min, max] | paper | ours / paper |",
          "|---|---|---|---|"]
    for unit, lab in UNITS:
        for stat in ("mean", "max", "std"):
            s = st[f"full_pose.measured.{unit}.before.{stat}"]
            p = fig10[unit]["before"][stat]
            L.append(f"| {lab} {stat} | {s['mean']:.4f} [{s['min']:.4f}, {s['max']:.4f}] | {p} | {s['mean'] / p:.2f} |")
    L += ["", "## After compensation, measured (noise N(0, 0.01^2) mm on the sphere centres)", "",
          "| method | angle mean [deg] | angle max | angle impr. % | position mean [mm] | position max | position impr. % |",
          "|---|---|---|---|---|---|---|"]
    for m in METHODS:
        cells = []
        for unit, _ in UNITS:
            a, x = st[f"{m}.measured.{unit}.after.mean"], st[f"{m}.measured.{unit}.after.max"]
            i = st[f"{m}.measured.{unit}.improvement_percent"]
            cells += [f"{a['mean']:.4f} [{a['min']:.4f}, {a['max']:.4f}]", f"{x['mean']:.4f}", f"{i['mean']:.1f}"]
        L.append(f"| {m} | " + " | ".join(cells) + " |")
    cells = []
    for unit, _ in UNITS:
        cells += [str(fig10[unit]["after"]["mean"]), str(fig10[unit]["after"]["max"]), str(fig10[unit]["improvement_percent"])]
    L.append("| *paper, separation (Fig. 10)* | " + " | ".join(f"*{c}*" for c in cells) + " |")
    L += ["", "## After compensation on the world's truth (same frames, no measurement noise)", "",
          "| method | angle mean [deg] | position mean [mm] |", "|---|---|---|"]
    for m in METHODS:
        L.append(f"| {m} | " + " | ".join(f"{st[f'{m}.truth.{u}.after.mean']['mean']:.4f}" for u, _ in UNITS) + " |")
    L += ["", "## The paper's Figure 11 claims (after-compensation means), seeds where they hold", "",
          "| claim | separation (our variant) | separation, paper-literal |", "|---|---|---|"]
    for claim, e in b["orderings"].items():
        lit = b.get("orderings_literal", {}).get(claim)
        lit_cell = "-" if lit is None else f"{lit['holds']}/{lit['n']}"
        L.append(f"| {claim} | {e['holds']}/{e['n']} | {lit_cell} |")
    L += ["", "## Pairwise orderings of the after-compensation means holding in >= 95 % of seeds", ""]
    for key, table in b["pairwise"].items():
        held = [f"{p} ({e['holds']}/{e['n']})" for p, e in sorted(table.items()) if e["holds"] / e["n"] >= 0.95]
        L.append(f"* {key}: " + ("; ".join(held) if held else "none"))
    L += ["", "## Worsening a regression test can see (tests/test_regression_matched.py: 6 new seeds, 99 % one-sided)", "",
          "| method | angle after-mean | position after-mean |", "|---|---|---|"]
    for m in METHODS:
        L.append(f"| {m} | " + " | ".join(f"x{detectable_factor(st[f'{m}.measured.{u}.after.mean'], 6, 0.99):.3f}" for u, _ in UNITS) + " |")
    out = HERE / "results" / "separation_matched" / "summary.md"
    out.write_text("\n".join(L) + "\n")
    print("\n".join(L))
    return 0


if __name__ == "__main__":
    sys.exit(main())
