"""The geometric model extended by effect candidates: residuals, Jacobians and the joint fit.

An extended parameter vector is ``z = (x, psi_1, ..., psi_m)``: the estimator's geometric vector ``x``
(:class:`twin.estimator.problem.ParamSpace`) and, per chosen candidate ``c``, reduced coordinates ``psi_c``
with ``phi_c = B_c psi_c`` (``B_c`` ``(K_c, r_c)`` a basis of the directions of the candidate that the data
can tell apart from the geometry and from noise; see :func:`reduced_basis`).

Prediction with effects (commanded joints ``q``, all rows in measurement order for history):

* joint effects: ``q_eff = q + sum_c G_c(q, ctx) phi_c`` (exact: the chain is evaluated at ``q_eff``);
* length effects: link lengths ``L_j -> L_j (1 + s(ctx) phi)``, applied to first order through the length
  columns of the Jacobian (the growth is ~1e-5 relative: the second-order term is below 1e-9 m);
* plate effects: sphere ``s`` sits at ``spheres_tool[s] + phi[3 s: 3 s + 3]`` in the tool frame (exact).

Jacobian of an effect column: ``sum_i J[:, theta_i] G[row, i, k]`` (a joint offset moves the chain as a
theta offset does), ``sum_j J[:, L_j] L_j s[row, k]``, and ``R_tool2meas`` for plate offsets.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..estimator.problem import Observations, ParamSpace, Residuals, absolute_residuals, predict_points
from .candidates import Candidate, RowContext

__all__ = ["EffectTerm", "ExtendedModel", "reduced_basis"]


@dataclass(frozen=True, eq=False)
class EffectTerm:
    """A candidate with its reference constants, its regressor on the fit rows and its reduced basis.

    ``G`` is ``(n, 6, K)`` (joint), ``(n, K)`` (length) or None (plate), on the rows of the observations
    the model is built for; ``basis`` ``(K, r)``.
    """

    candidate: Candidate
    reference: dict
    G: np.ndarray | None
    basis: np.ndarray

    @property
    def name(self) -> str:
        return self.candidate.name

    @property
    def kind(self) -> str:
        return self.candidate.kind

    @property
    def K(self) -> int:
        return self.basis.shape[0]

    @property
    def r(self) -> int:
        return self.basis.shape[1]


def term_regressor(candidate: Candidate, ref: dict, ctx: RowContext, rows: np.ndarray) -> np.ndarray | None:
    """The candidate's regressor on all rows of ``ctx`` (history), restricted to ``rows``."""
    if candidate.kind == "plate":
        return None
    G = candidate.regressor(ctx, ref)
    return G[rows]


