"""The cell: the instrument (stations, what it sees, its noise), the pose plan, the visit order, the time stamps and
the cell's temperature.

Two instruments:

* ``stereo`` (with the IRB 1200): a stereo rig on a tripod measuring the three sphere centres of the plate on the
  flange, in the left camera's frame (x right, y down, z along the line of sight); a row is seen when the plate
  centre lies within the rig's cone (half-angle drawn 16-24 deg), 0.55-1.6 m deep, and the plate faces the rig
  (the flange z axis within 60 deg of the direction to it). Noise per sphere: ``sigma_lat (r / 0.85 m)`` across the
  line of sight, ``los_factor`` times that (times ``r / 0.85 m``) along it.
* ``tracker`` (with a UR): a laser tracker 1.5-3.5 m away measuring one reflector on the flange, off its axis; a row
  is seen when the reflector faces the tracker within 55 deg; the tracker's frame has z up and x towards the robot.
  Noise isotropic per coordinate:
  ``sigma_0 + sigma_per_m * range``.

Stations are placements of the instrument; each has its own ``base2meas``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from twin.units import M_PER_MM, RAD_PER_DEG

from . import kin

__all__ = [
    "PLATE_SPHERES", "SPHERE_DIAMETER_MM", "Station", "Instrument", "draw_instrument", "draw_stations", "visible",
    "sample_plan", "order", "times", "noise", "temperature_wander"
]

PLATE_SPHERES = np.array([[60.0, 0.0, 50.0], [-60.0, 0.0, 50.0], [-20.52, 56.38, 50.0]]) * M_PER_MM
SPHERE_DIAMETER_MM = 25.4
FLOOR_Z = 0.1  # [m]: the wrist centre and the flange stay this far above the base plane


@dataclass
class Station:
    """One placement of the instrument: ``base2meas`` 4x4, the instrument's origin ``eye`` and look direction
    ``axis`` in the base frame [m] (the stereo rig's line of sight; the tracker's frame has z up)."""

    base2meas: np.ndarray
    eye: np.ndarray
    axis: np.ndarray

    def record(self) -> dict:
        return {"base2meas": np.round(self.base2meas, 12).tolist()}


@dataclass
class Instrument:
    """``kind`` (``stereo``/``tracker``), the marker points in the tool frame ``points_tool`` ``(K, 3)`` [m], the
    noise constants and the view rule's constants."""

    kind: str
    points_tool: np.ndarray
    noise: dict
    cone_deg: float = 20.0

    @property
    def K(self) -> int:
        return len(self.points_tool)


def draw_instrument(rng: np.random.Generator, robot_name: str) -> Instrument:
    if robot_name == "irb1200":
        return Instrument("stereo", PLATE_SPHERES.copy(),
                          {"sigma_lat_mm": float(rng.uniform(0.0022, 0.004)), "los_factor": float(rng.uniform(2.4, 3.2))},
                          cone_deg=float(rng.uniform(16, 24)))
    r = rng.uniform(25, 60) * M_PER_MM  # the reflector's nest: off the flange axis (joint 6 turns it)
    phi = rng.uniform(0, 2 * np.pi)
    p = np.array([[r * np.cos(phi), r * np.sin(phi), rng.uniform(20, 60) * M_PER_MM]])
    return Instrument("tracker", p, {"sigma0_mm": float(rng.uniform(0.005, 0.012)),
                                     "sigma_per_m_mm": float(rng.uniform(0.001, 0.004))})


def _look_at(eye: np.ndarray, target: np.ndarray, up_hint=np.array([0.0, 0.0, 1.0])) -> np.ndarray:
    """cam2base of a frame at ``eye`` with z towards ``target`` and y pointing down (OpenCV)."""
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up_hint)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = eye
    return T


def draw_stations(rng: np.random.Generator, robot_name: str, instrument: Instrument, n: int) -> list[Station]:
    """``n`` placements of the instrument around the robot's work (azimuths spread over +-55 deg)."""
    out = []
    az0 = rng.uniform(-20, 20)
    azs = [az0] if n == 1 else list(np.linspace(-45, 45, n) + rng.uniform(-10, 10, n))
    for az in azs:
        a = az * RAD_PER_DEG
        if instrument.kind == "stereo":
            target = np.array([0.45, 0.0, 0.55]) + rng.normal(0, 0.04, 3)
            target[:2] = kin.rotz(a)[:2, :2] @ target[:2]
            el = rng.uniform(5, 35) * RAD_PER_DEG
            dist = rng.uniform(0.95, 1.35)
            d = np.array([np.cos(el) * np.cos(a), np.cos(el) * np.sin(a), np.sin(el)])
            eye = target + dist * d
            c2b = _look_at(eye, target)
            c2b[:3, :3] = c2b[:3, :3] @ kin.rotz(rng.uniform(-4, 4) * RAD_PER_DEG)
        else:
            dist = rng.uniform(1.5, 3.5)
            eye = np.array([dist * np.cos(a), dist * np.sin(a), rng.uniform(0.2, 1.2)])
            x = -eye[:2] / np.linalg.norm(eye[:2])
            c2b = np.eye(4)  # the tracker's own frame at its head: z up, x towards the robot's base
            c2b[:3, :3] = np.array([[x[0], -x[1], 0.0], [x[1], x[0], 0.0], [0.0, 0.0, 1.0]])
            c2b[:3, 3] = eye
        out.append(Station(kin.inv(c2b), c2b[:3, 3].copy(), c2b[:3, 2].copy()))
    return out


