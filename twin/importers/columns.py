"""Column-map import: the laser-tracker and motion-capture CSVs people have -> a dataset folder (``twin import
--map``). The map format is ``docs/formats.md`` ("Column map"); its reader is :func:`read_column_map`, the import
:func:`import_columns`.

A column map (TOML) says how to read one kind of CSV: its dialect (separator, decimal mark, header row), the
robot (a known name, a ``dataset.toml`` robot table, or a URDF), the joint columns in the robot's order and
their unit, the measurement (K >= 1 points whose coordinates are columns or sums/differences of two columns, or
a 6-DOF pose: position columns and Euler-angle columns with their convention), the time (a column with a
format, or the row order), the temperature, the columns to keep, each row's ``set`` (a fixed role, a column, or
"the last fraction F of the rows is validation"), ``session`` and ``station``, and the nominal frames when they
are known (``base2meas``, ``tool2flange``, the points on the flange). ``[[files]]`` entries list the CSVs with
their own role, session, station and any other per-file difference.

The import:

1. reads every CSV with its map (numbers with the map's decimal mark; errors name the file, the data row, the
   file line, the column and the value);
2. converts to SI: joints [rad, m], positions [m], orientations from Euler angles
   (:meth:`scipy.spatial.transform.Rotation.from_euler`: upper-case axes intrinsic, lower-case extrinsic);
3. orders the rows in time (a time that goes back is an error unless the map says ``order = "time"``; a time
   column whose values are all equal, or that is not a time stamp, is an error unless ``time = "row"``);
4. places the measurement on the robot: the frames the map gives, else fitted on the calibration rows with the
   nominal robot (a 6-DOF pose: the closed-form hand-eye registration of :func:`twin.importers.mocap.hand_eye`;
   points: alternating rigid registration of the base and least squares of the points on the flange); each
   station's ``base2meas`` registered on its rows. These are nominal values, a start: the estimator identifies
   base and tool again;
5. writes ``poses.csv`` (joints in degrees / millimetres, points ``p0_x ..`` or the pose ``x y z`` [mm] ``rx ry
   rz`` [rad, rotation vector], ``set``, ``station``, ``temp_c``, ``t_s``, ``session`` and the kept columns) and
   ``dataset.toml`` (the robot, ``[markers]``, ``[tool]`` for a pose, ``[stations.*]``, ``[noise]`` when given,
   the provenance with every input's sha256 and how each frame was obtained and how well the nominal robot fits).

The map's reader and the reading of one CSV (steps 1-3: :func:`read_column_map`, :func:`read_mapped_csv`) are
:mod:`twin.importers.column_map`'s, re-exported here; this module places the rows on the robot and writes the
dataset (steps 4-5: :func:`fit_points_on_flange`, :func:`import_columns`).
"""

from __future__ import annotations

import datetime as _dt
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from ..dataset import (OPTIONAL_COLUMNS, POSE_COLUMNS, Dataset, DatasetError, Plate, joint_columns, marker_columns,
                       write_dataset)
from ..kinematics import flange2base
from ..transforms import invert_transform, kabsch, make_transform, matrix_to_rotvec
from ..units import M_PER_MM, RAD_PER_DEG
from .column_map import (MAP_SCHEMA_VERSION, ColumnMap, FileMap, FileSpec, MappedRows, parse_file_argument,
                         read_column_map, read_frame_file, read_mapped_csv)
from .mocap import file_sha256, hand_eye

__all__ = ["MAP_SCHEMA_VERSION", "ColumnMap", "FileSpec", "FileMap", "MappedRows", "ImportReport", "read_column_map",
           "read_mapped_csv", "read_frame_file", "fit_points_on_flange", "import_columns", "parse_file_argument"]

_START_M = 0.1  # [m] the starts of fit_points_on_flange off the flange origin


# ------------------------------------------------------------------------------------------------
# Frames on the nominal robot
# ------------------------------------------------------------------------------------------------

