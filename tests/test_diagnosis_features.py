"""Tests of twin.diagnosis.features: the typed features of the atoms and the dicts diagnosis.json and
calibration.json store them as."""

import dataclasses
import json

import numpy as np
import pytest

from twin.diagnosis.atoms import Atom
from twin.diagnosis.values import feature_values, with_records
from twin.diagnosis.candidates import RowContext
from twin.diagnosis.features import (FEATURE_KINDS, BaseMoment, CartDir, Const, Cos, Exp, Feature, Field, Gated, Grav,
                                     GravityDir, GravMix, Heat, HeatRecord, Hinge, Lag, LagRecord, LastMove, LoadSign,
                                     Moment, Play, Pow, Prod, Settle, Sign, Sin, Station, Step, StepIn, Torque, Window,
                                     feature_from_dict)
from twin.robots import irb1200

_FIELD = {"z_c": 1.2, "z_h": 0.3, "r_c": 1.25, "r_h": 0.31, "rho2_h": 0.04}


def _one_of_each() -> list[Feature]:
    """One feature of every kind, the optional fields set on some."""
    gm = GravMix(i=2, cols=((2, 0), (2, 1), (3, 0)), w=(0.5, -0.25, 0.125), h=3.0)
    return [
        Pow(ch="q3", p=2, c=0.1, h=1.5),
        Sin(ch="q2", k=3),
        Cos(ch="t_s", k=0.0125, t_span=(0.0, 500.0)),
        Prod(ch=("q1", "q2"), c=(0.1, -0.2), h=(1.0, 2.0)),
        Sign(j=4),
        Grav(i=2, k=3, c=1),
        LastMove(j=1, w=0.1),
        LastMove(j=3, w=0.5, law="clip"),
        LastMove(j=2, w=0.3, law="exp"),
        gm,
        Torque(j=2, h=1.0),
        Moment(j=0, axis=1, h=1.0),
        Moment(j=0, axis=1, h=1.0, about=0, shape=2),
        BaseMoment(axis=0, shape=1, w=(0.25, 0.5), h=2.0),
        BaseMoment(axis=1, shape=3, w=(0.25, 0.5), h=2.0, about=0),
        GravityDir(axis=2),
        Step(ch="row", at=12.0, record_pose_id=(3, 1, 2)),
        Window(ch="t_s", at=100.0, until=200.0),
        LoadSign(f=gm, u=(0.6, 0.8)),
        LoadSign(f=Torque(j=3, h=1.0)),
        LoadSign(f=gm, u=(0.6, 0.8), width=0.2),
        LoadSign(f=Torque(j=3, h=1.0), width=4.0, law="clip"),
        Hinge(ch="q2", at=0.3, side=-1, p=2, h=0.7),
        StepIn(j=5),
        Heat(tau=120.0, joints=(1, 2, 3), h=0.5, record=HeatRecord(t_s=(0.0, 1.0), q=((0.0,) * 6, (0.1,) * 6),
                                                                   reset=(False, True))),
        Settle(tau=60.0, t0=(("A", 0.0), ("B", 30.0)), only="B", t_span=(0.0, 90.0)),
        Gated(f=gm, ch="t_s", at=50.0, until=80.0),
        Play(j=2, h=0.001),
        CartDir(axis=1, tcp=(0.0, 0.0, 0.05)),
        Exp(ch="t_s", t0=0.0, tau=30.0),
        Exp(ch="t_s", t0=5.0, tau=30.0, ramp=60.0, t_span=(0.0, 40.0)),
        Lag(ch="temp_c", tau=300.0, c=21.0, h=1.0, record=LagRecord(t_s=(0.0, 10.0), x=(20.5, 21.5))),
        Station(name="B"),
        Const(),
        Field(g="view1", **_FIELD, n_tool=(0.0, 0.0, 1.0)),
        Field(g="depth_scale", **_FIELD, station="A", t0=0.0, tau=45.0, t_span=(0.0, 90.0)),
    ]


def test_every_kind_reads_back_from_its_dict():
    """Every kind's dict, also through JSON, reads back as the same feature (and hashes), and the examples cover
    every kind there is."""
    feats = _one_of_each()
    assert {f.kind for f in feats} == set(FEATURE_KINDS)
    for f in feats:
        d = f.to_dict()
        assert d["kind"] == f.kind
        assert feature_from_dict(d) == f, f
        assert feature_from_dict(json.loads(json.dumps(d))) == f, f
        assert hash(feature_from_dict(d)) == hash(f)


