"""One drawn campaign: the robot, instrument, stations, plan, times, the family's instance and its size, the noise;
written in the blind-campaign format (``docs/formats.md``, "Blind campaigns") with the truth beside it.

Random streams of instance ``seed`` of family ``f`` (index in ``FAMILY_ORDER``): ``default_rng([SEED_BASE, f, seed,
k])``, k = 1 robot, instrument, geometry and stations, 2 pose plan and order, 3 times and temperature, 4 the effect, 5
the noise (and the clean family's extras), 6 the size (a campaign drawn again appends the attempt to the key).

**The size.** The effect's size is drawn as a ratio to the noise, log-uniform in ``RATIO`` (1 to 20): the RMS over
the dataset rows of the part of the effect that the geometry cannot take (each point's displacement, after a
least-squares fit of every geometric parameter, every station's base2meas and the tool frame, on the dataset rows)
over the RMS of the noise's displacement per point. The family's ``scale`` is set to reach it (the effect is linear
in it to first order); an instance whose size would be physically implausible (``families.Family.check``) is drawn
again (joint, shape, timing and ratio), at most ``MAX_TRIES`` times.

**Several effects at once** (``MIXED``, not one of ``FAMILY_ORDER``): two or three families from distinct slots of
``MIXED_SLOTS`` (at most one family that names compliance, one backlash, one thermal growth, one change outside the
catalogue, ...), drawn on the effect's stream in slot order; each instance drawn, sized (its own ratio to the noise,
as above, alone) and checked as when it is the campaign's only effect, then composed (:func:`compose`). Its streams
are those of family index ``MIXED_INDEX``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from twin.units import DEG_PER_RAD, MM_PER_M, M_PER_MM, RAD_PER_DEG

from . import cell, kin
from .families import FAMILIES, Ctx, Effect, Redraw, air_profile
from .robots import ROBOTS, params_from_record, params_record, robot_toml, true_params

__all__ = [
    "SEED_BASE", "FAMILY_ORDER", "MIXED", "MIXED_INDEX", "MIXED_SLOTS", "RATIO", "ROWS", "LATER_ROWS", "ROBOT_WEIGHTS",
    "Instance", "NoInstance", "streams", "build", "compose", "write", "read_context", "recompute_effect",
    "chain_points", "geometric_jacobian", "column_basis", "visible_part", "rms_norm"
]

SEED_BASE = 20261201
FAMILY_ORDER = tuple(FAMILIES)
MIXED = "mixed"  # several families' effects in one campaign (module docstring)
MIXED_INDEX = 100  # the family index of its random streams (beyond FAMILY_ORDER's)
MIXED_SLOTS = {  # at most one family of each slot in a campaign of several effects
    "compliance": ("compliance", "payload"), "backlash": ("backlash_motion", "backlash_load", "backlash_size"),
    "tilt": ("tilt",), "thermal": ("thermal", "motion_heat"), "cyclic": ("cyclic",), "gear_ratio": ("gear_ratio",),
    "coupling": ("coupling",), "change": ("zero_step", "zero_glitch", "frame_change")}
MIXED_COUNT = (2, 3)  # families per campaign, drawn uniformly
RATIO = (1.0, 20.0)  # the effect's visible RMS over the noise's RMS, log-uniform
ROBOT_WEIGHTS = {"irb1200": 0.5, "ur5": 0.25, "ur10": 0.25}
ROWS = (180, 320)  # dataset rows
LATER_ROWS = (40, 80)  # rows measured after the campaign
MAX_TRIES = 60
CAMPAIGN_TRIES = 5
XYZ = "xyz"


def streams(family: str, seed: int, attempt: int = 0):
    """The instance's random streams (module docstring); ``attempt`` > 0: the campaign drawn again."""
    f = MIXED_INDEX if family == MIXED else FAMILY_ORDER.index(family)
    return [np.random.default_rng([SEED_BASE, f, int(seed), k] + ([attempt] if attempt else [])) for k in range(1, 7)]


