"""Compensation on chains without a closed-form inverse (twin.estimator.compensation): position-only targets of a
point marker, the orientation held; the point a position target places; damped least squares where Newton stops."""

from dataclasses import replace

import numpy as np
import pytest

from twin.dataset import Plate, robot_from_spec
from twin.estimator import calibrate, compensation
from twin.estimator.compensation import compensation_position, point_frame
from twin.estimator.simulate import random_configurations, simulate_dataset
from twin.kinematics import UnreachableError, tool2base
from twin.transforms import matrix_to_rotvec, pose6_to_transform
from twin.units import M_PER_MM, RAD_PER_DEG

ARM7 = {"name": "arm7", "convention": "dh", "theta_deg": [0] * 7, "d_mm": [340, 10, 400, 5, 400, 8, 126],
        "a_mm": [20, 30, 25, 15, 10, 12, 0], "alpha_deg": [-90, 90, 90, -90, -90, 90, 0],
        "q_min_deg": [-170, -120, -170, -120, -170, -120, -175], "q_max_deg": [170, 120, 170, 120, 170, 120, 175]}
ARM3 = {"name": "arm3", "convention": "dh", "theta_deg": [0, 0, 0], "d_mm": [300, 0, 0], "a_mm": [50, 400, 350],
        "alpha_deg": [90, 0, 0], "q_min_deg": [-170, -100, -150], "q_max_deg": [170, 100, 150]}
B = pose6_to_transform(np.array([1.0, 0.2, 0.3, 0.1, -0.2, 0.3]))


def _calibration(spec, seed, *, kind="spheres", points=((0.0, 0.0, 0.08),)):
    """A calibration of ``spec`` with small errors in every length and angle, noise-free, one point or a pose."""
    rng = np.random.default_rng(seed)
    nom = robot_from_spec(spec)
    dev = np.zeros(nom.layout.size)
    for k, n in enumerate(nom.layout.names):
        if not n.startswith("base_") and not n.startswith("tool_"):
            dev[k] = rng.normal(0, 0.3 * M_PER_MM if nom.layout.units[k] == "m" else 0.06 * RAD_PER_DEG)
    truth = nom.perturbed(dev)
    q = random_configurations(nom, 60, rng)
    plate = Plate(0.0, np.array(points))
    ds, _ = simulate_dataset(truth, q, robot_spec=spec, plate=plate, kind=kind, base2meas={"0": B},
                             noise_position=1e-6, noise_orientation=1e-6, rng=rng)
    return calibrate(ds), nom, rng


@pytest.fixture(scope="module")
def arm7():
    return _calibration(ARM7, 1)


@pytest.fixture(scope="module")
def arm3():
    return _calibration(ARM3, 2)


def test_a_position_target_of_a_redundant_arm_is_reached_holding_the_reference_orientation(arm7):
    """Seven joints: the point reaches each target on the identified model (1e-9 m) and the tool keeps the orientation
    it has at the reference joints (1e-9 rad)."""
    cal, nom, rng = arm7
    mid, half = 0.5 * (nom.q_min + nom.q_max), 0.5 * (nom.q_max - nom.q_min)
    q_ref = mid + 0.7 * half * rng.uniform(-1, 1, (8, 7))  # the limits away: the orientation can be held
    q_ref[:, 3] = rng.choice([-1, 1], 8) * rng.uniform(30, 90, 8) * RAD_PER_DEG  # the elbow bent: 1 cm more is in reach
    robot = cal.robot.with_frames(base2meas=np.eye(4))
    T_ref = tool2base(robot, q_ref) @ point_frame(cal)
    p = T_ref[:, :3, 3] + rng.normal(0, 0.01, (8, 3))
    res = compensation_position(cal, p, q_ref)
    T = tool2base(robot, res.q) @ point_frame(cal)
    assert np.abs(T[:, :3, 3] - p).max() < 1e-9 and res.position_error.max() < 1e-9
    assert np.abs(matrix_to_rotvec(T[:, :3, :3] @ np.swapaxes(T_ref[:, :3, :3], 1, 2))).max() < 1e-9
    assert res.rotation_error.max() < 1e-9


def test_at_a_joint_limit_the_position_is_reached_and_the_orientation_kept_near(arm7):
    """A reference joint 0.5 deg from its limit, where holding the orientation would cross it: the position is
    reached within the limits and the orientation stays within 0.05 rad of the held one."""
    cal, nom, rng = arm7
    q_ref = np.array([[4.5, 69.8, 169.5, -5.8, -69.2, 19.1, -44.9]]) * RAD_PER_DEG
    robot = cal.robot.with_frames(base2meas=np.eye(4))
    p = (tool2base(robot, q_ref) @ point_frame(cal))[:, :3, 3] + [[0.0064, -0.0039, 0.0075]]
    res = compensation_position(cal, p, q_ref)
    assert res.position_error.max() < 1e-9 and robot.within_limits(res.q).all()
    assert 1e-6 < res.rotation_error.max() < 0.05


def test_a_position_target_of_a_three_joint_arm_is_reached_the_orientation_as_it_comes(arm3):
    """Three joints: the point reaches the target (1e-9 m) within the joint limits; the orientation cannot be held
    and its departure is reported."""
    cal, nom, rng = arm3
    q_ref = random_configurations(nom, 6, rng)
    robot = cal.robot.with_frames(base2meas=np.eye(4))
    q_t = np.clip(q_ref + rng.normal(0, 0.05, q_ref.shape), nom.q_min, nom.q_max)
    p = (tool2base(robot, q_t) @ point_frame(cal))[:, :3, 3]
    res = compensation_position(cal, p, q_ref)
    assert np.abs((tool2base(robot, res.q) @ point_frame(cal))[:, :3, 3] - p).max() < 1e-9
    assert robot.within_limits(res.q).all() and res.rotation_error.max() > 1e-6


def test_a_position_out_of_reach_is_refused_naming_the_target(arm3):
    """A point 10 m away: UnreachableError naming the target's row."""
    cal, nom, rng = arm3
    p = np.array([[0.3, 0.2, 0.5], [10.0, 0.0, 0.0]])
    with pytest.raises(UnreachableError, match=r"targets \[1\]: the identified model does not reach their position"):
        compensation_position(cal, p, np.zeros(3))


def test_a_reachable_pose_of_a_three_joint_arm_is_compensated(arm3):
    """A pose the identified three-joint arm takes (not the nominal one): the nominal answer is only a start and the
    identified model reaches it (1e-9 m, 1e-9 rad)."""
    cal, nom, rng = arm3
    q_ref = random_configurations(nom, 6, rng)
    T = tool2base(cal.robot.with_frames(base2meas=np.eye(4)), np.clip(q_ref + 0.02, nom.q_min, nom.q_max))
    res = compensation(cal, T, q_ref)
    assert res.position_error.max() < 1e-8 and res.rotation_error.max() < 1e-8


def test_the_point_of_a_position_target_is_the_marker_or_the_pose_origin(arm3):
    """A point calibration places its first marker; a pose calibration, or a pose read as three points on the tool's
    axes, places the tool origin."""
    cal, _, _ = arm3
    assert np.allclose(point_frame(cal)[:3, 3], cal.spheres_tool[0]) and np.linalg.norm(cal.spheres_tool[0]) > 0.05
    assert np.array_equal(point_frame(replace(cal, measurement="pose")), np.eye(4))
    assert np.array_equal(point_frame(replace(cal, measurement="spheres", spheres_tool=0.1 * np.eye(3))), np.eye(4))