def test_the_kept_repr_is_the_dataclass_repr():
    """Every kind's repr (the key of its values, kept once made) is the text a dataclass' own repr gives for the same
    fields and values, records and nested features included, and is the same text when asked again."""
    for f in _one_of_each() + [HeatRecord(t_s=(0.0,), q=((0.1,) * 6,), reset=(True,)), LagRecord(t_s=(0.0,), x=(1.5,))]:
        names = [fl.name for fl in dataclasses.fields(f)]
        twin_cls = dataclasses.make_dataclass(type(f).__qualname__, names)  # the dataclass' generated repr
        expected = repr(twin_cls(*(getattr(f, n) for n in names)))
        assert repr(f) == expected
        assert repr(f) is repr(f)


def test_dicts_keep_the_keys_in_their_order():
    """``to_dict`` gives the dicts the diagnosis has always written: the same keys in the same order, lists where
    they had lists, an optional key only when set."""
    gm = GravMix(i=2, cols=((2, 0), (2, 1)), w=(0.5, -0.25), h=3.0)
    want = [
        (Pow(ch="q3", p=2, c=0.1, h=1.5), {"kind": "pow", "ch": "q3", "p": 2, "c": 0.1, "h": 1.5}),
        (Prod(ch=("q1", "q2"), c=(0.1, -0.2), h=(1.0, 2.0)),
         {"kind": "prod", "ch": ["q1", "q2"], "c": [0.1, -0.2], "h": [1.0, 2.0]}),
        (gm, {"kind": "gravmix", "i": 2, "cols": [[2, 0], [2, 1]], "w": [0.5, -0.25], "h": 3.0}),
        (LoadSign(f=gm, u=(0.6, 0.8)),
         {"kind": "loadsign", "f": {"kind": "gravmix", "i": 2, "cols": [[2, 0], [2, 1]], "w": [0.5, -0.25], "h": 3.0},
          "u": [0.6, 0.8]}),
        (LoadSign(f=Torque(j=3, h=1.0)), {"kind": "loadsign", "f": {"kind": "torque", "j": 3, "h": 1.0}}),
        (Heat(tau=120.0, joints=(1, 2, 3), h=0.5), {"kind": "heat", "tau": 120.0, "joints": [1, 2, 3], "h": 0.5}),
        (Settle(tau=60.0, t0=(("A", 0.0), ("B", 30.0)), only="B"),
         {"kind": "settle", "tau": 60.0, "t0": {"A": 0.0, "B": 30.0}, "only": "B"}),
        (Gated(f=Torque(j=2, h=1.0), ch="t_s", at=50.0, until=80.0),
         {"kind": "gated", "f": {"kind": "torque", "j": 2, "h": 1.0}, "ch": "t_s", "at": 50.0, "until": 80.0}),
        (Window(ch="row", at=3.0, until=9.0), {"kind": "window", "ch": "row", "at": 3.0, "until": 9.0}),
        (CartDir(axis=0, tcp=(0.0, 0.0, 0.05)), {"kind": "cartdir", "axis": 0, "tcp": [0.0, 0.0, 0.05]}),
        (Field(g="view2", **_FIELD, n_tool=(0.0, 0.0, 1.0), station="A"),
         {"kind": "field", "g": "view2", **_FIELD, "n_tool": [0.0, 0.0, 1.0], "station": "A"}),
        (Const(), {"kind": "const"}),
    ]
    for f, d in want:
        assert list(f.to_dict().items()) == list(d.items()), f


def test_records_are_written_as_before():
    """The records a lag, the motion heat, a term in the row order and a term of time carry
    (:func:`twin.diagnosis.atoms.with_records`) are written with the keys, order and values they always had."""
    t = np.array([0.0, 10.0, 25.0])
    q = np.arange(18, dtype=float).reshape(3, 6) * 0.01
    ctx = RowContext(q=q, t_s=t, temp_c=np.array([20.0, 20.5, 21.0]), pose_id=np.array([7, 8, 9]),
                     history_reset=np.array([False, True, False]))
    got = [f.to_dict() for f in with_records((Lag(ch="temp_c", tau=30.0, c=20.5, h=1.0),
                                              Heat(tau=40.0, joints=(1, 2), h=0.5),
                                              Step(ch="row", at=1.0),
                                              Gated(f=Pow(ch="t_s", p=1, c=12.5, h=12.5), ch="t_s", at=10.0)), ctx)]
    assert [list(d.items()) for d in got] == [list(d.items()) for d in [
        {"kind": "lag", "ch": "temp_c", "tau": 30.0, "c": 20.5, "h": 1.0,
         "record": {"t_s": [0.0, 10.0, 25.0], "x": [20.0, 20.5, 21.0]}},
        {"kind": "heat", "tau": 40.0, "joints": [1, 2], "h": 0.5,
         "record": {"t_s": [0.0, 10.0, 25.0], "q": q.tolist(), "reset": [False, True, False]}},
        {"kind": "step", "ch": "row", "at": 1.0, "record_pose_id": [7, 8, 9]},
        {"kind": "gated", "f": {"kind": "pow", "ch": "t_s", "p": 1, "c": 12.5, "h": 12.5, "t_span": [0.0, 25.0]},
         "ch": "t_s", "at": 10.0, "t_span": [0.0, 25.0]},
    ]]
    for d in got:
        assert feature_from_dict(d).to_dict() == d


