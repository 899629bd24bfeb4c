"""Tests of twin.diagnosis.rule's judgement of an extra term beside a named family: where a kept term acts, and the
row-by-row comparison of two models on the confirmation rows (the nested test of the terms taken out)."""

from types import SimpleNamespace

import numpy as np

from twin.diagnosis.atoms import Atom
from twin.diagnosis.features import LoadSign, Sign, Torque
from twin.diagnosis.rule import _better_rows, _distinct, _places, _rival_readings
from twin.diagnosis.scoring import Scored


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


def _scored(atom, dchi2, logp_adj=-20.0):
    return Scored(atom, np.eye(1), np.zeros(1), dchi2, logp_adj, np.zeros(1))


def _load_backlash(j, u):
    f = LoadSign(f=Torque(j=j, h=1.0), u=u)
    return Atom("backlash", "joint", f"theta{j}", (f,), f"load_sign_j{j} {u}", f"joint {j} backlash (load)", "load", (j,))


def test_candidates_equal_on_every_calibration_row_are_tried_once_and_rejected_together():
    """Two directions of a load that give every calibration row the same sign are one candidate: the round keeps the
    first and lists the other as rejected with it; a direction that splits the rows differently is kept."""
    a, b, c = _load_backlash(7, (1.0, 0.0)), _load_backlash(7, (0.0, 1.0)), _load_backlash(7, (0.7, 0.7))
    values = {a.key: np.array([[1.0], [-1.0], [1.0]]), b.key: np.array([[1.0], [-1.0], [1.0]]),
              c.key: np.array([[1.0], [1.0], [1.0]])}
    prob = SimpleNamespace(features_cal=lambda atom: values[atom.key])
    kept, same = _distinct(prob, [_scored(a, 735.0), _scored(b, 735.0), _scored(c, 735.0)])
    assert [s.atom.key for s in kept] == [a.key, c.key]
    assert same == {a.key: [b.key]}


def test_a_backlash_tried_in_one_reading_is_followed_by_its_joints_other_reading():
    """A joint's load-signed backlash tried first brings the same joint's motion-signed backlash into the round's
    tries, ahead of the terms elsewhere; a reading that is not significant does not."""
    load = _scored(_load_backlash(7, (1.0, 0.0)), 735.0, -18.7)
    motion = _scored(Atom("backlash", "joint", "theta7", (Sign(j=7),), "approach_sign_j7", "joint 7 backlash (motion)",
                          "catalogue", (7,)), 639.0, -16.7)
    other = _scored(Atom("cyclic", "joint", "theta4", (), "q4", "joint 4, 1st harmonic", "catalogue", (4,)), 700.0, -17.5)
    order = [load, other, motion]
    assert _rival_readings(order, [load, other], np.log(0.01)) == [load, motion, other]
    assert _rival_readings(order, [load, other], -30.0) == [load, other]
