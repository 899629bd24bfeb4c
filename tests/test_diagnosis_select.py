"""The scoring's shortcuts compute what their definitions do (twin.diagnosis.scoring, grams, problem, extend).

Each shortcut of the scoring at scale is checked against the plain formula it replaces, on a small problem at its
geometric fit: per-row sums laid out by row against a sparse sum over the residuals, a step's products from suffix
sums against the products of its feature column, a family acting from different moments against its atoms'
features, a wide product atom on its distinct rows or in batches against one batch, the column store against
stacked features, a model column picked from the Jacobian against the product with it, and a kept model against one
built anew.
"""

import numpy as np
import pytest
from scipy import sparse

import _diagnosis_helpers as H
from twin.diagnosis import grams, scoring
from twin.diagnosis.problem import MODELS_KEPT, ColumnStore, runs_of_length
from twin.diagnosis.atoms import Atom
from twin.diagnosis.diagnose import atom_pool, fit_geometry, prepare_diagnosis
from twin.diagnosis.extend import AtomTerm, ExtendedModel, _times_weights, param_weights
from twin.diagnosis.features import Gated, Step


@pytest.fixture(scope="module")
def problem():
    """A 150-row sphere-centre problem with t_s and temp_c at its geometric fit, its pool and scoring basis."""
    n = 120
    m = n + n // 4
    rng = np.random.default_rng(7)
    ds, _ = H.make_dataset(seed=7, n=n, effect=H.cyclic(amp_deg=0.01, joint=2, k=2), t_s=np.cumsum(rng.uniform(8, 12, m)),
                           temp=21.0 + 0.3 * rng.standard_normal(m))
    setup = prepare_diagnosis(ds)
    prob = setup.problem
    fit = fit_geometry(prob, setup.x0)
    pool, sizes = atom_pool(setup)
    return prob, fit, scoring.scoring_basis(prob, fit), pool, sizes


def _close(got, want, scale, tol=1e-12):
    """``got`` equals ``want`` within ``tol`` of ``scale``: the same sums of the absolute values of the terms
    (a sum that cancels to ~0 is exact only to the rounding of its terms)."""
    got, want, scale = np.asarray(got), np.asarray(want), np.asarray(scale)
    assert got.shape == want.shape
    assert np.all(np.abs(got - want) <= tol * scale + 1e-300), float(np.max(np.abs(got - want) / (scale + 1e-300)))


def _steps(place, target, ats):
    return [Atom("unnamed", place, target, (Step(ch="t_s", at=float(a)),), f"step {a}", f"step {a}",
                 "generic") for a in ats]


def test_block_products_equal_those_of_the_atoms_columns(problem):
    """Per feature set, the products from the per-row aggregates equal those of the atom's columns over the kept
    residuals (``E[m, k] = b[m] F[row(m), k]``): ``E^T E``, ``Q^T E``, ``E^T r``."""
    prob, fit, sb, pool, _ = problem
    atoms = [a for a in pool if a.place == "joint" and a.target == "theta4" and a.pool == "generic"
             and len(a.features) == 2][:5]
    assert len(atoms) == 5
    w, Qb, br = scoring._screen_aggregates(prob, fit, sb, atoms[0])
    F = np.stack([prob.features_cal(a) for a in atoms], axis=2)  # (n, 2, g)
    got = grams.block_stats(F, w, Qb, br)
    b = scoring._kept_base(prob, fit, sb, atoms[0])[:, 0] * sb.sw_kept
    for i, (nrm2, EtE, QtE, Etr) in enumerate(got):
        E = b[:, None] * F[sb.rows, :, i]
        Ea = np.abs(E)
        _close(EtE, E.T @ E, Ea.T @ Ea)
        _close(nrm2, np.sum(E**2, axis=0), np.sum(E**2, axis=0))
        _close(QtE, sb.Q.T @ E, np.abs(sb.Q).T @ Ea)
        _close(Etr, E.T @ sb.r, Ea.T @ np.abs(sb.r))


