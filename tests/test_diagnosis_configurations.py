"""Terms judged on configurations (twin.diagnosis.configurations): the harmonic orders a joint's sampling supports,
the folds of its values, the confirmation of a term on folds it was not fitted on, and the diagnosis on grid
campaigns (an aliasing trap is not kept; a true harmonic of low order is). Rates over many seeds of whole diagnoses
are in ``experiments/bench_configurations.py`` (section ``diagnosis_configurations`` of results/benchmark.json)."""

import numpy as np
import pytest

import _diagnosis_helpers as H
from twin.diagnosis import diagnose, diagnosis_dict
from twin.diagnosis.configurations import (RIVAL_MARGIN, Z_MIN, FoldConfirmation, alias_frequency, block_widths,
                                           configuration_folds, fold_confirmation, harmonic_orders, joint_sampling,
                                           joints_read, max_order, offered, spectral_window, value_groups)
from twin.diagnosis.features import Const, Cos, Gated, GravMix, Pow, Prod, Sign, Sin, Step
from twin.diagnosis.structure import chi2_logsf
from twin.units import MM_PER_M, RAD_PER_DEG

DEG = RAD_PER_DEG
AMP = 0.01 * DEG


def _lattice(step_deg, lo=-40.0, hi=40.0, repeats=30):
    return np.deg2rad(np.repeat(np.arange(lo, hi + 1e-9, step_deg), repeats))


# ---- the order bound ---------------------------------------------------------------------------------------

def test_a_regular_grid_supports_orders_below_half_its_alias_frequency():
    """Values every 10 deg alias at 36 cycles per turn (found at 35-36): orders up to 17 are supported, not 18."""
    s = joint_sampling(_lattice(10.0)[:, None], [True])[0]
    assert s.alias_frequency in (35, 36) and s.max_order == 17
    assert s.distinct_values == 9 and s.groups == 9


def test_the_bound_follows_the_grid_step():
    """A 5 deg grid supports orders up to 35, a 20 deg grid up to 8 (Nyquist's 180 / step, less one)."""
    assert joint_sampling(_lattice(5.0)[:, None], [True])[0].max_order == 35
    assert joint_sampling(_lattice(20.0)[:, None], [True])[0].max_order == 8


def test_jitter_around_the_grid_values_keeps_the_bound_and_the_groups():
    """Grid values with 0.3 deg of jitter: the same bound (17) and one group per grid value."""
    x = _lattice(10.0) + np.random.default_rng(0).normal(0.0, 0.3 * DEG, 270)
    s = joint_sampling(x[:, None], [True])[0]
    assert s.max_order == 17 and s.groups == 9


def test_random_values_have_no_alias_and_no_bound():
    """200 values drawn at random over 300 deg: the spectral window never returns to 0.9, every order is offered
    (on 10 seeds)."""
    for seed in range(10):
        x = np.random.default_rng(seed).uniform(-150 * DEG, 150 * DEG, 200)
        s = joint_sampling(x[:, None], [True])[0]
        assert s.alias_frequency is None and s.max_order is None, seed


def test_a_joint_at_two_values_supports_the_first_order_only():
    """Values at 0 and 90 deg only: every order of 4 cycles per turn sits at one phase; orders above 1 alias."""
    s = joint_sampling(np.deg2rad(np.repeat([0.0, 90.0], 20))[:, None], [True])[0]
    assert s.alias_frequency == 4 and s.max_order == 1


def test_one_value_supports_no_order_and_a_prismatic_joint_gets_no_bound():
    """A joint held at one value: order 0; a prismatic joint (no harmonics): no bound."""
    q = np.column_stack([np.full(10, 0.3), np.linspace(0.0, 0.2, 10)])
    s = joint_sampling(q, [True, False])
    assert s[0].max_order == 0 and s[1].max_order is None and not s[1].revolute


def test_spectral_window_is_one_at_the_grid_frequency():
    """W(36) = 1 on a 10 deg grid, W(0) = 1, and W(18) small (the grid's values spread over every phase of it)."""
    W = spectral_window(_lattice(10.0), [0, 18, 36])
    assert W[0] == pytest.approx(1.0) and W[2] == pytest.approx(1.0) and W[1] < 0.2