def test_features_read_back_give_the_same_values():
    """A feature read back from its dict (with its records) gives the same values on the rows, to the bit."""
    rng = np.random.default_rng(0)
    q = rng.uniform(-1, 1, (12, 6))
    ctx = RowContext(q=q, t_s=np.linspace(0, 100, 12), temp_c=np.linspace(20, 22, 12), station=np.array(["A", "B"] * 6))
    # every kind of the rows but the loads from mass properties (the 6R robots have none) and the point fields
    plain = [f for f in _one_of_each() if not isinstance(f, (Field, Heat, Lag, Settle, Torque, Moment, BaseMoment))
             and not (isinstance(f, LoadSign) and isinstance(f.f, Torque))
             and getattr(f, "record_pose_id", None) is None]
    feats = tuple(with_records(tuple(plain)
                               + (BaseMoment(axis=1, shape=0, w=tuple(np.linspace(-1, 1, 24).tolist()), h=2.0),
                                  Lag(ch="temp_c", tau=30.0, c=21.0), Heat(tau=40.0, h=0.5),
                                  Settle(tau=20.0, t0=(("A", 0.0), ("B", 5.0)))), ctx))
    back = tuple(feature_from_dict(json.loads(json.dumps(f.to_dict()))) for f in feats)
    assert back == feats
    assert np.array_equal(feature_values(back, ctx, irb1200()), feature_values(feats, ctx, irb1200()))


def test_an_atom_spec_round_trips():
    """``Atom.spec`` writes the features' dicts and ``Atom.from_spec`` reads them back as the same features."""
    a = Atom("compliance", "joint", "theta2", (Gated(f=Torque(j=2, h=1.0), ch="t_s", at=5.0),), "ch", "label",
             "catalogue", (2,))
    spec = a.spec()
    assert spec["features"] == [{"kind": "gated", "f": {"kind": "torque", "j": 2, "h": 1.0}, "ch": "t_s", "at": 5.0}]
    assert Atom.from_spec(json.loads(json.dumps(spec))).features == a.features


def test_an_unknown_kind_or_key_is_refused_with_its_name():
    """A dict of a kind nobody knows, or with a key its kind does not have or lacking one it needs, is a
    ``ValueError`` naming the kind (and the key)."""
    with pytest.raises(ValueError, match="unknown feature kind 'spline'"):
        feature_from_dict({"kind": "spline", "ch": "q1"})
    with pytest.raises(ValueError, match="unknown feature kind None"):
        feature_from_dict({"ch": "q1"})
    with pytest.raises(ValueError, match="feature kind 'pow' has no 'q'"):
        feature_from_dict({"kind": "pow", "ch": "q1", "p": 1, "c": 0.0, "h": 1.0, "q": 2})
    with pytest.raises(ValueError, match="feature kind 'step' is missing 'at'"):
        feature_from_dict({"kind": "step", "ch": "t_s"})
    with pytest.raises(ValueError, match="unknown feature kind 'spline'"):
        Atom.from_spec({"family": "unnamed", "place": "joint", "target": "theta1", "features": [{"kind": "spline"}]})


