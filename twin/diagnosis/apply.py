"""Using an extended calibration (``calibration.json`` with ``effects``): prediction and compensation.

Each stored effect is an atom (:mod:`twin.diagnosis.atoms`) with its features' constants and its values
``phi``; it is evaluated from the rows of the input in their order (history: approach directions, with the
first row's approach unknown unless ``q_start`` is given) and their channels (``temp_c``, ``t_s``,
``station``). Joint atoms change the commanded joints exactly; length, parameter and scale atoms act to
first order through the parameter Jacobian of the predicted points (as in the fit); plate atoms move the
sphere centres in the plate frame. A row's prediction does not depend on which other rows are given, except for
the terms that need the order of the moves (:func:`history_unknown_rows` says which rows lacked it): a lagged
temperature and the motion heat continue the campaign's record by ``t_s``, a term in the row order numbers the
campaign's rows by their pose ids.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..dataset import temperature_gaps
from ..estimator.calibration import Calibration, Prediction
from ..estimator.compensation import CompensationResult, compensation
from ..estimator.problem import ParamSpace, predict_points
from ..estimator.register import prediction_errors, register, select_rows, session_residuals
from ..transforms import kabsch, matrix_to_rotvec
from ..units import M_PER_MM
from .atoms import Atom, tilt_axis, tilt_coefficient
from .values import HISTORY_FEATURES, feature_channel, feature_values, history_unknown
from .candidates import RowContext
from .features import Exp, Gated, Heat, Lag, Pow, Station, Step, Window
from .extend import param_weights
from .field import field_values, station_mask
from .floor import row_context

__all__ = ["effect_atoms", "required_channels", "effective_joints", "predict_extended", "compensate_extended",
           "history_unknown_rows", "STATE_BLOCKS", "term_state", "prediction_states", "row_states", "dataset_predictor", "block_errors", "new_session_errors", "SessionChoice",
           "choose_for_session", "prune_for_session", "SESSION_FOLDS", "SESSION_Z_MIN"]


def effect_atoms(cal: Calibration) -> list[tuple[Atom, np.ndarray]]:
    """The calibration's effects as ``(atom, phi)``; ``ValueError`` naming the entry when one is malformed."""
    out = []
    for k, e in enumerate(cal.effects):
        if not isinstance(e, dict):
            raise ValueError(f"calibration effects[{k}] is not a table: {e!r}")
        try:
            a = Atom.from_spec(e)
        except ValueError as exc:
            raise ValueError(f"calibration effects[{k}]: {exc} (written by an older twin diagnose? re-run it)") from None
        phi = np.asarray(e.get("values", []), dtype=float)
        if phi.shape != (a.K,) or not np.all(np.isfinite(phi)):
            raise ValueError(f"calibration effects[{k}] ({e.get('label', a.target)}): values must be {a.K} finite "
                             f"numbers, got {e.get('values')!r}")
        out.append((a, phi))
    return out


def required_channels(cal: Calibration) -> set[str]:
    """Row channels the effects read (``t_s``, ``temp_c``, ``station``): rows lacking one get an error. A term of
    time that recorded its campaign's span (or record) does not need ``t_s``: rows without it are a new session
    and read the state the campaign ended in."""
    need = set()
    for a, _ in effect_atoms(cal):
        for f in a.features:
            ch = getattr(f, "ch", None)
            for c in ch if isinstance(ch, tuple) else [ch]:
                if c == "temp_c" or (c == "t_s" and getattr(f, "t_span", None) is None
                                     and getattr(f, "record", None) is None):
                    need.add(c)
            if isinstance(f, Station):
                need.add("station")
    return need


def _check_ctx(cal: Calibration, ctx: RowContext) -> None:
    for c in sorted(required_channels(cal)):
        if getattr(ctx, c) is None:
            raise ValueError(f"the calibration's effects depend on '{c}': the rows need a '{c}' column")
    gaps = temperature_gaps(ctx.temp_c, ctx.pose_id if ctx.pose_id is not None else np.arange(len(ctx.q)))
    if "temp_c" in required_channels(cal) and gaps:
        raise ValueError(f"the calibration's effects depend on 'temp_c': {gaps}; give those rows their temperature, "
                         "or leave them out")


def effective_joints(cal: Calibration, ctx: RowContext) -> np.ndarray:
    """Joints ``(n, N)`` [rad; m for a prismatic joint] the robot is predicted to reach for the commanded ``ctx.q``
    (joint atoms)."""
    _check_ctx(cal, ctx)
    q = ctx.q.copy()
    cache: dict = {}
    for a, phi in effect_atoms(cal):
        if a.place == "joint":
            q[:, int(a.target[5:]) - 1] += feature_values(a.features, ctx, cal.nominal, cache) @ phi
    return q


