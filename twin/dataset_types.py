"""The dataset's types (``docs/formats.md``): the column names of ``poses.csv``, the marker set (:class:`Plate`,
:func:`default_plate`), the dataset in memory (:class:`Dataset`), its error (:class:`DatasetError`), and the robot
a ``dataset.toml`` names (:func:`robot_from_spec`).

The reader and the writer of the dataset folder are :mod:`twin.dataset`, which re-exports every name of this module.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from .kinematics import RobotModel
from .robots import ROBOTS, check_robot_fields, get_robot
from .units import M_PER_MM, RAD_PER_DEG, deg_to_rad

__all__ = [
    "SCHEMA_VERSION",
    "JOINT_COLUMNS",
    "SPHERE_COLUMNS",
    "LENGTH_UNITS",
    "POSE_COLUMNS",
    "OPTIONAL_COLUMNS",
    "SETS",
    "marker_columns",
    "joint_columns",
    "DatasetError",
    "Plate",
    "default_plate",
    "Dataset",
    "robot_from_spec",
]

SCHEMA_VERSION = 1
JOINT_COLUMNS = tuple(f"q{i}" for i in range(1, 7))
SPHERE_COLUMNS = tuple(f"p{k}_{c}" for k in range(3) for c in "xyz")
# Units of the marker (p<k>_x ...) and pose position (x y z) columns of poses.csv, to metres.
LENGTH_UNITS = {"mm": M_PER_MM, "m": 1.0}


def marker_columns(k: int) -> tuple[str, ...]:
    """The columns ``p0_x .. p<k-1>_z`` of ``k`` marker points."""
    return tuple(f"p{i}_{c}" for i in range(int(k)) for c in "xyz")


def joint_columns(robot: RobotModel) -> tuple[str, ...]:
    """The joint columns of ``robot``'s datasets: its joint names (``q1..q6`` for the 6R conventions)."""
    return tuple(robot.joint_names)

POSE_COLUMNS = ("x", "y", "z", "rx", "ry", "rz")
OPTIONAL_COLUMNS = ("set", "station", "pair", "temp_c", "t_s", "status")
SETS = ("calibration", "validation")


class DatasetError(ValueError):
    """A dataset that cannot be used as it is; the message names the file, row and column."""


@dataclass(frozen=True)
class Plate:
    """The rigid marker set measured on every row: the twin's three-sphere plate, a motion-capture body's
    points, one reflector. ``spheres_flange`` ``(K, 3)`` [m]: nominal points in the flange frame (K >= 1);
    ``sphere_diameter`` [m] (0 for points that are not spheres)."""

    sphere_diameter: float
    spheres_flange: np.ndarray

    def __post_init__(self) -> None:
        s = np.asarray(self.spheres_flange, dtype=float)
        if s.ndim != 2 or s.shape[1] != 3 or s.shape[0] < 1 or not np.all(np.isfinite(s)):
            raise ValueError(f"spheres_flange must be a finite (K, 3) array [m] with K >= 1, got shape {s.shape}")
        if not (np.isfinite(self.sphere_diameter) and self.sphere_diameter >= 0):
            raise ValueError(f"sphere_diameter must be >= 0 [m], got {self.sphere_diameter!r}")
        s.setflags(write=False)
        object.__setattr__(self, "spheres_flange", s)

    @property
    def n_points(self) -> int:
        """K, the number of points."""
        return int(self.spheres_flange.shape[0])

    @property
    def pairs(self) -> tuple[tuple[int, int], ...]:
        """Point pairs ``(a, b)``, ``a < b``, in the order of :attr:`pairwise_distances`."""
        k = self.n_points
        return tuple((a, b) for a in range(k) for b in range(a + 1, k))

    @property
    def pairwise_distances(self) -> np.ndarray:
        """Distances ``(K(K-1)/2,)`` [m] between points (0-1, 0-2, ..., 1-2, ...)."""
        s = self.spheres_flange
        return np.array([np.linalg.norm(s[a] - s[b]) for a, b in self.pairs])


