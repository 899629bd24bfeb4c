"""Tests of twin.diagnosis.rule's judgement of an extra term beside a named family: where a kept term acts, and the
row-by-row comparison of two models on the confirmation rows (the nested test of the terms taken out)."""

from types import SimpleNamespace

import numpy as np
import pytest

from twin.diagnosis.atoms import Atom
from twin.diagnosis.candidates import RowContext
from twin.diagnosis.features import Cos, Pow, Prod, Sin, Torque
from twin.diagnosis.loads import own_link_atom
from twin.diagnosis.rule import _better_rows, _own_variables, _places, _spanning
from twin.diagnosis.values import feature_values
from twin.robots import irb1200


def _prob(n_joints=6, keep_val=None):
    return SimpleNamespace(prep=SimpleNamespace(nominal=SimpleNamespace(n_joints=n_joints)), keep_val=keep_val)


def _fit(row_errors, coords=3):
    """A fit whose model predicts each confirmation row with the whitened residual ``row_errors[k]`` on every
    coordinate of row ``k``."""
    e = np.asarray(row_errors, float)
    row = np.repeat(np.arange(e.size), coords)
    res = SimpleNamespace(r=np.repeat(e, coords), row=row)
    model = SimpleNamespace(residuals=lambda z, jacobian=True: res, obs=SimpleNamespace(n=e.size))
    return SimpleNamespace(model_val=model, z=np.zeros(1))


def test_a_kept_term_acts_at_its_joint_a_supports_tilt_at_the_joints_its_moment_bends():
    """A joint term acts at its joint; the base's tilt at itself and joints 2 and 3; a wrist support's tilt at itself
    and the joints on either side; a link's growth at no joint."""
    prob = _prob()
    joint = Atom("cyclic", "joint", "theta4", (), "q4", "joint 4, 1st harmonic", "catalogue", (4,))
    base = Atom("tilt", "param", "tilt0", (), "", "base tilt", "catalogue")
    wrist = Atom("tilt", "param", "tilt5", (), "", "support 5 tilt", "catalogue")
    grow = Atom("thermal", "length", "a2", (), "t_s", "growth of a2", "catalogue")
    assert _places(prob, joint) == {"theta4"}
    assert _places(prob, base) == {"tilt0", "theta2", "theta3"}
    assert _places(prob, wrist) == {"tilt5", "theta4", "theta5", "theta6"}
    assert _places(prob, grow) == set()


def test_rows_each_predicted_better_by_the_other_model_score_beyond_three():
    """Forty confirmation rows each predicted better with the extra terms score beyond 3 (the terms stay); the same
    model against itself scores 0; rows left out count for nothing."""
    rng = np.random.default_rng(3)
    e = 1.0 + rng.uniform(0.0, 1.0, 40)
    family_alone, with_extra = _fit(e), _fit(0.8 * e)
    assert _better_rows(_prob(keep_val=np.ones(40, bool)), family_alone, with_extra) > 3.0
    assert _better_rows(_prob(keep_val=np.ones(40, bool)), family_alone, family_alone) == 0.0
    keep = np.zeros(40, bool)
    keep[:2] = True
    assert abs(_better_rows(_prob(keep_val=keep), family_alone, with_extra)) < 3.0


def test_rows_predicted_better_on_half_and_worse_on_the_other_half_do_not_keep_the_terms():
    """Rows predicted better and worse alike by the extra terms (an error moved, not removed) score below 3."""
    rng = np.random.default_rng(4)
    e = 1.0 + rng.uniform(0.0, 1.0, 40)
    f = np.where(np.arange(40) % 2 == 0, 0.8, 1.2) * e
    assert abs(_better_rows(_prob(keep_val=np.ones(40, bool)), _fit(e), _fit(f))) < 3.0


def _harmonic(j: int, k: int) -> Atom:
    return Atom("cyclic", "joint", f"theta{j}", (Sin(ch=f"q{j}", k=float(k)), Cos(ch=f"q{j}", k=float(k))),
                f"cyclic_j{j}_k{k}", f"joint {j}, harmonic {k}", "catalogue", (j,))


def test_a_harmonic_is_read_as_the_family_term_whose_columns_span_it_over_the_rows():
    """The shoulder's own link weight (its axis level) spans its angle's 1st harmonic over any rows, so the harmonic
    is read as it; a 2nd harmonic there, and the elbow's 1st beside the elbow's link weight (which turns with q2 + q3),
    are not spanned and stay."""
    model = irb1200()
    q = np.random.default_rng(3).uniform(-1.2, 1.2, (60, model.n_joints))
    ctx = RowContext(q=q)
    prob = SimpleNamespace(ctx=ctx, features=lambda a: feature_values(a.features, ctx, model))
    own2, own3 = own_link_atom(model, q, 2), own_link_atom(model, q, 3)
    first, second, elbow = _harmonic(2, 1), _harmonic(2, 2), _harmonic(3, 1)
    assert _spanning(prob, [first], [own3, own2]) == [(first, own2)]
    assert _spanning(prob, [second], [own2]) == []
    assert _spanning(prob, [elbow], [own3]) == []


