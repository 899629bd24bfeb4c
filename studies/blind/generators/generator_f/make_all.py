"""Generate batch F: python studies/blind/generators/generator_f/make_all.py --out BATCH_DIR --seed 43 [--only f03 f17]

Deterministic from the seed: the same bytes every run. Campaign folders f01..f30 are named by a permutation of the
specs drawn with default_rng([seed, 0]); campaign fNN's random streams are default_rng([seed, NN, k]) (assemble.py).
"""
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
    return {i: f"f{perm[i] + 1:02d}" for i in range(len(SPECS))}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--seed", type=int, default=43)
    ap.add_argument("--only", "--names", nargs="*", default=None, help="campaign folder names, e.g. f03 f17")
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
    index = {}
    for i in todo:
        name = nm[i]
        num = int(name[1:])
        t0 = time.time()
        spec = SPECS[i]
        res = assemble.assemble(spec, a.seed, num)
        base = os.path.join(a.out, name)
        cols = writers.write_dataset(os.path.join(base, "dataset"), name, spec, res)
        writers.write_key(os.path.join(base, "key"), name, spec, res, a.seed, num, cols)
        eff = "; ".join(f"{e['family']} {e['rms_mm']:.3f}" for e in res["effects"]) or "-"
        print(f"{name} {spec['category']:9s} rows={res['n_data']:3d}+{len(res['qdeg']) - res['n_data']} "
              f"noise={res['sigma_pc'] * 1e3:.4f} [{eff}] {time.time() - t0:.1f}s", flush=True)
        index[name] = f"{name},{spec['category']},{res['n_data']},{res['sigma_pc'] * 1e3:.4f},{';'.join(cols)},{len(res['stations'])}"
    path = os.path.join(a.out, "index.csv")
    old = {}
    if os.path.exists(path):
        for ln in open(path).read().splitlines()[1:]:
            old[ln.split(",")[0]] = ln
    old.update(index)
    with open(path, "w", newline="\n") as fh:
        fh.write("name,category,rows,noise_mm,channels,stations\n")
        fh.write("".join(old[n] + "\n" for n in sorted(old)))


if __name__ == "__main__":
    main()
