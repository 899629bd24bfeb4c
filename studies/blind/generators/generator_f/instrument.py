"""What the stereo rig reports: the true centres plus its noise, and bursts of bad rows that are the instrument's
fault (nothing of the robot changes): a glare on one sphere in one camera, the plate still ringing while the two
cameras expose a few milliseconds apart, a mismatched blob (gross row), spheres not found."""
from __future__ import annotations

import numpy as np

import cell


def triangulate_mid(station, pl, pr):
    """Midpoint triangulation of a left ray through the point ``pl`` and a right ray through ``pr`` (both (..., 3),
    left camera frame [m]): the middle of the shortest segment between the two rays."""
    c = station.c_right
    dl = pl / np.linalg.norm(pl, axis=-1, keepdims=True)
    dr = (pr - c) / np.linalg.norm(pr - c, axis=-1, keepdims=True)
    w0 = -c  # left origin minus right origin
    a = np.sum(dl * dl, -1)
    b = np.sum(dl * dr, -1)
    cc = np.sum(dr * dr, -1)
    d = np.sum(dl * w0, -1)
    e = np.sum(dr * w0, -1)
    den = a * cc - b * b
    s = (b * e - cc * d) / den
    t = (a * e - b * d) / den
    return 0.5 * (s[..., None] * dl + c + t[..., None] * dr)


def glare(station, P, shift_px, direction_rad):
    """One sphere's left-image centre pulled ``shift_px`` along ``direction_rad`` by a reflection (the right image
    clean): the triangulated point (3,) of the true centre ``P`` (3,)."""
    u = P[:2] / P[2]
    u2 = u + shift_px / cell.F_PX * np.array([np.cos(direction_rad), np.sin(direction_rad)])
    pl = np.array([u2[0], u2[1], 1.0]) * P[2]
    return triangulate_mid(station, pl, P)


def vibration(station, S, amp_m, amp_rad, freq_hz, desync_s, phase, axis_t, axis_r):
    """The plate ringing during the exposure: a rigid oscillation (translation ``amp_m`` along ``axis_t``, rotation
    ``amp_rad`` about ``axis_r`` through the plate centre), the left camera exposing at phase ``phase`` and the right
    one ``desync_s`` later; each sphere (3, 3) triangulated from the two views."""

    def moved(ph):
        d = np.sin(ph)
        ang = amp_rad * d
        K = np.array([[0, -axis_r[2], axis_r[1]], [axis_r[2], 0, -axis_r[0]], [-axis_r[1], axis_r[0], 0]])
        R = np.eye(3) + np.sin(ang) * K + (1 - np.cos(ang)) * K @ K
        c = S.mean(axis=0)
        return (S - c) @ R.T + c + axis_t * amp_m * d

    pl = moved(phase)
    pr = moved(phase + 2 * np.pi * freq_hz * desync_s)
    return triangulate_mid(station, pl, pr)
