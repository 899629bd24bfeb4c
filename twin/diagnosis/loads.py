"""Terms of the arm's own gravity load that need no mass properties: backlash signed by the load, the base tilting.

* **Load-signed backlash** of joint ``j``: ``dtheta_j = b sign(tau_j(q))``. A gear held against gravity rests on
  the flank its load pushes it to, whatever the direction of the last move: the offset's sign follows the sign of
  the joint's gravity torque. The torque is the URDF masses' (:func:`twin.diagnosis.candidates.gravity_torques`)
  when the chain has them. Without masses it is a combination of the joint's three leading principal torque shapes
  under the generic prior the compliance atoms use (:func:`twin.diagnosis.pools.catalogue_atoms`; the load lies
  close to their span, and the leading shape alone puts the sign's change ~10 % of the rows off): the sign of the
  combination along each of ``LOAD_DIRECTIONS`` directions over a hemisphere of that span (a pool of its own,
  ``load``, whose size is its Bonferroni factor), the kept one refined (:func:`refine_load_sign`). The sign is
  known from the first row on (no motion
  history); it competes with the motion-signed backlash for the joint's one backlash slot, and where the rows
  cannot tell the two apart the other is reported as the alternative.
* **Base compliance** without masses: the robot's base rotating about its horizontal axes ``x``, ``y`` through its
  origin under the gravity moment of the arm, ``(delta_x, delta_y) = (c_x M_x(q), c_y M_y(q))``. The moment is
  linear in the links' unknown mass moments ``(m_k, h_k = m_k c_k)``: ``M_a = sum_k e_a . ((m_k o_k + R_k h_k)
  x g)``, so ``Y[:, a, k] = (e_a . (o_k x g), R_k^T (g x e_a))`` (:func:`twin.diagnosis.candidates.base_moment_regressor`; the joint
  gravity-torque regressor with the axis ``e_a`` through the base origin). One compliance ``c`` for both axes: the
  tilt ``c (Y_x w, Y_y w)`` is linear in ``c w``; the prior-weighted columns of both axes stacked (the compliance
  atoms' prior: masses of one order, centres ~0.1 m off the frames) are reduced to their ``TILT_RANK`` leading
  principal shapes, each a pair of features (``axis`` 0 and 1, one ``shape``) with one coefficient; the atom (family
  ``tilt``, target ``tilt0``) has ``TILT_RANK`` coefficients, as a joint's compliance. With the chain's masses the
  catalogue's ``tilt`` atoms (one compliance per axis under the known moment) hold the same effect. The shoulder's
  torque and the base's moment follow the same mass moments: where the rows cannot tell the tilt from the shoulder's
  compliance, the one not kept is reported as the other's alternative (:func:`load_alternatives`).
"""

from __future__ import annotations

from dataclasses import replace as replace_atom

import numpy as np

from ..kinematics import RobotModel
from .atoms import Atom, joint_words
from .candidates import RowContext, base_moment_regressor, gravity_torque_regressor, gravity_torques, has_masses
from .extend import error_stats
from .features import BaseMoment, GravMix, LoadSign, Torque
from .problem import psi_init
from .scoring import score_atoms
from .values import feature_values

__all__ = ["TILT_RANK", "COM_PRIOR_M", "LOAD_SHAPES", "LOAD_DIRECTIONS", "torque_shapes", "load_atoms", "load_sign_feature",
           "refine_load_sign", "load_alternatives", "tilt_angles"]

TILT_RANK = 3  # principal shapes of the base's gravity moment kept (each turns the base about both axes)
COM_PRIOR_M = 0.1  # [m] the torque shapes' prior: a link's centre of mass ~0.1 m off its frame
LOAD_SHAPES = 3  # a joint's leading torque shapes whose combinations' signs the load-signed backlash tries


def _prior(N: int) -> np.ndarray:
    return np.tile(np.array([1.0, COM_PRIOR_M, COM_PRIOR_M, COM_PRIOR_M]), N)


