"""Tests of twin.camera: the MuJoCo/OpenCV flip, projection and distortion."""

import numpy as np

from twin.camera import (
    CameraIntrinsics,
    distort_normalized,
    focal_px_from_fovy,
    mujoco_to_opencv_cam2world,
    opencv_to_mujoco_cam2world,
    project_points,
    undistort_normalized,
)
from twin.transforms import invert_transform, rotvec_to_matrix


def test_flip_puts_points_in_front_of_a_mujoco_camera_at_positive_z():
    """A point on a MuJoCo camera's -z axis lies on OpenCV's +z axis; MuJoCo +y (up) is OpenCV -y (down)."""
    R_mj = rotvec_to_matrix(np.array([0.3, -0.2, 0.5]))
    pos = np.array([0.1, -0.7, 0.4])
    T = mujoco_to_opencv_cam2world(pos, R_mj.reshape(9))
    world2cam = invert_transform(T)
    ahead = pos - 2.0 * R_mj[:, 2]  # 2 m along the MuJoCo camera's -z
    up = pos + 0.1 * R_mj[:, 1]
    pc = world2cam[:3, :3] @ ahead + world2cam[:3, 3]
    pu = world2cam[:3, :3] @ up + world2cam[:3, 3]
    assert np.allclose(pc, [0, 0, 2.0])
    assert np.allclose(pu, [0, -0.1, 0])
    p2, R2 = opencv_to_mujoco_cam2world(T)
    assert np.allclose(p2, pos) and np.allclose(R2, R_mj)


def test_mv_em500m_focal_length_from_fovy():
    """The MV-EM500M (2.2 um pixels, 16 mm lens, 1944 rows) has f = 7272.7 px at fovy 15.225 deg."""
    assert abs(focal_px_from_fovy(15.225, 1944) - 16e-3 / 2.2e-6) < 1.0


def test_undistort_inverts_distort():
    """undistort_normalized inverts distort_normalized over the field of view to 1e-12."""
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.15, 0.15, (200, 2))
    dist = (-0.12, 0.08, 1e-4, -2e-4, 0.01)
    assert np.abs(undistort_normalized(distort_normalized(xy, dist), dist) - xy).max() < 1e-12


def test_project_points_principal_point_and_scaling():
    """A point on the optical axis lands on (cx, cy); half resolution keeps the pixel-centre convention."""
    intr = CameraIntrinsics.ideal(2592, 1944, 15.225)
    assert np.allclose(project_points(np.array([[0, 0, 0.7]]), np.eye(4), intr), [[1295.5, 971.5]])
    half = intr.scaled(0.5)
    assert (half.width, half.height) == (1296, 972)
    p = np.array([[0.01, -0.02, 0.7]])
    assert np.allclose((project_points(p, np.eye(4), intr) + 0.5) / 2 - 0.5, project_points(p, np.eye(4), half))


def test_discs_in_image_against_sampled_disc_boundaries():
    """A disc is inside exactly when every point of its boundary lies within [0, width-1] x [0, height-1] (the
    boundary sampled densely, including its four extreme points)."""
    from twin.camera import discs_in_image

    rng = np.random.default_rng(2)
    w, h = 64, 48
    uv = rng.uniform(-5, 70, size=(400, 2))
    r = rng.uniform(0.0, 12.0, size=400)
    t = np.linspace(0, 2 * np.pi, 721)  # every 0.5 deg, 0/90/180/270 deg included
    bx = uv[:, :1] + r[:, None] * np.cos(t)
    by = uv[:, 1:] + r[:, None] * np.sin(t)
    oracle = np.all((bx >= -1e-9) & (bx <= w - 1 + 1e-9) & (by >= -1e-9) & (by <= h - 1 + 1e-9), axis=1)
    got = discs_in_image(uv, r, w, h)
    assert got.shape == (400,) and 50 < got.sum() < 350
    np.testing.assert_array_equal(got, oracle)


def test_spheres_in_view_is_projection_plus_disc_test():
    """spheres_in_view(centres, intr, radius, margin) equals: every sphere in front, and project_points' pixels
    with discs of fx*r/z + margin inside the image (discs_in_image), on random plate poses."""
    from twin.camera import CameraIntrinsics, discs_in_image, project_points, spheres_in_view

    intr = CameraIntrinsics(800.0, 805.0, 319.5, 239.5, 640, 480, (-0.1, 0.05, 0.001, -0.001, 0.0))
    rng = np.random.default_rng(5)
    centres = rng.uniform([-0.4, -0.3, 0.5], [0.4, 0.3, 1.2], size=(300, 1, 3)) + rng.normal(scale=0.05, size=(300, 3, 3))
    r, margin = 0.0127, 20.0
    got = spheres_in_view(centres, intr, radius=r, margin_px=margin, min_depth=0.05)
    uv = project_points(centres.reshape(-1, 3), np.eye(4), intr).reshape(-1, 3, 2)
    oracle = discs_in_image(uv, intr.fx * r / centres[..., 2] + margin, intr.width, intr.height).all(axis=1)
    assert got.shape == (300,) and 30 < got.sum() < 270
    np.testing.assert_array_equal(got, oracle)


def test_spheres_in_view_rejects_a_sphere_behind_or_too_close():
    """A plate with one sphere at or behind min_depth is out of view, wherever its pixel would fall."""
    from twin.camera import CameraIntrinsics, spheres_in_view

    intr = CameraIntrinsics.ideal(640, 480, 40.0)
    plate = np.array([[0.0, 0.0, 0.7], [0.02, 0.0, 0.7], [0.0, 0.02, 0.7]])
    assert spheres_in_view(plate, intr, radius=0.01)
    for z in (0.05, 0.0, -0.7):
        p = plate.copy()
        p[1, 2] = z
        assert not spheres_in_view(p, intr, radius=0.01, min_depth=0.05)
