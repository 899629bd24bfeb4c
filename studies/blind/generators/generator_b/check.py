"""Sanity checks of a generated batch (run after make_all.py):
  python studies/blind/generators/generator_b/check.py --batch BATCH_DIR --work WORK_DIR [--no-twin]
1. every dataset through `twin calibrate` (black box): accepted? validation RMS vs the noise-only expectation;
2. t - e equals the effect-free centres recomputed from key/geometry.json with this package's FK;
3. m - t (noise) per axis of the station frame vs the key (gross rows left out); gross rows as the key says;
4. the geometric-fit leftover of e (recomputed from sequence.csv + geometry.json) vs the key;
5. format facts: rows, validation share, columns.
Writes WORK/checks.json and WORK/checks.md."""
from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import kin  # noqa: E402
from campaign import leftover  # noqa: E402

DEG = np.pi / 180


def read_csv(p):
    with open(p) as f:
        return list(csv.DictReader(f))


def arr(rows, cols):
    return np.array([[float(r[c]) if r[c] != "" else np.nan for c in cols] for r in rows])


def fk_points(geo, q_deg, station, jitter=None, pv=None, tool=None):
    pv = np.array(geo["pv_true"]) if pv is None else pv
    F = kin.flange2base(q_deg * DEG, pv)
    if jitter is not None:
        F = F @ kin.sixdof(jitter)
    T = kin.sixdof(np.array(geo["tool2flange_sixdof"])) if tool is None else tool
    B = np.array(geo["base2meas"])[station]
    return kin.apply(B @ F @ T, np.broadcast_to(np.array(geo["spheres_tool_mm"]), (len(q_deg), 3, 3)))