def visible(instrument: Instrument, station: Station, F: np.ndarray, tool2flange: np.ndarray) -> np.ndarray:
    """Rows ``(n,)`` the station measures, from the frames ``(n, 7, 4, 4)`` at the commanded joints (nominal-ish
    geometry)."""
    T = F[:, 6] @ tool2flange
    P = np.einsum("nij,kj->nki", T[:, :3, :3], instrument.points_tool) + T[:, None, :3, 3]
    c = P.mean(axis=1)
    to_eye = station.eye - c
    rng_ = np.linalg.norm(to_eye, axis=1)
    facing = np.einsum("ij,ij->i", T[:, :3, 2], to_eye / rng_[:, None])
    above = (F[:, 5, 2, 3] > FLOOR_Z) & (F[:, 6, 2, 3] > FLOOR_Z) & (c[:, 2] > FLOOR_Z)
    if instrument.kind == "stereo":
        along = -np.einsum("ij,j->i", to_eye, station.axis)
        inside = along > rng_ * np.cos(instrument.cone_deg * RAD_PER_DEG)
        return inside & (along > 0.55) & (along < 1.6) & (facing > np.cos(60 * RAD_PER_DEG)) & above
    return (facing > np.cos(55 * RAD_PER_DEG)) & above & (rng_ > 0.8)


def sample_plan(rng: np.random.Generator, robot, instrument: Instrument, station: Station, box: np.ndarray, n: int,
                tool2flange: np.ndarray, max_batches: int = 400) -> np.ndarray:
    """``n`` commanded joint vectors ``(n, 6)`` [rad] drawn uniformly in ``box`` ``(6, 2)`` [rad] and kept when the
    station sees them (nominal geometry); joint angles rounded to 1e-4 deg as a controller logs them."""
    out = []
    for _ in range(max_batches):
        q = rng.uniform(box[:, 0], box[:, 1], size=(4000, 6))
        ok = visible(instrument, station, robot.frames(robot.params, q), tool2flange)
        out.extend(q[ok])
        if len(out) >= n:
            break
    if len(out) < n:
        raise RuntimeError(f"only {len(out)} of {n} visible poses in the joint box")
    q = np.array(out[:n])
    return np.round(q / RAD_PER_DEG, 4) * RAD_PER_DEG


def order(rng: np.random.Generator, Q: np.ndarray, kind: str) -> np.ndarray:
    """Visit order: ``random``, ``nearest`` (greedy nearest neighbour in joint space, weighted towards the big
    joints) or ``sweep`` (sorted by one joint, back and forth in chunks)."""
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
        j = int(rng.integers(0, 5))
        idx = np.argsort(Q[:, j])
        chunks = np.array_split(idx, max(2, n // 25))
        return np.concatenate([c if k % 2 == 0 else c[::-1] for k, c in enumerate(chunks)])
    raise ValueError(f"order must be random, nearest or sweep, got {kind!r}")


V_MAX = np.array([90.0, 70.0, 80.0, 150.0, 150.0, 200.0]) * RAD_PER_DEG  # joint speeds [rad/s] at full speed


def times(rng: np.random.Generator, Q: np.ndarray, station: np.ndarray, n_data: int) -> tuple[np.ndarray, dict]:
    """Time stamps [s] ``(N,)``: a move lasts its slowest joint at the campaign's speed, then the settling and the
    measurement (``dwell``, 4-20 s: a campaign of 250 rows takes 0.5-1.8 h); a station change 5-15 min; a pause
    of 2-20 min now and then (2 % of the moves); the rows after the campaign follow 1-10 min after its last row."""
    speed = rng.uniform(0.2, 0.5)
    dwell = rng.uniform(4.0, 20.0)
    t = np.zeros(len(Q))
    t[0] = round(float(rng.uniform(5, 60)), 1)
    for i in range(1, len(Q)):
        dt = float(np.max(np.abs(Q[i] - Q[i - 1]) / (V_MAX * speed))) + dwell * rng.uniform(0.85, 1.15)
        if station[i] != station[i - 1]:
            dt += rng.uniform(300, 900)
        elif rng.uniform() < 0.02:
            dt += rng.uniform(120, 1200)
        if i == n_data:
            dt += rng.uniform(60, 600)
        t[i] = t[i - 1] + dt
    return np.round(t, 1), {"speed": round(float(speed), 3), "dwell_s": round(float(dwell), 2)}


def noise(rng: np.random.Generator, instrument: Instrument, P: np.ndarray, station: Station) -> np.ndarray:
    """The instrument's noise on the points ``P`` ``(n, K, 3)`` [m] of one station (measurement frame)."""
    eye_meas = np.zeros(3)  # the instrument's origin is its frame's origin
    v = P - eye_meas
    r = np.linalg.norm(v, axis=-1, keepdims=True)
    g = rng.normal(size=P.shape)
    if instrument.kind == "tracker":
        s = (instrument.noise["sigma0_mm"] + instrument.noise["sigma_per_m_mm"] * r) * M_PER_MM
        return g * s
    u = v / r
    s_lat = instrument.noise["sigma_lat_mm"] * M_PER_MM * (r / 0.85)
    s_los = instrument.noise["los_factor"] * s_lat * (r / 0.85)
    along = np.sum(g * u, axis=-1, keepdims=True)
    return (g - along * u) * s_lat + along * u * s_los


def temperature_wander(rng: np.random.Generator, t: np.ndarray) -> np.ndarray:
    """The cell's air temperature when nothing drives it [deg C]: a slow swing and a wander (no effect follows it)."""
    T0 = rng.uniform(19.5, 23.0)
    per = rng.uniform(5, 9) * 3600
    walk = np.cumsum(rng.normal(0, 0.003, len(t)))
    return T0 + 0.3 * np.sin(2 * np.pi * t / per + rng.uniform(0, 2 * np.pi)) + walk