class NoInstance(RuntimeError):
    """The family has no plausible instance of a visible size on this campaign."""


@dataclass
class Instance:
    """A drawn campaign: everything the writers need, and the record of what was drawn (``drawn``)."""

    family: str
    seed: int
    robot: object
    instrument: cell.Instrument
    stations: list
    params: dict
    tool2flange: np.ndarray
    bodies: tuple
    Q: np.ndarray
    t: np.ndarray
    station: np.ndarray
    n_data: int
    P: np.ndarray  # true points with the effect (N, K, 3) [m]
    P0: np.ndarray  # without it
    M: np.ndarray  # measured
    air_c: np.ndarray  # the air temperature the instrument writes [deg C]
    air_wander_c: np.ndarray  # its part no family drives
    temp_written: bool
    masses_stated: tuple | None
    noise_stated_mm: float | None
    effect_params: dict | list[dict] | None  # one per family (a list) for MIXED
    effect_key: dict | list[dict] | None  # one per family (a list) for MIXED
    drawn: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        return f"{self.family}_{self.seed:03d}"

    @property
    def E(self) -> np.ndarray:
        return self.P - self.P0

    @property
    def effect_keys(self) -> list[dict]:
        """The key's entry of every effect (none for a clean campaign)."""
        if not self.effect_key:
            return []
        return list(self.effect_key) if isinstance(self.effect_key, list) else [self.effect_key]


def compose(effects: list[Effect]) -> Effect:
    """One effect acting as all of ``effects``: joint offsets added, length scales multiplied, the tool, measurement
    and base transforms multiplied in the list's order."""
    out = Effect()
    for e in effects:
        if e.dq is not None:
            out.dq = e.dq if out.dq is None else out.dq + e.dq
        if e.length_scale is not None:
            out.length_scale = e.length_scale if out.length_scale is None else out.length_scale * e.length_scale
        for name in ("tool", "meas", "base"):
            a, b = getattr(e, name), getattr(out, name)
            if a is not None:
                setattr(out, name, a if b is None else b @ a)
    return out


def chain_points(robot, params, Q, effect: Effect | None, base2meas_rows, tool2flange, points_tool) -> np.ndarray:
    """The true points ``(N, K, 3)`` [m] of every row with the effect (``None``: without)."""
    e = effect or Effect()
    dq = 0.0 if e.dq is None else e.dq
    F6 = robot.frames(params, Q + dq, e.length_scale)[:, 6]
    if e.base is not None:
        F6 = e.base @ F6
    B = base2meas_rows if e.meas is None else e.meas @ base2meas_rows
    T = tool2flange if e.tool is None else tool2flange[None] @ e.tool
    return kin.points(F6, B, T, points_tool)


def geometric_jacobian(robot, params, Q, base2meas_rows, station, tool2flange, points_tool, h=1e-7) -> np.ndarray:
    """Columns ``(n K 3, p)``: the points' change per unit of every geometric parameter (``theta, d, a, alpha`` of
    each joint, beta of the declared joints, each station's base2meas and the tool frame, 6 each)."""
    P0 = chain_points(robot, params, Q, None, base2meas_rows, tool2flange, points_tool).ravel()
    cols = []
    for k in ("theta", "d", "a", "alpha"):
        for i in range(6):
            p = {kk: v.copy() for kk, v in params.items()}
            p[k][i] += h
            cols.append((chain_points(robot, p, Q, None, base2meas_rows, tool2flange, points_tool).ravel() - P0) / h)
    for j in robot.beta_joints:
        p = {kk: v.copy() for kk, v in params.items()}
        p["beta"][j - 1] += h
        cols.append((chain_points(robot, p, Q, None, base2meas_rows, tool2flange, points_tool).ravel() - P0) / h)
    for s in np.unique(station):
        for a in range(6):
            v = np.zeros(6)
            v[a] = h
            D = kin.transform(v[3:], v[:3])
            B = base2meas_rows.copy()
            B[station == s] = D @ B[station == s]
            cols.append((chain_points(robot, params, Q, None, B, tool2flange, points_tool).ravel() - P0) / h)
    for a in range(6):
        v = np.zeros(6)
        v[a] = h
        T = tool2flange @ kin.transform(v[3:], v[:3])
        cols.append((chain_points(robot, params, Q, None, base2meas_rows, T, points_tool).ravel() - P0) / h)
    return np.stack(cols, axis=1)


