"""Shared steps of every identification method: reading a dataset into observations, the calibration /
validation split, the parameter space with one ``base2meas`` per station, closed-form registration of the
stations, bad-data checks, identifiability, and the statistics written into a :class:`Calibration`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from ..dataset import Dataset
from ..kinematics import RobotModel
from ..transforms import matrix_to_rotvec, transform_to_pose6
from ..units import M_PER_MM, RAD_PER_DEG
from .chain import Chain
from .identifiability import Identifiability, analyse_jacobian, preference_order
from .problem import (
    Observations,
    ParamSpace,
    absolute_residuals,
    kabsch,
    observations_from_dataset,
    predict_points,
)
from .solvers import TraceEntry, covariance

__all__ = [
    "Prepared",
    "Identified",
    "prepare",
    "register_bases",
    "check_design",
    "analyse",
    "residual_stats",
    "error_summary",
    "predicted_error",
    "ErrorModel",
]

ErrorModel = Literal["tmmdh", "structural"]


@dataclass(frozen=True, eq=False)
class Prepared:
    """A dataset made ready for identification (SI units).

    ``obs`` holds every usable row; ``cal`` / ``val`` index into it. ``x_nominal`` is the nominal robot and
    tool with each station's ``base2meas`` from a closed-form registration of the nominal model onto the
    calibration rows (or from ``dataset.toml`` when ``bases_given``).
    """

    dataset: Dataset
    nominal: RobotModel
    obs: Observations
    rows: np.ndarray
    skipped: tuple[tuple[int, str], ...]
    cal: np.ndarray
    val: np.ndarray
    split: str
    space: ParamSpace
    x_nominal: np.ndarray
    bases_given: tuple[str, ...]
    noise_given: dict[str, bool]
    notes: tuple[str, ...] = ()

    @property
    def obs_cal(self) -> Observations:
        return self.obs.subset(self.cal)

    @property
    def obs_val(self) -> Observations:
        return self.obs.subset(self.val)


@dataclass(frozen=True, eq=False)
class Identified:
    """What an identification method returns (before the statistics shared by all methods).

    ``x`` ``(P,)``; ``status`` per parameter (``identified``/``fixed``/``given``); ``covariance`` ``(P, P)``
    or None; ``inlier`` over the calibration rows; ``rejected`` ``(cal row index, reason)``; ``noise``
    (the sigmas used and where they came from); ``trace``.
    """

    x: np.ndarray
    status: tuple[str, ...]
    covariance: np.ndarray | None
    identifiability: Identifiability | None
    inlier: np.ndarray
    rejected: tuple[tuple[int, str], ...]
    noise: dict[str, Any]
    trace: tuple[TraceEntry, ...]
    notes: tuple[str, ...] = ()
    extra: dict[str, Any] = field(default_factory=dict)


def prepare(
    ds: Dataset,
    *,
    measurement: Literal["auto", "spheres", "pose"] = "auto",
    noise_position: float | None = None,
    noise_orientation: float | None = None,
    validation_fraction: float = 0.2,
    seed: int = 0,
    use_given_bases: bool = False,
) -> Prepared:
    """Observations, split, parameter space and registered station frames for ``ds``.

    ``noise_position`` [m] / ``noise_orientation`` [rad] override ``dataset.toml``'s ``[noise]``.
    Without a ``set`` column a seeded random ``validation_fraction`` of the rows is held out (and the
    split says so). ``use_given_bases``: start from (and, for the structural error model, keep) the
    stations' ``base2meas`` of ``dataset.toml`` instead of registering them.
    """
    if not isinstance(ds, Dataset):
        raise ValueError(f"dataset must be a twin.dataset.Dataset, got {type(ds).__name__}")
    if not (0.0 <= validation_fraction < 1.0):
        raise ValueError(f"validation_fraction must be in [0, 1), got {validation_fraction!r}")
    nominal = ds.robot
    _check_finite(ds)
    obs, rows, skipped = observations_from_dataset(
        ds,
        measurement=measurement,
        sigma_position=noise_position,
        sigma_orientation=noise_orientation,
        tool2flange_nominal=nominal.tool2flange,
    )
    noise_given = {
        "position": noise_position is not None or ds.noise_position is not None,
        "orientation": noise_orientation is not None or ds.noise_orientation is not None,
    }
    n = obs.n
    notes = []
    if ds.set is not None:
        sets = ds.set[rows]
        cal = np.flatnonzero(sets == "calibration")
        val = np.flatnonzero(sets == "validation")
        split = f"the dataset's 'set' column: {cal.size} calibration rows, {val.size} validation rows"
    else:
        rng = np.random.default_rng(seed)
        perm = rng.permutation(n)
        n_val = int(round(validation_fraction * n))
        val = np.sort(perm[:n_val])
        cal = np.sort(perm[n_val:])
        split = (
            f"no 'set' column: held out a seeded random {validation_fraction:.0%} of the rows for validation "
            f"(seed {seed}): {cal.size} calibration rows, {val.size} validation rows"
        )
        notes.append(split)
    if cal.size == 0:
        raise ValueError(f"dataset {ds.path}: no calibration rows with a usable measurement")
    space = ParamSpace(Chain.of(nominal), obs.station_names)
    x0 = space.from_model(nominal)
    given = tuple(s for s in obs.station_names if s in ds.stations_base2meas)
    if use_given_bases:
        missing = [s for s in obs.station_names if s not in ds.stations_base2meas]
        if missing:
            raise ValueError(f"use_given_bases: dataset.toml gives no base2meas for stations {missing}")
        for k, s in enumerate(space.stations):
            x0[space.base_slice(k)] = transform_to_pose6(ds.stations_base2meas[s])
    else:
        x0 = register_bases(space, x0, obs.subset(cal))
    return Prepared(
        dataset=ds,
        nominal=nominal,
        obs=obs,
        rows=rows,
        skipped=tuple(skipped),
        cal=cal,
        val=val,
        split=split,
        space=space,
        x_nominal=x0,
        bases_given=given if use_given_bases else (),
        noise_given=noise_given,
        notes=tuple(notes),
    )


def _check_finite(ds: Dataset) -> None:
    """Refuse non-finite joints or measurements (a dataset built in memory bypasses the file reader)."""
    bad = ~np.isfinite(ds.q)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise ValueError(
            f"dataset {ds.path or '(in memory)'}: row {i + 1} (pose_id {int(ds.pose_id[i])}), column "
            f"'{ds.robot.joint_names[j]}': "
            f"commanded joint is not finite ({ds.q[i, j]!r})"
        )
    sb = ds.sphere_seen[..., None] & ~np.isfinite(ds.spheres)
    if sb.any():
        i, s, c = np.argwhere(sb)[0]
        raise ValueError(
            f"dataset {ds.path or '(in memory)'}: row {i + 1} (pose_id {int(ds.pose_id[i])}), column 'p{s}_{'xyz'[c]}': "
            "point marked as seen but not finite"
        )
    pb = ds.pose_seen & ~np.all(np.isfinite(ds.pose.reshape(ds.n, -1)), axis=1)
    if pb.any():
        i = int(np.flatnonzero(pb)[0])
        raise ValueError(f"dataset {ds.path or '(in memory)'}: row {i + 1} (pose_id {int(ds.pose_id[i])}): pose marked as seen but not finite")


def register_bases(space: ParamSpace, x: np.ndarray, obs: Observations) -> np.ndarray:
    """Closed-form ``base2meas`` of every station: rigid registration (Kabsch) of the model's predicted
    points in the base frame onto the measured ones (sphere centres; for pose data the tool origin and
    three points 0.1 m along the tool axes). Uses nothing but the model and the measurements, so the
    result does not depend on any start value."""
    x = np.array(x, dtype=float)
    base_space = ParamSpace(space.chain, ("base",))
    xb = np.concatenate([x[: space.n_rt], np.zeros(6)])
    for k, s in enumerate(space.stations):
        idx = np.flatnonzero(obs.station == k)
        if idx.size == 0:
            raise ValueError(f"station {s!r} has no calibration rows: its base2meas cannot be registered")
        sub = obs.subset(idx)
        if sub.kind == "spheres":
            pred, _ = predict_points(base_space, xb, sub.q, np.zeros(idx.size, int), sub.spheres_tool)
            A = pred[sub.seen]
            B = sub.spheres[sub.seen]
        else:
            pts = np.concatenate([np.zeros((1, 3)), 0.1 * np.eye(3)])
            pred, _ = predict_points(base_space, xb, sub.q, np.zeros(idx.size, int), pts)
            meas = sub.pose_p[:, None, :] + 0.1 * np.concatenate(
                [np.zeros((idx.size, 1, 3)), np.swapaxes(sub.pose_R, 1, 2)], axis=1
            )
            A = pred.reshape(-1, 3)
            B = meas.reshape(-1, 3)
        if A.shape[0] < 3:
            raise ValueError(f"station {s!r}: fewer than three measured points, base2meas cannot be registered")
        R, t = kabsch(A, B)
        x[space.base_slice(k)] = np.concatenate([t, matrix_to_rotvec(R)])
    return x


def check_design(obs: Observations, n_free: int, what: str = "calibration") -> None:
    """Refuse data that cannot determine ``n_free`` parameters: no rows, every row the same joint
    configuration, or fewer scalar equations than parameters. ``ValueError`` naming the counts."""
    n = obs.n
    if n == 0:
        raise ValueError(f"no {what} rows")
    qr = np.round(obs.q, 9)
    distinct = np.unique(qr, axis=0).shape[0]
    if distinct == 1:
        raise ValueError(
            f"all {n} {what} rows have the same joint configuration: nothing about the kinematics can be "
            "identified from them"
        )
    if obs.kind == "spheres":
        m = int(obs.seen.sum()) * 3
        per = "sphere coordinates"
    else:
        m = 6 * n
        per = "pose components"
    if m < n_free:
        raise ValueError(
            f"{n} {what} rows give {m} {per}, fewer than the {n_free} parameters to identify; measure more poses "
            f"(at least {int(np.ceil(n_free / (m / n)))} with this instrument)"
        )


def analyse(
    space: ParamSpace,
    x: np.ndarray,
    obs: Observations,
    candidates: np.ndarray,
    *,
    gauge: Literal["frames", "structure"] = "frames",
    part: Literal["full", "position", "orientation"] = "full",
    tol: float = 1e-6,
) -> Identifiability:
    """Identifiability of the ``candidates`` (bool mask over ``space``) at ``x`` for the rows of ``obs``."""
    res = absolute_residuals(space, x, obs, part=part)
    names = [n for n, c in zip(space.names, candidates) if c]
    return analyse_jacobian(
        res.J, space.names, candidates=names, order=preference_order(names, gauge), tol=tol
    )


def generic_configurations(model: RobotModel, n: int = 60, seed: int = 12345) -> np.ndarray:
    """Random joint configurations ``(n, N)`` inside the limits (at most +-pi): a generic design for telling
    structural couplings from data-dependent ones."""
    rng = np.random.default_rng(seed)
    lo = np.maximum(model.q_min, -np.pi)
    hi = np.minimum(model.q_max, np.pi)
    return rng.uniform(lo, hi, (n, model.n_joints))


def residual_stats(space: ParamSpace, x: np.ndarray, obs: Observations) -> dict[str, Any]:
    """Error statistics of a model on rows: per sphere (3-D distance) or per pose (position [mm],
    orientation [deg]): ``{n_rows, position_mm: {mean, rms, max}, orientation_deg: {...}}``."""
    if obs.n == 0:
        return {"n_rows": 0}
    if obs.kind == "spheres":
        pred, _ = predict_points(space, x, obs.q, obs.station, obs.spheres_tool)
        e = np.linalg.norm(obs.spheres - pred, axis=-1)[obs.seen]
        return {"n_rows": obs.n, "n_spheres": int(e.size), "position_mm": error_summary(e / M_PER_MM)}
    from .problem import station_eval

    R, p, _ = station_eval(space, x, obs.q, obs.station, False)
    ep = np.linalg.norm(obs.pose_p - p, axis=-1)
    er = np.linalg.norm(matrix_to_rotvec(obs.pose_R @ np.swapaxes(R, -1, -2)), axis=-1)
    return {"n_rows": obs.n, "position_mm": error_summary(ep / M_PER_MM), "orientation_deg": error_summary(er / RAD_PER_DEG)}


def error_summary(e: np.ndarray) -> dict[str, float]:
    """The mean, RMS, largest and smallest of the errors ``e`` (any shape, in the unit they come in)."""
    return {
        "mean": float(np.mean(e)),
        "rms": float(np.sqrt(np.mean(e**2))),
        "max": float(np.max(e)),
        "min": float(np.min(e)),
    }


def predicted_error(space: ParamSpace, x: np.ndarray, cov: np.ndarray, obs: Observations) -> dict[str, float]:
    """The Cramer-Rao floor on rows: RMS over predicted points of ``sqrt(trace(J C J^T))``, the error of
    the identified model's predictions against the noise-free truth that the parameter covariance ``C``
    implies (for a correctly specified model). Spheres: per sphere 3-D [mm]; poses: position [mm] and
    orientation [deg]."""
    if obs.n == 0:
        return {}
    if obs.kind == "spheres":
        _, Jk = predict_points(space, x, obs.q, obs.station, obs.spheres_tool, jacobian=True)
        v = np.einsum("pkcn,pq,qkcn->nk", Jk, cov, Jk)  # (n, 3) summed over coordinates
        v = v[obs.seen]
        return {"position_mm": float(np.sqrt(np.mean(v)) / M_PER_MM)}
    from .problem import station_eval

    _, _, J = station_eval(space, x, obs.q, obs.station, True)
    vp = np.einsum("pcn,pq,qcn->n", J[:, :3], cov, J[:, :3])
    vr = np.einsum("pcn,pq,qcn->n", J[:, 3:], cov, J[:, 3:])
    return {"position_mm": float(np.sqrt(np.mean(vp)) / M_PER_MM), "orientation_deg": float(np.sqrt(np.mean(vr)) / RAD_PER_DEG)}


def full_covariance(space: ParamSpace, J_free: np.ndarray, free_idx: np.ndarray, row_weights=None) -> np.ndarray:
    """Covariance ``(P, P)`` with the free block from the whitened Jacobian and zeros elsewhere."""
    C = np.zeros((space.size, space.size))
    C[np.ix_(free_idx, free_idx)] = covariance(J_free, row_weights)
    return C