def fit_points_on_flange(flange2base_T: np.ndarray, points_meas: np.ndarray, base2meas: np.ndarray | None = None, *,
                         max_iter: int = 500, tol: float = 1e-10) -> tuple[np.ndarray, np.ndarray]:
    """``(base2meas, points_flange)``: K points fixed on the flange, measured ``points_meas`` ``(n, K, 3)`` [m] at the
    flange poses ``flange2base_T`` ``(n, 4, 4)``, with ``p_meas = base2meas F_i x_k``.

    With ``base2meas`` given, the points are the linear least squares ``x_k = mean_i R_i^T (base2meas^-1 p_ik -
    t_i)`` (exact: the ``R_i`` are rotations). Otherwise alternately: ``base2meas`` by a rigid fit (Kabsch) of the
    predicted points onto the measured ones, then the points as above, until the points move less than ``tol`` [m]
    (at most ``max_iter`` rounds), from seven starts (the flange origin, 0.1 m along each flange axis); the fit of
    the least squared residual."""
    F = np.asarray(flange2base_T, dtype=float)
    P = np.asarray(points_meas, dtype=float)
    if F.ndim != 3 or F.shape[1:] != (4, 4) or P.ndim != 3 or P.shape[0] != F.shape[0] or P.shape[2] != 3:
        raise ValueError(f"flange2base_T must be (n, 4, 4) and points_meas (n, K, 3), got {F.shape} and {P.shape}")
    R, tt = F[:, :3, :3], F[:, :3, 3]

    def points_given(B):
        Binv = invert_transform(B)
        pb = P @ Binv[:3, :3].T + Binv[:3, 3]  # (n, K, 3) in the base frame
        return np.einsum("nji,nkj->nki", R, pb - tt[:, None, :]).mean(axis=0)

    if base2meas is not None:
        B = np.asarray(base2meas, dtype=float)
        return B, points_given(B)

    def alternate(X):
        B = np.eye(4)
        for _ in range(max_iter):
            pred = np.einsum("nij,kj->nki", R, X) + tt[:, None, :]
            Rb, tb = kabsch(pred.reshape(-1, 3), P.reshape(-1, 3))
            B = make_transform(Rb, tb)
            X_new = points_given(B)
            done = np.abs(X_new - X).max() < tol
            X = X_new
            if done:
                break
        pred = np.einsum("nij,kj->nki", R, X) + tt[:, None, :]
        return float(np.sum((pred @ B[:3, :3].T + B[:3, 3] - P) ** 2)), B, X

    # from the flange origin, and from 0.1 m along each flange axis: where the flange origins hardly move (axes that
    # meet in a point, a pan-tilt head) the first rigid fit is undetermined and one start can end in a wrong minimum
    K = P.shape[1]
    starts = [np.zeros((K, 3))] + [np.tile(sign * _START_M * e, (K, 1)) for e in np.eye(3) for sign in (1.0, -1.0)]
    best = min((alternate(X0) for X0 in starts), key=lambda r: r[0])
    return best[1], best[2]


def _register(F: np.ndarray, tool: np.ndarray, P: np.ndarray, rot: np.ndarray | None) -> tuple[np.ndarray, float, float | None]:
    """``base2meas`` registered (Kabsch) from the predicted tool origins (and axis points for a pose) onto the
    measured ones, and the RMS position [m] / orientation [rad] residuals after it."""
    T = F @ tool
    if rot is None:
        pred, meas = T[:, :3, 3], P[:, 0]
        Rb, tb = kabsch(pred, meas)
    else:
        pts = np.concatenate([np.zeros((1, 3)), 0.1 * np.eye(3)])
        pred = (np.einsum("nij,kj->nki", T[:, :3, :3], pts) + T[:, None, :3, 3]).reshape(-1, 3)
        meas = (np.einsum("nij,kj->nki", rot, pts) + P[:, 0][:, None, :]).reshape(-1, 3)
        Rb, tb = kabsch(pred, meas)
    B = make_transform(Rb, tb)
    return B, *_fit_rms(F, tool, B, P, rot)


def _fit_rms(F, tool, B, P, rot) -> tuple[float, float | None]:
    T = B @ F @ tool
    ep = float(np.sqrt(np.mean(np.sum((T[:, :3, 3] - P[:, 0]) ** 2, axis=-1))))
    if rot is None:
        return ep, None
    er = np.linalg.norm(matrix_to_rotvec(rot @ np.swapaxes(T[:, :3, :3], 1, 2)), axis=-1)
    return ep, float(np.sqrt(np.mean(er**2)))


