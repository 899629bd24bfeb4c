"""The README's chain on newcomer cases drawn at random -> the ``newcomer`` section of results/benchmark.json.

The suite's newcomer matrix (``tests/test_newcomer.py``) is a covering design: 26 cases that take every value of
every axis and every pair of values of three axis pairs. A robot, file layout or campaign outside those pairs can
still break the chain. Here each case draws every axis uniformly (``tests/_newcomer_chain.py``, ``drawn_case``:
the form and joint count of the robot, a prismatic joint, what the instrument measures, the layout in files and
sets, the time column, the CSV dialect, a backlash, whether the noise is stated) from seeds ``SEED0 + k``, runs
``import -> calibrate -> diagnose -> import -> register -> predict -> compensate -> export`` on it and applies the
matrix's own checks (``check``). Each case ends as one of:

* ``passed``: every check held (a step that refused did so with a named error its case explains);
* ``failed``: a check failed (the case, its seed and the check's message are listed: each is a defect to mend
  or a refusal to name, and a mended one becomes a test: ``DRAWN_SEEDS`` in the test file);
* ``not_drawable``: the generator could not write the case (a constant tool orientation over a cube of positions
  that the drawn robot cannot hold).

The target: no case failed. Also recorded: the named refusals met, per step and message. Then ``--corrupted``
drawn cases whose first CSV is corrupted one way (``corrupt_csv``: a cell nan, inf, a word or 1e308, a column
dropped, the file cut, a byte-order mark, CRLF, a header doubled or swapped, rows shuffled, bytes that are no
UTF-8, ...) or whose column map is (``corrupt_map``: a key dropped or twice, a value of another type, a unit unknown,
a name beyond ASCII, broken TOML, ...) go through ``twin import`` and, where it imports, ``twin calibrate``
(``run_corrupted``): each is
imported, refused with an error naming the file, or a defect (a traceback, another exit code, a refusal naming no
file, a dataset written that does not read back); the target: no defect. Last, data/'s three real campaigns (other
labs' files: TIAGo's through the FIGAROH path, the UR5's and the UR10's through their column maps), each corrupted
every way it can be, once (``run_real_corrupted``), with the same outcomes and target (``--no-real``: not them).

    python experiments/bench_newcomer.py [--cases 400] [--corrupted 400] [--no-real] [--workers 2] [--no-write]
"""

from __future__ import annotations

