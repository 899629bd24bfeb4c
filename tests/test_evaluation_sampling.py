"""Tests of twin.runner.sampling: configurations the station sees, motion pairs, fixed-distance moves."""

import numpy as np
import pytest

from twin.camera import CameraIntrinsics, project_points
from twin.dataset import default_plate
from twin.runner.sampling import (
    SamplingError,
    SamplingOptions,
    look_at_cam2base,
    plate_in_view,
    sample_configurations,
    sample_distance_moves,
    sample_motion_pairs,
    stereo_station,
)
from twin.kinematics import flange2base
from twin.robots import irb1200
from twin.transforms import rotation_angle_between

K = CameraIntrinsics.ideal(2592, 1944, 15.225)
MODEL = irb1200()
PLATE = default_plate()
STATION = stereo_station("front", np.array([1.25, 0.0, 0.75]), np.array([0.55, 0.0, 0.55]), 0.25, K)


def _spheres_base(q):
    F = flange2base(MODEL, q)
    return np.einsum("nij,mj->nmi", F[:, :3, :3], PLATE.spheres_flange) + F[:, None, :3, 3]


def test_look_at_camera_looks_at_target():
    """The OpenCV z axis of a look-at camera points at the target and its image 'down' points down in the world."""
    T = look_at_cam2base([1.0, 0.0, 1.0], [0.0, 0.0, 1.0])
    np.testing.assert_allclose(T[:3, 2], [-1.0, 0.0, 0.0], atol=1e-12)
    assert T[2, 1] < 0  # y (down in the image) points to -z of the world
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)


def test_sampled_configurations_are_in_limits_and_in_view():
    """Every sampled configuration is inside the joint limits and projects all spheres into both images."""
    q = sample_configurations(MODEL, STATION, PLATE, 20, np.random.default_rng(0))
    assert q.shape == (20, 6)
    assert MODEL.within_limits(q).all()
    pts = _spheres_base(q).reshape(-1, 3)
    for cam in STATION.cameras:
        uv = project_points(pts, cam.base2cam, cam.intrinsics)
        assert (uv >= 0).all() and (uv[:, 0] < K.width).all() and (uv[:, 1] < K.height).all()
    assert plate_in_view(MODEL, q, STATION, PLATE).all()


def test_sampling_is_reproducible_from_the_seed():
    """The same seed gives the same configurations; another seed gives others."""
    a = sample_configurations(MODEL, STATION, PLATE, 5, np.random.default_rng(3))
    b = sample_configurations(MODEL, STATION, PLATE, 5, np.random.default_rng(3))
    c = sample_configurations(MODEL, STATION, PLATE, 5, np.random.default_rng(4))
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_plate_in_view_rejects_a_plate_outside_the_image():
    """A station aimed away from the robot sees none of the sampled poses."""
    away = stereo_station("away", np.array([0.0, 3.0, 0.8]), np.array([0.0, 5.0, 0.8]), 0.25, K)
    q = sample_configurations(MODEL, STATION, PLATE, 5, np.random.default_rng(1))
    assert not plate_in_view(MODEL, q, away, PLATE).any()


def test_impossible_station_raises_naming_it():
    """A station whose field of view the robot cannot reach raises SamplingError, not an endless loop."""
    far = stereo_station("far", np.array([4.0, 0.0, 0.8]), np.array([3.3, 0.0, 0.8]), 0.25, K)
    with pytest.raises(SamplingError, match="'far'"):
        sample_configurations(MODEL, far, PLATE, 1, np.random.default_rng(0), SamplingOptions(max_attempts=256))


def test_motion_pairs_have_distinct_orientations():
    """Motion pairs are two different in-view configurations of the same station."""
    a, b = sample_motion_pairs(MODEL, STATION, PLATE, 6, np.random.default_rng(2))
    Fa, Fb = flange2base(MODEL, a), flange2base(MODEL, b)
    assert (rotation_angle_between(Fa[:, :3, :3], Fb[:, :3, :3]) > np.deg2rad(1)).all()


def test_distance_moves_translate_by_exactly_the_distance():
    """On the nominal model the flange moves by exactly the requested distance and does not turn."""
    d = np.array([0.05, 0.06, 0.08, 0.1])
    a, b = sample_distance_moves(MODEL, STATION, PLATE, d, np.random.default_rng(5))
    Fa, Fb = flange2base(MODEL, a), flange2base(MODEL, b)
    np.testing.assert_allclose(np.linalg.norm(Fb[:, :3, 3] - Fa[:, :3, 3], axis=1), d, atol=1e-9)
    np.testing.assert_allclose(rotation_angle_between(Fa[:, :3, :3], Fb[:, :3, :3]), 0.0, atol=1e-9)
    assert plate_in_view(MODEL, b, STATION, PLATE).all()


