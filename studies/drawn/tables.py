"""The drawn families' tables, made from the sets' results.json: studies/drawn/README.md's tables (per family and
set: named / report rows within the goal / named with the later rows within 1.2x; the later rows' after/oracle,
median and worst over every set; per set of the current code its totals, the rows of an earlier code's run kept) and
docs/diagnosis.md's coverage table (per family and set: named with the later rows within 1.2x, of 20). The tables'
other columns (goal, size, what each family covers and misses) are written by hand and kept.

    python -m studies.drawn.tables            # rewrite both tables
    python -m studies.drawn.tables --check    # print what would change; exit 1 when anything would
"""

from __future__ import annotations

import argparse
import difflib
import json
import re
import statistics
import sys
from pathlib import Path

__all__ = ["SETS", "tables"]

ROOT = Path(__file__).resolve().parents[2]
# (results folder, seeds) of every set the tables show, in their column order
SETS = (("results", "0-19"), ("results_fresh", "100-119"), ("results_held", "200-219"), ("results_300", "300-319"),
        ("results_400", "400-419"), ("results_500", "500-519"), ("results_600", "600-619"),
        ("results_700", "700-719"), ("results_800", "800-819"), ("results_900", "900-919"),
        ("results_1000", "1000-1019"), ("results_1100", "1100-1119"))
_ROW = re.compile(r"\| ([a-z_]+)( \(no alarm\))? \| ")
# a row of the README's totals table: its label (the seeds, then what code ran them) and its first count
_TOTALS = re.compile(r"\| ((\d+-\d+)(?: [^|]*)?) \| \d+/\d+ \| ")
_EARLIER = re.compile(r"older code|code before")  # a row of an earlier code's run (its _before folder), kept


def _readme(text: str, res: dict, fams: list[str]) -> str:
    def cell(s):
        return f"{s['named']} / {s['report']['within_goal']} / {s['named_and_test_within_1.2']}"

    def median_worst(f):
        v = [i["test"]["after_over_oracle"] for d, _ in SETS for i in res[d]["instances"]
             if i["family"] == f and i.get("test")]
        return f"{statistics.median(v):.2f} / {max(v):.2f}"

    by_seeds = dict((s, d) for d, s in SETS)

    def totals_row(label: str, t: dict) -> str:
        return (f"| {label} | {t['named']}/{t['effect_instances']} | {t['report_within_goal']}/{t['effect_instances']} | "
                f"{t['test_within_goal']}/{t['effect_instances']} | {t['named_and_test_within_1.2']}/"
                f"{t['effect_instances']} | {t['families_at_9_of_10']}/{t['effect_families']} | "
                f"{t['clean_false_alarms']}/{t['clean_instances']} |")

    out = []
    for ln in text.split("\n"):
        tot = _TOTALS.match(ln)
        if tot and tot.group(2) in by_seeds and not _EARLIER.search(tot.group(1)):
            out.append(totals_row(tot.group(1), res[by_seeds[tot.group(2)]]["totals"]))
            continue
        if ln.startswith("| family | goal | size |"):
            ln = ("| family | goal | size | " + " | ".join(s for _, s in SETS)
                  + f" | later rows after/oracle, median / worst ({20 * len(SETS)}) |")
        elif ln.startswith("|---|---|---|---|") and out and out[-1].startswith("| family | goal | size |"):
            ln = "|" + "---|" * (4 + len(SETS))
        else:
            m = re.match(r"\| ([a-z_]+)( \(no alarm\))? \| ([^|]+) \| ([^|]+) \| ", ln)
            if m and m.group(1) in fams:
                f = m.group(1)
                ln = (f"| {f}{m.group(2) or ''} | {m.group(3)} | {m.group(4)} | "
                      + " | ".join(cell(res[d]["summary"][f]) for d, _ in SETS) + f" | {median_worst(f)} |")
        out.append(ln)
    return "\n".join(out)


def _coverage(text: str, res: dict, fams: list[str]) -> str:
    out = []
    for ln in text.split("\n"):
        if ln.startswith("| family | covers (as drawn) |"):
            ln = ("| family | covers (as drawn) | " + " | ".join(f"seeds {s}" for _, s in SETS)
                  + " | not covered (the misses) |")
        elif ln.startswith("|---|---|---|") and out and out[-1].startswith("| family | covers (as drawn) |"):
            ln = "|" + "---|" * (3 + len(SETS))
        else:
            m = _ROW.match(ln)
            if m and m.group(1) in fams and ln.count("|") >= 13:
                cells = ln.split(" | ")
                n_old = sum(1 for c in cells[2:] if re.fullmatch(r"\d+/20", c))
                ln = " | ".join(cells[:2] + [f"{res[d]['summary'][m.group(1)]['named_and_test_within_1.2']}/20"
                                             for d, _ in SETS] + cells[2 + n_old:])
        out.append(ln)
    return "\n".join(out)


def tables(root: Path = ROOT) -> dict[Path, tuple[str, str]]:
    """``{file: (its text, its text with the tables made from the results)}`` for the two files."""
    res = {d: json.loads((root / "studies" / "drawn" / d / "results.json").read_text()) for d, _ in SETS}
    fams = list(res["results"]["summary"])
    readme, doc = root / "studies" / "drawn" / "README.md", root / "docs" / "diagnosis.md"
    old_r, old_d = readme.read_text(), doc.read_text()
    return {readme: (old_r, _readme(old_r, res, fams)), doc: (old_d, _coverage(old_d, res, fams))}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="print what would change; exit 1 when anything would")
    a = ap.parse_args()
    changed = False
    for path, (old, new) in tables().items():
        if old == new:
            continue
        changed = True
        if a.check:
            sys.stdout.writelines(difflib.unified_diff(old.splitlines(True), new.splitlines(True),
                                                       str(path.relative_to(ROOT)), str(path.relative_to(ROOT)), n=0))
        else:
            path.write_text(new)
    return 1 if (changed and a.check) else 0


if __name__ == "__main__":
    raise SystemExit(main())
