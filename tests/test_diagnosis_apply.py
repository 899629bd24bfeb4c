"""Tests of twin.diagnosis.apply: an extended calibration predicts and compensates with its effects."""

import numpy as np
import pytest

import _diagnosis_helpers as H
from twin.diagnosis import diagnose, row_context, write_diagnosis
from twin.diagnosis.apply import compensate_extended, predict_extended
from twin.diagnosis.values import approach_unknown
from twin.estimator import Calibration
from twin.kinematics import tool2meas


@pytest.fixture(scope="module")
def backlash_case(tmp_path_factory):
    eff = H.backlash()
    ds, truth = H.make_dataset(seed=21, n=120, effect=eff)
    res = diagnose(ds)
    assert res.effects == ("backlash",)
    out = tmp_path_factory.mktemp("diag")
    write_diagnosis(res, out, plots=False)
    return ds, truth, eff, Calibration.load(out / "calibration.json"), Calibration.load(out / "calibration_geometric.json")


@pytest.mark.slow
def test_extended_prediction_matches_measurements_to_the_noise(backlash_case):
    """Predictions of the reloaded extended calibration on every row of known history (history applied) are
    at the noise level, the geometric one's are not."""
    ds, _, _, cal, geo = backlash_case
    ctx = row_context(ds)
    seen = ds.sphere_seen & ~approach_unknown(ctx)[:, None]  # the first rows' approach is unknown to the model
    e_ext = np.linalg.norm(predict_extended(cal, ctx, ds.station_ids).spheres - ds.spheres, axis=-1)[seen]
    e_geo = np.linalg.norm(geo.predict(ds.q, ds.station_ids).spheres - ds.spheres, axis=-1)[seen]
    rms_ext = np.sqrt(np.mean(e_ext**2))
    assert rms_ext < 1.3 * np.sqrt(3) * H.SIGMA
    assert np.sqrt(np.mean(e_geo**2)) > 5 * rms_ext


def test_the_dataset_predictor_of_a_few_rows_equals_the_whole_file(backlash_case):
    """dataset_predictor evaluates the rows up to the last one asked: its predictions of the first rows, of a block
    in the middle and of scattered rows equal those of the whole file (approach history included), bit for bit."""
    from twin.diagnosis.apply import dataset_predictor

    ds, _, _, cal, _ = backlash_case
    full = predict_extended(cal, row_context(ds), ds.station_ids)
    predict = dataset_predictor(ds)
    for idx in (np.arange(10), np.arange(40, 70), np.array([3, 17, 55, 90])):
        p = predict(cal, idx)
        assert np.array_equal(p.spheres, full.spheres[idx]) and np.array_equal(p.pose, full.pose[idx])


@pytest.mark.slow
def test_compensation_with_effects_reaches_targets_through_the_true_robot(backlash_case):
    """Commands from compensate_extended, sent through the true robot *with* backlash in the order given,
    put the plate within a few micrometres of targets given in the measurement frame."""
    ds, truth, eff, cal, _ = backlash_case
    true = truth["true"]
    rng = np.random.default_rng(3)
    q_goal = H.configurations(rng, 15, true)
    T_meas = tool2meas(true, q_goal)  # where we want the plate, as the camera sees it
    B = cal.base2meas["0"]
    T_base = np.linalg.inv(B) @ T_meas
    ctx = row_context(ds)
    from dataclasses import replace

    # the robot starts at home (the true backlash assumes it): the user knows where it starts
    res = compensate_extended(cal, T_base, q_goal, replace(ctx, q=np.zeros((15, 6)), q_start=np.zeros(6), temp_c=None,
                                                           t_s=None))
    q_act = eff(res.q, true)  # the true backlash, following the commands' own order
    err = np.linalg.norm(tool2meas(true, q_act)[:, :3, 3] - T_meas[:, :3, 3], axis=1)
    assert err.max() < 0.02e-3


def test_compensation_with_a_parameter_term_lands_where_the_extended_model_predicts(backlash_case):
    """An extended calibration with a robot-side parameter term (d3 varying with sin q5 by 0.1 mm) besides its
    backlash: the commands of compensate_extended put the plate where predict_extended, reading the same commands in
    their order, says the targets are (1e-7 m in the measurement frame; the term's first-order change is taken in the
    robot base frame, not in the station's)."""
    from dataclasses import replace

    _, truth, _, cal, _ = backlash_case
    term = {"family": "unnamed", "place": "param", "target": "d3", "features": [{"kind": "sin", "ch": "q5", "k": 1}],
            "label": "d3 varies with sin q5", "values": [1e-4]}
    ext = replace(cal, effects=tuple(cal.effects) + (term,))
    q_goal = H.configurations(np.random.default_rng(5), 10, truth["true"])
    B = cal.base2meas["0"]
    T_meas = tool2meas(cal.model("0"), q_goal)
    ctx = row_context(H.make_dataset(seed=21, n=20)[0])
    start = replace(ctx, q=np.zeros((10, 6)), q_start=np.zeros(6), temp_c=None, t_s=None, station=None,
                    history_reset=None, session_start=None, pose_id=None)
    res = compensate_extended(ext, np.linalg.inv(B) @ T_meas, q_goal, start)
    got = predict_extended(ext, replace(start, q=res.q), np.full(10, "0", dtype=object)).pose
    assert np.abs(got[:, :3, 3] - T_meas[:, :3, 3]).max() < 1e-7


