"""Geometry of the stereo rig and its stations (pure numpy; MuJoCo camera axes unless named ``_cv``).

Rig frame: origin at the middle of the baseline, x right, y up, looking along -z (MuJoCo's camera axes).
The left camera sits at ``x = -baseline/2`` and the right one at ``+baseline/2``, each turned towards the
other by the toe-in angle so that the optical axes cross at the stand-off distance (or at the configured
vergence). A station places the rig in the lab (MuJoCo world) frame: the rig sits at ``standoff`` from
the station's target, along the direction given by azimuth and elevation, looking at the target.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import RectBivariateSpline

from ..camera import CameraIntrinsics, distort_normalized, undistort_normalized
from .config import RenderConfig, RigConfig, StationConfig

__all__ = [
    "camera2rig",
    "station_rig2world",
    "true_intrinsics",
    "render_focal_px",
    "distortion_maps",
    "renders_ideally",
]


def camera2rig(rig: RigConfig) -> tuple[np.ndarray, np.ndarray]:
    """Left and right camera poses ``(4, 4)`` in the rig frame (MuJoCo camera axes)."""
    phi = rig.toe_in()
    out = []
    for x, yaw in ((-0.5 * rig.baseline, -phi), (0.5 * rig.baseline, phi)):
        c, s = np.cos(yaw), np.sin(yaw)
        T = np.eye(4)
        T[:3, :3] = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])  # RotY(yaw): -z turns towards -x*sin(yaw)
        T[0, 3] = x
        out.append(T)
    return out[0], out[1]


def station_rig2world(station: StationConfig, rig: RigConfig) -> np.ndarray:
    """Rig pose ``(4, 4)`` in the lab frame for ``station`` (rig looks at the target, up ~ lab +z)."""
    d = station.standoff if station.standoff is not None else rig.standoff
    ce, se = np.cos(station.elevation), np.sin(station.elevation)
    u = np.array([ce * np.cos(station.azimuth), ce * np.sin(station.azimuth), se])  # target -> rig
    up = np.array([0.0, 0.0, 1.0])
    x = np.cross(up, u)
    if np.linalg.norm(x) < 1e-6:
        raise ValueError(f"station {station.name!r}: elevation of +-90 deg leaves the rig's roll undefined")
    x /= np.linalg.norm(x)
    y = np.cross(u, x)
    cr, sr = np.cos(station.roll), np.sin(station.roll)
    x, y = cr * x + sr * y, -sr * x + cr * y
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, u], axis=1)
    T[:3, 3] = station.target + d * u
    return T


def true_intrinsics(rig: RigConfig, render: RenderConfig) -> tuple[CameraIntrinsics, CameraIntrinsics]:
    """The cameras' true intrinsics at the render scale (what the instrument has to estimate)."""
    s = render.scale
    w, h = int(round(rig.width_px * s)), int(round(rig.height_px * s))
    f = rig.focal_px * s
    out = []
    for pp, dist in ((render.principal_offset_left, render.distortion_left),
                     (render.principal_offset_right, render.distortion_right)):
        out.append(CameraIntrinsics(f, f, w / 2 - 0.5 + pp[0] * s, h / 2 - 0.5 + pp[1] * s, w, h,
                                    tuple(float(x) for x in dist)))
    return out[0], out[1]


def _border_pixels(intr: CameraIntrinsics, n: int = 400) -> np.ndarray:
    """Centres of the outermost pixels ``(4n, 2)``."""
    w, h = intr.width, intr.height
    u = np.linspace(0.0, w - 1.0, n)
    v = np.linspace(0.0, h - 1.0, n)
    return np.concatenate([
        np.stack([u, np.zeros(n)], 1), np.stack([u, np.full(n, h - 1.0)], 1),
        np.stack([np.zeros(n), v], 1), np.stack([np.full(n, w - 1.0), v], 1),
    ])


