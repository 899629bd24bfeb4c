"""The maximum-a-posteriori option of the default estimator: a Gaussian prior on the robot parameters'
deviations from nominal."""

from __future__ import annotations

import numpy as np
import pytest

from twin.estimator import calibrate, simulate_dataset
from twin.estimator.core import prepare
from twin.estimator.problem import absolute_residuals
from twin.robots import get_robot
from twin.transforms import pose6_to_transform


@pytest.fixture(scope="module")
def data():
    rng = np.random.default_rng(3)
    nom = get_robot("irb1200")
    lay = nom.layout
    dev = np.where(lay.is_length, rng.normal(0, 0.5e-3, lay.size), rng.normal(0, 2e-3, lay.size))
    dev[lay.base_slice] = 0.0
    dev[lay.index("d2")] = 0.0
    truth = nom.perturbed(dev).with_frames(base2meas=pose6_to_transform(np.array([0.1, 0.2, 1.2, 0.5, 1.0, -0.4])))
    q = rng.uniform(np.maximum(nom.q_min, -np.pi), np.minimum(nom.q_max, np.pi), (25, 6))
    ds, _ = simulate_dataset(truth, q, robot_spec="irb1200", noise_position=2e-5, rng=rng)
    return ds


def test_a_vanishing_prior_is_least_squares(data):
    """Prior standard deviations of 1 km / 1000 rad give the least-squares estimate (1e-9)."""
    ls = calibrate(data, robust=False, validation_fraction=0.0)
    mp = calibrate(data, robust=False, validation_fraction=0.0, prior={"length": 1e3, "angle": 1e3})
    assert np.abs(mp.x - ls.x).max() < 1e-9


def test_map_estimate_is_a_stationary_point_of_the_posterior(data):
    """The gradient of the posterior cost (data residuals plus prior rows, built here from the public residual
    function), taken by central differences over the identified parameters, vanishes at the MAP estimate."""
    prior = {"length": 2e-4, "angle": 5e-4}
    cal = calibrate(data, robust=False, validation_fraction=0.0, prior=prior)
    prep = prepare(data, validation_fraction=0.0)
    sig = cal.details["sigma_position"]
    obs = prep.obs.with_sigma(sig)
    sp = prep.space
    joint = set(sp.chain.structure.joint_params)
    free = [k for k, s in enumerate(cal.status) if s == "identified"]
    sd = np.array([np.inf if (k >= sp.n_robot or sp.names[k] in joint) else
                   (prior["length"] if sp.units[k] == "m" else prior["angle"]) for k in range(sp.size)])

    def cost(x):
        r = absolute_residuals(sp, x, obs, jacobian=False).r
        d = np.where(np.isfinite(sd), (x - prep.x_nominal) / sd, 0.0)
        return float(r @ r + d @ d)

    c0 = cost(cal.x)
    for k in free:
        h = 1e-7 if sp.units[k] == "m" else 1e-6
        e = np.zeros(sp.size)
        e[k] = h
        g = (cost(cal.x + e) - cost(cal.x - e)) / (2 * h)
        curv = (cost(cal.x + e) - 2 * c0 + cost(cal.x - e)) / h**2
        assert abs(g) <= 1e-4 * max(curv * (1e-6 if sp.units[k] == "m" else 1e-5), 1.0), sp.names[k]


def test_prior_shrinks_deviations_and_the_covariance(data):
    """MAP trades data fit for the prior: its prior term sum((dev/sd)^2) is below the least-squares estimate's,
    its data residual above, and every prior-held parameter's posterior sd is below its least-squares sd."""
    prior = {"length": 5e-5, "angle": 1e-4}
    ls = calibrate(data, robust=False, validation_fraction=0.0)
    mp = calibrate(data, robust=False, validation_fraction=0.0, prior=prior)
    held = [k for k, n in enumerate(ls.names) if ls.status[k] == "identified" and k < ls.space.n_robot
            and not n.startswith("theta")]
    sd = np.array([prior["length"] if ls.space.units[k] == "m" else prior["angle"] for k in held])
    assert np.sum(((mp.x - mp.x_nominal)[held] / sd) ** 2) < np.sum(((ls.x - ls.x_nominal)[held] / sd) ** 2)
    assert mp.residuals["calibration"]["position_mm"]["rms"] > ls.residuals["calibration"]["position_mm"]["rms"]
    assert np.all(mp.std[held] < ls.std[held])
    assert mp.details["prior"] == {"length": 5e-5, "angle": 1e-4}


def test_a_bad_prior_is_a_named_error(data):
    """An unknown key or a non-positive standard deviation is a ValueError naming it."""
    with pytest.raises(ValueError, match="unknown keys \\['lenght'\\]"):
        calibrate(data, prior={"lenght": 1e-3})
    with pytest.raises(ValueError, match="angle must be a positive"):
        calibrate(data, prior={"angle": 0.0})