def test_commands_too_close_for_their_backlash_correction_are_named(backlash_case):
    """Two consecutive targets whose commands differ by less than the backlash correction: the correction turns the
    approach over and back; compensate_extended refuses, naming the row and the joint that do not settle."""
    from dataclasses import replace

    _, truth, _, cal, _ = backlash_case
    q = H.configurations(np.random.default_rng(5), 4, truth["true"])
    q[1] = q[0]
    q[1, 1] += 2e-5
    T = np.linalg.inv(cal.base2meas["0"]) @ tool2meas(cal.model("0"), q)
    ctx = replace(row_context(H.make_dataset(seed=21, n=20)[0]), q=np.zeros((4, 6)), q_start=np.zeros(6),
                  temp_c=None, t_s=None)
    with pytest.raises(ValueError, match=r"did not settle in 30 rounds \(last step .* rad; still moving: row 1 joint \d"):
        compensate_extended(cal, T, q, ctx)


@pytest.mark.slow
def test_predict_command_applies_the_effects(backlash_case, tmp_path):
    """twin predict with an extended calibration.json gives the extended predictions (not the geometric ones)."""
    from twin.cli import main
    from twin.dataset import Joints, write_joints_csv
    from twin.estimator.files import write_pred_csv  # noqa: F401  (the format's writer, read back below)

    ds, _, _, cal, _ = backlash_case
    import json

    p = tmp_path / "cal.json"
    cal.save(p)
    write_joints_csv(tmp_path / "J.csv", Joints(pose_id=ds.pose_id, q=ds.q, station=ds.station_ids))
    assert main(["predict", str(p), str(tmp_path / "J.csv"), "--out", str(tmp_path / "P.csv")]) == 0
    import csv

    rows = list(csv.DictReader(open(tmp_path / "P.csv")))
    got = np.array([[float(r[f"p{s}_{c}"]) for s in range(3) for c in "xyz"] for r in rows]).reshape(-1, 3, 3) * 1e-3
    want = predict_extended(cal, row_context(ds), ds.station_ids).spheres
    assert np.abs(got - want).max() < 1e-8
    assert {e["family"] for e in json.loads(p.read_text())["effects"]} == {"backlash"}


def _bumped(seed=4):
    """A camera moved 27 um after 40 % of the campaign (a measurement-side change point, no catalogue term), inside
    the rows that fit the model (the held-out rows are the end of the campaign)."""
    from dataclasses import replace

    n = 160
    m = n + n // 4
    t = np.arange(m) * 10.0
    ds, _ = H.make_dataset(seed=seed, n=n, t_s=t, temp=np.full(m, 21.0))
    sph = ds.spheres.copy()
    sph[t >= 0.4 * t.max()] += np.array([15e-6, -10e-6, 20e-6])
    return replace(ds, spheres=sph)


@pytest.mark.slow
def test_unnamed_frame_term_is_predicted_from_the_rows_time(tmp_path):
    """The extended calibration of a camera bump has a change (a step in t_s) of the measurement frame and predicts
    every row to the noise from its t_s after reload (>= 9/10 seeds)."""
    out = []
    for seed in H.rate_seeds(range(4, 4 + 10)):
        ds = _bumped(seed)
        res = diagnose(ds)
        write_diagnosis(res, tmp_path / str(seed), plots=False)
        cal = Calibration.load(tmp_path / str(seed) / "calibration.json")
        e = np.linalg.norm(predict_extended(cal, row_context(ds), ds.station_ids).spheres - ds.spheres, axis=-1)
        out.append({"seed": seed, "step": any(c["target"] == "base" and c["kind"] == "step" and c["t_s"] is not None
                                              for c in res.changes),
                    "noise": float(np.sqrt(np.mean(e[ds.sphere_seen] ** 2))) < 1.3 * np.sqrt(3) * H.SIGMA})
    H.tally(out, step=(9, 10), noise=(9, 10))


