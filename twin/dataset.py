"""The measured dataset: the seam between the instrument and the estimator (``docs/formats.md``).

The one reader (:func:`read_dataset`) and the one writer (:func:`write_dataset`, :class:`DatasetWriter`)
of the dataset folder (``poses.csv`` + ``dataset.toml``), and of ``JOINTS.csv``
(:func:`read_joints_csv` / :func:`write_joints_csv`). Everything here could come from a real robot:
nothing reads truth. Inside, units are SI; the files hold millimetres and degrees (the marker columns may be
declared in metres in ``dataset.toml``).

A row holds the commanded joints of the dataset's robot (``q1..q6`` for the 6R conventions, the joint names of
any other chain; degrees for revolute joints, millimetres for prismatic ones) and K >= 1 points of one rigid
body (the plate's three spheres, a motion-capture body's markers, one reflector) and/or a 6-DOF pose.

The dataset's types (the columns, :class:`Plate`, :class:`Dataset`, :class:`DatasetError`, :func:`robot_from_spec`)
are :mod:`twin.dataset_types`', re-exported here.
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from .files import (check_pose_id, check_readings, check_row_width, columns_beyond_joints, duplicate_names, open_text, parse_finite,
                    read_toml, separator_hint)
from .dataset_types import (JOINT_COLUMNS, LENGTH_UNITS, OPTIONAL_COLUMNS, POSE_COLUMNS, SCHEMA_VERSION, SETS,
                            SPHERE_COLUMNS, Dataset, DatasetError, Plate, default_plate, joint_columns, marker_columns,
                            robot_from_spec)
from .kinematics import RobotModel
from .transforms import pose6_to_transform, transform_to_pose6
from .units import M_PER_MM, RAD_PER_DEG

__all__ = [
    "SCHEMA_VERSION",
    "SPHERE_COLUMNS",
    "POSE_COLUMNS",
    "OPTIONAL_COLUMNS",
    "JOINT_COLUMNS",
    "Plate",
    "Dataset",
    "DatasetError",
    "DatasetWriter",
    "PoseRow",
    "default_plate",
    "read_dataset",
    "write_dataset",
    "write_dataset_toml",
    "read_joints_csv",
    "write_joints_csv",
    "robot_from_spec",
    "marker_columns",
    "joint_columns",
    "LENGTH_UNITS",
    "NOISE_KEYS",
    "read_noise_table",
    "temperature_gaps",
]


def temperature_gaps(temp_c: np.ndarray | None, pose_id: np.ndarray) -> str:
    """Words naming the rows without a temperature (NaN in ``temp_c`` ``(n,)`` [degC]: an empty ``temp_c`` cell)
    by their ``pose_id``, empty when every row has one or there is no temperature at all. What reads the
    temperature of every row refuses with them."""
    if temp_c is None:
        return ""
    gap = np.flatnonzero(np.isnan(np.asarray(temp_c, dtype=float)))
    if not gap.size:
        return ""
    ids = [int(x) for x in np.asarray(pose_id)[gap[:20]]]
    return (f"column 'temp_c' is empty in {gap.size} of {np.size(temp_c)} rows (pose_id {ids}"
            f"{' ...' if gap.size > 20 else ''})")


# ------------------------------------------------------------------------------------------------
# Reading
# ------------------------------------------------------------------------------------------------

def _parse_float(text: str, file: str, row: int, pid: str, col: str) -> float:
    return parse_finite(text, f"{file}: row {row} (pose_id {pid}), column {col!r}", DatasetError)


NOISE_KEYS = ("position_mm", "orientation_rad")  # the keys of a [noise] table (dataset.toml, a column map)
# the largest noise a [noise] table may state, per key: 1 m and 1 rad, far beyond any instrument a calibration can use
# (a value beyond is a unit or typing error: its weights would vanish)
NOISE_MAX = {"position_mm": 1000.0, "orientation_rad": 1.0}


def read_noise_table(table: Any, where: str) -> tuple[float | None, float | None]:
    """The instrument's 1-sigma noise stated by a ``[noise]`` table (``dataset.toml``, a column map):
    ``(position [m], orientation [rad])`` from ``position_mm`` and ``orientation_rad``, None where the table does not
    state it (``table`` None or empty: neither). ``DatasetError`` naming ``where`` and the key for a key of another
    name, a value that is not a positive finite number, or one beyond ``NOISE_MAX``."""
    if table is None:
        return None, None
    if not isinstance(table, dict):
        raise DatasetError(f"{where}: [noise] must be a table ({', '.join(NOISE_KEYS)}), got {table!r}")
    unknown = sorted(set(table) - set(NOISE_KEYS))
    if unknown:
        raise DatasetError(f"{where}: [noise]: unknown key(s) {unknown}; known: {sorted(NOISE_KEYS)}")
    for k, v in table.items():
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not (math.isfinite(v) and v > 0):
            raise DatasetError(f"{where}: noise.{k}: must be a positive number, got {v!r}")
        if v > NOISE_MAX[k]:
            raise DatasetError(f"{where}: noise.{k}: {v!r} is beyond any instrument's noise (at most {NOISE_MAX[k]:g}): "
                               "a unit or typing error?")
    position = float(table["position_mm"]) * M_PER_MM if "position_mm" in table else None
    orientation = float(table["orientation_rad"]) if "orientation_rad" in table else None
    return position, orientation


_TOML_KEYS = {"schema_version", "robot", "provenance", "plate", "markers", "noise", "stations", "tool"}


def _read_toml(path: Path) -> dict:
    meta = read_toml(path, DatasetError, missing="missing (a dataset folder holds poses.csv and dataset.toml)")
    version = meta.get("schema_version", SCHEMA_VERSION)
    if version != SCHEMA_VERSION:
        raise DatasetError(f"{path}: schema_version {version!r} is not supported (this library reads {SCHEMA_VERSION})")
    unknown = sorted(set(meta) - _TOML_KEYS)
    if unknown:  # a misspelt table ([station.0], [nosie]) would be ignored
        raise DatasetError(f"{path}: unknown key(s) or table(s) {unknown}; dataset.toml holds {sorted(_TOML_KEYS)}")
    return meta


def _plate_from_meta(meta: dict, where: str) -> tuple[Plate, str]:
    """The marker set (``[plate]`` or ``[markers]``) and the unit of the marker/pose columns of poses.csv."""
    if "plate" in meta and "markers" in meta:
        raise DatasetError(f"{where}: give either [plate] or [markers], not both")
    if "markers" in meta:
        tab, what, key, dkey = meta["markers"], "[markers]", "points_mm", "diameter_mm"
    else:
        tab, what, key, dkey = meta.get("plate"), "[plate]", "spheres_mm", "sphere_diameter_mm"
    if not isinstance(tab, dict):
        raise DatasetError(f"{where}: missing table [plate] (sphere_diameter_mm, spheres_mm) or [markers] (points_mm, unit)")
    diam = 0.0
    if dkey in tab or what == "[plate]":
        try:
            diam = float(tab[dkey]) * M_PER_MM
        except KeyError:
            raise DatasetError(f"{where}: {what} lacks field {dkey!r}") from None
        except (TypeError, ValueError):
            raise DatasetError(f"{where}: {what} {dkey} is not a number: {tab[dkey]!r}") from None
    if key not in tab:
        raise DatasetError(f"{where}: {what} lacks field {key!r} (nominal points in the flange frame)")
    try:
        s = np.asarray(tab[key], dtype=float)
    except (TypeError, ValueError):
        raise DatasetError(f"{where}: {what} {key} must be triples of numbers, got {tab[key]!r}") from None
    if s.ndim != 2 or s.shape[1] != 3 or s.shape[0] < 1 or not np.all(np.isfinite(s)):
        raise DatasetError(f"{where}: {what} {key} must be one or more triples of finite numbers, got {tab[key]!r}")
    if what == "[plate]" and not (math.isfinite(diam) and diam > 0):
        raise DatasetError(f"{where}: [plate] sphere_diameter_mm must be positive, got {tab[dkey]!r}")
    if not (math.isfinite(diam) and diam >= 0):
        raise DatasetError(f"{where}: {what} {dkey} must be >= 0, got {tab[dkey]!r}")
    unit = tab.get("unit", "mm")
    if unit not in LENGTH_UNITS:
        raise DatasetError(f"{where}: {what} unit must be one of {sorted(LENGTH_UNITS)} (the unit of the marker and "
                           f"pose position columns of poses.csv), got {unit!r}")
    return Plate(diam, s * M_PER_MM), str(unit)


def _pose6_mm_to_transform(d: dict, where: str) -> np.ndarray:
    try:
        v = np.array(
            [d["x_mm"] * M_PER_MM, d["y_mm"] * M_PER_MM, d["z_mm"] * M_PER_MM, d["rx_rad"], d["ry_rad"], d["rz_rad"]], dtype=float
        )
    except (KeyError, TypeError) as exc:
        raise DatasetError(f"{where}: needs x_mm, y_mm, z_mm, rx_rad, ry_rad, rz_rad ({exc})") from None
    return pose6_to_transform(v)


def _transform_to_pose6_mm(T: np.ndarray) -> dict:
    v = transform_to_pose6(T)
    return {
        "x_mm": float(v[0] / M_PER_MM), "y_mm": float(v[1] / M_PER_MM), "z_mm": float(v[2] / M_PER_MM),
        "rx_rad": float(v[3]), "ry_rad": float(v[4]), "rz_rad": float(v[5]),
    }


@dataclass(frozen=True)
class _Meta:
    """What ``dataset.toml`` says, in SI: the robot (with its nominal tool), the marker set, the noise, the
    stations' nominal ``base2meas``."""

    raw: dict
    robot: RobotModel
    plate: Plate
    length_unit: str
    noise_position: float | None
    noise_orientation: float | None
    stations_base2meas: dict[str, np.ndarray]


