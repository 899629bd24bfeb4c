"""The TM-MDH paper's Levenberg-Marquardt (its section 3.2.1) and cross-identification C-LM (3.2.2),
batched over many start values at once (the convergence study runs 3969 starts per method).

LM, as the paper states it::

    d_rho_k = (J^T J + mu_k I)^-1 J^T dP(rho_k)          (unscaled normal equations, SI units)
    mu_0 = 0.001;  mu_{k+1} = mu_k / lam if |dP(rho_{k+1})| < |dP(rho_k)| else mu_k * lam   (lam = 10)
    rho_{k+1} = rho_k + d_rho_k                             (the paper's Step 3 updates unconditionally)

``accept="always"`` follows Step 3 literally; ``accept="improve"`` is the usual LM that rejects a step
that raises the cost (kept for comparison). Each run stops when its largest parameter step falls below
``tol_step`` or after ``max_iter`` iterations.

C-LM repeats two LM stages: (1) the orientation residual only, over the angle parameters (theta, alpha,
beta, the base and tool rotations); (2) the full residual over every parameter, from the stage-1 result.
The cycle stops after ``n_cycles`` (the paper iterates 20 times), or earlier for a run whose ``stop``
predicate holds (e.g. it reproduces the data) or whose parameters a whole cycle no longer changes.

Residual providers evaluate a batch ``X`` ``(B, P)`` and return residuals ``r`` ``(B, m)`` and the
Jacobian of the prediction ``Jt`` ``(B, P, m)`` (parameter-major, so ``J^T J`` is one batched product).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Literal, Protocol

import numpy as np

from ..transforms import matrix_to_rotvec
from .problem import Observations, ParamSpace, absolute_residuals

__all__ = [
    "BatchProblem",
    "PoseBatch",
    "PerRunPoseBatch",
    "GenericBatch",
    "LMSettings",
    "LMTrace",
    "LMResult",
    "levenberg_marquardt",
    "cross_identification",
]


class BatchProblem(Protocol):
    size: int

    def __call__(
        self, X: np.ndarray, part: Literal["full", "orientation", "position"], jacobian: bool = True
    ) -> tuple[np.ndarray, np.ndarray | None]: ...


class PoseBatch:
    """Single-station 6-DOF pose observations, evaluated for a whole batch of parameter vectors at once
    through the batched chain. Residuals are whitened by the observations' sigmas (pass sigmas of 1 for the
    paper's unweighted SI residuals)."""

    def __init__(self, space: ParamSpace, obs: Observations) -> None:
        if obs.kind != "pose" or len(space.stations) != 1:
            raise ValueError("PoseBatch needs one station of pose observations; use GenericBatch otherwise")
        self.space = space
        self.obs = obs
        self.size = space.size

    def __call__(self, X, part="full", jacobian=True):
        sp, o = self.space, self.obs
        X = np.atleast_2d(X)
        B = X.shape[0]
        ev = sp.chain.evaluate(X[:, : sp.n_rt], o.q, base6=X[:, sp.n_rt:], jacobian=jacobian)
        sp_, so = o.sigma_position, o.sigma_orientation
        rs = []
        if part in ("full", "position"):
            rs.append(((o.pose_p[None] - ev.p) / sp_).transpose(0, 2, 1).reshape(B, -1))
        if part in ("full", "orientation"):
            e = matrix_to_rotvec(o.pose_R[None] @ np.swapaxes(ev.R, -1, -2)) / so
            rs.append(e.transpose(0, 2, 1).reshape(B, -1))
        r = np.concatenate(rs, axis=1) if len(rs) > 1 else rs[0]
        if not jacobian:
            return r, None
        J = ev.J  # (B, P, 6, n), freshly allocated: scaled in place
        if part == "full":
            if sp_ == so:
                if sp_ != 1.0:
                    J *= 1.0 / sp_
            else:
                J[:, :, :3] *= 1.0 / sp_
                J[:, :, 3:] *= 1.0 / so
            # component-major rows (px, py, pz, wx, wy, wz): a view, no copy
            return r, J.reshape(B, sp.size, -1)
        blk = J[:, :, :3] if part == "position" else J[:, :, 3:]
        s = sp_ if part == "position" else so
        return r, (blk * (1.0 / s)).reshape(B, sp.size, -1)


