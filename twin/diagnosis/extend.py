"""The geometric model extended by atoms: residuals, Jacobians, reduced bases.

An extended parameter vector is ``z = (x, psi_1, ..., psi_m)``: the estimator's geometric vector ``x``
(:class:`twin.estimator.problem.ParamSpace`) and, per chosen atom ``a``, reduced coordinates ``psi_a`` with
``phi_a = B_a psi_a`` (``B_a`` ``(K_a, r_a)``: the directions of the atom the data tell apart from the
geometry; :func:`reduced_basis`). With the atom's features ``F_a`` ``(n, K_a)`` on the rows:

* ``joint`` atoms: ``q_eff = q + F_a phi_a`` on the target joint, evaluated exactly through the chain;
* ``length`` atoms: ``L -> L (1 + F_a phi_a)`` (one link, or every ``d``/``a``), to first order through the
  length columns of the Jacobian (relative changes ~1e-5: the second-order term is below 1e-9 m);
* ``param`` atoms: ``x_p -> x_p + F_a phi_a`` for one parameter, or the six of the tool / the row's base
  frame (six columns per feature), to first order;
* ``plate`` atoms: sphere ``s`` at ``spheres_tool[s] + phi`` in the tool frame (exact), or at
  ``spheres_tool[s] + F_a phi_a`` (``phi`` ``(K_f, 3)``; first order) when the offset varies with features;
* ``scale`` atoms: measured points ``p -> p (1 + F_a phi_a)`` about the measurement origin (first order);
* ``field`` atoms: measured points ``p -> p + sum_k phi_k G_k(p)`` (:mod:`twin.diagnosis.field`, first order).

Whitened residual ``r = (measured - predicted) / sigma``; the column of an atom feature is the derivative
of the prediction, e.g. ``J[:, theta_j] F[row, k]`` or ``J[:, L] L F[row, k]``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..estimator.memo import KeptResults, array_key
from ..estimator.problem import Observations, ParamSpace, Residuals, absolute_residuals, predict_points
from ..transforms import kabsch, left_jacobian_so3, matrix_to_rotvec, rotvec_to_matrix
from ..units import M_PER_MM, RAD_PER_DEG
from .atoms import Atom, tilt_axis, tilt_coefficient
from .field import field_values, plate_normals, station_mask


__all__ = ["AtomTerm", "ExtendedModel", "reduced_basis", "param_weights", "joint_index", "end_length", "length_indices",
           "tilt_weights", "error_stats"]


@dataclass(frozen=True, eq=False)
class AtomTerm:
    """An atom with its features ``F`` ``(n, K_f)`` on the model's rows and its reduced basis ``(K, r)``."""

    atom: Atom
    F: np.ndarray
    basis: np.ndarray

    @property
    def K(self) -> int:
        return self.basis.shape[0]

    @property
    def r(self) -> int:
        return self.basis.shape[1]


def joint_index(space: ParamSpace, target: str) -> tuple[int, float]:
    """The parameter a joint atom's target (``"theta<j>"``, 1-based) moves, and the sign with which the
    commanded joint enters it (a joint atom adds to the commanded joint)."""
    st = space.chain.structure
    if st.convention != "urdf":
        return space.index(target), 1.0
    j = int(target[5:])
    return space.index(st.joint_params[j - 1]), float(st.joint_signs[j - 1])


def end_length(structure) -> np.ndarray:
    """``(3,)`` [m]: the translation of a ``"urdf"`` chain's constant end transform (last joint -> flange) in the
    flange's frame, ``R_end^T e_end`` (zero without one): what the flange moves per unit of relative growth of it."""
    if structure.convention != "urdf" or structure.end_origin is None:
        return np.zeros(3)
    E = np.reshape(np.asarray(structure.end_origin, float), (4, 4))
    return E[:3, :3].T @ E[:3, 3]


def length_indices(space: ParamSpace, target: str) -> np.ndarray:
    """Indices of the lengths a length atom's target grows: ``"all_lengths"`` (every ``d``/``a``; every origin
    translation of a ``"urdf"`` chain), one length (``"a2"``) or one joint's origin translation
    (``"<joint>.xyz"``, its three components together)."""
    if target == "all_lengths":
        fams = ("d", "a") if space.chain.structure.convention != "urdf" else ("x", "y", "z")
        return np.concatenate([space.family(f) for f in fams])
    if target.endswith(".xyz"):
        j = target[: -len(".xyz")]
        return np.array([space.index(f"{j}.{c}") for c in "xyz"])
    return np.array([space.index(target)])


