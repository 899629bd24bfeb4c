"""`make bench`: our calibrators side by side with the peers, the measurement pipeline, growth with the work, the
diagnosis at scale and on drawn instances of every effect family.

Writes the ``peers``, ``pipeline``, ``growth``, ``diagnosis_scale`` and ``drawn_effects`` sections of
``results/benchmark.json`` (other sections are left alone) and ``results/benchmark_table.md``. See
``docs/benchmark.md``.

    python experiments/benchmark.py                      # everything (about an hour on 2 cores)
    python experiments/benchmark.py --sections peers --quick
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

# One BLAS thread for every method (set before NumPy loads): on a 2-core machine shared with other jobs,
# multi-threaded BLAS made our 0.04 s fit take 0.1-0.6 s, and the peers are Python-bound either way.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)

from experiments.peers import sections  # noqa: E402
from twin.benchio import DEFAULT_PATH  # noqa: E402

ALL = ("peers", "pipeline", "growth", "diagnosis_scale", "drawn_effects")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sections", default=",".join(ALL), help=f"comma-separated subset of {','.join(ALL)}")
    p.add_argument("--seeds", type=int, default=5, help="seeds per cell (default 5)")
    p.add_argument("--repeats", type=int, default=5, help="timed runs per method on the first seed (default 5)")
    p.add_argument("--quick", action="store_true", help="1 seed, 1 repeat, 50 poses: a smoke run, not figures")
    p.add_argument("--out", type=Path, default=DEFAULT_PATH, help="benchmark JSON (default results/benchmark.json)")
    p.add_argument("--table", type=Path, default=None, help="markdown table (default beside the JSON)")
    args = p.parse_args(argv)
    wanted = [s.strip() for s in args.sections.split(",") if s.strip()]
    unknown = sorted(set(wanted) - set(ALL))
    if unknown:
        p.error(f"unknown sections {unknown}; choose from {list(ALL)}")
    if args.seeds < 1 or args.repeats < 1:
        p.error(f"--seeds and --repeats must be >= 1, got {args.seeds}, {args.repeats}")
    table = args.table or args.out.with_name("benchmark_table.md")
    for name in wanted:
        sections.run_section(name, out=args.out, seeds=args.seeds, repeats=args.repeats, quick=args.quick)
    sections.write_table(args.out, table)
    print(f"wrote {args.out} and {table}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
