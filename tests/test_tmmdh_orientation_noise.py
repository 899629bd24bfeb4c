"""orientation_noise: the three readings of the TM-MDH paper's '0.002 rad' orientation noise."""

import numpy as np
import pytest

from twin.transforms import euler_zyx_from_matrix, matrix_from_euler_zyx, matrix_to_rotvec, rotvec_to_matrix
from twin.estimator.simulate import orientation_noise

SIGMA = 0.002


def _R(n=20000, seed=0):
    rng = np.random.default_rng(seed)
    return matrix_from_euler_zyx(rng.uniform([-3, -1.2, -3], [3, 1.2, 3], (n, 3)))


def _rms_angle(R, Rn):
    return float(np.sqrt(np.mean(np.sum(matrix_to_rotvec(Rn @ np.swapaxes(R, 1, 2)) ** 2, axis=1))))


def test_rotvec_reading_keeps_the_old_random_stream():
    """'rotvec' draws exactly what simulate_dataset drew before the readings existed."""
    R = _R(50)
    old = rotvec_to_matrix(np.random.default_rng(4).normal(0.0, SIGMA, (50, 3))) @ R
    np.testing.assert_array_equal(orientation_noise(R, SIGMA, "rotvec", np.random.default_rng(4)), old)


def test_rotvec_reading_rms_angle_is_sqrt3_sigma():
    """Per rotation-vector component: the RMS rotation angle is sqrt(3) sigma."""
    R = _R()
    assert _rms_angle(R, orientation_noise(R, SIGMA, "rotvec", np.random.default_rng(1))) == pytest.approx(
        np.sqrt(3) * SIGMA, rel=0.02)


def test_norm_reading_rms_angle_is_sigma():
    """As a norm: the RMS rotation angle is sigma."""
    R = _R()
    assert _rms_angle(R, orientation_noise(R, SIGMA, "norm", np.random.default_rng(1))) == pytest.approx(SIGMA, rel=0.02)


def test_euler_reading_perturbs_each_euler_angle_by_sigma():
    """On Euler angles: each Z-Y-X angle of the noisy rotation differs by N(0, sigma^2)."""
    R = _R()
    d = euler_zyx_from_matrix(orientation_noise(R, SIGMA, "euler", np.random.default_rng(1))) - euler_zyx_from_matrix(R)
    np.testing.assert_allclose(np.std(d, axis=0), SIGMA, rtol=0.03)


def test_unknown_reading_is_rejected():
    """An unknown reading raises ValueError naming the argument."""
    with pytest.raises(ValueError, match="reading"):
        orientation_noise(_R(3), SIGMA, "quaternion", np.random.default_rng(0))
