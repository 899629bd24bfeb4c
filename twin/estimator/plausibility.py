"""Plausibility of a dataset and of a fit: refuse what cannot be right, with the likely cause in words.

Checks on data a user has (nothing here reads truth):

* **Marker geometry per row.** The pairwise distances of the K >= 2 points of the rigid marker set are known
  (``dataset.toml`` ``[plate] spheres_mm`` / ``[markers] points_mm``), so each measured row can be checked: a
  row whose labels are permuted is relabelled (the permutation whose distances match the set best, when it
  matches far better than the labels given; distinct distances make it unambiguous); a row whose distances are
  off by more than ``k`` robust standard deviations of all rows is flagged and left out. The median ratio of
  measured to nominal distances tells units (1000x: millimetres written in metres or the reverse).
* **Length unit** (any K, poses too): the spread of the measured positions over the campaign against the spread
  the nominal robot gives them at the same joints (no registration needed: a spread does not depend on the
  frame). A ratio near 1/1000 or 1000 is a unit declared wrong in ``dataset.toml``.
* **Joints.** Values outside the robot's limits; all joints within a few degrees of zero over a campaign that
  must move (joints written in radians in the degree columns).
* **Fit.** A calibrated model that misses its own calibration rows by a sizeable fraction (5 %) of how far they
  move cannot be the robot's: mislabelled data (joint columns swapped, rows of several stations without their
  ``station`` column, another robot) are refused. A residual merely far above the noise (the whitened residual
  scale, or the residual against the instrument's error seen in the marker distances) is a robot with errors
  the geometric model lacks: it is said, never refused (``twin diagnose`` looks for them).
* **Targets** (``twin compensate``). Plate positions against the reach of the calibrated robot within its joint
  limits: every target within a few millimetres of the base origin (metres written in the millimetre columns),
  targets beyond the reach (wrong units or frame).
* **A forced calibration** (``twin calibrate --force``): the reasons it was forced past, for the commands that
  use it to warn.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from itertools import permutations

import numpy as np

from ..dataset import Dataset
from ..transforms import rotation_angle_between
from ..units import MM_PER_M, RAD_PER_DEG, DEG_PER_RAD

__all__ = ["PlateCheck", "ImplausibleData", "check_plate_rows", "check_joints", "check_joint_values",
           "radians_warning", "RADIANS_MIN_ROWS", "fit_beyond_noise", "fit_miss", "check_fit_miss", "plate_noise",
           "tool_reach", "check_targets",
           "forced_reasons", "check_length_unit", "position_spread", "BEYOND_NOISE", "MAX_MISS_FRACTION",
           "MAX_ORIENTATION_MISS_RAD"]

_PAIRS = ((0, 1), (0, 2), (1, 2))
_MAX_RELABEL_POINTS = 6  # K! permutations are tried per row


class ImplausibleData(ValueError):
    """The data cannot be right; the message names the likely cause."""


@dataclass(frozen=True, eq=False)
class PlateCheck:
    """The dataset with permuted labels fixed and implausible rows removed, and what was done.

    ``relabelled``: pose_ids whose sphere labels were permuted back; ``flagged``: ``{pose_id: reason}`` of the
    rows left out; ``distance_ratio``: median measured / nominal inter-sphere distance."""

    dataset: Dataset
    relabelled: tuple[int, ...] = ()
    flagged: dict = field(default_factory=dict)
    distance_ratio: float = 1.0

    def summary(self) -> dict:
        return {"relabelled": list(self.relabelled), "flagged": {str(k): v for k, v in self.flagged.items()},
                "distance_ratio": self.distance_ratio,
                "rule": "labels permuted back when another order matches the plate's distinct distances better; rows "
                        "whose distances are off by more than k robust sd of all rows left out"}


def _distances(P: np.ndarray, pairs=_PAIRS) -> np.ndarray:
    return np.stack([np.linalg.norm(P[:, a] - P[:, b], axis=-1) for a, b in pairs], axis=-1)


def check_plate_rows(ds: Dataset, *, k: float = 10.0, min_sd_m: float = 2e-6) -> PlateCheck:
    """Relabel permuted rows, flag rows the plate geometry rules out, check units (module docstring).

    ``k``: how many robust standard deviations (of the distance errors over all rows, at least ``min_sd_m``)
    make a row implausible. Raises :class:`ImplausibleData` when the distances are 1000x (or 1/1000x) the
    plate's, or when more than half of the complete rows are implausible.
    """
    if not isinstance(ds, Dataset):
        raise ValueError(f"ds must be a twin.dataset.Dataset, got {type(ds).__name__}")
    if not (k > 0):
        raise ValueError(f"k must be positive, got {k!r}")
    full = ds.sphere_seen.all(axis=1)
    pairs = ds.plate.pairs
    if full.sum() == 0 or not pairs:
        return PlateCheck(ds)
    nom = _distances(ds.plate.spheres_flange[None], pairs)[0]  # (K(K-1)/2,)
    P = ds.spheres[full]
    d = _distances(P, pairs)
    ratio = float(np.median(d / nom))
    unit = getattr(ds, "length_unit", "mm")
    if not 0.5 < ratio < 2.0:
        if 300 < ratio < 3000:
            cause = ("marker positions in micrometres, or the marker set in metres?" if unit == "mm" else
                     f"marker positions in millimetres? (dataset.toml declares unit {unit!r})")
        elif 3e-4 < ratio < 3e-3:
            cause = f"positions in metres? (dataset.toml declares unit {unit!r}: poses.csv must hold millimetres)"
        else:
            cause = "a different plate, or wrong units?"
        label = ("sphere distances", "the plate's") if ds.plate.sphere_diameter > 0 else ("marker distances",
                                                                                        "the marker set's")
        raise ImplausibleData(f"{label[0]} are {ratio:.4g}x {label[1]} ({', '.join(f'{x * MM_PER_M:.2f}' for x in nom[:6])} "
                              f"mm in dataset.toml): {cause}")
    K = ds.plate.n_points
    spheres = ds.spheres.copy()
    rows = np.flatnonzero(full)
    relabelled = []
    if K <= _MAX_RELABEL_POINTS:
        perms = list(permutations(range(K)))
        for r in rows:
            errs = []
            for p in perms:
                errs.append(float(np.sum((_distances(spheres[r][list(p)][None], pairs)[0] - nom) ** 2)))
            best = int(np.argmin(errs))
            if best != 0 and errs[0] > 100 * errs[best] and errs[0] > (50e-6) ** 2:
                spheres[r] = spheres[r][list(perms[best])]
                relabelled.append(int(ds.pose_id[r]))
    e = _distances(spheres[full], pairs) - nom  # (m, K(K-1)/2)
    med = np.median(e, axis=0)  # a plate slightly off its nominal geometry: a common offset, not an error
    dev = np.abs(e - med)
    sd = np.maximum(1.4826 * np.median(dev, axis=0), min_sd_m)
    bad = np.any(dev > k * sd, axis=1)
    flagged = {}
    for r, b, x in zip(rows, bad, dev):
        if b:
            flagged[int(ds.pose_id[r])] = (f"plate geometry off: inter-point distances differ from the campaign's by "
                                           f"{', '.join(f'{v * MM_PER_M:.3f}' for v in x)} mm (> {k:g} robust sd): not what the "
                                           f"instrument could have measured")
    if bad.mean() > 0.5:
        raise ImplausibleData(f"{int(bad.sum())} of {int(full.sum())} rows have marker distances that do not fit the "
                              "marker set in dataset.toml: wrong geometry, units, or not one rigid body?")
    out = replace(ds, spheres=spheres)
    if flagged:
        keep = ~np.isin(out.pose_id, list(flagged))
        out = out.subset(keep)
    return PlateCheck(out, tuple(relabelled), flagged, ratio)


def check_joints(ds: Dataset) -> list[str]:
    """Problems of the commanded joints of a dataset in words (empty when none); :class:`ImplausibleData` when
    the joints cannot be degrees (see :func:`check_joint_values`)."""
    r = ds.robot
    if r.n_joints == 6 and tuple(r.joint_names) == tuple(f"q{j}" for j in range(1, 7)):
        return check_joint_values(ds.q, ds.pose_id, r.q_min, r.q_max, where="poses.csv")
    return check_joint_values(ds.q, ds.pose_id, r.q_min, r.q_max, where="poses.csv", joint_names=r.joint_names,
                              prismatic=r.is_prismatic)


# from this many rows on, joints all within pi degrees of zero that move are refused as radians; below, only warned
RADIANS_MIN_ROWS = 10


# a joint in radians read as degrees lies within 2 pi "degrees" of zero (1.02: rounding of the written values)
RADIANS_FULL_TURN = 2.0 * np.pi * RAD_PER_DEG * 1.02  # [rad]
# the limits of a robot whose joints may be radians span at least this many times that band (a joint of any
# industrial arm spans far more than 12.8 deg: such a file uses under a tenth of the range the robot has)
RADIANS_LIMIT_RATIO = 10.0


def radians_warning(q: np.ndarray, prismatic=None, *, where: str = "JOINTS.csv", q_min=None, q_max=None,
                    joint_names=None) -> str:
    """Words when the joints ``q`` ``(n, N)`` [rad] (read from degree columns) may be radians, empty otherwise.

    Two rules, neither a refusal (a joints file carries no measurement to tell them apart: a few postures near
    the zero posture, a check near home, are as genuine in degrees as postures in radians are):

    * fewer than :data:`RADIANS_MIN_ROWS` rows whose revolute joints all lie within pi degrees of zero, not all at
      zero (from that many rows on, :func:`check_joint_values` refuses them);
    * any number of rows whose revolute joints all lie within 2 pi degrees of zero, one beyond pi degrees (a joint
      in radians beyond pi rad, which the first rule and the refusal miss), when the limits ``q_min`` / ``q_max``
      ``(N,)`` [rad] are given and span :data:`RADIANS_LIMIT_RATIO` times that band or more: the words name the
      largest joint (by ``joint_names``, default ``q1..qN``) and the limits' span."""
    q = np.asarray(q, dtype=float)
    if q.ndim != 2:
        raise ValueError(f"q must have shape (n, N), got {q.shape}")
    pris = np.zeros(q.shape[1], bool) if prismatic is None else np.asarray(prismatic, dtype=bool)
    rev = q[:, ~pris]
    n = q.shape[0]
    if not n or not rev.size or not np.any(rev != 0) or not np.all(np.abs(rev) <= RADIANS_FULL_TURN):
        return ""
    big = float(np.abs(rev).max())
    if big <= np.pi * RAD_PER_DEG * 1.02:
        if n >= RADIANS_MIN_ROWS:
            return ""
        return (f"every joint of its {n} row(s) lies within {big / RAD_PER_DEG:.3g} deg of zero: radians "
                f"written in the degree columns? ({where} expects degrees; a file of {RADIANS_MIN_ROWS} rows or more "
                "like this is refused, fewer rows near the zero posture can be genuine degrees)")
    if q_min is None or q_max is None:
        return ""
    span = (np.asarray(q_max, dtype=float) - np.asarray(q_min, dtype=float))
    if span.shape != (q.shape[1],):
        raise ValueError(f"q_min and q_max must have shape ({q.shape[1]},), got {np.shape(q_min)} and "
                         f"{np.shape(q_max)}")
    span = span[~pris]
    if span.max() < RADIANS_LIMIT_RATIO * 2.0 * RADIANS_FULL_TURN:
        return ""
    r, c = np.unravel_index(int(np.argmax(np.abs(rev))), rev.shape)
    k = int(np.flatnonzero(~pris)[c])
    name = joint_names[k] if joint_names is not None else f"q{k + 1}"
    return (f"every joint of its {n} row(s) lies within {big / RAD_PER_DEG:.3g} deg of zero ({name} reads "
            f"{rev[r, c] / RAD_PER_DEG:.4g} deg in data row {r + 1}: within 2 pi, as a joint in radians is) while the "
            f"robot's joints span up to {span.max() / RAD_PER_DEG:.4g} deg: radians written in the degree columns? "
            f"({where} expects degrees; postures within a few degrees of the zero posture read the same)")


