"""Campaign configs (``experiments/*.toml``): schema, loader, validation (``docs/formats.md``, "Campaign configs").

The file is in millimetres and degrees; :func:`load_campaign_config` returns a frozen
:class:`CampaignConfig` in SI. Every key is checked: an unknown key or a bad value raises ``ValueError``
naming the file and the key (a typo must not silently fall back to a default). The ``[world]`` table is
the world's (scene, effects, image formation) and is passed through unchanged; its keys are documented by
the world.

``--quick`` deep-merges the file's ``[quick]`` table over the rest before validation, so a quick variant is
the same campaign with a few values replaced (half resolution, fewer poses). That variant is validated on every
load, with ``--quick`` or without.
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..camera import FLIP_MUJOCO_OPENCV, CameraIntrinsics
from ..dataset import Plate, default_plate
from ..files import read_toml
from ..kinematics import RobotModel
from ..transforms import invert_transform, make_transform, pose6_to_transform
from ..units import M_PER_MM, RAD_PER_DEG
from ..world.config import WorldConfig, nominal_robot_from_spec
from ..world.rig import camera2rig, station_rig2world
from .sampling import SamplingOptions, Station, ViewCamera

__all__ = [
    "SCHEMA_VERSION",
    "KNOWN_METHODS",
    "GROUP_KINDS",
    "MeasurementConfig",
    "PoseGroup",
    "OutputConfig",
    "DiagnosisConfig",
    "CampaignConfig",
    "load_campaign_config",
    "parse_campaign_config",
]

SCHEMA_VERSION = 1
KNOWN_METHODS = ("distance", "full_pose", "separation", "separation_paper", "default")
GROUP_KINDS = ("motion_pairs", "distance_moves", "configurations", "joints_csv")
MEASUREMENT_MODES = ("images", "truth_noise")


class _Reader:
    """Pops keys from one TOML table and complains, naming the file and the dotted key."""

    def __init__(self, table: Any, where: str, path: str) -> None:
        if not isinstance(table, dict):
            raise ValueError(f"{path}: [{where}] must be a table, got {type(table).__name__}")
        self.t = dict(table)
        self.where = where
        self.path = path

    def key(self, k: str) -> str:
        return f"{self.where}.{k}" if self.where else k

    def err(self, k: str, msg: str) -> ValueError:
        return ValueError(f"{self.path}: {self.key(k)}: {msg}")

    def get(self, k: str, default: Any = None, *, required: bool = False) -> Any:
        if k not in self.t:
            if required:
                raise ValueError(f"{self.path}: missing required key {self.key(k)}")
            return default
        return self.t.pop(k)

    def number(self, k: str, default: float | None = None, *, required=False, positive=False, nonneg=False) -> float:
        v = self.get(k, default, required=required)
        if v is None:
            return None  # type: ignore[return-value]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise self.err(k, f"must be a finite number, got {v!r}")
        if positive and v <= 0:
            raise self.err(k, f"must be positive, got {v!r}")
        if nonneg and v < 0:
            raise self.err(k, f"must be >= 0, got {v!r}")
        return float(v)

    def integer(self, k: str, default: int | None = None, *, required=False, minimum: int | None = None) -> int:
        v = self.get(k, default, required=required)
        if v is None:
            return None  # type: ignore[return-value]
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.err(k, f"must be an integer, got {v!r}")
        if minimum is not None and v < minimum:
            raise self.err(k, f"must be >= {minimum}, got {v!r}")
        return int(v)

    def string(self, k: str, default: str | None = None, *, required=False, choices=None) -> str:
        v = self.get(k, default, required=required)
        if v is None:
            return None  # type: ignore[return-value]
        if not isinstance(v, str):
            raise self.err(k, f"must be a string, got {v!r}")
        if choices is not None and v not in choices:
            raise self.err(k, f"must be one of {list(choices)}, got {v!r}")
        return v

    def boolean(self, k: str, default: bool) -> bool:
        v = self.get(k, default)
        if not isinstance(v, bool):
            raise self.err(k, f"must be true or false, got {v!r}")
        return v

    def vector(self, k: str, n: int, default=None, *, required=False) -> np.ndarray | None:
        v = self.get(k, default, required=required)
        if v is None:
            return None
        try:
            a = np.asarray(v, dtype=float)
        except (TypeError, ValueError):
            raise self.err(k, f"must be a list of {n} numbers, got {v!r}") from None
        if a.shape != (n,) or not np.all(np.isfinite(a)):
            raise self.err(k, f"must be a list of {n} finite numbers, got {v!r}")
        return a

    def table(self, k: str) -> "_Reader":
        return _Reader(self.get(k, {}), self.key(k), self.path)

    def done(self) -> None:
        if self.t:
            raise ValueError(f"{self.path}: unknown key(s) {[self.key(k) for k in sorted(self.t)]}")


def _planning_stations(world: WorldConfig) -> tuple[Station, ...]:
    """Nominal camera stations (OpenCV ``cam2base``, ideal pinhole intrinsics at the render scale) for the pose
    samplers: the world's rig geometry (:func:`twin.world.rig.station_rig2world`, :func:`~twin.world.rig.camera2rig`)
    at the configured placements, expressed in the nominal robot base frame."""
    rig = world.rig
    s = world.render.scale
    w, h = int(round(rig.width_px * s)), int(round(rig.height_px * s))
    f = rig.focal_px * s
    K = CameraIntrinsics(f, f, w / 2 - 0.5, h / 2 - 0.5, w, h)
    world2base = invert_transform(pose6_to_transform(world.mount_pose6))
    left2rig, right2rig = camera2rig(rig)
    flip = make_transform(FLIP_MUJOCO_OPENCV, np.zeros(3))
    out = []
    for st in world.stations:
        R = world2base @ station_rig2world(st, rig)
        out.append(Station(st.name, (ViewCamera(R @ left2rig @ flip, K), ViewCamera(R @ right2rig @ flip, K))))
    return tuple(out)


@dataclass(frozen=True)
class MeasurementConfig:
    """``images``: the world renders, the instrument measures (stereo calibration from the world's rendered
    board views, ``[world.board] views``). ``truth_noise``: the separation paper's own simulation (true sphere centres plus
    N(0, ``noise_position``^2) per coordinate, no images). ``seconds_per_pose`` [s]: the time stamp of the
    ``k``-th measurement in the robot's visit order is ``k * seconds_per_pose`` (time-dependent effects such
    as thermal drift). ``record_temp_c`` / ``record_t_s``: the instrument records the robot's temperature
    [°C] / the time stamp [s] of each measurement, written as the ``temp_c`` / ``t_s`` columns of poses.csv
    (off by default: the papers' instruments record neither). ``bias_correction``: the instrument corrects
    the perspective bias of the sphere outlines (``images`` mode only; on by default)."""

    mode: str
    noise_position: float
    seconds_per_pose: float = 10.0
    record_temp_c: bool = False
    record_t_s: bool = False
    bias_correction: bool = True


@dataclass(frozen=True)
class PoseGroup:
    """A block of poses measured one after the other (``docs/formats.md``, "Campaign configs")."""

    name: str
    set: str
    kind: str
    count: int
    distances: tuple[float, ...]
    stations: tuple[str, ...]
    sampling: SamplingOptions
    evaluate: tuple[str, ...]
    path: Path | None = None
    pairing: str = "none"  # joints_csv: 'consecutive' makes rows (0, 1), (2, 3), ... motion pairs


@dataclass(frozen=True)
class OutputConfig:
    recording: bool = True
    recording_images: str = "dataset"  # 'all', 'dataset' (the measured dataset only) or 'none'
    recording_lossless: bool = False
    jpeg_quality: int = 85
    figures: bool = True
    paper: str = "simulation"  # which of the paper's experiments to print beside ours: 'simulation' or 'real'


@dataclass(frozen=True)
class DiagnosisConfig:
    """``[diagnosis]``: ``enabled`` runs ``twin diagnose`` on the campaign's dataset (the diagnose stage) at
    significance ``alpha``; the residual, the terms found and the error before and after go to the table,
    results.json and the recording, the diagnosis files to ``diagnosis/``."""

    enabled: bool = False
    alpha: float = 0.01


@dataclass(frozen=True, eq=False)
class CampaignConfig:
    """A validated campaign (SI inside). ``world`` is the ``[world]`` table, passed to the world unchanged
    (robot, injected errors, effects, rig, stations, rendering); ``raw`` is the TOML as used (``[quick]``
    merged in when ``quick``), recorded in results.json."""

    name: str
    description: str
    seed: int
    world: dict[str, Any]
    measurement: MeasurementConfig
    groups: tuple[PoseGroup, ...]
    methods: tuple[str, ...]
    outputs: OutputConfig
    workers: int
    quick: bool
    source: Path | None
    raw: dict[str, Any] = field(repr=False)
    _stations: tuple[Station, ...] = field(repr=False, default=())
    diagnosis: DiagnosisConfig = DiagnosisConfig()

    @property
    def plate(self) -> Plate:
        """The nominal plate (what the dataset declares and the planner uses)."""
        return default_plate()

    @property
    def robot(self) -> Any:
        """The robot spec of the world (a name twin.robots knows, or an inline table)."""
        return self.world_config().robot

    def world_config(self) -> WorldConfig:
        """The world's config (``[world]``; its ``seed`` defaults to the campaign seed)."""
        return _world_config(self.world, self.seed, str(self.source) if self.source else "<config>")

    def nominal_model(self) -> RobotModel:
        return nominal_robot_from_spec(self.world_config().robot)

    def true_deviation(self) -> dict[str, float]:
        """Injected kinematic deviation (SI) by parameter name: preset + explicit + seeded random errors."""
        nominal = self.nominal_model()
        dev = self.world_config().deviation(nominal)
        return {n: float(v) for n, v in zip(nominal.layout.names, dev) if v != 0.0}

    def stations(self) -> tuple[Station, ...]:
        """Nominal stations the planner uses (at the render scale)."""
        return self._stations

    def with_seed(self, seed: int) -> "CampaignConfig":
        raw = copy.deepcopy(self.raw)
        raw["seed"] = int(seed)
        return parse_campaign_config(raw, source=self.source, quick=False, _quick_applied=self.quick)

    def fingerprint(self) -> str:
        """Hash of everything that determines the measurements (resume refuses a different campaign); the
        ``[diagnosis]`` table reads the dataset and changes no measurement, so it is left out."""
        raw = {k: v for k, v in self.raw.items() if k != "diagnosis"}
        blob = json.dumps({"config": raw, "quick": self.quick}, sort_keys=True, default=str).encode()
        return hashlib.sha256(blob).hexdigest()[:16]


def _deep_merge(base: dict, over: dict) -> dict:
    """``over`` into ``base``; an array of tables (``poses``) is merged by the tables' ``name``."""
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), list):
            names = [t.get("name") for t in out[k] if isinstance(t, dict)]
            for name, sub in v.items():
                if name not in names:
                    raise ValueError(f"[quick.{k}.{name}]: no [[{k}]] table named {name!r} (known: {names})")
                i = names.index(name)
                out[k][i] = _deep_merge(out[k][i], sub)
        elif isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _deep_merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def _sampling(r: _Reader, defaults: SamplingOptions) -> SamplingOptions:
    depth = r.vector("depth_mm", 2)
    tilt = r.number("max_tilt_deg", None)
    margin = r.number("margin_px", None, nonneg=True)
    branch = r.string("branch", None, choices=("random", "home"))
    attempts = r.integer("max_attempts", None, minimum=1)
    pitch = r.number("max_euler_pitch_deg", None, positive=True)
    roll = r.number("max_roll_deg", None, nonneg=True)
    lim = r.number("limit_margin_deg", None, nonneg=True)
    turn = r.vector("turn_deg", 2)
    shift = r.vector("shift_mm", 2)
    dturn = r.vector("distance_turn_deg", 2)
    step = r.number("max_joint_step_deg", None, positive=True)
    kw: dict[str, Any] = {}
    kw["turn"] = (float(turn[0]) * RAD_PER_DEG, float(turn[1]) * RAD_PER_DEG) if turn is not None else defaults.turn
    kw["shift"] = (float(shift[0]) * M_PER_MM, float(shift[1]) * M_PER_MM) if shift is not None else defaults.shift
    kw["distance_turn"] = (float(dturn[0]) * RAD_PER_DEG, float(dturn[1]) * RAD_PER_DEG) if dturn is not None else defaults.distance_turn
    kw["max_joint_step"] = step * RAD_PER_DEG if step is not None else defaults.max_joint_step
    if shift is not None and kw["turn"] is None:
        raise ValueError(f"{r.path}: [{r.where}]: shift_mm: only a local motion (turn_deg set) takes a shift")
    kw["limit_margin"] = lim * RAD_PER_DEG if lim is not None else defaults.limit_margin
    kw["max_roll"] = roll * RAD_PER_DEG if roll is not None else defaults.max_roll
    kw["max_euler_pitch"] = pitch * RAD_PER_DEG if pitch is not None else defaults.max_euler_pitch
    if depth is not None:
        kw["depth_min"], kw["depth_max"] = float(depth[0]) * M_PER_MM, float(depth[1]) * M_PER_MM
    else:
        kw["depth_min"], kw["depth_max"] = defaults.depth_min, defaults.depth_max
    kw["max_tilt"] = tilt * RAD_PER_DEG if tilt is not None else defaults.max_tilt
    kw["margin_px"] = margin if margin is not None else defaults.margin_px
    kw["branch"] = branch or defaults.branch
    kw["max_attempts"] = attempts or defaults.max_attempts
    try:
        return SamplingOptions(**kw)
    except ValueError as exc:
        raise ValueError(f"{r.path}: [{r.where}]: {exc}") from None