def history_unknown_rows(cal: Calibration, ctx: RowContext) -> np.ndarray:
    """Rows ``(n,)`` whose prediction lacks the history one of the calibration's terms needs (an approach
    direction, the last move: the joint has not moved since the first row given or a restart), so that term
    reads its unknown state there (0). Terms of time or temperature never do: they read the rows' own ``t_s`` and
    ``temp_c``, a lag or the motion heat continuing the campaign's record."""
    return history_unknown([a.features for a, _ in effect_atoms(cal)], ctx)


STATE_BLOCKS = ("report_rows", "rows_after_the_campaign", "new_session")
# [m] (an orientation weighted by its m/rad) the extended model's miss at which the commands' fixed point has settled,
# whatever its last step: a step along a direction a position-first least squares weighs little may stay near 1e-7
# rad, the floor of its numbers, while the targets are met to far below any instrument
SETTLED_MISS = 1e-12


def _stateful(f):
    """The feature of ``f`` that carries a state (a gated feature's gate), and its kind of state."""
    if isinstance(f, (Step, Window)) or (isinstance(f, Gated)):
        return "change"
    if isinstance(f, Lag):
        return "lag"
    if isinstance(f, Heat):
        return "heat"
    if isinstance(f, Exp):
        return "air"
    if isinstance(f, Pow) and f.ch == "t_s":
        return "drift"
    if isinstance(f, Pow) and f.ch == "row":
        return "rows"
    if f.kind in HISTORY_FEATURES:
        return "history"
    return None


def term_state(atom: Atom, block: str) -> str | None:
    """In words, the state the term ``atom`` reads when it predicts the rows of ``block`` (one of ``STATE_BLOCKS``:
    the diagnosis' report rows, the rows measured after the campaign with their ``t_s``, a new session whose ``t_s``
    is not recorded or another session); None for a term that has none (a function of the row's own joints)."""
    if block not in STATE_BLOCKS:
        raise ValueError(f"block must be one of {STATE_BLOCKS}, got {block!r}")
    stateful = [(k, f) for k, f in ((_stateful(f), f) for f in atom.features) if k is not None]
    if not stateful:
        return None
    kind, f0 = stateful[0]
    if kind == "change":
        until = getattr(f0, "until", None)
        if until is None:
            return {"report_rows": f"the state after the change for the rows at or after {f0.ch} {f0.at:.6g}, the state "
                                   "before it for earlier rows",
                    "rows_after_the_campaign": "the state after the change (the last state the campaign held)",
                    "new_session": "the state after the change"}[block]
        return {"report_rows": f"the changed state inside {f0.ch} {f0.at:.6g} to {until:.6g}, the state before it "
                               "elsewhere",
                "rows_after_the_campaign": "the state before the change (it ended within the campaign)",
                "new_session": "the state before the change (it ended within the campaign)"}[block]
    if kind == "lag":
        return {"report_rows": f"the recorded {f0.ch} through the lag of {f0.tau:.4g} s over the campaign's record to "
                               "each row",
                "rows_after_the_campaign": f"the lag of {f0.tau:.4g} s carried from the campaign's last row, driven by "
                                           f"the rows' own {f0.ch} (merged with the campaign's record by t_s)",
                "new_session": f"the row's own {f0.ch}, settled (rows without t_s: the lag has run its course)"}[block]
    if kind == "heat":
        return {"report_rows": "the motors' heat over the campaign's moves to each row",
                "rows_after_the_campaign": "the motors' heat carried from the campaign's last row, leaking over the "
                                           "time since and fed by the rows' own moves (merged by t_s)",
                "new_session": "the heat the campaign ended with (rows without t_s)"}[block]
    if kind == "air":
        ramp = f" over {f0.ramp:.4g} s" if f0.ramp else ""
        return {"report_rows": f"the air's change from t_s {f0.t0:.6g}{ramp} through the lag of {f0.tau:.4g} s at the "
                               "row's t_s",
                "rows_after_the_campaign": f"the air's change through the lag of {f0.tau:.4g} s at the row's t_s, going "
                                           "on from the campaign's end (a ramp not seen to end: the air held at the "
                                           "state the campaign's last row reached)",
                "new_session": "the state the campaign ended in (rows without t_s)"}[block]
    if kind == "drift":
        return {"report_rows": "the drift at the row's t_s",
                "rows_after_the_campaign": "the drift at the row's t_s within as long again as the campaign lasted, "
                                           "the state the campaign ended in beyond",
                "new_session": "the state the campaign ended in"}[block]
    if kind == "rows":
        return {"report_rows": "the row's place in the campaign",
                "rows_after_the_campaign": "the row count continued after the campaign's last row",
                "new_session": "the row count continued after the campaign's last row"}[block]
    return {"report_rows": "the approach history from the campaign's rows before each row",
            "rows_after_the_campaign": "the approach history from the rows before in the same file (unknown, read as "
                                       "0, until each joint moves)",
            "new_session": "a new history (unknown, read as 0, until each joint moves)"}[block]