@dataclass(frozen=True)
class _Columns:
    """The columns of a ``poses.csv`` header, checked against the robot and the marker set."""

    file: str
    index: dict[str, int]
    joints: tuple[str, ...]
    joint_scale: list[float]  # [m/mm] or [rad/deg] per joint
    markers: tuple[str, ...]
    n_points: int
    has_markers: bool
    has_pose: bool
    optional: tuple[str, ...]
    extra: tuple[str, ...]

    def cell(self, r: list[str], c: str) -> str:
        i = self.index[c]
        return r[i].strip() if i < len(r) else ""


@dataclass
class _Rows:
    """The cells of the data rows, read and checked: joints and measurements in SI, the other columns as text."""

    pose_id: np.ndarray
    q: np.ndarray
    spheres: np.ndarray
    seen: np.ndarray
    pose: np.ndarray
    pose_seen: np.ndarray
    optional: dict[str, list[str]]
    extra: dict[str, list[str]]


def read_dataset(folder: str | os.PathLike, *, max_rows_without_spheres: float = 0.5) -> Dataset:
    """Read and validate a dataset folder. Errors are :class:`DatasetError` naming file, row and column.

    ``max_rows_without_spheres``: largest fraction of rows that may lack one or more spheres (and a pose)
    before the dataset is refused as unusable.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise DatasetError(f"{folder}: not a dataset folder (expected poses.csv and dataset.toml inside)")
    meta = _read_meta(folder)
    header, rows = _read_csv_table(folder / "poses.csv")
    cols = _check_columns(str(folder / "poses.csv"), header, meta.robot, meta.plate)
    if not rows:
        raise DatasetError(f"{cols.file}: no data rows")
    data = _read_rows(cols, rows, LENGTH_UNITS[meta.length_unit], meta.robot.n_joints)
    _check_measured_rows(cols, data, max_rows_without_spheres)
    opt = _optional_arrays(cols.file, data)
    return Dataset(
        robot=meta.robot,
        robot_spec=meta.raw["robot"],
        plate=meta.plate,
        pose_id=data.pose_id,
        q=data.q,
        spheres=data.spheres,
        sphere_seen=data.seen,
        pose=data.pose,
        pose_seen=data.pose_seen,
        **opt,
        extra={c: np.array(v, dtype=object) for c, v in data.extra.items()},
        noise_position=meta.noise_position,
        noise_orientation=meta.noise_orientation,
        stations_base2meas=meta.stations_base2meas,
        provenance=str(meta.raw.get("provenance", "")),
        path=folder,
        length_unit=meta.length_unit,
    )


def _read_meta(folder: Path) -> _Meta:
    """``dataset.toml`` of ``folder``: the robot (and its ``[tool]``), the marker set, ``[noise]``, the stations."""
    toml_path = folder / "dataset.toml"
    meta = _read_toml(toml_path)
    if "robot" not in meta:
        raise DatasetError(f"{toml_path}: missing field 'robot' (a robot name or an inline table)")
    robot = robot_from_spec(meta["robot"], str(toml_path), base_dir=folder)
    tool = meta.get("tool")
    if tool is not None:
        if not isinstance(tool, dict) or not isinstance(tool.get("tool2flange"), dict):
            raise DatasetError(f"{toml_path}: [tool] must hold tool2flange = {{ x_mm, y_mm, z_mm, rx_rad, ry_rad, rz_rad }} "
                               f"(the nominal tool frame in the flange frame), got {tool!r}")
        robot = robot.with_frames(tool2flange=_pose6_mm_to_transform(tool["tool2flange"], f"{toml_path}: [tool].tool2flange"))
    plate, length_unit = _plate_from_meta(meta, str(toml_path))
    noise_position, noise_orientation = read_noise_table(meta.get("noise"), str(toml_path))
    stations_b2m = {}
    for sid, st in (meta.get("stations") or {}).items():
        if isinstance(st, dict) and "base2meas" in st:
            stations_b2m[str(sid)] = _pose6_mm_to_transform(st["base2meas"], f"{toml_path}: [stations.{sid}].base2meas")
    return _Meta(meta, robot, plate, length_unit, noise_position, noise_orientation, stations_b2m)


def _read_csv_table(csv_path: Path) -> tuple[list[str], list[list[str]]]:
    """The header (stripped) and the non-blank rows of ``poses.csv``."""
    if not csv_path.exists():
        raise DatasetError(f"{csv_path}: missing (a dataset folder holds poses.csv and dataset.toml)")
    with open_text(csv_path, DatasetError) as f:
        reader = csv.reader(f)
        try:
            header = [h.strip() for h in next(reader)]
        except StopIteration:
            raise DatasetError(f"{csv_path}: empty file (no header row)") from None
        rows = [r for r in reader if any(c.strip() for c in r)]
    return header, rows


def _check_columns(file: str, header: list[str], robot: RobotModel, plate: Plate) -> _Columns:
    """The header's columns: no duplicate, the robot's joints, the marker set's points and/or a whole pose."""
    col = {h: i for i, h in enumerate(header)}
    if len(col) != len(header):
        dup = sorted({h for h in header if header.count(h) > 1})
        raise DatasetError(f"{file}: duplicate columns {dup}")
    jcols = joint_columns(robot)
    jscale = [M_PER_MM if pr else RAD_PER_DEG for pr in robot.is_prismatic]
    missing = [c for c in ("pose_id",) + jcols if c not in col]
    if missing:
        raise DatasetError(f"{file}: missing required columns {missing} (the joints of robot {robot.name!r}: "
                           f"{', '.join(jcols)}){separator_hint(header)}")
    beyond_joints = columns_beyond_joints(header, jcols)
    if beyond_joints:
        raise DatasetError(f"{file}: columns {beyond_joints} name joints robot {robot.name!r} does not have (its "
                           f"{len(jcols)} joints: {', '.join(jcols)}): joints of another robot?")
    K = plate.n_points
    mcols = marker_columns(K)
    beyond = [h for h in header if h.startswith("p") and h[1:].split("_")[0].isdigit() and h not in mcols]
    if beyond:
        raise DatasetError(f"{file}: columns {beyond[:6]} name marker points beyond the {K} of dataset.toml's marker "
                           "set")
    has_sph_cols = all(c in col for c in mcols)
    has_pose_cols = all(c in col for c in POSE_COLUMNS)
    part_sph = [c for c in mcols if c in col]
    if part_sph and not has_sph_cols:
        raise DatasetError(f"{file}: marker columns incomplete, missing {[c for c in mcols if c not in col]}")
    part_pose = [c for c in POSE_COLUMNS if c in col]
    if part_pose and not has_pose_cols:
        raise DatasetError(f"{file}: pose columns incomplete, missing {[c for c in POSE_COLUMNS if c not in col]}")
    if not (has_sph_cols or has_pose_cols):
        raise DatasetError(f"{file}: no measurement columns: need {mcols[0]}..{mcols[-1]} (markers) or x y z rx ry rz "
                           "(pose)")
    known = set(("pose_id",) + jcols + mcols + POSE_COLUMNS + OPTIONAL_COLUMNS)
    return _Columns(file=file, index=col, joints=jcols, joint_scale=jscale, markers=mcols, n_points=K,
                    has_markers=has_sph_cols, has_pose=has_pose_cols,
                    optional=tuple(c for c in OPTIONAL_COLUMNS if c in col),
                    extra=tuple(h for h in header if h not in known))


