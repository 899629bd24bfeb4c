"""Atoms: the smallest effect terms diagnosis selects from, each one channel acting at one place.

An *atom* is ``delta(place) = sum_k phi_k f_k(row)``: a few *features* ``f_k`` (functions of what was
recorded for the row: commanded joints, their approach directions, ``t_s``, ``temp_c``, the row order, the
station) acting at one *place* of the model:

==========  =============================================================================================
``joint``   a joint angle (``target = "theta3"``): the robot reaches ``q_j + delta`` (applied exactly)
``length``  a link length, relative (``"a2"``, or ``"all_lengths"``): ``L -> L (1 + delta)`` (first order)
``param``   any parameter of the estimator's vector (``"alpha3"``, ``"tool_rz"``, ``"d4"`` absolute [m]);
            ``"tool"`` / ``"base"`` name the whole 6-DOF frame (six columns per feature; ``base`` acts on
            the station of each row), ``"base_along"`` a displacement in the robot base frame along the
            direction its three features give, one coefficient (first order)
``plate``   the centre of one sphere in the plate frame (``"sphere1"``, three columns per feature) [m]: constant
            (exact), or varying with its features (a loose sphere rolling with gravity; first order)
``scale``   the measurement frame's scale about its origin (``"meas_scale"``): ``p -> p (1 + delta)``
``field``   the measurement field (``"meas_field"``): ``p -> p + sum_k phi_k G_k(p)``, lens distortion, a
            scale that changes with depth, a quadratic field (:mod:`twin.diagnosis.field`; first order)
==========  =============================================================================================

Atoms come in two pools. The *catalogue* names physical effects (family from :data:`EFFECT_VOCABULARY`),
split per joint, harmonic order, link and sphere: ``compliance`` of joint ``i`` (the gravity-torque regressor
of joint ``i``, linear in the unknown mass moments), ``backlash`` of joint ``j`` (the sign of its last move),
``cyclic`` order ``k`` of joint ``j`` (``sin``/``cos(k q_j)``), ``gear_ratio`` of joint ``j`` (``q_j``),
``coupling`` (``theta6`` with ``q5``), ``thermal`` growth of each link and of all links together (against
``temp_c``, or a cubic in ``t_s``), ``plate_geometry`` per sphere. The *generic* pool (family ``unnamed``)
is the dictionary for what no catalogue holds: every joint angle, link length, twist, the tool and base
frames and the measurement scale, against low-order polynomials and harmonics of every joint, products of
two joints, approach signs, the gravity direction in the flange frame, polynomials and change points in
time (or row order), temperature, and the station.

A feature is a small typed object (:mod:`twin.diagnosis.features`: ``Pow(ch="q3", p=2, c=..., h=...)``, stored as
``{"kind": "pow", "ch": "q3", "p": 2, "c": ..., "h": ...}``) whose constants (centres, scales, reference
temperature, change-point times) are fixed on the rows the atom is identified on, so that ``twin predict``
evaluates the same regressor on new rows. Nothing here reads truth.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..kinematics import RobotModel, link_frames
from .candidates import (GRAVITY, RowContext, approach_signs, carried_moments, gravity_torque_regressor,
                         gravity_torques, has_masses)
from .features import (BaseMoment, CartDir, Const, Cos, Exp, Feature, Field, Gated, Grav, GravityDir, GravMix, Heat,
                       HeatRecord, Hinge, Lag, LagRecord, LastMove, LoadSign, Moment, Play, Pow, Prod, Settle, Sign, Sin,
                       Station, Step, StepIn, Torque, Window, feature_from_dict)

__all__ = [
    "Atom",
    "play_backlash",
    "hinge_atom",
    "feature_values",
    "catalogue_atoms",
    "generic_atoms",
    "approach_unknown",
    "history_signs",
    "history_unknown",
    "with_records",
]

_DEG = np.pi / 180.0
HISTORY_KINDS = ("sign",)
SCAN_ORDERS = (1.5, 150.0, 0.5)  # cyclic-error orders scanned (beyond the integers 1-3): first, last, step
MOVE_WIDTHS_DEG = (2.0, 6.0, 20.0)  # widths of the move-size hysteresis shapes in the dictionary (then refined)
TAU_FRACTIONS = (0.125, 0.5, 2.0)  # time constants of transients and lags, as fractions of the campaign's span (then refined)
MIN_THERMAL_LENGTH = 0.01  # [m] links shorter than this get no thermal atom of their own
PLAY_HALF_DEG = (0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0)  # half clearances tried for a kept backlash (then refined)
TIME_CYCLES = tuple(np.arange(1.5, 20.01, 0.5))  # cycles over the campaign of the periodic time terms (then refined)
WRIST_COUPLINGS = ((5, 4), (6, 4), (6, 5))  # (driven joint, driving joint) of a 6R arm: wrist drive shafts pass through joints 4, 5
HINGE_POINTS = 9  # angles (deciles of a joint's range) past which a one-sided pull may start (then refined)
HINGE_POWERS = (1, 2)  # the pull grows linearly (a spring) or with the square of the overtravel
COMPLIANCE_RANK = 3  # principal gravity-torque shapes kept per joint
COM_PRIOR_M = 0.1  # [m] typical distance of a link's centre of mass from its frame (prior for the shapes)  # features that depend on the order of the rows (their state can be unknown)
_ORD = {1: "1st", 2: "2nd", 3: "3rd"}
PLACES = ("joint", "length", "param", "plate", "scale", "field")


@dataclass(frozen=True, eq=False)
class Atom:
    """One candidate term: ``family`` (catalogue name or ``"unnamed"``), ``place`` and ``target`` (where it
    acts), ``features`` (``K`` features, :mod:`twin.diagnosis.features`), ``channel`` (what it depends on, for
    people), ``label`` (words), ``pool`` (``"catalogue"``/``"generic"``), and ``joints`` (1-based joints it
    involves)."""

    family: str
    place: str
    target: str
    features: tuple[Feature, ...]
    channel: str
    label: str
    pool: str
    joints: tuple[int, ...] = ()
    meta: dict = field(default_factory=dict)

    @property
    def K(self) -> int:
        if self.place == "plate":
            return 3 * len(self.features)
        if self.place == "param" and self.target in ("tool", "base"):
            return 6 * len(self.features)
        if self.place == "param" and self.target == "base_along":
            return 1
        if self.place == "param" and self.target.startswith("tilt") and \
                any(getattr(f, "shape", None) is not None for f in self.features):
            return len({int(f.shape) for f in self.features})  # one coefficient per shape, both axes
        return len(self.features)

    @property
    def varying_plate(self) -> bool:
        """A plate atom whose offset changes from row to row (first order), not a constant one (exact)."""
        return self.place == "plate" and any(not isinstance(f, Const) for f in self.features)

    @property
    def first_order(self) -> bool:
        """Whether the atom acts on the prediction to first order (through the Jacobian), not exactly through
        the joints or a constant plate offset."""
        return self.place in ("length", "param", "scale", "field") or self.varying_plate

    @property
    def key(self) -> str:
        return f"{self.family}:{self.place}:{self.target}:{self.channel}"

    def spec(self) -> dict:
        """JSON-ready description (values are added by the caller)."""
        return {"family": self.family, "place": self.place, "target": self.target, "channel": self.channel,
                "label": self.label, "joints": list(self.joints), "features": [f.to_dict() for f in self.features]}

    @classmethod
    def from_spec(cls, d: dict) -> "Atom":
        for k in ("family", "place", "target", "features"):
            if k not in d:
                raise ValueError(f"effect term is missing {k!r}: {d!r}")
        if d["place"] not in PLACES:
            raise ValueError(f"effect term place {d['place']!r} is not one of {', '.join(PLACES)}")
        return cls(family=d["family"], place=d["place"], target=d["target"],
                   features=tuple(feature_from_dict(f) for f in d["features"]),
                   channel=d.get("channel", ""), label=d.get("label", ""), pool=d.get("pool", ""),
                   joints=tuple(d.get("joints", ())))


# ------------------------------------------------------------------------------------------------
# Features
# ------------------------------------------------------------------------------------------------

def _channel(ctx: RowContext, name: str) -> np.ndarray:
    if name.startswith("q") and name[1:].isdigit():
        j = int(name[1:])
        if not 1 <= j <= ctx.q.shape[1]:
            raise ValueError(f"feature channel {name!r}: no such joint")
        return ctx.q[:, j - 1]
    if name == "t_s":
        if ctx.t_s is None:
            raise ValueError("this effect term depends on t_s: the rows need a t_s column")
        return ctx.t_s
    if name == "temp_c":
        if ctx.temp_c is None:
            raise ValueError("this effect term depends on temp_c: the rows need a temp_c column")
        return ctx.temp_c
    if name == "row":
        return np.arange(len(ctx.q), dtype=float)
    raise ValueError(f"unknown feature channel {name!r}")


def _row_channel(ctx: RowContext, f: Feature | None) -> np.ndarray:
    """The row order of a feature in ``row``: with the campaign's pose ids recorded (``f.record_pose_id``) and the
    rows' pose ids known, a campaign row reads its place in the campaign and any other row continues the count
    after the campaign's last (in the order given); otherwise the rows' positions in the order given."""
    rec = getattr(f, "record_pose_id", None)
    if rec is None or ctx.pose_id is None:
        return _channel(ctx, "row")
    index = {int(p): k for k, p in enumerate(rec)}
    pid = np.asarray(ctx.pose_id).astype(np.int64)
    out = np.array([index.get(int(p), -1) for p in pid], dtype=float)
    new = out < 0
    out[new] = len(rec) + np.arange(int(new.sum()))
    return out


def _time(ctx: RowContext, f: Feature | None) -> np.ndarray:
    """``t_s`` of the rows for a feature of time (``None``: the channel alone). A feature fitted on a campaign records
    its time span (``f.t_span``, :func:`with_records`). Rows without ``t_s`` (a new session whose time is not recorded)
    read the state the campaign ended in. A polynomial drift, which grows without bound, goes on for rows that continue the
    campaign (within as long again as the campaign lasted after its end, or before its start) and holds the state the
    campaign ended (or began) in for rows further away: another session. The bounded shapes (a step, a transient that
    settles, an oscillation) go on as fitted, which for a transient is the state it settles to."""
    span = getattr(f, "t_span", None)
    if ctx.t_s is None:
        if span is None:
            raise ValueError("this effect term depends on t_s: the rows need a t_s column")
        return np.full(len(ctx.q), float(span[1]))
    t = np.asarray(ctx.t_s, float)
    if span is None or not isinstance(f, Pow):
        return t
    t0, t1 = float(span[0]), float(span[1])
    d = t1 - t0
    return np.where(t > t1 + d, t1, np.where(t < t0 - d, t0, t))


def _ch(ctx: RowContext, f: Feature | None, name: str | None = None) -> np.ndarray:
    """The values of the channel ``name`` (default the feature's ``ch``) on the rows, time and row order as the
    feature ``f`` recorded them (``None``: as the rows give them)."""
    name = f.ch if name is None else name
    if name == "t_s":
        return _time(ctx, f)
    return _row_channel(ctx, f) if name == "row" else _channel(ctx, name)


def history_signs(ctx: RowContext) -> np.ndarray:
    """Approach signs ``(n, 6)``, 0 where the state is unknown (before a joint's first move after the start
    or a recorded restart)."""
    n = len(ctx.q)
    reset = np.zeros(n, bool) if ctx.history_reset is None else np.asarray(ctx.history_reset, bool)
    if ctx.q_start is None:
        return approach_signs(ctx.q, None, unknown=reset)
    # a known start: the move from it into the first row counts
    q = np.vstack([np.asarray(ctx.q_start, float)[None], ctx.q])
    return approach_signs(q, None, unknown=np.concatenate([[True], reset]))[1:]


def _history(ctx: RowContext) -> tuple[np.ndarray, np.ndarray]:
    """The commanded joints ``(m, 6)`` [rad] in order, with the start prepended when it is known (``m = n + 1``,
    else ``n``), and the rows ``(m,)`` where the history starts anew (the first, a recorded restart). The
    history-dependent features below run over them and return their last ``n`` rows."""
    reset = np.zeros(len(ctx.q), bool) if ctx.history_reset is None else np.asarray(ctx.history_reset, bool).copy()
    q = np.asarray(ctx.q, float)
    if ctx.q_start is not None:
        q = np.vstack([np.asarray(ctx.q_start, float)[None], q])
        reset = np.concatenate([[False], reset])
    if len(reset):
        reset[0] = True
    return q, reset


def _last_moves(ctx: RowContext) -> np.ndarray:
    """The last nonzero move ``(n, 6)`` [rad] of each joint before each row (0 while unknown: after the start
    or a restart, until the joint moves)."""
    q, reset = _history(ctx)
    N = q.shape[1]
    out = np.zeros((len(q), N))
    last = np.zeros(N)
    for k in range(len(q)):
        if reset[k]:
            last = np.zeros(N)
        else:
            d = q[k] - q[k - 1]
            last = np.where(d != 0, d, last)
        out[k] = last
    return out[-len(ctx.q):]


def _steps_in(ctx: RowContext) -> np.ndarray:
    """The move ``(n, 6)`` [rad] into each row from the one before (0 for the first row, a repeat, after a
    restart; from ``q_start`` when known)."""
    q, reset = _history(ctx)
    d = np.vstack([np.zeros((1, q.shape[1])), np.diff(q, axis=0)])
    d[reset] = 0.0
    return d[-len(ctx.q):]


def _motion_heat(ctx: RowContext, tau: float, joints: tuple[int, ...] | None = None) -> np.ndarray:
    """Heat the motors of ``joints`` (1-based; default all) put into the arm with its motion, through a first-order
    lag of time constant ``tau`` [s]: each move adds their joint travel ``sum_j |dq_j|`` [rad], which decays with
    ``tau`` over ``t_s`` (``h_k = h_{k-1} exp(-dt / tau) + travel_k``) [rad]. Needs ``t_s``."""
    joints = tuple(range(1, ctx.q.shape[1] + 1)) if joints is None else joints
    return _heat_series(_channel(ctx, "t_s"), _steps_in(ctx), tau, joints)


def _heat_series(t: np.ndarray, steps: np.ndarray, tau: float, joints) -> np.ndarray:
    travel = np.abs(steps[:, [j - 1 for j in joints]]).sum(axis=1)
    h = np.empty(len(t))
    acc = 0.0
    for k in range(len(t)):
        acc = acc * (np.exp(-max(t[k] - t[k - 1], 0.0) / tau) if k else 0.0) + travel[k]
        h[k] = acc
    return h


def _merge_record(t_rec: np.ndarray, t_new: np.ndarray, tol: float = 1e-6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The campaign's record of row times ``t_rec`` (in its measurement order) merged with the times of the rows
    given ``t_new``: a given row within ``tol`` [s] of a recorded time *is* that recorded row. Returns the merged
    order (indices into ``concat(t_rec, new rows)``, the record first at equal times), which given rows are new,
    and each given row's position in the merged order."""
    t_rec = np.asarray(t_rec, float)
    t_new = np.asarray(t_new, float)
    srt = np.argsort(t_rec, kind="stable")
    pos = np.clip(np.searchsorted(t_rec[srt], t_new), 0, max(len(t_rec) - 1, 0))
    near = [srt[np.clip(pos + d, 0, len(t_rec) - 1)] for d in (-1, 0)] if len(t_rec) else []
    match = np.full(len(t_new), -1)
    for cand in near:
        ok = (match < 0) & (np.abs(t_rec[cand] - t_new) <= tol)
        match[ok] = cand[ok]
    new = match < 0
    t_all = np.concatenate([t_rec, t_new[new]])
    order = np.argsort(t_all, kind="stable")
    where = np.empty(len(t_all), int)
    where[order] = np.arange(len(t_all))
    at = np.where(new, 0, match)
    at[new] = len(t_rec) + np.arange(int(new.sum()))
    return order, new, where[at]


def _recorded_lag(f: Lag, ctx: RowContext) -> np.ndarray:
    """A lagged channel on the given rows, continuing the campaign's record ``f.record`` (its times and channel
    values): the rows are placed among the recorded ones by ``t_s``, so that a row alone, a subset or rows after
    the campaign read the lag the campaign's own sequence gives."""
    rec = f.record
    t_new, x_new = _channel(ctx, "t_s"), _channel(ctx, f.ch)
    order, new, at = _merge_record(rec.t_s, t_new)
    t_all = np.concatenate([np.asarray(rec.t_s, float), t_new[new]])[order]
    x_all = np.concatenate([np.asarray(rec.x, float), x_new[new]])[order]
    return _lagged(x_all, t_all, f.tau)[at]


def _recorded_heat(f: Heat, ctx: RowContext) -> np.ndarray:
    """Motion heat on the given rows, continuing the campaign's record ``f.record`` (times, commanded joints,
    rows where its history restarted), merged by ``t_s`` as :func:`_recorded_lag` does."""
    rec = f.record
    t_new = _channel(ctx, "t_s")
    order, new, at = _merge_record(rec.t_s, t_new)
    t_all = np.concatenate([np.asarray(rec.t_s, float), t_new[new]])[order]
    N = ctx.q.shape[1]
    q_all = np.concatenate([np.asarray(rec.q, float).reshape(-1, N), np.asarray(ctx.q, float)[new]])[order]
    reset = np.concatenate([np.asarray(rec.reset, bool), np.zeros(int(new.sum()), bool)])[order]
    reset[0] = True
    steps = np.vstack([np.zeros((1, N)), np.diff(q_all, axis=0)])
    steps[reset] = 0.0
    return _heat_series(t_all, steps, f.tau, tuple(range(1, N + 1) if f.joints is None else f.joints))[at]


def _play(ctx: RowContext, j: int, h: float) -> np.ndarray:
    """Backlash as a play operator on the commanded joint ``j`` with half clearance ``h`` [rad]: the output
    ``o_k = clip(o_{k-1}, u_k - h, u_k + h)`` lags the command ``u``; the feature is ``(o - u) / h`` in [-1, 1]
    (-1 after a move up by more than ``2 h``, +1 after one down; moves within the clearance do not switch it).
    After the start or a restart the output is only known to lie within ``[u - h, u + h]``; the moves since
    narrow that interval (each end passes through the operator) and the feature reads its middle: 0 at the
    start, the exact play once the joint has travelled ``2 h`` one way, and continuous in ``h`` in between."""
    q, reset = _history(ctx)
    u = q[:, j - 1]
    out = np.zeros(len(u))
    lo = hi = u[0]
    for k in range(len(u)):
        if reset[k]:
            lo, hi = u[k] - h, u[k] + h
        else:
            lo, hi = min(max(lo, u[k] - h), u[k] + h), min(max(hi, u[k] - h), u[k] + h)
        out[k] = (0.5 * (lo + hi) - u[k]) / h
    return out[-len(ctx.q):]


def _cartesian_moves(ctx: RowContext, model: RobotModel, tcp: np.ndarray) -> np.ndarray:
    """Unit vector ``(n, 3)`` of the last move of the tool centre point ``tcp`` (flange frame [m]; the plate's
    centre) in the base frame (nominal kinematics; zero after the start or a restart, and kept through rows
    that do not move)."""
    q, reset = _history(ctx)
    F = link_frames(model, q)[:, -1]
    pos = F[:, :3, 3] + F[:, :3, :3] @ tcp
    out = np.zeros((len(pos), 3))
    last = np.zeros(3)
    for k in range(len(pos)):
        if reset[k]:
            last = np.zeros(3)
        else:
            d = pos[k] - pos[k - 1]
            nd = np.linalg.norm(d)
            if nd > 1e-6:
                last = d / nd
        out[k] = last
    return out[-len(ctx.q):]


def _lagged(x: np.ndarray, t: np.ndarray, tau: float) -> np.ndarray:
    """``x`` ``(n,)`` through a first-order lag of time constant ``tau`` [s] over the row times ``t`` ``(n,)``
    [s]: ``y_k = y_{k-1} + (1 - exp(-(t_k - t_{k-1}) / tau)) (x_k - y_{k-1})``, ``y_0 = x_0``."""
    y = np.empty_like(x, dtype=float)
    if len(x) == 0:
        return y
    a = -np.expm1(-np.clip(np.diff(t), 0.0, None) / tau)
    y[0] = x[0]
    for k in range(1, len(x)):
        y[k] = y[k - 1] + a[k - 1] * (x[k] - y[k - 1])
    return y


def with_records(features, ctx: RowContext) -> list[Feature]:
    """``features`` with what evaluating them on other rows needs from the campaign they were fitted on:
    a lagged channel and the motion heat carry the campaign's record (times, channel values, joints, restarts),
    a term in the row order the campaign's pose ids (:func:`feature_values` merges new rows with the record), so
    that a row's prediction does not depend on which other rows are in the file; a term of time its time span
    (outside it, the term holds the state the campaign ended in: :func:`_time`)."""
    out = []
    for f in features:
        if isinstance(f, Lag) and ctx.t_s is not None:
            f = replace(f, record=LagRecord(t_s=tuple(np.asarray(ctx.t_s, float).tolist()),
                                            x=tuple(_channel(ctx, f.ch).tolist())))
        elif isinstance(f, Heat) and ctx.t_s is not None:
            reset = np.zeros(len(ctx.q), bool) if ctx.history_reset is None else np.asarray(ctx.history_reset, bool)
            f = replace(f, record=HeatRecord(t_s=tuple(np.asarray(ctx.t_s, float).tolist()),
                                             q=tuple(map(tuple, np.asarray(ctx.q, float).tolist())),
                                             reset=tuple(reset.tolist())))
        ch = getattr(f, "ch", None)
        if ch == "row" and ctx.pose_id is not None:
            f = replace(f, record_pose_id=tuple(np.asarray(ctx.pose_id).astype(int).tolist()))
        if (ch == "t_s" or isinstance(f, (Settle, Field)) and f.tau is not None) and ctx.t_s is not None:
            f = replace(f, t_span=(float(np.min(ctx.t_s)), float(np.max(ctx.t_s))))
        if isinstance(f, Gated):
            f = replace(f, f=with_records([f.f], ctx)[0])
        out.append(f)
    return out


HISTORY_FEATURES = ("sign", "play", "lastmove", "stepin", "cartdir")  # need the order of the moves


def history_unknown(features_list, ctx: RowContext) -> np.ndarray:
    """Rows ``(n,)`` where a term that needs the order of the moves (an approach direction, the last move, a
    play, the direction of the last Cartesian move: ``HISTORY_FEATURES``) lacks its history: its joint has not
    moved since the first row given or a restart (for the Cartesian direction: no joint has). ``features_list``:
    one feature tuple per term."""
    s = history_signs(ctx)
    out = np.zeros(len(ctx.q), bool)
    for feats in features_list:
        for f in feats:
            if f.kind not in HISTORY_FEATURES:
                continue
            if isinstance(f, CartDir):
                out |= np.all(s == 0, axis=1)
            else:
                out |= s[:, int(f.j) - 1] == 0
    return out


def approach_unknown(ctx: RowContext) -> np.ndarray:
    """Rows ``(n,)`` where some joint that moves during the campaign has an unknown approach direction (after
    the start or a restart, until it moves): history-dependent terms cannot be predicted there."""
    s = history_signs(ctx)
    moves = np.ptp(ctx.q, axis=0) > 0
    return np.any((s == 0) & moves[None, :], axis=1)


def feature_values(features, ctx: RowContext, model: RobotModel, cache: dict | None = None) -> np.ndarray:
    """Values ``(n, K)`` of ``features`` (:mod:`twin.diagnosis.features`) on the rows of ``ctx`` (``model``: the
    nominal robot, for gravity)."""
    cache = {} if cache is None else cache
    n = len(ctx.q)
    out = np.empty((n, len(features)))
    for k, f in enumerate(features):
        if isinstance(f, Pow):
            out[:, k] = ((_ch(ctx, f) - f.c) / f.h) ** f.p
        elif isinstance(f, (Sin, Cos)):
            x = f.k * _ch(ctx, f)
            out[:, k] = np.sin(x) if isinstance(f, Sin) else np.cos(x)
        elif isinstance(f, Prod):
            a, b = f.ch
            out[:, k] = (_channel(ctx, a) - f.c[0]) / f.h[0] * (_channel(ctx, b) - f.c[1]) / f.h[1]
        elif isinstance(f, Sign):
            if "signs" not in cache:
                cache["signs"] = history_signs(ctx)
            out[:, k] = cache["signs"][:, f.j - 1]
        elif isinstance(f, Grav):
            if "grav" not in cache:
                cache["grav"] = gravity_torque_regressor(model, ctx.q)
            out[:, k] = cache["grav"][:, f.i - 1, f.k - 1, f.c] / (1.0 if f.h is None else f.h)
        elif isinstance(f, LastMove):
            if "moves" not in cache:
                cache["moves"] = _last_moves(ctx)
            out[:, k] = np.tanh(cache["moves"][:, f.j - 1] / f.w)
        elif isinstance(f, GravMix):
            if "grav" not in cache:
                cache["grav"] = gravity_torque_regressor(model, ctx.q)
            Yg = cache["grav"]
            out[:, k] = sum(w * Yg[:, f.i - 1, kk - 1, c] for w, (kk, c) in zip(f.w, f.cols)) / f.h
        elif isinstance(f, Torque):
            # the gravity load of joint j from the chain's mass properties [N m, or N along a prismatic axis]
            if "torque" not in cache:
                cache["torque"] = gravity_torques(model, ctx.q)
            out[:, k] = cache["torque"][:, f.j - 1] / (1.0 if f.h is None else f.h)
        elif isinstance(f, Moment):
            # the gravity moment of what joint j carries about its origin (j = 0: the base), one axis of its frame
            key = ("moment", f.j)
            if key not in cache:
                cache[key] = carried_moments(model, ctx.q, int(f.j))
            out[:, k] = cache[key][:, f.axis] / (1.0 if f.h is None else f.h)
        elif isinstance(f, BaseMoment):
            # the arm's gravity moment about one horizontal axis of the base through its origin, as a combination of
            # the links' unknown mass moments (:func:`twin.diagnosis.loads.base_moment_regressor`)
            if "basemoment" not in cache:
                from .loads import base_moment_regressor

                cache["basemoment"] = base_moment_regressor(model, ctx.q)
            Yb = cache["basemoment"][:, f.axis].reshape(n, -1)
            out[:, k] = Yb @ np.asarray(f.w, float) / (1.0 if f.h is None else f.h)
        elif isinstance(f, GravityDir):
            if "gdir" not in cache:
                fr = link_frames(model, ctx.q)
                R = fr[:, -1, :3, :3]  # flange (last link frame) in the base frame
                cache["gdir"] = np.einsum("nji,j->ni", R, GRAVITY / np.linalg.norm(GRAVITY))
            out[:, k] = cache["gdir"][:, f.axis]
        elif isinstance(f, Step):
            out[:, k] = (_ch(ctx, f) >= f.at).astype(float)
        elif isinstance(f, Window):
            # a change and back: the state differs from ``at`` until ``until`` (a step and its return)
            x = _ch(ctx, f)
            out[:, k] = ((x >= f.at) & (x < f.until)).astype(float)
        elif isinstance(f, LoadSign):
            # the side of the gear flank the joint's gravity load pushes it to: the sign of the load (the URDF
            # masses' torque, or the leading gravity-torque shape when the masses are unknown)
            out[:, k] = np.sign(feature_values((f.f,), ctx, model, cache)[:, 0])
        elif isinstance(f, Hinge):
            # zero on one side of an angle, growing as a power of the overtravel past it (a cable going taut)
            out[:, k] = (np.clip(f.side * (_channel(ctx, f.ch) - f.at), 0.0, None) / f.h) ** f.p
        elif isinstance(f, StepIn):
            out[:, k] = _steps_in(ctx)[:, f.j - 1]
        elif isinstance(f, Heat):
            joints = tuple(range(1, ctx.q.shape[1] + 1) if f.joints is None else f.joints)
            key = ("heat", f.tau, joints, f.record is not None)
            if key not in cache:
                if f.record is not None and ctx.t_s is None:
                    # a new session whose time is not recorded: the heat the campaign ended with
                    rec = f.record
                    steps = np.vstack([np.zeros((1, ctx.q.shape[1])), np.diff(np.asarray(rec.q, float).reshape(-1, ctx.q.shape[1]), axis=0)])
                    steps[np.asarray(rec.reset, bool)] = 0.0
                    end = _heat_series(np.asarray(rec.t_s, float), steps, f.tau, joints)[-1]
                    cache[key] = np.full(len(ctx.q), end)
                else:
                    cache[key] = _recorded_heat(f, ctx) if f.record is not None else _motion_heat(ctx, f.tau, joints)
            out[:, k] = cache[key] / f.h  # a scale fixed on the rows the atom was built on
        elif isinstance(f, Settle):
            st = np.asarray(ctx.station).astype(str) if ctx.station is not None else None
            if st is None:
                raise ValueError("this effect term depends on the station: the rows need a station column")
            t0s = dict(f.t0)
            t0 = np.array([t0s.get(s, np.nan) for s in st])
            if np.any(np.isnan(t0)):
                raise ValueError(f"this effect term knows the set-up times of stations {sorted(t0s)} only")
            out[:, k] = -np.expm1(-np.clip(_time(ctx, f) - t0, 0.0, None) / f.tau)
            if f.only is not None:
                out[:, k] *= st == str(f.only)
        elif isinstance(f, Gated):
            # an inner feature that acts from a moment on (a payload added at a restart)
            x = _ch(ctx, f)
            on = (x >= f.at) & (x < f.until) if f.until is not None else x >= f.at
            out[:, k] = feature_values((f.f,), ctx, model, cache)[:, 0] * on
        elif isinstance(f, Play):
            key = ("play", f.j, f.h)
            if key not in cache:
                cache[key] = _play(ctx, f.j, f.h)
            out[:, k] = cache[key]
        elif isinstance(f, CartDir):
            tcp = (0.0, 0.0, 0.0) if f.tcp is None else f.tcp
            key = ("cartdir", tuple(tcp))
            if key not in cache:
                cache[key] = _cartesian_moves(ctx, model, np.asarray(tcp, dtype=float))
            out[:, k] = cache[key][:, f.axis]
        elif isinstance(f, Exp):
            # a transient settling with time constant tau from t0 (a warm-up): 1 - exp(-(t - t0) / tau)
            # (zero before t0: rows of an earlier session)
            out[:, k] = -np.expm1(-np.clip(_ch(ctx, f) - f.t0, 0.0, None) / f.tau)
        elif isinstance(f, Lag):
            # the channel seen through a first-order lag of time constant tau (a link's temperature follows
            # the air's): exact for a channel constant between rows, started at the first row's value
            if f.record is not None and ctx.t_s is None:
                lag = _channel(ctx, f.ch)  # a new session whose time is not recorded: the channel settled
            else:
                lag = _recorded_lag(f, ctx) if f.record is not None else _lagged(_channel(ctx, f.ch), _channel(ctx, "t_s"), f.tau)
            out[:, k] = (lag - f.c) / (1.0 if f.h is None else f.h)
        elif isinstance(f, Station):
            if ctx.station is None:
                raise ValueError("this effect term depends on the station: the rows need a station column")
            out[:, k] = (np.asarray(ctx.station).astype(str) == str(f.name)).astype(float)
        elif isinstance(f, Const) or (isinstance(f, Field) and f.tau is None):
            out[:, k] = 1.0  # a field atom's values depend on the point, not the row (twin.diagnosis.field)
        elif isinstance(f, Field):
            # a field that grows with a settling transient (an instrument warming up after switch-on)
            out[:, k] = -np.expm1(-np.clip(_time(ctx, f) - f.t0, 0.0, None) / f.tau)
        else:
            raise ValueError(f"unknown feature kind {getattr(f, 'kind', None)!r} in {f!r}")
    if not np.all(np.isfinite(out)):
        bad = np.unique(np.nonzero(~np.isfinite(out))[0])[:10]
        raise ValueError(f"effect features are not finite in rows {bad.tolist()} (check t_s / temp_c)")
    return out


# ------------------------------------------------------------------------------------------------
# Pools
# ------------------------------------------------------------------------------------------------

def _norm(x: np.ndarray) -> tuple[float, float]:
    c = float(np.mean(x))
    h = float(max(0.5 * np.ptp(x), 1e-9))
    return c, h


def play_backlash(j: int, h: float) -> Atom:
    """Joint ``j``'s backlash as a play operator with half clearance ``h`` [rad] (moves shorter than the
    clearance do not switch the side): it competes with the sign backlash (:func:`twin.diagnosis.select.prefer_play`)."""
    hd = np.rad2deg(h)
    return Atom("backlash", "joint", f"theta{j}", (Play(j=j, h=float(h)),), f"play j{j} half {hd:.3g} deg",
                f"joint {j} backlash with a half clearance of {hd:.3g} deg (play: short moves do not switch the side)",
                "catalogue", (j,))


def hinge_atom(j: int, at: float, side: int, p: int, h: float, *, prismatic: bool = False,
               words: str | None = None) -> Atom:
    """Joint ``j``'s angle growing as ``(max(0, side (q_j - at)) / h)^p`` [``at`` rad, ``h`` rad a scale]: zero on one
    side of the angle ``at``, a power of the overtravel past it (a cable or hose going taut and pulling). A
    prismatic joint's position likewise ([m]); ``words``: the joint in words (default ``j``)."""
    ad, unit = (at * 1e3, "mm") if prismatic else (np.rad2deg(at), "deg")
    rel = f"q{j} - {ad:.4g} {unit}" if side > 0 else f"{ad:.4g} {unit} - q{j}"
    ch = f"max(0, {rel})" + ("" if p == 1 else f"^{p}")
    what = "position varies with {} (a pull past a position)" if prismatic else "angle varies with {} (a pull past an angle)"
    return Atom("unnamed", "joint", f"theta{j}", (Hinge(ch=f"q{j}", at=float(at), side=int(side),
                                                  p=int(p), h=float(h)),), ch,
                f"unnamed: joint {words or j} {what.format(ch)}", "generic", (j,))


def _nominal_length(model: RobotModel, name: str) -> float:
    """The nominal value [m] of length parameter ``name`` of ``model`` (``"a3"``, ``"d4"``; a ``"urdf"`` chain's
    ``"<joint>.xyz"``: the length of the joint's origin translation)."""
    if name.endswith(".xyz"):
        j = name[: -len(".xyz")]
        return float(np.linalg.norm([model.params[model.layout.index(f"{j}.{c}")] for c in "xyz"]))
    return float(model.params[model.layout.index(name)])


def joint_words(model: RobotModel, j: int) -> str:
    """How a joint is named in words: ``"3"`` on the 6R robots, ``"3 (arm_2_joint)"`` on a named chain."""
    return str(j) if model.convention != "urdf" else f"{j} ({model.joint_names[j - 1]})"


def wrist_couplings(model: RobotModel) -> tuple[tuple[int, int], ...]:
    """``(driven, driving)`` 1-based joint pairs whose drives may be coupled: the last three joints of the chain
    when they are revolute (a wrist whose drive shafts pass through the joints before; a 6R arm's 5-4, 6-4, 6-5)."""
    N = model.n_joints
    if N < 3 or any(model.joint_kinds[j] != "revolute" for j in range(N - 3, N)):
        return ()
    a, b, c = N - 2, N - 1, N
    return ((b, a), (c, a), (c, b))


def _session_starts(ctx: RowContext) -> list[tuple[str, float]]:
    """``(time channel, value)`` at the first row of every session after the first (a gap in ``t_s`` or a
    recorded restart: ``ctx.session_start``)."""
    if ctx.session_start is None:
        return []
    tch = _time_channel(ctx) or "row"
    tv = _channel(ctx, tch)
    rows = np.flatnonzero(np.asarray(ctx.session_start, bool))
    return [(tch, float(tv[r])) for r in rows if r > 0]


def _time_channel(ctx: RowContext) -> str | None:
    if ctx.t_s is not None and np.ptp(ctx.t_s) > 0:
        return "t_s"
    return None


def _time_features(ctx: RowContext, ch: str) -> list[Feature]:
    c, h = _norm(_channel(ctx, ch))
    return [Pow(ch=ch, p=1, c=c, h=h)]


def catalogue_atoms(model: RobotModel, ctx: RowContext, length_names: list[str], *,
                    harmonic_orders: tuple[int, ...] = (1, 2, 3), n_points: int = 3,
                    whole_orders: bool = True) -> list[Atom]:
    """The named pool (see the module docstring), built on the nominal ``model`` and the rows of ``ctx``
    (``n_points``: the points of the marker set, one ``plate_geometry`` atom each). Any serial chain: its joints
    by index (``theta<j>``, ``q<j>``, 1-based) and in words by name (:func:`joint_words`); harmonics, cyclic
    scans and the wrist couplings for revolute joints only; with the chain's mass properties (a URDF's
    inertials), compliance under the gravity load they give and the tilt of each joint's support (and of the
    base) under the gravity moment it carries. ``whole_orders``: the cyclic scan takes whole cycles per joint turn
    only (a physical period); half orders only where terms are confirmed on another session."""
    atoms: list[Atom] = []
    N = model.n_joints
    jw = lambda j: joint_words(model, j)  # noqa: E731
    revolute = [k == "revolute" for k in model.joint_kinds]
    # compliance: dtheta_i = c_i tau_i(q), tau_i linear in the mass moments (m_k, h_k = m_k c_k) of links
    # k >= i. The linear relaxation has up to 24 columns per joint; with a generic prior on the moments
    # (masses of one order, centres of mass ~0.1 m off the link frames) the torques a real arm can have
    # lie close to the leading COMPLIANCE_RANK principal shapes of the prior-weighted columns on these rows:
    # the atom keeps those (a broad atom would collect a little of every other effect).
    Y = gravity_torque_regressor(model, ctx.q)
    for i in range(1, N + 1):
        cols, prior = [], []
        for k in range(i, N + 1):
            for c in range(4):
                cols.append([k, c])
                prior.append(1.0 if c == 0 else COM_PRIOR_M)
        M = np.stack([Y[:, i - 1, k - 1, c] for k, c in cols], axis=1) * np.array(prior)
        if not np.any(np.abs(M) > 1e-9):
            continue
        _, sv, Vt = np.linalg.svd(M, full_matrices=False)
        rk = int(np.sum(sv > 1e-6 * sv[0]))

        def shapes(a, b):
            return tuple(GravMix(i=i, cols=tuple(map(tuple, cols)), w=tuple((Vt[j] * np.array(prior)).tolist()),
                          h=float(sv[j] / np.sqrt(len(M)))) for j in range(a, min(b, rk)))

        atoms.append(Atom("compliance", "joint", f"theta{i}", shapes(0, COMPLIANCE_RANK), f"gravity torque of joint {i}",
                          f"joint {jw(i)} compliance under gravity", "catalogue", (i,)))
        for tch, at in _session_starts(ctx):
            # a payload added (or a brake set) at a restart changes the torque from then on
            atoms.append(Atom("compliance", "joint", f"theta{i}",
                              tuple(Gated(f=f, ch=tch, at=at) for f in shapes(0, COMPLIANCE_RANK)),
                              f"gravity torque of joint {i} from {tch} >= {at:.6g}",
                              f"joint {jw(i)} compliance under gravity, changed at the restart ({tch} >= {at:.6g})",
                              "catalogue", (i,)))
        if rk > COMPLIANCE_RANK:
            # the further shapes (a payload, wrist masses): a broad atom, tried after the small ones
            atoms.append(Atom("compliance", "joint", f"theta{i}", shapes(COMPLIANCE_RANK, 3 * COMPLIANCE_RANK),
                              f"gravity torque of joint {i} (further shapes)",
                              f"joint {jw(i)} compliance under gravity, further torque shapes", "catalogue", (i,)))
    if has_masses(model):
        # with the chain's mass properties the load is known: one stiffness per joint, dq_i = c_i tau_i(q)
        tau = gravity_torques(model, ctx.q)
        for i in range(1, N + 1):
            t = tau[:, i - 1]
            if np.ptp(t) <= 1e-9 * max(1.0, float(np.max(np.abs(t)))):
                continue  # a constant load (a vertical lift carries the same weight everywhere): the offset holds it
            what = "force along it" if model.joint_kinds[i - 1] == "prismatic" else "torque about it"
            atoms.append(Atom("compliance", "joint", f"theta{i}", (Torque(j=i, h=1.0),),
                              f"gravity load of joint {i} (URDF masses)",
                              f"joint {jw(i)} compliance under gravity (the {what} from the URDF masses)",
                              "catalogue", (i,)))
        # the support of a joint (a column, a bearing, the base on its wheels or a pedestal) tilting about two
        # axes of its frame under the gravity moment of everything it carries, one compliance per axis
        for i in range(0, N + 1):
            M = carried_moments(model, ctx.q, i)
            feats = tuple(Moment(j=i, axis=a, h=1.0) for a in (0, 1)
                          if np.ptp(M[:, a]) > 1e-9 * max(1.0, float(np.max(np.abs(M[:, a])))))
            if len(feats) < 2:
                continue
            where = ("the robot's base tilting about its horizontal axes" if i == 0 else
                     f"the support of joint {jw(i)} tilting about its x and y axes")
            atoms.append(Atom("tilt", "param", f"tilt{i}", feats, f"gravity moment carried by {'the base' if i == 0 else f'joint {i}'}",
                              f"{where} under the gravity moment it carries (URDF masses)", "catalogue",
                              (i,) if i else ()))
    for j in range(1, N + 1):
        atoms.append(Atom("backlash", "joint", f"theta{j}", (Sign(j=j),), f"approach_sign_j{j}",
                          f"joint {jw(j)} backlash (offset signed by the direction of its last move)", "catalogue", (j,)))
        if revolute[j - 1]:
            for k in harmonic_orders:
                atoms.append(Atom("cyclic", "joint", f"theta{j}",
                                  (Sin(ch=f"q{j}", k=k), Cos(ch=f"q{j}", k=k)),
                                  f"sin/cos({k} q{j})", f"joint {jw(j)}, {_ORD.get(k, f'{k}th')} harmonic", "catalogue", (j,),
                                  {"order": k}))
        atoms.append(Atom("gear_ratio", "joint", f"theta{j}", (Pow(ch=f"q{j}", p=1, c=0.0, h=1.0),),
                          f"q{j}", f"joint {jw(j)} gear-ratio error (theta_{j} grows with q{j})" if revolute[j - 1] else
                          f"joint {jw(j)} travel scale error (its offset grows with q{j})", "catalogue", (j,)))
    # cyclic errors of the motor-side stages: k = N h cycles per joint turn (gear ratios of 50-150 are usual): whole
    # orders (a pool of their own: its size enters the evidence threshold). A stage with a non-integer ratio (a
    # belt, an intermediate gear) is scanned on a half-order grid and its order refined only where a term is
    # confirmed on another session: on one session's pose pattern a free period fits the pattern, not the robot
    for j in range(1, N + 1):
        if np.ptp(ctx.q[:, j - 1]) < 1e-6 or not revolute[j - 1]:
            continue
        for k in np.arange(SCAN_ORDERS[0], SCAN_ORDERS[1] + 1e-9, SCAN_ORDERS[2]):
            k = float(k)
            if whole_orders and k != round(k):
                continue
            if k in harmonic_orders or k * np.ptp(ctx.q[:, j - 1]) < 1.5 * (2 * np.pi):
                continue  # a period is evidence only where the rows see it repeat (1.5 periods over the range)
            atoms.append(Atom("cyclic", "joint", f"theta{j}",
                              (Sin(ch=f"q{j}", k=k), Cos(ch=f"q{j}", k=k)),
                              f"sin/cos({k:.4g} q{j})", f"joint {jw(j)}, harmonic of order {k:.4g} (cycles per joint turn)",
                              "scan", (j,), {"order": k}))
    # wrist coupling: the drives of the last two joints pass through the one before (a 6R arm's 5 and 6 through 4,
    # 6's through 5): a coupling-ratio error turns the driven joint with the driving one
    for jd, js in wrist_couplings(model):
        atoms.append(Atom("coupling", "joint", f"theta{jd}", (Pow(ch=f"q{js}", p=1, c=0.0, h=1.0),),
                          f"q{js}", f"wrist coupling (theta{jd} follows q{js})", "catalogue", (js, jd)))
    # thermal growth: each link, and all links together, against temp_c (linear) or a cubic in t_s
    if ctx.temp_c is not None and np.ptp(ctx.temp_c) > 0:
        ref = float(np.median(ctx.temp_c))
        feats = (Pow(ch="temp_c", p=1, c=ref, h=1.0),)
        ch = "temp_c"
    elif _time_channel(ctx):
        feats = tuple(_time_features(ctx, "t_s"))
        ch = "t_s"  # linear: a polynomial in time goes where the rows are not (later rows), a warm-up settles
    else:
        feats = ()
    variants = [(feats, ch)] if feats else []
    # a link's temperature lags the recorded one (the air's, a sensor elsewhere on the arm): the temperature
    # through a first-order lag; without a temperature, the warm-up as a transient 1 - exp(-t / tau) beside the
    # linear drift. And whatever the air does, the motors heat the arm with its motion: each link against the
    # joints' travel through a first-order lag (heat in per move, out with tau). Time constants on a coarse
    # grid, refined when an atom is kept.
    span = float(np.ptp(ctx.t_s)) if _time_channel(ctx) else 0.0
    if span > 0:
        for tau in (fr * span for fr in TAU_FRACTIONS):
            if ch == "temp_c":
                f = Lag(ch="temp_c", tau=float(tau), c=ref, h=1.0)
                variants.append(((f,), f"temp_c lagged {tau:.4g} s"))
            else:
                f = Exp(ch="t_s", t0=float(ctx.t_s[0]), tau=float(tau))
                variants.append(((f,), f"warm-up 1-exp(-t/{tau:.4g} s)"))
            # the motors' holding current heats too, from servo-on: the same lag applied to a constant input
            # the arm's motors (joints 1-3) and the wrist's (4-6) each heat what is near them
            heat = [Heat(tau=float(tau), joints=tuple(js),
                     h=float(max(np.mean(_motion_heat(ctx, float(tau), tuple(js))), 1e-9)))
                    for js in (list(range(1, N - 2)), list(range(N - 2, N + 1))) if js]
            variants.append(((*heat,
                              Exp(ch="t_s", t0=float(ctx.t_s[0]), tau=float(tau))),
                             f"motion heat lagged {tau:.4g} s"))
    for fs, chan in variants:
        atoms.append(Atom("thermal", "length", "all_lengths", fs, chan, f"thermal growth of all link lengths vs {chan}",
                          "catalogue"))
        for L in length_names:
            if abs(_nominal_length(model, L)) < MIN_THERMAL_LENGTH:
                continue  # a link of nominal length ~0 (a2 of the IRB 1200) has no length to grow
            atoms.append(Atom("thermal", "length", L, fs, chan, f"thermal growth of link {L} vs {chan}", "catalogue"))
    for s in range(n_points):
        atoms.append(Atom("plate_geometry", "plate", f"sphere{s}", (Const(),), "constant",
                          f"sphere {s} off its nominal plate position", "catalogue"))
    # the arm's own load without its masses: backlash signed by the load, the base tilting under the arm's moment
    from .loads import load_atoms

    return atoms + load_atoms(model, ctx)


def generic_atoms(model: RobotModel, ctx: RowContext, param_names: list[str], length_names: list[str],
                  catalogue: list[Atom], *, n_change_points: int = 9, points: np.ndarray | None = None,
                  plate_spheres: np.ndarray | None = None) -> list[Atom]:
    """The unnamed dictionary: every place against every smooth basis of every channel (module docstring).
    Atoms whose columns equal a catalogue atom's are left out (the catalogue names them). ``points``: the
    measured points ``(n, K, 3)`` [m] in the measurement frame (NaN where not seen), for the field
    atoms' constants (none without them); ``plate_spheres`` ``(K, 3)`` [m]: the nominal points in the
    plate frame (their plane's normal, for the field that follows the plate's tilt). Any serial chain: harmonics
    of revolute joints only, a prismatic joint's move widths in millimetres."""
    q = ctx.q
    N = model.n_joints
    revolute = [k == "revolute" for k in model.joint_kinds]
    jw = lambda j: joint_words(model, j)  # noqa: E731
    couplings = wrist_couplings(model)
    feats: list[tuple[str, Feature | tuple, tuple[int, ...]]] = []  # (channel label, feature(s), joints)
    for j in range(1, N + 1):
        c, h = _norm(q[:, j - 1])
        if np.ptp(q[:, j - 1]) < 1e-6:
            continue
        for p in (1, 2, 3):
            # a polynomial of degree p (all lower powers with it: a centred power alone cannot follow an
            # offset curve)
            feats.append((f"q{j}^{p}" if p > 1 else f"q{j}",
                          tuple(Pow(ch=f"q{j}", p=e, c=c, h=h) for e in range(1, p + 1)), (j,)))
        if revolute[j - 1]:
            for k in (1, 2, 3):
                feats.append((f"sin/cos({k} q{j})", (Sin(ch=f"q{j}", k=k), Cos(ch=f"q{j}", k=k)), (j,)))
        feats.append((f"approach_sign_j{j}", Sign(j=j), (j,)))
        for w_deg in MOVE_WIDTHS_DEG:
            # hysteresis that follows the size of the last move (friction-like), on the joint angles only
            if revolute[j - 1]:
                feats.append((f"tanh(last move j{j} / {w_deg:.3g} deg)", LastMove(j=j, w=w_deg * _DEG), (j,)))
            else:
                feats.append((f"tanh(last move j{j} / {w_deg:.3g} mm)", LastMove(j=j, w=w_deg * 1e-3), (j,)))
        # the step into this row (zero for a repeat): a joint still settling from the move it just made
        feats.append((f"step into the row j{j}", StepIn(j=j), (j,)))
    for a in range(1, N + 1):
        for b in range(a + 1, N + 1):
            if np.ptp(q[:, a - 1]) < 1e-6 or np.ptp(q[:, b - 1]) < 1e-6:
                continue
            ca, ha = _norm(q[:, a - 1])
            cb, hb = _norm(q[:, b - 1])
            # the product with both linear terms (a centred product alone leaves a linear remainder)
            feats.append((f"q{a}*q{b}", (Pow(ch=f"q{a}", p=1, c=ca, h=ha),
                                         Pow(ch=f"q{b}", p=1, c=cb, h=hb),
                                         Prod(ch=(f"q{a}", f"q{b}"), c=(ca, cb), h=(ha, hb))),
                          (a, b)))
    for ax, nm in enumerate("xyz"):
        feats.append((f"gravity_dir_flange_{nm}", GravityDir(axis=ax), ()))
    # time: only in t_s (a term in the row count says nothing of the next session); linear, change points,
    # settling transients and (on the cell) oscillations; no higher polynomial in time: it goes where the rows are
    # not (the next rows, later), and a blind campaign's re-seated plate, fitted with t^2, was predicted 13x worse
    # than its oracle on the rows after the campaign
    tch = _time_channel(ctx)
    span = 0.0
    if tch is not None:
        tv = _channel(ctx, tch)
        c, h = _norm(tv)
        feats.append((tch, (Pow(ch=tch, p=1, c=c, h=h),), ()))
        for qq in np.linspace(0, 1, n_change_points + 2)[1:-1]:
            at = float(np.quantile(tv, qq))
            feats.append((f"step({tch} >= {at:.6g})", Step(ch=tch, at=at), ()))
        span = float(np.ptp(tv))
        for tau in (fr * span for fr in TAU_FRACTIONS):
            # a transient that settles (warm-up of the robot, the camera mount, the cell): extrapolates as it settles
            feats.append((f"1-exp(-{tch}/{tau:.4g})", Exp(ch=tch, t0=float(tv[0]), tau=float(tau)), ()))
    # a change at a session start (a restart, another day) is a term of the sessions, located by t_s or the row
    starts = _session_starts(ctx)
    sch = tch or "row"
    for _, at in starts:
        feats.append((f"step({sch} >= {at:.6g}) (restart)", Step(ch=sch, at=at), ()))
    if len(starts) > 1:
        # a change at every restart (a joint re-homed, a plate re-seated each time): one term, a step at each
        feats.append(("a step at every session start", tuple(Step(ch=sch, at=at) for _, at in starts), ()))
    if ctx.temp_c is not None and np.ptp(ctx.temp_c) > 0:
        c, h = _norm(ctx.temp_c)
        for p in (1, 2):
            feats.append(("temp_c" if p == 1 else "temp_c^2",
                          tuple(Pow(ch="temp_c", p=e, c=c, h=h) for e in range(1, p + 1)), ()))
        if tch == "t_s":
            for tau in (fr * span for fr in TAU_FRACTIONS):
                feats.append((f"temp_c lagged {tau:.4g} s", Lag(ch="temp_c", tau=float(tau), c=c, h=h), ()))
    if ctx.station is not None:
        names = sorted(set(np.asarray(ctx.station).astype(str).tolist()))
        if len(names) > 1:
            for s in names:
                feats.append((f"station=={s}", Station(name=s), ()))

    # an oscillation in time (the air conditioning's cycle swaying a stand, warming a mount): on the cell's
    # places only (the measurement frame and scale), the period refined when kept
    cell_feats = []
    if span > 0:
        for cyc in TIME_CYCLES:
            k = 2 * np.pi * cyc / span
            cell_feats.append((f"sin/cos(2pi {tch}/{span / cyc:.4g})", (Sin(ch=tch, k=float(k)),
                                                                        Cos(ch=tch, k=float(k))), ()))
    places: list[tuple[str, str, str, tuple[int, ...]]] = [
        ("joint", f"theta{j}", f"joint {jw(j)} " + ("angle" if revolute[j - 1] else "position"), (j,))
        for j in range(1, N + 1)]
    places += [("param", p, f"parameter {p}", ()) for p in param_names]
    places += [("param", "tool", "tool (plate) frame", ()), ("param", "base", "base (measurement) frame", ()),
               ("scale", "meas_scale", "measurement scale", ())]
    cat_keys = {(a.place, a.target, _fkey(a.features)) for a in catalogue}
    atoms = []
    for place, target, pl_words, pj in places:
        for ch, f, fj in feats:
            fs = f if isinstance(f, tuple) else (f,)
            f0 = fs[0]
            if isinstance(f0, (LastMove, StepIn)) and place != "joint":
                continue
            if isinstance(f0, Sign) and not (place == "joint" and (int(target[5:]), f0.j) in couplings):
                # a joint's motion history acts on that joint (the catalogue's backlash) or on a joint its drive
                # passes through (a wrist coupling), not on another joint's frame or the cell
                continue
            if (place, target, _fkey(fs)) in cat_keys:
                continue
            if place == "joint" and len(fs) == 1 and isinstance(f0, Pow) and f0.p == 1 and f0.ch == target.replace("theta", "q"):
                continue  # = gear_ratio up to the geometry's constant
            if place == "joint" and isinstance(f0, (Sin, Cos)) and f0.ch == target.replace("theta", "q"):
                continue  # = cyclic
            if place == "joint" and isinstance(f0, Sign) and f0.j == int(target[5:]):
                continue  # = backlash
            if place == "joint" and len(fs) == 1 and isinstance(f0, Pow) and f0.p == 1 and \
                    (int(target[5:]), int(f0.ch[1:]) if f0.ch.startswith("q") else 0) in couplings:
                continue  # = coupling
            if place == "param" and target in length_names and getattr(f0, "ch", None) in ("temp_c", "t_s") and isinstance(f0, Pow) \
                    and len(fs) <= (1 if f0.ch == "temp_c" else 3):
                continue  # = thermal (absolute instead of relative: the same column)
            if place == "param" and target in length_names and isinstance(f0, (Lag, Exp)):
                continue  # = thermal with a lag or a warm-up (absolute instead of relative)
            joints = tuple(sorted(set(pj) | set(fj)))
            if place == "scale":
                # the geometry cannot absorb a constant scale (the plate's size pins it), and the features are
                # centred: the scale atom carries its own constant (s = s0 + s1 f)
                fs = (Const(),) + fs
            atoms.append(Atom("unnamed", place, target, fs, ch, f"unnamed: {pl_words} varies with {ch}", "generic", joints))
    # a station's instrument settling after it was set up (a tripod foot sinking, a mount relaxing): a transient
    # from each station's first row, on the measurement frame
    if ctx.station is not None and tch == "t_s" and span > 0:
        st = np.asarray(ctx.station).astype(str)
        t_first = {s: float(tv[np.flatnonzero(st == s)[0]]) for s in sorted(set(st.tolist()))}
        for tau in (fr * span for fr in TAU_FRACTIONS):
            # one transient per station (each set-up settles its own way, about its own axis)
            cell_feats.append((f"settling since set-up 1-exp(-t/{tau:.4g})",
                               tuple(Settle(tau=float(tau), t0=tuple(t_first.items()), only=s) for s in t_first), ()))
    for place, target, pl_words in (("param", "base", "base (measurement) frame"), ("scale", "meas_scale", "measurement scale")):
        for ch, fs, _ in cell_feats:
            fs = ((Const(),) if place == "scale" else ()) + fs
            atoms.append(Atom("unnamed", place, target, fs, ch, f"unnamed: {pl_words} varies with {ch}", "generic"))
    # a pull that starts past an angle (a cable or dress pack going taut): zero on one side of the angle, a power of
    # the overtravel beyond it, on the joint itself; the angle on the deciles of the joint's range (then refined)
    for j in range(1, N + 1):
        x = q[:, j - 1]
        if np.ptp(x) < 1e-6:
            continue
        for at in np.quantile(x, np.linspace(0, 1, HINGE_POINTS + 2)[1:-1]):
            for side in (1, -1):
                for pw in HINGE_POWERS:
                    atoms.append(hinge_atom(j, float(at), side, pw, float(max(0.5 * np.ptp(x), 1e-9)),
                                            prismatic=not revolute[j - 1], words=jw(j)))
    # the flange stops short of (or beyond) its target along its last move (settling): a displacement in the
    # base frame along the direction of the last Cartesian move
    tcp = [0.0, 0.0, 0.0] if plate_spheres is None else np.mean(np.asarray(plate_spheres, float), axis=0).tolist()
    atoms.append(Atom("unnamed", "param", "base_along", tuple(CartDir(axis=a, tcp=tuple(tcp)) for a in range(3)),
                      "direction of the last Cartesian move", "unnamed: the flange is displaced along its last Cartesian move",
                      "generic"))
    for sph in range(0 if plate_spheres is None else len(plate_spheres)):
        # a sphere that moves on the plate with the direction of gravity (loose in its seat, a flexing holder)
        atoms.append(Atom("unnamed", "plate", f"sphere{sph}", tuple(GravityDir(axis=ax) for ax in range(3)),
                          "gravity_dir_flange", f"unnamed: sphere {sph} moves on the plate with the gravity direction",
                          "generic"))
    if points is not None:
        from .field import field_applicable, field_atom_specs, field_constants

        P = np.asarray(points, dtype=float).reshape(-1, 3)
        if field_applicable(P):
            n_tool = None
            if plate_spheres is not None and len(plate_spheres) >= 3:  # one or two points span no plate normal
                S = np.asarray(plate_spheres, dtype=float)
                n = np.cross(S[1] - S[0], S[2] - S[0])
                if np.linalg.norm(n) > 0:
                    n_tool = n / np.linalg.norm(n) * (1.0 if n[2] >= 0 else -1.0)
            stations = sorted(set(np.asarray(ctx.station).astype(str).tolist())) if ctx.station is not None else None
            specs = field_atom_specs(field_constants(P), n_tool, stations)
            for ch, fs, words in specs:
                atoms.append(Atom("unnamed", "field", "meas_field", fs, ch, f"unnamed: {words}", "generic"))
            if _time_channel(ctx):
                # the instrument warming up after switch-on: its scale and range errors settle with time (here
                # the time channel is t_s, and span its range)
                for ch, fs, words in specs:
                    if ch not in ("scale vs depth", "range error vs range", "range error vs range^2"):
                        continue
                    for tau in (fr * span for fr in TAU_FRACTIONS):
                        ft = tuple(replace(f, t0=float(ctx.t_s[0]), tau=float(tau)) for f in fs)
                        if ch == "range error vs range^2":
                            # a stereo bar bending as it warms: the convergence error was already growing when
                            # the first row was measured (switched on earlier), so the field's constant part
                            # comes with it: G (c0 + c1 (1 - exp(-(t - t0) / tau)))
                            ft = fs + ft
                        atoms.append(Atom("unnamed", "field", "meas_field", ft, f"{ch}, warm-up 1-exp(-t_s/{tau:.4g})",
                                          f"unnamed: {words}, growing as the instrument warms up (1-exp(-t_s/{tau:.4g}))",
                                          "generic"))
    return atoms


def _fkey(features) -> str:
    return repr([(f.kind, getattr(f, "ch", None), getattr(f, "k", None), getattr(f, "p", None), getattr(f, "j", None),
                  getattr(f, "axis", None), getattr(f, "tau", None)) for f in features])
