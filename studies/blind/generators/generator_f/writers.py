"""Writers: dataset/poses.csv, dataset/dataset.toml (docs/formats.md) and key/key.json, key/sequence.csv
(docs/formats.md, "Blind campaigns"), plus key/truth_geometry.json (not part of the format: for checking)."""
from __future__ import annotations

import json
import os

import numpy as np

import kin

XYZ = [f"{k}_{a}" for k in range(3) for a in "xyz"]


def _f(x, nd):
    if x is None or not np.isfinite(x):
        return ""
    s = f"{x:.{nd}f}"
    if s.startswith("-") and float(s) == 0.0:
        s = s[1:]
    return s


def _num(x, nd=6):
    s = _f(float(x), nd).rstrip("0").rstrip(".")
    if s in ("", "-0", "-"):
        s = "0"
    return s if "." in s else s + ".0"


def _list(v, nd=6):
    return "[" + ", ".join(_num(x, nd) for x in v) + "]"


def columns(spec, res):
    cols = []
    if res["role"][0] != "data":
        cols.append("set")
    if len(res["stations"]) > 1:
        cols.append("station")
    cols.append("t_s")
    if res["temp"] is not None:
        cols.append("temp_c")
    if res["session"] is not None:
        cols.append("session")
    if any(res["status"][: res["n_data"]]):
        cols.append("status")
    return cols


def _cell(c, i, res):
    if c == "set":
        return res["role"][i]
    if c == "station":
        return str(int(res["station"][i]))
    if c == "t_s":
        return _f(res["t"][i], 1)
    if c == "temp_c":
        return _f(res["temp"][i], 2)
    if c == "session":
        return str(res["session"][i])
    if c == "status":
        return res["status"][i]
    raise KeyError(c)


def write_dataset(folder, name, spec, res):
    os.makedirs(folder, exist_ok=True)
    cols = columns(spec, res)
    lines = [",".join(["pose_id"] + [f"q{j}" for j in range(1, 7)] + ["p" + x for x in XYZ] + cols)]
    for i in range(res["n_data"]):
        row = [str(int(res["pose_id"][i]))] + [_f(x, 4) for x in res["qdeg"][i]]
        row += [_f(x * 1e3, 4) for x in res["M"][i].ravel()]
        row += [_cell(c, i, res) for c in cols]
        lines.append(",".join(row))
    with open(os.path.join(folder, "poses.csv"), "w", newline="\n") as fh:
        fh.write("\n".join(lines) + "\n")

    chain = spec.get("robot") == "chain"
    t = ["schema_version = 1"]
    if not chain:
        t.append('robot = "irb1200"')
    t.append(f'provenance = "Cell F, campaign {name}: a stereo camera on a tripod measures the three-sphere plate on '
             f'the flange of an IRB 1200; joints from the controller log, time from the camera PC"')
    if chain:
        t += _joint_table(res["stated_bodies"])
    t += ["", "[plate]", "sphere_diameter_mm = 25.4",
          "spheres_mm = [" + ", ".join(_list(s * 1e3, 2) for s in kin.SPHERES_FLANGE) + "]"]
    if spec["noise"].get("stated"):
        t += ["", "[noise]", f"position_mm = {_num(round(res['sigma_pc'] * 1e3, 4), 4)}"]
    with open(os.path.join(folder, "dataset.toml"), "w", newline="\n") as fh:
        fh.write("\n".join(t) + "\n")
    return cols


def _joint_table(stated):
    """The IRB 1200's MDH table as a joint table with the user's mass properties (docs/formats.md)."""
    lines = ["", "[robot]", 'name = "irb1200_masses"', 'convention = "urdf"', "joints = ["]
    for i, (xyz, rpy) in enumerate(kin.mdh_to_joint_table()):
        _, m, c = stated[i]
        lim = [kin.Q_MIN_DEG[i], kin.Q_MAX_DEG[i]]
        lines.append(f'  {{ name = "q{i + 1}", type = "revolute", xyz_mm = {_list(xyz * 1e3, 4)}, '
                     f"rpy_deg = {_list(rpy / kin.DEG, 6)}, axis = [0, 0, 1], limits = {_list(lim, 1)}, "
                     f"mass_kg = {_num(m, 3)}, com_mm = {_list(c * 1e3, 1)} }},")
    lines += ["]", "end = { xyz_mm = [0, 0, 0], rpy_deg = [0, 0, 0] }"]
    return lines


