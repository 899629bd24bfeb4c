"""Identification methods and the :func:`calibrate` entry point.

``best`` (the default, ours) is here; the papers' methods (``distance``, ``fullpose``, ``separation``,
``lm``, ``clm``) are in :mod:`twin.estimator.paper_methods`. Every method works on a
:class:`~twin.dataset.Dataset` (sphere centres or 6-DOF poses, any number of camera stations) and returns
a :class:`~twin.estimator.calibration.Calibration`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Literal

import numpy as np

from ..dataset import Dataset
from ..units import M_PER_MM, rad_to_deg
from .calibration import Calibration
from .core import (
    ErrorModel,
    Identified,
    Prepared,
    analyse,
    check_design,
    full_covariance,
    generic_configurations,
    predicted_error,
    prepare,
    residual_stats,
)
from .identifiability import analyse_jacobian, preference_order
from .problem import Observations, ParamSpace, absolute_residuals
from .solvers import TraceEntry, gauss_newton, robust_fit

__all__ = ["calibrate", "identify_best", "identifiability", "METHODS", "candidates", "build_calibration"]


LEVELS = ("full", "offsets", "frames")


def candidates(space: ParamSpace, error_model: ErrorModel, level: str = "full") -> np.ndarray:
    """Mask of the parameters an error model estimates: ``"tmmdh"`` all (robot structure, tool, a base per
    station: the TM-MDH paper's model, 37 for one station); ``"structural"`` the robot structure only (the
    separation paper's MDH+beta / the TM-MDH paper's DH+beta: base and tool held at their given values).

    ``level`` restricts the robot structure: ``"full"`` every geometric parameter of every joint,
    ``"offsets"`` the joint offsets only (``theta_i`` of a 6R chain, ``<joint>.offset`` of any chain),
    ``"frames"`` none (base and tool only)."""
    if level not in LEVELS:
        raise ValueError(f"level must be one of {LEVELS}, got {level!r}")
    if error_model == "tmmdh":
        m = np.ones(space.size, dtype=bool)
    elif error_model == "structural":
        m = np.zeros(space.size, dtype=bool)
        m[: space.n_robot] = True
    else:
        raise ValueError(f"error_model must be 'tmmdh' or 'structural', got {error_model!r}")
    if level != "full":
        joint = set(space.chain.structure.joint_params) if level == "offsets" else set()
        m[: space.n_robot] &= np.array([n in joint for n in space.names[: space.n_robot]], dtype=bool)
    if not m.any():
        raise ValueError(f"error_model {error_model!r} with level {level!r} leaves no parameter to estimate")
    return m


def _variance_components(res, J_w: np.ndarray, inl_rows: np.ndarray) -> dict[int, tuple[float, float]]:
    """Per residual block: (sum of squared whitened residuals, redundancy ``m_b - sum_b h_ii``) on inlier
    rows, with ``h`` the diagonal of the hat matrix of the whitened Jacobian."""
    sel = inl_rows[res.row]
    Q, _ = np.linalg.qr(J_w[sel])
    h = np.sum(Q**2, axis=1)
    out = {}
    for b in np.unique(res.block[sel]):
        mb = res.block[sel] == b
        out[int(b)] = (float(np.sum(res.r[sel][mb] ** 2)), float(np.sum(mb) - np.sum(h[mb])))
    return out


def identify_best(
    prep: Prepared,
    *,
    error_model: ErrorModel = "tmmdh",
    gauge: Literal["frames", "structure"] = "frames",
    robust: bool = True,
    alpha: float = 1e-3,
    level: str = "full",
    prior: dict[str, float] | None = None,
    selection: str = "ordered",
    callback: Callable[[TraceEntry], None] | None = None,
) -> Identified:
    """Our estimator: statistically weighted, column-scaled, robust, start-independent.

    1. Start: the nominal robot and tool, each station's ``base2meas`` from closed-form registration
       (:func:`~twin.estimator.core.register_bases`): no user start value is involved.
    2. Identifiability at the start (exact couplings at the nominal geometry): the unidentifiable
       parameters of each coupled set are fixed at nominal (``gauge`` says which member survives).
    3. Whitened residuals (sphere centres with the instrument's noise, or pose position / orientation
       with theirs), column-scaled Gauss-Newton with LM safeguarding, then the outlier rule and IRLS of
       :func:`~twin.estimator.solvers.robust_fit` (Cauchy weights, chi-square rule per row, final plain
       least squares on the inliers).
    4. Noise not stated in the dataset: estimated per residual block (position, orientation) by variance
       components ``sigma_b^2 <- sigma_b^2 * sum_b r^2 / (m_b - sum_b h_ii)`` (hat-matrix redundancy), refitting
       until the ratio settles (it changes the fit only when there are two blocks).
    5. Covariance ``(J^T W J)^-1`` of the whitened Jacobian on the inliers.

    ``prior`` (maximum a posteriori instead of least squares): ``{"length": sd [m], "angle": sd [rad]}`` and
    optionally ``"offset"`` [rad; m for prismatic joints], a zero-mean Gaussian prior on the deviation of every
    identified robot parameter from its nominal value (joint offsets only with ``"offset"``; base and tool
    never). The rows and the noise are settled without it (steps 3-4); a final fit on the inlier rows adds the
    rows ``(x - x_nominal) / sd`` and the covariance becomes the posterior ``(J^T W J + diag(1/sd^2))^-1``.

    ``selection`` (which parameters step 2 estimates): ``"ordered"`` every identifiable one (the ordered
    rank-revealing pass); ``"figaroh"`` (a ``"urdf"`` chain at ``level="full"``) FIGAROH's full-parameter set
    reproduced on our parameterisation (:func:`~twin.estimator.identifiability.figaroh_full_selection`: its
    structural QR on random configurations, the first six base parameters replaced by the base frame, the
    directions these configurations barely excite dropped), the others held at nominal.
    """
    space = prep.space
    obs = prep.obs_cal
    if selection not in SELECTIONS:
        raise ValueError(f"selection must be one of {SELECTIONS}, got {selection!r}")
    if selection == "figaroh" and (level != "full" or space.chain.structure.convention != "urdf"):
        raise ValueError(f"selection 'figaroh' is FIGAROH's full-parameter level of a URDF chain: it needs level='full' "
                         f"and a 'urdf' chain, got level={level!r} on a {space.chain.structure.convention!r} chain")
    x0 = prep.x_nominal.copy()
    sel = _select_parameters(prep, x0, error_model, level, gauge, selection)
    trace: list[TraceEntry] = []

    def cb(e):
        trace.append(e)
        if callback:
            callback(e)

    fit = _fit_settling_noise(prep, x0, sel.free_idx, sel.res0, robust, alpha, cb)
    x, res, Jw, sig_p, sig_o = fit.x, fit.residuals, fit.Jw, fit.sigma_position, fit.sigma_orientation
    w_rows = fit.inlier.astype(float)[res.row]
    if prior:
        sd = prior_sd(space, prior, sel.cand)
        x, res, Jw, w_rows = _map_fit(space, obs.with_sigma(sig_p, sig_o), x, x0, sd, sel.free_idx, fit.inlier, cb)
    C = full_covariance(space, Jw, sel.free_idx, w_rows)
    rejected = _rejected_rows(fit, alpha) if robust else []
    status = ["identified" if sel.free_full[k] else "fixed" if sel.cand[k] else "given" for k in range(space.size)]
    noise = _noise_report(prep, sig_p, sig_o)
    # residual scale check: with stated noise, how do the inlier residuals compare?
    m_in = float(np.sum(w_rows))
    chi2 = float(np.sum(res.r**2 * w_rows))
    noise["residual_scale"] = float(np.sqrt(chi2 / max(m_in - sel.free_idx.size, 1)))
    return Identified(
        x=x,
        status=tuple(status),
        covariance=C,
        identifiability=sel.identifiability,
        inlier=fit.inlier,
        rejected=tuple(rejected),
        noise=noise,
        trace=tuple(trace),
        notes=tuple(fit.notes),
        extra={"sigma_position": sig_p, "sigma_orientation": sig_o, "error_model": error_model, "gauge": gauge,
               "level": level, **({"prior": {k: float(v) for k, v in prior.items()}} if prior else {}),
               **sel.extra},
    )


@dataclass(frozen=True)
class _Selection:
    """Step 2 of :func:`identify_best`: the candidate parameters of the error model and level, the identifiability
    at the start, the parameters estimated (``free_full`` mask, ``free_idx`` indices) and the residuals at the
    start."""

    cand: np.ndarray
    identifiability: Any
    free_full: np.ndarray
    free_idx: np.ndarray
    res0: Any
    extra: dict


def _select_parameters(prep: Prepared, x0: np.ndarray, error_model: ErrorModel, level: str, gauge: str,
                       selection: str) -> _Selection:
    """The parameters :func:`identify_best` estimates: every identifiable candidate (``"ordered"``) or FIGAROH's
    full-parameter set on our parameterisation (``"figaroh"``); the design is checked for each count."""
    space, obs = prep.space, prep.obs_cal
    cand = candidates(space, error_model, level)
    check_design(obs, int(cand.sum()))
    res0 = absolute_residuals(space, x0, obs)
    cand_names = [n for n, c in zip(space.names, cand) if c]
    ida = analyse_jacobian(res0.J, space.names, candidates=cand_names, order=preference_order(cand_names, gauge))
    free_full = np.zeros(space.size, dtype=bool)
    selected = ida.identifiable
    sel_extra: dict = {}
    if selection == "figaroh":
        from .identifiability import figaroh_full_selection

        frames = [n for n in ida.identifiable if n.startswith(("base_", "tool_"))]
        orientation = obs.kind == "pose" or obs.spheres.shape[1] > 1
        fs = figaroh_full_selection(prep.nominal, res0.J, space.names, frames, n_samples=obs.n, orientation=orientation)
        selected = tuple(n for n in space.names if n in set(fs.kept) and n in set(cand_names))
        sel_extra = {"selection": {"rule": "figaroh", "structural": list(fs.structural),
                                   "as_base_frame": list(fs.as_base_frame), "absorbed": list(fs.absorbed),
                                   "estimated": list(selected)}}
    free_full[[space.index(n) for n in selected]] = True
    free_idx = np.flatnonzero(free_full)
    check_design(obs, int(free_idx.size))
    return _Selection(cand=cand, identifiability=ida, free_full=free_full, free_idx=free_idx, res0=res0,
                      extra=sel_extra)


@dataclass(frozen=True)
class _NoiseFit:
    """Steps 3-4 of :func:`identify_best`: the solution, its inlier rows (and, robust, each row's statistic and
    threshold), the residuals and whitened free-column Jacobian at it, and the settled noise [m], [rad]."""

    x: np.ndarray
    inlier: np.ndarray
    row_stat: np.ndarray | None
    threshold: np.ndarray | None
    residuals: Any
    Jw: np.ndarray
    sigma_position: float
    sigma_orientation: float
    notes: tuple[str, ...]


def _fit_settling_noise(prep: Prepared, x0: np.ndarray, free_idx: np.ndarray, res0, robust: bool, alpha: float,
                        cb: Callable[[TraceEntry], None]) -> _NoiseFit:
    """The robust (or plain) fit, refitted with the noise re-estimated by variance components until the ratio of
    the position and orientation noise settles (at most 6 rounds; a stated noise is kept)."""
    space, obs = prep.space, prep.obs_cal
    given_p = prep.noise_given["position"]
    given_o = prep.noise_given["orientation"] or obs.kind == "spheres"
    sig_p, sig_o = obs.sigma_position, obs.sigma_orientation
    x = x0
    notes = []
    for round_ in range(6):
        o = obs.with_sigma(sig_p, sig_o)

        def fun(xx, o=o):
            return absolute_residuals(space, xx, o)

        if robust:
            rr = robust_fit(fun, x, free_idx, o.n, alpha=alpha, scale_known=given_p and given_o, callback=cb,
                            res0=res0 if round_ == 0 else None)
            x, inlier, final = rr.x, rr.inlier, rr.final
            row_stat, thr = rr.row_stat, rr.threshold
        else:
            final = gauss_newton(fun, x, free_idx, callback=cb, res0=res0 if round_ == 0 else None)
            x = final.x
            inlier = np.ones(o.n, dtype=bool)
            row_stat = thr = None
        res = final.residuals
        Jw = res.J[:, free_idx]
        if given_p and given_o:
            break
        vc = _variance_components(res, Jw, inlier)
        new_p, new_o = sig_p, sig_o
        if not given_p and 0 in vc and vc[0][1] > 0:
            new_p = sig_p * np.sqrt(vc[0][0] / vc[0][1])
        if not prep.noise_given["orientation"] and 1 in vc and vc[1][1] > 0:
            new_o = sig_o * np.sqrt(vc[1][0] / vc[1][1])
        ratio_change = abs(np.log((new_p / new_o) / (sig_p / sig_o))) if obs.kind == "pose" else 0.0
        sig_p, sig_o = new_p, new_o
        if ratio_change < 1e-3:
            # the solution does not depend on a common scale: only the covariance is rescaled below
            o = obs.with_sigma(sig_p, sig_o)
            res = absolute_residuals(space, x, o)
            Jw = res.J[:, free_idx]
            break
    else:
        notes.append("noise estimation did not settle in 6 rounds")
    return _NoiseFit(x=x, inlier=inlier, row_stat=row_stat, threshold=thr, residuals=res, Jw=Jw,
                     sigma_position=sig_p, sigma_orientation=sig_o, notes=tuple(notes))


def _rejected_rows(fit: _NoiseFit, alpha: float) -> list[tuple[int, str]]:
    """The rows the robust fit left out, each with the chi-square rule's numbers."""
    if fit.row_stat is None:
        return []
    row_stat, thr = fit.row_stat, fit.threshold
    return [(int(i), f"outlier: sum of squared normalised residuals {row_stat[i]:.4g} > threshold {thr[i]:.4g} "
                     f"(chi-square rule, alpha={alpha:g} over {int(np.sum(row_stat >= 0))} rows)")
            for i in np.flatnonzero(~fit.inlier)]


