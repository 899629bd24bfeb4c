"""Self-checks of a written batch: `python check.py --out BATCH --seed 23`.

* t - e equals the geometry-only forward kinematics computed here directly (true MDH parameters, true plate,
  true station base2meas, commanded joints read back from sequence.csv);
* e is zero on clean campaigns and non-zero where effects act;
* the dataset's sphere columns equal the m columns of the non-test rows of sequence.csv;
* m - t scatter matches the stated noise (outliers excluded).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from campaign import build  # noqa: E402
from kin import DEG, PLATE_SPHERES_MM, apply_T, flange2base  # noqa: E402
from make_all import SPECS  # noqa: E402


def read_csv(path):
    with open(path) as f:
        r = list(csv.DictReader(f))
    return r


def arr(rows, cols):
    return np.array([[float(r[c]) if r[c] != "" else np.nan for c in cols] for r in rows])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--seed", type=int, default=23)
    a = ap.parse_args()
    perm = np.random.default_rng([a.seed, 999]).permutation(len(SPECS))
    ok_all = True
    for i, spec in enumerate(SPECS):
        name = f"d{perm[i] + 1:02d}"
        c = build(spec, a.seed, i, name)
        seq = read_csv(os.path.join(a.out, name, "key", "sequence.csv"))
        poses = read_csv(os.path.join(a.out, name, "dataset", "poses.csv"))
        key = json.load(open(os.path.join(a.out, name, "key", "key.json")))
        q = arr(seq, [f"q{j}" for j in range(1, 7)]) * DEG
        st = np.array([int(r.get("station", 0) or 0) for r in seq])
        T = arr(seq, [f"t{i}_{x}" for i in range(3) for x in "xyz"]).reshape(-1, 3, 3)
        Ecol = arr(seq, [f"e{i}_{x}" for i in range(3) for x in "xyz"]).reshape(-1, 3, 3)
        M = arr(seq, [f"m{i}_{x}" for i in range(3) for x in "xyz"]).reshape(-1, 3, 3)
        # independent geometry-only FK
        F = flange2base(c["P"], q)
        B = np.stack([c["base2meas"][s] for s in st])
        g = apply_T(B @ F @ c["tool2flange"][None], np.tile(PLATE_SPHERES_MM, (len(q), 1, 1)))
        d_fk = np.max(np.abs((T - Ecol) - g))
        e_rms = float(np.sqrt(np.mean(np.sum(Ecol ** 2, axis=2))))
        e_max = float(np.max(np.abs(Ecol)))
        nd = len(poses)
        Mp = arr(poses, [f"p{i}_{x}" for i in range(3) for x in "xyz"]).reshape(-1, 3, 3)
        same = np.array_equal(np.isnan(Mp), np.isnan(M[:nd])) and np.nanmax(np.abs(Mp - M[:nd])) < 1e-9
        roles = {r["role"] for r in seq}
        ntest = sum(r["role"] == "test" for r in seq)
        resid = (M - T)
        good = ~c["outliers"][..., None].repeat(3, 2) & ~np.isnan(resid)
        sig_xyz = np.sqrt(np.nanmean(np.where(good, resid, np.nan) ** 2, axis=(0, 1)))
        miss = int(np.isnan(Mp[..., 0]).sum())
        clean = spec["category"] == "clean"
        ok = d_fk < 2e-6 and same and ntest == 60 and ((e_max == 0) if clean else (e_rms > 0.005))
        ok &= len(key["effects"]) == len(spec.get("effects", []))
        ok_all &= ok
        print(f"{name} {spec['category']:9s} rows {nd:3d} roles {sorted(roles)} |t-e-FK|max {d_fk:.1e} mm  e_rms {e_rms:.4f} "
              f"(max {e_max:.3f}) m-t sd xyz {np.round(sig_xyz, 4).tolist()} missing spheres {miss} poses==seq {same} "
              f"{'OK' if ok else 'FAIL'}")
    print("ALL OK" if ok_all else "SOME CHECKS FAILED")


if __name__ == "__main__":
    main()
