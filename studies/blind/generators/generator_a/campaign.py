"""Build one campaign (session, truth, effects, noise) and write its dataset/ and key/ folders."""

from __future__ import annotations

import csv
import json
import os
from dataclasses import dataclass, field

import numpy as np

import plan
from effects import Ctx
from kin import (DEG, ROBOTS, Mods, T_to_pose6, param_jacobian, pose6_to_T, residual_after_geometric_fit,
                 rotvec_to_R, sphere_points)

N_TEST = 60
DEFAULT_PLATE = np.array([[60.0, 0.0, 50.0], [-60.0, 0.0, 50.0], [-20.52, 56.38, 50.0]])


@dataclass
class Spec:
    label: str
    category: str  # clean | catalogue | outside | mixed
    robot: str = "irb1200"
    n_rows: int = 250
    n_stations: int = 1
    station_names: list | None = None  # station labels written in the `station` column
    station_col: bool = False  # write a `station` column even with one station
    noise_kind: str = "iso"  # iso | depth
    sigma_mm: float = 0.005  # lateral (iso: every axis) per-coordinate sigma of the instrument
    depth_factor: float = 1.0
    repeatability_mm: float = 0.0  # robot repeatability: per-visit flange translation sigma per axis
    repeat_frac: float = 0.0  # fraction of visits measured 2-3 times in a row
    # 'still': re-measured without moving (same repeatability draw); 'reapproach': the robot backs off a few mm
    # and returns to the same commanded joints (new repeatability draw). Default: reapproach iff repeatability > 0
    repeat_mode: str | None = None
    set_col: bool = True
    t_col: bool = True
    temp_col: bool = False
    n_missing: int = 0
    n_outliers: int = 0
    plate: str = "default"  # default | random
    state_noise: bool = True
    effects: list = field(default_factory=list)  # [(factory(rng, info) -> Effect, target_ratio)]
    expected_names: list = field(default_factory=list)
    notes: str = ""
    temp_rise: tuple = (1.5, 4.0)  # K over the session's warm-up (air temperature)


# ------------------------------------------------------------------------------------------------ helpers
def perturb_robot(nom, rng):
    r = nom.copy()
    sgn = lambda k: rng.choice([-1.0, 1.0], size=k)
    r.d = r.d + sgn(6) * rng.uniform(0.1, 1.0, 6)
    r.a = r.a + sgn(6) * rng.uniform(0.1, 1.0, 6)
    r.theta = r.theta + sgn(6) * rng.uniform(0.01, 0.1, 6) * DEG
    r.alpha = r.alpha + sgn(6) * rng.uniform(0.01, 0.1, 6) * DEG
    r.beta2 = float(rng.choice([-1, 1]) * rng.uniform(0.01, 0.05) * DEG)
    return r


def random_plate(rng):
    for _ in range(1000):
        ang = np.sort(rng.uniform(0, 2 * np.pi, 3))
        rad = rng.uniform(45, 78, 3)
        h = rng.uniform(35, 62, 3)
        P = np.stack([rad * np.cos(ang), rad * np.sin(ang), h], axis=1)
        dist = [np.linalg.norm(P[i] - P[j]) for i, j in ((0, 1), (1, 2), (0, 2))]
        if min(dist) > 60 and max(dist) - min(dist) > 12:
            return np.round(P, 2)
    raise RuntimeError("no plate")


def fmt(x, nd):
    return "" if not np.isfinite(x) else f"{x:.{nd}f}"


