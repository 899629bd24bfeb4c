"""Feature values on the rows: what every term reads from what was recorded for a row (its commanded joints and
their history, ``t_s``, ``temp_c``, the row order, the station), :func:`feature_values` for every kind of
:mod:`twin.diagnosis.features`.

The history-dependent features (approach signs, the last move, a play, the step into the row, the direction of the
last Cartesian move) run over the rows in their order from the start or a recorded restart; a lagged channel and
the motion heat continue the campaign's record (:func:`with_records`), so that a row's value does not depend on
which other rows are given. Nothing here reads truth.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..kinematics import RobotModel, link_frames
from .candidates import (GRAVITY, RowContext, approach_signs, base_moment_regressor, carried_moments,
                         gravity_torque_regressor, gravity_torques)
from .features import (BaseMoment, CartDir, Const, Cos, Exp, Feature, Field, Gated, Grav, GravityDir, GravMix, Heat,
                       HeatRecord, Hinge, Lag, LagRecord, LastMove, LoadSign, Moment, Play, Pow, Prod, Settle, Sign, Sin,
                       Station, Step, StepIn, Torque, Window)

__all__ = ["channel", "feature_channel", "history_signs", "lag_response", "motion_heat", "with_records", "HISTORY_FEATURES",
           "history_unknown", "approach_unknown", "feature_values"]


def channel(ctx: RowContext, name: str) -> np.ndarray:
    """The values ``(n,)`` of the channel ``name`` on the rows as given: a joint ``q<j>`` (1-based) [rad or m],
    ``t_s`` [s], ``temp_c`` [degC] or ``row`` (the position in the order given); a ``ValueError`` names a channel
    the rows lack or an unknown one."""
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
        return channel(ctx, "row")
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


def feature_channel(ctx: RowContext, f: Feature | None, name: str | None = None) -> np.ndarray:
    """The values of the channel ``name`` (default the feature's ``ch``) on the rows, time and row order as the
    feature ``f`` recorded them (``None``: as the rows give them)."""
    name = f.ch if name is None else name
    if name == "t_s":
        return _time(ctx, f)
    return _row_channel(ctx, f) if name == "row" else channel(ctx, name)


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


def motion_heat(ctx: RowContext, tau: float, joints: tuple[int, ...] | None = None) -> np.ndarray:
    """Heat the motors of ``joints`` (1-based; default all) put into the arm with its motion, through a first-order
    lag of time constant ``tau`` [s]: each move adds their joint travel ``sum_j |dq_j|`` [rad], which decays with
    ``tau`` over ``t_s`` (``h_k = h_{k-1} exp(-dt / tau) + travel_k``) [rad]. Needs ``t_s``."""
    joints = tuple(range(1, ctx.q.shape[1] + 1)) if joints is None else joints
    return _heat_series(channel(ctx, "t_s"), _steps_in(ctx), tau, joints)


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
    t_new, x_new = channel(ctx, "t_s"), channel(ctx, f.ch)
    order, new, at = _merge_record(rec.t_s, t_new)
    t_all = np.concatenate([np.asarray(rec.t_s, float), t_new[new]])[order]
    x_all = np.concatenate([np.asarray(rec.x, float), x_new[new]])[order]
    return _lagged(x_all, t_all, f.tau, f.gap)[at]


def _recorded_heat(f: Heat, ctx: RowContext) -> np.ndarray:
    """Motion heat on the given rows, continuing the campaign's record ``f.record`` (times, commanded joints,
    rows where its history restarted), merged by ``t_s`` as :func:`_recorded_lag` does."""
    rec = f.record
    t_new = channel(ctx, "t_s")
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


def lag_response(u: np.ndarray, tau: float, ramp: float | None = None) -> np.ndarray:
    """The response of a first-order lag of time constant ``tau`` [s], at rest at 0, to a unit step of its input at
    ``u = 0`` (``ramp`` None or 0), or to a unit ramp of its input over ``u`` in ``[0, ramp]`` [s] (then held at 1):
    ``y = u / T - (tau / T) (1 - e^{-u / tau})`` for ``0 <= u <= T``, ``y = 1 - (tau / T) (e^{-(u - T) / tau} -
    e^{-u / tau})`` after; 0 before ``u = 0``."""
    u = np.clip(np.asarray(u, float), 0.0, None)
    if not ramp:
        return -np.expm1(-u / tau)
    T = float(ramp)
    during = u / T + (tau / T) * np.expm1(-u / tau)
    after = 1.0 - (tau / T) * (np.exp(-np.clip(u - T, 0.0, None) / tau) - np.exp(-u / tau))
    return np.where(u <= T, during, after)


def _lagged(x: np.ndarray, t: np.ndarray, tau: float, gap: float | None = None) -> np.ndarray:
    """``x`` ``(n,)`` through a first-order lag of time constant ``tau`` [s] over the row times ``t`` ``(n,)`` [s], the
    channel linear between rows (a temperature recorded at the rows changes continuously between them; exact for a
    piecewise-linear channel): with ``h = t_k - t_{k-1}``, ``a = exp(-h / tau)`` and the slope ``s = (x_k - x_{k-1}) /
    h``, ``y_k = x_k - s tau + (y_{k-1} - x_{k-1} + s tau) a``; ``y_0 = x_0``. ``gap`` in [0, 1]: the channel instead
    holds ``x_{k-1}`` until ``t_{k-1} + gap h`` and steps to ``x_k`` there (a change between rows whose time the record
    does not give): ``y_k = x_k + (x_{k-1} - x_k) e^{-(1 - gap) h / tau} + (y_{k-1} - x_{k-1}) a``."""
    x = np.asarray(x, float)
    y = np.empty_like(x)
    if len(x) == 0:
        return y
    h = np.clip(np.diff(t), 0.0, None)
    a = np.exp(-h / tau)
    dx = np.diff(x)
    y[0] = x[0]
    if gap is not None:
        b = np.exp(-(1.0 - float(gap)) * h / tau)
        for k in range(1, len(x)):
            y[k] = x[k] - dx[k - 1] * b[k - 1] + (y[k - 1] - x[k - 1]) * a[k - 1]
        return y
    # s tau (1 - a) / h -> the step x_k - x_{k-1} times (1 - a) tau / h, which is 1 at h = 0 (a repeat: no time passes)
    g = np.where(h > 0, -np.expm1(-h / tau) * tau / np.where(h > 0, h, 1.0), 1.0)
    for k in range(1, len(x)):
        # y_k = a y_{k-1} + (1 - a) x_{k-1} + (1 - g) (x_k - x_{k-1})
        y[k] = a[k - 1] * y[k - 1] + (1.0 - a[k - 1]) * x[k - 1] + (1.0 - g[k - 1]) * dx[k - 1]
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
                                            x=tuple(channel(ctx, f.ch).tolist())))
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


def _grav_mix(f: GravMix, cache: dict):
    """``sum_j w_j Y[:, i, k_j, c_j]`` ``(n,)`` of a :class:`GravMix` over the gravity-torque regressor ``cache["grav"]``,
    summed in the order of its columns from 0 (as ``sum``), from the columns stacked once per joint and column set."""
    if not f.cols:
        return 0
    key = ("gravmix columns", f.i, f.cols)
    Y = cache.get(key)
    if Y is None:
        Yg = cache["grav"]
        Y = cache[key] = np.stack([Yg[:, f.i - 1, kk - 1, c] for kk, c in f.cols])  # (len(cols), n)
    terms = np.asarray(f.w, dtype=float)[:, None] * Y
    acc = terms[0] + 0.0
    for t in terms[1:]:
        acc += t
    return acc


def feature_values(features, ctx: RowContext, model: RobotModel, cache: dict | None = None) -> np.ndarray:
    """Values ``(n, K)`` of ``features`` (:mod:`twin.diagnosis.features`) on the rows of ``ctx`` (``model``: the
    nominal robot, for gravity)."""
    cache = {} if cache is None else cache
    n = len(ctx.q)
    out = np.empty((n, len(features)))
    for k, f in enumerate(features):
        if isinstance(f, Pow):
            out[:, k] = ((feature_channel(ctx, f) - f.c) / f.h) ** f.p
        elif isinstance(f, (Sin, Cos)):
            x = f.k * feature_channel(ctx, f)
            out[:, k] = np.sin(x) if isinstance(f, Sin) else np.cos(x)
        elif isinstance(f, Prod):
            a, b = f.ch
            out[:, k] = (channel(ctx, a) - f.c[0]) / f.h[0] * (channel(ctx, b) - f.c[1]) / f.h[1]
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
            x = cache["moves"][:, f.j - 1] / f.w
            if f.law is None:
                out[:, k] = np.tanh(x)
            elif f.law == "clip":
                out[:, k] = np.clip(x, -1.0, 1.0)
            elif f.law == "exp":
                out[:, k] = np.sign(x) * -np.expm1(-np.abs(x))
            else:
                raise ValueError(f"unknown law {f.law!r} of a lastmove feature (known: tanh when absent, 'clip', "
                                 "'exp')")
        elif isinstance(f, GravMix):
            if "grav" not in cache:
                cache["grav"] = gravity_torque_regressor(model, ctx.q)
            out[:, k] = _grav_mix(f, cache) / f.h
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
            # the links' unknown mass moments (:func:`twin.diagnosis.candidates.base_moment_regressor`)
            if "basemoment" not in cache:
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
            out[:, k] = (feature_channel(ctx, f) >= f.at).astype(float)
        elif isinstance(f, Window):
            # a change and back: the state differs from ``at`` until ``until`` (a step and its return)
            x = feature_channel(ctx, f)
            out[:, k] = ((x >= f.at) & (x < f.until)).astype(float)
        elif isinstance(f, LoadSign):
            # the side of the gear flank the joint's gravity load pushes it to: the sign of the load (the URDF
            # masses' torque, or a combination of the gravity-torque shapes when the masses are unknown), or a
            # smooth flank taken up over a width of the load
            v = feature_values((f.f,), ctx, model, cache)[:, 0]
            if f.width is None:
                out[:, k] = np.sign(v)
            elif f.law is None:
                out[:, k] = np.tanh(v / f.width)
            elif f.law == "clip":
                out[:, k] = np.clip(v / f.width, -1.0, 1.0)
            else:
                raise ValueError(f"unknown law {f.law!r} of a loadsign feature (known: tanh when absent, 'clip')")
        elif isinstance(f, Hinge):
            # zero on one side of an angle, growing as a power of the overtravel past it (a cable going taut)
            out[:, k] = (np.clip(f.side * (channel(ctx, f.ch) - f.at), 0.0, None) / f.h) ** f.p
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
                    cache[key] = _recorded_heat(f, ctx) if f.record is not None else motion_heat(ctx, f.tau, joints)
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
            x = feature_channel(ctx, f)
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
            # a transient settling with time constant tau from t0 (a warm-up; a step or a ramp of the air's
            # temperature through the links' lag): zero before t0 (rows of an earlier session)
            ramp, scale = f.ramp, 1.0
            if ramp and f.t_span is not None and f.t0 + ramp > f.t_span[1]:
                # a ramp the campaign did not see end: the air holds the state it reached at the campaign's last
                # row, and the links go on following it through the lag
                seen = max(f.t_span[1] - f.t0, 0.0)
                ramp, scale = seen, seen / ramp
            out[:, k] = scale * lag_response(feature_channel(ctx, f) - f.t0, f.tau, ramp) if ramp or not f.ramp else 0.0
        elif isinstance(f, Lag):
            # the channel seen through a first-order lag of time constant tau (a link's temperature follows
            # the air's): exact for a channel constant between rows, started at the first row's value
            if f.record is not None and ctx.t_s is None:
                lag = channel(ctx, f.ch)  # a new session whose time is not recorded: the channel settled
            else:
                lag = _recorded_lag(f, ctx) if f.record is not None else \
                    _lagged(channel(ctx, f.ch), channel(ctx, "t_s"), f.tau, f.gap)
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
    if not np.isfinite(out).all():
        bad = np.unique(np.nonzero(~np.isfinite(out))[0])[:10]
        raise ValueError(f"effect features are not finite in rows {bad.tolist()} (check t_s / temp_c)")
    return out
