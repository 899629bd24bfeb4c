"""World configuration: the ``[world]`` table of a campaign config (schema in ``docs/formats.md``).

Millimetres and degrees in the TOML, SI in the dataclasses. Unknown keys are errors (a typo must not
silently fall back to a default). :func:`load_world_config` reads a file; :meth:`WorldConfig.from_dict`
takes the ``[world]`` table (or a whole config holding one).
"""

from __future__ import annotations

import math
import numbers
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..files import read_toml
from ..kinematics import ParameterLayout, RobotModel
from ..presets import PRESETS, preset_deviation, preset_robot
from ..robots import ROBOTS
from ..units import M_PER_MM, M_PER_UM, RAD_PER_DEG

__all__ = [
    "StationConfig",
    "RigConfig",
    "RenderConfig",
    "BoardConfig",
    "PlateConfig",
    "WorldConfig",
    "load_world_config",
    "check_keys",
    "table_number",
    "table_vector",
    "default_stations",
    "errors_from_edge_units",
    "MAX_SUPERSAMPLE",
]

# Largest render.supersample: 4 x 2592 = 10368 px a side is inside GL's 16384 (llvmpipe here); the sampling-grid
# buffers grow with s^2 (0.55 GB at s = 2). The GL limit itself is checked when the renderer is built.
MAX_SUPERSAMPLE = 4
# Largest render.window_supersample: windows are drawn in buffer-sized tiles, so only their cost limits it.
MAX_WINDOW_SUPERSAMPLE = 8


def check_keys(table: Mapping[str, Any], allowed: set[str], where: str) -> None:
    """``ValueError`` naming the table ``where`` and every key of ``table`` outside ``allowed``."""
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")


# the largest magnitude of a setting in a config's own units (mm, deg, px, K, kg, s): far beyond any cell or rig, so
# that 1e308 (a typing error) is named here rather than met as a meaningless angle or an overflow in a render
SETTING_MAX = 1e9


def table_number(table: Mapping[str, Any], key: str, default: float, where: str, *, positive=False, nonneg=False) -> float:
    """``table[key]`` (``default`` when absent) as a finite float within ``SETTING_MAX``; ``ValueError`` naming
    ``where.key`` otherwise (a boolean or a string is not a number: TOML's ``true`` is not 1)."""
    v = table.get(key, default)
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real):
        raise ValueError(f"{where}.{key} must be a number, got {v!r}")
    x = float(v)
    if not math.isfinite(x) or (positive and x <= 0) or (nonneg and x < 0):
        what = "positive" if positive else "non-negative" if nonneg else "finite"
        raise ValueError(f"{where}.{key} must be a {what} number, got {v!r}")
    if abs(x) > SETTING_MAX:
        raise ValueError(f"{where}.{key} must be within {SETTING_MAX:g} in its unit, got {v!r}")
    return x


def _station_name(v: Any, where: str) -> str:
    """A station's name: a non-empty string (an integer index when not given)."""
    if isinstance(v, bool) or not isinstance(v, (str, int)) or (isinstance(v, str) and not v.strip()):
        raise ValueError(f"{where}.name must be a non-empty string, got {v!r}")
    return str(v)


