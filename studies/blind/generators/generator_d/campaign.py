"""Campaign assembly: true geometry, stations, protocol and time line, effects, noise, writers."""

from __future__ import annotations

import json
import os

import numpy as np

from cell import Station, sample_in_view, visible, WIDTH, HEIGHT, F_PX
from kin import (
    DEG,
    PLATE_SPHERES_MM,
    SPHERE_DIAMETER_MM,
    apply_T,
    copy_params,
    link_frames,
    nominal_params,
    pose6_to_T,
)

HOME_DEG = np.array([0.0, 0.0, 0.0, 0.0, 30.0, 0.0])
N_TEST = 60


# ------------------------------------------------------------------------------------------------ geometry
def true_geometry(rng):
    P = nominal_params()
    P["theta"] = P["theta"] + np.clip(rng.normal(0, 0.025, 6), -0.06, 0.06) * DEG
    P["alpha"] = P["alpha"] + np.clip(rng.normal(0, 0.025, 6), -0.06, 0.06) * DEG
    P["d"] = P["d"] + np.clip(rng.normal(0, 0.25, 6), -0.6, 0.6)
    P["a"] = P["a"] + np.clip(rng.normal(0, 0.25, 6), -0.6, 0.6)
    P["beta2"] = float(np.clip(rng.normal(0, 0.025), -0.06, 0.06) * DEG)
    u = rng.normal(size=3)
    t = u / np.linalg.norm(u) * rng.uniform(0.3, 1.5)
    w = rng.normal(size=3)
    r = w / np.linalg.norm(w) * rng.uniform(0.05, 0.3) * DEG
    tool2flange = pose6_to_T(np.concatenate([t, r]))
    return P, tool2flange


def make_stations(rng, n_st):
    st = []
    az0 = rng.uniform(-20, 20)
    for s in range(n_st):
        az = az0 + (0 if s == 0 else (1 if s % 2 else -1) * rng.uniform(30, 45)) * (1 if s < 2 else 1.3)
        target = np.array([rng.uniform(480, 600), rng.uniform(-100, 100), rng.uniform(480, 650)])
        standoff = rng.uniform(650, 1100)
        err = np.concatenate([rng.normal(0, 3.0, 3), rng.normal(0, 0.2, 3) * DEG])
        st.append(Station(s, target, standoff, az * DEG, rng.uniform(5, 25) * DEG, rng.uniform(-3, 3) * DEG, err))
    return st


# ------------------------------------------------------------------------------------------------ protocol
def grid_centres(station, rng, n):
    z0 = station.standoff
    nz = 3
    zs = np.linspace(z0 - 100, z0 + 100, nz)
    pts = []
    for z in zs:
        hx = (WIDTH / 2 - 100 - 700) / F_PX * z * 0.75
        hy = (HEIGHT / 2 - 100 - 700) / F_PX * z * 0.75
        for y in np.linspace(-hy, hy, 3):
            for x in np.linspace(-hx, hx, 4):
                pts.append([x, y, z])
    pts = np.array(pts)
    reps = int(np.ceil(n / len(pts)))
    return np.concatenate([pts] * reps)[:n]