def test_row_aggregates_are_the_sums_over_each_rows_residuals(problem):
    """The per-row sums laid out by row equal the sparse sums over the kept residuals of each row."""
    prob, fit, sb, pool, _ = problem
    atom = next(a for a in pool if a.place == "param" and a.target == "base")
    base = scoring._kept_base(prob, fit, sb, atom) * sb.sw_kept[:, None]
    rows, n, m = sb.rows, prob.obs_cal.n, len(sb.rows)
    Sm = sparse.csr_matrix((np.ones(m), (rows, np.arange(m))), shape=(n, m))
    W, QB, Br = scoring.row_aggregates(prob, fit, sb, atom)
    c = base.shape[1]

    def sums(b, Q, r):
        return ((Sm @ (b[:, :, None] * b[:, None, :]).reshape(m, c * c)).reshape(n, c, c),
                (Sm @ (Q[:, :, None] * b[:, None, :]).reshape(m, -1)).reshape(QB.shape), Sm @ (b * r[:, None]))

    for got, want, scale in zip((W, QB, Br), sums(base, sb.Q, sb.r), sums(np.abs(base), np.abs(sb.Q), np.abs(sb.r))):
        _close(got, want, scale)


def test_step_products_from_suffix_sums_equal_those_of_its_column(problem):
    """A step's products with the per-row aggregates read off suffix sums equal those of its 0/1 feature column."""
    prob, fit, sb, _, _ = problem
    t = prob.ctx.t_s[prob.rows_cal]
    steps = _steps("joint", "theta3", np.quantile(t, [0.0, 0.13, 0.5, 0.87]) + [0.0, 0.5, 0.0, 0.0])
    w, Qb, br = scoring._screen_aggregates(prob, fit, sb, steps[0])
    got = scoring._step_stats(prob, steps, w, Qb, br)
    F = np.stack([prob.features_cal(a) for a in steps], axis=2)  # (n, 1, g)
    want = grams.block_stats(F, w, Qb, br)
    scale = grams.block_stats(F, np.abs(w), np.abs(Qb), np.abs(br))
    assert len(got) == len(want) == len(steps)
    for g, h, sc in zip(got, want, scale):
        for x, y, z in zip(g, h, sc):
            _close(x, y, z, 1e-11)


def test_family_acting_from_different_moments_equals_its_atoms_products(problem):
    """Gated atoms (a compliance from each restart on) scored from suffix sums equal their features' products."""
    prob, fit, sb, pool, _ = problem
    comp = next(a for a in pool if a.family == "compliance" and a.target == "theta2" and "further" not in a.channel)
    t = prob.ctx.t_s[prob.rows_cal]
    family = [Atom("compliance", "joint", "theta2", tuple(Gated(f=f, ch="t_s", at=float(at))
                                                          for f in comp.features), f"from {at}", f"from {at}",
                   "catalogue", (2,)) for at in np.quantile(t, [0.1, 0.4, 0.75])]
    W, QB, Br = scoring.row_aggregates(prob, fit, sb, family[0])
    got = scoring._gate_grams(prob, family, W, QB, Br)
    F = np.stack([prob.features_cal(a) for a in family], axis=1)  # (n, g, K)
    want = grams.product_grams(F, W, QB, Br)
    scale = grams.product_grams(np.abs(F), np.abs(W), np.abs(QB), np.abs(Br))
    for i in range(len(family)):
        for j in range(3):
            _close(got[i][j], want[j][i], scale[j][i], 1e-11)
        assert got[i][3]


def test_wide_product_atom_equals_one_batch_when_split_or_on_distinct_rows(problem, monkeypatch):
    """Product Gram matrices of a batch split below the size bound, or of an atom too wide alone (on its distinct
    rows, or over blocks of rows), equal those of the whole batch."""
    prob, fit, sb, _, _ = problem
    t = prob.ctx.t_s[prob.rows_cal]
    at = np.quantile(t, np.linspace(0.05, 0.95, 12))
    wide = Atom("unnamed", "param", "base", tuple(Step(ch="t_s", at=float(a)) for a in at),
                "steps", "steps", "generic")
    W, QB, Br = scoring.row_aggregates(prob, fit, sb, wide)
    F = prob.features_cal(wide)[:, None, :]
    want = grams.product_grams(F, W, QB, Br)
    scale = grams.product_grams(np.abs(F), np.abs(W), np.abs(QB), np.abs(Br))
    n = F.shape[0]
    monkeypatch.setattr(scoring, "PRODUCT_BATCH_MAX", n * 12 * 12 - 1)  # the atom alone is too wide: its distinct rows
    assert prob.distinct_rows_cal(wide) is not None
    for x, y, z in zip(scoring._product_grams_bounded(prob, [wide], F, W, QB, Br), want, scale):
        _close(x, y, z, 1e-11)
    monkeypatch.setattr(prob, "distinct_rows_cal", lambda a: None)  # no distinct rows: blocks of rows
    for x, y, z in zip(scoring._product_grams_bounded(prob, [wide], F, W, QB, Br), want, scale):
        _close(x, y, z, 1e-11)
    steps = _steps("param", "base", at)
    F1 = np.stack([prob.features_cal(a) for a in steps], axis=1)  # (n, 12, 1): split into batches of 5
    monkeypatch.setattr(scoring, "PRODUCT_BATCH_MAX", n * 5)
    got = scoring._product_grams_bounded(prob, steps, F1, W, QB, Br)
    want = grams.product_grams(F1, W, QB, Br)
    scale = grams.product_grams(np.abs(F1), np.abs(W), np.abs(QB), np.abs(Br))
    for x, y, z in zip(got, want, scale):
        _close(x, y, z, 1e-11)