def _alone_and_in_file(cal, ds, rows):
    """Predictions of ``rows`` each predicted alone and inside the whole file, as `twin predict` reads a JOINTS.csv
    (its t_s, temp_c, station and pose ids; the history restarting at the file's first row), and the rows the
    prediction alone flags as lacking their history."""
    from twin.dataset import Joints
    from twin.diagnosis.apply import history_unknown_rows
    from twin.diagnosis.floor import joints_context

    joints = Joints(pose_id=ds.pose_id, q=ds.q, temp_c=ds.temp_c, t_s=ds.t_s, station=ds.station_ids)

    def ctx(idx):
        return joints_context(joints, idx)

    every = np.arange(ds.n)
    full = predict_extended(cal, ctx(every), ds.station_ids).spheres[rows]
    alone = np.stack([predict_extended(cal, ctx(np.array([i])), ds.station_ids[[i]]).spheres[0] for i in rows])
    flagged = np.array([history_unknown_rows(cal, ctx(np.array([i])))[0] for i in rows])
    return alone, full, flagged


@pytest.mark.slow
def test_a_row_predicted_alone_reads_its_lagged_temperature_as_in_the_file():
    """Links growing with a temperature that lags the recorded one: every held-out row predicted alone equals its
    prediction inside the whole file (the lag continues the campaign's recorded temperatures by t_s); without
    that record it would not."""
    from dataclasses import replace

    from test_diagnosis_atoms import _lagged_own

    n = 120
    m = n + n // 4
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(10, 15, m))
    air = 20.0 + 4.0 * (1 - np.exp(-t / 1200.0)) + 0.05 * rng.standard_normal(m)
    ds, _ = H.make_dataset(seed=3, n=n, effect=("lengths", 40e-6 * (_lagged_own(air, t, 1500.0) - 20.0)), t_s=t,
                           temp=air)
    cal = diagnose(ds).calibration
    assert any(f["kind"] == "lag" for e in cal.effects for f in e["features"]), [e["label"] for e in cal.effects]
    rows = np.flatnonzero(ds.set == "validation")
    alone, full, flagged = _alone_and_in_file(cal, ds, rows)
    assert not flagged.any() and np.abs(alone - full).max() < 1e-12
    no_record = replace(cal, effects=tuple(dict(e, features=[{k: v for k, v in f.items() if k != "record"}
                                                             for f in e["features"]]) for e in cal.effects))
    a2, f2, _ = _alone_and_in_file(no_record, ds, rows)
    assert np.abs(a2 - f2).max() > 1e-6


@pytest.mark.slow
def test_a_drift_in_the_row_order_is_no_term_and_a_row_alone_says_it_lacks_its_approach():
    """A backlash and a drift in the row order (no t_s): no term in the row count is kept (it says nothing of the next
    session); a held-out row predicted alone equals its prediction inside the whole file except through the
    backlash, and every such row is flagged as lacking the history the backlash needs."""
    from dataclasses import replace

    ds, _ = H.make_dataset(seed=3, n=120, effect=H.backlash((0, 0.01, 0, 0, 0, 0)))
    sph = ds.spheres.copy()
    sph[:, :, 0] += (np.arange(ds.n) / ds.n * 30e-6)[:, None]
    ds = replace(ds, spheres=sph)
    cal = diagnose(ds).calibration
    fams = {f.get("ch") for e in cal.effects for f in e["features"]}
    assert "row" not in fams and any(e["family"] == "backlash" for e in cal.effects), [e["label"] for e in cal.effects]
    rows = np.flatnonzero(ds.set == "validation")
    alone, full, flagged = _alone_and_in_file(cal, ds, rows)
    assert flagged.all()
    no_backlash = replace(cal, effects=tuple(e for e in cal.effects if e["family"] != "backlash"))
    alone, full, flagged = _alone_and_in_file(no_backlash, ds, rows)
    assert not flagged.any() and np.abs(alone - full).max() < 1e-12


