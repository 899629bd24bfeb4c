"""Confirming a term on the held-out rows: a scored atom's prediction of the confirmation rows tested against their
residual (:func:`confirm`: Wilcoxon's signed ranks per row, without the most favourable row, the held-out error, and
for a term of time whether the nearest rows in time predict as well), and whether the held-out residual is
predictable from the nearest rows in joint space or time at all (:func:`smooth_confirm`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .atoms import Atom
from .configurations import RIVAL_MARGIN, Z_MIN as CONFIGURATION_Z
from .configurations import FoldConfirmation, block_widths, configuration_folds, fold_confirmation, joints_read
from .extend import ExtendedModel
from .features import Const
from .problem import Fit, Problem
from .scoring import Scored, raw_columns, scoring_basis
from .structure import signed_rank_z

__all__ = ["time_only", "of_time", "moves_the_cell", "reads_the_wander", "serial_inflation", "vector_inflation",
           "Confirmation", "confirm", "confirm_configurations", "NEIGHBOURS", "JOINT_WEIGHTS", "joint_weights",
           "row_blocks", "neighbour_predictions", "time_blocks", "earlier_rows_prediction", "smooth_confirm"]


def time_only(atom: Atom) -> bool:
    """Whether an atom's features are functions of the time channel alone (a drift, a step or a window, a transient,
    an oscillation in ``t_s`` or the row order, on any place)."""
    kinds = {f.kind for f in atom.features} - {"const"}
    return bool(kinds) and kinds <= {"pow", "step", "window", "exp", "sin", "cos"} and all(
        getattr(f, "ch", None) in ("t_s", "row") for f in atom.features if not isinstance(f, Const))


TIME_KINDS = {"lag", "heat", "settle"}  # features of a channel smooth in time (the air's temperature, the motors' heat)


def of_time(atom: Atom) -> bool:
    """Whether an atom's prediction is smooth in time from row to row: a term of time alone (:func:`time_only`), or
    of the air's temperature or the motors' heat (a lag, a heat, a station settling, a power or a step of
    ``temp_c``). A load or a joint term switched on at a time (``gated``) reads the configuration: not of time."""
    fs = [f for f in atom.features if not isinstance(f, Const)]
    return bool(fs) and all(f.kind in TIME_KINDS or (f.kind in ("pow", "step", "window", "exp", "sin", "cos") and
                                                     getattr(f, "ch", None) in ("t_s", "row", "temp_c")) for f in fs)


def moves_the_cell(atom: Atom) -> bool:
    """Whether an atom displaces the measurement side as a whole: the measurement frame of each station (``base``,
    ``base_along``), its scale or its field. A wander of the cell is such a displacement, so a term of time there
    follows it from row to row; a term through the arm (a joint, a link, a load, the tool) meets it along directions
    that change with each row's pose."""
    return atom.place in ("scale", "field") or (atom.place == "param" and atom.target in ("base", "base_along"))


def reads_the_wander(atom: Atom) -> bool:
    """Whether a term's held-out check also reads the noise's wander on every coordinate of the remainder
    (:func:`vector_inflation`): a term of time on the measurement side (:func:`moves_the_cell`) that is not a change.
    A change (a step, a window) is constant over its rows and read along its prediction alone."""
    return of_time(atom) and moves_the_cell(atom) and atom.family != "change"