def test_the_air_s_step_and_ramp_through_the_lag_is_the_lag_of_their_input():
    """An Exp feature (the links' lag of the air's change at t0, a step or a ramp over `ramp`) equals the air's
    profile through a first-order lag integrated finely; a ramp the campaign did not see end holds the air at the
    state the campaign's last row reached."""
    from twin.diagnosis.values import lag_response

    t = np.linspace(0.0, 400.0, 400001)
    dt = t[1] - t[0]

    def lagged(u, tau):
        y = np.zeros_like(u)
        for k in range(1, len(u)):
            y[k] = y[k - 1] + (1 - np.exp(-dt / tau)) * (u[k] - y[k - 1])
        return y

    step = (t >= 50.0).astype(float)
    ramp = np.clip((t - 50.0) / 120.0, 0.0, 1.0)
    np.testing.assert_allclose(lag_response(t - 50.0, 30.0), lagged(step, 30.0), atol=2e-4)
    np.testing.assert_allclose(lag_response(t - 50.0, 30.0, 120.0), lagged(ramp, 30.0), atol=2e-4)
    # the campaign ends at t = 110 s, mid-ramp: after it the air holds what it reached at 110 s
    f = Exp(ch="t_s", t0=50.0, tau=30.0, ramp=120.0, t_span=(0.0, 110.0))
    rows = t[::4000]
    ctx = RowContext(q=np.zeros((len(rows), 6)), t_s=rows)
    held = np.where(t <= 110.0, ramp, 0.5)
    np.testing.assert_allclose(feature_values((f,), ctx, irb1200())[:, 0], lagged(held, 30.0)[::4000], atol=2e-4)


def test_a_lagged_temperature_reads_the_channel_linear_between_rows():
    """A Lag feature of temp_c equals the lag of the recorded temperature interpolated linearly between the rows
    (integrated finely), across gaps of many time constants and a repeat at one time: a ramp recorded before and
    after a pause is not read as a jump at the pause's start."""
    rows = np.array([0.0, 20.0, 40.0, 40.0, 300.0, 320.0, 900.0, 910.0])
    temp = np.array([20.0, 20.1, 20.2, 20.2, 22.0, 22.1, 20.5, 20.4])
    ctx = RowContext(q=np.zeros((len(rows), 6)), t_s=rows, temp_c=temp)
    f = Lag(ch="temp_c", tau=60.0, c=20.0, h=1.0)
    t = np.linspace(0.0, 910.0, 910001)
    u = np.interp(t, rows, temp)
    y = np.empty_like(u)
    y[0] = u[0]
    a = -np.expm1(-(t[1] - t[0]) / 60.0)
    for k in range(1, len(t)):
        y[k] = y[k - 1] + a * (0.5 * (u[k] + u[k - 1]) - y[k - 1])
    np.testing.assert_allclose(feature_values((f,), ctx, irb1200())[:, 0], np.interp(rows, t, y) - 20.0, atol=1e-4)


def test_a_lagged_temperature_with_a_gap_fraction_steps_the_channel_there():
    """A Lag feature with ``gap`` 0.7 equals the exact lag of a channel that holds each row's value until 0.7 of the
    interval to the next row and steps to it there: a -7 K step of the air inside a 900 s pause, 630 s after the row
    before it, read at the rows after the pause as the step's own response (not the linear interpolation's)."""
    rows = np.array([0.0, 20.0, 40.0, 940.0, 960.0, 1000.0])
    temp = np.array([22.0, 22.0, 22.0, 15.0, 15.0, 15.0])
    ctx = RowContext(q=np.zeros((len(rows), 6)), t_s=rows, temp_c=temp)
    tau = 300.0
    got = feature_values((Lag(ch="temp_c", tau=tau, c=20.0, h=1.0, gap=0.7),), ctx, irb1200())[:, 0]
    step_at = 40.0 + 0.7 * 900.0
    want = 22.0 - 7.0 * np.where(rows > step_at, -np.expm1(-np.clip(rows - step_at, 0.0, None) / tau), 0.0) - 20.0
    np.testing.assert_allclose(got, want, atol=1e-9)
    linear = feature_values((Lag(ch="temp_c", tau=tau, c=20.0, h=1.0),), ctx, irb1200())[:, 0]
    assert abs(linear[3] - want[3]) > 0.5  # read as linear over the pause, 0.63 K off at the first row after it


def test_a_backlash_taken_up_at_a_rate_follows_one_minus_the_exponential_of_the_last_move():
    """The ``exp`` law of a last move ``m`` reads ``sign(m) (1 - exp(-|m| / w))``: half a width's move takes up 39 %, a
    move back of three widths 95 % on the other side, and a joint that has not moved yet reads 0."""
    q = np.zeros((4, 6))
    q[1, 1] = 0.15  # +0.15 rad on joint 2
    q[2, 1] = 0.15  # no move into this row: the last move stays +0.15
    q[3, 1] = 0.15 - 0.9  # -0.9 rad
    v = feature_values((LastMove(j=2, w=0.3, law="exp"),), RowContext(q=q), irb1200())[:, 0]
    assert v == pytest.approx([0.0, 1 - np.exp(-0.5), 1 - np.exp(-0.5), -(1 - np.exp(-3.0))])
