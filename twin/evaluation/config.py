"""Campaign configs (``experiments/*.toml``): schema, loader, validation (``docs/formats.md``, "Campaign configs").

The file is in millimetres and degrees; :func:`load_campaign_config` returns a frozen
:class:`CampaignConfig` in SI. Every key is checked: an unknown key or a bad value raises ``ValueError``
naming the file and the key (a typo must not silently fall back to a default). The ``[world]`` table is
the world's (scene, effects, image formation) and is passed through unchanged; its keys are documented by
the world.

``--quick`` deep-merges the file's ``[quick]`` table over the rest before validation, so a quick variant is
the same campaign with a few values replaced (half resolution, fewer poses).
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..camera import CameraIntrinsics, mujoco_to_opencv_cam2world
from ..dataset import Plate, default_plate
from ..kinematics import RobotModel
from ..presets import preset_deviation, preset_robot
from ..robots import get_robot
from .sampling import SamplingOptions, Station, ViewCamera

__all__ = [
    "SCHEMA_VERSION",
    "KNOWN_METHODS",
    "GROUP_KINDS",
    "MeasurementConfig",
    "PoseGroup",
    "OutputConfig",
    "CampaignConfig",
    "load_campaign_config",
    "parse_campaign_config",
]

SCHEMA_VERSION = 1
KNOWN_METHODS = ("distance", "full_pose", "separation", "default")
GROUP_KINDS = ("motion_pairs", "distance_moves", "configurations", "joints_csv")
MEASUREMENT_MODES = ("images", "truth_noise")
_MM = 1e-3
_DEG = math.pi / 180.0


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


def _planning_stations_from_world(world: dict, path: str) -> tuple[Station, ...]:
    """Nominal camera stations (OpenCV ``cam2base``, ideal intrinsics at the render scale) from the ``[world]``
    table, for the pose samplers.

    Same geometry as the world's rig (``docs/formats.md``, world sub-section): the rig sits at ``standoff``
    from ``target`` along (azimuth about base z, elevation), looks at the target, lab +z up, turned by
    ``roll``; its cameras sit at -+baseline/2 on the rig's x axis, toed in so that their axes cross at the
    standoff (or at ``vergence``).
    TODO(runner): replace by ``twin.world`` (WorldConfig, station_rig2world, camera2rig) once merged.
    """
    rig = world.get("rig", {}) or {}
    baseline = float(rig.get("baseline_mm", 250.0)) * _MM
    standoff_default = float(rig.get("standoff_mm", 700.0)) * _MM
    toe = (0.5 * float(rig["vergence_deg"]) * _DEG) if "vergence_deg" in rig else None
    w, h = int(rig.get("width_px", 2592)), int(rig.get("height_px", 1944))
    f = float(rig.get("focal_mm", 16.0)) / float(rig.get("pixel_um", 2.2)) * 1e3
    scale = float((world.get("render", {}) or {}).get("scale", 1.0))
    K = CameraIntrinsics(f, f, w / 2 - 0.5, h / 2 - 0.5, w, h)
    if scale != 1.0:
        K = K.scaled(scale)
    stations_raw = world.get("stations")
    if not isinstance(stations_raw, list) or not stations_raw:
        raise ValueError(f"{path}: world.stations must be a non-empty array of tables ([[world.stations]])")
    out = []
    for k, st in enumerate(stations_raw):
        try:
            target = np.asarray(st["target_mm"], dtype=float).reshape(3) * _MM
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"{path}: world.stations[{k}].target_mm must be 3 numbers") from None
        az = float(st.get("azimuth_deg", 0.0)) * _DEG
        el = float(st.get("elevation_deg", 0.0)) * _DEG
        roll = float(st.get("roll_deg", 0.0)) * _DEG
        d = float(st["standoff_mm"]) * _MM if "standoff_mm" in st else standoff_default
        u = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        x = np.cross([0.0, 0.0, 1.0], u)
        x /= np.linalg.norm(x)
        y = np.cross(u, x)
        x, y = np.cos(roll) * x + np.sin(roll) * y, -np.sin(roll) * x + np.cos(roll) * y
        rig2world = np.eye(4)
        rig2world[:3, :3] = np.stack([x, y, u], axis=1)
        rig2world[:3, 3] = target + d * u
        phi = toe if toe is not None else math.atan2(0.5 * baseline, standoff_default)
        cams = []
        for xo, yaw in ((-0.5 * baseline, -phi), (0.5 * baseline, phi)):
            c, s_ = np.cos(yaw), np.sin(yaw)
            T = np.eye(4)
            T[:3, :3] = np.array([[c, 0, s_], [0, 1, 0], [-s_, 0, c]])
            T[0, 3] = xo
            M = rig2world @ T  # MuJoCo camera axes
            cams.append(ViewCamera(mujoco_to_opencv_cam2world(M[:3, 3], M[:3, :3]), K))
        out.append(Station(str(st.get("name", k)), tuple(cams)))
    names = [s.name for s in out]
    if len(set(names)) != len(names):
        raise ValueError(f"{path}: world.stations: station names must be unique, got {names}")
    return tuple(out)


@dataclass(frozen=True)
class MeasurementConfig:
    """``images``: the world renders, the instrument measures. ``truth_noise``: the separation paper's own
    simulation (true sphere centres plus N(0, ``noise_position``^2) per coordinate, no images)."""

    mode: str
    noise_position: float


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


@dataclass(frozen=True)
class OutputConfig:
    recording: bool = True
    recording_images: str = "dataset"  # 'all', 'dataset' (the measured dataset only) or 'none'
    recording_lossless: bool = False
    jpeg_quality: int = 85
    figures: bool = True


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

    @property
    def plate(self) -> Plate:
        """The nominal plate (what the dataset declares and the planner uses)."""
        return default_plate()

    @property
    def robot(self) -> str:
        return str(self.world.get("robot", "irb1200"))

    def nominal_model(self) -> RobotModel:
        return get_robot(self.robot)

    def true_deviation(self) -> dict[str, float]:
        """Injected kinematic deviation (SI): ``world.preset`` plus ``world.errors``, summed by name.
        TODO(runner): take it from twin.world once merged (random errors, mount)."""
        dev = dict(preset_deviation(self.world["preset"])) if self.world.get("preset") else {}
        layout = self.nominal_model().layout
        for k, v in _errors(_Reader(self.world.get("errors", {}) or {}, "world.errors", "<config>"), layout.names).items():
            dev[k] = dev.get(k, 0.0) + v
        return dev

    def true_model(self) -> RobotModel:
        """The twin's true kinematics (nominal + injected errors). Evaluation and world only."""
        return self.nominal_model().perturbed(self.true_deviation(), name=f"{self.robot}-true")

    def stations(self) -> tuple[Station, ...]:
        """Nominal stations the planner uses (at the render scale)."""
        return self._stations

    def with_seed(self, seed: int) -> "CampaignConfig":
        raw = copy.deepcopy(self.raw)
        raw["seed"] = int(seed)
        return parse_campaign_config(raw, source=self.source, quick=False, _quick_applied=self.quick)

    def fingerprint(self) -> str:
        """Hash of everything that determines the measurements (resume refuses a different campaign)."""
        blob = json.dumps({"config": self.raw, "quick": self.quick}, sort_keys=True, default=str).encode()
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


