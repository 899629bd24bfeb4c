"""Measurement backends: how a campaign turns a commanded configuration into a measured pose.

A backend is built once per worker process from a picklable :class:`BackendSpec` (:func:`get_backend`
caches it), then measures :class:`PoseTask` s one by one (:func:`measure_pose`, the function the executor
runs). Two backends:

* ``images`` (:class:`ImageBackend`): the world renders the stereo pair, the instrument measures it (stereo
  calibration from rendered board views, once per campaign and cached on disk).
* ``truth_noise`` (:class:`TruthNoiseBackend`): the separation paper's own simulation (section 3.1): the true
  model's sphere centres in the station's measurement frame plus N(0, sigma^2) per coordinate. No images.

Both return a :class:`~twin.evaluation.store.PoseResult` with the measured spheres (what goes into the
dataset) and, apart, the world's truth for the pose (what only evaluation reads). Per-pose noise is
seeded from the campaign seed and the pose key (:func:`twin.evaluation.plan.pose_seed`), so a pose measured
again after a resume, or in another process, gives the same numbers.

Every measurement appends one line to ``<work>/renders.log`` (the resume test counts them).
"""

from __future__ import annotations

import importlib
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from ..kinematics import flange2base
from ..transforms import invert_transform
from .config import CampaignConfig, parse_campaign_config
from .executor import worker_identity
from .store import PoseResult

__all__ = [
    "PoseTask",
    "BackendSpec",
    "MeasurementBackend",
    "TruthNoiseBackend",
    "get_backend",
    "measure_pose",
    "backend_spec_for",
    "StationTruth",
]


@dataclass(frozen=True)
class PoseTask:
    """One pose to measure: a unique ``key`` (``m/<pose_id>`` for the campaign's own poses,
    ``c/<method>/<pose_id>`` for compensated ones), the commanded joints ``q`` ``(6,)`` [rad], the station,
    and the per-pose seed."""

    key: str
    pose_id: int
    q: np.ndarray
    station: str
    seed: int


@dataclass(frozen=True)
class BackendSpec:
    """Everything a worker needs to build the backend: its factory (``module:callable``), the campaign config
    (as its TOML dict), the campaign's work folder, and free options."""

    factory: str
    config_raw: dict
    config_source: str | None
    quick: bool
    work_dir: str
    options: dict = field(default_factory=dict)

    def config(self) -> CampaignConfig:
        return parse_campaign_config(
            self.config_raw, source=Path(self.config_source) if self.config_source else None, _quick_applied=self.quick
        )

    @property
    def cache_key(self) -> str:
        return f"{self.factory}|{self.work_dir}|{self.config().fingerprint()}|{sorted(self.options.items())}"


@dataclass(frozen=True)
class StationTruth:
    """What evaluation needs to know of a station: true ``base2meas`` ``(4, 4)`` and the true cameras
    (``name -> (cam2meas (4, 4), CameraIntrinsics)``) for the recording."""

    name: str
    base2meas: np.ndarray
    cameras: dict


class MeasurementBackend(Protocol):
    def prepare(self) -> None:
        """One-off work per campaign, in the main process (e.g. stereo calibration); cached on disk."""

    def measure(self, task: PoseTask) -> PoseResult:
        """Measure one pose."""

    def stations_truth(self) -> dict[str, StationTruth]:
        """True station geometry (evaluation only)."""

    def truth_record(self) -> dict[str, Any]:
        """Campaign-level truth for ``truth.json`` (evaluation only)."""

    def noise_position(self) -> float | None:
        """The instrument's 1-sigma noise per coordinate [m] for ``dataset.toml``, when known."""


def _log_render(work_dir: str, key: str, what: str) -> None:
    """One line per measurement in ``renders.log`` (an O_APPEND write of one short line is atomic)."""
    path = Path(work_dir) / "renders.log"
    line = f"{what} {key} {os.getpid()}\n".encode()
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    try:
        os.write(fd, line)
    finally:
        os.close(fd)


