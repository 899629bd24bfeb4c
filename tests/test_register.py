"""Tests of twin.estimator.register and `twin register`: a calibrated robot's measurement frame (and tool)
re-identified from a few rows of a new session, the robot model held."""

import re
from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

import _diagnosis_helpers as H
from _estimator_helpers import random_truth, regauge_frames
from twin.dataset import Plate, write_dataset
from twin.estimator import Calibration, calibrate, random_configurations, simulate_dataset
from twin.estimator.register import prediction_errors, register, select_rows
from twin.robots import get_robot
from twin.transforms import invert_transform, pose6_to_transform, transform_to_pose6

SIGMA = 1e-5  # [m] per coordinate
SIGMA_O = 1e-4  # [rad] per rotation-vector component
B_CAL = pose6_to_transform(np.array([0.05, 0.1, 1.0, 2.6, 0.3, -0.2]))
# the new station: some 400 mm and 35 degrees away from the calibration's
B_NEW = pose6_to_transform(np.array([0.3, -0.2, 1.25, 2.1, -0.2, 0.35]))
CHI2_6 = stats.chi2.ppf(0.999, 6)


def _mahalanobis(cal: Calibration, names, x_true) -> float:
    """``e^T C^-1 e`` of the parameters ``names`` of ``cal`` against ``x_true`` (SI), with the calibration's
    covariance: within the noise when below the chi-square quantile."""
    k = [cal.space.index(n) for n in names]
    e = cal.x[k] - np.asarray(x_true)
    return float(e @ np.linalg.solve(cal.covariance[np.ix_(k, k)], e))


def _other(ds, rows):
    return np.setdiff1d(np.arange(ds.n), rows)


@pytest.fixture(scope="module")
def spheres_case():
    """A robot with geometric errors calibrated on station '0'; 200 rows of a new session on station '1'."""
    rng = np.random.default_rng(7)
    nom = get_robot("irb1200")
    truth = random_truth("irb1200", rng)
    q = random_configurations(nom, 100, rng)
    ds, _ = simulate_dataset(truth, q, robot_spec="irb1200", base2meas={"0": B_CAL}, noise_position=SIGMA, rng=rng)
    cal = calibrate(ds)
    q2 = random_configurations(nom, 200, rng)
    ds2, _ = simulate_dataset(truth, q2, robot_spec="irb1200", base2meas={"1": B_NEW}, station=np.full(200, "1"),
                              noise_position=SIGMA, rng=rng)
    _, bases = regauge_frames(truth, nom, {"1": B_NEW})
    return cal, ds2, bases["1"]


@pytest.mark.parametrize("n", [10, 50])
def test_new_base_is_recovered_within_its_noise(spheres_case, n):
    """From the first 10 / 50 rows of the new station, the registered base2meas differs from the true one (in the
    calibration's gauge) by no more than its covariance says (chi-square, 6 dof, 99.9 %), and the move is large."""
    cal, ds2, B_true = spheres_case
    reg = register(cal, ds2, select_rows(ds2, first=n))
    new = reg.calibration
    assert reg.stations == ("1",) and new.stations == ("0", "1") and reg.converged
    names = [f"base_{c}@1" for c in ("x", "y", "z", "rx", "ry", "rz")]
    assert _mahalanobis(new, names, transform_to_pose6(B_true)) < CHI2_6
    assert np.linalg.norm(new.base2meas["1"][:3, 3] - cal.base2meas["0"][:3, 3]) > 0.3
    # the robot model and the calibration's own station are untouched
    assert np.array_equal(new.x[: cal.space.n_rt], cal.x[: cal.space.n_rt])
    assert np.array_equal(new.base2meas["0"], cal.base2meas["0"])


@pytest.mark.parametrize("n", [10, 50])
def test_prediction_of_the_other_rows_equals_the_true_bases_within_the_noise(spheres_case, n):
    """On the rows not used, the RMS error with the registered base2meas differs from the RMS error with the true
    one by less than the noise sigma, and both are at the noise level (3-D: sqrt(3) sigma)."""
    cal, ds2, B_true = spheres_case
    rows = select_rows(ds2, first=n)
    new = register(cal, ds2, rows).calibration
    x = new.x.copy()
    x[new.space.base_slice(1)] = transform_to_pose6(B_true)
    e_reg = prediction_errors(new, ds2, _other(ds2, rows))["position_mm"]["rms"]
    e_true = prediction_errors(replace(new, x=x), ds2, _other(ds2, rows))["position_mm"]["rms"]
    assert abs(e_reg - e_true) < SIGMA / 1e-3
    assert e_reg < 1.3 * np.sqrt(3) * SIGMA / 1e-3


