"""The cell: instrument placement, reachable-and-visible configurations, measurement protocols, timing,
temperature, instrument noise and robot repeatability. Millimetres, radians, seconds."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

import kin

DEG = np.pi / 180.0


# ----------------------------------------------------------------------------------------------- stations

class Station:
    def __init__(self, name, base2meas, view):
        self.name = name
        self.base2meas = base2meas  # true pose of the instrument (never written to the dataset)
        self.view = view  # dict: tan_hx, tan_hy, zmin, zmax, facing_deg, standoff


def place_station(rng, robot: kin.Robot, centre_base, azimuth, elevation, standoff, roll, view):
    """Instrument at `standoff` from the working-region centre, looking at it (OpenCV axes: z along the
    line of sight, y pointing down-ish, x right)."""
    P = np.asarray(centre_base, float)
    d = np.array([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
    C = P + standoff * d
    z = -d
    down = np.array([0.0, 0.0, -1.0])
    y = down - (down @ z) * z
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    Rr = Rotation.from_rotvec(z * roll).as_matrix()
    x, y = Rr @ x, Rr @ y
    cam2base = np.eye(4)
    cam2base[:3, :3] = np.stack([x, y, z], axis=1)
    cam2base[:3, 3] = C
    base2meas = kin.inv_T(cam2base)
    v = dict(view)
    v["standoff"] = standoff
    return base2meas, v


# ----------------------------------------------------------------------------------------------- visibility

def visible(geom_nominal_kp, plate_flange, base2meas, view, q, robot: kin.Robot, margin=1.0):
    """Boolean (N,): all three spheres in the field of view and depth window, plate facing the instrument,
    flange above the table, wrist away from the column, joints inside the limits."""
    frames = kin.fk_frames(geom_nominal_kp, q)
    F = frames[-1]
    p_base = kin.apply_T(F, plate_flange[None])
    p = kin.apply_T(np.broadcast_to(base2meas, F.shape), p_base)
    z = p[..., 2]
    tx, ty = view["tan_hx"] * margin, view["tan_hy"] * margin
    ok = np.all(z > view["zmin"], axis=1) & np.all(z < view["zmax"], axis=1)
    ok &= np.all(np.abs(p[..., 0]) < tx * z, axis=1) & np.all(np.abs(p[..., 1]) < ty * z, axis=1)
    n_m = np.einsum("ij,nj->ni", base2meas[:3, :3], F[:, :3, 2])
    c = p.mean(axis=1)
    cosang = -np.einsum("ni,ni->n", n_m, c) / np.linalg.norm(c, axis=1)
    ok &= cosang > np.cos(view["facing_deg"] * DEG)
    ok &= F[:, 2, 3] > 120.0  # flange above the table
    wc = frames[3][:, :3, 3]
    ok &= np.hypot(wc[:, 0], wc[:, 1]) > 220.0  # wrist centre off the column
    ok &= frames[2][:, 2, 3] > 150.0  # elbow above the table
    ok &= np.all((q >= robot.qmin) & (q <= robot.qmax), axis=1)
    ok &= np.abs(q[:, 4]) > 4 * DEG  # no measurement at the wrist singularity
    return ok


def sample_box(robot: kin.Robot, q1_centre):
    lo = np.array([q1_centre - 60 * DEG, -70 * DEG, -150 * DEG, -200 * DEG, -120 * DEG, -300 * DEG])
    hi = np.array([q1_centre + 60 * DEG, 100 * DEG, 60 * DEG, 200 * DEG, 120 * DEG, 300 * DEG])
    return np.maximum(lo, robot.qmin), np.minimum(hi, robot.qmax)


def sample_pool(rng, robot, kp_nom, plate_flange, station: Station, q1_centre, want=2500, max_batches=40):
    lo, hi = sample_box(robot, q1_centre)
    got = []
    n = 0
    for _ in range(max_batches):
        q = lo + (hi - lo) * rng.random((40000, 6))
        ok = visible(kp_nom, plate_flange, station.base2meas, station.view, q, robot, margin=0.95)
        got.append(q[ok])
        n += ok.sum()
        if n >= want:
            break
    pool = np.concatenate(got)[:want]
    if len(pool) < 200:
        raise RuntimeError(f"only {len(pool)} visible configurations for station {station.name}")
    return pool


# ----------------------------------------------------------------------------------------------- protocols

def protocol_random(rng, pool, n):
    idx = rng.choice(len(pool), size=min(n, len(pool)), replace=False)
    return pool[idx]


def _targets_from_plate_poses(station, centroid_meas, normal_meas, roll, plate_flange):
    """Flange2base targets putting the plate centroid at centroid_meas with the plate normal (flange z)
    along normal_meas and a roll about it."""
    m = len(roll)
    c_f = plate_flange.mean(axis=0)
    meas2base = kin.inv_T(station.base2meas)
    T = np.zeros((m, 4, 4))
    for k in range(m):
        n = normal_meas[k] / np.linalg.norm(normal_meas[k])
        ref = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        x = ref - (ref @ n) * n
        x /= np.linalg.norm(x)
        y = np.cross(n, x)
        Rr = Rotation.from_rotvec(n * roll[k]).as_matrix()
        R = Rr @ np.stack([x, y, n], axis=1)
        o = centroid_meas[k] - R @ c_f
        Tm = np.eye(4)
        Tm[:3, :3] = R
        Tm[:3, 3] = o
        T[k] = meas2base @ Tm
    return T


def _solve_targets(robot, kp_nom, pool, pool_F, targets):
    # seed: the pool configuration nearest in flange position and orientation
    dpos = np.linalg.norm(pool_F[None, :, :3, 3] - targets[:, None, :3, 3], axis=2) / 100.0
    cos = np.einsum("mij,nij->mn", targets[:, :3, :3], pool_F[:, :3, :3])  # trace(R_t^T R_p)
    dang = np.arccos(np.clip((cos - 1) / 2, -1, 1))
    best = np.argsort(dpos + dang, axis=1)[:, :3]
    qs, oks = [], []
    for k in range(best.shape[1]):
        q, ok = kin.ik_batch(kp_nom, targets, pool[best[:, k]], robot.qmin, robot.qmax)
        qs.append(q)
        oks.append(ok)
    q = qs[0].copy()
    ok = oks[0].copy()
    for k in range(1, len(qs)):
        take = ~ok & oks[k]
        q[take] = qs[k][take]
        ok |= oks[k]
    return q, ok


def protocol_serpentine(rng, robot, kp_nom, plate_flange, station, pool, n_target):
    """A grid of plate positions in the instrument's field (nx x ny x nz), visited layer by layer in serpentine
    order; at each position a fixed list of plate orientations (tilt toward four directions and roll)."""
    v = station.view
    n_or = int(rng.integers(3, 6))
    n_pos = int(np.ceil(n_target * 1.25 / n_or))
    nz = 3
    nxy = max(2, int(round(np.sqrt(n_pos / nz * 4 / 3))))
    nx, ny = nxy + 1, max(2, nxy)
    zs = np.linspace(v["zmin"] + 0.25 * (v["zmax"] - v["zmin"]), v["zmax"] - 0.25 * (v["zmax"] - v["zmin"]), nz)
    tilts = [(0.0, 0.0)] + [(float(rng.uniform(15, 30)) * DEG, (k * 360.0 / (n_or - 1) + 20) * DEG) for k in range(n_or - 1)]
    rolls = rng.uniform(-120, 120, n_or) * DEG
    cents, norms, rl = [], [], []
    for iz, z in enumerate(zs):
        xs = np.linspace(-0.6, 0.6, nx) * v["tan_hx"] * z
        ys = np.linspace(-0.55, 0.55, ny) * v["tan_hy"] * z
        yorder = ys if iz % 2 == 0 else ys[::-1]
        for iy, y in enumerate(yorder):
            xorder = xs if (iy + iz) % 2 == 0 else xs[::-1]
            for x in xorder:
                c = np.array([x, y, z])
                base_n = -c / np.linalg.norm(c)
                for (tilt, az), r in zip(tilts, rolls):
                    a = np.array([np.cos(az), np.sin(az), 0.0])
                    a -= (a @ base_n) * base_n
                    a /= np.linalg.norm(a)
                    nrm = Rotation.from_rotvec(a * tilt).apply(base_n)
                    cents.append(c)
                    norms.append(nrm)
                    rl.append(r)
    T = _targets_from_plate_poses(station, np.array(cents), np.array(norms), np.array(rl), plate_flange)
    pool_F = kin.fk(kp_nom, pool)
    q, ok = _solve_targets(robot, kp_nom, pool, pool_F, T)
    ok &= visible(kp_nom, plate_flange, station.base2meas, v, q, robot, margin=0.98)
    q = q[ok]
    if len(q) > n_target:  # drop a seeded subset, keeping the order
        keep = np.sort(rng.choice(len(q), n_target, replace=False))
        q = q[keep]
    return q


def protocol_sweeps(rng, robot, kp_nom, plate_flange, station, pool, n_target):
    """A few plate positions; at each, the operator sweeps the roll about the plate normal through its range
    (alternating direction), with the tilt stepping between sweeps."""
    v = station.view
    n_posn = int(rng.integers(5, 8))
    per = int(np.ceil(n_target * 1.3 / n_posn))
    cents, norms, rl = [], [], []
    for k in range(n_posn):
        z = rng.uniform(v["zmin"] + 0.2 * (v["zmax"] - v["zmin"]), v["zmax"] - 0.2 * (v["zmax"] - v["zmin"]))
        c = np.array([rng.uniform(-0.5, 0.5) * v["tan_hx"] * z, rng.uniform(-0.5, 0.5) * v["tan_hy"] * z, z])
        base_n = -c / np.linalg.norm(c)
        rolls = np.linspace(-160, 160, per) * DEG
        if k % 2:
            rolls = rolls[::-1]
        for j, r in enumerate(rolls):
            tilt = (0.0, 18.0, 30.0)[j % 3] * DEG
            az = (j * 137.5) * DEG
            a = np.array([np.cos(az), np.sin(az), 0.0])
            a -= (a @ base_n) * base_n
            a /= np.linalg.norm(a)
            cents.append(c)
            norms.append(Rotation.from_rotvec(a * tilt).apply(base_n))
            rl.append(r)
    T = _targets_from_plate_poses(station, np.array(cents), np.array(norms), np.array(rl), plate_flange)
    pool_F = kin.fk(kp_nom, pool)
    q, ok = _solve_targets(robot, kp_nom, pool, pool_F, T)
    ok &= visible(kp_nom, plate_flange, station.base2meas, v, q, robot, margin=0.98)
    q = q[ok]
    if len(q) > n_target:
        keep = np.sort(rng.choice(len(q), n_target, replace=False))
        q = q[keep]
    return q


def protocol_pairs(rng, robot, kp_nom, plate_flange, station, pool, n_pairs):
    """Motion pairs: a start configuration and an end reached by moving one to three joints by 10-40 deg."""
    starts, ends = [], []
    tries = 0
    while len(starts) < n_pairs and tries < 50:
        tries += 1
        s = pool[rng.choice(len(pool), 400)]
        e = s.copy()
        for i in range(len(e)):
            js = rng.choice(6, size=int(rng.integers(1, 4)), replace=False)
            e[i, js] += rng.choice([-1, 1], len(js)) * rng.uniform(10, 40, len(js)) * DEG
        ok = visible(kp_nom, plate_flange, station.base2meas, station.view, e, robot, margin=0.95)
        starts.extend(s[ok])
        ends.extend(e[ok])
    starts, ends = np.array(starts[:n_pairs]), np.array(ends[:n_pairs])
    return starts, ends


# ----------------------------------------------------------------------------------------------- timing, temperature

def move_time(dq_rad, rng):
    """Seconds for a joint move, settling and capture (axis speeds ~ 60-120 deg/s, with ramps)."""
    spd = np.array([90, 80, 90, 120, 120, 150]) * DEG
    tmove = np.max(np.abs(dq_rad) / spd) if np.any(dq_rad) else 0.0
    return 1.2 + 1.6 * tmove + 1.0 + 0.35 + rng.uniform(0.0, 0.8)


def ambient_profile(rng, kind, t, params):
    """True air temperature [degC] at times t [s]."""
    if kind == "room":
        return params["T0"] + params["drift_per_h"] * t / 3600.0 + params["hvac_amp"] * np.sin(
            2 * np.pi * t / params["hvac_period"] + params["hvac_phase"]
        )
    if kind == "warming":
        return params["T0"] + params["rise"] * (1 - np.exp(-t / params["tau"])) + params["hvac_amp"] * np.sin(
            2 * np.pi * t / params["hvac_period"] + params["hvac_phase"]
        )
    raise ValueError(kind)


# ----------------------------------------------------------------------------------------------- noise

def instrument_noise(rng, model, p_true):
    """Noise (N, 3, 3) [mm] for true centres p_true in the measurement frame.

    iso:     N(0, sigma^2 I) per coordinate.
    stereo:  lateral sigma_l = s0 (r / r0)^2, along the line of sight k_ray * sigma_l (r = distance from the
             instrument); a fraction rho of the variance is common to the three spheres of a row (the same
             image pair, the same calibration state).
    tracker: along the beam sigma_r (interferometer/ADM), across the beam r * sigma_ang (angle encoders);
             independent spheres (measured one after the other)."""
    n = p_true.shape[0]
    r = np.linalg.norm(p_true, axis=2)  # (N,3)
    u = p_true / r[..., None]
    kind = model["kind"]
    if kind == "iso":
        return rng.normal(0.0, model["sigma"], p_true.shape)
    if kind == "stereo":
        sl = model["s0"] * (r / model["r0"]) ** 2
        sr = model["k_ray"] * sl
        rho = model["rho"]
        common = rng.normal(size=(n, 1, 3))
        own = rng.normal(size=(n, 3, 3))
        z = np.sqrt(rho) * common + np.sqrt(1 - rho) * own  # unit variance, correlated across spheres
        along = np.einsum("nki,nki->nk", z, u)
        lat = z - along[..., None] * u
        return lat * sl[..., None] + (along * sr)[..., None] * u
    if kind == "tracker":
        z = rng.normal(size=p_true.shape)
        along = np.einsum("nki,nki->nk", z, u)
        lat = z - along[..., None] * u
        return lat * (r * model["sigma_ang"])[..., None] + (along * model["sigma_r"])[..., None] * u
    raise ValueError(kind)


def repeatability_deltas(rng, n_visits, sigma_mm, lever_mm=200.0):
    """One random rigid flange displacement per visit: translation sigma per axis, rotation sigma/lever."""
    v = np.concatenate([rng.normal(0, sigma_mm, (n_visits, 3)), rng.normal(0, sigma_mm / lever_mm, (n_visits, 3))], axis=1)
    return kin.pose6(v)