class TruthNoiseBackend:
    """The separation paper's simulation: true sphere centres + N(0, sigma^2) per coordinate (no images).

    The true model is the campaign's nominal robot plus its injected errors; the stations are the nominal
    placements (the measurement frame of a station is its left camera's OpenCV frame). A sphere whose true
    centre is outside either camera image is reported as not seen (``p<k>:out_of_frame``).
    """

    def __init__(self, spec: BackendSpec) -> None:
        self.spec = spec
        self.cfg = spec.config()
        self.true_model = self.cfg.true_model().with_frames(base2meas=np.eye(4), tool2flange=np.eye(4))
        self.plate = self.cfg.plate
        self.stations = {s.name: s for s in self.cfg.stations()}
        self.sigma = self.cfg.measurement.noise_position

    def prepare(self) -> None:
        Path(self.spec.work_dir).mkdir(parents=True, exist_ok=True)

    def stations_truth(self) -> dict[str, StationTruth]:
        out = {}
        for name, st in self.stations.items():
            meas2base = st.cameras[0].cam2base
            cams = {
                cam_name: (invert_transform(meas2base) @ cam.cam2base, cam.intrinsics)
                for cam_name, cam in zip(("left", "right"), st.cameras)
            }
            out[name] = StationTruth(name, invert_transform(meas2base), cams)
        return out

    def truth_record(self) -> dict[str, Any]:
        m = self.cfg.true_model()
        return {
            "backend": "truth_noise",
            "robot": {"name": m.name, "convention": m.convention, "names": list(m.layout.names), "params": m.params.tolist()},
            "deviation": self.cfg.true_deviation(),
            "stations": {k: {"base2meas": v.base2meas.tolist()} for k, v in self.stations_truth().items()},
            "tool2flange": np.eye(4).tolist(),
            "spheres_flange": self.plate.spheres_flange.tolist(),
            "noise_position": self.sigma,
        }

    def noise_position(self) -> float | None:
        return self.sigma

    def measure(self, task: PoseTask) -> PoseResult:
        t0 = time.perf_counter()
        st = self.stations[task.station]
        base2meas = invert_transform(st.cameras[0].cam2base)
        F = flange2base(self.true_model, task.q)[0]
        s_base = self.plate.spheres_flange @ F[:3, :3].T + F[:3, 3]
        s_meas = s_base @ base2meas[:3, :3].T + base2meas[:3, 3]
        rng = np.random.default_rng(task.seed)
        noisy = s_meas + rng.normal(scale=self.sigma, size=(3, 3))
        spheres: list = []
        status = []
        for k in range(3):
            seen = True
            for cam in st.cameras:
                pc = cam.base2cam[:3, :3] @ s_base[k] + cam.base2cam[:3, 3]
                if pc[2] <= 0:
                    seen = False
                    break
                u = cam.intrinsics.fx * pc[0] / pc[2] + cam.intrinsics.cx
                v = cam.intrinsics.fy * pc[1] / pc[2] + cam.intrinsics.cy
                if not (0 <= u < cam.intrinsics.width and 0 <= v < cam.intrinsics.height):
                    seen = False
                    break
            spheres.append(noisy[k] if seen else None)
            if not seen:
                status.append(f"p{k}:out_of_frame")
        _log_render(self.spec.work_dir, task.key, "measure")
        return PoseResult(
            key=task.key,
            pose_id=task.pose_id,
            q=np.asarray(task.q, dtype=float),
            station=task.station,
            spheres=spheres,
            status=";".join(status),
            truth={"q_actual": np.asarray(task.q, dtype=float), "spheres_meas": s_meas, "flange2base": F},
            timings={"measure_s": time.perf_counter() - t0},
            worker=f"{worker_identity()['host']}:{os.getpid()}",
        )


BACKENDS = {
    "truth_noise": "twin.evaluation.pipeline:TruthNoiseBackend",
    "images": "twin.evaluation.imaging:ImageBackend",
}

_CACHE: dict[str, Any] = {}


def _load_factory(path: str):
    mod, _, attr = path.partition(":")
    if not mod or not attr:
        raise ValueError(f"backend factory must be 'module:callable', got {path!r}")
    return getattr(importlib.import_module(mod), attr)


def get_backend(spec: BackendSpec):
    """The backend of ``spec``, built once per process (a renderer costs ~0.6 s to start)."""
    key = spec.cache_key
    b = _CACHE.get(key)
    if b is None:
        b = _load_factory(spec.factory)(spec)
        _CACHE.clear()  # one campaign per process at a time: free the previous renderer
        _CACHE[key] = b
    return b


def measure_pose(spec: BackendSpec, task: PoseTask) -> PoseResult:
    """Worker entry point: measure one pose with the (cached) backend of ``spec``."""
    return get_backend(spec).measure(task)


def backend_spec_for(cfg: CampaignConfig, work_dir: str | os.PathLike, factory: str | None = None, **options) -> BackendSpec:
    """The spec of the campaign's backend (``cfg.measurement.mode``) or of an explicit ``factory``."""
    f = factory or BACKENDS[cfg.measurement.mode]
    return BackendSpec(
        factory=f,
        config_raw=cfg.raw,
        config_source=str(cfg.source) if cfg.source else None,
        quick=cfg.quick,
        work_dir=str(work_dir),
        options=dict(options),
    )