def default_plate() -> Plate:
    """The twin's plate (separation paper section 2.2.2): 25.4 mm spheres on a 60 mm circle at z = 50 mm,
    at 0, 180 and 110 deg (unequal spacing so that the three can be labelled by their distances)."""
    ang = deg_to_rad(np.array([0.0, 180.0, 110.0]))
    s = np.stack([60.0 * np.cos(ang), 60.0 * np.sin(ang), np.full(3, 50.0)], axis=1) * M_PER_MM
    return Plate(25.4 * M_PER_MM, s)


@dataclass(frozen=True, eq=False)
class Dataset:
    """A measured dataset in SI units. ``n`` rows in measurement order.

    ``spheres`` ``(n, K, 3)`` [m] (the K points of ``plate``) and ``pose`` ``(n, 4, 4)`` hold measurements
    only where ``sphere_seen`` ``(n, K)`` / ``pose_seen`` ``(n,)`` say so; elsewhere they are NaN and must not
    be used (every consumer selects with the masks). ``q`` ``(n, N)`` [rad, m for prismatic joints] are the
    commanded joints. ``length_unit``: the unit the file's marker columns were written in (``"mm"``/``"m"``).
    """

    robot: RobotModel
    robot_spec: Any
    plate: Plate
    pose_id: np.ndarray
    q: np.ndarray
    spheres: np.ndarray
    sphere_seen: np.ndarray
    pose: np.ndarray
    pose_seen: np.ndarray
    set: np.ndarray | None = None
    station: np.ndarray | None = None
    pair: np.ndarray | None = None
    temp_c: np.ndarray | None = None
    t_s: np.ndarray | None = None
    status: np.ndarray | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    noise_position: float | None = None
    noise_orientation: float | None = None
    stations_base2meas: dict[str, np.ndarray] = field(default_factory=dict)
    provenance: str = ""
    path: Path | None = None
    length_unit: str = "mm"

    @property
    def n(self) -> int:
        return int(self.q.shape[0])

    @property
    def n_points(self) -> int:
        """K, the number of marker points per row."""
        return int(self.spheres.shape[1])

    @property
    def has_spheres(self) -> bool:
        return bool(self.sphere_seen.any())

    @property
    def has_poses(self) -> bool:
        return bool(self.pose_seen.any())

    @property
    def station_ids(self) -> np.ndarray:
        """Station of every row ``(n,)`` as strings (``"0"`` when the dataset has no station column)."""
        return self.station if self.station is not None else np.full(self.n, "0", dtype=object)

    def subset(self, mask_or_index: np.ndarray) -> "Dataset":
        """Rows selected by a boolean mask ``(n,)`` or an index array, order kept."""
        idx = np.asarray(mask_or_index)
        if idx.dtype == bool:
            if idx.shape != (self.n,):
                raise ValueError(f"mask must have shape ({self.n},), got {idx.shape}")
            idx = np.flatnonzero(idx)

        def take(a):
            return None if a is None else a[idx]

        return replace(
            self,
            pose_id=self.pose_id[idx],
            q=self.q[idx],
            spheres=self.spheres[idx],
            sphere_seen=self.sphere_seen[idx],
            pose=self.pose[idx],
            pose_seen=self.pose_seen[idx],
            set=take(self.set),
            station=take(self.station),
            pair=take(self.pair),
            temp_c=take(self.temp_c),
            t_s=take(self.t_s),
            status=take(self.status),
            extra={k: v[idx] for k, v in self.extra.items()},
        )


# ------------------------------------------------------------------------------------------------
# Robot specs (dataset.toml "robot")
# ------------------------------------------------------------------------------------------------

