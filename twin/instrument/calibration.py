"""Stereo calibration of the camera rig from ChArUco board views (OpenCV).

Both cameras' intrinsics and distortion and the left-to-right extrinsics are *estimated* from images of
a board of known geometry, never read from the world. Steps:

1. ChArUco corners in every image (``cv2.aruco.CharucoDetector``, sub-pixel corners). A view whose board
   is not found in one of the images (fewer than ``min_corners`` corners) is rejected with the reason.
2. Each camera alone: ``cv2.calibrateCameraExtended`` on its views; views whose reprojection RMS exceeds
   ``max(outlier_factor * median, max_view_rms_px)`` are rejected (a corrupt or mis-detected view) and
   the camera recalibrated.
3. The pair: ``cv2.stereoCalibrateExtended`` on the corners both images of a view share, starting from
   the single-camera intrinsics and refining everything jointly; again outlying views are rejected.

OpenCV runs these on one thread (its thread count restored after): its threads sum the normal equations in any
order, so two runs on the same corners would differ in the last bits (~1e-12 relative) and a campaign would not
reproduce its own files.

The result is small (two intrinsics, a transform, per-view figures) and saved as JSON
(``docs/formats.md``, "Stereo calibration") so that campaigns reuse it.
"""

from __future__ import annotations

import json
import os
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Sequence

import cv2
import numpy as np

from ..camera import CameraIntrinsics
from ..files import read_json
from ..units import M_PER_MM, MM_PER_M
from .detect import as_gray

__all__ = [
    "BoardSpec",
    "BoardView",
    "ViewReport",
    "StereoCalibration",
    "detect_board",
    "calibrate_stereo",
    "calibrate_stereo_views",
    "CALIBRATION_SCHEMA_VERSION",
]

