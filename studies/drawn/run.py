"""Draw instances of every family, score `twin diagnose` on each, write the per-family rates and the per-instance table.

    python -m studies.drawn.run [--draws 20] [--families all] [--workers 2] [--out studies/drawn/results]

Each instance is drawn (``studies/drawn/generator``), written to a scratch folder and scored (``scoring.py``: ``twin
diagnose`` and ``twin predict`` through ``twin.cli.main`` in the worker process) in one job; the jobs run on
``--workers`` processes. Writes ``OUT/results.json`` (per instance and per family, with the provenance) and
``OUT/summary.md``. The benchmark (``experiments/bench_drawn_effects.py``) runs the same and writes its section of
``results/benchmark.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()  # one BLAS thread (2 shared cores) before numpy loads, inherited by the workers

from studies.drawn.generator.campaign import FAMILY_ORDER  # noqa: E402
from studies.drawn.generator.make import parse_families, parse_seeds  # noqa: E402
from twin.benchio import atomic_write_text, provenance  # noqa: E402

__all__ = ["run", "write_results", "main", "OUT"]

OUT = ROOT / "studies" / "drawn" / "results"


def one(job: tuple[str, int, str, bool]) -> dict:
    """Draw, write and score one instance (a job of the pool); a failure is a result, named."""
    from studies.drawn.generator.campaign import build, write
    from studies.drawn.scoring import score_instance

    family, seed, scratch, keep = job
    t0, c0 = time.time(), time.process_time()
    folder = Path(scratch) / f"{family}_{seed:03d}"
    try:
        write(build(family, seed), folder)
        r = score_instance(folder, folder / "work", in_process=True)
    except Exception as exc:  # the generator's or the scorer's failure: recorded, never hidden
        r = {"name": folder.name, "family": family, "seed": seed, "error": f"{type(exc).__name__}: {exc}",
             "drawn": {"family": family, "seed": seed}}
    if not keep:
        shutil.rmtree(folder, ignore_errors=True)
    r["seconds"] = round(time.time() - t0, 2)
    r["cpu_s_job"] = round(time.process_time() - c0, 2)
    return r


def run(families: list[str], seeds: list[int], *, workers: int = 2, keep: Path | None = None,
        verbose: bool = True) -> tuple[list[dict], dict]:
    """Every (family, seed) drawn and scored on ``workers`` processes; returns the per-instance results (in family
    and seed order) and the run's facts (wall and CPU seconds, the load it started under)."""
    load = os.getloadavg()
    scratch = keep or Path(tempfile.mkdtemp(prefix="drawn_effects_"))
    jobs = [(f, s, str(scratch), keep is not None) for f in families for s in seeds]
    t0 = time.time()
    results = []
    with ProcessPoolExecutor(workers) as ex:
        for r in ex.map(one, jobs):
            results.append(r)
            if verbose:
                ratio = (r.get("test") or {}).get("after_over_oracle")
                print(f"{r['name']:<22} named={r.get('named')} effects={r.get('effects')} "
                      f"later after/oracle={ratio if ratio is None else round(ratio, 2)} {r['seconds']:.1f}s "
                      f"{r.get('error', '')[:160]}", flush=True)
    if keep is None:
        shutil.rmtree(scratch, ignore_errors=True)
    facts = {"wall_s": round(time.time() - t0, 1), "cpu_s_jobs": round(sum(r["cpu_s_job"] for r in results), 1),
             "workers": workers, "instances": len(results), "provenance": provenance(load)}
    return results, facts


def write_results(results: list[dict], facts: dict, out: Path, command: str) -> dict:
    from studies.drawn.scoring import summarise, summary_markdown, totals

    summary = summarise(results)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "results.json", json.dumps({"command": command, **facts, "summary": summary,
                                                        "totals": totals(summary), "instances": results}, indent=1) + "\n")
    atomic_write_text(out / "summary.md", summary_markdown(
        results, summary, f"Drawn instances: `twin diagnose` per family ({command})"))
    return summary


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--draws", type=int, default=20, help="instances per family: seeds 0..draws-1")
    ap.add_argument("--seeds", default=None, help="the seeds instead, e.g. 0-2 or 3,7")
    ap.add_argument("--families", default="all",
                    help=f"comma-separated subset of {','.join(FAMILY_ORDER)}, "
                         "or mixed (several effects at once; not in all)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--keep", type=Path, default=None, help="keep the campaigns and work folders here")
    a = ap.parse_args(argv)
    try:
        fams = parse_families(a.families)
        seeds = parse_seeds(a.seeds) if a.seeds else list(range(a.draws))
    except ValueError as exc:
        ap.error(str(exc))
    if a.draws < 1 or a.workers < 1:
        ap.error(f"--draws and --workers must be >= 1, got {a.draws}, {a.workers}")
    results, facts = run(fams, seeds, workers=a.workers, keep=a.keep)
    cmd = f"python -m studies.drawn.run --families {a.families} --seeds {seeds[0]}-{seeds[-1]}"
    summary = write_results(results, facts, a.out, cmd)
    for fam, s in summary.items():
        n = s["n"] - s["errors"]
        print(f"{fam:<16} named {s['named']}/{n}  report<=goal {s['report']['within_goal']}/{n}  "
              f"after<=goal {s['test']['within_goal']}/{n}  after<=1.2 {s['test']['within_1.2']}/{n}  "
              f"median after/oracle {s['test']['median_after_over_oracle']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