def test_jacobian_through_a_prediction_function_matches_the_analytic_one(spheres_case):
    """Registering through a prediction function (central differences) gives the analytic path's estimate and
    covariance: the finite-difference Jacobian equals the estimator's analytic one."""
    cal, ds2, _ = spheres_case
    rows = select_rows(ds2, first=20)
    a = register(cal, ds2, rows, tool=True)
    b = register(cal, ds2, rows, tool=True, predict=lambda c, idx: c.predict(ds2.q[idx], ds2.station_ids[idx]))
    assert np.abs(a.calibration.x - b.calibration.x).max() < 1e-10
    assert np.allclose(b.calibration.covariance, a.calibration.covariance, rtol=1e-5, atol=1e-20)


def test_rows_of_two_stations_register_both(spheres_case):
    """Rows of two new stations register each station's base2meas (within its noise); the calibration's station
    is kept; a station of the same name as the calibration's is replaced, not added."""
    cal, _, _ = spheres_case
    rng = np.random.default_rng(11)
    nom = get_robot("irb1200")
    truth = random_truth("irb1200", np.random.default_rng(7))  # the spheres_case robot (same draw)
    B2 = pose6_to_transform(np.array([-0.2, 0.4, 0.9, 1.0, 1.2, -0.5]))
    st = np.array(["0", "2"] * 30, dtype=object)
    ds, _ = simulate_dataset(truth, random_configurations(nom, 60, rng), robot_spec="irb1200",
                             base2meas={"0": B_NEW, "2": B2}, station=st, noise_position=SIGMA, rng=rng)
    new = register(cal, ds, np.arange(60)).calibration
    assert new.stations == ("0", "2")
    _, bases = regauge_frames(truth, nom, {"0": B_NEW, "2": B2})
    for s in ("0", "2"):
        names = [f"base_{c}@{s}" for c in ("x", "y", "z", "rx", "ry", "rz")]
        assert _mahalanobis(new, names, transform_to_pose6(bases[s])) < CHI2_6


@pytest.fixture(scope="module")
def pose_case():
    """6-DOF pose data: calibrated on station '0'; the new session on station '1' with another tool mounted."""
    rng = np.random.default_rng(17)
    nom = get_robot("irb1200")
    truth = random_truth("irb1200", rng)
    kw = dict(robot_spec="irb1200", kind="pose", noise_position=SIGMA, noise_orientation=SIGMA_O)
    ds, _ = simulate_dataset(truth, random_configurations(nom, 100, rng), base2meas={"0": B_CAL}, rng=rng, **kw)
    cal = calibrate(ds)
    # the new tool: 3-6 mm and 3-5 degrees off the old one
    T2 = truth.tool2flange @ pose6_to_transform(np.array([0.004, -0.003, 0.006, 0.05, -0.08, 0.06]))
    truth2 = truth.with_frames(tool2flange=T2)
    ds2, _ = simulate_dataset(truth2, random_configurations(nom, 150, rng), base2meas={"1": B_NEW},
                              station=np.full(150, "1"), rng=rng, **kw)
    robot2, bases = regauge_frames(truth2, nom, {"1": B_NEW})
    return cal, ds2, bases["1"], robot2.tool2flange


def test_changed_tool_is_recovered_with_tool(pose_case):
    """With tool=True, 50 pose rows recover the new station's base2meas and the changed tool2flange within their
    noise (chi-square, 12 dof); the other rows are then predicted at the noise level (position and orientation)."""
    cal, ds2, B_true, T_true = pose_case
    rows = select_rows(ds2, first=50)
    new = register(cal, ds2, rows, tool=True).calibration
    names = ["tool_x", "tool_y", "tool_z", "tool_rx", "tool_ry", "tool_rz"] + [
        f"base_{c}@1" for c in ("x", "y", "z", "rx", "ry", "rz")]
    truth = np.r_[transform_to_pose6(T_true), transform_to_pose6(B_true)]
    assert _mahalanobis(new, names, truth) < stats.chi2.ppf(0.999, 12)
    err = prediction_errors(new, ds2, _other(ds2, rows))
    assert err["position_mm"]["rms"] < 1.3 * np.sqrt(3) * SIGMA / 1e-3
    assert err["orientation_deg"]["rms"] < 1.3 * np.degrees(np.sqrt(3) * SIGMA_O)