def torque_shapes(model: RobotModel, q: np.ndarray, i: int, rank: int | None = None,
                  Y: np.ndarray | None = None) -> tuple[GravMix, ...]:
    """Joint ``i``'s (1-based) leading principal gravity-torque shapes under the generic prior, as ``gravmix`` features
    (the compliance atoms' shapes, leading first): the right singular vectors of the prior-weighted columns
    ``Y[:, i, k, c] prior_c`` (``k >= i``; prior 1 for a mass, ``COM_PRIOR_M`` for a mass moment) whose singular values
    pass ``1e-6`` of the largest, each scaled to unit RMS over the rows; the first ``rank`` of them (all when None), or
    ``()`` when the joint carries no varying torque. ``Y``: :func:`~twin.diagnosis.candidates.gravity_torque_regressor`
    on ``q`` when already computed."""
    Y = gravity_torque_regressor(model, q) if Y is None else Y
    N = model.n_joints
    cols, prior = [], []
    for k in range(i, N + 1):
        for c in range(4):
            cols.append([k, c])
            prior.append(1.0 if c == 0 else COM_PRIOR_M)
    M = np.stack([Y[:, i - 1, k - 1, c] for k, c in cols], axis=1) * np.array(prior)
    if not np.any(np.abs(M) > 1e-9):
        return ()
    _, sv, Vt = np.linalg.svd(M, full_matrices=False)
    rk = int(np.sum(sv > 1e-6 * sv[0]))
    rk = rk if rank is None else min(rank, rk)
    return tuple(GravMix(i=i, cols=tuple(map(tuple, cols)), w=tuple((Vt[k] * np.array(prior)).tolist()),
                         h=float(sv[k] / np.sqrt(len(M)))) for k in range(rk))


def refine_load_sign(prob, fit, s, pool_sizes: dict):
    """A kept load-signed backlash found on the grid of directions moved to the direction in the span of the joint's
    torque shapes whose sign explains most (Nelder-Mead on the direction from the grid's best, scored as every atom
    is: :func:`twin.diagnosis.scoring.score_atoms`). Returns the scored atom."""
    from scipy.optimize import minimize

    f0 = s.atom.features[0]
    if not isinstance(f0, LoadSign) or f0.u is None:
        return s
    shapes = torque_shapes(prob.prep.nominal, prob.ctx.q, int(f0.f.i), LOAD_SHAPES)
    if len(shapes) < 2:
        return s
    best = [s]

    def cost(u):
        u = np.asarray(u, float)
        if not np.linalg.norm(u) > 0:
            return 0.0
        a = replace_atom(s.atom, features=(load_sign_feature(shapes, u / np.linalg.norm(u)),))
        got = score_atoms(prob, fit, [a], pool_sizes, exact_top=1)
        if not got:
            return 0.0
        if got[0].dchi2 > best[0].dchi2:
            best[0] = got[0]
        return -got[0].dchi2

    minimize(cost, np.asarray(f0.u, float), method="Nelder-Mead",
             options={"xatol": 1e-3, "fatol": 1e-3, "maxfev": 80, "initial_simplex": None})
    return best[0]


LOAD_DIRECTIONS = 300  # directions in the span of a joint's leading torque shapes whose sign is tried (then refined)


def _hemisphere(k: int) -> np.ndarray:
    """``k`` unit vectors ``(k, 3)`` spread over a hemisphere (a Fibonacci lattice; a direction and its opposite give
    the same sign feature up to its coefficient)."""
    i = np.arange(k) + 0.5
    z = i / k
    phi = np.pi * (1 + 5**0.5) * i
    r = np.sqrt(1 - z**2)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def load_sign_feature(shapes: tuple, u: np.ndarray) -> LoadSign:
    """The sign of the combination ``u`` ``(k,)`` of a joint's torque shapes (``gravmix`` features, each scaled to unit
    RMS) as a ``loadsign`` feature."""
    w = sum(ui * np.asarray(f.w, float) / f.h for ui, f in zip(u, shapes))
    f0 = shapes[0]
    return LoadSign(f=GravMix(i=f0.i, cols=f0.cols, w=tuple(w.tolist()), h=1.0), u=tuple(float(x) for x in u))


def load_atoms(model: RobotModel, ctx: RowContext) -> list:
    """The load-signed backlash of every joint whose gravity load changes sign over the rows, and, on a chain without
    mass properties, the base tilting under the arm's unknown gravity moment (module docstring)."""
    atoms = []
    N = model.n_joints
    masses = has_masses(model)
    tau = gravity_torques(model, ctx.q) if masses else None
    cache: dict = {}
    for j in range(1, N + 1):
        if masses:
            feats = [LoadSign(f=Torque(j=j, h=1.0))]
        else:
            # the masses are unknown: the sign of combinations of the joint's leading torque shapes (the load lies
            # close to their span), on a grid of directions refined when kept (refine_load_sign)
            shapes = torque_shapes(model, ctx.q, j, LOAD_SHAPES)
            if not shapes:
                continue
            U = _hemisphere(LOAD_DIRECTIONS) if len(shapes) == 3 else np.eye(len(shapes))
            feats = [load_sign_feature(shapes, u[:len(shapes)]) for u in U]
        for f in feats:
            s = feature_values((f,), ctx, model, cache)[:, 0]
            if min(np.sum(s > 0), np.sum(s < 0)) < 3:
                continue  # the load keeps one sign: the offset is a constant the geometry holds
            u = f.u
            atoms.append(Atom("backlash", "joint", f"theta{j}", (f,), f"load_sign_j{j}" + ("" if u is None else
                              f" ({', '.join(f'{x:+.3f}' for x in u)})"),
                              f"joint {joint_words(model, j)} backlash (offset signed by its gravity load)",
                              "catalogue" if masses else "load", (j,)))
    if not masses:
        Y = base_moment_regressor(model, ctx.q)
        n = len(ctx.q)
        prior = _prior(N)
        # one compliance for both axes: the moment's two components share the mass moments, so a shape is a pair of
        # features (one per axis) with one coefficient
        M = np.concatenate([Y[:, 0].reshape(n, -1), Y[:, 1].reshape(n, -1)]) * prior
        feats = []
        if np.any(np.abs(M) > 1e-9):
            _, sv, Vt = np.linalg.svd(M, full_matrices=False)
            rk = int(np.sum(sv > 1e-6 * sv[0]))
            feats = [BaseMoment(axis=a, shape=k, w=tuple((Vt[k] * prior).tolist()), h=float(sv[k] / np.sqrt(n)))
                     for k in range(min(TILT_RANK, rk)) for a in (0, 1)]
        if feats:
            atoms.append(Atom("tilt", "param", "tilt0", tuple(feats), "gravity moment carried by the base (shapes)",
                              "the robot's base tilting about its horizontal axes under the arm's gravity moment "
                              "(base compliance; the moment's shapes from unknown link masses)", "catalogue"))
    return atoms


