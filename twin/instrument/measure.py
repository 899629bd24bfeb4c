"""One stereo pair -> the three sphere centres in the left camera's frame (or a reason per sphere).

Steps (all pure, arrays in, results out):

1. :func:`twin.instrument.detect.detect_spheres` in each image (estimated intrinsics, the plate's sphere
   radius): candidates measured to sub-pixel precision or rejected with a reason.
2. **Matching.** Every measured candidate also gives its centre from one camera (cone axis times
   ``R / sin(theta)``); right-camera centres are moved into the left frame with the estimated extrinsics and
   left/right candidates closer than ``match_tol`` are the same sphere. A matched pair must also pass the
   **epipolar check** (the right centre ray within ``epipolar_tol_px`` of the left ray's epipolar line).
3. **Triangulation** of the matched centre rays (``cv2.correctMatches`` + ``cv2.triangulatePoints`` on
   undistorted normalized points), with the cone axes (bias corrected) and, beside them, with the
   ellipse centres (uncorrected), so the perspective bias stays visible.
4. **Labelling** by pairwise distances against the plate geometry (unequal spacing makes it unique).
   Two accepted spheres alone fit two labellings; under each the third sphere lies on a known circle, and
   the centre ray of a rejected candidate (reliable even when its outline is not) near one circle and not
   the other decides; otherwise both stay unlabelled. Rejected candidates never give a centre: they only
   explain which sphere failed and why.
5. **Flags, never guesses.** A sphere that is out of frame, occluded, merged, too small, not round, not
   matched, failing the epipolar or size checks, or not labelled uniquely has no centre; its reason goes to
   ``status`` (``p2:out_of_frame(left)``). A centre is only ever the triangulation of two accepted outlines.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass, field

import numpy as np

from ..dataset import Plate
from ..transforms import invert_transform
from .calibration import StereoCalibration
from .detect import DetectorConfig, SphereImage, as_gray, detect_spheres
from .geometry import epipolar_distance_px, pixels_to_rays, rays_to_pixels, triangulate_rays
from .plate import PlateFit, check_plate_labelable, label_by_distances, plate_pose_from_spheres

__all__ = ["MeasureConfig", "PairMeasurement", "measure_pair", "format_status", "status_reasons"]


@dataclass(frozen=True)
class MeasureConfig:
    """Tolerances of :func:`measure_pair` (lengths [m])."""

    detector: DetectorConfig = field(default_factory=DetectorConfig)
    match_tol: float = 0.008  # left/right single-camera centres closer than this are one sphere [m]
    match_tol_rel: float = 0.01  # ... plus this fraction of the distance (single-camera depth is ~1e-3)
    epipolar_tol_px: float = 1.0  # right centre ray vs left epipolar line [px]
    label_tol: float = 0.004  # pairwise distances vs the plate's [m] (triangulated centres)
    mono_weight: float = 2.0  # single-camera centres may miss the plate distances by this x label_tol
    rough_ray_tol: float = 0.008  # a rejected sphere's centre ray vs the circle where it must lie [m]
    size_tol_rel: float = 0.03  # stereo vs single-camera distance (sphere size) [fraction]

    def __post_init__(self) -> None:
        for name in ("match_tol", "epipolar_tol_px", "label_tol", "size_tol_rel", "mono_weight", "rough_ray_tol"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be positive, got {v!r}")


def format_status(reasons) -> str:
    """``status`` cell from per-sphere reasons: ``"p0:occluded(left);p2:not_found"`` (empty if all measured)."""
    return ";".join(f"p{k}:{r}" for k, r in enumerate(reasons) if r)


_NUMBER = re.compile(r"\([0-9.]+(px|%)\)")


def status_reasons(status: str) -> list[str]:
    """The per-sphere reasons of a ``status`` cell (:func:`format_status`), each reduced to its kind: numbers in
    parentheses dropped (``"occluded(left)"`` stays, ``"epipolar(3.2px)"`` becomes ``"epipolar"``)."""
    out = []
    for part in filter(None, status.split(";")):
        _, _, why = part.partition(":")
        out.append(_NUMBER.sub("", why))
    return out


@dataclass(frozen=True, eq=False)
class PairMeasurement:
    """What one stereo pair measured. Frames: the left camera's OpenCV frame (the measurement frame).

    * ``centres``: three entries, each ``(3,)`` [m] or None (sphere ``k`` not measured; ``reasons[k]`` says
      why). Bias-corrected unless ``bias_correction`` was False.
    * ``centres_corrected`` / ``centres_uncorrected``: both versions, whatever the flag (cone axes vs
      ellipse centres triangulated).
    * ``left`` / ``right``: the accepted :class:`SphereImage` of each label in each image (or None);
      ``candidates_left`` / ``candidates_right``: everything detected, rejected ones with their reason.
    * ``epipolar_px`` ``(3,)``: epipolar distance of each matched sphere [px] (NaN where not matched).
    * ``time_s``: wall time of detection + matching + triangulation [s].
    """

    centres: tuple
    centres_corrected: tuple
    centres_uncorrected: tuple
    reasons: tuple
    left: tuple
    right: tuple
    candidates_left: tuple
    candidates_right: tuple
    epipolar_px: np.ndarray
    bias_correction: bool
    time_s: float

    @property
    def status(self) -> str:
        return format_status(self.reasons)

    @property
    def measured(self) -> np.ndarray:
        """``(3,)`` bool: which spheres have a centre."""
        return np.array([c is not None for c in self.centres])

    @property
    def complete(self) -> bool:
        return bool(self.measured.all())

    def centres_array(self) -> np.ndarray:
        """``(3, 3)`` [m]; only for a complete measurement (raises ``ValueError`` otherwise)."""
        if not self.complete:
            raise ValueError(f"centres_array: not all spheres were measured ({self.status})")
        return np.stack(self.centres)

    def plate_pose(self, plate: Plate) -> PlateFit | None:
        """Rigid plate pose from the three centres, or None when a sphere is missing."""
        return plate_pose_from_spheres(self.centres, plate) if self.complete else None


@dataclass
class _Cluster:
    """One physical sphere seen by one or both cameras (accepted observations only)."""

    left: SphereImage | None = None
    right: SphereImage | None = None
    point: np.ndarray | None = None  # position in the left frame: triangulated, or one camera's
    weight: float = 1.0  # labelling tolerance factor (single-camera positions are less precise)
    centre_c: np.ndarray | None = None
    centre_u: np.ndarray | None = None
    epi: float = float("nan")
    reason: str = ""


def measure_pair(
    left: np.ndarray,
    right: np.ndarray,
    calib: StereoCalibration,
    plate: Plate,
    *,
    bias_correction: bool = True,
    config: MeasureConfig | None = None,
) -> PairMeasurement:
    """Measure the three sphere centres in one stereo pair (images as arrays; greyscale or RGB).

    ``calib``: the estimated rig (:func:`twin.instrument.calibrate_stereo`); ``plate``: the nominal plate
    (sphere diameter and layout, used for the sphere radius and the labels). Never raises on a bad image:
    spheres that cannot be measured come back as None with a reason.
    """
    cfg = config or MeasureConfig()
    if not isinstance(calib, StereoCalibration):
        raise ValueError(f"calib must be a StereoCalibration, got {type(calib).__name__}")
    if not isinstance(plate, Plate):
        raise ValueError(f"plate must be a twin.dataset.Plate, got {type(plate).__name__}")
    check_plate_labelable(plate, cfg.mono_weight * cfg.label_tol)
    t0 = time.perf_counter()
    R = 0.5 * plate.sphere_diameter
    cands_l = tuple(_safe_detect(left, calib.left, R, cfg.detector, "left"))
    cands_r = tuple(_safe_detect(right, calib.right, R, cfg.detector, "right"))
    l2r = calib.left2right
    r2l = invert_transform(l2r)
    rig = _Rig(calib, r2l)

    # ---- match accepted candidates by their single-camera centres (in the left frame)
    ok_l = [c for c in cands_l if c.ok]
    ok_r = [c for c in cands_r if c.ok]
    pl = [c.centre_mono() for c in ok_l]
    pr = [rig.to_left(c.centre_mono()) for c in ok_r]
    pairs = []
    for i, a in enumerate(pl):
        for j, b in enumerate(pr):
            d = np.linalg.norm(a - b)
            if d < cfg.match_tol + cfg.match_tol_rel * np.linalg.norm(a):
                pairs.append((d, i, j))
    used_l, used_r = set(), set()
    clusters: list[_Cluster] = []
    f_r = 0.5 * (calib.right.fx + calib.right.fy)
    for _, i, j in sorted(pairs, key=lambda x: x[0]):
        if i in used_l or j in used_r:
            continue
        used_l.add(i)
        used_r.add(j)
        a, b = ok_l[i], ok_r[j]
        cl = _Cluster(left=a, right=b)
        cl.epi = float(epipolar_distance_px(a.ray[None], b.ray[None], l2r, f_r)[0])
        cl.centre_c = triangulate_rays(a.ray[None], b.ray[None], l2r)[0]
        cl.centre_u = triangulate_rays(a.ray_uncorrected[None], b.ray_uncorrected[None], l2r)[0]
        cl.point = cl.centre_c
        if cl.epi > cfg.epipolar_tol_px:
            cl.reason = f"epipolar({cl.epi:.2f}px)"
            cl.point = 0.5 * (pl[i] + pr[j])
            cl.weight = cfg.mono_weight
        else:
            # sphere size: stereo distance vs each camera's R / sin(theta)
            dl = np.linalg.norm(cl.centre_c)
            dr = np.linalg.norm(l2r[:3, :3] @ cl.centre_c + l2r[:3, 3])
            rel = max(abs(dl / a.distance - 1), abs(dr / b.distance - 1))
            if rel > cfg.size_tol_rel:
                cl.reason = f"size_mismatch({100 * rel:.1f}%)"
        clusters.append(cl)
    for i, c in enumerate(ok_l):
        if i not in used_l:
            cl = _Cluster(left=c, point=pl[i], weight=cfg.mono_weight)
            cl.reason = _other_side_reason(cl.point, "right", rig, cands_r, R)
            clusters.append(cl)
    for j, c in enumerate(ok_r):
        if j not in used_r:
            cl = _Cluster(right=c, point=pr[j], weight=cfg.mono_weight)
            cl.reason = _other_side_reason(cl.point, "left", rig, cands_l, R)
            clusters.append(cl)

    # ---- labels
    labels = -np.ones(len(clusters), dtype=int)
    third_reason = ""
    if clusters:
        P = np.array([c.point for c in clusters])
        w = np.array([c.weight for c in clusters])
        lab, amb = label_by_distances(P, plate, cfg.label_tol, weights=w)
        labels[:] = lab
        if amb and len(amb) == 2:
            lab2, third_reason = _label_pair_by_rejected_rays(P[amb], plate, rig, cands_l, cands_r, cfg)
            if lab2 is not None:
                labels[amb] = lab2
    centres_c, centres_u, reasons, obs_l, obs_r = [None] * 3, [None] * 3, [""] * 3, [None] * 3, [None] * 3
    epi = np.full(3, np.nan)
    n_unlabelled = int(np.sum(labels < 0))
    for k in range(3):
        idx = np.flatnonzero(labels == k)
        if idx.size == 0:
            if third_reason and sum(labels >= 0) == 2:
                reasons[k] = third_reason
            elif n_unlabelled and len(clusters) >= 1 and not (labels >= 0).any():
                reasons[k] = "unlabelled"
            else:
                reasons[k] = _missing_reason(cands_l, cands_r)
            continue
        cl = clusters[idx[0]]
        obs_l[k], obs_r[k], epi[k] = cl.left, cl.right, cl.epi
        if cl.reason or cl.centre_c is None:
            reasons[k] = cl.reason or "not_matched"
            continue
        centres_c[k] = cl.centre_c
        centres_u[k] = cl.centre_u
    centres = centres_c if bias_correction else centres_u
    return PairMeasurement(
        centres=tuple(centres),
        centres_corrected=tuple(centres_c),
        centres_uncorrected=tuple(centres_u),
        reasons=tuple(reasons),
        left=tuple(obs_l),
        right=tuple(obs_r),
        candidates_left=cands_l,
        candidates_right=cands_r,
        epipolar_px=epi,
        bias_correction=bool(bias_correction),
        time_s=time.perf_counter() - t0,
    )


@dataclass(frozen=True)
class _Rig:
    calib: StereoCalibration
    r2l: np.ndarray

    def to_left(self, p):
        return self.r2l[:3, :3] @ p + self.r2l[:3, 3]

    def to_side(self, p_left, side):
        if side == "left":
            return np.asarray(p_left, float)
        T = self.calib.left2right
        return T[:3, :3] @ p_left + T[:3, 3]

    def intr(self, side):
        return self.calib.left if side == "left" else self.calib.right

    def origin_left(self, side):
        """Camera centre of ``side`` in the left frame."""
        return np.zeros(3) if side == "left" else self.r2l[:3, 3].copy()

    def dir_left(self, ray, side):
        return np.asarray(ray, float) if side == "left" else self.r2l[:3, :3] @ ray


def _predict_in(p_left, side, rig: _Rig, radius):
    """Pixel position and radius [px] where a sphere at ``p_left`` would appear in ``side``'s image."""
    p = rig.to_side(p_left, side)
    if p[2] <= radius:
        return None, 0.0
    intr = rig.intr(side)
    uv = rays_to_pixels((p / np.linalg.norm(p))[None], intr)[0]
    r_px = 0.5 * (intr.fx + intr.fy) * radius / np.linalg.norm(p)
    return uv, r_px


