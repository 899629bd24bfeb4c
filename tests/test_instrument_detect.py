"""Sphere detection on analytic (ray-traced, anti-aliased) images with a known camera."""

import numpy as np
import pytest

from twin.camera import CameraIntrinsics, project_points
from twin.instrument.detect import DetectorConfig, as_gray, detect_spheres, estimate_noise
from twin.instrument.synthetic import add_sensor_noise, render_spheres

# half the MV-EM500M's resolution keeps the tests fast; the geometry scales with it
CAM = CameraIntrinsics.ideal(1296, 972, 15.225)
R = 0.0127
EYE = np.eye(4)


def _img(centres, seed=0, noise=2.0, **kw):
    rng = np.random.default_rng(seed)
    return add_sensor_noise(render_spheres(CAM, EYE, np.atleast_2d(centres), R, supersample=3, **kw), noise, rng)


def test_side_lit_sphere_centre_to_hundredths_of_a_pixel():
    """A side-lit off-axis sphere's corrected centre lands within 0.03 px of the projected true centre."""
    C = np.array([0.075, 0.05, 0.7])
    (s,) = detect_spheres(_img(C), CAM, R)
    assert s.ok, s.reason
    assert np.linalg.norm(s.centre_px - project_points(C[None], EYE, CAM)[0]) < 0.03


def test_uncorrected_ellipse_centre_shows_the_perspective_bias():
    """The plain ellipse centre of the same outline is off by the perspective bias (> 0.1 px here)."""
    C = np.array([0.075, 0.05, 0.7])
    (s,) = detect_spheres(_img(C), CAM, R)
    true_px = project_points(C[None], EYE, CAM)[0]
    assert np.linalg.norm(s.centre_px_uncorrected - true_px) > 0.1
    assert np.linalg.norm(s.centre_px_uncorrected - true_px) > 5 * np.linalg.norm(s.centre_px - true_px)


def test_single_camera_distance_from_known_radius():
    """The cone's half-angle and the known radius give the distance to within 0.3 %."""
    C = np.array([-0.04, 0.02, 0.85])
    (s,) = detect_spheres(_img(C), CAM, R)
    assert abs(s.distance / np.linalg.norm(C) - 1) < 3e-3
    assert np.linalg.norm(s.centre_mono() - C) < 0.003


@pytest.mark.parametrize("light", [(1.0, -0.3, -0.4), (-1.0, 0.5, -0.2), (0.0, 1.0, -0.3)])
def test_shading_direction_does_not_move_the_centre(light):
    """Whatever side the light comes from, the centre stays within 0.03 px."""
    C = np.array([0.02, -0.03, 0.65])
    (s,) = detect_spheres(_img(C, light_dir=light), CAM, R)
    assert s.ok and np.linalg.norm(s.centre_px - project_points(C[None], EYE, CAM)[0]) < 0.03


def test_specular_highlight_does_not_move_the_centre():
    """A bright highlight inside the outline leaves the outline-based centre unchanged."""
    C = np.array([0.05, 0.03, 0.7])
    (s,) = detect_spheres(_img(C, specular=120.0, light_dir=(0.3, -0.3, -1.0)), CAM, R)
    assert s.ok and np.linalg.norm(s.centre_px - project_points(C[None], EYE, CAM)[0]) < 0.03


def test_sphere_out_of_frame_is_flagged():
    """A sphere cut by the image border is rejected as out_of_frame, with no centre."""
    for shift_px in (30.0, -50.0):  # centre outside, and centre inside with the outline cut
        x = (CAM.width - 1 - CAM.cx + shift_px) / CAM.fx * 0.7
        (s,) = detect_spheres(_img([x, 0.0, 0.7]), CAM, R)
        assert not s.ok and s.reason == "out_of_frame" and s.ray is None


def test_occluded_sphere_is_flagged():
    """A bar (the arm) in front of part of the outline leaves the sphere unmeasured, reason occluded."""
    img = render_spheres(CAM, EYE, np.array([[0.0, 0.0, 0.7]]), R, supersample=3)
    img[:, 690:760] = 140.0  # covers the right part of the sphere (x from about 582 to 714)
    s = detect_spheres(add_sensor_noise(img, 2.0, np.random.default_rng(0)), CAM, R)
    main = min(s, key=lambda c: np.linalg.norm(c.coarse_px - [CAM.cx, CAM.cy]))
    assert not main.ok and main.reason == "occluded" and main.ray is None
    assert not any(c.ok for c in s)


def test_merged_spheres_are_flagged():
    """Two spheres overlapping in the image are both rejected (merged), neither gets a centre."""
    res = detect_spheres(_img([[0.0, 0.0, 0.7], [0.02, 0.005, 0.75]]), CAM, R)
    assert len(res) == 2 and all(not s.ok and s.reason == "merged" for s in res)


def test_blank_image_has_no_candidates():
    """A featureless noisy image yields no candidate at all (and no exception)."""
    img = add_sensor_noise(np.full((972, 1296), 30.0), 2.0, np.random.default_rng(0))
    assert detect_spheres(img, CAM, R) == []


def test_far_sphere_is_too_small():
    """A sphere well beyond the working range (2.6 m; the default range ends at 1.5 m) is too_small."""
    (s,) = detect_spheres(_img([0.0, 0.0, 2.6]), CAM, R)
    assert not s.ok and s.reason == "too_small"
    assert detect_spheres(_img([0.0, 0.0, 2.6]), CAM, R, DetectorConfig(distance_range=(0.4, 3.0)))[0].ok


def test_noise_estimate_matches_added_noise():
    """The robust noise estimate recovers the added Gaussian sigma."""
    img = add_sensor_noise(np.full((400, 600), 80.0), 3.0, np.random.default_rng(4))
    assert abs(estimate_noise(img) - 3.0) < 0.3


def test_rgb_input_is_accepted():
    """An RGB image gives the same measurement as its greyscale version."""
    g = _img([0.01, 0.0, 0.7])
    rgb = np.repeat(g[:, :, None], 3, axis=2)
    assert as_gray(rgb).shape == g.shape
    (a,) = detect_spheres(g, CAM, R)
    (b,) = detect_spheres(rgb, CAM, R)
    assert np.allclose(a.centre_px, b.centre_px)


def test_bad_arguments_raise():
    """A wrong image size or a non-positive radius is a ValueError naming the argument."""
    with pytest.raises(ValueError, match="image"):
        detect_spheres(np.zeros((10, 10), np.uint8), CAM, R)
    with pytest.raises(ValueError, match="sphere_radius"):
        detect_spheres(np.zeros((972, 1296), np.uint8), CAM, -1.0)
    with pytest.raises(ValueError, match="distance_range"):
        DetectorConfig(distance_range=(1.0, 0.5))