def _read_rows(cols: _Columns, rows: list[list[str]], to_m: float, n_joints: int) -> _Rows:
    """Every data row: a unique integer ``pose_id``, the commanded joints (all given), whole marker points and/or a
    whole pose (a row without any says why in ``status``); lengths in [m] by ``to_m``, joints in [rad] / [m]."""
    file, K, mcols = cols.file, cols.n_points, cols.markers
    n = len(rows)
    pose6 = np.full((n, 6), np.nan)  # the poses' x, y, z [m] and rotation vector [rad], for the readings' check
    out = _Rows(pose_id=np.zeros(n, dtype=np.int64), q=np.zeros((n, n_joints)), spheres=np.full((n, K, 3), np.nan),
                seen=np.zeros((n, K), dtype=bool), pose=np.full((n, 4, 4), np.nan), pose_seen=np.zeros(n, dtype=bool),
                optional={c: [] for c in cols.optional}, extra={c: [] for c in cols.extra})
    opt, seen_ids = out.optional, {}
    for k, r in enumerate(rows):
        rown = k + 1
        pid_txt = cols.cell(r, "pose_id")
        check_row_width(list(cols.index), r, f"{file}: row {rown} (pose_id {pid_txt})", DatasetError)
        try:
            pid = int(pid_txt)
        except ValueError:
            raise DatasetError(f"{file}: row {rown}, column 'pose_id': not an integer: {pid_txt!r}") from None
        check_pose_id(pid, pid_txt, f"{file}: row {rown}, column 'pose_id'", DatasetError)
        if pid in seen_ids:
            raise DatasetError(f"{file}: row {rown}, column 'pose_id': duplicate id {pid} (first in row {seen_ids[pid]})")
        seen_ids[pid] = rown
        out.pose_id[k] = pid
        for j, c in enumerate(cols.joints):
            t = cols.cell(r, c)
            if t == "":
                raise DatasetError(f"{file}: row {rown} (pose_id {pid}), column {c!r}: empty (commanded joints are required)")
            out.q[k, j] = _parse_float(t, file, rown, str(pid), c) * cols.joint_scale[j]
        if cols.has_markers:
            for s in range(K):
                cs = mcols[3 * s:3 * s + 3]
                texts = [cols.cell(r, c) for c in cs]
                if all(t == "" for t in texts):
                    continue
                if any(t == "" for t in texts):
                    empty = [c for c, t in zip(cs, texts) if t == ""]
                    raise DatasetError(f"{file}: row {rown} (pose_id {pid}), columns {empty}: point p{s} is partly empty")
                out.spheres[k, s] = [_parse_float(t, file, rown, str(pid), c) * to_m for t, c in zip(texts, cs)]
                out.seen[k, s] = True
        if cols.has_pose:
            texts = [cols.cell(r, c) for c in POSE_COLUMNS]
            if any(t != "" for t in texts):
                if any(t == "" for t in texts):
                    empty = [c for c, t in zip(POSE_COLUMNS, texts) if t == ""]
                    raise DatasetError(f"{file}: row {rown} (pose_id {pid}), columns {empty}: pose is partly empty")
                v = [_parse_float(t, file, rown, str(pid), c) for t, c in zip(texts, POSE_COLUMNS)]
                pose6[k] = [v[0] * to_m, v[1] * to_m, v[2] * to_m, v[3], v[4], v[5]]
                out.pose[k] = pose6_to_transform(pose6[k])
                out.pose_seen[k] = True
        for c in opt:
            opt[c].append(cols.cell(r, c))
        for c in out.extra:
            out.extra[c].append(cols.cell(r, c))
        if not out.seen[k].any() and not out.pose_seen[k] and (not opt.get("status") or opt["status"][-1] == ""):
            raise DatasetError(
                f"{file}: row {rown} (pose_id {pid}): no measurement and no 'status' saying why"
            )
    check_readings(((out.q, lambda j: cols.joints[j], lambda j: cols.joint_scale[j]),
                     (out.spheres, lambda s, a: mcols[3 * s + a], lambda s, a: to_m),
                     (pose6, lambda j: POSE_COLUMNS[j], lambda j: to_m if j < 3 else 1.0)),
                   lambda k: f"{file}: row {k + 1} (pose_id {int(out.pose_id[k])})", DatasetError)
    return out


