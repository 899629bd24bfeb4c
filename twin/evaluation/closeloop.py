"""Close-the-loop evaluation: datasets from the world's effects, effect sizes, truth beside diagnosis.

Evaluation code (it reads the world's truth). Two ways to make a dataset with an undeclared effect:

* :func:`synthetic_dataset` — the world's true sphere centres (effects applied by the world: compliance by
  MuJoCo statics, backlash from the command history, thermal from the campaign's time, ...) plus Gaussian
  noise at the instrument's measured level; no images. For tests and the detection-rate sweep.
* the rendered path — the runner's measure stage through images and the instrument (the close-loop study,
  ``studies/close_loop/``).

Plans (:func:`plan_poses`) follow what a real campaign can do: configurations the cameras see at each
station, measured station by station, every ``repeats_every``-th pose measured twice in a row (the noise
floor), calibration and validation rows alternating.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Sequence

import numpy as np

from ..dataset import Dataset, default_plate, robot_from_spec
from ..transforms import kabsch
from ..units import M_PER_MM, deg_to_rad

__all__ = ["Plan", "plan_poses", "synthetic_dataset", "effect_size", "true_model_error", "truth_effects",
           "effect_delta", "oracle_delta_fit"]


@dataclass(frozen=True)
class Plan:
    """Commanded joints ``q`` ``(n, 6)`` [rad] in measurement order, station index per row, set per row, time
    stamps ``t_s`` ``(n,)`` [s] (a fixed cadence), and which rows repeat the previous one."""

    q: np.ndarray
    stations: np.ndarray
    sets: np.ndarray
    t_s: np.ndarray
    repeat: np.ndarray


def plan_poses(world, per_station: int, *, repeats_every: int = 4, seed: int = 0, seconds_per_pose: float = 12.0,
               stations: Sequence[int] | None = None) -> Plan:
    """Visible configurations, station by station; calibration/validation alternate by configuration."""
    if per_station < 2:
        raise ValueError(f"per_station must be at least 2, got {per_station}")
    st_list = list(range(world.n_stations)) if stations is None else [int(s) for s in stations]
    q_rows, st_rows, set_rows, rep_rows = [], [], [], []
    k = 0
    for s in st_list:
        qs = _one_arm_branch(world.visible_configurations(s, 3 * per_station, seed=seed * 1000 + s))[:per_station]
        if len(qs) < per_station:
            raise RuntimeError(f"station {s}: only {len(qs)} visible configurations on one arm branch")
        for i, q in enumerate(qs):
            tag = "calibration" if k % 2 == 0 else "validation"
            reps = 2 if (repeats_every and i % repeats_every == 0) else 1
            for r in range(reps):
                q_rows.append(q)
                st_rows.append(s)
                set_rows.append(tag)
                rep_rows.append(r > 0)
            k += 1
    n = len(q_rows)
    return Plan(
        q=np.asarray(q_rows),
        stations=np.asarray(st_rows, dtype=int),
        sets=np.asarray(set_rows, dtype=object),
        t_s=np.arange(n) * float(seconds_per_pose),
        repeat=np.asarray(rep_rows, dtype=bool),
    )


def _one_arm_branch(q: np.ndarray, tol_deg: float = 60.0) -> np.ndarray:
    """Keep the configurations whose arm joints (1-3) lie within ``tol_deg`` of their median: an operator
    jogging a robot in front of a camera stays on one shoulder/elbow branch (the world's sampler mixes
    branches; a far branch is an extrapolation no calibration campaign would test on)."""
    med = np.median(q[:, :3], axis=0)
    d = np.abs((q[:, :3] - med + np.pi) % (2 * np.pi) - np.pi)
    return q[np.all(d <= deg_to_rad(tol_deg), axis=1)]


def synthetic_dataset(world, plan: Plan, *, sigma: float, seed: int = 0, record_temp: bool = False,
                      record_time: bool = True, robot: str = "irb1200") -> tuple[Dataset, list]:
    """The world's true sphere centres for ``plan`` plus N(0, sigma^2) per coordinate [m].

    Nothing about the effects reaches the dataset: commanded joints, station, set, and, as a real instrument
    would, ``t_s`` (``record_time``) and ``temp_c`` (``record_temp``, the world's true temperature). The noise
    is not declared (the diagnosis takes its floor from the repeats). Returns the dataset and the captures
    (truth, for evaluation only).
    """
    caps = world.true_sequence(plan.q, list(plan.stations), t_s=plan.t_s)
    rng = np.random.default_rng(seed)
    n = len(caps)
    spheres = np.stack([c.spheres_meas for c in caps]) + rng.normal(0.0, sigma, (n, 3, 3))
    names = np.array([world.station_names[s] for s in plan.stations], dtype=object)
    temp = np.array([c.temp_c for c in caps], dtype=float) if record_temp else None
    ds = Dataset(
        robot=robot_from_spec(robot),
        robot_spec=robot,
        plate=default_plate(),
        pose_id=np.arange(n, dtype=np.int64),
        q=plan.q.copy(),
        spheres=spheres,
        sphere_seen=np.ones((n, 3), dtype=bool),
        pose=np.full((n, 4, 4), np.nan),
        pose_seen=np.zeros(n, dtype=bool),
        set=plan.sets.copy(),
        station=names,
        t_s=plan.t_s.copy() if record_time else None,
        temp_c=temp,
        provenance=f"twin.evaluation.closeloop.synthetic_dataset: world truth + N(0, {sigma / M_PER_MM:g} mm^2), seed {seed}",
    )
    return ds, caps


def effect_size(world_with_effect, plan: Plan, sigma: float, **kw) -> float:
    """What an effect leaves after a perfect geometric-only calibration, in noise sigmas per coordinate:
    the validation RMS per coordinate of the default estimator fitted to noise-free data with the effect."""
    from ..estimator import calibrate

    ds, _ = synthetic_dataset(world_with_effect, plan, sigma=0.0, **kw)
    ds = replace(ds, noise_position=1e-9)
    cal = calibrate(ds)
    return float(cal.residuals["validation"]["position_mm"]["rms"] * M_PER_MM / np.sqrt(3) / sigma)


def true_model_error(ds: Dataset, true_spheres: np.ndarray) -> dict[str, Any]:
    """Validation error of the true model (geometry + effects): its predictions are the true centres
    ``true_spheres`` ``(n, 3, 3)`` [m] of the dataset's rows. The true centres are in the true camera frame; a
    measured dataset is in the instrument's estimated frame, so each station's true centres are first brought
    over by the rigid fit of the calibration rows (the frame difference is what every calibration absorbs in
    ``base2meas``). What is left is the instrument's error."""
    true = np.asarray(true_spheres, dtype=float)
    if true.shape != ds.spheres.shape:
        raise ValueError(f"true_spheres must have the dataset's sphere shape {ds.spheres.shape}, got {true.shape}")
    aligned = true.copy()
    st = ds.station_ids
    for s in np.unique(st):
        cal = (st == s) & (ds.set == "calibration")
        seen = ds.sphere_seen[cal]
        R, t = kabsch(true[cal][seen], ds.spheres[cal][seen])
        rows = st == s
        aligned[rows] = true[rows] @ R.T + t
    val = np.flatnonzero(ds.set == "validation")
    e = np.linalg.norm(ds.spheres[val] - aligned[val], axis=-1)[ds.sphere_seen[val]] / M_PER_MM
    return {"n_rows": int(val.size), "position_mm": {"mean": float(e.mean()), "rms": float(np.sqrt(np.mean(e**2))),
                                                      "max": float(e.max())}}


def truth_effects(world) -> list[dict]:
    """The world's effects and their true parameters (for the evaluation table beside the identified ones)."""
    out = []
    for e in getattr(world, "effects", []):
        name = getattr(e, "name", type(e).__name__)
        params = e.params() if hasattr(e, "params") else {}
        out.append({"name": name, "params": params})
    return out


def effect_delta(world, plan: Plan) -> np.ndarray:
    """What the world's effects add to every measured sphere centre ``(n, 3, 3)`` [m]: the true centres of the
    plan with the effects minus those without (same true geometry, plate and stations). Evaluation only."""
    with_fx = world.true_sequence(plan.q, list(plan.stations), t_s=plan.t_s)
    saved = list(world.effects)
    world.effects = []
    try:
        without = world.true_sequence(plan.q, list(plan.stations), t_s=plan.t_s)
    finally:
        world.effects = saved
    return np.stack([c.spheres_meas for c in with_fx]) - np.stack([c.spheres_meas for c in without])


def oracle_delta_fit(ds: Dataset, delta: np.ndarray):
    """The oracle: the true effect known exactly (``delta``, :func:`effect_delta`) and the geometry
    re-identified on the same noisy calibration rows. The geometric model is fitted to ``measured - delta``;
    its validation error there equals that of ``geometric prediction + delta`` against the measurements.
    Works for every effect (robot, plate, base, instrument, changing in time), whatever its shape."""
    from ..diagnosis import fit_with_effects

    delta = np.asarray(delta, dtype=float)
    if delta.shape != ds.spheres.shape:
        raise ValueError(f"delta must have the dataset's sphere shape {ds.spheres.shape}, got {delta.shape}")
    return fit_with_effects(replace(ds, spheres=ds.spheres - delta), [])