def check_joint_values(q: np.ndarray, pose_id: np.ndarray, q_min: np.ndarray, q_max: np.ndarray, *,
                       where: str = "poses.csv", joint_names=None, prismatic=None) -> list[str]:
    """Joints ``q`` ``(n, N)`` [rad; m for prismatic joints] (read from degree / millimetre columns) against the
    limits ``q_min``/``q_max``. ``joint_names`` (default ``q1..qN``), ``prismatic`` ``(N,)`` mask (default none).

    Returns the rows outside the limits in words (empty when none). Raises :class:`ImplausibleData` when the
    joints cannot be degrees: every revolute joint within 3.2 deg of zero over :data:`RADIANS_MIN_ROWS` rows or
    more that move (radians written in the degree columns of ``where``; fewer rows: :func:`radians_warning`)."""
    q = np.asarray(q, dtype=float)
    if q.ndim != 2 or q.shape[1] != np.size(q_min):
        raise ValueError(f"q must have shape (n, {np.size(q_min)}), got {q.shape}")
    nj = q.shape[1]
    names = tuple(joint_names) if joint_names is not None else tuple(f"q{j + 1}" for j in range(nj))
    pris = np.zeros(nj, bool) if prismatic is None else np.asarray(prismatic, dtype=bool)
    pose_id = np.asarray(pose_id)
    if pose_id.shape != (q.shape[0],):
        raise ValueError(f"pose_id must have shape ({q.shape[0]},), got {pose_id.shape}")
    n = q.shape[0]
    rev = q[:, ~pris]
    if n >= RADIANS_MIN_ROWS and rev.size and np.all(np.abs(rev) <= np.pi * RAD_PER_DEG * 1.02) and np.ptp(rev, axis=0).max() > 0:
        cols = "q1..q6" if joint_names is None else ", ".join(n_ for n_, p in zip(names, pris) if not p)
        raise ImplausibleData(f"every joint of the {n} rows lies within {np.abs(rev).max() / RAD_PER_DEG:.3g} deg of zero: "
                              f"joints look like radians ({where} expects {cols} in degrees)")
    lo, hi = np.asarray(q_min, float), np.asarray(q_max, float)
    out = []
    for j in range(nj):
        b = np.flatnonzero((q[:, j] < lo[j] - 1e-9) | (q[:, j] > hi[j] + 1e-9))
        if b.size:
            f, u = (MM_PER_M, "mm") if pris[j] else (DEG_PER_RAD, "deg")
            out.append(f"{names[j]} outside the robot's limits [{lo[j] * f:.1f}, {hi[j] * f:.1f}] {u} in "
                       f"{b.size} rows (pose_id {[int(x) for x in pose_id[b[:5]]]})")
    return out


