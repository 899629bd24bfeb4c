"""Tests of twin.world.effects_shapes: the world's effects of other shapes than the diagnosis' candidates."""

import numpy as np
import pytest

from twin.kinematics import link_frames
from twin.robots import irb1200
from twin.world.effects import EffectContext, contexts_for_sequence
from twin.world.effects_catalogue import effect_from_spec
from twin.world.effects_shapes import Repeatability, flange_repeatability, repeatability_sigma

DEG = np.pi / 180


def _ctx(q, t_s=0.0, history=None):
    return EffectContext(t_s=t_s, q_cmd=np.asarray(q, float),
                         q_cmd_history=np.zeros((0, 6)) if history is None else np.asarray(history, float))


def test_joint_polynomial_acts_on_its_target_joint_only():
    """A quadratic in q2 moves joint 3 by c ((q2 - centre) / scale)^2 and leaves the other joints alone."""
    e = effect_from_spec({"name": "joint_polynomial", "target_joint": 3, "source_joint": 2,
                          "coefficients_deg": [0.0, 0.01], "centre_deg": 10.0, "scale_deg": 45.0})
    q = np.array([0.1, 0.5, -0.2, 0.3, 0.9, 0.0])
    d = e.joints(q, _ctx(q)) - q
    want = 0.01 * DEG * ((0.5 - 10 * DEG) / (45 * DEG)) ** 2
    np.testing.assert_allclose(d, [0, 0, want, 0, 0, 0], atol=1e-15)


def test_joint_product_is_bilinear_in_its_two_joints():
    """Doubling q3 - c3 doubles the offset of the product effect."""
    e = effect_from_spec({"name": "joint_product", "target_joint": 2, "joints": [2, 3], "coefficient_deg_per_rad2": 0.02})
    q1 = np.array([0, 0.4, 0.3, 0, 0, 0.0])
    q2 = np.array([0, 0.4, 0.6, 0, 0, 0.0])
    d1 = (e.joints(q1, _ctx(q1)) - q1)[1]
    d2 = (e.joints(q2, _ctx(q2)) - q2)[1]
    assert d1 == pytest.approx(0.02 * DEG * 0.4 * 0.3) and d2 == pytest.approx(2 * d1)


def test_move_lag_follows_the_size_of_the_last_move():
    """A 1 deg move lags less than a 30 deg move (not a constant clearance), in the direction of the move."""
    e = effect_from_spec({"name": "move_lag", "lag_deg": [0, 0.01, 0, 0, 0, 0], "width_deg": 5.0})
    ctxs = contexts_for_sequence(np.array([[0, 0, 0, 0, 0, 0], [0, 1 * DEG, 0, 0, 0, 0], [0, 31 * DEG, 0, 0, 0, 0.0]]))
    lags = [e.joints(c.q_cmd, c)[1] - c.q_cmd[1] for c in ctxs[1:]]
    assert -0.01 * DEG < lags[0] < 0 and lags[1] < lags[0]
    assert lags[1] == pytest.approx(-0.01 * DEG * np.tanh(30 / 5))


def test_link_growth_changes_one_link_following_a_lagging_temperature():
    """Only a3 (the upper arm) grows; at t = 0 nothing; later the link (lagging) is cooler than the casing it follows."""
    e = effect_from_spec({"name": "link_growth", "link": "a3", "temp_rise_k": 10.0, "tau_s": 1000.0, "lag_s": 500.0})
    robot = irb1200()
    r0 = e.geometry(robot, EffectContext(t_s=0.0))
    r1 = e.geometry(robot, EffectContext(t_s=1000.0))
    changed = np.flatnonzero(r1.params != robot.params)
    assert np.allclose(r0.params, robot.params)
    assert [robot.layout.names[i] for i in changed] == ["a3"]
    assert e.link_temperature_c(1000.0) < e.temperature_c(1000.0)