def render_focal_px(intr: CameraIntrinsics, margin_px: float = 1.0) -> float:
    """Focal length [px] of the ideal (pinhole, centred) render from which the true image is resampled.

    Every pixel of the true image must come from inside the ideal one. The ideal camera keeps the true
    focal length when that holds (then an undistorted, centred camera needs no resampling at all);
    otherwise its field of view widens just enough, with ``margin_px`` to spare.
    """
    uv = _border_pixels(intr)
    xy_d = np.stack([(uv[:, 0] - intr.cx) / intr.fx, (uv[:, 1] - intr.cy) / intr.fy], axis=1)
    xy = undistort_normalized(xy_d, intr.dist)
    ccx, ccy = intr.width / 2 - 0.5, intr.height / 2 - 0.5
    f = min(intr.fx, intr.fy)
    ax, ay = np.max(np.abs(xy[:, 0])), np.max(np.abs(xy[:, 1]))
    if f * ax <= ccx * (1 + 1e-12) and f * ay <= ccy * (1 + 1e-12):
        return float(f)
    return float(min(f, (ccx - margin_px) / ax, (ccy - margin_px) / ay))


def renders_ideally(intr: CameraIntrinsics, f_render: float) -> bool:
    """True when the true camera ``intr`` is the ideal render of focal length ``f_render`` [px] (no distortion,
    centred, that focal length): then :func:`distortion_maps` is ``None``."""
    ccx, ccy = intr.width / 2 - 0.5, intr.height / 2 - 0.5
    return bool(
        not np.any(intr.dist_array)
        and abs(intr.cx - ccx) < 1e-12
        and abs(intr.cy - ccy) < 1e-12
        and abs(intr.fx - f_render) < 1e-9
        and abs(intr.fy - f_render) < 1e-9
    )


def distortion_maps(intr: CameraIntrinsics, f_render: float) -> tuple[np.ndarray, np.ndarray] | None:
    """``cv2.remap`` maps ``(H, W)`` float32: for each true (distorted) pixel, where it lies in the ideal render.

    ``None`` when the true camera equals the ideal one (no resampling needed).
    """
    ccx, ccy = intr.width / 2 - 0.5, intr.height / 2 - 0.5
    if renders_ideally(intr, f_render):
        return None
    # The inverse distortion is smooth: solve it on a 16-px grid (padded past the border) and evaluate a
    # bicubic spline at every pixel; the spline error is checked below on a sample of pixels.
    step = 16
    us = np.arange(-2 * step, intr.width + 2 * step + 1, step, dtype=float)
    vs = np.arange(-2 * step, intr.height + 2 * step + 1, step, dtype=float)
    U, V = np.meshgrid(us, vs)
    xy = undistort_normalized(np.stack([(U - intr.cx) / intr.fx, (V - intr.cy) / intr.fy], axis=-1), intr.dist)
    u_full = np.arange(intr.width, dtype=float)
    v_full = np.arange(intr.height, dtype=float)
    maps = []
    for c, cc in ((0, ccx), (1, ccy)):
        spline = RectBivariateSpline(vs, us, xy[..., c], kx=3, ky=3)
        m = spline(v_full, u_full)  # (H, W) float64; scaled in place (supersampled grids are 20 Mpx)
        m *= f_render
        m += cc
        maps.append(m)
    # Check: distorting the ray of each sampled pixel lands back on that pixel.
    rng = np.random.default_rng(0)
    su = rng.integers(0, intr.width, 20000)
    sv = rng.integers(0, intr.height, 20000)
    ray = np.stack([(maps[0][sv, su] - ccx) / f_render, (maps[1][sv, su] - ccy) / f_render], axis=-1)
    back = distort_normalized(ray, intr.dist)
    err = max(np.max(np.abs(back[:, 0] * intr.fx + intr.cx - su)), np.max(np.abs(back[:, 1] * intr.fy + intr.cy - sv)))
    if err > 1e-4:
        raise ValueError(f"distortion {intr.dist} cannot be inverted over the image (residual {err:.2g} px)")
    map_x = maps[0].astype(np.float32)
    map_y = maps[1].astype(np.float32)
    return map_x, map_y


def check_distortion_monotonic(intr: CameraIntrinsics) -> None:
    """Refuse distortion that folds the image (radius not increasing out to the image corners)."""
    r_max = np.hypot(max(intr.cx, intr.width - intr.cx) / intr.fx, max(intr.cy, intr.height - intr.cy) / intr.fy)
    r = np.linspace(0.0, 1.3 * r_max, 400)
    xy = np.stack([r, np.zeros_like(r)], axis=1)
    rd = distort_normalized(xy, intr.dist)[:, 0]
    if np.any(np.diff(rd) <= 0):
        raise ValueError(f"distortion {intr.dist} folds the image within its field of view")


__all__.append("check_distortion_monotonic")
