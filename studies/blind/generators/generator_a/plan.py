"""Cell layout, pose planning, measurement order, time and temperature (the campaign's 'session')."""

from __future__ import annotations

import numpy as np

from kin import DEG, Robot, flange2base, link_frames

# working region of the flange in the robot base frame [mm] per robot, and the camera's aim point
REGIONS = {
    "irb1200": dict(x=(300, 700), y=(-300, 300), z=(150, 800), aim=(520, 0, 480)),
    "heldout_arm_b": dict(x=(280, 620), y=(-280, 280), z=(120, 700), aim=(460, 0, 420)),
    "heldout_arm_c": dict(x=(380, 850), y=(-350, 350), z=(150, 1000), aim=(620, 0, 560)),
}

# instrument: a stereo tracker with a wide field (the twin's 16 mm lens field is too narrow for this region)
FOV_HALF_DEG = 26.0
RANGE_MM = (450.0, 1150.0)
MAX_INCIDENCE_DEG = 60.0  # plate normal vs line of sight


def place_station(rng, robot_name: str, az_deg: float, el_deg: float, standoff_mm: float, roll_deg: float):
    """A camera frame (OpenCV axes: x right, y down, z forward) looking at the aim point. Returns base2meas."""
    reg = REGIONS[robot_name]
    aim = np.array(reg["aim"], float) + rng.normal(0, 25, 3)
    az, el = az_deg * DEG, el_deg * DEG
    u = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])  # aim -> camera
    cam = aim + standoff_mm * u
    z = -u
    down = np.array([0, 0, -1.0])
    y = down - (down @ z) * z
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    R = np.stack([x, y, z], axis=1)  # cam2base rotation: columns are camera axes in the base frame
    r = roll_deg * DEG
    Rr = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1]])
    R = R @ Rr
    cam2base = np.eye(4)
    cam2base[:3, :3] = R
    cam2base[:3, 3] = cam
    base2meas = np.linalg.inv(cam2base)
    return base2meas, dict(aim_mm=aim.tolist(), camera_mm=cam.tolist(), azimuth_deg=az_deg, elevation_deg=el_deg,
                           standoff_mm=standoff_mm, roll_deg=roll_deg)


def sample_joints(rng, robot: Robot, n: int) -> np.ndarray:
    """Joint samples in the ranges this generator finds sensible [rad] (documented in README)."""
    lo = robot.q_min / DEG + 5
    hi = robot.q_max / DEG - 5
    lo4 = np.array([-65, lo[1], lo[2], max(lo[3], -200), lo[4], max(lo[5], -300)])
    hi4 = np.array([65, hi[1], hi[2], min(hi[3], 200), hi[4], min(hi[5], 300)])
    q = rng.uniform(lo4, hi4, size=(n, 6))
    return q * DEG


def visible(robot: Robot, q: np.ndarray, base2meas: np.ndarray, spheres_nom: np.ndarray, name: str):
    """Mask of configurations that are physically sensible and seen by the station (nominal geometry)."""
    reg = REGIONS[name]
    frames = link_frames(robot, q)
    F = frames[5]
    p = F[:, :3, 3]
    ok = (p[:, 0] > reg["x"][0]) & (p[:, 0] < reg["x"][1]) & (np.abs(p[:, 1]) < reg["y"][1])
    ok &= (p[:, 2] > reg["z"][0]) & (p[:, 2] < reg["z"][1])
    # elbow (frame 3) and wrist centre (frame 4/5) well above the floor, wrist in front of the column
    ok &= frames[2][:, 2, 3] > 150
    ok &= frames[4][:, 2, 3] > 120
    ok &= np.hypot(frames[4][:, 0, 3], frames[4][:, 1, 3]) > 180
    ok &= np.abs(q[:, 4]) > 15 * DEG  # away from the wrist singularity
    # plate spheres in the camera
    T = base2meas[None] @ F
    P = np.einsum("nij,kj->nki", T[:, :3, :3], spheres_nom) + T[:, None, :3, 3]
    depth = P[..., 2]
    off = np.degrees(np.arctan2(np.hypot(P[..., 0], P[..., 1]), depth))
    ok &= np.all((depth > RANGE_MM[0]) & (depth < RANGE_MM[1]) & (off < FOV_HALF_DEG), axis=1)
    # the plate faces the camera: plate normal (flange z) against the direction to the camera
    nrm = T[:, :3, 2]
    c = T[:, :3, 3] + nrm * spheres_nom[:, 2].mean()
    to_cam = -c / np.linalg.norm(c, axis=1, keepdims=True)
    ok &= np.einsum("ni,ni->n", nrm, to_cam) > np.cos(MAX_INCIDENCE_DEG * DEG)
    return ok


def plan_poses(rng, robot: Robot, base2meas, spheres_nom, n_needed: int) -> np.ndarray:
    out = []
    got = 0
    for _ in range(60):
        q = sample_joints(rng, robot, 20000)
        m = visible(robot, q, base2meas, spheres_nom, robot.name)
        out.append(q[m])
        got += m.sum()
        if got >= n_needed:
            break
    q = np.concatenate(out)
    if q.shape[0] < n_needed:
        raise RuntimeError(f"planning found only {q.shape[0]} of {n_needed} poses")
    return q[:n_needed]


def temperature_profile(rng, rise_range=(1.5, 4.0)):
    """True air temperature [degC] as a function of time [s]: warm-up + HVAC cycling."""
    T0 = rng.uniform(19.0, 23.0)
    rise = rng.uniform(*rise_range)
    tau = rng.uniform(1500, 4500)
    A = rng.uniform(0.2, 0.6)
    P = rng.uniform(1300, 2800)
    ph = rng.uniform(0, 2 * np.pi)
    t_on = rng.uniform(0, 600)

    def T(t):
        t = np.asarray(t, float)
        return T0 + rise * (1 - np.exp(-(t + t_on) / tau)) + A * np.sin(2 * np.pi * t / P + ph)

    return T, dict(T0_c=T0, rise_k=rise, tau_s=tau, hvac_amplitude_k=A, hvac_period_s=P, hvac_phase_rad=ph,
                   warm_since_s=t_on,
                   model="T(t) = T0 + rise*(1-exp(-(t+warm_since)/tau)) + A*sin(2 pi t/P + phase)")
