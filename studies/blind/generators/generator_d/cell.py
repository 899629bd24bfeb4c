"""The cell: stereo rig stations, visibility, and in-view pose planning (own model, mm / rad)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from kin import (
    DEG,
    PLATE_SPHERES_MM,
    Q_MAX_DEG,
    Q_MIN_DEG,
    SPHERE_DIAMETER_MM,
    apply_T,
    flange2base,
    ik_batch,
    inv_T,
    link_frames,
    nominal_params,
    pose6_to_T,
    T_to_pose6,
)

# MV-EM500M with 16 mm lens (docs/conventions.md)
WIDTH, HEIGHT = 2592, 1944
F_PX = 7272.7
CX, CY = WIDTH / 2 - 0.5, HEIGHT / 2 - 0.5
BASELINE_MM = 250.0
CENTROID_FLANGE = PLATE_SPHERES_MM.mean(axis=0)


def look_at(cam_pos, target, roll):
    """cam2base (OpenCV axes: x right, y down, z forward) looking from cam_pos to target, rolled about z."""
    z = target - cam_pos
    z = z / np.linalg.norm(z)
    down = np.array([0.0, 0.0, -1.0])
    y = down - (down @ z) * z
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    R = np.stack([x, y, z], axis=1)
    R = R @ Rotation.from_rotvec([0, 0, roll]).as_matrix()
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = cam_pos
    return T


@dataclass
class Station:
    index: int
    target: np.ndarray  # convergence point, base frame [mm]
    standoff: float  # [mm]
    azimuth: float  # [rad]
    elevation: float  # [rad]
    roll: float  # [rad]
    placement_err: np.ndarray  # (6,) mm/rad error of the rig as placed
    nominal_stated_err: np.ndarray = field(default_factory=lambda: np.zeros(6))

    def _rig(self, err):
        d = np.array([np.cos(self.elevation) * np.cos(self.azimuth), np.cos(self.elevation) * np.sin(self.azimuth), np.sin(self.elevation)])
        centre = self.target + self.standoff * d
        rig2base = look_at(centre, self.target, self.roll)
        rig2base = rig2base @ pose6_to_T(err)
        # left camera half a baseline to the left (-x of the rig), toed in to the convergence point
        conv = rig2base @ np.array([0, 0, self.standoff, 1.0])
        left_pos = (rig2base @ np.array([-BASELINE_MM / 2, 0, 0, 1.0]))[:3]
        right_pos = (rig2base @ np.array([BASELINE_MM / 2, 0, 0, 1.0]))[:3]
        roll_rig = 0.0
        L = look_at(left_pos, conv[:3], roll_rig)
        Rr = look_at(right_pos, conv[:3], roll_rig)
        # keep the rig's roll: rotate the look_at frames so their y axes follow the rig's y
        for C in (L, Rr):
            z = C[:3, 2]
            y_rig = rig2base[:3, 1]
            y = y_rig - (y_rig @ z) * z
            y /= np.linalg.norm(y)
            C[:3, 1] = y
            C[:3, 0] = np.cross(y, z)
        return L, Rr

    @property
    def true_cams(self):
        return self._rig(self.placement_err)

    @property
    def nominal_cams(self):
        return self._rig(np.zeros(6))

    @property
    def base2meas_true(self):
        return inv_T(self.true_cams[0])

    @property
    def base2meas_nominal(self):
        return inv_T(self.nominal_cams[0])

    def base2meas_stated(self):
        """the nominal base2meas written to dataset.toml (the planned rig placement)"""
        return T_to_pose6(self.base2meas_nominal)


def project(cam2base, pts_base):
    """pts_base (n,k,3) -> pixel u, v, depth z (n,k)."""
    pc = apply_T(inv_T(cam2base), pts_base)
    z = pc[..., 2]
    u = F_PX * pc[..., 0] / z + CX
    v = F_PX * pc[..., 1] / z + CY
    return u, v, z


def visible(cams, pts_base, margin_px=20.0):
    """(n,k) bool: sphere seen fully inside both images, in front, 450..1400 mm deep."""
    ok = np.ones(pts_base.shape[:2], bool)
    for C in cams:
        u, v, z = project(C, pts_base)
        r = F_PX * (SPHERE_DIAMETER_MM / 2) / np.maximum(z, 1.0)
        ok &= (z > 450) & (z < 1400)
        ok &= (u - r > margin_px) & (u + r < WIDTH - 1 - margin_px)
        ok &= (v - r > margin_px) & (v + r < HEIGHT - 1 - margin_px)
    return ok


def facing(cams, flange2base_T, max_tilt):
    """plate normal (flange z) within max_tilt of the direction to the left camera."""
    n = flange2base_T[:, :3, 2]
    c = flange2base_T[:, :3, :3] @ CENTROID_FLANGE + flange2base_T[:, :3, 3]
    to_cam = cams[0][:3, 3] - c
    to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True)
    return np.einsum("ni,ni->n", n, to_cam) > np.cos(max_tilt)


def sample_in_view(station: Station, n: int, rng, depth_range=None, max_tilt=35 * DEG, max_roll=180 * DEG,
                   lateral_frac=1.0, limit_margin=5 * DEG, centres=None, stay_nominal=False):
    """n joint vectors [rad] (rounded to 1e-6 deg) whose plate is in view of the station (planned with the
    nominal robot and the nominal rig, as a user would), facing it. `centres` (n,3) in the nominal left-camera
    frame forces plate centroid positions (grid protocol)."""
    nom = nominal_params()
    Lnom, Rnom = station.nominal_cams
    out = []
    tries = 0
    while sum(len(o) for o in out) < n:
        tries += 1
        if tries > 200:
            raise RuntimeError("pose sampling failed")
        m = max(4 * (n - sum(len(o) for o in out)), 40)
        if centres is not None:
            need = n - sum(len(o) for o in out)
            # retry orientations for the same grid centres until all succeed, in order
            cen = centres[len(centres) - need:]
            cen = np.repeat(cen, 10, axis=0)
            m = len(cen)
        else:
            lo, hi = depth_range if depth_range is not None else (station.standoff - 120, station.standoff + 120)
            z = rng.uniform(lo, hi, m)
            hx = (WIDTH / 2 - 100 - 700) / F_PX * z * lateral_frac  # leave room for the plate's extent
            hy = (HEIGHT / 2 - 100 - 700) / F_PX * z * lateral_frac
            cen = np.stack([rng.uniform(-1, 1, m) * np.maximum(hx, 5), rng.uniform(-1, 1, m) * np.maximum(hy, 5), z], 1)
        # orientation: normal towards the camera, tilted, rolled
        los = cen / np.linalg.norm(cen, axis=1, keepdims=True)
        nrm = -los
        tilt = max_tilt * np.sqrt(rng.uniform(0, 1, m))
        az = rng.uniform(-np.pi, np.pi, m)
        # any axis perpendicular to the normal
        a1 = np.cross(nrm, np.array([0.0, 1.0, 0.0]))
        a1 /= np.linalg.norm(a1, axis=1, keepdims=True)
        a2 = np.cross(nrm, a1)
        axis = np.cos(az)[:, None] * a1 + np.sin(az)[:, None] * a2
        Rt = Rotation.from_rotvec(axis * tilt[:, None])
        # base plate frame: z = -los, x roughly camera x
        zc = nrm
        xc = np.array([1.0, 0, 0]) - zc[:, 0:1] * zc
        xc /= np.linalg.norm(xc, axis=1, keepdims=True)
        yc = np.cross(zc, xc)
        R0 = np.stack([xc, yc, zc], axis=2)
        roll = rng.uniform(-max_roll, max_roll, m)
        R = (Rt * Rotation.from_matrix(R0) * Rotation.from_rotvec(np.stack([0 * roll, 0 * roll, roll], 1))).as_matrix()
        f2m = np.tile(np.eye(4), (m, 1, 1))
        f2m[:, :3, :3] = R
        f2m[:, :3, 3] = cen - R @ CENTROID_FLANGE
        f2b = Lnom[None] @ f2m
        # seeds: the elbow-up home branch looking along the line towards the rig
        p = f2b[:, :3, 3]
        seed = np.zeros((m, 6))
        seed[:, 0] = np.arctan2(p[:, 1], p[:, 0])
        seed[:, 1] = rng.uniform(-10, 20, m) * DEG
        seed[:, 2] = rng.uniform(-10, 20, m) * DEG
        seed[:, 3] = rng.uniform(-60, 60, m) * DEG
        seed[:, 4] = rng.uniform(-40, 40, m) * DEG
        seed[:, 5] = rng.uniform(-90, 90, m) * DEG
        q, ok = ik_batch(nom, f2b, seed)
        # wrap q4, q6 into a sane range (they are periodic), keep q1..q3, q5 as found
        for j in (0, 3, 5):
            q[:, j] = (q[:, j] + np.pi) % (2 * np.pi) - np.pi
        qd = q / DEG
        ok &= np.all((qd > Q_MIN_DEG + limit_margin / DEG) & (qd < Q_MAX_DEG - limit_margin / DEG), axis=1)
        ok &= np.abs(qd[:, 4]) > 8  # stay off the wrist singularity
        qd = np.round(qd, 6)
        q = qd * DEG
        F = flange2base(nom, q)
        sph = apply_T(F, PLATE_SPHERES_MM[None].repeat(m, 0))
        ok &= np.all(visible((Lnom, Rnom), sph), axis=1)
        ok &= facing((Lnom, Rnom), F, max_tilt + 3 * DEG)
        frames = link_frames(nom, q)
        ok &= np.all(frames[:, 2:, 2, 3] > 100.0, axis=1)
        if centres is not None:
            # keep the first success per grid centre, preserve order
            idx = []
            for g in range(len(cen) // 10):
                w = np.nonzero(ok[10 * g:10 * g + 10])[0]
                if len(w) == 0:
                    break
                idx.append(10 * g + w[0])
            out.append(q[idx])
        else:
            out.append(q[ok])
    q = np.concatenate(out)[:n]
    return q