def table_vector(v: Any, n: int, where: str) -> np.ndarray:
    """``v`` as ``n`` finite floats; ``ValueError`` naming ``where`` otherwise."""
    if isinstance(v, (list, tuple)) and any(isinstance(x, (bool, np.bool_, str)) for x in v):
        raise ValueError(f"{where} must be {n} numbers, got {v!r}")
    try:
        a = np.asarray(v, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{where} must be {n} numbers, got {v!r}") from None
    if a.shape != (n,) or not np.all(np.isfinite(a)) or np.any(np.abs(a) > SETTING_MAX):
        raise ValueError(f"{where} must be {n} finite numbers within {SETTING_MAX:g}, got {v!r}")
    return a


@dataclass(frozen=True)
class StationConfig:
    """A placement of the whole rig, relative to the nominal robot base (= the MuJoCo world frame).

    The rig converges on ``target`` ``(3,)`` [m]; it sits at ``standoff`` from it in the direction given
    by ``azimuth`` (about base z, 0 = base +x) and ``elevation`` [rad]; ``roll`` [rad] turns it about
    its viewing axis. ``standoff`` ``None`` takes the rig's default.
    """

    name: str
    target: np.ndarray
    azimuth: float = 0.0
    elevation: float = 0.0
    roll: float = 0.0
    standoff: float | None = None

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], index: int) -> "StationConfig":
        where = f"world.stations[{index}]"
        check_keys(d, {"name", "target_mm", "azimuth_deg", "elevation_deg", "roll_deg", "standoff_mm"}, where)
        if "target_mm" not in d:
            raise ValueError(f"{where}: missing 'target_mm' (the point the rig converges on, robot base frame)")
        standoff = None
        if "standoff_mm" in d:
            standoff = table_number(d, "standoff_mm", 0, where, positive=True) * M_PER_MM
        return cls(
            name=_station_name(d.get("name", index), where),
            target=table_vector(d["target_mm"], 3, f"{where}.target_mm") * M_PER_MM,
            azimuth=table_number(d, "azimuth_deg", 0.0, where) * RAD_PER_DEG,
            elevation=table_number(d, "elevation_deg", 0.0, where) * RAD_PER_DEG,
            roll=table_number(d, "roll_deg", 0.0, where) * RAD_PER_DEG,
            standoff=standoff,
        )


def default_stations() -> tuple[StationConfig, ...]:
    """Four placements around the IRB-1200's front workspace, each facing a region the plate can face.

    In front (base +x), to either side from 35 deg and from above at 35 deg elevation. Every one is
    checked by ``tests/test_world_render.py`` to see the plate in reachable configurations.
    """
    return (
        StationConfig("front", np.array([0.50, 0.0, 0.55]), 0.0, 5 * RAD_PER_DEG),
        StationConfig("left", np.array([0.42, 0.22, 0.45]), 35 * RAD_PER_DEG, 10 * RAD_PER_DEG),
        StationConfig("right", np.array([0.42, -0.22, 0.45]), -35 * RAD_PER_DEG, 10 * RAD_PER_DEG),
        StationConfig("above", np.array([0.45, 0.0, 0.30]), 0.0, 35 * RAD_PER_DEG),
    )