def serial_inflation(e: np.ndarray, t: np.ndarray) -> float:
    """The factor ``>= 1`` by which the serial correlation of the noise in the series ``e`` ``(n,)`` (rows in time
    order, at times ``t`` ``(n,)``) inflates the variance of its sum over that of ``n`` independent rows. Its slow
    part, a level and a linear trend in time fitted by least squares, is taken out first: over a block of rows that
    is a term's misfit (a drift it follows in part), a structure, not the noise's dependence. On what is left, Newey
    and West's long-run variance over the rows' variance, ``1 + 2 sum_{h <= L} (1 - h / (L + 1)) rho_h``
    (``rho_h`` the correlation at lag ``h``), with Andrews' bandwidth for the Bartlett kernel from the lag-one
    correlation ``rho`` (clipped to [0, 0.95]): ``L = ceil(1.1447 (alpha n)^(1/3))``, ``alpha = 4 rho^2 / ((1 -
    rho)^2 (1 + rho)^2)``. 1 for white rows (up to the estimate's scatter) and for fewer than 8 rows."""
    e = np.asarray(e, float)
    n = e.size
    if n < 8:
        return 1.0
    t = np.asarray(t, float)
    X = np.column_stack([np.ones(n), (t - t.mean()) / max(float(np.ptp(t)), 1e-300)])
    e = e - X @ np.linalg.lstsq(X, e, rcond=None)[0]
    ss = float(e @ e)
    if ss <= 0:
        return 1.0
    rho = float(np.clip(e[:-1] @ e[1:] / ss, 0.0, 0.95))
    alpha = 4.0 * rho**2 / ((1.0 - rho) ** 2 * (1.0 + rho) ** 2)
    L = min(n - 1, int(np.ceil(1.1447 * (alpha * n) ** (1.0 / 3.0) - 1e-9)))
    acc = sum((1.0 - h / (L + 1.0)) * float(e[:-h] @ e[h:]) / ss for h in range(1, L + 1))
    return max(1.0, 1.0 + 2.0 * acc)


def vector_inflation(R: np.ndarray, U: np.ndarray) -> float:
    """The factor ``>= 1`` by which the serial correlation of the rows' noise inflates the variance of ``sum_k R_k .
    U_k`` over that of independent rows: ``R`` ``(n, d)`` the rows' remainder (residual less the term's prediction),
    ``U`` ``(n, d)`` the term's prediction, rows in time order (0 where not measured). The noise is read as white
    per coordinate plus a wander that decays geometrically from row to row (an instrument's frame or a cell that
    drifts and returns): its correlation at lag ``h`` is ``a rho^h``, with ``rho = gamma_2 / gamma_1`` and ``a =
    gamma_1 / rho`` from the correlations ``gamma_h = sum_k R_k . R_(k+h) / sum_k |R_k|^2`` read on every coordinate
    of the remainder (a term's misfit is one direction among them, where a wander moves every row), ``rho`` clipped to
    [0, 0.95]; a correlation within twice its scatter over white coordinates (``1 / sqrt(m)``, ``m`` the coordinates
    measured) is read as none: ``gamma_1`` so small, no dependence; ``gamma_2`` so small, the correlation at lag 1
    alone. The sum's variance is then ``sum_k |U_k|^2 + 2 sum_h a rho^h sum_k U_k . U_(k+h)``: its ratio to the first
    term. 1 for white rows, for a prediction that changes sign from row to row, and for fewer than 8 rows."""
    R, U = np.asarray(R, float), np.asarray(U, float)
    n = len(R)
    ss, uu = float(np.sum(R * R)), float(np.sum(U * U))
    if n < 8 or ss <= 0 or uu <= 0:
        return 1.0
    g1, g2 = (float(np.sum(R[:-h] * R[h:])) / ss for h in (1, 2))
    se = 1.0 / np.sqrt(max(np.count_nonzero(R), 1))  # a correlation's scatter over that many white coordinates
    if g1 <= 2.0 * se:
        return 1.0
    rho = float(np.clip(g2 / g1, 0.0, 0.95)) if g2 > 2.0 * se else 0.0
    if rho <= 0:
        return max(1.0, 1.0 + 2.0 * g1 * float(np.sum(U[:-1] * U[1:])) / uu)
    a = g1 / rho
    # the lags whose weight a rho^h is above 1e-12 of a (beyond them the sum changes by less than that share)
    h_max = min(n - 1, int(np.ceil(np.log(1e-12) / np.log(rho))))
    acc = sum(a * rho**h * float(np.sum(U[:-h] * U[h:])) for h in range(1, h_max + 1))
    return max(1.0, 1.0 + 2.0 * acc / uu)


