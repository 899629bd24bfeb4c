"""Using an extended calibration (``calibration.json`` with ``effects``): prediction and compensation.

The effects stored by diagnosis are linear models on the commanded joints in measurement order and on
the recorded channels (``temp_c``, ``t_s``): joint effects add ``G(q, ctx) phi`` to the commanded joints,
thermal growth scales the link lengths per row, plate effects move the sphere centres in the plate frame.
History-dependent effects (backlash) use the row order of the input and the configuration the robot
started from (``q_start``, home by default).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..estimator.calibration import Calibration, Prediction
from ..estimator.compensation import CompensationResult, compensation
from .candidates import Candidate, RowContext, candidate_catalogue

__all__ = ["effective_joints", "predict_extended", "compensate_extended"]


def _catalogue(cal: Calibration) -> dict[str, Candidate]:
    return {c.name: c for c in candidate_catalogue(cal.nominal)}


def _check(cal: Calibration) -> None:
    known = _catalogue(cal)
    for e in cal.effects:
        if e.get("name") not in known:
            raise ValueError(f"calibration effect {e.get('name')!r} is not in the vocabulary {sorted(known)}")


def effective_joints(cal: Calibration, ctx: RowContext) -> np.ndarray:
    """Joints ``(n, 6)`` [rad] the robot is predicted to reach for the commanded ``ctx.q`` (joint effects)."""
    _check(cal)
    cat = _catalogue(cal)
    q = ctx.q.copy()
    for e in cal.effects:
        if e["kind"] == "joint":
            G = cat[e["name"]].regressor(ctx, e.get("reference", {}))
            q = q + np.einsum("nik,k->ni", G, np.asarray(e["values"], dtype=float))
    return q


def _length_scale(cal: Calibration, ctx: RowContext) -> np.ndarray | None:
    cat = _catalogue(cal)
    s = None
    for e in cal.effects:
        if e["kind"] == "length":
            g = cat[e["name"]].regressor(ctx, e.get("reference", {})) @ np.asarray(e["values"], dtype=float)
            s = g if s is None else s + g
    return s


def _with_lengths(cal: Calibration, scale: float) -> Calibration:
    sp = cal.space
    idx = np.concatenate([sp.family("d"), sp.family("a")])
    x = cal.x.copy()
    x[idx] *= 1.0 + scale
    return replace(cal, x=x)


def _with_plate(cal: Calibration) -> Calibration:
    off = np.zeros((3, 3))
    for e in cal.effects:
        if e["kind"] == "plate":
            off += np.asarray(e["values"], dtype=float).reshape(3, 3)
    if not off.any():
        return cal
    return replace(cal, spheres_tool=cal.spheres_tool + off)


def predict_extended(cal: Calibration, ctx: RowContext, station: np.ndarray | None = None) -> Prediction:
    """Like :meth:`Calibration.predict`, with the calibration's effects applied to the rows of ``ctx``."""
    q_eff = effective_joints(cal, ctx)
    c = _with_plate(cal)
    scale = _length_scale(cal, ctx)
    if scale is None:
        return c.predict(q_eff, station)
    n = q_eff.shape[0]
    parts = [
        _with_lengths(c, float(scale[k])).predict(q_eff[k:k + 1], None if station is None else station[k:k + 1])
        for k in range(n)
    ]
    cat = lambda name: None if getattr(parts[0], name) is None else np.concatenate([getattr(p, name) for p in parts])  # noqa: E731
    return Prediction(spheres=cat("spheres"), pose=cat("pose"), frame=cat("frame"), station=cat("station"),
                      sd_spheres=cat("sd_spheres"), sd_pose=cat("sd_pose"))


def compensate_extended(
    cal: Calibration,
    targets_tool2base: np.ndarray,
    q_ref: np.ndarray,
    ctx: RowContext,
    *,
    max_rounds: int = 20,
    tol: float = 1e-10,
) -> CompensationResult:
    """Commands that put the plate at the targets on the identified robot *with* its effects.

    1. The geometric answer ``q_geo`` (iterative inverse kinematics on the identified model; per row at the
       row's length scale when thermal growth is modelled).
    2. Fixed point ``q_cmd <- q_geo - (q_eff(q_cmd) - q_cmd)``: the joint effect evaluated at the commands
       themselves (so backlash follows the order and directions of the commands), until the commands move by
       less than ``tol`` [rad].
    ``ctx`` gives the rows' channels (``temp_c``, ``t_s``) and ``q_start``; its ``q`` is ignored.
    """
    T = np.asarray(targets_tool2base, dtype=float)
    if T.ndim == 2:
        T = T[None]
    n = T.shape[0]
    scale = _length_scale(cal, replace(ctx, q=np.zeros((n, 6))))
    if scale is None:
        base = compensation(_with_plate(cal), T, q_ref)
        q_geo = base.q
    else:
        q_ref_b = np.broadcast_to(np.asarray(q_ref, dtype=float), (n, 6))
        res = [compensation(_with_lengths(_with_plate(cal), float(scale[k])), T[k:k + 1], q_ref_b[k:k + 1])
               for k in range(n)]
        q_geo = np.concatenate([r.q for r in res])
        base = replace(res[0], q=q_geo, q_nominal=np.concatenate([r.q_nominal for r in res]),
                       position_error=np.concatenate([r.position_error for r in res]),
                       rotation_error=np.concatenate([r.rotation_error for r in res]))
    if not any(e["kind"] == "joint" for e in cal.effects):
        return base
    q_cmd = q_geo.copy()
    for _ in range(max_rounds):
        d = effective_joints(cal, replace(ctx, q=q_cmd)) - q_cmd
        q_new = q_geo - d
        step = float(np.max(np.abs(q_new - q_cmd)))
        q_cmd = q_new
        if step < tol:
            break
    else:
        raise ValueError(f"compensation with effects did not settle in {max_rounds} rounds (last step {step:.3g} rad)")
    return replace(base, q=q_cmd)