def prediction_states(cal: Calibration, block: str) -> list[dict]:
    """``[{label, state}]``: every term of ``cal`` that carries a state and the state it reads for ``block``
    (:func:`term_state`)."""
    out = []
    for a, _ in effect_atoms(cal):
        st = term_state(a, block)
        if st is not None:
            out.append({"label": a.label, "state": st})
    return out


def row_states(cal: Calibration, ctx: RowContext) -> list[str]:
    """For the rows of ``ctx`` (a ``twin predict`` file), one line per term of ``cal`` that carries a state: which state
    its rows read (before or after a change, the campaign's record continued or the state it ended in, the history
    from the rows before)."""
    out = []
    t = ctx.t_s
    for a, _ in effect_atoms(cal):
        stateful = [(k, f) for k, f in ((_stateful(f), f) for f in a.features) if k is not None]
        if not stateful:
            continue
        kinds, f0 = [stateful[0][0]], stateful[0][1]
        if kinds[0] == "change":
            x = feature_channel(ctx, f0, f0.ch) if (f0.ch != "t_s" or t is not None) else None
            until = getattr(f0, "until", None)
            if x is None:
                words = ("the state after it (rows without t_s)" if until is None else
                         "the state before it (rows without t_s; it ended within the campaign)")
            elif until is None:
                words = f"{int(np.sum(x >= f0.at))} row(s) after it (its state), {int(np.sum(x < f0.at))} before"
            else:
                inside = (x >= f0.at) & (x < until)
                words = f"{int(inside.sum())} row(s) inside it, {int((~inside).sum())} outside (the state before it)"
        elif kinds[0] in ("lag", "heat", "air", "drift"):
            words = ("the state the campaign ended in (rows without t_s)" if t is None else
                     "the campaign's record continued to the rows' t_s" if kinds[0] in ("lag", "heat") else
                     "its value at the rows' t_s")
        elif kinds[0] == "rows":
            words = "the rows' place in the campaign (others continue its row count)"
        else:
            lack = int(np.sum(history_unknown([a.features], ctx)))
            words = f"the approach history from the rows before in this file ({lack} row(s) unknown: read as 0)"
        out.append(f"{a.label}: {words}")
    return out


def _plate(cal: Calibration) -> Calibration:
    off = np.zeros_like(np.asarray(cal.spheres_tool, dtype=float))
    for a, phi in effect_atoms(cal):
        if a.place == "plate" and not a.varying_plate:
            off[int(a.target[6:])] += phi
    return cal if not off.any() else replace(cal, spheres_tool=cal.spheres_tool + off)


def _first_order(cal: Calibration, ctx: RowContext, space: ParamSpace, rows_station: np.ndarray,
                 q_eff: np.ndarray, spheres_tool: np.ndarray, known: np.ndarray, x: np.ndarray | None = None
                 ) -> np.ndarray:
    """Change ``(n, K, 3)`` [m] of the predicted points from length, parameter and scale atoms, in the frame of
    ``space`` at the parameters ``x`` (default the calibration's own: its stations' measurement frames)."""
    n = len(q_eff)
    d = np.zeros((n, len(spheres_tool), 3))
    fo = [(a, phi) for a, phi in effect_atoms(cal) if a.first_order]
    if not fo:
        return d
    cache: dict = {}
    x = cal.x if x is None else x
    pts, Jk = predict_points(space, x, q_eff, rows_station, spheres_tool, jacobian=True)  # Jk (P, 3, 3, n)
    plate_axes: list[np.ndarray] = []

    def plate2meas() -> np.ndarray:
        """``(n, 3, 3)``: each row's plate axes in the measurement frame (columns), computed once."""
        if not plate_axes:
            axes, _ = predict_points(space, x, q_eff, rows_station, np.concatenate([np.zeros((1, 3)), np.eye(3)]))
            plate_axes.append(np.swapaxes(axes[:, 1:] - axes[:, :1], 1, 2))
        return plate_axes[0]

    for a, phi in fo:
        F = feature_values(a.features, ctx, cal.nominal, cache)  # (n, K_f)
        if a.place == "scale":
            d += (F @ phi)[:, None, None] * pts
            continue
        if a.place == "plate":
            # the sphere's offset in the plate frame, turned into the measurement frame by each row's plate
            off = F @ phi.reshape(len(a.features), 3)  # (n, 3) in the plate frame
            d[:, int(a.target[6:])] += np.einsum("ncj,nj->nc", plate2meas(), off)
            continue
        if a.place == "field":
            n_tool = next((f.n_tool for f in a.features if getattr(f, "n_tool", None) is not None), None)
            nrm = None
            if n_tool is not None:
                # the plate normal of each predicted row (the view fields follow the plate's tilt)
                nrm = np.repeat(plate2meas() @ np.asarray(n_tool, dtype=float), pts.shape[1], axis=0)
            G = field_values(a.features, pts.reshape(-1, 3), nrm).reshape(*pts.shape[:2], len(a.features), 3)
            G = G * (station_mask(a.features, np.asarray(space.stations)[rows_station]) * F)[:, None, :, None]
            d += np.einsum("nskc,k->nsc", G, phi)
            continue
        W = param_weights(space, x, a)  # (P, c)
        c = W.shape[1]
        if a.target == "base_along":
            dx = F * phi[0]  # (n, 3): the displacement along the row's direction
        elif a.target.startswith("tilt"):
            # (n, 2): each feature turns the pivot about its axis (one rotation axis per feature)
            dx = np.zeros((n, 2))
            for k, f in enumerate(a.features):
                dx[:, tilt_axis(f, k)] += F[:, k] * phi[tilt_coefficient(f, k)]
        else:
            dx = np.einsum("nf,fc->nc", F, phi.reshape(len(a.features), c))  # (n, c) per-row change along W
        d += np.einsum("pscn,pk,nk->nsc", Jk, W, dx)
    if not np.all(known):
        # rows in the robot base frame (unknown station): measurement-side atoms do not apply
        base_only = [a.place in ("scale", "field") or (a.place == "param" and a.target == "base") for a, _ in fo]
        if any(base_only):
            raise ValueError("the calibration's effects act on the measurement frame: rows need a known station")
    return d


