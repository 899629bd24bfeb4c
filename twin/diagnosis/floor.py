"""The noise floor a user can measure, and the rows whose history is unknown.

* **Repeats**: the same commanded joints measured twice or more in a row; their pooled spread per axis of the
  measurement frame is the sensor noise.
* **The plate's rigid geometry**: the three inter-sphere distances are constant, so their spread over the
  campaign is the instrument's pose-to-pose error. For independent centre errors with standard deviations
  ``(sigma_x, sigma_y, sigma_z)`` in the measurement frame, a distance along the unit vector ``u`` varies as
  ``var(d) = 2 sum_c u_c^2 sigma_c^2``; regressing the squared deviations of the distances on ``2 u_c^2``
  over every row and pair gives the per-axis error (a stereo instrument is worse in depth, ``z``, than
  across). Rows more than 5 MAD off are left out.
* **Stated**: ``dataset.toml [noise] position_mm`` (an artifact measurement; one figure per coordinate, read
  as the RMS over the axes: spread over them in the shape the plate shows when it has at least 100 degrees of
  freedom and the axes differ by 1.5x or more, never below the stated figure on an axis the distances barely
  measure; isotropic otherwise).
* **Assumed**: a figure the diagnosis derives from stated ones for points it constructs (:class:`AssumedNoise`:
  the virtual points of a pose, from its stated position and orientation noise), reported as its assumption
  with the stated figures it came from, never as a stated figure.

The floor per axis is the largest estimate available; its scalar ``sigma`` is their RMS. Never the world's truth.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from ..dataset import Dataset, Joints
from ..estimator.distributions import f_sf
from ..kinematics import link_frames
from ..transforms import kabsch
from ..files import MARKER_STD_COLUMN, parse_marker_std
from ..units import M_PER_MM
from .candidates import GRAVITY, RowContext
from .features import Field
from .field import POINT_FIELDS, field_applicable, field_constants, field_values

__all__ = ["DiagnosisError", "NoiseFloor", "AssumedNoise", "noise_floor", "marker_noise", "MARKER_STD_COLUMN", "SESSION_COLUMN", "session_changes",
           "history_resets",
           "row_resets", "row_context", "joints_context"]

ANISOTROPY_MIN = 1.5  # a stated figure is spread over the axes only when they differ by this factor or more
WEAK_LEVER = 0.15  # an axis the plate's distances point along less than this (mean squared component) is weakly measured


class DiagnosisError(ValueError):
    """The dataset lacks what diagnosis needs; the message says what to add."""


@dataclass(frozen=True)
class NoiseFloor:
    """Measurement noise ``sigma`` [m] per sphere coordinate (RMS over the axes), per axis of the measurement
    frame ``axis_sigma`` ``(3,)`` [m] (None: isotropic), its degrees of freedom (``inf`` when stated), where
    it came from, how many repeat groups there were, and every estimate available (``components``:
    ``repeats``, ``plate``, ``stated``, ``assumed``, ``marker_std`` -> ``{sigma_mm, axis_sigma_mm, dof, source}``,
    ``assumed`` with ``from_stated``, the stated figures it was derived from);
    ``lower_bound``: the floor is set by the instrument's marker noise alone (``marker_std``), which the robot's own
    pose-to-pose scatter may exceed (no repeats measured it)."""

    sigma: float
    dof: float
    source: str
    groups: int
    components: dict = field(default_factory=dict)
    axis_sigma: np.ndarray | None = None
    lower_bound: bool = False


@dataclass(frozen=True)
class AssumedNoise:
    """A noise figure per point coordinate the diagnosis assumes for points it constructs, derived from figures the
    user stated: ``sigma`` [m], ``source`` (how it was derived, in words) and ``stated`` (the stated figures it came
    from, by name, e.g. ``{"position_mm": 0.02, "orientation_rad": 6e-05}``)."""

    sigma: float
    source: str
    stated: dict


def _repeat_floor(ds: Dataset) -> tuple[np.ndarray, int, int]:
    """Pooled variance of consecutive repeats per axis: ``(sum of squares (3,), dof per axis, groups)``."""
    st = ds.station_ids
    qr = np.round(ds.q, 9)
    ss, dof, groups, k, n = np.zeros(3), 0, 0, 0, ds.n
    while k < n:
        j = k + 1
        while j < n and np.array_equal(qr[j], qr[k]) and st[j] == st[k]:
            j += 1
        if j - k >= 2:
            block = ds.spheres[k:j]
            seen = ds.sphere_seen[k:j]
            for s in range(block.shape[1]):
                rows = seen[:, s]
                if rows.sum() >= 2:
                    v = block[rows, s]
                    ss += np.sum((v - v.mean(axis=0)) ** 2, axis=0)
                    dof += int(rows.sum()) - 1
            groups += 1
        k = j
    return ss, dof, groups


def _row_regressors(ds: Dataset, full: np.ndarray) -> np.ndarray:
    """What a plate's distances may follow besides the place in the field ``(n_full, k)``: the gravity
    direction in the flange frame, linear and quadratic (a loose sphere rolling in its seat, a holder that
    flexes), and ``t_s`` / ``temp_c`` when recorded (the plate or the instrument growing)."""
    R = link_frames(ds.robot, ds.q[full])[:, -1, :3, :3]
    g = np.einsum("nji,j->ni", R, GRAVITY / np.linalg.norm(GRAVITY))
    cols = [g, g**2, g[:, [0]] * g[:, [1]], g[:, [0]] * g[:, [2]], g[:, [1]] * g[:, [2]]]
    for ch in (ds.t_s, ds.temp_c):
        if ch is not None and np.ptp(ch[full]) > 0:
            x = ch[full]
            cols.append(((x - x.mean()) / np.ptp(x))[:, None])
    return np.hstack(cols)


def _systematic_distances(P: np.ndarray, keep: list[np.ndarray], dev: list[np.ndarray], rows: np.ndarray,
                          alpha: float = 0.01) -> tuple[list[np.ndarray], list[np.ndarray], dict | None]:
    # P (n_full, K, 3): the plate's nominal sphere centres rigidly fitted to each row's measured ones
    """Remove from the distance deviations what varies systematically, when an F-test finds it (``p < alpha``):
    with the plate's place in the measurement field (the instrument's distortion or a scale changing with depth
    moves the three distances together with the place; :mod:`twin.diagnosis.field`; only in a line-of-sight
    frame) and, per pair, with the row regressors ``rows`` ``(n_full, k)`` (:func:`_row_regressors`). Returns
    the deviations to use, their variance inflation ``1 / (1 - leverage)``, and what was found (or None)."""
    infl = [np.ones(len(x)) for x in dev]
    feats = (tuple(Field(g=g, **field_constants(P)) for g in POINT_FIELDS)
             if field_applicable(P) else ())
    cols, ys = [], []
    nr = rows.shape[1]
    pairs = _pairs(P.shape[1])
    npair = len(pairs)
    for k, (a, b) in enumerate(pairs):
        # the fields at the rigid fit of the nominal plate (P is that): evaluated at the measured centres, a
        # field close to a scale would reproduce the measured distance, noise and all, and empty the floor
        pa, pb = P[keep[k], a], P[keep[k], b]
        u = (pa - pb) / np.linalg.norm(pa - pb, axis=1)[:, None]
        # change of the distance a-b under each field: (G(p_a) - G(p_b)) . u (one field for all pairs)
        C = (np.einsum("mkc,mc->mk", field_values(feats, pa) - field_values(feats, pb), u) if feats
             else np.zeros((len(u), 0)))
        # the pair's own constant and its own response to the row regressors
        own = np.zeros((len(u), npair * (1 + nr)))
        own[:, k] = 1.0
        own[:, npair + k * nr:npair + (k + 1) * nr] = rows[keep[k]]
        cols.append(np.hstack([own, C]))
        ys.append(dev[k])
    A, y = np.vstack(cols), np.concatenate(ys)
    y0 = np.concatenate([np.full(len(x), x.mean()) for x in ys])  # each pair's own mean
    sc = np.linalg.norm(A, axis=0)
    As = A / np.where(sc > 0, sc, 1.0)
    Q, R = np.linalg.qr(As)
    rank = int(np.sum(np.abs(np.diag(R)) > 1e-8 * np.abs(R[0, 0])))
    Q = Q[:, :rank]
    fit = Q @ (Q.T @ y)
    res = y - fit
    n, p3 = len(y), npair  # the pairs' constants
    ss0 = float(np.sum((y - y0) ** 2))
    ss1 = float(res @ res)
    dfn, dfd = rank - p3, n - rank
    if dfn <= 0 or dfd <= 0 or ss1 <= 0:
        return dev, infl, None

    F = ((ss0 - ss1) / dfn) / (ss1 / dfd)
    pval = float(f_sf(F, dfn, dfd))
    if pval >= alpha:
        return dev, infl, None
    h = np.sum(Q**2, axis=1)
    out, inf2, k0 = [], [], 0
    for x in ys:
        out.append(res[k0:k0 + len(x)])
        inf2.append(1.0 / np.clip(1.0 - h[k0:k0 + len(x)], 0.05, None))
        k0 += len(x)
    return out, inf2, {"p_value": pval, "rms_removed_mm": float(np.sqrt(np.mean((fit - y0) ** 2))) / M_PER_MM,
                       "parameters": dfn}


def _pairs(K: int) -> list[tuple[int, int]]:
    """The pairs of a marker set's ``K`` points, in order (``(0, 1), (0, 2), (1, 2)`` for the plate)."""
    return list(itertools.combinations(range(K), 2))


