"""Motion-capture campaigns in FIGAROH's CSV form -> a dataset folder (``twin import``).

A FIGAROH-style mocap CSV has one row per static posture: the joint positions under the robot's joint names
(revolute [rad], prismatic [m]) and the K points of one tracked rigid body as ``x1, y1, z1, ..., xK, yK, zK``
[m] in the mocap frame fixed to the robot base; other columns (time windows, ``marker_std_mm``) are kept as
extra columns of the dataset.

The import (:func:`import_mocap`):

1. reads the robot's chain from the URDF (:func:`twin.urdf.read_urdf_chain`, root link to end link);
2. reads every CSV, checks the joint columns, the length unit and that the K points are one rigid body (their
   pairwise distances constant over the rows, to ``rigid_tol_mm``); a point whose three cells are empty (or NaN)
   in a row was not seen there (an occluded marker): the row is kept, that point written as not seen, and steps
   2-4 use the rows that saw every point;
3. builds the marker set's geometry: the mean shape over the rows (Procrustes), in a body frame with its origin
   at point 1, x towards point 2, z normal to the plane of points 1, 2 and the last point;
4. places it on the flange with a closed-form hand-eye registration on the rows of the first file (the
   training rows), ``tool2meas_i = base2meas flange2base(q_i) tool2flange``: the tool rotation from the
   rotation axes of relative motions (``A_ij Y = Y B_ij``, Park and Martin), its translation by linear least
   squares, the base by a rigid fit of the points; these are *nominal* values, a starting point that the
   estimator identifies again (base and tool are estimated 6-DOF);
5. writes ``poses.csv`` (joint names in degrees / millimetres, ``p0_x ..`` in millimetres, ``set`` from each
   file's role, ``t_s`` the middle of the averaging window when the CSV has ``t_start_robot``/``t_end_robot``)
   and ``dataset.toml`` (the URDF copied beside it, ``[markers]``, the provenance with every file's sha256).
"""

from __future__ import annotations

import csv
import hashlib
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..dataset import Dataset, DatasetError, Plate, write_dataset
from ..files import (MARKER_STD_COLUMN, check_readings, check_row_width, duplicate_names, open_text, parse_finite,
                     parse_marker_std, separator_hint)
from ..kinematics import RobotModel, flange2base
from ..transforms import invert_transform, kabsch, make_transform, matrix_to_rotvec
from ..units import M_PER_MM, MM_PER_M

__all__ = ["MocapRows", "read_mocap_csv", "marker_geometry", "hand_eye", "import_mocap", "file_sha256"]

_TIME_COLUMNS = ("t_start_robot", "t_end_robot")
# hand_eye: the relative rotations turn about one axis when their second singular value is below this share of the
# largest rotation (axes within about a degree: a planar arm, whose small errors tilt them apart)
_ONE_AXIS = 0.02


@dataclass(frozen=True)
class MocapRows:
    """Rows of a mocap CSV in SI: ``q`` ``(n, N)`` [rad, m], ``points`` ``(n, K, 3)`` [m] (NaN: a point not seen
    in that row), the other columns as text (``extra``), the file and its sha256."""

    path: Path
    q: np.ndarray
    points: np.ndarray
    extra: dict[str, list[str]]
    sha256: str


