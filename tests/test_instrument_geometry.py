"""Instrument geometry: rays, the sphere's tangent cone, ellipses, triangulation (no rendering)."""

import cv2
import numpy as np
import pytest

from twin.camera import CameraIntrinsics, project_points
from twin.instrument.geometry import (
    ellipse_of_cone,
    epipolar_distance_px,
    fit_cone,
    fit_cone_robust,
    fit_ellipse,
    pixels_to_rays,
    rays_to_pixels,
    triangulate_rays,
    undistort_pixels,
)
from twin.instrument.synthetic import look_at_world2cam
from twin.transforms import invert_transform

LEFT = CameraIntrinsics.ideal(2592, 1944, 15.225, (-0.05, 0.1, 2e-4, -1e-4, 0.0))
RIGHT = CameraIntrinsics(7280.0, 7275.0, 1300.0, 965.0, 2592, 1944, (-0.04, 0.05, -1e-4, 2e-4, 0.0))
W2L = look_at_world2cam([-0.125, 0.0, 0.0], [0.0, 0.0, 0.7], up=(0, -1, 0))
W2R = look_at_world2cam([0.125, 0.0, 0.0], [0.0, 0.0, 0.7], up=(0, -1, 0))
L2R = W2R @ invert_transform(W2L)


def _cone_rays(axis, half_angle, n, phase=0.0):
    """Exact unit rays on the cone around ``axis``."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    u = np.cross(a, [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(a, u)
    t = phase + np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.cos(half_angle) * a + np.sin(half_angle) * (np.cos(t)[:, None] * u + np.sin(t)[:, None] * v)


def test_project_then_triangulate_round_trip():
    """Points projected by two known distorted cameras triangulate back to themselves (no rendering)."""
    rng = np.random.default_rng(0)
    P = np.stack([rng.uniform(-0.1, 0.1, 200), rng.uniform(-0.08, 0.08, 200), rng.uniform(0.5, 1.0, 200)], axis=1)
    pl = project_points(P, W2L, LEFT)
    pr = project_points(P, W2R, RIGHT)
    X = triangulate_rays(pixels_to_rays(pl, LEFT), pixels_to_rays(pr, RIGHT), L2R)
    P_left = P @ W2L[:3, :3].T + W2L[:3, 3]
    assert np.max(np.linalg.norm(X - P_left, axis=1)) < 1e-9


def test_undistort_pixels_matches_opencv():
    """The vectorised undistortion agrees with cv2.undistortPoints run to convergence."""
    rng = np.random.default_rng(1)
    px = rng.uniform([0, 0], [2592, 1944], size=(300, 2))
    ours = undistort_pixels(px, LEFT)
    cv = cv2.undistortPoints(px.reshape(-1, 1, 2), LEFT.K, LEFT.dist_array, criteria=(3, 100, 1e-15)).reshape(-1, 2)
    assert np.max(np.abs(ours - cv)) * LEFT.fx < 1e-7


def test_rays_to_pixels_inverts_pixels_to_rays():
    """pixels -> rays -> pixels is the identity (distortion included)."""
    rng = np.random.default_rng(2)
    px = rng.uniform([10, 10], [2580, 1930], size=(100, 2))
    assert np.max(np.abs(rays_to_pixels(pixels_to_rays(px, RIGHT), RIGHT) - px)) < 1e-6


def test_cone_fit_recovers_exact_axis_and_angle():
    """Exact tangent rays of a sphere give back its centre direction and half-angle."""
    C = np.array([0.08, -0.05, 0.7])
    th = np.arcsin(0.0127 / np.linalg.norm(C))
    axis, half = fit_cone(_cone_rays(C, th, 50))
    assert np.degrees(np.arccos(np.clip(axis @ C / np.linalg.norm(C), -1, 1))) < 1e-9
    assert abs(half - th) < 1e-12


def test_robust_cone_fit_rejects_outliers():
    """A fifth of the edge rays pushed 3 px off the outline are rejected and do not move the axis."""
    rng = np.random.default_rng(3)
    C = np.array([-0.06, 0.04, 0.8])
    th = np.arcsin(0.0127 / np.linalg.norm(C))
    f = 7272.7
    rays = _cone_rays(C, th, 400) + rng.normal(0, 0.05 / f, (400, 3))
    bad = rng.choice(400, 80, replace=False)
    c = C / np.linalg.norm(C)
    out = rays[bad] - np.outer(rays[bad] @ c, c)  # radial (outward) direction of each bad ray
    rays[bad] += 3.0 / f * out / np.linalg.norm(out, axis=1, keepdims=True)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    fit = fit_cone_robust(rays, scale_rad=1 / f)
    err_px = np.arccos(np.clip(fit.axis @ C / np.linalg.norm(C), -1, 1)) * f
    assert err_px < 0.02
    assert not fit.inliers[bad].any() and fit.inliers.sum() >= 300


def test_ellipse_centre_is_biased_but_cone_axis_is_not():
    """The fitted outline ellipse's centre is off the projected sphere centre off-axis (perspective bias)."""
    cam = CameraIntrinsics.ideal(2592, 1944, 15.225)
    C = np.array([0.09, 0.06, 0.7])
    th = np.arcsin(0.0127 / np.linalg.norm(C))
    rays = _cone_rays(C, th, 720)
    pts = rays_to_pixels(rays, cam)
    centre_true = project_points(C[None], np.eye(4), cam)[0]
    ell = fit_ellipse(pts)
    ell_cone = ellipse_of_cone(C / np.linalg.norm(C), th, cam)
    assert np.linalg.norm(ell.centre - ell_cone.centre) < 1e-3  # the fit finds the cone's ellipse
    bias = np.linalg.norm(ell.centre - centre_true)
    assert 0.2 < bias < 1.0  # the bias is real at this offset (0.2-0.5 px per the design card)
    axis, _ = fit_cone(pixels_to_rays(pts, cam))
    assert np.linalg.norm(rays_to_pixels(axis[None], cam)[0] - centre_true) < 1e-6