def _world_config(world: Any, seed: int, path: str) -> WorldConfig:
    if not isinstance(world, dict):
        raise ValueError(f"{path}: [world] must be a table")
    table = dict(world)
    table.setdefault("seed", seed)
    try:
        return WorldConfig.from_dict(table)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def parse_campaign_config(
    raw: dict[str, Any], *, source: Path | None = None, quick: bool = False, _quick_applied: bool = False
) -> CampaignConfig:
    """Validate a campaign dict (as read from TOML) into a :class:`CampaignConfig`."""
    path = str(source) if source else "<config>"
    raw = copy.deepcopy(raw)
    quick_table = raw.pop("quick", {})
    if not isinstance(quick_table, dict):
        raise ValueError(f"{path}: [quick] must be a table")
    if quick_table and not (quick or _quick_applied):
        # the [quick] variant is checked on every load, so that a fault in it is named before a --quick run meets it
        try:
            parse_campaign_config({**raw, "quick": quick_table}, source=source, quick=True)
        except ValueError as exc:
            raise ValueError(f"{exc} (in the [quick] variant: the file's [quick] table merged over the rest)") from None
    try:
        merged = _deep_merge(raw, quick_table) if quick else raw
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    is_quick = quick or _quick_applied
    r = _Reader(merged, "", path)
    version = r.get("schema_version", required=True)
    if version != SCHEMA_VERSION:
        raise ValueError(f"{path}: unknown schema_version {version!r} (this reader knows {SCHEMA_VERSION})")
    name = r.string("name", required=True)
    description = r.string("description", "")
    seed = r.integer("seed", required=True, minimum=0)
    world = r.get("world", {})
    stations = _planning_stations(_world_config(world, seed, path))
    station_names = tuple(s.name for s in stations)

    mr = r.table("measurement")
    measurement = MeasurementConfig(
        mode=mr.string("mode", "images", choices=MEASUREMENT_MODES),
        noise_position=mr.number("noise_mm", 0.01, nonneg=True) * M_PER_MM,
        seconds_per_pose=mr.number("seconds_per_pose", 10.0, nonneg=True),
        record_temp_c=mr.boolean("record_temp_c", False),
        record_t_s=mr.boolean("record_t_s", False),
        bias_correction=mr.boolean("bias_correction", True),
    )
    mr.done()
    if not measurement.bias_correction and measurement.mode != "images":
        raise ValueError(f"{path}: measurement.bias_correction: only the 'images' mode has an instrument to set; "
                         f"mode is {measurement.mode!r}")

    sr_default = r.table("sampling")
    default_sampling = _sampling(sr_default, SamplingOptions())
    sr_default.done()

    groups = []
    glist = r.get("poses", None, required=True)
    if not isinstance(glist, list) or not glist:
        raise ValueError(f"{path}: poses must be a non-empty array of tables ([[poses]])")
    for k, g in enumerate(glist):
        gr = _Reader(g, f"poses[{k}]", path)
        gname = gr.string("name", required=True)
        gset = gr.string("set", required=True, choices=("calibration", "validation"))
        kind = gr.string("kind", required=True, choices=GROUP_KINDS)
        count = gr.integer("count", 0, minimum=0)
        distances: tuple[float, ...] = ()
        gpath = None
        if kind == "distance_moves":
            dl = gr.get("distances_mm", None, required=True)
            per = gr.integer("per_distance", 1, minimum=1)
            if not isinstance(dl, list) or not dl or not all(
                isinstance(x, (int, float)) and not isinstance(x, bool) and x > 0 for x in dl
            ):
                raise gr.err("distances_mm", f"must be a non-empty list of positive numbers, got {dl!r}")
            distances = tuple(float(d) * M_PER_MM for d in dl for _ in range(per))
            count = len(distances)
        elif kind == "joints_csv":
            p = gr.string("path", required=True)
            gpath = Path(p) if Path(p).is_absolute() or source is None else (Path(source).parent / p)
        elif count < 1:
            raise gr.err("count", f"must be >= 1 for kind {kind!r}")
        pairing = gr.string("pairing", "none", choices=("none", "consecutive"))
        if pairing != "none" and kind != "joints_csv":
            raise gr.err("pairing", "only a joints_csv group takes a pairing")
        gst = gr.get("stations", list(station_names))
        if isinstance(gst, str):
            gst = [gst]
        if not isinstance(gst, list) or not gst or any(str(x) not in station_names for x in gst):
            raise gr.err("stations", f"must name stations among {list(station_names)}, got {gst!r}")
        default_eval = {"motion_pairs": ["angle", "position"], "distance_moves": ["position"]}.get(kind, [])
        ev = gr.get("evaluate", default_eval if gset == "validation" else [])
        if not isinstance(ev, list) or any(e not in ("angle", "position") for e in ev):
            raise gr.err("evaluate", f"must be a list of 'angle' / 'position', got {ev!r}")
        if ev and (kind == "configurations" or (kind == "joints_csv" and pairing == "none")):
            raise gr.err("evaluate", "single configurations carry no motion to evaluate; use motion pairs")
        if ev and gset != "validation":
            raise gr.err("evaluate", "only validation groups are evaluated")
        samp_r = gr.table("sampling")
        samp = _sampling(samp_r, default_sampling)
        samp_r.done()
        gr.done()
        groups.append(PoseGroup(gname, gset, kind, count, distances, tuple(str(x) for x in gst), samp, tuple(ev), gpath,
                                pairing))
    if len({g.name for g in groups}) != len(groups):
        raise ValueError(f"{path}: poses: group names must be unique")
    if not any(g.set == "calibration" for g in groups):
        raise ValueError(f"{path}: poses: at least one group must have set = 'calibration'")

    methods = r.get("methods", list(KNOWN_METHODS))
    if not isinstance(methods, list) or any(m not in KNOWN_METHODS for m in methods) or len(set(methods)) != len(methods):
        raise ValueError(f"{path}: methods must be a list of distinct names among {list(KNOWN_METHODS)}, got {methods!r}")

    orr = r.table("outputs")
    outputs = OutputConfig(
        recording=orr.boolean("recording", True),
        recording_images=orr.string("recording_images", "dataset", choices=("all", "dataset", "none")),
        recording_lossless=orr.boolean("recording_lossless", False),
        jpeg_quality=orr.integer("jpeg_quality", 85, minimum=1),
        figures=orr.boolean("figures", True),
        paper=orr.string("paper", "simulation", choices=("simulation", "real")),
    )
    orr.done()
    dr = r.table("diagnosis")
    diagnosis = DiagnosisConfig(enabled=dr.boolean("enabled", False), alpha=dr.number("alpha", 0.01, positive=True))
    dr.done()
    if not diagnosis.alpha < 0.5:
        raise ValueError(f"{path}: diagnosis.alpha must be in (0, 0.5), got {diagnosis.alpha!r}")
    er = r.table("execution")
    workers = er.integer("workers", min(2, os.cpu_count() or 1), minimum=1)
    er.done()
    r.done()
    return CampaignConfig(
        name=name,
        description=description,
        seed=seed,
        world=world,
        measurement=measurement,
        groups=tuple(groups),
        methods=tuple(methods),
        outputs=outputs,
        workers=workers,
        quick=is_quick,
        source=source,
        raw=merged,
        _stations=stations,
        diagnosis=diagnosis,
    )


def load_campaign_config(path: str | os.PathLike, *, quick: bool = False) -> CampaignConfig:
    """Read and validate ``experiments/<name>.toml`` (``ValueError`` naming the file and key on any problem)."""
    p = Path(path)
    if not p.exists():
        raise ValueError(f"campaign config {p} does not exist")
    return parse_campaign_config(read_toml(p), source=p, quick=quick)