def predict_extended(cal: Calibration, ctx: RowContext, station: np.ndarray | None = None) -> Prediction:
    """Like :meth:`Calibration.predict`, with the calibration's effects applied to the rows of ``ctx``."""
    _check_ctx(cal, ctx)
    q_eff = effective_joints(cal, ctx)
    c = _plate(cal)
    pred = c.predict(q_eff, station)
    if not any(a.first_order for a, _ in effect_atoms(cal)):
        return pred
    known = pred.frame == "measurement"
    sp = cal.space
    st_idx = np.array([sp.stations.index(s) if s in sp.stations else 0 for s in pred.station])
    d = _first_order(c, ctx, sp, st_idx, q_eff, c.spheres_tool, known)
    spheres = pred.spheres + d
    # the plate pose follows the moved spheres (rigid fit of the plate to them)
    A = np.broadcast_to(c.spheres_tool, spheres.shape)
    R, t = kabsch(A, spheres)
    pose = pred.pose.copy()
    pose[:, :3, :3] = R
    pose[:, :3, 3] = t
    return replace(pred, spheres=spheres, pose=pose)


def compensate_extended(
    cal: Calibration,
    targets_tool2base: np.ndarray,
    q_ref: np.ndarray,
    ctx: RowContext,
    *,
    max_rounds: int = 30,
    tol: float = 1e-10,
    weight_rotation: float = 1.0,
) -> CompensationResult:
    """Commands that put the plate at the targets on the identified robot *with* its effects.

    1. The geometric answer ``q_geo`` (iterative inverse kinematics on the identified model).
    2. Fixed point on the commands: ``q_cmd <- q_cmd + J_q^+ e`` with ``e`` the pose error of the extended
       model at ``q_cmd`` (joint atoms evaluated at the commands themselves, so backlash follows the order
       and directions of the commands; robot-side length and parameter atoms to first order), until the
       commands move by less than ``tol`` [rad] or the extended model at them misses the targets by at most
       ``SETTLED_MISS`` (the orientation weighted by ``weight_rotation``). Measurement-side atoms (base frame,
       scale) do not change where the robot goes and are ignored here.
    ``ctx`` gives the rows' channels (``temp_c``, ``t_s``) and ``q_start``; its ``q`` is ignored.
    ``weight_rotation`` [m/rad] weighs the orientation against the position in the least squares of a step (a
    position target of a chain of fewer than six joints: small, the position first).
    """
    T = np.asarray(targets_tool2base, dtype=float)
    if T.ndim == 2:
        T = T[None]
    n = T.shape[0]
    cp = _plate(cal)
    base = compensation(cp, T, q_ref)
    atoms = [(a, phi) for a, phi in effect_atoms(cal)
             if not (a.place in ("scale", "field", "plate") or (a.place == "param" and a.target == "base"))]
    if not atoms:
        return base
    sp = ParamSpace(cp.space.chain, ("base",))
    x = np.concatenate([cp.x[: cp.space.n_rt], np.zeros(6)])
    origin = np.zeros((1, 3))
    pts_tool = np.concatenate([origin, np.eye(3)])
    theta = sp.family("joint")
    signs = sp.chain.structure.joint_signs  # d(point) / d(joint) = sign * d(point) / d(its parameter)
    N = len(theta)
    sub = replace(cp, effects=tuple(e for e in cal.effects if Atom.from_spec(e).place in ("joint", "length", "param")
                                    and Atom.from_spec(e).target != "base"))
    q_cmd = base.q.copy()
    step = np.inf
    for _ in range(max_rounds):
        # the commands are the rows: their own order is the history (the caller's rows are not)
        c2 = RowContext(q=q_cmd, q_start=ctx.q_start, temp_c=ctx.temp_c, t_s=ctx.t_s, station=None, history_reset=None)
        q_eff = effective_joints(sub, c2)
        P, Jk = predict_points(sp, x, q_eff, np.zeros(n, int), pts_tool, jacobian=True)
        # in the robot base frame: the space's one station at zero
        d = _first_order(sub, c2, sp, np.zeros(n, int), q_eff, pts_tool, np.ones(n, bool), x=x)
        P = P + d
        o = P[:, 0]
        R = np.swapaxes(P[:, 1:] - o[:, None, :], 1, 2)
        U, _, Vt = np.linalg.svd(R)
        R = U @ Vt
        e_p = T[:, :3, 3] - o
        e_r = matrix_to_rotvec(T[:, :3, :3] @ np.swapaxes(R, 1, 2))
        if (np.linalg.norm(e_p, axis=1).max(initial=0.0) <= SETTLED_MISS
                and weight_rotation * np.linalg.norm(e_r, axis=1).max(initial=0.0) <= SETTLED_MISS):
            step = 0.0  # the extended model at these commands, their own directions included, lands on the targets
            break
        # joint Jacobian of the tool origin and orientation: the theta columns of the parameter Jacobian
        Jq = Jk[theta] * signs[:, None, None, None]
        Jp = Jq[:, 0]  # (N, 3, n)
        Jax = Jq[:, 1:] - Jq[:, :1]  # (N, 3 axes, 3, n)
        dq = np.empty((n, N))
        for i in range(n):
            Jfull = np.concatenate([Jp[:, :, i].T, _angular(Jax[:, :, :, i], R[i])], axis=0)  # (6, N)
            Jfull[3:] *= weight_rotation
            dq[i] = np.linalg.lstsq(Jfull, np.concatenate([e_p[i], weight_rotation * e_r[i]]), rcond=None)[0]
        q_cmd = q_cmd + dq
        step = float(np.max(np.abs(dq)))
        if step < tol:
            break
    else:
        rows, joints = np.nonzero(np.abs(dq) >= tol)
        where = ", ".join(f"row {r} joint {j + 1}" for r, j in list(zip(rows.tolist(), joints.tolist()))[:5])
        raise ValueError(f"compensation with effects did not settle in {max_rounds} rounds (last step {step:.3g} rad; "
                         f"still moving: {where}; rows count from 0): a term of the history (backlash) reads the "
                         "direction each command moves from the previous one, and where two consecutive commands of a "
                         "joint are closer than its correction, the correction turns that direction over")
    # the extended model's miss at the commands of the last round (its step is below tol)
    return replace(base, q=q_cmd, position_error=np.linalg.norm(e_p, axis=1), rotation_error=np.linalg.norm(e_r, axis=1))


