"""The identification problem: parameter space (robot, tool, one base per station), observations taken
from a :class:`~twin.dataset.Dataset`, and whitened residuals with their analytic Jacobians.

Residual kinds (every residual is ``(measured - predicted) / sigma``, so a correct model with the stated
noise gives unit-variance residuals):

* ``spheres`` (absolute): the three sphere centres of a row in its station's measurement frame, one
  residual per seen coordinate, ``sigma = sigma_position``. This is the statistically right residual for
  the stereo instrument: it measures sphere centres with (nearly) independent noise per coordinate; a pose
  derived from three spheres has correlated, anisotropic noise.
* ``pose`` (absolute): position of the tool origin (``sigma_position``) and ``log(R_meas R_pred^T)``
  (``sigma_orientation``), for 6-DOF instruments (laser-tracker probe; the TM-MDH paper's data).
* ``distance`` (pairs): ``|p_i - p_j|_meas - |p_i - p_j|_pred`` per sphere (or tool origin) of a motion
  pair, ``sigma = sqrt(2) sigma_position``; invariant to the base, so it needs no registration.
* ``rotation_change`` (pairs): ``log(Q_meas Q_pred^T)`` with ``Q = R_i^T R_j`` (the rotation of the motion
  seen in the tool frame at its start), ``sigma = sqrt(2) sigma_orientation``; invariant to the base.
* ``euler_change`` (pairs, the separation paper's eq. 23-27, 43): difference of the ZYX Euler angles of
  the tool in the *base* frame between the pair's end and start, measured minus predicted. The measured
  orientations are brought into the base frame with a given base rotation (from ``dataset.toml`` or a
  registration: the paper's ``R_bc``); kept for faithful reproduction.

Jacobians are derivatives of the *predicted* quantity (so ``r(x + dx) ~ r(x) - J dx / sigma``; the
returned ``J`` is already divided by sigma).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from ..dataset import Dataset
from ..kinematics import RobotModel
from ..transforms import (
    euler_zyx_from_matrix,
    kabsch,
    matrix_to_rotvec,
    pose6_to_transform,
    transform_to_pose6,
)
from .chain import Chain
from .memo import KeptResults, array_key

__all__ = [
    "ParamSpace",
    "Observations",
    "Residuals",
    "observations_from_dataset",
    "absolute_residuals",
    "predict_points",
    "pair_residuals",
    "make_pairs",
    "plate_pose_from_spheres",
    "station_eval",
    "kabsch",  # the foundation's rigid fit (twin.transforms), re-exported for the estimator's callers
]

MeasurementKind = Literal["spheres", "pose"]


# ------------------------------------------------------------------------------------------------
# Parameter space
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class ParamSpace:
    """Names and positions of the estimated vector: robot structure, tool, then one base per station.

    Order: the foundation layout without the base (the chain's structural parameters, for a 6R chain
    ``theta1..6, d1..6, a1..6, alpha1..6, beta_j``; then ``tool_x..tool_rz``), then ``base_x..base_rz`` of every
    station (named ``base_x@<station>`` when the data have more than one station). Units SI ([m], [rad]).
    """

    chain: Chain
    stations: tuple[str, ...]
    names: tuple[str, ...] = field(init=False)
    units: tuple[str, ...] = field(init=False)

    def __post_init__(self) -> None:
        if not self.stations:
            raise ValueError("stations must name at least one station")
        comp = ("x", "y", "z", "rx", "ry", "rz")
        base = []
        for s in self.stations:
            suffix = "" if len(self.stations) == 1 else f"@{s}"
            base += [f"base_{c}{suffix}" for c in comp]
        names = tuple(self.chain.rt_names) + tuple(base)
        lay = self.chain.layout
        units = tuple(lay._unit(n.split("@")[0]) for n in names)
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "units", units)

    @property
    def size(self) -> int:
        return len(self.names)

    @property
    def n_rt(self) -> int:
        return self.chain.n_rt

    @property
    def n_robot(self) -> int:
        return self.chain.n_robot

    @property
    def tool_slice(self) -> slice:
        return self.chain.tool_slice

    def base_slice(self, station: int) -> slice:
        i = self.n_rt + 6 * int(station)
        return slice(i, i + 6)

    @property
    def is_length(self) -> np.ndarray:
        return np.array([u == "m" for u in self.units])

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f"unknown parameter name {name!r}; known: {', '.join(self.names)}") from None

    def station_index(self, station: str) -> int:
        try:
            return self.stations.index(str(station))
        except ValueError:
            raise ValueError(f"unknown station {station!r}; known: {list(self.stations)}") from None

    def family(self, fam: str) -> np.ndarray:
        """Indices of a structural family ('theta', 'd', 'a', 'alpha', 'beta' of a 6R chain; 'offset', 'x', ...,
        'rz' of a "urdf" chain), 'joint' (the parameter each joint's command adds to), 'tool', 'base' (all
        stations) or 'structure'."""
        if fam == "structure":
            return np.arange(self.n_robot)
        if fam == "tool":
            return np.arange(self.tool_slice.start, self.tool_slice.stop)
        if fam == "base":
            return np.arange(self.n_rt, self.size)
        if fam == "joint":
            return np.array([self.index(n) for n in self.chain.structure.joint_params], int)
        lay = self.chain.layout
        return np.array([i for i, n in enumerate(self.names[: self.n_robot]) if lay.family_of(n) == fam], int)

    def angle_mask(self) -> np.ndarray:
        """Parameters in [rad]: theta, alpha, beta, tool and base rotations."""
        return ~self.is_length

    # --- conversions ---------------------------------------------------------------------------------
    def from_model(self, model: RobotModel, bases: dict[str, np.ndarray] | None = None) -> np.ndarray:
        """Vector from a model (robot + tool) and ``base2meas`` ``(4, 4)`` per station (default: the model's)."""
        if model.convention != self.chain.convention or tuple(model.beta_joints) != self.chain.beta_joints or \
                model.layout.names != self.chain.layout.names:
            raise ValueError(
                f"model {model.name!r} ({model.convention}, beta {model.beta_joints}) does not match the parameter "
                f"space ({self.chain.convention}, beta {self.chain.beta_joints})"
            )
        rt, b = self.chain.split_full(model.params)
        x = np.empty(self.size)
        x[: self.n_rt] = rt
        for k, s in enumerate(self.stations):
            x[self.base_slice(k)] = transform_to_pose6(bases[s]) if bases and s in bases else b
        return x

    def model(self, x: np.ndarray, template: RobotModel, station: int | None = None, name: str | None = None) -> RobotModel:
        """A :class:`RobotModel` (limits from ``template``) with this vector's robot and tool and the base of
        ``station`` (index), or an identity base when ``station`` is None."""
        x = np.asarray(x, dtype=float)
        base = np.zeros(6) if station is None else x[self.base_slice(station)]
        return template.with_params(self.chain.join_full(x[: self.n_rt], base), name=name or template.name)

    def bases(self, x: np.ndarray) -> dict[str, np.ndarray]:
        """``base2meas`` ``(4, 4)`` per station name."""
        return {s: pose6_to_transform(x[self.base_slice(k)]) for k, s in enumerate(self.stations)}


# ------------------------------------------------------------------------------------------------
# Observations
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Observations:
    """Measured rows in SI units, ready for residuals.

    ``kind`` ``"spheres"``: ``spheres`` ``(n, K, 3)`` [m] (K marker points) with ``seen`` ``(n, K)``;
    ``"pose"``: ``pose_R`` ``(n, 3, 3)`` and ``pose_p`` ``(n, 3)`` [m] (tool2meas). ``q`` ``(n, N)``.
    ``station`` ``(n,)`` indexes ``station_names``. ``spheres_tool`` ``(K, 3)`` [m]: the points in the tool
    frame.
    """

    kind: MeasurementKind
    q: np.ndarray
    station: np.ndarray
    station_names: tuple[str, ...]
    pose_id: np.ndarray
    spheres_tool: np.ndarray
    sigma_position: float
    sigma_orientation: float
    spheres: np.ndarray | None = None
    seen: np.ndarray | None = None
    pose_R: np.ndarray | None = None
    pose_p: np.ndarray | None = None
    pair: np.ndarray | None = None

    @property
    def n(self) -> int:
        return int(self.q.shape[0])

    def subset(self, idx: np.ndarray) -> "Observations":
        idx = np.asarray(idx)
        if idx.dtype == bool:
            idx = np.flatnonzero(idx)

        def take(a):
            return None if a is None else a[idx]

        return replace(
            self,
            q=self.q[idx],
            station=self.station[idx],
            pose_id=self.pose_id[idx],
            spheres=take(self.spheres),
            seen=take(self.seen),
            pose_R=take(self.pose_R),
            pose_p=take(self.pose_p),
            pair=take(self.pair),
        )

    def with_sigma(self, sigma_position: float | None = None, sigma_orientation: float | None = None) -> "Observations":
        return replace(
            self,
            sigma_position=self.sigma_position if sigma_position is None else float(sigma_position),
            sigma_orientation=self.sigma_orientation if sigma_orientation is None else float(sigma_orientation),
        )

    def as_poses(self) -> "Observations":
        """Pose observations: unchanged for pose data; for marker data the rigid body's pose in every row with all
        K points (rigid registration of its geometry onto them; K >= 3 points not on one line). The pose noise is
        derived from the point noise (centroid: ``sigma / sqrt(K)``; rotation: ``sigma`` over the body's RMS
        radius, times ``sqrt(2 / K)``: for the plate's K = 3 the factor ``1 / sqrt(1.5)``)."""
        if self.kind == "pose":
            return self
        k = self.spheres_tool.shape[0]
        c0 = self.spheres_tool - self.spheres_tool.mean(axis=0)
        if k < 3 or np.linalg.svd(c0, compute_uv=False)[1] < 1e-6 * max(np.abs(c0).max(), 1e-12):
            raise ValueError(f"a pose needs at least 3 marker points not on one line; this marker set has {k}")
        full = self.seen.all(axis=1)
        sub = self.subset(full)
        R, p = plate_pose_from_spheres(sub.spheres, self.spheres_tool)
        c = self.spheres_tool - self.spheres_tool.mean(axis=0)
        rad = float(np.sqrt(np.mean(np.sum(c**2, axis=1))))
        return replace(
            sub,
            kind="pose",
            pose_R=R,
            pose_p=p,
            spheres=None,
            seen=None,
            sigma_position=self.sigma_position / np.sqrt(float(k)),
            sigma_orientation=self.sigma_position / max(rad, 1e-9) / np.sqrt(k / 2.0),
        )


def plate_pose_from_spheres(spheres_meas: np.ndarray, spheres_tool: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Plate (tool) poses ``(R (n, 3, 3), p (n, 3))`` in the measurement frame from measured points
    ``(n, K, 3)`` and the marker geometry ``(K, 3)`` in the tool frame."""
    A = np.broadcast_to(np.asarray(spheres_tool, dtype=float), np.shape(spheres_meas))
    return kabsch(A, spheres_meas)


def observations_from_dataset(
    ds: Dataset,
    *,
    measurement: Literal["auto", "spheres", "pose"] = "auto",
    sigma_position: float | None = None,
    sigma_orientation: float | None = None,
    tool2flange_nominal: np.ndarray | None = None,
) -> tuple[Observations, np.ndarray, list[tuple[int, str]]]:
    """Observations from a dataset.

    Returns ``(obs, rows, skipped)``: ``rows`` are the dataset row indices kept, ``skipped`` a list of
    ``(row index, reason)`` for rows without a usable measurement. ``measurement="auto"`` uses the spheres
    when the dataset has any (the raw measurement; a pose column next to them is usually derived from
    them) and the 6-DOF pose otherwise. Noise: the arguments, else ``dataset.toml``'s ``[noise]``, else a
    placeholder of 0.01 mm / 1e-4 rad (the estimator then estimates it from the residuals).
    """
    if measurement not in ("auto", "spheres", "pose"):
        raise ValueError(f"measurement must be 'auto', 'spheres' or 'pose', got {measurement!r}")
    kind = measurement
    if kind == "auto":
        kind = "spheres" if ds.has_spheres else "pose"
    if kind == "spheres" and not ds.has_spheres:
        raise ValueError(f"measurement='spheres' but dataset {ds.path} has no sphere centres")
    if kind == "pose" and not ds.has_poses:
        raise ValueError(f"measurement='pose' but dataset {ds.path} has no 6-DOF pose columns")
    skipped: list[tuple[int, str]] = []
    if kind == "spheres":
        usable = ds.sphere_seen.any(axis=1)
        for i in np.flatnonzero(~usable):
            why = "" if ds.status is None else str(ds.status[i])
            skipped.append((int(i), f"no sphere measured{': ' + why if why else ''}"))
    else:
        usable = ds.pose_seen.copy()
        for i in np.flatnonzero(~usable):
            why = "" if ds.status is None else str(ds.status[i])
            skipped.append((int(i), f"no pose measured{': ' + why if why else ''}"))
    rows = np.flatnonzero(usable)
    st_all = ds.station_ids
    names = tuple(sorted({str(s) for s in st_all[rows]}, key=_station_key))
    st_idx = np.array([names.index(str(s)) for s in st_all[rows]], dtype=int)
    T0 = np.eye(4) if tool2flange_nominal is None else np.asarray(tool2flange_nominal, dtype=float)
    # Plate geometry is given in the flange frame; the tool frame is the plate frame, whose nominal
    # placement on the flange is the robot's nominal tool2flange.
    s_fl = ds.plate.spheres_flange
    Tinv = np.linalg.inv(T0)
    spheres_tool = s_fl @ Tinv[:3, :3].T + Tinv[:3, 3]
    sp = sigma_position if sigma_position is not None else ds.noise_position
    so = sigma_orientation if sigma_orientation is not None else ds.noise_orientation
    for name, v in (("noise position", sp), ("noise orientation", so)):
        if v is not None and not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a positive number (dataset.toml [noise] or the argument), got {v!r}")
    obs = Observations(
        kind=kind,
        q=ds.q[rows],
        station=st_idx,
        station_names=names,
        pose_id=ds.pose_id[rows],
        spheres_tool=spheres_tool,
        sigma_position=float(sp) if sp is not None else 1e-5,
        sigma_orientation=float(so) if so is not None else 1e-4,
        spheres=ds.spheres[rows] if kind == "spheres" else None,
        seen=ds.sphere_seen[rows] if kind == "spheres" else None,
        pose_R=ds.pose[rows, :3, :3] if kind == "pose" else None,
        pose_p=ds.pose[rows, :3, 3] if kind == "pose" else None,
        pair=None if ds.pair is None else ds.pair[rows],
    )
    return obs, rows, skipped


def _station_key(s: str):
    try:
        return (0, int(s), s)
    except ValueError:
        return (1, 0, s)


# ------------------------------------------------------------------------------------------------
# Residuals
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Residuals:
    """Whitened residuals ``r`` ``(m,)``, Jacobian ``J`` ``(m, P)`` of the *prediction* (whitened), the
    observation row of every residual ``row`` ``(m,)`` and its block ``block`` ``(m,)`` (0 position-like,
    1 orientation-like)."""

    r: np.ndarray
    J: np.ndarray | None
    row: np.ndarray
    block: np.ndarray


def station_eval(space: ParamSpace, x: np.ndarray, q: np.ndarray, station: np.ndarray, jacobian: bool):
    """Per-row tool poses ``R (n, 3, 3)``, ``p (n, 3)`` in the rows' measurement frames and, with
    ``jacobian``, ``J (P, 6, n)`` over the whole space (parameter-major)."""
    n = q.shape[0]
    R = np.empty((n, 3, 3))
    p = np.empty((n, 3))
    J = np.zeros((space.size, 6, n)) if jacobian else None
    rt = x[: space.n_rt]
    for s in np.unique(station):
        idx = np.flatnonzero(station == s)
        bs = space.base_slice(s)
        ev = space.chain.evaluate(rt, q[idx], base6=x[bs], jacobian=jacobian)
        R[idx] = ev.R[0]
        p[idx] = ev.p[0]
        if jacobian:
            if idx.size == n:
                J[: space.n_rt] = ev.J[0, : space.n_rt]
                J[bs] = ev.J[0, space.n_rt:]
            else:
                J[: space.n_rt, :, idx] = ev.J[0, : space.n_rt]
                J[bs, :, idx] = ev.J[0, space.n_rt:]
    return R, p, J


# the latest predictions, given again for the same space and inputs (a refit starts where the last fit ended; models
# that differ in their effect terms alone evaluate the geometry at the same point): 8 of them, at most 32 MB
_PREDICTIONS = KeptResults(8, 1 << 25)


def predict_points(space: ParamSpace, x: np.ndarray, q: np.ndarray, station: np.ndarray, points_tool: np.ndarray,
                   jacobian: bool = False):
    """Points fixed in the tool frame ``(k, 3)`` [m] seen in the rows' measurement frames: ``(n, k, 3)``,
    and with ``jacobian`` their Jacobian ``(P, k, 3, n)``. The latest few are kept and given again for the same space
    and the same inputs to the bit (read-only arrays; without the Jacobian, the points of an evaluation with it)."""
    base = (id(space), array_key(x), array_key(q), array_key(station), array_key(points_tool))
    got = _PREDICTIONS.get(base + (True,))
    if got is None and not jacobian:
        got = _PREDICTIONS.get(base + (False,))
    if got is not None:
        return got if jacobian else (got[0], None)
    return _PREDICTIONS.put(base + (jacobian,), _predict_points(space, x, q, station, points_tool, jacobian), (space,))


def _predict_points(space: ParamSpace, x: np.ndarray, q: np.ndarray, station: np.ndarray, points_tool: np.ndarray,
                    jacobian: bool):
    """:func:`predict_points` computed."""
    R, p, J = station_eval(space, x, q, station, jacobian)
    v = np.einsum("nij,kj->nki", R, points_tool)  # (n, k, 3): R s_k
    pts = p[:, None, :] + v
    if not jacobian:
        return pts, None
    Jk = np.empty((space.size, points_tool.shape[0], 3, q.shape[0]))
    tmp = np.empty((space.size, q.shape[0]))
    for k in range(points_tool.shape[0]):
        # d(p + R s) = dp + w x (R s) = dp - (R s) x w, component by component into Jk without temporaries:
        # component c is J_c - (v_a w_b - v_b w_a) for (c, a, b) cyclic
        for c, (a, b) in enumerate(((1, 2), (2, 0), (0, 1))):
            out = Jk[:, k, c]
            np.multiply(v[:, k, a], J[:, 3 + b], out=out)
            np.multiply(v[:, k, b], J[:, 3 + a], out=tmp)
            np.subtract(out, tmp, out=out)
            np.subtract(J[:, c], out, out=out)
    return pts, Jk


def absolute_residuals(
    space: ParamSpace,
    x: np.ndarray,
    obs: Observations,
    *,
    jacobian: bool = True,
    part: Literal["full", "position", "orientation"] = "full",
) -> Residuals:
    """Whitened absolute residuals (spheres or poses in the measurement frames) and their Jacobian.

    ``part`` selects the position rows, the orientation rows or both (pose data). For sphere data
    ``"orientation"`` is not defined (use :meth:`Observations.as_poses`).
    """
    if obs.kind == "spheres":
        if part == "orientation":
            raise ValueError("part='orientation' needs pose observations (Observations.as_poses())")
        pts, Jk = predict_points(space, x, obs.q, obs.station, obs.spheres_tool, jacobian)
        # order: (sphere k, coordinate c, row i)
        res = (np.transpose(obs.spheres, (1, 2, 0)) - np.transpose(pts, (1, 2, 0))) / obs.sigma_position
        mask = np.broadcast_to(obs.seen.T[:, None, :], res.shape)
        rows = np.broadcast_to(np.arange(obs.n)[None, None, :], res.shape)
        r = res[mask]
        J = None
        if jacobian:
            J = (Jk / obs.sigma_position)[:, mask].T
        return Residuals(r=r, J=J, row=rows[mask], block=np.zeros(r.size, dtype=int))
    R, p, Jp = station_eval(space, x, obs.q, obs.station, jacobian)
    blocks = []
    if part in ("full", "position"):
        blocks.append(0)
    if part in ("full", "orientation"):
        blocks.append(1)
    rs, Js, rows, blk = [], [], [], []
    for b in blocks:
        if b == 0:
            e = (obs.pose_p - p) / obs.sigma_position  # (n, 3)
            Jb = None if Jp is None else Jp[:, :3] / obs.sigma_position
        else:
            e = matrix_to_rotvec(obs.pose_R @ np.swapaxes(R, -1, -2)) / obs.sigma_orientation
            Jb = None if Jp is None else Jp[:, 3:] / obs.sigma_orientation
        rs.append(e.T.reshape(-1))
        rows.append(np.tile(np.arange(obs.n), 3))
        blk.append(np.full(3 * obs.n, b))
        if Jb is not None:
            Js.append(Jb.reshape(space.size, -1).T)
    return Residuals(
        r=np.concatenate(rs),
        J=np.concatenate(Js) if jacobian else None,
        row=np.concatenate(rows),
        block=np.concatenate(blk),
    )


# ------------------------------------------------------------------------------------------------
# Pair residuals (the separation paper's constraints)
# ------------------------------------------------------------------------------------------------

def make_pairs(obs: Observations) -> tuple[np.ndarray, str]:
    """Motion pairs ``(k, 2)`` of row indices and how they were formed.

    With a ``pair`` column: rows sharing an id, in measurement order (start, end); an id on more than two
    rows links consecutive rows of that id. Without it: consecutive rows of the same station. A pair whose
    ends were measured by different stations is skipped (its distance would mix two measurement frames).
    """
    pairs = []
    skipped = 0
    if obs.pair is not None and np.any(obs.pair >= 0):
        for pid in np.unique(obs.pair[obs.pair >= 0]):
            idx = np.flatnonzero(obs.pair == pid)
            for k in range(len(idx) - 1):
                if obs.station[idx[k]] == obs.station[idx[k + 1]]:
                    pairs.append((idx[k], idx[k + 1]))
                else:
                    skipped += 1
        how = "the dataset's 'pair' column"
    else:
        for s in np.unique(obs.station):
            idx = np.flatnonzero(obs.station == s)
            pairs += [(idx[k], idx[k + 1]) for k in range(len(idx) - 1)]
        how = "consecutive rows of each station (the dataset has no 'pair' column)"
    if skipped:
        how += f"; {skipped} pair(s) across two stations skipped"
    return np.array(pairs, dtype=int).reshape(-1, 2), how


def _euler_rate_inverse(E: np.ndarray) -> np.ndarray:
    """``M^-1`` ``(n, 3, 3)`` mapping a spatial angular rate to ZYX Euler rates ``(rx, ry, rz)``.

    ``R = Rz(c) Ry(b) Rx(a)``: ``w = a' Rz(c) Ry(b) e_x + b' Rz(c) e_y + c' e_z``.
    """
    a, b, c = E[:, 0], E[:, 1], E[:, 2]
    cb, sb, cc, sc = np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    M = np.zeros((E.shape[0], 3, 3))
    M[:, :, 0] = np.stack([cc * cb, sc * cb, -sb], axis=-1)
    M[:, :, 1] = np.stack([-sc, cc, np.zeros_like(c)], axis=-1)
    M[:, 2, 2] = 1.0
    return np.linalg.inv(M)


def pair_residuals(
    space: ParamSpace,
    x: np.ndarray,
    obs: Observations,
    pairs: np.ndarray,
    kind: Literal["distance", "rotation_change", "euler_change"],
    *,
    jacobian: bool = True,
    base2meas: dict[int, np.ndarray] | None = None,
) -> Residuals:
    """Whitened pair residuals (see the module docstring) and their Jacobian ``(m, P)``.

    ``euler_change`` needs the base rotation of every station (``base2meas`` ``(4, 4)`` by station index).
    """
    i, j = pairs[:, 0], pairs[:, 1]
    k = len(pairs)
    if k == 0:
        raise ValueError("no motion pairs: the method needs at least one pair of rows")
    if kind == "distance":
        sig = np.sqrt(2.0) * obs.sigma_position
        if obs.kind == "spheres":
            pts, Jk = predict_points(space, x, obs.q, obs.station, obs.spheres_tool, jacobian)
            dm = obs.spheres[i] - obs.spheres[j]  # (k, 3 spheres, 3)
            dp = pts[i] - pts[j]
            ok = obs.seen[i] & obs.seen[j]  # (k, 3)
        else:
            pts, Jk = predict_points(space, x, obs.q, obs.station, np.zeros((1, 3)), jacobian)
            dm = (obs.pose_p[i] - obs.pose_p[j])[:, None, :]
            dp = pts[i] - pts[j]
            ok = np.ones((k, 1), dtype=bool)
        Lm = np.linalg.norm(dm, axis=-1)
        Lp = np.linalg.norm(dp, axis=-1)
        r = ((Lm - Lp) / sig)[ok]
        J = None
        if jacobian:
            u = dp / np.maximum(Lp, 1e-300)[..., None]  # (k, s, 3)
            # d|dp| = u . (J_i - J_j); Jk (P, s, 3, n)
            D = Jk[..., i] - Jk[..., j]  # (P, s, 3, k)
            Jd = np.einsum("ksc,psck->pks", u, D)
            J = (Jd / sig)[:, ok].T
        rows = np.broadcast_to(i[:, None], ok.shape)[ok]
        return Residuals(r=r, J=J, row=rows, block=np.zeros(r.size, dtype=int))
    if obs.kind != "pose":
        raise ValueError(f"{kind} residuals need pose observations: pass obs.as_poses() and pairs of its rows")
    sig = np.sqrt(2.0) * obs.sigma_orientation
    if kind == "rotation_change":
        R, p, Jp = station_eval(space, x, obs.q, obs.station, jacobian)
        Qm = np.swapaxes(obs.pose_R[i], -1, -2) @ obs.pose_R[j]
        Qp = np.swapaxes(R[i], -1, -2) @ R[j]
        e = matrix_to_rotvec(Qm @ np.swapaxes(Qp, -1, -2)) / sig  # (k, 3)
        J = None
        if jacobian:
            dW = Jp[:, 3:, j] - Jp[:, 3:, i]  # (P, 3, k): spatial rate difference
            # left perturbation of Q = R_i^T R_j is R_i^T (w_j - w_i)
            Jq = np.einsum("kab,pak->pbk", R[i], dW)
            J = (Jq / sig).reshape(space.size, -1).T
        return Residuals(r=e.T.reshape(-1), J=J, row=np.tile(i, 3), block=np.ones(3 * k, dtype=int))
    if kind == "euler_change":
        if base2meas is None:
            raise ValueError("euler_change needs base2meas per station (the base rotation)")
        # measured orientations brought into the base frame with the given base rotation; the model's
        # orientations are evaluated in the base frame directly (its base parameters play no part)
        Rb = np.stack([np.asarray(base2meas[int(s)], dtype=float)[:3, :3] for s in obs.station])  # (n, 3, 3)
        Rm_base = np.swapaxes(Rb, -1, -2) @ obs.pose_R
        ev = space.chain.evaluate(x[: space.n_rt], obs.q, jacobian=jacobian)
        Rp_base = ev.R[0]
        Em = euler_zyx_from_matrix(Rm_base)
        Ep = euler_zyx_from_matrix(Rp_base)
        dEm = _wrap(Em[j] - Em[i])
        dEp = _wrap(Ep[j] - Ep[i])
        e = _wrap(dEm - dEp) / sig
        J = None
        if jacobian:
            Minv = _euler_rate_inverse(Ep)  # (n, 3, 3)
            dE = np.zeros((space.size, 3, obs.n))
            dE[: space.n_rt] = np.einsum("nab,pbn->pan", Minv, ev.J[0, :, 3:])  # (P_rt, 3, n)
            J = ((dE[:, :, j] - dE[:, :, i]) / sig).reshape(space.size, -1).T
        return Residuals(r=e.T.reshape(-1), J=J, row=np.tile(i, 3), block=np.ones(3 * k, dtype=int))
    raise ValueError(f"kind must be 'distance', 'rotation_change' or 'euler_change', got {kind!r}")


def _wrap(a: np.ndarray) -> np.ndarray:
    return np.mod(a + np.pi, 2 * np.pi) - np.pi
