"""The blind-campaign study in one command: generate the five batches, score `twin diagnose` on each, the overview.

    python studies/blind/run.py [--workers 2] [--only a b ...]

Each generator (studies/blind/generators/generator_?) writes its batch with its own seed into
studies/blind/campaigns/ (git-ignored); studies/blind/score.py scores it into studies/blind/results/batch?/ and
studies/blind/overview.py writes studies/blind/results/overview.{md,json}. Nothing outside studies/blind/ is
written. The first passes (results/batch?_first_pass) are the historical blind scores and are not rewritten.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
GENERATORS = {"a": 1, "b": 7, "c": 11, "d": 23, "e": 31}  # generator -> the seed its batch was written with
# batches scored but not yet in tests/test_blind_campaigns.py (their first pass: results/batch?_first_pass)
NEW_GENERATORS = {"f": 43}


def generate(gen: str, out: Path) -> None:
    """Write generator ``gen``'s batch into ``out`` (deterministic: its seed, the same bytes every run)."""
    subprocess.run([sys.executable, str(HERE / "generators" / f"generator_{gen}" / "make_all.py"), "--out", str(out),
                    "--seed", str({**GENERATORS, **NEW_GENERATORS}[gen])], check=True, capture_output=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--only", nargs="*", default=None, help="generators to run (a b c d e, and f; default: a-e)")
    a = ap.parse_args()
    sys.path.insert(0, str(HERE))
    from overview import main as overview
    from score import score_batch

    for gen in a.only or list(GENERATORS):
        batch = HERE / "campaigns" / f"batch{gen.upper()}"
        t = time.time()
        generate(gen, batch)
        print(f"generated {batch.name} in {time.time() - t:.0f} s", flush=True)
        score_batch(batch, HERE / "results" / f"batch{gen.upper()}", workers=a.workers)
    return overview()


if __name__ == "__main__":
    sys.exit(main())