@dataclass(frozen=True)
class RigConfig:
    """Two MV-EM500M-like cameras: ``baseline`` [m]; the optical axes cross at ``standoff`` [m] unless a
    total ``vergence`` [rad] is given; ``backdrop_behind`` [m] puts the dark board behind the target
    (``None``: no backdrop).

    Placement tolerances (the true rig deviates from the nominal one, as on a real cell; seeded by the world's
    seed, 1 sigma per axis): each station's rig pose by ``placement_sigma`` [m] and ``placement_sigma_rot``
    [rad] (a rig bolted to brackets against marks: 3 mm, 0.2 deg by default), each camera on the rig's bar by
    ``camera_mount_sigma`` [m] and ``camera_mount_sigma_rot`` [rad] (0.2 mm, 0.05 deg). Zero places the rig
    exactly where the configuration says."""

    baseline: float = 0.25
    standoff: float = 0.70
    vergence: float | None = None
    width_px: int = 2592
    height_px: int = 1944
    pixel_size: float = 2.2e-6
    focal_length: float = 0.016
    backdrop_behind: float | None = 0.30
    placement_sigma: float = 3.0e-3
    placement_sigma_rot: float = 0.2 * RAD_PER_DEG
    camera_mount_sigma: float = 0.2e-3
    camera_mount_sigma_rot: float = 0.05 * RAD_PER_DEG

    @property
    def focal_px(self) -> float:
        """Focal length in pixels at full resolution [px] (16 mm / 2.2 um = 7272.7)."""
        return self.focal_length / self.pixel_size

    def toe_in(self) -> float:
        """Turn of each camera towards the other [rad]."""
        if self.vergence is not None:
            return 0.5 * self.vergence
        return math.atan2(0.5 * self.baseline, self.standoff)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "RigConfig":
        where = "world.rig"
        check_keys(d, {"baseline_mm", "standoff_mm", "vergence_deg", "width_px", "height_px", "pixel_um",
                        "focal_mm", "backdrop_behind_mm", "backdrop", "placement_sigma_mm",
                        "placement_sigma_deg", "camera_mount_sigma_mm", "camera_mount_sigma_deg"}, where)
        tol = {}
        for key, default, lim in (("placement_sigma_mm", 3.0, 100.0), ("placement_sigma_deg", 0.2, 5.0),
                                  ("camera_mount_sigma_mm", 0.2, 10.0), ("camera_mount_sigma_deg", 0.05, 2.0)):
            v = table_number(d, key, default, where, nonneg=True)
            if v > lim:
                raise ValueError(f"{where}.{key} must be within 0..{lim} (a placement tolerance, 1 sigma), got {v!r}")
            tol[key] = v
        vergence = None if "vergence_deg" not in d else table_number(d, "vergence_deg", 0, where) * RAD_PER_DEG
        backdrop = bool(d.get("backdrop", True))
        standoff = table_number(d, "standoff_mm", 700.0, where, positive=True) * M_PER_MM
        if not 0.2 <= standoff <= 3.0:
            raise ValueError(f"{where}.standoff_mm must be within 200..3000 mm, got {d.get('standoff_mm')!r}")
        w, h = int(d.get("width_px", 2592)), int(d.get("height_px", 1944))
        if w <= 0 or h <= 0:
            raise ValueError(f"{where}: width_px/height_px must be positive, got {w}x{h}")
        return cls(
            baseline=table_number(d, "baseline_mm", 250.0, where, positive=True) * M_PER_MM,
            standoff=standoff,
            vergence=vergence,
            width_px=w,
            height_px=h,
            pixel_size=table_number(d, "pixel_um", 2.2, where, positive=True) * M_PER_UM,
            focal_length=table_number(d, "focal_mm", 16.0, where, positive=True) * M_PER_MM,
            backdrop_behind=(table_number(d, "backdrop_behind_mm", 300.0, where, positive=True) * M_PER_MM) if backdrop else None,
            placement_sigma=tol["placement_sigma_mm"] * M_PER_MM,
            placement_sigma_rot=tol["placement_sigma_deg"] * RAD_PER_DEG,
            camera_mount_sigma=tol["camera_mount_sigma_mm"] * M_PER_MM,
            camera_mount_sigma_rot=tol["camera_mount_sigma_deg"] * RAD_PER_DEG,
        )


_DEFAULT_DIST_LEFT = (-0.08, 0.10, 2.0e-4, -1.0e-4, 0.0)
_DEFAULT_DIST_RIGHT = (-0.07, 0.08, -1.0e-4, 2.0e-4, 0.0)
_DEFAULT_PP_LEFT = (6.5, -4.0)
_DEFAULT_PP_RIGHT = (-3.0, 5.5)


