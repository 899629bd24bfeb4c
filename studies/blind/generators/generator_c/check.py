"""Sanity checks of a generated batch: python check.py BATCH_DIR [--calibrate]

* files: dataset.toml parses, poses.csv columns/row counts/set fraction, sequence.csv m-columns equal poses.csv;
* e-columns: t - e equals the effect-free centres of the true geometry (key/geometry.json, own kinematics);
* sizes: RMS of e (single-effect campaigns) equals the key's rms_mm; measured - true RMS equals the key's noise;
* --calibrate: `twin calibrate` (black box) on every dataset: refused or not, validation RMS (3-D per sphere)
  against the expectation sqrt(3 (noise^2 + left^2)) from the key.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import tomllib

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import kin  # noqa: E402

DEG = np.pi / 180.0
# the project's own `twin`, run from the repository root (this file: studies/blind/generators/generator_c/)
REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))))
TWIN = [sys.executable, "-m", "twin.cli"]


def load_geometry(path):
    g = json.load(open(path))
    kp = np.array(g["true"], float)
    kp[:6] *= DEG
    kp[18:] *= DEG
    names = list(g["stations"])
    B = [np.array(g["stations"][n]["base2meas"]) for n in names]
    return kin.Geometry(kp, np.array(g["tool2flange"]), np.array(g["spheres_tool_mm"]), B), names


def check_campaign(cdir):
    out = {"name": os.path.basename(cdir)}
    ds = os.path.join(cdir, "dataset")
    toml = tomllib.load(open(os.path.join(ds, "dataset.toml"), "rb"))
    poses = list(csv.DictReader(open(os.path.join(ds, "poses.csv"))))
    seq = list(csv.DictReader(open(os.path.join(cdir, "key", "sequence.csv"))))
    key = json.load(open(os.path.join(cdir, "key", "key.json")))
    geom, st_names = load_geometry(os.path.join(cdir, "key", "geometry.json"))
    out["rows"] = len(poses)
    out["category"] = key["category"]
    if "set" in poses[0]:
        out["validation_fraction"] = round(sum(r["set"] == "validation" for r in poses) / len(poses), 3)
    data = [r for r in seq if r["role"] != "test"]
    test = [r for r in seq if r["role"] == "test"]
    assert len(data) == len(poses) and len(test) == 60, "sequence row counts"
    mcols = [f"m{k}_{a}" for k in range(3) for a in "xyz"]
    pcols = [f"p{k}_{a}" for k in range(3) for a in "xyz"]
    ids = [r["pose_id"] for r in seq]
    assert len(set(ids)) == len(ids), "pose ids unique"
    for r, p in zip(data, poses):
        assert r["pose_id"] == p["pose_id"]
        assert [r[c] for c in mcols] == [p[c] for c in pcols], f"m columns differ at pose {r['pose_id']}"
        for i in range(1, 7):
            assert r[f"q{i}"] == p[f"q{i}"]
    q = np.array([[float(r[f"q{i}"]) for i in range(1, 7)] for r in seq]) * DEG
    st = np.array([st_names.index(r["station"]) for r in seq]) if "station" in seq[0] else np.zeros(len(seq), int)
    T = np.array([[float(r[f"t{k}_{a}"]) for k in range(3) for a in "xyz"] for r in seq]).reshape(-1, 3, 3)
    E = np.array([[float(r[f"e{k}_{a}"]) for k in range(3) for a in "xyz"] for r in seq]).reshape(-1, 3, 3)
    c0 = kin.centres(geom, q, st)
    out["max_abs(t-e-FK)_mm"] = float(np.max(np.abs(T - E - c0)))
    # measured - true over complete, non-gross rows
    gross = set(str(g) for g in key["noise"]["gross_pose_ids"])
    M, ok = [], []
    for r in seq:
        cells = [r[c] for c in mcols]
        good = all(cells) and r["pose_id"] not in gross
        ok.append(good)
        M.append([float(c) if c else np.nan for c in cells])
    M = np.array(M).reshape(-1, 3, 3)
    ok = np.array(ok)
    isdata = np.array([r["role"] != "test" for r in seq])
    d = (M - T)[ok & isdata]
    out["noise_rms_mm"] = float(np.sqrt(np.mean(d**2)))
    out["key_noise_rms_mm"] = key["noise"]["rms_per_coordinate_mm"]
    if gross:
        gi = [i for i, r in enumerate(seq) if r["pose_id"] in gross]
        out["gross_max_mm"] = float(np.nanmax(np.abs((M - T)[gi])))
    out["e_rms_mm"] = float(np.sqrt(np.mean(E[ok & isdata] ** 2)))
    out["key_rms_mm"] = [e["rms_mm"] for e in key["effects"]]
    out["left_over_noise"] = key["noise"]["effect_left_over_noise"]
    if key["category"] == "clean":
        assert np.max(np.abs(E)) == 0.0
    out["stated"] = toml.get("noise", {}).get("position_mm")
    return out


def calibrate(cdir, tmp):
    o = os.path.join(tmp, os.path.basename(cdir))
    p = subprocess.run([*TWIN, "calibrate", os.path.abspath(os.path.join(cdir, "dataset")), "--out", os.path.abspath(o),
                        "--quiet"], capture_output=True, text=True, cwd=REPO)
    if p.returncode != 0:
        return dict(refused=True, stderr=p.stderr[-500:])
    c = json.load(open(os.path.join(o, "calibration.json")))
    v = c["residuals"]["validation"]["position_mm"]["rms"]
    return dict(refused=False, validation_rms_mm=v, residual_scale=c["noise"].get("residual_scale"),
                rejected=len(c["rows"].get("calibration_rejected", [])))


def main():
    batch = sys.argv[1]
    do_cal = "--calibrate" in sys.argv
    import tempfile

    tmp = tempfile.mkdtemp(prefix="heldout_c_check_")
    res = []
    for name in sorted(os.listdir(batch)):
        cdir = os.path.join(batch, name)
        if not os.path.isdir(cdir):
            continue
        r = check_campaign(cdir)
        if do_cal:
            r.update(calibrate(cdir, tmp))
            k = json.load(open(os.path.join(cdir, "key", "key.json")))
            s = k["noise"]["rms_per_coordinate_mm"]
            left = k["noise"]["effect_left_after_geometric_fit_rms_mm"]
            r["expected_validation_rms_mm"] = float(np.sqrt(3 * (s**2 + left**2)))
        res.append(r)
        print(json.dumps(r), flush=True)
    json.dump(res, open(os.path.join(tmp, "summary.json"), "w"), indent=1)


if __name__ == "__main__":
    main()