# ------------------------------------------------------------------------------------------------ build
def build(spec: Spec, seed: int, idx: int, name: str, outdir: str) -> dict:
    rng = np.random.default_rng([seed, idx, 20240611])
    nom = ROBOTS[spec.robot]()
    true = perturb_robot(nom, rng)
    spheres_nom = DEFAULT_PLATE.copy() if spec.plate == "default" else random_plate(rng)
    tool_err = np.concatenate([rng.choice([-1, 1], 3) * rng.uniform(0.2, 1.0, 3),
                               rng.choice([-1, 1], 3) * rng.uniform(0.05, 0.2, 3) * DEG])
    tool2flange = pose6_to_T(tool_err)  # nominal plate frame = flange
    spheres_tool = spheres_nom.copy()

    # ---- stations
    S = spec.n_stations
    az_base = {1: [0.0], 2: [-38.0, 34.0], 3: [-48.0, 2.0, 47.0]}[S]
    base2meas, st_info = [], []
    for s in range(S):
        az = az_base[s] + rng.uniform(-12, 12) if S > 1 else rng.uniform(-35, 35)
        b2m, info = plan.place_station(rng, nom.name, az, rng.uniform(15, 40), rng.uniform(620, 880),
                                       rng.uniform(-8, 8))
        base2meas.append(b2m)
        st_info.append(info)
    labels = spec.station_names or [str(s) for s in range(S)]

    # ---- visits (groups of rows measured without moving in between), per station block
    rows_per_station = np.full(S, spec.n_rows // S)
    rows_per_station[: spec.n_rows - rows_per_station.sum()] += 1
    groups = []  # (station, n_repeat)
    for s in range(S):
        left = rows_per_station[s]
        while left > 0:
            k = 1
            if spec.repeat_frac > 0 and rng.random() < spec.repeat_frac:
                k = int(rng.choice([2, 3], p=[0.6, 0.4]))
            k = min(k, left)
            groups.append((s, k))
            left -= k
    test_station = S - 1
    n_vis = np.bincount([g[0] for g in groups], minlength=S)
    Q = {}
    for s in range(S):
        need = n_vis[s] + (N_TEST if s == test_station else 0)
        Q[s] = list(plan.plan_poses(rng, nom, base2meas[s], spheres_nom, need))
    # the planned lists are independent random draws: their order is the (random) visiting order
    mode = spec.repeat_mode or ("reapproach" if spec.repeatability_mm > 0 else "still")
    q_rows, st_rows, moved, visit, placement = [], [], [], [], []
    for v, (s, k) in enumerate(groups):
        q = Q[s].pop(0)
        for r in range(k):
            q_rows.append(q)
            st_rows.append(s)
            moved.append(r == 0)
            visit.append(v)
            placement.append(len(placement) if (r == 0 or mode == "reapproach") else placement[-1])
    n_data = len(q_rows)
    for _ in range(N_TEST):
        q_rows.append(Q[test_station].pop(0))
        st_rows.append(test_station)
        moved.append(True)
        visit.append(visit[-1] + 1)
        placement.append(len(placement))
    q_rows = np.round(np.array(q_rows) / DEG, 6) * DEG  # exactly the commanded joints written to the files
    st_rows = np.array(st_rows)
    moved = np.array(moved)
    visit = np.array(visit)
    placement = np.unique(np.array(placement), return_inverse=True)[1]  # one repeatability draw per placement
    n = q_rows.shape[0]

    # ---- time and temperature
    t = np.zeros(n)
    t[0] = rng.uniform(30, 300)
    pause_rows = set(rng.choice(np.arange(20, n_data - 20), size=int(rng.integers(1, 3)), replace=False).tolist())
    pause_rows = {r for r in pause_rows if moved[r]}
    for r in range(1, n):
        dt = rng.uniform(8, 15) if moved[r] else (rng.uniform(3, 6) if mode == "still" else rng.uniform(6, 10))
        if r in pause_rows:
            dt += rng.uniform(300, 1500)
        if st_rows[r] != st_rows[r - 1] and r < n_data:
            dt += rng.uniform(600, 1200)  # moving the camera to the next station
        if r == n_data:
            dt += rng.uniform(120, 600)  # the test block comes a little later
        t[r] = t[r - 1] + dt
    T_air_fn, temp_info = plan.temperature_profile(rng, spec.temp_rise)
    T_air = T_air_fn(t)
    temp_rec = np.round(T_air + rng.normal(0, 0.015, n), 2)

    q_start = np.array([0, 0, 0, 0, 30, 0]) * DEG  # home pose before the session (not recorded)
    ctx = Ctx(robot=true, q=q_rows, moved=moved, t=t, temp_air=T_air, temp_fn=T_air_fn, station=st_rows,
              q_start=q_start)

    # ---- effect-free truth, noise scale, linearised geometric fit on the dataset rows
    P0 = sphere_points(true, q_rows, st_rows, base2meas, tool2flange, spheres_tool)
    sig_axis = np.array([spec.sigma_mm, spec.sigma_mm, spec.sigma_mm * spec.depth_factor])
    instr_rms = float(np.sqrt(np.mean(sig_axis ** 2)))

    # robot repeatability: a rigid flange motion per visit (shared by the repeats of that visit)
    rep_mods = None
    rep_rms = 0.0
    if spec.repeatability_mm > 0:
        npl = placement.max() + 1
        xi = np.concatenate([rng.normal(0, spec.repeatability_mm, (npl, 3)),
                             rng.normal(0, spec.repeatability_mm / 120.0, (npl, 3))], axis=1)
        Tv = np.stack([pose6_to_T(x) for x in xi])
        rep_mods = Tv[placement]
    data = np.arange(n_data)
    Jd = param_jacobian(true, q_rows[data], st_rows[data], base2meas, tool2flange, spheres_tool, S)
    wts = np.tile(1.0 / sig_axis, n_data * 3)

    def postfit_rms(E):
        r = residual_after_geometric_fit(Jd, E[data].reshape(-1), wts)
        return float(np.sqrt(np.mean(r ** 2)))

    def points(mods):
        return sphere_points(true, q_rows, st_rows, base2meas, tool2flange, spheres_tool, mods)

    if rep_mods is not None:
        m_rep = Mods(n)
        m_rep.flange = rep_mods
        rep_rms = float(np.sqrt(np.mean((points(m_rep) - P0)[data] ** 2)))
    sigma_eff = float(np.sqrt(instr_rms ** 2 + rep_rms ** 2))

    # ---- effects, each scaled so that what a geometric fit leaves of it is `ratio` x sigma_eff
    info = dict(t=t, n_data=n_data, rng=rng, robot=true, q=q_rows)
    total = Mods(n)
    eff_keys = []
    for factory, ratio in spec.effects:
        eff = factory(rng, info)
        E0 = points(eff.mods(ctx, eff.a0)) - P0
        r0 = postfit_rms(E0)
        amp = eff.a0 * ratio * sigma_eff / r0
        m_e = eff.mods(ctx, amp)
        E = points(m_e) - P0
        for _ in range(3):  # refine (effects are nearly, not exactly, linear in their amplitude)
            got = postfit_rms(E)
            if abs(got / (ratio * sigma_eff) - 1) < 0.01:
                break
            amp *= ratio * sigma_eff / got
            m_e = eff.mods(ctx, amp)
            E = points(m_e) - P0
        d = eff.describe(amp)
        eff_keys.append(dict(
            family=eff.family, description=d["description"], formula=d["formula"], joints=list(eff.joints),
            links=list(eff.links), place=eff.place, channel=eff.channel,
            rms_mm=float(np.sqrt(np.mean(E[data] ** 2))),
            rms_after_geometric_fit_mm=postfit_rms(E),
            ratio_to_noise=postfit_rms(E) / sigma_eff,
            rms_test_rows_mm=float(np.sqrt(np.mean(E[n_data:] ** 2))),
            max_abs_mm=float(np.max(np.abs(E[data]))),
            parameters=d["parameters"], target_ratio=ratio, class_name=type(eff).__name__,
        ))
        total.add(m_e)

    P_true = points(total)
    E_tot = P_true - P0

    # ---- measurement: repeatability + instrument noise + gross outliers + missing spheres
    if rep_mods is not None:
        total_rep = Mods(n)
        total_rep.add(total)
        total_rep.flange = rep_mods if total.flange is None else total.flange @ rep_mods
        P_rep = points(total_rep)
    else:
        P_rep = P_true.copy()
    M = P_rep + rng.normal(0, 1, (n, 3, 3)) * sig_axis[None, None]
    status = [""] * n
    cand = [r for r in range(n_data)]
    miss_rows = sorted(rng.choice(cand, size=spec.n_missing, replace=False).tolist()) if spec.n_missing else []
    missing = []
    for r in miss_rows:
        k = int(rng.integers(0, 3))
        M[r, k] = np.nan
        reason = rng.choice(["occluded", "occluded", "out_of_frame", "specular"])
        status[r] = f"p{k}:{reason}"
        missing.append(dict(row=r, sphere=k, reason=str(reason)))
    out_rows = [r for r in cand if r not in miss_rows]
    outliers = []
    if spec.n_outliers:
        for r in sorted(rng.choice(out_rows, size=spec.n_outliers, replace=False).tolist()):
            k = int(rng.integers(0, 3))
            v = rng.normal(size=3)
            v *= rng.uniform(0.1, 0.5) / np.linalg.norm(v)
            M[r, k] += v
            outliers.append(dict(row=r, sphere=k, offset_mm=v.tolist(), size_mm=float(np.linalg.norm(v))))

    # ---- sets (per visit, so repeats share a set)
    nv = visit.max() + 1
    vset = np.where(rng.random(nv) < 0.3, "validation", "calibration")
    role = np.array([vset[v] for v in visit], dtype=object)
    if not spec.set_col:
        role[:] = "data"
    role[n_data:] = "test"

    pid0 = int(rng.integers(1, 900)) * 10
    pose_id = pid0 + np.arange(n)
    for o in outliers:
        o["pose_id"] = int(pose_id[o["row"]])
    for mm in missing:
        mm["pose_id"] = int(pose_id[mm["row"]])

    # ---- write the dataset
    ds = os.path.join(outdir, name, "dataset")
    kd = os.path.join(outdir, name, "key")
    os.makedirs(ds, exist_ok=True)
    os.makedirs(kd, exist_ok=True)
    has_station = S > 1 or spec.station_col
    has_status = any(status[:n_data])
    hdr = ["pose_id"] + [f"q{i}" for i in range(1, 7)] + [f"p{k}_{c}" for k in range(3) for c in "xyz"]
    if has_station:
        hdr.append("station")
    if spec.set_col:
        hdr.append("set")
    if spec.t_col:
        hdr.append("t_s")
    if spec.temp_col:
        hdr.append("temp_c")
    if has_status:
        hdr.append("status")
    with open(os.path.join(ds, "poses.csv"), "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(hdr)
        for r in range(n_data):
            row = [int(pose_id[r])] + [f"{x:.6f}" for x in q_rows[r] / DEG]
            row += [fmt(M[r, k, c], 5) for k in range(3) for c in range(3)]
            if has_station:
                row.append(labels[st_rows[r]])
            if spec.set_col:
                row.append(role[r])
            if spec.t_col:
                row.append(f"{t[r]:.1f}")
            if spec.temp_col:
                row.append(f"{temp_rec[r]:.2f}")
            if has_status:
                row.append(status[r])
            w.writerow(row)
    pl = "[" + ", ".join("[" + ", ".join(f"{x:.2f}" for x in p) + "]" for p in spheres_nom) + "]"
    toml = ["schema_version = 1"]
    if nom.named:
        toml.append(f'robot = "{nom.name}"')
    toml.append(f'provenance = "held-out campaign {name}: three 25.4 mm spheres on the flange plate measured by a '
                f'stereo tracker ({S} station{"s" if S > 1 else ""})"')
    toml.append("")
    if not nom.named:
        toml.append(nom.toml_table())
    toml.append("[plate]\nsphere_diameter_mm = 25.4\nspheres_mm = " + pl + "\n")
    stated = None
    if spec.state_noise:
        stated = round(instr_rms, 4)
        toml.append(f"[noise]\nposition_mm = {stated}\n")
    with open(os.path.join(ds, "dataset.toml"), "w") as f:
        f.write("\n".join(toml))

    # ---- key/sequence.csv
    with open(os.path.join(kd, "sequence.csv"), "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(["pose_id"] + [f"q{i}" for i in range(1, 7)] + ["station", "t_s", "temp_c", "role"]
                   + [f"m{k}_{c}" for k in range(3) for c in "xyz"] + [f"t{k}_{c}" for k in range(3) for c in "xyz"]
                   + [f"e{k}_{c}" for k in range(3) for c in "xyz"])
        for r in range(n):
            row = [int(pose_id[r])] + [f"{x:.6f}" for x in q_rows[r] / DEG]
            row += [labels[st_rows[r]], f"{t[r]:.1f}", f"{temp_rec[r]:.2f}", role[r]]
            row += [fmt(M[r, k, c], 5) for k in range(3) for c in range(3)]
            row += [f"{P_true[r, k, c]:.7f}" for k in range(3) for c in range(3)]
            row += [f"{E_tot[r, k, c]:.7f}" for k in range(3) for c in range(3)]
            w.writerow(row)

    # ---- key/key.json
    def geo(r):
        return dict(theta_deg=(r.theta / DEG).tolist(), d_mm=r.d.tolist(), a_mm=r.a.tolist(),
                    alpha_deg=(r.alpha / DEG).tolist(), beta2_deg=r.beta2 / DEG)

    channels = [c for c, on in (("station", has_station), ("set", spec.set_col), ("t_s", spec.t_col),
                                ("temp_c", spec.temp_col), ("status", has_status)) if on]
    noise = dict(
        model="isotropic" if spec.noise_kind == "iso" else "depth-anisotropic (camera z axis = line of sight)",
        sigma_lateral_mm=spec.sigma_mm, sigma_depth_mm=spec.sigma_mm * spec.depth_factor,
        depth_factor=spec.depth_factor, instrument_rms_per_coordinate_mm=instr_rms,
        robot_repeatability_mm=spec.repeatability_mm or None,
        robot_repeatability_rot_deg=(spec.repeatability_mm / 120.0 / DEG) if spec.repeatability_mm else None,
        repeatability_rms_per_coordinate_mm=rep_rms or None,
        total_rms_per_coordinate_mm=sigma_eff,
        stated_in_dataset_toml_mm=stated,
        repeats=None if spec.repeat_frac == 0 else (
            "re-measured without moving (same repeatability draw, fresh instrument noise)" if mode == "still" else
            "re-approach: the robot backs off a few mm and returns to the same commanded joints (not recorded); "
            "each repeat has its own repeatability draw; the commanded joints (and joint history) are unchanged"),
        gross_outliers=outliers, missing_spheres=missing,
        temperature_sensor="recorded = round(true air + N(0, 0.015 K), 0.01 K)",
    )
    n_rep_rows = int((~moved[:n_data]).sum())
    key = dict(
        schema_version=1, name=name, label=spec.label, category=spec.category,
        expected_names=sorted(set(spec.expected_names)), effects=eff_keys, noise=noise, seed=seed,
        campaign_index=idx,
        notes=(spec.notes + " " if spec.notes else "") + (
            "Effect sizes: each amplitude is set so that what a linearised, noise-weighted geometric calibration "
            "(all MDH parameters, beta2, tool, one base2meas per station) leaves of it over the dataset rows is "
            "target_ratio x noise.total_rms_per_coordinate_mm; rms_mm is the raw contribution, including the part "
            "a geometric calibration absorbs." if spec.effects else "No effect: e = 0."),
        rows=dict(dataset=n_data, test=N_TEST, repeat_rows=n_rep_rows,
                  validation=int((role[:n_data] == "validation").sum()) if spec.set_col else None),
        recorded_channels=channels,
        e_rms_total_mm=float(np.sqrt(np.mean(E_tot[:n_data] ** 2))),
        e_rms_total_after_geometric_fit_mm=postfit_rms(E_tot),
        robot=dict(name=nom.name, inline=not nom.named, nominal=geo(nom), true=geo(true),
                   deviation=dict(theta_deg=((true.theta - nom.theta) / DEG).tolist(),
                                  d_mm=(true.d - nom.d).tolist(), a_mm=(true.a - nom.a).tolist(),
                                  alpha_deg=((true.alpha - nom.alpha) / DEG).tolist(),
                                  beta2_deg=true.beta2 / DEG)),
        tool2flange=dict(x_mm=tool_err[0], y_mm=tool_err[1], z_mm=tool_err[2], rx_rad=tool_err[3],
                         ry_rad=tool_err[4], rz_rad=tool_err[5]),
        plate=dict(nominal_spheres_mm=spheres_nom.tolist(), true_spheres_tool_mm=spheres_tool.tolist()),
        stations=[dict(label=labels[s], base2meas=dict(zip(["x_mm", "y_mm", "z_mm", "rx_rad", "ry_rad", "rz_rad"],
                                                            T_to_pose6(base2meas[s]).tolist())), **st_info[s])
                  for s in range(S)],
        session=dict(start_pose_deg=(q_start / DEG).tolist(), test_station=labels[test_station],
                     temperature=temp_info, pauses_after_rows=sorted(pause_rows)),
        conventions="sequence.csv: m = measured (noisy, as poses.csv), t = noise-free true centres with the effects, "
        "e = t minus the same true geometry without effects; mm, measurement frame of the row's station. t and e "
        "exclude robot repeatability (it is part of the noise).",
    )
    with open(os.path.join(kd, "key.json"), "w") as f:
        json.dump(key, f, indent=1, default=float)

    noise_txt = (f"iso {spec.sigma_mm:g}" if spec.noise_kind == "iso" else
                 f"depth {spec.sigma_mm:g}x{spec.depth_factor:g}")
    if spec.repeatability_mm:
        noise_txt += f" + repeatability {spec.repeatability_mm:g}"
    return dict(name=name, category=spec.category, rows=n_data, noise=noise_txt,
                channels=";".join(channels) if channels else "-", robot=nom.name, stations=S,
                repeats="yes" if n_rep_rows else "no")
