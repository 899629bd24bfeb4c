"""Batched forward kinematics and identification Jacobians over *many parameter vectors at once*.

The foundation (:mod:`twin.kinematics`) evaluates one :class:`~twin.kinematics.RobotModel` at a time with
4x4 matrix products. Identification evaluates the same chain hundreds of times per fit and, in the
convergence study, thousands of parameter vectors per iteration; this module evaluates the same chain
(same convention, same parameter layout, same Jacobian definition) for a batch ``(B, P)`` of parameter
vectors by updating rotation columns in place of 4x4 products (an elementary rotation about a local axis
touches two columns, a translation one vector). ``tests/test_estimator_chain.py`` checks it against
:func:`twin.kinematics.tool2meas` / :func:`twin.kinematics.pose_jacobian` (which are themselves checked
against finite differences), so the maths has one reference.

Frames: without a base the chain is evaluated in the robot *base* frame; given a ``base2meas`` per batch
entry it starts from it and gives measurement-frame poses, with the six base columns appended last (rows
of different camera stations are evaluated station by station, sharing the robot and tool parameters).

Jacobian definition (as in the foundation): rows 0-2 are the derivative of the tool origin, rows 3-5 the
spatial angular rate ``w`` (``dR R^T = [w]x``). A rotation about a local axis ``u`` of an intermediate
frame ``F`` gives ``[w x (p - o_F); w]`` with ``w = R_F u``; a translation gives ``[R_F u; 0]``; the tool
translation moves the tool origin with the flange rotation; the tool rotation vector enters through the
left Jacobian of SO(3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..kinematics import ChainStructure, Convention, ParameterLayout, RobotModel
from ..transforms import left_jacobian_so3, matrix_to_rotvec, rotvec_to_matrix

__all__ = ["Chain", "ChainEval", "cross"]


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product over the last axis (faster than ``np.cross`` on small batched arrays)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


@dataclass(frozen=True)
class ChainEval:
    """Tool poses and, optionally, their Jacobian, for a batch of parameter vectors.

    ``R`` ``(B, n, 3, 3)``, ``p`` ``(B, n, 3)`` [m]. ``J`` ``(B, P, 6, n)`` or None, *parameter-major*:
    ``J[b, j, :, i]`` is the 6-vector (tool-origin velocity [m per unit], spatial angular rate [rad per
    unit]) of pose ``i`` for parameter ``j``. (This layout keeps every column contiguous, which makes
    batched evaluation several times faster than the row-major ``(n, 6, P)`` of the foundation;
    :meth:`rows` gives that view.)
    """

    R: np.ndarray
    p: np.ndarray
    J: np.ndarray | None

    def rows(self) -> np.ndarray:
        """The Jacobian as ``(B, n, 6, P)`` (a transposed view), the foundation's row-major layout."""
        if self.J is None:
            raise ValueError("this evaluation has no Jacobian (evaluate(..., jacobian=True))")
        return np.transpose(self.J, (0, 3, 2, 1))