def _check_measured_rows(cols: _Columns, data: _Rows, max_rows_without_spheres: float) -> None:
    """Refuse a marker dataset where more than ``max_rows_without_spheres`` of the rows lack a point and a pose."""
    incomplete = ~(data.seen.all(axis=1) | data.pose_seen)
    if cols.has_markers and incomplete.mean() > max_rows_without_spheres:
        K = cols.n_points
        raise DatasetError(
            f"{cols.file}: {int(incomplete.sum())} of {incomplete.size} rows have fewer than "
            f"{'three spheres' if K == 3 else f'{K} marker points'} and no pose "
            f"(more than {max_rows_without_spheres:.0%}); check the instrument's 'status' column"
        )


def _optional_arrays(file: str, data: _Rows) -> dict[str, np.ndarray | None]:
    """The optional columns as the dataset's arrays (None where absent), checked in the order ``set``, ``pair``,
    ``temp_c``, ``t_s``: a ``set`` of calibration/validation, an integer ``pair``, finite temperatures (an empty
    ``temp_c`` cell: none recorded for the row, NaN) and times."""
    opt, pose_id, n = data.optional, data.pose_id, data.pose_id.size

    def floats(c: str) -> np.ndarray | None:
        if c not in opt:
            return None
        out = np.full(n, np.nan)
        for k, t in enumerate(opt[c]):
            if t == "" and c == "temp_c":  # no temperature recorded for this row: NaN (see check_temperature)
                continue
            if t == "":
                raise DatasetError(f"{file}: row {k + 1} (pose_id {pose_id[k]}), column {c!r}: empty")
            out[k] = _parse_float(t, file, k + 1, str(pose_id[k]), c)
        return out

    set_arr = None
    if "set" in opt:
        for k, t in enumerate(opt["set"]):
            if t not in SETS:
                raise DatasetError(
                    f"{file}: row {k + 1} (pose_id {pose_id[k]}), column 'set': {t!r} is not one of {list(SETS)}"
                )
        set_arr = np.array(opt["set"], dtype=object)
    pair = None
    if "pair" in opt:
        pair = np.full(n, -1, dtype=np.int64)
        for k, t in enumerate(opt["pair"]):
            if t == "":
                continue
            try:
                pair[k] = int(t)
            except ValueError:
                raise DatasetError(f"{file}: row {k + 1} (pose_id {pose_id[k]}), column 'pair': not an integer: {t!r}") from None
    station = None
    if "station" in opt:
        station = np.array([t if t != "" else "0" for t in opt["station"]], dtype=object)
    return {"set": set_arr, "station": station, "pair": pair, "temp_c": floats("temp_c"), "t_s": floats("t_s"),
            "status": np.array(opt["status"], dtype=object) if "status" in opt else None}


