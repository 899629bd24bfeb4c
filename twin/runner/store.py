"""Per-pose results on disk, written atomically: what makes a campaign resumable.

One JSON file per measured pose (``<folder>/<key>.json``, the key's ``/`` becoming ``__``), written to a
temporary name and renamed (``os.replace`` is atomic on POSIX), after the pose's image files. A file that
exists is complete; a pose whose file is missing is measured again. Floats are written with ``repr`` so a
result read back is bit-identical to the one written (the dataset assembled after a resume is byte-identical
to an uninterrupted run's).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..benchio import atomic_write_bytes, atomic_write_text

__all__ = ["PoseResult", "PoseStore", "MemoryStore"]


def _enc(x: Any) -> Any:
    if isinstance(x, np.ndarray):
        return {"__nd__": x.tolist(), "dtype": str(x.dtype)}
    if isinstance(x, (np.floating,)):
        return float(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, dict):
        return {k: _enc(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_enc(v) for v in x]
    return x


def _dec(x: Any) -> Any:
    if isinstance(x, dict):
        if "__nd__" in x:
            return np.array(x["__nd__"], dtype=x["dtype"])
        return {k: _dec(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_dec(v) for v in x]
    return x


@dataclass
class PoseResult:
    """One measured pose.

    ``spheres``: three entries, each ``(3,)`` [m] in the station's measurement frame or ``None`` (not measured;
    ``status`` says why). ``truth``: what the world knows about the pose (actual joints, true sphere centres,
    true plate pose), read only by evaluation. ``overlays``: per camera, ``centres_px`` ``(k, 2)`` and
    ``outlines_px`` (list of ``(m, 2)``) for the recording. ``images``: per camera, the encoded image bytes
    (not serialised into the JSON; stored as files beside it). ``timings`` [s].
    """

    key: str
    pose_id: int
    q: np.ndarray
    station: str
    spheres: list
    status: str = ""
    truth: dict[str, Any] = field(default_factory=dict)
    overlays: dict[str, Any] = field(default_factory=dict)
    images: dict[str, bytes] = field(default_factory=dict)
    image_format: str = ""
    timings: dict[str, float] = field(default_factory=dict)
    worker: str = ""

    def spheres_array(self) -> tuple[np.ndarray, np.ndarray]:
        """``(3, 3)`` [m] (NaN where not measured) and the seen mask ``(3,)``."""
        out = np.full((3, 3), np.nan)
        seen = np.zeros(3, dtype=bool)
        for i, s in enumerate(self.spheres):
            if s is not None:
                out[i] = np.asarray(s, dtype=float)
                seen[i] = True
        return out, seen

    def to_json(self) -> str:
        d = {
            "key": self.key,
            "pose_id": int(self.pose_id),
            "q": [float(x) for x in np.asarray(self.q, dtype=float)],
            "station": str(self.station),
            "spheres": [None if s is None else [float(x) for x in np.asarray(s, dtype=float)] for s in self.spheres],
            "status": self.status,
            "truth": _enc(self.truth),
            "overlays": _enc(self.overlays),
            "image_format": self.image_format,
            "image_cameras": sorted(self.images),
            "timings": _enc(self.timings),
            "worker": self.worker,
        }
        return json.dumps(d)

    @classmethod
    def from_json(cls, text: str) -> "PoseResult":
        d = json.loads(text)
        d.pop("image_cameras", None)
        return cls(
            key=d["key"],
            pose_id=int(d["pose_id"]),
            q=np.array(d["q"], dtype=float),
            station=d["station"],
            spheres=[None if s is None else np.array(s, dtype=float) for s in d["spheres"]],
            status=d["status"],
            truth=_dec(d["truth"]),
            overlays=_dec(d["overlays"]),
            image_format=d.get("image_format", ""),
            timings=_dec(d["timings"]),
            worker=d.get("worker", ""),
        )


class PoseStore:
    """A folder of :class:`PoseResult` files keyed by strings such as ``"m/00012"`` or ``"c/separation/00101"``."""

    def __init__(self, folder: str | os.PathLike) -> None:
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)

    @staticmethod
    def _name(key: str) -> str:
        if not key or any(c in key for c in "\\.\0") or key.startswith("/"):
            raise ValueError(f"key must be a non-empty relative name without '.', got {key!r}")
        return key.replace("/", "__")

    def path(self, key: str) -> Path:
        return self.folder / f"{self._name(key)}.json"

    def image_path(self, key: str, camera: str, fmt: str) -> Path:
        return self.folder / "images" / f"{self._name(key)}_{camera}.{fmt}"

    def has(self, key: str) -> bool:
        return self.path(key).exists()

    def write(self, result: PoseResult) -> None:
        """Images first, then the JSON by atomic rename: a JSON that exists is a complete pose."""
        for cam, data in result.images.items():
            atomic_write_bytes(self.image_path(result.key, cam, result.image_format or "bin"), data)
        atomic_write_text(self.path(result.key), result.to_json())

    def read(self, key: str, with_images: bool = False) -> PoseResult:
        p = self.path(key)
        if not p.exists():
            raise ValueError(f"no stored result for pose key {key!r} in {self.folder}")
        r = PoseResult.from_json(p.read_text())
        if with_images:
            d = json.loads(p.read_text())
            for cam in d.get("image_cameras", []):
                ip = self.image_path(key, cam, r.image_format or "bin")
                if ip.exists():
                    r.images[cam] = ip.read_bytes()
        return r

    def keys(self) -> list[str]:
        return sorted(p.stem.replace("__", "/") for p in self.folder.glob("*.json"))


class MemoryStore:
    """The :class:`PoseStore` interface in memory (a run that needs no resume: ``twin measure --render``)."""

    def __init__(self) -> None:
        self._results: dict[str, PoseResult] = {}

    def has(self, key: str) -> bool:
        return key in self._results

    def write(self, result: PoseResult) -> None:
        self._results[result.key] = result

    def read(self, key: str, with_images: bool = False) -> PoseResult:
        if key not in self._results:
            raise ValueError(f"no result for pose key {key!r}")
        return self._results[key]

    def keys(self) -> list[str]:
        return sorted(self._results)
