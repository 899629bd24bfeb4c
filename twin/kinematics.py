"""Kinematics of serial chains (pure numpy, batched): the papers' 6R arms and any chain of revolute and
prismatic joints.

A chain is a sequence of elementary operations (:class:`ChainOp`) per joint: a rotation about, or a translation
along, a local axis by a parameter (plus, for the joint's own operation, the commanded joint value), or a
constant rotation or translation. Two families of structures (see ``docs/conventions.md``):

* the papers' 6R conventions, six revolute joints with columns ``q1..q6``:

  * ``"mdh"`` -- the separation paper's eq. 1 (Craig modified DH). The transform from frame ``i-1`` to frame
    ``i`` is ``RotX(alpha_i) TransX(a_i) TransZ(d_i) RotZ(theta_i + q_i) RotY(beta_i)``. Here
    ``alpha_i``/``a_i`` are Craig's ``alpha_{i-1}``/``a_{i-1}``: every parameter is named after the joint
    whose transform it sits in, as in the paper's Table 1.
  * ``"dh"`` -- the TM-MDH paper's eq. 1 (standard DH + beta):
    ``RotZ(theta_i + q_i) TransZ(d_i) TransX(a_i) RotX(alpha_i) RotY(beta_i)``.

  ``RotY(beta_i)`` exists only for joints listed in ``beta_joints``. Parameter vector (SI: [m], [rad]),
  ordered as in the TM-MDH paper: ``theta1..6, d1..6, a1..6, alpha1..6, beta_j (j in beta_joints)``.

* ``"urdf"`` -- any chain of N revolute or prismatic joints described as URDF joints (``origin`` xyz + rpy,
  ``axis``; :class:`JointSpec`): joint ``j``'s transform is ``Trans(x_j, y_j, z_j) R_j RotX(rx_j) RotY(ry_j)
  RotZ(rz_j) Joint_j(offset_j + q_j)`` where ``R_j`` is the nominal origin rotation (constant), ``rx, ry, rz``
  small origin rotation errors (nominal 0) about the origin frame's axes and ``Joint_j`` a rotation about
  (revolute) or a translation along (prismatic) the joint axis. Parameters are named ``<joint>.<family>``,
  family-major: ``offset`` of every joint, then ``x``, ``y``, ``z``, ``rx``, ``ry``, ``rz``. A constant
  transform after the last joint (fixed joints up to the chain's end link) makes the flange the end link.

Both are followed by the base and tool 6-DOF transforms::

    base_x, base_y, base_z, base_rx, base_ry, base_rz,   # base2meas: translation [m], rotation vector [rad]
    tool_x, tool_y, tool_z, tool_rx, tool_ry, tool_rz    # tool2flange: translation [m], rotation vector [rad]

The tool pose in the measurement frame is ``tool2meas = base2meas @ flange2base(q) @ tool2flange``. A 6-DOF
transform is perturbed additively on its (translation, rotation vector) pair.

This module holds the forward kinematics, the Jacobians and the inverse kinematics; the chain's types
(:class:`ChainOp`, :class:`JointSpec`, :class:`ChainStructure`, :class:`ParameterLayout`, :class:`RobotModel`) are
:mod:`twin.robot_model`'s, re-exported here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Literal

import numpy as np

from .robot_model import (N_JOINTS, URDF_FAMILIES, ChainOp, ChainStructure, Convention, JointSpec, ParameterLayout,
                    RobotModel)
from .transforms import invert_transform, left_jacobian_so3, matrix_to_rotvec, skew

__all__ = [
    "Convention",
    "N_JOINTS",
    "ChainOp",
    "ChainStructure",
    "JointSpec",
    "ParameterLayout",
    "RobotModel",
    "UnreachableError",
    "IKSolutions",
    "IKResult",
    "IKTraceEntry",
    "link_transforms",
    "link_frames",
    "flange2base",
    "tool2base",
    "tool2meas",
    "pose_jacobian",
    "point_jacobian",
    "joint_jacobian",
    "pose_error",
    "inverse_kinematics_closed_form",
    "inverse_kinematics_iterative",
    "closest_branch",
    "wrap_angle",
    "URDF_FAMILIES",
    "elementary_transform",
]


class UnreachableError(ValueError):
    """A target pose that no joint configuration of the model reaches."""


def wrap_angle(angle: np.ndarray) -> np.ndarray:
    """Wrap angles [rad] into (-pi, pi]."""
    a = np.mod(np.asarray(angle, dtype=float) + np.pi, 2.0 * np.pi) - np.pi
    return np.where(a <= -np.pi, a + 2.0 * np.pi, a)


# ------------------------------------------------------------------------------------------------
# Forward kinematics
# ------------------------------------------------------------------------------------------------

def _as_q(q: np.ndarray, n_joints: int = N_JOINTS) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    if q.ndim == 1:
        q = q[None, :]
    if q.ndim != 2 or q.shape[1] != n_joints:
        raise ValueError(f"q must have shape (n, {n_joints}) [rad, m for prismatic joints], got {q.shape}")
    if not np.all(np.isfinite(q)):
        rows = np.unique(np.nonzero(~np.isfinite(q))[0])
        raise ValueError(f"q contains non-finite values in rows {rows[:10].tolist()}")
    return q


def _elementary(kind: str, axis: int, value: np.ndarray) -> np.ndarray:
    """Batched elementary transform ``(n, 4, 4)`` for values ``(n,)``."""
    value = np.asarray(value, dtype=float)
    T = np.zeros(value.shape + (4, 4))
    T[..., 0, 0] = T[..., 1, 1] = T[..., 2, 2] = T[..., 3, 3] = 1.0
    if kind == "t":
        T[..., axis, 3] = value
        return T
    c, s = np.cos(value), np.sin(value)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    T[..., i, i] = c
    T[..., j, j] = c
    T[..., i, j] = -s
    T[..., j, i] = s
    return T


def elementary_transform(kind: Literal["r", "t"], axis: int, value: np.ndarray) -> np.ndarray:
    """Rotation about (``"r"``) or translation along (``"t"``) local axis ``axis`` (0, 1, 2 = x, y, z) by
    ``value`` ``(...)`` [rad or m]: transforms ``(..., 4, 4)``."""
    if kind not in ("r", "t") or axis not in (0, 1, 2):
        raise ValueError(f"kind must be 'r' or 't' and axis 0, 1 or 2, got {kind!r}, {axis!r}")
    return _elementary(kind, axis, value)


def _op_value(op: ChainOp, value: float, q: np.ndarray, n: int) -> np.ndarray:
    """Value ``(n,)`` of a parameterised operation: the parameter, plus or minus its joint's commanded value."""
    if op.joint < 0:
        return np.full(n, value)
    return value + q[:, op.joint] if op.sign > 0 else value - q[:, op.joint]