@dataclass(frozen=True)
class RenderConfig:
    """Image formation: resolution ``scale``, samples per pixel (``supersample`` x ``supersample``: MuJoCo
    renders that many times the pixels with the same field of view and each output pixel is the mean of its
    block), target windows (``window_supersample`` x ``window_supersample`` samples per pixel in a window
    around each target the camera sees, ``window_margin_px`` [px] beyond the target's projected outline;
    a large sphere's outline is covered by a ring of windows, one per ``window_arc_px`` [px] of outline;
    0 = no windows; see :meth:`twin.world.World.target_windows`), the frame under the windows at one sample
    per ``frame_subsample`` x ``frame_subsample`` pixels (needs windows and ``supersample`` 1; the world renders
    it at full resolution when an effect changes the images), sensor noise ``noise_sigma`` [grey levels, 1 sigma], lens distortion per camera (OpenCV
    ``k1 k2 p1 p2 k3``), principal-point offsets from the sensor centre [px at full resolution], lighting
    (key light direction relative to the rig's viewing axis, strengths in MuJoCo's 0..1 light units)."""

    scale: float = 1.0
    supersample: int = 1
    window_supersample: int = 0
    window_margin_px: float = 4.0
    window_arc_px: float = 48.0
    frame_subsample: int = 1
    noise_sigma: float = 2.0
    distortion_left: tuple[float, ...] = _DEFAULT_DIST_LEFT
    distortion_right: tuple[float, ...] = _DEFAULT_DIST_RIGHT
    principal_offset_left: tuple[float, float] = _DEFAULT_PP_LEFT
    principal_offset_right: tuple[float, float] = _DEFAULT_PP_RIGHT
    key_light_azimuth: float = 40 * RAD_PER_DEG
    key_light_elevation: float = 25 * RAD_PER_DEG
    key_light: float = 0.55
    key_ambient: float = 0.10
    headlight: float = 0.35
    ambient: float = 0.12

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "RenderConfig":
        where = "world.render"
        check_keys(d, {"scale", "supersample", "window_supersample", "window_margin_px", "window_arc_px",
                        "frame_subsample", "noise_sigma", "distortion", "distortion_left", "distortion_right",
                        "principal_offset_px", "principal_offset_left_px", "principal_offset_right_px",
                        "key_light_azimuth_deg", "key_light_elevation_deg", "key_light", "key_ambient",
                        "headlight", "ambient"}, where)
        scale = table_number(d, "scale", 1.0, where, positive=True)
        if scale > 1.0:
            raise ValueError(f"{where}.scale must be in (0, 1] (a fraction of the sensor resolution), got {scale!r}")
        ss = d.get("supersample", 1)
        if isinstance(ss, bool) or not isinstance(ss, (int, np.integer)) or not 1 <= ss <= MAX_SUPERSAMPLE:
            raise ValueError(f"{where}.supersample must be an integer 1..{MAX_SUPERSAMPLE} (samples per pixel along "
                             f"each axis), got {ss!r}")
        ws = d.get("window_supersample", 0)
        if isinstance(ws, bool) or not isinstance(ws, (int, np.integer)) or not 0 <= ws <= MAX_WINDOW_SUPERSAMPLE:
            raise ValueError(f"{where}.window_supersample must be an integer 0..{MAX_WINDOW_SUPERSAMPLE} (samples per "
                             f"pixel along each axis in the target windows, 0 = no windows), got {ws!r}")
        fs = d.get("frame_subsample", 1)
        if isinstance(fs, bool) or not isinstance(fs, (int, np.integer)) or fs not in (1, 2, 4):
            raise ValueError(f"{where}.frame_subsample must be 1, 2 or 4 (the frame under the target windows at one "
                             f"sample per k x k pixels), got {fs!r}")
        if fs > 1 and (ws < 1 or ss != 1):
            raise ValueError(f"{where}.frame_subsample = {fs} needs target windows (window_supersample >= 1, got {ws}) "
                             f"and supersample = 1 (got {ss}): without windows every outline would be sampled coarsely")
        dl = dr = None
        if "distortion" in d:
            dl = dr = tuple(table_vector(d["distortion"], 5, f"{where}.distortion"))
        if "distortion_left" in d:
            dl = tuple(table_vector(d["distortion_left"], 5, f"{where}.distortion_left"))
        if "distortion_right" in d:
            dr = tuple(table_vector(d["distortion_right"], 5, f"{where}.distortion_right"))
        pl = pr = None
        if "principal_offset_px" in d:
            pl = pr = tuple(table_vector(d["principal_offset_px"], 2, f"{where}.principal_offset_px"))
        if "principal_offset_left_px" in d:
            pl = tuple(table_vector(d["principal_offset_left_px"], 2, f"{where}.principal_offset_left_px"))
        if "principal_offset_right_px" in d:
            pr = tuple(table_vector(d["principal_offset_right_px"], 2, f"{where}.principal_offset_right_px"))
        for name, v in (("principal_offset", pl), ("principal_offset", pr)):
            if v is not None and max(abs(x) for x in v) > 100:
                raise ValueError(f"{where}.{name}_px must be within +-100 px, got {v!r}")
        return cls(
            scale=scale,
            supersample=int(ss),
            window_supersample=int(ws),
            window_margin_px=table_number(d, "window_margin_px", 4.0, where, nonneg=True),
            window_arc_px=table_number(d, "window_arc_px", 48.0, where, positive=True),
            frame_subsample=int(fs),
            noise_sigma=table_number(d, "noise_sigma", 2.0, where, nonneg=True),
            distortion_left=dl if dl is not None else _DEFAULT_DIST_LEFT,
            distortion_right=dr if dr is not None else _DEFAULT_DIST_RIGHT,
            principal_offset_left=pl if pl is not None else _DEFAULT_PP_LEFT,
            principal_offset_right=pr if pr is not None else _DEFAULT_PP_RIGHT,
            key_light_azimuth=table_number(d, "key_light_azimuth_deg", 40.0, where) * RAD_PER_DEG,
            key_light_elevation=table_number(d, "key_light_elevation_deg", 25.0, where) * RAD_PER_DEG,
            key_light=table_number(d, "key_light", 0.55, where, nonneg=True),
            key_ambient=table_number(d, "key_ambient", 0.10, where, nonneg=True),
            headlight=table_number(d, "headlight", 0.35, where, nonneg=True),
            ambient=table_number(d, "ambient", 0.12, where, nonneg=True),
        )