def _errors(r: _Reader, layout_names: tuple[str, ...]) -> dict[str, float]:
    out: dict[str, float] = {}
    for key in list(r.t):
        v = r.number(key, required=True)
        if key.endswith("_deg"):
            name, scale = key[:-4], _DEG
        elif key.endswith("_mm"):
            name, scale = key[:-3], _MM
        else:
            raise r.err(key, "must end in _deg or _mm (e.g. theta2_deg = 0.1)")
        if name not in layout_names:
            raise r.err(key, f"unknown parameter {name!r}; known: {', '.join(layout_names)}")
        out[name] = out.get(name, 0.0) + v * scale
    return out


def _sampling(r: _Reader, defaults: SamplingOptions) -> SamplingOptions:
    depth = r.vector("depth_mm", 2)
    tilt = r.number("max_tilt_deg", None)
    margin = r.number("margin_px", None, nonneg=True)
    branch = r.string("branch", None, choices=("random", "home"))
    attempts = r.integer("max_attempts", None, minimum=1)
    pitch = r.number("max_euler_pitch_deg", None, positive=True)
    roll = r.number("max_roll_deg", None, nonneg=True)
    kw: dict[str, Any] = {}
    kw["max_roll"] = roll * _DEG if roll is not None else defaults.max_roll
    kw["max_euler_pitch"] = pitch * _DEG if pitch is not None else defaults.max_euler_pitch
    if depth is not None:
        kw["depth_min"], kw["depth_max"] = float(depth[0]) * _MM, float(depth[1]) * _MM
    else:
        kw["depth_min"], kw["depth_max"] = defaults.depth_min, defaults.depth_max
    kw["max_tilt"] = tilt * _DEG if tilt is not None else defaults.max_tilt
    kw["margin_px"] = margin if margin is not None else defaults.margin_px
    kw["branch"] = branch or defaults.branch
    kw["max_attempts"] = attempts or defaults.max_attempts
    try:
        return SamplingOptions(**kw)
    except ValueError as exc:
        raise ValueError(f"{r.path}: [{r.where}]: {exc}") from None


