"""Write held-out batch D: `python studies/blind/generators/generator_d/make_all.py --out BATCH_DIR --seed 23`."""

from __future__ import annotations

import argparse
import os
import shutil
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import effects as E  # noqa: E402
from campaign import build, write  # noqa: E402
from kin import DEG  # noqa: E402


def sgn(rng):
    return float(rng.choice([-1.0, 1.0]))


# effect factories: (rng, ctx) -> Effect
def compliance(payload=0.0):
    return lambda rng, ctx: E.Compliance(rng, payload_kg=payload)


def backlash(joint):
    return lambda rng, ctx: E.Backlash(rng, joints=(joint,), half_deg=(0.01,))


def cyclic(joint, orders):
    return lambda rng, ctx: E.Cyclic(rng, joint=joint, orders=orders, amps_deg=tuple(0.01 / (1 + i) for i in range(len(orders))))


def gear(joints):
    return lambda rng, ctx: E.GearRatio(rng, joints=joints, eps=tuple(sgn(rng) * rng.uniform(0.6, 1.0) * 3e-4 for _ in joints))


def coupling(a, b):
    return lambda rng, ctx: E.Coupling(rng, driving=a, driven=b, c=sgn(rng) * 1e-3)


def thermal():
    return lambda rng, ctx: E.Thermal(rng)


def plate():
    def f(rng, ctx):
        d = rng.normal(size=3)
        d = d / np.linalg.norm(d) * 0.2
        return E.PlateGeometry(rng, sphere=int(rng.integers(0, 3)), delta_mm=d)
    return f


def cable():
    return lambda rng, ctx: E.CableDrag(rng)


def creep():
    return lambda rng, ctx: E.CameraCreep(rng)


def settling():
    return lambda rng, ctx: E.Settling(rng)


def occlusion():
    return lambda rng, ctx: E.HolderOcclusion(rng)


def bump():
    return lambda rng, ctx: E.CameraBump(rng, ctx["t_bump"])


def sag():
    return lambda rng, ctx: E.AdapterSag(rng)


def slip():
    return lambda rng, ctx: E.PlateSlip(rng)


def vergence():
    return lambda rng, ctx: E.VergenceDrift(rng)


def decenter():
    return lambda rng, ctx: E.LensDecentering(rng)


def iso(s, out=0.0):
    return {"model": "iso", "sigma": s, "outlier_rate": out}


def depth(s, k=3.0, out=0.0):
    return {"model": "depth", "sigma": s, "depth_factor": k, "outlier_rate": out}