@dataclass(frozen=True)
class BoardConfig:
    """The ChArUco board (``docs/formats.md``, ``rig.toml``) and how its views are sampled.

    ``texture_px_per_square``: texels per square of the generated texture (256 gives 0.07 mm texels, about
    one image pixel at 500 mm). ``margin``: white border around the pattern [m]. Views: ``distance_range``
    [m] along the rig axis, tilts up to ``max_tilt`` [rad], in-plane turn up to ``max_roll`` [rad]; a view is
    kept when at least ``min_corners`` interior corners fall inside both images.
    """

    squares_x: int = 11
    squares_y: int = 8
    square: float = 0.018
    marker: float = 0.0135
    dictionary: str = "DICT_5X5_100"
    texture_px_per_square: int = 256
    margin: float = 0.012
    thickness: float = 0.004
    views: int = 24
    distance_range: tuple[float, float] = (0.5, 1.0)
    max_tilt: float = 40 * RAD_PER_DEG
    max_roll: float = 30 * RAD_PER_DEG
    min_corners: int = 20

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "BoardConfig":
        where = "world.board"
        check_keys(d, {"type", "squares_x", "squares_y", "square_mm", "marker_mm", "dictionary",
                        "texture_px_per_square", "margin_mm", "thickness_mm", "views", "distance_min_mm",
                        "distance_max_mm", "max_tilt_deg", "max_roll_deg", "min_corners"}, where)
        if d.get("type", "charuco") != "charuco":
            raise ValueError(f"{where}.type must be 'charuco', got {d.get('type')!r}")
        sx, sy = int(d.get("squares_x", 11)), int(d.get("squares_y", 8))
        if sx < 3 or sy < 3:
            raise ValueError(f"{where}: squares_x/squares_y must be >= 3, got {sx}x{sy}")
        square = table_number(d, "square_mm", 18.0, where, positive=True) * M_PER_MM
        marker = table_number(d, "marker_mm", 13.5, where, positive=True) * M_PER_MM
        if marker >= square:
            raise ValueError(f"{where}.marker_mm must be smaller than square_mm, got {marker / M_PER_MM} >= {square / M_PER_MM}")
        dmin = table_number(d, "distance_min_mm", 500.0, where, positive=True) * M_PER_MM
        dmax = table_number(d, "distance_max_mm", 1000.0, where, positive=True) * M_PER_MM
        if dmax < dmin:
            raise ValueError(f"{where}: distance_max_mm {dmax / M_PER_MM} < distance_min_mm {dmin / M_PER_MM}")
        ppsq = int(d.get("texture_px_per_square", 256))
        if not 16 <= ppsq <= 512:
            raise ValueError(f"{where}.texture_px_per_square must be within 16..512, got {ppsq}")
        return cls(
            squares_x=sx,
            squares_y=sy,
            square=square,
            marker=marker,
            dictionary=str(d.get("dictionary", "DICT_5X5_100")),
            texture_px_per_square=ppsq,
            margin=table_number(d, "margin_mm", 12.0, where, nonneg=True) * M_PER_MM,
            thickness=table_number(d, "thickness_mm", 4.0, where, positive=True) * M_PER_MM,
            views=int(d.get("views", 24)),
            distance_range=(dmin, dmax),
            max_tilt=table_number(d, "max_tilt_deg", 40.0, where, nonneg=True) * RAD_PER_DEG,
            max_roll=table_number(d, "max_roll_deg", 30.0, where, nonneg=True) * RAD_PER_DEG,
            min_corners=int(d.get("min_corners", 20)),
        )


