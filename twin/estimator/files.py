"""Readers and writers of the estimator's CSV files (``docs/formats.md``): ``PRED.csv`` (output of
``twin predict``) and ``TARGETS.csv`` (input of ``twin compensate``). Millimetres, radians for rotation
vectors, a unit quaternion (w first) for targets; SI inside."""

from __future__ import annotations

import csv
import os
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..dataset import DatasetError, read_csv_rows
from ..files import parse_finite
from ..transforms import make_transform, matrix_to_quat_wxyz, quat_wxyz_to_matrix, transform_to_pose6
from ..units import M_PER_MM
from .calibration import Prediction

__all__ = ["PRED_COLUMNS", "TARGET_COLUMNS", "TARGET_POSITION_COLUMNS", "Targets", "write_pred_csv", "read_pred_csv",
           "read_targets", "read_targets_csv", "write_targets_csv"]

SPHERE_COLS = tuple(f"p{k}_{c}" for k in range(3) for c in "xyz")
POSE_COLS = ("x", "y", "z", "rx", "ry", "rz")
PRED_COLUMNS = ("pose_id",) + SPHERE_COLS + POSE_COLS + ("frame",)
TARGET_COLUMNS = ("pose_id", "x", "y", "z", "qw", "qx", "qy", "qz")
TARGET_POSITION_COLUMNS = ("pose_id", "x", "y", "z")


def _point_cols(k: int) -> tuple[str, ...]:
    return tuple(f"p{i}_{c}" for i in range(k) for c in "xyz")


def write_pred_csv(path: str | os.PathLike, pose_id: np.ndarray, pred: Prediction, station: np.ndarray | None = None) -> Path:
    """Write ``PRED.csv``: ``pose_id, p0_x..p<K-1>_z`` [mm], ``x y z`` [mm], ``rx ry rz`` [rad], ``frame``,
    (``station`` when given), and ``sd_p0_x..``, ``sd_x..sd_rz`` when the prediction has them."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    n = len(pose_id)
    pcols = _point_cols(pred.spheres.shape[1])
    cols = ["pose_id", *pcols, *POSE_COLS, "frame"] + (["station"] if station is not None else [])
    has_sd = pred.sd_spheres is not None
    if has_sd:
        cols += [f"sd_{c}" for c in pcols] + [f"sd_{c}" for c in POSE_COLS]
    pose6 = transform_to_pose6(pred.pose)
    with _atomic(path) as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(cols)
        for i in range(n):
            row = [str(int(pose_id[i]))]
            row += [f"{v / M_PER_MM:.6f}" for v in pred.spheres[i].reshape(-1)]
            row += [f"{v / M_PER_MM:.6f}" for v in pose6[i, :3]] + [f"{v:.12f}" for v in pose6[i, 3:]]
            row.append(str(pred.frame[i]))
            if station is not None:
                row.append(str(station[i]))
            if has_sd:
                row += [f"{v / M_PER_MM:.6g}" for v in pred.sd_spheres[i].reshape(-1)]
                row += [f"{v / M_PER_MM:.6g}" for v in pred.sd_pose[i, :3]] + [f"{v:.6g}" for v in pred.sd_pose[i, 3:]]
            w.writerow(row)
    return path


@contextmanager
def _atomic(path: Path):
    """A text file opened for writing beside ``path`` and moved onto it only when the block ends without an
    error (no partial output file)."""
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with open(tmp, "w", newline="") as f:
            yield f
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def read_pred_csv(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read ``PRED.csv`` back: ``pose_id`` ``(n,)``, ``spheres`` ``(n, K, 3)`` [m], ``pose6`` ``(n, 6)``
    (translation [m], rotation vector [rad]), ``frame`` ``(n,)``, and ``sd_spheres`` when present."""
    path = Path(path)
    header, rows = read_csv_rows(path, ("pose_id", "p0_x", "p0_y", "p0_z") + tuple(POSE_COLS) + ("frame",))
    K = 0
    while f"p{K}_x" in header:
        K += 1
    pcols = _point_cols(K)
    out = {
        "pose_id": np.array([int(r["pose_id"]) for r in rows]),
        "spheres": np.array([[float(r[c]) for c in pcols] for r in rows]).reshape(-1, K, 3) * M_PER_MM,
        "pose6": np.array([[float(r[c]) * (M_PER_MM if c in "xyz" else 1.0) for c in POSE_COLS] for r in rows]),
        "frame": np.array([r["frame"] for r in rows], dtype=object),
    }
    if "sd_p0_x" in rows[0]:
        out["sd_spheres"] = np.array([[float(r[f"sd_{c}"]) for c in pcols] for r in rows]).reshape(-1, K, 3) * M_PER_MM
    return out