def tool_reach(robot, *, n: int = 4000, seed: int = 0, refine: int = 16) -> tuple[float, float]:
    """The median and largest distance [m] of the tool (plate) origin from the robot base origin over ``n``
    joint configurations drawn uniformly within the robot's limits (a fixed seed: the same answer each call).
    ``robot``: a :class:`~twin.kinematics.RobotModel` whose base frame is the robot base.

    The largest distance is then climbed from the ``refine`` farthest draws by projected gradient ascent within
    the limits (``r(q) = |p(q)|``, ``dr/dq = p^T J_p / r``, a step that grows while ``r`` grows and halves when
    it does not): the farthest reach lies on the limits of some joints (a prismatic joint fully out), where
    uniform draws seldom come."""
    from ..kinematics import joint_jacobian, tool2base

    if n < 10:
        raise ValueError(f"n must be at least 10, got {n!r}")
    rng = np.random.default_rng(seed)
    q = rng.uniform(robot.q_min, robot.q_max, (n, robot.n_joints))
    r = np.linalg.norm(tool2base(robot, q)[:, :3, 3], axis=-1)
    qk = q[np.argsort(r)[-refine:]] if refine > 0 else q[:0]
    rk = np.linalg.norm(tool2base(robot, qk)[:, :3, 3], axis=-1)
    step = np.full(len(qk), 0.05)
    for _ in range(40 if len(qk) else 0):
        p = tool2base(robot, qk)[:, :3, 3]
        g = np.einsum("ki,kij->kj", p / np.maximum(rk, 1e-12)[:, None], joint_jacobian(robot, qk, frame="base")[:, :3])
        g /= np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)
        q_new = np.clip(qk + step[:, None] * g, robot.q_min, robot.q_max)
        r_new = np.linalg.norm(tool2base(robot, q_new)[:, :3, 3], axis=-1)
        up = r_new > rk
        qk[up], rk[up] = q_new[up], r_new[up]
        step = np.where(up, step * 1.5, step * 0.5)
    return float(np.median(r)), float(max(r.max(), rk.max() if len(rk) else 0.0))


