"""Calibration objects: file round trip, prediction with standard deviations, compensation."""

import json
from dataclasses import replace

import numpy as np
import pytest

from twin.kinematics import UnreachableError, tool2base
from twin.robots import get_robot
from twin.transforms import pose6_to_transform
from twin.estimator import Calibration, calibrate, compensate, compensation, predict
from twin.estimator.simulate import random_configurations, simulate_dataset

from _estimator_helpers import camera_base, random_truth


@pytest.fixture(scope="module")
def fitted():
    rng = np.random.default_rng(31)
    truth = random_truth("irb1200", rng).with_frames(tool2flange=pose6_to_transform([2e-4, -1e-4, 3e-4, 1e-3, 0, -2e-3]))
    bases = {"a": camera_base(rng), "b": camera_base(rng)}
    q = random_configurations(get_robot("irb1200"), 120, rng)
    st = np.array(["a", "b"] * 60, dtype=object)
    sets = np.array((["calibration"] * 4 + ["validation"]) * 24, dtype=object)
    ds, _ = simulate_dataset(truth, q, robot_spec="irb1200", base2meas=bases, station=st, noise_position=1e-5, rng=rng, set_=sets)
    return truth, bases, calibrate(ds)


def test_calibration_json_round_trip(tmp_path, fitted):
    """save/load keeps parameters, status, covariance, stations, plate and the statistics."""
    _, _, cal = fitted
    p = cal.save(tmp_path / "calibration.json")
    d = json.loads(p.read_text())
    assert d["schema_version"] == 1 and d["kind"] == "calibration"
    back = Calibration.load(p)
    assert back.stations == cal.stations and back.status == cal.status
    assert np.allclose(back.x, cal.x, rtol=0, atol=1e-15)
    assert np.allclose(back.covariance, cal.covariance, rtol=1e-12, atol=1e-30)
    q = random_configurations(get_robot("irb1200"), 5, np.random.default_rng(1))
    assert np.allclose(back.predict(q).spheres, cal.predict(q).spheres, atol=1e-14)


def test_load_refuses_unknown_schema_version(tmp_path, fitted):
    """A calibration file with another schema_version is refused, naming the file and the version."""
    _, _, cal = fitted
    p = cal.save(tmp_path / "c.json")
    d = json.loads(p.read_text())
    d["schema_version"] = 99
    p.write_text(json.dumps(d))
    with pytest.raises(ValueError, match="schema_version 99"):
        Calibration.load(p)


def test_predict_frames_and_standard_deviations(fitted):
    """Known stations predict in their measurement frame, unknown ones in the base frame; the predicted sd of a
    sphere coordinate matches a Monte-Carlo over the parameter covariance."""
    truth, bases, cal = fitted
    q = random_configurations(get_robot("irb1200"), 4, np.random.default_rng(2))
    pr = predict(cal, q, np.array(["a", "b", "zz", "a"], dtype=object))
    assert pr.frame.tolist() == ["measurement", "measurement", "base", "measurement"]
    # base-frame row: consistent with the identified robot's tool2base
    T = tool2base(cal.robot, q[2:3])[0]
    assert np.allclose(pr.pose[2], T, atol=1e-12)
    # Monte-Carlo of the sd
    rng = np.random.default_rng(3)
    idx = np.flatnonzero(np.array(cal.status) == "identified")
    C = cal.covariance[np.ix_(idx, idx)]
    L = np.linalg.cholesky(C)
    samples = []
    for _ in range(400):
        x = cal.x.copy()
        x[idx] += L @ rng.normal(size=idx.size)
        samples.append(replace(cal, x=x, covariance=None).predict(q[:1], np.array(["a"], dtype=object)).spheres[0])
    sd_mc = np.std(np.array(samples), axis=0)
    assert np.allclose(pr.sd_spheres[0], sd_mc, rtol=0.15)


def test_compensation_reaches_targets_on_the_identified_model(fitted):
    """Corrected commands put the identified model's plate on the targets; they differ from the nominal ones."""
    _, _, cal = fitted
    rng = np.random.default_rng(4)
    q_true = random_configurations(get_robot("irb1200"), 6, rng, margin=0.3)
    targets = tool2base(get_robot("irb1200"), q_true)
    res = compensation(cal, targets, q_true)
    T = tool2base(cal.robot, res.q)
    assert np.abs(T[:, :3, 3] - targets[:, :3, 3]).max() < 1e-9
    assert np.abs(res.q - res.q_nominal).max() > 1e-5
    assert np.allclose(compensate(cal, targets, q_true), res.q)


def test_unreachable_target_is_a_clear_error(fitted):
    """A target 5 m away raises UnreachableError naming it."""
    _, _, cal = fitted
    T = np.eye(4)
    T[:3, 3] = [5.0, 0, 0]
    with pytest.raises(UnreachableError, match=r"\[0\]"):
        compensate(cal, T[None], np.zeros(6))