class PerRunPoseBatch:
    """Single-station 6-DOF poses at the same joints ``q`` ``(n, 6)`` but measured *per run*: run ``k`` of a
    batch fits its own poses ``pose_p[k]`` ``(n, 3)`` [m], ``pose_R[k]`` ``(n, 3, 3)`` (e.g. one simulated
    robot per start of a convergence map). The solvers drop finished runs from the batch, so a run is
    identified by an extra last column of ``X`` holding its index into ``pose_p``: build starts with
    :meth:`starts` and keep that column out of ``free`` (:meth:`free`). Residuals are divided by
    ``sigma_position`` [m] and ``sigma_orientation`` [rad] (1 and 1: the paper's unweighted SI).

    ``rotation_residual``: ``"log"`` (ours: the rotation vector of ``R_meas R^T``, exact at any size) or
    ``"first_order"`` (the TM-MDH paper's differential rotation read off ``dT T^-1``: the axial vector of the
    antisymmetric part of ``R_meas R^T``, i.e. ``sin(angle) * axis``, which equals the rotation vector to first
    order and shrinks again beyond pi/2). The Jacobian is the same small-error one in both cases."""

    def __init__(self, space: ParamSpace, q: np.ndarray, pose_p: np.ndarray, pose_R: np.ndarray,
                 sigma_position: float = 1.0, sigma_orientation: float = 1.0,
                 rotation_residual: Literal["log", "first_order"] = "log") -> None:
        if rotation_residual not in ("log", "first_order"):
            raise ValueError(f"rotation_residual must be 'log' or 'first_order', got {rotation_residual!r}")
        self.rotation_residual = rotation_residual
        pose_p, pose_R = np.asarray(pose_p, float), np.asarray(pose_R, float)
        q = np.asarray(q, float)
        if pose_p.ndim != 3 or pose_p.shape[1:] != (q.shape[0], 3):
            raise ValueError(f"pose_p must be (runs, {q.shape[0]}, 3), got {pose_p.shape}")
        if pose_R.shape != pose_p.shape + (3,):
            raise ValueError(f"pose_R must be {pose_p.shape + (3,)}, got {pose_R.shape}")
        if len(space.stations) != 1:
            raise ValueError("PerRunPoseBatch needs a parameter space with one station")
        self.space, self.q, self.pose_p, self.pose_R = space, q, pose_p, pose_R
        self.sigma_position, self.sigma_orientation = float(sigma_position), float(sigma_orientation)
        self.size = space.size + 1

    def starts(self, X0: np.ndarray) -> np.ndarray:
        """Start values ``(runs, P)`` -> ``(runs, P + 1)`` with the run index appended."""
        X0 = np.atleast_2d(np.asarray(X0, float))
        if X0.shape != (self.pose_p.shape[0], self.space.size):
            raise ValueError(f"X0 must be ({self.pose_p.shape[0]}, {self.space.size}), got {X0.shape}")
        return np.c_[X0, np.arange(X0.shape[0], dtype=float)]

    def free(self, free: np.ndarray) -> np.ndarray:
        """A ``(P,)`` free mask -> ``(P + 1,)`` with the run-index column held."""
        return np.r_[np.asarray(free, dtype=bool), False]

    def evaluate(self, X: np.ndarray, jacobian: bool):
        sp = self.space
        X = np.atleast_2d(X)
        k = X[:, -1].astype(int)
        ev = sp.chain.evaluate(X[:, : sp.n_rt], self.q, base6=X[:, sp.n_rt: sp.size], jacobian=jacobian)
        return ev, self.pose_p[k], self.pose_R[k]

    def position_rms(self, X: np.ndarray) -> np.ndarray:
        """RMS position residual [m] of each run against its own measured poses."""
        ev, p, _ = self.evaluate(X, False)
        return np.sqrt(np.mean(np.sum((ev.p - p) ** 2, axis=-1), axis=1))

    def __call__(self, X, part="full", jacobian=True):
        X = np.atleast_2d(X)
        B, sp_, so = X.shape[0], self.sigma_position, self.sigma_orientation
        ev, p, R = self.evaluate(X, jacobian)
        rs = []
        if part in ("full", "position"):
            rs.append(((p - ev.p) / sp_).transpose(0, 2, 1).reshape(B, -1))
        if part in ("full", "orientation"):
            A = R @ np.swapaxes(ev.R, -1, -2)
            if self.rotation_residual == "log":
                e = matrix_to_rotvec(A)
            else:
                e = 0.5 * np.stack([A[..., 2, 1] - A[..., 1, 2], A[..., 0, 2] - A[..., 2, 0],
                                    A[..., 1, 0] - A[..., 0, 1]], axis=-1)
            rs.append((e / so).transpose(0, 2, 1).reshape(B, -1))
        r = np.concatenate(rs, axis=1) if len(rs) > 1 else rs[0]
        if not jacobian:
            return r, None
        J = ev.J  # (B, P, 6, n)
        if part == "full":
            J[:, :, :3] *= 1.0 / sp_
            J[:, :, 3:] *= 1.0 / so
            J = J.reshape(B, self.space.size, -1)
        else:
            J = J[:, :, :3] if part == "position" else J[:, :, 3:]
            J = (J * (1.0 / (sp_ if part == "position" else so))).reshape(B, self.space.size, -1)
        return r, np.concatenate([J, np.zeros((B, 1, J.shape[-1]))], axis=1)