# ------------------------------------------------------------------------------------------------
# Writing
# ------------------------------------------------------------------------------------------------

def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        x = float(v)
        if not math.isfinite(x):
            raise ValueError(f"cannot write non-finite number {x!r} to TOML")
        return repr(x)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def write_dataset_toml(
    folder: str | os.PathLike,
    robot_spec: Any,
    plate: Plate,
    *,
    noise_position: float | None = None,
    noise_orientation: float | None = None,
    stations_base2meas: dict[str, np.ndarray] | None = None,
    provenance: str = "",
    length_unit: str = "mm",
    tool2flange: np.ndarray | None = None,
) -> Path:
    """Write ``dataset.toml`` (SI in, mm/deg out). The twin's plate (three spheres, columns in millimetres) is
    written as ``[plate]``, any other marker set as ``[markers]`` with ``length_unit``, the unit of the marker and
    pose position columns of poses.csv. ``tool2flange`` ``(4, 4)``: the nominal tool frame (the frame of a
    measured 6-DOF pose; the marker points' frame) in the flange frame, written as ``[tool]`` when given."""
    if length_unit not in LENGTH_UNITS:
        raise ValueError(f"length_unit must be one of {sorted(LENGTH_UNITS)}, got {length_unit!r}")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    lines = [f"schema_version = {SCHEMA_VERSION}"]
    if isinstance(robot_spec, str):
        lines.append(f"robot = {_toml_value(robot_spec)}")
    lines.append(f"provenance = {_toml_value(provenance)}")
    if isinstance(robot_spec, dict):
        lines += ["", "[robot]"] + [f"{k} = {_toml_value(v)}" for k, v in robot_spec.items()]
    if plate.n_points == 3 and plate.sphere_diameter > 0 and length_unit == "mm":
        lines += [
            "",
            "[plate]",
            f"sphere_diameter_mm = {_toml_value(plate.sphere_diameter / M_PER_MM)}",
            f"spheres_mm = {_toml_value([[round(float(x) / M_PER_MM, 9) for x in s] for s in plate.spheres_flange])}",
        ]
    else:
        lines += [
            "",
            "[markers]",
            f"unit = {_toml_value(length_unit)}",
            f"diameter_mm = {_toml_value(plate.sphere_diameter / M_PER_MM)}",
            f"points_mm = {_toml_value([[round(float(x) / M_PER_MM, 9) for x in s] for s in plate.spheres_flange])}",
        ]
    if noise_position is not None or noise_orientation is not None:
        lines += ["", "[noise]"]
        if noise_position is not None:
            lines.append(f"position_mm = {_toml_value(noise_position / M_PER_MM)}")
        if noise_orientation is not None:
            lines.append(f"orientation_rad = {_toml_value(noise_orientation)}")
    if tool2flange is not None:
        lines += ["", "[tool]", f"tool2flange = {_toml_value(_transform_to_pose6_mm(np.asarray(tool2flange, float)))}"]
    for sid, T in (stations_base2meas or {}).items():
        lines += ["", f"[stations.{_toml_key(sid)}]", f"base2meas = {_toml_value(_transform_to_pose6_mm(T))}"]
    path = folder / "dataset.toml"
    tmp = path.with_suffix(".toml.tmp")
    tmp.write_text("\n".join(lines) + "\n")
    os.replace(tmp, path)
    return path


