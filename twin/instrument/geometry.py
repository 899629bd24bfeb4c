"""Geometry of the instrument: pixel rays, the sphere's tangent cone, ellipses, triangulation.

Pure numpy/OpenCV functions on arrays; no images and no truth.

The perspective bias, and why the cone removes it
-------------------------------------------------
A sphere of radius ``R`` with centre ``C`` (camera frame) is seen along the rays ``d`` that touch it:
the tangent cone ``{d : angle(d, C) = theta}`` with ``sin(theta) = R / |C|``. In undistorted normalized
image coordinates its outline is the conic ``x^T (c c^T - cos^2(theta) I) x = 0`` (``c = C / |C|``,
``x = (u, v, 1)``): an ellipse whose centre is *not* the projection of ``c`` as soon as ``c`` is off the
optical axis (the near side of the sphere is magnified more than the far side). Here the shift is
0.2-0.5 px, and it does not cancel between the two cameras of a stereo rig.

The outline rays, normalised to unit length, lie on a small circle of the unit sphere: the plane
``c . d = cos(theta)``. Fitting that plane to the unit rays of the measured edge points (a total
least-squares plane fit: three parameters, linear, no ellipse needed) recovers the true centre ray
``c`` and the half-angle ``theta`` directly. The algebraic residual ``c . d_i - cos(theta)`` equals
``sin(theta) * (theta - angle(c, d_i))`` to first order, the same factor for every point, so the plane
fit is the geometric (angular) fit up to second order. With the sphere's radius known, the cone also
gives the distance ``|C| = R / sin(theta)`` from one camera (used for labelling and sanity checks).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..camera import CameraIntrinsics
from ..units import rad_to_deg

__all__ = [
    "ConeFit",
    "Ellipse",
    "undistort_pixels",
    "pixels_to_rays",
    "rays_to_pixels",
    "fit_cone",
    "fit_cone_robust",
    "fit_ellipse",
    "ellipse_of_cone",
    "triangulate_rays",
    "epipolar_distance_px",
]


def undistort_pixels(pixels: np.ndarray, intr: CameraIntrinsics, *, tol: float = 1e-14, max_iter: int = 50) -> np.ndarray:
    """Undistorted normalized coordinates ``(n, 2)`` of distorted pixels ``(n, 2)`` [px].

    OpenCV's fixed-point inversion of its distortion model (as ``cv2.undistortPoints``), vectorised and run
    to convergence (``tol`` in normalized units, about 1e-10 px here) rather than a fixed count.
    """
    px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    xd = np.stack([(px[:, 0] - intr.cx) / intr.fx, (px[:, 1] - intr.cy) / intr.fy], axis=1)
    k1, k2, p1, p2, k3 = intr.dist
    if k1 == k2 == p1 == p2 == k3 == 0.0:
        return xd
    x, y = xd[:, 0].copy(), xd[:, 1].copy()
    for _ in range(max_iter):
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        xn = (xd[:, 0] - dx) / radial
        yn = (xd[:, 1] - dy) / radial
        done = max(np.max(np.abs(xn - x), initial=0.0), np.max(np.abs(yn - y), initial=0.0)) < tol
        x, y = xn, yn
        if done:
            break
    return np.stack([x, y], axis=1)


def pixels_to_rays(pixels: np.ndarray, intr: CameraIntrinsics) -> np.ndarray:
    """Unit rays ``(n, 3)`` in the OpenCV camera frame of distorted pixel coordinates ``(n, 2)`` [px]."""
    xy = undistort_pixels(pixels, intr)
    d = np.concatenate([xy, np.ones((xy.shape[0], 1))], axis=1)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def rays_to_pixels(rays: np.ndarray, intr: CameraIntrinsics) -> np.ndarray:
    """Distorted pixel coordinates ``(n, 2)`` [px] of camera-frame directions ``(n, 3)`` (``z > 0``)."""
    d = np.asarray(rays, dtype=np.float64).reshape(-1, 3)
    if np.any(d[:, 2] <= 0):
        raise ValueError("rays: every direction must point forward (z > 0 in the camera frame)")
    pts, _ = cv2.projectPoints(d, np.zeros(3), np.zeros(3), intr.K, intr.dist_array)
    return pts.reshape(-1, 2)


@dataclass(frozen=True)
class ConeFit:
    """A circular cone of rays fitted to a sphere's outline (camera frame).

    ``axis`` ``(3,)``: unit ray through the sphere's centre; ``half_angle`` [rad]; ``residual_rad`` ``(n,)``:
    signed angular distance of every input ray from the cone (positive outside); ``inliers`` ``(n,)`` bool.
    """

    axis: np.ndarray
    half_angle: float
    residual_rad: np.ndarray
    inliers: np.ndarray

    def distance(self, sphere_radius: float) -> float:
        """Distance [m] from the camera centre to the sphere's centre, ``R / sin(theta)``."""
        return float(sphere_radius / np.sin(self.half_angle))

    def centre(self, sphere_radius: float) -> np.ndarray:
        """Sphere centre ``(3,)`` [m] in the camera frame from one camera and the known radius."""
        return self.axis * self.distance(sphere_radius)