class GenericBatch:
    """Any observations (spheres or poses, any number of stations), one run at a time."""

    def __init__(self, space: ParamSpace, obs: Observations) -> None:
        self.space = space
        self.obs = obs
        self.size = space.size

    def __call__(self, X, part="full", jacobian=True):
        X = np.atleast_2d(X)
        rs, Js = [], []
        for x in X:
            res = absolute_residuals(self.space, x, self.obs, jacobian=jacobian, part=part)
            rs.append(res.r)
            if jacobian:
                Js.append(res.J.T)
        return np.stack(rs), (np.stack(Js) if jacobian else None)


@dataclass(frozen=True)
class LMSettings:
    """``mu0`` initial damping, ``lam`` its factor, ``max_iter`` cap, ``tol_step`` [SI] stop on the largest
    parameter change, ``accept`` ``"always"`` (the paper's Step 3) or ``"improve"``. ``damping``:
    ``"cumulative"`` (ours: ``mu_{k+1} = mu_k / lam`` when the cost falls, ``mu_k * lam`` otherwise) or
    ``"paper"`` (the TM-MDH paper's section 3.2 as it reads: ``mu_{k+1} = mu0 / lam`` when
    ``|dP(rho_{k+1})| < |dP(rho_k)|``, else ``mu0 * lam``, with ``2.5 <= lam <= 10``: bounded, never
    accumulated)."""

    mu0: float = 1e-3
    lam: float = 10.0
    max_iter: int = 100
    tol_step: float = 1e-12
    accept: Literal["always", "improve"] = "always"
    damping: Literal["cumulative", "paper"] = "cumulative"

    def __post_init__(self) -> None:
        if self.damping not in ("cumulative", "paper"):
            raise ValueError(f"damping must be 'cumulative' or 'paper', got {self.damping!r}")
        if self.damping == "paper" and not 2.5 <= self.lam <= 10.0:
            raise ValueError(f"lam must lie in [2.5, 10] for the paper's damping, got {self.lam!r}")


@dataclass(frozen=True)
class LMTrace:
    """Per iteration of a batch: stage name, iteration, number of active runs, median cost of the batch."""

    stage: str
    iteration: int
    active: int
    median_cost: float


@dataclass(frozen=True)
class LMResult:
    """``X`` ``(B, P)``, ``cost`` ``(B,)`` (sum of squared residuals of the last stage), ``iterations``
    ``(B,)`` (total LM iterations), ``cycles`` ``(B,)`` (C-LM only, else 0), ``stopped_early`` ``(B,)``
    and the trace."""

    X: np.ndarray
    cost: np.ndarray
    iterations: np.ndarray
    cycles: np.ndarray
    stopped_early: np.ndarray
    trace: tuple[LMTrace, ...]


