"""The two papers' identification methods, reproduced as published (weaknesses included).

Separation paper (Wang et al. 2023), section 2.1.3-2.1.5:

* ``distance`` -- length and angle parameters from the distances a motion pair moves (eq. 28-30): per pair
  and sphere, ``|p_i - p_j|_measured - |p_i - p_j|_model``. Needs no base (distances are invariant to it).
* ``fullpose`` -- all parameters from absolute measurements (sphere centres or poses) in the measurement
  frame, each station's ``base2meas`` estimated with them.
* ``separation`` -- step 1: the angle parameters of eq. 21 (``theta1, alpha1, theta2 (= the sum
  theta2 + theta3), alpha2, beta2, alpha3, theta4, alpha4, theta5, alpha5, theta6, alpha6``) from the
  orientation changes of motion pairs (eq. 23-27); step 2: the length parameters and the split of
  theta2/theta3 (eq. 22) from the distance constraints (eq. 28-30), the angles of step 1 held. As in the
  paper's Tables 3 and 5, step 2 keeps ``theta2 + theta3`` at its step-1 value and identifies the split.
  The orientation change is ``angle_residual="relative"`` (default): ``log(Q_meas Q_model^T)`` with
  ``Q = R_i^T R_j``, the rotation of the motion seen in the plate frame, which needs no base; or
  ``"euler"``: the paper's literal eq. 43, differences of ZYX Euler angles in the base frame, which needs
  the base rotation (from ``dataset.toml``'s station ``base2meas`` when given, else from a closed-form
  registration of the nominal model).
* Solver (section 2.1.5): ``solver="spectral"`` (default) -- Gauss-Newton whose unscaled normal equations
  are solved by the spectral-correction iteration (eq. 33-36) on the paper's parameter list as it is (its
  unidentifiable directions stay where they start); ``solver="scaled"`` -- our column-scaled Gauss-Newton
  on the identifiable subset of the same list (the properly scaled comparison).

TM-MDH paper (Lao et al. 2023), section 3.2:

* ``lm`` -- Levenberg-Marquardt (eq. 27-28) on the full residual, every parameter of the error model at
  once (``error_model="tmmdh"``: 37 for one station; ``"structural"``: the robot's 25, base and tool held).
* ``clm`` -- cross identification: LM on the orientation residual over the angle parameters, then LM on the
  full residual over all, repeated ``n_cycles`` (20) times.

Residuals of the papers' methods are unweighted in SI units (metres and radians), as the papers state them
(``weighting="noise"`` whitens them with the dataset's noise instead). Their covariance is not reported:
they are not maximum-likelihood estimators; use ``best`` for uncertainties.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable, Literal

import numpy as np

from ..units import M_PER_MM
from .core import Identified, Prepared, analyse, check_design, register_bases
from .identifiability import analyse_jacobian, preference_order
from .lm import GenericBatch, LMSettings, PoseBatch, cross_identification, levenberg_marquardt
from .methods import METHODS, candidates
from .problem import (
    Observations,
    ParamSpace,
    Residuals,
    absolute_residuals,
    make_pairs,
    pair_residuals,
)
from .solvers import TraceEntry, gauss_newton

__all__ = [
    "identify_distance",
    "identify_fullpose",
    "identify_separation",
    "identify_separation_paper",
    "SEPARATION_PAPER_HELD",
    "identify_lm",
    "identify_clm",
    "identify_lm_paper",
    "identify_clm_paper",
    "EQ21_ANGLES",
    "EQ22_LENGTHS",
]

EQ21_ANGLES = ("theta1", "alpha1", "theta2", "alpha2", "beta2", "alpha3", "theta4", "alpha4", "theta5", "alpha5",
               "theta6", "alpha6")
EQ22_LENGTHS = tuple(f"{f}{i}" for i in range(1, 7) for f in ("d", "a")) + ("theta2", "theta3")


def _mask(space: ParamSpace, names) -> np.ndarray:
    m = np.zeros(space.size, dtype=bool)
    for n in names:
        m[space.index(n)] = True
    return m


def _weighted(obs: Observations, weighting: str) -> Observations:
    if weighting == "paper":
        return obs.with_sigma(1.0, 1.0)
    if weighting == "noise":
        return obs
    if weighting == "mm_rad":  # unweighted, positions in mm and angles in rad
        return obs.with_sigma(M_PER_MM, 1.0)
    raise ValueError(f"weighting must be 'paper', 'mm_rad' or 'noise', got {weighting!r}")


def _frame_fixed(ida) -> set[str]:
    """Parameters the papers' methods hold at nominal even with their own solver: those with no effect on the
    residual, and those coupled with a base/tool parameter. The papers have no base/tool unknowns (their base
    is known, their plate pinned to the flange); ours come from the unknown camera placement and plate
    mounting, and in a coupling with them the robot parameter is held so that the robot base frame stays the
    nominal one (the frame in which compensation targets are given). Couplings among robot parameters (d2/d3)
    are left to the paper's solver."""
    out = set()
    for c in ida.combinations:
        if c.kind == "no_effect" or any(n.startswith(("base_", "tool_")) for n in c.names):
            out.add(c.dropped)
    return out