def file_sha256(path: str | os.PathLike) -> str:
    """sha256 hex digest of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def read_mocap_csv(path: str | os.PathLike, robot: RobotModel, *, marker_unit: str = "m") -> MocapRows:
    """Read a FIGAROH-style mocap CSV for ``robot`` (its joint names are the joint columns).

    ``marker_unit``: the unit of the ``x1..zK`` columns (``"m"`` as FIGAROH writes them, or ``"mm"``).
    :class:`~twin.dataset.DatasetError` naming the file, the row and the column: missing file, missing joint
    columns, no marker columns, empty or non-numeric joint cells, a point with some of its cells empty, a column name
    twice in the header, a time cell (``t_start_robot``, ``t_end_robot``) that is no finite number, a
    ``marker_std_mm`` cell of a row with points that is no finite number >= 0. A point whose three cells are all
    empty (or NaN) was not seen in that row (an occluded marker): NaN in ``points``."""
    from ..dataset import LENGTH_UNITS

    path = Path(path)
    if marker_unit not in LENGTH_UNITS:
        raise ValueError(f"marker_unit must be one of {sorted(LENGTH_UNITS)}, got {marker_unit!r}")
    if not path.is_file():
        raise DatasetError(f"{path}: no such mocap CSV")
    with open_text(path, DatasetError) as f:
        reader = csv.DictReader(f)
        header = [h.strip() for h in (reader.fieldnames or [])]
        rows = []
        for k, r in enumerate(reader):
            check_row_width(header, header + r.pop(None, []), f"{path}: row {k + 1}", DatasetError)
            rows.append({(c or "").strip(): (v or "").strip() for c, v in r.items()})
    # every column is kept (the others in the dataset's poses.csv): a name twice would keep one of them, unsaid
    dup = [h for h in duplicate_names(header) if h]
    if dup:
        raise DatasetError(f"{path}: columns {dup} appear more than once in the header")
    missing = [c for c in robot.joint_names if c not in header]
    if missing:
        raise DatasetError(f"{path}: missing joint columns {missing} (robot {robot.name!r} has joints "
                           f"{', '.join(robot.joint_names)}){separator_hint(header)}")
    K = 0
    while all(f"{c}{K + 1}" in header for c in "xyz"):
        K += 1
    if K == 0:
        others = [h for h in header if h not in robot.joint_names]
        raise DatasetError(f"{path}: no marker columns x1, y1, z1 (one rigid body's points x1..zK in the mocap frame, "
                           f"named exactly so, no unit in the name: --marker-unit gives it); the header's other "
                           f"columns: {', '.join(repr(h) for h in others[:9])}{' ...' if len(others) > 9 else ''}")
    if not rows:
        raise DatasetError(f"{path}: no data rows")
    n = len(rows)
    q = np.zeros((n, robot.n_joints))
    P = np.zeros((n, K, 3))

    def num(r, k, c):
        return parse_finite(r.get(c, ""), f"{path}: row {k + 1}, column {c!r}", DatasetError)

    for k, r in enumerate(rows):
        for j, c in enumerate(robot.joint_names):
            q[k, j] = num(r, k, c)
        for i in range(K):  # a point whose three cells are all empty (or NaN) was not seen (occluded): NaN
            cells = [f"{c}{i + 1}" for c in "xyz"]
            seen = any(r.get(c, "").lower() not in ("", "nan") for c in cells)
            P[k, i] = [num(r, k, c) for c in cells] if seen else np.nan
    P *= LENGTH_UNITS[marker_unit]
    check_readings(((q, lambda j: robot.joint_names[j], lambda j: 1.0),
                    (P, lambda i, a: f"{'xyz'[a]}{i + 1}", lambda i, a: LENGTH_UNITS[marker_unit])),
                   lambda k: f"{path}: row {k + 1}", DatasetError)
    known = set(robot.joint_names) | {f"{c}{i + 1}" for i in range(K) for c in "xyz"}
    extra = {h: [r.get(h, "") for r in rows] for h in header if h not in known}
    timed = all(c in extra for c in _TIME_COLUMNS)
    for c in _TIME_COLUMNS if timed else ():
        # the robot's clock: the rows' time (t_s) is the middle of each row's window
        for k, v in enumerate(extra[c]):
            parse_finite(v, f"{path}: row {k + 1}, column {c!r}", DatasetError)
    for k in np.flatnonzero(np.isfinite(P).any(axis=(1, 2))) if MARKER_STD_COLUMN in extra else ():
        # the instrument's noise of a row with points: the diagnosis' noise floor reads it
        parse_marker_std(extra[MARKER_STD_COLUMN][k], f"{path}: row {k + 1}, column {MARKER_STD_COLUMN!r}", DatasetError)
    return MocapRows(path=path, q=q, points=P, extra=extra, sha256=file_sha256(path))


def _pair_distances(P: np.ndarray) -> tuple[list[tuple[int, int]], np.ndarray]:
    K = P.shape[1]
    pairs = [(a, b) for a in range(K) for b in range(a + 1, K)]
    return pairs, np.stack([np.linalg.norm(P[:, a] - P[:, b], axis=-1) for a, b in pairs], axis=-1) if pairs else np.zeros((P.shape[0], 0))


def check_rigid(P: np.ndarray, where: str, *, rigid_tol_mm: float = 1.0, marker_unit: str = "m") -> None:
    """:class:`~twin.dataset.DatasetError` when the points ``(n, K, 3)`` [m] are not one rigid body (a pairwise
    distance whose spread over the rows exceeds ``rigid_tol_mm``) or when their size cannot be a tool's in the
    declared unit (a median pairwise distance above 5 m or below 1 mm)."""
    pairs, d = _pair_distances(P)
    if not pairs:
        return
    med = np.median(d, axis=0)
    if np.median(med) > 5.0:
        raise DatasetError(f"{where}: the markers are {np.median(med):.4g} m apart: the columns look like millimetres "
                           f"but the unit given is {marker_unit!r} (FIGAROH writes metres; pass marker_unit='mm', twin import --marker-unit mm)")
    if np.median(med) < 1e-3:
        raise DatasetError(f"{where}: the markers are {np.median(med) * MM_PER_M:.4g} mm apart: the columns look like "
                           f"metres but the unit given is {marker_unit!r}")
    spread = d.max(axis=0) - d.min(axis=0)
    worst = int(np.argmax(spread))
    if spread[worst] > rigid_tol_mm * M_PER_MM:
        a, b = pairs[worst]
        raise DatasetError(f"{where}: the points are not one rigid body: the distance between points {a + 1} and {b + 1} "
                           f"varies by {spread[worst] * MM_PER_M:.3f} mm over the rows (from {d[:, worst].min() * MM_PER_M:.3f} to "
                           f"{d[:, worst].max() * MM_PER_M:.3f} mm; tolerance {rigid_tol_mm:g} mm)")


def marker_geometry(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The marker set's mean shape ``(K, 3)`` [m] in its body frame (origin at point 1, x towards point 2, z
    normal to points 1, 2 and K) and each row's body pose ``(n, 4, 4)`` in the mocap frame (rigid fit of the
    shape onto the row's points). Needs K >= 3 points not on one line."""
    n, K, _ = P.shape
    if K < 3:
        raise ValueError(f"the body frame needs at least 3 points, got {K}")
    ref = P[0] - P[0].mean(axis=0)
    shape = ref
    for _ in range(5):  # Procrustes mean: align every row onto the current mean shape, average
        aligned = []
        for k in range(n):
            R, t = kabsch(P[k], shape + 0.0)
            aligned.append(P[k] @ R.T + t)
        shape = np.mean(aligned, axis=0)
        shape -= shape.mean(axis=0)
    x = shape[1] - shape[0]
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("points 1 and 2 coincide: no body frame")
    x /= np.linalg.norm(x)
    z = np.cross(shape[1] - shape[0], shape[K - 1] - shape[0])
    if np.linalg.norm(z) < 1e-9 * max(np.abs(shape).max(), 1e-12) ** 2:
        raise ValueError("points 1, 2 and the last are on one line: no body frame")
    z /= np.linalg.norm(z)
    y = np.cross(z, x)
    Rb = np.stack([x, y, z], axis=1)  # body axes in the shape frame
    body = (shape - shape[0]) @ Rb  # points in the body frame
    poses = np.empty((n, 4, 4))
    for k in range(n):
        R, t = kabsch(body, P[k])
        poses[k] = make_transform(R, t)
    return body, poses


