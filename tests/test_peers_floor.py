"""The benchmark's synthetic problem, its noise floor and its scoring (experiments/peers; no peer library needed)."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from experiments.peers.common import register_base_and_tool  # noqa: E402
from experiments.peers.floor import floor_fit, identifiable_spectrum  # noqa: E402
from experiments.peers.metrics import validation_errors  # noqa: E402
from experiments.peers.synthetic import NOISE_LEVELS, NoiseLevel, make_problem, make_split, to_dataset  # noqa: E402
from twin.kinematics import tool2meas  # noqa: E402
from twin.transforms import rotation_angle_between  # noqa: E402


@pytest.fixture(scope="module")
def problem():
    return make_problem()


def test_splits_are_deterministic_and_nested(problem):
    """The same seed gives the same data, and the 50-pose set is the first half of the 100-pose set."""
    a = make_split(problem, 3, 100, NOISE_LEVELS[0])
    b = make_split(problem, 3, 100, NOISE_LEVELS[0])
    c = make_split(problem, 3, 50, NOISE_LEVELS[0])
    np.testing.assert_array_equal(a.tool2meas_cal, b.tool2meas_cal)
    np.testing.assert_array_equal(a.q_cal[:50], c.q_cal)
    np.testing.assert_array_equal(a.tool2meas_cal[:50], c.tool2meas_cal)
    assert not np.allclose(a.q_cal, make_split(problem, 4, 100, NOISE_LEVELS[0]).q_cal)


def test_noise_has_the_stated_size(problem):
    """Measured minus true poses scatter with the stated sigma per coordinate (position and rotation vector)."""
    noise = NoiseLevel(0.05e-3, 0.003)
    sp = make_split(problem, 0, 100, noise)
    dp = sp.tool2meas_cal[:, :3, 3] - sp.tool2meas_cal_true[:, :3, 3]
    ang = rotation_angle_between(sp.tool2meas_cal_true[:, :3, :3], sp.tool2meas_cal[:, :3, :3])
    assert np.std(dp) == pytest.approx(noise.position, rel=0.15)
    # the angle of a 3-D Gaussian rotation vector has RMS sqrt(3) sigma
    assert np.sqrt(np.mean(ang**2)) == pytest.approx(np.sqrt(3) * noise.orientation, rel=0.15)


def test_dataset_for_the_estimator_carries_no_truth(problem):
    """The dataset handed to our estimator has the nominal robot, no base2meas, and only measured poses."""
    sp = make_split(problem, 0, 50, NOISE_LEVELS[1])
    ds = to_dataset(problem, sp)
    assert ds.robot is problem.nominal and ds.stations_base2meas == {}
    np.testing.assert_array_equal(ds.pose, sp.tool2meas_cal)
    assert ds.noise_position == NOISE_LEVELS[1].position and ds.pose_seen.all()


def test_floor_keeps_every_identifiable_direction(problem):
    """Full-pose data identify 30 directions (4 per joint + 6 of the base), positions 27; the floor keeps
    exactly those: the dropped singular values are round-off, the kept ones far above its threshold."""
    sp = make_split(problem, 0, 50, NOISE_LEVELS[0])
    for use_orientation, rank in ((True, 30), (False, 27)):
        s = identifiable_spectrum(problem.truth, sp.q_cal, use_orientation=use_orientation)
        assert s[rank - 1] > 1e-3 and (len(s) == rank or s[rank] < 1e-12)
        f = floor_fit(problem.truth, sp.q_cal, sp.tool2meas_cal, 1e-5, 1e-4, use_orientation=use_orientation)
        assert f.rank == rank


def test_floor_recovers_the_truth_on_noise_free_data(problem):
    """Started off the truth and fed noise-free poses, the floor fit predicts validation poses exactly."""
    sp = make_split(problem, 1, 50, NOISE_LEVELS[0])
    start = problem.truth.perturbed(np.full(problem.truth.layout.size, 1e-4))
    f = floor_fit(start, sp.q_cal, sp.tool2meas_cal_true, 1e-5, 1e-4, iterations=6)
    T = tool2meas(f.model, sp.q_val)
    e = validation_errors(sp.tool2meas_val_true, T[:, :3, 3], T[:, :3, :3])
    assert e.position_max_mm < 1e-6 and e.orientation_max_deg < 1e-6


def test_floor_error_scales_with_the_noise(problem):
    """On noisy data the floor's validation error is of the order of the noise, and shrinks with it."""
    errs = []
    for noise in NOISE_LEVELS:
        sp = make_split(problem, 2, 100, noise)
        f = floor_fit(problem.truth, sp.q_cal, sp.tool2meas_cal, noise.position, noise.orientation)
        T = tool2meas(f.model, sp.q_val)
        errs.append(validation_errors(sp.tool2meas_val_true, T[:, :3, 3]).position_rms_mm)
    assert 0.1 * NOISE_LEVELS[0].position * 1e3 < errs[0] < 3 * NOISE_LEVELS[0].position * 1e3
    assert errs[1] < errs[0]


def test_registration_recovers_base_and_tool_point(problem):
    """The closed-form start recovers base2meas and the tool point exactly when the joints are nominal."""
    model = problem.nominal.with_frames(base2meas=problem.truth.base2meas, tool2flange=problem.truth.tool2flange)
    sp = make_split(problem, 0, 50, NOISE_LEVELS[0])
    T = tool2meas(model, sp.q_cal)
    base2meas, t = register_base_and_tool(problem.nominal, sp.q_cal, T[:, :3, 3])
    np.testing.assert_allclose(base2meas, problem.truth.base2meas, atol=1e-9)
    np.testing.assert_allclose(t, problem.truth.tool2flange[:3, 3], atol=1e-9)


def test_validation_errors_measure_distance_and_angle():
    """Scoring: a 1 mm shift and a 0.1 deg turn on every pose read as 1 mm and 0.1 deg; bad shapes raise."""
    T = np.broadcast_to(np.eye(4), (5, 4, 4)).copy()
    c, s = np.cos(np.deg2rad(0.1)), np.sin(np.deg2rad(0.1))
    R = np.broadcast_to(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]), (5, 3, 3))
    e = validation_errors(T, np.tile([0.001, 0, 0], (5, 1)), R)
    assert e.position_rms_mm == pytest.approx(1.0) and e.position_max_mm == pytest.approx(1.0)
    assert e.orientation_rms_deg == pytest.approx(0.1)
    with pytest.raises(ValueError, match="positions"):
        validation_errors(T, np.zeros((4, 3)))


def test_growth_campaign_config_has_the_asked_number_of_poses():
    """The resized separation campaign of the growth figures plans exactly the asked number of poses."""
    from experiments.peers.growth import campaign_raw
    from twin.runner.config import parse_campaign_config
    from twin.runner.plan import make_plan

    cfg = parse_campaign_config(campaign_raw(16))
    assert cfg.measurement.mode == "truth_noise" and cfg.methods == ("default",)
    assert make_plan(cfg).n == 16
    with pytest.raises(ValueError, match="multiple of 4"):
        campaign_raw(10)