def test_changed_tool_is_not_absorbed_without_tool(pose_case):
    """Without tool=True the old tool is held: the same rows leave the other rows' error far above the noise (the
    option matters when the tool was changed)."""
    cal, ds2, _, _ = pose_case
    rows = select_rows(ds2, first=50)
    err = prediction_errors(register(cal, ds2, rows).calibration, ds2, _other(ds2, rows))
    assert err["position_mm"]["rms"] > 10 * np.sqrt(3) * SIGMA / 1e-3


# ---- an extended calibration (a backlash term from twin.diagnosis) ---------------------------------------------

@pytest.fixture(scope="module")
def backlash_case():
    """An IRB-1200 with backlash: the extended calibration fitted by twin.diagnosis on one session; a new session
    (history starting anew) at another base2meas."""
    from twin.diagnosis import fit_with_effects, row_context
    from twin.diagnosis.apply import history_unknown_rows, predict_extended

    ds, truth = H.make_dataset(seed=21, n=120, effect=H.backlash())
    ext = fit_with_effects(ds, ["backlash"]).calibration
    assert {e["family"] for e in ext.effects} == {"backlash"}
    true = truth["true"]
    rng = np.random.default_rng(5)
    q = H.configurations(rng, 160, true)
    ds2, _ = simulate_dataset(true.with_frames(base2meas=B_NEW), H.backlash()(q, None), robot_spec="irb1200",
                              nominal=get_robot("irb1200"), noise_position=H.SIGMA, rng=rng)
    ds2 = replace(ds2, q=q)  # the controller was told q; the robot stood at q + backlash
    ctx = row_context(ds2)

    def predict(c, idx):
        p = predict_extended(c, ctx, ds2.station_ids)
        return replace(p, spheres=p.spheres[idx], pose=p.pose[idx], frame=p.frame[idx], station=p.station[idx],
                       sd_spheres=None, sd_pose=None)

    # the first row's approach is unknown to the model (a new session): leave it out of the comparison
    known = np.flatnonzero(~history_unknown_rows(ext, ctx))
    # the true new base in the calibration's gauge: the same gauge change as the calibration's own station
    B_true = B_NEW @ invert_transform(true.base2meas) @ ext.base2meas["0"]
    return ext, ds2, predict, known, B_true


@pytest.mark.parametrize("n", [10, 50])
def test_extended_calibration_is_registered_with_its_effects(backlash_case, n):
    """An extended calibration registered on 10 / 50 rows of the new session predicts the others as well as with
    the true base2meas (within the noise sigma) and at the noise level; registering its geometry alone leaves
    the backlash: at least 5x the error."""
    ext, ds2, predict, known, B_true = backlash_case
    rows, others = known[:n], known[n:]
    new = register(ext, ds2, rows, predict=predict).calibration
    assert new.effects == ext.effects
    x = new.x.copy()
    x[new.space.base_slice(0)] = transform_to_pose6(B_true)
    e_reg = prediction_errors(new, ds2, others, predict=predict)["position_mm"]["rms"]
    e_true = prediction_errors(replace(new, x=x), ds2, others, predict=predict)["position_mm"]["rms"]
    assert abs(e_reg - e_true) < H.SIGMA / 1e-3
    assert e_reg < 2 * np.sqrt(3) * H.SIGMA / 1e-3
    geo = register(replace(ext, effects=()), ds2, rows).calibration
    assert prediction_errors(geo, ds2, others)["position_mm"]["rms"] > 5 * e_reg


def test_extended_calibration_without_its_prediction_is_refused(backlash_case):
    """An extended calibration cannot be registered (or scored) with the geometric model alone: ValueError."""
    ext, ds2, _, known, _ = backlash_case
    with pytest.raises(ValueError, match="has effects"):
        register(ext, ds2, known[:10])
    with pytest.raises(ValueError, match="has effects"):
        prediction_errors(ext, ds2, known[:10])


# ---- judged on the new session: the extended model only where it predicts the session's rows better ------------

