"""Build one campaign: geometry, stations, rows, timeline, effects, sizing, noise, files."""
from __future__ import annotations

import json
import os
from types import SimpleNamespace

import numpy as np

import kin
import scene
from effects import EFFECTS
from kin import DEG
from robots import ROBOTS, toml_robot

DEFAULT_PLATE = np.array([[60.0, 0.0, 50.0], [-60.0, 0.0, 50.0], [-20.52, 56.38, 50.0]])
N_TEST = 60
MISS_REASONS = ["occluded", "out_of_frame", "low_contrast", "specular_glint"]


def random_plate(rng):
    while True:
        r = rng.uniform(45, 80, 3)
        a = np.radians(np.array([rng.uniform(-20, 20), rng.uniform(100, 145), rng.uniform(215, 260)]))
        z = rng.uniform(40, 62, 3)
        S = np.round(np.stack([r * np.cos(a), r * np.sin(a), z], 1), 2)
        d = [np.linalg.norm(S[i] - S[j]) for i, j in ((0, 1), (0, 2), (1, 2))]
        if min(d) > 70 and max(d) - min(d) > 8:
            return S


def true_geometry(rng, robot):
    pv_nom = kin.pack(robot)
    dv = np.zeros(25)
    sgn = lambda k: rng.choice([-1.0, 1.0], size=k)
    dv[0:6] = sgn(6) * rng.uniform(0.01, 0.1, 6) * DEG       # theta
    dv[6:12] = sgn(6) * rng.uniform(0.1, 1.0, 6)             # d
    dv[12:18] = sgn(6) * rng.uniform(0.1, 1.0, 6)            # a
    dv[18:24] = sgn(6) * rng.uniform(0.01, 0.1, 6) * DEG     # alpha
    dv[24] = sgn(1)[0] * rng.uniform(0.01, 0.05) * DEG       # beta2
    u = rng.normal(size=3); u /= np.linalg.norm(u)
    w = rng.normal(size=3); w /= np.linalg.norm(w)
    tool = np.concatenate([u * rng.uniform(0.2, 1.0), w * rng.uniform(0.05, 0.2) * DEG])
    return pv_nom, pv_nom + dv, dv, tool


def build_rows(rng, spec, robot, pv_nom, stations, plate_centre):
    n_data = spec["rows"]
    n_st = len(stations)
    rep_mode = spec.get("repeats", "none")
    extras = int(round(n_data * rng.uniform(0.08, 0.14))) if rep_mode != "none" else 0
    n_unique = n_data - extras
    if n_st == 1:
        counts = [n_unique]
    else:
        w = rng.uniform(0.7, 1.3, n_st); w /= w.sum()
        counts = list(np.floor(w * n_unique).astype(int)); counts[-1] += n_unique - sum(counts)
    order = list(rng.permutation(n_st))
    rows = []
    for s in order:
        qs = scene.sample_configs(rng, robot, pv_nom, stations[s], plate_centre, counts[s])
        for q in qs[rng.permutation(len(qs))]:
            rows.append(dict(q=q, station=int(s), kind="move"))
    # consecutive repeats
    if extras:
        kind = "static" if rep_mode == "static" else "reapproach"
        left = extras
        cand = list(rng.permutation(len(rows)))
        plan = {}
        while left > 0:
            i = int(cand.pop())
            k = min(left, int(rng.integers(1, 3)))
            plan[i] = k
            left -= k
        new = []
        for i, r in enumerate(rows):
            new.append(r)
            for _ in range(plan.get(i, 0)):
                new.append(dict(q=r["q"].copy(), station=r["station"], kind=kind, rep_of=i))
        rows = new
    test_station = int(order[-1])
    qs = scene.sample_configs(rng, robot, pv_nom, stations[test_station], plate_centre, N_TEST)
    for q in qs:
        rows.append(dict(q=q, station=test_station, kind="move", test=True))
    return rows, test_station