@dataclass(frozen=True)
class Targets:
    """Targets of ``twin compensate``: ``pose_id`` ``(n,)``, ``position`` ``(n, 3)`` [m] in the robot base frame of the
    calibration and ``rotation`` ``(n, 3, 3)`` of the tool, or None for position-only targets (a point marker)."""

    pose_id: np.ndarray
    position: np.ndarray
    rotation: np.ndarray | None

    @property
    def tool2base(self) -> np.ndarray:
        """``(n, 4, 4)``; only for targets with an orientation."""
        if self.rotation is None:
            raise ValueError("position-only targets have no tool2base")
        return np.stack([make_transform(R, p) for R, p in zip(self.rotation, self.position)]) if len(self.position) \
            else np.zeros((0, 4, 4))


def read_targets(path: str | os.PathLike) -> Targets:
    """Read ``TARGETS.csv``: ``pose_id, x, y, z`` [mm] with ``qw, qx, qy, qz`` (a tool pose) or without them (a
    position: the calibration's first marker point, e.g. one reflector).

    Errors (:class:`~twin.dataset.DatasetError`) name the file, row and column: missing columns (some of the
    quaternion's but not all), duplicate ids, non-numeric or non-finite values, quaternions whose norm is not 1
    within 1e-6 (they are not silently renormalised: a wrong target must not become a plausible one)."""
    path = Path(path)
    header, _ = read_csv_rows(path, TARGET_POSITION_COLUMNS)
    quat = [c for c in TARGET_COLUMNS[4:] if c in header]
    if quat and len(quat) < 4:
        read_csv_rows(path, TARGET_COLUMNS)  # names the missing quaternion columns
    if not quat:
        pid, T = _read_target_rows(path, TARGET_POSITION_COLUMNS)
        return Targets(pid, T[:, :3, 3].copy(), None)
    pid, T = _read_target_rows(path, TARGET_COLUMNS)
    return Targets(pid, T[:, :3, 3].copy(), T[:, :3, :3].copy())


def read_targets_csv(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read ``TARGETS.csv`` of tool poses (``pose_id, x, y, z`` [mm], ``qw, qx, qy, qz``): ``(pose_id (n,),
    tool2base (n, 4, 4))``; errors as :func:`read_targets` (missing quaternion columns named)."""
    return _read_target_rows(Path(path), TARGET_COLUMNS)


def _read_target_rows(path: Path, columns: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    _, rows = read_csv_rows(path, columns)
    n = len(rows)
    pid = np.zeros(n, dtype=np.int64)
    T = np.tile(np.eye(4), (n, 1, 1))
    seen: dict[int, int] = {}
    for k, r in enumerate(rows):
        try:
            pid[k] = int(r["pose_id"])
        except (TypeError, ValueError):
            raise DatasetError(f"{path}: row {k + 1}, column 'pose_id': not an integer: {r['pose_id']!r}") from None
        if pid[k] in seen:
            raise DatasetError(f"{path}: row {k + 1}, column 'pose_id': duplicate id {pid[k]} (first in row {seen[pid[k]]})")
        seen[int(pid[k])] = k + 1
        vals = {c: parse_finite((r[c] or "").strip(), f"{path}: row {k + 1} (pose_id {pid[k]}), column {c!r}",
                                DatasetError) for c in columns[1:]}
        T[k, :3, 3] = np.array([vals["x"], vals["y"], vals["z"]]) * M_PER_MM
        if "qw" not in vals:
            continue
        qv = np.array([vals["qw"], vals["qx"], vals["qy"], vals["qz"]])
        if abs(np.linalg.norm(qv) - 1.0) > 1e-6:
            raise DatasetError(
                f"{path}: row {k + 1} (pose_id {pid[k]}), columns qw..qz: not a unit quaternion (norm {np.linalg.norm(qv):.9g})"
            )
        T[k, :3, :3] = quat_wxyz_to_matrix(qv)
    return pid, T


def write_targets_csv(path: str | os.PathLike, pose_id: np.ndarray, tool2base: np.ndarray) -> Path:
    """Write ``TARGETS.csv`` from plate poses in the base frame ``(n, 4, 4)``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    q = matrix_to_quat_wxyz(tool2base[:, :3, :3])
    with open(path, "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(TARGET_COLUMNS)
        for i in range(len(pose_id)):
            w.writerow([str(int(pose_id[i]))] + [f"{v / M_PER_MM:.6f}" for v in tool2base[i, :3, 3]] + [f"{v:.12f}" for v in q[i]])
    return path
