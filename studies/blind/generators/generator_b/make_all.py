"""Generate held-out batch B: python make_all.py --out DIR --seed 7 (deterministic)."""
from __future__ import annotations

import argparse
import csv
import os
import shutil
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from campaign import Campaign  # noqa: E402
from campaigns import SPECS  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--only", default=None, help="comma-separated labels (debugging)")
    ap.add_argument("--names", nargs="*", default=None, help="write only these campaigns (folder names, e.g. b01 b07); the others are left as they are")
    a = ap.parse_args(argv)
    t0 = time.time()
    root = os.path.abspath(a.out)
    if os.path.isdir(root) and a.only is None and a.names is None:
        shutil.rmtree(root)
    os.makedirs(root, exist_ok=True)
    ss = np.random.SeedSequence(a.seed)
    perm = np.random.default_rng(ss.spawn(1)[0]).permutation(len(SPECS))
    names = {i: f"b{int(p) + 1:02d}" for i, p in enumerate(perm)}
    if a.names is not None and set(a.names) - set(names.values()):
        ap.error(f"unknown campaign names: {sorted(set(a.names) - set(names.values()))}")
    children = np.random.SeedSequence(a.seed, spawn_key=(1,)).spawn(len(SPECS))
    index = []
    for i, spec in enumerate(SPECS):
        if a.only and spec["label"] not in a.only.split(","):
            continue
        if a.names is not None and names[i] not in a.names:
            continue
        c = Campaign(spec, children[i], names[i]).build().size()
        index.append(c.write(root))
        st = " ".join(f"{type(e).__name__}:{s['ratio']:.2f}" for e, s in zip(c.effects, c.eff_stats))
        print(f"{names[i]} {spec['label']:40s} rows={spec['rows']} nu={c.nu:.4f} {st}", flush=True)
    index.sort(key=lambda r: r["name"])
    if a.only is None and a.names is None:
        with open(os.path.join(root, "index.csv"), "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=["name", "category", "rows", "noise", "channels", "stations", "repeats"])
            w.writeheader()
            w.writerows(index)
    print(f"done in {time.time() - t0:.1f} s")


if __name__ == "__main__":
    main()