def tilt_weights(space: ParamSpace, x: np.ndarray, target: str) -> np.ndarray:
    """``(P, 2)``: the parameter directions of a rotation about the x and y axes of a tilt's pivot frame (target
    ``"tilt<i>"``): for a joint ``i >= 1`` of a ``"urdf"`` chain its origin rotations ``rx``, ``ry`` (rotations about
    the axes of its origin frame, through its origin); for ``i = 0`` a rotation of the robot's base about its own
    x and y axes through its origin, i.e. of every station's ``base2meas`` on the right: ``R exp([d]) = R(r + dr)``
    with ``dr = J_r(r)^-1 d`` (``J_r(r) = J_l(r)^T``, :func:`twin.transforms.left_jacobian_so3`)."""
    i = int(target[4:])
    w = np.zeros((space.size, 2))
    if i == 0:
        for k in range(len(space.stations)):
            sl = space.base_slice(k)
            Jr_inv = np.linalg.inv(left_jacobian_so3(x[sl.start + 3:sl.stop]).T)
            w[sl.start + 3:sl.stop, :] = Jr_inv[:, :2]
        return w
    name = space.chain.structure.joint_names[i - 1]
    w[space.index(f"{name}.rx"), 0] = 1.0
    w[space.index(f"{name}.ry"), 1] = 1.0
    return w


def param_weights(space: ParamSpace, x: np.ndarray, atom: Atom) -> np.ndarray:
    """``(P, c)``: the parameter-space direction(s) an atom's place moves per unit of one feature
    (``c = 6`` for the tool/base frames, ``c = 2`` for a tilt (one per feature, :func:`tilt_weights`), else 1)."""
    P = space.size
    t = atom.target
    if atom.place == "joint":
        w = np.zeros((P, 1))
        idx, sign = joint_index(space, t)
        w[idx, 0] = sign
        return w
    if atom.place == "length":
        w = np.zeros((P, 1))
        idx = length_indices(space, t)
        w[idx, 0] = x[idx]
        if t == "all_lengths":
            # the chain's fixed end (a "urdf" chain's flange offset from its last joint) grows with the links: the
            # flange moves by delta R_end^T e_end in its own frame, where the tool's translation is read
            w[space.family("tool")[:3], 0] = end_length(space.chain.structure)
        return w
    if atom.place == "param" and t.startswith("tilt"):
        return tilt_weights(space, x, t)
    if atom.place == "param":
        if t == "tool":
            w = np.zeros((P, 6))
            w[space.family("tool"), np.arange(6)] = 1.0
            return w
        if t == "base":
            w = np.zeros((P, 6))
            for k in range(len(space.stations)):
                sl = space.base_slice(k)
                w[np.arange(sl.start, sl.stop), np.arange(6)] = 1.0
            return w
        if t == "base_along":
            # a displacement e_a in the robot base frame moves the measured points by R_base2meas e_a: the
            # translation of each station's base2meas along the columns of its rotation (one column per axis)
            w = np.zeros((P, 3))
            for k in range(len(space.stations)):
                sl = space.base_slice(k)
                w[sl.start:sl.start + 3, :] = rotvec_to_matrix(x[sl.start + 3:sl.stop])
            return w
        w = np.zeros((P, 1))
        w[space.index(t), 0] = 1.0
        return w
    raise ValueError(f"atom place {atom.place!r} has no parameter direction")


def _times_weights(J: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``J[:, :P] @ w`` ``(m, c)`` for weights ``w`` ``(P, c)``; when each column of ``w`` has one nonzero entry (a
    joint, a parameter, one axis of a frame) that column of ``J`` times it: the same numbers without a pass over
    ``J``, laid out as the product's (C order; ``+ 0.0`` makes a zero ``+0`` as the product's sum does), since the
    layout and the sign of a zero steer the later factorizations' rounding."""
    nz = w != 0
    if np.all(nz.sum(axis=0) == 1):
        idx = np.argmax(nz, axis=0)
        out = np.multiply(J[:, idx], w[idx, np.arange(w.shape[1])], order="C")
        out += 0.0
        return out
    return J[:, : w.shape[0]] @ w


# the latest residual evaluations ExtendedModel.residuals keeps: a fit's residuals are asked for again at once (its
# scoring basis, its tests, its gross rows); by (id(model), z), each held for its model (weakly)
RESIDUALS_KEPT = 16
RESIDUALS_KEPT_BYTES = 1 << 26  # and at most this many bytes of them (but the latest), on a campaign of many rows
_KEPT = KeptResults(RESIDUALS_KEPT, RESIDUALS_KEPT_BYTES)