def _op_transform(op: ChainOp, model: RobotModel, k: int, i: int, q: np.ndarray, n: int) -> np.ndarray:
    """Transform ``(n, 4, 4)`` (or ``(4, 4)`` for a constant) of operation ``k`` of joint ``i``."""
    if op.kind in ("R", "P"):
        return op.matrix()
    v = model.params[model._pindex[i][k]]  # type: ignore[attr-defined]
    return _elementary(op.kind, op.axis, _op_value(op, v, q, n))


def link_transforms(model: RobotModel, q: np.ndarray) -> np.ndarray:
    """Per-joint transforms ``(n, N, 4, 4)``: entry ``i`` maps frame ``i+1`` into frame ``i`` (the last one
    includes the chain's constant end transform, so frame ``N`` is the flange)."""
    st = model.structure
    q = _as_q(q, st.n_joints)
    n = q.shape[0]
    out = np.empty((n, st.n_joints, 4, 4))
    for i, ops in enumerate(st.ops):
        T = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
        for k, op in enumerate(ops):
            T = T @ _op_transform(op, model, k, i, q, n)
        if i == st.n_joints - 1:
            for op in st.end:
                T = T @ op.matrix()
        out[:, i] = T
    return out


def link_frames(model: RobotModel, q: np.ndarray, frame: Literal["base", "meas"] = "base") -> np.ndarray:
    """Poses of frames 0..N ``(n, N+1, 4, 4)`` (frame 0 = robot base, frame N = flange), in ``frame``."""
    L = link_transforms(model, q)
    n, nj = L.shape[:2]
    out = np.empty((n, nj + 1, 4, 4))
    out[:, 0] = model.base2meas if frame == "meas" else np.eye(4)
    for i in range(nj):
        out[:, i + 1] = out[:, i] @ L[:, i]
    return out