# ------------------------------------------------------------------------------------------------
# The import
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class ImportReport:
    """What :func:`import_columns` wrote: the dataset, per file ``{path, sha256, rows, calibration, validation,
    session, station, time}``, per station the nominal fit ``{rows, position_rms_mm, orientation_rms_deg,
    base2meas}`` (the nominal robot with the frames written, on every row of the station) and the notes."""

    dataset: Dataset
    files: tuple[dict, ...]
    stations: dict[str, dict] = field(default_factory=dict)
    notes: tuple[str, ...] = ()


def import_columns(cmap: ColumnMap | str | os.PathLike, out: str | os.PathLike, *,
                   files: Sequence[tuple[str | os.PathLike, dict]] | None = None, attribution: str = "",
                   tool: tuple[np.ndarray, str] | None = None) -> ImportReport:
    """Import the CSVs of a column map into the dataset folder ``out`` (see the module docstring).

    ``files``: ``(path, overrides)`` pairs read instead of the map's ``[[files]]`` (overrides: keys of a
    ``[[files]]`` entry, e.g. ``{"set": "validation", "session": "B", "station": "B", "time": "row"}``).
    ``attribution``: text added to the provenance. ``tool``: ``(frame, source)``, the robot's tool known from
    elsewhere (e.g. its calibration): a pose's ``tool2flange`` ``(4, 4)``, or the points on the flange ``(K, 3)``
    [m]; it replaces the map's frame and any fit. Returns an :class:`ImportReport`.

    No ``set`` given (in the map, a ``[[files]]`` entry or ``files``): no ``set`` column is written. No calibration
    row (a session to predict or to score): the frames are fitted on every row. Poses that cannot place the tool
    (one tool orientation over the rows, an ISO cube's probe; rotations about one axis only, a planar arm) with no
    tool given: the tool's rotation is read from the rows and its position on the flange left at the flange's
    origin, said in the notes (``twin register`` holds the calibrated robot's tool)."""
    if not isinstance(cmap, ColumnMap):
        cmap = read_column_map(cmap)
    specs = [cmap.for_file(p, o) for p, o in files] if files else list(cmap.files)
    if not specs:
        raise ValueError(f"{cmap.path}: no CSV to import: list [[files]] in the map or give CSVs")
    robot = cmap.robot
    parts = [read_mapped_csv(s) for s in specs]
    K = cmap.base.n_points
    for r in parts:
        if r.points.shape[1] != K:
            raise DatasetError(f"{r.path}: {r.points.shape[1]} point(s) per row where the map has {K}")
    pose = cmap.base.kind == "pose"
    n_tot = sum(r.n for r in parts)
    q = np.concatenate([r.q for r in parts])
    P = np.concatenate([r.points for r in parts])
    rot = np.concatenate([r.rot for r in parts]) if pose else None
    sets = np.concatenate([r.set for r in parts])
    session = np.concatenate([r.session for r in parts])
    many = len(parts) > 1
    st_given = [r.station is not None for r in parts]
    if any(st_given):
        station = np.concatenate([r.station if r.station is not None else np.full(r.n, "0", dtype=object)
                                  for r in parts])
    else:
        station = None
    st_ids = station if station is not None else np.full(n_tot, "0", dtype=object)
    F = flange2base(robot, q)
    notes: list[str] = [n for r in parts for n in r.notes]
    set_given = any(s.map.set_given for s in specs)
    if not set_given:
        notes.append("no set column: no set was given (map, [[files]] or command line); twin diagnose holds out the "
                     "end of the campaign, twin calibrate a seeded random fraction")
    cal = sets == "calibration"
    if not cal.any():
        cal = np.ones(n_tot, bool)
        notes.append("every row is validation (a session to predict or to score): the frames below were fitted on all "
                     "of them")
    tool_points = tool_frame = None
    tool_src = ""
    if tool is not None:
        T_tool, tool_src = np.asarray(tool[0], dtype=float), str(tool[1])
        if T_tool.shape != ((4, 4) if pose else (K, 3)):
            raise DatasetError(f"{tool_src}: holds {'a tool frame' if T_tool.shape == (4, 4) else f'{len(T_tool)} point(s)'}"
                               f" where the map measures {'a 6-DOF pose' if pose else f'{K} point(s)'}")
        tool_frame, tool_points = (T_tool, None) if pose else (None, T_tool)
    frames_txt: list[str] = []
    # the tool (pose) or the points on the flange
    given_b2m: dict[str, np.ndarray] = {}
    b2m_src: dict[str, str] = {}
    for r, s in zip(parts, specs):
        if s.map.base2meas is not None:
            for sid in np.unique(r.station if r.station is not None else np.array(["0"], dtype=object)):
                given_b2m[str(sid)] = s.map.base2meas
                b2m_src[str(sid)] = s.map.base2meas_source
    first = str(st_ids[np.flatnonzero(cal)[0]])
    seen = np.isfinite(P).all(axis=-1)  # (n, K): the points seen; the frames are fitted on rows that saw every point
    sel = np.flatnonzero(cal & (st_ids == first) & seen.all(axis=1))
    if not seen.all():
        notes.append(f"{int((~seen).sum())} point(s) of {int((~seen.all(axis=1)).sum())} row(s) empty in the CSV (not seen): "
                     "written empty, status p<k>:empty; the frames fitted on the rows that saw every point")
    he_tool = None
    from_map = pose and tool_frame is None and cmap.tool2flange is not None
    given_tool = (tool_frame, tool_src) if tool_frame is not None else \
        ((cmap.tool2flange, cmap.tool2flange_source) if from_map else None)
    one_orientation = False
    if pose:
        take = sel[np.linspace(0, sel.size - 1, min(sel.size, 40)).round().astype(int)]
        try:
            _, he_tool = hand_eye(F[take], _poses(rot[take], P[take, 0]))
        except ValueError as exc:
            one_orientation = given_tool is None
            he_fail = str(exc)
        if given_tool is not None:
            tool = given_tool[0]
            frames_txt.append(f"tool2flange: {given_tool[1]}")
        elif one_orientation:
            tool = _tool_rotation(F[sel], P[sel, 0], rot[sel], given_b2m.get(first))
            frames_txt.append(f"tool2flange: unknown: the rows cannot place the tool on the flange ({he_fail}: one "
                              "orientation, or turns about one axis only); its rotation read from the rows with the "
                              "nominal robot, its position left at the flange's origin. twin register with the robot's "
                              "calibration holds the calibrated tool (twin import --calibration CAL.json, or "
                              "frames.tool2flange in the map, gives it here)")
        else:
            tool = he_tool
            frames_txt.append(f"tool2flange: closed-form hand-eye registration of the nominal robot on {take.size} "
                              f"calibration rows of station {first} (a start: the estimator identifies it again)")
        pts_flange = tool[:3, 3][None].copy()
    else:
        tool = np.eye(4)
        if tool_points is not None:
            pts_flange = tool_points
            frames_txt.append(f"points on the flange: {tool_src}")
        elif cmap.points_flange is not None:
            pts_flange = cmap.points_flange
            frames_txt.append("points on the flange: given in the map")
        else:
            _, pts_flange = fit_points_on_flange(F[sel], P[sel], given_b2m.get(first))
            frames_txt.append(f"points on the flange: fitted with the nominal robot on the {sel.size} calibration rows "
                              f"of station {first}"
                              f" ({'its given base2meas' if first in given_b2m else 'base2meas fitted alongside'}; a "
                              "start: the estimator identifies the tool again)")
    # every station's base2meas and the nominal fit
    stations: dict[str, dict] = {}
    bases: dict[str, np.ndarray] = {}
    for sid in sorted({str(s) for s in st_ids}):
        rows = np.flatnonzero(st_ids == sid)
        r_rot = None if rot is None else rot[rows]
        if sid in given_b2m:
            B = given_b2m[sid]
        elif pose:
            B = _register(F[rows], tool, P[rows], None if one_orientation else r_rot)[0]
        else:
            m = seen[rows].reshape(-1)
            Rb, tb = kabsch(_on_flange(F[rows], pts_flange).reshape(-1, 3)[m], P[rows].reshape(-1, 3)[m])
            B = make_transform(Rb, tb)
        if pose:
            ep, er = _fit_rms(F[rows], tool, B, P[rows], r_rot)
        else:
            pm = _on_flange(F[rows], pts_flange) @ B[:3, :3].T + B[:3, 3]
            ep, er = float(np.sqrt(np.mean(np.sum((pm - P[rows]) ** 2, axis=-1)[seen[rows]]))), None
        bases[sid] = B
        stations[sid] = {"rows": int(rows.size), "position_rms_mm": ep / M_PER_MM,
                         "orientation_rms_deg": None if er is None else er / RAD_PER_DEG,
                         "base2meas": b2m_src.get(sid, "registered on its rows with the nominal robot")}
    if from_map:
        # the direction of a given tool frame, checked against the data: its inverse must not fit far better
        inv = invert_transform(tool)
        worse = []
        for sid in bases:
            rows = np.flatnonzero(st_ids == sid)
            _, ep_i, _ = _register(F[rows], inv, P[rows], rot[rows])
            worse.append((stations[sid]["position_rms_mm"], ep_i / M_PER_MM))
        given_rms = float(np.median([a for a, _ in worse]))
        inv_rms = float(np.median([b for _, b in worse]))
        he = ""
        if he_tool is not None:
            rows = np.flatnonzero(st_ids == first)
            _, ep_h, er_h = _register(F[rows], he_tool, P[rows], rot[rows])
            he = (f"; a hand-eye fit instead would place the tool at {_fmt_mm(he_tool[:3, 3])} mm on the flange and fit "
                  f"station {first} to {ep_h / M_PER_MM:.3g} mm, {er_h / RAD_PER_DEG:.3g} deg")
        frames_txt.append(f"tool2flange checked against the data: the nominal robot fits to {given_rms:.3g} mm RMS with "
                          f"it (tool at {_fmt_mm(tool[:3, 3])} mm on the flange), {inv_rms:.3g} mm with its inverse{he}")
        if inv_rms * 3 < given_rms and given_rms - inv_rms > 1.0:
            raise DatasetError(f"{cmap.path}: frames.tool2flange ({cmap.tool2flange_source}) fits the data to "
                               f"{given_rms:.4g} mm RMS, its inverse to {inv_rms:.4g} mm: the file holds the other "
                               "direction (set direction to the other value)")
    # time
    has_t = [r.t is not None for r in parts]
    t_s = None
    extra: dict[str, np.ndarray] = {}
    if all(has_t):
        t0 = min(float(r.t.min()) for r in parts)
        t_s = np.concatenate([r.t - t0 for r in parts])
        notes.append(f"t_s: seconds since {_dt.datetime.fromtimestamp(t0, _dt.timezone.utc):%Y-%m-%d %H:%M:%S} "
                     "(the earliest time stamp)")
    else:
        if any(has_t):
            t0 = min(float(r.t.min()) for r in parts if r.t is not None)
            extra["time_s"] = np.concatenate([np.array([f"{v - t0:.3f}" for v in r.t], dtype=object) if r.t is not None
                                              else np.full(r.n, "", dtype=object) for r in parts])
            notes.append("no t_s column: " + ", ".join(r.path.name for r in parts if r.t is None) + " has no usable "
                         "time (row order only); the time stamps of the others are kept as the extra column time_s")
        else:
            notes.append("no t_s column: the rows carry no time, only their order (time = \"row\")")
    temp_c = None
    if all(r.temp_c is not None for r in parts):
        temp_c = np.concatenate([r.temp_c for r in parts])
    elif any(r.temp_c is not None for r in parts):
        notes.append("no temp_c column: not every file has a temperature")
    keep_names = [c for r in parts for c in r.keep]
    reserved = {"pose_id", "session", "time_s", *POSE_COLUMNS, *OPTIONAL_COLUMNS, *joint_columns(robot),
                *marker_columns(K)}
    for c in dict.fromkeys(keep_names):
        if c in reserved:
            raise DatasetError(f"{cmap.path}: keep: a kept column may not be named {c!r}, a column the dataset "
                               "writes itself")
        extra[c] = np.concatenate([np.array(r.keep[c], dtype=object) if c in r.keep else np.full(r.n, "", dtype=object)
                                   for r in parts])
    extra["session"] = session.astype(object)
    pid_given = [r.pose_id is not None for r in parts]
    if all(pid_given) and not many:
        pose_id = parts[0].pose_id
    elif any(pid_given):
        raise ValueError(f"{cmap.path}: pose_id from a column needs a single file (ids of several files may clash); "
                         "leave pose_id out to number the rows")
    else:
        pose_id = np.arange(n_tot, dtype=np.int64)
    # write
    outp = Path(out)
    outp.mkdir(parents=True, exist_ok=True)
    if cmap.urdf is not None:
        dst = outp / cmap.urdf.name
        if cmap.urdf.resolve() != dst.resolve():
            shutil.copyfile(cmap.urdf, dst)
    pose_T = np.full((n_tot, 4, 4), np.nan)
    if pose:
        pose_T = _poses(rot, P[:, 0])
    lines = [f"imported by twin import --map {cmap.path.name} (sha256 {cmap.sha256}) from "
             + "; ".join(f"{r.path.name} ({r.n} rows: {int(np.sum(r.set == 'calibration'))} calibration, "
                         f"{int(np.sum(r.set == 'validation'))} validation; session {', '.join(sorted(set(r.session)))}; "
                         f"sha256 {r.sha256})" for r in parts)]
    if cmap.description:
        lines.append(cmap.description)
    if cmap.attribution:
        lines.append(f"data attribution: {cmap.attribution}")
    if attribution:
        lines.append(f"data attribution: {attribution}")
    if cmap.urdf is not None:
        lines.append(f"robot: {cmap.urdf.name} (sha256 {file_sha256(cmap.urdf)})")
    lines += frames_txt
    for sid, st in stations.items():
        o = "" if st["orientation_rms_deg"] is None else f", {st['orientation_rms_deg']:.3g} deg"
        lines.append(f"station {sid}: base2meas {st['base2meas']}; the nominal robot fits its {st['rows']} rows to "
                     f"{st['position_rms_mm']:.3g} mm{o} RMS")
    lines += notes
    ds = Dataset(
        robot=robot.with_frames(tool2flange=tool) if pose else robot,
        robot_spec=cmap.robot_spec,
        plate=Plate(0.0, pts_flange),
        pose_id=pose_id,
        q=q,
        spheres=np.full((n_tot, K, 3), np.nan) if pose else P,
        sphere_seen=np.zeros((n_tot, K), bool) if pose else seen,
        status=None if pose or seen.all() else np.array([";".join(f"p{i}:empty" for i in np.flatnonzero(~v))
                                                          for v in seen], dtype=object),
        pose=pose_T,
        pose_seen=np.full(n_tot, pose),
        set=sets.astype(object) if set_given else None,
        station=None if station is None else station.astype(object),
        temp_c=temp_c,
        t_s=t_s,
        extra=extra,
        noise_position=cmap.noise_position,
        noise_orientation=cmap.noise_orientation,
        stations_base2meas=bases,
        provenance="; ".join(lines),
        path=outp,
    )
    write_dataset(outp, ds)
    info = tuple({"path": str(r.path), "sha256": r.sha256, "rows": r.n,
                  "calibration": int(np.sum(r.set == "calibration")), "validation": int(np.sum(r.set == "validation")),
                  "session": sorted(set(r.session)), "station": None if r.station is None else sorted(set(r.station)),
                  "time": "row order" if r.t is None else "time stamps"} for r in parts)
    return ImportReport(dataset=ds, files=info, stations=stations, notes=tuple(frames_txt + notes))