def _noise_report(prep: Prepared, sig_p: float, sig_o: float) -> dict[str, Any]:
    """``noise`` of the result: the noise used [mm] / [rad] and whether it was stated or estimated."""
    noise: dict[str, Any] = {
        "position_mm": sig_p / M_PER_MM,
        "position_source": "given" if prep.noise_given["position"] else "estimated from residuals",
    }
    if prep.obs_cal.kind == "pose":
        noise["orientation_rad"] = sig_o
        noise["orientation_source"] = "given" if prep.noise_given["orientation"] else "estimated from residuals"
    return noise


PRIOR_KEYS = ("length", "angle", "offset")
SELECTIONS = ("ordered", "figaroh")


def prior_sd(space: ParamSpace, prior: dict[str, float], cand: np.ndarray) -> np.ndarray:
    """Prior standard deviation ``(P,)`` [SI] of every parameter (``inf`` = no prior) from ``prior``
    (see :func:`identify_best`); ``ValueError`` naming a bad key or value."""
    bad = [k for k in prior if k not in PRIOR_KEYS]
    if bad:
        raise ValueError(f"prior: unknown keys {bad}; known: {list(PRIOR_KEYS)}")
    for k, v in prior.items():
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"prior: {k} must be a positive standard deviation [SI], got {v!r}")
    joint = set(space.chain.structure.joint_params)
    sd = np.full(space.size, np.inf)
    for k in range(space.n_robot):
        if not cand[k]:
            continue
        name = space.names[k]
        if name in joint:
            sd[k] = prior.get("offset", np.inf)
        else:
            sd[k] = prior.get("length" if space.units[k] == "m" else "angle", np.inf)
    return sd