def flange2base(model: RobotModel, q: np.ndarray) -> np.ndarray:
    """Flange poses in the base frame ``(n, 4, 4)`` for joints ``q`` ``(n, N)``."""
    L = link_transforms(model, q)
    T = L[:, 0]
    for i in range(1, L.shape[1]):
        T = T @ L[:, i]
    return T


def tool2base(model: RobotModel, q: np.ndarray) -> np.ndarray:
    """Tool (plate) poses in the base frame ``(n, 4, 4)``."""
    return flange2base(model, q) @ model.tool2flange


def tool2meas(model: RobotModel, q: np.ndarray) -> np.ndarray:
    """Tool (plate) poses in the measurement frame ``(n, 4, 4)``."""
    return model.base2meas @ flange2base(model, q) @ model.tool2flange


# ------------------------------------------------------------------------------------------------
# Identification Jacobians
# ------------------------------------------------------------------------------------------------

def pose_jacobian(model: RobotModel, q: np.ndarray, frame: Literal["meas", "base"] = "meas") -> np.ndarray:
    """Jacobian ``(n, 6, P)`` of the tool pose with respect to every model parameter.

    Rows 0-2: derivative of the tool origin [m per unit]; rows 3-5: spatial angular rate ``w`` with
    ``dR R^T = [w]x``, both expressed in ``frame``. Each parameter moves the chain by an elementary
    screw: a rotation about a local axis ``u`` of an intermediate frame ``F`` gives the column
    ``[w x (p - o_F); w]`` with ``w = R_F u``; a translation gives ``[R_F u; 0]``. Base and tool
    rotation vectors enter through the left Jacobian of SO(3). With ``frame="base"`` the base
    parameters get zero columns (the pose excludes ``base2meas``).
    """
    st = model.structure
    q = _as_q(q, st.n_joints)
    n = q.shape[0]
    lay = model.layout
    J = np.zeros((n, 6, lay.size))
    B = model.base2meas if frame == "meas" else np.eye(4)
    # First pass: walk the chain, remember each parameter's axis and origin.
    T = np.broadcast_to(B, (n, 4, 4)).copy()
    rot_axes: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    trans_axes: dict[int, np.ndarray] = {}
    for i, ops in enumerate(st.ops):
        for k, op in enumerate(ops):
            T = T @ _op_transform(op, model, k, i, q, n)
            if op.kind in ("R", "P"):
                continue
            col = model._pindex[i][k]  # type: ignore[attr-defined]
            if op.kind == "r":
                rot_axes[col] = (T[:, :3, op.axis].copy(), T[:, :3, 3].copy())
            else:
                trans_axes[col] = T[:, :3, op.axis].copy()
    for op in st.end:
        T = T @ op.matrix()
    flange = T
    tool = flange @ model.tool2flange
    p = tool[:, :3, 3]
    for col, (w, o) in rot_axes.items():
        J[:, :3, col] = np.cross(w, p - o)
        J[:, 3:, col] = w
    for col, u in trans_axes.items():
        J[:, :3, col] = u
    # base2meas = [R(r), t]: dp = dt + w x (p - t), w = J_l(r) dr.
    if frame == "meas":
        bs = lay.base_slice
        base = model.params[bs]
        J[:, :3, bs.start:bs.start + 3] = np.eye(3)
        W = left_jacobian_so3(base[3:])
        for k in range(3):
            w = W[:, k]
            J[:, :3, bs.start + 3 + k] = np.cross(w, p - base[:3])
            J[:, 3:, bs.start + 3 + k] = w
    # tool2flange = [R(r'), t']: the tool origin moves with t' only; r' rotates the tool in place.
    ts = lay.tool_slice
    tool_pose = model.params[ts]
    RA = flange[:, :3, :3]
    J[:, :3, ts.start:ts.start + 3] = RA
    J[:, 3:, ts.start + 3:ts.start + 6] = RA @ left_jacobian_so3(tool_pose[3:])
    return J