CALIBRATION_SCHEMA_VERSION = 1


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board: ``squares_x`` x ``squares_y`` squares of ``square`` [m] with ArUco markers of
    ``marker`` [m] from the OpenCV dictionary ``dictionary`` (e.g. ``"DICT_5X5_100"``)."""

    squares_x: int = 11
    squares_y: int = 8
    square: float = 0.018
    marker: float = 0.0135
    dictionary: str = "DICT_5X5_100"
    type: str = "charuco"

    def __post_init__(self) -> None:
        if self.type != "charuco":
            raise ValueError(f"board.type: only 'charuco' is supported, got {self.type!r}")
        if self.squares_x < 2 or self.squares_y < 2:
            raise ValueError(f"board: squares_x, squares_y must be >= 2, got {self.squares_x} x {self.squares_y}")
        if not (0 < self.marker < self.square):
            raise ValueError(f"board: need 0 < marker < square [m], got marker={self.marker}, square={self.square}")
        if not hasattr(cv2.aruco, self.dictionary):
            raise ValueError(f"board.dictionary: unknown OpenCV ArUco dictionary {self.dictionary!r}")

    @classmethod
    def from_table(cls, table: dict[str, Any]) -> "BoardSpec":
        """From the ``[board]`` table of ``rig.toml`` (``square_mm``, ``marker_mm``, ...)."""
        try:
            return cls(
                squares_x=int(table["squares_x"]),
                squares_y=int(table["squares_y"]),
                square=float(table["square_mm"]) / MM_PER_M,
                marker=float(table["marker_mm"]) / MM_PER_M,
                dictionary=str(table["dictionary"]),
                type=str(table.get("type", "charuco")),
            )
        except KeyError as exc:
            raise ValueError(f"board: missing field {exc.args[0]!r}") from None

    def to_table(self) -> dict[str, Any]:
        return {
            "type": self.type,
            "squares_x": self.squares_x,
            "squares_y": self.squares_y,
            "square_mm": self.square * MM_PER_M,
            "marker_mm": self.marker * MM_PER_M,
            "dictionary": self.dictionary,
        }

    def cv_board(self):
        """The ``cv2.aruco.CharucoBoard``."""
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square, self.marker, d)


@dataclass(frozen=True, eq=False)
class BoardView:
    """ChArUco corners found in one image: ``ids`` ``(n,)``, ``corners_px`` ``(n, 2)``, ``object_points``
    ``(n, 3)`` [m] in the board frame; ``reason`` is empty when the view is usable."""

    ids: np.ndarray
    corners_px: np.ndarray
    object_points: np.ndarray
    n_markers: int
    reason: str = ""

    @property
    def ok(self) -> bool:
        return self.reason == ""


def detect_board(image: np.ndarray, board: BoardSpec, *, min_corners: int = 12, _detector=None) -> BoardView:
    """ChArUco corners of ``board`` in ``image`` (sub-pixel). Never raises on a bad image: a view without
    enough corners comes back with ``reason`` set."""
    empty = BoardView(np.zeros(0, int), np.zeros((0, 2)), np.zeros((0, 3)), 0)
    try:
        gray = as_gray(image)
    except ValueError as exc:
        return BoardView(empty.ids, empty.corners_px, empty.object_points, 0, f"unreadable image ({exc})")
    if gray.dtype != np.uint8:
        g = gray.astype(np.float64)
        if g.max() > 255:
            g = g * (255.0 / max(g.max(), 1.0))
        gray = np.clip(np.rint(g), 0, 255).astype(np.uint8)
    cvb = board.cv_board()
    det = _detector or cv2.aruco.CharucoDetector(cvb)
    try:
        ch_corners, ch_ids, m_corners, m_ids = det.detectBoard(gray)
    except cv2.error as exc:  # pragma: no cover - OpenCV refusing an image
        return BoardView(empty.ids, empty.corners_px, empty.object_points, 0, f"detector error ({exc.msg.strip()})")
    n_markers = 0 if m_ids is None else len(m_ids)
    n = 0 if ch_ids is None else len(ch_ids)
    if n < min_corners:
        return BoardView(
            empty.ids, empty.corners_px, empty.object_points, n_markers,
            f"pattern not found ({n} ChArUco corners, {n_markers} markers; need {min_corners} corners)",
        )
    ids = ch_ids.reshape(-1).astype(int)
    obj = cvb.getChessboardCorners()[ids]
    return BoardView(ids, ch_corners.reshape(-1, 2).astype(np.float64), np.asarray(obj, np.float64), n_markers)


@dataclass(frozen=True)
class ViewReport:
    """What happened to one board view: ``used`` in the final stereo calibration or ``reason`` why not;
    corner counts and reprojection RMS [px] (NaN where not computed)."""

    index: int
    name: str
    used: bool
    reason: str
    corners_left: int
    corners_right: int
    corners_common: int
    rms_left_px: float = float("nan")
    rms_right_px: float = float("nan")


@dataclass(frozen=True, eq=False)
class StereoCalibration:
    """An estimated stereo rig. ``left2right`` ``(4, 4)`` maps left-camera points into the right camera
    frame (OpenCV frames; ``p_right = R p_left + t``, ``t`` [m]). ``rms_px`` is the overall stereo
    reprojection RMS, ``rms_left_px``/``rms_right_px`` those of the cameras' own calibrations."""

    left: CameraIntrinsics
    right: CameraIntrinsics
    left2right: np.ndarray
    rms_px: float
    rms_left_px: float
    rms_right_px: float
    views: tuple[ViewReport, ...] = ()
    board: BoardSpec | None = None
    flags: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        T = np.asarray(self.left2right, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"left2right must be a finite (4, 4) transform, got shape {T.shape}")
        if (self.left.width, self.left.height) != (self.right.width, self.right.height):
            raise ValueError("left/right: the two cameras must have the same image size")
        T = T.copy()
        T.setflags(write=False)
        object.__setattr__(self, "left2right", T)

    @property
    def baseline(self) -> float:
        """Distance between the two camera centres [m]."""
        return float(np.linalg.norm(self.left2right[:3, 3]))

    @property
    def image_size(self) -> tuple[int, int]:
        return (self.left.width, self.left.height)

    @property
    def n_views_used(self) -> int:
        return sum(v.used for v in self.views)

    # -------------------------------------------------------------- JSON (docs/formats.md)
    def to_dict(self) -> dict[str, Any]:
        def cam(c: CameraIntrinsics) -> dict[str, Any]:
            return {"fx_px": c.fx, "fy_px": c.fy, "cx_px": c.cx, "cy_px": c.cy, "dist": list(c.dist)}

        return {
            "schema_version": CALIBRATION_SCHEMA_VERSION,
            "kind": "stereo_calibration",
            "image_width": self.left.width,
            "image_height": self.left.height,
            "left": cam(self.left),
            "right": cam(self.right),
            "left2right": {
                "R": [[float(x) for x in row] for row in self.left2right[:3, :3]],
                "t_mm": [float(x) / M_PER_MM for x in self.left2right[:3, 3]],
            },
            "baseline_mm": self.baseline / M_PER_MM,
            "rms_px": self.rms_px,
            "rms_left_px": self.rms_left_px,
            "rms_right_px": self.rms_right_px,
            "board": self.board.to_table() if self.board else None,
            "flags": self.flags,
            "views": [_nan_to_none(asdict(v)) for v in self.views],
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "stereo calibration") -> "StereoCalibration":
        if d.get("schema_version") != CALIBRATION_SCHEMA_VERSION:
            raise ValueError(f"{where}: unknown schema_version {d.get('schema_version')!r} (this reader knows {CALIBRATION_SCHEMA_VERSION})")
        if d.get("kind") != "stereo_calibration":
            raise ValueError(f"{where}: field 'kind' is {d.get('kind')!r}, expected 'stereo_calibration'")
        try:
            w, h = int(d["image_width"]), int(d["image_height"])

            def cam(c: dict) -> CameraIntrinsics:
                return CameraIntrinsics(
                    float(c["fx_px"]), float(c["fy_px"]), float(c["cx_px"]), float(c["cy_px"]), w, h,
                    tuple(float(x) for x in c["dist"]),
                )

            T = np.eye(4)
            T[:3, :3] = np.asarray(d["left2right"]["R"], float)
            T[:3, 3] = np.asarray(d["left2right"]["t_mm"], float) * M_PER_MM
            views = tuple(ViewReport(**{k: (float("nan") if v is None else v) for k, v in vd.items()}) for vd in d.get("views", []))
            board = BoardSpec.from_table(d["board"]) if d.get("board") else None
            return cls(
                cam(d["left"]), cam(d["right"]), T, float(d["rms_px"]), float(d["rms_left_px"]), float(d["rms_right_px"]),
                views, board, dict(d.get("flags") or {}),
            )
        except (KeyError, TypeError) as exc:
            raise ValueError(f"{where}: missing or malformed field ({exc})") from None

    def save(self, path: str | os.PathLike) -> Path:
        """Write the calibration as JSON (mm and px at the edge)."""
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(json.dumps(self.to_dict(), indent=2) + "\n")
        return p

    @classmethod
    def load(cls, path: str | os.PathLike) -> "StereoCalibration":
        p = Path(path)
        return cls.from_dict(read_json(p, missing="no such stereo-calibration file"), str(p))