def _map_fit(space, obs, x, x0, sd, free_idx, inlier, cb):
    """Gauss-Newton on the inlier rows plus the prior rows ``(x - x0) / sd`` (one extra pseudo-row)."""
    from .problem import Residuals

    w = np.where(np.isfinite(sd), 1.0 / sd, 0.0)
    pk = np.flatnonzero(w > 0)

    def fun(xx):
        r = absolute_residuals(space, xx, obs)
        Jp = np.zeros((pk.size, space.size))
        Jp[np.arange(pk.size), pk] = w[pk]
        return Residuals(r=np.concatenate([r.r, -(xx[pk] - x0[pk]) * w[pk]]), J=np.concatenate([r.J, Jp]),
                         row=np.concatenate([r.row, np.full(pk.size, obs.n)]),
                         block=np.concatenate([r.block, np.full(pk.size, 2)]))

    row_w = np.append(inlier.astype(float), 1.0)
    g = gauss_newton(fun, x, free_idx, row_weights=row_w, stage="map", callback=cb)
    res = g.residuals
    return g.x, res, res.J[:, free_idx], row_w[res.row]


def build_calibration(prep: Prepared, ident: Identified, method: str, options: dict[str, Any]) -> Calibration:
    """Assemble the :class:`Calibration`: parameters, covariance, rows used/rejected, residual statistics on
    the calibration inliers and the validation rows, and the predicted validation error (Cramer-Rao floor)."""
    space = prep.space
    ds = prep.dataset
    sig_p = ident.extra.get("sigma_position", prep.obs.sigma_position)
    sig_o = ident.extra.get("sigma_orientation", prep.obs.sigma_orientation)
    obs_cal = prep.obs_cal.with_sigma(sig_p, sig_o)
    obs_val = prep.obs_val.with_sigma(sig_p, sig_o)
    pid = prep.obs.pose_id
    cal_pid = pid[prep.cal]
    rejected = [{"pose_id": int(cal_pid[i]), "reason": why} for i, why in ident.rejected]
    skipped = [{"pose_id": int(ds.pose_id[i]), "reason": why} for i, why in prep.skipped]
    inl = ident.inlier
    residuals: dict[str, Any] = {
        "calibration": residual_stats(space, ident.x, obs_cal.subset(inl)),
        "calibration_all": residual_stats(space, ident.x, obs_cal),
        "validation": residual_stats(space, ident.x, obs_val),
        "before_calibration": {
            "validation": residual_stats(space, prep.x_nominal, obs_val),
            "note": "nominal robot and tool with the registered station frames",
        },
    }
    if ident.covariance is not None and prep.val.size:
        floor = predicted_error(space, ident.x, ident.covariance, obs_val)
        exp = {}
        if obs_val.kind == "spheres":
            exp["position_mm"] = float(np.sqrt(3 * (sig_p / M_PER_MM) ** 2 + floor["position_mm"] ** 2))
        else:
            exp["position_mm"] = float(np.sqrt(3 * (sig_p / M_PER_MM) ** 2 + floor["position_mm"] ** 2))
            exp["orientation_deg"] = float(np.sqrt(3 * rad_to_deg(sig_o) ** 2 + floor["orientation_deg"] ** 2))
        residuals["predicted_validation"] = {
            "model_error_rms": floor,
            "expected_residual_rms": exp,
            "note": "model_error_rms: RMS error of the predictions against the noise-free truth implied by the "
                    "parameter covariance (the Cramer-Rao floor of a correctly specified model); "
                    "expected_residual_rms adds the measurement noise, to compare with validation.rms",
        }
    ida = ident.identifiability
    idd: dict[str, Any] = {}
    combos = ()
    if ida is not None:
        idd = ida.summary()
        combos = ida.combinations
    if ida is not None and method in ("best", "fullpose", "lm", "clm"):
        # which couplings are structural (any design) and which come from these configurations (only for
        # methods whose analysis is of the absolute residuals, which a generic design is analysed with)
        try:
            qg = generic_configurations(prep.nominal, n=60 * len(prep.obs.station_names))
            n_st = len(prep.obs.station_names)
            og = Observations(
                kind=prep.obs.kind, q=qg, station=np.arange(len(qg)) % n_st, station_names=prep.obs.station_names,
                pose_id=np.arange(len(qg)), spheres_tool=prep.obs.spheres_tool,
                sigma_position=sig_p, sigma_orientation=sig_o,
            )
            og = _synthetic_like(space, prep.x_nominal, og)
            cand = np.array([n in set(ida.names) for n in space.names])
            gen = analyse(space, prep.x_nominal, og, cand, gauge=ident.extra.get("gauge", "frames"))
            data_dep = [d for d in ida.dropped if d not in set(gen.dropped)]
            idd["structural_dropped"] = list(gen.dropped)
            idd["data_dependent_dropped"] = data_dep
        except ValueError:
            pass
    st_map = {k: s for k, s in enumerate(prep.obs.station_names)}
    rows = {
        "split": prep.split,
        "calibration_used": [int(p) for p, ok in zip(cal_pid, inl) if ok],
        "calibration_rejected": rejected,
        "validation": [int(p) for p in pid[prep.val]],
        "skipped": skipped,
        "stations": {st_map[k]: int(np.sum(prep.obs.station == k)) for k in st_map},
    }
    notes = list(prep.notes) + list(ident.notes)
    if idd.get("data_dependent_dropped"):
        notes.append(
            "rank deficiency from these configurations (not structural): "
            + ", ".join(idd["data_dependent_dropped"])
            + " fixed at nominal; measure more varied configurations"
        )
    return Calibration(
        method=method,
        nominal=prep.nominal,
        stations=prep.obs.station_names,
        x=ident.x,
        x_nominal=prep.x_nominal,
        status=ident.status,
        covariance=ident.covariance,
        plate=ds.plate,
        spheres_tool=prep.obs.spheres_tool,
        measurement=prep.obs.kind,
        noise=ident.noise,
        combinations=combos,
        identifiability=idd,
        rows=rows,
        residuals=residuals,
        options=options,
        notes=tuple(notes),
        trace=ident.trace,
        dataset=str(ds.path) if ds.path else "",
        details={k: v for k, v in ident.extra.items() if isinstance(v, (str, int, float, bool, dict, list))},
    )


