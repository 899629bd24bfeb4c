"""Regenerate the whole batch deterministically:
    python studies/blind/generators/generator_a/make_all.py --out BATCH_DIR --seed 1
"""

from __future__ import annotations

import argparse
import csv
import os
import shutil
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402

from campaign import build  # noqa: E402
from specs import SPECS  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", required=True)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--only", default=None, help="comma-separated labels (debugging)")
    ap.add_argument("--names", nargs="*", default=None, help="write only these campaigns (folder names, e.g. hA01 hA07); the others are left as they are")
    a = ap.parse_args(argv)
    t0 = time.time()
    # neutral folder names: the campaigns are listed in a seeded random order as hA01..hA26
    perm = np.random.default_rng([a.seed, 99]).permutation(len(SPECS))
    known = {f"hA{k + 1:02d}" for k in range(len(SPECS))}
    if a.names is not None and set(a.names) - known:
        ap.error(f"unknown campaign names: {sorted(set(a.names) - known)}")
    if os.path.isdir(a.out) and a.only is None and a.names is None:
        for d in os.listdir(a.out):
            p = os.path.join(a.out, d)
            if d.startswith("hA") and os.path.isdir(p):
                shutil.rmtree(p)
    os.makedirs(a.out, exist_ok=True)
    rows = []
    for pos, si in enumerate(perm):
        spec = SPECS[si]
        if a.only and spec.label not in a.only.split(","):
            continue
        name = f"hA{pos + 1:02d}"
        if a.names is not None and name not in a.names:
            continue
        t1 = time.time()
        info = build(spec, a.seed, int(si), name, a.out)
        rows.append(info)
        print(f"{name} {spec.category:9s} {spec.label:38s} rows={info['rows']} {time.time() - t1:.1f}s", flush=True)
    if a.only is None and a.names is None:
        with open(os.path.join(a.out, "index.csv"), "w", newline="") as f:
            w = csv.writer(f, lineterminator="\n")
            w.writerow(["name", "category", "rows", "noise", "channels", "robot", "stations", "repeats"])
            for r in rows:
                w.writerow([r[k] for k in ("name", "category", "rows", "noise", "channels", "robot", "stations",
                                           "repeats")])
    print(f"done in {time.time() - t0:.1f} s")


if __name__ == "__main__":
    main()
