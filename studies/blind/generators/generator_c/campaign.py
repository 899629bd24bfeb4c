"""Build one campaign of batch C: true geometry, stations, measurement sequence, effects scaled against what a
geometric calibration absorbs, instrument noise, and the files (dataset/ and key/)."""

from __future__ import annotations

import csv
import json
import os

import numpy as np

import cell
import kin

DEG = np.pi / 180.0
STD_PLATE = [[60.0, 0.0, 50.0], [-60.0, 0.0, 50.0], [-20.52, 56.38, 50.0]]
PLATES = [
    [[72.0, 0.0, 45.0], [-48.0, 18.0, 45.0], [-10.0, -61.0, 52.0]],
    [[55.0, 10.0, 60.0], [-65.0, 5.0, 40.0], [0.0, 70.0, 50.0]],
    [[80.0, -20.0, 35.0], [-40.0, -45.0, 35.0], [-25.0, 60.0, 70.0]],
    [[90.0, 0.0, 30.0], [-45.0, 78.0, 30.0], [-45.0, -78.0, 30.0]],
    [[50.0, 0.0, 80.0], [-70.0, 20.0, 45.0], [10.0, 65.0, 45.0]],
    [[64.5, -12.0, 48.0], [-58.0, -8.5, 48.0], [-4.0, 66.0, 62.5]],
]
HOME = np.array([0, 0, 0, 0, 30, 0]) * DEG


class Ctx:
    pass


def fmt(x, nd):
    return f"{x:.{nd}f}"


def _true_geometry(rng, robot, plate, stations_true):
    kp = robot.kp.copy()
    s = lambda n: rng.choice([-1.0, 1.0], n)
    kp[kin.I_TH:kin.I_TH + 6] += s(6) * rng.uniform(0.01, 0.1, 6) * DEG
    kp[kin.I_D:kin.I_D + 6] += s(6) * rng.uniform(0.1, 1.0, 6)
    kp[kin.I_A:kin.I_A + 6] += s(6) * rng.uniform(0.1, 1.0, 6)
    kp[kin.I_AL:kin.I_AL + 6] += s(6) * rng.uniform(0.01, 0.1, 6) * DEG
    kp[kin.I_BE] += s(1)[0] * rng.uniform(0.01, 0.05) * DEG
    tool = kin.pose6(np.r_[s(3) * rng.uniform(0.2, 1.5, 3), s(3) * rng.uniform(0.03, 0.3, 3) * DEG])
    return kin.Geometry(kp, tool, np.array(plate), stations_true)


def _stations(rng, robot, spec):
    """Working region and instrument placements (retry until enough configurations are visible)."""
    reach = robot.a_mm[2] + robot.d_mm[3]
    names = spec["stations"]
    ns = len(names)
    lens = spec.get("fov_deg", float(rng.uniform(15, 22)))
    for attempt in range(30):
        r = rng.uniform(0.55, 0.78) * reach
        psi = rng.uniform(-35, 35) * DEG
        h = robot.d_mm[0] + rng.uniform(-200, 150)
        centre = np.array([r * np.cos(psi), r * np.sin(psi), h])
        if ns == 1:
            azs = [psi + rng.uniform(-40, 40) * DEG]
        else:
            spread = rng.uniform(30, 45) * DEG
            azs = [psi + (k - (ns - 1) / 2) * spread * 2 / max(ns - 1, 1) * (1.0 if ns > 2 else 0.75) for k in range(ns)]
        out = []
        for k, az in enumerate(azs):
            standoff = rng.uniform(600, 1100)
            half_depth = rng.uniform(0.2, 0.3) * standoff
            view = dict(tan_hx=np.tan(lens * DEG), tan_hy=np.tan(0.75 * lens * DEG), zmin=standoff - half_depth,
                        zmax=standoff + half_depth, facing_deg=float(rng.uniform(55, 70)))
            B, v = cell.place_station(rng, robot, centre, az, rng.uniform(0, 35) * DEG, standoff, rng.uniform(-6, 6) * DEG, view)
            out.append(cell.Station(names[k], B, v))
        return out, centre, psi
    raise RuntimeError("no station placement")