def _plate_floor(ds: Dataset) -> tuple[np.ndarray, float, dict | None, np.ndarray] | None:
    """Per-axis centre error ``(3,)`` [m] from the spread of the inter-point distances of the marker set (the
    plate's three inter-sphere distances) over the campaign (module docstring), its degrees of freedom, the
    systematic variation of the distances over the measurement field that was taken out first (None if none was
    found) and each axis' lever ``(3,)`` (the mean squared component of the distances' directions along it: how
    well the axis is measured); None with fewer than 10 complete rows or fewer than two points."""
    from scipy.optimize import nnls

    full = ds.sphere_seen.all(axis=1)
    K = ds.spheres.shape[1]
    if full.sum() < 10 or K < 2:
        return None
    P = ds.spheres[full]
    keeps, devs, us, var_iso = [], [], [], []
    for a, b in _pairs(K):
        v = P[:, a] - P[:, b]
        d = np.linalg.norm(v, axis=1)
        dev = d - np.median(d)
        mad = 1.4826 * float(np.median(np.abs(dev)))
        keep = np.abs(dev) <= 5 * max(mad, 1e-12)  # a few gross or mislabelled rows do not set the floor
        keeps.append(keep)
        us.append(v[keep] / d[keep, None])
        devs.append(d[keep] - d[keep].mean())
        var_iso.append(mad**2 / 2)

    R, t = kabsch(np.broadcast_to(ds.plate.spheres_flange, P.shape), P)
    P_fit = np.einsum("nij,sj->nsi", R, ds.plate.spheres_flange) + t[:, None, :]
    devs, infl, systematic = _systematic_distances(P_fit, keeps, devs, _row_regressors(ds, full))
    X = np.concatenate([2 * u**2 for u in us])
    Y = np.concatenate([dk**2 * f for dk, f in zip(devs, infl)])
    var_iso = [float(np.mean(dk**2 * f)) / 2 if len(dk) > 2 else v for dk, f, v in zip(devs, infl, var_iso)]
    s2, _ = nnls(X, Y)
    iso = float(np.mean(var_iso))
    # an axis the distances barely point along is not measured: it gets at least the isotropic figure
    lever = X.mean(axis=0) / 2
    s2 = np.where((lever < 0.01) | (s2 <= 0), np.maximum(s2, iso), s2)
    # three distances of one row share their spheres: about two independent values per row (K points: the
    # 3 K - 6 distances of a rigid set, one value for a pair)
    per_row = 2 if K == 3 else max(3 * K - 6, 1)
    return np.sqrt(s2), float(per_row * (full.sum() - 1)), systematic, lever


