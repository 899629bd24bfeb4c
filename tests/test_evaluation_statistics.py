"""Tests of twin.evaluation.statistics: the separation paper's statistics."""

import numpy as np
import pytest

from twin.evaluation.statistics import (
    absolute_pose_errors,
    euler_change_error,
    improvement_percent,
    moved_distance_error,
    summarize,
)
from twin.transforms import make_transform, matrix_from_euler_zyx, rot_z, rotvec_to_matrix


def test_moved_distance_error_is_the_difference_of_lengths():
    """A 100 mm commanded move measured as 100.3 mm long has a 0.3 mm error, whatever the direction."""
    rng = np.random.default_rng(1)
    start = rng.normal(size=(5, 3))
    d = rng.normal(size=(5, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    cmd_end = start + 0.1 * d
    other = rng.normal(size=(5, 3))
    other /= np.linalg.norm(other, axis=1, keepdims=True)
    meas_start = start + 1.0  # another frame: only distances matter
    meas_end = meas_start + 0.1003 * other
    err = moved_distance_error(meas_start, meas_end, start, cmd_end)
    np.testing.assert_allclose(err, 0.0003, atol=1e-12)


def test_moved_distance_error_rejects_mismatched_rows():
    """Inputs with different numbers of rows are refused, naming them."""
    with pytest.raises(ValueError, match="same number of rows"):
        moved_distance_error(np.zeros((2, 3)), np.ones((2, 3)), np.zeros((3, 3)), np.ones((3, 3)))


def test_moved_distance_error_rejects_nan():
    """A NaN measurement is an error, not a NaN statistic."""
    p = np.zeros((2, 3))
    q = p.copy()
    q[1, 0] = np.nan
    with pytest.raises(ValueError, match="p_end_meas contains non-finite"):
        moved_distance_error(p, q, p, p + 1)


def test_euler_change_error_matches_hand_computed_example():
    """Measured change (0.1, 0.2, 0.3) deg vs commanded (0, 0.2, 0.3) deg gives 0.1 deg (eq. 25)."""
    d = np.deg2rad
    R0 = matrix_from_euler_zyx(d(np.array([10.0, 20.0, 30.0])))
    R_cmd = matrix_from_euler_zyx(d(np.array([10.0, 20.2, 30.3])))
    R_meas = matrix_from_euler_zyx(d(np.array([10.1, 20.2, 30.3])))
    err = euler_change_error(R0, R_meas, R0, R_cmd)
    assert np.rad2deg(err[0]) == pytest.approx(0.1, abs=1e-9)


def test_euler_change_error_wraps_across_180_deg():
    """A yaw change across +-180 deg measured as the commanded one gives zero error, not 360 deg."""
    R0 = rot_z(np.deg2rad(179.0))
    R1 = rot_z(np.deg2rad(-179.0))
    assert euler_change_error(R0, R1, R0, R1)[0] == pytest.approx(0.0, abs=1e-12)
    # measured change +2 deg through 180, commanded +1 deg: error 1 deg
    err = euler_change_error(R0, R1, R0, rot_z(np.deg2rad(180.0)))
    assert np.rad2deg(err[0]) == pytest.approx(1.0, abs=1e-9)


def test_euler_change_error_is_zero_for_identical_motion_in_another_start():
    """The same measured and commanded rotations give zero error (the statistic can be zero)."""
    rng = np.random.default_rng(2)
    Ra = rotvec_to_matrix(rng.normal(scale=0.5, size=(4, 3)))
    Rb = rotvec_to_matrix(rng.normal(scale=0.5, size=(4, 3)))
    np.testing.assert_allclose(euler_change_error(Ra, Rb, Ra, Rb), 0.0, atol=1e-12)


def test_summary_statistics_of_a_known_set():
    """max/mean/rms/std of (1, 2, 3, 4) are 4, 2.5, sqrt(7.5), and the sample std 1.29."""
    s = summarize([1.0, 2.0, 3.0, 4.0])
    assert (s.n, s.max, s.mean) == (4, 4.0, 2.5)
    assert s.rms == pytest.approx(np.sqrt(7.5))
    assert s.std == pytest.approx(np.std([1, 2, 3, 4], ddof=1))
    assert s.scaled(1e3).mean == pytest.approx(2500.0)


def test_summary_refuses_empty_and_nan():
    """Empty or non-finite errors raise instead of giving NaN."""
    with pytest.raises(ValueError, match="empty"):
        summarize([])
    with pytest.raises(ValueError, match="non-finite"):
        summarize([1.0, np.nan])


def test_improvement_reproduces_the_papers_percentages():
    """The improvement of the mean gives the paper's 80.7 %, 87.8 %, 86.2 % and 66.9 %."""
    assert improvement_percent(0.4913, 0.0947) == pytest.approx(80.7, abs=0.05)
    assert improvement_percent(0.1615, 0.0197) == pytest.approx(87.8, abs=0.05)
    assert improvement_percent(1.261, 0.1735) == pytest.approx(86.2, abs=0.05)
    assert improvement_percent(0.7873, 0.2604) == pytest.approx(66.9, abs=0.05)
    with pytest.raises(ValueError, match="before must be a positive"):
        improvement_percent(0.0, 1.0)


def test_absolute_pose_errors():
    """A pose shifted by (3, 4, 0) mm and turned 0.2 rad has errors 5 mm and 0.2 rad."""
    A = make_transform(rot_z(0.2), np.array([0.003, 0.004, 0.0]))
    pos, rot = absolute_pose_errors(A, np.eye(4))
    assert pos[0] == pytest.approx(0.005)
    assert rot[0] == pytest.approx(0.2)
