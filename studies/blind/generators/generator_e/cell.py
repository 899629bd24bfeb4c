"""Cell and instrument: camera stations (OpenCV-like frame, z along the line of sight), view checks, noise."""
from __future__ import annotations

import numpy as np

import kin

DEG = kin.DEG

# working region per robot: radius of the target point from axis 1 and its height [mm]
WORK = {"irb1200": (480.0, 520.0), "cx900": (620.0, 640.0), "lr560": (380.0, 420.0)}


def make_station(robot, rng, az_target_deg, az_offset_deg, elev_deg, dist_mm, roll_deg=0.0):
    """Camera placed dist_mm from a target point of the working region, looking at it.

    Returns dict with base2meas (4x4), cam position, settings. Camera frame: x right, y down, z forward.
    """
    R_t, z_t = WORK[robot]
    az = az_target_deg * DEG
    target = np.array([R_t * np.cos(az), R_t * np.sin(az), z_t]) + rng.normal(0, 20, 3)
    a2 = (az_target_deg + az_offset_deg) * DEG
    el = elev_deg * DEG
    u = np.array([np.cos(a2) * np.cos(el), np.sin(a2) * np.cos(el), np.sin(el)])
    cam = target + dist_mm * u
    z = -u
    y0 = np.array([0.0, 0.0, -1.0])
    y = y0 - (y0 @ z) * z
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    R = np.column_stack([x, y, z])
    R = R @ kin.rotvec_to_R(np.array([0, 0, roll_deg * DEG]))  # small roll about the line of sight
    cam2base = kin.make_T(R, cam)
    return dict(base2meas=kin.inv_T(cam2base), cam=cam, target=target, dist=dist_mm)


def view_ok(P, T_tool_meas, spec, frames=None, q=None, robot=None):
    """Boolean mask of rows whose spheres are in view and whose plate faces the camera.

    P (n,3,3) sphere centres in the camera frame; T_tool_meas (n,4,4)."""
    z = P[..., 2]
    zmin, zmax = spec["depth_mm"]
    ok = np.all((z > zmin) & (z < zmax), axis=1)
    tx, ty = np.tan(spec["hfov_deg"] * DEG), np.tan(spec["hfov_deg"] * 0.75 * DEG)
    marg = 25.0 / np.maximum(z, 1)
    ok &= np.all(np.abs(P[..., 0]) / np.maximum(z, 1) < tx - marg, axis=1)
    ok &= np.all(np.abs(P[..., 1]) / np.maximum(z, 1) < ty - marg, axis=1)
    c = P.mean(axis=1)
    to_cam = -c / np.linalg.norm(c, axis=1)[:, None]
    nrm = T_tool_meas[:, :3, 2]
    ok &= np.einsum("ni,ni->n", nrm, to_cam) > np.cos(spec["max_tilt_deg"] * DEG)
    if frames is not None:
        o = frames[:, :, :3, 3]
        ok &= np.all(o[:, 3:7, 2] > 150.0, axis=1)               # elbow, wrist, flange above the floor plate
        ok &= np.hypot(o[:, 5, 0], o[:, 5, 1]) > 200.0            # wrist centre away from axis 1
    return ok


def tilt_deg(P, T_tool_meas):
    c = P.mean(axis=1)
    to_cam = -c / np.linalg.norm(c, axis=1)[:, None]
    return np.degrees(np.arccos(np.clip(np.einsum("ni,ni->n", T_tool_meas[:, :3, 2], to_cam), -1, 1)))


# ---------------------------------------------------------------- noise
def noise_sigmas(P, model):
    """Per-sphere transverse and line-of-sight sigmas [mm], (n,3) each."""
    r = np.linalg.norm(P, axis=2)
    s = model["sigma_mm"]
    kind = model["kind"]
    if kind == "iso":
        st = np.full(r.shape, s)
        sl = st.copy()
    elif kind == "los":
        st = np.full(r.shape, s)
        sl = st * model["los_factor"]
    elif kind == "range":
        f = r / model["r0_mm"]
        st = s * f
        sl = s * model["los_factor"] * f**2
    else:
        raise ValueError(kind)
    return st, sl


def per_coordinate_sigma(P, model):
    st, sl = noise_sigmas(P, model)
    return float(np.sqrt(np.mean((2 * st**2 + sl**2) / 3.0)))


def draw_noise(P, model, rng):
    st, sl = noise_sigmas(P, model)
    v = P / np.linalg.norm(P, axis=2)[..., None]
    xi = rng.standard_normal(P.shape)
    along = np.einsum("nki,nki->nk", xi, v)
    trans = xi - along[..., None] * v
    return st[..., None] * trans + (sl * along)[..., None] * v