def test_base_shift_applies_from_its_time_on():
    """Before at_s the base is the true one; from at_s on it is displaced by the stated shift."""
    e = effect_from_spec({"name": "base_shift", "at_s": 100.0, "shift_mm": [0.01, 0, 0]})
    robot = irb1200()
    assert np.allclose(e.geometry(robot, EffectContext(t_s=99.0)).base2meas, robot.base2meas)
    moved = e.geometry(robot, EffectContext(t_s=100.0)).base2meas
    assert np.linalg.norm(moved[:3, 3] - robot.base2meas[:3, 3]) == pytest.approx(1e-5)


def test_plate_flex_moves_the_plate_along_the_flange_axis_by_the_gravity_component():
    """The tool offset lies along the flange z axis and changes sign with the gravity component along it."""
    e = effect_from_spec({"name": "plate_flex", "k_mm_per_g": 0.02})
    robot = irb1200()
    d = []
    for q5 in (0.6, -0.6):
        q = np.array([0, 0.2, 0.1, 0, q5, 0.0])
        T = e.geometry(robot, _ctx(q)).tool2flange
        d.append(T[:3, 3] - robot.tool2flange[:3, 3])
    for v in d:
        assert abs(v[0]) < 1e-15 and abs(v[1]) < 1e-15 and 0 < abs(v[2]) <= 2e-5
    assert np.sign(d[0][2]) != np.sign(d[1][2]) or abs(d[0][2] - d[1][2]) > 1e-7


@pytest.mark.parametrize("spec, field", [
    ({"name": "joint_polynomial", "target_joint": 7, "source_joint": 2, "coefficients_deg": [0.01]}, "target_joint"),
    ({"name": "link_growth", "link": "b3"}, "link"),
    ({"name": "base_shift", "shift_mm": [0, 0, 0]}, "at_s"),
    ({"name": "move_lag", "lag_deg": [0, 0.01], "width_deg": 5.0}, "lag_deg"),
    ({"name": "plate_flex", "k_mm_per_g": 0.01, "stiffness": 3}, "stiffness"),
])
def test_bad_effect_tables_name_the_field(spec, field):
    """A wrong or unknown key is an error naming it."""
    with pytest.raises(ValueError, match=field):
        effect_from_spec(spec)


def test_repeatability_draw_depends_on_pose_index_only():
    """The same pose index gives the same joint offsets (resume), another index a new draw."""
    e = effect_from_spec({"name": "repeatability", "sigma_deg": 0.001, "seed": 7})
    q = np.array([0.1, 0.5, -0.2, 0.3, 0.9, 0.0])
    a = e.joints(q, EffectContext(pose_index=3, q_cmd=q))
    b = e.joints(q, EffectContext(pose_index=3, q_cmd=q, t_s=50.0))
    c = e.joints(q, EffectContext(pose_index=4, q_cmd=q))
    np.testing.assert_array_equal(a, b)
    assert np.max(np.abs(a - c)) > 1e-7
    assert np.max(np.abs(a - q)) < 5 * 0.001 * DEG


def test_repeatability_sigma_gives_the_asked_flange_rp():
    """Joint offsets sized by repeatability_sigma scatter the flange with RP = mean + 3 std of about 0.02 mm."""
    robot = irb1200()
    rng = np.random.default_rng(0)
    q = rng.uniform(-1.0, 1.0, size=(8, 6))
    sigma = repeatability_sigma(robot, q, 0.02e-3)
    e = Repeatability(sigma, seed=1)
    # the effect itself, one arrival per pose index at each configuration
    rp = []
    for k, qk in enumerate(q):
        qs = np.array([e.joints(qk, EffectContext(pose_index=1000 * k + i, q_cmd=qk)) for i in range(300)])
        p = link_frames(robot, qs)[:, -1, :3, 3]
        d = np.linalg.norm(p - p.mean(axis=0), axis=1)
        rp.append(d.mean() + 3 * d.std())
    assert np.mean(rp) == pytest.approx(0.02e-3, rel=0.1)
    assert flange_repeatability(robot, q, 2 * sigma, seed=3) == pytest.approx(0.04e-3, rel=0.1)


def test_repeatability_rejects_negative_sigma():
    """A negative sigma is refused, naming the effect."""
    with pytest.raises(ValueError, match="repeatability"):
        effect_from_spec({"name": "repeatability", "sigma_deg": -0.001})