def robot_from_spec(spec: Any, where: str = "dataset.toml", base_dir: str | os.PathLike | None = None) -> RobotModel:
    """A nominal :class:`RobotModel` from a robot name or a table (``docs/formats.md``): a 6R table
    (``convention = "mdh"``/``"dh"``), a joint table (``convention = "urdf"``, ``joints = [...]``) or a URDF file
    (``urdf = "file.urdf"`` relative to ``base_dir``, ``root_link``, ``end_link``)."""
    if isinstance(spec, str):
        if spec not in ROBOTS:
            raise DatasetError(f"{where}: field 'robot': unknown robot name {spec!r}; known: {', '.join(sorted(ROBOTS))}")
        return get_robot(spec)
    if not isinstance(spec, dict):
        raise DatasetError(f"{where}: field 'robot' must be a robot name or a table, got {type(spec).__name__}")
    try:
        check_robot_fields(spec)
    except ValueError as exc:
        raise DatasetError(f"{where}: {exc}") from None
    if "urdf" in spec:
        from .urdf import read_urdf_chain

        for k in ("root_link", "end_link"):
            if k not in spec:
                raise DatasetError(f"{where}: table 'robot' with a urdf lacks field {k!r}")
        path = Path(str(spec["urdf"]))
        if not path.is_absolute() and base_dir is not None:
            path = Path(base_dir) / path
        try:
            return read_urdf_chain(path, str(spec["root_link"]), str(spec["end_link"]), name=spec.get("name"))
        except ValueError as exc:
            raise DatasetError(f"{where}: table 'robot': {exc}") from None
    if spec.get("convention") == "urdf":
        from .robots import robot_from_joint_table

        try:
            return robot_from_joint_table(spec, where=f"{where}: table 'robot'")
        except DatasetError:
            raise
        except (TypeError, ValueError) as exc:
            raise DatasetError(str(exc)) from None
    need = ("convention", "theta_deg", "d_mm", "a_mm", "alpha_deg")
    for k in need:
        if k not in spec:
            raise DatasetError(f"{where}: table 'robot' lacks field {k!r}")
    try:
        beta_joints = [int(j) for j in spec.get("beta_joints", [])]
        beta_deg = [float(b) for b in spec.get("beta_deg", [0.0] * len(beta_joints))]
        if len(beta_deg) != len(beta_joints):
            raise DatasetError(f"{where}: robot.beta_deg has {len(beta_deg)} values for {len(beta_joints)} beta_joints")
        if spec["convention"] not in ("mdh", "dh"):
            raise DatasetError(f"{where}: robot.convention must be 'mdh', 'dh' or 'urdf', got {spec['convention']!r}")
        arrays = {}
        for k in ("theta_deg", "d_mm", "a_mm", "alpha_deg"):
            v = np.asarray(spec[k], dtype=float)
            if v.ndim != 1 or v.size < 1 or not np.all(np.isfinite(v)):
                raise DatasetError(f"{where}: robot.{k} must be a list of N >= 1 finite numbers (one per joint), "
                                   f"got {spec[k]!r}")
            arrays[k] = v
        n = arrays["theta_deg"].size
        uneven = {k: v.size for k, v in arrays.items() if v.size != n}
        if uneven:
            raise DatasetError(f"{where}: robot.theta_deg has {n} entries but "
                               f"{', '.join(f'robot.{k} has {m}' for k, m in uneven.items())}: every table needs one "
                               "entry per joint")
        bad = [j for j in beta_joints if not 1 <= j <= n]
        if bad:
            raise DatasetError(f"{where}: robot.beta_joints {bad} are not joint numbers of this {n}-joint table "
                               f"(1..{n})")
        kw = {}
        for k in ("q_min_deg", "q_max_deg"):
            if k in spec:
                v = np.asarray(spec[k], dtype=float)
                if v.shape != (n,) or not np.all(np.isfinite(v)):
                    raise DatasetError(f"{where}: robot.{k} must be {n} finite numbers (one per joint), got {spec[k]!r}")
                kw[k[:5]] = v * RAD_PER_DEG
        return RobotModel.from_tables(
            str(spec.get("name", "custom")),
            spec["convention"],
            theta=arrays["theta_deg"] * RAD_PER_DEG,
            d=arrays["d_mm"] * M_PER_MM,
            a=arrays["a_mm"] * M_PER_MM,
            alpha=arrays["alpha_deg"] * RAD_PER_DEG,
            beta={j: b * RAD_PER_DEG for j, b in zip(beta_joints, beta_deg)},
            **kw,
        )
    except DatasetError:
        raise
    except (TypeError, ValueError) as exc:
        raise DatasetError(f"{where}: table 'robot': {exc}") from None