def _tool_rotation(F: np.ndarray, p: np.ndarray, rot: np.ndarray, base2meas: np.ndarray | None) -> np.ndarray:
    """A tool frame ``(4, 4)`` for poses of one orientation: ``base2meas`` (given, or registered on the positions
    ``p`` ``(n, 3)`` [m] against the flange origins ``F`` ``(n, 4, 4)``: the tool's offset is one constant shift
    then), the rotation ``R_tool`` the mean (projected on SO(3)) of ``(R_B R_F,i)^T R_i`` over the rows, the
    translation zero (not determined by one orientation)."""
    if base2meas is None:
        Rb, _ = kabsch(F[:, :3, 3], p)
    else:
        Rb = base2meas[:3, :3]
    M = np.einsum("nji,njk->ik", Rb @ F[:, :3, :3], rot)
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return make_transform(U @ D @ Vt, np.zeros(3))


def _fmt_mm(p: np.ndarray) -> str:
    return "(" + ", ".join(f"{v / M_PER_MM:.4g}" for v in p) + ")"


def _on_flange(F: np.ndarray, pts_flange: np.ndarray) -> np.ndarray:
    """Points ``(K, 3)`` of the flange frame at the flange poses ``F`` ``(n, 4, 4)``: ``(n, K, 3)`` in the base frame."""
    return np.einsum("nij,kj->nki", F[:, :3, :3], pts_flange) + F[:, None, :3, 3]


def _poses(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    T = np.zeros((R.shape[0], 4, 4))
    T[:, :3, :3] = R
    T[:, :3, 3] = p
    T[:, 3, 3] = 1.0
    return T
