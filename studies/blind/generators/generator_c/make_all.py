"""Batch C of held-out campaigns: python make_all.py --out DIR --seed 11 (deterministic)."""

from __future__ import annotations

import argparse
import csv
import os
import shutil
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import campaign  # noqa: E402
import effects as fx  # noqa: E402
import write  # noqa: E402

E = fx


def specs():
    """The 30 campaigns (category, effects with the target 'left after geometric calibration / noise', design)."""
    S = []

    def add(tag, cat, expected, effs, **kw):
        S.append(dict(uid=len(S) + 1, tag=tag, cat=cat, expected=expected, effects=effs, **kw))

    # ------------------------------------------------------------------ clean
    add("K1", "clean", [], [], robot="irb1200", stations=["cam"], station_col=False, noise=dict(kind="iso", rms=0.005),
        protocol="random", n=220, t_s=True, status=True, restarts=1, missing=2, repeats=("still", 0.2), stated="ok",
        extras=["note"], order=0)
    add("K2", "clean", [], [], robot="irb1200", plate=0, stations=["north", "east"], noise=dict(kind="stereo", rms=0.0035, rho=0.5),
        protocol="random", n=260, t_s=False, stated="none", extras=["exposure_ms"], order=1)
    add("K3", "clean", [], [], robot="irb1200", stations=["cam"], station_col=True, noise=dict(kind="iso", rms=0.003), rep=0.012,
        repeats=("reapproach", 0.3), protocol="random", n=240, temp=True, stated="none", order=2, extras=["operator"])
    add("K4", "clean", [], [], robot="irb1200", stations=["front"], station_col=False, noise=dict(kind="stereo", rms=0.008, rho=0.3),
        rep=0.008, repeats=("still", 0.35), protocol="serpentine", n=280, stated="none", extras=["frame"], order=0)
    add("K5", "clean", [], [], robot="A", plate=3, stations=["stand"], station_col=False, noise=dict(kind="tracker", rms=0.005),
        protocol="random", n=180, set=False, stated="x2", order=3, fov_deg=24.0)
    add("K6", "clean", [], [], robot="irb1200", stations=["left", "centre", "right"], noise=dict(kind="stereo", rms=0.016, rho=0.4),
        protocol="sweeps", n=300, temp=True, gross=2, status=True, missing=3, repeats=("still", 0.15), stated="ok",
        extras=["exposure_ms", "note"], order=1, id_gaps=True)

    # ------------------------------------------------------------------ catalogue
    add("A1", "catalogue", ["compliance"], [(lambda r, env: E.Compliance(r, [2, 3], 1.0, (0, 0, 40), [1.0, 1.6]), 4.5)],
        robot="irb1200", stations=["cam"], station_col=False, noise=dict(kind="iso", rms=0.006), protocol="serpentine", n=250,
        temp=True, repeats=("still", 0.2), stated="ok", order=0)
    add("A2", "catalogue", ["compliance"],
        [(lambda r, env: E.Compliance(r, [4, 5, 6], 6.5, (75, -45, 125), [1.0, 0.8, 1.3], label="payload"), 3.5)],
        robot="irb1200", plate=1, stations=["tripod"], station_col=True, noise=dict(kind="stereo", rms=0.005, rho=0.45), protocol="random",
        n=230, stated="none", order=2, extras=["exposure_ms"])
    add("A3", "catalogue", ["backlash"], [(lambda r, env: E.Backlash(r, [1, 6], [1.0, 1.8]), 5.0)],
        robot="irb1200", stations=["cam"], station_col=False, noise=dict(kind="iso", rms=0.004), protocol="pairs", pair_col=True,
        n=240, temp=True, gross=1, stated="ok", order=0, extras=["operator"])
    add("A4", "catalogue", ["backlash"], [(lambda r, env: E.Backlash(r, [4], [1.0], angle_dependent=True), 2.2)],
        robot="irb1200", stations=["bench"], station_col=True, noise=dict(kind="stereo", rms=0.007, rho=0.4), protocol="sweeps", n=260,
        status=True, missing=3, repeats=("still", 0.2), stated="none", order=1)
    add("A5", "catalogue", ["cyclic"], [(lambda r, env: E.Cyclic(r, [(3, 1, 1.0), (3, 2, 0.6)]), 6.0)],
        robot="irb1200", stations=["window", "door"], noise=dict(kind="iso", rms=0.008), protocol="random", n=300, t_s=False,
        missing=3, stated="ok", order=3)
    add("A6", "catalogue", ["cyclic"], [(lambda r, env: E.Cyclic(r, [(4, 1.5, 1.0)]), 3.0)],
        robot="irb1200", plate=2, stations=["cam"], station_col=False, noise=dict(kind="iso", rms=0.004), rep=0.005, protocol="random",
        n=220, temp=True, stated="none", order=0, extras=["note"])
    add("A7", "catalogue", ["gear_ratio"], [(lambda r, env: E.GearRatio(r, [1, 3], [1.0, -0.7]), 4.0)],
        robot="B", stations=["cam"], station_col=False, noise=dict(kind="stereo", rms=0.01, rho=0.35), protocol="random", n=200,
        set=False, stated="ok", order=0)
    add("A8", "catalogue", ["coupling"], [(lambda r, env: E.Coupling(r, 4, 6), 2.3)],
        robot="irb1200", stations=["cam"], station_col=False, noise=dict(kind="iso", rms=0.005), protocol="random", n=210,
        temp=True, repeats=("still", 0.25), stated="none", order=2, extras=["image"])
    add("A9", "catalogue", ["thermal"], [(lambda r, env: E.ThermalMotors(r, r.uniform(1200, 2000), r.uniform(700, 1300)), 4.0)],
        robot="irb1200", stations=["bench", "pillar"], noise=dict(kind="stereo", rms=0.006, rho=0.5), protocol="random", n=290,
        temp=True, repeats=("still", 0.12), stated="ok", t_start=(60, 150), noise_clip=(0.002, 0.015), order=1, extras=["operator"])
    add("A10", "catalogue", ["plate_geometry"], [(lambda r, env: E.PlateSphere(r, 2), 3.5)],
        robot="irb1200", plate=4, stations=["cam"], station_col=False, noise=dict(kind="iso", rms=0.01), protocol="random", n=170,
        t_s=False, repeats=("still", 0.2), stated="none", order=0)

    # ------------------------------------------------------------------ outside the vocabulary
    add("O1", "outside", [], [(lambda r, env: E.TripodSettle(r, env["n_stations"]), 4.0)],
        robot="irb1200", stations=["east", "west"], noise=dict(kind="stereo", rms=0.006, rho=0.5), protocol="random", n=260,
        temp=True, repeats=("still", 0.15), stated="none", order=0, extras=["exposure_ms"])
    add("O2", "outside", [], [(lambda r, env: E.BarWarmup(r), 4.0)],
        robot="irb1200", stations=["cam"], station_col=False, noise=dict(kind="stereo", rms=0.005, rho=0.6), protocol="sweeps", n=240,
        temp=True, repeats=("still", 0.2), stated="ok", order=1)
    add("O3", "outside", [], [(lambda r, env: E.LensDistortion(r), 3.0)],
        robot="irb1200", plate=5, stations=["cam"], station_col=False, noise=dict(kind="iso", rms=0.004), protocol="serpentine", n=200,
        set=False, t_s=False, stated="none", order=0, fov_deg=22.0)
    add("O4", "outside", [], [(lambda r, env: E.TripodBump(r), 3.0)],
        robot="irb1200", stations=["floor"], station_col=True, noise=dict(kind="iso", rms=0.003), rep=0.006, repeats=("still", 0.15),
        protocol="random", n=230, stated="none", order=2, extras=["frame"])
    add("O5", "outside", [], [(lambda r, env: E.SpecularBias(r, 12.7), 2.5)],
        robot="irb1200", stations=["cam"], station_col=False, noise=dict(kind="stereo", rms=0.008, rho=0.4), protocol="serpentine", n=270,
        temp=True, gross=2, stated="ok", order=0)
    add("O6", "outside", [], [(lambda r, env: E.RockingBase(r), 5.0)],
        robot="C", stations=["cam"], station_col=False, noise=dict(kind="iso", rms=0.006), protocol="random", n=220,
        status=True, missing=2, repeats=("still", 0.2), stated="none", order=1)
    add("O7", "outside", [], [(lambda r, env: E.SettleLag(r, [1, 2, 3], [1.0, 0.8, 1.2]), 4.0)],
        robot="irb1200", stations=["cam"], station_col=False, noise=dict(kind="iso", rms=0.005), protocol="pairs", pair_col=True,
        n=200, temp=True, stated="ok", order=0)
    add("O8", "outside", [], [(lambda r, env: E.PlateRemount(r), 3.5)],
        robot="irb1200", plate=1, stations=["cam"], station_col=False, noise=dict(kind="stereo", rms=0.004, rho=0.5), protocol="random",
        n=250, temp=True, repeats=("still", 0.2), stated="none", order=3, extras=["note"])
    add("O9", "outside", [], [(lambda r, env: E.RestartOffset(r, 3), 3.0)],
        robot="irb1200", stations=["cam"], station_col=False, noise=dict(kind="iso", rms=0.007), protocol="random", n=240,
        status=True, restarts=2, missing=2, stated="ok", order=0)

    # ------------------------------------------------------------------ mixed
    add("M1", "mixed", ["thermal"],
        [(lambda r, env: E.ThermalAmbient(r, [("a3", 14), ("d4", 9)], r.uniform(400, 800)), 4.0), (lambda r, env: E.LensDistortion(r), 3.0)],
        robot="irb1200", stations=["cam"], station_col=False, noise=dict(kind="iso", rms=0.005), protocol="random", n=280,
        temp=True, temp_kind="warming", temp_rise=8.0, temp_T0=14.0, temp_tau=(1200, 1800), t_start=(120, 300), stated="ok", order=0)
    add("M2", "mixed", ["backlash", "compliance"],
        [(lambda r, env: E.Backlash(r, [1], [1.0]), 3.0), (lambda r, env: E.Compliance(r, [2, 3], 1.5, (0, 0, 45), [1.0, 1.3]), 3.5)],
        robot="irb1200", stations=["cam"], station_col=False, noise=dict(kind="stereo", rms=0.006, rho=0.4), protocol="pairs", pair_col=True,
        n=260, stated="none", order=2, extras=["operator"])
    add("M3", "mixed", ["coupling"], [(lambda r, env: E.Coupling(r, 5, 6), 3.5), (lambda r, env: E.TripodBump(r, station=-1), 3.0)],
        robot="irb1200", stations=["aisle", "wall"], noise=dict(kind="iso", rms=0.006), protocol="random", n=300, temp=True,
        missing=2, stated="none", order=1)
    add("M4", "mixed", ["gear_ratio", "plate_geometry"],
        [(lambda r, env: E.GearRatio(r, [2], [1.0]), 3.0), (lambda r, env: E.PlateSphere(r, 0), 3.0)],
        robot="irb1200", plate=3, stations=["cam"], station_col=False, noise=dict(kind="iso", rms=0.009), protocol="random", n=220,
        set=False, t_s=False, gross=3, stated="ok", order=0)
    add("M5", "mixed", ["cyclic"], [(lambda r, env: E.Cyclic(r, [(2, 2, 1.0)]), 3.5), (lambda r, env: E.BarWarmup(r), 3.0)],
        robot="irb1200", stations=["cam"], station_col=True, noise=dict(kind="stereo", rms=0.007, rho=0.5), protocol="random", n=250,
        temp=True, repeats=("still", 0.2), stated="none", order=0, extras=["exposure_ms", "note"])
    return S


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", required=True)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--only", default="", help="comma-separated internal tags (debugging)")
    ap.add_argument("--names", nargs="*", default=None, help="write only these campaigns (folder names, e.g. c01 c07); the others are left as they are")
    args = ap.parse_args(argv)
    t0 = time.time()
    S = specs()
    rng = np.random.default_rng(args.seed)
    order = rng.permutation(len(S))
    known = {f"c{k + 1:02d}" for k in range(len(S))}
    if args.names is not None and set(args.names) - known:
        ap.error(f"unknown campaign names: {sorted(set(args.names) - known)}")
    if os.path.isdir(args.out) and not args.only and args.names is None:
        shutil.rmtree(args.out)
    os.makedirs(args.out, exist_ok=True)
    index = []
    only = set(filter(None, args.only.split(",")))
    for pos, si in enumerate(order):
        spec = S[si]
        name = f"c{pos + 1:02d}"
        if only and spec["tag"] not in only:
            continue
        if args.names is not None and name not in args.names:
            continue
        res = campaign.build(spec, args.seed, args.out, name)
        row = write.write_campaign(spec, res, args.out, name, args.seed, spec["cat"], spec["expected"])
        index.append(row)
        print(f"{name} {spec['tag']:4s} {spec['cat']:9s} rows={row['rows']} noise={row['noise']} "
              f"left/noise={[round(e['left'] / res['sigma_ref'], 2) for e in res['eff_out']]} "
              f"all={res['left_all'] / res['sigma_ref']:.2f} amp/phys={[round(e['eff'].amp / e['amp_phys'], 2) for e in res['eff_out']]} ({time.time() - t0:.1f} s)", flush=True)
    if not only and args.names is None:
        with open(os.path.join(args.out, "index.csv"), "w", newline="") as f:
            w = csv.DictWriter(f, ["name", "category", "rows", "noise", "channels", "stations", "repeats"], lineterminator="\n")
            w.writeheader()
            for r in sorted(index, key=lambda r: r["name"]):
                w.writerow(r)
    print(f"done in {time.time() - t0:.1f} s")


if __name__ == "__main__":
    main()