def test_column_store_screens_as_stacked_features_do(problem):
    """The screening's p-values from the column store equal those from each place's stacked features."""
    prob, fit, sb, pool, sizes = problem
    atoms = [a for a in pool if a.pool != "catalogue" and scoring._screenable(a)]
    store = prob.column_store(atoms)
    assert store is not None and any(store.has(a.feature_key) for a in atoms)
    got = scoring._screen(prob, fit, atoms, sb.rc, sb.keep, sb.sw, sb.Q, sb.r, sizes)
    prob._store, kept = None, prob._store
    try:
        ColumnStore.MIN_ATOMS, min_atoms = 10**9, ColumnStore.MIN_ATOMS
        want = scoring._screen(prob, fit, atoms, sb.rc, sb.keep, sb.sw, sb.Q, sb.r, sizes)
    finally:
        prob._store, ColumnStore.MIN_ATOMS = kept, min_atoms
    fin = np.isfinite(want)
    assert np.array_equal(fin, np.isfinite(got)) and fin.sum() > 100
    np.testing.assert_allclose(got[fin], want[fin], rtol=1e-9, atol=1e-9)


def test_model_column_picked_from_the_jacobian_is_the_product_with_it(problem):
    """A place's model column picked from the Jacobian equals its product with the weights: values, the sign of
    zeros and the C layout."""
    prob, fit, sb, pool, _ = problem
    J = np.asfortranarray(sb.rc.J)
    J[::7, :] = -0.0
    x = fit.z[: prob.prep.space.size]
    places = {(a.place, a.target): a for a in pool if a.place in ("joint", "length", "param")
              and a.target not in ("base_along",) and not a.target.startswith("tilt")}
    for a in places.values():
        w = param_weights(prob.prep.space, x, a)
        got, want = _times_weights(J, w), J[:, : w.shape[0]] @ w
        assert np.array_equal(got, want) and np.array_equal(np.signbit(got), np.signbit(want)), a.target
        assert got.flags["C_CONTIGUOUS"]


def test_tail_sums_are_the_sums_from_each_position_on():
    """Sums of the rows from each position on, with repeated positions, the first row and past the last row."""
    rng = np.random.default_rng(3)
    X = rng.normal(size=(50, 4))
    pos = np.array([7, 0, 50, 7, 49, 23, 23])
    got = grams.tail_sums(X, pos)
    want = np.array([X[p:].sum(axis=0) for p in pos])
    _close(got, want, np.array([np.abs(X[p:]).sum(axis=0) for p in pos]), 1e-13)


def test_leading_eigenpairs_of_a_wide_gram_matrix_are_the_full_decompositions():
    """For a wide projected Gram matrix, the leading eigenvalues equal the full decomposition's and their
    eigenvectors span the same directions."""
    rng = np.random.default_rng(5)
    A = rng.normal(size=(grams.WIDE_EIGH_MIN + 20, 900))
    G = (A @ A.T / 900)[None]
    lam, V = grams.leading_eigh(G, 6)
    full, U = np.linalg.eigh(G[0])
    np.testing.assert_allclose(lam[0], full[::-1][:6], rtol=1e-12)
    np.testing.assert_allclose(np.abs(np.sum(V[0] * U[:, ::-1][:, :6], axis=0)), 1.0, rtol=1e-9)