def _zero_step_round(seed: int):
    """A joint zero's step (joint, size and row drawn per seed, in the rows that fit) at its geometric fit: the
    problem, the fit, the change scan's candidates and the pool sizes; the joint and the step's row; the atom pool."""
    import _diagnosis_helpers as H
    from twin.diagnosis.changes import change_places, scan_changes, selection_short
    from twin.diagnosis.diagnose import atom_pool, fit_geometry, prepare_diagnosis

    rng = np.random.default_rng(40 + seed)
    n_poses = 120
    m = n_poses + n_poses // 4
    joint = int(rng.integers(1, 7))
    row = int(rng.integers(int(0.25 * m), int(0.5 * m)))
    size_deg = rng.uniform(0.02, 0.05) * (3 if joint >= 4 else 1)  # a wrist joint's zero moves the plate less

    def eff(q, model):
        out = q.copy()
        out[row:, joint - 1] += np.deg2rad(size_deg)
        return out

    ds, _ = H.make_dataset(seed=seed, n=n_poses, effect=eff, t_s=np.cumsum(rng.uniform(8, 12, m)))
    setup = prepare_diagnosis(ds)
    prob = setup.problem
    fit = fit_geometry(prob, setup.x0)
    pool, sizes = atom_pool(setup)
    places = change_places(prob.prep.nominal, [a for a in pool if a.pool == "catalogue"], prob.ctx.q)
    found = scan_changes(prob, fit, places, short=selection_short(prob.obs_cal.n))
    return prob, fit, found, sizes, joint, row, pool


def _windows_first(monkeypatch, structured: bool):
    """Every window turned down by the wander test (against rows outside it that are ``structured``, or a wander)
    and ranked before every other candidate."""
    from twin.diagnosis import ordering, rule
    from twin.diagnosis.changes import STRUCTURED_OUTSIDE, is_window

    outside_ms = 2.0 * STRUCTURED_OUTSIDE if structured else 1.0
    monkeypatch.setattr(rule, "window_wander", lambda *a, **k: (0.0, outside_ms))
    order = ordering.order_candidates
    monkeypatch.setattr(rule, "order_candidates", lambda s: sorted(order(s), key=lambda c: not is_window(c.atom)))


@pytest.mark.parametrize("seed", range(3))
def test_a_window_turned_down_against_a_change_outside_it_takes_no_try(seed, monkeypatch):
    """A change and back turned down by the wander test where the rows outside it hold a change the model lacks is
    not one of the round's tries: with every window so turned down and ranked first, the round keeps the joint zero's
    step at its row (joint, size and row drawn)."""
    from twin.diagnosis import rule
    from twin.diagnosis.changes import is_step, is_window, row_times

    prob, fit, found, sizes, joint, row, _ = _zero_step_round(seed)
    assert any(is_window(a) for a in found) and any(is_step(a) for a in found)
    _windows_first(monkeypatch, structured=True)
    r = rule.selection_round(prob, fit, found, sizes, 1, alpha_select=0.01, z_min=3.0)
    assert r.accepted is not None and is_step(r.accepted.atom), [c.decision for c in r.scores]
    t = row_times(prob.ctx)[1]
    assert r.accepted.atom.target == f"theta{joint}"
    assert t[row - 1] < r.accepted.atom.features[0].at <= t[row], (r.accepted.atom.label, t[row])


@pytest.mark.parametrize("seed", range(2))
def test_a_window_turned_down_against_a_wander_ends_the_round(seed, monkeypatch):
    """A change and back turned down by the wander test against rows outside it that only wander ends the round as
    a candidate not significant does: ranked first, nothing is kept, though the step behind it would be."""
    from twin.diagnosis import rule

    prob, fit, found, sizes, _, _, _ = _zero_step_round(seed)
    _windows_first(monkeypatch, structured=False)
    r = rule.selection_round(prob, fit, found, sizes, 1, alpha_select=0.01, z_min=3.0)
    assert r.accepted is None
    assert r.scores and all(c.decision == "not significant on the calibration rows" for c in r.scores)


@pytest.mark.parametrize("seed", range(2))
def test_after_a_window_turned_down_against_a_change_outside_it_only_changes_are_tried(seed, monkeypatch):
    """A window turned down where the rows outside it hold a change sends the round on to changes only: with the
    scan's windows ranked first and so turned down, and the catalogue's terms (some significant) the only other
    candidates, the round tries no catalogue term and keeps nothing."""
    from twin.diagnosis import rule
    from twin.diagnosis.changes import is_window
    from twin.diagnosis.scoring import score_atoms

    prob, fit, found, sizes, _, _, pool = _zero_step_round(seed)
    windows = [a for a in found if is_window(a)]
    catalogue = [a for a in pool if a.pool == "catalogue"]
    assert windows and any(s.logp_adj < np.log(0.01) for s in score_atoms(prob, fit, catalogue, sizes))
    _windows_first(monkeypatch, structured=True)
    r = rule.selection_round(prob, fit, windows + catalogue, sizes, 1, alpha_select=0.01, z_min=3.0)
    assert r.accepted is None
    assert {c.name for c in r.scores} <= {a.label for a in windows}, [c.name for c in r.scores]


def test_a_term_of_a_joint_angle_names_its_joint_variables_when_its_own_is_among_them():
    """A term of joint 4's angle in q4*q5 or q4^2 gives its joint variables (the catalogue's shapes of each are
    tried in its place); one in q2*q3, one of a torque or a term of a frame give none."""
    def term(target, *features, place="joint"):
        return Atom("generic", place, target, features, "", "x", "generic")

    prod = Prod(ch=("q4", "q5"), c=(0.0, 0.0), h=(1.0, 1.0))
    assert _own_variables(term("theta4", prod)) == {"q4", "q5"}
    assert _own_variables(term("theta4", Pow(ch="q4", p=2, c=0.0, h=1.0))) == {"q4"}
    assert _own_variables(term("theta4", Prod(ch=("q2", "q3"), c=(0.0, 0.0), h=(1.0, 1.0)))) == set()
    assert _own_variables(term("theta4", Torque(j=4))) == set()
    assert _own_variables(term("base", prod, place="param")) == set()
