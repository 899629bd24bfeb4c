"""Rows of two robots mixed in one campaign: how often `twin calibrate`'s split finds them, and what it calls one
robot's backlash and a knocked instrument.

    python -m studies.mixture.run [--seeds 1000-1029] [--workers 2]

Each seed draws a campaign (``tests/_newcomer_chain.py``'s ``mixed_campaign``: a robot of a drawn form and joint count,
160-240 rows, the second kind's share drawn in 0.25-0.75, interleaved at random) of three kinds: rows of two robots
as built (interleaved, or in two blocks: a file appended to another), rows of one robot with backlash on a drawn
joint, rows of one robot seen from two places of the instrument.
Each is imported with `twin import`, calibrated (``twin.estimator.calibrate``) and split
(``twin.estimator.mixture.split_rows``); the split is scored against the generator's labels. `twin diagnose` runs on
each too, and what its split (where it looked for one) named is recorded beside. Writes
``studies/mixture/results/results.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
for p in (ROOT, ROOT / "tests"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()

from twin.benchio import atomic_write_text, provenance  # noqa: E402

KINDS = ("robot", "robot_blocks", "backlash", "frame")
# what each kind must give: the split found and called two robots; never two robots; found and called a frame
EXPECTED = {"robot": "found, kind robots, >= 95 % of the rows with their own robot",
            "robot_blocks": "found, kind robots, >= 95 % of the rows with their own robot",
            "backlash": "not called two robots (kind parameter, frames or tool, or not found)",
            "frame": "found, kind frames, >= 95 % of the rows with their own place"}
OUT = ROOT / "studies" / "mixture" / "results" / "results.json"


def one(job: tuple[str, int]) -> dict:
    """Draw, import, calibrate and split one campaign (a job of the pool)."""
    import numpy as np

    import _newcomer_chain as C
    from twin.estimator import calibrate
    from twin.estimator.mixture import split_rows

    kind, seed = job
    t0 = time.process_time()
    with tempfile.TemporaryDirectory() as d, warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        ds, is_b = C.mixed_campaign(Path(d), seed, second=kind.removesuffix("_blocks"), blocks=kind.endswith("_blocks"))
        cal = calibrate(ds)
        s = split_rows(cal, ds)
        dg = C.twin(["diagnose", Path(d) / "ds", "--out", Path(d) / "diag", "--no-plots", "--no-recording"])
        diag = {"exit_code": dg.code}
        if dg.code == 0:
            dj = json.loads((Path(d) / "diag" / "diagnosis.json").read_text())
            g = dj.get("two_groups") or {}
            diag.update({"structured": dj["structured"], "terms": [a["label"] for a in dj["atoms"]],
                         "explained_fraction": dj.get("explained_fraction"), "split_looked_for": bool(g),
                         "found": bool(g.get("found")), "named": g.get("kind", "")})
            if g.get("found"):
                diag["agreement"] = C.split_agreement(g["groups"], ds.pose_id, is_b)
    agree = C.split_agreement(s.groups, ds.pose_id, is_b) if s.groups[0] else None
    two = s.found and s.kind == "robots" and agree is not None and agree >= 0.95
    ok = {"robot": two, "robot_blocks": two,
          "backlash": s.kind != "robots",
          "frame": s.found and s.kind == "frames" and agree is not None and agree >= 0.95}[kind]
    return {"kind": kind, "seed": seed, "robot": ds.robot.name, "rows": int(ds.n), "share_second": float(np.mean(is_b)),
            "residual_scale": cal.noise.get("residual_scale"),
            "rejected": len(cal.rows.get("calibration_rejected", [])), "found": s.found, "named": s.kind,
            "parameter": s.parameter, "rms_one_mm": s.rms_one_mm, "rms_two_mm": list(s.rms_two_mm),
            "agreement": agree, "as_expected": bool(ok), "diagnose": diag, "cpu_s": round(time.process_time() - t0, 2)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1000-1029", help="a-b: the seeds of every kind")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default=str(OUT))
    a = ap.parse_args(argv)
    try:
        lo, hi = (int(x) for x in a.seeds.split("-"))
    except ValueError:
        ap.error(f"--seeds must be a-b, got {a.seeds!r}")
    if a.workers < 1:
        ap.error(f"--workers must be positive, got {a.workers}")
    jobs = [(k, s) for k in KINDS for s in range(lo, hi + 1)]
    t0 = time.time()
    with ProcessPoolExecutor(a.workers) as ex:
        rows = list(ex.map(one, jobs))
    summary = {k: {"expected": EXPECTED[k], "n": sum(r["kind"] == k for r in rows),
                   "as_expected": sum(r["kind"] == k and r["as_expected"] for r in rows),
                   "named": {n: sum(r["kind"] == k and r["named"] == n for r in rows)
                             for n in sorted({r["named"] for r in rows if r["kind"] == k})},
                   "diagnose_named": {n: sum(r["kind"] == k and r["diagnose"].get("found", False)
                                             and r["diagnose"].get("named") == n for r in rows)
                                      for n in sorted({r["diagnose"].get("named", "") for r in rows
                                                       if r["kind"] == k and r["diagnose"].get("found")})},
                   "diagnose_min_agreement": min((r["diagnose"]["agreement"] for r in rows
                                                  if r["kind"] == k and "agreement" in r["diagnose"]), default=None)}
               for k in KINDS}
    out = {"command": f"python -m studies.mixture.run --seeds {a.seeds} --workers {a.workers}",
           "summary": summary, "instances": rows, "wall_s": round(time.time() - t0, 1), "provenance": provenance()}
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(Path(a.out), json.dumps(out, indent=1) + "\n")
    for k, v in summary.items():
        print(f"{k:9s} {v['as_expected']}/{v['n']} as expected ({v['expected']}); named {v['named']}; "
              f"twin diagnose named {v['diagnose_named']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