def tilt_angles(features, F: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """The tilt ``(n, 2)`` [rad] about the pivot's ``x`` and ``y`` axes of a tilt atom with ``features`` (each turns
    the pivot about its ``axis``), values ``F`` ``(n, K)`` and coefficients ``phi`` ``(K,)``."""
    out = np.zeros((F.shape[0], 2))
    for k, f in enumerate(features):
        out[:, int(getattr(f, "axis", k))] += F[:, k] * phi[int(getattr(f, "shape", k))]
    return out


ALT_RMS = 1.02  # a counterpart predicting the confirmation rows within this factor is an alternative


def _counterparts(a, pool: list) -> list:
    """The terms of the other reading of the same load effect: a backlash signed by the last move <-> signed by the
    load (same joint); a joint's compliance <-> the base tilting under the arm's moment (the shoulder's torque and the
    base's moment follow the same mass moments)."""
    kinds = {f.kind for f in a.features}
    if a.family == "backlash":
        want = "loadsign" if kinds <= {"sign", "play"} else "sign"
        return [c for c in pool if c.family == "backlash" and c.target == a.target
                and {f.kind for f in c.features} == {want}]
    if a.family == "compliance" and a.pool == "catalogue" and kinds == {"gravmix"}:
        return [c for c in pool if c.family == "tilt" and c.target == "tilt0"]
    if a.family == "tilt" and a.target == "tilt0":
        return [c for c in pool if c.family == "compliance" and c.pool == "catalogue"
                and {f.kind for f in c.features} == {"gravmix"} and c.joints and c.joints[0] <= 3]
    return []


def load_alternatives(prob, fit, pool: list, sizes: dict, alpha_select: float) -> list[dict]:
    """Alternatives the rows cannot tell from a kept load term: each kept backlash, compliance or base tilt is replaced
    by the strongest significant term of its other reading (:func:`_counterparts`), the model refitted; when that
    predicts the confirmation rows within ``ALT_RMS`` of the model as kept, it is reported as the kept term's
    alternative (``held_out_rms_mm``: the alternative's and the kept model's confirmation RMS)."""
    out = []
    P = prob.prep.space.size
    e_now = None
    for a, _ in list(fit.chosen):
        cands = _counterparts(a, pool)
        if not cands:
            continue
        keep = [(c, B) for c, B in fit.chosen if c is not a]
        base = prob.fit(fit.z[:P], keep, psi_init(fit, keep))
        scored = [s for s in score_atoms(prob, base, cands, sizes, exact_top=len(cands))
                  if s.logp_adj < np.log(alpha_select)]
        if not scored:
            continue
        best = max(scored, key=lambda s: s.dchi2)
        alt = prob.fit(base.z[:P], keep + [(best.atom, best.basis)], psi_init(base, keep + [(best.atom, best.basis)]))
        e_alt = error_stats(alt.model_val, alt.z, prob.keep_val)["position_mm"]["rms"]
        if e_now is None:
            e_now = error_stats(fit.model_val, fit.z, prob.keep_val)["position_mm"]["rms"]
        if e_alt <= ALT_RMS * e_now:
            out.append({"of": a.label, "alternative": best.atom.label, "family": best.atom.family,
                        "channel": best.atom.channel, "target": best.atom.target, "delta_chi2": best.dchi2,
                        "delta_chi2_chosen": float("nan"), "share_reproduced": float("nan"),
                        "held_out_rms_mm": [e_alt, e_now]})
    return out