SPECS = [
    # ---------------------------------------------------------------- clean
    dict(category="clean", rows=60, protocol="random", noise=iso(0.005), set_column=True),
    dict(category="clean", rows=400, protocol="random", noise=depth(0.006, 3.0)),
    dict(category="clean", rows=240, protocol="random", stations=2, noise=iso(0.01), set_column=True, nominal_given=True),
    dict(category="clean", rows=150, protocol="random", noise=iso(0.02), occlusion_rate=0.04, row_fail_rate=0.02,
         noise_stated=False, sampling={"lateral_frac": 1.1}),
    dict(category="clean", rows=210, protocol="repeat", repeats=3, noise=iso(0.008, out=0.01), pauses_s=[1800, 2700],
         t_column=True, temp_column="air", set_column=True),
    dict(category="clean", rows=144, protocol="grid", noise=iso(0.002), t_column=True, nominal_given=True, offset_ids=True),
    # ---------------------------------------------------------------- catalogue
    dict(category="catalogue", rows=200, protocol="random", noise=iso(0.005), set_column=True,
         effects=[(compliance(), 0.12)], expected=["compliance"]),
    dict(category="catalogue", rows=300, protocol="random", stations=2, noise=depth(0.005, 3.0), t_column=True,
         effects=[(compliance(2.5), 0.2)], expected=["compliance"]),
    dict(category="catalogue", rows=250, protocol="random", noise=iso(0.006),
         effects=[(backlash(1), 0.06)], expected=["backlash"]),
    dict(category="catalogue", rows=220, protocol="random", noise=iso(0.005),
         effects=[(cyclic(2, (2,)), 0.06)], expected=["cyclic"]),
    dict(category="catalogue", rows=260, protocol="random", noise=iso(0.004), set_column=True,
         effects=[(cyclic(6, (1, 2)), 0.03)], expected=["cyclic"]),
    dict(category="catalogue", rows=180, protocol="random", noise=iso(0.004), set_column=True,
         effects=[(gear((2, 3)), 0.06)], expected=["gear_ratio"]),
    dict(category="catalogue", rows=200, protocol="random", noise=iso(0.006),
         effects=[(coupling(4, 5), 0.08)], expected=["coupling"]),
    dict(category="catalogue", rows=300, protocol="random", noise=iso(0.005), t_column=True, temp_column="arm",
         cadence_s=(12.0, 18.0), arm_rise_k=9.0, pauses_s=[1200], effects=[(thermal(), 0.08)], expected=["thermal"]),
    dict(category="catalogue", rows=160, protocol="random", noise=iso(0.005),
         effects=[(plate(), 0.12)], expected=["plate_geometry"]),
    # ---------------------------------------------------------------- outside
    dict(category="outside", rows=240, protocol="random", noise=iso(0.005), effects=[(cable(), 0.08)]),
    dict(category="outside", rows=280, protocol="random", noise=depth(0.004, 2.5), t_column=True,
         effects=[(creep(), 0.08)]),
    dict(category="outside", rows=220, protocol="random", noise=iso(0.005), effects=[(settling(), 0.06)]),
    dict(category="outside", rows=200, protocol="random", noise=iso(0.006), set_column=True,
         sampling={"max_tilt": 45 * DEG}, effects=[(occlusion(), 0.05)]),
    dict(category="outside", rows=260, protocol="random", noise=iso(0.005), t_column=True, pauses_s=[2400],
         t_bump_cut=True, effects=[(bump(), 0.07)]),
    dict(category="outside", rows=230, protocol="random", noise=iso(0.004), effects=[(sag(), 0.05)]),
    dict(category="outside", rows=250, protocol="random", noise=iso(0.006), t_column=True, effects=[(slip(), 0.07)]),
    dict(category="outside", rows=300, protocol="random", noise=depth(0.005, 3.0), t_column=True,
         cadence_s=(10.0, 20.0), effects=[(vergence(), 0.05)]),
    dict(category="outside", rows=180, protocol="random", stations=2, noise=iso(0.004), nominal_given=True,
         effects=[(decenter(), 0.03)]),
    # ---------------------------------------------------------------- mixed
    dict(category="mixed", rows=300, protocol="random", noise=iso(0.005), t_column=True,
         effects=[(compliance(), 0.1), (creep(), 0.06)], expected=["compliance"]),
    dict(category="mixed", rows=250, protocol="random", noise=iso(0.005), set_column=True,
         effects=[(backlash(2), 0.05), (sag(), 0.05)], expected=["backlash"]),
    dict(category="mixed", rows=320, protocol="random", noise=iso(0.006), t_column=True, temp_column="arm",
         pauses_s=[1500], arm_rise_k=8.0, effects=[(thermal(), 0.07), (gear((3,)), 0.05)],
         expected=["thermal", "gear_ratio"]),
    dict(category="mixed", rows=220, protocol="random", noise=depth(0.005, 2.5),
         effects=[(coupling(5, 6), 0.06), (occlusion(), 0.04)], expected=["coupling"]),
    dict(category="mixed", rows=200, protocol="repeat", repeats=2, noise=iso(0.005),
         effects=[(plate(), 0.08), (settling(), 0.05)], expected=["plate_geometry"]),
    dict(category="mixed", rows=360, protocol="random", stations=2, noise=iso(0.006, out=0.005), set_column=True,
         effects=[(compliance(), 0.12), (backlash(1), 0.05), (cable(), 0.06)], expected=["compliance", "backlash"]),
]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", required=True)
    ap.add_argument("--seed", type=int, default=23)
    ap.add_argument("--only", type=int, nargs="*", help="spec indices (debug)")
    ap.add_argument("--names", nargs="*", default=None, help="write only these campaigns (folder names, e.g. d01 d07); the others are left as they are")
    a = ap.parse_args(argv)
    n = len(SPECS)
    perm = np.random.default_rng([a.seed, 999]).permutation(n)
    names = [f"d{perm[i] + 1:02d}" for i in range(n)]
    if a.names is not None and set(a.names) - set(names):
        ap.error(f"unknown campaign names: {sorted(set(a.names) - set(names))}")
    if os.path.isdir(a.out) and not a.only and a.names is None:
        for d in os.listdir(a.out):
            p = os.path.join(a.out, d)
            if os.path.isdir(p) and len(d) == 3 and d.startswith("d"):
                shutil.rmtree(p)
    os.makedirs(a.out, exist_ok=True)
    rows = []
    for i, spec in enumerate(SPECS):
        if a.only and i not in a.only:
            continue
        if a.names is not None and names[i] not in a.names:
            continue
        c = build(spec, a.seed, i, names[i])
        rows.append(write(c, a.out))
        print(f"{names[i]} [{i:2d}] {spec['category']:9s} rows {c['n_data']:3d} "
              f"effects {[round(r, 4) for r in c['per_effect']]}", flush=True)
    if not a.only and a.names is None:
        rows.sort(key=lambda r: r["name"])
        with open(os.path.join(a.out, "index.csv"), "w", newline="\n") as f:
            f.write("name,category,rows,noise,channels,stations\n")
            for r in rows:
                f.write(f"{r['name']},{r['category']},{r['rows']},{r['noise']},{r['channels']},{r['stations']}\n")


if __name__ == "__main__":
    main()