def _other_side_reason(p_left, side, rig: _Rig, cands, radius) -> str:
    """Why a sphere accepted in one image has no partner in the other: what lies where it should appear."""
    uv, r_px = _predict_in(p_left, side, rig, radius)
    intr = rig.intr(side)
    if uv is None:
        return f"out_of_frame({side})"
    if uv[0] - r_px < 0 or uv[1] - r_px < 0 or uv[0] + r_px > intr.width - 1 or uv[1] + r_px > intr.height - 1:
        return f"out_of_frame({side})"
    near = [c for c in cands if not c.ok and np.linalg.norm(c.coarse_px - uv) < 0.5 * r_px + 5.0]
    if near:
        c = min(near, key=lambda c: np.linalg.norm(c.coarse_px - uv))
        return f"{c.reason}({side})"
    ok_near = [c for c in cands if c.ok and np.linalg.norm(c.centre_px - uv) < 0.5 * r_px + 5.0]
    if ok_near:
        return f"not_matched({side})"
    return f"not_found({side})"


def _third_circle(pa, pb, da, db):
    """Circle of points at distance ``da`` from ``pa`` and ``db`` from ``pb``: (centre, axis, radius) or None."""
    L = np.linalg.norm(pb - pa)
    e = (pb - pa) / L
    x = (da * da - db * db + L * L) / (2 * L)
    r2 = da * da - x * x
    if r2 <= 0:
        return None
    return pa + x * e, e, np.sqrt(r2)


