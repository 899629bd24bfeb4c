"""A calibrated robot in a new session: keep the robot model, re-identify the measurement frame (and the tool if
asked) from a few rows, predict the rest (``docs/estimator.md``, "A calibrated robot in a new session").

A robot calibrated in one session is moved, or its instrument is placed anew: the robot's parameters hold, the
``base2meas`` of the new station (and perhaps ``tool2flange``) does not. :func:`register` estimates only those
frames from the selected rows of the new session, every other parameter of the calibration held;
:func:`select_rows` picks the rows (the first N measured rows, given pose ids, a ``set``), and
:func:`prediction_errors` states a calibration's error on any measured rows.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Callable, Sequence

import numpy as np

from ..dataset import Dataset
from ..transforms import matrix_to_rotvec, transform_to_pose6
from ..units import M_PER_MM, RAD_PER_DEG
from .calibration import Calibration, Prediction
from .chain import Chain
from .core import error_summary, register_bases
from .identifiability import analyse_jacobian
from .problem import Observations, ParamSpace, Residuals, absolute_residuals, observations_from_dataset
from .solvers import GNResult, TraceEntry, covariance, gauss_newton

__all__ = ["Registration", "register", "select_rows", "check_same_robot", "prediction_errors", "session_residuals",
           "SESSION_COLUMN", "MARKER_SHAPE_TOL_M", "PredictFn"]

SESSION_COLUMN = "session"  # the poses.csv column naming a row's recording session (docs/formats.md)
MARKER_SHAPE_TOL_M = 1.0 * M_PER_MM  # [m] (+ 1 % of the set's size): a session's marker set is the calibration's when its
# pairwise distances agree to this (an import fits them with the nominal robot)
_FD_STEP = 1e-6  # [m] and [rad]: central-difference step of the Jacobian through a prediction function
_XTOL_PREDICT = 1e-10  # [m] and [rad]: convergence step through a prediction function

#: ``predict(calibration, rows) -> Prediction``: the prediction of the dataset rows ``rows`` ``(k,)`` (indices, in
#: measurement order) by ``calibration``; how an extended calibration's effects enter (e.g. with
#: ``twin.diagnosis.apply.predict_extended`` over the dataset's rows in order, which the command layer supplies).
PredictFn = Callable[[Calibration, np.ndarray], Prediction]


@dataclass(frozen=True, eq=False)
class Registration:
    """Result of :func:`register`.

    ``calibration``: the input calibration with the registered stations' ``base2meas`` (and ``tool2flange`` when
    ``tool``) replaced, its other stations kept, the registration in ``details["registration"]``. ``stations``: the
    registered stations; ``rows`` ``(k,)``: the dataset rows used (indices, measurement order), ``pose_id`` ``(k,)``;
    ``start``: ``base2meas`` ``(4, 4)`` per registered station from the closed-form start; ``residuals``: the error
    on the rows used (``{n_rows, position_mm: {mean, rms, max, min}}``, ``orientation_deg`` for poses, ``n_spheres``
    for points); ``residual_scale``: RMS whitened residual over the redundancy; ``converged``, ``iterations``,
    ``trace``: the Gauss-Newton iterations.
    """

    calibration: Calibration
    stations: tuple[str, ...]
    tool: bool
    rows: np.ndarray
    pose_id: np.ndarray
    start: dict[str, np.ndarray]
    residuals: dict[str, Any]
    residual_scale: float
    converged: bool
    iterations: int
    trace: tuple[TraceEntry, ...]
    session: tuple[str, ...] | None


def register(
    calibration: Calibration,
    dataset: Dataset,
    rows: Sequence[int] | np.ndarray,
    *,
    tool: bool = False,
    predict: PredictFn | None = None,
    max_iter: int = 50,
) -> Registration:
    """Re-identify the measurement frame of the stations of ``rows`` (and ``tool2flange`` when ``tool``) with the
    robot model of ``calibration`` held.

    ``rows``: dataset row indices ``(k,)`` or a bool mask ``(n,)``, each a row with a measurement (points or a
    6-DOF pose). ``predict``: required when ``calibration`` has ``effects`` (an extended calibration: the
    estimator cannot evaluate them; see :data:`PredictFn`), None for a geometric one.

    Model and residuals. The row ``i`` of station ``s`` is predicted as ``y_i = B_s g(q_i) T`` with the robot's
    forward kinematics ``g`` (held, and with an extended calibration its effects, evaluated from the rows in
    measurement order), ``T = tool2flange`` and ``B_s = base2meas`` of the station, ``B = [R(r) | t]``, ``theta_s =
    (t, r)`` (translation [m], rotation vector [rad]). Whitened residuals as in ``calibrate``: measured minus
    predicted marker points ``/ sigma_p``; for 6-DOF rows the position ``/ sigma_p`` and ``log(R_meas R_pred^T) /
    sigma_o``. The sigmas are ``dataset.toml``'s ``[noise]`` when it states them, else the calibration's noise.

    Estimate. ``min_theta sum_i |e_i(theta)|^2`` over ``theta = (theta_s for each station of the rows [,
    tool2flange's six])``: a closed-form start (rigid registration of the calibrated model's points onto the
    measured ones: :func:`~twin.estimator.core.register_bases`), then Gauss-Newton with Levenberg-Marquardt
    safeguarding on the column-scaled Jacobian (:func:`~twin.estimator.solvers.gauss_newton`). The Jacobian is the
    estimator's analytic one (:func:`~twin.estimator.problem.absolute_residuals`) for a geometric calibration, and
    central differences of ``predict`` (step 1e-6 m / rad) otherwise: ``J_k = -(e(theta + h u_k) - e(theta - h
    u_k)) / 2h`` (converged there when no parameter moves by 1e-10 m / rad: the prediction's rounding). Refused (``ValueError`` naming the cause): fewer scalar equations than the 6 (12) parameters, or
    rows that leave a combination of them undetermined (the rank-revealing analysis of the identifiability names
    it: e.g. the tool's rotation with one point per row, base and tool from rows at one configuration).

    Covariance (when the calibration has one). ``theta`` is estimated with the robot parameters ``rho`` held at
    values with covariance ``C_rho``: ``delta theta = A delta rho + (J_t^T J_t)^-1 J_t^T e`` with ``A = -(J_t^T
    J_t)^-1 J_t^T J_rho`` (whitened Jacobians at the solution; ``J_rho`` of the geometric model), so
    ``C_theta = A C_rho A^T + s^2 (J_t^T J_t)^-1`` and ``C_{theta rho} = A C_rho``, with ``s^2 = max(1, S / (m -
    p))`` the residual scale (``m`` residuals, ``p`` parameters): ``twin predict``'s standard deviations then
    carry both the robot's and the registration's uncertainty.

    The result keeps the calibration's other stations (a station of the same name is replaced) and its effects
    as they are; history-dependent terms read the rows as ``predict`` gives them (a new session starts a new
    history where the ``session`` column changes or in a file of its own).
    """
    _check_arguments(calibration, dataset, tool, predict, max_iter)
    check_same_robot(calibration, dataset)
    idx = _row_indices(dataset, rows)
    obs_all, obs, registered = _registration_rows(calibration, dataset, idx, tool)
    setup = _parameter_space(calibration, obs_all, obs, registered, tool)
    sp, obs, free, template = setup.space, setup.obs, setup.free, setup.template
    fun = _residual_function(sp, obs, template, free, idx, dataset, predict)
    res0 = fun(setup.x0)
    _check_determined(res0, sp, free, obs.n, tool)
    # through a prediction function the residuals carry its rounding (~1e-12 m): a step below 1e-10 m / rad is none
    gn = gauss_newton(fun, setup.x0, free, res0=res0, max_iter=max_iter, stage="register",
                      **({} if predict is None else {"xtol": _XTOL_PREDICT}))
    x = gn.x
    res = gn.residuals
    m, p = res.r.size, free.size
    s2 = float(gn.cost / (m - p)) if m > p else float("nan")
    old = calibration
    cov = None
    if old.covariance is not None:
        cov = _covariance(old, sp, x, obs, res.J[:, free], free, s2)
    new = replace(template, x=x, covariance=cov)
    pred = _predict(new, dataset, idx, predict)
    stats = _errors(obs, pred, idx, dataset)
    sessions = _sessions(dataset, idx)
    info = _registration_info(old, dataset, idx, obs, registered, tool, sessions, stats, s2, gn)
    details = dict(old.details)
    details["registration"] = info
    where = f" of session {', '.join(sessions)}" if sessions else ""
    note = (f"base2meas of station(s) {', '.join(repr(s) for s in registered)}{' and the tool' if tool else ''} "
            f"re-registered on {idx.size} rows{where} of {info['dataset'] or 'a dataset in memory'} (robot model held)")
    new = replace(new, details=details, notes=tuple(old.notes) + (note,))
    return Registration(
        calibration=new,
        stations=registered,
        tool=bool(tool),
        rows=idx,
        pose_id=dataset.pose_id[idx].copy(),
        start=setup.start,
        residuals=stats,
        residual_scale=float(np.sqrt(s2)) if np.isfinite(s2) else float("nan"),
        converged=bool(gn.converged),
        iterations=int(gn.iterations),
        trace=gn.trace,
        session=sessions,
    )


def _check_arguments(calibration, dataset, tool, predict, max_iter) -> None:
    """``ValueError`` naming the argument of :func:`register` that is not what it must be."""
    if not isinstance(calibration, Calibration):
        raise ValueError(f"calibration must be a twin.estimator.Calibration, got {type(calibration).__name__}")
    if not isinstance(dataset, Dataset):
        raise ValueError(f"dataset must be a twin.dataset.Dataset, got {type(dataset).__name__}")
    if not isinstance(tool, (bool, np.bool_)):
        raise ValueError(f"tool must be True or False, got {tool!r}")
    if predict is not None and not callable(predict):
        raise ValueError(f"predict must be a function (calibration, rows) -> Prediction, got {type(predict).__name__}")
    if calibration.effects and predict is None:
        labels = "; ".join(str(e.get("label", e.get("family", "?"))) for e in calibration.effects if isinstance(e, dict))
        raise ValueError(
            f"calibration has effects ({labels}): pass predict= (e.g. twin.diagnosis.apply.predict_extended over the "
            "dataset's rows, as `twin register` does); registering with the geometric model alone would misplace "
            "the frame")
    if not (isinstance(max_iter, (int, np.integer)) and max_iter >= 1):
        raise ValueError(f"max_iter must be a positive integer, got {max_iter!r}")


def _registration_rows(calibration: Calibration, dataset: Dataset, idx: np.ndarray,
                       tool: bool) -> tuple[Observations, Observations, tuple[str, ...]]:
    """The observations of every measured row, those of the rows ``idx`` and the stations they register; refused
    when they give fewer scalar equations than the parameters (6 per station, 6 more with the tool)."""
    obs_all, kept = _observations(calibration, dataset)
    pos = _positions(dataset, kept, idx)
    obs = obs_all.subset(pos)
    registered = tuple(obs_all.station_names[k] for k in sorted(set(obs.station.tolist())))
    n_free = 6 * len(registered) + (6 if tool else 0)
    m = int(obs.seen.sum()) * 3 if obs.kind == "spheres" else 6 * obs.n
    if m < n_free:
        per = "marker coordinates" if obs.kind == "spheres" else "pose components"
        raise ValueError(f"rows: {obs.n} row(s) give {m} {per}, fewer than the {n_free} parameters (6 per station"
                         f"{' + 6 of the tool' if tool else ''}); give more rows")
    return obs_all, obs, registered


@dataclass(frozen=True)
class _Setup:
    """The registration's parameter space: the calibration's stations with the registered ones (a registered
    station replacing one of the same name), the start ``x0`` (the registered bases in closed form), the free
    parameters, the observations relabelled to the space's stations and the calibration it fills in."""

    space: ParamSpace
    obs: Observations
    x0: np.ndarray
    free: np.ndarray
    start: dict[str, np.ndarray]
    template: Calibration


def _parameter_space(old: Calibration, obs_all: Observations, obs: Observations, registered: tuple[str, ...],
                     tool: bool) -> _Setup:
    """The parameter space, start and free parameters of a registration (see :class:`_Setup`)."""
    old_sp = old.space
    stations = tuple(s for s in old.stations) + tuple(s for s in registered if s not in old.stations)
    sp = ParamSpace(old_sp.chain, stations)
    P = sp.size
    x0 = np.empty(P)
    xn = np.empty(P)
    x0[: sp.n_rt] = old.x[: old_sp.n_rt]
    xn[: sp.n_rt] = old.x_nominal[: old_sp.n_rt]
    status = list(old.status[: old_sp.n_rt]) + ["identified"] * (6 * len(stations))
    for k, s in enumerate(stations):
        if s in old.stations:
            j = old_sp.station_index(s)
            x0[sp.base_slice(k)] = old.x[old_sp.base_slice(j)]
            xn[sp.base_slice(k)] = old.x_nominal[old_sp.base_slice(j)]
            status[sp.base_slice(k)] = old.status[old_sp.base_slice(j)]
    st_new = np.array([stations.index(obs_all.station_names[k]) for k in obs.station], dtype=int)
    obs = replace(obs, station=st_new, station_names=stations)
    # closed-form start of every registered station (the calibrated robot and tool)
    reg_sp = ParamSpace(sp.chain, registered)
    reg_obs = replace(obs, station=np.array([registered.index(stations[k]) for k in obs.station], dtype=int),
                      station_names=registered)
    xs = register_bases(reg_sp, np.concatenate([x0[: sp.n_rt], np.zeros(6 * len(registered))]), reg_obs)
    start = {}
    for k, s in enumerate(registered):
        b = xs[reg_sp.base_slice(k)]
        x0[sp.base_slice(stations.index(s))] = b
        xn[sp.base_slice(stations.index(s))] = b
        start[s] = reg_sp.bases(xs)[s]
    free = np.concatenate([np.arange(sp.base_slice(stations.index(s)).start, sp.base_slice(stations.index(s)).stop)
                           for s in registered])
    for k in free:
        status[k] = "identified"
    if tool:
        free = np.concatenate([np.arange(sp.tool_slice.start, sp.tool_slice.stop), free])
        for k in range(sp.tool_slice.start, sp.tool_slice.stop):
            status[k] = "identified"
    template = replace(old, stations=stations, x=x0, x_nominal=xn, status=tuple(status), covariance=None)
    return _Setup(space=sp, obs=obs, x0=x0, free=free, start=start, template=template)


def _residual_function(sp: ParamSpace, obs: Observations, template: Calibration, free: np.ndarray, idx: np.ndarray,
                       dataset: Dataset, predict: PredictFn | None) -> Callable[[np.ndarray], Residuals]:
    """The whitened residuals and their Jacobian at ``x``: the estimator's analytic ones for a geometric
    calibration, central differences of ``predict`` over the free parameters otherwise."""
    if predict is None:
        def fun(x: np.ndarray) -> Residuals:
            return absolute_residuals(sp, x, obs)
        return fun

    P = sp.size

    def resid(x: np.ndarray) -> np.ndarray:
        pred = predict(replace(template, x=x), idx)
        return _residuals_from_prediction(obs, pred, idx, dataset).r

    def fun(x: np.ndarray) -> Residuals:
        pred = predict(replace(template, x=x), idx)
        res = _residuals_from_prediction(obs, pred, idx, dataset)
        J = np.zeros((res.r.size, P))
        for k in free:
            e = np.zeros(P)
            e[k] = _FD_STEP
            J[:, k] = -(resid(x + e) - resid(x - e)) / (2.0 * _FD_STEP)
        return replace(res, J=J)
    return fun


def _check_determined(res0: Residuals, sp: ParamSpace, free: np.ndarray, n_rows: int, tool: bool) -> None:
    """Refuse rows that leave a combination of the free parameters undetermined, naming it."""
    ida = analyse_jacobian(res0.J[:, free], [sp.names[k] for k in free])
    if ida.dropped:
        raise ValueError(
            f"rows: the {n_rows} rows given cannot determine {', '.join(ida.dropped)} "
            f"({'; '.join(c.describe() for c in ida.combinations)}); measure more varied configurations"
            + (" (the tool needs rows whose orientations differ about two axes)" if tool else ""))


def _registration_info(old: Calibration, dataset: Dataset, idx: np.ndarray, obs: Observations,
                       registered: tuple[str, ...], tool: bool, sessions: tuple[str, ...] | None,
                       stats: dict[str, Any], s2: float, gn: GNResult) -> dict[str, Any]:
    """``details.registration`` of the registered calibration (``docs/formats.md``)."""
    return {
        "dataset": str(dataset.path) if dataset.path else "",
        "session": list(sessions) if sessions is not None else None,
        "stations": list(registered),
        "tool": bool(tool),
        "rows": [int(v) for v in dataset.pose_id[idx]],
        "n_rows": int(idx.size),
        "measurement": obs.kind,
        "noise": {"position_mm": obs.sigma_position / M_PER_MM,
                  **({"orientation_rad": obs.sigma_orientation} if obs.kind == "pose" else {})},
        "residuals": stats,
        "residual_scale": float(np.sqrt(s2)) if np.isfinite(s2) else None,
        "iterations": int(gn.iterations),
        "converged": bool(gn.converged),
        "start": "closed-form rigid registration of the calibrated model's points onto the measured ones",
        "effects": "applied (held)" if old.effects else "none",
        "base2meas_before": {s: _pose_json(old.base2meas[s]) for s in registered if s in old.stations},
    }


def select_rows(
    dataset: Dataset,
    *,
    first: int | None = None,
    pose_ids: Sequence[int] | np.ndarray | None = None,
    set_: str | None = None,
    session: str | None = None,
    station: str | None = None,
) -> np.ndarray:
    """Dataset row indices ``(k,)`` in measurement order: the rows with a measurement (points or a pose), of
    ``session`` and ``station`` when given, then exactly one of: the ``first`` N of them, those whose pose id is in
    ``pose_ids``, those of ``set_`` (the ``set`` column). ``ValueError`` naming the argument and its value."""
    if not isinstance(dataset, Dataset):
        raise ValueError(f"dataset must be a twin.dataset.Dataset, got {type(dataset).__name__}")
    given = [k for k, v in (("first", first), ("pose_ids", pose_ids), ("set_", set_)) if v is not None]
    if len(given) != 1:
        raise ValueError(f"give exactly one of first, pose_ids, set_ (got {given or 'none'})")
    measured = dataset.sphere_seen.any(axis=1) | dataset.pose_seen
    ok = measured.copy()
    what = []
    if session is not None:
        col = dataset.extra.get(SESSION_COLUMN)
        if col is None:
            raise ValueError(f"session {session!r}: the dataset has no '{SESSION_COLUMN}' column")
        vals = np.asarray(col).astype(str)
        if str(session) not in set(vals.tolist()):
            raise ValueError(f"session {session!r} is not in the dataset (sessions: {_listed(vals)})")
        ok &= vals == str(session)
        what.append(f"session {session!r}")
    if station is not None:
        st = dataset.station_ids.astype(str)
        if str(station) not in set(st.tolist()):
            raise ValueError(f"station {station!r} is not in the dataset (stations: {_listed(st)})")
        ok &= st == str(station)
        what.append(f"station {station!r}")
    scope = f" of {' and '.join(what)}" if what else ""
    cand = np.flatnonzero(ok)
    if first is not None:
        if isinstance(first, bool) or not isinstance(first, (int, np.integer)) or first < 1:
            raise ValueError(f"first must be a positive integer, got {first!r}")
        if first > cand.size:
            raise ValueError(f"first {first}: the dataset has only {cand.size} measured rows{scope}")
        return cand[: int(first)]
    if set_ is not None:
        if dataset.set is None:
            raise ValueError(f"set {set_!r}: the dataset has no 'set' column")
        sel = cand[np.asarray(dataset.set)[cand] == set_]
        if sel.size == 0:
            raise ValueError(f"set {set_!r}: no measured rows{scope} have set = {set_!r}")
        return sel
    ids = np.asarray(pose_ids)
    if ids.ndim != 1 or ids.size == 0:
        raise ValueError(f"pose_ids must be a non-empty list of integers, got {pose_ids!r}")
    try:
        ids_i = ids.astype(np.int64)
    except (TypeError, ValueError):
        raise ValueError(f"pose_ids must be integers, got {pose_ids!r}") from None
    if ids.dtype.kind == "f" and not np.all(ids_i == ids):
        raise ValueError(f"pose_ids must be integers, got {pose_ids!r}")
    u, cnt = np.unique(ids_i, return_counts=True)
    dup = u[cnt > 1]
    if dup.size:
        raise ValueError(f"pose_ids: duplicate ids {dup[:10].tolist()}")
    where = {int(p): i for i, p in enumerate(dataset.pose_id)}
    missing = [int(p) for p in ids_i if int(p) not in where]
    if missing:
        raise ValueError(f"pose_ids: {len(missing)} id(s) not in the dataset: {missing[:10]}")
    sel = np.array(sorted(where[int(p)] for p in ids_i), dtype=int)
    unmeasured = sel[~measured[sel]]
    if unmeasured.size:
        raise ValueError(f"pose_ids: {unmeasured.size} row(s) without a measurement: pose_id "
                         f"{dataset.pose_id[unmeasured][:10].tolist()}")
    outside = sel[~ok[sel]]
    if outside.size:
        raise ValueError(f"pose_ids: {outside.size} row(s) not{scope}: pose_id {dataset.pose_id[outside][:10].tolist()}")
    return sel


def prediction_errors(calibration: Calibration, dataset: Dataset, rows: Sequence[int] | np.ndarray, *,
                      predict: PredictFn | None = None) -> dict[str, Any]:
    """The error of ``calibration`` on the measured dataset rows ``rows`` (indices ``(k,)`` or a bool mask):
    ``{n_rows, position_mm: {mean, rms, max, min}}`` per marker point (3-D distance, with ``n_spheres``) or per
    pose (position, and ``orientation_deg``: the angle of ``R_meas R_pred^T``). ``predict`` as in :func:`register`
    (required for an extended calibration). Rows of a station the calibration does not know are refused."""
    idx, obs = _rows_observed(calibration, dataset, rows, predict, known_stations=True)
    return _errors(obs, _predict(calibration, dataset, idx, predict), idx, dataset)


def session_residuals(calibration: Calibration, dataset: Dataset, rows: Sequence[int] | np.ndarray, *,
                      predict: PredictFn | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The whitened residuals of ``calibration`` on the dataset rows ``rows`` (indices ``(k,)`` or a bool mask), as
    :func:`register` fits them: ``(r, row, position, sigma_position)`` with ``r`` ``(m,)``, ``row`` ``(m,)`` the
    position in ``rows`` of each residual's row, ``position`` ``(m,)`` True for a position component (marker point
    or pose position, whitened by ``sigma_position`` [m]; the others are a pose's rotation). ``predict`` as in
    :func:`register`."""
    idx, obs = _rows_observed(calibration, dataset, rows, predict)
    res = _residuals_from_prediction(obs, _predict(calibration, dataset, idx, predict), idx, dataset)
    return res.r, res.row, res.block == 0, float(obs.sigma_position)


# ------------------------------------------------------------------------------------------------------------------
# internals
# ------------------------------------------------------------------------------------------------------------------

def _rows_observed(calibration: Calibration, dataset: Dataset, rows, predict: PredictFn | None, *,
                   known_stations: bool = False) -> tuple[np.ndarray, Observations]:
    """The checked row indices ``(k,)`` and their observations, for :func:`prediction_errors` and
    :func:`session_residuals` (``known_stations``: rows of a station the calibration lacks are refused)."""
    if not isinstance(calibration, Calibration):
        raise ValueError(f"calibration must be a twin.estimator.Calibration, got {type(calibration).__name__}")
    if not isinstance(dataset, Dataset):
        raise ValueError(f"dataset must be a twin.dataset.Dataset, got {type(dataset).__name__}")
    if calibration.effects and predict is None:
        raise ValueError("calibration has effects: pass predict= (see register)")
    check_same_robot(calibration, dataset)
    idx = _row_indices(dataset, rows)
    if known_stations:
        unknown = sorted({s for s in dataset.station_ids[idx].astype(str) if s not in calibration.stations})
        if unknown:
            raise ValueError(f"rows: station(s) {unknown} are not in the calibration (stations: "
                             f"{list(calibration.stations)})")
    obs_all, kept = _observations(calibration, dataset)
    return idx, obs_all.subset(_positions(dataset, kept, idx))


def _listed(v: np.ndarray, k: int = 12) -> str:
    u = list(dict.fromkeys(np.asarray(v).astype(str).tolist()))
    return ", ".join(repr(s) for s in u[:k]) + (f", ... ({len(u)} in all)" if len(u) > k else "")


def check_same_robot(cal: Calibration, ds: Dataset) -> None:
    """The dataset's robot must be the calibration's nominal robot (same chain, same nominal structure): a
    ``ValueError`` naming the dataset, both robots and the first parameter that differs otherwise."""
    a, b = cal.nominal, ds.robot
    if a.convention != b.convention or tuple(a.joint_names) != tuple(b.joint_names):
        raise ValueError(
            f"dataset {ds.path or '(in memory)'}: robot {b.name!r} ({b.convention}, joints {', '.join(b.joint_names)}) is "
            f"not the calibration's robot {a.name!r} ({a.convention}, joints {', '.join(a.joint_names)})")
    ca, cb = Chain.of(a), Chain.of(b)
    if ca.rt_names != cb.rt_names:
        raise ValueError(f"dataset {ds.path or '(in memory)'}: robot {b.name!r} has another parameter set than the "
                         f"calibration's robot {a.name!r}")
    ra, _ = ca.split_full(a.params)
    rb, _ = cb.split_full(b.params)
    n = ca.n_robot
    d = np.abs(ra[:n] - rb[:n])
    if d.size and d.max() > 1e-6:
        k = int(np.argmax(d))
        raise ValueError(
            f"dataset {ds.path or '(in memory)'}: the nominal robot differs from the calibration's: {ca.rt_names[k]} "
            f"{rb[k]:.9g} against {ra[k]:.9g} (SI); a dataset of another robot cannot be registered to this calibration")


def _row_indices(ds: Dataset, rows) -> np.ndarray:
    r = np.asarray(rows)
    if r.dtype == bool:
        if r.shape != (ds.n,):
            raise ValueError(f"rows: a mask must have shape ({ds.n},), got {r.shape}")
        r = np.flatnonzero(r)
    if r.ndim != 1 or r.size == 0:
        raise ValueError(f"rows must be a non-empty list of row indices (or a bool mask), got shape {r.shape}")
    if r.dtype.kind not in "iu":
        raise ValueError(f"rows must be integer row indices, got dtype {r.dtype}")
    if r.min() < 0 or r.max() >= ds.n:
        bad = r[(r < 0) | (r >= ds.n)]
        raise ValueError(f"rows: indices {bad[:10].tolist()} are outside the dataset's {ds.n} rows")
    if np.unique(r).size != r.size:
        raise ValueError("rows: an index is given twice")
    return np.sort(r.astype(int))


def _observations(cal: Calibration, ds: Dataset) -> tuple[Observations, np.ndarray]:
    """Every measured row of ``ds`` with the calibration's marker set and noise (``dataset.toml``'s when stated)."""
    if ds.has_spheres and ds.n_points != cal.spheres_tool.shape[0]:
        raise ValueError(f"dataset {ds.path or '(in memory)'}: {ds.n_points} marker points per row, the calibration's "
                         f"marker set has {cal.spheres_tool.shape[0]}")
    if ds.has_spheres:
        # the shape of the marker set (its pairwise distances): where a session's import placed it on the flange is a
        # start fitted with the nominal robot; the calibration's own placement (its tool) is what registers
        a, b = ds.plate.spheres_flange, cal.plate.spheres_flange
        da = np.linalg.norm(a[:, None] - a[None], axis=-1)
        db = np.linalg.norm(b[:, None] - b[None], axis=-1)
        d = np.abs(da - db)
        if d.size and d.max() > MARKER_SHAPE_TOL_M + 0.01 * db.max():
            i, j = np.unravel_index(int(np.argmax(d)), d.shape)
            raise ValueError(
                f"dataset {ds.path or '(in memory)'}: its marker set differs from the calibration's (distance p{i}-p{j} "
                f"{da[i, j] / M_PER_MM:.4f} mm against {db[i, j] / M_PER_MM:.4f} mm); another marker set needs a calibration of "
                "its own")
    sp = ds.noise_position if ds.noise_position is not None else _noise(cal, "position_mm", M_PER_MM)
    so = ds.noise_orientation if ds.noise_orientation is not None else _noise(cal, "orientation_rad", 1.0)
    obs, kept, _ = observations_from_dataset(ds, sigma_position=sp, sigma_orientation=so)
    return replace(obs, spheres_tool=np.asarray(cal.spheres_tool, dtype=float)), kept


def _noise(cal: Calibration, key: str, to_si: float) -> float | None:
    v = (cal.noise or {}).get(key)
    try:
        v = float(v) * to_si
    except (TypeError, ValueError):
        return None
    return v if np.isfinite(v) and v > 0 else None


def _positions(ds: Dataset, kept: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Positions of the dataset rows ``idx`` among the observations' rows ``kept``; rows without a measurement are
    refused by pose id."""
    pos = np.searchsorted(kept, idx)
    bad = (pos >= kept.size) | (kept[np.minimum(pos, kept.size - 1)] != idx)
    if bad.any():
        raise ValueError(f"rows: {int(bad.sum())} row(s) without a usable measurement: pose_id "
                         f"{ds.pose_id[idx[bad]][:10].tolist()}")
    return pos


def _predict(cal: Calibration, ds: Dataset, idx: np.ndarray, predict: PredictFn | None) -> Prediction:
    if predict is None:
        return cal.predict(ds.q[idx], ds.station_ids[idx])
    return predict(cal, idx)


def _check_prediction(pred: Prediction, n: int, ds: Dataset, idx: np.ndarray) -> None:
    if not isinstance(pred, Prediction) or pred.pose.shape != (n, 4, 4):
        shape = getattr(getattr(pred, "pose", None), "shape", None)
        raise ValueError(f"predict must return a Prediction of the {n} rows given (pose (n, 4, 4)), got "
                         f"{type(pred).__name__} with pose shape {shape}")
    off = np.asarray(pred.frame) != "measurement"
    if off.any():
        raise ValueError(f"predict gave rows outside a measurement frame: pose_id {ds.pose_id[idx[off]][:10].tolist()}")


def _residuals_from_prediction(obs: Observations, pred: Prediction, idx: np.ndarray, ds: Dataset) -> Residuals:
    """Whitened residuals in :func:`~twin.estimator.problem.absolute_residuals`' order from a prediction (no
    Jacobian)."""
    _check_prediction(pred, obs.n, ds, idx)
    if obs.kind == "spheres":
        pts = np.asarray(pred.spheres, dtype=float)
        res = (np.transpose(obs.spheres, (1, 2, 0)) - np.transpose(pts, (1, 2, 0))) / obs.sigma_position
        mask = np.broadcast_to(obs.seen.T[:, None, :], res.shape)
        rows = np.broadcast_to(np.arange(obs.n)[None, None, :], res.shape)
        r = res[mask]
        return Residuals(r=r, J=None, row=rows[mask], block=np.zeros(r.size, dtype=int))
    R = pred.pose[:, :3, :3]
    ep = (obs.pose_p - pred.pose[:, :3, 3]) / obs.sigma_position
    er = matrix_to_rotvec(obs.pose_R @ np.swapaxes(R, -1, -2)) / obs.sigma_orientation
    r = np.concatenate([ep.T.reshape(-1), er.T.reshape(-1)])
    return Residuals(r=r, J=None, row=np.tile(np.arange(obs.n), 6),
                     block=np.concatenate([np.zeros(3 * obs.n, int), np.ones(3 * obs.n, int)]))


def _errors(obs: Observations, pred: Prediction, idx: np.ndarray, ds: Dataset) -> dict[str, Any]:
    """Error statistics of a prediction on the observations' rows (as ``residual_stats``)."""
    _check_prediction(pred, obs.n, ds, idx)
    if obs.kind == "spheres":
        e = np.linalg.norm(obs.spheres - pred.spheres, axis=-1)[obs.seen]
        return {"n_rows": obs.n, "n_spheres": int(e.size), "position_mm": error_summary(e / M_PER_MM)}
    ep = np.linalg.norm(obs.pose_p - pred.pose[:, :3, 3], axis=-1)
    er = np.linalg.norm(matrix_to_rotvec(obs.pose_R @ np.swapaxes(pred.pose[:, :3, :3], -1, -2)), axis=-1)
    return {"n_rows": obs.n, "position_mm": error_summary(ep / M_PER_MM), "orientation_deg": error_summary(er / RAD_PER_DEG)}


def _sessions(ds: Dataset, idx: np.ndarray) -> tuple[str, ...] | None:
    col = ds.extra.get(SESSION_COLUMN)
    if col is None:
        return None
    return tuple(dict.fromkeys(np.asarray(col)[idx].astype(str).tolist()))


def _covariance(old: Calibration, sp: ParamSpace, x: np.ndarray, obs: Observations, Jt: np.ndarray,
                free: np.ndarray, s2: float) -> np.ndarray:
    """The new calibration's covariance ``(P, P)``: the calibration's over the held parameters, the registered
    ones' conditional covariance plus the held robot parameters' uncertainty carried through the fit (see
    :func:`register`)."""
    P = sp.size
    old_sp = old.space
    fr = set(free.tolist())
    # each held parameter of the new space and its index in the calibration's (by station, not by name: a
    # one-station space names its base without the @station suffix)
    held, ho = [], []
    for k in range(P):
        if k in fr:
            continue
        if k < sp.n_rt:
            j = k
        else:
            s = sp.stations[(k - sp.n_rt) // 6]
            if s not in old.stations:
                continue
            j = old_sp.base_slice(old_sp.station_index(s)).start + (k - sp.n_rt) % 6
        if old.status[j] == "identified":
            held.append(k)
            ho.append(j)
    C = np.zeros((P, P))
    C[np.ix_(held, held)] = old.covariance[np.ix_(ho, ho)]
    Ct = covariance(Jt) * max(1.0, s2 if np.isfinite(s2) else 1.0)
    # the held robot and tool parameters move the registered rows' predictions (the kept stations' bases do not)
    rt = [k for k in held if k < sp.n_rt]
    if rt:
        Jr = absolute_residuals(sp, x, obs).J[:, rt]
        A = -np.linalg.lstsq(Jt, Jr, rcond=None)[0]  # (p, r) = -(Jt^T Jt)^-1 Jt^T Jr
        Ct = Ct + A @ C[np.ix_(rt, rt)] @ A.T
        cross = A @ C[np.ix_(rt, held)]
        C[np.ix_(free, held)] = cross
        C[np.ix_(held, free)] = cross.T
    C[np.ix_(free, free)] = Ct
    return C


def _pose_json(T: np.ndarray) -> dict[str, float]:
    v = transform_to_pose6(T)
    return {"x_mm": float(v[0] / M_PER_MM), "y_mm": float(v[1] / M_PER_MM), "z_mm": float(v[2] / M_PER_MM),
            "rx_rad": float(v[3]), "ry_rad": float(v[4]), "rz_rad": float(v[5])}