class ExtendedModel:
    """Residuals of the geometric model plus effect terms on one set of observations.

    ``space``/``obs``: the estimator's parameter space and (whitened-by-sigma) observations; ``terms``:
    effect terms whose ``G`` rows match ``obs`` rows.
    """

    def __init__(self, space: ParamSpace, obs: Observations, terms: list[EffectTerm]):
        self.space = space
        self.obs = obs
        self.terms = list(terms)
        self.theta_idx = space.family("theta")
        self.len_idx = np.concatenate([space.family("d"), space.family("a")])
        sizes = [t.r for t in self.terms]
        self.offsets = np.concatenate([[space.size], space.size + np.cumsum(sizes)]).astype(int)
        self.size = int(self.offsets[-1])

    def split(self, z: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
        """Geometric vector and full effect parameters ``phi_c = B_c psi_c`` of every term."""
        x = z[: self.space.size]
        phis = [t.basis @ z[self.offsets[k]:self.offsets[k + 1]] for k, t in enumerate(self.terms)]
        return x, phis

    def effective_obs(self, phis: list[np.ndarray]) -> Observations:
        q = self.obs.q.copy()
        sph = self.obs.spheres_tool.copy()
        for t, phi in zip(self.terms, phis):
            if t.kind == "joint":
                q = q + np.einsum("nik,k->ni", t.G, phi)
            elif t.kind == "plate":
                sph = sph + phi.reshape(3, 3)
        return replace(self.obs, q=q, spheres_tool=sph)

    def residuals(self, z: np.ndarray, jacobian: bool = True) -> Residuals:
        """Whitened residuals and the Jacobian ``(m, size)`` of the prediction over ``z``."""
        x, phis = self.split(z)
        obs = self.effective_obs(phis)
        need_J = jacobian or any(t.kind == "length" for t in self.terms)
        res = absolute_residuals(self.space, x, obs, jacobian=need_J)
        r = res.r
        J = res.J
        cols = []
        for t, phi in zip(self.terms, phis):
            if t.kind == "length":
                L = x[self.len_idx]
                JL = J[:, self.len_idx] * L  # (m, nL): column j per unit relative growth of L_j
                E = JL.sum(axis=1)[:, None] * t.G[res.row]  # (m, K): all lengths grow together
                r = r - E @ phi
            elif not jacobian:
                continue
            elif t.kind == "joint":
                # d pred / d phi_k = sum_i J[:, theta_i] G[row, i, k]
                E = np.einsum("mi,mik->mk", J[:, self.theta_idx], t.G[res.row])
            else:
                E = self._plate_columns(x, obs, res)
            cols.append(E @ t.basis)
        if not jacobian:
            return Residuals(r=r, J=None, row=res.row, block=res.block)
        Jz = np.concatenate([J] + cols, axis=1) if cols else J
        return Residuals(r=r, J=Jz, row=res.row, block=res.block)

    def _plate_columns(self, x: np.ndarray, obs: Observations, res: Residuals) -> np.ndarray:
        if obs.kind != "spheres":
            raise ValueError("plate_geometry needs sphere observations")
        pts = np.concatenate([np.zeros((1, 3)), np.eye(3)])
        P, _ = predict_points(self.space, x, obs.q, obs.station, pts)
        R = np.swapaxes(P[:, 1:] - P[:, :1], 1, 2)  # (n, 3, 3): columns are the tool axes
        # residual order of absolute_residuals: (sphere k, coordinate c, row i), masked by seen
        shape = (3, 3, obs.n)
        mask = np.broadcast_to(obs.seen.T[:, None, :], shape)
        sph = np.broadcast_to(np.arange(3)[:, None, None], shape)[mask]
        crd = np.broadcast_to(np.arange(3)[None, :, None], shape)[mask]
        E = np.zeros((res.r.size, 9))
        for s in range(3):
            sel = sph == s
            # d(pred_c of sphere s) / d(offset_j of sphere s) = R[row, c, j]
            E[sel, 3 * s:3 * s + 3] = R[res.row[sel], crd[sel], :]
        return E / obs.sigma_position


def reduced_basis(E: np.ndarray, A: np.ndarray, *, rel_tol: float = 1e-6, max_rank: int = 40) -> np.ndarray:
    """Basis ``(K, r)`` of the candidate directions the data can see beyond the geometry.

    ``E`` ``(m, K)``: whitened effect columns; ``A`` ``(m, p)``: whitened columns of the free geometric
    parameters. Columns are scaled to unit norm, the part in the span of ``A`` is projected out (what the
    geometry absorbs is not evidence of the effect), and the right singular vectors of the remainder with
    singular values above ``rel_tol`` of the largest are kept (at most ``max_rank``).
    """
    nrm = np.linalg.norm(E, axis=0)
    keep = nrm > 1e-12 * max(float(nrm.max(initial=0.0)), 1e-300)
    if not np.any(keep):
        return np.zeros((E.shape[1], 0))
    D = np.where(keep, 1.0 / np.where(keep, nrm, 1.0), 0.0)
    Es = E * D
    Q, _ = np.linalg.qr(A)
    Ep = Es - Q @ (Q.T @ Es)
    _, s, Vt = np.linalg.svd(Ep, full_matrices=False)
    if s.size == 0 or s[0] <= 1e-12:
        return np.zeros((E.shape[1], 0))
    r = int(min(np.sum(s > rel_tol * s[0]), max_rank))
    return D[:, None] * Vt[:r].T
