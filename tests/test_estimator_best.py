"""The default estimator ('best'): exact recovery, honest covariance, robustness, noise estimation, bad data."""

from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from twin.robots import get_robot
from twin.transforms import pose6_to_transform
from twin.estimator.methods import calibrate
from twin.estimator.simulate import random_configurations, simulate_dataset

from _estimator_helpers import camera_base, random_truth, regauge_frames

MM = 1e-3


def _truth_and_data(robot, kind, rng, *, n_cal=60, n_val=20, stations=1, noise=(0.0, 0.0), declare=True, q=None):
    truth = random_truth(robot, rng)
    truth = truth.with_frames(tool2flange=pose6_to_transform(np.r_[rng.normal(0, 0.5e-3, 3), rng.normal(0, 3e-3, 3)]))
    bases = {str(s): camera_base(rng) for s in range(stations)}
    n = n_cal + n_val
    q = random_configurations(get_robot(robot), n, rng) if q is None else q
    st = np.array([str(k % stations) for k in range(n)], dtype=object)
    sets = np.array(["calibration"] * n_cal + ["validation"] * n_val, dtype=object)
    ds, true = simulate_dataset(truth, q, robot_spec=robot, kind=kind, base2meas=bases,
                                station=st if stations > 1 else None, noise_position=noise[0],
                                noise_orientation=noise[1], rng=rng, set_=sets, declare_noise=declare)
    return truth, bases, ds, true


def _gauge_vector(cal, truth, bases):
    robot, B = regauge_frames(truth, get_robot(truth.name), bases)
    return cal.space.from_model(robot, B)


@pytest.mark.parametrize("robot,kind,stations", [("irb1200", "spheres", 1), ("irb1200", "spheres", 3),
                                                 ("brtirus0707a", "pose", 1), ("brtirus0707a", "spheres", 2),
                                                 ("irb1200", "pose", 2)])
def test_noise_free_recovery_of_every_identifiable_parameter(robot, kind, stations):
    """Injected errors (all but d2, see docs/estimator.md), noise-free data, unknown base per station and tool:
    every identified parameter equals the truth re-expressed in the frames gauge to 1e-8 of the deviations, the
    fixed ones are exactly the gauge, and predictions on fresh configurations match the truth."""
    rng = np.random.default_rng(11)
    truth, bases, ds, _ = _truth_and_data(robot, kind, rng, stations=stations, noise=(0, 0))
    cal = calibrate(ds, noise_position=1e-5, noise_orientation=1e-4)
    xs = _gauge_vector(cal, truth, bases)
    dev = np.abs(xs - cal.x_nominal)
    for unit in ("m", "rad"):
        sel = np.array([u == unit for u in cal.space.units])
        err = np.abs(cal.x - xs)[sel].max()
        assert err <= 1e-8 * dev[sel & (np.array(cal.status) == "identified")].max(), (unit, err)
    assert set(n for n, s in zip(cal.names, cal.status) if s == "fixed") == set(cal.identifiability["dropped"])
    assert len(cal.identifiability["dropped"]) == 7
    q_new = random_configurations(get_robot(robot), 30, rng)
    for s in cal.stations:
        p = cal.predict(q_new, np.full(30, s, dtype=object)).spheres
        _, true_new = simulate_dataset(truth, q_new, robot_spec=robot, base2meas={"0": bases[s]})
        assert np.abs(p - true_new["spheres"]).max() < 1e-11


@pytest.mark.slow
def test_nees_of_identified_parameters_lies_in_the_chi_square_band():
    """Monte-Carlo over 25 seeds: mean NEES of the 30 identified parameters lies in its 99 % chi-square band,
    i.e. the reported covariance is honest (sphere data at 0.01 mm)."""
    rng0 = np.random.default_rng(21)
    truth, bases, _, _ = _truth_and_data("irb1200", "spheres", rng0, noise=(0, 0))
    q = random_configurations(get_robot("irb1200"), 60, rng0)
    nees, p = [], None
    for seed in range(25):
        rng = np.random.default_rng(100 + seed)
        sets = np.array(["calibration"] * 60, dtype=object)
        ds, _ = simulate_dataset(truth, q, robot_spec="irb1200", base2meas=bases, noise_position=1e-5, rng=rng, set_=sets)
        cal = calibrate(ds)
        xs = _gauge_vector(cal, truth, bases)
        idx = np.flatnonzero(np.array(cal.status) == "identified")
        e = (cal.x - xs)[idx]
        C = cal.covariance[np.ix_(idx, idx)]
        nees.append(float(e @ np.linalg.solve(C, e)))
        p = idx.size
    N = len(nees)
    lo, hi = stats.chi2.ppf([0.005, 0.995], N * p) / N
    assert lo <= np.mean(nees) <= hi, (np.mean(nees), lo, hi)


def _val_error(cal, truth, bases, q_val, robot):
    p = cal.predict(q_val).spheres
    _, t = simulate_dataset(truth, q_val, robot_spec=robot, base2meas=bases)
    return float(np.sqrt(np.mean(np.sum((p - t["spheres"]) ** 2, axis=-1))))