def test_max_order_of_an_alias_frequency():
    """ceil(d / 2) - 1: 36 -> 17, 35 -> 17, 4 -> 1; None -> None."""
    assert [max_order(36), max_order(35), max_order(4), max_order(None)] == [17, 17, 1, None]


def test_alias_frequency_refuses_a_bad_range():
    """d_max must be a positive integer (ValueError naming it)."""
    with pytest.raises(ValueError, match="d_max"):
        alias_frequency(np.zeros(3), 0)


def test_joint_sampling_refuses_mismatched_joint_kinds():
    """One revolute flag per joint, else ValueError naming it."""
    with pytest.raises(ValueError, match="revolute"):
        joint_sampling(np.zeros((4, 2)), [True])


def test_a_harmonic_above_its_joints_bound_is_not_offered():
    """With joint 1's bound at 17: order 17 is offered, order 30 (and a nested one) is not; other joints and
    non-harmonic terms are unaffected."""
    s = joint_sampling(np.column_stack([_lattice(10.0), np.linspace(-1, 1, 270)]), [True, True])
    assert offered((Sin(ch="q1", k=17.0), Cos(ch="q1", k=17.0)), s)
    assert not offered((Sin(ch="q1", k=30.0), Cos(ch="q1", k=30.0)), s)
    assert not offered((Gated(f=Sin(ch="q1", k=30.0), ch="t_s", at=0.0),), s)
    assert offered((Sin(ch="q2", k=90.0),), s)
    assert offered((Pow(ch="q1", p=3, c=0.0, h=1.0),), s)
    assert harmonic_orders((Sin(ch="q1", k=4.0), Cos(ch="t_s", k=0.1))) == {1: 4.0}


# ---- groups, blocks and folds -----------------------------------------------------------------------------

def test_joints_read_are_the_named_joint_channels():
    """Harmonics, powers, products and nested features of q<j> read joints; time, history, load and constants
    read none."""
    assert joints_read((Sin(ch="q3", k=2.0), Prod(ch=("q1", "q5"), c=(0.0, 0.0), h=(1.0, 1.0)))) == (1, 3, 5)
    assert joints_read((Gated(f=Pow(ch="q2", p=1, c=0.0, h=1.0), ch="t_s", at=0.0),)) == (2,)
    assert joints_read((Pow(ch="t_s", p=1, c=0.0, h=1.0), Sign(j=2), Step(ch="t_s", at=1.0), Const(),
                        GravMix(i=2, cols=((2, 0),), w=(1.0,), h=1.0))) == ()


def test_value_groups_keep_a_grid_value_whole():
    """Repeats and jitter at a grid value are one group, numbered in the order of the values."""
    x = _lattice(10.0) + np.random.default_rng(1).normal(0.0, 0.2 * DEG, 270)
    g = value_groups(x)
    assert len(np.unique(g)) == 9
    assert np.all(np.diff(g[np.argsort(x)]) >= 0)


def test_folds_leave_out_whole_periods_of_the_harmonic():
    """Order 12 on a 10 deg grid over 80 deg: blocks of one period (30 deg), 3 blocks, 3 folds; each grid value in
    one fold; neighbouring blocks in different folds."""
    q = _lattice(10.0)
    w = block_widths((Sin(ch="q1", k=12.0),), (1,), [np.ptp(q)])
    assert w[0] == pytest.approx(2 * np.pi / 12)
    folds = configuration_folds(q[:, None], w)
    fold = folds.fold
    assert set(fold.tolist()) == {0, 1, 2} and folds.blocks == 3
    assert len(np.unique(folds.unit)) == 9  # one configuration per grid value
    vals = np.round(np.rad2deg(q))
    assert all(len(set(fold[vals == v].tolist())) == 1 for v in np.unique(vals))
    assert fold[vals == -40][0] != fold[vals == -10][0]


def test_no_folds_when_a_period_exceeds_a_third_of_the_range():
    """A 1st harmonic over 80 deg: one block; not judged between the values (None)."""
    q = _lattice(10.0)
    assert configuration_folds(q[:, None], block_widths((Sin(ch="q1", k=1.0),), (1,), [np.ptp(q)])) is None