@dataclass(frozen=True)
class Confirmation:
    """The held-out check of a scored atom on the confirmation rows: ``z``, ``z`` without the most favourable row,
    whether the held-out residual norm drops (``better``), and for an atom of time alone, whether the mean
    residual of the nearest calibration rows in time predicts those rows at least as well (``local``: a wander
    of the cell correlated over a few rows, which a drift, a step or an oscillation fitted to this campaign
    follows only by chance and which does not continue into later rows)."""

    z: float
    z_without_best_row: float
    better: bool
    local: bool = False

    def holds(self, z_min: float) -> bool:
        """Whether the held-out check passes at ``z_min``: ``z`` and ``z`` without the most favourable row above it,
        the held-out error lower, and not a wander the nearest rows in time predict as well (``local``)."""
        return self.z > z_min and self.z_without_best_row > z_min and self.better and not self.local


def confirm(prob: Problem, fit: Fit, s: Scored, z_min: float) -> Confirmation:
    """Held-out check of a scored atom (:class:`Confirmation`); its prediction ``u`` on the confirmation rows is
    linearised, the geometry re-adjusting to it."""
    sb = scoring_basis(prob, fit)
    A = (sb.rc.J[:, fit.free] * sb.sw[:, None])[sb.keep]
    # geometry re-adjusts to the atom: beta_A = -A^+ E B psi
    beta_A = -np.linalg.lstsq(A, s.E @ s.psi, rcond=None)[0]
    rv = fit.model_val.residuals(fit.z)
    kv = prob.keep_val[rv.row]
    Fv = prob.features(s.atom)[prob.rows_val]
    Ev = raw_columns(fit.model_val, s.atom, Fv, fit.z, rv) @ s.basis
    u_all = Ev @ s.psi + rv.J[:, fit.free] @ beta_A
    u = u_all[kv]
    r = rv.r[kv]
    nu = float(np.linalg.norm(u))
    if nu <= 0:
        return Confirmation(0.0, 0.0, False)
    # per row c_k = r_k . u_k: under the null (u independent of the held-out residual) each is symmetric about zero
    # and the rows are independent, whatever the residual's size and its correlation within a row (an unmodelled
    # effect moves every coordinate of a row together: a coordinate-wise z would count them as independent and pass
    # a chance correlation as a confirmation). The rank test of their sum (Wilcoxon's signed ranks, as a normal
    # score) keeps that level and the power a few rows of large residual would take from a ratio of sums.
    contrib = np.bincount(rv.row[kv], weights=r * u, minlength=fit.model_val.obs.n)
    c = contrib[np.bincount(rv.row[kv], minlength=fit.model_val.obs.n) > 0]
    z = signed_rank_z(c)
    z_minus = signed_rank_z(np.delete(c, int(np.argmax(c)))) if c.size > 1 else 0.0
    if of_time(s.atom) and moves_the_cell(s.atom):
        # a term of time on the measurement side predicts neighbouring rows alike, and noise that wanders over a few
        # rows (an instrument's frame, the cell) moves their residuals together as the term does: the rows' products
        # are then not independent. The score is deflated by the variance their serial correlation adds, the larger
        # of two readings of it: on every coordinate of the rows' remainder r_k - u_k (vector_inflation: white plus
        # a wander decaying from row to row), and along the prediction, e_k = (r_k - u_k) . u_k (serial_inflation:
        # zero-mean when the term is right, whatever the wander). A term through the arm is scored on rows taken as
        # independent: its remainder's slow misfit (a partial thermal term, the geometry's misprediction) reads as a
        # wander there, and deflating it would reject true thermal terms. A change (a step, a window) is read along
        # its prediction alone: constant over its rows, it turns any slow remainder on every coordinate (another
        # station's misfit) into a large inflation, and a bumped instrument's step, an order of magnitude above the
        # rows' scatter, would not be confirmed
        t = prob.ctx.t_s if prob.ctx.t_s is not None else np.arange(len(prob.ctx.q), dtype=float)
        order = np.argsort(t[prob.rows_val], kind="stable")
        present = np.bincount(rv.row[kv], minlength=fit.model_val.obs.n)[order] > 0
        Rm = row_blocks(fit.model_val, rv.r - u_all)
        Rm[~prob.keep_val] = np.nan
        Um = row_blocks(fit.model_val, u_all)
        Um[~np.isfinite(Rm)] = 0.0
        e = np.bincount(rv.row[kv], weights=(r - u) * u, minlength=fit.model_val.obs.n)
        inflation = serial_inflation(e[order][present], t[prob.rows_val][order][present])
        if reads_the_wander(s.atom):
            inflation = max(inflation, vector_inflation(np.nan_to_num(Rm[order][present]), Um[order][present]))
        deflate = 1.0 / np.sqrt(inflation)
        z, z_minus = z * deflate, z_minus * deflate
    err_term = float(np.sum((r - u) ** 2))
    better = err_term < float(r @ r)
    local = False
    if time_only(s.atom):
        U, Rv = neighbour_predictions(prob, fit)["time"]
        Ut = row_blocks(fit.model_val, u_all)
        ok = np.isfinite(Rv) & np.isfinite(U) & np.isfinite(Ut)
        # strictly better: a change that happened before the held-out block is predicted alike by the term and by
        # the last rows' state, and the term is the model that says so
        local = float(np.sum((Rv - U)[ok] ** 2)) < float(np.sum((Rv - Ut)[ok] ** 2))
    return Confirmation(z, z_minus, better, local)