def levenberg_marquardt(
    problem: BatchProblem,
    X0: np.ndarray,
    free: np.ndarray,
    *,
    part: Literal["full", "orientation", "position"] = "full",
    settings: LMSettings = LMSettings(),
    stage: str = "lm",
    callback: Callable[[LMTrace], None] | None = None,
) -> LMResult:
    """The paper's LM for a batch of start values ``X0`` ``(B, P)`` over the parameters ``free`` (bool ``(P,)``)."""
    X = np.array(np.atleast_2d(X0), dtype=float)
    B, P = X.shape
    fidx = np.flatnonzero(np.asarray(free, dtype=bool))
    all_free = fidx.size == P
    its = np.zeros(B, dtype=int)
    cost = np.zeros(B)
    stopped = np.zeros(B, dtype=bool)
    trace: list[LMTrace] = []
    eye = np.eye(fidx.size)
    # compact state of the active runs only (finished runs are written back and dropped)
    act = np.arange(B)
    Xa = X.copy()
    ra, Ja = problem(Xa, part, True)
    ca = np.einsum("bm,bm->b", ra, ra)
    cost[:] = ca
    mua = np.full(B, settings.mu0)
    for it in range(1, settings.max_iter + 1):
        if act.size == 0:
            break
        Jf = Ja if all_free else Ja[:, fidx, :]  # (A, F, m)
        H = Jf @ np.swapaxes(Jf, 1, 2)
        g = np.einsum("afm,am->af", Jf, ra)
        Hd = H + mua[:, None, None] * eye
        try:
            d = np.linalg.solve(Hd, g[..., None])[..., 0]
        except np.linalg.LinAlgError:
            d = np.stack([np.linalg.lstsq(Hd[k], g[k], rcond=None)[0] for k in range(act.size)])
        d = np.where(np.isfinite(d), d, 0.0)
        Xn = Xa.copy()
        Xn[:, fidx] += d
        rn, Jn = problem(Xn, part, True)
        cn = np.einsum("bm,bm->b", rn, rn)
        better = cn < ca
        if settings.damping == "paper":
            mua = np.where(better, settings.mu0 / settings.lam, settings.mu0 * settings.lam)
        else:
            mua = np.clip(np.where(better, mua / settings.lam, mua * settings.lam), 1e-300, 1e16)
        if settings.accept == "always":
            Xa, ra, Ja, ca = Xn, rn, Jn, cn
        else:
            Xa = np.where(better[:, None], Xn, Xa)
            ra = np.where(better[:, None], rn, ra)
            Ja = np.where(better[:, None, None], Jn, Ja)
            ca = np.where(better, cn, ca)
        its[act] += 1
        step = np.max(np.abs(d), axis=1)
        done = (step < settings.tol_step) | ~np.isfinite(cn)
        X[act] = Xa
        cost[act] = ca
        e = LMTrace(stage, it, int(act.size), float(np.median(ca)))
        trace.append(e)
        if callback:
            callback(e)
        if np.any(done):
            stopped[act[done]] = True
            keep = ~done
            act, Xa, ra, Ja, ca, mua = act[keep], Xa[keep], ra[keep], Ja[keep], ca[keep], mua[keep]
    return LMResult(X=X, cost=cost, iterations=its, cycles=np.zeros(B, int), stopped_early=stopped, trace=tuple(trace))


def cross_identification(
    problem_orientation: BatchProblem,
    problem_full: BatchProblem,
    X0: np.ndarray,
    free: np.ndarray,
    angle: np.ndarray,
    *,
    n_cycles: int = 20,
    settings_orientation: LMSettings = LMSettings(max_iter=10),
    settings_full: LMSettings = LMSettings(max_iter=10),
    stop: Callable[[np.ndarray], np.ndarray] | None = None,
    tol_cycle: float = 1e-13,
    callback: Callable[[LMTrace], None] | None = None,
) -> LMResult:
    """C-LM (the TM-MDH paper's section 3.2.2) for a batch of start values ``X0`` ``(B, P)``.

    Stage 1: LM on ``problem_orientation(X, "orientation")`` over ``free & angle``; stage 2: LM on
    ``problem_full(X, "full")`` over ``free``; repeated ``n_cycles`` times. A run leaves the loop when
    ``stop(X) -> (B,) bool`` holds, when a cycle moves none of its parameters by more than ``tol_cycle``, or
    when a cycle does not lower its full-residual cost (it is stuck: further cycles repeat the same moves).
    """
    X = np.array(np.atleast_2d(X0), dtype=float)
    B = X.shape[0]
    free = np.asarray(free, dtype=bool)
    ang = free & np.asarray(angle, dtype=bool)
    active = np.ones(B, dtype=bool)
    its = np.zeros(B, dtype=int)
    cyc = np.zeros(B, dtype=int)
    cost = np.full(B, np.nan)
    prev_cost = np.full(B, np.inf)
    trace: list[LMTrace] = []
    for c in range(1, n_cycles + 1):
        a = np.flatnonzero(active)
        if a.size == 0:
            break
        X_prev = X[a].copy()
        r1 = levenberg_marquardt(problem_orientation, X[a], ang, part="orientation", settings=settings_orientation,
                                 stage=f"clm{c}-orientation", callback=callback)
        r2 = levenberg_marquardt(problem_full, r1.X, free, part="full", settings=settings_full,
                                 stage=f"clm{c}-full", callback=callback)
        X[a] = r2.X
        cost[a] = r2.cost
        its[a] += r1.iterations + r2.iterations
        cyc[a] = c
        trace += list(r1.trace) + list(r2.trace)
        moved = np.max(np.abs(r2.X - X_prev), axis=1)
        done = moved < tol_cycle
        if c > 1:
            done |= r2.cost >= prev_cost[a] * (1.0 - 1e-9)  # a whole cycle without progress: stuck
        prev_cost[a] = r2.cost
        if stop is not None:
            done |= np.asarray(stop(X[a]), dtype=bool)
        active[a[done]] = False
    return LMResult(X=X, cost=cost, iterations=its, cycles=cyc, stopped_early=~active, trace=tuple(trace))
