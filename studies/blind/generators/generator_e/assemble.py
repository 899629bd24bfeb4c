"""Campaign assembly: truth, stations, pose plan, time/temperature, effects, noise, outputs."""
from __future__ import annotations

import numpy as np

import cell
import effects as fx
import kin

DEG = kin.DEG

PLATES = {
    "std": np.array([[60.0, 0.0, 50.0], [-60.0, 0.0, 50.0], [-20.52, 56.38, 50.0]]),
    "alt": np.array([[55.0, 0.0, 45.0], [-27.5, 47.63, 45.0], [-27.5, -47.63, 45.0]]),
}
Q_HOME_DEG = np.array([0.0, 0.0, 0.0, 0.0, 30.0, 0.0])


class Truth:
    def __init__(self, spec, rng):
        self.robot = spec["robot"]
        self.params = kin.perturb_geometry(self.robot, rng)
        t = np.clip(rng.normal(0, 0.6, 3), -1.5, 1.5)
        r = np.clip(rng.normal(0, 0.12, 3), -0.3, 0.3) * DEG
        self.T_tool = kin.make_T(kin.rotvec_to_R(r), t)
        self.tool_xyzrv = np.concatenate([t, r])
        self.spheres_nominal = PLATES[spec.get("plate", "std")]
        self.spheres_tool = self.spheres_nominal.copy()  # the nominal plate frame is the flange
        self.stations = []
        for (az, off, el, dist, roll) in spec["stations"]:
            self.stations.append(cell.make_station(self.robot, rng, az, off, el, dist, roll))
        rob = kin.ROBOTS[self.robot]
        self.qmin = np.array(rob["q_min"], float)
        self.qmax = np.array(rob["q_max"], float)

    def P(self, qdeg, st_idx, params=None):
        q = np.atleast_2d(qdeg) * DEG
        B = np.stack([self.stations[s]["base2meas"] for s in np.broadcast_to(st_idx, (len(q),))])
        return kin.spheres_meas(self.params if params is None else params, q, B, self.T_tool, self.spheres_tool)

    def valid(self, qdeg, s, inst):
        qdeg = np.atleast_2d(qdeg)
        q = qdeg * DEG
        fr = kin.fk_frames(self.params, q)
        Tm = self.stations[s]["base2meas"] @ fr[:, 6] @ self.T_tool
        P = np.einsum("nij,kj->nki", Tm[:, :3, :3], self.spheres_tool) + Tm[:, None, :3, 3]
        ok = cell.view_ok(P, Tm, inst, frames=fr)
        ok &= np.all((qdeg > self.qmin + 5) & (qdeg < self.qmax - 5), axis=1)
        return ok, P, Tm


def build_pool(truth, s, inst, rng, n=30000):
    """Valid poses (deg, rounded to 1e-4) for station s, found by rejection sampling in joint space."""
    az = float(np.degrees(np.arctan2(truth.stations[s]["target"][1], truth.stations[s]["target"][0])))
    lo = np.array([az - 45, -45, -95, -170, -115, -200])
    hi = np.array([az + 45, 80, 45, 170, 115, 200])
    lo, hi = np.maximum(lo, truth.qmin + 6), np.minimum(hi, truth.qmax - 6)
    keep = []
    for _ in range(6):
        q = np.round(lo + (hi - lo) * rng.random((n, 6)), 4)
        ok, P, _ = truth.valid(q, s, inst)
        keep.append(q[ok])
        if sum(len(k) for k in keep) > 1500:
            break
    pool = np.concatenate(keep)
    cen = truth.P(pool, s).mean(axis=1)
    return pool, cen