def hand_eye(flange2base_T: np.ndarray, tool2meas_T: np.ndarray, *, min_angle: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form ``(base2meas, tool2flange)`` ``(4, 4)`` from ``tool2meas_i = base2meas F_i tool2flange`` with
    ``F_i = flange2base`` ``(n, 4, 4)`` and measured ``tool2meas`` ``(n, 4, 4)`` (see the module docstring).

    For every pair of rows whose relative rotation exceeds ``min_angle`` [rad]: ``A = M_i^-1 M_j``,
    ``B = F_i^-1 F_j`` satisfy ``B Y = Y A``; the rotation axes give ``R_Y`` (``axis(B) = R_Y axis(A)``, a
    rigid fit of the axes), then ``(R_B - I) t_Y = R_Y t_A - t_B`` by least squares, then ``base2meas`` from a
    rigid fit of the tool origins and axis points. ``ValueError`` when fewer than two pairs rotate enough or
    their axes are all parallel."""
    F = np.asarray(flange2base_T, dtype=float)
    M = np.asarray(tool2meas_T, dtype=float)
    n = F.shape[0]
    a_ax, b_ax, A_list, B_list = [], [], [], []
    for i in range(n):
        for j in range(i + 1, n):
            A = invert_transform(M[i]) @ M[j]
            B = invert_transform(F[i]) @ F[j]
            ra, rb = matrix_to_rotvec(A[:3, :3]), matrix_to_rotvec(B[:3, :3])
            if np.linalg.norm(ra) < min_angle or np.linalg.norm(rb) < min_angle:
                continue
            a_ax.append(ra)
            b_ax.append(rb)
            A_list.append(A)
            B_list.append(B)
    if len(a_ax) < 2:
        raise ValueError(f"hand_eye: {len(a_ax)} row pairs rotate more than {min_angle} rad; need at least two")
    a_ax, b_ax = np.array(a_ax), np.array(b_ax)
    if np.linalg.svd(a_ax, compute_uv=False)[1] < _ONE_AXIS * np.linalg.norm(a_ax, axis=1).max():
        raise ValueError("hand_eye: every relative rotation turns about one axis: the tool rotation is not determined")
    RY, _ = _kabsch_dirs(a_ax, b_ax)
    lhs = np.concatenate([B[:3, :3] - np.eye(3) for B in B_list])
    rhs = np.concatenate([RY @ A[:3, 3] - B[:3, 3] for A, B in zip(A_list, B_list)])
    tY = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    Y = make_transform(RY, tY)
    pts = np.concatenate([np.zeros((1, 3)), 0.1 * np.eye(3)])
    pred = np.concatenate([(F[k] @ Y)[:3, :3] @ pts.T + (F[k] @ Y)[:3, 3:4] for k in range(n)], axis=1).T
    meas = np.concatenate([M[k][:3, :3] @ pts.T + M[k][:3, 3:4] for k in range(n)], axis=1).T
    R, t = kabsch(pred, meas)
    return make_transform(R, t), Y


def _kabsch_dirs(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R with ``b_k ~ R a_k`` for vectors (no translation)."""
    H = a.T @ b
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0])
    return Vt.T @ D @ U.T, np.zeros(3)