@pytest.fixture(scope="module")
def judged_case():
    """A backlash calibrated in one session (the extended model and the geometric one it extends); two new
    sessions at another base2meas: one where the backlash persists, one where it is gone (the joint repaired)."""
    from twin.diagnosis import fit_with_effects

    ds, truth = H.make_dataset(seed=21, n=120, effect=H.backlash())
    fit = fit_with_effects(ds, ["backlash"])
    true = truth["true"].with_frames(base2meas=B_NEW)
    rng = np.random.default_rng(11)
    q = H.configurations(rng, 120, truth["true"])
    kept, _ = simulate_dataset(true, H.backlash()(q, None), robot_spec="irb1200", nominal=get_robot("irb1200"),
                               noise_position=H.SIGMA, rng=rng)
    gone, _ = simulate_dataset(true, q, robot_spec="irb1200", nominal=get_robot("irb1200"), noise_position=H.SIGMA,
                               rng=rng)
    return fit.calibration_geometric, fit.calibration, replace(kept, q=q), gone


def _backlash_joints(cal) -> set[int]:
    return {int(e["target"][5:]) for e in cal.effects if e["family"] == "backlash"}


def test_the_extended_model_is_chosen_where_its_effect_persists(judged_case):
    """In a session where the backlash persists, the extended model (pruned or not) predicts the registration
    rows' blocks better than the geometric one (by more than 3x) and is chosen with the backlash of joints 2, 3
    and 5, the joints that have it."""
    from twin.diagnosis.apply import choose_for_session

    geo, ext, kept, _ = judged_case
    c = choose_for_session({"geometric": geo, "extended": ext}, kept, np.arange(1, 41))
    assert c.chosen in ("extended", "extended (pruned)")
    assert {2, 3, 5} <= _backlash_joints(c.candidates[c.chosen])
    assert c.cv_position_rms_mm["geometric"] > 3 * c.cv_position_rms_mm[c.chosen]
    assert len(c.folds) == 5 and sum(f.size for f in c.folds) == 40


def test_the_backlash_is_dropped_where_it_is_gone(judged_case):
    """In a session without the backlash, a model without it (the geometric one, or the extended one pruned of
    the backlash of joints 2, 3 and 5) predicts the registration rows better and is chosen; on the session's other rows it is indeed
    better than the extended model."""
    from twin.diagnosis.apply import choose_for_session, dataset_predictor

    geo, ext, _, gone = judged_case
    rows = np.arange(1, 41)
    c = choose_for_session({"geometric": geo, "extended": ext}, gone, rows)
    assert c.chosen in ("geometric", "extended (pruned)")
    assert not {2, 3, 5} & _backlash_joints(c.candidates[c.chosen])
    others = np.arange(41, gone.n)
    pred = dataset_predictor(gone)
    e_chosen = prediction_errors(c.registered[c.chosen], gone, others, predict=pred)["position_mm"]["rms"]
    e_ext = prediction_errors(c.registered["extended"], gone, others, predict=pred)["position_mm"]["rms"]
    assert e_chosen < e_ext


@pytest.fixture(scope="module")
def two_effects_case():
    """Backlash and gear-ratio errors calibrated in one session (every joint's backlash and gear-ratio term); a new
    session at another base2meas where the gear ratios persist and the backlash is gone."""
    from twin.diagnosis import fit_with_effects

    bl, gr = H.backlash(), H.gear_ratio()
    ds, truth = H.make_dataset(seed=21, n=160, effect=lambda q, m: gr(bl(q, m), m))
    ext = fit_with_effects(ds, ["backlash", "gear_ratio"]).calibration
    true = truth["true"].with_frames(base2meas=B_NEW)
    rng = np.random.default_rng(12)
    q = H.configurations(rng, 160, truth["true"])
    ds2, _ = simulate_dataset(true, gr(q, None), robot_spec="irb1200", nominal=get_robot("irb1200"),
                              noise_position=H.SIGMA, rng=rng)
    return ext, replace(ds2, q=q)