def _world_table(world: Any, path: str) -> dict[str, Any]:
    if not isinstance(world, dict):
        raise ValueError(f"{path}: [world] must be a table")
    robot = world.get("robot", "irb1200")
    try:
        nominal = get_robot(robot)
    except ValueError as exc:
        raise ValueError(f"{path}: world.robot: {exc}") from None
    preset = world.get("preset")
    if preset is not None:
        try:
            other = preset_robot(preset)
        except ValueError as exc:
            raise ValueError(f"{path}: world.preset: {exc}") from None
        if other != robot:
            raise ValueError(f"{path}: world.preset: {preset!r} applies to robot {other!r}, not {robot!r}")
    _errors(_Reader(world.get("errors", {}) or {}, "world.errors", path), nominal.layout.names)
    return world


def parse_campaign_config(
    raw: dict[str, Any], *, source: Path | None = None, quick: bool = False, _quick_applied: bool = False
) -> CampaignConfig:
    """Validate a campaign dict (as read from TOML) into a :class:`CampaignConfig`."""
    path = str(source) if source else "<config>"
    raw = copy.deepcopy(raw)
    quick_table = raw.pop("quick", {})
    if not isinstance(quick_table, dict):
        raise ValueError(f"{path}: [quick] must be a table")
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
    world = _world_table(r.get("world", {}), path)
    stations = _planning_stations_from_world(world, path)
    station_names = tuple(s.name for s in stations)

    mr = r.table("measurement")
    measurement = MeasurementConfig(
        mode=mr.string("mode", "images", choices=MEASUREMENT_MODES),
        noise_position=mr.number("noise_mm", 0.01, nonneg=True) * _MM,
    )
    mr.done()

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
            distances = tuple(float(d) * _MM for d in dl for _ in range(per))
            count = len(distances)
        elif kind == "joints_csv":
            p = gr.string("path", required=True)
            gpath = Path(p) if Path(p).is_absolute() or source is None else (Path(source).parent / p)
        elif count < 1:
            raise gr.err("count", f"must be >= 1 for kind {kind!r}")
        gst = gr.get("stations", list(station_names))
        if isinstance(gst, str):
            gst = [gst]
        if not isinstance(gst, list) or not gst or any(str(x) not in station_names for x in gst):
            raise gr.err("stations", f"must name stations among {list(station_names)}, got {gst!r}")
        default_eval = {"motion_pairs": ["angle", "position"], "distance_moves": ["position"]}.get(kind, [])
        ev = gr.get("evaluate", default_eval if gset == "validation" else [])
        if not isinstance(ev, list) or any(e not in ("angle", "position") for e in ev):
            raise gr.err("evaluate", f"must be a list of 'angle' / 'position', got {ev!r}")
        if ev and kind == "configurations":
            raise gr.err("evaluate", "single configurations carry no motion to evaluate; use motion_pairs")
        if ev and gset != "validation":
            raise gr.err("evaluate", "only validation groups are evaluated")
        samp_r = gr.table("sampling")
        samp = _sampling(samp_r, default_sampling)
        samp_r.done()
        gr.done()
        groups.append(PoseGroup(gname, gset, kind, count, distances, tuple(str(x) for x in gst), samp, tuple(ev), gpath))
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
    )
    orr.done()
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
    )


def load_campaign_config(path: str | os.PathLike, *, quick: bool = False) -> CampaignConfig:
    """Read and validate ``experiments/<name>.toml`` (``ValueError`` naming the file and key on any problem)."""
    p = Path(path)
    if not p.exists():
        raise ValueError(f"campaign config {p} does not exist")
    try:
        raw = tomllib.loads(p.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{p}: not valid TOML: {exc}") from None
    return parse_campaign_config(raw, source=p, quick=quick)
