"""Tests of twin.diagnosis.ordering's choice of the candidates a selection round tries: distinct terms, and a
joint's backlash in each reading the rows hold."""

from types import SimpleNamespace

import numpy as np

from twin.diagnosis.atoms import Atom
from twin.diagnosis.features import Gated, LoadSign, Sign, Step, Torque
from twin.diagnosis.ordering import distinct_terms, payload_rivals, rival_readings
from twin.diagnosis.scoring import Scored


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
    kept, same = distinct_terms(prob, [_scored(a, 735.0), _scored(b, 735.0), _scored(c, 735.0)])
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
    assert rival_readings(order, [load, other], np.log(0.01)) == [load, motion, other]
    assert rival_readings(order, [load, other], -30.0) == [load, other]


def _load_change(j, at):
    f = Gated(f=Torque(j=j, h=1.0), ch="t_s", at=at)
    return Atom("change", "joint", f"theta{j}", (f,), f"change(t_s >= {at})",
                f"change of the joint {j} compliance (a payload) from t_s {at} on", "change", (j,))


def test_a_payloads_change_tried_at_one_joint_brings_the_strongest_at_each_other_joint():
    """After a round's tries of a change of joint 3's compliance (beside a frame's step) failed, the strongest
    significant change of each other joint's compliance is tried (joint 5's, not joint 3's other reading); none that is
    not significant, none where no payload's change was tried."""
    j3 = _scored(_load_change(3, 100.0), 900.0, -30.0)
    j3_other = _scored(_load_change(3, 150.0), 890.0, -29.0)
    frame = _scored(Atom("change", "param", "base", (Step(ch="t_s", at=100.0),), "change(t_s >= 100)",
                         "change of the base frame from t_s 100 on", "change", ()), 950.0, -28.0)
    j5 = _scored(_load_change(5, 150.0), 800.0, -25.0)
    j5_other = _scored(_load_change(5, 120.0), 700.0, -24.0)
    order = [j3, frame, j3_other, j5, j5_other]
    assert payload_rivals(order, [j3, frame], np.log(0.01)) == [j5]
    assert payload_rivals(order, [j3, frame], -27.0) == []
    assert payload_rivals(order, [frame], np.log(0.01)) == []
