"""Score `twin diagnose` on a batch of blind campaigns written by another generator (answer keys beside them).

    python experiments/blind_campaigns.py BATCH_DIR --out results/blind/BATCH_NAME [--workers 2] [--only NAME ...]

BATCH_DIR holds one folder per campaign (`dataset/`, `key/`; format in docs/formats.md, "Blind campaigns").
Writes OUT/results.json (per campaign: verdict, terms, trace, before/after/oracle on the validation rows and
on the test block) and OUT/summary.md; per-campaign work folders go to OUT/work/ (git-ignored).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import twin  # noqa: F401  (single-threaded BLAS)
from twin.evaluation.blind import score_campaign, summarise, summary_markdown


def _one(args: tuple[str, str]) -> dict:
    campaign, work = args
    t = time.time()
    try:
        r = score_campaign(campaign, work)
    except Exception as exc:  # a failure of the scorer is a result too (named, never hidden)
        r = {"name": Path(campaign).name, "category": "?", "error": f"scorer: {type(exc).__name__}: {exc}"}
    r["seconds"] = round(time.time() - t, 1)
    return r


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("batch")
    ap.add_argument("--out", required=True)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--only", nargs="*", default=None, help="campaign names to score (default: all)")
    a = ap.parse_args()
    batch, out = Path(a.batch), Path(a.out)
    names = sorted(p.name for p in batch.iterdir() if (p / "key" / "key.json").exists())
    if a.only:
        names = [n for n in names if n in set(a.only)]
    if not names:
        raise SystemExit(f"{batch}: no campaign folders with key/key.json")
    jobs = [(str(batch / n), str(out / "work" / n)) for n in names]
    with ProcessPoolExecutor(a.workers) as ex:
        results = list(ex.map(_one, jobs))
    for r in results:
        ratio = r.get("validation", {}).get("after_over_oracle")
        print(f"{r['name']:<28} {r['category']:<9} structured={r.get('structured')} effects={r.get('effects')} "
              f"after/oracle={ratio if ratio is None else round(ratio, 2)} {r.get('error', '')[:200]}", flush=True)
    summary = summarise(results)
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps({"batch": str(batch), "command": " ".join(sys.argv),
                                                  "summary": summary, "campaigns": results}, indent=1) + "\n")
    (out / "summary.md").write_text(summary_markdown(results, summary, f"Blind campaigns: {batch.name}"))
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