def test_gross_errors_are_flagged_and_do_not_spoil_the_fit():
    """5 % of the calibration poses get a 5 mm gross error: the robust default flags exactly them and its
    validation error stays within 1.2x of the fit on clean data."""
    rng = np.random.default_rng(5)
    truth, bases, ds, _ = _truth_and_data("irb1200", "spheres", rng, n_cal=100, n_val=40, noise=(1e-5, 0))
    clean = calibrate(ds)
    bad = rng.choice(100, 5, replace=False)
    sph = ds.spheres.copy()
    off = rng.normal(size=(5, 3))
    sph[bad] += (5 * MM * off / np.linalg.norm(off, axis=1, keepdims=True))[:, None, :]
    dirty = calibrate(replace(ds, spheres=sph))
    flagged = {r["pose_id"] for r in dirty.rows["calibration_rejected"]}
    assert flagged == set(int(i) for i in bad)
    assert all("outlier" in r["reason"] for r in dirty.rows["calibration_rejected"])
    q_val = ds.q[100:]
    e_clean = _val_error(clean, truth, bases, q_val, "irb1200")
    e_dirty = _val_error(dirty, truth, bases, q_val, "irb1200")
    assert e_dirty <= 1.2 * e_clean, (e_dirty, e_clean)
    plain = calibrate(replace(ds, spheres=sph), robust=False)
    assert _val_error(plain, truth, bases, q_val, "irb1200") > 3 * e_clean  # the test can fail


def test_clean_data_flags_nothing():
    """On clean data the outlier rule (alpha = 1e-3 over all rows) rejects no row."""
    rng = np.random.default_rng(6)
    _, _, ds, _ = _truth_and_data("brtirus0707a", "pose", rng, n_cal=100, noise=(2e-5, 2e-3))
    cal = calibrate(ds)
    assert cal.rows["calibration_rejected"] == []


@pytest.mark.parametrize("kind", ["spheres", "pose"])
def test_noise_is_estimated_when_the_dataset_does_not_state_it(kind):
    """Without [noise] the position (and orientation) sigma are estimated from the residuals within 12 %."""
    rng = np.random.default_rng(8)
    _, _, ds, _ = _truth_and_data("brtirus0707a", kind, rng, n_cal=100, noise=(2e-5, 1e-3), declare=False)
    cal = calibrate(ds)
    assert cal.noise["position_source"].startswith("estimated")
    assert cal.noise["position_mm"] == pytest.approx(0.02, rel=0.12)
    if kind == "pose":
        assert cal.noise["orientation_rad"] == pytest.approx(1e-3, rel=0.12)


def test_validation_error_is_reported_next_to_its_cramer_rao_prediction():
    """The calibration carries the achieved validation residual and the one its covariance predicts; with a
    correct model they agree within 15 %."""
    rng = np.random.default_rng(9)
    _, _, ds, _ = _truth_and_data("irb1200", "spheres", rng, n_cal=80, n_val=80, noise=(1e-5, 0))
    cal = calibrate(ds)
    achieved = cal.residuals["validation"]["position_mm"]["rms"]
    expected = cal.residuals["predicted_validation"]["expected_residual_rms"]["position_mm"]
    assert achieved == pytest.approx(expected, rel=0.15)
    assert cal.residuals["predicted_validation"]["model_error_rms"]["position_mm"] < expected


# --- bad datasets -------------------------------------------------------------------------------------

def _small(rng, n=30, **kw):
    return _truth_and_data("irb1200", "spheres", rng, n_cal=n, n_val=0, noise=(1e-5, 0), **kw)[2]


def test_nan_joint_is_refused_naming_row_and_column():
    """A non-finite commanded joint is an error naming the row, pose_id and column."""
    ds = _small(np.random.default_rng(1))
    q = ds.q.copy()
    q[4, 2] = np.nan
    with pytest.raises(ValueError, match=r"row 5 \(pose_id 4\), column 'q3'"):
        calibrate(replace(ds, q=q))


def test_fewer_measurements_than_parameters_is_refused():
    """Three poses (27 sphere coordinates) cannot determine 37 parameters: a clear error."""
    with pytest.raises(ValueError, match="fewer than the 37 parameters"):
        calibrate(_small(np.random.default_rng(2), n=3))


def test_identical_poses_are_refused():
    """Every calibration row at the same configuration: a clear error, not a model."""
    rng = np.random.default_rng(3)
    q = np.repeat(random_configurations(get_robot("irb1200"), 1, rng), 30, axis=0)
    with pytest.raises(ValueError, match="same joint configuration"):
        calibrate(_small(rng, q=q))


def test_degenerate_wrist_gives_a_rank_report():
    """Joint 5 fixed at 0: the fit still runs but reports the data-dependent rank deficiency by name."""
    rng = np.random.default_rng(4)
    q = random_configurations(get_robot("irb1200"), 40, rng)
    q[:, 4] = 0.0
    cal = calibrate(_small(rng, n=40, q=q))
    dd = cal.identifiability["data_dependent_dropped"]
    assert dd and cal.identifiability["rank"] < 30
    assert any("rank deficiency" in n for n in cal.notes)
