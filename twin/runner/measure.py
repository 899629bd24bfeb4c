"""The measure stage: commanded configurations -> the world renders -> the instrument measures -> a dataset.

This is the one render -> measure -> dataset loop of the project: ``twin campaign`` (its dataset and its
compensated poses), ``twin measure --render`` and the close-loop study all measure through it.

A backend is built once per worker process from a picklable :class:`BackendSpec` (:func:`get_backend` caches
it), then measures :class:`PoseTask` s one by one (:func:`measure_pose`, the function the executor runs;
:func:`measure_tasks` runs a list of them, resumably). Two backends:

* ``images`` (:class:`ImageBackend`): the world renders the stereo pair, the instrument measures it (stereo
  calibration from rendered board views, once per run and cached on disk).
* ``truth_noise`` (:class:`TruthNoiseBackend`): the separation paper's own simulation (section 3.1): the true
  model's sphere centres in the station's measurement frame plus N(0, sigma^2) per coordinate. No images.

Both return a :class:`~twin.runner.store.PoseResult` with the measured spheres (what goes into the dataset)
and, apart, the world's truth for the pose (what only evaluation reads, from
:meth:`twin.world.World.true_pose` / :meth:`~twin.world.World.capture`: one definition of truth). The effect
context of a pose (its command history, time stamp, index in the robot's visit order) comes with the task,
built from the plan by :func:`twin.world.effects.contexts_for_sequence`, and its image noise is seeded by the
task's seed; so a pose measured again after a resume, or in another process, gives the same numbers. A task
without a seed takes the world's own image counter (one process, poses in order: ``twin measure --render``).

:func:`write_measured_dataset` writes the rows (``poses.csv``) of measured poses through the instrument's one
row writer (:class:`twin.instrument.folder.MeasuredRowsWriter`); each caller writes its own ``dataset.toml``. With a work folder, every measurement appends one line to ``<work>/renders.log`` (the resume
test counts them).
"""

from __future__ import annotations

import concurrent.futures as cf
import hashlib
import importlib
import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Protocol, Sequence

import numpy as np

from ..dataset import Plate
from ..evaluation.images import encode_image
from ..instrument.folder import MeasuredRowsWriter
from ..transforms import invert_transform
from ..units import deg_to_rad
from .config import CampaignConfig
from .executor import SerialExecutor, run_tasks, worker_identity
from .store import MemoryStore, PoseResult, PoseStore

__all__ = [
    "PoseTask",
    "InstrumentSetup",
    "BackendSpec",
    "MeasurementBackend",
    "TruthNoiseBackend",
    "ImageBackend",
    "get_backend",
    "measure_pose",
    "board_view_corners",
    "measure_tasks",
    "backend_spec_for",
    "setup_from_campaign",
    "StationTruth",
    "write_measured_dataset",
]

Progress = Callable[[str, int, int], None]  # (phase, done, total)


@dataclass(frozen=True)
class PoseTask:
    """One pose to measure: a unique ``key`` (``m/<pose_id>`` for a campaign's own poses,
    ``c/<method>/<pose_id>`` for compensated ones), the commanded joints ``q`` ``(6,)`` [rad], the station,
    the per-pose noise ``seed`` (``None``: the world's own image counter, poses measured in order in one
    process), and the pose's effect ``context``.

    ``context``: a :class:`twin.world.effects.EffectContext` from
    :func:`twin.world.effects.contexts_for_sequence` over the robot's whole visit order (``world`` left
    ``None``: the backend fills it): ``q_cmd_history``, ``pose_index``, ``t_s`` [s], ``station`` index.
    Without it (callers that measure single poses, e.g. benchmarks), the history is ``q_prev`` alone (one
    previous command, ``None`` for the first) and the time stamp ``pose_id * seconds_per_pose``.
    """

    key: str
    pose_id: int
    q: np.ndarray
    station: str
    seed: int | None
    q_prev: np.ndarray | None = None  # used only without a context: the command measured just before
    context: Any = None  # EffectContext from the plan (world=None)


