"""The noise floor: a correctly specified reference fit on the same calibration rows.

The floor of a cell is the validation error of the best fit one can hope for on that cell's data: the model
that generated the data (MDH + beta2 + base + tool, 37 parameters), every identifiable direction of it free,
fitted by plain weighted Gauss-Newton **started from the truth**. It uses the truth (as a start point and for
the model structure), so it lives here, in the benchmark, and never in ``twin/estimator``.

Math. Rows of pose ``i``: ``e_i = W [p_meas - p(x); log(R_meas R(x)^T)]`` with ``W = diag(1/s_p I3, 1/s_r I3)``
(position-only fits keep the first three rows). With ``J = twin.kinematics.pose_jacobian`` the linearisation is
``e(x + dx) ~ e(x) - W J dx``. Columns are scaled to unit norm (``J_s = W J D``) and the step is the truncated
SVD solution ``dx = D V_k S_k^-1 U_k^T e`` keeping singular values ``s > rtol * s_max``: the dropped directions
are the exactly unidentifiable combinations (d2/d3, joint 1 vs base, joint 6 vs tool, ... see
``docs/conventions.md``), which are held at the truth and do not change any predicted pose. ``rtol`` is far
below the smallest *identifiable* singular value (checked by ``tests/test_peers_floor.py``), so no weakly
identifiable direction is pinned to the truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from twin.kinematics import RobotModel, pose_error, pose_jacobian, tool2meas

__all__ = ["FloorFit", "floor_fit", "identifiable_spectrum"]


@dataclass(frozen=True, eq=False)
class FloorFit:
    """The fitted model, the number of directions kept, and the weighted residual RMS per iteration."""

    model: RobotModel
    rank: int
    n_params: int
    residual_rms: tuple[float, ...]


def _weighted_system(model: RobotModel, q, T_meas, s_p, s_r, use_orientation):
    e = pose_error(T_meas, tool2meas(model, q))  # (n, 6)
    J = pose_jacobian(model, q)  # (n, 6, P)
    w = np.array([1 / s_p] * 3 + [1 / s_r] * 3)
    rows = slice(0, 6) if use_orientation else slice(0, 3)
    e = (e * w)[:, rows].reshape(-1)
    J = (J * w[None, :, None])[:, rows, :].reshape(-1, J.shape[-1])
    return e, J


def identifiable_spectrum(model: RobotModel, q, use_orientation: bool = True) -> np.ndarray:
    """Singular values of the column-normalised pose Jacobian at ``q``, relative to the largest, descending."""
    _, J = _weighted_system(model, q, tool2meas(model, q), 1.0, 1.0, use_orientation)
    norms = np.linalg.norm(J, axis=0)
    Js = J[:, norms > 0] / norms[norms > 0]
    s = np.linalg.svd(Js, compute_uv=False)
    return s / s[0]


def floor_fit(
    truth: RobotModel,
    q: np.ndarray,
    tool2meas_measured: np.ndarray,
    position_sigma: float,
    orientation_sigma: float,
    *,
    use_orientation: bool = True,
    iterations: int = 4,
    rtol: float = 1e-8,
) -> FloorFit:
    """Weighted Gauss-Newton from the truth on all identifiable directions (see the module docstring).

    ``q`` ``(n, 6)`` [rad], ``tool2meas_measured`` ``(n, 4, 4)`` [m]; ``position_sigma`` [m] and
    ``orientation_sigma`` [rad] are the 1-sigma noise of the measurements (the weights).
    """
    q = np.asarray(q, dtype=float)
    T = np.asarray(tool2meas_measured, dtype=float)
    if q.ndim != 2 or q.shape[1] != 6 or T.shape != (q.shape[0], 4, 4):
        raise ValueError(f"q must be (n, 6) and tool2meas_measured (n, 4, 4); got {q.shape} and {T.shape}")
    if not (position_sigma > 0 and orientation_sigma > 0):
        raise ValueError(f"sigmas must be positive, got {position_sigma}, {orientation_sigma}")
    model = truth
    rms = []
    rank = 0
    for _ in range(iterations):
        e, J = _weighted_system(model, q, T, position_sigma, orientation_sigma, use_orientation)
        rms.append(float(np.sqrt(np.mean(e**2))))
        norms = np.linalg.norm(J, axis=0)
        live = norms > 0
        Js = J[:, live] / norms[live]
        U, s, Vt = np.linalg.svd(Js, full_matrices=False)
        keep = s > rtol * s[0]
        rank = int(keep.sum())
        dx_s = Vt[keep].T @ ((U[:, keep].T @ e) / s[keep])
        dx = np.zeros(J.shape[1])
        dx[live] = dx_s / norms[live]
        model = model.with_params(model.params + dx)
    e, _ = _weighted_system(model, q, T, position_sigma, orientation_sigma, use_orientation)
    rms.append(float(np.sqrt(np.mean(e**2))))
    return FloorFit(model=model, rank=rank, n_params=truth.layout.size, residual_rms=tuple(rms))