def import_mocap(
    files: Sequence[tuple[str | os.PathLike, str]],
    urdf: str | os.PathLike,
    root_link: str,
    end_link: str,
    out: str | os.PathLike,
    *,
    marker_unit: str = "m",
    points: Sequence[int] | None = None,
    rigid_tol_mm: float = 1.0,
    noise_position_mm: float | None = None,
    attribution: str = "",
) -> Dataset:
    """Import mocap CSVs into the dataset folder ``out`` (see the module docstring).

    ``files``: ``(path, set)`` pairs, ``set`` ``"calibration"`` or ``"validation"``; the hand-eye start uses the
    calibration rows. ``points``: 1-based marker numbers to keep (default all; e.g. ``[1]`` for a single-point
    position-only dataset); the body frame is built from all points. ``noise_position_mm``: the instrument's
    noise per coordinate written to ``[noise]`` (default: none, the estimator estimates it). Returns the
    written :class:`~twin.dataset.Dataset`."""
    from ..urdf import read_urdf_chain

    if not files:
        raise ValueError("files: give at least one (csv, set) pair")
    for _, s in files:
        if s not in ("calibration", "validation"):
            raise ValueError(f"files: set must be 'calibration' or 'validation', got {s!r}")
    if not any(s == "calibration" for _, s in files):
        raise ValueError("files: at least one file must be the calibration (training) set")
    urdf = Path(urdf)
    robot = read_urdf_chain(urdf, root_link, end_link)
    parts = [(read_mocap_csv(p, robot, marker_unit=marker_unit), s) for p, s in files]
    K = parts[0][0].points.shape[1]
    # the body's shape and its placement come from the rows that saw every point; the other rows are kept with
    # their seen points (nothing measured is lost)
    full = [np.isfinite(r.points).all(axis=(1, 2)) for r, _ in parts]
    for (r, _), f in zip(parts, full):
        if r.points.shape[1] != K:
            raise DatasetError(f"{r.path}: {r.points.shape[1]} marker points where {parts[0][0].path} has {K}")
        if not f.any():
            raise DatasetError(f"{r.path}: no row sees all {K} marker points: the body's shape needs rows that see "
                               "every point")
        check_rigid(r.points[f], str(r.path), rigid_tol_mm=rigid_tol_mm, marker_unit=marker_unit)
    P_all = np.concatenate([r.points for r, _ in parts])
    complete = np.concatenate(full)
    d_ref = _pair_distances(P_all[complete][:1])[1][0]
    for (r, _), f in zip(parts, full):
        d = _pair_distances(r.points[f])[1]
        if d.size and np.abs(np.median(d, axis=0) - d_ref).max() > rigid_tol_mm * M_PER_MM:
            raise DatasetError(f"{r.path}: its marker distances differ from {parts[0][0].path}'s by "
                               f"{np.abs(np.median(d, axis=0) - d_ref).max() * MM_PER_M:.3f} mm: another rigid body?")
    if K < 3:
        raise DatasetError(f"{parts[0][0].path}: {K} marker point(s) (x1..z{K}): this import places the body on the "
                           "flange by a hand-eye registration of its frame, which needs 3 points or more; a column map "
                           "(twin import --map, docs/formats.md) fits 1 or 2 points on the flange")
    body, poses = marker_geometry(P_all[complete])
    q_all = np.concatenate([r.q for r, _ in parts])
    sets = np.concatenate([[s] * r.q.shape[0] for r, s in parts])
    cal = sets == "calibration"
    base2meas, tool2flange = hand_eye(flange2base(robot, q_all[cal & complete]), poses[cal[complete]])
    keep = list(range(K)) if points is None else [int(p) - 1 for p in points]
    bad = [p + 1 for p in keep if not 0 <= p < K]
    if bad or not keep:
        raise ValueError(f"points: marker numbers must be in 1..{K}, got {list(points) if points is not None else None}")
    pts_flange = body[keep] @ tool2flange[:3, :3].T + tool2flange[:3, 3]
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    urdf_copy = out / urdf.name
    if urdf.resolve() != urdf_copy.resolve():
        shutil.copyfile(urdf, urdf_copy)
    n = q_all.shape[0]
    extra: dict[str, np.ndarray] = {}
    t_s = None
    names = sorted({h for r, _ in parts for h in r.extra})
    for h in names:
        extra[h] = np.array([v for r, _ in parts for v in r.extra.get(h, [""] * r.q.shape[0])], dtype=object)
    if all(c in extra for c in _TIME_COLUMNS):
        try:
            t_s = np.array([(float(a) + float(b)) / 2 for a, b in zip(extra[_TIME_COLUMNS[0]], extra[_TIME_COLUMNS[1]])])
        except ValueError:
            t_s = None
    extra["session"] = np.array([r.path.stem for r, _ in parts for _ in range(r.q.shape[0])], dtype=object)
    spec = {"urdf": urdf_copy.name, "root_link": root_link, "end_link": end_link}
    lines = [f"imported by twin import from {', '.join(f'{r.path.name} ({s}, {r.q.shape[0]} rows, sha256 {r.sha256})' for r, s in parts)}",
             f"robot: {urdf.name} (sha256 {file_sha256(urdf)}), chain {root_link} -> {end_link} ({robot.n_joints} joints: "
             f"{', '.join(robot.joint_names)})",
             f"markers: points {', '.join(str(p + 1) for p in keep)} of {K} of one tracked rigid body; nominal placement on "
             f"the flange from a closed-form hand-eye registration of the nominal model on the calibration rows "
             f"(a start: base and tool are identified again)"]
    if attribution:
        lines.append(f"data attribution: {attribution}")
    K_keep = len(keep)
    spheres = np.empty((n, K_keep, 3))
    for k in range(n):
        spheres[k] = P_all[k][keep]
    ds = Dataset(
        robot=robot, robot_spec=spec, plate=Plate(0.0, pts_flange), pose_id=np.arange(n, dtype=np.int64), q=q_all,
        spheres=spheres, sphere_seen=np.isfinite(spheres).all(axis=-1), pose=np.full((n, 4, 4), np.nan),
        pose_seen=np.zeros(n, bool), set=sets.astype(object), t_s=t_s, extra=extra,
        noise_position=None if noise_position_mm is None else noise_position_mm * M_PER_MM,
        stations_base2meas={"0": base2meas}, provenance="; ".join(lines), path=out,
    )
    write_dataset(out, ds)
    return ds
