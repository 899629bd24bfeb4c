"""Pose plans: commanded joints whose plate the station's rig sees (cell.Station.visible), and their order."""
from __future__ import annotations

import numpy as np

import cell
import kin

LIM_MARGIN = 3.0 * kin.DEG


def _in_limits(q):
    return np.all(q > kin.Q_MIN_DEG * kin.DEG + LIM_MARGIN) and np.all(q < kin.Q_MAX_DEG * kin.DEG - LIM_MARGIN)


def _wrap(q):
    """Angles to [-pi, pi) (the representative nearest zero; joints 4 and 6 could turn further but need not)."""
    return (q + np.pi) % (2 * np.pi) - np.pi


def visible_rows(params, station, q, tool2flange=np.eye(4)):
    """Which rows of q (n, 6) [rad] the station sees, with the nominal-ish geometry ``params``."""
    F = kin.frames(params, q)
    f2m = station.base2meas[None] @ F[:, 6] @ tool2flange[None]
    S = np.einsum("nij,kj->nki", f2m[:, :3, :3], kin.SPHERES_FLANGE) + f2m[:, None, :3, 3]
    return station.visible(S, f2m, F[:, 5, 2, 3], F[:, 6, 2, 3])


def sample(rng, params, station, n, depth=(0.62, 1.2), tilt_max_deg=42.0, seeds=None, q1_window_deg=70.0,
           max_tries=40000):
    """``n`` commanded joint vectors (n, 6) [rad] whose plate the station sees: a plate centre drawn uniformly in the
    image and in depth, the plate normal within ``tilt_max_deg`` of the direction to the rig, a random turn about
    it; the flange pose solved by numerical IK from seeds (``seeds``: (k, 6) [rad] starting configurations, one
    drawn per try, perturbed); rows kept when in limits, joint 1 within ``q1_window_deg`` of the direction to the
    station's target (the arm faces its work, no reach over its head) and visible."""
    q1c = np.arctan2(station.target[1], station.target[0])
    meas2base = station.cam2base
    out = []
    tries = 0
    while len(out) < n and tries < max_tries:
        tries += 1
        z = rng.uniform(*depth)
        u = rng.uniform(180, cell.W - 180)
        v = rng.uniform(180, cell.H - 180)
        # the left camera's point; pull it halfway towards the right camera's view
        c = np.array([(u - cell.CX) / cell.F_PX * z, (v - cell.CY) / cell.F_PX * z, z])
        c[0] += 0.5 * station.baseline * (z / 1.6)
        to_rig = station.mid - c
        to_rig /= np.linalg.norm(to_rig)
        ax = np.cross(to_rig, rng.normal(size=3))
        ax /= np.linalg.norm(ax)
        tilt = tilt_max_deg * kin.DEG * np.sqrt(rng.uniform())
        nz = kin.rotvec_to_matrix(ax * tilt) @ to_rig
        x0 = np.cross(nz, rng.normal(size=3))
        x0 /= np.linalg.norm(x0)
        R = np.stack([x0, np.cross(nz, x0), nz], axis=1)
        f2m = np.eye(4)
        f2m[:3, :3] = R
        f2m[:3, 3] = c - R @ kin.PLATE_CENTRE
        target = meas2base @ f2m
        q0 = seeds[rng.integers(len(seeds))] + rng.normal(0, 0.25, 6) if seeds is not None else rng.uniform(
            kin.Q_MIN_DEG * kin.DEG, kin.Q_MAX_DEG * kin.DEG) * 0.6
        q = kin.ik(params, target, q0)
        if q is None:
            continue
        q = q.copy()
        q = _wrap(q)
        if abs(_wrap(q[0] - q1c)) > q1_window_deg * kin.DEG or abs(q[3]) > 200 * kin.DEG:
            continue
        if not _in_limits(q):
            continue
        if not visible_rows(params, station, q[None])[0]:
            continue
        out.append(q)
    if len(out) < n:
        raise RuntimeError(f"only {len(out)} of {n} visible poses after {tries} tries")
    return np.array(out)


def order(rng, Q, kind):
    """Visit order of the poses: ``random``, ``nearest`` (greedy nearest neighbour in joint space, weighted towards
    the big joints), or ``sweep`` (sorted by one joint's angle back and forth in chunks)."""
    n = len(Q)
    if kind == "random":
        return rng.permutation(n)
    if kind == "nearest":
        w = np.array([1.5, 1.5, 1.2, 0.6, 0.6, 0.3])
        left = list(range(n))
        cur = left.pop(int(rng.integers(n)))
        seq = [cur]
        while left:
            d = np.abs((Q[left] - Q[cur]) * w).max(axis=1)
            cur = left.pop(int(np.argmin(d)))
            seq.append(cur)
        return np.array(seq)
    if kind == "sweep":
        j = int(rng.integers(1, 5))
        idx = np.argsort(Q[:, j])
        chunks = np.array_split(idx, max(2, n // 25))
        return np.concatenate([c if k % 2 == 0 else c[::-1] for k, c in enumerate(chunks)])
    raise ValueError(kind)
