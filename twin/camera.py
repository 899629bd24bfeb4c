"""Pinhole camera model shared by the world (rendering, truth) and the instrument (estimation).

Pure numpy and no truth: the world uses it to place MuJoCo cameras and to distort rendered images;
the instrument estimates its own parameters with OpenCV and uses the same formulas.

Frames (see ``docs/conventions.md``):

* OpenCV camera frame: +x right, +y down, +z forward (optical axis).
* MuJoCo camera frame: +x right, +y up, -z forward.
* :func:`mujoco_to_opencv_cam2world` is the one function that flips between them:
  ``R_cv = R_mj @ diag(1, -1, -1)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .units import deg_to_rad, rad_to_deg

__all__ = [
    "FLIP_MUJOCO_OPENCV",
    "CameraIntrinsics",
    "mujoco_to_opencv_cam2world",
    "opencv_to_mujoco_cam2world",
    "focal_px_from_fovy",
    "fovy_deg_from_focal_px",
    "project_points",
    "discs_in_image",
    "spheres_in_view",
    "distort_normalized",
    "undistort_normalized",
]

# diag(1, -1, -1): MuJoCo camera axes (x right, y up, looking along -z) <-> OpenCV (x right, y down, +z).
FLIP_MUJOCO_OPENCV = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics [px] with OpenCV's 5-term distortion ``(k1, k2, p1, p2, k3)``.

    The principal point follows OpenCV's pixel-centre convention: pixel ``(u, v)`` covers
    ``[u - 0.5, u + 0.5]``; for an ideal centred sensor ``cx = width/2 - 0.5``.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    dist: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        for name in ("fx", "fy"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive focal length [px], got {v!r}")
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"width/height must be positive [px], got {self.width}x{self.height}")
        if len(self.dist) != 5:
            raise ValueError(f"dist must have 5 coefficients (k1, k2, p1, p2, k3), got {self.dist!r}")

    @property
    def K(self) -> np.ndarray:
        """Camera matrix ``(3, 3)``."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_array(self) -> np.ndarray:
        return np.asarray(self.dist, dtype=float)

    @classmethod
    def ideal(cls, width: int, height: int, fovy_deg: float, dist=(0.0, 0.0, 0.0, 0.0, 0.0)) -> "CameraIntrinsics":
        """Square pixels, centred principal point, focal length from the vertical field of view."""
        f = focal_px_from_fovy(fovy_deg, height)
        return cls(f, f, width / 2 - 0.5, height / 2 - 0.5, int(width), int(height), tuple(float(x) for x in dist))

    def scaled(self, factor: float) -> "CameraIntrinsics":
        """Intrinsics of the same camera at ``factor`` times the resolution."""
        w, h = int(round(self.width * factor)), int(round(self.height * factor))
        return CameraIntrinsics(
            self.fx * factor, self.fy * factor, (self.cx + 0.5) * factor - 0.5, (self.cy + 0.5) * factor - 0.5, w, h, self.dist
        )


def mujoco_to_opencv_cam2world(cam_xpos: np.ndarray, cam_xmat: np.ndarray) -> np.ndarray:
    """OpenCV ``cam2world`` ``(4, 4)`` from MuJoCo's ``data.cam_xpos`` ``(3,)`` and ``data.cam_xmat`` ``(9,)``.

    The MuJoCo camera looks along its -z with +y up; OpenCV's looks along +z with +y down, so the
    axes differ by ``diag(1, -1, -1)``. The OpenCV extrinsics (``world2cam``) are the inverse:
    ``R = diag(1, -1, -1) @ xmat.T``, ``t = -R @ xpos``.
    """
    R_mj = np.asarray(cam_xmat, dtype=float).reshape(3, 3)
    T = np.eye(4)
    T[:3, :3] = R_mj @ FLIP_MUJOCO_OPENCV
    T[:3, 3] = np.asarray(cam_xpos, dtype=float).reshape(3)
    return T