def _split_dropped(ida, solver: str) -> tuple[set[str], set[str]]:
    """(fixed, coupled): what is held at nominal, what the solver estimates although only a combination is seen."""
    fixed = _frame_fixed(ida)
    if solver == "scaled":
        return set(ida.dropped), set()
    return fixed, set(ida.dropped) - fixed


def _solve(fun: Callable[[np.ndarray], Residuals], x0, free, solver: str, stage: str, max_iter: int, cb,
           space: ParamSpace, fixed=()) -> tuple[np.ndarray, tuple]:
    if solver not in ("spectral", "scaled"):
        raise ValueError(f"solver must be 'spectral' or 'scaled', got {solver!r}")
    idx = np.array([i for i in np.flatnonzero(free) if space.names[i] not in set(fixed)], dtype=int)
    g = gauss_newton(fun, x0, idx, max_iter=max_iter, stage=stage, linear_solver=solver, callback=cb)
    return g.x, g.trace


def _status(space: ParamSpace, free: np.ndarray, coupled: set[str], fixed: set[str] = frozenset()) -> tuple[str, ...]:
    out = []
    for k, n in enumerate(space.names):
        if n in fixed:
            out.append("fixed")
        elif free[k]:
            out.append("coupled" if n in coupled else "identified")
        else:
            out.append("given")
    return tuple(out)


def _tool_names(space: ParamSpace, which: str) -> tuple[str, ...]:
    if which == "nominal":
        return ()
    if which == "estimate":
        return tuple(space.names[space.tool_slice])
    raise ValueError(f"tool must be 'estimate' or 'nominal', got {which!r}")


def _pair_analysis(space, x, obs, pairs, kind, free, base2meas=None, gauge="frames"):
    res = pair_residuals(space, x, obs, pairs, kind, base2meas=base2meas)
    names = [n for n, f in zip(space.names, free) if f]
    return analyse_jacobian(res.J, space.names, candidates=names, order=preference_order(names, gauge))


def _noise_info(prep: Prepared, weighting: str) -> dict:
    d = {"weighting": "unweighted SI residuals (the papers')" if weighting == "paper" else "whitened by the dataset noise"}
    d["position_mm"] = prep.obs.sigma_position / M_PER_MM
    d["position_source"] = "given" if prep.noise_given["position"] else "placeholder (not used by the papers' methods)"
    return d


# ------------------------------------------------------------------------------------------------
# distance
# ------------------------------------------------------------------------------------------------

def identify_distance(
    prep: Prepared,
    *,
    solver: Literal["spectral", "scaled"] = "spectral",
    tool: Literal["estimate", "nominal"] = "estimate",
    weighting: Literal["paper", "noise"] = "paper",
    max_iter: int = 50,
    callback: Callable[[TraceEntry], None] | None = None,
) -> Identified:
    """Distance constraints (separation paper, eq. 28-30): every robot parameter (and the tool) from the
    distances moved by motion pairs; the base is registered afterwards in closed form (for reporting and
    prediction only)."""
    space = prep.space
    obs = _weighted(prep.obs_cal, weighting)
    pairs, how = make_pairs(obs)
    free = _mask(space, space.names[: space.n_robot] + _tool_names(space, tool))
    check_design(obs, int(free.sum()))
    x0 = prep.x_nominal.copy()
    ida = _pair_analysis(space, x0, obs, pairs, "distance", free)
    trace: list[TraceEntry] = []
    cb = _collect(trace, callback)
    fixed, coupled = _split_dropped(ida, solver)
    x, _ = _solve(lambda y: pair_residuals(space, y, obs, pairs, "distance"), x0, free, solver, "distance",
                  max_iter, cb, space, fixed)
    x = register_bases(space, x, prep.obs_cal)
    return Identified(
        x=x, status=_status(space, free, coupled, fixed), covariance=None, identifiability=ida,
        inlier=np.ones(obs.n, bool), rejected=(), noise=_noise_info(prep, weighting), trace=tuple(trace),
        notes=(f"motion pairs: {len(pairs)} from {how}", "base2meas registered in closed form after the fit"),
        extra={"pairs": int(len(pairs))},
    )


