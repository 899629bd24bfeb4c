"""The result of a calibration: :class:`Calibration`, its file (``calibration.json``, schema_version 1,
``docs/formats.md``), prediction with standard deviations, and the parameter table.

SI inside; the file holds millimetres and degrees (and radians for rotation-vector components of the
station and tool transforms, as ``dataset.toml`` does).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..dataset import Plate
from ..files import read_json
from ..kinematics import RobotModel
from ..transforms import pose6_to_transform, transform_to_pose6
from ..units import M_PER_MM, RAD_PER_DEG
from .chain import Chain
from .identifiability import Combination
from .problem import ParamSpace, predict_points

__all__ = ["Calibration", "Prediction", "CALIBRATION_SCHEMA_VERSION", "parameter_table"]

CALIBRATION_SCHEMA_VERSION = 1


def _display(name: str, unit: str) -> tuple[str, float]:
    """Display unit and factor (SI -> display) of a parameter."""
    return ("mm", 1.0 / M_PER_MM) if unit == "m" else ("deg", 1.0 / RAD_PER_DEG)


@dataclass(frozen=True)
class Prediction:
    """Predicted marker points ``(n, K, 3)`` [m], plate poses ``tool2frame`` ``(n, 4, 4)``, the frame of
    each row (``"measurement"`` or ``"base"``) and standard deviations (same shapes as the points, and
    ``(n, 6)`` for the pose: position [m], rotation vector [rad]) or None without covariance."""

    spheres: np.ndarray
    pose: np.ndarray
    frame: np.ndarray
    station: np.ndarray
    sd_spheres: np.ndarray | None
    sd_pose: np.ndarray | None


@dataclass(frozen=True, eq=False)
class Calibration:
    """An identified robot: parameters with uncertainty, station frames, and how they were obtained.

    ``x`` ``(P,)`` follows ``names`` (robot structure, tool, then ``base_*`` per station; see
    :class:`~twin.estimator.problem.ParamSpace`); ``status[k]`` is ``"identified"``, ``"fixed"`` (held at
    its nominal value: unidentifiable, see ``combinations``) or ``"given"`` (not estimated by this
    method/error model). ``covariance`` ``(P, P)`` [SI] is zero on non-identified parameters.
    """

    method: str
    nominal: RobotModel
    stations: tuple[str, ...]
    x: np.ndarray
    x_nominal: np.ndarray
    status: tuple[str, ...]
    covariance: np.ndarray | None
    plate: Plate
    spheres_tool: np.ndarray
    measurement: str
    noise: dict[str, Any] = field(default_factory=dict)
    combinations: tuple[Combination, ...] = ()
    identifiability: dict[str, Any] = field(default_factory=dict)
    rows: dict[str, Any] = field(default_factory=dict)
    residuals: dict[str, Any] = field(default_factory=dict)
    options: dict[str, Any] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    effects: tuple[dict, ...] = ()
    trace: tuple = ()
    dataset: str = ""
    details: dict[str, Any] = field(default_factory=dict)

    # --- structure -------------------------------------------------------------------------------
    @property
    def space(self) -> ParamSpace:
        sp = self.__dict__.get("_space")
        if sp is None:
            sp = ParamSpace(Chain.of(self.nominal), self.stations)
            object.__setattr__(self, "_space", sp)
        return sp

    @property
    def names(self) -> tuple[str, ...]:
        return self.space.names

    @property
    def std(self) -> np.ndarray:
        """Standard deviations ``(P,)`` [SI]; NaN for parameters that were not identified."""
        if self.covariance is None:
            return np.full(self.x.size, np.nan)
        sd = np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))
        return np.where(np.array(self.status) == "identified", sd, np.nan)

    def value(self, name: str) -> float:
        return float(self.x[self.space.index(name)])

    @property
    def robot(self) -> RobotModel:
        """The identified robot and tool, base frame = identity (the robot base frame of the gauge: the
        parameters fixed at nominal define it)."""
        return self.space.model(self.x, self.nominal, station=None, name=f"{self.nominal.name}-calibrated")

    def model(self, station: str | None = None) -> RobotModel:
        """The identified :class:`RobotModel` with the ``base2meas`` of ``station`` (identity if None)."""
        if station is None:
            return self.robot
        return self.space.model(self.x, self.nominal, station=self.space.station_index(station),
                                name=f"{self.nominal.name}-calibrated@{station}")

    @property
    def base2meas(self) -> dict[str, np.ndarray]:
        """``base2meas`` ``(4, 4)`` per station."""
        return self.space.bases(self.x)

    @property
    def tool2flange(self) -> np.ndarray:
        return pose6_to_transform(self.x[self.space.tool_slice])

    # --- prediction ------------------------------------------------------------------------------
    def predict(self, q: np.ndarray, station: np.ndarray | None = None) -> Prediction:
        """Marker points and tool poses for joints ``q`` ``(n, N)`` [rad, m for prismatic joints].

        Rows whose ``station`` the calibration knows are predicted in that station's measurement frame;
        without a station column, a single-station calibration uses its station; every other row is
        predicted in the robot base frame. Standard deviations propagate the parameter covariance
        (``sd^2 = diag(J C J^T)``): the uncertainty of the model, not the instrument's noise.
        """
        q = np.asarray(q, dtype=float)
        nj = self.nominal.n_joints
        if q.ndim != 2 or q.shape[1] != nj:
            raise ValueError(f"q must have shape (n, {nj}) ({', '.join(self.nominal.joint_names)}), got {q.shape}")
        if not np.all(np.isfinite(q)):
            rows = np.unique(np.nonzero(~np.isfinite(q))[0])
            raise ValueError(f"q contains non-finite values in rows {rows[:10].tolist()}")
        n = q.shape[0]
        sp = self.space
        if station is None:
            st = np.array([self.stations[0] if len(self.stations) == 1 else ""] * n, dtype=object)
        else:
            st = np.asarray(station, dtype=object).astype(str)
            if st.shape != (n,):
                raise ValueError(f"station must have shape ({n},), got {st.shape}")
        known = np.array([s in self.stations for s in st])
        frame = np.where(known, "measurement", "base")
        K = self.spheres_tool.shape[0]
        spheres = np.empty((n, K, 3))
        pose = np.empty((n, 4, 4))
        sd_s = np.full((n, K, 3), np.nan) if self.covariance is not None else None
        sd_p = np.full((n, 6), np.nan) if self.covariance is not None else None
        C = self.covariance
        # Group rows: each known station, then the base frame (a zero base with no base columns).
        groups = [(k, np.flatnonzero(st == s)) for k, s in enumerate(self.stations)]
        groups.append((None, np.flatnonzero(~known)))
        pts_tool = np.concatenate([self.spheres_tool, np.zeros((1, 3)), np.eye(3)], axis=0)
        for k, idx in groups:
            if idx.size == 0:
                continue
            x = self.x.copy()
            sp_use = sp
            if k is None:
                # base frame: evaluate with a one-station space whose base is the identity
                sp_use = ParamSpace(sp.chain, ("base",))
                x = np.concatenate([self.x[: sp.n_rt], np.zeros(6)])
                st_idx = np.zeros(idx.size, dtype=int)
            else:
                st_idx = np.full(idx.size, k)
            pts, Jk = predict_points(sp_use, x, q[idx], st_idx, pts_tool, jacobian=C is not None)
            spheres[idx] = pts[:, :K]
            o = pts[:, K]
            Rcols = pts[:, K + 1:K + 4] - o[:, None, :]
            T = np.zeros((idx.size, 4, 4))
            T[:, :3, :3] = np.swapaxes(Rcols, 1, 2)
            T[:, :3, 3] = o
            T[:, 3, 3] = 1.0
            pose[idx] = T
            if C is not None:
                if k is None:
                    Cu = np.zeros((sp_use.size, sp_use.size))
                    Cu[: sp.n_rt, : sp.n_rt] = C[: sp.n_rt, : sp.n_rt]
                else:
                    Cu = C
                # sphere coordinates
                for s in range(K):
                    Js = Jk[:, s]  # (P, 3, n)
                    sd_s[idx, s] = np.sqrt(np.clip(np.einsum("pcn,pq,qcn->nc", Js, Cu, Js), 0, None))
                sd_p[idx, :3] = np.sqrt(np.clip(np.einsum("pcn,pq,qcn->nc", Jk[:, K], Cu, Jk[:, K]), 0, None))
                # rotation: the rate of the tool frame = (unit-axis points) derivative; use the pose
                # Jacobian's angular rows through the relation d(R e_k) = w x (R e_k)
                Ja = _angular_rows(Jk[:, K + 1:K + 4] - Jk[:, K:K + 1], Rcols)
                sd_p[idx, 3:] = np.sqrt(np.clip(np.einsum("pcn,pq,qcn->nc", Ja, Cu, Ja), 0, None))
        return Prediction(spheres=spheres, pose=pose, frame=frame, station=st, sd_spheres=sd_s, sd_pose=sd_p)

    # --- table -------------------------------------------------------------------------------------
    def table(self) -> list[dict[str, Any]]:
        """One row per parameter: name, unit, nominal, identified, deviation, sd (display units), status."""
        return parameter_table(self)

    # --- file ---------------------------------------------------------------------------------------
    def to_json_dict(self) -> dict[str, Any]:
        sp = self.space
        nom = self.nominal
        params = []
        sd = self.std
        for k, name in enumerate(sp.names):
            unit, f = _display(name, sp.units[k])
            params.append(
                {
                    "name": name,
                    "unit": unit,
                    "nominal": float(self.x_nominal[k] * f),
                    "identified": float(self.x[k] * f),
                    "deviation": float((self.x[k] - self.x_nominal[k]) * f),
                    "sd": None if not np.isfinite(sd[k]) else float(sd[k] * f),
                    "status": self.status[k],
                }
            )
        cov = None
        if self.covariance is not None:
            ident = [k for k, s in enumerate(self.status) if s == "identified"]
            fac = np.array([_display(sp.names[k], sp.units[k])[1] for k in ident])
            C = self.covariance[np.ix_(ident, ident)] * fac[:, None] * fac[None, :]
            cov = {"names": [sp.names[k] for k in ident], "units": "mm and deg", "matrix": C.tolist()}
        return {
            "schema_version": CALIBRATION_SCHEMA_VERSION,
            "kind": "calibration",
            "method": self.method,
            "dataset": self.dataset,
            "measurement": self.measurement,
            "robot": _robot_json(nom),
            "plate": {
                "sphere_diameter_mm": self.plate.sphere_diameter / M_PER_MM,
                "spheres_mm": (self.plate.spheres_flange / M_PER_MM).tolist(),
            },
            "parameters": params,
            "covariance": cov,
            "stations": {s: {"base2meas": _pose_mm(T)} for s, T in self.base2meas.items()},
            "tool2flange": _pose_mm(self.tool2flange),
            "unidentifiable": [
                {"dropped": c.dropped, "kind": c.kind, "terms": [[n, v] for n, v in c.terms], "text": c.describe()}
                for c in self.combinations
            ],
            "fixed": [n for n, s in zip(sp.names, self.status) if s == "fixed"],
            "given": [n for n, s in zip(sp.names, self.status) if s == "given"],
            "identifiability": self.identifiability,
            "noise": self.noise,
            "rows": self.rows,
            "residuals": self.residuals,
            "options": self.options,
            "notes": list(self.notes),
            "effects": list(self.effects),
            "details": self.details,
        }

    def save(self, path: str | os.PathLike) -> Path:
        """Write ``calibration.json`` (atomic)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(path.suffix + ".tmp")
        tmp.write_text(json.dumps(_jsonable(self.to_json_dict()), indent=2) + "\n")
        os.replace(tmp, path)
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Calibration":
        """Read ``calibration.json``; ``ValueError`` naming the file and the field when it is not valid."""
        path = Path(path)
        if path.is_dir():
            inside = " (it holds calibration.json: give that file)" if (path / "calibration.json").is_file() else (
                ": twin calibrate DATASET --out DIR (or twin diagnose) writes DIR/calibration.json")
            raise ValueError(f"{path}: a folder, not a calibration.json{inside}")
        return cls.from_json_dict(read_json(path), where=str(path))

    @classmethod
    def from_json_dict(cls, d: dict, where: str = "calibration.json") -> "Calibration":
        if not isinstance(d, dict):
            raise ValueError(f"{where}: not a calibration (a JSON object expected, got {type(d).__name__})")
        ver = d.get("schema_version")
        if ver != CALIBRATION_SCHEMA_VERSION:
            raise ValueError(f"{where}: schema_version {ver!r} is not supported (this library reads {CALIBRATION_SCHEMA_VERSION})")
        try:
            rb = d["robot"]
            nominal = _robot_from_json(rb)
            tool = _pose_from_mm(rb["nominal"]["tool2flange"])
            stations = tuple(d["stations"].keys())
            sp = ParamSpace(Chain.of(nominal), stations)
            by_name = {p["name"]: p for p in d["parameters"]}
            missing = [n for n in sp.names if n not in by_name]
            if missing:
                raise ValueError(f"parameters lack {missing}")
            x = np.empty(sp.size)
            x0 = np.empty(sp.size)
            status = []
            for k, n in enumerate(sp.names):
                _, f = _display(n, sp.units[k])
                x[k] = float(by_name[n]["identified"]) / f
                x0[k] = float(by_name[n]["nominal"]) / f
                status.append(str(by_name[n]["status"]))
            cov = None
            if d.get("covariance"):
                cn = d["covariance"]["names"]
                M = np.asarray(d["covariance"]["matrix"], dtype=float)
                cov = np.zeros((sp.size, sp.size))
                ii = [sp.index(n) for n in cn]
                fac = np.array([_display(n, sp.units[sp.index(n)])[1] for n in cn])
                cov[np.ix_(ii, ii)] = M / fac[:, None] / fac[None, :]
            plate = Plate(float(d["plate"]["sphere_diameter_mm"]) * M_PER_MM, np.asarray(d["plate"]["spheres_mm"], float) * M_PER_MM)
            Tinv = np.linalg.inv(tool)
            spheres_tool = plate.spheres_flange @ Tinv[:3, :3].T + Tinv[:3, 3]
            combos = tuple(
                Combination(dropped=c["dropped"], kind=c["kind"], terms=tuple((str(n), float(v)) for n, v in c["terms"]))
                for c in d.get("unidentifiable", [])
            )
            _check_finite(nominal=nominal.params, q_min=nominal.q_min, q_max=nominal.q_max,
                          tool2flange=tool, parameters=x, nominal_parameters=x0, plate=plate.spheres_flange,
                          sphere_diameter=plate.sphere_diameter, covariance=cov)
            if not np.all(nominal.q_min < nominal.q_max):
                raise ValueError("robot: q_min_deg must be below q_max_deg for every joint")
            opt = {}
            for key, typ in (("noise", dict), ("identifiability", dict), ("rows", dict), ("residuals", dict),
                             ("options", dict), ("details", dict), ("notes", list), ("effects", list)):
                v = d.get(key, typ())
                if not isinstance(v, typ):
                    raise ValueError(f"field {key!r} must be a {'table' if typ is dict else 'list'}, got {v!r:.40}")
                opt[key] = v
            for key in ("method", "measurement", "dataset"):
                if not isinstance(d.get(key, ""), str):
                    raise ValueError(f"field {key!r} must be text, got {d[key]!r:.40}")
            if not isinstance(rb["name"], str) or not isinstance(rb["convention"], str):
                raise ValueError("robot: fields 'name' and 'convention' must be text")
        except KeyError as exc:
            raise ValueError(f"{where}: missing field {exc}") from None
        except (TypeError, ValueError, AttributeError, IndexError, OverflowError) as exc:
            raise ValueError(f"{where}: {exc}") from None
        return cls(
            method=str(d.get("method", "")),
            nominal=nominal,
            stations=stations,
            x=x,
            x_nominal=x0,
            status=tuple(status),
            covariance=cov,
            plate=plate,
            spheres_tool=spheres_tool,
            measurement=str(d.get("measurement", "")),
            noise=opt["noise"],
            combinations=combos,
            identifiability=opt["identifiability"],
            rows=opt["rows"],
            residuals=opt["residuals"],
            options=opt["options"],
            notes=tuple(str(n) for n in opt["notes"]),
            effects=tuple(opt["effects"]),
            dataset=str(d.get("dataset", "")),
            details=opt["details"],
        )