def test_pruning_drops_the_terms_a_session_lacks_and_keeps_those_it_has(two_effects_case):
    """prune_for_session on 40 rows of the new session drops the backlash of joints 2, 3 and 5 (gone) and keeps
    their gear-ratio terms (still there), significantly (z >= 3 row by row); the pruned model predicts the session's
    other rows at least 3x better than the whole one, and its linearised score falls at every step of the trace."""
    from twin.diagnosis.apply import dataset_predictor, prune_for_session

    ext, ds2 = two_effects_case
    rows = np.arange(1, 41)
    pruned, dropped, trace, z = prune_for_session(ext, ds2, rows)
    assert z >= 3
    for j in (2, 3, 5):
        assert any(lbl.startswith(f"joint {j} backlash") for lbl in dropped), dropped
        assert any(e["label"].startswith(f"joint {j} gear-ratio") for e in pruned.effects), dropped
    assert [s for _, s in trace] == sorted((s for _, s in trace), reverse=True) and trace[0][0] is None
    pred = dataset_predictor(ds2)
    others = np.arange(41, ds2.n)
    e = {k: prediction_errors(register(c, ds2, rows, predict=pred).calibration, ds2, others, predict=pred)
         ["position_mm"]["rms"] for k, c in (("whole", ext), ("pruned", pruned))}
    assert e["whole"] > 3 * e["pruned"], e


def test_drops_that_are_not_significant_are_not_kept(two_effects_case):
    """The same backward pass with a threshold it cannot reach keeps every term (and reports the pass in its trace);
    with no threshold it drops them."""
    from twin.diagnosis.apply import prune_for_session

    ext, ds2 = two_effects_case
    rows = np.arange(1, 41)
    pruned, dropped, trace, z = prune_for_session(ext, ds2, rows, z_min=np.inf)
    assert dropped == () and pruned.effects == ext.effects and len(trace) > 1 and np.isfinite(z)
    assert prune_for_session(ext, ds2, rows, z_min=-np.inf)[1] == tuple(lbl for lbl, _ in trace[1:])


def test_pruning_scores_match_the_exact_blocked_registrations(two_effects_case):
    """Each step of the linearised backward pass scores the model without the terms dropped so far as the exact
    blocked registrations do (choose_for_session without pruning), within 1 %."""
    from twin.diagnosis.apply import choose_for_session, prune_for_session

    ext, ds2 = two_effects_case
    rows = np.arange(1, 41)
    _, dropped, trace, _ = prune_for_session(ext, ds2, rows)
    for k, (_, lin) in enumerate(trace):
        gone = set(dropped[:k])
        cal = replace(ext, effects=tuple(e for e in ext.effects if e["label"] not in gone))
        exact = choose_for_session({"model": cal}, ds2, rows, prune=False).cv_position_rms_mm["model"]
        assert lin == pytest.approx(exact, rel=0.01), (k, dropped[:k])


@pytest.mark.parametrize("bad,match", [
    (dict(models={}), "models must be a non-empty dict"),
    (dict(folds=1), "folds must be an integer >= 2"),
    (dict(rows=np.arange(3)), "3 row\\(s\\) cannot make 5 folds"),
])
def test_a_session_choice_refuses_bad_input_naming_it(judged_case, bad, match):
    """No models, one fold, or fewer rows than folds: ValueError naming the argument (choose_for_session, and
    prune_for_session for the last two)."""
    from twin.diagnosis.apply import choose_for_session, prune_for_session

    geo, ext, kept, _ = judged_case
    kw = dict(models={"geometric": geo, "extended": ext}, rows=np.arange(1, 41))
    kw.update(bad)
    with pytest.raises(ValueError, match=match):
        choose_for_session(kw.pop("models"), kept, kw.pop("rows"), **kw)
    if "models" not in bad:
        kw = dict(rows=np.arange(1, 41))
        kw.update(bad)
        with pytest.raises(ValueError, match=match):
            prune_for_session(ext, kept, kw.pop("rows"), **kw)


