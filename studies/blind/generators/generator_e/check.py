"""Sanity checks of a generated batch: python check.py BATCH."""
import csv, json, os, sys
import numpy as np
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import kin, cell

batch = sys.argv[1]
for name in sorted(d for d in os.listdir(batch) if d.startswith("e")):
    key = json.load(open(f"{batch}/{name}/key/key.json"))
    geo = json.load(open(f"{batch}/{name}/key/truth_geometry.json"))
    rows = list(csv.DictReader(open(f"{batch}/{name}/key/sequence.csv")))
    ds = list(csv.DictReader(open(f"{batch}/{name}/dataset/poses.csv")))
    f = lambda r, p: np.array([[float(r[f"{p}{k}_{a}"]) if r[f"{p}{k}_{a}"] != "" else np.nan for a in "xyz"] for k in range(3)])
    q = np.array([[float(r[f"q{j}"]) for j in range(1, 7)] for r in rows])
    M = np.stack([f(r, "m") for r in rows]); T = np.stack([f(r, "t") for r in rows]); E = np.stack([f(r, "e") for r in rows])
    st = np.array([int(r.get("station", 0) or 0) for r in rows])
    # geometry-only FK from the stored truth
    tp = geo["true_parameters"]; p = {}
    for k in ("theta", "d", "a", "alpha"):
        p[k] = np.array([tp[f"{k}{i}" + ("_deg" if k in ("theta", "alpha") else "_mm")] for i in range(1, 7)]) * (kin.DEG if k in ("theta", "alpha") else 1)
    p["beta"] = np.zeros(6); p["beta"][1] = tp["beta2_deg"] * kin.DEG
    tx = geo["tool2flange"]
    Tt = kin.T_from_xyzrv(np.array([tx[k] for k in ("x_mm", "y_mm", "z_mm", "rx_rad", "ry_rad", "rz_rad")]))
    B = np.stack([np.array(geo["base2meas"][str(s)]) for s in st])
    P0 = kin.spheres_meas(p, q * kin.DEG, B, Tt, np.array(geo["spheres_tool_mm"]))
    d_geo = np.max(np.abs(T - E - P0))
    # dataset rows equal the first rows of the sequence
    nd = len(ds)
    same = all(ds[i][c] == rows[i][c.replace("p", "m", 1) if c.startswith("p") else c] for i in range(nd) for c in ds[0] if (c[0] == "q" or c[:2] in ("p0", "p1", "p2")))
    roles = sorted(set(r["role"] for r in rows))
    res = (M - T)[:nd]
    ok = np.isfinite(res)
    rr = np.sqrt(np.nanmean(res[ok] ** 2)) if ok.any() else np.nan
    e_rms = np.sqrt(np.nanmean(np.sum(E[:nd] ** 2, axis=2)))
    e_test = np.sqrt(np.nanmean(np.sum(E[nd:] ** 2, axis=2)))
    lim = np.array(kin.ROBOTS[geo["robot"]]["q_min"]), np.array(kin.ROBOTS[geo["robot"]]["q_max"])
    inlim = np.all((q > lim[0]) & (q < lim[1]))
    tilt = cell.tilt_deg(T, B @ kin.flange2base(p, q * kin.DEG) @ Tt)
    z = T[..., 2]
    ts = [float(r["t_s"]) for r in rows] if "t_s" in rows[0] else None
    mono = ts is None or all(b > a for a, b in zip(ts, ts[1:]))
    cat = key["category"]
    flag = ""
    if cat == "clean" and np.max(np.abs(E)) != 0: flag += " E_NONZERO_ON_CLEAN"
    if cat != "clean" and e_rms < 0.005: flag += " E_TINY"
    if d_geo > 2e-5: flag += " T-E!=FK"
    if not same: flag += " DATASET!=SEQ"
    if not inlim: flag += " LIMITS"
    if not mono: flag += " TIME"
    print(f"{name} {cat:9s} n={nd:3d}+{len(rows)-nd} roles={','.join(roles):32s} |t-e-fk|max={d_geo:.1e} "
          f"rms(m-t)/coord={rr:.4f} (key {key['noise']['per_coordinate_mm']:.4f}) e_rms data/test={e_rms:.3f}/{e_test:.3f} "
          f"z={z.min():.0f}..{z.max():.0f} tilt<={tilt.max():.0f}{flag}")