def build(spec, seed, outdir, name):
    rng = np.random.default_rng([seed, spec["uid"]])
    robot = kin.irb1200() if spec["robot"] == "irb1200" else kin.inline_robot(spec["robot"])
    plate = STD_PLATE if spec.get("plate") is None else PLATES[spec["plate"]]
    plate_arr = np.array(plate)

    # ---- stations and configuration pools (retry placement when the view holds too few configurations)
    for attempt in range(20):
        stations, centre, psi = _stations(rng, robot, spec)
        try:
            pools = [cell.sample_pool(rng, robot, robot.kp, plate_arr, stn, psi, want=2500) for stn in stations]
            break
        except RuntimeError:
            continue
    else:
        raise RuntimeError(f"{name}: no usable station placement")
    geom = _true_geometry(rng, robot, plate, [s.base2meas for s in stations])
    ns = len(stations)

    # ---- measurement sequence (dataset rows)
    n_total = spec["n"]
    n_restart = spec.get("restarts", 0)
    rep_mode, rep_frac = spec.get("repeats") or (None, 0.0)
    rows = []  # dicts: q (rad), st, visit, rep (None/'still'/'reapproach'), pair, group
    visit = 0
    group = 0
    per_station = np.diff(np.round(np.linspace(0, n_total, ns + 1)).astype(int))
    for s, stn in enumerate(stations):
        n_s = int(per_station[s])
        n_base = int(round(n_s / (1 + rep_frac * 1.3))) if rep_mode else n_s
        proto = spec["protocol"]
        if proto == "pairs":
            starts, ends = cell.protocol_pairs(rng, robot, robot.kp, plate_arr, stn, pools[s], n_s // 2)
            for a, b in zip(starts, ends):
                pid = group
                rows.append(dict(q=a, st=s, visit=visit, rep=None, pair=pid, group=group))
                rows.append(dict(q=b, st=s, visit=visit + 1, rep=None, pair=pid, group=group))
                visit += 2
                group += 1
            continue
        if proto == "serpentine":
            qs = cell.protocol_serpentine(rng, robot, robot.kp, plate_arr, stn, pools[s], n_base)
        elif proto == "sweeps":
            qs = cell.protocol_sweeps(rng, robot, robot.kp, plate_arr, stn, pools[s], n_base)
        else:
            qs = cell.protocol_random(rng, pools[s], n_base)
        for q in qs:
            rows.append(dict(q=q, st=s, visit=visit, rep=None, pair=None, group=group))
            if rep_mode and rng.random() < rep_frac:
                for _ in range(int(rng.choice([1, 1, 2]))):
                    if rep_mode == "reapproach":
                        visit += 1
                    rows.append(dict(q=q, st=s, visit=visit, rep=rep_mode, pair=None, group=group))
            visit += 1
            group += 1
    # controller restarts: a row whose pose was commanded but never measured
    restart_at = []
    if n_restart:
        cand = [i for i in range(20, len(rows) - 20) if rows[i]["rep"] is None and rows[i]["pair"] is None]
        restart_at = sorted(rng.choice(cand, n_restart, replace=False).tolist())
        # keep them apart
        if n_restart > 1 and abs(restart_at[1] - restart_at[0]) < 40:
            restart_at[1] = min(len(rows) - 15, restart_at[0] + int(len(rows) * 0.35))
        for i in restart_at:
            rows[i]["restart"] = True
    n_data = len(rows)

    # test rows: 60 afterwards, at the last station
    st_test = ns - 1
    tq = cell.protocol_random(rng, pools[st_test], 60)
    for q in tq:
        rows.append(dict(q=q, st=st_test, visit=visit, rep=None, pair=None, group=-1, test=True))
        visit += 1
    N = len(rows)

    # commanded angles as written (deg, 4 decimals) define the truth
    q_deg = np.round(np.array([r["q"] for r in rows]) / DEG, 4)
    q = q_deg * DEG
    st = np.array([r["st"] for r in rows])

    # ---- time line and temperature
    t = np.zeros(N)
    setup_t = np.zeros(ns)
    cur = float(rng.uniform(*spec.get("t_start", (240, 900))))
    setup_t[0] = cur - float(rng.uniform(90, 200))
    prev_q = HOME
    for k in range(N):
        r = rows[k]
        if k > 0 and (st[k] != st[k - 1]) and not r.get("test"):
            cur += float(rng.uniform(420, 900))  # moving the instrument to its next station
            setup_t[st[k]] = cur - float(rng.uniform(60, 150))
        if r.get("test") and not rows[k - 1].get("test"):
            cur += float(rng.uniform(90, 420))
        if r["rep"] == "still":
            cur += float(rng.uniform(0.6, 1.3))
        elif r["rep"] == "reapproach":
            cur += float(rng.uniform(4.0, 7.0))
        else:
            cur += cell.move_time(q[k] - prev_q, rng)
        t[k] = cur
        if r.get("restart"):
            cur += float(rng.uniform(150, 420))  # fault, restart, re-reference
        prev_q = q[k]
    temp_kind = spec.get("temp_kind", "room")
    hv = dict(T0=float(spec.get("temp_T0", rng.uniform(19.5, 23.0))), drift_per_h=float(rng.uniform(-0.4, 0.6)), hvac_amp=float(rng.uniform(0.1, 0.35)),
              hvac_period=float(rng.uniform(900, 1600)), hvac_phase=float(rng.uniform(-np.pi, np.pi)),
              rise=float(spec.get("temp_rise", 3.5)), tau=float(rng.uniform(*spec.get("temp_tau", (2500, 4000)))))
    temp_true = cell.ambient_profile(rng, temp_kind, t, hv)
    temp_dec = int(rng.choice([1, 2]))
    temp_rec = np.round(temp_true + rng.normal(0, 0.03, N), temp_dec)

    # history: step and last-motion direction of every joint
    step = np.zeros((N, 6))
    dirs = np.zeros((N, 6))
    d = np.sign(q[0] - HOME)
    d[d == 0] = 1
    prev = HOME
    for k in range(N):
        stp = q[k] - prev
        if rows[k]["rep"] is not None:
            stp = np.zeros(6)
        step[k] = stp
        nz = np.abs(stp) > 1e-12
        d = np.where(nz, np.sign(stp), d)
        dirs[k] = d
        prev = q[k]

    # ---- which rows carry measurements
    data_rows = np.zeros(N, bool)
    data_rows[:n_data] = True
    has_meas = np.array([not r.get("restart") for r in rows])
    missing = {}  # row -> sphere index
    n_miss = spec.get("missing", 0)
    c_nom = kin.centres(geom, q, st)
    if n_miss:
        cand = [i for i in range(n_data) if has_meas[i] and rows[i]["rep"] is None]
        for i in rng.choice(cand, n_miss, replace=False):
            p = c_nom[i]
            edge = np.max(np.abs(p[:, :2] / p[:, 2:3]) / [stations[st[i]].view["tan_hx"], stations[st[i]].view["tan_hy"]], axis=1)
            k = int(np.argmax(edge)) if rng.random() < 0.6 else int(rng.integers(3))
            missing[int(i)] = k

    # roles (set column), in groups (a visit with its repeats, a motion pair)
    roles = ["data"] * n_data
    if spec.get("set", True):
        groups = sorted({rows[i]["group"] for i in range(n_data)})
        for _ in range(200):
            if spec.get("set_pattern") == "every4":
                off = int(rng.integers(4))
                val = {g for g in groups if (g + off) % 4 == 0 or rng.random() < 0.05}
            else:
                val = {g for g in groups if rng.random() < 0.3}
            frac = np.mean([rows[i]["group"] in val for i in range(n_data)])
            if 0.25 <= frac <= 0.35:
                break
        roles = ["validation" if rows[i]["group"] in val else "calibration" for i in range(n_data)]
    roles += ["test"] * (N - n_data)

    # ---- context for effects
    ctx = Ctx()
    ctx.n, ctx.q, ctx.t, ctx.temp, ctx.st = N, q, t, temp_true, st
    ctx.step, ctx.dirs = step, dirs
    ctx.robot, ctx.kp_nom, ctx.geom = robot, robot.kp, geom
    ctx.n_stations, ctx.setup_t = ns, setup_t
    ctx.restart_rows = [i for i in range(N) if rows[i].get("restart")]
    ctx.data_rows, ctx.has_meas = data_rows, has_meas
    ctx.c_nom = c_nom
    env = dict(hvac=hv, n_stations=ns, robot=robot)

    # ---- noise (instrument + robot repeatability): unit-level draws, scaled below
    noise_model = dict(spec["noise"])
    r0 = float(np.mean([s.view["standoff"] for s in stations]))
    if noise_model["kind"] == "stereo":
        noise_model.setdefault("k_ray", float(rng.uniform(2.5, 3.5)))
        noise_model.setdefault("rho", float(rng.uniform(0.3, 0.6)))
        noise_model.update(r0=r0)
    unit = dict(noise_model, rms=1.0)
    if unit["kind"] == "stereo":
        unit.update(s0=1.0 / np.sqrt((2 + unit["k_ray"] ** 2) / 3))
    elif unit["kind"] == "tracker":
        unit.update(sigma_r=0.8, sigma_ang=1.1 / r0)
    else:
        unit.update(sigma=1.0)
    inst_unit = cell.instrument_noise(rng, unit, c_nom)
    rep_sigma = spec.get("rep")
    flange_delta = None
    if rep_sigma:
        visits = np.array([r["visit"] for r in rows])
        uniq, inv = np.unique(visits, return_inverse=True)
        flange_delta = cell.repeatability_deltas(rng, len(uniq), rep_sigma)[inv]

    # ---- rows used for the effect-size bookkeeping
    use = data_rows & has_meas
    for i in missing:
        use[i] = False
    gross_rows = []
    if spec.get("gross", 0):
        cand = [i for i in range(n_data) if use[i] and rows[i]["rep"] is None]
        gross_rows = sorted(int(i) for i in rng.choice(cand, spec["gross"], replace=False))
    for i in gross_rows:
        use[i] = False
    if spec.get("set", True):
        fit = use & np.array([r == "calibration" for r in roles])
    else:
        fit = use & (rng.random(N) > 0.3)
    eval_rows = use
    J = kin.geometric_jacobian(geom, q, st, ns)
    rep_disp = np.zeros_like(c_nom)
    if flange_delta is not None:
        rep_disp = kin.centres(geom, q, st, None, flange_delta) - c_nom
    rep_rms = float(np.sqrt(np.mean(rep_disp[eval_rows] ** 2)))
    unit_rms = float(np.sqrt(np.mean(inst_unit[eval_rows] ** 2)))

    # ---- effects at physically plausible sizes decide the noise level; then sizes are set on the targets
    effects = [(factory(rng, env), target) for factory, target in spec["effects"]]
    if effects:
        ratios = []
        for eff, target in effects:
            eff.amp = float(spec.get("phys_amp", {}).get(type(eff).__name__, eff.phys_amp))
            eff.amp_phys = eff.amp
            e = kin.centres(geom, q, st, eff.mods(ctx, eff.amp)) - c_nom
            _, left = kin.left_after_geometric(J, e, fit, eval_rows)
            ratios.append(left / target)
        lo, hi = spec.get("noise_clip", (0.0025, 0.015))
        sigma_des = float(np.clip(np.exp(np.mean(np.log(ratios))), lo, hi))
    else:
        sigma_des = float(spec["noise"]["rms"])
    inst_sigma = np.sqrt(max(sigma_des**2 - rep_rms**2, (0.45 * sigma_des) ** 2)) / unit_rms
    inst = inst_unit * inst_sigma
    if noise_model["kind"] == "stereo":
        noise_model.update(s0=unit["s0"] * inst_sigma)
    elif noise_model["kind"] == "tracker":
        noise_model.update(sigma_r=0.8 * inst_sigma, sigma_ang=1.1 * inst_sigma / r0)
    else:
        noise_model.update(sigma=inst_sigma)
    sigma_ref = float(np.sqrt(np.mean((inst + rep_disp)[eval_rows] ** 2)))  # noise per coordinate of the rows used
    mods_all = kin.Mods(N)
    eff_out = []
    for eff, target in effects:
        for _ in range(4):
            e = kin.centres(geom, q, st, eff.mods(ctx, eff.amp)) - c_nom
            _, left = kin.left_after_geometric(J, e, fit, eval_rows)
            ratio = left / sigma_ref
            if abs(ratio / target - 1) < 0.01:
                break
            eff.amp *= target / ratio
        e = kin.centres(geom, q, st, eff.mods(ctx, eff.amp)) - c_nom
        _, left = kin.left_after_geometric(J, e, fit, eval_rows)
        mods_all = mods_all.compose(eff.mods(ctx, eff.amp))
        eff_out.append(dict(eff=eff, target=target, amp_phys=eff.amp_phys, rms=float(np.sqrt(np.mean(e[eval_rows] ** 2))), left=left))
    t_true = kin.centres(geom, q, st, mods_all)
    e_all = t_true - c_nom
    _, left_all = kin.left_after_geometric(J, e_all, fit, eval_rows) if spec["effects"] else (None, 0.0)
    if flange_delta is not None:
        rep_disp = kin.centres(geom, q, st, mods_all, flange_delta) - t_true
    meas = t_true + rep_disp + inst

    # gross rows: a sphere matched to a reflection, or the whole row taken while the arm still moved
    gross_info = []
    for i in gross_rows:
        if rng.random() < 0.5:
            k = int(rng.integers(3))
            v = rng.normal(size=3)
            v *= rng.uniform(0.4, 1.5) / np.linalg.norm(v)
            meas[i, k] += v
            gross_info.append(dict(pose_index=i, kind=f"sphere p{k} mismatched", offset_mm=np.round(v, 3).tolist()))
        else:
            v = rng.normal(size=3)
            v *= rng.uniform(0.15, 0.5) / np.linalg.norm(v)
            meas[i] += v
            gross_info.append(dict(pose_index=i, kind="row captured during motion", offset_mm=np.round(v, 3).tolist()))

    # ---- write
    return dict(
        rows=rows, n_data=n_data, q_deg=q_deg, st=st, t=t, temp_rec=temp_rec, roles=roles, missing=missing,
        restart_rows=ctx.restart_rows, meas=meas, t_true=t_true, e_all=e_all, c_nom=c_nom, stations=stations,
        geom=geom, robot=robot, plate=plate, eff_out=eff_out, sigma_ref=sigma_ref, left_all=left_all,
        noise_model=noise_model, rep_sigma=rep_sigma, gross_info=gross_info, gross_rows=gross_rows,
        eval_rows=eval_rows, centre=centre, hv=hv, inst=inst, rep_disp=rep_disp, temp_dec=temp_dec,
    )