def point_jacobian(
    model: RobotModel, q: np.ndarray, points_tool: np.ndarray, frame: Literal["meas", "base"] = "meas"
) -> np.ndarray:
    """Jacobian ``(n, m, 3, P)`` of points fixed in the tool frame, ``points_tool`` ``(m, 3)`` [m].

    ``d(p + R s) = J_p dx + w x (R s) = (J_p - [R s]x J_w) dx``.
    """
    pts = np.asarray(points_tool, dtype=float).reshape(-1, 3)
    Jpose = pose_jacobian(model, q, frame=frame)
    T = tool2meas(model, q) if frame == "meas" else tool2base(model, q)
    Rs = np.einsum("nij,mj->nmi", T[:, :3, :3], pts)  # (n, m, 3)
    return Jpose[:, None, :3, :] - skew(Rs) @ Jpose[:, None, 3:, :]


def joint_jacobian(model: RobotModel, q: np.ndarray, frame: Literal["meas", "base"] = "base") -> np.ndarray:
    """Geometric Jacobian ``(n, 6, N)`` of the tool pose with respect to the joints ``q``."""
    J = pose_jacobian(model, q, frame=frame)
    st = model.structure
    Jq = J[:, :, model.layout.indices(st.joint_params)]
    signs = st.joint_signs
    return Jq if np.all(signs > 0) else Jq * signs