def _stated_axes(sig: float, pl: tuple | None) -> tuple[np.ndarray, str]:
    """The stated figure ``sig`` [m] per axis ``(3,)``, and how it was read. One figure per coordinate is an
    average over the axes: where the plate's distances (``pl``, :func:`_plate_floor`) show how the axes differ (a
    stereo instrument is worse in depth), it is spread over them in that shape with the same RMS, or the better
    axes' floor is inflated and the test blunted there. An axis the distances barely point along (the depth,
    when the plate faces the instrument: lever ~0.09) is estimated low and noisily: it may raise the stated
    figure there, never lower it; the well-measured axes share the rest of the RMS. Only a clear difference
    counts (``ANISOTROPY_MIN``): the plate's per-axis figures scatter by ~15 %, and a floor lowered on one axis
    by that much let a spurious term in on a blind campaign."""
    iso = np.full(3, sig)
    if pl is None or pl[1] < 100 or not np.all(pl[0] > 0):
        return iso, ""
    shape, lever = pl[0], pl[3]
    shaped = sig * shape / np.sqrt(np.mean(shape**2))
    weak = lever < WEAK_LEVER
    shaped[weak] = np.maximum(shaped[weak], sig)
    rest = 3 * sig**2 - float(np.sum(shaped[weak] ** 2))
    if np.any(~weak) and rest > 0:
        shaped[~weak] = shape[~weak] * np.sqrt(rest / float(np.sum(shape[~weak] ** 2)))
    if shaped.max() < ANISOTROPY_MIN * shaped.min():
        return iso, ""
    return shaped, ", spread over the axes as the plate shows"