def test_distance_moves_refuse_nonpositive_distance():
    """A zero or negative distance is refused, naming the argument."""
    with pytest.raises(ValueError, match="distances must be positive"):
        sample_distance_moves(MODEL, STATION, PLATE, np.array([0.05, 0.0]), np.random.default_rng(0))


def test_sampled_joints_keep_a_margin_inside_the_limits():
    """Planned joints stay limit_margin inside the joint limits (room for the compensated command)."""
    opt = SamplingOptions(limit_margin=np.deg2rad(5.0))
    q = sample_configurations(MODEL, STATION, PLATE, 30, np.random.default_rng(9), opt)
    assert np.all(q >= MODEL.q_min + np.deg2rad(5.0) - 1e-12) and np.all(q <= MODEL.q_max - np.deg2rad(5.0) + 1e-12)


def test_plate_pitch_stays_away_from_the_euler_singularity():
    """The plate's ZYX pitch in the base frame stays within max_euler_pitch (eq. 43 is singular at 90 deg)."""
    from twin.transforms import euler_zyx_from_matrix

    opt = SamplingOptions(max_euler_pitch=np.deg2rad(40.0), max_roll=np.pi)
    q = sample_configurations(MODEL, STATION, PLATE, 30, np.random.default_rng(4), opt)
    pitch = euler_zyx_from_matrix(flange2base(MODEL, q)[:, :3, :3])[:, 1]
    assert np.all(np.abs(pitch) <= np.deg2rad(40.0) + 1e-9)


def _plate2base(q):
    from twin.instrument.plate import paper_frame_from_spheres

    return flange2base(MODEL, q) @ MODEL.tool2flange @ paper_frame_from_spheres(PLATE.spheres_flange)


def test_local_motion_pairs_turn_and_shift_within_the_ranges():
    """With turn/shift set, every pair's plate turns by an angle in turn and its centre moves by a length in shift."""
    opt = SamplingOptions(margin_px=40, max_roll=np.deg2rad(45), turn=(np.deg2rad(5), np.deg2rad(18)), shift=(0.05, 0.1))
    a, b = sample_motion_pairs(MODEL, STATION, PLATE, 6, np.random.default_rng(3), opt)
    Pa, Pb = _plate2base(a), _plate2base(b)
    turn = rotation_angle_between(Pa[:, :3, :3], Pb[:, :3, :3])
    shift = np.linalg.norm(Pb[:, :3, 3] - Pa[:, :3, 3], axis=1)
    assert np.all((turn >= np.deg2rad(5) - 1e-7) & (turn <= np.deg2rad(18) + 1e-7))
    assert np.all((shift >= 0.05 - 1e-7) & (shift <= 0.1 + 1e-7))
    assert plate_in_view(MODEL, b, STATION, PLATE, opt).all()


def test_independent_motion_pairs_turn_more_than_local_ones():
    """Without turn the end is an independent configuration: larger turns than a 0-18 deg local motion allows."""
    base = SamplingOptions(margin_px=40, max_roll=np.deg2rad(45))
    a, b = sample_motion_pairs(MODEL, STATION, PLATE, 8, np.random.default_rng(4), base)
    turn = rotation_angle_between(_plate2base(a)[:, :3, :3], _plate2base(b)[:, :3, :3])
    assert turn.max() > np.deg2rad(18)


def test_turning_distance_moves_keep_the_distance_and_turn_in_range():
    """With distance_turn set, the plate centre still moves by exactly the distance and the plate turns in range."""
    opt = SamplingOptions(margin_px=40, distance_turn=(np.deg2rad(20), np.deg2rad(45)))
    d = np.array([0.05, 0.1])
    a, b = sample_distance_moves(MODEL, STATION, PLATE, d, np.random.default_rng(5), opt)
    Pa, Pb = _plate2base(a), _plate2base(b)
    np.testing.assert_allclose(np.linalg.norm(Pb[:, :3, 3] - Pa[:, :3, 3], axis=1), d, atol=1e-9)
    turn = rotation_angle_between(Pa[:, :3, :3], Pb[:, :3, :3])
    assert np.all((turn >= np.deg2rad(20) - 1e-7) & (turn <= np.deg2rad(45) + 1e-7))


@pytest.mark.parametrize("kw", [
    {"turn": (0.3, 0.1)}, {"turn": (-0.1, 0.1)}, {"shift": (0.0, -0.01)}, {"distance_turn": (0.0, 4.0)},
    {"max_joint_step": 0.0},
])
def test_bad_motion_ranges_are_refused_naming_them(kw):
    """A reversed, negative or too-large motion range is a ValueError naming the option."""
    with pytest.raises(ValueError, match=next(iter(kw))):
        SamplingOptions(**kw)
