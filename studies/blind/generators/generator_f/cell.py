"""The measurement cell: a stereo camera on a tripod (station), what it sees, and its noise.

The measurement frame of a station is the left camera's OpenCV frame (x right, y down, z along the line of sight,
docs/conventions.md). Both cameras are MV-EM500M-like: 2592 x 1944 px, f = 7272.7 px; the right camera sits
``baseline`` to the right (+x) of the left one, toed in by ``toe`` about its y axis towards the left camera's axis.

Visibility rule (stated in the README): a row is measurable when every sphere centre projects inside both images
with a margin of the sphere's image radius + 25 px, its depth is 0.55-1.35 m, the plate faces the rig (the angle
between the flange z axis, along which the spheres stand off the plate, and the direction from the plate centre to
the rig's midpoint is below 50 deg), the wrist centre and flange are at least 0.12 m above the floor (base z = 0)
and every joint is at least 3 deg inside its limits.
"""
from __future__ import annotations

import numpy as np

import kin

W, H, F_PX = 2592, 1944, 7272.7
CX, CY = W / 2 - 0.5, H / 2 - 0.5
SPHERE_R = 0.0127
DEPTH = (0.55, 1.35)
FACING_MAX_DEG = 50.0
MARGIN_PX = 25.0


class Station:
    """A placement of the stereo rig: the left camera looks from ``distance`` at ``target`` (base frame, m) from the
    direction (azimuth about base z from base +x, elevation above horizontal) with a roll about its axis."""

    def __init__(self, target, distance, azimuth_deg, elevation_deg, roll_deg=0.0, baseline=0.25, toe_deg=15.0):
        self.target = np.asarray(target, float)
        d = np.array([np.cos(elevation_deg * kin.DEG) * np.cos(azimuth_deg * kin.DEG),
                      np.cos(elevation_deg * kin.DEG) * np.sin(azimuth_deg * kin.DEG),
                      np.sin(elevation_deg * kin.DEG)])
        cam = self.target + distance * d
        z = -d
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z], axis=1) @ kin.rotz(roll_deg * kin.DEG)
        cam2base = np.eye(4)
        cam2base[:3, :3] = R
        cam2base[:3, 3] = cam
        self.cam2base = cam2base
        self.base2meas = kin.inv(cam2base)
        self.baseline = baseline
        # right camera: centre at (baseline, 0, 0) of the left frame, turned by -toe about y (towards the left axis)
        self.R_l2r = kin.roty(-toe_deg * kin.DEG).T
        self.c_right = np.array([baseline, 0.0, 0.0])
        self.mid = np.array([baseline / 2, 0.0, 0.0])
        self.desc = dict(target_m=[round(float(v), 4) for v in self.target], distance_m=distance,
                         azimuth_deg=azimuth_deg, elevation_deg=elevation_deg, roll_deg=roll_deg,
                         baseline_m=baseline, toe_deg=toe_deg)

    def project(self, P):
        """Points in the measurement frame (..., 3) -> left and right pixel coordinates (..., 2) each."""
        pl = P[..., :2] / P[..., 2:3] * F_PX + np.array([CX, CY])
        Pr = (P - self.c_right) @ self.R_l2r.T
        pr = Pr[..., :2] / Pr[..., 2:3] * F_PX + np.array([CX, CY])
        return pl, pr, Pr[..., 2]

    def visible(self, S_meas, flange2meas, wrist_z, flange_z):
        """Rows (n,) that the rig measures: ``S_meas`` (n, 3, 3) sphere centres, ``flange2meas`` (n, 4, 4)."""
        pl, pr, zr = self.project(S_meas)
        zl = S_meas[..., 2]
        rad = SPHERE_R / np.maximum(zl, 1e-3) * F_PX + MARGIN_PX
        inside = lambda p: (p[..., 0] > rad) & (p[..., 0] < W - rad) & (p[..., 1] > rad) & (p[..., 1] < H - rad)
        ok = np.all(inside(pl) & inside(pr) & (zl > DEPTH[0]) & (zl < DEPTH[1]) & (zr > DEPTH[0]), axis=1)
        centre = S_meas.mean(axis=1)
        to_rig = self.mid - centre
        to_rig /= np.linalg.norm(to_rig, axis=1, keepdims=True)
        facing = np.einsum("ij,ij->i", flange2meas[:, :3, 2], to_rig) > np.cos(FACING_MAX_DEG * kin.DEG)
        return ok & facing & (wrist_z > 0.12) & (flange_z > 0.12)


def noise(rng, S_meas, station, sigma_lat, los_factor, r0=0.85, power=1.0):
    """Stereo triangulation noise (n, 3, 3) [m]: per sphere, sigma_lat * (r/r0)^power across the line of sight from
    the rig's midpoint and los_factor times it (times r/r0 once more) along it."""
    v = S_meas - station.mid
    r = np.linalg.norm(v, axis=-1, keepdims=True)
    u = v / r
    s_lat = sigma_lat * (r / r0) ** power
    s_los = los_factor * s_lat * (r / r0)
    g = rng.normal(size=S_meas.shape)
    along = np.sum(g * u, axis=-1, keepdims=True)
    return (g - along * u) * s_lat + along * u * s_los