def _robot_json(nom: RobotModel) -> dict[str, Any]:
    """The ``robot`` field of calibration.json: 6R DH tables, or a chain's joint table (``docs/formats.md``)."""
    if nom.convention == "urdf":
        from ..robots import joint_table

        scale = np.where(nom.is_prismatic, 1.0 / M_PER_MM, 1.0 / RAD_PER_DEG)
        return {"name": nom.name, "convention": "urdf", "joint_names": list(nom.joint_names),
                "joint_units": ["mm" if p else "deg" for p in nom.is_prismatic],
                "table": joint_table(nom), "nominal": {"tool2flange": _pose_mm(nom.tool2flange)},
                "q_min": (nom.q_min * scale).tolist(), "q_max": (nom.q_max * scale).tolist()}
    return {
        "name": nom.name,
        "convention": nom.convention,
        "beta_joints": list(nom.beta_joints),
        "nominal": {
            "theta_deg": (nom.theta / RAD_PER_DEG).tolist(),
            "d_mm": (nom.d / M_PER_MM).tolist(),
            "a_mm": (nom.a / M_PER_MM).tolist(),
            "alpha_deg": (nom.alpha / RAD_PER_DEG).tolist(),
            "beta_deg": [float(nom.param(f"beta{j}") / RAD_PER_DEG) for j in nom.beta_joints],
            "tool2flange": _pose_mm(nom.tool2flange),
        },
        "q_min_deg": (nom.q_min / RAD_PER_DEG).tolist(),
        "q_max_deg": (nom.q_max / RAD_PER_DEG).tolist(),
    }


