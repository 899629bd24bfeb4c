"""Benchmark of the diagnosis on drawn instances of every effect family -> the ``drawn_effects`` section of
results/benchmark.json, and the per-instance table ``studies/drawn/results/summary.md``.

Each family's instances are drawn by ``studies/drawn/generator`` (it imports no part of the diagnosis): the robot
(IRB 1200 with a stereo rig on the sphere plate, or a UR5 / UR10 with a laser tracker on one reflector), the joint
(every joint where the family can act), the size (1-20x the noise, the part the geometry cannot take), the timing (a
change anywhere in the campaign, on, off, a window), the law's shape; each campaign has rows measured after it that
the diagnosis never sees. Each instance is scored as the blind study scores (``studies/drawn/scoring.py``: ``twin
diagnose`` and ``twin predict``, the oracle fitted on the same rows). Per family: the draws' ranges, the rate named
right, the rates within the oracle goal (1.2x for a named family, 1.5x outside) and within 1.2x on the report rows
and on the rows after the campaign, the median and worst after/oracle, false alarms on the clean campaigns; wall and
CPU seconds. The instances run on both cores (processes).

    python experiments/bench_drawn_effects.py [--draws 20] [--families all] [--quick]
    python experiments/bench_drawn_effects.py --from-results   # the section again from the study's results.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from twin.runtime import available_cores, set_process_defaults  # noqa: E402

set_process_defaults()  # one BLAS thread (2 shared cores) before numpy loads, inherited by the workers

from studies.drawn.generator.campaign import FAMILY_ORDER, LATER_ROWS, RATIO, ROBOT_WEIGHTS, ROWS  # noqa: E402
from studies.drawn.generator.make import parse_families  # noqa: E402
from studies.drawn.run import OUT, run, write_results  # noqa: E402
from studies.drawn.scoring import GOAL, summarise, totals  # noqa: E402
from twin.benchio import update_benchmark_section  # noqa: E402

SECTION = "drawn_effects"
DRAWS = 20


def section(draws: int = DRAWS, families: list[str] | None = None, quick: bool = False, workers: int | None = None,
            out: Path = OUT) -> dict:
    """Draw and score ``draws`` instances (seeds ``0..draws-1``) of every family (``quick``: 2, a smoke run, not
    figures); writes the study's results and returns the section."""
    fams = list(families or FAMILY_ORDER)
    seeds = list(range(2 if quick else draws))
    workers = workers or max(1, min(2, available_cores()))
    results, facts = run(fams, seeds, workers=workers)
    cmd = f"python experiments/bench_drawn_effects.py --draws {len(seeds)}" + (" --quick" if quick else "")
    write_results(results, facts, out, cmd)
    return section_from_results(out / "results.json", quick=quick)


def section_from_results(path: Path, quick: bool = False) -> dict:
    """The section from the study's ``results.json`` (written by :func:`section` or ``studies/drawn/run.py``)."""
    res = json.loads(Path(path).read_text())
    summary = summarise(res["instances"])
    seeds = sorted({r["seed"] for r in res["instances"]})
    return {
        "quick": quick,
        "command": res["command"],
        "draws_per_family": len(seeds),
        "seeds": [seeds[0], seeds[-1]],
        "generator": "studies/drawn/generator (imports twin.units only; no part of the diagnosis)",
        "scoring": "studies/drawn/scoring.py on studies/blind/blind_scoring.py: twin diagnose and twin predict "
                   "(in the worker process), the oracle (the key's effect known exactly, the geometry re-identified "
                   "on the same rows)",
        "campaigns": {"robots": ROBOT_WEIGHTS, "rows": list(ROWS), "later_rows": list(LATER_ROWS),
                      "size_over_noise": list(RATIO),
                      "size": "RMS over the dataset rows of the effect's part the geometry cannot take (each "
                              "point's displacement after a least-squares fit of every geometric parameter, "
                              "base2meas per station and the tool) over the RMS of the noise per point; "
                              "log-uniform"},
        "goals": {"catalogue": GOAL["catalogue"], "outside": GOAL["outside"]},
        "families": summary,
        "totals": totals(summary),
        "instances_table": "studies/drawn/results/summary.md",
        "wall_s": res["wall_s"],
        "cpu_s": res["cpu_s_jobs"],
        "workers": res["workers"],
        "provenance": res["provenance"],
        "note": "named: a catalogue family's names exactly the key's; a change (zero step or glitch, a frame knocked, "
                "slipped or bumped) one change of the right kind and place within 2 rows and no catalogue name; "
                "clean: not structured, nothing named (else a false alarm). report: the diagnosis' held-out rows "
                "used for nothing else (models fitted before them); test: the rows measured after the campaign (the "
                "models to use). cpu_s: the jobs' own CPU time (generation and scoring, in the workers). "
                "families_at_9_of_10: the issue's target, named and the rows after the campaign within 1.2x the "
                "oracle on at least 9 of 10 instances.",
    }


def table(data: dict) -> str:
    """The section's markdown table (one row per family)."""
    lines = ["| family | n | named | report <= goal | later <= goal | later <= 1.2 | median / worst after/oracle "
             "(later rows) |", "|---|---|---|---|---|---|---|"]
    for fam, s in data["families"].items():
        n = s["n"] - s["errors"]
        lines.append(f"| {fam} | {s['n']} | {s['named']}/{n} | {s['report']['within_goal']}/{n} | "
                     f"{s['test']['within_goal']}/{n} | {s['test']['within_1.2']}/{n} | "
                     f"{s['test']['median_after_over_oracle']} / {s['test']['worst_after_over_oracle']} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=DRAWS, help=f"instances per family (default {DRAWS})")
    ap.add_argument("--families", default="all", help=f"comma-separated subset of {','.join(FAMILY_ORDER)}")
    ap.add_argument("--quick", action="store_true", help="2 instances per family: a smoke run, not figures")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--no-write", action="store_true", help="do not update results/benchmark.json")
    ap.add_argument("--from-results", action="store_true",
                    help="no new run: the section from the committed studies/drawn/results/results.json")
    a = ap.parse_args(argv)
    try:
        fams = parse_families(a.families)
    except ValueError as exc:
        ap.error(str(exc))
    if a.draws < 1:
        ap.error(f"--draws must be >= 1, got {a.draws}")
    if a.from_results:
        data = section_from_results(OUT / "results.json")
    else:
        data = section(draws=a.draws, families=fams, quick=a.quick, workers=a.workers)
    print(table(data))
    if not a.no_write:
        print(f"wrote section {SECTION} of {update_benchmark_section(SECTION, data)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