import argparse
import collections
import os
import re
import sys
import tempfile
import time
import traceback
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
for p in (ROOT, ROOT / "tests"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()  # MUJOCO_GL=egl and one BLAS thread before numpy or mujoco load (twin.runtime)

from twin.benchio import update_benchmark_section  # noqa: E402

SEED0 = 900000  # case k draws from seed SEED0 + k
SEED_CORRUPT = 910000  # corrupted case k: seed SEED_CORRUPT + k, the (k mod 40)th corruption (20 of a CSV, 20 of the map)
SEED_REAL = 920000  # data/'s real campaigns: the k-th corruption a campaign takes (real_kinds) draws from SEED_REAL + k


def _class(message: str, folder: str) -> str:
    """A refusal's or a failure's message as a class: the case's folder named ``CASE``, numbers as ``#``."""
    text = re.sub(r"\d+(\.\d+)?(e-?\d+)?", "#", message.replace(folder, "CASE"))
    return re.sub(r"(row # joint #, )+row # joint #", "row # joint #, ...", text)[:300]


def one(seed: int) -> dict:
    """Draw, write, run and check one case (a job of the pool)."""
    import _newcomer_chain as C

    case = C.drawn_case(seed)
    out = {"seed": seed, "case": case.name}
    t0 = time.process_time()
    with tempfile.TemporaryDirectory() as d, warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        try:
            C.make_world(case)
        except RuntimeError as exc:
            return {**out, "outcome": "not_drawable", "message": str(exc)}
        o = None
        try:
            o = C.run_case(case, Path(d))
            C.check(o, Path(d))
            out["outcome"] = "passed"
        except AssertionError as exc:  # a check failed: the assert's line and its message
            line = (traceback.extract_tb(exc.__traceback__)[-1].line or "").strip()
            text = f"{line} -- {str(exc).strip().splitlines()[0] if str(exc).strip() else ''}"
            out.update(outcome="failed", message=text.replace(d, "CASE")[:400])
        except Exception:  # a traceback out of the chain: a defect, listed with its last line
            last = traceback.format_exc().strip().splitlines()[-1]
            out.update(outcome="failed", message=last.replace(d, "CASE")[:400])
        if o is not None and out["outcome"] == "failed":
            out["figures"] = {k: round(v, 6) for k, v in o.figures.items()}
        if o is not None:
            out["refused"] = {k: _class(s.err.strip().splitlines()[-1].split(": error: ", 1)[-1], d)
                              for k, s in o.steps.items() if s.code != 0}
    out["cpu_s"] = round(time.process_time() - t0, 2)
    return out


def one_corrupted(k: int) -> dict:
    """Corrupt one drawn case's first CSV and import it (a job of the pool)."""
    import _newcomer_chain as C

    kinds = C.CORRUPTIONS + C.MAP_CORRUPTIONS
    kind = kinds[k % len(kinds)]
    with tempfile.TemporaryDirectory() as d, warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return C.run_corrupted(SEED_CORRUPT + k, kind, Path(d))


def one_real(job: tuple[str, int]) -> dict:
    """Corrupt one of data/'s real campaigns one way and import it (a job of the pool)."""
    import _newcomer_chain as C

    name, k = job
    with tempfile.TemporaryDirectory() as d, warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return C.run_real_corrupted(name, C.real_kinds(name)[k], SEED_REAL + k, Path(d))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=400, help="cases drawn (seeds SEED0 .. SEED0 + cases - 1)")
    ap.add_argument("--corrupted", type=int, default=400, help="drawn cases with a corrupted CSV (0: none)")
    ap.add_argument("--real", action=argparse.BooleanOptionalAction, default=True,
                    help="also data/'s three real campaigns, each corrupted every way it can be (default on)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--no-write", action="store_true", help="print only; leave results/benchmark.json alone")
    args = ap.parse_args()
    if args.cases < 1:
        raise SystemExit(f"--cases must be at least 1, got {args.cases}")
    if args.workers < 1:
        raise SystemExit(f"--workers must be at least 1, got {args.workers}")
    load0 = list(os.getloadavg())
    t0 = time.perf_counter()
    seeds = [SEED0 + k for k in range(args.cases)]
    if args.corrupted < 0:
        raise SystemExit(f"--corrupted must be at least 0, got {args.corrupted}")
    import _newcomer_chain as C

    jobs = [(name, k) for name in C.REAL_CAMPAIGNS for k in range(len(C.real_kinds(name)))] if args.real else []
    with ProcessPoolExecutor(args.workers) as ex:
        rows = list(ex.map(one, seeds))
        bad = list(ex.map(one_corrupted, range(args.corrupted)))
        real = list(ex.map(one_real, jobs))
    wall = time.perf_counter() - t0
    counts = collections.Counter(r["outcome"] for r in rows)
    refusals = collections.Counter(f"{step}: {msg}" for r in rows for step, msg in r.get("refused", {}).items())
    failed = [{k: r[k] for k in ("seed", "case", "message", "figures") if k in r} for r in rows
              if r["outcome"] == "failed"]
    data = {
        "command": f"python experiments/bench_newcomer.py --cases {args.cases} --corrupted {args.corrupted}"
                   + ("" if args.real else " --no-real"),
        "cases": args.cases,
        "seeds": [seeds[0], seeds[-1]],
        "draw": "tests/_newcomer_chain.py drawn_case: every axis uniform over its values (AXES), redrawn until allowed",
        "checks": "tests/_newcomer_chain.py check (the matrix's checks: named refusals only, documented files, the "
                  "oracle's accuracy on an effect-free robot)",
        "counts": {k: counts.get(k, 0) for k in ("passed", "failed", "not_drawable")},
        "failed": failed,
        "refusals_met": dict(sorted(refusals.items(), key=lambda kv: -kv[1])),
        "corrupted": {
            "cases": args.corrupted,
            "seeds": [SEED_CORRUPT, SEED_CORRUPT + args.corrupted - 1] if args.corrupted else [],
            "how": "tests/_newcomer_chain.py run_corrupted: the drawn case's first CSV (corrupt_csv) or its column map "
                   "(corrupt_map) corrupted one way, each of CORRUPTIONS + MAP_CORRUPTIONS in turn, then twin import "
                   "and, where it imports, twin calibrate",
            "counts": {k: sum(r["outcome"] == k for r in bad) for k in ("imported", "refused", "defect", "not_drawable")},
            "per_kind": {kind: dict(collections.Counter(r["outcome"] for r in bad if r["kind"] == kind))
                         for kind in dict.fromkeys(r["kind"] for r in bad)},
            "defects": [{k: r.get(k) for k in ("seed", "kind", "case", "corruption", "message")}
                        for r in bad if r["outcome"] == "defect"],
        },
        "real": {
            "cases": len(real),
            "how": "tests/_newcomer_chain.py run_real_corrupted: each of data/'s real campaigns (REAL_CAMPAIGNS: TIAGo's "
                   "two mocap files through the FIGAROH path, the UR5 and the UR10 laser-tracker files through their "
                   "column maps) copied, its CSV or its column map corrupted each way it can be (real_kinds), once, "
                   "then imported as its README says and, where it imports, calibrated",
            "counts": {k: sum(r["outcome"] == k for r in real) for k in ("imported", "refused", "defect")},
            "per_campaign": {name: dict(collections.Counter(r["outcome"] for r in real if r["case"] == name))
                             for name in dict.fromkeys(r["case"] for r in real)},
            "defects": [{k: r.get(k) for k in ("seed", "kind", "case", "corruption", "message")}
                        for r in real if r["outcome"] == "defect"],
        },
        "target": "no case failed; no corrupted case a defect (a traceback, an exit code other than 0 or 2, a refusal "
                  "that names no file, a dataset written that does not read back)",
        "meets_target": not failed and not any(r["outcome"] == "defect" for r in bad + real),
        "wall_s": round(wall, 1),
        "cpu_s_cases": round(sum(r.get("cpu_s", 0.0) for r in rows), 1),
        "workers": args.workers,
        "load_average_1_5_15": load0,
    }
    print(f"{args.cases} drawn cases: {data['counts']}; {args.corrupted} corrupted: {data['corrupted']['counts']}; "
          f"{wall:.0f} s")
    if real:
        print(f"{len(real)} corrupted real campaigns: {data['real']['counts']}")
    for r in data["corrupted"]["defects"] + data["real"]["defects"]:
        print(f"  defect {r['seed']} {r['kind']} {r['case']}: {r['message']}")
    for f in failed:
        print(f"  failed {f['seed']} {f['case']}: {f['message']}")
    if not args.no_write:
        update_benchmark_section("newcomer", data)
    return 0


if __name__ == "__main__":
    sys.exit(main())
