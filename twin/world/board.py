"""The ChArUco calibration board: its texture (``cv2.aruco``) and the poses it is shown at.

Board frame (OpenCV's, as in ``CharucoBoard.getChessboardCorners``): origin at the outer top-left corner
of the chessboard, x along ``squares_x``, y along ``squares_y`` (down on the printed face), z into the
board. The texture covers the pattern plus a white margin; square edges fall on texel edges so the
geometry is exact up to texture filtering.

Mipmaps: MuJoCo samples 2-D textures with ``GL_LINEAR_MIPMAP_LINEAR`` from levels made by
``glGenerateMipmap``. A level whose parent has an odd side is a resampling, not a 2x2 average, and it moves
the pattern by a fraction of its (coarse) texels: with the bare 3158 x 2390 texture (odd sides from level 2
on) the stereo calibration from the twin's board views came out with both focal lengths ~0.6 px short. So
the texture is padded (white, right and below, outside the face's texture coordinates) to sides that are
multiples of :func:`mip_block` texels: every level down to 4 texels per square is then an exact 2x2 average.
(Padding on all sides so that square edges also fall on the texel edges of every level was tried: it
sharpens the coarse levels, and the corners' reprojection RMS rose from 0.047 to 0.051 px with no gain in
the focal lengths.)
"""

from __future__ import annotations

import cv2
import numpy as np

from ..camera import FLIP_MUJOCO_OPENCV, CameraIntrinsics, project_points
from ..transforms import invert_transform, rotvec_to_matrix
from ..units import deg_to_rad
from .config import BoardConfig

__all__ = [
    "charuco_board", "board_texture", "board_texture_layout", "board_texcoords", "mip_block", "board_extent", "interior_corners", "marker_corners", "corner_markers",
    "detectable_corners", "sample_board_poses",
]


def charuco_board(cfg: BoardConfig) -> "cv2.aruco.CharucoBoard":
    """The OpenCV board object of ``cfg`` (lengths in metres)."""
    try:
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, cfg.dictionary))
    except AttributeError:
        raise ValueError(f"board dictionary {cfg.dictionary!r} is not an OpenCV ArUco dictionary") from None
    return cv2.aruco.CharucoBoard((cfg.squares_x, cfg.squares_y), cfg.square, cfg.marker, dictionary)


def _margin_px(cfg: BoardConfig) -> int:
    return int(round(cfg.margin / cfg.square * cfg.texture_px_per_square))


def board_extent(cfg: BoardConfig) -> tuple[float, float, float, float]:
    """``(x0, y0, x1, y1)`` [m] of the textured face in the board frame (pattern plus margin)."""
    m = _margin_px(cfg) / cfg.texture_px_per_square * cfg.square  # margin snapped to whole texels
    return (-m, -m, cfg.squares_x * cfg.square + m, cfg.squares_y * cfg.square + m)


def mip_block(cfg: BoardConfig) -> int:
    """Texels ``2**L`` such that mip levels ``1..L`` halve the texture exactly: down to 4 texels per square
    (coarser levels have lost the pattern and are not sampled at working distances)."""
    return 2 ** max(0, int(np.floor(np.log2(cfg.texture_px_per_square))) - 2)


