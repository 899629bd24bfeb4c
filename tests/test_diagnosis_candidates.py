"""Tests of twin.diagnosis.candidates: effect regressors from commanded joints and the nominal model."""

import numpy as np

from twin.diagnosis.candidates import (
    RowContext,
    approach_signs,
    gravity_torque_regressor,
)
from twin.kinematics import link_frames
from twin.robots import brtirus0707a, irb1200


def _potential_gradient(model, q, masses, coms, g):
    """d/dq of sum_k m_k g . p_ck by central differences (p_ck = o_k + R_k c_k)."""
    def V(qq):
        F = link_frames(model, qq[None])[0]
        return sum(m * g @ (F[k + 1, :3, 3] + F[k + 1, :3, :3] @ c) for k, (m, c) in enumerate(zip(masses, coms)))

    h = 1e-6
    N = q.size
    out = np.zeros(N)
    for i in range(N):
        e = np.zeros(N)
        e[i] = h
        out[i] = (V(q + e) - V(q - e)) / (2 * h)
    return out


def test_gravity_regressor_matches_potential_energy_gradient():
    """Y @ (m, m c) equals the gradient of the gravitational potential for random masses and centres of mass."""
    rng = np.random.default_rng(0)
    g = np.array([0.0, 0.0, -9.81])
    for model in (irb1200(), brtirus0707a()):
        masses = rng.uniform(1, 10, 6)
        coms = rng.normal(0, 0.1, (6, 3))
        q = rng.uniform(-2, 2, (5, 6))
        Y = gravity_torque_regressor(model, q, g)
        theta = np.concatenate([masses[:, None], masses[:, None] * coms], axis=1)  # (6, 4)
        tau = np.einsum("nikc,kc->ni", Y, theta)
        for k in range(5):
            assert np.allclose(tau[k], _potential_gradient(model, q[k], masses, coms, g), atol=1e-6)


def test_gravity_regressor_of_a_dh_table_of_any_length_matches_the_potential_gradient():
    """A 7-joint DH and a 3-joint MDH table (the DH tables a user gives): the regressor has one row per joint and
    equals the gradient of the gravitational potential."""
    from twin.dataset import robot_from_spec

    rng = np.random.default_rng(3)
    g = np.array([0.0, 0.0, -9.81])
    wam = {"convention": "dh", "theta_deg": [0] * 7, "d_mm": [0, 0, 550, 0, 300, 0, 60], "a_mm": [0, 0, 45, -45, 0, 0, 0],
           "alpha_deg": [-90, 90, -90, 90, -90, 90, 0]}
    arm3 = {"convention": "mdh", "theta_deg": [0, -90, 30], "d_mm": [300, 0, 50], "a_mm": [0, 0, 400],
            "alpha_deg": [0, -90, 0]}
    for spec in (wam, arm3):
        model = robot_from_spec(spec)
        N = model.n_joints
        masses, coms, q = rng.uniform(1, 10, N), rng.normal(0, 0.1, (N, 3)), rng.uniform(-2, 2, (4, N))
        Y = gravity_torque_regressor(model, q, g)
        assert Y.shape == (4, N, N, 4)
        tau = np.einsum("nikc,kc->ni", Y, np.concatenate([masses[:, None], masses[:, None] * coms], axis=1))
        for k in range(4):
            assert np.allclose(tau[k], _potential_gradient(model, q[k], masses, coms, g), atol=1e-6)


def test_joint1_of_a_vertical_axis_feels_no_gravity_torque():
    """Joint 1 turns about the vertical: its regressor row is zero."""
    Y = gravity_torque_regressor(irb1200(), np.random.default_rng(1).uniform(-2, 2, (10, 6)))
    assert np.abs(Y[:, 0]).max() < 1e-12


def test_approach_signs_follow_last_motion_and_hold_when_still():
    """Signs follow the last move of each joint and persist while the joint does not move."""
    q = np.array([[0.1, 0, 0, 0, 0, 0], [0.05, 0, 0, 0, 0, 0], [0.05, 0.2, 0, 0, 0, 0], [0.3, 0.1, 0, 0, 0, 0]])
    s = approach_signs(q)
    assert s[:, 0].tolist() == [1, -1, -1, 1]
    assert s[:, 1].tolist() == [1, 1, 1, -1]
    assert np.all(s[:, 2] == 1)


def test_every_atom_of_both_pools_has_one_feature_column_per_feature():
    """Catalogue and dictionary atoms evaluate to (rows, features) finite values on a row context."""
    from twin.diagnosis.pools import catalogue_atoms, generic_atoms
    from twin.diagnosis.values import feature_values

    model = irb1200()
    q = np.random.default_rng(2).uniform(-1, 1, (40, 6))
    ctx = RowContext(q=q, q_start=np.zeros(6), temp_c=np.linspace(20, 25, 40), t_s=np.arange(40) * 10.0)
    lengths = ["d1", "d4", "a3"]
    cat = catalogue_atoms(model, ctx, lengths)
    gen = generic_atoms(model, ctx, ["d1", "alpha2"], lengths, cat)
    for a in cat + gen[::50]:
        F = feature_values(a.features, ctx, model)
        assert F.shape == (40, len(a.features)) and np.all(np.isfinite(F)), a.label