def confirm_configurations(prob: Problem, fit: Fit, s: Scored, scored: list[Scored],
                           sizes: dict[str, int]) -> FoldConfirmation | None:
    """The check of a scored atom between the sampled configurations
    (:func:`twin.diagnosis.configurations.fold_confirmation`): on each fold of the joint values it reads, the rows of
    the other folds choose again among it and its rivals (the atoms of ``scored`` at its place reading the same
    joints within :data:`twin.diagnosis.configurations.RIVAL_MARGIN` of its evidence) and the one chosen predicts the
    fold, the geometry re-adjusting, judged at :data:`twin.diagnosis.configurations.Z_MIN`; None when it reads no
    joint angle or its joints have too few blocks of values."""
    joints = joints_read(s.atom.features)
    if not joints:
        return None
    q = prob.ctx.q[prob.rows_cal][:, [j - 1 for j in joints]]
    folds = configuration_folds(q, block_widths(s.atom.features, joints, np.ptp(q, axis=0)))
    if folds is None:
        return None
    place = (s.atom.place, s.atom.target)
    rivals = [o for o in scored if o.atom.key != s.atom.key and (o.atom.place, o.atom.target) == place
              and joints_read(o.atom.features) == joints and o.logp_adj < s.logp_adj + RIVAL_MARGIN]
    sb = scoring_basis(prob, fit)
    A = (sb.rc.J[:, fit.free] * sb.sw[:, None])[sb.keep]
    return fold_confirmation(A, s.E, (sb.rc.r * sb.sw)[sb.keep], sb.rows, folds, CONFIGURATION_Z,
                             rivals=[o.E for o in rivals], log_pool=[np.log(sizes[o.atom.pool]) for o in [s, *rivals]],
                             evidence_scale=prob.evidence_scale)


NEIGHBOURS = 4  # rows a neighbour smoother averages
JOINT_WEIGHTS = np.array([1.0, 1.0, 1.0, 0.3, 0.3, 0.3])  # arm joints move the plate more than the wrist's


def joint_weights(n_joints: int) -> np.ndarray:
    """Weights ``(N,)`` of the joints in the neighbours' distance: the last three (the wrist) ``0.3``, the others 1
    (``JOINT_WEIGHTS`` for six joints)."""
    w = np.ones(n_joints)
    w[max(n_joints - 3, 0):] = 0.3
    return w