def test_scores_on_two_threads_equal_those_on_one(problem):
    """Scoring the pool with its places on two threads gives the same atoms and the same log p-values, bit for bit."""
    prob, fit, sb, pool, sizes = problem
    one = scoring.score_atoms(prob, fit, pool, sizes)
    sb.cache.clear()  # the per-place quantities derived anew, on the threads
    prob.threads = 2
    try:
        two = scoring.score_atoms(prob, fit, pool, sizes)
    finally:
        prob.threads = 1
    assert len(one) > 20
    assert [s.atom.key for s in two] == [s.atom.key for s in one]
    assert [(s.logp_adj, s.dchi2) for s in two] == [(s.logp_adj, s.dchi2) for s in one]


def test_scores_of_other_atoms_against_the_same_basis_equal_those_of_a_fresh_basis(problem):
    """Scoring the pool less one atom of a place, then less another atom of that place (as many atoms there), on the
    same basis (its places' sums and scores kept in ``ScoringBasis.memo``) gives the same atoms and numbers, bit for
    bit, as on a fresh basis of the same fit: screened places and exactly scored ones."""
    from dataclasses import replace

    prob, fit, _, pool, sizes = problem
    pairs = []
    for screened in (True, False):
        by: dict = {}
        for a in pool:
            if (a.pool != "catalogue" and scoring._screenable(a)) == screened and scoring._product(a):
                by.setdefault((a.place, a.target), []).append(a)
        pairs.append(next(v[:2] for v in by.values() if len(v) >= 2))
    first = [a for a in pool if all(a is not p[0] for p in pairs)]
    second = [a for a in pool if all(a is not p[1] for p in pairs)]
    scoring.score_atoms(prob, fit, first, sizes)
    again = scoring.score_atoms(prob, fit, second, sizes)
    assert len(scoring.scoring_basis(prob, fit).memo) > 0
    fresh = scoring.score_atoms(prob, replace(fit, cache={}), second, sizes)
    assert len(fresh) > 20
    assert [s.atom.key for s in again] == [s.atom.key for s in fresh]
    assert [(s.logp_adj, s.dchi2, s.basis.tobytes(), s.psi.tobytes()) for s in again] == \
        [(s.logp_adj, s.dchi2, s.basis.tobytes(), s.psi.tobytes()) for s in fresh]
    assert [s.Ep.tobytes() for s in again[:5]] == [s.Ep.tobytes() for s in fresh[:5]]
    screened = [a for a in second if a.pool != "catalogue" and scoring._screenable(a)]
    lp = []
    for f in (fit, replace(fit, cache={})):
        sb = scoring.scoring_basis(prob, f)
        lp.append(scoring._screen(prob, f, screened, sb.rc, sb.keep, sb.sw, sb.Q, sb.r, sizes))
    assert np.isfinite(lp[1]).sum() > 20 and lp[0].tobytes() == lp[1].tobytes()


def test_a_call_kept_on_the_fit_is_made_again_under_other_row_weights(problem):
    """``memo_on_fit`` computes a call once for equal arguments (a scored atom with the same numbers, another object)
    and returns the new call's argument where the result was the argument; other row weights compute it again."""
    prob, fit, _, pool, sizes = problem
    calls = []

    @scoring.memo_on_fit
    def echo(prob, fit, s, sizes):
        calls.append(s)
        return s

    one = scoring.score_atoms(prob, fit, pool[:5], sizes, exact_top=5)[0]
    two = scoring.Scored(one.atom, one.basis.copy(), one.psi.copy(), one.dchi2, one.logp_adj, one.r)
    assert echo(prob, fit, one, sizes) is one
    assert echo(prob, fit, two, sizes) is two and len(calls) == 1
    w = prob.w_cal
    prob.w_cal = w.copy()
    try:
        assert echo(prob, fit, two, sizes) is two and len(calls) == 2
    finally:
        prob.w_cal = w