@dataclass(frozen=True, eq=False)
class InstrumentSetup:
    """What a measurement backend needs (picklable): the world and how the instrument measures.

    ``world``: the ``[world]`` table (``twin.world.WorldConfig.from_dict``; its ``seed`` set). ``mode``:
    ``images`` or ``truth_noise``; ``noise_position`` [m]: the 1-sigma noise per coordinate of
    ``truth_noise``. ``seconds_per_pose`` [s]: time stamp of a task without a context. ``bias_correction``:
    the instrument corrects the perspective bias of the sphere outlines. ``board_views`` / ``board_seed``:
    board views rendered for the stereo calibration (``None``: the world's ``board.views`` and seed);
    ``calibration_file``: a stereo calibration to use instead (``stereo_calibration.json``). ``keep_images``:
    encoded images kept with the results (``none``, ``dataset``: the campaign's own poses, ``all``),
    ``lossless`` (PNG) or JPEG at ``jpeg_quality``. ``plate``: the nominal plate the instrument labels the
    spheres with (``None``: the world's nominal plate)."""

    world: dict
    mode: str = "images"
    noise_position: float = 1e-5
    seconds_per_pose: float = 10.0
    bias_correction: bool = True
    board_views: int | None = None
    board_seed: int | None = None
    calibration_file: str | None = None
    keep_images: str = "none"
    lossless: bool = False
    jpeg_quality: int = 85
    plate: Plate | None = None

    def __post_init__(self) -> None:
        if self.mode not in BACKENDS:
            raise ValueError(f"mode must be one of {sorted(BACKENDS)}, got {self.mode!r}")
        if self.keep_images not in ("none", "dataset", "all"):
            raise ValueError(f"keep_images must be 'none', 'dataset' or 'all', got {self.keep_images!r}")

    def key(self) -> str:
        """A fingerprint of everything that determines the measurements (the backend cache key)."""
        d = {k: getattr(self, k) for k in ("world", "mode", "noise_position", "seconds_per_pose", "bias_correction",
                                         "board_views", "board_seed", "calibration_file", "keep_images", "lossless",
                                         "jpeg_quality")}
        if self.plate is not None:
            d["plate"] = [float(self.plate.sphere_diameter), np.asarray(self.plate.spheres_flange).tolist()]
        return hashlib.sha256(json.dumps(d, sort_keys=True, default=str).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class BackendSpec:
    """Everything a worker needs to build the backend: its factory (``module:callable``), the instrument set-up,
    the run's work folder (``None``: nothing cached, no log) and free options."""

    factory: str
    setup: InstrumentSetup
    work_dir: str | None
    options: dict = field(default_factory=dict)

    @property
    def cache_key(self) -> str:
        return f"{self.factory}|{self.work_dir}|{self.setup.key()}|{sorted(self.options.items())}"


@dataclass(frozen=True)
class StationTruth:
    """What evaluation needs to know of a station: true ``base2meas`` ``(4, 4)`` and the true cameras
    (``name -> (cam2meas (4, 4), CameraIntrinsics)``) for the recording."""

    name: str
    base2meas: np.ndarray
    cameras: dict


class MeasurementBackend(Protocol):
    def prepare(self, executor: cf.Executor | None = None) -> None:
        """One-off work per run, from the main process (e.g. stereo calibration; ``executor`` may take parts of
        it); cached on disk."""

    def measure(self, task: PoseTask) -> PoseResult:
        """Measure one pose."""

    def stations_truth(self) -> dict[str, StationTruth]:
        """True station geometry (evaluation only)."""

    def truth_record(self, results: list[PoseResult]) -> dict[str, Any]:
        """``truth.json`` content for the measured poses (evaluation only)."""

    def noise_position(self) -> float | None:
        """The instrument's 1-sigma noise per coordinate [m] for ``dataset.toml``, when known."""


def _log_render(work_dir: str | None, key: str, what: str) -> None:
    """One line per measurement in ``renders.log`` (an O_APPEND write of one short line is atomic)."""
    if work_dir is None:
        return
    path = Path(work_dir) / "renders.log"
    line = f"{what} {key} {os.getpid()}\n".encode()
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    try:
        os.write(fd, line)
    finally:
        os.close(fd)


class _WorldBackend:
    """Shared part of the backends: the world (true robot, effects, stations), per-pose effect context and
    truth. Building a :class:`twin.world.World` compiles the MJCF but creates no renderer until an image is
    asked for."""

    def __init__(self, spec: BackendSpec) -> None:
        from ..world import World, WorldConfig  # the world is only built where measurements are made

        self.spec = spec
        self.setup = spec.setup
        self.world = World.from_config(WorldConfig.from_dict(self.setup.world))
        self.station_index = {name: k for k, name in enumerate(self.world.station_names)}
        self.plate = self.setup.plate if self.setup.plate is not None else self.world.nominal_plate
        self.seconds_per_pose = self.setup.seconds_per_pose

    def prepare(self, executor: cf.Executor | None = None) -> None:
        if self.spec.work_dir is not None:
            Path(self.spec.work_dir).mkdir(parents=True, exist_ok=True)

    def stations_truth(self) -> dict[str, StationTruth]:
        il, ir = self.world.true_intrinsics()
        right2left = invert_transform(self.world.true_left2right())
        return {
            name: StationTruth(name, self.world.true_base2meas(k), {"left": (np.eye(4), il), "right": (right2left, ir)})
            for name, k in self.station_index.items()
        }

    def truth_record(self, results: list[PoseResult]) -> dict[str, Any]:
        """The world's truth.json content for the measured poses (``twin.world.truth``)."""
        from ..world import Capture

        empty = np.empty((0, 0), np.uint8)
        caps = []
        for r in results:
            t = r.truth
            caps.append(Capture(
                pose_id=int(r.pose_id), station=self.station_index[r.station], q_cmd=np.asarray(r.q, dtype=float),
                q_actual=np.asarray(t["q_actual"], dtype=float), left=empty, right=empty,
                spheres_meas=np.asarray(t["spheres_meas"], dtype=float), tool2meas=np.asarray(t["tool2meas"], dtype=float),
                t_s=float(t.get("t_s", 0.0)), temp_c=float(t.get("temp_c", 20.0)),
                params=None if t.get("params") is None else np.asarray(t["params"], dtype=float),
            ))
        return self.world.truth_dict(caps)

    def noise_position(self) -> float | None:
        return None

    def true_robot(self):
        """The world's true robot (evaluation only; its base_* is the robot's mount in the lab)."""
        return self.world.true_robot

    def _context(self, task: PoseTask):
        """Effect context of a pose: the task's own (from the plan, :func:`contexts_for_sequence`) with the
        world filled in; without one, a history of ``q_prev`` alone and time ``pose_id * seconds_per_pose``."""
        from ..world.effects import EffectContext

        k = self.station_index[task.station]
        if task.context is not None:
            ctx = task.context
            if not isinstance(ctx, EffectContext):
                raise ValueError(f"task {task.key}: context must be an EffectContext, got {type(ctx).__name__}")
            if ctx.station != k:
                raise ValueError(f"task {task.key}: context station {ctx.station} is not station "
                                 f"{task.station!r} (index {k})")
            if ctx.q_cmd is not None and np.max(np.abs(ctx.q_cmd - np.asarray(task.q, dtype=float))) > 1e-12:
                raise ValueError(f"task {task.key}: context q_cmd differs from the task's command")
            return ctx.with_(world=self.world)
        hist = np.zeros((0, 6)) if task.q_prev is None else np.asarray(task.q_prev, dtype=float).reshape(1, 6)
        return EffectContext(t_s=task.pose_id * self.seconds_per_pose, pose_index=task.pose_id, station=k,
                             q_cmd=np.asarray(task.q, dtype=float), q_cmd_history=hist, world=self.world)

    def _truth(self, cap) -> dict[str, Any]:
        return {
            "q_actual": np.asarray(cap.q_actual, dtype=float),
            "spheres_meas": np.asarray(cap.spheres_meas, dtype=float),
            "tool2meas": np.asarray(cap.tool2meas, dtype=float),
            "t_s": float(cap.t_s),
            "temp_c": float(cap.temp_c),
            "params": None if cap.params is None else np.asarray(cap.params, dtype=float),
        }


class TruthNoiseBackend(_WorldBackend):
    """The separation paper's simulation: the world's true sphere centres + N(0, sigma^2) per coordinate.

    No images are rendered. A sphere whose true centre projects outside either camera image is reported as
    not seen (``p<k>:out_of_frame``).
    """

    def __init__(self, spec: BackendSpec) -> None:
        super().__init__(spec)
        self.sigma = self.setup.noise_position

    def noise_position(self) -> float | None:
        return self.sigma

    def measure(self, task: PoseTask) -> PoseResult:
        t0 = time.perf_counter()
        k = self.station_index[task.station]
        cap = self.world.true_pose(np.asarray(task.q, dtype=float), k, self._context(task), task.pose_id)
        spheres_true = cap.spheres_meas
        rng = np.random.default_rng(task.seed)
        noisy = spheres_true + rng.normal(scale=self.sigma, size=(3, 3))
        w, h = self.world.image_size
        spheres: list = []
        status = []
        uvl, uvr = self.world.project_spheres(spheres_true, k)
        for j in range(3):
            inside = all(0 <= uv[j, 0] < w and 0 <= uv[j, 1] < h for uv in (uvl, uvr))
            spheres.append(noisy[j] if inside else None)
            if not inside:
                status.append(f"p{j}:out_of_frame")
        _log_render(self.spec.work_dir, task.key, "measure")
        return PoseResult(
            key=task.key, pose_id=task.pose_id, q=np.asarray(task.q, dtype=float), station=task.station,
            spheres=spheres, status=";".join(status), truth=self._truth(cap),
            timings={"measure_s": time.perf_counter() - t0},
            worker=f"{worker_identity()['host']}:{os.getpid()}",
        )


class ImageBackend(_WorldBackend):
    """World renders the stereo pair, the instrument measures it (``images`` mode).

    :meth:`prepare` renders the board views and runs the instrument's stereo calibration once per run (cached
    as ``<work>/stereo_calibration.json``; the instrument never sees the world's camera parameters), or loads
    the set-up's ``calibration_file``. Image noise is seeded per pose, so a pose rendered again (resume,
    another worker) is the same image. ``image_sink`` (in-process callers only): called with
    ``("board", index, left, right)`` for every board view and ``("pair", task, left, right)`` for every
    measured pair, to keep the raw images (``twin measure --render --keep-images``).
    """

    def __init__(self, spec: BackendSpec) -> None:
        super().__init__(spec)
        self.calib_path = None if spec.work_dir is None else Path(spec.work_dir) / "stereo_calibration.json"
        self._calib = None
        self.keep_images = self.setup.keep_images != "none"
        self.keep_after = self.setup.keep_images == "all"
        self.image_sink: Callable[..., None] | None = None
        self._board = None

    def prepare(self, executor: cf.Executor | None = None) -> None:
        """Load the run's stereo calibration, or draw the board views, find their corners and calibrate.

        ``executor``: where the views are drawn and their corners found, one task per view (the processes that
        measure the poses next build their world meanwhile); without one, or with an image sink (which wants
        the images here), in this process. Each view's pose and noise come from the board seed alone
        (:meth:`twin.world.World.board_view_poses`), so the calibration is the same either way."""
        from ..instrument import BoardSpec, StereoCalibration, calibrate_stereo_views

        super().prepare()
        if self.setup.calibration_file is not None:
            self._calib = StereoCalibration.load(self.setup.calibration_file)
            return
        if self.calib_path is not None and self.calib_path.exists():
            self._calib = StereoCalibration.load(self.calib_path)
            return
        items = []
        for T, seed in self.world.board_view_poses(self.setup.board_views, seed=self.setup.board_seed):
            items.append((self.world.record_board_view(T), T, seed))
        if executor is None or isinstance(executor, SerialExecutor) or self.image_sink is not None:
            found = [self._board_view(item) for item in items]
        else:
            found = run_tasks(executor, board_view_corners, items, args=(self.spec,))
        board = BoardSpec.from_table(self.world.rig_info()["board"])
        calib = calibrate_stereo_views([(left, right) for _, left, right in found], self.world.image_size, board,
                                       names=[f"{k:03d}" for k, _, _ in found])
        if self.calib_path is not None:
            tmp = self.calib_path.with_name(self.calib_path.name + ".tmp.json")
            calib.save(tmp)
            os.replace(tmp, self.calib_path)
        self._calib = calib

    def _board_view(self, item: tuple[int, np.ndarray, int]) -> tuple[int, Any, Any]:
        """Draw board view ``item`` = ``(index, board2meas, noise seed)`` (not recorded: the caller did) and find
        its corners in both images (:func:`twin.instrument.detect_board`); hand the images to the image sink."""
        from ..instrument import BoardSpec, detect_board

        k, T, seed = item
        view = self.world.render_board(np.asarray(T, dtype=float), 0, noise_seed=int(seed), record=False)
        if self.image_sink is not None:
            self.image_sink("board", k, view.left, view.right)
        if self._board is None:
            self._board = BoardSpec.from_table(self.world.rig_info()["board"])
        return k, detect_board(view.left, self._board), detect_board(view.right, self._board)

    @property
    def calibration(self):
        if self._calib is None:
            from ..instrument import StereoCalibration

            if self.calib_path is None or not self.calib_path.exists():
                raise ValueError(f"{self.calib_path}: no stereo calibration yet (the run calls prepare() first)")
            self._calib = StereoCalibration.load(self.calib_path)
        return self._calib

    def measure(self, task: PoseTask) -> PoseResult:
        from ..instrument import measure_pair

        t0 = time.perf_counter()
        k = self.station_index[task.station]
        # Image noise per pose: noise_seed makes the pair's noise a function of (world seed, pose seed) alone,
        # independent of what this process rendered before (resume, several workers).
        cap = self.world.capture(np.asarray(task.q, dtype=float), k, self._context(task), task.pose_id, record=False,
                                 noise_seed=None if task.seed is None else int(task.seed))
        if self.image_sink is not None:
            self.image_sink("pair", task, cap.left, cap.right)
        t1 = time.perf_counter()
        m = measure_pair(cap.left, cap.right, self.calibration, self.plate,
                         bias_correction=self.setup.bias_correction)
        t2 = time.perf_counter()
        overlays = {}
        for cam, obs in (("left", m.left), ("right", m.right)):
            centres, outlines = [], []
            for s in obs:
                if s is None:
                    continue
                if s.centre_px is not None:
                    centres.append(np.asarray(s.centre_px, dtype=float))
                if s.ellipse is not None:
                    e = s.ellipse
                    pts = cv2_ellipse_points(e.cx, e.cy, e.width, e.height, e.angle_deg)
                    outlines.append(pts)
            overlays[cam] = {"centres_px": np.array(centres).reshape(-1, 2), "outlines_px": outlines}
        images: dict[str, bytes] = {}
        fmt = ""
        if (self.keep_images and task.key.startswith("m/")) or self.keep_after:
            lossless = self.setup.lossless
            for cam, img in (("left", cap.left), ("right", cap.right)):
                images[cam], media = encode_image(img, lossless=lossless, jpeg_quality=self.setup.jpeg_quality)
            fmt = "png" if lossless else "jpg"
        _log_render(self.spec.work_dir, task.key, "render")
        return PoseResult(
            key=task.key, pose_id=task.pose_id, q=np.asarray(task.q, dtype=float), station=task.station,
            spheres=list(m.centres), status=m.status, truth=self._truth(cap), overlays=overlays, images=images,
            image_format=fmt,
            timings={"render_s": t1 - t0, "measure_s": t2 - t1, "encode_s": time.perf_counter() - t2},
            worker=f"{worker_identity()['host']}:{os.getpid()}",
        )


def cv2_ellipse_points(cx: float, cy: float, width: float, height: float, angle_deg: float, n: int = 48) -> np.ndarray:
    """``n`` points ``(n, 2)`` [px] on an ellipse in OpenCV's RotatedRect convention (full axes, angle)."""
    t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    a, b = 0.5 * width, 0.5 * height
    c, s = np.cos(deg_to_rad(angle_deg)), np.sin(deg_to_rad(angle_deg))
    x, y = a * np.cos(t), b * np.sin(t)
    return np.stack([cx + c * x - s * y, cy + s * x + c * y], axis=1)


BACKENDS = {
    "truth_noise": "twin.runner.measure:TruthNoiseBackend",
    "images": "twin.runner.measure:ImageBackend",
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
        _CACHE.clear()  # one run per process at a time: free the previous renderer
        _CACHE[key] = b
    return b


def measure_pose(spec: BackendSpec, task: PoseTask) -> PoseResult:
    """Worker entry point: measure one pose with the (cached) backend of ``spec``."""
    return get_backend(spec).measure(task)


def board_view_corners(spec: BackendSpec, item: tuple[int, np.ndarray, int]) -> tuple[int, Any, Any]:
    """Worker entry point: draw board view ``item`` = ``(index, board2meas, noise seed)`` with the (cached) image
    backend of ``spec`` and find its corners (:meth:`ImageBackend._board_view`)."""
    return get_backend(spec)._board_view(item)


def setup_from_campaign(cfg: CampaignConfig) -> InstrumentSetup:
    """The instrument set-up of a campaign: its world (seed defaulting to the campaign's), ``[measurement]``,
    the images its recording keeps, board views rendered with the campaign seed."""
    world = dict(cfg.world)
    world.setdefault("seed", cfg.seed)
    out = cfg.outputs
    keep = "none" if not out.recording else out.recording_images
    return InstrumentSetup(
        world=world, mode=cfg.measurement.mode, noise_position=cfg.measurement.noise_position,
        seconds_per_pose=cfg.measurement.seconds_per_pose, bias_correction=cfg.measurement.bias_correction,
        board_views=None, board_seed=cfg.seed, keep_images=keep, lossless=out.recording_lossless,
        jpeg_quality=out.jpeg_quality, plate=cfg.plate,
    )


def backend_spec_for(cfg: CampaignConfig, work_dir: str | os.PathLike, factory: str | None = None, **options) -> BackendSpec:
    """The spec of the campaign's backend (``cfg.measurement.mode``) or of an explicit ``factory``."""
    return BackendSpec(
        factory=factory or BACKENDS[cfg.measurement.mode],
        setup=setup_from_campaign(cfg),
        work_dir=str(work_dir),
        options=dict(options),
    )


def _stored_for(store: PoseStore | MemoryStore, task: PoseTask) -> bool:
    """True when the store holds a result of ``task.key`` measured at the task's commanded joints."""
    if not store.has(task.key):
        return False
    q_stored = np.asarray(store.read(task.key).q, dtype=float)
    return q_stored.shape == np.shape(task.q) and bool(np.all(np.abs(q_stored - np.asarray(task.q, dtype=float)) <= 1e-12))


def measure_tasks(executor: cf.Executor, spec: BackendSpec, tasks: Sequence[PoseTask], store: PoseStore | MemoryStore,
                  phase: str = "measuring", progress: Progress | None = None,
                  on_result: Callable[[PoseTask, PoseResult], None] | None = None) -> int:
    """Measure the tasks not yet in ``store``; every result is written as soon as it arrives. Returns how many
    were measured in this call.

    A stored result is reused only when it was measured at the task's own command: a compensated pose whose
    command changed (the identification was redone on a re-measured dataset) is measured again, so a command
    is never paired with spheres measured at another one. ``on_result(task, result)`` runs in the calling
    process after each new result is stored."""
    pending = [t for t in tasks if not _stored_for(store, t)]
    done = len(tasks) - len(pending)
    if progress:
        progress(phase, done, len(tasks))
    counter = {"n": done}

    def on_done(task: PoseTask, res: PoseResult) -> None:
        store.write(res)
        counter["n"] += 1
        if on_result is not None:
            on_result(task, res)
        if progress:
            progress(phase, counter["n"], len(tasks))

    run_tasks(executor, measure_pose, pending, args=(spec,), on_done=on_done)
    return len(pending)


def write_measured_dataset(folder: str | os.PathLike, results: Sequence[PoseResult], q: np.ndarray | None = None, *,
                           set: Sequence[str] | None = None, station: Sequence[str] | None = None,
                           pair: Sequence[int] | None = None, t_s: Sequence[float] | None = None,
                           temp_c: Sequence[float] | None = None) -> MeasuredRowsWriter:
    """``poses.csv`` of measured poses, in the order given: ``pose_id``, the commanded joints (``q`` ``(n, 6)``
    [rad], default each result's own), the measured sphere centres, ``status``, and the optional columns given
    (``pair`` ``-1`` for a row outside a pair). The caller writes ``dataset.toml``. Returns the closed writer
    (its ``path``; its ``summary(calib)`` counts the rows, their reasons and measurement times)."""
    n = len(results)
    cols = {"set": set, "station": station, "pair": pair, "t_s": t_s, "temp_c": temp_c}
    for name, v in cols.items():
        if v is not None and len(v) != n:
            raise ValueError(f"{name}: {len(v)} entries for {n} measured poses")
    if q is not None and np.shape(q) != (n, 6):
        raise ValueError(f"q must be ({n}, 6) [rad], got {np.shape(q)}")
    given = {k: v for k, v in cols.items() if v is not None}
    with MeasuredRowsWriter(folder, columns=list(given)) as w:
        for k, r in enumerate(results):
            w.write(r.pose_id, r.q if q is None else q[k], r.spheres, r.status,
                    time_s=r.timings.get("measure_s"), **{c: v[k] for c, v in given.items()})
    return w
