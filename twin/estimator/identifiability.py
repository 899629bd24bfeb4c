"""Identifiability of kinematic parameters from the column-scaled identification Jacobian.

Given the whitened Jacobian ``J`` ``(m, P)`` of the actual measurement configurations, each column is
scaled to unit norm (``A = J D``, ``D = diag(1 / |J_k|)``), which makes the analysis independent of units.
Then:

* columns with ``|J_k| = 0`` have **no effect** on the measurements;
* an *ordered* rank-revealing Gram-Schmidt pass (a column-pivoted QR whose pivot order is a stated
  preference instead of the column norms) accepts a column when its component orthogonal to the span of
  the accepted ones exceeds ``tol`` (the sine of its angle to that span) and otherwise reports it as
  **coupled**: ``A_k = sum_j c_j A_j`` gives the null direction ``dp_k = 1/|J_k|``, ``dp_j = -c_j/|J_j|``,
  i.e. the named combination of parameters that moves no measurement. The preference order decides which
  member of a coupled set is dropped (fixed at its nominal value); ``gauge="frames"`` keeps the base and
  tool transforms whole and drops robot parameters (joint 1's pre-joint parameters, the last link's
  post-joint parameters, d2 of the parallel pair), ``gauge="structure"`` keeps the robot parameters and
  drops base/tool components (the TM-MDH paper's choice in its section 4.2);
* on the accepted columns: singular values ``s_1 >= ... >= s_L`` of ``A``, the condition number
  ``s_1 / s_L`` and the observability indices of Borm-Menq (``O1 = (s_1 ... s_L)^(1/L) / sqrt(m)``,
  ``O3 = s_L``) and Nahvi-Hollerbach (``O4 = s_L^2 / s_1``).

The analysis is meant to run at the *nominal* model (with registered bases): there the couplings are
exact (e.g. axes 2 and 3 exactly parallel), whereas at an identified model a tilt of ``1e-3`` rad would
turn an unidentifiable pair into a badly conditioned but formally identifiable one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Sequence

import numpy as np
from scipy import linalg as sla

__all__ = ["Combination", "Identifiability", "analyse_jacobian", "preference_order", "FigarohSelection",
           "figaroh_full_selection", "figaroh_joint_names"]


@dataclass(frozen=True)
class Combination:
    """A parameter that cannot be identified given the ones kept before it.

    ``kind`` ``"no_effect"`` (its column is zero) or ``"coupled"``; ``terms`` the null direction as
    ``(name, coefficient)`` pairs with the dropped parameter first at coefficient 1 (SI units: moving
    every named parameter by ``coefficient * t`` leaves every measurement unchanged to first order).
    """

    dropped: str
    kind: Literal["no_effect", "coupled"]
    terms: tuple[tuple[str, float], ...] = ()

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(n for n, _ in self.terms) if self.terms else (self.dropped,)

    def describe(self) -> str:
        """``"d2 - d3"`` style text of the null direction (or ``"d1: no effect"``)."""
        if self.kind == "no_effect":
            return f"{self.dropped}: no effect on these measurements"
        parts = []
        for k, (n, c) in enumerate(self.terms):
            mag = abs(c)
            coef = "" if abs(mag - 1.0) < 5e-4 else f"{mag:.4g} "
            sign = "-" if c < 0 else "+"
            parts.append((f"-{coef}{n}" if c < 0 else f"{coef}{n}") if k == 0 else f" {sign} {coef}{n}")
        return "null direction " + "".join(parts)


@dataclass(frozen=True, eq=False)
class Identifiability:
    """Result of :func:`analyse_jacobian`. Indices refer to ``names``."""

    names: tuple[str, ...]
    identifiable: tuple[str, ...]
    combinations: tuple[Combination, ...]
    n_equations: int
    column_norms: np.ndarray
    singular_values: np.ndarray  # of the column-scaled Jacobian of the identifiable parameters
    singular_values_all: np.ndarray  # of the column-scaled Jacobian of every parameter with an effect
    tol: float
    order: tuple[str, ...] = field(default=())

    @property
    def dropped(self) -> tuple[str, ...]:
        return tuple(c.dropped for c in self.combinations)

    @property
    def rank(self) -> int:
        return len(self.identifiable)

    @property
    def condition_number(self) -> float:
        s = self.singular_values
        return float(s[0] / s[-1]) if s.size and s[-1] > 0 else float("inf")

    @property
    def O1(self) -> float:
        """Borm-Menq O1: geometric mean of the singular values over ``sqrt(m)``."""
        s = self.singular_values
        if not s.size or s[-1] <= 0:
            return 0.0
        return float(np.exp(np.mean(np.log(s))) / np.sqrt(self.n_equations))

    @property
    def O3(self) -> float:
        """Borm-Menq O3: the smallest singular value."""
        return float(self.singular_values[-1]) if self.singular_values.size else 0.0

    @property
    def O4(self) -> float:
        """Nahvi-Hollerbach O4 (noise amplification index): ``s_min^2 / s_max``."""
        s = self.singular_values
        return float(s[-1] ** 2 / s[0]) if s.size and s[0] > 0 else 0.0

    def mask(self, names: Sequence[str] | None = None) -> np.ndarray:
        """Boolean mask over ``names`` (default: this analysis' names) of the identifiable parameters."""
        names = self.names if names is None else names
        keep = set(self.identifiable)
        return np.array([n in keep for n in names])

    def find(self, *members: str) -> Combination | None:
        """The reported combination whose terms include all ``members`` (None when there is none)."""
        for c in self.combinations:
            if set(members) <= set(c.names):
                return c
        return None

    def summary(self) -> dict:
        return {
            "rank": self.rank,
            "n_parameters": len(self.names),
            "n_equations": self.n_equations,
            "condition_number": self.condition_number,
            "O1": self.O1,
            "O3": self.O3,
            "O4": self.O4,
            "dropped": list(self.dropped),
            "combinations": [
                {"dropped": c.dropped, "kind": c.kind, "terms": [[n, v] for n, v in c.terms], "text": c.describe()}
                for c in self.combinations
            ],
        }


def preference_order(names: Sequence[str], gauge: Literal["frames", "structure"] = "frames") -> tuple[str, ...]:
    """Order in which parameters are offered to the rank-revealing pass (earlier = kept when coupled).

    ``"frames"``: base (every station) and tool first, then the robot parameters family by family (6R: theta,
    d, a, alpha, beta; a ``"urdf"`` chain's ``<joint>.<family>``: offset, x, y, z, rx, ry, rz) from the last
    joint down to joint 1, so that of a coupled set the base/tool survives, of the parallel pair d3 survives
    and d2 is dropped, and a joint offset survives against an origin rotation about the same axis.
    ``"structure"``: the robot parameters first (joint 1 up), then base and tool.
    """
    if gauge not in ("frames", "structure"):
        raise ValueError(f"gauge must be 'frames' or 'structure', got {gauge!r}")
    frames = [n for n in names if n.startswith(("base_", "tool_"))]
    robot = [n for n in names if not n.startswith(("base_", "tool_"))]
    fam_rank = {"theta": 0, "d": 1, "a": 2, "alpha": 3, "beta": 4,
                "offset": 0, "x": 1, "y": 2, "z": 3, "rx": 4, "ry": 5, "rz": 6}
    joint_order: dict[str, int] = {}
    for n in robot:
        if "." in n:
            joint_order.setdefault(n.rsplit(".", 1)[0], len(joint_order) + 1)

    def key(n: str, descending: bool):
        if "." in n:
            jn, fam = n.rsplit(".", 1)
            j = joint_order[jn]
        else:
            fam = n.rstrip("0123456789")
            j = int(n[len(fam):]) if len(fam) < len(n) else 0
        return (fam_rank.get(fam, 9), -j if descending else j)

    if gauge == "frames":
        return tuple(frames + sorted(robot, key=lambda n: key(n, True)))
    return tuple(sorted(robot, key=lambda n: key(n, False)) + frames)


def analyse_jacobian(
    J: np.ndarray,
    names: Sequence[str],
    *,
    order: Sequence[str] | None = None,
    candidates: Sequence[str] | None = None,
    tol: float = 1e-6,
    prune: float = 1e-3,
) -> Identifiability:
    """Identifiability of the parameters ``names`` (columns of the whitened Jacobian ``J`` ``(m, P)``).

    ``candidates``: the subset to analyse (default all); ``order``: preference order (default
    :func:`preference_order` with ``gauge="frames"``); ``tol``: smallest accepted sine between a column
    and the span of the columns kept before it; ``prune``: members of a combination whose scaled coefficient is
    below this fraction of the largest are left out of it (e.g. a 1e-6 tilt of a registered base adds
    negligible base_x/base_y parts to ``d1 - base_z``).
    """
    J = np.asarray(J, dtype=float)
    names = tuple(names)
    if J.ndim != 2 or J.shape[1] != len(names):
        raise ValueError(f"J must have shape (m, {len(names)}), got {J.shape}")
    if not np.all(np.isfinite(J)):
        raise ValueError("J contains non-finite values")
    cand = tuple(names) if candidates is None else tuple(candidates)
    unknown = [c for c in cand if c not in names]
    if unknown:
        raise ValueError(f"candidates: unknown names {unknown}")
    order = preference_order(cand) if order is None else tuple(n for n in order if n in cand)
    missing = [c for c in cand if c not in order]
    order = tuple(order) + tuple(missing)
    idx = {n: i for i, n in enumerate(names)}
    norms = np.linalg.norm(J, axis=0)
    big = float(norms[[idx[n] for n in cand]].max()) if cand else 0.0
    m = J.shape[0]
    P = len(order)
    Q = np.zeros((m, P))  # orthonormal basis of the kept scaled columns (first k columns used)
    Rk = np.zeros((P, P))  # A_kept = Q[:, :k] Rk[:k, :k]
    k_acc = 0
    kept: list[str] = []
    combos: list[Combination] = []
    for n in order:
        k = idx[n]
        if norms[k] <= 1e-12 * max(big, 1e-300):
            combos.append(Combination(dropped=n, kind="no_effect"))
            continue
        a = J[:, k] / norms[k]
        Qk = Q[:, :k_acc]
        c1 = Qk.T @ a
        v = a - Qk @ c1
        c2 = Qk.T @ v  # re-orthogonalisation (classical Gram-Schmidt twice is stable)
        v = v - Qk @ c2
        proj = c1 + c2
        s = float(np.linalg.norm(v))
        if s > tol:
            Q[:, k_acc] = v / s
            Rk[:k_acc, k_acc] = proj
            Rk[k_acc, k_acc] = s
            k_acc += 1
            kept.append(n)
            continue
        # a = A_kept coef  <=>  Rk coef = Q^T a
        coef = sla.solve_triangular(Rk[:k_acc, :k_acc], proj, check_finite=False) if k_acc else np.zeros(0)
        terms = [(n, 1.0)]
        big_c = max(1.0, float(np.max(np.abs(coef)))) if coef.size else 1.0
        for t in np.argsort(-np.abs(coef)):
            if abs(coef[t]) < prune * big_c:
                continue
            c = kept[t]
            terms.append((c, float(-coef[t] * norms[k] / norms[idx[c]])))
        combos.append(Combination(dropped=n, kind="coupled", terms=tuple(terms)))
    kept_set = set(kept)
    kept_sorted = tuple(n for n in cand if n in kept_set)
    sv = np.linalg.svd(Rk[:k_acc, :k_acc], compute_uv=False) if k_acc else np.zeros(0)
    eff = [idx[c] for c in cand if norms[idx[c]] > 1e-12 * max(big, 1e-300)]
    if eff:
        Rall = np.linalg.qr(J[:, eff] / norms[eff], mode="r")
        sv_all = np.linalg.svd(Rall, compute_uv=False)
    else:
        sv_all = np.zeros(0)
    return Identifiability(
        names=cand,
        identifiable=kept_sorted,
        combinations=tuple(combos),
        n_equations=m,
        column_norms=norms[[idx[c] for c in cand]],
        singular_values=sv,
        singular_values_all=sv_all,
        tol=tol,
        order=order,
    )


# ------------------------------------------------------------------------------------------------
# FIGAROH's full-parameter selection, reproduced on our parameterisation
# ------------------------------------------------------------------------------------------------

FIGAROH_TOL_QR = 1e-6  # FIGAROH's structural QR tolerance on |diag R| (absolute, unscaled regressor)
FIGAROH_TOL_EFFECT = 1e-6  # FIGAROH drops regressor columns below this norm ("no effect")
FIGAROH_TOL_ABSORBED = 1e-4  # FIGAROH's data-level tolerance on the orthogonal part of a unit column
FIGAROH_COMPONENTS = ("px", "py", "pz", "phix", "phiy", "phiz")


def figaroh_joint_names(model, joint: int) -> tuple[str, ...]:
    """Our parameter for each of FIGAROH's six placement errors of joint ``joint`` (0-based) of a ``"urdf"`` chain,
    in FIGAROH's order ``d_px, d_py, d_pz, d_phix, d_phiy, d_phiz``. FIGAROH moves a joint placement ``M`` to
    ``M SE3(exp(phi), p)`` (translation in the joint's origin frame, rotation vector on the right); ours is
    ``Trans(x, y, z) R RotX RotY RotZ`` (translation in the parent frame): its rotations are ours to first order,
    its translation ``p_k`` is our translation along ``R[:, k]`` (named by the axis it lies along, exact when the
    origin's rotation maps axes onto axes). The rotation about a revolute joint's own axis is its offset."""
    j = model.structure.joints[joint]
    R = j.origin[:3, :3]
    ax = np.abs(np.asarray(j.axis))
    k_ax = int(np.argmax(ax)) if abs(ax.max() - 1.0) < 1e-9 else -1
    out = []
    for k in range(3):
        out.append(f"{j.name}.{'xyz'[int(np.argmax(np.abs(R[:, k])))]}")
    for k in range(3):
        out.append(f"{j.name}.offset" if (j.kind == "revolute" and k == k_ax) else f"{j.name}.r{'xyz'[k]}")
    return tuple(out)


@dataclass(frozen=True)
class FigarohSelection:
    """FIGAROH's full-parameter set on our parameterisation: ``structural`` (the base parameters of its QR on random
    configurations, in chain order, as FIGAROH names them), ``as_base_frame`` (the first six of them, which FIGAROH
    replaces by the base frame), ``absorbed`` (dropped on the data: within ``FIGAROH_TOL_ABSORBED`` of the frames
    and the parameters before them), ``kept`` (our names of what is estimated, frames included)."""

    structural: tuple[str, ...]
    as_base_frame: tuple[str, ...]
    absorbed: tuple[str, ...]
    kept: tuple[str, ...]


def figaroh_full_selection(model, J_data: np.ndarray, names: Sequence[str], frames: Sequence[str], *,
                           n_samples: int, orientation: bool, seed: int = 0) -> FigarohSelection:
    """FIGAROH's (1.0.2) choice of the parameters of its ``full_params`` level, step by step, on our
    parameterisation of a ``"urdf"`` chain (``model``: its nominal model):

    1. the structural regressor: the end link's position (and orientation when the measurements see it,
       ``orientation``) w.r.t. the six placement errors of every joint (:func:`figaroh_joint_names`), at
       ``n_samples`` configurations drawn uniformly within the joint limits (``[-pi, pi]`` for a revolute joint
       whose range exceeds a turn; ``np.random.default_rng(seed)``), base and tool known, unscaled (m and rad);
    2. columns of norm below ``FIGAROH_TOL_EFFECT`` dropped; LAPACK's column-pivoted QR
       (``scipy.linalg.qr(pivoting=True)``), rank = the pivots with ``|R_kk| > FIGAROH_TOL_QR``, the base
       parameters taken in column (chain) order;
    3. the *first six* of them replaced by the base frame (FIGAROH's ``add_base_name``: "the leading base
       parameters carry the base frame"), so they are not estimated as joint errors;
    4. on the data, ``J_data`` ``(m, len(names))`` at the start (nominal robot, registered base): columns scaled to
       unit norm, the frames (``frames``, always kept) first, then the joint parameters in that order; a column is
       dropped when its part orthogonal to those kept before is below ``FIGAROH_TOL_ABSORBED``
       (``select_identifiable_parameters``).

    Steps 1-2 give the set of a generic design (any random draw); step 3 drops six directions the base frame does
    not all absorb, and step 4 the directions these configurations barely excite: together FIGAROH's implicit
    regularisation by truncation."""
    from scipy import linalg as sla

    from ..kinematics import pose_jacobian

    if model.convention != "urdf":
        raise ValueError(f"figaroh selection: model {model.name!r} is not a 'urdf' chain")
    names = list(names)
    rng = np.random.default_rng(seed)
    lo = np.asarray(model.q_min, float).copy()
    hi = np.asarray(model.q_max, float).copy()
    wide = (~model.is_prismatic) & (hi - lo > 2 * np.pi)
    lo[wide], hi[wide] = -np.pi, np.pi
    q = rng.uniform(lo, hi, (int(n_samples), model.n_joints))
    m0 = model.with_frames(np.eye(4), np.eye(4))
    Jp = pose_jacobian(m0, q, frame="base")  # (n, 6, P)
    rows = Jp if orientation else Jp[:, :3]
    W = np.transpose(rows, (1, 0, 2)).reshape(-1, Jp.shape[2])  # component-major, as FIGAROH stacks them
    lay = m0.layout
    cols, fnames, ours = [], [], []
    for i, j in enumerate(model.structure.joints):
        R = j.origin[:3, :3]
        txyz = W[:, [lay.index(f"{j.name}.{c}") for c in "xyz"]] @ R  # FIGAROH's translation in the origin frame
        mapped = figaroh_joint_names(model, i)
        for k in range(3):
            cols.append(txyz[:, k])
        for k in range(3):
            cols.append(W[:, lay.index(mapped[3 + k])])
        fnames += [f"d_{c}_{j.name}" for c in FIGAROH_COMPONENTS]
        ours += list(mapped)
    A = np.stack(cols, axis=1)
    effect = np.linalg.norm(A, axis=0) >= FIGAROH_TOL_EFFECT
    A, fnames, ours = A[:, effect], [n for n, e in zip(fnames, effect) if e], [n for n, e in zip(ours, effect) if e]
    _, Rq, piv = sla.qr(A, pivoting=True, mode="economic")
    rank = int(np.sum(np.abs(np.diag(Rq)) > FIGAROH_TOL_QR))
    base = sorted(piv[:rank].tolist())
    structural = [fnames[b] for b in base]
    as_base = structural[:6]
    joint_ours = [ours[b] for b in base[6:]]
    # step 4: the data's unit columns, frames first
    pos = {n: k for k, n in enumerate(names)}
    order = [n for n in frames] + [n for n in joint_ours if n in pos]
    basis = np.zeros((J_data.shape[0], 0))
    kept, absorbed = [], []
    for n in order:
        col = J_data[:, pos[n]]
        nrm = float(np.linalg.norm(col))
        res = 0.0
        if nrm > 0:
            r = col / nrm
            for _ in range(2):
                r = r - basis @ (basis.T @ r)
            res = float(np.linalg.norm(r))
        if n in frames or res > FIGAROH_TOL_ABSORBED:
            kept.append(n)
            if res > FIGAROH_TOL_ABSORBED:
                basis = np.column_stack([basis, r / res])
        else:
            absorbed.append(n)
    fig_of = {o: f for o, f in zip([ours[b] for b in base], structural)}
    return FigarohSelection(tuple(structural), tuple(as_base), tuple(fig_of.get(n, n) for n in absorbed),
                            tuple(kept))