@pytest.mark.slow
def test_rows_without_t_s_or_after_the_campaign_hold_the_state_it_ended_in(tmp_path):
    """A term in t_s (a camera bump) on rows without t_s (a new session whose time is not recorded) or after the
    campaign reads the state the campaign ended in; a term without its recorded span (written before spans were
    recorded) still needs t_s: a named error, not a silent geometric answer."""
    from dataclasses import replace

    ds = _bumped()
    res = diagnose(ds)
    write_diagnosis(res, tmp_path, plots=False)
    cal = Calibration.load(tmp_path / "calibration.json")
    assert any(f.get("ch") == "t_s" for e in cal.effects for f in e["features"])
    ctx = row_context(ds)
    st = ds.station_ids

    def pred(t):
        return predict_extended(cal, replace(ctx, t_s=t), st).spheres

    at_end = pred(np.full(ds.n, ds.t_s.max()))
    np.testing.assert_allclose(pred(None), at_end, rtol=0, atol=1e-12)
    np.testing.assert_allclose(pred(ds.t_s + ds.t_s.max() + 1e5), at_end, rtol=0, atol=1e-12)
    assert np.abs(pred(np.full(ds.n, ds.t_s.min())) - at_end).max() > 5e-6  # the bump is in the model
    old = replace(cal, effects=tuple({**e, "features": [{k: v for k, v in f.items() if k != "t_span"}
                                                        for f in e["features"]]} for e in cal.effects))
    with pytest.raises(ValueError, match="'t_s'"):
        predict_extended(old, replace(ctx, t_s=None), st)


def test_joints_context_reads_a_subset_as_a_file_of_its_own():
    """A JOINTS.csv's rows read as `twin predict` reads them: a subset's first row and every session change have an
    unknown history, the channels are the subset's own rows in order."""
    from twin.dataset import Joints
    from twin.diagnosis.floor import joints_context

    j = Joints(pose_id=np.arange(6), q=np.arange(36.0).reshape(6, 6), temp_c=np.linspace(20, 25, 6),
               t_s=np.arange(6) * 10.0, session=np.array(["a", "a", "a", "b", "b", "b"]))
    ctx = joints_context(j)
    assert ctx.history_reset.tolist() == [True, False, False, True, False, False]
    sub = joints_context(j, np.array([4, 5]))
    assert sub.history_reset.tolist() == [True, False]
    assert sub.t_s.tolist() == [40.0, 50.0] and sub.pose_id.tolist() == [4, 5] and sub.q[0, 0] == 24.0
    assert sub.station is None


def test_a_drift_goes_on_while_the_campaign_continues_and_holds_in_another_session():
    """A linear drift in t_s fitted on 0-1000 s: rows up to one campaign's length after its end continue the drift,
    rows further away (another session) and rows without t_s hold the state at its end."""
    from dataclasses import replace

    from twin.diagnosis.values import feature_values
    from twin.diagnosis.candidates import RowContext
    from twin.diagnosis.features import feature_from_dict
    from twin.robots import irb1200

    f = feature_from_dict({"kind": "pow", "ch": "t_s", "p": 1, "c": 500.0, "h": 500.0, "t_span": [0.0, 1000.0]})
    ctx = RowContext(q=np.zeros((4, 6)), t_s=np.array([500.0, 1500.0, 1999.0, 2500.0]))
    v = feature_values((f,), ctx, irb1200())[:, 0]
    assert v.tolist() == pytest.approx([0.0, 2.0, 2.998, 1.0])
    assert feature_values((f,), replace(ctx, t_s=None), irb1200())[:, 0].tolist() == pytest.approx([1.0] * 4)


def test_each_term_says_which_state_it_reads_on_report_later_and_new_session_rows():
    """term_state: a change reads the state after it (before it once it ended) after the campaign and in a new
    session, a lag of the temperature is carried from the campaign's last row or settled without t_s, the approach
    history starts anew in a new session, a function of the joints has no state."""
    from twin.diagnosis.apply import STATE_BLOCKS, term_state
    from twin.diagnosis.atoms import Atom
    from twin.diagnosis.features import Const, Exp, Lag, Pow, Sign, Step, Window

    def atom(f, place="joint", target="theta2"):
        return Atom("change", place, target, (f,), "", "a term", "catalogue")

    step, win = atom(Step(ch="t_s", at=100.0)), atom(Window(ch="t_s", at=100.0, until=200.0))
    assert "after the change" in term_state(step, "rows_after_the_campaign")
    assert "after the change" in term_state(step, "new_session")
    assert "before the change" in term_state(win, "rows_after_the_campaign")
    lag = atom(Lag(ch="temp_c", tau=300.0, c=20.0, h=1.0), "length", "all_lengths")
    assert "last row" in term_state(lag, "rows_after_the_campaign") and "settled" in term_state(lag, "new_session")
    assert "new history" in term_state(atom(Sign(j=2)), "new_session")
    settling = Atom("unnamed", "scale", "meas_scale", (Const(), Exp(ch="t_s", t0=0.0, tau=800.0)), "", "a term", "generic")
    assert "ended in" in term_state(settling, "new_session")  # the state is the feature's that has one
    assert all(term_state(atom(Pow(ch="q2", p=1, c=0.0, h=1.0)), b) is None for b in STATE_BLOCKS)
    with pytest.raises(ValueError, match="block"):
        term_state(step, "later")