def _nan_to_none(d: dict) -> dict:
    return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in d.items()}


def _dist_flags(dist_model: str) -> int:
    if dist_model == "k1k2p1p2":
        return cv2.CALIB_FIX_K3
    if dist_model == "k1k2p1p2k3":
        return 0
    if dist_model == "k1k2":
        return cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
    if dist_model == "none":
        return cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
    raise ValueError(f"dist_model must be one of 'none', 'k1k2', 'k1k2p1p2', 'k1k2p1p2k3', got {dist_model!r}")


_CRIT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)


@contextmanager
def _one_opencv_thread():
    """OpenCV on one thread inside the block (the same bits on every run), its thread count restored after."""
    n = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(n)


def _calibrate_one(obj, img, size, flags):
    with _one_opencv_thread():
        rms, K, dist, rvecs, tvecs, _, _, per_view = cv2.calibrateCameraExtended(
            obj, img, size, None, None, flags=flags, criteria=_CRIT
        )
    return float(rms), K, dist.reshape(-1), np.asarray(per_view).reshape(-1)


def calibrate_stereo(
    board_pairs: Sequence[tuple[np.ndarray, np.ndarray]],
    board: BoardSpec,
    *,
    names: Sequence[str] | None = None,
    min_corners: int = 12,
    min_views: int = 6,
    max_view_rms_px: float = 0.5,
    outlier_factor: float = 3.0,
    dist_model: str = "k1k2p1p2",
    fix_aspect_ratio: bool = False,
) -> StereoCalibration:
    """Estimate the stereo rig from pairs of board images ``[(left, right), ...]`` (same moment each).

    Views whose board is not found in one image, that share fewer than ``min_corners`` corners between the
    images, or whose reprojection RMS is an outlier (above ``max(outlier_factor * median, max_view_rms_px)``)
    are rejected and reported in ``views`` with the reason. Raises ``ValueError`` if fewer than
    ``min_views`` views remain. ``dist_model`` chooses which of OpenCV's coefficients are estimated
    (``"k1k2p1p2"`` by default: k3 fixed at zero, which a narrow lens does not constrain). The corners of each
    image are found by :func:`detect_board`, then :func:`calibrate_stereo_views` does the rest.
    """
    pairs = list(board_pairs)
    if len(pairs) < min_views:
        raise ValueError(f"board_pairs: need at least {min_views} views, got {len(pairs)}")
    sizes = set()
    det = cv2.aruco.CharucoDetector(board.cv_board())
    views = []
    for il, ir in pairs:
        views.append((detect_board(il, board, min_corners=min_corners, _detector=det),
                      detect_board(ir, board, min_corners=min_corners, _detector=det)))
        for im in (il, ir):
            a = np.asarray(im)
            if a.ndim >= 2:
                sizes.add((a.shape[1], a.shape[0]))
    if len(sizes) != 1:
        raise ValueError(f"board_pairs: images differ in size: {sorted(sizes)}")
    return calibrate_stereo_views(views, sizes.pop(), board, names=names, min_corners=min_corners,
                                  min_views=min_views, max_view_rms_px=max_view_rms_px, outlier_factor=outlier_factor,
                                  dist_model=dist_model, fix_aspect_ratio=fix_aspect_ratio, _what="board_pairs")


