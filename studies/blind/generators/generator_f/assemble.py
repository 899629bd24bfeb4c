"""One campaign from its spec: true geometry, stations, pose plan, time, effects, instrument, roles.

Random streams of campaign number ``idx``: ``default_rng([seed, idx, k])``, k = 1 geometry and stations, 2 pose
plan, 3 instrument noise and bursts, 4 time, temperature and roles, 5 effects.
"""
from __future__ import annotations

import numpy as np

import cell
import effects as fx
import instrument
import kin
import plan
from campaigns import STATIONS as STATIONS_BY_NAME

V_MAX_DEG_S = np.array([90.0, 70.0, 80.0, 150.0, 150.0, 200.0])  # the slowest joint sets a move's time


def _stream(seed, idx, k):
    return np.random.default_rng([seed, idx, k])


def _stations(rng, specs):
    out = []
    for s in specs:
        tgt = np.array(s["target"]) + rng.normal(0, 0.02, 3)
        out.append(cell.Station(tgt, s["distance"] + rng.uniform(-0.03, 0.03), s["azimuth"] + rng.uniform(-4, 4),
                                s["elevation"] + rng.uniform(-3, 3), rng.uniform(-4, 4)))
    return out


def _seeds(station):
    q1 = np.arctan2(station.target[1], station.target[0])
    base = np.array([[0, 0.0, 0.0, 0, 0.6, 0], [0, 0.35, -0.2, 0, 0.7, 0], [0, 0.1, 0.1, 1.4, -0.8, 0],
                     [0, -0.3, -0.5, 0, 1.0, 0], [0, 0.2, -0.9, -1.2, 0.9, 1.0], [0, 0.6, 0.3, 0.3, 0.4, -1.0]])
    base[:, 0] = q1
    return base


def _true_tool(rng):
    v = np.concatenate([np.clip(rng.normal(0, 0.4e-3, 3), -1e-3, 1e-3), np.clip(rng.normal(0, 0.1, 3), -0.25, 0.25) * kin.DEG])
    return kin.T_from_xyzrv(v), v


def _plan(rng, spec, stations, nominal):
    """Commanded joints (deg, 1e-4 rounded) of the dataset rows then the test rows, station and repeat flags."""
    n_data, n_test = spec["rows"], spec["test_rows"]
    shares = np.array(spec.get("station_shares", [1.0] * len(stations)), float)
    per = np.floor(shares / shares.sum() * n_data).astype(int)
    per[-1] += n_data - per.sum()
    rep_frac = spec.get("repeats", 0.0)
    Q, st, rep = [], [], []
    for s, (station, n_s) in enumerate(zip(stations, per)):
        n_rep = int(round(rep_frac * n_s / 2))
        n_uniq = n_s - n_rep
        q = plan.sample(rng, nominal, station, n_uniq, seeds=_seeds(station), depth=spec.get("depth", (0.62, 1.2)))
        q = q[plan.order(rng, q, spec.get("order", "random"))]
        twice = set(rng.choice(n_uniq, n_rep, replace=False).tolist()) if n_rep else set()
        for i in range(n_uniq):
            Q.append(q[i]), st.append(s), rep.append(False)
            if i in twice:
                Q.append(q[i]), st.append(s), rep.append(True)
    last = len(stations) - 1
    qt = plan.sample(rng, nominal, stations[last], n_test, seeds=_seeds(stations[last]), depth=spec.get("depth", (0.62, 1.2)))
    qt = qt[plan.order(rng, qt, spec.get("test_order", "random"))]
    for q in qt:
        Q.append(q), st.append(last), rep.append(False)
    qdeg = np.round(np.array(Q) / kin.DEG, 4)
    return qdeg, np.array(st), np.array(rep)


def _times(rng, spec, qdeg, st, rep, n_data):
    """Time stamps [s]: each move lasts its slowest joint at the campaign's speed plus acceleration, settling and the
    exposure; a repeat only the settling; a station change 400-900 s, a new session 0.5-3 h, the test rows follow
    after 60-300 s. Returns t (N,) and the rows starting a session."""
    n = len(qdeg)
    speed = rng.uniform(0.25, 0.5)
    dwell = rng.uniform(1.5, 3.0)
    sess_rows = sorted(int(round(fx.draw(rng, f) * n_data)) for f in spec.get("sessions_at", []))
    t = np.zeros(n)
    t[0] = round(rng.uniform(5, 60), 1)
    for i in range(1, n):
        if rep[i]:
            dt = dwell + 0.5 + rng.uniform(0, 0.3)
        else:
            dt = np.max(np.abs(qdeg[i] - qdeg[i - 1]) / (V_MAX_DEG_S * speed)) + 0.6 + dwell + 0.4 + rng.uniform(0, 0.4)
        if st[i] != st[i - 1]:
            dt += rng.uniform(400, 900)
        if i in sess_rows:
            dt += rng.uniform(1800, 10800)
        if i == n_data:
            dt += rng.uniform(60, 300)
        t[i] = t[i - 1] + dt
    return np.round(t, 1), sess_rows