def _ray_circle_distance(o, d, circle, n=360):
    c, e, r = circle
    u = np.cross(e, [1.0, 0.0, 0.0])
    if np.linalg.norm(u) < 1e-6:
        u = np.cross(e, [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(e, u)
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    pts = c + r * (np.cos(t)[:, None] * u + np.sin(t)[:, None] * v)
    w = pts - o
    along = np.maximum(w @ d, 0.0)
    return float(np.min(np.linalg.norm(w - along[:, None] * d, axis=1)))


def _label_pair_by_rejected_rays(P2, plate, rig: _Rig, cands_l, cands_r, cfg):
    """Two accepted spheres fit two labels both ways round. Under each hypothesis the third sphere lies on
    a known circle; a rejected candidate's centre ray (its direction is reliable even when its outline is
    not) passing near one circle and clearly not the other decides. Returns (labels (2,), reason of the
    third sphere) or (None, "")."""
    D = plate.pairwise_distances
    dmap = {frozenset((0, 1)): D[0], frozenset((0, 2)): D[1], frozenset((1, 2)): D[2]}
    L = np.linalg.norm(P2[1] - P2[0])
    pair = min(dmap, key=lambda k: abs(dmap[k] - L))
    i, j = sorted(pair)
    k = ({0, 1, 2} - {i, j}).pop()
    rays = []
    for side, cands in (("left", cands_l), ("right", cands_r)):
        for c in cands:
            if c.ok:
                continue
            d = c.cone.axis if c.cone is not None else pixels_to_rays(c.coarse_px[None], rig.intr(side))[0]
            rays.append((rig.origin_left(side), rig.dir_left(d, side), c, side))
    if not rays:
        return None, ""
    hyps = [np.array([i, j]), np.array([j, i])]  # labels of P2[0], P2[1]
    scores = []
    for h in hyps:
        lab2pt = {int(h[0]): P2[0], int(h[1]): P2[1]}
        circ = _third_circle(lab2pt[i], lab2pt[j], dmap[frozenset((i, k))], dmap[frozenset((j, k))])
        if circ is None:
            scores.append((np.inf, None))
            continue
        best = min(((_ray_circle_distance(o, d, circ), (c, side)) for o, d, c, side in rays), key=lambda x: x[0])
        scores.append(best)
    (s0, w0), (s1, w1) = scores
    good, bad = (0, 1) if s0 < s1 else (1, 0)
    s_good, s_bad = scores[good][0], scores[bad][0]
    tol = cfg.rough_ray_tol
    if s_good < tol and s_bad > 2 * tol:
        c, side = scores[good][1]
        same = [f"{x.reason}({sd})" for o, d, x, sd in rays
                if _ray_circle_distance(o, d, _third_circle(*_hyp_points(hyps[good], P2, i, j), dmap[frozenset((i, k))], dmap[frozenset((j, k))])) < tol]
        return hyps[good], "/".join(dict.fromkeys(same)) or f"{c.reason}({side})"
    return None, ""


def _hyp_points(h, P2, i, j):
    lab2pt = {int(h[0]): P2[0], int(h[1]): P2[1]}
    return lab2pt[i], lab2pt[j]


def _safe_detect(image, intr, radius, cfg, side) -> list[SphereImage]:
    try:
        g = as_gray(image)
    except ValueError:
        return []
    if g.shape != (intr.height, intr.width):
        raise ValueError(
            f"{side}: image size {g.shape[1]}x{g.shape[0]} differs from the calibration's {intr.width}x{intr.height}"
        )
    return detect_spheres(g, intr, radius, cfg)


def _missing_reason(cands_l, cands_r) -> str:
    """Reason for a label no accepted sphere claimed: what each image shows."""
    why = []
    for side, cands in (("left", cands_l), ("right", cands_r)):
        rej = sorted({c.reason for c in cands if not c.ok})
        if not cands:
            why.append(f"not_found({side})")
        elif len(rej) == 1:
            why.append(f"{rej[0]}({side})")
    return "/".join(why) if why else "not_found"
