"""One table of every scored blind batch (studies/blind/results/*/results.json) -> studies/blind/results/overview.md
and .json.

    python studies/blind/overview.py

First passes (`*_first_pass`) are the blind scores: the diagnosis as it stood when the batch arrived, its after/oracle
on every validation row (which also confirmed its terms). The others are the same batches scored by the current code,
which was improved on them (no longer an exam), on the diagnosis' report rows (held out and used for nothing else);
names are "right" when the names found are exactly the key's (the first passes counted a superset as right).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent / "results"
CATS = ("clean", "catalogue", "outside", "mixed")


def _row(name: str, s: dict) -> dict:
    out = {"batch": name}
    for cat in CATS:
        x = s.get(cat)
        if not x:
            continue
        # the held-out rows: the report rows (current), every validation row (first passes)
        v = x.get("after_over_oracle_report", x.get("after_over_oracle_validation", {}))
        t = x.get("after_over_oracle_test", {})
        out[cat] = {"n": x["n"], "errors": x["errors"], "structured": x["structured"],
                    "named_right": x.get("named_right"), "traced": x.get("traced"), "extra_names": x["extra_names"],
                    "val_within_1_2": v.get("within_1.2"), "val_within_1_5": v.get("within_1.5"), "val_max": v.get("max"),
                    "test_within_1_5": t.get("within_1.5"), "test_max": t.get("max")}
    return out


def main() -> int:
    rows, provenance = [], {}
    for p in sorted(ROOT.glob("*/results.json")):
        res = json.loads(p.read_text())
        rows.append(_row(p.parent.name, res["summary"]))
        # each batch's own record (versions, CPU, load); the first passes predate the record: null
        provenance[p.parent.name] = res.get("provenance")
    # the README's table: per batch and for all current scores together
    agg = {}
    groups = {r["batch"]: [r] for r in rows}
    # the batches of the regression test (studies/blind/run.py GENERATORS); a newer batch stands on its own row
    from run import GENERATORS

    tested = {f"batch{g.upper()}" for g in GENERATORS}
    groups["current"] = [r for r in rows if r["batch"] in tested]
    groups["first_passes"] = [r for r in rows if r["batch"].endswith("_first_pass")]
    for name, rs in groups.items():
        def tot(cat, key):
            return sum((r.get(cat) or {}).get(key) or 0 for r in rs)
        effect_cats = ("catalogue", "outside", "mixed")
        agg[name] = {
            "clean_no_alarm": f"{tot('clean', 'n') - tot('clean', 'structured')}/{tot('clean', 'n')}",
            "catalogue_named_right": f"{tot('catalogue', 'named_right')}/{tot('catalogue', 'n')}",
            "outside_val_within_1_5": f"{tot('outside', 'val_within_1_5')}/{tot('outside', 'n')}",
            "effects_test_within_1_5": f"{sum(tot(c, 'test_within_1_5') for c in effect_cats)}/"
                                       f"{sum(tot(c, 'n') for c in effect_cats)}",
            # effect campaigns given a catalogue name their key does not expect
            "effects_extra_names": f"{sum(tot(c, 'extra_names') for c in effect_cats)}/"
                                   f"{sum(tot(c, 'n') for c in effect_cats)}",
        }
    (ROOT / "overview.json").write_text(json.dumps({"batches": {r["batch"]: r for r in rows}, "aggregate": agg,
                                                    "provenance": provenance}, indent=1) + "\n")
    lines = ["# Blind campaigns: every batch", "",
             "First passes are blind scores (the diagnosis as it stood when the batch arrived); the others are the",
             "current code on the same batches, after it was improved on them. Per category: campaigns; errors; structured;",
             "named right (catalogue, mixed: exactly the key's names; a superset was counted in the first passes); traced",
             "(effects acting where a kept term acts); campaigns with a catalogue name the key does not expect; after/oracle",
             "on the held-out rows (val: the report rows, used for nothing else; every validation row in the first passes)",
             "<= 1.2 / <= 1.5 and the largest; on the test block (rows measured after the campaign) <= 1.5 and the largest.", "",
             "| batch | category | n | err | structured | named right | traced | extra names | val <= 1.2 | val <= 1.5 | val max | test <= 1.5 | test max |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        for cat in CATS:
            if cat not in r:
                continue
            c = r[cat]
            lines.append(f"| {r['batch']} | {cat} | {c['n']} | {c['errors']} | {c['structured']} | "
                         f"{'-' if c['named_right'] is None else c['named_right']} | {'-' if c['traced'] is None else c['traced']} | "
                         f"{c['extra_names']} | {c['val_within_1_2']} | {c['val_within_1_5']} | {c['val_max']:.2f} | "
                         f"{c['test_within_1_5']} | {c['test_max']:.2f} |")
    (ROOT / "overview.md").write_text("\n".join(lines) + "\n")
    print((ROOT / "overview.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