def test_ellipse_bias_vanishes_on_axis():
    """On the optical axis the outline is a circle centred on the projected centre."""
    cam = CameraIntrinsics.ideal(2592, 1944, 15.225)
    C = np.array([0.0, 0.0, 0.7])
    e = ellipse_of_cone(C / 0.7, np.arcsin(0.0127 / 0.7), cam)
    assert np.linalg.norm(e.centre - [cam.cx, cam.cy]) < 1e-9
    assert abs(e.axis_ratio - 1) < 1e-12


def test_epipolar_distance_zero_for_true_match_large_for_wrong_one():
    """Corresponding rays lie on each other's epipolar lines; a ray of another point does not."""
    P = np.array([[0.02, 0.01, 0.7], [-0.06, 0.03, 0.75]])
    rl = pixels_to_rays(project_points(P, W2L, LEFT), LEFT)
    rr = pixels_to_rays(project_points(P, W2R, RIGHT), RIGHT)
    good = epipolar_distance_px(rl, rr, L2R, RIGHT.fx)
    wrong = epipolar_distance_px(rl, rr[::-1], L2R, RIGHT.fx)
    assert np.all(good < 1e-6)
    assert np.all(wrong > 50)


def test_bad_inputs_raise_value_error():
    """Too few rays or points, and backward rays, are refused with a ValueError naming the argument."""
    with pytest.raises(ValueError, match="rays"):
        fit_cone(np.eye(3)[:2])
    with pytest.raises(ValueError, match="points"):
        fit_ellipse(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="rays"):
        rays_to_pixels(np.array([[0.0, 0.0, -1.0]]), LEFT)
    with pytest.raises(ValueError, match="ray_left"):
        triangulate_rays(np.ones((2, 3)), np.ones((3, 3)), L2R)
