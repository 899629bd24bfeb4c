"""Analytic images with a known camera, for validating the instrument without the world.

Ray-traced, anti-aliased (supersampled) images of shaded spheres, and ChArUco board views mapped through
an exact pinhole + OpenCV distortion model. They are exact where a rasteriser is approximate (a sphere's
outline is the true tangent cone, including its perspective bias), so tests and the benchmark can
separate the instrument's own error from the renderer's. Nothing in the measurement code uses this module.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from ..camera import CameraIntrinsics, undistort_normalized

__all__ = ["render_spheres", "render_board", "add_sensor_noise", "look_at_world2cam"]


def look_at_world2cam(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """OpenCV ``world2cam`` ``(4, 4)`` of a camera at ``eye`` [m] looking at ``target`` [m]; image y points
    away from ``up``."""
    eye = np.asarray(eye, float)
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, -np.asarray(up, float))
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("up: parallel to the viewing direction")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ eye
    return T


def _pixel_rays(u: np.ndarray, v: np.ndarray, intr: CameraIntrinsics) -> np.ndarray:
    """Rays ``(..., 3)`` (not normalised, z = 1) of distorted pixel coordinates."""
    xd = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy], axis=-1)
    if np.any(np.asarray(intr.dist) != 0):
        xy = undistort_normalized(xd, intr.dist, iterations=30)
    else:
        xy = xd
    return np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)


def render_spheres(
    intr: CameraIntrinsics,
    world2cam: np.ndarray,
    centres: np.ndarray,
    radius: float,
    *,
    background: float | np.ndarray = 25.0,
    light_dir: np.ndarray = (1.0, -0.3, -0.4),
    ambient: float = 45.0,
    diffuse: float = 190.0,
    specular: float = 0.0,
    shininess: float = 40.0,
    supersample: int = 4,
) -> np.ndarray:
    """Float image ``(height, width)`` of spheres ``centres`` ``(n, 3)`` [m] (world frame) of ``radius`` [m].

    Lambertian shading ``ambient + diffuse * max(0, n . l)`` plus an optional Phong highlight, with ``l``
    the unit direction towards the light (world frame). Each pixel averages ``supersample**2`` rays, so the
    outline is anti-aliased by exact area coverage. ``background`` is a level or an image.
    """
    c_w = np.asarray(centres, float).reshape(-1, 3)
    T = np.asarray(world2cam, float)
    c = c_w @ T[:3, :3].T + T[:3, 3]
    if np.any(c[:, 2] <= radius):
        raise ValueError("centres: every sphere must be in front of the camera")
    l = T[:3, :3] @ np.asarray(light_dir, float)
    l /= np.linalg.norm(l)
    H, W = intr.height, intr.width
    if np.isscalar(background) or np.ndim(background) == 0:
        img = np.full((H, W), float(background))
        bg_img = None
    else:
        bg_img = np.asarray(background, float)
        if bg_img.shape != (H, W):
            raise ValueError(f"background: shape {bg_img.shape} differs from the image ({H}, {W})")
        img = bg_img.copy()
    s = int(supersample)
    offs = (np.arange(s) + 0.5) / s - 0.5
    fmax = max(intr.fx, intr.fy)
    for k in range(c.shape[0]):
        # bounding box of this sphere's outline (with margin for distortion)
        dist = np.linalg.norm(c[k])
        r_px = fmax * radius / np.sqrt(max(dist**2 - radius**2, 1e-12)) * (dist / c[k, 2]) ** 2
        pc = np.array([intr.fx * c[k, 0] / c[k, 2] + intr.cx, intr.fy * c[k, 1] / c[k, 2] + intr.cy])
        if np.any(np.asarray(intr.dist) != 0):
            from ..camera import distort_normalized

            xy = distort_normalized((c[k, :2] / c[k, 2])[None], intr.dist)[0]
            pc = np.array([intr.fx * xy[0] + intr.cx, intr.fy * xy[1] + intr.cy])
        m = 1.15 * r_px + 6
        u0, u1 = int(max(0, np.floor(pc[0] - m))), int(min(W, np.ceil(pc[0] + m) + 1))
        v0, v1 = int(max(0, np.floor(pc[1] - m))), int(min(H, np.ceil(pc[1] + m) + 1))
        if u0 >= u1 or v0 >= v1:
            continue
        uu, vv = np.meshgrid(np.arange(u0, u1, dtype=float), np.arange(v0, v1, dtype=float))
        acc = np.zeros(uu.shape)
        for du in offs:
            for dv in offs:
                d = _pixel_rays(uu + du, vv + dv, intr)
                d /= np.linalg.norm(d, axis=-1, keepdims=True)
                t_best = np.full(uu.shape, np.inf)
                val = np.full(uu.shape, np.nan)
                for j in range(c.shape[0]):
                    b = d @ c[j]
                    disc = b * b - (c[j] @ c[j] - radius**2)
                    hit = disc >= 0
                    t = np.where(hit, b - np.sqrt(np.where(hit, disc, 0.0)), np.inf)
                    closer = hit & (t > 0) & (t < t_best)
                    if not closer.any():
                        continue
                    t_best = np.where(closer, t, t_best)
                    p = d[closer] * t[closer][:, None]
                    n = (p - c[j]) / radius
                    ndl = np.maximum(0.0, n @ l)
                    shade = ambient + diffuse * ndl
                    if specular > 0:
                        v_dir = -d[closer]
                        r_dir = 2 * (n @ l)[:, None] * n - l
                        shade = shade + specular * np.maximum(0.0, np.sum(r_dir * v_dir, axis=1)) ** shininess
                    val[closer] = shade
                miss = np.isnan(val)
                if bg_img is None:
                    val[miss] = float(background)
                else:
                    val[miss] = bg_img[v0:v1, u0:u1][miss]
                acc += val
        img[v0:v1, u0:u1] = acc / (s * s)
    return img


def render_board(
    intr: CameraIntrinsics,
    board2cam: np.ndarray,
    board,
    *,
    black: float = 20.0,
    white: float = 215.0,
    surround: float = 60.0,
    texture_px_per_m: float = 10000.0,
    margin_squares: float = 0.5,
    supersample: int = 2,
) -> np.ndarray:
    """Float image of an OpenCV ``CharucoBoard`` (``board``) whose frame maps into the camera by
    ``board2cam`` ``(4, 4)``. Board coordinates follow OpenCV's object points (origin at the top-left
    outer corner, x along the squares' rows, y down, z into the board); a white margin of
    ``margin_squares`` squares surrounds the pattern; outside it the image shows ``surround``.
    """
    sx, sy = board.getChessboardSize()
    sq = board.getSquareLength()
    s = texture_px_per_m
    W_t, H_t = int(round(sx * sq * s)), int(round(sy * sq * s))
    tex = board.generateImage((W_t, H_t), marginSize=0, borderBits=1).astype(np.float32)
    mpx = int(round(margin_squares * sq * s))
    tex = cv2.copyMakeBorder(tex, mpx, mpx, mpx, mpx, cv2.BORDER_CONSTANT, value=255.0)
    tex = black + (white - black) * tex / 255.0
    H, W = intr.height, intr.width
    T = np.asarray(board2cam, float)
    R, t = T[:3, :3], T[:3, 3]
    o_b = -R.T @ t  # camera centre in the board frame
    acc = np.zeros((H, W), np.float32)
    for xy in _undistorted_grids(intr, int(supersample)):
        x, y = xy[..., 0], xy[..., 1]
        # ray direction in the board frame: R^T (x, y, 1)
        dx = x * R[0, 0] + y * R[1, 0] + R[2, 0]
        dy = x * R[0, 1] + y * R[1, 1] + R[2, 1]
        dz = x * R[0, 2] + y * R[1, 2] + R[2, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            tt = -o_b[2] / dz
        mapx = ((o_b[0] + tt * dx) * s + (mpx - 0.5)).astype(np.float32)
        mapy = ((o_b[1] + tt * dy) * s + (mpx - 0.5)).astype(np.float32)
        bad = ~(tt > 0)
        mapx[bad] = -1e6
        mapy[bad] = -1e6
        acc += cv2.remap(tex, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=surround)
    return acc / int(supersample) ** 2


@functools.lru_cache(maxsize=4)
def _undistorted_grids(intr: CameraIntrinsics, ss: int) -> tuple[np.ndarray, ...]:
    """Normalized undistorted coordinates ``(H, W, 2)`` of every pixel's ``ss x ss`` sub-samples (cached:
    they depend on the camera only)."""
    H, W = intr.height, intr.width
    offs = (np.arange(ss) + 0.5) / ss - 0.5
    uu, vv = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    out = []
    for du in offs:
        for dv in offs:
            px = np.stack([uu + du, vv + dv], axis=-1).reshape(-1, 1, 2)
            xy = cv2.undistortPoints(px, intr.K, intr.dist_array, criteria=(3, 30, 1e-12)).reshape(H, W, 2)
            out.append(xy.astype(np.float32))
    return tuple(out)


def add_sensor_noise(img: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """8-bit image: ``img`` plus Gaussian noise of ``sigma`` grey levels, rounded and clipped."""
    out = np.asarray(img, float) + (rng.normal(0.0, sigma, np.shape(img)) if sigma > 0 else 0.0)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)
