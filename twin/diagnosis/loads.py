"""Terms of the arm's own gravity load that need no mass properties: backlash signed by the load, the base tilting.

* **Load-signed backlash** of joint ``j``: ``dtheta_j = b sign(tau_j(q))``. A gear held against gravity rests on
  the flank its load pushes it to, whatever the direction of the last move: the offset's sign follows the sign of
  the joint's gravity torque. The torque is the URDF masses' (:func:`twin.diagnosis.candidates.gravity_torques`)
  when the chain has them, alone or with a carried load's torque beside it (the masses hold the arm, not the tool or
  the instrument's nest it carries, which may set a wrist's load: :func:`carried_shapes`, directions of the pool
  ``load``). Without masses it is a combination of the joint's three leading principal torque shapes
  under the generic prior the compliance atoms use (:func:`twin.diagnosis.pools.catalogue_atoms`; the load lies
  close to their span, and the leading shape alone puts the sign's change ~10 % of the rows off): the sign of the
  combination along each of ``LOAD_DIRECTIONS`` directions over a hemisphere of that span (a pool of its own,
  ``load``, whose size is its Bonferroni factor), the kept one refined (:func:`refine_load_sign`). A sharp flank's
  load is then placed from the flank each row's own residual reads (a row on the wrong flank is off by twice the
  backlash), in the full span of the joint's torque shapes, with the largest margin (:func:`_flank_read`); the models
  to use read it on every row, the report rows on every row before them. The sign is known from the first row on
  (no motion history); it competes with the motion-signed backlash for the joint's one backlash slot, and where the rows
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

from ..estimator import distributions as dists
from ..kinematics import RobotModel
from .atoms import Atom, joint_words, tilt_axis, tilt_coefficient
from .candidates import RowContext, base_moment_regressor, gravity_torque_regressor, gravity_torques, has_masses
from .features import BaseMoment, GravMix, LoadSign, Torque
from .problem import held_out_rms, psi_init
from .scoring import raw_columns, score_atoms, scoring_basis
from .values import feature_values

__all__ = ["TILT_RANK", "COM_PRIOR_M", "LOAD_SHAPES", "LOAD_DIRECTIONS", "torque_shapes", "payload_shapes",
           "carried_shapes", "load_atoms", "load_sign_feature", "refine_load_sign", "reads_its_load",
           "load_alternatives", "tilt_angles", "FLANK_WIDTHS", "REFINE_SHAPES", "STIFFENING_WIDTH", "STIFFENING_GRID",
           "STIFFENING_LAWS", "STATED_SPREAD", "FLANK_SEEN", "law_atom", "stiffening_atoms", "fitted_load",
           "own_link_atom", "own_link_channel", "own_link_stiffening", "along_link_weight", "load_candidates",
           "OWN_LINK_DIRECTIONS", "link_tilt_atom", "stated_load_mix"]

TILT_RANK = 3  # principal shapes of the base's gravity moment kept (each turns the base about both axes)
COM_PRIOR_M = 0.1  # [m] the torque shapes' prior: a link's centre of mass ~0.1 m off its frame
LOAD_SHAPES = 3  # a joint's leading torque shapes whose combinations' signs the load-signed backlash tries


def _prior(N: int) -> np.ndarray:
    return np.tile(np.array([1.0, COM_PRIOR_M, COM_PRIOR_M, COM_PRIOR_M]), N)


def torque_shapes(model: RobotModel, q: np.ndarray, i: int, rank: int | None = None,
                  Y: np.ndarray | None = None, links: tuple[int, ...] | None = None) -> tuple[GravMix, ...]:
    """Joint ``i``'s (1-based) leading principal gravity-torque shapes under the generic prior, as ``gravmix`` features
    (the compliance atoms' shapes, leading first): the right singular vectors of the prior-weighted columns
    ``Y[:, i, k, c] prior_c`` (``k >= i``; prior 1 for a mass, ``COM_PRIOR_M`` for a mass moment) whose singular values
    pass ``1e-6`` of the largest, each scaled to unit RMS over the rows; the first ``rank`` of them (all when None), or
    ``()`` when the joint carries no varying torque. ``Y``: :func:`~twin.diagnosis.candidates.gravity_torque_regressor`
    on ``q`` when already computed. ``links``: the links whose mass moments load the joint (1-based; default every
    link from ``i`` on)."""
    Y = gravity_torque_regressor(model, q) if Y is None else Y
    N = model.n_joints
    cols, prior = [], []
    for k in (range(i, N + 1) if links is None else links):
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


def payload_shapes(model: RobotModel, q: np.ndarray, i: int, Y: np.ndarray | None = None) -> tuple[GravMix, ...]:
    """Joint ``i``'s gravity-torque shapes of a payload: a point mass ``m`` at an unknown offset ``c`` from the flange
    loads joint ``i`` with ``tau_i = Y[:, i, N] @ (m, m c')`` (``c'``: the offset in the last link's frame, the flange's
    offset and turn from it absorbed: ``m c' = m d + R m c`` is linear in ``(m, m c)``), the last link's four
    columns of :func:`~twin.diagnosis.candidates.gravity_torque_regressor`: :func:`torque_shapes` of them alone
    (``()`` when the payload gives the joint no varying torque)."""
    return torque_shapes(model, q, i, Y=Y, links=(model.n_joints,))


# a smooth flank's widths tried, as fractions of the load's RMS over the rows (beyond STIFFENING_WIDTH: a stiffening)
FLANK_WIDTHS = (0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0)
STIFFENING_GRID = (0.7, 1.5, 3.0)  # widths (fractions of the load's RMS) of the stiffening compliance atoms
# the stiffening's laws: saturating smoothly (tanh of the load over the width), or two stiffnesses (in proportion to
# the load up to the width, stiffer beyond: clip)
STIFFENING_LAWS = (None, "clip")
REFINE_SHAPES = 5  # a joint's leading torque shapes the direction of a kept load-signed backlash is refined in
# [fraction of the load's RMS] a load law taken up over a wider width than this is the joint's stiffness rising with
# its load (a compliance), over a narrower one a gear's flank changing sides (a backlash: the flank changes while the
# load crosses zero, within the joint's friction, a fraction of its load)
STIFFENING_WIDTH = 1.0 / 3.0
STATED_SPREAD = 0.1  # the stated masses' error, as a share of the generic prior's spread of the torque shapes
# a smooth flank is seen by the rows whose law differs from the load's sign by more than a tenth of the offset
FLANK_SEEN = 0.9
SIMPLEX_STEP = 0.1  # the refinement's first steps along each direction (each of unit RMS over the rows)
# directions over a half turn in the plane of a link's own first mass moment whose stiffening is tried on a chain
# without masses (a direction and its opposite give the same odd law up to its coefficient)
OWN_LINK_DIRECTIONS = 12


def law_atom(model: RobotModel, atom: Atom, f: LoadSign, rms: float) -> Atom:
    """A law of joint ``atom.target``'s gravity load with the feature ``f`` (its load, direction and width as set;
    ``rms``: the RMS of the load over the rows, the width's unit): a backlash (offset signed by the load) when the
    law changes sides sharply or within ``STIFFENING_WIDTH`` of the load's RMS, else a compliance stiffening with the
    load (the law and the load itself: two coefficients); channel and label to match, pool as ``atom``'s."""
    j = int(atom.target[5:])
    jw = joint_words(model, j)
    u = "" if f.u is None else f" ({', '.join(f'{x:+.3f}' for x in f.u)})"
    if f.width is None:
        return replace_atom(atom, family="backlash", features=(f,), channel=f"load_sign_j{j}{u}",
                            label=f"joint {jw} backlash (offset signed by its gravity load)")
    rel = f.width / rms
    fn = "tanh" if f.law is None else f.law
    law = f"{fn}(load / {f.width:.3g} N m)" if isinstance(f.f, Torque) else f"{fn}(load / {rel:.3g} of its RMS)"
    if rel <= STIFFENING_WIDTH:
        return replace_atom(atom, family="backlash", features=(f,), channel=f"load_sign_j{j}{u} {fn} width {rel:.3g} rms",
                            label=f"joint {jw} backlash (offset signed by its gravity load, its flank taken up "
                                  f"smoothly: {law})")
    # the law with its load in proportion beside it (the stiffness beyond the change): the law alone would read a
    # linear compliance wherever the load stays within the width, and stand in for one
    return replace_atom(atom, family="compliance", features=(f, f.f),
                        channel=f"stiffening_j{j}{u} {fn} width {rel:.3g} rms",
                        label=f"joint {jw} compliance under gravity, stiffening with the load (its deflection follows "
                              f"{law})")


def stiffening_atoms(model: RobotModel, ctx: RowContext, j: int, load, *, u: tuple | None = None) -> list[Atom]:
    """Joint ``j``'s compliance stiffening with its gravity load ``load`` (a :class:`Torque` of the stated masses, or a
    :class:`GravMix` combination of its torque shapes: a linear compliance's fitted torque): ``tanh(load / w)`` for
    ``w`` in ``STIFFENING_GRID`` of the load's RMS over the rows, and ``clip(load / w, -1, 1)`` (two stiffnesses, the
    change at ``w``), refined when kept (:func:`refine_load_sign`). Softer near zero load than under a large one: a
    harmonic drive's first stiffness, a gear's teeth coming into contact. ``u``: the load's coordinates in the shapes
    it was combined from, carried by its features (:func:`own_link_stiffening`)."""
    v = feature_values((load,), ctx, model)[:, 0]
    rms = float(np.sqrt(np.mean(v ** 2)))
    if not rms > 0:
        return []
    base = Atom("compliance", "joint", f"theta{j}", (), "", "", "catalogue", (j,))
    return [law_atom(model, base, LoadSign(f=load, u=u, width=float(fr * rms), law=law), rms)
            for law in STIFFENING_LAWS for fr in STIFFENING_GRID]


def load_candidates(prob, fit, pool: list[Atom], targets: set[str], have: set[str]) -> list[Atom]:
    """The load family's terms of the joints ``targets`` not in ``have``: the pool's compliances of those joints, the
    compliance under the weight of the link each moves, the stiffening of each linear compliance ``fit`` holds, and,
    where ``fit`` holds the weight of the link a joint moves and the chain states no masses, that weight's stiffening
    along the directions of its plane (:func:`own_link_stiffening`: the fitted torque places the load's zero only up
    to what the joint's zero takes). The candidates of ``twin.diagnosis.rule``'s family swaps (``prob`` a
    :class:`twin.diagnosis.problem.Problem`, ``fit`` its :class:`Fit`)."""
    model = prob.prep.nominal
    out = [c for c in pool if c.family == "compliance" and c.place == "joint" and c.target in targets
           and c.pool == "catalogue" and c.key not in have]
    own = {t: own_link_atom(model, prob.ctx.q, int(t[5:])) for t in sorted(targets)}
    out += [a for a in own.values() if a is not None and a.key not in have]
    for t in sorted(targets):
        load = fitted_load(fit, int(t[5:]))
        if load is not None:
            out += [c for c in stiffening_atoms(model, prob.ctx, int(t[5:]), load) if c.key not in have]
        if any(c.channel == own_link_channel(int(t[5:])) for c, _ in fit.chosen):
            out += [c for c in own_link_stiffening(model, prob.ctx, int(t[5:]), own=own[t]) if c.key not in have]
    return out


def own_link_channel(j: int) -> str:
    """The channel of joint ``j``'s compliance under the weight of the link it moves (:func:`own_link_atom`)."""
    return f"gravity torque of link {j} on joint {j}"


def own_link_stiffening(model: RobotModel, ctx: RowContext, j: int, *, own: Atom | None = None) -> list[Atom]:
    """Joint ``j``'s compliance stiffening with the weight of the link it moves, on a chain without mass properties:
    :func:`stiffening_atoms` of the load along each of ``OWN_LINK_DIRECTIONS`` directions over a half turn of the plane
    its own first mass moment spans (:func:`own_link_atom`'s two shapes, each of unit RMS over the rows). A stiffening
    bends the load about its zero, and a linear compliance's fitted torque places that zero only up to the part of
    the load the joint's zero takes: where the load keeps one sign over most rows, its fitted combination is near a
    constant and its law a line (:func:`fitted_load`). The link's weight places the zero where its own moment
    vanishes. Empty with masses (the stated load's law is in the pool) or where the link carries no such plane.
    ``own``: :func:`own_link_atom` of ``j`` on ``ctx``'s rows when the caller has it."""
    if has_masses(model):
        return []
    own = own if own is not None else own_link_atom(model, ctx.q, j)
    if own is None or len(own.features) != 2:
        return []
    f1, f2 = own.features
    out: list[Atom] = []
    for a in np.pi * np.arange(OWN_LINK_DIRECTIONS) / OWN_LINK_DIRECTIONS:
        u = (float(np.cos(a)), float(np.sin(a)))
        w = u[0] * np.asarray(f1.w, float) / f1.h + u[1] * np.asarray(f2.w, float) / f2.h
        out += stiffening_atoms(model, ctx, j, GravMix(i=j, cols=f1.cols, w=tuple(w.tolist()), h=1.0), u=u)
    return out


def along_link_weight(atom: Atom) -> bool:
    """Whether ``atom`` is a stiffening along a direction of its link's weight's plane (:func:`own_link_stiffening`:
    its load's ``u`` the direction's two coordinates in the plane's unit shapes)."""
    f = atom.features[0] if atom.features else None
    return (atom.family == "compliance" and isinstance(f, LoadSign) and isinstance(f.f, GravMix)
            and f.u is not None and len(f.u) == 2 and len(atom.features) == 2)


def own_link_atom(model: RobotModel, q: np.ndarray, j: int) -> Atom | None:
    """Joint ``j``'s compliance under the weight of the link it moves itself (its first mass moment ``m_j c_j``: the
    regressor's columns of link ``j``, the mass itself lying on the axis), the directions they span over the rows as
    ``gravmix`` features: a heavy upper arm whose centre of mass lies far along it, which the torque shapes of the
    generic prior (centres of mass ~0.1 m off each frame) carry only in part. None when they carry no torque."""
    Y = gravity_torque_regressor(model, q)
    cols = tuple((j, c) for c in (1, 2, 3))
    M = np.stack([Y[:, j - 1, j - 1, c] for _, c in cols], axis=1)
    if not np.any(np.abs(M) > 1e-9):
        return None
    _, sv, Vt = np.linalg.svd(M, full_matrices=False)
    rk = int(np.sum(sv > 1e-6 * sv[0]))
    feats = tuple(GravMix(i=j, cols=cols, w=tuple(Vt[k].tolist()), h=float(sv[k] / np.sqrt(len(M)))) for k in range(rk))
    return Atom("compliance", "joint", f"theta{j}", feats, own_link_channel(j),
                f"joint {joint_words(model, j)} compliance under gravity, the weight of the link it moves", "catalogue",
                (j,))


def link_tilt_atom(model: RobotModel, q: np.ndarray, k: int) -> Atom | None:
    """The base tilting under the gravity moment of link ``k``'s first mass moment (``m_k c_k``: a heavy upper arm
    whose centre of mass lies far along it, which the moment's shapes under the generic prior carry only in part), as
    :func:`load_atoms`' tilt: each shape a pair of ``basemoment`` features (both axes, one coefficient); without the
    chain's masses only. None when that moment does not vary."""
    if has_masses(model):
        return None
    Y = base_moment_regressor(model, q)
    n, N = len(q), model.n_joints
    sel = np.zeros((N, 4))
    sel[k - 1, 1:] = 1.0
    M = np.concatenate([(Y[:, 0] * sel).reshape(n, -1), (Y[:, 1] * sel).reshape(n, -1)])
    if not np.any(np.abs(M) > 1e-9):
        return None
    _, sv, Vt = np.linalg.svd(M, full_matrices=False)
    rk = int(np.sum(sv > 1e-6 * sv[0]))
    feats = tuple(BaseMoment(axis=a, shape=r, w=tuple(Vt[r].tolist()), h=float(sv[r] / np.sqrt(n)))
                  for r in range(rk) for a in (0, 1))
    return Atom("tilt", "param", "tilt0", feats, f"gravity moment of link {k} carried by the base",
                f"the robot's base tilting about its horizontal axes under the weight of link {k} (base compliance; "
                "the link's own first mass moment)", "catalogue")


def fitted_load(fit, j: int) -> GravMix | None:
    """Joint ``j``'s torque as the kept linear compliances of the joint fitted it (``fit``'s atoms of the joint whose
    features are ``gravmix`` shapes: the leading shapes, their further shapes, the weight of the link it moves): their
    coefficients' combination as one ``gravmix`` feature over the leading shapes' regressor columns (without them, the
    weight of the link the joint moves, when that is kept: the joint's load is then its own link's). None unless one
    of those is kept (the joint's load is theirs; a part of it is no load a law follows)."""
    main = f"gravity torque of joint {j}"
    kept = [(k, a, B) for k, (a, B) in enumerate(fit.chosen) if a.family == "compliance" and a.target == f"theta{j}"
            and a.features and all(isinstance(f, GravMix) for f in a.features)]
    # the leading shapes; without them the weight of the link the joint moves (its own first mass moment) is the load
    lead = ([a for _, a, _ in kept if a.channel == main]
            or [a for _, a, _ in kept if a.channel == own_link_channel(j)])
    if not lead:
        return None
    cols = lead[0].features[0].cols
    at = {c: n for n, c in enumerate(cols)}
    w = np.zeros(len(cols))
    for k, a, B in kept:
        phi = B @ fit.z[fit.model_cal.offsets[k]:fit.model_cal.offsets[k + 1]]
        for p, f in zip(phi, a.features):
            for c, x in zip(f.cols, f.w):
                if tuple(c) in at:
                    w[at[tuple(c)]] += p * x / f.h
    if not np.any(w):
        return None
    return GravMix(i=j, cols=cols, w=tuple(w.tolist()), h=1.0)


def stated_load_mix(model: RobotModel, i: int, cols: tuple) -> GravMix | None:
    """Joint ``i``'s gravity torque from the chain's stated mass properties as a ``gravmix`` feature over the regressor
    columns ``cols`` (``(k, c)`` pairs of :func:`torque_shapes`): the weights are the links' mass moments ``(m_k,
    m_k c_k)`` in their joint frames (``h`` 1); None without masses."""
    if not has_masses(model):
        return None
    pi = {}
    for k, j in enumerate(model.structure.joints, start=1):
        m = float(j.inertial["mass"]) if j.inertial else 0.0
        c = np.asarray(j.inertial["com"], float) if j.inertial else np.zeros(3)
        pi[(k, 0)] = m
        for a in range(3):
            pi[(k, a + 1)] = m * float(c[a])
    return GravMix(i=i, cols=cols, w=tuple(pi.get((int(k), int(c)), 0.0) for k, c in cols), h=1.0)


def reads_its_load(atom: Atom) -> bool:
    """Whether ``atom`` is a law of a joint's gravity load whose direction among the torque shapes is read from the rows
    (what :func:`refine_load_sign` moves): a load-signed backlash or a stiffening, each with its direction ``u``."""
    return bool(atom.features) and isinstance(atom.features[0], LoadSign) and atom.features[0].u is not None


def refine_load_sign(prob, fit, s, pool_sizes: dict):
    """A kept load-signed backlash refined: its load (the stated masses' torque, or the grid's best direction when
    the masses are unknown) moved within the span of that load and the joint's ``REFINE_SHAPES`` leading torque
    shapes to the combination whose sign explains most (Nelder-Mead from the start, scored as every atom is:
    :func:`twin.diagnosis.scoring.score_atoms`): stated masses are off by some per cent and three shapes hold the
    load only to a few per cent, and either moves the sign's change past rows near zero load. Then its flank: a
    gear whose flank is taken up over a range of the load (friction, a preload, the teeth's compliance) follows
    ``tanh(load / w)``, not the load's sign, and the sign alone misplaces every row near the flank's change. The
    smooth flank (its width from ``FLANK_WIDTHS`` of the load's RMS, then refined on its log with the direction)
    replaces the sign when it explains significantly more: beyond ``chi2_1`` at 1 % / the number of widths tried,
    with at least 3 calibration rows that see the flank (``|tanh| < FLANK_SEEN``: its law differs there from the sign
    by more than a tenth of the offset; a narrow flank shows in the rows beside its middle). A compliance stiffening
    with its load is refined so under each of its laws (``STIFFENING_LAWS``: smooth, or two stiffnesses changing at
    the width), the one that explains most kept. Returns the scored atom."""
    from scipy.optimize import minimize

    f0 = s.atom.features[0]
    if not isinstance(f0, LoadSign):
        return s
    model, rows = prob.prep.nominal, prob.rows_cal
    i = int(f0.f.i) if isinstance(f0.f, GravMix) else int(f0.f.j)
    shapes = torque_shapes(model, prob.ctx.q, i, REFINE_SHAPES)
    if not shapes:
        return s
    cols = shapes[0].cols
    # the stated masses' torque (when the chain has them) beside the shapes: it lies in their full span, not in the
    # leading few, and a load read with a carried one beside it is read about it as well
    stated = [m for m in (stated_load_mix(model, i, cols),) if m is not None]
    basis = stated + [GravMix(i=i, cols=cols, w=tuple((np.asarray(f.w, float) / f.h).tolist()), h=1.0) for f in shapes]
    V = feature_values(tuple(basis), prob.ctx, model)
    scale = np.sqrt(np.mean(V[rows] ** 2, axis=0))
    ok = scale > 0
    basis = [f for f, k in zip(basis, ok) if k]
    W = np.array([np.asarray(f.w, float) / sc for f, sc in zip(basis, scale[ok])])  # each unit RMS over the rows
    V = V[:, ok] / scale[ok]
    # each direction's prior scale (in its unit-RMS coordinate): a torque shape's under the generic prior, relative to
    # the leading one; beside the stated masses' torque, their error spread like those shapes (STATED_SPREAD of it)
    prior = np.array(([1.0] if stated else []) + [f.h / shapes[0].h for f in shapes])[ok]
    if stated:
        prior[1:] *= STATED_SPREAD
    if isinstance(f0.f, Torque):
        u0 = np.zeros(len(basis))
        u0[0] = 1.0
    else:
        # the grid's direction in the refinement's coordinates
        v0 = feature_values((f0.f,), prob.ctx, model)[rows, 0]
        u0 = np.linalg.lstsq(V[rows], v0 / np.sqrt(np.mean(v0 ** 2)), rcond=None)[0]
    best = [s]
    rec = {}

    def feature(u, frac, law=f0.law):
        u = np.asarray(u, float)
        v = V @ u
        rms = float(np.sqrt(np.mean(v[rows] ** 2)))
        mix = GravMix(i=i, cols=cols, w=tuple((u @ W).tolist()), h=1.0)
        return LoadSign(f=mix, u=tuple(float(x) for x in u), width=None if frac is None else float(frac * rms),
                        law=None if frac is None else law), rms

    def score(u, frac, law=f0.law):
        f, rms = feature(u, frac, law)
        if not rms > 0:
            return 0.0
        got = score_atoms(prob, fit, [law_atom(model, s.atom, f, rms)], pool_sizes, exact_top=1)
        if not got:
            return 0.0
        if got[0].dchi2 > best[0].dchi2:
            best[0] = got[0]
        d = got[0].dchi2
        key = "sharp" if frac is None else "smooth"
        if d > rec.get(key, (-1.0,))[0]:
            rec[key] = (d, got[0])
        return d

    def simplex(x0, steps):
        return np.vstack([x0] + [x0 + np.eye(len(x0))[k] * steps[k] for k in range(len(x0))])

    m = len(basis)
    opts = {"xatol": 1e-3, "fatol": 1e-3}
    # the direction and a flank's width together on the smooth flank (the sign is a step function of the direction:
    # a search on it flips single rows, and a boundary placed by a few rows' noise mispredicts the rows near it);
    # from the best width of the grid at the start, steps of SIMPLEX_STEP of the load along each direction
    # a stiffening compliance: each of its laws (smooth, or two stiffnesses changing at the width) so refined, the
    # better kept; the grid's widths place a change of stiffness only to within a factor of two
    for law in (STIFFENING_LAWS if s.atom.family == "compliance" else (f0.law,)):
        top = max(FLANK_WIDTHS, key=lambda fr: score(u0, fr, law))
        x0 = np.concatenate([u0, [0.0]])
        minimize(lambda x: -score(x[:-1], top * np.exp(x[-1]), law), x0, method="Nelder-Mead",
                 options=dict(opts, maxfev=60 * (m + 1), initial_simplex=simplex(x0, [SIMPLEX_STEP] * m + [0.5])))
    # the sign at the start and at the smooth flank's direction
    score(u0, None)
    if "smooth" in rec:
        score(np.asarray(rec["smooth"][1].atom.features[0].u, float), None)
    if "sharp" not in rec:
        return s  # no law of this load scores against the fit (its columns lie within the model's)
    sharp, smooth = rec["sharp"][1], rec.get("smooth", (0.0, None))[1]
    if smooth is not None and (smooth.dchi2 - sharp.dchi2) / prob.evidence_scale >= \
            dists.chi2_isf(0.01 / len(FLANK_WIDTHS), 1):
        fo = smooth.atom.features[0]
        v = feature_values((fo.f,), prob.ctx, model)[rows, 0]
        if int(np.sum(np.abs(np.tanh(v / fo.width)) < FLANK_SEEN)) >= 3:
            return smooth
        # a flank seen by fewer than 3 rows is a sharp one (its width fits the rows near zero load the direction put
        # on the wrong side)
    sharp = sharp if sharp.dchi2 >= s.dchi2 else s
    read = _flank_read(prob, fit, sharp, i, stated, pool_sizes)
    if read is not None:
        return read
    if sharp.atom.features[0].u is None or len(sharp.atom.features[0].u) != m:
        return sharp
    # the sign's change placed in the middle of the gap the rows leave: of the directions that put every
    # calibration row on the same side, the one farthest from all of them (the largest margin, each direction
    # measured on its prior scale: the load lies close to the leading shapes, or to the stated masses' torque);
    # the rows near zero load after the campaign are then on the side the rows around them suggest, not on the
    # side a search happened to stop at
    u_mm = _max_margin(V[rows] * prior, np.asarray(sharp.atom.features[0].u, float) / prior)
    u_mm = None if u_mm is None else u_mm * prior
    if u_mm is not None:
        f, rms = feature(u_mm, None)
        got = score_atoms(prob, fit, [law_atom(model, s.atom, f, rms)], pool_sizes, exact_top=1)
        if got and got[0].dchi2 >= sharp.dchi2 - 1e-9 * abs(sharp.dchi2):
            return got[0]
    return sharp


def _flank_sides(prob, fit, sharp) -> np.ndarray:
    """The flank each calibration row rests on, read from its own residual ``(n_cal,)``: ``+1``/``-1`` the side of the
    load's sign the sharp law ``sharp`` (scored against ``fit``) gives it or the other, ``0`` where the row cannot
    tell. Moving one row to the other flank changes its offset by twice the term's: the row's chi2 changes by
    ``4 (t . r_a + |t|^2)`` (``t`` its whitened part of the term, ``r_a`` its residual with the term and the geometry's
    share of it fitted, linearised); the row reads the side whose chi2 is lower by more than ``chi2_1`` at 1 % / the
    number of rows. Every row is read, those the fit set aside as gross included: a row put on the wrong flank is off
    by twice the backlash, which is what makes it look gross."""
    sb = scoring_basis(prob, fit)
    rc, sw, keep = sb.rc, sb.sw, sb.keep
    n = len(prob.rows_cal)
    phi = sharp.basis @ sharp.psi
    F = prob.features(sharp.atom)[prob.rows_cal]
    t = raw_columns(fit.model_cal, sharp.atom, F, fit.z, rc) @ phi
    # the geometry's share of the term on the kept rows (E psi - Ep psi = A dx), carried to every row
    A = (rc.J[:, fit.free] * sw[:, None])[keep]
    dx = np.linalg.lstsq(A, sharp.E @ sharp.psi - sharp.fitted, rcond=None)[0]
    ra = rc.r - t + rc.J[:, fit.free] @ dx
    ok = rc.row < n  # measurements of the rows (a prior's pseudo-rows carry no flank)
    C = np.bincount(rc.row[ok], t[ok] * ra[ok], minlength=n)[:n]
    T = np.bincount(rc.row[ok], t[ok] ** 2, minlength=n)[:n]
    delta = 4.0 * (C + T) / prob.evidence_scale
    side = np.sign(F[:, 0])
    bar = dists.chi2_isf(0.01 / n, 1)
    return np.where(delta > bar, side, np.where(delta < -bar, -side, 0.0))


def _flank_read(prob, fit, sharp, i: int, stated: list, pool_sizes: dict):
    """The sharp flank's load placed from the flank every calibration row rests on (:func:`_flank_sides`): of the
    loads in the full span of joint ``i``'s torque shapes (every shape the links' mass moments give the joint; beside
    the stated masses' torque when ``stated`` holds it, their error spread as ``STATED_SPREAD`` of the shapes'), the
    one that puts every row that tells its side on that side with the largest margin, each direction measured on its
    prior scale (:func:`_max_margin`). The leading shapes hold the load only to a few per cent of its RMS, and a
    direction placed by the rows' sides within them moves the sign's change past rows near zero load; the joint's
    load lies in the full span, and the largest margin there is the side the rows around an unseen one suggest.
    Returns the scored atom when it explains at least as much as ``sharp`` (within ``chi2_1`` at 1 %), else None."""
    model, rows = prob.prep.nominal, prob.rows_cal
    sides = _flank_sides(prob, fit, sharp)
    told = sides != 0
    if int(np.sum(sides > 0)) < 3 or int(np.sum(sides < 0)) < 3:
        return None
    shapes = torque_shapes(model, prob.ctx.q, i)
    if not shapes:
        return None
    cols = shapes[0].cols
    basis = list(stated) + [GravMix(i=i, cols=cols, w=tuple((np.asarray(f.w, float) / f.h).tolist()), h=1.0)
                            for f in shapes]
    V = feature_values(tuple(basis), prob.ctx, model)
    scale = np.sqrt(np.mean(V[rows] ** 2, axis=0))
    ok = scale > 0
    basis = [f for f, k in zip(basis, ok) if k]
    W = np.array([np.asarray(f.w, float) / sc for f, sc in zip(basis, scale[ok])])
    V = V[:, ok] / scale[ok]
    prior = np.array(([1.0] if stated else []) + [f.h / shapes[0].h for f in shapes])[ok]
    if stated:
        prior[1:] *= STATED_SPREAD
    v0 = feature_values((sharp.atom.features[0].f,), prob.ctx, model)[rows, 0]
    u0 = np.linalg.lstsq(V[rows], v0, rcond=None)[0]
    w = _max_margin(V[rows][told] * prior, u0 / prior, sides[told])
    if w is None:
        return None
    u = w * prior
    v = V @ u
    rms = float(np.sqrt(np.mean(v[rows] ** 2)))
    f = LoadSign(f=GravMix(i=i, cols=cols, w=tuple((u @ W).tolist()), h=1.0), u=tuple(float(x) for x in u))
    got = score_atoms(prob, fit, [law_atom(model, sharp.atom, f, rms)], pool_sizes, exact_top=1)
    if not got or got[0].dchi2 < sharp.dchi2 - dists.chi2_isf(0.01, 1) * prob.evidence_scale:
        return None
    return got[0]


def _max_margin(V: np.ndarray, u: np.ndarray, sgn: np.ndarray | None = None) -> np.ndarray | None:
    """The direction ``u'`` (unit norm) that puts every row of ``V`` ``(n, m)`` on the side ``sgn`` (default the side
    ``u`` puts it on, ``sign(V u)``) with the largest margin ``min_i s_i V_i u'`` (a hard-margin separation through
    the origin, solved as ``min |w|^2`` subject to ``s_i V_i w >= 1``, SLSQP from ``u``); None when that fails or a
    side is zero."""
    from scipy.optimize import minimize

    sgn = np.sign(V @ u) if sgn is None else np.asarray(sgn, float)
    if not np.all(sgn != 0):
        return None
    A = sgn[:, None] * V
    w0 = u / max(float(np.min(A @ u)), 1e-12) if np.min(A @ u) > 0 else u / max(float(np.max(np.abs(A @ u))), 1e-12)
    res = minimize(lambda w: float(w @ w), w0, jac=lambda w: 2 * w, method="SLSQP",
                   constraints=[{"type": "ineq", "fun": lambda w: A @ w - 1.0, "jac": lambda w: A}],
                   options={"maxiter": 200, "ftol": 1e-10})
    w = res.x
    if not np.all(np.isfinite(w)) or np.any(A @ w <= 0):
        return None
    return w / np.linalg.norm(w)


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


def carried_shapes(model: RobotModel, ctx: RowContext, j: int) -> tuple[GravMix, ...]:
    """Joint ``j``'s load with the chain's stated masses and something carried at the flank: the stated masses' torque
    and the two leading torque shapes of a payload (:func:`payload_shapes`), as ``gravmix`` features over the columns
    of :func:`torque_shapes` (each ``h`` its RMS over the rows); ``()`` when the joint has no stated load or a carried
    load gives it fewer than two shapes."""
    shapes = torque_shapes(model, ctx.q, j, 1)
    if not shapes:
        return ()
    cols = shapes[0].cols
    stated = stated_load_mix(model, j, cols)
    carried = payload_shapes(model, ctx.q, j)
    if stated is None or len(carried) < 2:
        return ()
    at = {tuple(c): k for k, c in enumerate(cols)}
    out = [stated]
    for f in carried[:2]:
        w = np.zeros(len(cols))
        for c, x in zip(f.cols, f.w):
            w[at[tuple(c)]] = x
        out.append(GravMix(i=j, cols=cols, w=tuple(w.tolist()), h=1.0))
    V = feature_values(tuple(out), ctx, model)
    rms = np.sqrt(np.mean(V ** 2, axis=0))
    if not np.all(rms > 0):
        return ()
    return tuple(GravMix(i=j, cols=cols, w=f.w, h=float(r)) for f, r in zip(out, rms))


def load_atoms(model: RobotModel, ctx: RowContext, *, values: dict | None = None) -> list:
    """The load-signed backlash of every joint whose gravity load changes sign over the rows, and, on a chain without
    mass properties, the base tilting under the arm's unknown gravity moment (module docstring). ``values``: when
    given, the feature values ``(n, 1)`` on every row of ``ctx`` of each load-signed atom, by atom, are put in it (the
    pool computes them to keep an atom; the scoring need not again, :meth:`twin.diagnosis.problem.Problem.seed_features`)."""
    atoms = []
    N = model.n_joints
    masses = has_masses(model)
    tau = gravity_torques(model, ctx.q) if masses else None
    cache: dict = {}
    for j in range(1, N + 1):
        if masses:
            feats = [LoadSign(f=Torque(j=j, h=1.0))]
            if np.ptp(tau[:, j - 1]) > 1e-9 * max(1.0, float(np.max(np.abs(tau[:, j - 1])))):
                # the stated load known: its compliance stiffening with it (without masses, from a kept linear
                # compliance's fitted torque: the selection's rounds add them)
                atoms += stiffening_atoms(model, ctx, j, Torque(j=j, h=1.0))
            # the stated masses hold the arm, not what it carries (a tool, the instrument's nest, a cable): the sign of
            # the stated load with a carried load's torque beside it, on the grid of directions (the pool ``load``)
            carried = carried_shapes(model, ctx, j)
            if len(carried) == 3:
                feats += [load_sign_feature(carried, u) for u in _hemisphere(LOAD_DIRECTIONS)]
        else:
            # the masses are unknown: the sign of combinations of the joint's leading torque shapes (the load lies
            # close to their span), on a grid of directions refined when kept (refine_load_sign)
            shapes = torque_shapes(model, ctx.q, j, LOAD_SHAPES)
            if not shapes:
                continue
            U = _hemisphere(LOAD_DIRECTIONS) if len(shapes) == 3 else np.eye(len(shapes))
            feats = [load_sign_feature(shapes, u[:len(shapes)]) for u in U]
        for f in feats:
            F = feature_values((f,), ctx, model, cache)
            s = F[:, 0]
            if min(np.sum(s > 0), np.sum(s < 0)) < 3:
                continue  # the load keeps one sign: the offset is a constant the geometry holds
            u = f.u
            atoms.append(Atom("backlash", "joint", f"theta{j}", (f,), f"load_sign_j{j}" + ("" if u is None else
                              f" ({', '.join(f'{x:+.3f}' for x in u)})"),
                              f"joint {joint_words(model, j)} backlash (offset signed by its gravity load)",
                              "catalogue" if u is None else "load", (j,)))
            if values is not None:
                values[atoms[-1]] = F
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
            # a base stiffer about one horizontal axis than the other (principal axes anywhere): the compliance
            # c I + d1 diag(1, -1) + d2 [[0, 1], [1, 0]]; its anisotropic part acts on the leading shape of the moment
            # (the arm's reach), two coefficients beside the shapes' own
            w0, h0 = feats[0].w, feats[0].h
            neg = tuple(-x for x in w0)
            aniso = (BaseMoment(axis=0, shape=len(feats) // 2, w=w0, h=h0, about=0),
                     BaseMoment(axis=1, shape=len(feats) // 2, w=neg, h=h0, about=1),
                     BaseMoment(axis=1, shape=len(feats) // 2 + 1, w=w0, h=h0, about=0),
                     BaseMoment(axis=0, shape=len(feats) // 2 + 1, w=w0, h=h0, about=1))
            atoms.append(Atom("tilt", "param", "tilt0", tuple(feats) + aniso,
                              "gravity moment carried by the base (shapes), axes turned",
                              "the robot's base tilting about its horizontal axes under the arm's gravity moment, stiffer "
                              "about one axis than the other (base compliance per axis; the moment's shapes from unknown "
                              "link masses)", "catalogue"))
    return atoms


def tilt_angles(features, F: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """The tilt ``(n, 2)`` [rad] about the pivot's ``x`` and ``y`` axes of a tilt atom with ``features`` (each turns
    the pivot about its ``axis``), values ``F`` ``(n, K)`` and coefficients ``phi`` ``(K,)``."""
    out = np.zeros((F.shape[0], 2))
    for k, f in enumerate(features):
        out[:, tilt_axis(f, k)] += F[:, k] * phi[tilt_coefficient(f, k)]
    return out


ALT_RMS = 1.02  # a counterpart predicting the confirmation rows within this factor is an alternative


def _counterparts(a, pool: list) -> list:
    """The terms of the other reading of the same load effect: a backlash signed by the last move <-> signed by the
    load (same joint); a joint's compliance <-> the base tilting under the arm's moment (the shoulder's torque and the
    base's moment follow the same mass moments)."""
    kinds = {f.kind for f in a.features}
    if a.family == "backlash":
        want = "loadsign" if kinds <= {"sign", "play", "lastmove"} else "sign"
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
        e_alt = held_out_rms(prob, alt)
        if e_now is None:
            e_now = held_out_rms(prob, fit)
        if e_alt <= ALT_RMS * e_now:
            out.append({"of": a.label, "alternative": best.atom.label, "family": best.atom.family,
                        "channel": best.atom.channel, "target": best.atom.target, "delta_chi2": best.dchi2,
                        "delta_chi2_chosen": float("nan"), "share_reproduced": float("nan"),
                        "held_out_rms_mm": [e_alt, e_now]})
    return out