# ------------------------------------------------------------------------------------------------
# full pose
# ------------------------------------------------------------------------------------------------

def identify_fullpose(
    prep: Prepared,
    *,
    solver: Literal["spectral", "scaled"] = "spectral",
    tool: Literal["estimate", "nominal"] = "estimate",
    weighting: Literal["paper", "noise"] = "paper",
    max_iter: int = 50,
    callback: Callable[[TraceEntry], None] | None = None,
) -> Identified:
    """Full-pose constraint: every robot parameter, each station's base2meas (and the tool) from absolute
    measurements in the measurement frame, from the nominal model with registered stations."""
    space = prep.space
    obs = _weighted(prep.obs_cal, weighting)
    free = _mask(space, space.names[: space.n_robot] + _tool_names(space, tool)) | (np.arange(space.size) >= space.n_rt)
    check_design(obs, int(free.sum()))
    x0 = prep.x_nominal.copy()
    ida = analyse(space, x0, obs, free)
    trace: list[TraceEntry] = []
    fixed, coupled = _split_dropped(ida, solver)
    x, _ = _solve(lambda y: absolute_residuals(space, y, obs), x0, free, solver, "fullpose", max_iter,
                  _collect(trace, callback), space, fixed)
    return Identified(
        x=x, status=_status(space, free, coupled, fixed), covariance=None, identifiability=ida,
        inlier=np.ones(obs.n, bool), rejected=(), noise=_noise_info(prep, weighting), trace=tuple(trace),
    )


# ------------------------------------------------------------------------------------------------
# separation
# ------------------------------------------------------------------------------------------------