class Chain:
    """The kinematic chain of one robot structure, evaluated in batches.

    ``Chain(convention, beta_joints)`` is a papers' 6R chain (``"mdh"`` / ``"dh"``);
    ``Chain(structure=...)`` or :meth:`of` (a model) any chain (a DH table of any length included). Parameter vectors given to :meth:`evaluate` are
    the *robot-and-tool* part of the foundation layout: the structural parameters (for the 6R chains ``theta1..6,
    d1..6, a1..6, alpha1..6, beta_j``), then ``tool_x..tool_rz`` (``P_rt = P - 6``). Use :meth:`split_full` to
    obtain it from a full vector.
    """

    def __init__(self, convention: Convention | None = None, beta_joints: tuple[int, ...] = (), *,
                 structure: ChainStructure | None = None) -> None:
        if structure is None:
            if convention not in ("mdh", "dh"):
                raise ValueError(f"convention must be 'mdh' or 'dh' (or give structure=...), got {convention!r}")
            structure = ChainStructure.six_r(convention, tuple(int(j) for j in beta_joints))
            self.layout = ParameterLayout(structure.beta_joints)
        else:
            six_r = structure.convention in ("mdh", "dh") and structure.n_joints == 6
            self.layout = ParameterLayout(structure.beta_joints) if six_r else ParameterLayout(structure=structure)
        self.structure = structure
        self.convention = structure.convention
        self.beta_joints = tuple(structure.beta_joints)
        self.n_joints = structure.n_joints
        full = self.layout.names
        bs = self.layout.base_slice
        self.rt_names: tuple[str, ...] = full[: bs.start] + full[bs.stop:]
        self.n_rt = len(self.rt_names)
        self.n_robot = bs.start  # structural parameters
        self.tool_slice = slice(self.n_robot, self.n_robot + 6)
        ops = []
        for i, jops in enumerate(structure.ops):
            for op in jops:
                if op.kind in ("R", "P"):
                    ops.append((op.kind, 0, False, -1, -1, 1.0, np.asarray(op.const, dtype=float)))
                else:
                    ops.append((op.kind, op.axis, op.joint >= 0, op.joint, self.rt_names.index(op.param), op.sign, None))
        for op in structure.end:
            ops.append((op.kind, 0, False, -1, -1, 1.0, np.asarray(op.const, dtype=float)))
        self._ops = tuple(ops)

    @classmethod
    def of(cls, model: RobotModel) -> "Chain":
        """The chain of a model's structure."""
        if model.convention in ("mdh", "dh") and model.n_joints == 6:
            return cls(model.convention, model.beta_joints)
        return cls(structure=model.structure)

    # --- parameter vector helpers ---------------------------------------------------------------
    def split_full(self, params_full: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Full layout ``(..., P)`` -> (robot-and-tool ``(..., P-6)``, base ``(..., 6)``)."""
        p = np.asarray(params_full, dtype=float)
        bs = self.layout.base_slice
        return np.concatenate([p[..., : bs.start], p[..., bs.stop:]], axis=-1), p[..., bs]

    def join_full(self, params_rt: np.ndarray, base6: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`split_full`."""
        p = np.asarray(params_rt, dtype=float)
        b = np.broadcast_to(np.asarray(base6, dtype=float), p.shape[:-1] + (6,))
        return np.concatenate([p[..., : self.n_robot], b, p[..., self.n_robot:]], axis=-1)

    # --- evaluation ------------------------------------------------------------------------------
    def evaluate(
        self, params_rt: np.ndarray, q: np.ndarray, base6: np.ndarray | None = None, jacobian: bool = True
    ) -> ChainEval:
        """Tool poses (and Jacobian) for parameters ``(B, P_rt)`` or ``(P_rt,)`` and joints ``q`` ``(n, N)``
        [rad, m for prismatic joints] shared by the batch.

        Without ``base6`` the poses are in the robot base frame and ``J`` has ``P_rt`` columns. With
        ``base6`` ``(B, 6)`` or ``(6,)`` (``base2meas`` as translation [m] + rotation vector [rad]) they are
        in the measurement frame and ``J`` has the six base columns appended *last* (``P_rt + 6``):
        translation ``I``, rotation ``[w x (p - t_b); w]`` with ``w = J_l(r_b) e_k``.
        """
        P = np.asarray(params_rt, dtype=float)
        if P.ndim == 1:
            P = P[None]
        if P.ndim != 2 or P.shape[1] != self.n_rt:
            raise ValueError(f"params_rt must have shape (B, {self.n_rt}), got {np.shape(params_rt)}")
        q = np.asarray(q, dtype=float)
        if q.ndim != 2 or q.shape[1] != self.n_joints:
            raise ValueError(f"q must have shape (n, {self.n_joints}) [rad, m for prismatic joints], got {q.shape}")
        B, n = P.shape[0], q.shape[0]
        # Structure of arrays: every vector is (3, B, n) (or (3, B, 1) before the first joint angle).
        if base6 is None:
            eye = np.eye(3)
            c0 = np.broadcast_to(eye[:, 0, None, None], (3, B, 1))
            c1 = np.broadcast_to(eye[:, 1, None, None], (3, B, 1))
            c2 = np.broadcast_to(eye[:, 2, None, None], (3, B, 1))
            t = np.zeros((3, B, 1))
        else:
            base6 = np.asarray(base6, dtype=float)
            if base6.ndim == 1:
                base6 = base6[None]
            if base6.shape not in ((B, 6), (1, 6)):
                raise ValueError(f"base6 must have shape ({B}, 6) or (6,), got {base6.shape}")
            base6 = np.broadcast_to(base6, (B, 6))
            Rb = rotvec_to_matrix(base6[:, 3:])  # (B, 3, 3)
            c0, c1, c2 = (Rb[:, :, k].T[:, :, None] for k in range(3))
            t = base6[:, :3].T[:, :, None].copy()
        rot_cols: list[tuple[int, np.ndarray, np.ndarray]] = []
        trans_cols: list[tuple[int, np.ndarray]] = []
        for kind, axis, is_theta, joint, col, sign, const in self._ops:
            if kind == "P":
                t = t + c0 * const[0] + c1 * const[1] + c2 * const[2]
                continue
            if kind == "R":
                M = const.reshape(3, 3)
                c0, c1, c2 = (c0 * M[0, k] + c1 * M[1, k] + c2 * M[2, k] for k in range(3))
                continue
            v = P[:, col][:, None]  # (B, 1)
            if is_theta:
                v = v + q[None, :, joint] if sign > 0 else v - q[None, :, joint]  # (B, n)
            if kind == "t":
                ax = (c0, c1, c2)[axis]
                t = t + v * ax
                if jacobian:
                    trans_cols.append((col, ax))
                continue
            c, s = np.cos(v), np.sin(v)
            if axis == 0:
                c1, c2 = c * c1 + s * c2, c * c2 - s * c1
                w = c0
            elif axis == 1:
                c0, c2 = c * c0 - s * c2, s * c0 + c * c2
                w = c1
            else:
                c0, c1 = c * c0 + s * c1, c * c1 - s * c0
                w = c2
            if jacobian:
                rot_cols.append((col, w, t))
        shape = (3, B, n)
        c0, c1, c2, t = (np.broadcast_to(a, shape) for a in (c0, c1, c2, t))
        tool = P[:, self.tool_slice]
        tt = tool[:, :3].T[:, :, None]  # (3, B, 1)
        p = t + c0 * tt[0] + c1 * tt[1] + c2 * tt[2]
        R_fl = np.stack([c0, c1, c2], axis=-1)  # (3 comp, B, n, 3 col)
        R_fl = np.moveaxis(R_fl, 0, 2)  # (B, n, 3, 3)
        R_tool = rotvec_to_matrix(tool[:, 3:])  # (B, 3, 3)
        R = R_fl @ R_tool[:, None]
        p_out = np.moveaxis(p, 0, -1)
        if not jacobian:
            return ChainEval(R=R, p=p_out, J=None)
        nb = 0 if base6 is None else 6
        J = np.zeros((B, self.n_rt + nb, 6, n))
        for col, w, o in rot_cols:
            d = p - o
            J[:, col, 0] = w[1] * d[2] - w[2] * d[1]
            J[:, col, 1] = w[2] * d[0] - w[0] * d[2]
            J[:, col, 2] = w[0] * d[1] - w[1] * d[0]
            J[:, col, 3:] = w.transpose(1, 0, 2)
        for col, u in trans_cols:
            J[:, col, :3] = u.transpose(1, 0, 2)
        ts = self.tool_slice
        cols = (c0, c1, c2)
        for k in range(3):
            J[:, ts.start + k, :3] = cols[k].transpose(1, 0, 2)
        Jl = left_jacobian_so3(tool[:, 3:])  # (B, 3, 3)
        for k in range(3):
            # R_fl @ Jl[:, :, k]: rotation rate of the tool for its k-th rotation-vector entry
            w = c0 * Jl[:, 0, k][:, None] + c1 * Jl[:, 1, k][:, None] + c2 * Jl[:, 2, k][:, None]
            J[:, ts.start + 3 + k, 3:] = w.transpose(1, 0, 2)
        if base6 is not None:
            P0 = self.n_rt
            for k in range(3):
                J[:, P0 + k, k] = 1.0
            W = left_jacobian_so3(base6[:, 3:])  # (B, 3, 3)
            d = p - base6[:, :3].T[:, :, None]
            for k in range(3):
                w = W[:, :, k].T[:, :, None]  # (3, B, 1)
                J[:, P0 + 3 + k, 0] = w[1] * d[2] - w[2] * d[1]
                J[:, P0 + 3 + k, 1] = w[2] * d[0] - w[0] * d[2]
                J[:, P0 + 3 + k, 2] = w[0] * d[1] - w[1] * d[0]
                J[:, P0 + 3 + k, 3:] = w.transpose(1, 0, 2)
        return ChainEval(R=R, p=p_out, J=J)


def rotation_log(R: np.ndarray) -> np.ndarray:
    """Rotation vectors of rotation matrices ``(..., 3, 3)`` (foundation's ``matrix_to_rotvec``)."""
    return matrix_to_rotvec(R)
