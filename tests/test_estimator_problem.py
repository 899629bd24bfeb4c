"""Residuals of the identification problem: analytic Jacobians against finite differences, registration."""

import numpy as np
import pytest
from dataclasses import replace

from twin.dataset import default_plate
from twin.robots import brtirus0707a, irb1200
from twin.transforms import pose6_to_transform, rotvec_to_matrix
from twin.estimator.chain import Chain
from twin.estimator.problem import (
    Observations,
    ParamSpace,
    station_eval,
    absolute_residuals,
    kabsch,
    make_pairs,
    pair_residuals,
    predict_points,
)


def _setup(make, seed=1, n=16):
    rng = np.random.default_rng(seed)
    m = make()
    space = ParamSpace(Chain(m.convention, m.beta_joints), ("0", "1"))
    x = space.from_model(m)
    x[space.base_slice(0)] = [0.1, 0.2, 0.9, 0.3, -0.2, 0.1]
    x[space.base_slice(1)] = [-0.3, 0.1, 1.0, -0.1, 0.4, 2.0]
    x[: space.n_rt] += rng.normal(0, 1e-2, space.n_rt)
    q = rng.uniform(-1.5, 1.5, (n, 6))
    st = rng.integers(0, 2, n)
    plate = default_plate()
    x1 = x + rng.normal(0, 1e-3, x.size)
    # measurements equal to the predictions at x1 (zero residual: the Jacobian is then exact)
    pts, _ = predict_points(space, x1, q, st, plate.spheres_flange)
    seen = rng.random((n, 3)) > 0.15
    R, p, _ = station_eval(space, x1, q, st, False)
    common = dict(q=q, station=st, station_names=("0", "1"), pose_id=np.arange(n), spheres_tool=plate.spheres_flange,
                  sigma_position=1e-5, sigma_orientation=1e-4)
    sph = Observations(kind="spheres", spheres=np.where(seen[..., None], pts, np.nan), seen=seen, **common)
    pose = Observations(kind="pose", pose_R=R, pose_p=p, **common)
    return space, x1, sph, pose


def _fd(fun, x, h=1e-7):
    r0 = fun(x).r
    J = np.zeros((r0.size, x.size))
    for k in range(x.size):
        xp, xm = x.copy(), x.copy()
        xp[k] += h
        xm[k] -= h
        J[:, k] = (fun(xp).r - fun(xm).r) / (2 * h)
    return J


def _check(fun, x):
    res = fun(x)
    Jn = _fd(lambda y: replace(fun(y), J=None), x)
    # residual = (meas - pred)/sigma, J = d pred/sigma: so dr/dx = -J
    return np.abs(-Jn - res.J).max() / np.abs(res.J).max()


@pytest.mark.parametrize("make", [irb1200, brtirus0707a])
def test_sphere_residual_jacobian_matches_finite_differences(make):
    """Sphere-centre residuals (two stations, some spheres missing) have the analytic Jacobian."""
    space, x, sph, _ = _setup(make)
    assert _check(lambda y: absolute_residuals(space, y, sph, jacobian=True), x) < 1e-6


@pytest.mark.parametrize("make", [irb1200, brtirus0707a])
def test_pose_residual_jacobian_matches_finite_differences(make):
    """Pose residuals (position and rotation vector of R_meas R_pred^T) have the analytic Jacobian at zero residual."""
    space, x, _, pose = _setup(make)
    assert _check(lambda y: absolute_residuals(space, y, pose), x) < 1e-6


@pytest.mark.parametrize("kind", ["distance", "rotation_change", "euler_change"])
def test_pair_residual_jacobians_match_finite_differences(kind):
    """Distance, tool-frame rotation-change and Euler-angle-change residuals of motion pairs."""
    space, x, sph, pose = _setup(irb1200, seed=4)
    obs = sph if kind == "distance" else pose
    pairs, _ = make_pairs(obs)
    bases = {k: pose6_to_transform(x[space.base_slice(k)]) for k in range(2)}
    err = _check(lambda y: pair_residuals(space, y, obs, pairs, kind, base2meas=bases), x)
    assert err < 1e-6


def test_distance_and_rotation_change_do_not_see_the_base():
    """Pair residuals are invariant to every station's base2meas (their base columns are zero)."""
    space, x, sph, pose = _setup(brtirus0707a)
    pairs, _ = make_pairs(sph)
    for obs, kind in ((sph, "distance"), (pose, "rotation_change")):
        J = pair_residuals(space, x, obs, pairs, kind).J
        assert np.abs(J[:, space.n_rt:]).max() < 1e-12 * np.abs(J).max()


def test_make_pairs_from_pair_column_and_consecutive_rows():
    """Pairs come from the pair column when present, else from consecutive rows of one station."""
    space, x, sph, _ = _setup(irb1200, n=6)
    sph2 = replace(sph, pair=np.array([5, 5, 7, 7, -1, 9]), station=np.zeros(6, int))
    pairs, how = make_pairs(sph2)
    assert pairs.tolist() == [[0, 1], [2, 3]] and "pair" in how
    pairs, how = make_pairs(replace(sph, station=np.array([0, 1, 0, 1, 0, 1])))
    assert pairs.tolist() == [[0, 2], [2, 4], [1, 3], [3, 5]] and "consecutive" in how


def test_kabsch_recovers_a_rigid_transform():
    """Rigid registration returns the rotation and translation that generated the points."""
    rng = np.random.default_rng(5)
    A = rng.normal(size=(20, 3))
    R = rotvec_to_matrix(np.array([0.3, -1.2, 2.0]))
    t = np.array([0.1, -0.4, 0.9])
    Rk, tk = kabsch(A, A @ R.T + t)
    assert np.abs(Rk - R).max() < 1e-12 and np.abs(tk - t).max() < 1e-12
