"""Candidate non-geometric effects of the TIAGo campaign, physically motivated (a prototype of what the
diagnosis will test on any chain; nothing here is part of ``twin``):

* ``compliance``: each joint deflects under the gravity torque it carries, ``q_eff_i = q_i + c_i tau_i(q)``
  (``c_i`` [rad/Nm]); ``tau_i`` from the URDF's masses by the recursive sum of each moving body's weight moment
  about the joint axis (``tau_i = sum_{k >= i} ((com_k - o_i) x m_k g) . a_i``), for the revolute joints whose
  torque varies over the campaign by more than ``min_range`` [Nm];
* ``tilt``: the torso column (and the mobile base on its suspension) tilts under the moment of everything the
  torso carries, ``R_tilt = exp([k_x M_x, k_y M_y, 0])`` applied at the torso joint's origin in the base frame
  (``k`` [rad/Nm], ``M`` the horizontal gravity moment of the bodies from the torso joint on about that origin).

Both are fitted jointly with the geometric parameters by Gauss-Newton on the estimator's residuals, with
analytic Jacobians: ``d p / d c_i = (d p / d offset_i) tau_i``; a tilt ``dr`` (base frame, at ``o``) moves a
point ``p`` by ``dr x (p - o)``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from twin.kinematics import link_frames
from twin.transforms import rotvec_to_matrix

G = np.array([0.0, 0.0, -9.81])


def frames_and_masses(model, q):
    """Joint frames ``(n, N, 4, 4)`` in the base frame (child frame of each joint, the end transform removed
    from the last), masses ``(N,)`` and centres of mass ``(n, N, 3)`` of what each joint moves up to the next."""
    F = link_frames(model, q)[:, 1:].copy()
    st = model.structure
    E = np.asarray(st.end_origin, dtype=float).reshape(4, 4)
    F[:, -1] = F[:, -1] @ np.linalg.inv(E)
    N = st.n_joints
    mass = np.zeros(N)
    com = np.zeros((q.shape[0], N, 3))
    for i, j in enumerate(st.joints):
        if j.inertial:
            mass[i] = j.inertial["mass"]
            com[:, i] = np.einsum("nij,j->ni", F[:, i, :3, :3], np.asarray(j.inertial["com"])) + F[:, i, :3, 3]
    return F, mass, com


def gravity_torques(model, q):
    """Gravity torque [Nm] (force [N] for a prismatic joint) each joint carries, ``(n, N)``."""
    F, mass, com = frames_and_masses(model, q)
    st = model.structure
    tau = np.zeros((q.shape[0], st.n_joints))
    for i, j in enumerate(st.joints):
        o = F[:, i, :3, 3]
        a = F[:, i, :3, :3] @ np.asarray(j.axis)
        for k in range(i, st.n_joints):
            f = mass[k] * G
            if j.kind == "revolute":
                tau[:, i] += np.einsum("ni,ni->n", np.cross(com[:, k] - o, f), a)
            else:
                tau[:, i] += a @ f
    return tau


def torso_moment(model, q, joint: int = 0):
    """Origin ``(n, 3)`` of joint ``joint`` in the base frame and the horizontal gravity moment ``(n, 2)`` [Nm]
    about it of every body from that joint on."""
    F, mass, com = frames_and_masses(model, q)
    o = F[:, joint, :3, 3]
    M = np.zeros((q.shape[0], 3))
    for k in range(joint, model.n_joints):
        M += np.cross(com[:, k] - o, mass[k] * G)
    return o, M[:, :2]


class EffectModel:
    """Geometric parameters (the estimator's space) plus effect parameters; predicts the marker points."""

    def __init__(self, prep, effects: tuple[str, ...], min_range: float = 5.0):
        self.prep = prep
        self.space = prep.space
        self.effects = effects
        model = prep.nominal
        ds = prep.dataset
        self.tau = gravity_torques(model, ds.q)
        self.origin, self.moment = torso_moment(model, ds.q)
        rev = [i for i in range(model.n_joints) if model.joint_kinds[i] == "revolute"]
        self.comp_joints = [i for i in rev if np.ptp(self.tau[:, i]) > min_range] if "compliance" in effects else []
        self.names = [f"c_{model.joint_names[i]}" for i in self.comp_joints]
        if "tilt" in effects:
            self.names += ["k_tilt_x", "k_tilt_y"]
        self.n_eff = len(self.names)

    def residuals(self, z, rows, obs):
        """Whitened residuals and Jacobian ``(m, P + n_eff)`` for dataset rows ``rows`` (observations ``obs``)."""
        from twin.estimator.problem import Residuals, absolute_residuals

        sp = self.space
        x, e = z[: sp.size], z[sp.size:]
        q = obs.q.copy()
        jidx = sp.family("joint")
        nc = len(self.comp_joints)
        for k, i in enumerate(self.comp_joints):
            q[:, i] += e[k] * self.tau[rows, i]
        r = absolute_residuals(sp, x, replace(obs, q=q))
        cols = [r.J[:, jidx[i]] * self.tau[rows[r.row], i] for i in self.comp_joints]
        if "tilt" in self.effects:
            kx, ky = e[nc], e[nc + 1]
            dr = np.c_[kx * self.moment[rows, 0], ky * self.moment[rows, 1], np.zeros(len(rows))]  # (n, 3) base frame
            B = self.prep.space.bases(x)
            Rb = np.stack([B[obs.station_names[s]][:3, :3] for s in obs.station])  # (n, 3, 3)
            tb = np.stack([B[obs.station_names[s]][:3, 3] for s in obs.station])
            # measured-frame points predicted without tilt -> base frame -> tilt about the torso origin
            pred = obs.spheres - r_to_points(r.r, obs)  # (n, K, 3) predicted (meas frame)
            p_base = np.einsum("nji,nkj->nki", Rb, pred - tb[:, None])
            o = self.origin[rows][:, None, :]
            Rt = rotvec_to_matrix(dr)
            moved = np.einsum("nij,nkj->nki", Rt, p_base - o) + o
            delta = np.einsum("nij,nkj->nki", Rb, moved - p_base)  # (n, K, 3) in meas frame
            sig = obs.sigma_position
            # residual order of absolute_residuals: (point k, coordinate c, row i), seen only
            d = np.transpose(delta, (1, 2, 0))
            mask = np.broadcast_to(obs.seen.T[:, None, :], d.shape)
            rr = r.r - d[mask] / sig
            for ax in range(2):
                mom = self.moment[rows, ax]
                lever = np.cross(np.eye(3)[ax][None, None, :], p_base - o)  # d(moved)/d(dr_ax) in base
                dm = np.einsum("nij,nkj->nki", Rb, lever) * mom[:, None, None]
                cols.append(np.transpose(dm, (1, 2, 0))[mask] / sig)
            r = Residuals(r=rr, J=r.J, row=r.row, block=r.block)
        J = np.concatenate([r.J] + [c[:, None] for c in cols], axis=1) if cols else r.J
        return Residuals(r=r.r, J=J, row=r.row, block=r.block)

    def predict(self, z, rows):
        """Predicted points ``(len(rows), K, 3)`` in the measurement frame."""
        from twin.estimator.problem import predict_points

        sp = self.space
        ds = self.prep.dataset
        x, e = z[: sp.size], z[sp.size:]
        q = ds.q[rows].copy()
        for k, i in enumerate(self.comp_joints):
            q[:, i] += e[k] * self.tau[rows, i]
        st = np.zeros(len(rows), int)
        pts, _ = predict_points(sp, x, q, st, self.prep.obs.spheres_tool)
        if "tilt" in self.effects:
            nc = len(self.comp_joints)
            dr = np.c_[e[nc] * self.moment[rows, 0], e[nc + 1] * self.moment[rows, 1], np.zeros(len(rows))]
            Bm = sp.bases(x)[self.prep.obs.station_names[0]]
            Rb, tb = Bm[:3, :3], Bm[:3, 3]
            p_base = (pts - tb) @ Rb
            o = self.origin[rows][:, None, :]
            moved = np.einsum("nij,nkj->nki", rotvec_to_matrix(dr), p_base - o) + o
            pts = moved @ Rb.T + tb
        return pts


def r_to_points(r: np.ndarray, obs) -> np.ndarray:
    """Measured minus predicted points ``(n, K, 3)`` from whitened residuals (order: point, coordinate, row)."""
    n, K = obs.spheres.shape[:2]
    out = np.zeros((K, 3, n))
    mask = np.broadcast_to(obs.seen.T[:, None, :], out.shape)
    out[mask] = r * obs.sigma_position
    return np.transpose(out, (2, 0, 1))


def fit(prep, effects: tuple[str, ...], free_geometric: np.ndarray, sigma: float):
    """Gauss-Newton over the free geometric parameters and the effect parameters on the calibration rows."""
    from twin.estimator.solvers import gauss_newton

    em = EffectModel(prep, effects)
    rows = prep.rows[prep.cal]
    obs = prep.obs_cal.with_sigma(sigma)
    z0 = np.concatenate([prep.x_nominal, np.zeros(em.n_eff)])
    free = np.concatenate([free_geometric, prep.space.size + np.arange(em.n_eff)])
    g = gauss_newton(lambda z: em.residuals(z, rows, obs), z0, free, max_iter=100)
    return em, g.x
