"""Writers for poses.csv, dataset.toml (docs/formats.md) and key/key.json, key/sequence.csv (Blind campaigns)."""
from __future__ import annotations

import json
import os

import numpy as np

import kin

SPH = [f"p{k}_{a}" for k in range(3) for a in "xyz"]


def _f(x, nd):
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return ""
    s = f"{x:.{nd}f}"
    if s.startswith("-") and float(s) == 0.0:
        s = s[1:]
    return s


def _fmt_list(v, nd=4):
    return "[" + ", ".join(_num(x, nd) for x in v) + "]"


def _num(x, nd=4):
    s = _f(float(x), nd)
    if "." in s:
        s = s.rstrip("0").rstrip(".")
    if s in ("", "-0"):
        s = "0"
    return s + (".0" if "." not in s and "e" not in s else "")


def optional_columns(spec, res):
    cols = []
    if spec.get("set"):
        cols.append("set")
    if len(res["truth"].stations) > 1:
        cols.append("station")
    if any(p is not None for p in res["pair"][: res["n_data"]]):
        cols.append("pair")
    if spec.get("t_s"):
        cols.append("t_s")
    if spec.get("temp_c"):
        cols.append("temp_c")
    if spec.get("status") or any(res["status"][: res["n_data"]]):
        cols.append("status")
    return cols


def write_dataset(folder, name, spec, res):
    os.makedirs(folder, exist_ok=True)
    nd = res["n_data"]
    cols = optional_columns(spec, res)
    hdr = ["pose_id"] + [f"q{j}" for j in range(1, 7)] + SPH + cols
    lines = [",".join(hdr)]
    for i in range(nd):
        row = [str(i + 1)] + [_f(x, 4) for x in res["qdeg"][i]] + [_f(x, 4) for x in res["M"][i].ravel()]
        for c in cols:
            row.append(_cell(c, i, res))
        lines.append(",".join(row))
    with open(os.path.join(folder, "poses.csv"), "w", newline="\n") as fh:
        fh.write("\n".join(lines) + "\n")

    robot = res["truth"].robot
    r = kin.ROBOTS[robot]
    t = ["schema_version = 1"]
    if not r["inline"]:
        t.append(f'robot = "{robot}"')
    t.append(f'provenance = "Cell E, campaign {name}: stereo camera on a tripod measuring the three-sphere plate on the flange; commanded joint angles from the controller log."')
    if r["inline"]:
        t += ["", "[robot]", f'name = "{robot}"', 'convention = "mdh"', "beta_joints = [2]",
              "theta_deg = " + _fmt_list(r["theta_deg"]), "d_mm = " + _fmt_list(r["d_mm"]),
              "a_mm = " + _fmt_list(r["a_mm"]), "alpha_deg = " + _fmt_list(r["alpha_deg"]), "beta_deg = [0]",
              "q_min_deg = " + _fmt_list(r["q_min"]), "q_max_deg = " + _fmt_list(r["q_max"])]
    sph = res["truth"].spheres_nominal
    t += ["", "[plate]", "sphere_diameter_mm = 25.4",
          "spheres_mm = [" + ", ".join(_fmt_list(s, 2) for s in sph) + "]"]
    if spec["noise"].get("stated"):
        t += ["", "[noise]", f"position_mm = {_num(round(res['sigma_pc'], 4))}"]
    with open(os.path.join(folder, "dataset.toml"), "w", newline="\n") as fh:
        fh.write("\n".join(t) + "\n")
    return cols


def _cell(c, i, res):
    if c == "set":
        return res["role"][i]
    if c == "station":
        return str(int(res["station"][i]))
    if c == "pair":
        p = res["pair"][i]
        return "" if p is None else str(int(p))
    if c == "t_s":
        return _f(res["t"][i], 1)
    if c == "temp_c":
        return _f(res["temp"][i], 2)
    if c == "status":
        return res["status"][i]
    raise KeyError(c)


def write_key(folder, name, spec, res, seed, index, cols):
    os.makedirs(folder, exist_ok=True)
    n = len(res["qdeg"])
    seqcols = [c for c in ("station", "t_s", "temp_c") if c in cols]
    hdr = ["pose_id"] + [f"q{j}" for j in range(1, 7)] + seqcols + ["role"]
    hdr += [f"m{k}_{a}" for k in range(3) for a in "xyz"] + [f"t{k}_{a}" for k in range(3) for a in "xyz"] + [f"e{k}_{a}" for k in range(3) for a in "xyz"]
    lines = [",".join(hdr)]
    for i in range(n):
        row = [str(i + 1)] + [_f(x, 4) for x in res["qdeg"][i]]
        for c in seqcols:
            row.append(_cell(c, i, res))
        row.append(res["role"][i])
        row += [_f(x, 4) for x in res["M"][i].ravel()]
        row += [_f(x, 5) for x in res["T"][i].ravel()]
        row += [_f(x, 5) for x in res["E"][i].ravel()]
        lines.append(",".join(row))
    with open(os.path.join(folder, "sequence.csv"), "w", newline="\n") as fh:
        fh.write("\n".join(lines) + "\n")

    nm = spec["noise"]
    noise = dict(
        model=nm["kind"], sigma_mm=nm["sigma_mm"], los_factor=nm.get("los_factor", 1.0), r0_mm=nm.get("r0_mm"),
        per_coordinate_mm=round(res["sigma_pc"], 5), stated_in_dataset=bool(nm.get("stated")),
        gross_outliers=int(res["n_outliers"]), p_missing_sphere=nm.get("p_missing", 0.0), p_failed_row=nm.get("p_fail", 0.0),
        description={
            "iso": "isotropic Gaussian per coordinate",
            "los": "Gaussian, sigma_mm across the line of sight, los_factor x sigma_mm along it",
            "range": "Gaussian, transverse sigma_mm*(r/r0), along the line of sight los_factor*sigma_mm*(r/r0)^2",
        }[nm["kind"]] + "; gross outliers (0.3-1.5 mm, random direction) only on dataset rows",
    )
    key = dict(
        schema_version=1, name=name, category=spec["category"], expected_names=list(spec.get("expected", [])),
        effects=res["effects"], noise=noise, seed=[seed, index], notes=spec.get("notes", ""),
    )
    with open(os.path.join(folder, "key.json"), "w", newline="\n") as fh:
        json.dump(key, fh, indent=2)
        fh.write("\n")
    tr = res["truth"]
    geo = dict(
        robot=tr.robot, true_parameters=kin.params_to_list(tr.params),
        tool2flange=dict(zip(["x_mm", "y_mm", "z_mm", "rx_rad", "ry_rad", "rz_rad"], [round(float(v), 9) for v in tr.tool_xyzrv])),
        base2meas={str(s): [[round(float(v), 9) for v in r] for r in st["base2meas"]] for s, st in enumerate(tr.stations)},
        spheres_tool_mm=tr.spheres_tool.tolist(),
    )
    with open(os.path.join(folder, "truth_geometry.json"), "w", newline="\n") as fh:
        json.dump(geo, fh, indent=1)
        fh.write("\n")