def _robot_from_json(rb: dict) -> RobotModel:
    """Inverse of :func:`_robot_json` (KeyError / ValueError on a malformed field)."""
    nomd = rb["nominal"]
    tool = _pose_from_mm(nomd["tool2flange"])
    if rb["convention"] == "urdf":
        from ..robots import robot_from_joint_table

        m = robot_from_joint_table(rb["table"], where="robot.table")
        scale = np.where(m.is_prismatic, M_PER_MM, RAD_PER_DEG)
        lo = np.asarray(rb["q_min"], float) * scale
        hi = np.asarray(rb["q_max"], float) * scale
        return replace(m.with_frames(tool2flange=tool), q_min=lo, q_max=hi)
    return RobotModel.from_tables(
        rb["name"],
        rb["convention"],
        theta=np.asarray(nomd["theta_deg"], float) * RAD_PER_DEG,
        d=np.asarray(nomd["d_mm"], float) * M_PER_MM,
        a=np.asarray(nomd["a_mm"], float) * M_PER_MM,
        alpha=np.asarray(nomd["alpha_deg"], float) * RAD_PER_DEG,
        beta={int(j): float(b) * RAD_PER_DEG for j, b in zip(rb["beta_joints"], nomd["beta_deg"])},
        tool2flange=tool,
        q_min=np.asarray(rb["q_min_deg"], float) * RAD_PER_DEG,
        q_max=np.asarray(rb["q_max_deg"], float) * RAD_PER_DEG,
    )


