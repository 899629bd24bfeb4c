"""Generate the held-out batch: python studies/blind/generators/generator_e/make_all.py --out BATCH_DIR --seed 31
[--only e03 e17]."""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import assemble  # noqa: E402
import writers  # noqa: E402
from campaigns import SPECS  # noqa: E402


def names(seed):
    perm = np.random.default_rng([seed, 0]).permutation(len(SPECS))
    return {i: f"e{perm[i] + 1:02d}" for i in range(len(SPECS))}


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--seed", type=int, default=31)
    ap.add_argument("--only", "--names", nargs="*", default=None, help="campaign folder names, e.g. e03 e17")
    a = ap.parse_args(argv)
    nm = names(a.seed)
    inv = {v: k for k, v in nm.items()}
    todo = sorted(nm, key=lambda i: nm[i])
    if a.only:
        bad = [x for x in a.only if x not in inv]
        if bad:
            ap.error(f"unknown campaign names: {bad}")
        todo = [inv[x] for x in sorted(a.only)]
    os.makedirs(a.out, exist_ok=True)
    index_rows = {}
    for i in todo:
        name = nm[i]
        cidx = int(name[1:])
        t0 = time.time()
        spec = SPECS[i]
        res = assemble.assemble(spec, a.seed, cidx)
        base = os.path.join(a.out, name)
        cols = writers.write_dataset(os.path.join(base, "dataset"), name, spec, res)
        writers.write_key(os.path.join(base, "key"), name, spec, res, a.seed, cidx, cols)
        eff = "; ".join(f"{e['family']} {e['rms_mm']:.3f}" for e in res["effects"]) or "-"
        print(f"{name} {spec['category']:9s} rows={res['n_data']:3d} sigma={res['sigma_pc']:.4f} [{eff}] {time.time()-t0:.1f}s", flush=True)
        index_rows[name] = (spec["category"], res["n_data"], round(res["sigma_pc"], 4), ";".join(cols), len(res["truth"].stations))
    # index.csv: always the whole batch (rows from the spec when a campaign was not regenerated now)
    path = os.path.join(a.out, "index.csv")
    old = {}
    if os.path.exists(path):
        for ln in open(path).read().splitlines()[1:]:
            f = ln.split(",")
            old[f[0]] = ln
    lines = ["name,category,rows,noise,channels,stations"]
    for i in sorted(nm, key=lambda i: nm[i]):
        n = nm[i]
        if n in index_rows:
            c, r, s, ch, ns = index_rows[n]
            lines.append(f"{n},{c},{r},{s:.4f},{ch},{ns}")
        elif n in old:
            lines.append(old[n])
    with open(path, "w", newline="\n") as fh:
        fh.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