def _temperature(rng, t):
    """Room temperature as the instrument's probe reads it [deg C] (no effect is driven by it): a slow daily swing,
    a wander, 0.03 K sensor noise, 0.01 K resolution."""
    T0 = rng.uniform(19.5, 23.0)
    per = rng.uniform(5, 9) * 3600
    walk = np.cumsum(rng.normal(0, 0.004, len(t)))
    T = T0 + 0.5 * np.sin(2 * np.pi * t / per + rng.uniform(0, 2 * np.pi)) + walk + rng.normal(0, 0.03, len(t))
    return np.round(T, 2)


def centres(params, Q, B, base, tool, spheres):
    """Sphere centres (n, 3, 3) [m] in the measurement frame: B_i . base_i . flange2base(params, Q_i) . tool_i . s_k."""
    T = B @ base @ kin.flange2base(params, Q) @ tool
    return np.einsum("nij,kj->nki", T[:, :3, :3], spheres) + T[:, None, :3, 3]


def assemble(spec, seed, idx):
    rg, rp, rn, rt, re = (_stream(seed, idx, k) for k in range(1, 6))
    params = kin.perturbed(rg)
    T_tool, tool_v = _true_tool(rg)
    stations = _stations(rg, [STATIONS_BY_NAME[x] for x in spec["stations"]])
    stated = None
    if spec.get("robot") == "chain":  # the user's mass properties: about 8 % and 8 mm off the true ones
        stated = [(f, m * (1 + rg.normal(0, 0.08)), c + rg.normal(0, 0.008, 3)) for f, m, c in kin.BODIES]
    qdeg, st, rep = _plan(rp, spec, stations, kin.NOMINAL)
    n_data = spec["rows"]
    N = len(qdeg)
    t, sess_rows = _times(rt, spec, qdeg, st, rep, n_data)
    temp = _temperature(rt, t) if spec.get("temp_c") else None
    Q = qdeg * kin.DEG
    F = kin.frames(params, Q)
    pose_id = np.arange(1, N + 1) + spec.get("pose_id_offset", 0)
    ctx = fx.Ctx(Q=Q, F=F, t=t, station=st, pose_id=pose_id, n_data=n_data, stations=stations, bodies=kin.BODIES,
                 session_start_rows=sess_rows)

    effs = [fx.make(e["kind"], e, re, ctx) for e in spec.get("effects", [])]
    B0 = np.stack([stations[s].base2meas for s in st])
    I = np.broadcast_to(np.eye(4), (N, 4, 4))
    S = kin.SPHERES_FLANGE

    def chain(sel):
        dq = sum((e.dq for e in sel if e.dq is not None), np.zeros((N, 6)))
        meas, base, tool = I.copy(), I.copy(), I.copy()
        for e in sel:
            if e.meas is not None:
                meas = e.meas @ meas
            if e.base is not None:
                base = e.base @ base
            if e.tool is not None:
                tool = tool @ e.tool
        return centres(params, Q + dq, meas @ B0, base, T_tool[None] @ tool, S)

    P0 = chain([])
    P = chain(effs)
    E = P - P0
    for e in effs:
        Ei = chain([e]) - P0
        nrm = np.linalg.norm(Ei, axis=2)
        e.key["rms_mm"] = round(float(np.sqrt(np.mean(nrm[:n_data] ** 2)) * 1e3), 5)
        e.key["max_mm"] = round(float(nrm[:n_data].max() * 1e3), 5)
        e.key["test_rms_mm"] = round(float(np.sqrt(np.mean(nrm[n_data:] ** 2)) * 1e3), 5)

    # the instrument
    nz = spec["noise"]
    M = P.copy()
    for s, station in enumerate(stations):
        sel = st == s
        M[sel] += cell.noise(rn, P[sel], station, nz["sigma_lat_mm"] * 1e-3, nz["los_factor"], power=nz.get("power", 1.0))
    noise_only = M - P
    sigma_pc = float(np.sqrt(np.mean(noise_only[:n_data] ** 2)))
    status = [""] * N
    bursts = []
    for b in spec.get("bursts", []):
        bursts.append(_burst(b, rn, spec, stations, st, P, M, status, pose_id, t, n_data))
    for _ in range(spec.get("gross", 0)):
        i = int(rn.integers(5, n_data - 5))
        k = int(rn.integers(3))
        d = rn.normal(size=3)
        M[i, k] += d / np.linalg.norm(d) * rn.uniform(0.3, 1.2) * 1e-3
        bursts.append(dict(kind="gross", rows=[i + 1], pose_ids=[int(pose_id[i])], t_s=[float(t[i])], sphere=k,
                           description="one sphere matched to a wrong blob: 0.3-1.2 mm off"))
    pm = spec.get("p_missing", 0.0)
    if pm:
        for i in range(N):
            if status[i] or rep[i]:
                continue
            if rn.uniform() < pm:
                k = int(rn.integers(3))
                M[i, k] = np.nan
                status[i] = f"p{k}:{['occluded', 'out_of_focus', 'glare'][int(rn.integers(3))]}"

    # roles
    mode = spec.get("set")
    role = np.array(["data"] * n_data + ["test"] * (N - n_data), dtype=object)
    if mode == "tail":
        frac = rt.uniform(0.2, 0.3)
        role[:n_data] = "calibration"
        role[int(round(n_data * (1 - frac))):n_data] = "validation"
    elif mode == "random":
        role[:n_data] = "calibration"
        role[rt.choice(n_data, int(round(0.2 * n_data)), replace=False)] = "validation"

    session = None
    if spec.get("session_column"):
        session = np.empty(N, dtype=object)
        k = 0
        for i in range(N):
            if i in sess_rows:
                k += 1
            session[i] = spec["session_names"][k]
    return dict(params=params, tool_v=tool_v, T_tool=T_tool, stations=stations, qdeg=qdeg, station=st, repeat=rep,
                t=t, temp=temp, pose_id=pose_id, n_data=n_data, P=P, P0=P0, E=E, M=M, status=status, role=role,
                session=session, stated_bodies=stated, effects=[e.key for e in effs], bursts=bursts, sigma_pc=sigma_pc, sess_rows=sess_rows)