def _synthetic_like(space: ParamSpace, x: np.ndarray, obs: Observations) -> Observations:
    """Observations of the same kind as ``obs`` predicted by ``x`` (only the Jacobian is used)."""
    from dataclasses import replace

    from .problem import station_eval, predict_points

    if obs.kind == "spheres":
        pts, _ = predict_points(space, x, obs.q, obs.station, obs.spheres_tool)
        return replace(obs, spheres=pts, seen=np.ones((obs.n, 3), bool))
    R, p, _ = station_eval(space, x, obs.q, obs.station, False)
    return replace(obs, pose_R=R, pose_p=p)


def _method_best(prep: Prepared, **kw) -> Identified:
    return identify_best(prep, **kw)


METHODS: dict[str, Callable[..., Identified]] = {"best": _method_best}


def calibrate(
    dataset: Dataset,
    method: str = "best",
    *,
    measurement: Literal["auto", "spheres", "pose"] = "auto",
    noise_position: float | None = None,
    noise_orientation: float | None = None,
    validation_fraction: float = 0.2,
    seed: int = 0,
    use_given_bases: bool = False,
    callback: Callable[[TraceEntry], None] | None = None,
    **options: Any,
) -> Calibration:
    """Identify the robot of ``dataset`` with ``method`` and return a :class:`Calibration`.

    Methods: ``best`` (default; :func:`identify_best`), and the papers' ``distance``, ``fullpose``,
    ``separation``, ``lm``, ``clm`` (:mod:`twin.estimator.paper_methods`). Fits on the rows with
    ``set = calibration`` and reports on ``validation`` rows (without a ``set`` column a seeded random
    ``validation_fraction`` is held out). ``options`` go to the method (e.g. ``error_model``, ``gauge``,
    ``robust``, ``solver``). ``noise_*`` [m] / [rad] override ``dataset.toml``'s ``[noise]``.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {sorted(METHODS)}, got {method!r}")
    if method != "best" and (dataset.robot.convention not in ("mdh", "dh") or dataset.robot.n_joints != 6):
        raise ValueError(f"method {method!r} reproduces a paper on 6R DH/MDH arms; robot {dataset.robot.name!r} is a "
                         f"{dataset.robot.n_joints}-joint {dataset.robot.convention!r} chain: use method 'best'")
    prep = prepare(
        dataset,
        measurement=measurement,
        noise_position=noise_position,
        noise_orientation=noise_orientation,
        validation_fraction=validation_fraction,
        seed=seed,
        use_given_bases=use_given_bases,
    )
    ident = METHODS[method](prep, callback=callback, **options)
    opts = {
        "measurement": prep.obs.kind,
        "validation_fraction": validation_fraction,
        "seed": seed,
        "use_given_bases": use_given_bases,
        **{k: v for k, v in options.items() if isinstance(v, (str, int, float, bool, type(None)))},
    }
    return build_calibration(prep, ident, method, opts)


def identifiability(
    dataset: Dataset,
    *,
    part: Literal["full", "position", "orientation"] = "full",
    error_model: ErrorModel = "tmmdh",
    gauge: Literal["frames", "structure"] = "frames",
    measurement: Literal["auto", "spheres", "pose"] = "auto",
    rows: Literal["calibration", "all"] = "calibration",
    tol: float = 1e-6,
    level: str = "full",
):
    """Identifiability analysis of ``dataset``'s configurations at the nominal model (stations registered).

    ``part="orientation"`` analyses the orientations alone (sphere data: the plate orientation from its
    three spheres), ``"position"`` the positions alone. Returns an
    :class:`~twin.estimator.identifiability.Identifiability`: identifiable parameters, unidentifiable
    combinations by name, condition number, O1, O3, O4 on the column-scaled Jacobian.
    """
    prep = prepare(dataset, measurement=measurement, validation_fraction=0.0 if rows == "all" else 0.2)
    obs = prep.obs if rows == "all" else prep.obs_cal
    if part != "full" and obs.kind == "spheres":
        obs = obs.as_poses()
    cand = candidates(prep.space, error_model, level)
    return analyse(prep.space, prep.x_nominal, obs, cand, gauge=gauge, part=part, tol=tol)