def plan_rows(spec, stations, rng):
    """dataset q (n,6) [rad] with station indices, then test rows (N_TEST) in the same protocol style."""
    n = spec["rows"]
    ns = len(stations)
    per = [n // ns + (1 if s < n % ns else 0) for s in range(ns)]
    per_t = [N_TEST // ns + (1 if s < N_TEST % ns else 0) for s in range(ns)]
    kw = spec.get("sampling", {})
    qs, sts, qts, stts = [], [], [], []
    for s, stn in enumerate(stations):
        proto = spec["protocol"]
        if proto == "grid":
            cen = grid_centres(stn, rng, per[s])
            q = sample_in_view(stn, per[s], rng, centres=cen, **kw)
            qt = sample_in_view(stn, per_t[s], rng, centres=grid_centres(stn, rng, per_t[s] + 7)[7:], **kw)
        elif proto == "repeat":
            r = spec.get("repeats", 3)
            k = int(np.ceil(per[s] / r))
            base = sample_in_view(stn, k, rng, **kw)
            order = np.concatenate([rng.permutation(k) for _ in range(r)])[: per[s]]
            q = base[order]
            qt = base[rng.choice(k, per_t[s], replace=per_t[s] > k)]
        else:
            q = sample_in_view(stn, per[s], rng, **kw)
            qt = sample_in_view(stn, per_t[s], rng, **kw)
        qs.append(q)
        sts.append(np.full(len(q), s))
        qts.append(qt)
        stts.append(np.full(len(qt), s))
    q = np.concatenate(qs + qts)
    station = np.concatenate(sts + stts)
    return q, station


def time_line(spec, rng, n_data, n_all):
    """time stamps [s]: cadence per row, pauses between sessions; test rows follow after a short gap."""
    lo, hi = spec.get("cadence_s", (9.0, 16.0))
    dt = rng.uniform(lo, hi, n_all)
    t = np.empty(n_all)
    running = np.ones(n_all, bool)  # whether the interval before row k was spent running
    pauses = spec.get("pauses_s", [])
    cuts = []
    if pauses:
        cuts = sorted(rng.choice(np.arange(int(0.25 * n_data), int(0.85 * n_data)), len(pauses), replace=False))
    extra = np.zeros(n_all)
    for c, p in zip(cuts, pauses):
        extra[c] = p
        running[c] = False
    extra[n_data] += rng.uniform(30, 120)  # gap before the test block
    t0 = rng.uniform(20, 60)
    t = t0 + np.cumsum(dt + extra) - dt[0]
    t = np.round(t, 3)
    return t, running, cuts


def temperatures(spec, rng, t, running):
    """arm temperature (first-order response to the duty) and air temperature (HVAC cycle + drift) [degC]."""
    Tamb0 = rng.uniform(19.5, 23.0)
    P = rng.uniform(1500, 2600)
    ph = rng.uniform(0, 2 * np.pi)
    a = rng.uniform(0.3, 0.8)
    drift = rng.uniform(-0.3, 0.5)  # K per hour
    T_air = Tamb0 + a * np.sin(2 * np.pi * t / P + ph) + drift * t / 3600.0
    rise = spec.get("arm_rise_k", rng.uniform(5, 10))
    tau = spec.get("arm_tau_s", rng.uniform(1500, 2700))
    T = np.empty_like(t)
    cur = Tamb0 + spec.get("arm_start_k", 0.0)
    prev_t = 0.0
    for k in range(len(t)):
        if running[k]:
            E = Tamb0 + rise
            cur = E + (cur - E) * np.exp(-(t[k] - prev_t) / tau)
        else:
            # pause: cool towards ambient for the pause, the last cadence interval running
            dtk = t[k] - prev_t
            E = Tamb0
            cur = E + (cur - E) * np.exp(-dtk / tau)
        T[k] = cur
        prev_t = t[k]
    return T, T_air, {"T_amb0": Tamb0, "hvac_period_s": P, "hvac_amp_k": a, "drift_k_per_h": drift,
                      "arm_rise_k": rise, "arm_tau_s": tau}


# ------------------------------------------------------------------------------------------------ truth
def make_ctx(q, station, t, T_arm, T_air, P, n_data):
    home = HOME_DEG * DEG
    prev = np.vstack([home[None], q[:-1]])
    step = q - prev
    # approach sign: sign of the last non-zero move of each joint (home before the first row: from home)
    appr = np.zeros_like(q)
    last = np.ones(6)
    for k in range(len(q)):
        nz = np.abs(step[k]) > 1e-12
        last = np.where(nz, np.sign(step[k]), last)
        appr[k] = last
    cum6 = np.cumsum(np.abs(step[:, 5]))
    return {
        "q": q, "station": station, "t": t, "T_robot": T_arm, "T_air": T_air, "T_ref": float(T_arm[0]),
        "T_air_cal": float(T_air[0]), "P": P, "approach": appr, "dq_prev": step, "cum_q6": cum6, "n_data": n_data,
    }


def true_points(ctx, effects, tool2flange, base2meas):
    """true sphere centres in the measurement frame of each row's station, with the given effects."""
    n = ctx["q"].shape[0]
    q = ctx["q"].copy()
    for e in effects:
        d = e.dq(ctx)
        if d is not None:
            q = q + d
    P = ctx["P"]
    for e in effects:
        P = e.params(ctx, P)
    F = link_frames(P, q)[:, 6]
    c2 = dict(ctx)
    c2["flange_R"] = F[:, :3, :3]
    T = np.tile(tool2flange, (n, 1, 1))
    S = np.tile(PLATE_SPHERES_MM, (n, 1, 1))
    for e in effects:
        T, S = e.tool(c2, T, S)
    B = np.stack([base2meas[s] for s in ctx["station"]])
    for e in effects:
        B = e.base(c2, B)
    tool2meas = B @ F @ T
    pts = apply_T(tool2meas, S)
    aux = {"normal": tool2meas[:, :3, 2]}
    for e in effects:
        pts = e.meas(c2, pts, aux)
    return pts


def rms3(e):
    return float(np.sqrt(np.mean(np.sum(e ** 2, axis=2))))


# ------------------------------------------------------------------------------------------------ noise
def add_noise(spec, rng, pts):
    nm = spec["noise"]
    sig = nm["sigma"]
    n = pts.shape[0]
    if nm["model"] == "depth":
        k = nm.get("depth_factor", 3.0)
        scale = np.array([sig, sig, k * sig])
    else:
        scale = np.array([sig, sig, sig])
    noise = rng.normal(size=(n, 3, 3)) * scale
    out_mask = rng.uniform(size=(n, 3)) < nm.get("outlier_rate", 0.0)
    if out_mask.any():
        d = rng.normal(size=(n, 3, 3))
        d /= np.linalg.norm(d, axis=2, keepdims=True)
        mag = rng.uniform(0.15, 0.8, (n, 3))
        noise = noise + out_mask[..., None] * d * mag[..., None]
    return pts + noise, out_mask


def stated_sigma(nm):
    if nm["model"] == "depth":
        k = nm.get("depth_factor", 3.0)
        return nm["sigma"] * np.sqrt((2 + k * k) / 3)
    return nm["sigma"]


# ------------------------------------------------------------------------------------------------ build
def build(spec, seed, index, name):
    rng_geo = np.random.default_rng([seed, index, 1])
    rng_pose = np.random.default_rng([seed, index, 2])
    rng_time = np.random.default_rng([seed, index, 3])
    rng_eff = np.random.default_rng([seed, index, 4])
    rng_noise = np.random.default_rng([seed, index, 5])
    rng_meta = np.random.default_rng([seed, index, 6])

    P, tool2flange = true_geometry(rng_geo)
    stations = make_stations(rng_geo, spec.get("stations", 1))
    base2meas = [s.base2meas_true for s in stations]

    q, station = plan_rows(spec, stations, rng_pose)
    n_all = len(q)
    n_data = n_all - N_TEST
    t, running, cuts = time_line(spec, rng_time, n_data, n_all)
    T_arm, T_air, temp_info = temperatures(spec, rng_time, t, running)
    ctx = make_ctx(q, station, t, T_arm, T_air, P, n_data)
    if "t_bump_cut" in spec and cuts:
        ctx["t_bump"] = float(t[cuts[0]])

    effects = []
    for factory, target in spec.get("effects", []):
        e = factory(rng_eff, ctx)
        base_pts = true_points(ctx, [], tool2flange, base2meas)
        for _ in range(3):
            d = true_points(ctx, [e], tool2flange, base2meas) - base_pts
            r = rms3(d)
            e.scale *= target / r
        effects.append(e)

    p0 = true_points(ctx, [], tool2flange, base2meas)
    p1 = true_points(ctx, effects, tool2flange, base2meas)
    e_all = p1 - p0
    per_effect = [rms3(true_points(ctx, [e], tool2flange, base2meas) - p0) for e in effects]

    # visibility with the true rig (spheres out of frame are not measured), occlusions, failed detections
    seen = np.ones((n_all, 3), bool)
    status = [[] for _ in range(n_all)]
    for s, stn in enumerate(stations):
        sel = station == s
        cams = stn.true_cams
        # points in meas frame -> base -> visibility with both true cameras
        pts_b = apply_T(np.linalg.inv(base2meas[s])[None].repeat(sel.sum(), 0), p1[sel])
        vis = visible(cams, pts_b, margin_px=2.0)
        idx = np.nonzero(sel)[0]
        for k, row in zip(idx, vis):
            for i in range(3):
                if not row[i]:
                    seen[k, i] = False
                    status[k].append(f"p{i}:out_of_frame")
    occ = rng_noise.uniform(size=(n_all, 3)) < spec.get("occlusion_rate", 0.0)
    fail = rng_noise.uniform(size=n_all) < spec.get("row_fail_rate", 0.0)
    for k in range(n_all):
        if fail[k]:
            for i in range(3):
                if seen[k, i]:
                    seen[k, i] = False
                    status[k].append(f"p{i}:not_detected")
            continue
        for i in range(3):
            if occ[k, i] and seen[k, i]:
                seen[k, i] = False
                status[k].append(f"p{i}:occluded")
    m, outl = add_noise(spec, rng_noise, p1)
    if spec["category"] != "clean" or spec.get("keep_test_complete", True):
        pass

    # set column
    roles = np.array(["data"] * n_all, dtype=object)
    if spec.get("set_column", False):
        vf = spec.get("validation_fraction", 0.25)
        v = rng_meta.uniform(size=n_data) < vf
        roles[:n_data] = np.where(v, "validation", "calibration")
    roles[n_data:] = "test"

    temp_meas = None
    if spec.get("temp_column") == "arm":
        temp_meas = np.round(T_arm + rng_noise.normal(0, 0.03, n_all), 2)
    elif spec.get("temp_column") == "air":
        temp_meas = np.round(T_air + rng_noise.normal(0, 0.03, n_all), 2)

    pose_start = int(rng_meta.integers(1, 5)) * 1000 + 1 if spec.get("offset_ids", False) else 1
    pose_id = np.arange(pose_start, pose_start + n_all)

    return {
        "spec": spec, "name": name, "index": index, "seed": seed, "P": P, "tool2flange": tool2flange,
        "stations": stations, "base2meas": base2meas, "q": q, "station": station, "t": t, "T_arm": T_arm,
        "T_air": T_air, "temp_info": temp_info, "temp_meas": temp_meas, "effects": effects, "per_effect": per_effect,
        "p0": p0, "p1": p1, "e": e_all, "m": m, "seen": seen, "status": status, "outliers": outl, "roles": roles,
        "pose_id": pose_id, "n_data": n_data, "cuts": cuts, "ctx": ctx,
    }


# ------------------------------------------------------------------------------------------------ writers
def _f(x, nd=6):
    return f"{x:.{nd}f}"


def write(c, out_dir):
    spec = c["spec"]
    name = c["name"]
    root = os.path.join(out_dir, name)
    ds = os.path.join(root, "dataset")
    kd = os.path.join(root, "key")
    os.makedirs(ds, exist_ok=True)
    os.makedirs(kd, exist_ok=True)
    n_data = c["n_data"]
    qd = c["q"] / DEG
    multi = len(c["stations"]) > 1 or spec.get("station_column", False)
    has_t = spec.get("t_column", False)
    has_temp = c["temp_meas"] is not None
    has_set = spec.get("set_column", False)
    has_status = any(len(s) for s in c["status"][:n_data])

    sph_cols = [f"p{i}_{a}" for i in range(3) for a in "xyz"]
    hdr = ["pose_id"] + [f"q{j}" for j in range(1, 7)]
    if has_set:
        hdr.append("set")
    if multi:
        hdr.append("station")
    if has_t:
        hdr.append("t_s")
    if has_temp:
        hdr.append("temp_c")
    hdr += sph_cols
    if has_status:
        hdr.append("status")
    lines = [",".join(hdr)]
    for k in range(n_data):
        row = [str(c["pose_id"][k])] + [_f(v) for v in qd[k]]
        if has_set:
            row.append(c["roles"][k])
        if multi:
            row.append(str(int(c["station"][k])))
        if has_t:
            row.append(_f(c["t"][k], 3))
        if has_temp:
            row.append(_f(c["temp_meas"][k], 2))
        for i in range(3):
            if c["seen"][k, i]:
                row += [_f(v) for v in c["m"][k, i]]
            else:
                row += ["", "", ""]
        if has_status:
            row.append(";".join(c["status"][k]))
        lines.append(",".join(row))
    with open(os.path.join(ds, "poses.csv"), "w", newline="\n") as f:
        f.write("\n".join(lines) + "\n")

    # dataset.toml
    sp = PLATE_SPHERES_MM
    toml = [
        "schema_version = 1",
        'robot = "irb1200"',
        f'provenance = "Held-out batch D, campaign {name}: three-sphere plate on the flange of an IRB 1200-7/0.7, sphere centres '
        f'measured by a binocular camera rig ({len(c["stations"])} station{"s" if len(c["stations"]) > 1 else ""}); '
        'simulated measurements for blind evaluation"',
        "",
        "[plate]",
        f"sphere_diameter_mm = {SPHERE_DIAMETER_MM}",
        "spheres_mm = [" + ", ".join("[" + ", ".join(f"{v:.2f}" for v in r) + "]" for r in sp) + "]",
    ]
    if spec.get("noise_stated", True):
        toml += ["", "[noise]", f"position_mm = {stated_sigma(spec['noise']):.4f}"]
    if spec.get("nominal_given", False):
        for s, stn in enumerate(c["stations"]):
            v = stn.base2meas_stated()
            toml += ["", f"[stations.{s}]",
                     f"base2meas = {{ x_mm = {v[0]:.3f}, y_mm = {v[1]:.3f}, z_mm = {v[2]:.3f}, "
                     f"rx_rad = {v[3]:.6f}, ry_rad = {v[4]:.6f}, rz_rad = {v[5]:.6f} }}"]
    with open(os.path.join(ds, "dataset.toml"), "w", newline="\n") as f:
        f.write("\n".join(toml) + "\n")

    # sequence.csv
    hdr = ["pose_id"] + [f"q{j}" for j in range(1, 7)]
    if multi:
        hdr.append("station")
    if has_t:
        hdr.append("t_s")
    if has_temp:
        hdr.append("temp_c")
    hdr.append("role")
    hdr += [f"m{i}_{a}" for i in range(3) for a in "xyz"]
    hdr += [f"t{i}_{a}" for i in range(3) for a in "xyz"]
    hdr += [f"e{i}_{a}" for i in range(3) for a in "xyz"]
    lines = [",".join(hdr)]
    for k in range(len(c["q"])):
        row = [str(c["pose_id"][k])] + [_f(v) for v in qd[k]]
        if multi:
            row.append(str(int(c["station"][k])))
        if has_t:
            row.append(_f(c["t"][k], 3))
        if has_temp:
            row.append(_f(c["temp_meas"][k], 2))
        row.append(c["roles"][k])
        for i in range(3):
            if c["seen"][k, i]:
                row += [_f(v) for v in c["m"][k, i]]
            else:
                row += ["", "", ""]
        for i in range(3):
            row += [_f(v) for v in c["p1"][k, i]]
        for i in range(3):
            row += [_f(v) for v in c["e"][k, i]]
        lines.append(",".join(row))
    with open(os.path.join(kd, "sequence.csv"), "w", newline="\n") as f:
        f.write("\n".join(lines) + "\n")

    # key.json
    eff = []
    for e, r in zip(c["effects"], c["per_effect"]):
        eff.append({
            "family": e.family, "description": e.description(), "formula": e.formula(), "joints": list(e.joints),
            "links": [str(x) for x in e.links], "place": e.place, "channel": e.channel, "rms_mm": round(r, 5),
        })
    nm = spec["noise"]
    noise = {"model": nm["model"], "sigma_mm": nm["sigma"], "stated_position_mm": round(stated_sigma(nm), 5),
             "stated_in_dataset": spec.get("noise_stated", True)}
    if nm["model"] == "depth":
        noise["depth_factor"] = nm.get("depth_factor", 3.0)
        noise["note"] = "sigma_mm on the camera x, y axes; depth (camera z) sigma = depth_factor x sigma_mm"
    if nm.get("outlier_rate", 0):
        noise["outlier_rate_per_sphere"] = nm["outlier_rate"]
        noise["outlier_size_mm"] = [0.15, 0.8]
        noise["outlier_pose_ids"] = [int(c["pose_id"][k]) for k in range(n_data) if c["outliers"][k].any()]
    ex = np.sqrt(np.mean(np.sum(c["e"][:n_data] ** 2, axis=2)))
    et = np.sqrt(np.mean(np.sum(c["e"][n_data:] ** 2, axis=2)))
    notes = spec.get("notes", "")
    notes += (f" Protocol: {spec['protocol']}, {n_data} dataset rows + {N_TEST} test rows, {len(c['stations'])} station(s)"
              f"{', pauses ' + str([int(p) for p in spec.get('pauses_s', [])]) + ' s' if spec.get('pauses_s') else ''}."
              f" Total effect RMS (3-D per sphere): dataset {ex:.4f} mm, test {et:.4f} mm."
              f" rms_mm of an effect = RMS over all rows (dataset + test) and spheres of the 3-D length of its contribution"
              f" alone, including any part a geometric recalibration can absorb."
              f" True geometry: all 25 MDH parameters off nominal (sd 0.25 mm / 0.025 deg), plate tool2flange off by"
              f" {np.linalg.norm(c['tool2flange'][:3, 3]):.2f} mm; station base2meas off the stated nominal by the rig placement error."
              f" Random streams: numpy default_rng([{c['seed']}, {c['index']}, k]).")
    if has_temp:
        notes += f" temp_c records the {'arm' if spec.get('temp_column') == 'arm' else 'air'} temperature (sensor noise 0.03 K)."
    key = {
        "schema_version": 1, "name": name, "category": spec["category"], "expected_names": spec.get("expected", []),
        "effects": eff, "noise": noise, "seed": c["seed"], "notes": notes.strip(),
    }
    with open(os.path.join(kd, "key.json"), "w", newline="\n") as f:
        json.dump(key, f, indent=2)
        f.write("\n")
    chans = [x for x, h in (("set", has_set), ("station", multi), ("t_s", has_t), ("temp_c", has_temp), ("status", has_status)) if h]
    noise_s = f"{nm['model']} {nm['sigma']}" + (f" x{nm.get('depth_factor', 3.0)}z" if nm["model"] == "depth" else "") + \
              (f" +outliers {nm['outlier_rate']}" if nm.get("outlier_rate", 0) else "")
    return {"name": name, "category": spec["category"], "rows": n_data, "noise": noise_s, "channels": ";".join(chans),
            "stations": len(c["stations"])}