def row_blocks(model: ExtendedModel, r: np.ndarray) -> np.ndarray:
    """Whitened residuals ``(m,)`` as ``(n, 3 K)`` per row (point-major, x y z), NaN where not measured."""
    obs = model.obs
    K = obs.spheres.shape[1]
    shape = (K, 3, obs.n)
    mask = np.broadcast_to(obs.seen.T[:, None, :], shape)
    tmp = np.full(shape, np.nan)
    tmp[mask] = r
    return np.transpose(tmp, (2, 0, 1)).reshape(obs.n, 3 * K)


def neighbour_predictions(prob: Problem, fit: Fit) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per smoother (``joints``, ``time``): the mean whitened residual ``(n_v, 9)`` of the ``NEIGHBOURS`` nearest
    calibration rows of each confirmation row (joint space: joints scaled by their spread and ``JOINT_WEIGHTS``;
    time: ``t_s``, else the row order; rows with the same commanded joints excluded: a repeat shares the visit's
    error), and the confirmation rows' own residual ``(n_v, 9)`` (NaN where not measured or gross)."""
    key = ("neighbours", id(prob.w_cal), id(prob.keep_val))
    got = fit.cache.get(key)
    if got is not None:
        return got
    rc = fit.model_cal.residuals(fit.z, jacobian=False)
    rv = fit.model_val.residuals(fit.z, jacobian=False)
    Rc = row_blocks(fit.model_cal, rc.r)
    Rv = row_blocks(fit.model_val, rv.r)
    Rc[prob.w_cal <= 0] = np.nan
    Rv[~prob.keep_val] = np.nan
    qc, qv = prob.ctx.q[prob.rows_cal], prob.ctx.q[prob.rows_val]
    scale = np.ptp(np.vstack([qc, qv]), axis=0)
    w = (JOINT_WEIGHTS if qc.shape[1] == 6 else joint_weights(qc.shape[1])) / np.where(scale > 1e-9, scale, 1.0)
    same = np.all(np.abs(qv[:, None, :] - qc[None, :, :]) < 1e-9, axis=2)
    t = prob.ctx.t_s if prob.ctx.t_s is not None else np.arange(len(prob.ctx.q), dtype=float)
    out = {}
    for name, D in (("joints", np.linalg.norm((qv[:, None, :] - qc[None, :, :]) * w, axis=2)),
                    ("time", np.abs(t[prob.rows_val][:, None] - t[prob.rows_cal][None, :]))):
        D = np.where(same | np.all(np.isnan(Rc), axis=1)[None, :], np.inf, D)
        k = min(NEIGHBOURS, D.shape[1])
        nb = np.argsort(D, axis=1)[:, :k]
        with np.errstate(invalid="ignore"):
            U = np.nanmean(Rc[nb], axis=1)  # (n_v, 9)
        out[name] = (U, Rv)
    fit.cache[key] = out
    return out


def time_blocks(prob: Problem) -> np.ndarray:
    """Block number ``(n_v,)`` of each confirmation row: consecutive runs of ``ceil(m^(1/3))`` of its ``m`` visits in
    measurement order (a visit, consecutive rows at the same commanded joints, stays in one block). The noise may be
    correlated from row to row over a few rows (an instrument frame or a cell that wanders); sums over blocks of
    that length are nearly independent where single rows are not (batch means; ``m^(1/3)`` blocks' length, the
    usual rate for a correlation of short range)."""
    q = np.round(prob.ctx.q[prob.rows_val], 9)
    new = np.ones(len(q), bool)
    if len(q):
        new[1:] = np.any(q[1:] != q[:-1], axis=1)
    vis = np.cumsum(new) - 1
    m = int(vis[-1]) + 1 if len(q) else 0
    length = max(1, int(np.ceil(m ** (1.0 / 3.0) - 1e-9)))
    return vis // length