@dataclass(frozen=True)
class PlateConfig:
    """Manufacturing error of the true plate: seeded Gaussian 6-DOF mounting error (1 sigma per axis,
    ``translation_sigma`` [m], ``rotation_sigma`` [rad]), folded into the true ``tool2flange``; optional
    explicit error ``error_pose6`` ``(6,)`` (SI) added on top; ``sphere_sigma`` [m] moves each sphere
    independently (breaks the rigid nominal plate; 0 by default)."""

    translation_sigma: float = 0.05e-3
    rotation_sigma: float = 0.05 * RAD_PER_DEG
    error_pose6: np.ndarray = field(default_factory=lambda: np.zeros(6))
    sphere_sigma: float = 0.0

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "PlateConfig":
        where = "world.plate"
        check_keys(d, {"translation_sigma_mm", "rotation_sigma_deg", "error", "sphere_sigma_mm"}, where)
        err = np.zeros(6)
        if "error" in d:
            e = d["error"]
            check_keys(e, {"x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg"}, f"{where}.error")
            err = np.array([float(e.get(k, 0.0)) for k in ("x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg")])
            err = err * np.array([M_PER_MM] * 3 + [RAD_PER_DEG] * 3)
        return cls(
            translation_sigma=table_number(d, "translation_sigma_mm", 0.05, where, nonneg=True) * M_PER_MM,
            rotation_sigma=table_number(d, "rotation_sigma_deg", 0.05, where, nonneg=True) * RAD_PER_DEG,
            error_pose6=err,
            sphere_sigma=table_number(d, "sphere_sigma_mm", 0.0, where, nonneg=True) * M_PER_MM,
        )