def test_command_judges_an_extended_calibration_against_the_geometric_one_beside_it(judged_case, tmp_path, capsys):
    """`twin register DIAG/calibration.json` judges it against DIAG/calibration_geometric.json on the session's rows:
    where the effect is gone it writes a model without it registered (and says so); --no-judge writes the extended
    one."""
    from twin.cli import main

    geo, ext, _, gone = judged_case
    diag = tmp_path / "diag"
    ext.save(diag / "calibration.json")
    geo.save(diag / "calibration_geometric.json")
    write_dataset(tmp_path / "new", gone)
    assert main(["register", str(diag / "calibration.json"), str(tmp_path / "new"), "--first", "40",
                 "--out", str(tmp_path / "reg.json")]) == 0
    out = capsys.readouterr().out
    assert "model is used" in out and "the extended model is used" not in out
    reg = Calibration.load(tmp_path / "reg.json")
    assert not {2, 3, 5} & _backlash_joints(reg)
    assert reg.details["session_choice"]["chosen"] in ("geometric", "extended (pruned)")
    assert main(["register", str(diag / "calibration.json"), str(tmp_path / "new"), "--first", "40", "--no-judge",
                 "--out", str(tmp_path / "reg2.json")]) == 0
    assert "judged" not in capsys.readouterr().out
    assert Calibration.load(tmp_path / "reg2.json").effects == Calibration.load(diag / "calibration.json").effects


def test_command_against_with_too_few_rows_names_the_option(judged_case, tmp_path, capsys):
    """--against with fewer registration rows than blocks is refused naming --against and the rows; nothing is
    written."""
    from twin.cli import main

    geo, ext, _, gone = judged_case
    ext.save(tmp_path / "ext.json")
    geo.save(tmp_path / "geo.json")
    write_dataset(tmp_path / "new", gone)
    assert main(["register", str(tmp_path / "ext.json"), str(tmp_path / "new"), "--first", "3", "--against",
                 str(tmp_path / "geo.json"), "--out", str(tmp_path / "reg.json")]) != 0
    assert re.search(r"--against \S*geo.json: --first 3 less 1 row\(s\) without the history a term needs: rows: 2 "
                     r"row\(s\) cannot make 5 folds", capsys.readouterr().err)
    assert not (tmp_path / "reg.json").exists()


# ---- bad input -------------------------------------------------------------------------------------------------

def test_session_residuals_are_the_registration_residuals_and_refuse_bad_input(spheres_case):
    """session_residuals of a registered calibration on its rows give the registration's residual RMS (its
    position components, whitened by the noise); a dataset that is not one, or an extended calibration without its
    prediction, is refused naming it."""
    from twin.estimator.register import session_residuals

    cal, ds2, _ = spheres_case
    rows = select_rows(ds2, first=30)
    reg = register(cal, ds2, rows)
    r, row, pos, sigma = session_residuals(reg.calibration, ds2, rows)
    assert pos.all() and set(row.tolist()) == set(range(30))
    rms_mm = np.sqrt(np.sum(r ** 2) / (r.size / 3)) * sigma / 1e-3  # RMS of the 3-D distance per marker point
    assert rms_mm == pytest.approx(reg.residuals["position_mm"]["rms"], rel=1e-6)
    with pytest.raises(ValueError, match="dataset must be"):
        session_residuals(cal, "not a dataset", rows)


def test_too_few_rows_for_the_parameters_are_refused(spheres_case):
    """One row of three points (9 coordinates) cannot give base and tool (12 parameters): the error says so."""
    cal, ds2, _ = spheres_case
    with pytest.raises(ValueError, match="fewer than the 12 parameters"):
        register(cal, ds2, [0], tool=True)


def test_rows_at_one_configuration_cannot_give_the_tool(spheres_case):
    """Rows all at one joint configuration give the base but not base and tool apart: tool=True names what the
    rows cannot determine."""
    cal, ds2, _ = spheres_case
    same = replace(ds2, q=np.repeat(ds2.q[:1], ds2.n, axis=0))
    with pytest.raises(ValueError, match="cannot determine"):
        register(cal, same, np.arange(5), tool=True)


def test_tool_rotation_from_single_points_is_refused():
    """With one marker point per row the tool's rotation has no effect: tool=True names what cannot be determined."""
    rng = np.random.default_rng(3)
    nom = get_robot("irb1200")
    truth = random_truth("irb1200", rng)
    plate = Plate(0.0, np.array([[0.0, 0.0, 0.05]]))
    kw = dict(robot_spec="irb1200", plate=plate, noise_position=SIGMA)
    ds, _ = simulate_dataset(truth, random_configurations(nom, 80, rng), base2meas={"0": B_CAL}, rng=rng, **kw)
    cal = calibrate(ds)
    with pytest.raises(ValueError, match="cannot determine tool_r"):
        register(cal, ds, np.arange(30), tool=True)