def _angular(Jax: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Angular velocity Jacobian ``(3, N)`` from the derivatives ``(N, 3 axes, 3)`` of the tool axes
    ``R e_k``: ``d(R e_k) = w x R e_k``, so ``w = 1/2 sum_k (R e_k) x d(R e_k)``."""
    w = np.zeros((3, Jax.shape[0]))
    for k in range(3):
        w += 0.5 * np.cross(R[:, k][None, :], Jax[:, k, :]).T
    return w



def dataset_predictor(dataset):
    """A prediction function ``predict(calibration, idx) -> Prediction`` of the rows ``idx`` of ``dataset`` (a
    :class:`~twin.dataset.Dataset`) with the calibration's effects evaluated from all its rows in measurement order
    (approach directions unknown at the first row and where the ``session`` column changes: a new session starts
    anew), for :func:`twin.estimator.register.register` and :func:`~twin.estimator.register.prediction_errors`.
    The rows are evaluated up to the last one asked for: a term reads a row and the rows before it, so the rows
    after it change nothing (and a few rows at the start of a long file cost a few rows)."""
    ctx = row_context(dataset)
    station = dataset.station_ids
    prefixes: dict[int, RowContext] = {}

    def upto(m: int) -> RowContext:
        # the first m rows as the whole file gives them: a term reads the row itself and the rows before it (the
        # approach history, a lagged record), never a later row
        if m >= dataset.n:
            return ctx
        if m not in prefixes:
            prefixes[m] = replace(ctx, **{f: None if getattr(ctx, f) is None else getattr(ctx, f)[:m]
                                          for f in _PER_ROW})
        return prefixes[m]

    def predict(c: Calibration, idx: np.ndarray) -> Prediction:
        idx = np.asarray(idx, dtype=int)
        m = int(idx.max()) + 1 if idx.size else 0
        p = predict_extended(c, upto(m), station[:m])
        return replace(p, spheres=p.spheres[idx], pose=p.pose[idx], frame=p.frame[idx], station=p.station[idx],
                       sd_spheres=None if p.sd_spheres is None else p.sd_spheres[idx],
                       sd_pose=None if p.sd_pose is None else p.sd_pose[idx])

    return predict


_PER_ROW = ("q", "temp_c", "t_s", "station", "history_reset", "session_start", "pose_id")  # RowContext's (n,) fields


def block_errors(geometric: Calibration, extended: Calibration, dataset, blocks: dict) -> dict:
    """The errors of a geometric and an extended calibration on named blocks of ``dataset``'s rows (``blocks``:
    name -> row indices ``(k,)`` or a boolean mask ``(n,)``; empty blocks are left out): per block ``{n_rows,
    geometric, extended, rms_ratio}``, each as :func:`twin.estimator.register.prediction_errors` gives it (3-D
    error per point [mm], and [deg] for poses), the extended model's effects evaluated from all the dataset's rows
    in measurement order (:func:`dataset_predictor`)."""
    predict = dataset_predictor(dataset)
    out = {}
    for name, rows in blocks.items():
        rows = np.asarray(rows)
        idx = np.flatnonzero(rows) if rows.dtype == bool else rows.astype(int)
        if idx.size == 0:
            continue
        g = prediction_errors(geometric, dataset, idx)
        e = prediction_errors(extended, dataset, idx, predict=predict if extended.effects else None)
        out[name] = {"n_rows": int(idx.size), "geometric": g, "extended": e,
                     "rms_ratio": e["position_mm"]["rms"] / g["position_mm"]["rms"]}
    return out


def new_session_errors(geometric: Calibration, extended: Calibration, dataset, *, first: int = 50,
                       tool: bool = False) -> dict:
    """A calibrated robot in a new session (``dataset``: its rows, another day or a moved instrument): each model
    keeps its robot and re-identifies the measurement frame (and the tool with ``tool``) from the session's
    ``first`` rows (:func:`twin.estimator.register.register`), then predicts the others. Returns ``{registered_on,
    tool, rows: {n_rows, geometric, extended, rms_ratio}, chosen, cv_position_rms_mm, dropped, prune_z,
    session_model}``:
    the errors on the other rows (:func:`block_errors`), the model :func:`choose_for_session` takes for the session
    from its ``first`` rows (the one ``twin register`` writes), the terms it dropped, and that model's errors on the
    other rows (``session_model``: ``{name, n_rows, geometric, extended, rms_ratio}``, its errors as ``extended``)."""
    rows = select_rows(dataset, first=first)
    choice = choose_for_session({"geometric": geometric, "extended": extended}, dataset, rows, tool=tool)
    geo, ext = choice.registered["geometric"], choice.registered["extended"]
    others = np.setdiff1d(select_rows(dataset, first=dataset.n), rows)
    e = block_errors(geo, ext, dataset, {"other rows": others})["other rows"]
    chosen = choice.registered[choice.chosen]
    e_chosen = prediction_errors(chosen, dataset, others, predict=dataset_predictor(dataset) if chosen.effects else None)
    return {"registered_on": int(rows.size), "tool": bool(tool), "rows": e,
            "chosen": choice.chosen, "cv_position_rms_mm": choice.cv_position_rms_mm, "dropped": list(choice.dropped),
            "prune_z": choice.prune_z,
            "session_model": {"name": choice.chosen, "n_rows": e["n_rows"], "geometric": e["geometric"],
                              "extended": e_chosen,
                              "rms_ratio": e_chosen["position_mm"]["rms"] / e["geometric"]["position_mm"]["rms"]}}


_FD_STEP = 1e-6  # [m] and [rad]: central-difference step of the residuals in the registered frames
SESSION_Z_MIN = 3.0  # a pruned model replaces the whole one at this z over the rows (diagnose's z_min)
SESSION_FOLDS = 5  # contiguous blocks of the registration rows in time, each predicted by the others' registration


@dataclass(frozen=True, eq=False)
class SessionChoice:
    """Result of :func:`choose_for_session`.

    ``chosen``: the name of the model to use in the session; ``registered``: each model registered on all the rows
    (name -> :class:`~twin.estimator.Calibration`); ``cv_position_rms_mm``: name -> the RMS of the position error
    [mm] of every row predicted by the model registered on the other folds (per marker point, or per pose);
    ``folds``: row indices ``(k_f,)`` of each fold; ``note``: the choice in words; ``dropped``: the labels of the
    terms the session's rows dropped from the extended model (``prune``), in the order they were dropped;
    ``trace``: ``(label dropped, linearised score [mm])`` per step of that backward pass, the first entry
    ``(None, score of the whole model)``; ``candidates``: every model judged, as given (not registered), the
    pruned one included; ``prune_z``: the pruned model's z against the whole one (:func:`prune_for_session`), None
    without a backward pass.
    """

    chosen: str
    registered: dict
    cv_position_rms_mm: dict
    folds: tuple
    note: str
    dropped: tuple = ()
    trace: tuple = ()
    candidates: dict | None = None
    prune_z: float | None = None


def choose_for_session(models: dict, dataset, rows, *, tool: bool = False, folds: int = SESSION_FOLDS,
                       prune: bool = True) -> SessionChoice:
    """Which of ``models`` (name -> calibration, the fallback first: a geometric model, then the extended model that
    extends it) to use in a new session, judged on the session's own registration rows ``rows`` (indices ``(k,)``
    in measurement order), which none of the models was fitted on.

    Each model's frames are registered (:func:`twin.estimator.register.register`, ``tool`` as there) on the rows
    less one fold and predict that fold; ``folds`` contiguous blocks of ``rows`` in measurement order, so that every
    row is predicted once by a registration that did not see it. The score is the RMS of the position error over
    all predicted rows (3-D per marker point, or per pose): ``sqrt(sum_f n_f rms_f^2 / sum_f n_f)``. A model
    replaces the first only where its score is lower; on a tie the first is kept. Every model is then registered
    on all of ``rows`` (``registered``). ``prune``: a model with terms (``effects``) is also tried without the terms
    this session does not bear out (:func:`prune_for_session`: a backward pass over its terms on the same blocks;
    the others keep their values), as the candidate ``"<name> (pruned)"`` after it, when a term is dropped.
    ``ValueError`` naming the argument when ``models`` is empty or holds
    something else than calibrations, when ``folds`` < 2 or exceeds the rows, or when a fold's registration is
    refused (too few rows: the message names the fold)."""
    if not isinstance(models, dict) or not models or not all(isinstance(c, Calibration) for c in models.values()):
        raise ValueError(f"models must be a non-empty dict of name -> twin.estimator.Calibration, got {models!r:.120}")
    idx = _fold_rows(rows, folds)
    predict = dataset_predictor(dataset)
    parts = tuple(np.array_split(idx, folds))
    dropped, trace, prune_z = (), (), None
    if prune:
        grown = {}
        for name, cal in models.items():
            grown[name] = cal
            if cal.effects and not dropped:
                pruned, dropped, trace, prune_z = prune_for_session(cal, dataset, idx, tool=tool, folds=folds)
                if dropped:
                    grown[f"{name} (pruned)"] = pruned
        models = grown
    scores, registered = {}, {}
    for name, cal in models.items():
        pred = predict if cal.effects else None
        num = den = 0.0
        for f, test in enumerate(parts):
            train = np.setdiff1d(idx, test)
            try:
                fitted = register(cal, dataset, train, tool=tool, predict=pred).calibration
            except ValueError as exc:
                raise ValueError(f"rows: fold {f + 1} of {folds} (registered on {train.size} rows): {exc}") from None
            e = prediction_errors(fitted, dataset, test, predict=pred)
            n = e.get("n_spheres", e["n_rows"])
            num += n * e["position_mm"]["rms"] ** 2
            den += n
        scores[name] = float(np.sqrt(num / den))
        registered[name] = register(cal, dataset, idx, tool=tool, predict=pred).calibration
    names = list(models)
    chosen = names[0]
    for name in names[1:]:
        if scores[name] < scores[chosen]:
            chosen = name
    listed = ", ".join(f"{k} {v:.4g} mm" for k, v in scores.items())
    note = (f"the {chosen} model is used in this session: each model registered on {folds - 1} of {folds} blocks of the "
            f"{idx.size} registration rows predicted the other block at (RMS) {listed}; a model replaces the "
            f"{names[0]} one only where it predicts these rows better")
    if dropped:
        note += (f"; the pruned model is the extended one without {len(dropped)} term(s) (z = {prune_z:.2f} against "
                 "the whole one): " + "; ".join(dropped))
    elif prune_z:
        note += (f"; dropping terms did not predict these rows significantly better (z = {prune_z:.2f} < "
                 f"{SESSION_Z_MIN:g}): every term kept")
    return SessionChoice(chosen=chosen, registered=registered, cv_position_rms_mm=scores, folds=parts, note=note,
                         dropped=dropped, trace=trace, candidates=dict(models), prune_z=prune_z)


def _fold_rows(rows, folds) -> np.ndarray:
    """``rows`` (indices or a bool mask) as indices ``(k,)``, checked to make ``folds`` blocks."""
    if not (isinstance(folds, (int, np.integer)) and not isinstance(folds, bool) and folds >= 2):
        raise ValueError(f"folds must be an integer >= 2, got {folds!r}")
    idx = np.asarray(rows)
    idx = np.flatnonzero(idx) if idx.dtype == bool else idx.astype(int)
    if idx.size < folds:
        raise ValueError(f"rows: {idx.size} row(s) cannot make {folds} folds; give more rows or fewer folds")
    return idx


def prune_for_session(calibration: Calibration, dataset, rows, *, tool: bool = False, folds: int = SESSION_FOLDS,
                      z_min: float = SESSION_Z_MIN) -> tuple[Calibration, tuple, tuple, float]:
    """The extended ``calibration`` without the terms a new session's registration rows ``rows`` (indices ``(k,)``,
    measurement order) do not bear out: a backward pass over its terms scored by blocked cross-validation of the
    registration, linearised.

    The model with every term is registered on all ``rows`` (:func:`twin.estimator.register.register`): frames
    ``theta_0``, whitened residuals ``r_0`` (:func:`twin.estimator.register.session_residuals`) and their Jacobian
    ``J`` in the registered frames (central differences, step 1e-6 m / rad). Dropping term ``t`` (its values set
    aside, the other terms and the robot kept) changes the residuals by ``d_t = r_{-t}(theta_0) - r_0``; a set
    ``D`` of dropped terms gives ``r_D = r_0 + sum_{t in D} d_t`` (first order in the frames, exact for one term).
    Its score: each of the ``folds`` contiguous blocks of ``rows`` in turn, ``delta = argmin |J_o delta + r_D,o|``
    on the other blocks ``o``, the block's residuals ``r_D,b + J_b delta``; the RMS of the 3-D position error over
    every predicted point (or pose) [mm]. Backward pass: drop the term whose removal lowers the score most, while
    one does. The pass searched many subsets, so its best score flatters it: the dropped terms stay dropped only
    where the pruned model beats the whole one significantly row by row, ``z = mean(s_w - s_p) / (sd(s_w - s_p) /
    sqrt(k)) >= z_min`` over the ``k`` rows' squared errors ``s`` (the diagnosis' confirmation threshold, 3).
    Returns ``(calibration without the dropped terms, labels dropped in order, trace, z)``; ``trace``: ``(label,
    score [mm])`` per step of the pass, the first ``(None, score with every term)`` (kept when the drops are not
    significant, with no label returned). Nothing is refitted: the
    session's rows only choose (the values came from the campaign that fitted them). ``ValueError`` naming the
    argument as in :func:`choose_for_session`."""
    if not isinstance(calibration, Calibration):
        raise ValueError(f"calibration must be a twin.estimator.Calibration, got {type(calibration).__name__}")
    idx = _fold_rows(rows, folds)
    eff = list(calibration.effects)
    if not eff:
        return calibration, (), (), 0.0
    predict = dataset_predictor(dataset)
    reg = register(calibration, dataset, idx, tool=tool, predict=predict)
    cal0 = reg.calibration
    sp = cal0.space
    free = [k for s in reg.stations for k in range(sp.base_slice(sp.station_index(s)).start,
                                                    sp.base_slice(sp.station_index(s)).stop)]
    if tool:
        free += list(range(sp.tool_slice.start, sp.tool_slice.stop))

    def resid(c: Calibration) -> np.ndarray:
        return session_residuals(c, dataset, idx, predict=predict if c.effects else None)[0]

    r0, row, pos, sigma = session_residuals(cal0, dataset, idx, predict=predict)
    J = np.empty((r0.size, len(free)))
    for j, k in enumerate(free):
        e = np.zeros(sp.size)
        e[k] = _FD_STEP
        J[:, j] = (resid(replace(cal0, x=cal0.x + e)) - resid(replace(cal0, x=cal0.x - e))) / (2.0 * _FD_STEP)
    d = [resid(replace(cal0, effects=tuple(eff[:t] + eff[t + 1:]))) - r0 for t in range(len(eff))]
    blocks = np.array_split(np.arange(idx.size), folds)
    n_points = pos.sum() / 3.0

    def per_row(drop: list[int]) -> np.ndarray:
        # each row's squared whitened position error, predicted by the registration on the other blocks
        r = r0 + (np.sum([d[t] for t in drop], axis=0) if drop else 0.0)
        out = np.zeros(idx.size)
        for b in blocks:
            test = np.isin(row, b)
            delta, *_ = np.linalg.lstsq(J[~test], -r[~test], rcond=None)
            e = r[test] + J[test] @ delta
            np.add.at(out, row[test][pos[test]], e[pos[test]] ** 2)
        return out

    def score(sq: np.ndarray) -> float:
        return float(np.sqrt(sq.sum() / n_points) * sigma / M_PER_MM)

    whole = per_row([])
    dropped: list[int] = []
    cur = whole
    trace = [(None, score(whole))]
    while len(dropped) < len(eff):
        trials = [(score(sq), t, sq) for t in range(len(eff)) if t not in dropped for sq in [per_row(dropped + [t])]]
        s_min, t_min, sq_min = min(trials, key=lambda v: (v[0], v[1]))
        if not s_min < score(cur):
            break
        dropped.append(t_min)
        cur = sq_min
        trace.append((str(eff[t_min].get("label", eff[t_min].get("family", t_min))), s_min))
    # the pass searched many subsets: its best is kept only where it beats the whole model significantly, row by row
    diff = whole - cur
    z = float(diff.mean() / (diff.std(ddof=1) / np.sqrt(diff.size))) if dropped and diff.std() > 0 else \
        (float("inf") if dropped else 0.0)
    if dropped and not z >= z_min:
        return calibration, (), tuple(trace), z
    kept = tuple(e for t, e in enumerate(eff) if t not in dropped)
    labels = tuple(lbl for lbl, _ in trace[1:])
    return replace(calibration, effects=kept), labels, tuple(trace), z
