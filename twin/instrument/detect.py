"""Sphere outlines in one image, to sub-pixel precision (pure: an image array in, results out).

Pipeline for one greyscale image (bright spheres on a darker local background):

1. **Coarse blobs.** On an image shrunk ``downsample`` times, a white top-hat (the image minus its
   morphological opening with a square larger than the largest expected sphere) removes the slowly
   varying background (plate, backdrop, large parts of the arm); blobs above ``min_contrast`` grey levels
   are candidate spheres (centroid and equivalent radius).
2. **Edge profiles along rays** from the coarse centre, sampled bilinearly, one ray per
   ``ray_spacing_px`` of outline. On each ray: the local background is the median of the ray's outer
   samples; the profile is followed outwards until it falls below a threshold *just above* that
   background (``max(edge_min_step, edge_k_sigma * noise)``), the inner level is read ``inner_offset_px``
   inside that point, and the edge is where the profile crosses the mean of the inner level and the
   background. A global (Otsu) threshold would cut through the shading of a side-lit sphere and move its
   centre by millimetres; this per-ray level does not.
3. **Cone fit with outlier rejection** of the undistorted edge rays (``geometry.fit_cone_robust``): the true
   centre ray and the half-angle; a second pass re-samples narrow profiles around the fitted outline.
4. **Checks**, each leaving a reason instead of a centre: outline crossing the image border
   (``out_of_frame``), radius below ``min_radius_px`` (``too_small``), a blob shaped like several spheres
   (``merged``), a contiguous stretch of outline missing or rejected (``occluded``), too large a fit residual
   or too many rejected edges (``not_round``), too little contrast (``low_contrast``), no outline (``no_edge``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from ..camera import CameraIntrinsics
from ..units import rad_to_deg
from .geometry import ConeFit, Ellipse, fit_cone_robust, fit_ellipse, pixels_to_rays, rays_to_pixels

__all__ = ["DetectorConfig", "SphereImage", "detect_spheres", "estimate_noise", "as_gray"]

REASONS = ("out_of_frame", "too_small", "merged", "occluded", "not_round", "low_contrast", "no_edge")


@dataclass(frozen=True)
class DetectorConfig:
    """Parameters of :func:`detect_spheres` (grey levels refer to 8-bit images)."""

    downsample: int = 8
    distance_range: tuple[float, float] = (0.4, 1.5)  # [m] working distances: sets the blob size range
    min_contrast: float = 8.0  # coarse blobs: grey levels above the local background
    min_blob_contrast: float = 20.0  # median level of a blob's core above the local background
    edge_min_step: float = 5.0  # per-ray threshold above the ray's background [grey levels]
    edge_k_sigma: float = 3.0  # ... or this many noise sigmas, whichever is larger
    inner_offset_px: float = 2.0  # where the inner level is first read, inside the threshold crossing [px]
    rim_inner_px: float = 1.5  # rim level: extrapolated from this far (and 1 px further) inside the edge [px]
    rim_extrapolate_px: float = 1.5  # ... by this distance outwards (towards the edge) [px]
    rim_iterations: int = 1  # refinements of the edge with the extrapolated rim level (0: plain 50 % level)
    ray_spacing_px: float = 1.0  # outline length per ray [px]
    min_rays: int = 64
    max_rays: int = 2048
    coarse_rays: int = 180  # rays of the first (wide-window) pass
    fine_half_window_px: float = 6.0  # second pass: profile half-length around the outline [px]
    step_px: float = 0.5  # sampling step along rays [px]
    min_radius_px: float = 12.0
    max_rms_px: float = 0.35  # roundness: RMS of the cone-fit residual of the inliers [px]
    min_inlier_fraction: float = 0.85
    max_gap_deg: float = 20.0  # largest contiguous stretch of outline without an accepted edge
    border_margin_px: float = 1.0
    max_candidates: int = 12  # blob peaks examined per image, largest first

    def __post_init__(self) -> None:
        if self.downsample < 1:
            raise ValueError(f"downsample must be >= 1, got {self.downsample}")
        lo, hi = self.distance_range
        if not (0 < lo < hi):
            raise ValueError(f"distance_range must be 0 < near < far [m], got {self.distance_range}")
        if self.step_px <= 0 or self.ray_spacing_px <= 0:
            raise ValueError("step_px and ray_spacing_px must be positive [px]")


@dataclass(frozen=True, eq=False)
class SphereImage:
    """One candidate sphere in one image.

    ``ok`` with ``reason == ""`` when measured; otherwise ``reason`` says why not and the measured fields
    may be None. Pixel coordinates are those of the (distorted) image; rays are unit vectors in the
    camera's OpenCV frame.

    * ``ray`` ``(3,)``: the sphere centre's direction from the cone fit (perspective bias corrected);
    * ``ray_uncorrected`` ``(3,)``: the direction of the centre of an ellipse fitted to the same undistorted
      edge points (what a plain ellipse-centre method measures);
    * ``centre_px`` / ``centre_px_uncorrected`` ``(2,)`` [px]: those two directions in the image;
    * ``ellipse``: ellipse fitted to the inlier edge points in image pixels (overlays);
    * ``edge_px`` ``(n, 2)`` [px] and ``inliers`` ``(n,)``: the edge points and which ones the fit kept;
    * ``distance`` [m]: camera-to-centre distance from the cone and the known radius (one camera);
    * ``centre_rough`` ``(3,)`` [m]: a rough centre from this camera alone, also for rejected candidates
      (from the first-pass cone, or from the blob's size): used only to label and to explain rejections.
    """

    ok: bool
    reason: str
    coarse_px: np.ndarray
    coarse_radius_px: float
    cone: ConeFit | None = None
    ray: np.ndarray | None = None
    ray_uncorrected: np.ndarray | None = None
    centre_px: np.ndarray | None = None
    centre_px_uncorrected: np.ndarray | None = None
    ellipse: Ellipse | None = None
    edge_px: np.ndarray | None = None
    inliers: np.ndarray | None = None
    radius_px: float = float("nan")
    rms_px: float = float("nan")
    inlier_fraction: float = float("nan")
    max_gap_deg: float = float("nan")
    contrast: float = float("nan")
    distance: float = float("nan")
    centre_rough: np.ndarray | None = None
    notes: dict = field(default_factory=dict)

    def centre_mono(self) -> np.ndarray | None:
        """Sphere centre ``(3,)`` [m] from this camera alone (cone axis times distance), or None."""
        if self.ray is None or not np.isfinite(self.distance):
            return None
        return self.ray * self.distance


def as_gray(image: np.ndarray) -> np.ndarray:
    """A 2-D greyscale view of ``image`` (``(h, w)``, ``(h, w, 1)`` or RGB ``(h, w, 3)``; 8 or 16 bit or float)."""
    a = np.asarray(image)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if a.ndim == 3 and a.shape[2] in (3, 4):
        a = cv2.cvtColor(np.ascontiguousarray(a[:, :, :3]), cv2.COLOR_RGB2GRAY) if a.dtype == np.uint8 else a[:, :, :3].mean(axis=2)
    if a.ndim != 2:
        raise ValueError(f"image: expected a (h, w) or (h, w, 3) array, got shape {np.shape(image)}")
    return a


def estimate_noise(gray: np.ndarray) -> float:
    """Robust sensor-noise sigma [grey levels]: MAD of horizontal pixel differences on a subset of rows."""
    rows = gray[:: max(1, gray.shape[0] // 16)].astype(np.float32)
    d = np.diff(rows, axis=1).ravel()
    mad = np.median(np.abs(d - np.median(d)))
    return float(1.4826 * mad / np.sqrt(2.0))


def _sample(gray: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``gray`` at float coordinates (pixel centres at integers); NaN outside.

    ``cv2.remap`` on the float32 region of interest (its float-map interpolation agrees with exact
    bilinear interpolation to about 0.002 grey levels, and is several times faster than numpy gathers).
    """
    H, W = gray.shape
    x0 = max(int(np.floor(np.nanmin(x))) - 1, 0)
    y0 = max(int(np.floor(np.nanmin(y))) - 1, 0)
    x1 = min(int(np.ceil(np.nanmax(x))) + 2, W)
    y1 = min(int(np.ceil(np.nanmax(y))) + 2, H)
    if x0 >= x1 or y0 >= y1:
        return np.full(np.shape(x), np.nan, np.float32)
    roi = np.ascontiguousarray(gray[y0:y1, x0:x1], dtype=np.float32)
    shape = np.shape(x)
    mx = np.ascontiguousarray((x - x0).reshape(-1, shape[-1] if len(shape) > 1 else 1), dtype=np.float32)
    my = np.ascontiguousarray((y - y0).reshape(mx.shape), dtype=np.float32)
    v = cv2.remap(roi, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan"))
    v = v.reshape(shape)
    # outside the image (not just the ROI): NaN, also for the last row/column's half pixel
    v[~((x >= 0) & (y >= 0) & (x <= W - 1) & (y <= H - 1))] = np.nan
    return v


def _interp_rows(P: np.ndarray, rows: np.ndarray, f: np.ndarray, M: int) -> np.ndarray:
    """``P[row, f]`` with linear interpolation in the fractional sample index ``f`` (clipped to the profile)."""
    i0 = np.clip(np.floor(f).astype(np.intp), 0, M - 2)
    w = np.clip(f - i0, 0.0, 1.0)
    return P[rows, i0] * (1 - w) + P[rows, i0 + 1] * w


def _ray_edges(gray, centre, angles, r_in, r_out, step, bg_from, sigma, cfg):
    """Sub-pixel edge radius on every ray (vectorised). Returns ``(r_edge, valid, contrast, border)``."""
    radii = np.arange(r_in, r_out + 1e-9, step)
    M = radii.size
    ca, sa = np.cos(angles), np.sin(angles)
    X = centre[0] + ca[:, None] * radii[None, :]
    Y = centre[1] + sa[:, None] * radii[None, :]
    P = _sample(gray, X, Y)
    N = angles.size
    border = np.isnan(P).any(axis=1)
    Pf = np.where(np.isnan(P), -1e9, P)  # outside the image counts as "below" any level
    j_bg = int(np.searchsorted(radii, bg_from))
    j_bg = min(max(j_bg, 1), M - 2)
    outer = P[:, j_bg:]
    bg = np.median(outer, axis=1)  # NaN (outside the image) propagates: such rays are invalid
    bg = np.where(np.isfinite(bg), bg, np.inf)
    T = bg + max(cfg.edge_min_step, cfg.edge_k_sigma * sigma)
    below = Pf < T[:, None]
    j = np.argmax(below, axis=1)
    rows = np.arange(N)
    valid = below.any(axis=1) & (j > 0) & np.isfinite(T)
    jj = np.clip(j, 1, M - 1)
    p_hi, p_lo = Pf[rows, jj - 1], Pf[rows, jj]
    with np.errstate(all="ignore"):
        frac = np.clip((p_hi - T) / (p_hi - p_lo), 0.0, 1.0)
    r_T = radii[jj - 1] + frac * step
    # inner level, read inner_offset_px inside the threshold crossing
    f_in = (r_T - cfg.inner_offset_px - radii[0]) / step
    valid &= f_in >= 0
    i0 = np.clip(np.floor(f_in).astype(np.intp), 0, M - 2)
    w = np.clip(f_in - i0, 0.0, 1.0)
    I_in = Pf[rows, i0] * (1 - w) + Pf[rows, i0 + 1] * w
    contrast = I_in - bg
    L = 0.5 * (I_in + bg)
    idx = np.arange(M)[None, :]
    below_L = (Pf < L[:, None]) & (idx > i0[:, None])
    k = np.argmax(below_L, axis=1)
    valid &= below_L.any(axis=1) & (k <= jj)
    kk = np.clip(k, 1, M - 1)
    q_hi, q_lo = Pf[rows, kk - 1], Pf[rows, kk]
    with np.errstate(all="ignore"):
        frac2 = np.clip((q_hi - L) / (q_hi - q_lo), 0.0, 1.0)
    r_edge = radii[kk - 1] + frac2 * step
    for _ in range(cfg.rim_iterations):
        # The shading keeps changing right up to the outline, so the level a few pixels inside is not the
        # level at the outline: extrapolate the inner profile linearly (samples rim_inner_px and
        # rim_inner_px + 1 inside the current edge) to the edge, and take the crossing of the mean of that
        # and the background. Without this the outline of a side-lit sphere moves by ~0.05 px with the
        # shading, i.e. its centre by ~0.03 px towards the lit side.
        fa = np.nan_to_num((r_edge - cfg.rim_inner_px - radii[0]) / step, nan=-1.0)
        fb = fa - 1.0 / step
        valid &= fb >= 0
        I_a = _interp_rows(Pf, rows, fa, M)
        I_b = _interp_rows(Pf, rows, fb, M)
        I_rim = I_a + (I_a - I_b) * cfg.rim_extrapolate_px
        with np.errstate(invalid="ignore"):
            I_rim = np.where(I_rim > bg + 0.25 * contrast, I_rim, I_a)  # no extrapolation through the background
        L = 0.5 * (I_rim + bg)
        ia = np.clip(np.floor(fa).astype(np.intp), 0, M - 2)
        below_L = (Pf < L[:, None]) & (idx > ia[:, None])
        k = np.argmax(below_L, axis=1)
        valid &= below_L.any(axis=1)
        kk = np.clip(k, 1, M - 1)
        q_hi, q_lo = Pf[rows, kk - 1], Pf[rows, kk]
        with np.errstate(all="ignore"):
            frac2 = np.clip((q_hi - L) / (q_hi - q_lo), 0.0, 1.0)
        r_edge = radii[kk - 1] + frac2 * step
    valid &= np.isfinite(r_edge) & np.isfinite(contrast)
    return r_edge, valid, contrast, border


def _max_gap_deg(angles: np.ndarray, keep: np.ndarray) -> float:
    a = np.sort(np.mod(angles[keep], 2 * np.pi))
    if a.size < 2:
        return 360.0
    gaps = np.diff(np.concatenate([a, a[:1] + 2 * np.pi]))
    return float(rad_to_deg(gaps.max()))


def _fit_outline(gray, intr, centre, radius, sigma, cfg, *, fine: bool):
    """One pass: rays around ``centre`` [px], edges, robust cone fit. Returns a dict of results."""
    n_rays = int(np.clip(round(2 * np.pi * radius / cfg.ray_spacing_px), cfg.min_rays, cfg.max_rays))
    if fine:
        w = cfg.fine_half_window_px
        r_in, r_out, bg_from, step = radius - w, radius + w, radius + 0.5 * w, cfg.step_px
    else:
        # coarse pass: a wide window, fewer rays and a coarser step (only to find the outline)
        n_rays = min(n_rays, cfg.coarse_rays)
        r_in = 0.4 * radius
        r_out = 1.8 * radius + 2 * cfg.downsample
        bg_from = 1.5 * radius + 1.5 * cfg.downsample
        step = 2 * cfg.step_px
    angles = (np.arange(n_rays) + 0.5) * (2 * np.pi / n_rays)
    r_in = max(r_in, 1.0)
    r_edge, valid, contrast, border = _ray_edges(gray, centre, angles, r_in, r_out, step, bg_from, sigma, cfg)
    # an edge that the profile could not separate from the frame border is not an edge
    H, W = gray.shape
    ex = centre[0] + np.cos(angles) * r_edge
    ey = centre[1] + np.sin(angles) * r_edge
    m = cfg.border_margin_px + 1.0
    near_border = ~((ex > m) & (ey > m) & (ex < W - 1 - m) & (ey < H - 1 - m))
    clipped = (border & ~valid) | (valid & near_border)
    valid &= ~near_border
    valid &= contrast >= cfg.min_contrast * 0.5
    out = dict(angles=angles, r_edge=r_edge, valid=valid, contrast=contrast, clipped=clipped, n_rays=n_rays)
    if valid.sum() < max(12, 0.25 * n_rays):
        out["cone"] = None
        return out
    pts = np.stack([ex[valid], ey[valid]], axis=1)
    rays = pixels_to_rays(pts, intr)
    f = 0.5 * (intr.fx + intr.fy)
    cone = fit_cone_robust(rays, scale_rad=1.0 / f)
    out.update(cone=cone, pts=pts, rays=rays, f=f)
    return out


def detect_spheres(
    image: np.ndarray,
    intr: CameraIntrinsics,
    sphere_radius: float,
    config: DetectorConfig | None = None,
) -> list[SphereImage]:
    """All sphere candidates in one image, measured or rejected with a reason.

    ``image``: greyscale or RGB array (bright spheres on a darker local background); ``intr``: the
    camera's *estimated* intrinsics (used to undistort edge points and to size the search);
    ``sphere_radius`` [m]. Candidates come back in decreasing order of blob area.
    """
    cfg = config or DetectorConfig()
    if not (np.isfinite(sphere_radius) and sphere_radius > 0):
        raise ValueError(f"sphere_radius must be positive [m], got {sphere_radius!r}")
    gray = as_gray(image)
    H, W = gray.shape
    if (W, H) != (intr.width, intr.height):
        raise ValueError(f"image: size {W}x{H} differs from the intrinsics' {intr.width}x{intr.height}")
    sigma = estimate_noise(gray)
    f = 0.5 * (intr.fx + intr.fy)
    r_max = f * sphere_radius / cfg.distance_range[0]
    r_min = max(cfg.min_radius_px, f * sphere_radius / cfg.distance_range[1])
    ds = cfg.downsample
    src = gray if gray.dtype in (np.uint8, np.uint16, np.float32) else gray.astype(np.float32)
    small = cv2.resize(src, (W // ds, H // ds), interpolation=cv2.INTER_AREA).astype(np.float32)
    k = int(2 * r_max / ds * 1.15) + 3
    k += 1 - k % 2
    opened = cv2.morphologyEx(small, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_RECT, (k, k)))
    tophat = small - opened
    mask = (tophat > max(cfg.min_contrast, 3.0 * sigma / ds)).astype(np.uint8)
    # candidate centres: peaks of the distance transform of the blob mask (the largest inscribed circles),
    # so that a sphere touching another blob (another sphere, an arm edge) still gets its own candidate
    dt = cv2.distanceTransform(mask, cv2.DIST_L2, 5)
    r_min_small = max(1.0, 0.5 * r_min / ds)
    peak = (dt >= cv2.dilate(dt, np.ones((3, 3), np.uint8)) - 1e-6) & (dt >= r_min_small)
    ys, xs = np.nonzero(peak)
    vals = dt[ys, xs]
    order = np.argsort(-vals, kind="stable")
    acc: list[tuple[float, float, float]] = []
    hs, ws = tophat.shape
    for i in order:
        x, y, v = float(xs[i]), float(ys[i]), float(vals[i])
        if any(np.hypot(x - a, y - b) < max(v, r) for a, b, r in acc):
            continue
        # a sphere is much brighter inside than its rim: skip faint blobs (plate edges, backdrop seams)
        rr = max(1, int(0.7 * v))
        win = tophat[max(0, int(y) - rr): min(hs, int(y) + rr + 1), max(0, int(x) - rr): min(ws, int(x) + rr + 1)]
        if win.size and float(np.median(win)) < cfg.min_blob_contrast:
            continue
        acc.append((x, y, v))
        if len(acc) >= cfg.max_candidates:
            break
    out: list[SphereImage] = []
    neighbours: list[list[int]] = []
    for n, (x, y, v) in enumerate(acc):
        c_px = np.array([(x + 0.5) * ds - 0.5, (y + 0.5) * ds - 0.5])
        r_px = float((v + 0.5) * ds)
        neighbours.append(
            [m for m, (a, b, r2) in enumerate(acc) if m != n and r2 >= 0.5 * v and np.hypot(x - a, y - b) < v + r2 + 2.0]
        )
        out.append(_measure_candidate(gray, intr, c_px, r_px, sigma, sphere_radius, cfg, False, r_min))
    # merged: the blob touches another blob that is itself sphere-like (an outline that fits a cone);
    # touching something else (an arm, a bracket) leaves the candidate to its own outline checks
    merged = [any(_sphere_like(out[m], cfg) for m in nb) for nb in neighbours]
    for n, s in enumerate(out):
        if merged[n] and s.reason in ("", "occluded", "not_round", "no_edge", "low_contrast"):
            object.__setattr__(s, "ok", False)
            object.__setattr__(s, "reason", "merged")
        s.notes["touching"] = [int(m) for m in neighbours[n]]
    return out


def _sphere_like(s: SphereImage, cfg: DetectorConfig) -> bool:
    """An outline that mostly fits a cone (accepted, or rejected only for a partial outline)."""
    return s.cone is not None and s.inlier_fraction >= 0.5 and s.rms_px <= 2 * cfg.max_rms_px


def _measure_candidate(gray, intr, c_px, r_px, sigma, sphere_radius, cfg, touching, r_min) -> SphereImage:
    rough: dict = {}
    s = _measure_candidate_inner(gray, intr, c_px, r_px, sigma, cfg, touching, r_min, rough)
    s.notes["rough_from"] = "cone" if (s.ok or "cone" in rough) else "blob"
    if s.ok:
        c = s.centre_mono()
    elif "cone" in rough:
        c = rough["cone"].centre(sphere_radius)
    else:
        f = 0.5 * (intr.fx + intr.fy)
        c = pixels_to_rays(np.asarray(c_px, float)[None], intr)[0] * (f * sphere_radius / max(r_px, 1.0))
    if not s.ok or s.ray is not None:
        # distance from the cone and the known radius (rejected candidates: from the last cone, if any)
        cone = s.cone if s.cone is not None else rough.get("cone")
        if cone is not None:
            object.__setattr__(s, "distance", cone.distance(sphere_radius))
    object.__setattr__(s, "centre_rough", c)
    return s


def _crosses_border(centre, radius, shape, margin) -> bool:
    H, W = shape
    return bool(
        centre[0] - radius < margin or centre[1] - radius < margin
        or centre[0] + radius > W - 1 - margin or centre[1] + radius > H - 1 - margin
    )


def _measure_candidate_inner(gray, intr, c_px, r_px, sigma, cfg, touching, r_min, rough) -> SphereImage:
    base = dict(coarse_px=np.asarray(c_px, float), coarse_radius_px=r_px)
    notes = {"touching_blob": touching}
    m = cfg.border_margin_px + 1.0
    if r_px * 1.3 < cfg.min_radius_px or r_px * 1.5 < r_min:
        reason = "out_of_frame" if _crosses_border(c_px, r_px, gray.shape, m) else "too_small"
        return SphereImage(False, reason, notes=notes, **base)
    if _crosses_border(c_px, r_px + cfg.downsample, gray.shape, m):
        # the blob's inscribed circle already reaches the border: no complete outline to measure
        return SphereImage(False, "out_of_frame", notes=notes, **base)
    p1 = _fit_outline(gray, intr, np.asarray(c_px, float), r_px, sigma, cfg, fine=False)
    if p1["cone"] is None:
        if _crosses_border(c_px, r_px, gray.shape, m) or p1["clipped"].mean() > 0.05:
            reason = "out_of_frame"
        elif touching:
            reason = "merged"
        else:
            con = p1["contrast"][np.isfinite(p1["contrast"])]
            reason = "low_contrast" if con.size and np.median(con) < cfg.min_contrast else "no_edge"
        return SphereImage(False, reason, notes=notes, **base)
    cone1 = p1["cone"]
    rough["cone"] = cone1
    # second pass around the fitted outline: centre of the inlier edge points' ellipse, mean radius
    try:
        e1 = fit_ellipse(p1["pts"][cone1.inliers])
    except (ValueError, cv2.error):
        return SphereImage(False, "no_edge", notes=notes, **base)
    c2, r2 = e1.centre, 0.25 * (e1.width + e1.height)
    if not (np.all(np.isfinite(c2)) and np.isfinite(r2) and r2 > 0):
        return SphereImage(False, "no_edge", notes=notes, **base)
    if _crosses_border(c2, r2 + 1.0, gray.shape, m):
        return SphereImage(False, "out_of_frame", radius_px=r2, notes=notes, **base)
    p2 = _fit_outline(gray, intr, c2, r2, sigma, cfg, fine=True)
    n_rays = p2["n_rays"]
    clipped_frac = float(p2["clipped"].mean())
    notes.update(pass1_inliers=float(cone1.inliers.mean()), clipped_fraction=clipped_frac, n_rays=n_rays)
    if clipped_frac > 0:
        return SphereImage(False, "out_of_frame", radius_px=r2, notes=notes, **base)
    if p2["cone"] is None:
        return SphereImage(False, "merged" if touching else "occluded", radius_px=r2, notes=notes, **base)
    cone = p2["cone"]
    rough["cone"] = cone
    valid = p2["valid"]
    inl_full = np.zeros(n_rays, dtype=bool)
    inl_full[np.flatnonzero(valid)[cone.inliers]] = True
    f = p2["f"]
    rms_px = float(np.sqrt(np.mean(cone.residual_rad[cone.inliers] ** 2)) * f)
    inlier_fraction = float(inl_full.mean())
    gap = _max_gap_deg(p2["angles"], inl_full)
    contrast = float(np.median(p2["contrast"][valid]))
    pts = p2["pts"]
    inl_pts = pts[cone.inliers]
    ell = fit_ellipse(inl_pts)
    # uncorrected: the centre of an ellipse fitted to the undistorted edge points (undistorted pixels)
    und = p2["rays"][cone.inliers]
    und_px = (und[:, :2] / und[:, 2:3]) * [intr.fx, intr.fy] + [intr.cx, intr.cy]
    e_und = fit_ellipse(und_px)
    ray_unc = np.array([(e_und.cx - intr.cx) / intr.fx, (e_und.cy - intr.cy) / intr.fy, 1.0])
    ray_unc /= np.linalg.norm(ray_unc)
    fields = dict(
        cone=cone,
        ray=cone.axis,
        ray_uncorrected=ray_unc,
        centre_px=rays_to_pixels(cone.axis[None], intr)[0],
        centre_px_uncorrected=rays_to_pixels(ray_unc[None], intr)[0],
        ellipse=ell,
        edge_px=pts,
        inliers=cone.inliers,
        radius_px=float(0.25 * (ell.width + ell.height)),
        rms_px=rms_px,
        inlier_fraction=inlier_fraction,
        max_gap_deg=gap,
        contrast=contrast,
        notes=notes,
    )
    reason = ""
    if fields["radius_px"] < cfg.min_radius_px or fields["radius_px"] * 1.25 < r_min:
        reason = "too_small"
    elif touching:
        reason = "merged"
    elif gap > cfg.max_gap_deg:
        reason = "occluded"
    elif rms_px > cfg.max_rms_px or inlier_fraction < cfg.min_inlier_fraction:
        reason = "not_round"
    elif contrast < cfg.min_contrast:
        reason = "low_contrast"
    return SphereImage(reason == "", reason, **base, **fields)