def _ur10_table(scale: float = 1.0) -> dict:
    """A UR10's joint table (URDF origins) with its flange offset as the chain's end, every length times ``scale``."""
    xyz = [[0, 0, 0], [0, 0, 127.3], [-612.0, 0, 0], [-572.3, 0, 0], [0, 0, 163.941], [0, 0, 115.7]]
    rpy = [[0, 0, 0], [90, 0, 0], [0, 0, 0], [0, 0, 0], [90, 0, 0], [-90, 0, 0]]
    joints = [{"name": f"q{k + 1}", "type": "revolute", "xyz_mm": [scale * v for v in xyz[k]], "rpy_deg": rpy[k],
               "axis": [0, 0, 1], "limits": [-360, 360]} for k in range(6)]
    return {"name": "ur10", "joints": joints, "end": {"xyz_mm": [0, 0, 92.2 * scale], "rpy_deg": [0, 0, 30]}}


def test_all_link_lengths_grow_the_chain_s_fixed_end_too():
    """The thermal growth of all link lengths of a URDF chain moves its tool as the chain whose every origin and end
    translation are grown by the same fraction (to second order): the flange's offset from the last joint grows too."""
    from twin.estimator.chain import Chain
    from twin.estimator.problem import ParamSpace
    from twin.robots import robot_from_joint_table
    from twin.transforms import pose6_to_transform
    from twin.diagnosis.features import Const

    tool = pose6_to_transform(np.array([0.03, -0.02, 0.05, 0.1, -0.2, 0.3]))
    model = robot_from_joint_table(_ur10_table()).with_frames(tool2flange=tool)
    delta = 1e-4
    grown = robot_from_joint_table(_ur10_table(1.0 + delta)).with_frames(tool2flange=tool)
    q = np.random.default_rng(5).uniform(-2.0, 2.0, (20, 6))
    sp = ParamSpace(Chain.of(model), ("s",))
    x = sp.from_model(model)
    atom = Atom("thermal", "length", "all_lengths", (Const(),), "constant", "all link lengths", "catalogue")
    x_grown = x + delta * param_weights(sp, x, atom)[:, 0]
    got = sp.chain.evaluate(x_grown[: sp.n_rt], q, jacobian=False).p[0]
    want = Chain.of(grown).evaluate(sp.from_model(grown)[: sp.n_rt], q, jacobian=False).p[0]
    assert np.max(np.abs(got - want)) < 1e-7  # the end's 92 mm grown 1e-4 is 9.2e-6 m


def test_a_kept_model_is_the_model_of_the_same_atoms_and_bases(problem):
    """``Problem.model`` gives its kept model for equal atoms, bases and block (another for another basis or block,
    and none once ``MODELS_KEPT`` others came after it), with the residuals of a model built anew to the bit."""
    prob, fit, sb, pool, sizes = problem
    a = next(x for x in pool if x.place == "joint")
    B = np.eye(a.K)[:, :1]
    m = prob.model([(a, B)], "cal")
    assert prob.model([(a, B.copy())], "cal") is m
    assert prob.model([(a, 2 * B)], "cal") is not m and prob.model([(a, B)], "val") is not m
    built = ExtendedModel(prob.prep.space, prob.obs_cal, [AtomTerm(a, prob.features(a)[prob.rows_cal], B)],
                          prob.floor.axis_sigma)
    z = np.concatenate([fit.z[: prob.prep.space.size], [1e-4]])
    got, want = m.residuals(z), built.residuals(z)
    assert np.array_equal(got.r, want.r) and np.array_equal(got.J, want.J)
    for k in range(MODELS_KEPT):
        prob.model([(a, (k + 3.0) * B)], "cal")
    assert prob.model([(a, B)], "cal") is not m


def test_runs_of_length_keeps_exactly_the_runs_as_long_as_asked():
    """runs_of_length keeps each run of consecutive True from ``least`` to ``most`` long and drops the shorter and the
    longer ones (against a row-by-row count, on random flags with a seeded rng)."""
    rng = np.random.default_rng(31)
    for _ in range(200):
        flag = rng.random(int(rng.integers(0, 40))) < rng.uniform(0.1, 0.9)
        least, most = int(rng.integers(0, 3)), int(rng.integers(0, 6))
        want = np.zeros_like(flag)
        k = 0
        while k < len(flag):
            if flag[k]:
                e = k
                while e < len(flag) and flag[e]:
                    e += 1
                want[k:e] = least <= e - k <= most
                k = e
            else:
                k += 1
        assert np.array_equal(runs_of_length(flag, least, most), want), (flag.astype(int), least, most)
