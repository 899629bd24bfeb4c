"""Terms of the arm's own gravity load that need no mass properties: backlash signed by the load, the base tilting.

* **Load-signed backlash** of joint ``j``: ``dtheta_j = b sign(tau_j(q))``. A gear held against gravity rests on
  the flank its load pushes it to, whatever the direction of the last move: the offset's sign follows the sign of
  the joint's gravity torque. The torque is the URDF masses' (:func:`twin.diagnosis.candidates.gravity_torques`)
  when the chain has them, else the leading principal shape of the joint's gravity-torque regressor under the
  generic prior the compliance atoms use (:func:`twin.diagnosis.atoms.catalogue_atoms`): the masses are unknown,
  the sign of the dominant shape is what the rows can see. The sign is known from the first row on (no motion
  history); it competes with the motion-signed backlash for the joint's one backlash slot, and where the rows
  cannot tell the two apart the other is reported as the alternative.
* **Base compliance** without masses: the robot's base rotating about its horizontal axes ``x``, ``y`` through its
  origin under the gravity moment of the arm, ``(delta_x, delta_y) = (c_x M_x(q), c_y M_y(q))``. The moment is
  linear in the links' unknown mass moments ``(m_k, h_k = m_k c_k)``: ``M_a = sum_k e_a . ((m_k o_k + R_k h_k)
  x g)``, so ``Y[:, a, k] = (e_a . (o_k x g), R_k^T (g x e_a))`` (:func:`base_moment_regressor`; the joint
  gravity-torque regressor with the axis ``e_a`` through the base origin). Per axis its prior-weighted columns (the
  compliance atoms' prior: masses of one order, centres ~0.1 m off the frames) are reduced to their
  ``TILT_RANK`` leading principal shapes; the atom (family ``tilt``, target ``tilt0``) has one coefficient per
  shape and axis. With the chain's masses the catalogue's ``tilt`` atoms (one compliance per axis under the known
  moment) hold the same effect.
"""

from __future__ import annotations

import numpy as np

from ..kinematics import RobotModel, link_frames
from .candidates import GRAVITY, RowContext, gravity_torque_regressor, gravity_torques, has_masses

__all__ = ["TILT_RANK", "base_moment_regressor", "load_atoms", "tilt_angles"]

TILT_RANK = 2  # principal moment shapes kept per horizontal axis of the base
COM_PRIOR_M = 0.1  # [m] the compliance atoms' prior: a link's centre of mass ~0.1 m off its frame


def base_moment_regressor(model: RobotModel, q: np.ndarray, g: np.ndarray = GRAVITY) -> np.ndarray:
    """The arm's gravity moment about the base's ``x`` and ``y`` axes through its origin as a linear map of the links'
    mass moments: ``(n, 2, N, 4)``, ``M_a(q) = sum_k Y[:, a, k] @ (m_k, h_k)`` with ``h_k = m_k c_k`` in link frame
    ``k`` (the frames of :func:`twin.diagnosis.candidates.gravity_torque_regressor`):
    ``Y[:, a, k] = (e_a . (o_k x g), R_k^T (g x e_a))``."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if model.convention == "urdf":
        from .candidates import joint_frames

        F = joint_frames(model, q)
    else:
        F = link_frames(model, q)[:, 1:model.n_joints + 1]
    n, N = F.shape[0], F.shape[1]
    Y = np.zeros((n, 2, N, 4))
    for a in (0, 1):
        e = np.zeros(3)
        e[a] = 1.0
        gxe = np.cross(g, e)
        for k in range(N):
            o, R = F[:, k, :3, 3], F[:, k, :3, :3]
            Y[:, a, k, 0] = np.cross(o, g) @ e
            Y[:, a, k, 1:] = np.einsum("nji,j->ni", R, gxe)
    return Y


def _prior(N: int) -> np.ndarray:
    return np.tile(np.array([1.0, COM_PRIOR_M, COM_PRIOR_M, COM_PRIOR_M]), N)


def _leading_torque_shape(model: RobotModel, q: np.ndarray, i: int) -> dict | None:
    """Joint ``i``'s (1-based) leading principal gravity-torque shape under the generic prior, as a ``gravmix``
    feature (the compliance atoms' first shape), or None when the joint carries no varying torque."""
    Y = gravity_torque_regressor(model, q)
    N = model.n_joints
    cols, prior = [], []
    for k in range(i, N + 1):
        for c in range(4):
            cols.append([k, c])
            prior.append(1.0 if c == 0 else COM_PRIOR_M)
    M = np.stack([Y[:, i - 1, k - 1, c] for k, c in cols], axis=1) * np.array(prior)
    if not np.any(np.abs(M) > 1e-9):
        return None
    _, sv, Vt = np.linalg.svd(M, full_matrices=False)
    return {"kind": "gravmix", "i": i, "cols": cols, "w": (Vt[0] * np.array(prior)).tolist(),
            "h": float(sv[0] / np.sqrt(len(M)))}


def load_atoms(model: RobotModel, ctx: RowContext) -> list:
    """The load-signed backlash of every joint whose gravity load changes sign over the rows, and, on a chain without
    mass properties, the base tilting under the arm's unknown gravity moment (module docstring)."""
    from .atoms import Atom, joint_words

    atoms = []
    N = model.n_joints
    masses = has_masses(model)
    tau = gravity_torques(model, ctx.q) if masses else None
    for j in range(1, N + 1):
        inner = {"kind": "torque", "j": j, "h": 1.0} if masses else _leading_torque_shape(model, ctx.q, j)
        if inner is None:
            continue
        if masses:
            t = tau[:, j - 1]
        else:
            from .atoms import feature_values

            t = feature_values((inner,), ctx, model)[:, 0]
        s = np.sign(t)
        if min(np.sum(s > 0), np.sum(s < 0)) < 3:
            continue  # the load keeps one sign: the offset is a constant the geometry holds
        atoms.append(Atom("backlash", "joint", f"theta{j}", ({"kind": "loadsign", "f": inner},), f"load_sign_j{j}",
                          f"joint {joint_words(model, j)} backlash (offset signed by its gravity load)", "catalogue",
                          (j,)))
    if not masses:
        Y = base_moment_regressor(model, ctx.q)
        n = len(ctx.q)
        prior = _prior(N)
        feats = []
        for a in (0, 1):
            M = Y[:, a].reshape(n, -1) * prior
            if not np.any(np.abs(M) > 1e-9):
                continue
            _, sv, Vt = np.linalg.svd(M, full_matrices=False)
            rk = int(np.sum(sv > 1e-6 * sv[0]))
            feats += [{"kind": "basemoment", "axis": a, "w": (Vt[k] * prior).tolist(), "h": float(sv[k] / np.sqrt(n))}
                      for k in range(min(TILT_RANK, rk))]
        if {f["axis"] for f in feats} == {0, 1}:
            atoms.append(Atom("tilt", "param", "tilt0", tuple(feats), "gravity moment carried by the base (shapes)",
                              "the robot's base tilting about its horizontal axes under the arm's gravity moment "
                              "(base compliance; the moment's shapes from unknown link masses)", "catalogue"))
    return atoms


def tilt_angles(features, F: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """The tilt ``(n, 2)`` [rad] about the pivot's ``x`` and ``y`` axes of a tilt atom with ``features`` (each turns
    the pivot about its ``axis``), values ``F`` ``(n, K)`` and coefficients ``phi`` ``(K,)``."""
    out = np.zeros((F.shape[0], 2))
    for k, f in enumerate(features):
        out[:, int(f.get("axis", k))] += F[:, k] * phi[k]
    return out