def errors_from_edge_units(table: Mapping[str, Any], layout: ParameterLayout, where: str) -> dict[str, float]:
    """``{"d1_mm": 0.3, "theta2_deg": -0.1, "base_rx_deg": ...}`` -> SI deviations keyed by parameter name.

    The suffix must match the parameter's unit: ``_mm`` for lengths, ``_deg`` for angles.
    """
    out: dict[str, float] = {}
    for key, v in table.items():
        if key.endswith("_mm"):
            name, scale, unit = key[:-3], M_PER_MM, "m"
        elif key.endswith("_deg"):
            name, scale, unit = key[:-4], RAD_PER_DEG, "rad"
        else:
            raise ValueError(f"{where}.{key}: a deviation needs a unit suffix '_mm' or '_deg'")
        try:
            idx = layout.index(name)
        except ValueError:
            raise ValueError(f"{where}.{key}: unknown parameter {name!r}; known: {', '.join(layout.names)}") from None
        if layout.units[idx] != unit:
            want = "_mm" if layout.units[idx] == "m" else "_deg"
            raise ValueError(f"{where}.{key}: parameter {name!r} is in {layout.units[idx]}, write it as {name}{want}")
        try:
            x = float(v)
        except (TypeError, ValueError):
            raise ValueError(f"{where}.{key} must be a number, got {v!r}") from None
        if not math.isfinite(x):
            raise ValueError(f"{where}.{key} must be finite, got {v!r}")
        out[name] = out.get(name, 0.0) + x * scale
    return out