def noise_floor(ds: Dataset, *, stated_ok: bool = True, plate: bool = True,
                assumed: AssumedNoise | None = None) -> NoiseFloor:
    """The sphere-coordinate noise floor (see the module docstring): per axis the largest of the repeats'
    spread, the plate-geometry spread, the stated figure (``stated_ok``) and the diagnosis' ``assumed`` one, with
    the smallest degrees of freedom of the estimates that set it."""
    if not ds.has_spheres:
        if ds.noise_position is not None and stated_ok:
            return NoiseFloor(ds.noise_position, float("inf"), "dataset.toml [noise] position_mm (stated)", 0,
                              {"stated": {"sigma_mm": ds.noise_position / M_PER_MM, "dof": None}})
        raise DiagnosisError("diagnosis of pose data needs [noise] position_mm/orientation_rad in dataset.toml")
    comps: dict[str, tuple[np.ndarray, float, str]] = {}
    ss, dof, groups = _repeat_floor(ds)
    if 3 * dof >= 30:
        comps["repeats"] = (np.sqrt(ss / dof), float(3 * dof), f"{groups} groups of consecutive repeats")
    pl = _plate_floor(ds) if plate else None  # virtual points of a pose are rigid by construction
    systematic = None
    if pl is not None:
        systematic = pl[2]
        extra = ("" if systematic is None else
                 f", after removing their systematic variation ({systematic['rms_removed_mm']:.5f} mm RMS, p = "
                 f"{systematic['p_value']:.2g}) with the place in the measurement field, the gravity direction, time "
                 "or temperature: the instrument's distortion, a sphere or plate that moves, thermal growth")
        comps["plate"] = (pl[0], pl[1], f"spread of the plate's inter-sphere distances over {int(pl[1] / 2 + 1)} rows{extra}")
    if stated_ok and ds.noise_position is not None:
        stated, how = _stated_axes(float(ds.noise_position), pl)
        comps["stated"] = (stated, float("inf"), f"dataset.toml [noise] position_mm (stated){how}")
    if assumed is not None:
        figure, how = _stated_axes(float(assumed.sigma), pl)
        comps["assumed"] = (figure, float("inf"), f"{assumed.source}{how}")
    ms = marker_noise(ds)
    if ms is not None:
        comps["marker_std"] = (np.full(3, ms[0]), float("inf"),
                               f"the rows' {MARKER_STD_COLUMN} column (the instrument's per-row marker noise, RMS over "
                               f"{ms[1]} rows)")
    if not comps:
        raise DiagnosisError(
            "diagnosis needs the measurement noise floor: repeat some configurations (measure the same commanded "
            "joints twice in a row, at least ~10 repeats), measure rows with all three spheres (their distances "
            "give the instrument's error), or state the instrument's noise in dataset.toml ([noise] position_mm)"
            + (f"; found only {groups} repeat groups ({3 * dof} degrees of freedom)" if groups else "")
        )
    names = list(comps)
    A = np.stack([comps[k][0] for k in names])  # (k, 3)
    axis = A.max(axis=0)
    setters = sorted({names[i] for i in A.argmax(axis=0)})
    nu = min(comps[k][1] for k in setters)
    sigma = float(np.sqrt(np.mean(axis**2)))

    def fmt(v):
        return "(" + ", ".join(f"{x / M_PER_MM:.5f}" for x in v) + ") mm"

    others = "; ".join(f"{k}: {fmt(v[0])}" for k, v in comps.items() if k not in setters)
    source = " and ".join(comps[k][2] for k in setters) + f", per axis x, y, z {fmt(axis)}" + (
        f" (the largest; {others})" if others else "")
    components = {k: {"sigma_mm": float(np.sqrt(np.mean(v[0] ** 2))) / M_PER_MM, "axis_sigma_mm": (v[0] / M_PER_MM).tolist(),
                      "dof": None if np.isinf(v[1]) else v[1], "source": v[2]} for k, v in comps.items()}
    if systematic is not None:
        components["plate"]["systematic"] = systematic
    if assumed is not None:
        components["assumed"]["from_stated"] = dict(assumed.stated)
    return NoiseFloor(sigma, nu, source, groups, components, axis_sigma=axis, lower_bound=setters == ["marker_std"])