def column_basis(J: np.ndarray) -> np.ndarray:
    """An orthonormal basis ``(m, r)`` of the columns of ``J`` ``(m, p)`` (through the eigenvectors of the scaled
    normal matrix; directions below 1e-10 of the largest dropped)."""
    Jn = J / np.maximum(np.linalg.norm(J, axis=0), 1e-300)
    lam, V = np.linalg.eigh(Jn.T @ Jn)
    keep = lam > lam.max() * 1e-10
    return Jn @ V[:, keep] / np.sqrt(lam[keep])


def visible_part(U: np.ndarray, e: np.ndarray) -> np.ndarray:
    """``e`` ``(n, K, 3)`` less its least-squares fit by the geometry (``U``: :func:`column_basis` of its Jacobian):
    what the geometry cannot take."""
    v = e.ravel()
    return (v - U @ (U.T @ v)).reshape(e.shape)


def rms_norm(x: np.ndarray) -> float:
    """RMS over rows and points of each point's displacement norm."""
    return float(np.sqrt(np.nanmean(np.sum(x**2, axis=-1))))


def _draw_setup(rng, family: str):
    names = list(ROBOT_WEIGHTS)
    robot = ROBOTS[names[int(rng.choice(len(names), p=list(ROBOT_WEIGHTS.values())))]]
    inst = cell.draw_instrument(rng, robot.name)
    n_st = int(rng.integers(1, 4)) if inst.kind == "stereo" else int(rng.integers(1, 3))
    stations = cell.draw_stations(rng, robot.name, inst, n_st)
    params = true_params(robot, rng)
    err = np.concatenate([np.clip(rng.normal(0, 0.3, 3), -0.9, 0.9) * M_PER_MM,
                          np.clip(rng.normal(0, 0.1, 3), -0.3, 0.3) * RAD_PER_DEG])
    tool2flange = kin.transform(err[3:], err[:3])
    bodies = list(robot.bodies)
    if inst.kind == "tracker":  # the reflector's nest and its holder
        bodies.append((6, float(rng.uniform(0.1, 0.3)), inst.points_tool[0] * 0.7))
    masses = None
    if rng.uniform() < 0.4:  # the dataset states the masses: each about 8 % and 8 mm off the true ones
        masses = tuple((f, m * (1 + float(rng.normal(0, 0.08))), c + rng.normal(0, 0.008, 3))
                       for f, m, c in robot.bodies)
    return robot, inst, stations, params, tool2flange, tuple(bodies), masses