def write_key(folder, name, spec, res, seed, index, cols):
    os.makedirs(folder, exist_ok=True)
    seqcols = [c for c in ("station", "t_s", "temp_c") if c in cols]
    hdr = ["pose_id"] + [f"q{j}" for j in range(1, 7)] + seqcols + ["role"]
    hdr += ["m" + x for x in XYZ] + ["t" + x for x in XYZ] + ["e" + x for x in XYZ]
    lines = [",".join(hdr)]
    for i in range(len(res["qdeg"])):
        row = [str(int(res["pose_id"][i]))] + [_f(x, 4) for x in res["qdeg"][i]]
        row += [_cell(c, i, res) for c in seqcols] + [res["role"][i]]
        row += [_f(x * 1e3, 4) for x in res["M"][i].ravel()]
        row += [_f(x * 1e3, 5) for x in res["P"][i].ravel()]
        row += [_f(x * 1e3, 5) for x in res["E"][i].ravel()]
        lines.append(",".join(row))
    with open(os.path.join(folder, "sequence.csv"), "w", newline="\n") as fh:
        fh.write("\n".join(lines) + "\n")

    nz = spec["noise"]
    noise = dict(
        model="stereo triangulation: Gaussian per sphere centre, sigma_lat * (r / 0.85 m) across the line of sight "
              "from the rig's midpoint, los_factor * sigma_lat * (r / 0.85 m)^2 along it",
        sigma_lat_mm=nz["sigma_lat_mm"], los_factor=nz["los_factor"],
        per_coordinate_mm=round(res["sigma_pc"] * 1e3, 5), stated_in_dataset=bool(nz.get("stated")),
        p_missing_sphere=spec.get("p_missing", 0.0), bursts=res["bursts"],
    )
    key = dict(schema_version=1, name=name, category=spec["category"], expected_names=list(spec["expected"]),
               effects=res["effects"], noise=noise, seed=[seed, index], notes=_notes(spec, res))
    with open(os.path.join(folder, "key.json"), "w", newline="\n") as fh:
        json.dump(key, fh, indent=2)
        fh.write("\n")
    geo = dict(
        robot="irb1200" if spec.get("robot") != "chain" else "irb1200_masses (joint table)",
        true_parameters=kin.params_to_dict(res["params"]),
        tool2flange=dict(zip(["x_mm", "y_mm", "z_mm", "rx_rad", "ry_rad", "rz_rad"],
                             [round(float(v), 9) for v in np.concatenate([res["tool_v"][:3] * 1e3, res["tool_v"][3:]])])),
        base2meas={str(s): [[round(float(v), 12) for v in r] for r in st.base2meas] for s, st in enumerate(res["stations"])},
        stations={str(s): st.desc for s, st in enumerate(res["stations"])},
        bodies=[dict(frame=f, mass_kg=m, com_mm=[round(float(x) * 1e3, 3) for x in c]) for f, m, c in kin.BODIES],
        spheres_flange_mm=(kin.SPHERES_FLANGE * 1e3).tolist(),
    )
    with open(os.path.join(folder, "truth_geometry.json"), "w", newline="\n") as fh:
        json.dump(geo, fh, indent=1)
        fh.write("\n")


def _notes(spec, res):
    n = [spec.get("notes", "")]
    n.append(f"{res['n_data']} dataset rows, {len(res['qdeg']) - res['n_data']} test rows (role 'test', measured after "
             f"the campaign at station {len(res['stations']) - 1}); {len(res['stations'])} station(s)")
    if res["sess_rows"]:
        n.append("sessions start at dataset rows " + ", ".join(str(r + 1) for r in res["sess_rows"]))
    if any(e["family"] in ("compliance", "backlash", "tilt") for e in res["effects"]):
        n.append("mass model (frame, kg, centre of mass in the MDH frame [mm]): " + "; ".join(
            f"{f}: {m} kg at {np.round(c * 1e3, 1).tolist()}" for f, m, c in kin.BODIES)
            + "; gravity -9.81 m/s^2 along base z")
    if spec.get("robot") == "chain":
        n.append("dataset.toml describes the arm as a joint table with the user's mass properties (about 8 % and 8 mm "
                 "off the true ones above)")
    return " ".join(x for x in n if x)