def _burst(b, rng, spec, stations, st, P, M, status, pose_id, t, n_data):
    """A burst of consecutive bad rows (the instrument's fault): ``glare`` or ``vibration``, in place on M."""
    L = fx.draw(rng, b["length"])
    r0 = int(round(fx.draw(rng, b["at"]) * n_data))
    r0 = min(max(r0, 3), n_data - L - 2)
    rows = list(range(r0, r0 + L))
    rec = dict(kind=b["kind"], rows=[r + 1 for r in rows], pose_ids=[int(pose_id[r]) for r in rows],
               t_s=[float(t[r]) for r in rows])
    noise = M - P
    if b["kind"] == "glare":
        k = int(rng.integers(3))
        shift = fx.draw(rng, b["shift_px"])
        direction = rng.uniform(0, 2 * np.pi)
        lost = []
        for r in rows:
            s = stations[st[r]]
            if rng.uniform() < b.get("p_lost", 0.0):
                M[r, k] = np.nan
                status[r] = f"p{k}:glare"
                lost.append(r + 1)
                continue
            sh = shift * rng.uniform(0.6, 1.3)
            M[r, k] = instrument.glare(s, P[r, k], sh, direction + rng.normal(0, 0.3)) + noise[r, k]
        dev = np.linalg.norm(M[rows, k] - P[rows, k], axis=1)
        rec.update(sphere=k, shift_px=round(shift, 4), direction_rad=round(direction, 4), rows_lost=lost,
                   error_mm=[round(float(x) * 1e3, 4) if np.isfinite(x) else None for x in dev],
                   description=f"a reflection (a window behind the robot) sits on sphere p{k}'s rim in the left image: its "
                               f"centre is pulled ~{shift:.2f} px, the triangulated centre moves mostly along the line "
                               f"of sight; rows {rows[0] + 1}..{rows[-1] + 1}")
    elif b["kind"] == "vibration":
        amp = fx.draw(rng, b["amp_mm"]) * 1e-3
        amp_r = fx.draw(rng, b["amp_deg"]) * kin.DEG
        f = fx.draw(rng, b["freq_hz"])
        dts = fx.draw(rng, b["desync_ms"]) * 1e-3
        ax_t = fx._unit(rng)
        ax_r = fx._unit(rng)
        errs = []
        for r in rows:
            s = stations[st[r]]
            decay = rng.uniform(0.5, 1.0)
            M[r] = instrument.vibration(s, P[r], amp * decay, amp_r * decay, f, dts, rng.uniform(0, 2 * np.pi), ax_t,
                                        ax_r) + noise[r]
            errs.append(round(float(np.sqrt(np.mean(np.sum((M[r] - P[r]) ** 2, axis=1)))) * 1e3, 4))
        rec.update(amp_mm=round(amp * 1e3, 5), amp_deg=round(amp_r / kin.DEG, 5), freq_hz=round(f, 3),
                   desync_ms=round(dts * 1e3, 3), rms_error_mm=errs,
                   description=f"the floor shakes (a truck at the loading door): the plate rings at {f:.1f} Hz with "
                               f"{amp * 1e3:.3f} mm / {amp_r / kin.DEG:.4f} deg amplitude while the two cameras expose "
                               f"{dts * 1e3:.1f} ms apart; each row's centres triangulated from the two displaced views; "
                               f"rows {rows[0] + 1}..{rows[-1] + 1}")
    else:
        raise ValueError(b["kind"])
    return rec