def pose_error(T_target: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Pose error ``(n, 6)``: position difference [m] and rotation vector of ``R_target R^T`` [rad]."""
    T_target = np.asarray(T_target, dtype=float)
    dp = T_target[..., :3, 3] - T[..., :3, 3]
    dr = matrix_to_rotvec(T_target[..., :3, :3] @ np.swapaxes(T[..., :3, :3], -1, -2))
    return np.concatenate([dp, dr], axis=-1)


# ------------------------------------------------------------------------------------------------
# Closed-form inverse kinematics (spherical wrist, axes 2 and 3 parallel)
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class IKSolutions:
    """All eight branches of the closed-form inverse.

    ``q`` ``(n, 8, 6)`` [rad] in (-pi, pi]; ``valid`` ``(n, 8)`` is False where a branch does not
    exist (its ``q`` rows are then meaningless and set to 0, never NaN); ``within_limits`` ``(n, 8)``
    also requires the joint limits. Branch index ``4*shoulder + 2*elbow + wrist``.
    """

    q: np.ndarray
    valid: np.ndarray
    within_limits: np.ndarray


def _split_joint(model: RobotModel, i: int) -> tuple[np.ndarray, np.ndarray]:
    """(pre, post) constant transforms ``(4, 4)`` around ``RotZ(theta_i + q_i)`` of joint ``i`` (the last
    joint's post includes the chain's end transform); ``ValueError`` when the joint is not a revolute joint
    about its local z axis."""
    st = model.structure
    pre, post = np.eye(4), np.eye(4)
    seen = False
    for k, op in enumerate(st.ops[i]):
        if op.joint == i:
            if not (op.kind == "r" and op.axis == 2 and op.sign > 0):
                raise ValueError(f"model {model.name!r}: joint {st.joint_names[i]!r} does not turn about its local z "
                                 "axis: no closed-form inverse (use inverse_kinematics_iterative)")
            seen = True
            continue
        if op.kind in ("R", "P"):
            E = op.matrix()
        else:
            E = _elementary(op.kind, op.axis, model.params[model._pindex[i][k]])  # type: ignore[attr-defined]
        if seen:
            post = post @ E
        else:
            pre = pre @ E
    if i == st.n_joints - 1:
        for op in st.end:
            post = post @ op.matrix()
    return pre, post


def _solve_trig(k1: np.ndarray, k2: np.ndarray, rhs: np.ndarray, tol: float):
    """Solve ``k1 cos x + k2 sin x = rhs``: two roots ``(2, n)`` and a mask ``(n,)`` of existence."""
    r = np.hypot(k1, k2)
    ratio = rhs / np.where(r < 1e-300, 1.0, r)
    ok = (r > 1e-300) & (np.abs(ratio) <= 1.0 + tol)
    phi = np.arctan2(k2, k1)
    delta = np.arccos(np.clip(ratio, -1.0, 1.0))
    return np.stack([phi + delta, phi - delta]), ok


def _affine_trig(f: Callable[[float], np.ndarray]):
    """Coefficients of ``f(x) = k0 + k1 cos x + k2 sin x`` from three samples."""
    f0, fpi, fhalf = f(0.0), f(np.pi), f(np.pi / 2)
    k0 = 0.5 * (f0 + fpi)
    return k0, 0.5 * (f0 - fpi), fhalf - k0


def _rz(x: np.ndarray) -> np.ndarray:
    return _elementary("r", 2, x)


def _check_ik_structure(model: RobotModel) -> tuple[np.ndarray, np.ndarray]:
    """Wrist centre in frame 3 and in the flange frame, checking the model admits the closed form."""
    if model.n_joints != N_JOINTS:
        raise ValueError(f"model {model.name!r} has {model.n_joints} joints: the closed-form inverse is for 6R arms "
                         "(use inverse_kinematics_iterative)")
    rng = np.random.default_rng(0)
    pre = [_split_joint(model, i) for i in range(N_JOINTS)]

    def T(i, th):
        return pre[i][0] @ _rz(np.float64(th)) @ pre[i][1]

    p3 = (T(3, 0.0) @ np.array([0, 0, 0, 1.0]))[:3]
    p3b = (T(3, 1.1) @ np.array([0, 0, 0, 1.0]))[:3]
    wcs = []
    for th5, th6 in [(0.0, 0.0), tuple(rng.uniform(-3, 3, 2)), tuple(rng.uniform(-3, 3, 2))]:
        wcs.append((invert_transform(T(4, th5) @ T(5, th6)) @ np.array([0, 0, 0, 1.0]))[:3])
    scale = 1.0 + float(np.max(np.abs(model.params[model.layout.is_length])))
    # Axes 2 and 3 parallel: the component of the wrist centre along axis 2 does not depend on q3.
    h = [(pre[1][1] @ T(2, th) @ np.append(p3, 1.0))[2] for th in (0.0, 0.7, 2.1)]
    if (
        np.linalg.norm(p3 - p3b) > 1e-9 * scale
        or max(np.linalg.norm(w - wcs[0]) for w in wcs) > 1e-9 * scale
        or np.ptp(h) > 1e-9 * scale
    ):
        raise ValueError(
            f"model {model.name!r} has no closed-form inverse (wrist not spherical or axes 2/3 not "
            "parallel, e.g. beta2 != 0); use inverse_kinematics_iterative"
        )
    return p3, wcs[0]


def inverse_kinematics_closed_form(
    model: RobotModel, flange2base_target: np.ndarray, tol: float = 1e-9
) -> IKSolutions:
    """All eight closed-form branches for flange targets ``(n, 4, 4)`` (or ``(4, 4)``) in the base frame.

    Decoupling at the wrist centre ``c`` (origin of frame 4, where axes 4-6 meet):

    1. shoulder: the component of ``c`` along axis 2, seen from frame 1, does not depend on
       ``q2, q3``; it is ``k0 + k1 cos th1 + k2 sin th1`` -> two ``th1``;
    2. elbow: ``|c - o_2|`` does not depend on ``th2`` -> ``k0 + k1 cos th3 + k2 sin th3`` -> two ``th3``;
    3. ``th2`` rotates the known in-plane vector onto ``c`` (one solution);
    4. wrist: with ``M = RotZ(th4) B RotZ(th5) C RotZ(th6)``, ``e_z^T M e_z`` gives two ``th5``, then
       ``th4`` and ``th6`` from the third column and row. At ``sin(th5) = 0`` (wrist singular) only
       ``th4 + th6`` matters: ``th4 = 0`` is chosen.

    The ``k`` coefficients are sampled from the model itself, so the same code serves both conventions.
    """
    Tt = np.asarray(flange2base_target, dtype=float)
    if Tt.ndim == 2:
        Tt = Tt[None]
    if Tt.ndim != 3 or Tt.shape[1:] != (4, 4):
        raise ValueError(f"flange2base_target must have shape (n, 4, 4), got {Tt.shape}")
    p3, wc_flange = _check_ik_structure(model)
    n = Tt.shape[0]
    split = [_split_joint(model, i) for i in range(N_JOINTS)]
    offs = model.params[model.layout.indices(model.structure.joint_params)]
    c = (Tt @ np.append(wc_flange, 1.0))[:, :3]  # wrist centre in base (n, 3)
    c_h = np.concatenate([c, np.ones((n, 1))], axis=1)

    def J(i, th):  # joint transform (n or scalar, 4, 4)
        return split[i][0] @ _rz(th) @ split[i][1]

    p3h = np.append(p3, 1.0)
    # 1. shoulder
    h_const = (split[1][1] @ J(2, 0.0) @ p3h)[2]

    def g(th1):
        F2 = J(0, np.full(n, th1)) @ split[1][0]
        return np.einsum("nij,nj->ni", invert_transform(F2), c_h)[:, 2]

    k0, k1, k2 = _affine_trig(g)
    th1s, ok1 = _solve_trig(k1, k2, h_const - k0, tol)

    # 2. elbow coefficients (independent of the target)
    def f3(th3):
        v = split[1][1] @ J(2, np.float64(th3)) @ p3h
        return np.dot(v[:3], v[:3])

    e0, e1, e2 = _affine_trig(f3)

    q = np.zeros((n, 8, N_JOINTS))
    valid = np.zeros((n, 8), dtype=bool)
    for s in range(2):
        th1 = th1s[s]
        F2 = J(0, th1) @ split[1][0]
        u = np.einsum("nij,nj->ni", invert_transform(F2), c_h)[:, :3]
        dist2 = np.einsum("ni,ni->n", u, u)
        th3s, ok3 = _solve_trig(np.full(n, e1), np.full(n, e2), dist2 - e0, tol)
        for e in range(2):
            th3 = th3s[e]
            w = np.einsum("ij,nj->ni", split[1][1], np.einsum("nij,j->ni", J(2, th3), p3h))[:, :3]
            th2 = np.arctan2(u[:, 1], u[:, 0]) - np.arctan2(w[:, 1], w[:, 0])
            T03 = J(0, th1) @ J(1, th2) @ J(2, th3)
            R36 = np.swapaxes(T03[:, :3, :3], 1, 2) @ Tt[:, :3, :3]
            M = split[3][0][:3, :3].T @ R36 @ split[5][1][:3, :3].T
            Bm = (split[3][1] @ split[4][0])[:3, :3]
            Cm = (split[4][1] @ split[5][0])[:3, :3]

            def f5(th5):
                return (Bm @ _rz(np.float64(th5))[:3, :3] @ Cm)[2, 2]

            w0, w1, w2 = _affine_trig(f5)
            th5s, ok5 = _solve_trig(np.full(n, w1), np.full(n, w2), M[:, 2, 2] - w0, tol)
            if abs(w0) < 1e-12 and abs(np.hypot(w1, w2) - 1.0) < 1e-12:
                # Perpendicular wrist axes: e_z^T M e_z = cos(th5 - phi) and the in-plane part of M e_z
                # has norm |sin(th5 - phi)|. atan2 of both keeps th5 exact near the singularity,
                # where arccos alone would lose half the digits.
                phi = np.arctan2(w2, w1)
                delta = np.arctan2(np.hypot(M[:, 0, 2], M[:, 1, 2]), M[:, 2, 2] - w0)
                th5s = np.stack([phi + delta, phi - delta])
            for wbit in range(2):
                th5 = th5s[wbit]
                Rz5 = _rz(th5)[:, :3, :3]
                w4 = (Bm @ Rz5 @ Cm)[:, :, 2]  # M e_z = Rz(th4) w4
                u4 = M[:, :, 2]
                w6 = np.einsum("nji,j->ni", Bm @ Rz5 @ Cm, np.array([0, 0, 1.0]))  # (B Rz5 C)^T e_z
                u6 = M[:, 2, :]  # M^T e_z, equals Rz(th6)^T w6
                singular = np.hypot(w4[:, 0], w4[:, 1]) < 1e-12
                th4 = np.where(singular, 0.0, np.arctan2(u4[:, 1], u4[:, 0]) - np.arctan2(w4[:, 1], w4[:, 0]))
                th6 = np.arctan2(w6[:, 1], w6[:, 0]) - np.arctan2(u6[:, 1], u6[:, 0])
                if np.any(singular):
                    N = np.swapaxes(_rz(th4)[:, :3, :3] @ Bm @ Rz5 @ Cm, 1, 2) @ M
                    th6 = np.where(singular, np.arctan2(N[:, 1, 0], N[:, 0, 0]), th6)
                b = 4 * s + 2 * e + wbit
                th = np.stack([th1, th2, th3, th4, th5, th6], axis=1)
                q[:, b] = wrap_angle(th - offs)
                valid[:, b] = ok1 & ok3 & ok5
    q = np.where(valid[..., None], q, 0.0)
    # Keep only branches that really reproduce the target (guards the tolerance of the trig solves).
    Tcheck = flange2base(model, q.reshape(-1, N_JOINTS)).reshape(n, 8, 4, 4)
    err = pose_error(np.broadcast_to(Tt[:, None], (n, 8, 4, 4)), Tcheck)
    scale = 1.0 + np.linalg.norm(Tt[:, None, :3, 3], axis=-1)
    good = (np.linalg.norm(err[..., :3], axis=-1) < 1e-6 * scale) & (np.linalg.norm(err[..., 3:], axis=-1) < 1e-6)
    valid &= good
    q = np.where(valid[..., None], q, 0.0)
    within = valid & np.all((q >= model.q_min - 1e-12) & (q <= model.q_max + 1e-12), axis=-1)
    return IKSolutions(q=q, valid=valid, within_limits=within)


def closest_branch(solutions: IKSolutions, q_ref: np.ndarray, require_limits: bool = True) -> np.ndarray:
    """Pick, per target, the valid branch nearest ``q_ref`` ``(n, 6)`` [rad]; raises when none exists."""
    mask = solutions.within_limits if require_limits else solutions.valid
    q_ref = np.broadcast_to(np.asarray(q_ref, dtype=float), (solutions.q.shape[0], N_JOINTS))
    dist = np.linalg.norm(wrap_angle(solutions.q - q_ref[:, None]), axis=-1)
    dist = np.where(mask, dist, np.inf)
    best = np.argmin(dist, axis=1)
    missing = np.flatnonzero(~np.isfinite(dist[np.arange(len(best)), best]))
    if missing.size:
        what = "inside the joint limits" if require_limits else "at all"
        raise UnreachableError(f"targets {missing[:10].tolist()} are not reachable {what}")
    return solutions.q[np.arange(len(best)), best]


# ------------------------------------------------------------------------------------------------
# Iterative inverse kinematics on any (perturbed) model -- the separation paper's section 2.4
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class IKTraceEntry:
    iteration: int
    max_position_error: float  # [m]
    max_rotation_error: float  # [rad]


@dataclass(frozen=True)
class IKResult:
    """Result of :func:`inverse_kinematics_iterative`: ``q`` ``(n, N)``, per-target convergence."""

    q: np.ndarray
    converged: np.ndarray
    position_error: np.ndarray  # (n,) [m]
    rotation_error: np.ndarray  # (n,) [rad]
    iterations: int
    trace: tuple[IKTraceEntry, ...]


def inverse_kinematics_iterative(
    model: RobotModel,
    target: np.ndarray,
    q0: np.ndarray,
    *,
    frame: Literal["flange", "tool", "meas"] = "flange",
    tol_position: float = 1e-12,
    tol_rotation: float = 1e-12,
    max_iter: int = 100,
    max_step: float = 0.2,
    callback: Callable[[IKTraceEntry], None] | None = None,
) -> IKResult:
    """Newton iteration ``q <- q + J^+ e`` on the model's own FK (the paper's section 2.4), any chain.

    ``target`` ``(n, 4, 4)``: flange pose in the base frame (``frame="flange"``), tool pose in the
    base frame (``"tool"``) or tool pose in the measurement frame (``"meas"``). ``q0`` ``(n, N)``:
    start, typically the closed-form solution of the nominal model. ``e`` stacks the position error
    [m] and the rotation vector of ``R_target R^T`` [rad]; ``J`` is :func:`joint_jacobian`. A 6-joint
    chain steps with ``(J^T J + 1e-14 I)^-1 J^T e`` (a tiny damping so near-singular wrists stay finite);
    any other joint count with the pseudo-inverse ``J^+ e`` (the minimum-norm step of a redundant chain, the
    least-squares step of a chain with fewer than six joints). Converged when both errors are below
    tolerance.
    """
    target = np.asarray(target, dtype=float)
    if target.ndim == 2:
        target = target[None]
    q = _as_q(q0, model.n_joints).copy()
    if target.shape != (q.shape[0], 4, 4):
        raise ValueError(f"target must have shape ({q.shape[0]}, 4, 4), got {target.shape}")
    if frame == "flange":
        m = model.with_frames(base2meas=np.eye(4), tool2flange=np.eye(4))
        fk_frame = "base"
    elif frame == "tool":
        m = model.with_frames(base2meas=np.eye(4))
        fk_frame = "base"
    elif frame == "meas":
        m = model
        fk_frame = "meas"
    else:
        raise ValueError(f"frame must be 'flange', 'tool' or 'meas', got {frame!r}")
    trace: list[IKTraceEntry] = []
    it = 0
    for it in range(1, max_iter + 1):
        T = tool2meas(m, q) if fk_frame == "meas" else tool2base(m, q)
        e = pose_error(target, T)
        ep = np.linalg.norm(e[:, :3], axis=1)
        er = np.linalg.norm(e[:, 3:], axis=1)
        entry = IKTraceEntry(it, float(ep.max()), float(er.max()))
        trace.append(entry)
        if callback is not None:
            callback(entry)
        done = (ep <= tol_position) & (er <= tol_rotation)
        if np.all(done):
            break
        Jq = joint_jacobian(m, q, frame=fk_frame)
        if model.n_joints == N_JOINTS:
            JT = np.swapaxes(Jq, 1, 2)
            H = JT @ Jq + 1e-14 * np.eye(N_JOINTS)
            dq = np.linalg.solve(H, np.einsum("nij,nj->ni", JT, e)[..., None])[..., 0]
        else:
            dq = np.einsum("nij,nj->ni", np.linalg.pinv(Jq, rcond=1e-10), e)
        # Trust region: at most max_step [rad] per joint and step, so a start near a singularity
        # cannot throw the iteration onto a far branch.
        big = np.abs(dq).max(axis=1, keepdims=True)
        dq = dq * np.minimum(1.0, max_step / np.maximum(big, 1e-300))
        q = q + np.where(done[:, None], 0.0, dq)
    T = tool2meas(m, q) if fk_frame == "meas" else tool2base(m, q)
    e = pose_error(target, T)
    ep = np.linalg.norm(e[:, :3], axis=1)
    er = np.linalg.norm(e[:, 3:], axis=1)
    return IKResult(
        q=q,
        converged=(ep <= tol_position * 10) & (er <= tol_rotation * 10),
        position_error=ep,
        rotation_error=er,
        iterations=it,
        trace=tuple(trace),
    )