def fit_cone(rays: np.ndarray) -> tuple[np.ndarray, float]:
    """Total least-squares plane ``axis . d = cos(half_angle)`` through unit rays ``(n, 3)``, ``n >= 3``.

    Returns ``(axis (3,), half_angle [rad])``; see the module docstring for why this is the cone fit.
    """
    d = np.asarray(rays, dtype=np.float64).reshape(-1, 3)
    if d.shape[0] < 3:
        raise ValueError(f"rays: need at least 3 rays to fit a cone, got {d.shape[0]}")
    m = d.mean(axis=0)
    _, _, vt = np.linalg.svd(d - m, full_matrices=False)
    n = vt[2]
    h = float(n @ m)
    if h < 0:
        n, h = -n, -h
    return n, float(np.arccos(np.clip(h, -1.0, 1.0)))


def _cone_residual(d: np.ndarray, axis: np.ndarray, half_angle: float) -> np.ndarray:
    # angle between unit d and the axis; sqrt(1 - c^2) keeps ~1e-13 relative precision at these angles
    c = d @ axis
    return np.arctan2(np.sqrt(np.maximum(0.0, 1.0 - c * c)), c) - half_angle


def fit_cone_robust(
    rays: np.ndarray,
    *,
    scale_rad: float,
    k_sigma: float = 3.5,
    floor_rad: float | None = None,
    iterations: int = 4,
) -> ConeFit:
    """Cone fit with iterative outlier rejection.

    Rays whose angular residual differs from the inliers' median residual by more than
    ``max(k_sigma * s, floor_rad)`` are dropped and the cone refitted, where ``s = 1.4826 * MAD`` of the
    inliers' residuals. ``scale_rad`` is one pixel in radians (``1 / f``);
    ``floor_rad`` defaults to 0.3 px so that a perfect noiseless outline does not reject half its points.
    """
    d = np.asarray(rays, dtype=np.float64).reshape(-1, 3)
    if d.shape[0] < 5:
        raise ValueError(f"rays: need at least 5 rays for a robust cone fit, got {d.shape[0]}")
    floor = 0.3 * scale_rad if floor_rad is None else floor_rad
    inl = np.ones(d.shape[0], dtype=bool)
    axis, th = fit_cone(d)
    for _ in range(iterations):
        r = _cone_residual(d, axis, th)
        ri = r[inl]
        med = np.median(ri)  # outliers on one side bias the first fit: judge against the median residual
        s = 1.4826 * np.median(np.abs(ri - med))
        new = np.abs(r - med) <= max(k_sigma * s, floor)
        if new.sum() < 5:
            break
        if np.array_equal(new, inl):
            break
        inl = new
        axis, th = fit_cone(d[inl])
    r = _cone_residual(d, axis, th)
    return ConeFit(axis=axis, half_angle=th, residual_rad=r, inliers=inl)


@dataclass(frozen=True)
class Ellipse:
    """An ellipse in pixel coordinates: centre ``(cx, cy)`` [px], full axes ``(width, height)`` [px] and
    rotation ``angle_deg`` (OpenCV's ``RotatedRect`` convention)."""

    cx: float
    cy: float
    width: float
    height: float
    angle_deg: float

    @property
    def centre(self) -> np.ndarray:
        return np.array([self.cx, self.cy])

    @property
    def axis_ratio(self) -> float:
        """Minor over major axis (1 for a circle)."""
        a, b = sorted((self.width, self.height))
        return float(a / b) if b > 0 else 0.0

    def as_tuple(self) -> tuple[float, float, float, float, float]:
        return (self.cx, self.cy, self.width, self.height, self.angle_deg)