def timeline(rng, spec, rows, n_data):
    n = len(rows)
    t = np.zeros(n)
    t[0] = rng.uniform(0, 40)
    restart_idx = None
    if spec.get("restart"):
        cand = [i for i in range(int(0.4 * n_data), int(0.6 * n_data)) if rows[i]["kind"] == "move"]
        restart_idx = int(rng.choice(cand))
    forced = set()
    if spec.get("pauses"):
        cand = [i for i in range(10, n_data - 10) if rows[i]["kind"] == "move" and i != restart_idx]
        forced = set(int(x) for x in rng.choice(cand, spec["pauses"], replace=False))
    gaps = np.zeros(n)
    for k in range(1, n):
        kind = rows[k]["kind"]
        g = {"move": rng.uniform(8, 20), "static": rng.uniform(3, 6), "reapproach": rng.uniform(10, 18)}[kind]
        if rows[k]["station"] != rows[k - 1]["station"]:
            g += rng.uniform(300, 900)
        elif k == restart_idx:
            g += rng.uniform(1500, 3600)
        elif k in forced:
            g += rng.uniform(150, 900)
        elif kind == "move" and rng.random() < 0.03:
            g += rng.uniform(60, 400)
        gaps[k] = g
        t[k] = t[k - 1] + g
    t = np.round(t, 1)
    gaps[1:] = np.diff(t)
    running = gaps < 120
    session = np.cumsum(gaps > 120)
    return t, running, session, restart_idx


def make_path(rows):
    """Commanded waypoints [deg] (start at a home pose) and each row's index in it."""
    home = np.array([0.0, 0.0, 0.0, 0.0, 30.0, 0.0])
    path = [home]
    idx = []
    for r in rows:
        if r["kind"] == "move":
            path.append(r["q"])
        elif r["kind"] == "reapproach":
            i0 = idx[-1]
            d = np.sign(path[i0] - path[i0 - 1]); d[d == 0] = 1
            path.append(r["q"] - 3.0 * d)
            path.append(r["q"])
        idx.append(len(path) - 1)
    return np.array(path), np.array(idx)


def simulate(ctx, geom, effects, jitter):
    n = ctx.n
    dq = np.zeros((n, 6)); dv = np.zeros((n, 25)); lag = np.zeros((n, 3))
    Dtool = np.broadcast_to(np.eye(4), (n, 4, 4)).copy(); Dbase = Dtool.copy()
    for e in effects:
        if e.kind == "joint": dq += e.joint(ctx)
        elif e.kind == "length": dv += e.length(ctx)
        elif e.kind == "lag": lag += e.lag(ctx)
        elif e.kind == "tool": Dtool = Dtool @ e.tool(ctx)
        elif e.kind == "base": Dbase = e.base(ctx) @ Dbase
    F = kin.flange2base(ctx.q + dq, geom["pv"][None, :] + dv) @ jitter
    F[:, :3, 3] += lag
    T2B = F @ kin.sixdof(geom["tool"])[None] @ Dtool
    S = np.broadcast_to(geom["spheres_tool"], (n, 3, 3)).copy()
    for e in effects:
        if e.kind == "plate": S += e.plate(ctx, T2B)
    B2M = geom["base2meas"][ctx.station]
    T2M = B2M @ Dbase @ T2B
    P = kin.apply(T2M, S)
    for e in effects:
        if e.kind == "meas": P = e.meas(ctx, P, T2M)
    return P


def jacobian(ctx, geom, rows):
    """d(sphere centres)/d(25 MDH + tool 6 + 6 per station) at the true geometry, commanded joints, no effect."""
    q = ctx.q[rows]; st = ctx.station[rows]
    stations = sorted(set(ctx.station[:ctx.n_data].tolist()))
    P = 25 + 6 + 6 * len(stations)

    def model(x):
        pv = geom["pv"] + x[:25]
        F = kin.flange2base(q, pv)
        T = kin.sixdof(geom["tool"]) @ kin.sixdof(x[25:31])
        # one frame per station: its rows share the matrix
        per = {s: geom["base2meas"][s] @ kin.sixdof(x[31 + 6 * stations.index(s): 37 + 6 * stations.index(s)])
               for s in set(st.tolist())}
        B = np.stack([per[s] for s in st.tolist()])
        return kin.apply(B @ F @ T, np.broadcast_to(geom["spheres_tool"], (len(q), 3, 3))).reshape(-1)

    h = 1e-6
    J = np.empty((len(q) * 9, P))
    for i in range(P):
        x = np.zeros(P); x[i] = h
        J[:, i] = (model(x) - model(-x)) / (2 * h)
    return J