def plan_block(kind, count, s, truth, inst, pool, cen, used, rng, opts):
    """Commanded joint angles (deg) of one protocol block; returns (q (count,6), pair ids or None)."""
    free = np.flatnonzero(~used)
    if kind == "random":
        idx = rng.choice(free, count, replace=False)
        used[idx] = True
        return pool[idx], None
    if kind == "grid":
        d = truth.stations[s]["dist"]
        nz = 3
        nxy = int(np.ceil(np.sqrt(count / nz)))
        tx, ty = np.tan(inst["hfov_deg"] * DEG), np.tan(inst["hfov_deg"] * 0.75 * DEG)
        xs = np.linspace(-0.6, 0.6, nxy)
        ys = np.linspace(-0.55, 0.55, nxy)
        zs = np.linspace(d - 140, d + 140, nz)
        nodes = []
        for iz, z in enumerate(zs):
            for iy, y in enumerate(ys):
                row = [(x * tx * z, y * ty * z, z) for x in xs]
                nodes += row if (iy + iz) % 2 == 0 else row[::-1]
        nodes = np.array(nodes)[:count]
        out = []
        for nd in nodes:
            f = np.flatnonzero(~used)
            k = f[np.argmin(np.linalg.norm(cen[f] - nd, axis=1))]
            used[k] = True
            out.append(pool[k])
        return np.array(out), None
    if kind == "repeats":
        K = opts.get("distinct", 20)
        idx = rng.choice(free, K, replace=False)
        used[idx] = True
        seq = []
        while len(seq) < count:
            seq += list(rng.permutation(idx)) if opts.get("interleave", True) else [i for i in idx for _ in range(opts.get("reps", 3))]
        return pool[np.array(seq[:count])], None
    if kind == "sweeps":
        joints = opts["joints"]
        out = []
        while len(out) < count:
            k = rng.choice(np.flatnonzero(~used))
            used[k] = True
            h = pool[k].copy()
            for j in joints:
                A = opts.get("amp_deg", 60)
                steps = np.concatenate([np.linspace(-A, A, 9), np.linspace(A, -A, 9)[1:]])
                for st in steps:
                    qq = h.copy()
                    qq[j - 1] = np.round(h[j - 1] + st, 4)
                    if truth.valid(qq, s, inst)[0][0]:
                        out.append(qq)
            # a few random poses in between sweeps
            for _ in range(opts.get("random_between", 6)):
                f = np.flatnonzero(~used)
                kk = rng.choice(f)
                used[kk] = True
                out.append(pool[kk])
        return np.array(out[:count]), None
    if kind == "pairs":
        out, pairs = [], []
        pid = opts.get("pair0", 1)
        while len(out) < count:
            k = rng.choice(np.flatnonzero(~used))
            used[k] = True
            a = pool[k]
            for _ in range(50):
                b = np.round(a + rng.normal(0, opts.get("step_deg", 8), 6), 4)
                if truth.valid(b, s, inst)[0][0]:
                    out += [a, b]
                    pairs += [pid, pid]
                    pid += 1
                    break
        return np.array(out[:count]), np.array(pairs[:count])
    raise ValueError(kind)


def temperature_fn(sc):
    if sc is None:
        return lambda t: np.full_like(np.asarray(t, float), 21.0)
    kind = sc["kind"]
    T0 = sc["T0"]
    if kind == "warmup":
        return lambda t: T0 + sc["rise"] * (1 - np.exp(-np.asarray(t, float) / sc["tau"])) + sc.get("slope_per_h", 0) * np.asarray(t) / 3600
    if kind == "wave":
        return lambda t: T0 + sc["amp"] * np.sin(2 * np.pi * np.asarray(t, float) / sc["period"] + sc.get("phase", 0)) + sc.get("slope_per_h", 0) * np.asarray(t) / 3600
    if kind == "door":  # warm-up, then a door opens at t_open and the cell cools towards T_out
        def f(t):
            t = np.asarray(t, float)
            base = T0 + sc["rise"] * (1 - np.exp(-t / sc["tau"]))
            cool = np.where(t > sc["t_open"], (sc["T_out"] - base) * (1 - np.exp(-(t - sc["t_open"]) / sc["tau2"])), 0.0)
            return base + cool
        return f
    raise ValueError(kind)


class Ctx:
    pass