def fit_ellipse(points: np.ndarray) -> Ellipse:
    """Direct least-squares ellipse (Fitzgibbon, ``cv2.fitEllipseDirect``) through points ``(n, 2)`` [px]."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if p.shape[0] < 6:
        raise ValueError(f"points: need at least 6 points to fit an ellipse, got {p.shape[0]}")
    # conditioning: fit around the centroid, then shift back
    m = p.mean(axis=0)
    (cx, cy), (w, h), ang = cv2.fitEllipseDirect((p - m).astype(np.float32))
    return Ellipse(float(cx + m[0]), float(cy + m[1]), float(w), float(h), float(ang))


def ellipse_of_cone(axis: np.ndarray, half_angle: float, intr: CameraIntrinsics) -> Ellipse:
    """The outline of the cone in *undistorted* pixel coordinates (``K [x y 1]``), as an ellipse.

    The conic ``Q = c c^T - cos^2(theta) I`` in normalized coordinates becomes ``K^-T Q K^-1`` in pixels.
    Useful for overlays and to show how far the ellipse centre sits from the projected centre ray.
    """
    c = np.asarray(axis, dtype=float).reshape(3)
    Q = np.outer(c, c) - np.cos(half_angle) ** 2 * np.eye(3)
    Ki = np.linalg.inv(intr.K)
    C = Ki.T @ Q @ Ki
    A, B, Cc, D, E = C[0, 0], 2 * C[0, 1], C[1, 1], 2 * C[0, 2], 2 * C[1, 2]
    F = C[2, 2]
    M = np.array([[A, B / 2], [B / 2, Cc]])
    centre = np.linalg.solve(M, -0.5 * np.array([D, E]))
    Fc = F + 0.5 * (D * centre[0] + E * centre[1])
    w, v = np.linalg.eigh(M)
    semi = np.sqrt(-Fc / w)
    ang = rad_to_deg(np.arctan2(v[1, 0], v[0, 0]))
    return Ellipse(float(centre[0]), float(centre[1]), float(2 * semi[0]), float(2 * semi[1]), float(ang))


def triangulate_rays(ray_left: np.ndarray, ray_right: np.ndarray, left2right: np.ndarray) -> np.ndarray:
    """Points ``(n, 3)`` [m] in the left camera frame from matched rays ``(n, 3)`` of both cameras.

    The rays are turned into normalized image points, moved onto their epipolar lines by
    ``cv2.correctMatches`` (Hartley-Sturm optimal correction, with the essential matrix as the fundamental
    matrix of normalized coordinates) and triangulated with ``cv2.triangulatePoints`` (``P_l = [I | 0]``,
    ``P_r = [R | t]`` of ``left2right``).
    """
    dl = np.asarray(ray_left, dtype=np.float64).reshape(-1, 3)
    dr = np.asarray(ray_right, dtype=np.float64).reshape(-1, 3)
    if dl.shape != dr.shape:
        raise ValueError(f"ray_left/ray_right: shapes differ, {dl.shape} vs {dr.shape}")
    if dl.shape[0] == 0:
        return np.zeros((0, 3))
    T = np.asarray(left2right, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    xl = dl[:, :2] / dl[:, 2:3]
    xr = dr[:, :2] / dr[:, 2:3]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    E = tx @ R
    xl_c, xr_c = cv2.correctMatches(E, xl.reshape(1, -1, 2), xr.reshape(1, -1, 2))
    Pl = np.hstack([np.eye(3), np.zeros((3, 1))])
    Pr = np.hstack([R, t.reshape(3, 1)])
    X = cv2.triangulatePoints(Pl, Pr, xl_c.reshape(-1, 2).T, xr_c.reshape(-1, 2).T)
    return (X[:3] / X[3]).T


def epipolar_distance_px(ray_left: np.ndarray, ray_right: np.ndarray, left2right: np.ndarray, f_right_px: float) -> np.ndarray:
    """Distance ``(n,)`` [px] of each right ray's image from the epipolar line of the left ray.

    Computed in normalized coordinates of the right camera and scaled by its focal length ``f_right_px``.
    """
    dl = np.asarray(ray_left, dtype=np.float64).reshape(-1, 3)
    dr = np.asarray(ray_right, dtype=np.float64).reshape(-1, 3)
    T = np.asarray(left2right, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    E = tx @ R
    xl = dl / dl[:, 2:3]
    xr = dr / dr[:, 2:3]
    lines = xl @ E.T  # epipolar lines in the right normalized image
    num = np.abs(np.sum(lines * xr, axis=1))
    return f_right_px * num / np.linalg.norm(lines[:, :2], axis=1)