def jac(geo, q_deg, station):
    stations = sorted(set(station.tolist()))
    P = 25 + 6 + 6 * len(stations)
    pv0 = np.array(geo["pv_true"])
    T0 = kin.sixdof(np.array(geo["tool2flange_sixdof"]))
    Bs = np.array(geo["base2meas"])
    S = np.broadcast_to(np.array(geo["spheres_tool_mm"]), (len(q_deg), 3, 3))

    def model(x):
        F = kin.flange2base(q_deg * DEG, pv0 + x[:25])
        T = T0 @ kin.sixdof(x[25:31])
        B = np.stack([Bs[s] @ kin.sixdof(x[31 + 6 * stations.index(s):37 + 6 * stations.index(s)]) for s in station])
        return kin.apply(B @ F @ T, S).reshape(-1)
    J = np.empty((len(q_deg) * 9, P))
    for i in range(P):
        x = np.zeros(P); x[i] = 1e-6
        J[:, i] = (model(x) - model(-x)) / 2e-6
    return J


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--batch", required=True)
    ap.add_argument("--work", required=True)
    ap.add_argument("--no-twin", action="store_true")
    # default: the project's own `twin`, run from the repository root
    ap.add_argument("--twin", default=None, help="a twin executable (default: this interpreter's twin.cli)")
    a = ap.parse_args()
    os.makedirs(a.work, exist_ok=True)
    out = []
    for name in sorted(d for d in os.listdir(a.batch) if os.path.isdir(os.path.join(a.batch, d))):
        base = os.path.join(a.batch, name)
        key = json.load(open(os.path.join(base, "key", "key.json")))
        geo = json.load(open(os.path.join(base, "key", "geometry.json")))
        seq = read_csv(os.path.join(base, "key", "sequence.csv"))
        poses = read_csv(os.path.join(base, "dataset", "poses.csv"))
        r = dict(name=name, category=key["category"], label=key["label"])
        q = arr(seq, [f"q{j}" for j in range(1, 7)])
        st = np.array([int(x["station"]) for x in seq])
        M = arr(seq, [f"m{k}_{c}" for k in range(3) for c in "xyz"]).reshape(-1, 3, 3)
        T = arr(seq, [f"t{k}_{c}" for k in range(3) for c in "xyz"]).reshape(-1, 3, 3)
        E = arr(seq, [f"e{k}_{c}" for k in range(3) for c in "xyz"]).reshape(-1, 3, 3)
        jit = np.array(geo["flange_jitter_sixdof"])
        # 2. e consistency
        P0 = fk_points(geo, q, st, jitter=jit)
        r["t_minus_e_vs_effect_free_max_mm"] = float(np.max(np.abs(T - E - P0)))
        n_data = len(poses)
        role = np.array([x["role"] for x in seq])
        data = role != "test"
        r["rows"] = n_data
        r["dataset_rows_match_sequence"] = bool(data.sum() == n_data and all(
            poses[i]["pose_id"] == seq[i]["pose_id"] for i in range(n_data)))
        # measurements in poses.csv == m columns
        pm = arr(poses, [f"p{k}_{c}" for k in range(3) for c in "xyz"]).reshape(-1, 3, 3)
        r["poses_equal_m_columns"] = bool(np.allclose(np.nan_to_num(pm, nan=1e9), np.nan_to_num(M[:n_data], nan=1e9), atol=1e-9))
        # 3. noise per station axis (gross rows out)
        gross_ids = set()
        for nt in key["notes"]:
            if nt.startswith("gross rows"):
                for part in nt.split(":", 1)[1].split(";"):
                    gross_ids.add(part.split()[1])
        ok = np.array([x["pose_id"] not in gross_ids for x in seq])
        d = (M - T)[ok]
        d = d[~np.isnan(d).any(axis=2)]
        r["noise_rms_xy_mm"] = float(np.sqrt(np.nanmean(d[:, :2] ** 2)))
        r["noise_rms_los_mm"] = float(np.sqrt(np.nanmean(d[:, 2] ** 2)))
        r["key_sigma_xy_mm"] = key["noise"]["sigma_xy_mm"]
        r["key_sigma_los_mm"] = key["noise"]["sigma_los_mm"]
        if gross_ids:
            g = np.array([x["pose_id"] in gross_ids for x in seq])
            r["gross_offsets_mm"] = [float(np.nanmax(np.linalg.norm(M[i] - T[i], axis=1))) for i in np.where(g)[0]]
        # 4. leftover of e (combined)
        present = ~np.isnan(M[:n_data]).any(axis=2)
        if "set" in poses[0]:
            cal = np.where(role[:n_data] == "calibration")[0]; ev = np.where(role[:n_data] == "validation")[0]
            r["validation_share"] = len(ev) / n_data
        else:
            cal = ev = np.arange(n_data)
        J = jac(geo, q[:n_data], st[:n_data]).reshape(n_data, 9, -1)
        mc = np.repeat(present[cal], 3, axis=1).reshape(-1); me = np.repeat(present[ev], 3, axis=1).reshape(-1)
        if key["effects"]:
            lo = leftover(J[cal].reshape(-1, J.shape[2])[mc], E[cal].reshape(-1)[mc],
                          J[ev].reshape(-1, J.shape[2])[me], E[ev].reshape(-1)[me])
            r["leftover_recomputed_mm"] = float(np.sqrt(np.mean(lo ** 2)))
            r["leftover_key_mm"] = [e["rms_mm"] for e in key["effects"]]
            comb = [n for n in key["notes"] if n.startswith("combined")]
            r["leftover_key_combined"] = comb[0] if comb else None
            r["ratio_key"] = [e["ratio"] for e in key["effects"]]
        r["noise_total_rms_per_coord_mm"] = key["noise"]["total_rms_per_coordinate_mm"]
        # 1. twin calibrate
        if not a.no_twin:
            od = os.path.join(a.work, "calibrate", name)
            twin = [a.twin] if a.twin else [sys.executable, "-m", "twin.cli"]
            p = subprocess.run([*twin, "calibrate", os.path.abspath(os.path.join(base, "dataset")), "--out",
                                os.path.abspath(od), "--quiet"], capture_output=True, text=True, cwd=os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))))
            r["twin_rc"] = p.returncode
            if p.returncode != 0:
                r["twin_stderr"] = p.stderr[-2000:]
            else:
                c = json.load(open(os.path.join(od, "calibration.json")))
                res = c["residuals"]
                r["twin_val_rms_mm"] = res["validation"]["position_mm"]["rms"]
                r["twin_expected_rms_mm"] = res.get("predicted_validation", {}).get("expected_residual_rms")
                r["twin_residual_scale"] = c["noise"].get("residual_scale")
                r["twin_noise_mm"] = c["noise"].get("position_mm")
                r["twin_noise_source"] = c["noise"].get("position_mm_source")
                r["twin_rejected"] = len(c["rows"].get("calibration_rejected", []))
                r["twin_skipped"] = len(c["rows"].get("skipped", []))
                n = key["noise"]
                # noise-only expectation of the 3-D per-sphere RMS (no fit-degrees-of-freedom correction)
                r["noise_only_3d_rms_mm"] = float(np.sqrt(2 * n["sigma_xy_mm"] ** 2 + n["sigma_los_mm"] ** 2
                                                          + 3 * n["repeatability_rms_per_coordinate_mm"] ** 2))
                r["twin_val_over_noise"] = r["twin_val_rms_mm"] / r["noise_only_3d_rms_mm"]
        out.append(r)
        print(json.dumps({k: (round(v, 5) if isinstance(v, float) else v) for k, v in r.items()}), flush=True)
    json.dump(out, open(os.path.join(a.work, "checks.json"), "w"), indent=1)


if __name__ == "__main__":
    main()
