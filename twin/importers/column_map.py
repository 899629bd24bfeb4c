"""The column map of ``twin import --map`` (``docs/formats.md``, "Column map"): its reader
(:func:`read_column_map`, the parsed :class:`ColumnMap`, :class:`FileMap` and :class:`FileSpec`, a CSV given on the
command line :func:`parse_file_argument`, a frame file :func:`read_frame_file`) and the reading of one CSV through
it (:func:`read_mapped_csv` -> :class:`MappedRows`, in SI).

The import itself (frames on the nominal robot, the dataset folder written) is :mod:`twin.importers.columns`, which
re-exports every name of this module.
"""

from __future__ import annotations

import csv
import io
import datetime as _dt
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..dataset import DatasetError, read_noise_table, robot_from_spec
from ..files import (check_pose_id, check_readings, check_row_width, duplicate_names, parse_finite, read_text, read_toml,
                     separator_hint)
from ..kinematics import RobotModel
from ..transforms import invert_transform, make_transform, pose6_to_transform, quat_wxyz_to_matrix
from ..units import M_PER_MM, RAD_PER_DEG
from .mocap import file_sha256

__all__ = ["MAP_SCHEMA_VERSION", "ColumnMap", "FileSpec", "FileMap", "MappedRows", "read_column_map", "read_mapped_csv",
           "read_frame_file", "parse_file_argument"]

MAP_SCHEMA_VERSION = 1
_LENGTH = {"mm": M_PER_MM, "m": 1.0}
_ANGLE = {"deg": RAD_PER_DEG, "rad": 1.0}
_TOP_KEYS = {"schema_version", "kind", "description", "attribution", "robot", "csv", "joints", "measurement", "time",
             "order", "temperature", "keep", "pose_id", "set", "session", "station", "frames", "noise", "files"}
# what a [[files]] entry (and a CSV given on the command line) may set for its own file
_FILE_KEYS = {"path", "csv", "joints", "measurement", "time", "order", "temperature", "keep", "pose_id", "set",
              "session", "station", "base2meas"}
_SETS = ("calibration", "validation")


# ------------------------------------------------------------------------------------------------
# The parsed map
# ------------------------------------------------------------------------------------------------

Terms = tuple[tuple[float, str], ...]  # a coordinate: sum of sign * column


@dataclass(frozen=True)
class FileMap:
    """How to read one CSV (the map with its file's overrides applied). Columns by header name; ``points``: K
    triples of :data:`Terms` (x, y, z); ``position``/``rotation``: the pose columns (``rotation``: three Euler
    angles of the sequence ``euler``, or with ``quaternion`` (``"xyzw"`` or ``"wxyz"``) a unit quaternion's four
    components in that order); ``time_column`` None for the row order; ``set_rule`` ``("fixed", label)``,
    ``("column", name)`` or ``("last_fraction", F)`` (``set_given``: whether
    the map, the file's entry or the command line gave it; otherwise every row is calibration); ``session``
    and ``station`` ``("fixed", label)``, ``("column", name)`` or None (session: the file's name; station: one
    station ``"0"``)."""

    separator: str
    decimal: str
    header_row: int
    joint_columns: tuple[str, ...]
    joint_scale: tuple[float, ...]
    kind: str
    length_scale: float
    points: tuple[tuple[Terms, Terms, Terms], ...] = ()
    position: tuple[Terms, Terms, Terms] | None = None
    rotation: tuple[str, ...] | None = None
    rotation_scale: float = 1.0
    euler: str = ""
    quaternion: str = ""
    time_column: str | None = None
    time_format: str = ""
    order: str = "file"
    temperature: str | None = None
    keep: tuple[str, ...] = ()
    pose_id: str | None = None
    set_rule: tuple[str, Any] = ("fixed", "calibration")
    set_given: bool = True
    session: tuple[str, str] | None = None
    station: tuple[str, str] | None = None
    base2meas: np.ndarray | None = None
    base2meas_source: str = ""

    @property
    def n_points(self) -> int:
        """K, the points per row (1 for a pose: its origin)."""
        return len(self.points) if self.kind == "points" else 1


@dataclass(frozen=True)
class FileSpec:
    """One CSV of the map (``path``) and how to read it (``map``)."""

    path: Path
    map: FileMap


@dataclass(frozen=True, eq=False)
class ColumnMap:
    """A read column map: the robot (``robot_spec`` as ``dataset.toml`` will hold it, ``robot`` the model,
    ``urdf`` the URDF file to copy beside the dataset or None), the map of its files (``base``), its ``[[files]]``
    (``files``), the nominal ``tool2flange`` ``(4, 4)`` of a pose and the nominal ``points_flange`` ``(K, 3)`` [m]
    of points (None: fitted), the noise (SI), free text, the raw table (``raw``, for per-file overrides) and the
    file's sha256."""

    path: Path
    raw: dict
    robot_spec: Any
    robot: RobotModel
    urdf: Path | None
    base: FileMap
    files: tuple[FileSpec, ...]
    tool2flange: np.ndarray | None = None
    tool2flange_source: str = ""
    points_flange: np.ndarray | None = None
    noise_position: float | None = None
    noise_orientation: float | None = None
    description: str = ""
    attribution: str = ""
    sha256: str = ""

    def for_file(self, path: str | os.PathLike, overrides: dict | None = None) -> FileSpec:
        """The :class:`FileSpec` of a CSV read with this map and ``overrides`` (keys of a ``[[files]]`` entry)."""
        return FileSpec(Path(path), _file_map(self.raw, dict(overrides or {}), self.path, self.robot,
                                              f"{self.path}: {path}"))