@dataclass(frozen=True)
class WorldConfig:
    """Everything the world needs to build a twin (SI). See ``docs/formats.md`` ("Campaign configs")."""

    robot: Any = "irb1200"  # a name twin.robots knows, or an inline table as in dataset.toml
    preset: str | None = None
    errors: dict[str, float] = field(default_factory=dict)  # extra deviations, SI, by parameter name
    random_length_sigma: float = 0.0  # [m] seeded Gaussian deviation of every length parameter
    random_angle_sigma: float = 0.0  # [rad] ... of every angle parameter of the chain
    mount_pose6: np.ndarray = field(default_factory=lambda: np.zeros(6))  # nominal base2world (SI)
    plate: PlateConfig = field(default_factory=PlateConfig)
    rig: RigConfig = field(default_factory=RigConfig)
    stations: tuple[StationConfig, ...] = field(default_factory=default_stations)
    render: RenderConfig = field(default_factory=RenderConfig)
    board: BoardConfig = field(default_factory=BoardConfig)
    effects: tuple[dict, ...] = ()  # effect specs (see twin.world.effects.effect_from_spec)
    seed: int = 0

    @classmethod
    def from_dict(cls, cfg: Mapping[str, Any]) -> "WorldConfig":
        """From the ``[world]`` table, or from a whole config that holds one."""
        if not isinstance(cfg, Mapping):
            raise ValueError(f"world config must be a table, got {type(cfg).__name__}")
        if "world" in cfg and isinstance(cfg["world"], Mapping):
            cfg = cfg["world"]
        where = "world"
        check_keys(cfg, {"robot", "preset", "errors", "random_errors", "mount", "plate", "rig", "stations",
                          "render", "board", "effects", "seed"}, where)
        robot = cfg.get("robot", "irb1200")
        if isinstance(robot, str) and robot not in ROBOTS:
            raise ValueError(f"world.robot: unknown robot name {robot!r}; known: {', '.join(sorted(ROBOTS))}")
        if not isinstance(robot, (str, Mapping)):
            raise ValueError(f"world.robot must be a robot name or a table, got {robot!r}")
        preset = cfg.get("preset")
        if preset is not None:
            if preset not in PRESETS:
                raise ValueError(f"world.preset: unknown preset {preset!r}; known: {', '.join(sorted(PRESETS))}")
            robot_name = robot if isinstance(robot, str) else robot.get("name")
            if robot_name != preset_robot(preset):
                raise ValueError(
                    f"world.preset {preset!r} applies to robot {preset_robot(preset)!r}, not {robot_name!r}"
                )
        nominal = nominal_robot_from_spec(robot)
        if nominal.convention in ("mdh", "dh") and nominal.n_joints != 6:
            raise ValueError(f"world.robot: the twin's world builds 6-joint DH arms; this table has {nominal.n_joints} "
                             "joints (a dataset.toml may hold a DH table of any length)")
        errors = errors_from_edge_units(cfg.get("errors", {}) or {}, nominal.layout, "world.errors")
        rnd = cfg.get("random_errors", {}) or {}
        check_keys(rnd, {"length_sigma_mm", "angle_sigma_deg"}, "world.random_errors")
        mount = cfg.get("mount", {}) or {}
        check_keys(mount, {"x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg"}, "world.mount")
        mount6 = np.array([float(mount.get(k, 0.0)) for k in ("x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg")])
        mount6 = mount6 * np.array([M_PER_MM] * 3 + [RAD_PER_DEG] * 3)
        stations_raw = cfg.get("stations")
        if stations_raw is None:
            stations = default_stations()
        else:
            if not isinstance(stations_raw, list) or not stations_raw:
                raise ValueError("world.stations must be a non-empty array of tables ([[world.stations]])")
            stations = tuple(StationConfig.from_dict(s, i) for i, s in enumerate(stations_raw))
            names = [s.name for s in stations]
            if len(set(names)) != len(names):
                raise ValueError(f"world.stations: station names must be unique, got {names}")
        effects = cfg.get("effects", []) or []
        if not isinstance(effects, list) or not all(isinstance(e, Mapping) for e in effects):
            raise ValueError("world.effects must be an array of tables ([[world.effects]] with a 'type')")
        try:
            seed = int(cfg.get("seed", 0))
        except (TypeError, ValueError):
            raise ValueError(f"world.seed must be an integer, got {cfg.get('seed')!r}") from None
        return cls(
            robot=robot if isinstance(robot, str) else dict(robot),
            preset=preset,
            errors=errors,
            random_length_sigma=table_number(rnd, "length_sigma_mm", 0.0, "world.random_errors", nonneg=True) * M_PER_MM,
            random_angle_sigma=table_number(rnd, "angle_sigma_deg", 0.0, "world.random_errors", nonneg=True) * RAD_PER_DEG,
            mount_pose6=mount6,
            plate=PlateConfig.from_dict(cfg.get("plate", {}) or {}),
            rig=RigConfig.from_dict(cfg.get("rig", {}) or {}),
            stations=stations,
            render=RenderConfig.from_dict(cfg.get("render", {}) or {}),
            board=BoardConfig.from_dict(cfg.get("board", {}) or {}),
            effects=tuple(dict(e) for e in effects),
            seed=seed,
        )

    def deviation(self, nominal: RobotModel) -> np.ndarray:
        """Total injected deviation ``(P,)`` (SI): preset + explicit errors + seeded random errors."""
        layout = nominal.layout
        dev = np.zeros(layout.size)
        if self.preset is not None:
            for k, v in preset_deviation(self.preset).items():
                dev[layout.index(k)] += v
        for k, v in self.errors.items():
            dev[layout.index(k)] += v
        if self.random_length_sigma > 0 or self.random_angle_sigma > 0:
            rng = np.random.default_rng([self.seed, 1])
            chain = np.array([not n.startswith(("base_", "tool_")) for n in layout.names])
            sig = np.where(layout.is_length, self.random_length_sigma, self.random_angle_sigma)
            dev += np.where(chain, rng.normal(size=layout.size) * sig, 0.0)
        return dev


def nominal_robot_from_spec(spec: Any) -> RobotModel:
    """Nominal :class:`RobotModel` from a robot name or an inline table (same schema as ``dataset.toml``)."""
    from ..dataset import robot_from_spec

    return robot_from_spec(spec, where="world.robot")


def load_world_config(path: str | os.PathLike) -> WorldConfig:
    """Read a TOML file holding a ``[world]`` table (a campaign config or ``experiments/world_default.toml``)."""
    path = Path(path)
    data = read_toml(path, missing="world config file not found")
    try:
        return WorldConfig.from_dict(data)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