def _toml_key(k: str) -> str:
    """``k`` as a TOML key: bare where TOML allows it (ASCII letters, digits, ``_`` and ``-``), else quoted."""
    k = str(k)
    return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else _toml_value(k)


@dataclass
class PoseRow:
    """One measured row, SI units. ``spheres``: K entries (the writer's ``n_points``), each ``(3,)`` [m] or
    ``None`` for a point that was not measured (say why in ``status``); NaN is NOT allowed."""

    pose_id: int
    q: np.ndarray  # (N,) [rad, m for prismatic joints] commanded
    spheres: Sequence[np.ndarray | None] | None = None  # K entries, each (3,) [m] or None
    pose: np.ndarray | None = None  # (4, 4) tool2meas
    set: str | None = None
    station: str | int | None = None
    pair: int | None = None
    temp_c: float | None = None
    t_s: float | None = None
    status: str = ""
    extra: dict[str, str] = field(default_factory=dict)


def _fmt_deg(x: float) -> str:
    """Degrees with 1e-10 deg resolution (2e-12 rad: far below any effect the library models)."""
    return f"{float(x) / RAD_PER_DEG:.10f}"


def _fmt_mm(x: float) -> str:
    return f"{float(x) / M_PER_MM:.6f}"


class DatasetWriter:
    """Streams rows into ``poses.csv`` (header first, one flushed line per row), so that a long campaign
    loses nothing already measured when it stops. Columns are fixed at construction: the joints of ``robot``
    (default ``q1..q6`` in degrees; a prismatic joint in millimetres), ``n_points`` marker points and/or a pose,
    lengths in ``length_unit``."""

    def __init__(
        self,
        folder: str | os.PathLike,
        *,
        spheres: bool = True,
        pose: bool = False,
        optional: Iterable[str] = (),
        extra: Iterable[str] = (),
        append: bool = False,
        robot: RobotModel | None = None,
        n_points: int = 3,
        length_unit: str = "mm",
    ) -> None:
        if length_unit not in LENGTH_UNITS:
            raise ValueError(f"length_unit must be one of {sorted(LENGTH_UNITS)}, got {length_unit!r}")
        if int(n_points) < 1:
            raise ValueError(f"n_points must be at least 1, got {n_points!r}")
        self._jcols = JOINT_COLUMNS if robot is None else joint_columns(robot)
        self._jscale = [RAD_PER_DEG] * 6 if robot is None else [M_PER_MM if p else RAD_PER_DEG for p in robot.is_prismatic]
        self._k = int(n_points)
        self._to_m = LENGTH_UNITS[length_unit]
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        opt = [c for c in OPTIONAL_COLUMNS if c in set(optional)]
        unknown = set(optional) - set(OPTIONAL_COLUMNS)
        if unknown:
            raise ValueError(f"optional: unknown columns {sorted(unknown)}; known: {list(OPTIONAL_COLUMNS)}")
        self.columns = ["pose_id", *self._jcols]
        if spheres:
            self.columns += marker_columns(self._k)
        if pose:
            self.columns += POSE_COLUMNS
        self.columns += opt + [c for c in extra]
        self._spheres, self._pose, self._opt, self._extra = spheres, pose, opt, list(extra)
        self.path = self.folder / "poses.csv"
        if append and self.path.exists():
            with open(self.path, newline="") as f:
                header = next(csv.reader(f), None)
            if header != self.columns:
                raise ValueError(f"{self.path}: existing header {header} differs from {self.columns}")
            self._f = open(self.path, "a", newline="")
        else:
            self._f = open(self.path, "w", newline="")
            self._f.write(",".join(self.columns) + "\n")
            self._f.flush()

    def _fmt_len(self, x: float) -> str:
        return _fmt_mm(x) if self._to_m == M_PER_MM else f"{float(x):.9f}"

    def write(self, row: PoseRow) -> None:
        nj = len(self._jcols)
        q = np.asarray(row.q, dtype=float).reshape(-1)
        if q.shape != (nj,):
            raise ValueError(f"pose_id {row.pose_id}: q must have {nj} values ({', '.join(self._jcols)}), got {q.size}")
        if not np.all(np.isfinite(q)):
            raise ValueError(f"pose_id {row.pose_id}: q must be finite, got {q}")
        cells = [str(int(row.pose_id))] + [f"{float(x) / sc:.10f}" for x, sc in zip(q, self._jscale)]
        if self._spheres:
            sph = list(row.spheres) if row.spheres is not None else [None] * self._k
            if len(sph) != self._k:
                raise ValueError(f"pose_id {row.pose_id}: spheres must have {self._k} entries (None where not seen)")
            for s in sph:
                if s is None:
                    cells += ["", "", ""]
                    continue
                s = np.asarray(s, dtype=float).reshape(3)
                if not np.all(np.isfinite(s)):
                    raise ValueError(f"pose_id {row.pose_id}: a marker point is not finite ({s}); pass None and a status")
                cells += [self._fmt_len(x) for x in s]
        if self._pose:
            if row.pose is None:
                cells += [""] * 6
            else:
                v = transform_to_pose6(np.asarray(row.pose, dtype=float))
                cells += [self._fmt_len(x) for x in v[:3]] + [f"{x:.12f}" for x in v[3:]]
        for c in self._opt:
            v = getattr(row, c)
            if v is None:
                cells.append("")
            elif c == "temp_c" and np.isnan(v):  # no temperature recorded for the row
                cells.append("")
            elif c in ("temp_c", "t_s"):
                cells.append(f"{float(v):.6f}")
            else:
                cells.append(str(v))
        cells += [str(row.extra.get(c, "")) for c in self._extra]
        buf = io.StringIO()
        csv.writer(buf, lineterminator="\n").writerow(cells)
        self._f.write(buf.getvalue())
        self._f.flush()

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()

    def __enter__(self) -> "DatasetWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def write_dataset(folder: str | os.PathLike, ds: Dataset) -> Path:
    """Write a whole :class:`Dataset` (``poses.csv`` + ``dataset.toml``)."""
    folder = Path(folder)
    write_dataset_toml(
        folder,
        ds.robot_spec,
        ds.plate,
        noise_position=ds.noise_position,
        noise_orientation=ds.noise_orientation,
        stations_base2meas=ds.stations_base2meas,
        provenance=ds.provenance,
        length_unit=ds.length_unit,
        tool2flange=None if np.allclose(ds.robot.tool2flange, np.eye(4), rtol=0, atol=1e-15) else ds.robot.tool2flange,
    )
    optional = [c for c in OPTIONAL_COLUMNS if getattr(ds, c) is not None]
    with DatasetWriter(
        folder, spheres=ds.has_spheres or not ds.has_poses, pose=ds.has_poses, optional=optional, extra=list(ds.extra),
        robot=ds.robot, n_points=ds.n_points, length_unit=ds.length_unit,
    ) as w:
        for k in range(ds.n):
            w.write(
                PoseRow(
                    pose_id=int(ds.pose_id[k]),
                    q=ds.q[k],
                    spheres=[ds.spheres[k, s] if ds.sphere_seen[k, s] else None for s in range(ds.n_points)],
                    pose=ds.pose[k] if ds.pose_seen[k] else None,
                    set=None if ds.set is None else ds.set[k],
                    station=None if ds.station is None else ds.station[k],
                    pair=None if ds.pair is None or ds.pair[k] < 0 else int(ds.pair[k]),
                    temp_c=None if ds.temp_c is None else ds.temp_c[k],
                    t_s=None if ds.t_s is None else ds.t_s[k],
                    status="" if ds.status is None else ds.status[k],
                    extra={c: v[k] for c, v in ds.extra.items()},
                )
            )
    return folder


