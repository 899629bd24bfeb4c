"""Writers of batch C: dataset/poses.csv, dataset/dataset.toml, key/key.json, key/sequence.csv,
key/geometry.json (extra: the true geometry, for anyone re-deriving the keys)."""

from __future__ import annotations

import csv
import json
import os

import numpy as np

import kin

DEG = np.pi / 180.0
SPH = [f"p{k}_{a}" for k in range(3) for a in "xyz"]


def _fl(x):
    return repr(float(x))


def _toml_list(v):
    return "[" + ", ".join(_fl(x) for x in v) + "]"


PROVENANCE = {
    "stereo": [
        "Stereo rig (2 x 5 MP mono cameras, {lens} mm lenses, 250 mm baseline) on a tripod; three-sphere plate on the flange. Operator {op}, {date}.",
        "Binocular camera measurement of the 3-ball plate, cell {cell}, {date}. Rig calibrated with a ChArUco board the same morning. Measured by {op}.",
        "Cell {cell} acceptance test, stereo camera system, sphere centres from ellipse fits. {op}, {date}.",
    ],
    "iso": [
        "Optical CMM (stereo, vendor software) watching the sphere plate; cell {cell}; {op}; {date}.",
        "Sphere plate measured with the lab's photogrammetry head, {date}, operator {op}.",
        "Camera-based sphere tracking, cell {cell}, {date}. Exported from the measurement software by {op}.",
    ],
    "tracker": [
        "Laser tracker, three 1.5 in SMRs in nests on the plate, tracker on its stand about a metre from the robot. {op}, {date}.",
    ],
}


def provenance(rng, kind):
    tpl = PROVENANCE[kind][int(rng.integers(len(PROVENANCE[kind])))]
    return tpl.format(
        lens=int(rng.choice([8, 12, 16])),
        op=str(rng.choice(["MK", "J. Ortega", "LW", "S. Haas", "team B", "RP"])),
        date=f"2025-{int(rng.integers(1, 13)):02d}-{int(rng.integers(1, 29)):02d}",
        cell=int(rng.integers(1, 9)),
    )