def _err(where: str, msg: str) -> DatasetError:
    return DatasetError(f"{where}: {msg}")


QUATERNION_ORDERS = ("xyzw", "wxyz")  # the component orders a map's measurement.quaternion names


def _quaternion_columns(m: dict, rot: Any, where: str) -> dict:
    """The :class:`FileMap` fields of a pose's rotation given as a unit quaternion: ``rotation`` the four columns,
    ``quaternion`` their order (no default: scipy writes ``xyzw``, many trackers ``wxyz``); ``euler`` and
    ``rotation_unit`` do not apply (an error naming them)."""
    order = m["quaternion"]
    if order not in QUATERNION_ORDERS:
        raise _err(f"{where}: measurement.quaternion", f"must be \"xyzw\" or \"wxyz\" (the order of the rotation "
                                                         f"columns' components), got {order!r}")
    if not isinstance(rot, list) or len(rot) != 4 or not all(isinstance(x, str) for x in rot):
        raise _err(f"{where}: measurement.rotation", f"must be the quaternion's four columns in the order {order}, "
                                                     f"got {rot!r}")
    extra = sorted(k for k in ("euler", "rotation_unit") if k in m)
    if extra:
        raise _err(f"{where}: [measurement]", f"{', '.join(extra)} do(es) not apply to a quaternion (quaternion = "
                                              f"{order!r})")
    return {"rotation": tuple(rot), "quaternion": order}


QUATERNION_NORM_TOL = 1e-3  # a quaternion whose norm is further from 1 is not a unit quaternion (a wrong column)


def _quaternion_rotations(values: np.ndarray, fm: "FileMap", path, lines) -> np.ndarray:
    """Rotations ``(n, 3, 3)`` of the quaternions ``values`` ``(n, 4)`` (components in the order ``fm.quaternion``);
    a row whose quaternion's norm is not 1 within :data:`QUATERNION_NORM_TOL` is an error naming the row, the line,
    the columns and the norm."""
    wxyz = values if fm.quaternion == "wxyz" else values[:, [3, 0, 1, 2]]
    norm = np.linalg.norm(wxyz, axis=1)
    bad = np.flatnonzero(~(np.abs(norm - 1.0) <= QUATERNION_NORM_TOL))
    if bad.size:
        k = int(bad[0])
        raise DatasetError(f"{path}: row {k + 1} (line {lines[k]}), columns {', '.join(fm.rotation)}: not a unit "
                           f"quaternion (norm {norm[k]:.6g}; {bad.size} such row(s)): a column other than the "
                           f"quaternion's, or its components in another order than {fm.quaternion!r}?")
    return quat_wxyz_to_matrix(wxyz)


def _check_keys(d: dict, allowed: set[str], where: str) -> None:
    unknown = sorted(set(d) - allowed)
    if unknown:
        raise _err(where, f"unknown key(s) {unknown}; known: {sorted(allowed)}")


def _parse_terms(text: Any, where: str) -> Terms:
    """``"a"``, ``"-a"``, ``"a - b"``, ``"a + b"`` (operators between spaces; column names may hold spaces)."""
    if not isinstance(text, str) or not text.strip():
        raise _err(where, f"must be a column name, or a sum or difference of columns (\"x_t - x_dif\"), got {text!r}")
    parts = re.split(r"\s+([+-])\s+", text.strip())
    terms = []
    sign = 1.0
    first = parts[0]
    if first.startswith("-") and len(first) > 1 and first[1] != " ":
        sign, first = -1.0, first[1:]
    terms.append((sign, first.strip()))
    for op, name in zip(parts[1::2], parts[2::2]):
        if not name.strip():
            raise _err(where, f"an operator without a column in {text!r}")
        terms.append((1.0 if op == "+" else -1.0, name.strip()))
    return tuple(terms)


def _label_rule(v: Any, where: str, *, allow_fraction: bool = False) -> tuple[str, Any] | None:
    if v is None:
        return None
    if isinstance(v, (str, int)) and not isinstance(v, bool):
        return ("fixed", str(v))
    if isinstance(v, dict):
        if allow_fraction and set(v) == {"validation_last_fraction"}:
            f = v["validation_last_fraction"]
            if not isinstance(f, (int, float)) or isinstance(f, bool) or not 0.0 < float(f) < 1.0:
                raise _err(where, f"validation_last_fraction must be a number between 0 and 1, got {f!r}")
            return ("last_fraction", float(f))
        if allow_fraction and set(v) == {"calibration_first_rows"}:
            f = v["calibration_first_rows"]
            if not isinstance(f, int) or isinstance(f, bool) or f < 1:
                raise _err(where, f"calibration_first_rows must be a whole number >= 1, got {f!r}")
            return ("first_rows", int(f))
        if set(v) == {"column"} and isinstance(v["column"], str):
            return ("column", v["column"])
    forms = "a label, { column = \"NAME\" }" + (", { validation_last_fraction = F } or { calibration_first_rows = N }"
                                                if allow_fraction else "")
    raise _err(where, f"must be {forms}, got {v!r}")