# ------------------------------------------------------------------------------------------------
# JOINTS.csv
# ------------------------------------------------------------------------------------------------

JOINTS_OPTIONAL = ("temp_c", "t_s", "station", "set", "session")


@dataclass(frozen=True)
class Joints:
    """Rows of ``JOINTS.csv``: ``pose_id`` ``(n,)``, ``q`` ``(n, N)`` [rad, m for prismatic joints], optional
    channels."""

    pose_id: np.ndarray
    q: np.ndarray
    temp_c: np.ndarray | None = None
    t_s: np.ndarray | None = None
    station: np.ndarray | None = None
    set: np.ndarray | None = None
    session: np.ndarray | None = None


__all__.append("Joints")


def read_csv_rows(path: str | os.PathLike, required: Sequence[str]) -> tuple[list[str], list[dict[str, str]]]:
    """The header and rows (dicts) of a CSV file with at least one data row and every ``required`` column.

    Raises :class:`DatasetError` naming the file: missing file, missing required columns, no data rows."""
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"{path}: missing")
    with open_text(path, DatasetError) as f:
        lines = [r for r in csv.reader(f)]
    header = [h.strip() for h in lines[0]] if lines else []
    missing = [c for c in required if c not in header]
    if missing:
        raise DatasetError(f"{path}: missing required columns {missing}{separator_hint(header)}")
    dup = duplicate_names(header)
    if dup:
        raise DatasetError(f"{path}: duplicate columns {dup}")
    rows = []
    for k, r in enumerate(r for r in lines[1:] if r):
        check_row_width(header, r, f"{path}: row {k + 1}", DatasetError)
        rows.append({h: (r[i] if i < len(r) else None) for i, h in enumerate(header)})
    if not rows:
        raise DatasetError(f"{path}: no data rows")
    return header, rows