def _angular_rows(Jaxes: np.ndarray, Rcols: np.ndarray) -> np.ndarray:
    """Angular-rate Jacobian ``(P, 3, n)`` from the Jacobians of the three unit axes ``(P, 3 axes, 3, n)``
    (``d(R e_k) = w x R e_k``; ``w = 1/2 sum_k (R e_k) x d(R e_k)``)."""
    w = np.zeros((Jaxes.shape[0], 3, Jaxes.shape[-1]))
    for k in range(3):
        a = Rcols[:, k]  # (n, 3)
        d = Jaxes[:, k]  # (P, 3, n)
        w += np.stack([a[:, 1] * d[:, 2] - a[:, 2] * d[:, 1], a[:, 2] * d[:, 0] - a[:, 0] * d[:, 2],
                       a[:, 0] * d[:, 1] - a[:, 1] * d[:, 0]], axis=1)
    return 0.5 * w


def _pose_mm(T: np.ndarray) -> dict[str, float]:
    v = transform_to_pose6(T)
    return {"x_mm": float(v[0] / M_PER_MM), "y_mm": float(v[1] / M_PER_MM), "z_mm": float(v[2] / M_PER_MM),
            "rx_rad": float(v[3]), "ry_rad": float(v[4]), "rz_rad": float(v[5])}


