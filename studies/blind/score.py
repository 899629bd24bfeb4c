"""Score `twin diagnose` on a batch of blind campaigns written by another generator (answer keys beside them).

    python studies/blind/score.py BATCH_DIR --out studies/blind/results/BATCH_NAME [--workers 2] [--only NAME ...]

BATCH_DIR holds one folder per campaign (`dataset/`, `key/`; format in docs/formats.md, "Blind campaigns").
Writes OUT/results.json (per campaign: verdict, terms, trace, before/after/oracle on the diagnosis' report rows and
on the test block; the package versions, CPU and load it ran under) and OUT/summary.md; per-campaign work folders
go to OUT/work/ (git-ignored). The user's commands (`twin diagnose`, `twin predict`) run through `twin.cli.main` in
the workers (the same code as on the command line, without an interpreter's start-up per command).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)
from twin.benchio import provenance

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from blind_scoring import score_campaign, summarise, summary_markdown  # noqa: E402


def _one(args: tuple[str, str]) -> dict:
    campaign, work = args
    t = time.time()
    try:
        r = score_campaign(campaign, work, in_process=True)
    except Exception as exc:  # a failure of the scorer is a result too (named, never hidden)
        r = {"name": Path(campaign).name, "category": "?", "error": f"scorer: {type(exc).__name__}: {exc}"}
    r["seconds"] = round(time.time() - t, 1)
    return r


def score_batch(batch: Path, out: Path, *, workers: int = 2, only: list[str] | None = None) -> dict:
    """Score every campaign folder of ``batch`` into ``out`` (results.json, summary.md); returns the summary."""
    load = os.getloadavg()
    names = sorted(p.name for p in batch.iterdir() if (p / "key" / "key.json").exists())
    if only:
        names = [n for n in names if n in set(only)]
    if not names:
        raise SystemExit(f"{batch}: no campaign folders with key/key.json")
    jobs = [(str(batch / n), str(out / "work" / n)) for n in names]
    with ProcessPoolExecutor(workers) as ex:
        results = list(ex.map(_one, jobs))
    for r in results:
        ratio = r.get("report", {}).get("after_over_oracle")
        print(f"{r['name']:<28} {r['category']:<9} structured={r.get('structured')} effects={r.get('effects')} "
              f"after/oracle={ratio if ratio is None else round(ratio, 2)} {r.get('error', '')[:200]}", flush=True)
    summary = summarise(results)
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps({
        "batch": batch.name, "command": f"studies/blind/score.py {batch.name} --out {out.name}",
        "provenance": provenance(load), "summary": summary, "campaigns": results}, indent=1) + "\n")
    (out / "summary.md").write_text(summary_markdown(results, summary, f"Blind campaigns: {batch.name}"))
    return summary


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("batch")
    ap.add_argument("--out", required=True)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--only", nargs="*", default=None, help="campaign names to score (default: all)")
    a = ap.parse_args()
    print(json.dumps(score_batch(Path(a.batch), Path(a.out), workers=a.workers, only=a.only), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