def assemble(spec, seed, index):
    rng_geo = np.random.default_rng([seed, index, 1])
    rng_plan = np.random.default_rng([seed, index, 2])
    rng_noise = np.random.default_rng([seed, index, 3])
    rng_time = np.random.default_rng([seed, index, 4])
    truth = Truth(spec, rng_geo)
    inst = dict(hfov_deg=spec["hfov_deg"], max_tilt_deg=spec.get("max_tilt_deg", 45.0))
    nst = len(truth.stations)
    pools = []
    for s in range(nst):
        d = truth.stations[s]["dist"]
        inst_s = dict(inst, depth_mm=(max(600.0, d - 320), min(1400.0, d + 320)))
        pools.append((inst_s,) + build_pool(truth, s, inst_s, rng_plan) + (np.zeros(0, bool),))
    pools = [(a, b, c, np.zeros(len(b), bool)) for (a, b, c, _) in pools]

    # ---- plan: dataset blocks then the test block
    Q, ST, PAIR, BLOCK = [], [], [], []
    for bi, blk in enumerate(spec["blocks"]):
        kind, count, s = blk[0], blk[1], blk[2]
        opts = blk[3] if len(blk) > 3 else {}
        inst_s, pool, cen, used = pools[s]
        if kind == "pairs":
            opts = dict(opts, pair0=1 + max([p for p in PAIR if p is not None], default=0))
        q, pr = plan_block(kind, count, s, truth, inst_s, pool, cen, used, rng_plan, opts)
        Q.append(q)
        ST += [s] * len(q)
        PAIR += list(pr) if pr is not None else [None] * len(q)
        BLOCK += [bi] * len(q)
    n_data = sum(len(q) for q in Q)
    s_test = spec.get("test_station", nst - 1)
    tk = spec.get("test_kind", ("random", {}))
    inst_s, pool, cen, used = pools[s_test]
    opts = dict(tk[1])
    if tk[0] == "pairs":
        opts["pair0"] = 1 + max([p for p in PAIR if p is not None], default=0)
    qt, prt = plan_block(tk[0], 60, s_test, truth, inst_s, pool, cen, used, rng_plan, opts)
    Q.append(qt)
    ST += [s_test] * 60
    PAIR += list(prt) if prt is not None else [None] * 60
    qdeg = np.round(np.concatenate(Q), 4)
    st = np.array(ST)
    n = len(qdeg)
    role = np.array(["data"] * n_data + ["test"] * 60, dtype=object)

    # ---- time: moves at a joint speed, dwell, pauses between sessions, camera moves between stations
    tm = spec.get("timing", {})
    speed, dwell = tm.get("speed_deg_s", 45.0), tm.get("dwell_s", 3.0)
    pauses = dict(spec.get("pauses", {}))  # row index (first row after the pause) -> seconds
    t = np.zeros(n)
    t[0] = 20.0 + 10 * rng_time.random()
    prev = Q_HOME_DEG
    session = np.zeros(n, int)
    for i in range(n):
        mv = np.max(np.abs(qdeg[i] - prev)) / speed + 1.2
        if i > 0:
            t[i] = t[i - 1] + mv + dwell + rng_time.random() * 0.8
            session[i] = session[i - 1]
            if i in pauses:
                t[i] += pauses[i]
                session[i] += 1
            elif st[i] != st[i - 1]:
                t[i] += 600 + 300 * rng_time.random()
        prev = qdeg[i]
    t = np.round(t, 1)
    temp_fn = temperature_fn(spec.get("temperature"))
    temp_true = temp_fn(t)
    temp_rec = np.round(temp_true + rng_time.normal(0, 0.03, n), 2)

    # ---- roles
    if spec.get("set", False):
        fval = spec.get("val_fraction", 0.25)
        nv = int(round(fval * n_data))
        vidx = rng_time.choice(n_data, nv, replace=False)
        role[:n_data] = "calibration"
        role[vidx] = "validation"

    # ---- effects
    ctx = Ctx()
    ctx.n, ctx.robot, ctx.params, ctx.T_tool = n, truth.robot, truth.params, truth.T_tool
    ctx.q, ctx.q_home, ctx.t, ctx.temp_fn, ctx.station, ctx.session = qdeg * DEG, Q_HOME_DEG * DEG, t, temp_fn, st, session
    session_start = {k: float(t[np.argmax(session == k)]) for k in range(session.max() + 1)}
    effs = []
    for kind, kw in spec.get("effects", []):
        kw = dict(kw)
        if isinstance(kw.get("t_step"), str):
            kw["t_step"] = session_start[int(kw["t_step"].replace("session", ""))]
        effs.append(fx.build((kind, kw)))

    B = np.stack([truth.stations[s]["base2meas"] for s in st])

    def chain(mods):
        q = ctx.q + mods.dq
        p = kin.copy_params(truth.params)
        pr = {k: np.broadcast_to(v, (n, 6)).copy() for k, v in p.items()}
        for k, v in mods.dparams.items():
            pr[k] = pr[k] + v
        T = mods.meas_post @ B @ mods.base_pre @ kin.flange2base(pr, q) @ truth.T_tool
        s_tool = truth.spheres_tool[None] + mods.dsph
        P = np.einsum("nij,nkj->nki", T[:, :3, :3], s_tool) + T[:, None, :3, 3]
        for f in mods.maps:
            P = f(P)
        return P

    P0 = chain(fx.Mods(n))
    allm = fx.Mods(n)
    eff_keys = []
    for ef in effs:
        m = ef.mods(ctx)
        Pk = chain(m)
        ek = Pk - P0
        k = ef.key()
        k["rms_mm"] = round(float(np.sqrt(np.mean(np.sum(ek[:n_data] ** 2, axis=2)))), 4)
        k["max_mm"] = round(float(np.max(np.linalg.norm(ek[:n_data], axis=2))), 4)
        eff_keys.append(k)
        allm.add(m)
    P1 = chain(allm)
    E = P1 - P0

    # ---- noise, outliers, missing spheres, failed rows
    nm = spec["noise"]
    M = P1 + cell.draw_noise(P1, nm, rng_noise)
    status = np.array([""] * n, dtype=object)
    n_out = 0
    if nm.get("p_outlier", 0) > 0:
        hit = rng_noise.random((n, 3)) < nm["p_outlier"]
        hit[n_data:] = False
        for i, k in zip(*np.nonzero(hit)):
            d = rng_noise.normal(size=3)
            M[i, k] += d / np.linalg.norm(d) * rng_noise.uniform(0.3, 1.5)
            n_out += 1
    fr_tool = None
    if nm.get("p_missing", 0) > 0 or nm.get("p_fail", 0) > 0:
        Tm = B @ kin.flange2base(truth.params, ctx.q) @ truth.T_tool
        tilt = cell.tilt_deg(P1, Tm)
        tx = np.tan(inst["hfov_deg"] * DEG)
        for i in range(n):
            r = rng_noise.random()
            if r < nm.get("p_fail", 0):
                M[i] = np.nan
                status[i] = rng_noise.choice(["no_detection:camera_timeout", "no_detection:robot_not_in_position", "p0:occluded;p1:occluded;p2:occluded"])
            elif r < nm.get("p_fail", 0) + nm.get("p_missing", 0):
                edge = np.abs(P1[i, :, 0] / P1[i, :, 2]) / tx
                if edge.max() > 0.8:
                    k = int(np.argmax(edge))
                    why = "out_of_frame"
                elif tilt[i] > 30:
                    k = int(np.argmax(P1[i, :, 2]))
                    why = "occluded"
                else:
                    k = int(rng_noise.integers(3))
                    why = "glare"
                M[i, k] = np.nan
                status[i] = f"p{k}:{why}"
    M = np.round(M, 4)
    sig_pc = cell.per_coordinate_sigma(P1[:n_data], nm)
    return dict(
        truth=truth, qdeg=qdeg, station=st, pair=PAIR, t=t, temp=temp_rec, role=role, status=status,
        M=M, T=P1, E=E, P0=P0, n_data=n_data, effects=eff_keys, sigma_pc=sig_pc, n_outliers=n_out,
        session=session, session_start=session_start,
    )