def test_folds_of_two_joints_interleave_in_both():
    """A term of two joints: a row's fold is the sum of its blocks modulo the folds, so that blocks next to each other
    in either joint are in different folds."""
    rng = np.random.default_rng(2)
    q = np.column_stack([rng.choice(np.arange(10) * 0.2, 400), rng.choice(np.arange(10) * 0.3, 400)])
    fold = configuration_folds(q, [0.2, 0.3]).fold
    b1, b2 = np.round(q[:, 0] / 0.2).astype(int), np.round(q[:, 1] / 0.3).astype(int)
    assert np.array_equal(fold, (b1 + b2) % 5)


def test_configuration_folds_refuse_bad_widths():
    """One positive width per joint, else ValueError naming them."""
    with pytest.raises(ValueError, match="widths"):
        configuration_folds(np.zeros((5, 2)), [0.1])
    with pytest.raises(ValueError, match="widths"):
        configuration_folds(np.zeros((5, 1)), [0.0])


# ---- the confirmation on folds (linear problems) -------------------------------------------------------------

GRID5 = (5.0, 16)  # a 5 deg grid over [-40, 40] deg (17 values, 16 rows each): orders up to 35


def _problem(seed, order, residual):
    """A linear problem on a 5 deg grid of q1 (17 values, 16 rows each, 3 residuals per row): model columns ``A`` (an
    offset and a slope of q1 and four random columns), the harmonic's columns ``E``, and ``residual`` in {"harmonic",
    "pattern"}: that harmonic plus noise, or a value of its own at each grid value plus noise. Returns ``A, E, r, row``
    and the folds of the harmonic's rows."""
    rng = np.random.default_rng(seed)
    q = _lattice(GRID5[0], repeats=GRID5[1])
    rng.shuffle(q)
    n = q.size
    row = np.repeat(np.arange(n), 3)
    x = q[row]
    lever = rng.normal(1.0, 0.3, 3 * n)
    A = np.column_stack([lever, lever * x, rng.normal(size=(3 * n, 4))])
    E = np.column_stack([lever * np.sin(order * x), lever * np.cos(order * x)])
    if residual == "harmonic":
        r = E @ np.array([0.3, -0.2])
    else:
        vals = np.unique(q)
        r = lever * rng.normal(0.0, 0.35, vals.size)[np.searchsorted(vals, x)]
    r = r + rng.normal(0.0, 1.0, 3 * n)
    r = r - A @ np.linalg.lstsq(A, r, rcond=None)[0]
    folds = configuration_folds(q[:, None], block_widths((Sin(ch="q1", k=float(order)),), (1,), [np.ptp(q)]))
    return A, E, r, row, folds


ORDERS = range(9, 30)  # rivals: orders with three blocks or more over the 80 deg, within the grid's bound (35)


def test_a_true_harmonic_holds_on_folds_it_was_not_fitted_on():
    """The residual is a harmonic of order 12 plus noise: judged with its rivals (orders 9-29, each fold choosing
    again), confirmed on the folds (z > Z_MIN) on >= 19/20 seeds."""
    out = []
    for s in range(20):
        A, E, r, row, folds = _problem(s, 12, "harmonic")
        rivals = [_problem(s, k, "harmonic")[1] for k in ORDERS if k != 12]
        out.append(fold_confirmation(A, E, r, row, folds, Z_MIN, rivals=rivals))
    assert all(isinstance(c, FoldConfirmation) and c.folds == 3 for c in out)
    assert sum(c.passed for c in out) >= 19, [(round(c.z, 2), c.rechosen) for c in out]