@pytest.mark.parametrize("kw, match", [
    (dict(first=500), "first 500: the dataset has only 200 measured rows"),
    (dict(first=0), "first must be a positive integer"),
    (dict(first=5, station="7"), "station '7' is not in the dataset"),
    (dict(first=5, session="B"), "no 'session' column"),
    (dict(pose_ids=[3, 4, 9999]), "not in the dataset: \\[9999\\]"),
    (dict(set_="calibration"), "no 'set' column"),
])
def test_bad_row_selections_are_refused(spheres_case, kw, match):
    """A selection the dataset cannot give is refused naming the argument and its value."""
    _, ds2, _ = spheres_case
    with pytest.raises(ValueError, match=match):
        select_rows(ds2, **kw)


def test_dataset_of_another_robot_is_refused(spheres_case):
    """A dataset of another robot cannot be registered to the calibration: the error names both robots."""
    cal, _, _ = spheres_case
    other = get_robot("brtirus0707a")
    ds, _ = simulate_dataset(other, random_configurations(other, 20, np.random.default_rng(0)),
                             robot_spec="brtirus0707a", noise_position=SIGMA)
    with pytest.raises(ValueError, match="not the calibration's robot"):
        register(cal, ds, np.arange(20))


def test_a_marker_set_placed_elsewhere_on_the_flange_registers_and_another_shape_is_refused(spheres_case):
    """A session whose import placed the same markers 2 mm off on the flange (a fit with the nominal robot) registers
    with the calibration's markers; a marker set of another shape is refused naming the distance that differs."""
    cal, ds2, B = spheres_case
    moved = replace(ds2, plate=Plate(ds2.plate.sphere_diameter, ds2.plate.spheres_flange + [0.002, -0.001, 0.0015]))
    reg = register(cal, moved, np.arange(30))
    assert np.abs(reg.calibration.base2meas["1"][:3, 3] - B[:3, 3]).max() < 1e-4
    other = ds2.plate.spheres_flange.copy()
    other[2] += [0.01, 0.0, 0.0]
    with pytest.raises(ValueError, match=r"marker set differs from the calibration's \(distance p\d-p2 "):
        register(cal, replace(ds2, plate=Plate(ds2.plate.sphere_diameter, other)), np.arange(30))


# ---- the command -----------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def cli_case(spheres_case, tmp_path_factory):
    cal, ds2, _ = spheres_case
    d = tmp_path_factory.mktemp("register")
    cal.save(d / "cal.json")
    write_dataset(d / "new", ds2)
    return d


def test_command_registers_and_predict_uses_the_new_frame(cli_case, capsys):
    """`twin register --first 20` writes a calibration whose base2meas of the new station makes `twin predict`
    reproduce the other rows' measurements at the noise level; it prints the residual on the rows used and the
    error on the others, and records the rows in its details."""
    from twin.cli import main
    from twin.dataset import Joints, read_dataset, write_joints_csv
    from twin.estimator.files import read_pred_csv

    d = cli_case
    assert main(["register", str(d / "cal.json"), str(d / "new"), "--first", "20", "--out", str(d / "reg.json")]) == 0
    out = capsys.readouterr().out
    assert "residual on the rows used (20 rows" in out and "error on the measured rows not used (180 rows" in out
    new = Calibration.load(d / "reg.json")
    info = new.details["registration"]
    assert info["rows"] == list(range(20)) and info["stations"] == ["1"] and info["tool"] is False
    ds2 = read_dataset(d / "new")
    others = np.arange(20, ds2.n)
    write_joints_csv(d / "J.csv", Joints(pose_id=ds2.pose_id[others], q=ds2.q[others], station=ds2.station_ids[others]))
    assert main(["predict", str(d / "reg.json"), str(d / "J.csv"), "--out", str(d / "P.csv")]) == 0
    pred = read_pred_csv(d / "P.csv")
    assert set(pred["frame"]) == {"measurement"}
    e = np.linalg.norm(pred["spheres"] - ds2.spheres[others], axis=-1)
    assert np.sqrt(np.mean(e**2)) < 1.3 * np.sqrt(3) * SIGMA