def _check_finite(**arrays) -> None:
    """ValueError naming the first field that holds a non-finite number (None fields are skipped)."""
    for name, a in arrays.items():
        if a is not None and not np.all(np.isfinite(np.asarray(a, dtype=float))):
            raise ValueError(f"{name}: not finite (NaN or infinity in the file)")


def _pose_from_mm(d: dict) -> np.ndarray:
    return pose6_to_transform(np.array([d["x_mm"] * M_PER_MM, d["y_mm"] * M_PER_MM, d["z_mm"] * M_PER_MM, d["rx_rad"], d["ry_rad"], d["rz_rad"]], float))


def _jsonable(o):
    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, np.ndarray):
        return _jsonable(o.tolist())
    if isinstance(o, (np.floating,)):
        o = float(o)
    if isinstance(o, float):
        return o if math.isfinite(o) else None
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.bool_,)):
        return bool(o)
    return o


def parameter_table(cal: Calibration) -> list[dict[str, Any]]:
    """Rows ``{name, unit, nominal, identified, deviation, sd, status}`` in display units (mm, deg)."""
    sp = cal.space
    sd = cal.std
    out = []
    for k, n in enumerate(sp.names):
        unit, f = _display(n, sp.units[k])
        out.append(
            {
                "name": n,
                "unit": unit,
                "nominal": cal.x_nominal[k] * f,
                "identified": cal.x[k] * f,
                "deviation": (cal.x[k] - cal.x_nominal[k]) * f,
                "sd": sd[k] * f if np.isfinite(sd[k]) else float("nan"),
                "status": cal.status[k],
            }
        )
    return out

