"""Sanity checks of a generated batch (writes nothing into the batch; scratch output in --work).

    python studies/blind/generators/generator_a/check.py --batch BATCH_DIR --work WORK_DIR

1. poses.csv == the dataset rows of key/sequence.csv (ids, joints, measured centres, channels);
2. e == t - (effect-free centres recomputed here from the key's true geometry with this generator's FK);
3. RMS of e per coordinate over the dataset rows == the key's figures;
4. m - t scatter (outliers left out) vs the key's noise model; the outliers are where the key says;
5. `twin calibrate` (black box) accepts every dataset; on clean campaigns the validation residual is at the
   noise level;
6. with --clean-twins: every campaign regenerated without its effects and calibrated (checks this FK for each
   robot, plate and station layout against the tool's reader/estimator).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402

from kin import DEG, ROBOTS, pose6_to_T, sphere_points  # noqa: E402

# the project's own `twin`, run from the repository root (this file: studies/blind/generators/generator_a/)
REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))))
TWIN = [sys.executable, "-m", "twin.cli"]


def read_csv(path):
    with open(path) as f:
        r = list(csv.DictReader(f))
    return r


def num(s):
    return np.nan if s == "" else float(s)


def robot_from_key(k):
    rob = ROBOTS[{"irb1200": "irb1200", "heldout_arm_b": "arm_b", "heldout_arm_c": "arm_c"}[k["robot"]["name"]]]()
    tr = k["robot"]["true"]
    rob.theta = np.array(tr["theta_deg"]) * DEG
    rob.d = np.array(tr["d_mm"], float)
    rob.a = np.array(tr["a_mm"], float)
    rob.alpha = np.array(tr["alpha_deg"]) * DEG
    rob.beta2 = tr["beta2_deg"] * DEG
    return rob


def expected_3d_rms(k):
    n = k["noise"]
    s = np.array([n["sigma_lateral_mm"], n["sigma_lateral_mm"], n["sigma_depth_mm"]])
    rep = n["repeatability_rms_per_coordinate_mm"] or 0.0
    return float(np.sqrt(np.sum(s ** 2) + 3 * rep ** 2))


def calibrate(ds, out):
    ds, out = os.path.abspath(ds), os.path.abspath(out)
    p = subprocess.run([*TWIN, "calibrate", ds, "--out", out, "--quiet"], cwd=REPO, capture_output=True,
                       text=True)
    if p.returncode != 0:
        return dict(ok=False, error=(p.stderr or p.stdout)[-600:])
    c = json.load(open(os.path.join(out, "calibration.json")))
    return dict(ok=True, val_rms=c["residuals"]["validation"]["position_mm"]["rms"],
                cal_rms=c["residuals"]["calibration"]["position_mm"]["rms"],
                expected_rms=c["residuals"].get("predicted_validation", {}).get("expected_residual_rms", {}).get(
                    "position_mm"),
                residual_scale=c["noise"]["residual_scale"], noise_used=c["noise"]["position_mm"],
                noise_source=c["noise"]["position_source"],
                rejected=[r["pose_id"] for r in c["rows"]["calibration_rejected"]],
                skipped=len(c["rows"]["skipped"]), split=c["rows"]["split"])


def check_campaign(cdir, work, run_cal=True):
    k = json.load(open(os.path.join(cdir, "key", "key.json")))
    seq = read_csv(os.path.join(cdir, "key", "sequence.csv"))
    poses = read_csv(os.path.join(cdir, "dataset", "poses.csv"))
    res = dict(name=k["name"], label=k["label"], category=k["category"])
    data = [r for r in seq if r["role"] != "test"]
    test = [r for r in seq if r["role"] == "test"]
    assert len(test) == 60, "60 test rows"
    assert len(poses) == len(data) == k["rows"]["dataset"]
    # 1. poses.csv == dataset rows of the sequence
    cols_m = [f"p{s}_{c}" for s in range(3) for c in "xyz"]
    for p, s in zip(poses, data):
        assert p["pose_id"] == s["pose_id"]
        for i in range(1, 7):
            assert p[f"q{i}"] == s[f"q{i}"]
        for j, c in enumerate(cols_m):
            assert p[c] == s[f"m{c[1]}_{c[3]}"], (p["pose_id"], c)
        if "t_s" in p:
            assert p["t_s"] == s["t_s"]
        if "temp_c" in p:
            assert p["temp_c"] == s["temp_c"]
        if "set" in p:
            assert p["set"] == s["role"]
        if "station" in p:
            assert p["station"] == s["station"]
    t_ = np.array([float(r["t_s"]) for r in seq])
    assert np.all(np.diff(t_) > 0), "time increases"
    # 2. e == t - effect-free truth (recomputed from the key)
    rob = robot_from_key(k)
    labels = [s["label"] for s in k["stations"]]
    b2m = [pose6_to_T([s["base2meas"][x] for x in ("x_mm", "y_mm", "z_mm", "rx_rad", "ry_rad", "rz_rad")])
           for s in k["stations"]]
    tf = k["tool2flange"]
    t2f = pose6_to_T([tf[x] for x in ("x_mm", "y_mm", "z_mm", "rx_rad", "ry_rad", "rz_rad")])
    sph = np.array(k["plate"]["true_spheres_tool_mm"])
    q = np.array([[float(r[f"q{i}"]) for i in range(1, 7)] for r in seq]) * DEG
    st = np.array([labels.index(r["station"]) for r in seq])
    P0 = sphere_points(rob, q, st, b2m, t2f, sph)
    T = np.array([[[float(r[f"t{s}_{c}"]) for c in "xyz"] for s in range(3)] for r in seq])
    E = np.array([[[float(r[f"e{s}_{c}"]) for c in "xyz"] for s in range(3)] for r in seq])
    Mm = np.array([[[num(r[f"m{s}_{c}"]) for c in "xyz"] for s in range(3)] for r in seq])
    res["max_|t-e-truth0|_mm"] = float(np.max(np.abs(T - E - P0)))
    assert res["max_|t-e-truth0|_mm"] < 2e-6, res["max_|t-e-truth0|_mm"]
    nd = len(data)
    # 3. effect RMS per coordinate
    e_rms = float(np.sqrt(np.mean(E[:nd] ** 2)))
    res["e_rms_mm"] = e_rms
    res["e_rms_key_mm"] = k["e_rms_total_mm"]
    assert abs(e_rms - k["e_rms_total_mm"]) < 1e-6 + 1e-4 * k["e_rms_total_mm"]
    if len(k["effects"]) == 1:
        assert abs(e_rms - k["effects"][0]["rms_mm"]) < 1e-6 + 1e-4 * e_rms
    if k["category"] == "clean":
        assert np.max(np.abs(E)) == 0.0
    res["effects"] = [dict(cls=e["class_name"], rms_mm=e["rms_mm"], post=e["rms_after_geometric_fit_mm"],
                           ratio=e["ratio_to_noise"]) for e in k["effects"]]
    # 4. noise
    out_rows = {o["pose_id"] for o in k["noise"]["gross_outliers"]}
    ids = np.array([int(r["pose_id"]) for r in seq])
    D = Mm - T
    keep = np.array([i not in out_rows for i in ids]) & (np.arange(len(seq)) < nd)
    Dk = D[keep]
    res["noise_rms_meas_mm"] = float(np.sqrt(np.nanmean(Dk ** 2)))
    res["noise_rms_key_mm"] = k["noise"]["total_rms_per_coordinate_mm"]
    res["noise_axis_rms_mm"] = [float(np.sqrt(np.nanmean(Dk[..., c] ** 2))) for c in range(3)]
    for o in k["noise"]["gross_outliers"]:
        i = int(np.where(ids == o["pose_id"])[0][0])
        assert np.linalg.norm(D[i, o["sphere"]]) > 0.09
    res["missing_cells_rows"] = int(np.isnan(Mm[:nd]).any(axis=(1, 2)).sum())
    # 5. the tool's reader and geometric calibration (black box)
    if run_cal:
        res["calibrate"] = calibrate(os.path.join(cdir, "dataset"), os.path.join(work, "cal_" + k["name"]))
        res["expected_3d_rms_mm"] = expected_3d_rms(k)
    return res


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--batch", required=True)
    ap.add_argument("--work", required=True)
    ap.add_argument("--clean-twins", action="store_true")
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    os.makedirs(a.work, exist_ok=True)
    names = sorted(d for d in os.listdir(a.batch) if d.startswith("hA"))
    report = []
    for n in names:
        r = check_campaign(os.path.join(a.batch, n), a.work)
        c = r["calibrate"]
        line = (f"{n} {r['category']:9s} {r['label'][:34]:34s} t-e-truth0 {r['max_|t-e-truth0|_mm']:.1e} "
                f"e_rms {r['e_rms_mm']:.4f} noise meas/key {r['noise_rms_meas_mm']:.4f}/{r['noise_rms_key_mm']:.4f} ")
        if c["ok"]:
            line += (f"| calibrate OK val_rms {c['val_rms']:.4f} (noise-only 3D {r['expected_3d_rms_mm']:.4f}) "
                     f"scale {c['residual_scale']:.2f} rejected {c['rejected']}")
        else:
            line += f"| calibrate REFUSED: {c['error']}"
        print(line, flush=True)
        report.append(r)
    if a.clean_twins:
        import campaign as cm
        from specs import SPECS
        perm = np.random.default_rng([a.seed, 99]).permutation(len(SPECS))
        tw = os.path.join(a.work, "clean_twins")
        print("clean twins (every campaign regenerated without its effects):")
        for pos, si in enumerate(perm):
            sp = SPECS[si]
            sp2 = cm.Spec(**{**sp.__dict__, "effects": [], "expected_names": [], "category": "clean"})
            name = f"hA{pos + 1:02d}"
            cm.build(sp2, a.seed, int(si), name, tw)
            r = check_campaign(os.path.join(tw, name), a.work + "/twin_cal", True)
            c = r["calibrate"]
            r["twin_of"] = sp.label
            print(f"  {name} {sp.label[:34]:34s} val_rms {c.get('val_rms', float('nan')):.4f} vs noise-only 3D "
                  f"{r['expected_3d_rms_mm']:.4f} (ratio {c.get('val_rms', np.nan) / r['expected_3d_rms_mm']:.2f}) "
                  f"scale {c.get('residual_scale', np.nan):.2f} rejected {c.get('rejected')}", flush=True)
            report.append(dict(clean_twin=r))
    with open(os.path.join(a.work, "check_report.json"), "w") as f:
        json.dump(report, f, indent=1, default=float)


if __name__ == "__main__":
    main()