def identify_separation(
    prep: Prepared,
    *,
    solver: Literal["spectral", "scaled"] = "spectral",
    angle_residual: Literal["relative", "euler"] = "relative",
    tool: Literal["estimate", "nominal"] = "estimate",
    weighting: Literal["paper", "noise"] = "paper",
    held: tuple[str, ...] = (),
    max_iter: int = 50,
    callback: Callable[[TraceEntry], None] | None = None,
) -> Identified:
    """The separation method: angles from orientation changes (eq. 21, 27), then lengths and the
    theta2/theta3 split from distances (eq. 22, 30) with ``theta2 + theta3`` held at its step-1 value.
    ``held``: parameter names kept at nominal in both steps (the paper-literal variant holds d2)."""
    space = prep.space
    for n in held:
        if n not in space.names:
            raise ValueError(f"held names an unknown parameter: {n!r}")
    obs_all = _weighted(prep.obs_cal, weighting)
    obs_rot = obs_all.as_poses()  # sphere data: plate orientation from the three spheres
    pairs_rot, how = make_pairs(obs_rot)
    pairs_d, _ = make_pairs(obs_all)
    tool_names = _tool_names(space, tool)
    x0 = prep.x_nominal.copy()
    trace: list[TraceEntry] = []
    cb = _collect(trace, callback)
    # --- step 1: angles from orientation changes (theta3 held: the sum goes into theta2, eq. 21)
    ang_names = tuple(n for n in EQ21_ANGLES + tuple(n for n in tool_names if n.startswith("tool_r")) if n not in held)
    free1 = _mask(space, ang_names)
    check_design(obs_rot, int(free1.sum()))
    kind = {"relative": "rotation_change", "euler": "euler_change"}.get(angle_residual)
    if kind is None:
        raise ValueError(f"angle_residual must be 'relative' or 'euler', got {angle_residual!r}")
    b2m = None
    notes = [f"motion pairs: {len(pairs_d)} from {how}"]
    if kind == "euler_change":
        given = prep.dataset.stations_base2meas
        b2m = {k: (given[s] if s in given else _pose(x0, space, k)) for k, s in enumerate(space.stations)}
        src = "dataset.toml" if all(s in given for s in space.stations) else "closed-form registration of the nominal model"
        notes.append(f"euler residual: base rotation from {src}")
    ida1 = _pair_analysis(space, x0, obs_rot, pairs_rot, kind, free1, base2meas=b2m)
    fixed1, coupled1 = _split_dropped(ida1, solver)
    x1, _ = _solve(lambda y: pair_residuals(space, y, obs_rot, pairs_rot, kind, base2meas=b2m), x0, free1,
                   solver, "separation-angles", max_iter, cb, space, fixed1)
    # --- step 2: lengths and the theta2/theta3 split from distances
    i2, i3 = space.index("theta2"), space.index("theta3")
    len_names = tuple(n for n in EQ22_LENGTHS if n not in ("theta2", "theta3")) + tuple(n for n in tool_names if not n.startswith("tool_r"))
    free2 = _mask(space, tuple(n for n in len_names if n not in held) + ("theta2",))
    s23 = x1[i2] + x1[i3]

    def fun2(y):
        y = y.copy()
        y[i3] = s23 - y[i2]  # theta2 + theta3 stays at the step-1 sum: theta2's column is d/dtheta2 - d/dtheta3
        res = pair_residuals(space, y, obs_all, pairs_d, "distance")
        J = res.J.copy()
        J[:, i2] = J[:, i2] - J[:, i3]
        J[:, i3] = 0.0
        return Residuals(r=res.r, J=J, row=res.row, block=res.block)

    check_design(obs_all, int(free2.sum()))
    ida2_res = fun2(x1)
    names2 = [n for n, f in zip(space.names, free2) if f]
    ida2 = analyse_jacobian(ida2_res.J, space.names, candidates=names2, order=preference_order(names2))
    fixed2, coupled2 = _split_dropped(ida2, solver)
    x2, _ = _solve(fun2, x1, free2, solver, "separation-lengths", max_iter, cb, space, fixed2)
    x2[i3] = s23 - x2[i2]
    x2 = register_bases(space, x2, prep.obs_cal)
    free = free1 | free2
    free[i3] = True
    coupled = coupled1 | coupled2
    fixed = (fixed1 | fixed2) - {"theta3"}
    notes.append("base2meas registered in closed form after the fit")
    return Identified(
        x=x2, status=_status(space, free, coupled - {"theta3"}, fixed), covariance=None, identifiability=ida1,
        inlier=np.ones(obs_all.n, bool), rejected=(), noise=_noise_info(prep, weighting), trace=tuple(trace),
        notes=tuple(notes),
        extra={"step1_identifiability": ida1.summary(), "step2_identifiability": ida2.summary(),
               "theta2_plus_theta3_step1": float(s23)},
    )


SEPARATION_PAPER_HELD = ("d2",)


def identify_separation_paper(
    prep: Prepared,
    *,
    solver: Literal["spectral", "scaled"] = "spectral",
    max_iter: int = 50,
    callback: Callable[[TraceEntry], None] | None = None,
) -> Identified:
    """The separation method as the paper states it: the paper's parameter set (d2 held at nominal, Tables 1
    and 4-6 mark it "-"), the plate pinned to the flange (nominal tool, not estimated) and the camera-to-base
    rotation given (eq. 42: Euler-angle changes in the base frame, rotation from ``dataset.toml``)."""
    res = identify_separation(prep, solver=solver, angle_residual="euler", tool="nominal", weighting="paper",
                              held=SEPARATION_PAPER_HELD, max_iter=max_iter, callback=callback)
    return replace(res, notes=res.notes + ("paper-literal: d2 held at nominal, nominal tool, given base rotation",))


def _pose(x, space, k):
    from ..transforms import pose6_to_transform

    return pose6_to_transform(x[space.base_slice(k)])


# ------------------------------------------------------------------------------------------------
# LM and C-LM (TM-MDH paper)
# ------------------------------------------------------------------------------------------------

def _providers(prep: Prepared, weighting: str):
    space = prep.space
    obs = _weighted(prep.obs_cal, weighting)
    if obs.kind == "pose" and len(space.stations) == 1:
        full = PoseBatch(space, obs)
        return full, full, obs
    full = GenericBatch(space, obs)
    rot = GenericBatch(space, obs.as_poses()) if obs.kind == "spheres" else full
    return rot, full, obs


def _lm_free(space: ParamSpace, error_model: str, exclude: tuple[str, ...]) -> np.ndarray:
    free = candidates(space, error_model)
    for n in exclude:
        free[space.index(n)] = False
    return free