def earlier_rows_prediction(prob: Problem, fit: Fit) -> tuple[np.ndarray, np.ndarray]:
    """The time smoother of a block of held-out rows: each confirmation row's residual predicted by the mean
    residual ``(n_v, 3 K)`` of the confirmation rows of the block of time two before its own
    (:func:`time_blocks`; NaN for the rows of the first two blocks), and the rows' own residual. The held-out rows
    are a block of time after the rows that fit: the calibration rows nearest in time are the same few for every one
    of them, and a prediction shared by every row is no test. The block between them keeps the noise's correlation
    from row to row (over less than a block) out of the prediction: noise correlated in time over a few rows is
    noise, and a structure in time worth the name lasts longer than that. Under that null each block's ``sum c_k``
    (``c_k = r_k . u_k``) has mean zero given the rows before it."""
    rv = fit.model_val.residuals(fit.z, jacobian=False)
    Rv = row_blocks(fit.model_val, rv.r)
    Rv[~prob.keep_val] = np.nan
    blk = time_blocks(prob)
    U = np.full_like(Rv, np.nan)
    for b in np.unique(blk):
        src = blk == b - 2
        if src.any() and np.isfinite(Rv[src]).any():
            with np.errstate(invalid="ignore"):
                U[blk == b] = np.nanmean(Rv[src], axis=0)
    return U, Rv


def smooth_confirm(prob: Problem, fit: Fit, z_min: float) -> dict:
    """Is the held-out residual predictable from the rows nearest to it, in joint space or in time?

    Joint space: each confirmation row's residual is predicted by the mean residual of its ``NEIGHBOURS`` nearest
    calibration rows (joints scaled by their spread and ``JOINT_WEIGHTS``), rows with the same commanded joints
    excluded (a repeat shares the visit's error); the calibration residuals are independent of the held-out ones.
    Time: by the confirmation rows of the block of time two before its own (:func:`earlier_rows_prediction`). A
    structure that is smooth in the configuration or in time makes neighbours alike; noise that changes from visit
    to visit (the robot's repeatability, an instrument error per pose), or within a few rows, does not. Per
    confirmation row ``c_k = r_k . u_k``, summed over the blocks of time of :func:`time_blocks` (the noise may be
    correlated from row to row within a block: the sums over blocks are the independent units, batch means): under
    that null each block's ``C_b`` is zero-mean (given what predicts it), so ``z = sum C_b / sqrt(sum C_b^2)`` is
    ~N(0, 1) or narrower whatever the noise's size, its correlation within a row and over a few rows. Confirmed when
    ``z > z_min`` also without the most favourable block (either smoother)."""
    out = {}
    smoothers = {"joints": neighbour_predictions(prob, fit)["joints"], "time": earlier_rows_prediction(prob, fit)}
    blk = time_blocks(prob)
    for name, (U, Rv) in smoothers.items():
        c = np.nansum(Rv * U, axis=1)
        ok_rows = np.isfinite(c) & np.any(np.isfinite(Rv * U), axis=1)
        C = np.bincount(blk[ok_rows], weights=c[ok_rows], minlength=int(blk.max(initial=-1)) + 1)
        C = C[np.bincount(blk[ok_rows], minlength=C.size) > 0]
        den = float(np.sqrt(np.sum(C**2)))
        z = float(C.sum() / den) if den > 0 else 0.0
        z_minus = float((C.sum() - C.max()) / np.sqrt(max(np.sum(C**2) - C.max() ** 2, 1e-300))) if C.size > 1 else 0.0
        out[name] = {"z": z, "z_without_best_block": z_minus, "rows": int(ok_rows.sum()), "blocks": int(C.size)}
    best = max(out, key=lambda k: out[k]["z"])
    return {"by": best, "z": out[best]["z"], "confirmed": any(v["z"] > z_min and v["z_without_best_block"] > z_min
                                                              for v in out.values()), "smoothers": out}
