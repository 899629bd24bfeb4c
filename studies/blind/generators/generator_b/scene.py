"""Cell layout (stations), joint-configuration sampling, timeline (times, temperatures, pauses)."""
from __future__ import annotations

import numpy as np

import kin
from kin import DEG
from robots import size_factor

FOV_HALF_DEG = 20.0      # half-angle of the instrument's useful cone around its line of sight
DEPTH_WINDOW_MM = 220.0  # plate centre depth within +- this of the station's nominal distance
FACING_MAX_DEG = 65.0    # plate normal (flange z) within this of the direction to the instrument
Q5_MIN_DEG = 8.0         # keep away from the wrist singularity


def look_frame(cam, target, roll, up=np.array([0.0, 0.0, 1.0])):
    """cam2base with z from cam to target, y pointing 'down' (OpenCV-like), rolled by `roll` [rad]."""
    z = target - cam
    z /= np.linalg.norm(z)
    y = -up + np.dot(up, z) * z
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    R = np.stack([x, y, z], 1)
    Rr = kin.rotz(roll)[:3, :3]
    R = R @ Rr
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = cam
    return M


def make_stations(rng, robot, n_stations):
    """Region centre and one instrument placement per station (true base2meas; never written to dataset.toml)."""
    s = size_factor(robot)
    reach = robot["a"][2] + robot["d"][3] + robot["d"][5]
    psi = rng.uniform(-30, 30) * DEG
    r = rng.uniform(380, 500) * s
    zc = rng.uniform(330, 600) * s
    centre = np.array([r * np.cos(psi), r * np.sin(psi), zc])
    stations = []
    used_phi = []
    for k in range(n_stations):
        for _ in range(1000):
            phi = rng.uniform(-70, 70) * DEG
            if any(abs(phi - u) < 25 * DEG for u in used_phi):
                continue
            el = rng.uniform(0, 35) * DEG
            D = rng.uniform(600, 1000)
            direction = np.array([np.cos(el) * np.cos(psi + phi), np.cos(el) * np.sin(psi + phi), np.sin(el)])
            cam = centre + D * direction
            if np.hypot(cam[0], cam[1]) < reach + 150:
                continue
            break
        used_phi.append(phi)
        target = centre + rng.normal(0, 30, 3) * s
        cam2base = look_frame(cam, target, rng.uniform(-10, 10) * DEG)
        D_true = float(np.linalg.norm(target - cam))
        stations.append(dict(cam2base=cam2base, base2meas=kin.inv(cam2base), distance_mm=D_true,
                             azimuth_deg=float((psi + phi) / DEG), elevation_deg=float(el / DEG)))
    return centre, stations


def accept(robot, pv_nom, q_deg, station, plate_centre_tool):
    """Boolean mask: configurations an optical instrument at `station` can watch (the documented rule)."""
    s = size_factor(robot)
    frames = kin.link_frames(q_deg * DEG, pv_nom)
    F = frames[-1]
    pc = kin.apply(F, plate_centre_tool[None, None, :])[:, 0, :]
    wc = frames[5][:, :3, 3]
    cam2base = station["cam2base"]
    cam = cam2base[:3, 3]
    zc = cam2base[:3, 2]
    v = pc - cam
    depth = v @ zc
    ang = np.degrees(np.arccos(np.clip(depth / np.linalg.norm(v, axis=1), -1, 1)))
    n = F[:, :3, 2]
    to_cam = -v / np.linalg.norm(v, axis=1)[:, None]
    facing = np.degrees(np.arccos(np.clip(np.sum(n * to_cam, 1), -1, 1)))
    ok = (ang < FOV_HALF_DEG) & (np.abs(depth - station["distance_mm"]) < DEPTH_WINDOW_MM)
    ok &= facing < FACING_MAX_DEG
    ok &= (pc[:, 2] > 80 * s) & (wc[:, 2] > 150 * s) & (np.hypot(wc[:, 0], wc[:, 1]) > 150 * s)
    ok &= np.abs(q_deg[:, 4]) > Q5_MIN_DEG
    # the arm reaches forward (no over-the-head configurations): wrist centre ahead of axis 1 along the
    # direction joint 1 points the arm
    fwd = wc[:, 0] * np.cos(q_deg[:, 0] * DEG) + wc[:, 1] * np.sin(q_deg[:, 0] * DEG)
    ok &= fwd > 150 * s
    return ok


def sample_configs(rng, robot, pv_nom, station, plate_centre_tool, n):
    """n random joint configurations (deg, 4 decimals) within the limits that pass `accept`."""
    out = []
    got = 0
    lo, hi = robot["qmin"], robot["qmax"]
    tries = 0
    while got < n:
        tries += 1
        if tries > 400:
            raise RuntimeError("pose sampling failed")
        q = rng.uniform(lo, hi, size=(20000, 6))
        q = np.round(q, 4)
        ok = accept(robot, pv_nom, q, station, plate_centre_tool)
        out.append(q[ok])
        got += int(ok.sum())
    return np.concatenate(out)[:n]


def temperature(rng, t, running_gap, profile):
    """True temperature [degC] at the row times. profile: 'warmup' (robot heating while it runs, cooling in
    long pauses) or 'room' (slow ramp plus a slow oscillation)."""
    T_amb0 = rng.uniform(19.0, 23.0)
    slope = (rng.uniform(2.5, 4.0) if profile == "hall" else rng.uniform(-1.0, 2.5)) / 3600.0
    A = rng.uniform(0.1, 0.4)
    P = rng.uniform(1800, 4000)
    ph = rng.uniform(0, 2 * np.pi)
    amb = T_amb0 + slope * (t - t[0]) + A * np.sin(2 * np.pi * (t - t[0]) / P + ph)
    if profile in ("room", "hall"):
        return amb, dict(profile=profile, T0=T_amb0, slope_K_per_h=slope * 3600, osc_K=A, period_s=P)
    dT = rng.uniform(4.0, 8.0)
    tau_h = rng.uniform(1200, 2400)
    tau_c = rng.uniform(1800, 3600)
    T = np.empty_like(t)
    cur = amb[0] + rng.uniform(0.0, 0.5)
    T[0] = cur
    for k in range(1, len(t)):
        g = t[k] - t[k - 1]
        run = g if running_gap[k] else min(g, 20.0)
        rest = g - run
        target = amb[k] + dT
        cur = target + (cur - target) * np.exp(-run / tau_h)
        if rest > 0:
            cur = amb[k] + (cur - amb[k]) * np.exp(-rest / tau_c)
        T[k] = cur
    return T, dict(profile="warmup", T_amb=T_amb0, rise_K=dT, tau_heat_s=tau_h, tau_cool_s=tau_c)