def test_a_harmonic_chosen_for_a_pattern_of_the_grid_values_fails_on_the_folds():
    """The residual is a value of its own at each grid value (nothing between them to predict): the harmonic of
    orders 9-29 that fits it best, significant on the rows it was fitted on, is not confirmed on the folds when each
    fold's choice among it and the orders within RIVAL_MARGIN of its evidence is made again on the other folds' rows
    (z > Z_MIN on <= 3/20 seeds; judged alone, the choice made on every row, on 12 of 40)."""
    passed, evidence = [], []
    for s in range(20):
        cands = []
        for k in ORDERS:
            A, E, r, row, folds = _problem(s, k, "pattern")
            Q = np.linalg.qr(A)[0]
            Ep = E - Q @ (Q.T @ E)
            d = float(np.sum((np.linalg.qr(Ep)[0].T @ r) ** 2))
            cands.append((chi2_logsf(d, 2), d, k, E, folds))
        lp, d, k, E, folds = min(cands, key=lambda t: t[0])
        evidence.append(d)
        rivals = [c[3] for c in cands if c[2] != k and c[0] < lp + RIVAL_MARGIN]
        passed.append(fold_confirmation(A, E, r, row, folds, Z_MIN, rivals=rivals).passed)
    assert np.median(evidence) > 30  # significant on the rows it was fitted on
    assert sum(passed) <= 3, passed


def test_the_rows_of_one_grid_value_count_once():
    """Nine grid values of 30 rows each, every row predicted exactly: nine sums are ranked, z = 2.67 (all in favour),
    not the z of 270 rows."""
    q = _lattice(10.0)
    E = np.cos(12 * q)[:, None]
    folds = configuration_folds(q[:, None], block_widths((Cos(ch="q1", k=12.0),), (1,), [np.ptp(q)]))
    c = fold_confirmation(np.ones((q.size, 1)), E, 5.0 * E[:, 0], np.arange(q.size), folds, Z_MIN)
    assert c.rows == 9 and c.better and c.z == pytest.approx(np.sqrt(1.5 * 9 * 10 / 19))


def test_fold_confirmation_refuses_mismatched_rows():
    """A, E, r and row must have the same rows (ValueError)."""
    with pytest.raises(ValueError, match="same rows"):
        fold_confirmation(np.zeros((6, 1)), np.zeros((5, 2)), np.zeros(6), np.zeros(6, int),
                          configuration_folds(np.repeat([0.0, 1.0, 2.0], 2), [1.0]), 3.0)


# ---- the diagnosis on grid campaigns ---------------------------------------------------------------------------

def _orders(res, joint):
    return sorted({float(f["k"]) for a in res.atoms for f in a["features"]
                   if f["kind"] in ("sin", "cos") and f["ch"] == f"q{joint}"})


def test_an_aliasing_harmonic_of_a_grid_is_not_kept():
    """Joint 1 on a 5 deg grid over [-40, 40] deg turns by 0.01 deg sin(6 q1): an order the scan does not offer over
    80 deg (1.3 periods), whose aliases (66, 78, 138, ...) match it at every grid value. No harmonic of joint 1 above
    the grid's bound (35, reported in diagnosis.json) is kept, and the model predicts rows between the grid's values
    within 2x the noise (the aliasing model, without the bound: 0.07-0.1 mm there;
    experiments/bench_configurations.py)."""
    ds, truth = H.grid_dataset(seed=0, effect=lambda q: q + AMP * np.sin(6 * q[:, [0]] + 0.7) * np.eye(6)[0])
    res = diagnose(ds)
    assert res.sampling["joints"][0]["max_order"] == 35
    assert diagnosis_dict(res)["sampling"]["joints"][0]["max_order"] == 35
    assert res.structured and all(k <= 35 for k in _orders(res, 1)), _orders(res, 1)
    assert H.between_grid_rms(res.calibration, truth) < 2 * np.sqrt(3) * H.SIGMA * MM_PER_M


def test_a_true_harmonic_of_low_order_on_a_grid_is_kept():
    """The same grid with 0.01 deg sin(11 q1) (within the bound): the harmonic of order 11 is kept, confirmed on the
    folds of joint 1's values it was not fitted on (its z_configurations recorded, above Z_MIN)."""
    ds, _ = H.grid_dataset(seed=0, effect=lambda q: q + AMP * np.sin(11 * q[:, [0]] + 0.7) * np.eye(6)[0])
    res = diagnose(ds)
    assert 11.0 in _orders(res, 1)
    kept = [s for s in res.scores if s.decision == "kept" and "order 11" in s.name]
    assert kept and kept[0].z_configurations > Z_MIN