def write_campaign(spec, res, root, name, seed, category, expected):
    rng = np.random.default_rng([seed, spec["uid"], 7])
    ds = os.path.join(root, name, "dataset")
    kd = os.path.join(root, name, "key")
    os.makedirs(ds, exist_ok=True)
    os.makedirs(kd, exist_ok=True)
    rows = res["rows"]
    N = len(rows)
    nd = res["n_data"]
    st_names = [s.name for s in res["stations"]]
    has_station = spec.get("station_col", len(st_names) > 1)
    has_set = spec.get("set", True)
    has_t = spec.get("t_s", True)
    has_temp = spec.get("temp", False)
    has_pair = spec.get("pair_col", False)
    has_status = spec.get("status", False)
    extras = spec.get("extras", [])

    # pose ids: a start and occasional gaps (rows deleted by the operator before export)
    pid0 = int(rng.choice([1, 1, 0, 101, 1001, 5000, 20]))
    ids = []
    cur = pid0
    for k in range(N):
        ids.append(cur)
        cur += 1 + (int(rng.integers(1, 4)) if spec.get("id_gaps") and rng.random() < 0.04 else 0)

    def meas_cells(k):
        if rows[k].get("restart"):
            return [""] * 9
        out = []
        for s in range(3):
            if res["missing"].get(k) == s:
                out += ["", "", ""]
            else:
                out += [f"{v:.4f}" for v in res["meas"][k, s]]
        return out

    reasons = ["out_of_frame", "occluded", "glare", "fit_failed"]
    status = [""] * N
    for k, s in res["missing"].items():
        status[k] = f"p{s}:{reasons[int(rng.integers(len(reasons)))]}"
    for k in res["restart_rows"]:
        status[k] = "controller_restart"

    t_dec = int(spec.get("t_dec", 2))
    cols_q = [f"q{i}" for i in range(1, 7)]
    opt = []
    if has_set:
        opt.append("set")
    if has_station:
        opt.append("station")
    if has_t:
        opt.append("t_s")
    if has_temp:
        opt.append("temp_c")
    if has_pair:
        opt.append("pair")
    if has_status:
        opt.append("status")
    order = spec.get("order", 0)
    if order == 0:
        header = ["pose_id"] + cols_q + SPH + opt + extras
    elif order == 1:
        header = ["pose_id"] + [c for c in ("station", "set", "t_s") if c in opt] + cols_q + SPH + [c for c in opt if c not in ("station", "set", "t_s")] + extras
    elif order == 2:
        header = extras[:1] + ["pose_id"] + [c for c in ("t_s", "temp_c", "station") if c in opt] + cols_q + SPH + [c for c in opt if c not in ("t_s", "temp_c", "station")] + extras[1:]
    else:
        header = [c for c in ("t_s",) if c in opt] + cols_q + ["pose_id"] + SPH + [c for c in opt if c != "t_s"] + extras

    ops = [str(rng.choice(["MK", "JO", "LW", "SH", "RP"])) for _ in range(2)]
    op_switch = int(rng.integers(nd // 3, 2 * nd // 3))
    exposure = float(rng.choice([6.0, 8.0, 10.0, 12.5]))
    notes = ["", "", "", "", "", "ok", "checked", "good", "ok"]
    frame0 = int(rng.integers(100, 5000))
    pairs = {}
    for k in range(N):
        if rows[k]["pair"] is not None:
            pairs.setdefault(rows[k]["pair"], len(pairs) + 1)

    def value(col, k):
        if col == "pose_id":
            return str(ids[k])
        if col.startswith("q") and len(col) == 2:
            return f"{res['q_deg'][k, int(col[1]) - 1]:.4f}"
        if col == "set":
            return res["roles"][k]
        if col == "station":
            return st_names[res["st"][k]]
        if col == "t_s":
            return f"{res['t'][k]:.{t_dec}f}"
        if col == "temp_c":
            return f"{res['temp_rec'][k]:.{res['temp_dec']}f}"
        if col == "pair":
            return str(pairs[rows[k]["pair"]]) if rows[k]["pair"] is not None else ""
        if col == "status":
            return status[k]
        if col == "exposure_ms":
            return f"{exposure + (rng.normal(0, 0.3) if spec.get('auto_exposure') else 0.0):.1f}"
        if col == "operator":
            return ops[0] if k < op_switch else ops[1]
        if col == "note":
            return "repeat shot" if rows[k]["rep"] else str(rng.choice(notes))
        if col == "frame":
            return str(frame0 + 2 * k)
        if col == "gain_db":
            return "0.0"
        if col == "image":
            return f"img_{frame0 + k:05d}.png"
        raise KeyError(col)

    with open(os.path.join(ds, "poses.csv"), "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(header)
        for k in range(nd):
            mc = dict(zip(SPH, meas_cells(k)))
            w.writerow([mc[c] if c in mc else value(c, k) for c in header])

    # dataset.toml
    kind = spec["noise"]["kind"]
    lines = ["schema_version = 1"]
    robot = res["robot"]
    if robot.by_name:
        lines.append(f'robot = "{robot.name}"')
    lines.append(f'provenance = "{provenance(rng, kind)}"')
    lines.append("")
    if not robot.by_name:
        lines += [
            "[robot]",
            f'name = "{robot.name}"',
            'convention = "mdh"',
            "beta_joints = [2]",
            f"theta_deg = {_toml_list(robot.theta_deg)}",
            f"d_mm = {_toml_list(robot.d_mm)}",
            f"a_mm = {_toml_list(robot.a_mm)}",
            f"alpha_deg = {_toml_list(robot.alpha_deg)}",
            "beta_deg = [0.0]",
            f"q_min_deg = {_toml_list(robot.qmin_deg)}",
            f"q_max_deg = {_toml_list(robot.qmax_deg)}",
            "",
        ]
    diam = spec.get("sphere_diameter_mm", 38.1 if kind == "tracker" else 25.4)
    lines += ["[plate]", f"sphere_diameter_mm = {diam}", "spheres_mm = [" + ", ".join(_toml_list(p) for p in res["plate"]) + "]", ""]
    stated = spec.get("stated", "none")
    true_rms = res["sigma_ref"]
    stated_val = None
    if stated == "ok":
        stated_val = float(f"{true_rms:.2g}")
    elif stated == "x2":
        stated_val = float(f"{2 * true_rms:.2g}")
    if stated_val is not None:
        lines += ["[noise]", f"position_mm = {stated_val}", ""]
    with open(os.path.join(ds, "dataset.toml"), "w") as f:
        f.write("\n".join(lines))

    # sequence.csv
    seq_cols = ["pose_id"] + [f"q{i}" for i in range(1, 7)]
    if has_station:
        seq_cols.append("station")
    if has_t:
        seq_cols.append("t_s")
    if has_temp:
        seq_cols.append("temp_c")
    seq_cols.append("role")
    seq_cols += [f"m{k}_{a}" for k in range(3) for a in "xyz"]
    seq_cols += [f"t{k}_{a}" for k in range(3) for a in "xyz"]
    seq_cols += [f"e{k}_{a}" for k in range(3) for a in "xyz"]
    with open(os.path.join(kd, "sequence.csv"), "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(seq_cols)
        for k in range(N):
            r = [str(ids[k])] + [f"{res['q_deg'][k, i]:.4f}" for i in range(6)]
            if has_station:
                r.append(st_names[res["st"][k]])
            if has_t:
                r.append(f"{res['t'][k]:.{t_dec}f}")
            if has_temp:
                r.append(f"{res['temp_rec'][k]:.{res['temp_dec']}f}")
            r.append(res["roles"][k])
            r += meas_cells(k)
            r += [f"{v:.6f}" for v in res["t_true"][k].reshape(-1)]
            r += [f"{v:.6f}" for v in res["e_all"][k].reshape(-1)]
            w.writerow(r)

    # key.json
    effs = []
    for eo in res["eff_out"]:
        e = eo["eff"]
        desc, form, channel = e.describe()
        effs.append(dict(
            family=e.family, description=desc, formula=form, joints=list(getattr(e, "joints", [])),
            links=list(getattr(e, "links", [])), place=e.place, channel=channel, rms_mm=round(eo["rms"], 6),
        ))
    nm = res["noise_model"]
    noise = dict(
        model=nm["kind"],
        rms_per_coordinate_mm=round(res["sigma_ref"], 6),
        instrument_rms_per_coordinate_mm=round(float(np.sqrt(np.mean(res["inst"][res["eval_rows"]] ** 2))), 6),
        stated_position_mm=stated_val,
        stated=stated,
        robot_repeatability_sigma_mm=res["rep_sigma"],
        repeats=(spec.get("repeats") or [None])[0],
        gross_pose_ids=[ids[g["pose_index"]] for g in res["gross_info"]],
        gross=[dict(pose_id=ids[g["pose_index"]], kind=g["kind"], offset_mm=g["offset_mm"]) for g in res["gross_info"]],
        missing_sphere_pose_ids=sorted(ids[k] for k in res["missing"]),
        restart_pose_ids=[ids[k] for k in res["restart_rows"]],
        effect_left_after_geometric_fit_rms_mm=round(res["left_all"], 6),
        effect_left_over_noise=round(res["left_all"] / res["sigma_ref"], 3),
        effect_left_over_noise_each=[round(eo["left"] / res["sigma_ref"], 3) for eo in res["eff_out"]],
    )
    if nm["kind"] == "stereo":
        noise.update(lateral_sigma_mm_at_r0=round(nm["s0"], 6), r0_mm=round(nm["r0"], 1), line_of_sight_factor=round(nm["k_ray"], 3),
                     sphere_correlation=round(nm["rho"], 3),
                     formula="lateral sigma = s0 (r/r0)^2, along the line of sight k * lateral; share rho of the variance common to the row's three spheres")
    elif nm["kind"] == "tracker":
        noise.update(sigma_range_mm=round(nm["sigma_r"], 6), sigma_angle_rad=float(f"{nm['sigma_ang']:.3e}"),
                     formula="along the beam sigma_range, across it r sigma_angle; spheres independent")
    else:
        noise.update(sigma_mm=nm["sigma"], formula="isotropic Gaussian per coordinate, independent")
    if res["rep_sigma"]:
        noise["repeatability_formula"] = ("random rigid flange displacement per visit: translation sigma per axis, rotation sigma/200 mm per axis; "
                                          + ("consecutive repeats re-approach the pose (new displacement)" if (spec.get("repeats") or [None])[0] == "reapproach"
                                             else "consecutive repeats without motion share it"))
    notes = (
        f"rms_mm of an effect: RMS over the dataset rows used and the 9 coordinates of its own e (per coordinate). "
        f"'effect_left_over_noise': RMS per coordinate of what a linearised geometric calibration (25 MDH parameters + tool + "
        f"base per station, fitted on the calibration rows) leaves of e, over the noise RMS per coordinate. "
        f"Time-ordered rows; test rows measured after the dataset at station '{st_names[-1]}'. Protocol: {spec['protocol']}."
    )
    key = dict(
        schema_version=1, name=name, category=category, expected_names=expected, effects=effs, noise=noise,
        seed=int(seed), notes=notes,
    )
    with open(os.path.join(kd, "key.json"), "w") as f:
        json.dump(key, f, indent=2)

    g = res["geom"]
    geo = dict(
        units="mm, deg; transforms 4x4 in mm",
        robot=robot.name,
        parameter_names=kin.KP_NAMES,
        nominal=[float(v / DEG) if (i < 6 or i >= 18) else float(v) for i, v in enumerate(robot.kp)],
        true=[float(v / DEG) if (i < 6 or i >= 18) else float(v) for i, v in enumerate(g.kp)],
        tool2flange=g.tool.tolist(),
        spheres_tool_mm=g.spheres.tolist(),
        stations={s.name: dict(base2meas=s.base2meas.tolist(), standoff_mm=s.view["standoff"]) for s in res["stations"]},
        working_region_centre_base_mm=np.round(res["centre"], 1).tolist(),
    )
    with open(os.path.join(kd, "geometry.json"), "w") as f:
        json.dump(geo, f, indent=1)

    return dict(
        name=name, category=category, rows=nd, noise=f"{nm['kind']}:{res['sigma_ref']:.4f}",
        channels=";".join(c for c in opt if c != "status") + (";status" if has_status else ""),
        stations=len(st_names), repeats=sum(1 for k in range(nd) if rows[k]["rep"]),
    )