__all__.append("read_csv_rows")


def read_joints_csv(path: str | os.PathLike, robot: RobotModel | None = None) -> Joints:
    """Read ``JOINTS.csv`` (``pose_id``, the joints of ``robot`` (default ``q1..q6``) in degrees (millimetres for
    a prismatic joint), optional ``temp_c, t_s, station, set, session``; an empty ``temp_c`` cell: NaN, no temperature
    recorded for the row)."""
    path = Path(path)
    jcols = JOINT_COLUMNS if robot is None else joint_columns(robot)
    jscale = [RAD_PER_DEG] * 6 if robot is None else [M_PER_MM if p else RAD_PER_DEG for p in robot.is_prismatic]
    header, rows = read_csv_rows(path, ("pose_id",) + tuple(jcols))
    beyond = columns_beyond_joints(header, jcols)
    if beyond:
        raise DatasetError(f"{path}: columns {beyond} name joints the robot does not have (its {len(jcols)} joints: "
                           f"{', '.join(jcols)}): joints of another robot?")
    n = len(rows)
    pid = np.zeros(n, dtype=np.int64)
    q = np.zeros((n, len(jcols)))
    chans: dict[str, list] = {c: [] for c in JOINTS_OPTIONAL if c in header}
    for k, r in enumerate(rows):
        try:
            v = int(r["pose_id"])
        except (TypeError, ValueError):
            raise DatasetError(f"{path}: row {k + 1}, column 'pose_id': not an integer: {r['pose_id']!r}") from None
        pid[k] = check_pose_id(v, r["pose_id"], f"{path}: row {k + 1}, column 'pose_id'", DatasetError)
        for j, c in enumerate(jcols):
            q[k, j] = _parse_float((r[c] or "").strip(), str(path), k + 1, str(pid[k]), c) * jscale[j]
        for c in chans:
            chans[c].append((r[c] or "").strip())
    check_readings(((q, lambda j: jcols[j], lambda j: jscale[j]),),
                   lambda k: f"{path}: row {k + 1} (pose_id {int(pid[k])})", DatasetError)
    if len(set(pid.tolist())) != n:
        ids, counts = np.unique(pid, return_counts=True)
        dup = ids[counts > 1]
        rows_ = (np.flatnonzero(pid == dup[0]) + 1).tolist()
        raise DatasetError(f"{path}: column 'pose_id' has duplicate ids {dup[:10].tolist()}"
                           f"{' ...' if dup.size > 10 else ''} (pose_id {int(dup[0])} in rows {rows_[:10]}); each row "
                           "needs its own id")

    def fl(c):
        if c not in chans:
            return None
        return np.array([np.nan if c == "temp_c" and t == "" else _parse_float(t, str(path), k + 1, str(pid[k]), c)
                         for k, t in enumerate(chans[c])])

    return Joints(
        pose_id=pid,
        q=q,
        temp_c=fl("temp_c"),
        t_s=fl("t_s"),
        station=np.array(chans["station"], dtype=object) if "station" in chans else None,
        set=np.array(chans["set"], dtype=object) if "set" in chans else None,
        session=np.array(chans["session"], dtype=object) if "session" in chans else None,
    )


def write_joints_csv(path: str | os.PathLike, joints: Joints, robot: RobotModel | None = None,
                     extra: dict[str, np.ndarray] | None = None) -> Path:
    """Write ``JOINTS.csv`` from :class:`Joints` (SI in, degrees (millimetres for a prismatic joint) out); the
    joint columns are ``robot``'s (default ``q1..q6``); ``extra``: further numeric columns ``(n,)`` written last as
    given (e.g. ``twin compensate``'s ``miss_mm``; a reader ignores them)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    jcols = JOINT_COLUMNS if robot is None else joint_columns(robot)
    jscale = [RAD_PER_DEG] * 6 if robot is None else [M_PER_MM if p else RAD_PER_DEG for p in robot.is_prismatic]
    if np.shape(joints.q)[1:] != (len(jcols),):
        raise ValueError(f"joints.q must have shape (n, {len(jcols)}) for columns {', '.join(jcols)}, got {np.shape(joints.q)}")
    cols = ["pose_id", *jcols] + [c for c in JOINTS_OPTIONAL if getattr(joints, c) is not None]
    extra = dict(extra or {})
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols + list(extra))
    for k in range(len(joints.pose_id)):
        row = [str(int(joints.pose_id[k]))] + [f"{float(x) / sc:.10f}" for x, sc in zip(joints.q[k], jscale)]
        for c in cols[1 + len(jcols):]:
            v = getattr(joints, c)[k]
            row.append("" if c == "temp_c" and np.isnan(v) else f"{float(v):.6f}" if c in ("temp_c", "t_s") else str(v))
        row += [f"{float(v[k]):.6g}" for v in extra.values()]
        w.writerow(row)
    tmp = path.with_name(f".{path.name}.tmp")  # written whole, then moved: no partial output file
    try:
        tmp.write_text(buf.getvalue())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path