def board_texture_layout(cfg: BoardConfig) -> tuple[tuple[int, int], tuple[int, int], tuple[int, int]]:
    """``((W, H), (x0, y0), (w, h))`` [texels]: padded texture size, offset and size of the face's content
    (pattern plus margin). ``W`` and ``H`` are multiples of :func:`mip_block`; the content sits at the
    texture's origin (``x0 = y0 = 0``), the padding right and below it."""
    p, m, b = cfg.texture_px_per_square, _margin_px(cfg), mip_block(cfg)
    w, h = cfg.squares_x * p + 2 * m, cfg.squares_y * p + 2 * m
    return (-(-w // b) * b, -(-h // b) * b), (0, 0), (w, h)


def board_texcoords(cfg: BoardConfig) -> tuple[float, float, float, float]:
    """``(u0, v0, u1, v1)``: texture coordinates of the face's corners ``(x0, y0)`` and ``(x1, y1)`` of
    :func:`board_extent` (``v = 0`` is the texture's first row, the board's -y edge)."""
    (W, H), (ox, oy), (w, h) = board_texture_layout(cfg)
    return (ox / W, oy / H, (ox + w) / W, (oy + h) / H)


def board_texture(cfg: BoardConfig) -> np.ndarray:
    """Greyscale texture ``(H, W)`` uint8 of the board face: ``texture_px_per_square`` texels per square,
    padded with white to the mip-friendly layout of :func:`board_texture_layout`."""
    p = cfg.texture_px_per_square
    m = _margin_px(cfg)
    size = (cfg.squares_x * p + 2 * m, cfg.squares_y * p + 2 * m)
    img = charuco_board(cfg).generateImage(size, marginSize=m, borderBits=1)
    if img.shape != (size[1], size[0]):
        raise RuntimeError(f"cv2.aruco produced a {img.shape} texture, expected {(size[1], size[0])}")
    (W, H), (ox, oy), _ = board_texture_layout(cfg)
    out = np.full((H, W), 255, dtype=np.uint8)
    out[oy:oy + size[1], ox:ox + size[0]] = img
    return out


def interior_corners(cfg: BoardConfig) -> np.ndarray:
    """Interior chessboard corners ``(N, 3)`` [m] in the board frame (OpenCV's ChArUco corner order)."""
    return np.asarray(charuco_board(cfg).getChessboardCorners(), dtype=float)


def marker_corners(cfg: BoardConfig) -> np.ndarray:
    """Corners of every marker ``(M, 4, 3)`` [m] in the board frame."""
    return np.asarray(charuco_board(cfg).getObjPoints(), dtype=float).reshape(-1, 4, 3)


def corner_markers(cfg: BoardConfig) -> np.ndarray:
    """For each interior corner, the indices ``(N, 2)`` of the two markers that touch it diagonally."""
    corners = interior_corners(cfg)
    centres = marker_corners(cfg).mean(axis=1)
    d = np.linalg.norm(corners[:, None, :2] - centres[None, :, :2], axis=-1)
    idx = np.argsort(d, axis=1)[:, :2]
    if not np.allclose(np.take_along_axis(d, idx, axis=1), cfg.square / np.sqrt(2), rtol=1e-6):
        raise RuntimeError("unexpected ChArUco layout: a corner without two diagonal markers")
    return idx


def detectable_corners(cfg: BoardConfig, board2cam: np.ndarray, intr: CameraIntrinsics, margin_px: float = 4.0) -> np.ndarray:
    """Mask ``(N,)`` of interior corners whose two neighbouring markers lie wholly inside the image.

    OpenCV finds a ChArUco corner by interpolating from detected markers next to it, so a corner counts
    only when those markers are in view.
    """
    mk = marker_corners(cfg)
    uv = project_points(mk.reshape(-1, 3), board2cam, intr).reshape(mk.shape[0], 4, 2)
    inside = np.all((uv[..., 0] > margin_px) & (uv[..., 0] < intr.width - 1 - margin_px)
                    & (uv[..., 1] > margin_px) & (uv[..., 1] < intr.height - 1 - margin_px), axis=1)
    return np.all(inside[corner_markers(cfg)], axis=1)


def sample_board_poses(
    cfg: BoardConfig,
    n: int,
    rng: np.random.Generator,
    world2cam_cv: tuple[np.ndarray, np.ndarray],
    intr: tuple[CameraIntrinsics, CameraIntrinsics],
    rig2world: np.ndarray,
    *,
    max_tries: int = 200,
) -> list[np.ndarray]:
    """``n`` board poses ``board2world`` ``(4, 4)`` in front of the rig, each seen by both cameras.

    Distance along the rig axis uniform in ``cfg.distance_range``; the board centre aimed at a uniformly
    drawn point of the left image (so views cover the whole image, corners included); tilted about a random
    in-plane axis by up to ``cfg.max_tilt`` and turned in-plane by up to ``cfg.max_roll``. A pose is kept
    when at least ``cfg.min_corners`` interior corners project inside both images (2 px margin) and the board
    faces each camera at less than 60 deg incidence; partial views are normal (ChArUco identifies corners). A
    corner counts when both markers next to it lie wholly inside the image (:func:`detectable_corners`).
    """
    if n < 1:
        raise ValueError(f"n must be a positive number of board views, got {n}")
    corners = interior_corners(cfg)
    x0, y0, x1, y1 = board_extent(cfg)
    centre_board = np.array([0.5 * cfg.squares_x * cfg.square, 0.5 * cfg.squares_y * cfg.square, 0.0])
    left_cam2world = invert_transform(world2cam_cv[0])
    # Facing the rig: board z (into the board) along the rig's viewing direction (-z of the rig frame),
    # board x along rig x, board y along -rig y.
    R_face = rig2world[:3, :3] @ FLIP_MUJOCO_OPENCV  # the rig's OpenCV-style axes
    out: list[np.ndarray] = []
    tries = 0
    while len(out) < n:
        tries += 1
        if tries > max_tries * n:
            raise RuntimeError(f"could not place {n} board views inside both images ({len(out)} found)")
        dist = rng.uniform(*cfg.distance_range)
        uv = np.array([rng.uniform(0.1, 0.9) * intr[0].width, rng.uniform(0.1, 0.9) * intr[0].height])
        ray_cam = np.array([(uv[0] - intr[0].cx) / intr[0].fx, (uv[1] - intr[0].cy) / intr[0].fy, 1.0])
        ray = left_cam2world[:3, :3] @ ray_cam
        origin = left_cam2world[:3, 3]
        axis_dir = -rig2world[:3, 2]
        # point on the ray at the chosen distance along the rig axis from the rig origin
        t = (dist - np.dot(origin - rig2world[:3, 3], axis_dir)) / np.dot(ray, axis_dir)
        centre = origin + t * ray
        tilt_axis_angle = rng.uniform(0, 2 * np.pi)
        tilt = cfg.max_tilt * np.sqrt(rng.uniform())
        tilt_axis = R_face @ np.array([np.cos(tilt_axis_angle), np.sin(tilt_axis_angle), 0.0])
        roll = rng.uniform(-cfg.max_roll, cfg.max_roll)
        R = rotvec_to_matrix(tilt_axis * tilt) @ R_face @ rotvec_to_matrix(np.array([0, 0, roll]))
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = centre - R @ centre_board
        ok = True
        for w2c, K in zip(world2cam_cv, intr):
            b2c = w2c @ T
            n_cam = b2c[:3, 2]  # board normal (into the board) in the camera frame
            pc = b2c[:3, :3] @ corners.T + b2c[:3, 3:4]
            if np.any(pc[2] <= 0.05):
                ok = False
                break
            view = pc.mean(axis=1) / np.linalg.norm(pc.mean(axis=1))
            if np.dot(n_cam, view) < np.cos(deg_to_rad(60.0)):
                ok = False
                break
            # whole face in front of the camera
            face = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]])
            if np.any((b2c[:3, :3] @ face.T + b2c[:3, 3:4])[2] <= 0.05):
                ok = False
                break
            if detectable_corners(cfg, b2c, K).sum() < cfg.min_corners:
                ok = False
                break
        if ok:
            out.append(T)
    return out