def calibrate_stereo_views(
    views: Sequence[tuple[BoardView, BoardView]],
    image_size: tuple[int, int],
    board: BoardSpec,
    *,
    names: Sequence[str] | None = None,
    min_corners: int = 12,
    min_views: int = 6,
    max_view_rms_px: float = 0.5,
    outlier_factor: float = 3.0,
    dist_model: str = "k1k2p1p2",
    fix_aspect_ratio: bool = False,
    _what: str = "views",
) -> StereoCalibration:
    """:func:`calibrate_stereo` from the board corners already found in each image (:func:`detect_board` of the
    left and the right image of each view, e.g. in other processes): ``views`` ``[(left, right), ...]``,
    ``image_size`` ``(width, height)`` [px] of every image. The same result as :func:`calibrate_stereo` on the
    images."""
    pairs = list(views)
    if len(pairs) < min_views:
        raise ValueError(f"views: need at least {min_views} views, got {len(pairs)}")
    for k, pair in enumerate(pairs):
        if len(pair) != 2 or not all(isinstance(v, BoardView) for v in pair):
            raise ValueError(f"views[{k}]: expected a (left, right) pair of BoardView, got {pair!r}")
    size = tuple(int(x) for x in image_size)
    if len(size) != 2 or min(size) <= 0:
        raise ValueError(f"image_size must be (width, height) > 0 [px], got {image_size!r}")
    names = list(names) if names is not None else [f"{k:03d}" for k in range(len(pairs))]
    if len(names) != len(pairs):
        raise ValueError(f"names: {len(names)} names for {len(pairs)} board views")
    flags = _dist_flags(dist_model)
    if fix_aspect_ratio:
        flags |= cv2.CALIB_FIX_ASPECT_RATIO
    views_l, views_r, reasons = [], [], []
    for vl, vr in pairs:
        why = []
        if not vl.ok:
            why.append(f"left: {vl.reason}")
        if not vr.ok:
            why.append(f"right: {vr.reason}")
        views_l.append(vl)
        views_r.append(vr)
        reasons.append("; ".join(why))

    # ---- each camera alone (views where that camera saw the board), with outlier rejection
    def mono(views):
        use = [k for k, v in enumerate(views) if v.ok]
        per = {}
        for _ in range(3):
            if len(use) < min_views:
                raise ValueError(
                    f"{_what}: only {len(use)} usable board views (need {min_views}); reasons: "
                    + "; ".join(f"{names[k]}: {r}" for k, r in enumerate(reasons) if r)
                )
            obj = [views[k].object_points.astype(np.float32) for k in use]
            img = [views[k].corners_px.astype(np.float32).reshape(-1, 1, 2) for k in use]
            rms, K, dist, pv = _calibrate_one(obj, img, size, flags)
            per = dict(zip(use, pv))
            lim = max(outlier_factor * float(np.median(pv)), max_view_rms_px)
            bad = [k for k in use if per[k] > lim]
            if not bad:
                return rms, K, dist, per, lim
            use = [k for k in use if k not in bad]
        return rms, K, dist, per, lim

    rms_l, K_l, d_l, per_l, lim_l = mono(views_l)
    rms_r, K_r, d_r, per_r, lim_r = mono(views_r)
    for k in range(len(pairs)):
        if reasons[k]:
            continue
        why = []
        if per_l.get(k, np.inf) > lim_l:
            why.append(f"left reprojection RMS {per_l.get(k, float('nan')):.3f} px is an outlier (limit {lim_l:.3f})")
        if per_r.get(k, np.inf) > lim_r:
            why.append(f"right reprojection RMS {per_r.get(k, float('nan')):.3f} px is an outlier (limit {lim_r:.3f})")
        reasons[k] = "; ".join(why)

    # ---- the pair: common corners, joint refinement
    common: dict[int, tuple] = {}
    for k in range(len(pairs)):
        if reasons[k]:
            continue
        ids, il, ir = np.intersect1d(views_l[k].ids, views_r[k].ids, return_indices=True)
        if ids.size < min_corners:
            reasons[k] = f"only {ids.size} corners seen by both cameras (need {min_corners})"
            continue
        common[k] = (views_l[k].object_points[il], views_l[k].corners_px[il], views_r[k].corners_px[ir])
    use = sorted(common)
    sflags = flags | cv2.CALIB_USE_INTRINSIC_GUESS
    for _ in range(3):
        if len(use) < min_views:
            raise ValueError(
                f"{_what}: only {len(use)} views usable for the stereo calibration (need {min_views}); reasons: "
                + "; ".join(f"{names[k]}: {r}" for k, r in enumerate(reasons) if r)
            )
        obj = [common[k][0].astype(np.float32) for k in use]
        pl = [common[k][1].astype(np.float32).reshape(-1, 1, 2) for k in use]
        pr = [common[k][2].astype(np.float32).reshape(-1, 1, 2) for k in use]
        with _one_opencv_thread():
            out = cv2.stereoCalibrateExtended(
                obj, pl, pr, K_l.copy(), d_l.copy(), K_r.copy(), d_r.copy(), size, None, None,
                flags=sflags, criteria=_CRIT,
            )
        rms, K1, D1, K2, D2, R, T = out[0], out[1], out[2], out[3], out[4], out[5], out[6]
        per_view = np.asarray(out[11]).reshape(len(use), 2)
        lim = max(outlier_factor * float(np.median(per_view)), max_view_rms_px)
        bad = [k for k, e in zip(use, per_view) if e.max() > lim]
        stereo_per = dict(zip(use, per_view))
        if not bad:
            break
        for k in bad:
            reasons[k] = f"stereo reprojection RMS {stereo_per[k].max():.3f} px is an outlier (limit {lim:.3f})"
        use = [k for k in use if k not in bad]

    def intr(K, D) -> CameraIntrinsics:
        D = np.asarray(D, float).reshape(-1)
        return CameraIntrinsics(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), size[0], size[1], tuple(float(x) for x in D[:5]))

    left2right = np.eye(4)
    left2right[:3, :3] = R
    left2right[:3, 3] = np.asarray(T, float).reshape(3)
    reports = []
    for k in range(len(pairs)):
        used = k in stereo_per and k in use
        pv = stereo_per.get(k)
        reports.append(
            ViewReport(
                index=k,
                name=str(names[k]),
                used=bool(used),
                reason="" if used else (reasons[k] or "rejected"),
                corners_left=int(views_l[k].ids.size),
                corners_right=int(views_r[k].ids.size),
                corners_common=int(common[k][0].shape[0]) if k in common else 0,
                rms_left_px=float(pv[0]) if pv is not None else float(per_l.get(k, float("nan"))),
                rms_right_px=float(pv[1]) if pv is not None else float(per_r.get(k, float("nan"))),
            )
        )
    return StereoCalibration(
        left=intr(K1, D1),
        right=intr(K2, D2),
        left2right=left2right,
        rms_px=float(rms),
        rms_left_px=float(rms_l),
        rms_right_px=float(rms_r),
        views=tuple(reports),
        board=board,
        flags={"dist_model": dist_model, "fix_aspect_ratio": fix_aspect_ratio, "min_corners": min_corners,
               "max_view_rms_px": max_view_rms_px, "outlier_factor": outlier_factor},
    )