@pytest.mark.parametrize("extra, match", [
    (["--first", "0"], "--first 0: first must be a positive integer"),
    (["--first", "5", "--station", "9"], "--first 5 --station 9: station '9' is not in the dataset"),
    (["--pose-ids", "IDS"], "--pose-ids .*not in the dataset: \\[12345\\]"),
    (["--first", "1", "--tool"], "--first 1: rows: 1 row\\(s\\) give 9 marker coordinates, fewer than the 12"),
    (["--first", "5", "--out-is-input"], "is the input calibration"),
])
def test_command_errors_name_the_argument(cli_case, capsys, extra, match):
    """Bad arguments exit 2 with a message naming the argument and its value, and write nothing."""
    import re

    from twin.cli import main

    d = cli_case
    (d / "IDS").write_text("pose_id\n3\n12345\n")
    out = d / "bad.json"
    args = [a.replace("IDS", str(d / "IDS")) for a in extra if a != "--out-is-input"]
    args += ["--out", str(d / "cal.json") if "--out-is-input" in extra else str(out)]
    assert main(["register", str(d / "cal.json"), str(d / "new"), *args]) == 2
    err = capsys.readouterr().err
    assert re.search(match, err), err
    assert not out.exists()


def test_command_registers_one_session_of_a_two_session_dataset(spheres_case, tmp_path, capsys):
    """In a dataset holding the calibration's session 'A' and a new session 'B' (same station name, the instrument
    moved), `--session B --first 20` registers on B's rows, scores B's other rows at the noise level, and leaves
    A's rows out of the score."""
    from twin.cli import main
    from twin.dataset import Dataset

    cal, ds2, _ = spheres_case
    rng = np.random.default_rng(23)
    nom = get_robot("irb1200")
    truth = random_truth("irb1200", np.random.default_rng(7))  # the spheres_case robot (same draw)
    kw = dict(robot_spec="irb1200", noise_position=SIGMA, rng=rng)
    a, _ = simulate_dataset(truth, random_configurations(nom, 30, rng), base2meas={"0": B_CAL}, **kw)
    b, _ = simulate_dataset(truth, random_configurations(nom, 60, rng), base2meas={"0": B_NEW}, **kw)
    both = Dataset(robot=a.robot, robot_spec=a.robot_spec, plate=a.plate, pose_id=np.arange(90),
                   q=np.concatenate([a.q, b.q]), spheres=np.concatenate([a.spheres, b.spheres]),
                   sphere_seen=np.concatenate([a.sphere_seen, b.sphere_seen]), pose=np.concatenate([a.pose, b.pose]),
                   pose_seen=np.concatenate([a.pose_seen, b.pose_seen]), noise_position=SIGMA,
                   extra={"session": np.array(["A"] * 30 + ["B"] * 60, dtype=object)})
    cal.save(tmp_path / "cal.json")
    write_dataset(tmp_path / "both", both)
    assert main(["register", str(tmp_path / "cal.json"), str(tmp_path / "both"), "--session", "B", "--first", "20",
                 "--out", str(tmp_path / "reg.json")]) == 0
    out = capsys.readouterr().out
    assert "of session 'B'" in out and "30 measured row(s) of other station(s) or session(s) not evaluated" in out
    line = next(ln for ln in out.splitlines() if ln.startswith("error on the measured rows not used"))
    assert "(40 rows" in line and float(line.split("rms ")[1].split(" ")[0]) < 1.3 * np.sqrt(3) * SIGMA / 1e-3
    info = Calibration.load(tmp_path / "reg.json").details["registration"]
    assert info["session"] == ["B"] and info["rows"] == list(range(30, 50))


def test_command_registers_an_extended_calibration(backlash_case, tmp_path, capsys):
    """`twin register` applies an extended calibration's effects: the error on the rows not used is at the noise
    level, and the written calibration keeps its effects."""
    from twin.cli import main

    ext, ds2, _, _, _ = backlash_case
    ext.save(tmp_path / "ext.json")
    write_dataset(tmp_path / "new", ds2)
    assert main(["register", str(tmp_path / "ext.json"), str(tmp_path / "new"), "--first", "30",
                 "--out", str(tmp_path / "reg.json")]) == 0
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.startswith("error on the measured rows not used"))
    rms = float(line.split("rms ")[1].split(" ")[0])
    assert rms < 2 * np.sqrt(3) * H.SIGMA / 1e-3
    assert Calibration.load(tmp_path / "reg.json").effects == Calibration.load(tmp_path / "ext.json").effects