def marker_noise(ds: Dataset) -> tuple[float, int] | None:
    """The noise per point coordinate [m] a motion-capture system reports per row (column ``marker_std_mm``: the
    standard deviation of the markers over the row's averaging window), as the RMS over the rows with points,
    and the number of those rows; None without the column. An upper bound of the averaged point's noise (the
    window averages many samples), and what a rigid body's virtual points cannot give: their distances are
    constant by construction. ``ValueError`` naming the row when a value is not a finite number >= 0."""
    raw = ds.extra.get(MARKER_STD_COLUMN)
    if raw is None:
        return None
    rows = ds.sphere_seen.any(axis=1) if ds.has_spheres else ds.pose_seen
    vals = []
    for k in np.flatnonzero(rows):
        where = f"{MARKER_STD_COLUMN}: row {k + 1} (pose_id {ds.pose_id[k]})"
        vals.append(parse_marker_std(str(raw[k]).strip(), where))
    if not vals:
        return None
    return float(np.sqrt(np.mean(np.square(vals)))) * M_PER_MM, len(vals)


SESSION_COLUMN = "session"  # optional poses.csv column: the recording session of the row (a day, a power cycle)


def session_changes(ds: Dataset | np.ndarray | None) -> np.ndarray | None:
    """Rows ``(n,)`` bool where the ``session`` column (of a dataset, or the column itself ``(n,)``) changes value
    from the row before (the robot was restarted between them: another day, a power cycle); None without it."""
    raw = ds.extra.get(SESSION_COLUMN) if isinstance(ds, Dataset) else ds
    if raw is None:
        return None
    v = np.asarray(raw).astype(str)
    out = np.zeros(len(v), bool)
    out[1:] = v[1:] != v[:-1]
    return out