def leftover(J_cal, e_cal, J_ev, e_ev):
    """Residual of a linearised geometric fit (on the calibration rows) evaluated on other rows."""
    sc = np.linalg.norm(J_cal, axis=0); sc[sc == 0] = 1
    x, *_ = np.linalg.lstsq(J_cal / sc, e_cal, rcond=1e-9)
    return e_ev - (J_ev / sc) @ x


class Campaign:
    def __init__(self, spec, seed_seq, name):
        self.spec = spec
        self.name = name
        self.rng = np.random.default_rng(seed_seq)
        self.seed_entropy = seed_seq.entropy
        self.seed_key = list(seed_seq.spawn_key)

    def build(self):
        spec, rng = self.spec, self.rng
        robot = ROBOTS[spec.get("robot", "irb1200")]
        self.robot = robot
        spheres = random_plate(rng) if spec.get("plate") == "custom" else DEFAULT_PLATE.copy()
        self.spheres_nom = spheres
        pv_nom, pv_true, dv, tool = true_geometry(rng, robot)
        centre, stations = scene.make_stations(rng, robot, spec.get("stations", 1))
        self.stations = stations
        plate_centre = spheres.mean(0)
        rows, test_station = build_rows(rng, spec, robot, pv_nom, stations, plate_centre)
        n_data = spec["rows"]
        n = len(rows)
        t, running, session, restart_idx = timeline(rng, spec, rows, n_data)
        T, temp_info = scene.temperature(rng, t, running, spec.get("temp_profile", "room"))
        T = np.round(T, 2)
        path_deg, idx = make_path(rows)
        q_deg = np.array([r["q"] for r in rows])
        ctx = SimpleNamespace(robot=robot, pv_nom=pv_nom, n=n, n_data=n_data, q=q_deg * DEG, q_deg=q_deg,
                              path=path_deg * DEG, row_path_idx=idx, t=t, T=T, session=session,
                              restart_idx=restart_idx, station=np.array([r["station"] for r in rows]),
                              station_distance={i: s["distance_mm"] for i, s in enumerate(stations)})
        ctx.frames_nom = kin.link_frames(ctx.q, pv_nom)
        ctx.path_plate_centre = kin.apply(kin.flange2base(ctx.path, pv_nom), plate_centre[None, None, :])[:, 0]
        self.ctx, self.rows, self.temp_info, self.test_station = ctx, rows, temp_info, test_station
        self.geom = dict(pv=pv_true, pv_nom=pv_nom, dv=dv, tool=tool, spheres_tool=spheres,
                         base2meas=np.stack([s["base2meas"] for s in stations]))
        # sets
        data_idx = np.arange(n_data)
        uniq = [i for i in data_idx if rows[i]["kind"] == "move"]
        f = rng.uniform(0.27, 0.33)
        val = set(int(i) for i in rng.choice(uniq, int(round(f * len(uniq))), replace=False))
        role = []
        for i in range(n):
            if i >= n_data:
                role.append("test"); continue
            j = i
            while rows[j]["kind"] != "move":
                j -= 1
            role.append("validation" if j in val else "calibration")
        self.role = np.array(role)
        # repeatability jitter (per visit)
        rep = spec.get("rep", 0.0)
        jit = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
        if rep > 0:
            for i in range(n):
                if rows[i]["kind"] == "static":
                    jit[i] = jit[i - 1]
                else:
                    jit[i] = kin.sixdof(np.concatenate([rng.normal(0, rep, 3), rng.normal(0, rep / 100.0, 3)]))
        self.jitter = jit
        # missing spheres, gross rows
        status = [""] * n
        present = np.ones((n, 3), bool)
        pm = spec.get("missing", 0.0)
        for i in range(n_data):
            if i == restart_idx:
                continue
            if rng.random() < pm:
                k = int(rng.integers(0, 3)); present[i, k] = False
                status[i] = f"p{k}:{rng.choice(MISS_REASONS)}"
        for _ in range(spec.get("missing_all", 0)):
            i = int(rng.integers(5, n_data - 5))
            if i == restart_idx:
                continue
            present[i] = False
            status[i] = ";".join(f"p{k}:out_of_frame" for k in range(3))
        if restart_idx is not None:
            status[restart_idx] = "restart"
        self.status, self.present = status, present
        gross = []
        cand = [i for i in range(n_data) if present[i].all() and i != restart_idx]
        for i in rng.choice(cand, spec.get("gross", 0), replace=False):
            k = int(rng.integers(0, 3)); v = rng.normal(size=3); v /= np.linalg.norm(v)
            gross.append((int(i), k, v * rng.uniform(0.05, 1.0)))
        self.gross = gross
        # effects
        self.effects = []
        for e in spec.get("effects", []):
            self.effects.append(EFFECTS[e["type"]](rng, ctx, **e.get("opts", {})))
        self.noise_raw = rng.normal(size=(n, 3, 3))
        return self

    # ------------------------------------------------------------------ sizing
    def _cal_eval(self):
        n_data = self.ctx.n_data
        if self.spec.get("set", True):
            cal = np.where(self.role[:n_data] == "calibration")[0]
            ev = np.where(self.role[:n_data] == "validation")[0]
        else:
            cal = ev = np.arange(n_data)
        return cal, ev

    def _mask(self, rows):
        return np.repeat(self.present[rows], 3, axis=1).reshape(-1)

    def effect_leftover(self, e_all):
        cal, ev = self._cal_eval()
        if not hasattr(self, "_J"):
            self._J = jacobian(self.ctx, self.geom, np.arange(self.ctx.n_data))
        J = self._J.reshape(self.ctx.n_data, 9, -1)
        mc, me = self._mask(cal), self._mask(ev)
        r = leftover(J[cal].reshape(-1, J.shape[2])[mc], e_all[cal].reshape(-1)[mc],
                     J[ev].reshape(-1, J.shape[2])[me], e_all[ev].reshape(-1)[me])
        return float(np.sqrt(np.mean(r ** 2)))

    def size(self):
        spec = self.spec
        self.base_pts = simulate(self.ctx, self.geom, [], self.jitter)
        nojit = np.broadcast_to(np.eye(4), self.jitter.shape)
        p_nojit = simulate(self.ctx, self.geom, [], nojit)
        d = (self.base_pts - p_nojit)[: self.ctx.n_data]
        self.rep_rms = float(np.sqrt(np.mean(d ** 2)))
        los = spec.get("los", 1.0)
        unit = []
        for e in self.effects:
            e.scale = 1.0
            eu = simulate(self.ctx, self.geom, [e], self.jitter) - self.base_pts
            unit.append(self.effect_leftover(eu))
        sig = spec["noise"]
        if sig == "auto":   # noise from the effect with a fixed physical size
            i = next(i for i, e in enumerate(spec["effects"]) if e.get("fixed"))
            target_nu = unit[i] / spec["effects"][i]["ratio"]
            nu_instr = np.sqrt(max(target_nu ** 2 - self.rep_rms ** 2, 1e-12))
            sig = nu_instr / np.sqrt((2 + los ** 2) / 3)
            sig = float(np.clip(np.round(sig, 4), 0.002, 0.02))
        self.sigma_xy = sig
        self.sigma_los = sig * los
        self.nu_instr = sig * np.sqrt((2 + los ** 2) / 3)
        self.nu = float(np.sqrt(self.nu_instr ** 2 + self.rep_rms ** 2))
        for e, u, es in zip(self.effects, unit, spec.get("effects", [])):
            if es.get("fixed"):
                e.scale = 1.0
            else:
                e.scale = es["ratio"] * self.nu / u
        # final
        self.true_pts = simulate(self.ctx, self.geom, self.effects, self.jitter)
        self.e = self.true_pts - self.base_pts
        self.eff_stats = []
        for e in self.effects:
            ei = simulate(self.ctx, self.geom, [e], self.jitter) - self.base_pts
            lo = self.effect_leftover(ei)
            self.eff_stats.append(dict(rms_mm=lo, ratio=lo / self.nu,
                                       raw_rms_mm=float(np.sqrt(np.mean(ei[: self.ctx.n_data] ** 2))),
                                       max_abs_mm=float(np.max(np.abs(ei[: self.ctx.n_data])))))
        self.combined_leftover = self.effect_leftover(self.e) if self.effects else 0.0
        # measurements
        sd = np.array([self.sigma_xy, self.sigma_xy, self.sigma_los])
        self.meas = self.true_pts + self.noise_raw * sd
        for i, k, v in self.gross:
            self.meas[i, k] += v
        return self

    # ------------------------------------------------------------------ writing
    def write(self, root):
        spec, ctx, rows = self.spec, self.ctx, self.rows
        out = os.path.join(root, self.name)
        ds, key = os.path.join(out, "dataset"), os.path.join(out, "key")
        os.makedirs(ds, exist_ok=True); os.makedirs(key, exist_ok=True)
        n_data = ctx.n_data
        multi = len(self.stations) > 1
        has_set, has_t, has_T = spec.get("set", True), spec.get("t_s", True), spec.get("temp", False)
        has_status = any(self.status[:n_data])
        fmt_m = lambda x: f"{x:.5f}"
        mstr = [[("" if not self.present[i, k] else fmt_m(self.meas[i, k, c])) for k in range(3) for c in range(3)]
                for i in range(ctx.n)]
        pid0 = int(self.rng.integers(1, 400))
        self.pose_ids = np.arange(pid0, pid0 + ctx.n)
        hdr = ["pose_id"] + [f"q{j}" for j in range(1, 7)]
        if multi or spec.get("station_col"): hdr.append("station")
        if has_set: hdr.append("set")
        if has_t: hdr.append("t_s")
        if has_T: hdr.append("temp_c")
        hdr += [f"p{k}_{c}" for k in range(3) for c in "xyz"]
        if has_status: hdr.append("status")
        lines = [",".join(hdr)]
        for i in range(n_data):
            r = [str(self.pose_ids[i])] + [f"{x:.4f}" for x in ctx.q_deg[i]]
            if multi or spec.get("station_col"): r.append(str(ctx.station[i]))
            if has_set: r.append(self.role[i])
            if has_t: r.append(f"{ctx.t[i]:.1f}")
            if has_T: r.append(f"{ctx.T[i]:.2f}")
            r += mstr[i]
            if has_status: r.append(self.status[i])
            lines.append(",".join(r))
        open(os.path.join(ds, "poses.csv"), "w").write("\n".join(lines) + "\n")
        # dataset.toml
        tl = ["schema_version = 1"]
        if not self.robot.get("inline"):
            tl.append(f'robot = "{self.robot["name"]}"')
        tl.append(f'provenance = "held-out batch B, campaign {self.name}: sphere-centre measurements with an optical '
                  f'instrument on a stand, {len(self.stations)} placement(s), rows in measurement order"')
        tl.append("")
        if self.robot.get("inline"):
            tl += [toml_robot(self.robot), ""]
        S = self.spheres_nom
        tl += ["[plate]", "sphere_diameter_mm = 25.4",
               "spheres_mm = [" + ", ".join("[" + ", ".join(f"{x:.2f}" for x in s) + "]" for s in S) + "]"]
        stated = spec.get("stated", "none")
        self.stated_mm = None
        if stated == "true":
            self.stated_mm = round(float(self.nu_instr), 5)
        elif stated == "half":
            self.stated_mm = round(float(self.nu_instr) / 2, 5)
        if self.stated_mm is not None:
            tl += ["", "[noise]", f"position_mm = {self.stated_mm}"]
        open(os.path.join(ds, "dataset.toml"), "w").write("\n".join(tl) + "\n")
        # sequence.csv
        sh = (["pose_id"] + [f"q{j}" for j in range(1, 7)] + ["station", "t_s", "temp_c", "role"]
              + [f"m{k}_{c}" for k in range(3) for c in "xyz"] + [f"t{k}_{c}" for k in range(3) for c in "xyz"]
              + [f"e{k}_{c}" for k in range(3) for c in "xyz"])
        sl = [",".join(sh)]
        for i in range(ctx.n):
            role = self.role[i] if (has_set or i >= n_data) else "data"
            r = ([str(self.pose_ids[i])] + [f"{x:.4f}" for x in ctx.q_deg[i]]
                 + [str(ctx.station[i]), f"{ctx.t[i]:.1f}", f"{ctx.T[i]:.2f}", role] + mstr[i]
                 + [f"{x:.8f}" for x in self.true_pts[i].reshape(-1)] + [f"{x:.8f}" for x in self.e[i].reshape(-1)])
            sl.append(",".join(r))
        open(os.path.join(key, "sequence.csv"), "w").write("\n".join(sl) + "\n")
        # key.json
        effects = []
        for e, st in zip(self.effects, self.eff_stats):
            k = e.key()
            k.update(st)
            k["channel"] = k["channel"]
            effects.append(k)
        rep_counts = {}
        for r in rows[:n_data]:
            rep_counts[r["kind"]] = rep_counts.get(r["kind"], 0) + 1
        noise = dict(model="independent Gaussian per sphere-centre coordinate in each station's frame (z = line of sight)",
                     sigma_xy_mm=self.sigma_xy, sigma_los_mm=self.sigma_los,
                     instrument_rms_per_coordinate_mm=self.nu_instr,
                     repeatability_flange_sigma_mm=spec.get("rep", 0.0),
                     repeatability_rms_per_coordinate_mm=self.rep_rms,
                     total_rms_per_coordinate_mm=self.nu, stated_position_mm=self.stated_mm,
                     stated=spec.get("stated", "none"),
                     repeats=spec.get("repeats", "none"), repeat_rows=n_data - rep_counts.get("move", 0))
        notes = list(spec.get("notes", []))
        if self.gross:
            notes.append("gross rows (sphere off by the stated amount, in the measurement only): " + "; ".join(
                f"pose_id {self.pose_ids[i]} p{k} {np.linalg.norm(v):.3f} mm" for i, k, v in self.gross))
        if ctx.restart_idx is not None:
            notes.append(f"status=restart on pose_id {self.pose_ids[ctx.restart_idx]} after a pause of "
                         f"{ctx.t[ctx.restart_idx] - ctx.t[ctx.restart_idx - 1]:.0f} s")
        if self.effects:
            notes.append(f"combined geometric-fit leftover of all effects: {self.combined_leftover:.5f} mm per coordinate "
                         f"({self.combined_leftover / self.nu:.2f} x noise)")
        notes.append(f"test rows measured at station {self.test_station}")
        for e in self.effects:
            if hasattr(e, "idx") and e.idx is not None:
                notes.append(f"{type(e).__name__} change at pose_id {self.pose_ids[e.idx]}")
        kj = dict(schema_version=1, name=self.name, category=spec["category"],
                  expected_names=sorted({e.family for e in self.effects if e.family}),
                  effects=effects, noise=noise,
                  seed=dict(master=int(self.seed_entropy), spawn_key=self.seed_key),
                  notes=notes, label=spec["label"])
        json.dump(_clean(kj), open(os.path.join(key, "key.json"), "w"), indent=1)
        # truth geometry for the checks
        geo = dict(robot=self.robot["name"], pv_nominal=list(self.geom["pv_nom"]), pv_true=list(self.geom["pv"]),
                   parameter_names=kin.PARAM_NAMES, units="mm and rad",
                   tool2flange_sixdof=list(self.geom["tool"]), spheres_tool_mm=self.spheres_nom.tolist(),
                   base2meas=[s["base2meas"].tolist() for s in self.stations],
                   stations=[dict(distance_mm=s["distance_mm"], azimuth_deg=s["azimuth_deg"],
                                  elevation_deg=s["elevation_deg"]) for s in self.stations],
                   flange_jitter_sixdof=[list(kin.to_sixdof(j)) for j in self.jitter],
                   temperature=self.temp_info)
        json.dump(_clean(geo), open(os.path.join(key, "geometry.json"), "w"))
        return dict(name=self.name, category=spec["category"], rows=n_data,
                    noise=self._noise_str(), channels=";".join(c for c in ["station" if multi else "", "set" if has_set else "",
                                                                       "t_s" if has_t else "", "temp_c" if has_T else "",
                                                                       "status" if has_status else ""] if c),
                    stations=len(self.stations),
                    repeats=f"{spec.get('repeats', 'none')} {n_data - rep_counts.get('move', 0)}" if spec.get("repeats", "none") != "none" else "none")

    def _noise_str(self):
        s = f"{self.sigma_xy:.4f}" if self.spec.get("los", 1) == 1 else f"{self.sigma_xy:.4f}/{self.sigma_los:.4f}(los)"
        if self.spec.get("rep", 0):
            s += f" +repeatability {self.spec['rep']:.3f}"
        return s


def _clean(o):
    if isinstance(o, dict):
        return {str(k): _clean(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_clean(v) for v in o]
    if isinstance(o, np.ndarray):
        return _clean(o.tolist())
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.bool_,)):
        return bool(o)
    return o