def identify_lm(
    prep: Prepared,
    *,
    error_model: Literal["tmmdh", "structural"] = "tmmdh",
    weighting: Literal["paper", "noise"] = "paper",
    exclude: tuple[str, ...] = (),
    max_iter: int = 100,
    accept: Literal["always", "improve"] = "always",
    damping: Literal["cumulative", "paper"] = "cumulative",
    callback: Callable[[TraceEntry], None] | None = None,
) -> Identified:
    """The TM-MDH paper's LM: every parameter of the error model at once from the nominal start (stations
    registered or given). ``exclude``: parameters held at nominal (the paper's section 4.2 suggests z,
    alpha, x', z', alpha', gamma' when the frames are calibrated well)."""
    space = prep.space
    rot, full, obs = _providers(prep, weighting)
    free = _lm_free(space, error_model, tuple(exclude))
    check_design(obs, int(free.sum()))
    ida = analyse(space, prep.x_nominal, prep.obs_cal, free)
    r = levenberg_marquardt(full, prep.x_nominal[None], free, settings=LMSettings(max_iter=max_iter, accept=accept, damping=damping))
    trace = tuple(TraceEntry(t.stage, t.iteration, t.median_cost, float("nan")) for t in r.trace)
    if callback:
        for t in trace:
            callback(t)
    return Identified(
        x=r.X[0], status=_status(space, free, set(ida.dropped), set(exclude)), covariance=None, identifiability=ida,
        inlier=np.ones(obs.n, bool), rejected=(), noise=_noise_info(prep, weighting), trace=trace,
        notes=(f"LM: {int(r.iterations[0])} iterations (cap {max_iter}), steps accepted '{accept}'",),
    )


def identify_clm(
    prep: Prepared,
    *,
    error_model: Literal["tmmdh", "structural"] = "tmmdh",
    weighting: Literal["paper", "noise"] = "paper",
    exclude: tuple[str, ...] = (),
    n_cycles: int = 20,
    max_iter_stage: int = 10,
    accept: Literal["always", "improve"] = "always",
    damping: Literal["cumulative", "paper"] = "cumulative",
    callback: Callable[[TraceEntry], None] | None = None,
) -> Identified:
    """The TM-MDH paper's C-LM: LM on orientations over the angle parameters, then LM on everything,
    ``n_cycles`` times (the paper: 20). For sphere data the orientation stage uses the plate orientation
    computed from the three spheres."""
    space = prep.space
    rot, full, obs = _providers(prep, weighting)
    free = _lm_free(space, error_model, tuple(exclude))
    check_design(obs, int(free.sum()))
    ida = analyse(space, prep.x_nominal, prep.obs_cal, free)
    st = LMSettings(max_iter=max_iter_stage, accept=accept, damping=damping)
    r = cross_identification(rot, full, prep.x_nominal[None], free, ~space.is_length, n_cycles=n_cycles,
                             settings_orientation=st, settings_full=st)
    trace = tuple(TraceEntry(t.stage, t.iteration, t.median_cost, float("nan")) for t in r.trace)
    if callback:
        for t in trace:
            callback(t)
    return Identified(
        x=r.X[0], status=_status(space, free, set(ida.dropped), set(exclude)), covariance=None, identifiability=ida,
        inlier=np.ones(obs.n, bool), rejected=(), noise=_noise_info(prep, weighting), trace=trace,
        notes=(f"C-LM: {int(r.cycles[0])} cycles (cap {n_cycles}), at most {max_iter_stage} LM iterations per stage",),
    )


def identify_lm_paper(prep: Prepared, **kwargs) -> Identified:
    """LM with the paper's bounded, non-cumulative damping (section 3.2), unweighted SI residuals."""
    return identify_lm(prep, **{"damping": "paper", **kwargs})


def identify_clm_paper(prep: Prepared, **kwargs) -> Identified:
    """C-LM with the paper's damping and unweighted residuals in mm and rad (``weighting="mm_rad"``)."""
    return identify_clm(prep, **{"damping": "paper", "weighting": "mm_rad", **kwargs})


def _collect(trace: list, callback):
    def cb(e):
        trace.append(e)
        if callback:
            callback(e)

    return cb


METHODS.update(
    {
        "distance": identify_distance,
        "fullpose": identify_fullpose,
        "separation": identify_separation,
        "separation_paper": identify_separation_paper,
        "lm": identify_lm,
        "clm": identify_clm,
        "lm_paper": identify_lm_paper,
        "clm_paper": identify_clm_paper,
    }
)