def opencv_to_mujoco_cam2world(cam2world_cv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`mujoco_to_opencv_cam2world`: ``(pos (3,), xmat (3, 3))`` of the MuJoCo camera."""
    T = np.asarray(cam2world_cv, dtype=float)
    return T[:3, 3].copy(), T[:3, :3] @ FLIP_MUJOCO_OPENCV


def focal_px_from_fovy(fovy_deg: float, height: int) -> float:
    """``f = 0.5 * height / tan(0.5 * fovy)`` [px]."""
    return 0.5 * height / np.tan(0.5 * deg_to_rad(fovy_deg))


def fovy_deg_from_focal_px(f_px: float, height: int) -> float:
    """Vertical field of view [deg] of a focal length [px] on ``height`` rows."""
    return float(rad_to_deg(2.0 * np.arctan(0.5 * height / f_px)))


def distort_normalized(xy: np.ndarray, dist) -> np.ndarray:
    """OpenCV's distortion of normalized image points ``(n, 2)`` (``x = X/Z``, ``y = Y/Z``)."""
    k1, k2, p1, p2, k3 = np.asarray(dist, dtype=float)
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


def undistort_normalized(xy_d: np.ndarray, dist, iterations: int = 20) -> np.ndarray:
    """Invert :func:`distort_normalized` by fixed-point iteration (as OpenCV's ``undistortPoints``)."""
    k1, k2, p1, p2, k3 = np.asarray(dist, dtype=float)
    xy = np.array(xy_d, dtype=float)
    for _ in range(iterations):
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        xy = np.stack([(xy_d[..., 0] - dx) / radial, (xy_d[..., 1] - dy) / radial], axis=-1)
    return xy


def project_points(points_world: np.ndarray, world2cam: np.ndarray, intr: CameraIntrinsics) -> np.ndarray:
    """Pixel coordinates ``(n, 2)`` [px] of world points ``(n, 3)`` [m] (OpenCV camera frame, distortion)."""
    P = np.asarray(points_world, dtype=float).reshape(-1, 3)
    Pc = P @ world2cam[:3, :3].T + world2cam[:3, 3]
    if np.any(Pc[:, 2] <= 0):
        raise ValueError("points_world: some points are behind the camera (z <= 0 in the camera frame)")
    xy = distort_normalized(Pc[:, :2] / Pc[:, 2:3], intr.dist)
    return np.stack([intr.fx * xy[:, 0] + intr.cx, intr.fy * xy[:, 1] + intr.cy], axis=-1)


def discs_in_image(uv: np.ndarray, radius_px: np.ndarray | float, width: int, height: int) -> np.ndarray:
    """Which discs lie wholly inside a ``width`` x ``height`` image: centres ``uv`` ``(..., 2)`` [px], radii
    ``radius_px`` (broadcast to ``uv[..., 0]``) [px] -- a sphere's image with a margin. The one test of "the
    camera sees it" of the planners and of the world: ``r <= u <= width - 1 - r`` and ``r <= v <= height - 1 - r``."""
    uv = np.asarray(uv, dtype=float)
    r = np.broadcast_to(np.asarray(radius_px, dtype=float), uv.shape[:-1])
    u, v = uv[..., 0], uv[..., 1]
    return (u - r >= 0) & (u + r <= width - 1) & (v - r >= 0) & (v + r <= height - 1)


def spheres_in_view(centres_cam: np.ndarray, intr: CameraIntrinsics, *, radius: float = 0.0, margin_px: float = 0.0,
                    min_depth: float = 0.0) -> np.ndarray:
    """Whether a camera sees the whole plate: the one "plate in view" predicate of the planners and of the world.

    ``centres_cam`` ``(..., K, 3)`` [m]: the K sphere centres of each plate pose in the camera's OpenCV frame.
    A pose is in view when every sphere is in front of the camera (depth ``z > min_depth`` [m]) and its image
    disc, of radius ``fx * radius / z`` [px] (``radius`` [m]: the sphere's; 0 for a disc of ``margin_px`` alone)
    plus ``margin_px`` [px], lies wholly inside the image (:func:`discs_in_image`; the centres projected with the
    camera's distortion, as :func:`project_points`). Returns a mask ``(...,)``.
    """
    P = np.asarray(centres_cam, dtype=float)
    if P.ndim < 2 or P.shape[-1] != 3:
        raise ValueError(f"centres_cam must be (..., K, 3) [m], got shape {P.shape}")
    z = P[..., 2]
    front = z > min_depth
    zs = np.where(front, z, np.nan)  # a sphere behind the camera is out of view: no pixel for it
    xy = distort_normalized(P[..., :2] / zs[..., None], intr.dist)
    uv = np.stack([intr.fx * xy[..., 0] + intr.cx, intr.fy * xy[..., 1] + intr.cy], axis=-1)
    inside = front & discs_in_image(uv, intr.fx * radius / zs + margin_px, intr.width, intr.height)
    return np.all(inside, axis=-1)