def check_targets(tool2base_targets: np.ndarray, pose_id: np.ndarray, robot, *, where: str = "TARGETS.csv",
                  margin: float = 1.02) -> None:
    """:class:`ImplausibleData` when target plate poses ``(n, 4, 4)`` in the robot base frame cannot be meant
    for ``robot`` (a :class:`~twin.kinematics.RobotModel`, tool = plate): all of them far nearer the base origin
    than the plate ever is (positions in metres in the millimetre columns), or any of them farther than the
    plate reaches within the joint limits (``margin`` x the largest sampled distance; wrong units or frame)."""
    T = np.asarray(tool2base_targets, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise ValueError(f"tool2base_targets must have shape (n, 4, 4), got {T.shape}")
    pose_id = np.asarray(pose_id)
    r = np.linalg.norm(T[:, :3, 3], axis=-1)
    typical, reach = tool_reach(robot)
    ratio = float(np.median(r)) / typical
    if ratio < 0.01:
        raise ImplausibleData(f"every target lies within {r.max() * MM_PER_M:.4g} mm of the robot base origin, where the "
                              f"plate is typically {typical * MM_PER_M:.0f} mm from it: positions in metres? ({where} expects "
                              "x, y, z in millimetres)")
    far = np.flatnonzero(r > margin * reach)
    if far.size:
        if far.size == r.size and 300 < ratio < 3000:
            cause = "positions in micrometres?"
        elif far.size == r.size and 20 < ratio < 30:
            cause = "positions 25.4x too large: millimetres converted as if inches?"
        else:
            cause = f"wrong units, or a frame other than the robot base? ({where} expects millimetres in the robot base frame)"
        raise ImplausibleData(f"{far.size} of {r.size} targets lie beyond the robot's reach ({reach * MM_PER_M:.0f} mm from "
                              f"the base origin within its joint limits; farthest {r.max() * MM_PER_M:.4g} mm, pose_id "
                              f"{[int(x) for x in pose_id[far[:10]]]}): {cause}")


def forced_reasons(details: dict) -> list[str]:
    """Why a calibration was written with ``twin calibrate --force`` (its ``details``; empty when it was not)."""
    pl = (details or {}).get("plausibility") if isinstance(details, dict) else None
    forced = pl.get("forced") if isinstance(pl, dict) else None
    if not forced:
        return []
    return [str(f) for f in (forced if isinstance(forced, list) else [forced])]


def check_length_unit(ds: Dataset, *, low: float = 0.05, high: float = 20.0) -> float | None:
    """:class:`ImplausibleData` when the measured positions (marker points, or pose positions) spread over the
    campaign ``low`` times less or ``high`` times more than the nominal robot moves the same points at the same
    joints: the length unit declared in ``dataset.toml`` (``[markers] unit``) is not the file's. Returns the
    ratio (the median over stations; None with fewer than 3 measured rows). The spread (RMS distance from the
    centroid, per station) does not depend on the measurement frame, so no registration is needed."""
    from ..kinematics import tool2base

    robot = ds.robot
    if ds.has_spheres:
        rows = np.flatnonzero(ds.sphere_seen.any(axis=1))
    elif ds.has_poses:
        rows = np.flatnonzero(ds.pose_seen)
    else:
        return None
    if rows.size < 3:
        return None
    T = tool2base(robot, ds.q[rows])
    if ds.has_spheres:
        T0 = np.linalg.inv(robot.tool2flange)
        pts_tool = ds.plate.spheres_flange @ T0[:3, :3].T + T0[:3, 3]
        pred = np.einsum("nij,kj->nki", T[:, :3, :3], pts_tool) + T[:, None, :3, 3]
        meas = ds.spheres[rows]
        seen = ds.sphere_seen[rows]
    else:
        pred = T[:, None, :3, 3]
        meas = ds.pose[rows, None, :3, 3]
        seen = np.ones((rows.size, 1), bool)

    st = ds.station_ids[rows]
    sm, sp = [], []
    for s_ in np.unique(st):
        sel = (st == s_)[:, None] & seen
        if sel.sum() >= 3:
            sm.append(position_spread(meas[sel]))
            sp.append(position_spread(pred[sel]))
    if not sp or min(sp) <= 0:
        return None
    ratio = float(np.median(np.array(sm) / np.array(sp)))
    sm_, sp = float(np.median(sm)), float(np.median(sp))
    unit = ds.length_unit
    if ratio < low or ratio > high:
        if 3e-4 < ratio < 3e-3:
            cause = (f"the values look like metres but dataset.toml declares unit {unit!r}" if unit == "mm"
                     else f"dataset.toml declares unit {unit!r}: values in micrometres?")
        elif 300 < ratio < 3000:
            cause = (f"the values look like millimetres but dataset.toml declares unit {unit!r}" if unit == "m"
                     else f"dataset.toml declares unit {unit!r}: values in micrometres?")
        else:
            cause = "wrong units, wrong robot, or joints in the wrong columns?"
        f = MM_PER_M if unit == "mm" else 1.0
        raise ImplausibleData(f"the measured positions spread {sm_ * f:.4g} {unit} over the campaign where "
                              f"the nominal robot moves them {sp * f:.4g} {unit} (ratio {ratio:.3g}): {cause}")
    return ratio


def plate_noise(ds: Dataset, *, virtual_m: float = 1e-6) -> float | None:
    """The instrument's error per coordinate [m] seen in the marker set: the robust spread of the inter-point
    distances over the rows with all K points, divided by sqrt(2) (None with fewer than 10 such rows or K < 2).
    No kinematic error changes these distances, so a fit cannot be much worse than this. Distances constant to
    below ``virtual_m`` (1 um: no instrument measures independent points that well) are the virtual points of a
    tracked rigid body (a motion-capture body's points, computed from its fitted pose): they carry no noise
    information, and the answer is None."""
    full = ds.sphere_seen.all(axis=1)
    if full.sum() < 10 or not ds.plate.pairs:
        return None
    d = _distances(ds.spheres[full], ds.plate.pairs)
    mad = 1.4826 * np.median(np.abs(d - np.median(d, axis=0)), axis=0)
    sigma = float(np.sqrt(np.mean(mad**2) / 2.0))
    return None if sigma < virtual_m else sigma


#: A fit whose residual is this many times what the noise explains: the robot has errors beyond its geometry.
BEYOND_NOISE = 3.0
#: A fit that misses the measured positions by this fraction of how far they move cannot be the robot's.
MAX_MISS_FRACTION = 0.05
#: A fit that misses the measured orientations (6-DOF poses) by this much RMS [rad] (5 deg) reads them wrong: no
#: robot's own errors turn its tool that far (angles in another unit, Euler sequence or order, a quaternion's
#: components in another order, three of its four read as angles).
MAX_ORIENTATION_MISS_RAD = 5.0 * RAD_PER_DEG


def fit_beyond_noise(residual_scale: float | None, fit_rms_per_coordinate_m: float | None,
                     sigma_plate_m: float | None, *, limit: float = BEYOND_NOISE, min_sigma_m: float = 1e-6,
                     dataset: str = "DATASET") -> dict:
    """Whether a geometric fit leaves more than the noise: the whitened residual scale (the residual over the noise
    stated or estimated) and the fit's residual per coordinate [m] over the instrument's error seen in the marker
    distances (``sigma_plate_m``, :func:`plate_noise`), each against ``limit``.

    Returns ``{detected, residual_scale, plate_ratio, limit, text}``: ``detected`` when either ratio is ``limit``
    or more (the robot has errors the geometric model lacks, or the stated noise is too small); ``text`` says so in
    words and points to ``twin diagnose`` on ``dataset`` (empty when not detected). Never refuses: a real robot whose errors are
    not geometric is not a wrong input. :class:`ImplausibleData` only for a residual scale that is not a finite
    number (a broken fit)."""
    if residual_scale is not None and not np.isfinite(residual_scale):
        raise ImplausibleData(f"the fit's residual scale is {residual_scale!r}")
    plate_ratio = None
    if sigma_plate_m is not None and fit_rms_per_coordinate_m is not None and np.isfinite(fit_rms_per_coordinate_m):
        plate_ratio = float(fit_rms_per_coordinate_m / max(sigma_plate_m, min_sigma_m))
    scale = None if residual_scale is None else float(residual_scale)
    why = []
    if scale is not None and scale >= limit:
        why.append(f"the residual is {scale:.3g}x what the noise explains")
    if plate_ratio is not None and plate_ratio >= limit:
        why.append(f"the residual per coordinate is {plate_ratio:.3g}x the instrument's error seen in the marker "
                   "distances")
    text = ""
    if why:
        text = (f"the robot has errors the geometric model lacks: {' and '.join(why)} (or the noise stated is too "
                f"small); the geometric calibration is written, and `twin diagnose {dataset}` looks for the effects "
                "(compliance, backlash, thermal growth, ...) that explain the rest")
    return {"detected": bool(why), "residual_scale": scale, "plate_ratio": plate_ratio, "limit": float(limit),
            "text": text}


def fit_miss(cal, ds: Dataset, *, trim: float = 0.05) -> dict | None:
    """How far a calibration's model misses the rows it was fitted on, against how far they move.

    Every calibration row (used or rejected by the outlier rule) of ``ds`` is predicted by ``cal`` (a
    :class:`~twin.estimator.Calibration` of ``ds``) in its station's frame; a row's miss [m] is the mean distance of
    its measured points (or pose position) from the prediction. ``miss_rms_m``: the RMS over the rows with the
    worst ``trim`` fraction left out (a few gross rows do not count; a third of the rows measured in another frame
    does). ``spread_m``: the RMS distance of the measured positions from their centroid, per station, the median
    over stations. Returns ``{miss_rms_m, spread_m, fraction, rows}`` (a pose's also ``orientation_miss_rms_rad``: the
    RMS [rad] of the angles between measured and predicted orientations, the worst ``trim`` left out), or None with
    fewer than 3 rows."""
    if not 0 <= trim < 1:
        raise ValueError(f"trim must be in [0, 1), got {trim!r}")
    rows = cal.rows or {}
    ids = {int(p) for p in rows.get("calibration_used", [])}
    ids |= {int(r["pose_id"]) for r in rows.get("calibration_rejected", []) if isinstance(r, dict) and "pose_id" in r}
    use_pose = cal.measurement == "pose"
    seen = ds.pose_seen if use_pose else ds.sphere_seen.any(axis=1)
    sel = np.flatnonzero(np.isin(ds.pose_id, sorted(ids)) & seen)
    if sel.size < 3:
        return None
    pred = cal.predict(ds.q[sel], None if ds.station is None else ds.station_ids[sel])
    turn = None
    if use_pose:
        meas = ds.pose[sel, None, :3, 3]
        P = pred.pose[:, None, :3, 3]
        m = np.ones((sel.size, 1), bool)
        turn = rotation_angle_between(ds.pose[sel, :3, :3], pred.pose[:, :3, :3])
    else:
        meas, P, m = ds.spheres[sel], pred.spheres, ds.sphere_seen[sel]
    d = np.where(m, np.linalg.norm(np.where(m[..., None], meas - P, 0.0), axis=-1), 0.0)
    miss = d.sum(axis=1) / m.sum(axis=1)
    keep = np.sort(miss)[: max(1, int(np.ceil((1.0 - trim) * miss.size)))]
    st = ds.station_ids[sel]
    spreads = []
    for s_ in np.unique(st):
        pts = meas[st == s_][m[st == s_]]
        if pts.shape[0] >= 3:
            spreads.append(position_spread(pts))
    if not spreads:
        return None
    spread = float(np.median(spreads))
    rms = float(np.sqrt(np.mean(keep**2)))
    out = {"miss_rms_m": rms, "spread_m": spread, "fraction": rms / spread if spread > 0 else float("inf"),
           "rows": int(sel.size), "trim": float(trim)}
    if turn is not None:
        kept = np.sort(turn)[: keep.size]
        out["orientation_miss_rms_rad"] = float(np.sqrt(np.mean(kept**2)))
    return out


def position_spread(points: np.ndarray) -> float:
    """How far measured positions ``(m, 3)`` [m] move: their RMS distance from their centroid [m]."""
    return float(np.sqrt(np.mean(np.sum((points - points.mean(axis=0)) ** 2, axis=-1))))


def check_fit_miss(miss: dict | None, *, limit: float = MAX_MISS_FRACTION) -> None:
    """:class:`ImplausibleData` when the calibrated model misses its own calibration rows (:func:`fit_miss`) by
    ``limit`` or more of how far they move, or misses their orientations (a pose) by
    :data:`MAX_ORIENTATION_MISS_RAD` or more: no robot's non-geometric errors are that large beside its motion; the
    data are mislabelled (joint columns swapped or in another order, rows of several stations without their
    ``station`` column, another robot, rotation columns read wrong)."""
    if miss is None:
        return
    turn = miss.get("orientation_miss_rms_rad")
    if turn is not None and turn >= MAX_ORIENTATION_MISS_RAD:
        raise ImplausibleData(
            f"the model cannot fit these data: the calibrated robot misses the orientations of its calibration rows by "
            f"{turn * DEG_PER_RAD:.4g} deg RMS (the worst {miss['trim']:.0%} left out; no robot's own errors turn its "
            f"tool {MAX_ORIENTATION_MISS_RAD * DEG_PER_RAD:.0f} deg): the rotation columns read wrong (their unit, "
            "Euler sequence or order, three of a quaternion's four components read as angles)?")
    if miss["fraction"] >= limit:
        raise ImplausibleData(
            f"the model cannot fit these data: the calibrated robot misses its calibration rows by "
            f"{miss['miss_rms_m'] * MM_PER_M:.4g} mm RMS (the worst {miss['trim']:.0%} left out), {miss['fraction']:.0%} of the "
            f"{miss['spread_m'] * MM_PER_M:.4g} mm the measured positions move over the campaign: no robot's own errors are "
            "that large (joint columns swapped or in the wrong order, rows of several stations without their 'station' "
            "column, another robot?)")