class ExtendedModel:
    """Residuals of the geometric model plus atom terms on one set of observations."""

    def __init__(self, space: ParamSpace, obs: Observations, terms: list[AtomTerm],
                 axis_sigma: np.ndarray | None = None):
        self.space = space
        self.obs = obs
        self.terms = list(terms)
        # per-axis noise of the measurement frame: residual c is whitened by axis_sigma[c] instead of the
        # observations' scalar sigma (a stereo instrument is worse in depth)
        K = obs.spheres.shape[1]
        shape = (K, 3, obs.n)
        mask = np.broadcast_to(obs.seen.T[:, None, :], shape)
        self._crd = np.broadcast_to(np.arange(3)[None, :, None], shape)[mask]
        self._sph = np.broadcast_to(np.arange(K)[:, None, None], shape)[mask]
        self._elem_row = np.broadcast_to(np.arange(obs.n)[None, None, :], shape)[mask]
        self._field_cache: dict[str, np.ndarray] = {}
        self._f = (np.ones(self._crd.size) if axis_sigma is None
                   else (obs.sigma_position / np.asarray(axis_sigma, dtype=float))[self._crd])
        self._f_one = bool(np.all(self._f == 1.0))  # an isotropic floor: whitening by the axes changes nothing
        sizes = [t.r for t in self.terms]
        self.offsets = np.concatenate([[space.size], space.size + np.cumsum(sizes)]).astype(int)
        self.size = int(self.offsets[-1])

    def split(self, z: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
        """Geometric vector and full atom parameters ``phi_a = B_a psi_a``."""
        x = z[: self.space.size]
        phis = [t.basis @ z[self.offsets[k]:self.offsets[k + 1]] for k, t in enumerate(self.terms)]
        return x, phis

    def effective_obs(self, phis: list[np.ndarray]) -> Observations:
        q = self.obs.q.copy()
        sph = self.obs.spheres_tool.copy()
        for t, phi in zip(self.terms, phis):
            if t.atom.place == "joint":
                j = int(t.atom.target[5:]) - 1
                q[:, j] += t.F @ phi
            elif t.atom.place == "plate" and not t.atom.varying_plate:
                sph[int(t.atom.target[6:])] += phi
        return replace(self.obs, q=q, spheres_tool=sph)

    def product_base(self, atom: Atom, x: np.ndarray, obs: Observations, res: Residuals) -> np.ndarray | None:
        """The whitened model columns ``(m, c)`` an atom's features multiply, when its columns are products
        ``E[m, k c + j] = F[row(m), k] base[m, j]`` (joint, length, parameter, frame, plate and scale atoms); None
        for the others (a displacement along the last move, a field)."""
        a = atom
        if a.place in ("joint", "length", "param"):
            if a.target == "base_along" or a.target.startswith("tilt"):
                return None
            return _times_weights(res.J, param_weights(self.space, x, a))  # (m, c)
        if a.place == "plate":
            return self._plate_columns(x, obs, res, int(a.target[6:])) * self._f[:, None]  # (m, 3)
        if a.place == "scale":
            return (self._coords(obs) * self._f)[:, None]
        if a.place == "field":
            return None
        raise ValueError(f"unknown atom place {a.place!r}")

    def columns(self, t: AtomTerm, x: np.ndarray, obs: Observations, res: Residuals) -> np.ndarray:
        """Whitened raw columns ``(m, K)`` of one term at the current point."""
        a = t.atom
        Fr = t.F[res.row]  # (m, K_f)
        if a.place == "param" and a.target == "base_along":
            base = res.J[:, : self.space.size] @ param_weights(self.space, x, a)  # (m, 3)
            return np.sum(Fr * base, axis=1, keepdims=True)  # along the row's direction, one coefficient
        if a.place == "param" and a.target.startswith("tilt"):
            # one rotation axis of the pivot per feature (the moment about that axis, its ``axis``): a diagonal
            # compliance; several features may turn about one axis (shapes of an unknown moment)
            base = res.J[:, : self.space.size] @ param_weights(self.space, x, a)  # (m, 2)
            cols = Fr * base[:, [tilt_axis(f, k) for k, f in enumerate(a.features)]]
            if not any(getattr(f, "shape", None) is not None for f in a.features):
                return cols
            # a shape of the moment turns the pivot about both axes with one coefficient
            out = np.zeros((len(res.r), a.K))
            for k, f in enumerate(a.features):
                out[:, tilt_coefficient(f, k)] += cols[:, k]
            return out
        if a.place == "field":
            return Fr * (self._field(a, obs) * self._f[:, None])
        base = self.product_base(a, x, obs, res)
        if a.place == "plate" and not a.varying_plate:
            return base
        return (Fr[:, :, None] * base[:, None, :]).reshape(len(res.r), -1)

    def field_grid(self, a: Atom) -> np.ndarray:
        """``G_k`` ``(n, points, K, 3)`` of a field atom at every row's measured points (zero where a point was not
        seen; the view fields take each row's plate normal from its measured points)."""
        key = repr(a.features)
        G = self._field_cache.get(key)
        if G is None:
            obs = self.obs
            K = obs.spheres.shape[1]
            pts = np.where(obs.seen[..., None], obs.spheres, np.array([0.0, 0.0, 1.0]))  # (n, K, 3)
            n_tool = next((f.n_tool for f in a.features if getattr(f, "n_tool", None) is not None), None)
            nrm = None if n_tool is None else np.repeat(
                plate_normals(obs.spheres, obs.seen, obs.spheres_tool, n_tool), K, axis=0)
            G = field_values(a.features, pts.reshape(-1, 3), nrm).reshape(obs.n, K, len(a.features), 3)
            G = np.where(obs.seen[:, :, None, None], G, 0.0)
            G = G * station_mask(a.features, np.asarray(obs.station_names)[obs.station])[:, None, :, None]
            self._field_cache[key] = G
        return G

    def _field(self, a: Atom, obs: Observations) -> np.ndarray:
        """``G_k`` at each residual's measured point, its coordinate, divided by sigma ``(m, K)``."""
        G = self.field_grid(a)
        return G[self._elem_row, self._sph, :, self._crd] / obs.sigma_position

    def scale_column(self, obs: Observations) -> np.ndarray:
        """Whitened column ``(m,)`` of the measurement scale: the measured coordinates in residual order over the
        noise of their axis (the derivative of a scale ``p -> p (1 + s)``)."""
        return self._coords(obs) * self._f

    def _coords(self, obs: Observations) -> np.ndarray:
        """Measured coordinates in residual order, divided by sigma (the derivative of a scale)."""
        v = np.transpose(obs.spheres, (1, 2, 0))
        mask = np.broadcast_to(obs.seen.T[:, None, :], v.shape)
        return v[mask] / obs.sigma_position

    def residuals(self, z: np.ndarray, jacobian: bool = True) -> Residuals:
        """Whitened residuals and the Jacobian ``(m, size)`` of the prediction over ``z``. The latest
        ``RESIDUALS_KEPT`` evaluations are kept (read-only arrays) and given again for the same model and the same
        ``z`` to the bit (the residuals without the Jacobian are those of an evaluation with it)."""
        key = (id(self), array_key(z))
        res = _KEPT.get(key, owner=self)
        if res is not None and (res.J is not None or not jacobian):
            return res if jacobian or res.J is None else Residuals(r=res.r, J=None, row=res.row, block=res.block)
        res = self._evaluate(z, jacobian)
        arrays = [a for a in (res.r, res.J, res.row, res.block) if a is not None]
        for a in arrays:
            a.flags.writeable = False
        return _KEPT.put(key, res, owner=self, nbytes=sum(a.nbytes for a in arrays))

    def _evaluate(self, z: np.ndarray, jacobian: bool) -> Residuals:
        """:meth:`residuals` computed."""
        x, phis = self.split(z)
        obs = self.effective_obs(phis)
        first_order = [t.atom.first_order for t in self.terms]
        need_J = jacobian or any(first_order)
        res = absolute_residuals(self.space, x, obs, jacobian=need_J)
        if not self._f_one:
            res = Residuals(r=res.r * self._f, J=None if res.J is None else res.J * self._f[:, None], row=res.row,
                            block=res.block)
        r = res.r
        cols = []
        for t, phi, fo in zip(self.terms, phis, first_order):
            if fo or jacobian:
                E = self.columns(t, x, obs, res)
                if fo:
                    r = r - E @ phi
                if jacobian:
                    cols.append(E @ t.basis)
        if not jacobian:
            return Residuals(r=r, J=None, row=res.row, block=res.block)
        Jz = np.concatenate([res.J] + cols, axis=1) if cols else res.J
        return Residuals(r=r, J=Jz, row=res.row, block=res.block)

    def unwhiten(self, r: np.ndarray) -> np.ndarray:
        """Whitened residuals back to metres (per residual, in ``absolute_residuals`` order)."""
        return r * self.obs.sigma_position / self._f

    def _plate_columns(self, x: np.ndarray, obs: Observations, res: Residuals, sphere: int) -> np.ndarray:
        if obs.kind != "spheres":
            raise ValueError("plate_geometry needs sphere observations")
        pts = np.concatenate([np.zeros((1, 3)), np.eye(3)])
        P, _ = predict_points(self.space, x, obs.q, obs.station, pts)
        R = np.swapaxes(P[:, 1:] - P[:, :1], 1, 2)  # (n, 3, 3): columns are the tool axes
        K = obs.spheres.shape[1]
        shape = (K, 3, obs.n)
        mask = np.broadcast_to(obs.seen.T[:, None, :], shape)
        sph = np.broadcast_to(np.arange(K)[:, None, None], shape)[mask]
        crd = np.broadcast_to(np.arange(3)[None, :, None], shape)[mask]
        E = np.zeros((res.r.size, 3))
        sel = sph == sphere
        # d(pred_c of sphere s) / d(offset_j of sphere s) = R[row, c, j]
        E[sel] = R[res.row[sel], crd[sel], :]
        return E / obs.sigma_position


def reduced_basis(E: np.ndarray, A: np.ndarray | None = None, *, rel_tol: float = 1e-2, max_rank: int = 6,
                  Q: np.ndarray | None = None) -> np.ndarray:
    """Basis ``(K, r)`` of the atom directions the data can see beyond the geometry.

    ``E`` ``(m, K)``: whitened atom columns; ``A`` ``(m, p)``: whitened columns of the free parameters already
    in the model (or ``Q``, an orthonormal basis of them). Columns are scaled to unit norm, the part in the
    span of ``A`` is projected out (what the geometry absorbs is not evidence of the effect), and the right
    singular vectors of the remainder with singular values above ``rel_tol`` of the largest are kept (at
    most ``max_rank``). A direction of which less than 1 % survives the projection only adds variance to
    the predictions.
    """
    nrm = np.linalg.norm(E, axis=0)
    keep = nrm > 1e-12 * max(float(nrm.max(initial=0.0)), 1e-300)
    if not np.any(keep):
        return np.zeros((E.shape[1], 0))
    D = np.where(keep, 1.0 / np.where(keep, nrm, 1.0), 0.0)
    Es = E * D
    if Q is None:
        Q, _ = np.linalg.qr(A)
    Ep = Es - Q @ (Q.T @ Es)
    _, s, Vt = np.linalg.svd(Ep, full_matrices=False)
    if s.size == 0:
        return np.zeros((E.shape[1], 0))
    # singular values are fractions of unit columns: keep what survives above rel_tol of a unit column
    r = int(min(np.sum(s > rel_tol * max(s[0], 1.0)), max_rank))
    return D[:, None] * Vt[:r].T


def _unmask(r: np.ndarray, model: ExtendedModel) -> np.ndarray:
    """Whitened point residuals back to ``(n, K, 3)`` [m] (order of ``absolute_residuals``)."""
    obs = model.obs
    shape = (obs.spheres.shape[1], 3, obs.n)
    mask = np.broadcast_to(obs.seen.T[:, None, :], shape)
    tmp = np.zeros(shape)
    tmp[mask] = model.unwhiten(r)
    return np.transpose(tmp, (2, 0, 1))


def _stats(e: np.ndarray) -> dict[str, float]:
    return {"mean": float(np.mean(e)), "rms": float(np.sqrt(np.mean(e**2))), "max": float(np.max(e))}


def error_stats(model: ExtendedModel, z: np.ndarray, keep: np.ndarray | None = None) -> dict[str, Any]:
    """Error statistics of ``model`` at ``z`` on its rows: 3-D point error [mm], and the marker set's (plate's)
    orientation error [deg] between rigid fits of it to the measured and to the predicted points (rows with all
    of them, at least three); ``keep`` ``(n,)``: the rows counted (gross rows left out)."""
    _, phis = model.split(z)
    obs = model.effective_obs(phis)
    res = model.residuals(z, jacobian=False)
    diff = _unmask(res.r, model)  # measured - predicted (n, K, 3) [m], zero where not seen
    rows = np.ones(obs.n, bool) if keep is None else keep
    seen = obs.seen & rows[:, None]
    e3 = np.linalg.norm(diff, axis=-1)[seen]
    out: dict[str, Any] = {"n_rows": int(rows.sum()), "position_mm": _stats(e3 / M_PER_MM)}
    full = seen.all(axis=1)
    if full.any() and obs.spheres.shape[1] >= 3:
        meas = obs.spheres[full]
        pred = meas - diff[full]
        A = np.broadcast_to(model.obs.spheres_tool, meas.shape)
        Rm, _ = kabsch(A, meas)
        Rp, _ = kabsch(A, pred)
        ang = np.linalg.norm(matrix_to_rotvec(Rm @ np.swapaxes(Rp, 1, 2)), axis=-1)
        out["orientation_deg"] = _stats(ang / RAD_PER_DEG)
    return out