def _draw_plan(rng, robot, inst, stations, n_data, n_later):
    box = robot.box.copy()
    for j in range(6):
        w = (box[j, 1] - box[j, 0]) * rng.uniform(0.55, 1.0)
        lo = rng.uniform(box[j, 0], box[j, 1] - w)
        box[j] = [lo, lo + w]
    kind = ["random", "nearest", "sweep"][int(rng.choice(3, p=[0.5, 0.3, 0.2]))]
    per = np.full(len(stations), n_data // len(stations))
    per[-1] += n_data - per.sum()
    Q, st = [], []
    for s, (station, n_s) in enumerate(zip(stations, per)):
        q = cell.sample_plan(rng, robot, inst, station, box, int(n_s), np.eye(4))
        Q.append(q[cell.order(rng, q, kind)])
        st += [s] * int(n_s)
    q = cell.sample_plan(rng, robot, inst, stations[-1], box, n_later, np.eye(4))
    Q.append(q[cell.order(rng, q, kind)])
    st += [len(stations) - 1] * n_later
    return np.concatenate(Q), np.array(st), box, kind


def build(family: str, seed: int, rows: tuple[int, int] = ROWS, later_rows: tuple[int, int] = LATER_ROWS) -> Instance:
    """Draw instance ``seed`` of ``family`` (module docstring): ``rows`` and ``later_rows`` the ranges of the dataset's
    rows and of the rows after the campaign (another range draws another instance). A campaign on which the family
    has no plausible instance of a visible size is drawn again (at most ``CAMPAIGN_TRIES`` times; ``drawn``
    records how often)."""
    if family not in FAMILIES and family != MIXED:
        raise ValueError(f"family must be one of {FAMILY_ORDER + (MIXED,)}, got {family!r}")
    if not (10 <= rows[0] <= rows[1] and 1 <= later_rows[0] <= later_rows[1]):
        raise ValueError(f"rows must be >= 10 and later_rows >= 1 (low <= high), got {rows}, {later_rows}")
    why = []
    for attempt in range(CAMPAIGN_TRIES):
        try:
            inst = _build(family, seed, rows, later_rows, attempt)
        except NoInstance as exc:
            why.append(str(exc))
            continue
        inst.drawn["campaign_redraws"] = attempt
        return inst
    raise NoInstance(f"{family} seed {seed}: no plausible instance on {CAMPAIGN_TRIES} campaigns ({why})")


def _build(family: str, seed: int, rows: tuple[int, int], later_rows: tuple[int, int], attempt: int) -> Instance:
    r_setup, r_plan, r_time, r_eff, r_noise, r_size = streams(family, seed, attempt)
    fam = FAMILIES.get(family)
    robot, inst, stations, params, tool2flange, bodies, masses = _draw_setup(r_setup, family)
    n_data = int(r_plan.integers(rows[0], rows[1] + 1))
    n_later = int(r_plan.integers(later_rows[0], later_rows[1] + 1))
    Q, st, box, order_kind = _draw_plan(r_plan, robot, inst, stations, n_data, n_later)
    t, timing = cell.times(r_time, Q, st, n_data)
    air = wander = cell.temperature_wander(r_time, t)
    temp_written = bool(r_time.uniform() < 0.3)
    B_rows = np.stack([stations[s].base2meas for s in st])
    F = robot.frames(params, Q)
    ctx = Ctx(robot=robot, params=params, Q=Q, F=F, t=t, station=st, n_data=n_data, bodies=bodies,
              base2meas=np.stack([s.base2meas for s in stations]), points_tool=inst.points_tool, air_c=air)
    P0 = chain_points(robot, params, Q, None, B_rows, tool2flange, inst.points_tool)
    noise = np.zeros_like(P0)
    for s, station in enumerate(stations):
        sel = st == s
        noise[sel] = cell.noise(r_noise, inst, P0[sel], station)
    noise_rms = rms_norm(noise[:n_data])
    drawn = {"family": family, "seed": int(seed), "robot": robot.name, "instrument": inst.kind, "K": inst.K,
             "stations": len(stations), "rows": n_data, "later_rows": n_later, "order": order_kind,
             "masses_stated": masses is not None, "span_s": round(float(t[n_data - 1] - t[0]), 1),
             "box_deg": np.round(box * DEG_PER_RAD, 1).tolist(), **timing,
             "noise_rms_mm": round(noise_rms * MM_PER_M, 5)}
    p_eff, key, P = None, None, P0
    if family == MIXED or fam.draw is not None:
        J = column_basis(geometric_jacobian(robot, params, Q[:n_data], B_rows[:n_data], st[:n_data], tool2flange,
                                            inst.points_tool))
        chain = (robot, params, Q, B_rows, tool2flange, inst.points_tool)
        names = _mixed_families(r_eff) if family == MIXED else [family]
        parts = [(name, *_draw_effect(FAMILIES[name], r_eff, r_size, ctx, chain, J, P0, noise_rms, n_data))
                 for name in names]
        keys = []
        for name, p, eff, info, P1 in parts:
            if name == "thermal":
                air = air + air_profile(p, t, float(t[0]), float(t[n_data - 1] - t[0]))
                temp_written = bool(p["temp_column"])
            keys.append(_effect_key(name, p, ctx, P1 - P0, n_data, t))
        if family == MIXED:
            P = chain_points(*chain[:3], compose([part[2] for part in parts]), *chain[3:])
            p_eff, key = [part[1] for part in parts], keys
            drawn.update({"families": names, "components": [part[3] for part in parts],
                          "ratio_visible": round(rms_norm(visible_part(J, (P - P0)[:n_data])) / noise_rms, 4),
                          "effect_rms_mm": round(rms_norm((P - P0)[:n_data]) * MM_PER_M, 5)})
        else:
            (_, p_eff, _, info, P), = parts
            key = keys[0]
            drawn.update(info)
    air = air + r_time.normal(0, 0.02, len(t))  # the probe's noise (written to 0.01 K)
    M = P + noise
    stated = None
    if inst.kind == "tracker":
        stated = round(inst.noise["sigma0_mm"] + inst.noise["sigma_per_m_mm"] * 2.5, 5)
    elif r_noise.uniform() < 0.3:
        stated = round(noise_rms * MM_PER_M / np.sqrt(3), 5)
    if family == "clean":
        M, extras = _clean_extras(r_noise, M, noise_rms, st, n_data, inst.K)
        drawn.update(extras)
    drawn["temp_written"] = temp_written
    return Instance(family, int(seed), robot, inst, stations, params, tool2flange, bodies, Q, t, st, n_data, P, P0, M,
                    air, wander, temp_written, masses, stated, p_eff, key, drawn)


def _mixed_families(rng) -> list[str]:
    """The families of a campaign of several effects: ``MIXED_COUNT`` distinct slots, one family in each."""
    slots = list(MIXED_SLOTS)
    k = int(rng.integers(MIXED_COUNT[0], MIXED_COUNT[1] + 1))
    pick = sorted(int(i) for i in rng.choice(len(slots), k, replace=False))
    return [MIXED_SLOTS[slots[i]][int(rng.integers(len(MIXED_SLOTS[slots[i]])))] for i in pick]


def _draw_effect(fam, r_eff, r_size, ctx: Ctx, chain: tuple, J: np.ndarray, P0: np.ndarray, noise_rms: float,
                 n_data: int) -> tuple[dict, Effect, dict, np.ndarray]:
    """One family's instance on the campaign: drawn, sized to its drawn ratio to the noise, checked (module
    docstring); its parameters, its effect, what was drawn and the true points with it ``(N, K, 3)`` [m].
    ``chain``: ``(robot, params, Q, base2meas rows, tool2flange, points_tool)``."""
    why = []
    for attempt in range(MAX_TRIES):
        try:
            p = fam.draw(r_eff, ctx)
        except Redraw as exc:
            why.append(str(exc))
            continue
        ratio = float(np.exp(r_size.uniform(np.log(RATIO[0]), np.log(RATIO[1]))))
        e1 = chain_points(*chain[:3], fam.apply(p, ctx), *chain[3:]) - P0
        v1 = rms_norm(visible_part(J, e1[:n_data]))
        if v1 <= 0:
            why.append("an effect the geometry takes whole")
            continue
        p["scale"] = float(p["scale"] * ratio * noise_rms / v1)
        eff = fam.apply(p, ctx)
        bad = fam.check(p, ctx, eff)
        if bad:
            why.append(bad)
            continue
        P = chain_points(*chain[:3], eff, *chain[3:])
        vis = rms_norm(visible_part(J, (P - P0)[:n_data]))
        info = {"ratio_drawn": round(ratio, 4), "ratio_visible": round(vis / noise_rms, 4),
                "effect_rms_mm": round(rms_norm((P - P0)[:n_data]) * MM_PER_M, 5),
                "redraws": attempt, "redraw_reasons": sorted(set(why))}
        return p, eff, info, P
    raise NoInstance(f"{fam.name}: no plausible instance in {MAX_TRIES} draws ({sorted(set(why))[:3]}...)")


def _effect_key(family: str, p: dict, ctx: Ctx, E: np.ndarray, n_data: int, t: np.ndarray) -> dict:
    """The key's entry of one effect (its words, parameters, size and changes) from its displacement ``E`` ``(N, K,
    3)`` [m]."""
    key = {"family": family, **FAMILIES[family].words(p, ctx), "params": _jsonable(p)}
    nrm = np.linalg.norm(E, axis=-1)
    key["rms_mm"] = round(float(np.sqrt(np.mean(nrm[:n_data] ** 2))) * MM_PER_M, 6)
    key["test_rms_mm"] = round(float(np.sqrt(np.mean(nrm[n_data:] ** 2))) * MM_PER_M, 6)
    key["changes"] = _changes(family, p, t)
    return key


def _changes(family: str, p: dict, t: np.ndarray) -> list[dict]:
    def at(r, what):
        return {"row": int(r) + 1, "pose_id": int(r) + 1, "t_s": round(float(t[r]), 1), "what": what}

    if family in ("zero_step", "frame_change") or (family == "payload" and p["timing"] in ("on", "off")):
        return [at(p["row"], p.get("kind", p.get("timing", "step")))]
    if family == "zero_glitch" or (family == "payload" and p["timing"] == "window"):
        return [at(p["row"], "start"), at(p["end_row"], "end")]
    return []


def _clean_extras(rng, M, noise_rms, st, n_data, K):
    """The clean family's own trouble, none of it the robot's: noise correlated in time (the instrument's frame
    wandering as an AR(1) of the rows), gross rows (one point matched to a wrong blob), a burst of noisy rows."""
    out = {}
    M = M.copy()
    N = len(M)
    if rng.uniform() < 0.6:
        rho, amp = float(rng.uniform(0.3, 0.85)), float(rng.uniform(0.2, 0.6))
        x = np.zeros((N, 3))
        for i in range(1, N):
            x[i] = rho * x[i - 1] + np.sqrt(1 - rho**2) * rng.normal(size=3) * amp * noise_rms / np.sqrt(3)
        M += x[:, None, :]
        out["correlated"] = {"rho": round(rho, 3), "amplitude_of_noise": round(amp, 3)}
    if rng.uniform() < 0.5:
        rows = sorted(int(r) for r in rng.choice(np.arange(5, n_data - 5), int(rng.integers(1, 4)), replace=False))
        for r in rows:
            d = rng.normal(size=3)
            M[r, int(rng.integers(K))] += d / np.linalg.norm(d) * rng.uniform(15, 60) * noise_rms
        out["gross_rows"] = [r + 1 for r in rows]
    if rng.uniform() < 0.3:
        L = int(rng.integers(3, 9))
        r0 = int(rng.integers(5, n_data - L - 5))
        f = float(rng.uniform(3, 5))
        M[r0:r0 + L] += rng.normal(size=M[r0:r0 + L].shape) * f * noise_rms / np.sqrt(3)
        out["burst"] = {"rows": [r0 + 1, r0 + L], "noise_factor": round(f, 2)}
    return M, out


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.floating,)):
        return float(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    return x


# ------------------------------------------------------------------------------------------ writers


def _f(x: float, nd: int) -> str:
    if not np.isfinite(x):
        return ""
    s = f"{x:.{nd}f}"
    return s[1:] if s.startswith("-") and float(s) == 0.0 else s


def _columns(inst: Instance) -> list[str]:
    cols = ["station"] if len(inst.stations) > 1 else []
    cols.append("t_s")
    if inst.temp_written:
        cols.append("temp_c")
    return cols


def _cell(inst: Instance, c: str, i: int) -> str:
    if c == "station":
        return str(int(inst.station[i]))
    if c == "t_s":
        return _f(inst.t[i], 1)
    return _f(round(float(inst.air_c[i]) + 0.0, 2), 2)


def write(inst: Instance, folder: str | Path) -> Path:
    """Write ``FOLDER/dataset/{poses.csv, dataset.toml}``, ``FOLDER/key/{key.json, sequence.csv, truth.json}``."""
    folder = Path(folder)
    (folder / "dataset").mkdir(parents=True, exist_ok=True)
    (folder / "key").mkdir(parents=True, exist_ok=True)
    K = inst.instrument.K
    pcols = [f"p{k}_{a}" for k in range(K) for a in XYZ]
    cols = _columns(inst)
    lines = [",".join(["pose_id"] + [f"q{j}" for j in range(1, 7)] + pcols + cols)]
    for i in range(inst.n_data):
        row = [str(i + 1)] + [_f(x, 4) for x in inst.Q[i] * DEG_PER_RAD] + [_f(x, 5) for x in inst.M[i].ravel() * MM_PER_M]
        lines.append(",".join(row + [_cell(inst, c, i) for c in cols]))
    (folder / "dataset" / "poses.csv").write_text("\n".join(lines) + "\n")

    toml = ["schema_version = 1"]
    robot_lines = robot_toml(inst.robot, inst.masses_stated)
    if robot_lines[0].startswith("robot ="):
        toml += robot_lines[:1]
        robot_lines = robot_lines[1:]
    what = ("a stereo rig measures the three-sphere plate" if inst.instrument.kind == "stereo"
            else "a laser tracker measures one reflector on the flange")
    toml.append(f'provenance = "drawn campaign {inst.name} (studies/drawn): {what} of an {inst.robot.name}"')
    if inst.instrument.kind == "stereo":
        toml += ["", "[plate]", f"sphere_diameter_mm = {cell.SPHERE_DIAMETER_MM}",
                 "spheres_mm = [" + ", ".join("[" + ", ".join(_f(x, 2) for x in s * MM_PER_M) + "]"
                                              for s in inst.instrument.points_tool) + "]"]
    else:
        toml += ["", "[markers]", 'unit = "mm"', "diameter_mm = 0.0",
                 "points_mm = [" + ", ".join("[" + ", ".join(_f(x, 3) for x in s * MM_PER_M) + "]"
                                             for s in inst.instrument.points_tool) + "]"]
    if inst.noise_stated_mm is not None:
        toml += ["", "[noise]", f"position_mm = {inst.noise_stated_mm}"]
    toml += robot_lines
    (folder / "dataset" / "dataset.toml").write_text("\n".join(toml) + "\n")

    seqcols = cols
    hdr = ["pose_id"] + [f"q{j}" for j in range(1, 7)] + seqcols + ["role"]
    for pre in "mte":
        hdr += [f"{pre}{k}_{a}" for k in range(K) for a in XYZ]
    lines = [",".join(hdr)]
    E = inst.E
    for i in range(len(inst.Q)):
        row = [str(i + 1)] + [_f(x, 4) for x in inst.Q[i] * DEG_PER_RAD] + [_cell(inst, c, i) for c in seqcols]
        row.append("data" if i < inst.n_data else "test")
        row += [_f(x, 5) for x in inst.M[i].ravel() * MM_PER_M]
        row += [_f(x, 6) for x in inst.P[i].ravel() * MM_PER_M]
        row += [_f(x, 6) for x in E[i].ravel() * MM_PER_M]
        lines.append(",".join(row))
    (folder / "key" / "sequence.csv").write_text("\n".join(lines) + "\n")

    if inst.family == MIXED:
        category = "mixed"
        expected = sorted({n for k in inst.effect_keys for n in FAMILIES[k["family"]].expected})
    else:
        category, expected = FAMILIES[inst.family].category, list(FAMILIES[inst.family].expected)
    key = {"schema_version": 1, "name": inst.name, "category": category, "expected_names": expected,
           "effects": inst.effect_keys,
           "noise": {"instrument": inst.instrument.kind, **inst.instrument.noise,
                     "rms_per_point_mm": inst.drawn["noise_rms_mm"], "stated_mm": inst.noise_stated_mm},
           "seed": [SEED_BASE, MIXED_INDEX if inst.family == MIXED else FAMILY_ORDER.index(inst.family), inst.seed],
           "drawn": _jsonable(inst.drawn),
           "notes": "drawn by studies/drawn/generator (it imports no part of the diagnosis)"}
    (folder / "key" / "key.json").write_text(json.dumps(key, indent=1) + "\n")
    truth = {"robot": inst.robot.name, "convention": inst.robot.convention,
             "true_parameters": params_record(inst.params, inst.robot.beta_joints),
             "tool2flange": np.round(inst.tool2flange, 15).tolist(),
             "base2meas": [np.round(s.base2meas, 15).tolist() for s in inst.stations],
             "points_tool_mm": (inst.instrument.points_tool * MM_PER_M).tolist(),
             "bodies": [[int(f), float(m), (np.asarray(c) * MM_PER_M).tolist()] for f, m, c in inst.bodies],
             "station": inst.station.tolist(), "t_s": inst.t.tolist(), "n_data": inst.n_data,
             "air_wander_c": inst.air_wander_c.tolist()}
    (folder / "key" / "truth.json").write_text(json.dumps(truth) + "\n")
    return folder


def read_context(folder: str | Path) -> tuple[Ctx, dict, dict]:
    """The campaign's context rebuilt from its written files alone (``key/truth.json``, ``key/sequence.csv``), the
    truth and the key: what :func:`recompute_effect` needs."""
    folder = Path(folder)
    truth = json.loads((folder / "key" / "truth.json").read_text())
    key = json.loads((folder / "key" / "key.json").read_text())
    robot = ROBOTS[truth["robot"]]
    params = params_from_record(truth["true_parameters"])
    import csv

    with open(folder / "key" / "sequence.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    Q = np.array([[float(r[f"q{j}"]) for j in range(1, 7)] for r in rows]) * RAD_PER_DEG
    t = np.array([float(r["t_s"]) for r in rows])
    bodies = tuple((f, m, np.asarray(c) * M_PER_MM) for f, m, c in truth["bodies"])
    ctx = Ctx(robot=robot, params=params, Q=Q, F=robot.frames(params, Q), t=t, station=np.array(truth["station"]),
              n_data=int(truth["n_data"]), bodies=bodies, base2meas=np.array(truth["base2meas"]),
              points_tool=np.array(truth["points_tool_mm"]) * M_PER_MM, air_c=np.array(truth["air_wander_c"]))
    return ctx, truth, key


def recompute_effect(folder: str | Path) -> np.ndarray:
    """The effect ``(N, K, 3)`` [m] recomputed from the key's parameters and the truth file (no random draw)."""
    ctx, truth, key = read_context(folder)
    T = np.array(truth["tool2flange"])
    B_rows = ctx.base2meas[ctx.station]
    P0 = chain_points(ctx.robot, ctx.params, ctx.Q, None, B_rows, T, ctx.points_tool)
    if not key["effects"]:
        return np.zeros_like(P0)
    eff = compose([FAMILIES[e["family"]].apply(e["params"], ctx) for e in key["effects"]])
    return chain_points(ctx.robot, ctx.params, ctx.Q, eff, B_rows, T, ctx.points_tool) - P0