def history_resets(ds: Dataset) -> np.ndarray:
    """Rows ``(n,)`` bool whose approach history is unknown: the first row, rows whose ``status`` says
    a restart, homing or power cycle, and rows that start another ``session`` (a column naming the recording
    session). A pause alone (a gap in ``t_s``) keeps the robot where it stood, so its approach history goes on
    across the pause."""
    out = row_resets(ds.n, ds.t_s, ds.status)
    ch = session_changes(ds)
    return out if ch is None else out | ch


SESSION_GAP_S = 1800.0  # [s] a pause shorter than this keeps the robot powered where it stood: not a new session


def row_resets(n: int, t_s: np.ndarray | None = None, status: np.ndarray | None = None, *, gaps: bool = False,
               gap_factor: float = 20.0) -> np.ndarray:
    """:func:`history_resets` from the channels themselves (``t_s`` ``(n,)`` [s], ``status`` ``(n,)`` text): what
    ``twin predict`` uses on a JOINTS.csv, so that new rows read their history as the diagnosis did. With
    ``gaps``, also rows after a gap in ``t_s`` longer than ``gap_factor`` times the median step and than
    ``SESSION_GAP_S`` (half an hour): the starts of the campaign's sessions (a restart, a night), where something may
    have changed (a laser-tracker grid paused 205 times for 2-50 minutes between its rows is one session)."""
    out = np.zeros(n, dtype=bool)
    if n:
        out[0] = True
    if gaps and t_s is not None and n > 2:
        dt = np.diff(t_s)
        med = float(np.median(dt[dt > 0])) if np.any(dt > 0) else 0.0
        if med > 0:
            out[1:] |= dt > max(gap_factor * med, SESSION_GAP_S)
    if status is not None:
        st = np.char.lower(np.asarray(status, dtype=str))
        out |= np.char.find(st, "restart") >= 0
        out |= np.char.find(st, "power") >= 0
        out |= np.char.find(st, "homed") >= 0
    return out


def _session_starts(ds: Dataset) -> np.ndarray:
    """Rows ``(n,)`` that start a session: the first, after a long gap in ``t_s`` or a recorded restart
    (:func:`row_resets` with gaps), where the ``session`` column changes."""
    out = row_resets(ds.n, ds.t_s, ds.status, gaps=True)
    ch = session_changes(ds)
    return out if ch is None else out | ch


def row_context(ds: Dataset, q_start: np.ndarray | None = None) -> RowContext:
    """Every row of the dataset in measurement order, with its auxiliary channels and unknown-history rows
    (``q_start``: where the robot stood before the first row, when known)."""
    reset = history_resets(ds)
    if q_start is not None:
        reset[0] = False
    return RowContext(
        q=ds.q.copy(),
        q_start=None if q_start is None else np.asarray(q_start, dtype=float),
        temp_c=None if ds.temp_c is None else ds.temp_c.copy(),
        t_s=None if ds.t_s is None else ds.t_s.copy(),
        station=ds.station_ids.copy() if ds.station is not None else None,
        history_reset=reset,
        session_start=_session_starts(ds),
        pose_id=np.asarray(ds.pose_id).copy(),
    )


def joints_context(j: Joints, rows: np.ndarray | None = None) -> RowContext:
    """The rows ``rows`` ``(k,)`` of a JOINTS.csv (indices into ``j``, in that order; default every row) as ``twin
    predict`` reads them, as a file of their own: their channels, the first row's history unknown (where the robot
    stood before it is not in the file) and again where the ``session`` column changes."""
    idx = np.arange(len(j.pose_id)) if rows is None else np.asarray(rows, dtype=int)

    def take(v):
        return None if v is None else np.asarray(v)[idx]

    t_s = take(j.t_s)
    reset = row_resets(len(idx), t_s)
    ch = session_changes(take(j.session))
    return RowContext(q=np.asarray(j.q)[idx], q_start=None, temp_c=take(j.temp_c), t_s=t_s, station=take(j.station),
                      history_reset=reset if ch is None else reset | ch, pose_id=np.asarray(j.pose_id)[idx])