def read_frame_file(path: str | os.PathLike, *, unit: str = "mm", where: str = "") -> np.ndarray:
    """A 4x4 homogeneous transform from a text file (16 numbers, whitespace or comma separated, row-major; the
    translation in ``unit``), as it is written. :class:`~twin.dataset.DatasetError` naming the file when it holds
    no 4x4 rigid transform (a last row other than ``0 0 0 1``, a rotation not orthonormal to 1e-5); the rotation
    is re-orthonormalised (SVD) so that later conversions are exact."""
    path = Path(path)
    if not isinstance(unit, str) or unit not in _LENGTH:
        raise _err(where or str(path), f"unit must be one of {sorted(_LENGTH)}, got {unit!r}")
    try:
        text = path.read_text()
    except OSError as exc:
        raise _err(where or str(path), f"cannot read the frame file {path}: {exc.strerror or exc}") from None
    try:
        v = np.array([float(t) for t in re.split(r"[\s,;]+", text.strip()) if t], dtype=float)
    except ValueError as exc:
        raise _err(str(path), f"not a 4x4 matrix of numbers ({exc})") from None
    if v.size != 16 or not np.all(np.isfinite(v)):
        raise _err(str(path), f"holds {v.size} numbers; a 4x4 transform has 16 finite numbers")
    T = v.reshape(4, 4)
    if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-9):
        raise _err(str(path), f"last row is {T[3].tolist()}, not [0, 0, 0, 1]: not a homogeneous transform")
    R = T[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-5 or np.linalg.det(R) < 0:
        raise _err(str(path), "the rotation part is not a rotation (not orthonormal to 1e-5, or a reflection)")
    U, _, Vt = np.linalg.svd(R)
    return make_transform(U @ Vt, T[:3, 3] * _LENGTH[unit])


def _frame(v: Any, where: str, base_dir: Path, directions: tuple[str, str]) -> tuple[np.ndarray, str]:
    """A frame of the map: ``"identity"``, ``{x_mm, y_mm, z_mm, rx_rad, ry_rad, rz_rad}`` or ``{file, unit,
    direction}`` (``direction`` one of ``directions``: the first as written, the second inverted)."""
    if v == "identity":
        return np.eye(4), "identity (given)"
    if isinstance(v, dict) and "file" in v:
        _check_keys(v, {"file", "unit", "direction"}, where)
        if v.get("direction") not in directions:
            raise _err(where, f"direction must be {directions[0]!r} (the file maps {directions[0].split('2')[0]} "
                              f"coordinates into the {directions[0].split('2')[1]} frame) or {directions[1]!r}, "
                              f"got {v.get('direction')!r}")
        p = Path(str(v["file"]))
        p = p if p.is_absolute() else base_dir / p
        T = read_frame_file(p, unit=str(v.get("unit", "mm")), where=where)
        inverted = v["direction"] == directions[1]
        return (invert_transform(T) if inverted else T), (f"{p.name} (sha256 {file_sha256(p)}, "
                                                          f"{'inverted: it holds ' + directions[1] if inverted else 'as written'})")
    if isinstance(v, dict):
        _check_keys(v, {"x_mm", "y_mm", "z_mm", "rx_rad", "ry_rad", "rz_rad"}, where)
        try:
            x = np.array([float(v.get(k, 0.0)) for k in ("x_mm", "y_mm", "z_mm", "rx_rad", "ry_rad", "rz_rad")])
        except (TypeError, ValueError):
            raise _err(where, f"x_mm .. rz_rad must be numbers, got {v!r}") from None
        if not np.all(np.isfinite(x)):
            raise _err(where, f"not finite: {v!r}")
        x[:3] *= M_PER_MM
        return pose6_to_transform(x), "given in the map"
    raise _err(where, f"must be \"identity\", {{ x_mm, y_mm, z_mm, rx_rad, ry_rad, rz_rad }} or {{ file, unit, "
                      f"direction }}, got {v!r}")


def _file_map(raw: dict, over: dict, map_path: Path, robot: RobotModel, where: str) -> FileMap:
    """Parse the per-file settings of the map ``raw`` with ``over`` (a ``[[files]]`` entry) on top."""
    _check_keys(over, _FILE_KEYS, where)
    d = {**raw, **{k: v for k, v in over.items() if k not in ("path", "base2meas")}}
    base_dir = map_path.parent
    # CSV dialect
    c = d.get("csv", {}) or {}
    if not isinstance(c, dict):
        raise _err(f"{where}: [csv]", f"must be a table, got {c!r}")
    _check_keys(c, {"separator", "decimal", "header_row"}, f"{where}: [csv]")
    sep = c.get("separator", ",")
    dec = c.get("decimal", ".")
    if sep == "\\t":
        sep = "\t"
    if not isinstance(sep, str) or len(sep) != 1:
        raise _err(f"{where}: csv.separator", f"must be one character (\",\", \";\", \"\\t\"), got {sep!r}")
    if dec not in (".", ","):
        raise _err(f"{where}: csv.decimal", f"must be \".\" or \",\", got {dec!r}")
    if dec == sep:
        raise _err(f"{where}: csv", f"the decimal mark and the separator are both {sep!r}")
    hr = c.get("header_row", 1)
    if not isinstance(hr, int) or isinstance(hr, bool) or hr < 1:
        raise _err(f"{where}: csv.header_row", f"must be a line number >= 1, got {hr!r}")
    # joints
    j = d.get("joints")
    if not isinstance(j, dict):
        raise _err(where, "missing table [joints] (columns = the joint columns in the robot's order, unit)")
    _check_keys(j, {"columns", "unit"}, f"{where}: [joints]")
    cols = j.get("columns")
    if not isinstance(cols, list) or not all(isinstance(x, str) for x in cols):
        raise _err(f"{where}: joints.columns", f"must be a list of column names, got {cols!r}")
    if len(cols) != robot.n_joints:
        raise _err(f"{where}: joints.columns", f"has {len(cols)} columns for the {robot.n_joints} joints of robot "
                                               f"{robot.name!r} ({', '.join(robot.joint_names)})")
    unit = j.get("unit", "deg")
    units = unit if isinstance(unit, list) else [unit] * robot.n_joints
    if len(units) != robot.n_joints:
        raise _err(f"{where}: joints.unit", f"has {len(units)} units for {robot.n_joints} joints")
    scale = []
    for k, (u, pris) in enumerate(zip(units, robot.is_prismatic)):
        ok = _LENGTH if pris else _ANGLE
        if not isinstance(u, str) or u not in ok:
            raise _err(f"{where}: joints.unit", f"joint {k + 1} ({robot.joint_names[k]}, "
                                                f"{'prismatic' if pris else 'revolute'}) must be in {sorted(ok)}, got {u!r}")
        scale.append(ok[u])
    # measurement
    m = d.get("measurement")
    if not isinstance(m, dict):
        raise _err(where, "missing table [measurement] (kind = \"points\" or \"pose\")")
    kind = m.get("kind")
    lu = m.get("unit", "mm")
    if not isinstance(lu, str) or lu not in _LENGTH:
        raise _err(f"{where}: measurement.unit", f"must be \"mm\" or \"m\", got {lu!r}")
    kw: dict[str, Any] = {}
    if kind == "points":
        _check_keys(m, {"kind", "unit", "points"}, f"{where}: [measurement]")
        pts = m.get("points")
        if not isinstance(pts, list) or not pts:
            raise _err(f"{where}: measurement.points", "must list K >= 1 points, each { x = ..., y = ..., z = ... }")
        parsed = []
        for i, p in enumerate(pts):
            if not isinstance(p, dict) or set(p) != {"x", "y", "z"}:
                raise _err(f"{where}: measurement.points[{i}]", f"must be {{ x = ..., y = ..., z = ... }}, got {p!r}")
            parsed.append(tuple(_parse_terms(p[a], f"{where}: measurement.points[{i}].{a}") for a in "xyz"))
        kw["points"] = tuple(parsed)
    elif kind == "pose":
        _check_keys(m, {"kind", "unit", "position", "rotation", "rotation_unit", "euler", "quaternion"},
                    f"{where}: [measurement]")
        pos, rot = m.get("position"), m.get("rotation")
        if not isinstance(pos, list) or len(pos) != 3:
            raise _err(f"{where}: measurement.position", f"must be the three position columns, got {pos!r}")
        position = tuple(_parse_terms(x, f"{where}: measurement.position[{i}]") for i, x in enumerate(pos))
        if "quaternion" in m:
            kw.update(position=position, **_quaternion_columns(m, rot, where))
        else:
            if not isinstance(rot, list) or len(rot) != 3 or not all(isinstance(x, str) for x in rot):
                raise _err(f"{where}: measurement.rotation", "must be the three Euler-angle columns (or a "
                           f"quaternion's four with quaternion = \"xyzw\" or \"wxyz\"), got {rot!r}")
            ru = m.get("rotation_unit", "deg")
            if not isinstance(ru, str) or ru not in _ANGLE:
                raise _err(f"{where}: measurement.rotation_unit", f"must be \"deg\" or \"rad\", got {ru!r}")
            eu = m.get("euler")
            if not (isinstance(eu, str) and len(eu) == 3 and (set(eu) <= set("xyz") or set(eu) <= set("XYZ"))
                    and eu[0] != eu[1] and eu[1] != eu[2]):
                raise _err(f"{where}: measurement.euler", "must be an Euler sequence of scipy's Rotation.from_euler: "
                                                          "three axes, upper case intrinsic (\"XYZ\"), lower case "
                                                          f"extrinsic (\"xyz\"), no axis twice in a row; got {eu!r}")
            kw.update(position=position, rotation=tuple(rot), rotation_scale=_ANGLE[ru], euler=eu)
    else:
        raise _err(f"{where}: measurement.kind", f"must be \"points\" or \"pose\", got {kind!r}")
    # time and order
    t = d.get("time", "row")
    if t == "row":
        tc, tf = None, ""
    elif isinstance(t, dict) and set(t) == {"column", "format"} and isinstance(t["column"], str) \
            and isinstance(t["format"], str) and t["format"]:
        tc, tf = t["column"], t["format"]
    else:
        raise _err(f"{where}: time", "must be \"row\" (the row order only) or { column = \"NAME\", format = "
                                     f"\"%Y%m%d%H%M%S\" (a strptime format) or \"seconds\" }}, got {t!r}")
    order = d.get("order", "file")
    if order not in ("file", "time"):
        raise _err(f"{where}: order", f"must be \"file\" (the file's row order) or \"time\" (sorted by time), got {order!r}")
    if order == "time" and tc is None:
        raise _err(f"{where}: order", "\"time\" needs a time column (time = { column, format })")
    temp = d.get("temperature")
    if temp is not None and not (isinstance(temp, dict) and set(temp) == {"column"} and isinstance(temp["column"], str)):
        raise _err(f"{where}: temperature", f"must be {{ column = \"NAME\" }} (degrees Celsius), got {temp!r}")
    keep = d.get("keep", [])
    if not isinstance(keep, list) or not all(isinstance(x, str) for x in keep):
        raise _err(f"{where}: keep", f"must be a list of column names, got {keep!r}")
    pid = d.get("pose_id")
    if pid is not None and not (isinstance(pid, dict) and set(pid) == {"column"} and isinstance(pid["column"], str)):
        raise _err(f"{where}: pose_id", f"must be {{ column = \"NAME\" }} (unique integers), got {pid!r}")
    set_rule = _label_rule(d.get("set", "calibration"), f"{where}: set", allow_fraction=True)
    if set_rule[0] == "fixed" and set_rule[1] not in _SETS:
        raise _err(f"{where}: set", f"must be one of {list(_SETS)} (or a column, or {{ validation_last_fraction = F }}), "
                                    f"got {set_rule[1]!r}")
    b2m, b2m_src = None, ""
    fr = over.get("base2meas", (raw.get("frames") or {}).get("base2meas"))
    if fr is not None:
        b2m, b2m_src = _frame(fr, f"{where}: base2meas", base_dir, ("base2meas", "meas2base"))
    return FileMap(
        separator=sep, decimal=dec, header_row=hr, joint_columns=tuple(cols), joint_scale=tuple(scale), kind=kind,
        length_scale=_LENGTH[lu], time_column=tc, time_format=tf, order=order,
        temperature=None if temp is None else temp["column"], keep=tuple(keep),
        pose_id=None if pid is None else pid["column"], set_rule=set_rule, set_given="set" in d,
        session=_label_rule(d.get("session"), f"{where}: session"),
        station=_label_rule(d.get("station"), f"{where}: station"), base2meas=b2m, base2meas_source=b2m_src, **kw)


def read_column_map(path: str | os.PathLike) -> ColumnMap:
    """Read and check a column map (``docs/formats.md``, "Column map"). :class:`~twin.dataset.DatasetError`
    naming the map and the key: unknown keys, a robot the library cannot build, joint columns that do not match
    the robot's joints, a measurement or time that cannot be read, a frame file that holds no rigid transform."""
    path = Path(path)
    raw = read_toml(path, DatasetError, missing="no such column map")
    where = str(path)
    _check_keys(raw, _TOP_KEYS, where)
    if raw.get("schema_version", MAP_SCHEMA_VERSION) != MAP_SCHEMA_VERSION:
        raise _err(where, f"schema_version {raw.get('schema_version')!r} is not supported (this library reads "
                          f"{MAP_SCHEMA_VERSION})")
    if raw.get("kind", "column_map") != "column_map":
        raise _err(where, f"kind must be \"column_map\", got {raw.get('kind')!r}")
    if "robot" not in raw:
        raise _err(where, "missing 'robot' (a robot name, a dataset.toml robot table, or a table with urdf, "
                          "root_link, end_link)")
    spec = raw["robot"]
    urdf = None
    if isinstance(spec, dict) and "urdf" in spec:
        urdf = Path(str(spec["urdf"]))
        urdf = urdf if urdf.is_absolute() else path.parent / urdf
        spec = {**spec, "urdf": urdf.name}
    robot = robot_from_spec(raw["robot"], f"{where}: robot", base_dir=path.parent)
    base = _file_map(raw, {}, path, robot, where)
    fr = raw.get("frames", {}) or {}
    if not isinstance(fr, dict):
        raise _err(f"{where}: [frames]", f"must be a table, got {fr!r}")
    _check_keys(fr, {"base2meas", "tool2flange", "points_mm"}, f"{where}: [frames]")
    tool, tool_src, pts = None, "", None
    if "tool2flange" in fr:
        if base.kind != "pose":
            raise _err(f"{where}: frames.tool2flange", "applies to a 6-DOF pose; points are placed by frames.points_mm")
        tool, tool_src = _frame(fr["tool2flange"], f"{where}: frames.tool2flange", path.parent,
                                ("tool2flange", "flange2tool"))
    if "points_mm" in fr:
        if base.kind != "points":
            raise _err(f"{where}: frames.points_mm", "applies to points; a pose is placed by frames.tool2flange")
        try:
            pts = np.asarray(fr["points_mm"], dtype=float) * M_PER_MM
        except (TypeError, ValueError):
            raise _err(f"{where}: frames.points_mm", f"must be K triples of numbers, got {fr['points_mm']!r}") from None
        if pts.shape != (base.n_points, 3) or not np.all(np.isfinite(pts)):
            raise _err(f"{where}: frames.points_mm", f"must be {base.n_points} triple(s) of finite numbers (one per "
                                                     f"measured point), got {fr['points_mm']!r}")
    noise_position, noise_orientation = read_noise_table(raw.get("noise"), where)
    files = []
    entries = raw.get("files", [])
    if not isinstance(entries, list):
        raise _err(f"{where}: files", "must be an array of tables ([[files]] path = ..., set = ...)")
    for i, e in enumerate(entries):
        if not isinstance(e, dict) or not isinstance(e.get("path"), str):
            raise _err(f"{where}: files[{i}]", f"needs path = \"FILE.csv\" (relative to the map), got {e!r}")
        p = Path(e["path"])
        p = p if p.is_absolute() else path.parent / p
        fm = _file_map(raw, e, path, robot, f"{where}: files[{i}] ({e['path']})")
        if fm.kind != base.kind or fm.n_points != base.n_points:
            raise _err(f"{where}: files[{i}]", "every file must give the same measurement kind and number of points")
        files.append(FileSpec(p, fm))
    for k in ("description", "attribution"):
        if not isinstance(raw.get(k, ""), str):
            raise _err(f"{where}: {k}", f"must be text, got {raw[k]!r}")
    return ColumnMap(path=path, raw=raw, robot_spec=spec, robot=robot, urdf=urdf, base=base, files=tuple(files),
                     tool2flange=tool, tool2flange_source=tool_src, points_flange=pts,
                     noise_position=noise_position, noise_orientation=noise_orientation,
                     description=str(raw.get("description", "")), attribution=str(raw.get("attribution", "")),
                     sha256=file_sha256(path))


def parse_file_argument(text: str) -> tuple[str, dict]:
    """A CSV given on the command line with its own settings: ``PATH[:key=value,key=value]``, keys ``set``
    (``calibration``/``validation``, ``last:F`` for "the last fraction F of the rows is validation", ``first:N`` for
    "the first N rows are calibration, the rest validation"), ``session``, ``station``, ``time`` (``row``) and ``order`` (``file``/``time``). Returns ``(path, overrides)``."""
    m = re.match(r"^(.+?):([A-Za-z_]+=.*)$", text)
    path, opts = (m.group(1), m.group(2)) if m else (text, "")
    over: dict[str, Any] = {}
    for item in [o for o in opts.split(",") if o]:
        k, eq, v = item.partition("=")
        k, v = k.strip(), v.strip()
        if not eq or not v:
            raise ValueError(f"{text}: {item!r} is not key=value")
        if k == "set":
            if v.startswith("first:"):
                try:
                    over["set"] = {"calibration_first_rows": int(v[6:])}
                except ValueError:
                    raise ValueError(f"{text}: set=first:N needs a whole number N, got {v!r}") from None
            elif v.startswith("last:"):
                try:
                    over["set"] = {"validation_last_fraction": float(v[5:])}
                except ValueError:
                    raise ValueError(f"{text}: set=last:F needs a number F, got {v!r}") from None
            else:
                over["set"] = v
        elif k in ("session", "station"):
            over[k] = v
        elif k == "time":
            if v != "row":
                raise ValueError(f"{text}: time=row is the only time a command line can set (a time column goes "
                                 "in the map)")
            over["time"] = "row"
        elif k == "order":
            over["order"] = v
        else:
            raise ValueError(f"{text}: unknown key {k!r}; known: set, session, station, time, order")
    return path, over


# ------------------------------------------------------------------------------------------------
# Reading one CSV
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class MappedRows:
    """One CSV read with its map, in SI, rows in measurement order: ``q`` ``(n, N)`` [rad, m], ``points`` ``(n, K,
    3)`` [m] (a pose: its position as the one point) and ``rot`` ``(n, 3, 3)`` or None, ``t`` ``(n,)`` [s] (time
    stamps; None for the row order), ``temp_c``, ``pose_id``, ``set``, ``session``, ``station`` ``(n,)``, the kept
    columns (text with ``.`` decimals), the file line of every row (``lines``), the file's sha256 and ``notes``."""

    path: Path
    q: np.ndarray
    points: np.ndarray
    rot: np.ndarray | None
    t: np.ndarray | None
    temp_c: np.ndarray | None
    pose_id: np.ndarray | None
    set: np.ndarray
    session: np.ndarray
    station: np.ndarray | None
    keep: dict[str, list[str]]
    lines: np.ndarray
    sha256: str
    notes: tuple[str, ...] = ()

    @property
    def n(self) -> int:
        return int(self.q.shape[0])


def _number(text: str, dec: str, where: str) -> float:
    t = text.strip()
    if t == "":
        raise DatasetError(f"{where}: empty")
    other = "," if dec == "." else "."
    if other in t:
        raise DatasetError(f"{where}: {t!r} holds {other!r} where the map's decimal mark is {dec!r}")
    return parse_finite(t, where, DatasetError, decimal=dec)


def _time_value(text: str, fmt: str, dec: str, where: str) -> float:
    if fmt == "seconds":
        return _number(text, dec, where)
    t = text.strip()
    try:
        return _dt.datetime.strptime(t, fmt).replace(tzinfo=_dt.timezone.utc).timestamp()
    except ValueError:
        raise DatasetError(f"{where}: not a time stamp of the map's format {fmt!r}: {t!r} (a spreadsheet may have "
                           "rounded it; with time = \"row\" in the map the row order stands for the time)") from None


def read_mapped_csv(spec: FileSpec) -> MappedRows:
    """Read one CSV with its map (:class:`FileSpec`). :class:`~twin.dataset.DatasetError` naming the file, the data
    row (1-based), the file line, the column and the value: a missing file or column, an empty or non-numeric
    cell, a decimal mark other than the map's, a time that is not a time stamp of the format, every row at the
    same time, a time going back (unless ``order = "time"``), a ``set`` value other than calibration/validation,
    duplicate pose ids."""
    path, fm = spec.path, spec.map
    if not path.is_file():
        raise DatasetError(f"{path}: no such CSV")
    lines = list(csv.reader(io.StringIO(read_text(path, DatasetError), newline=""), delimiter=fm.separator))
    if len(lines) < fm.header_row:
        raise DatasetError(f"{path}: {len(lines)} lines, no header row at line {fm.header_row}")
    header = [h.strip() for h in lines[fm.header_row - 1]]
    col = {h: i for i, h in enumerate(header)}
    data = [(fm.header_row + 1 + k, r) for k, r in enumerate(lines[fm.header_row:]) if any(c.strip() for c in r)]
    if not data:
        raise DatasetError(f"{path}: no data rows after the header (line {fm.header_row})")
    need: list[tuple[str, str]] = [(c, "joints.columns") for c in fm.joint_columns]
    if fm.kind == "points":
        need += [(name, f"measurement.points[{i}].{'xyz'[a]}") for i, p in enumerate(fm.points) for a in range(3)
                 for _, name in p[a]]
    else:
        need += [(name, "measurement.position") for terms in fm.position for _, name in terms]
        need += [(c, "measurement.rotation") for c in fm.rotation]
    for c, key in ((fm.time_column, "time.column"), (fm.temperature, "temperature.column"), (fm.pose_id, "pose_id.column")):
        if c is not None:
            need.append((c, key))
    need += [(c, "keep") for c in fm.keep]
    for rule, key in ((fm.set_rule, "set.column"), (fm.session, "session.column"), (fm.station, "station.column")):
        if rule is not None and rule[0] == "column":
            need.append((rule[1], key))
    missing = [(c, k) for c, k in need if c not in col]
    if missing:
        c, k = missing[0]
        raise DatasetError(f"{path}: no column {c!r} (the map's {k}); the header (line {fm.header_row}) has "
                           f"{', '.join(repr(h) for h in header)}{separator_hint(header, fm.separator)}")
    dup = [h for h in duplicate_names(header) if h in {c for c, _ in need}]
    if dup:
        raise DatasetError(f"{path}: the header (line {fm.header_row}) holds the map's column(s) {dup} more than once")
    n, N, K = len(data), len(fm.joint_columns), fm.n_points
    q = np.zeros((n, N))
    P = np.zeros((n, K, 3))
    eul = np.zeros((n, len(fm.rotation) if fm.rotation else 3))
    t = np.zeros(n) if fm.time_column is not None else None
    temp = np.zeros(n) if fm.temperature is not None else None
    pid = np.zeros(n, dtype=np.int64) if fm.pose_id is not None else None
    keep_text: dict[str, list[str]] = {c: [] for c in fm.keep}

    def cell(r, c):
        i = col[c]
        return r[i] if i < len(r) else ""

    def num(k, line, r, c):
        return _number(cell(r, c), fm.decimal, f"{path}: row {k + 1} (line {line}), column {c!r}")

    def terms_value(k, line, r, terms):
        return sum(s * num(k, line, r, c) for s, c in terms)

    for k, (line, r) in enumerate(data):
        check_row_width(header, r, f"{path}: row {k + 1} (line {line})", DatasetError, separator=fm.separator)
        for jj, c in enumerate(fm.joint_columns):
            q[k, jj] = num(k, line, r, c) * fm.joint_scale[jj]
        if fm.kind == "points":
            for i, p in enumerate(fm.points):  # a point whose cells are all empty (or NaN) was not seen: NaN
                seen = any(cell(r, c).strip().lower() not in ("", "nan") for a in range(3) for _, c in p[a])
                P[k, i] = [terms_value(k, line, r, p[a]) for a in range(3)] if seen else np.nan
        else:
            P[k, 0] = [terms_value(k, line, r, fm.position[a]) for a in range(3)]
            eul[k] = [num(k, line, r, c) for c in fm.rotation]
        if t is not None:
            t[k] = _time_value(cell(r, fm.time_column), fm.time_format, fm.decimal,
                               f"{path}: row {k + 1} (line {line}), column {fm.time_column!r}")
        if temp is not None:  # an empty (or NaN) cell: no temperature recorded for the row (written as missing)
            temp[k] = (np.nan if cell(r, fm.temperature).strip().lower() in ("", "nan")
                       else num(k, line, r, fm.temperature))
        if pid is not None:
            v = num(k, line, r, fm.pose_id)
            where = f"{path}: row {k + 1} (line {line}), column {fm.pose_id!r}"
            if v != int(v):
                raise DatasetError(f"{where}: not an integer: {cell(r, fm.pose_id)!r}")
            pid[k] = check_pose_id(int(v), cell(r, fm.pose_id), where, DatasetError)
        for c in fm.keep:  # numbers: checked, written with '.' decimals as the file gives their digits
            num(k, line, r, c)
            keep_text[c].append(cell(r, c).strip().replace(",", "."))
    P *= fm.length_scale
    readings = [(q, lambda j: fm.joint_columns[j], lambda j: fm.joint_scale[j]),
                (P, lambda i, a: " + ".join(c for _, c in (fm.points[i] if fm.kind == "points" else fm.position)[a]),
                 lambda i, a: fm.length_scale)]
    if fm.kind == "pose" and not fm.quaternion:
        readings.append((eul * fm.rotation_scale, lambda j: fm.rotation[j], lambda j: fm.rotation_scale))
    if temp is not None:
        readings.append((temp, lambda: fm.temperature, lambda: 1.0))
    check_readings(readings, lambda k: f"{path}: row {k + 1} (line {data[k][0]})", DatasetError)
    rot = None
    if fm.kind == "pose":
        from scipy.spatial.transform import Rotation

        if fm.quaternion:
            rot = _quaternion_rotations(eul, fm, path, [ln for ln, _ in data])
        else:
            rot = Rotation.from_euler(fm.euler, eul * fm.rotation_scale).as_matrix()
    line_no = np.array([ln for ln, _ in data])
    notes = []
    order = np.arange(n)
    if t is not None:
        if n >= 2 and np.all(t == t[0]):
            raise DatasetError(f"{path}: column {fm.time_column!r}: every one of the {n} rows has the same time "
                               f"{cell(data[0][1], fm.time_column)!r}: unusable as a time (a spreadsheet may have rounded "
                               "it); with time = \"row\" in the map the row order stands for the time")
        back = np.flatnonzero(np.diff(t) < 0)
        if back.size and fm.order == "file":
            k = int(back[0]) + 1
            raise DatasetError(f"{path}: row {k + 1} (line {line_no[k]}), column {fm.time_column!r}: the time "
                               f"{cell(data[k][1], fm.time_column)!r} is before the previous row's "
                               f"{cell(data[k - 1][1], fm.time_column)!r} ({back.size} such rows): the rows are not in "
                               "time order; order = \"time\" in the map sorts them by time")
        if back.size:
            order = np.argsort(t, kind="stable")
            notes.append(f"{path.name}: the time goes back at {back.size} row(s) (file lines "
                         f"{', '.join(str(int(line_no[b + 1])) for b in back[:10])}{' ...' if back.size > 10 else ''}); "
                         "rows sorted by time")
    if temp is not None and np.isnan(temp).any():
        gap = np.flatnonzero(np.isnan(temp))
        notes.append(f"{path.name}: column {fm.temperature!r} is empty in {gap.size} of its {n} rows (file lines "
                     f"{', '.join(str(int(line_no[g])) for g in gap[:10])}{' ...' if gap.size > 10 else ''}): their "
                     "temp_c is written as missing")
    sel = lambda a: None if a is None else a[order]  # noqa: E731
    q, P, rot, t, temp, pid, line_no = (sel(a) for a in (q, P, rot, t, temp, pid, line_no))
    data = [data[i] for i in order]

    def labels(rule, default):
        if rule is None:
            return np.full(n, default, dtype=object)
        if rule[0] == "fixed":
            return np.full(n, rule[1], dtype=object)
        vals = []
        for k, (line, r) in enumerate(data):
            v = cell(r, rule[1]).strip()
            if v == "":
                raise DatasetError(f"{path}: row {k + 1} (line {line}), column {rule[1]!r}: empty")
            vals.append(v)
        return np.array(vals, dtype=object)

    in_order = "time" if t is not None else "row"
    if fm.set_rule[0] == "last_fraction":
        n_val = int(round(fm.set_rule[1] * n))
        sets = np.array(["calibration"] * (n - n_val) + ["validation"] * n_val, dtype=object)
        notes.append(f"{path.name}: the last {n_val} of its {n} rows in {in_order} order ({fm.set_rule[1]:.0%}) are "
                     "validation, the rest calibration")
    elif fm.set_rule[0] == "first_rows":
        n_cal = min(fm.set_rule[1], n)
        sets = np.array(["calibration"] * n_cal + ["validation"] * (n - n_cal), dtype=object)
        notes.append(f"{path.name}: the first {n_cal} of its {n} rows in {in_order} order are calibration, the rest "
                     "validation")
    else:
        sets = labels(fm.set_rule, "calibration")
        for k, v in enumerate(sets):
            if v not in _SETS:
                raise DatasetError(f"{path}: row {k + 1} (line {line_no[k]}), column {fm.set_rule[1]!r}: {v!r} is not "
                                   f"one of {list(_SETS)}")
    if pid is not None and np.unique(pid).size != n:
        vals, counts = np.unique(pid, return_counts=True)
        raise DatasetError(f"{path}: column {fm.pose_id!r}: duplicate ids {vals[counts > 1][:5].tolist()}")
    keep = {c: [keep_text[c][i] for i in order] for c in fm.keep}
    return MappedRows(path=path, q=q, points=P, rot=rot, t=t, temp_c=temp, pose_id=pid, set=sets,
                      session=labels(fm.session, path.stem), station=None if fm.station is None else labels(fm.station, "0"),
                      keep=keep, lines=line_no, sha256=file_sha256(path), notes=tuple(notes))
