"""The image folder (``docs/formats.md``, "Image folder"): what the world hands the instrument on disk.

The same layout a real rig produces: ``rig.toml`` (image size and board geometry, no intrinsics),
``joints.csv`` (JOINTS.csv format, measurement order), ``board/<k>_left.png``/``_right.png`` and
``pairs/<pose_id>_left.png``/``_right.png``, 8-bit greyscale PNG. Nothing in it reveals that the
images were rendered. :class:`ImageFolderWriter` streams: each pair is on disk (and in ``joints.csv``)
as soon as it is added, so a long run loses nothing already rendered.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..dataset import Joints, write_joints_csv

__all__ = ["ImageFolderWriter", "write_rig_toml"]


def _toml_scalar(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    raise ValueError(f"rig.toml: cannot write {v!r}")


def write_rig_toml(path: str | os.PathLike, rig: dict[str, Any]) -> Path:
    """Write ``rig.toml`` from :meth:`twin.world.World.rig_info` (schema_version, image size, ``[board]``)."""
    for k in ("schema_version", "image_width", "image_height", "board"):
        if k not in rig:
            raise ValueError(f"rig info lacks {k!r}")
    lines = [f"{k} = {_toml_scalar(rig[k])}" for k in ("schema_version", "image_width", "image_height")]
    lines += ["", "[board]"] + [f"{k} = {_toml_scalar(v)}" for k, v in rig["board"].items()]
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path


def _write_png(path: Path, img: np.ndarray) -> None:
    if img.ndim != 2 or img.dtype != np.uint8:
        raise ValueError(f"{path.name}: images must be (H, W) uint8, got {img.shape} {img.dtype}")
    if not cv2.imwrite(str(path), img):
        raise OSError(f"could not write {path}")


class ImageFolderWriter:
    """Streams board views and stereo pairs into an image folder.

    ``rig`` is :meth:`twin.world.World.rig_info`. Pairs carry their commanded joints ``q`` ``(6,)`` [rad]
    and optional ``station``, ``set``, ``temp_c`` [°C], ``t_s`` [s]; ``joints.csv`` is rewritten after each
    pair through the one JOINTS.csv writer (:func:`twin.dataset.write_joints_csv`).
    """

    def __init__(self, folder: str | os.PathLike, rig: dict[str, Any]):
        self.folder = Path(folder)
        (self.folder / "board").mkdir(parents=True, exist_ok=True)
        (self.folder / "pairs").mkdir(parents=True, exist_ok=True)
        w, h = int(rig["image_width"]), int(rig["image_height"])
        self.size = (h, w)
        write_rig_toml(self.folder / "rig.toml", rig)
        self._rows: list[dict[str, Any]] = []
        self._n_board = 0

    def _check(self, left: np.ndarray, right: np.ndarray) -> None:
        for name, img in (("left", left), ("right", right)):
            if img.shape != self.size:
                raise ValueError(f"{name} image is {img.shape}, rig.toml says {self.size}")

    def add_board_view(self, left: np.ndarray, right: np.ndarray) -> int:
        """Write ``board/<k>_left.png``/``_right.png`` (k = 000, 001, ...); returns ``k``."""
        self._check(left, right)
        k = self._n_board
        _write_png(self.folder / "board" / f"{k:03d}_left.png", left)
        _write_png(self.folder / "board" / f"{k:03d}_right.png", right)
        self._n_board += 1
        return k

    def add_pair(self, pose_id: int, q: np.ndarray, left: np.ndarray, right: np.ndarray, *, station: Any = None,
                 set: str | None = None, temp_c: float | None = None, t_s: float | None = None) -> None:
        """Write ``pairs/<pose_id>_left.png``/``_right.png`` and append the row to ``joints.csv``."""
        self._check(left, right)
        pose_id = int(pose_id)
        if any(r["pose_id"] == pose_id for r in self._rows):
            raise ValueError(f"pose_id {pose_id} already written")
        q = np.asarray(q, dtype=float).reshape(-1)
        if q.shape != (6,) or not np.all(np.isfinite(q)):
            raise ValueError(f"q must be 6 finite joint angles [rad], got {q!r}")
        _write_png(self.folder / "pairs" / f"{pose_id}_left.png", left)
        _write_png(self.folder / "pairs" / f"{pose_id}_right.png", right)
        self._rows.append({"pose_id": pose_id, "q": q, "station": station, "set": set, "temp_c": temp_c, "t_s": t_s})
        self._write_joints()

    def _write_joints(self) -> None:
        rows = self._rows

        def col(name, kind):
            vals = [r[name] for r in rows]
            if all(v is None for v in vals):
                return None
            if any(v is None for v in vals):
                raise ValueError(f"column {name!r} must be given for every pair or for none")
            return np.array(vals, dtype=kind)

        joints = Joints(
            pose_id=np.array([r["pose_id"] for r in rows], dtype=np.int64),
            q=np.array([r["q"] for r in rows]),
            temp_c=col("temp_c", float),
            t_s=col("t_s", float),
            station=col("station", object),
            set=col("set", object),
        )
        tmp = self.folder / "joints.csv.tmp"
        write_joints_csv(tmp, joints)
        os.replace(tmp, self.folder / "joints.csv")

    @property
    def n_pairs(self) -> int:
        return len(self._rows)

    @property
    def n_board_views(self) -> int:
        return self._n_board
