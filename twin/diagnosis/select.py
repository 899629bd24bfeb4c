"""Sparse selection of atoms: the structure test, gross rows, scoring, ordering, held-out confirmation,
the backward pass and the alternatives (the procedure is in :mod:`twin.diagnosis.diagnose`).

Everything works on whitened residuals of :class:`~twin.diagnosis.extend.ExtendedModel` (per-axis noise of
the measurement frame, :class:`~twin.diagnosis.floor.NoiseFloor`).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, field
from dataclasses import replace as replace_atom

import numpy as np

from ..estimator import distributions as dists
from ..estimator.core import Prepared
from ..estimator.solvers import gauss_newton
from ..runtime import thread_map
from .atoms import Atom, feature_values
from .candidates import RowContext
from .configurations import RIVAL_MARGIN, Z_MIN as CONFIGURATION_Z
from .configurations import FoldConfirmation, block_widths, configuration_folds, fold_confirmation, joints_read
from .extend import AtomTerm, ExtendedModel, reduced_basis
from .features import Const, Feature, Gated, Pow, Step
from .floor import NoiseFloor

__all__ = [
    "StructureTest", "CATALOGUE_MARGIN", "Fit", "Problem", "Scored", "ScoringBasis", "structure_test", "row_rms",
    "gross_rows", "chi2_logsf", "raw_columns", "scoring_basis", "score_atoms", "order_candidates", "confirm",
    "smooth_confirm", "confirm_configurations", "neighbour_predictions", "time_only", "Confirmation", "row_blocks",
    "covariance", "update_gross",
    "refit_with", "psi_init", "backward", "alternatives",
    "prefer_play", "refine", "widen", "polish_in_fit", "NEIGHBOURS", "JOINT_WEIGHTS", "joint_weights",
]

CATALOGUE_MARGIN = 10.0  # [natural log of p] an unnamed term is preferred to a named one only beyond this
CATALOGUE_SHARE = 0.05  # ... or beyond this share of the named term's evidence when both act at the same place
# (or the named term's columns lie within the unnamed one's)


@dataclass(frozen=True)
class StructureTest:
    """``T`` (quadratic form of the validation residuals), its ``m`` degrees of freedom, ``p_value``, and the
    RMS of the whitened residuals (1 for noise alone)."""

    statistic: float
    dof: int
    p_value: float
    whitened_rms: float
    distribution: str



def structure_test(r: np.ndarray, Jv: np.ndarray, Jc: np.ndarray, floor: NoiseFloor) -> StructureTest:
    """``T = r^T (I + Jv C Jv^T)^-1 r`` with ``C = (Jc^T Jc)^-1`` (whitened units)."""
    m = r.size
    H = Jc.T @ Jc
    # Woodbury with C = H^-1: (I + Jv C Jv^T)^-1 = I - Jv (H + Jv^T Jv)^-1 Jv^T
    M = H + Jv.T @ Jv
    y = Jv.T @ r
    T = float(r @ r - y @ np.linalg.lstsq(M, y, rcond=None)[0]) if M.size else float(r @ r)
    if np.isinf(floor.dof):
        p = float(dists.chi2_sf(T, m))
        dist = f"chi2({m})"
    else:
        p = float(dists.f_sf(T / m, m, floor.dof))
        dist = f"F({m}, {int(floor.dof)})"
    return StructureTest(T, m, p, float(np.sqrt(np.mean(r**2))), dist)


def fit_block_test(r: np.ndarray, n_free: int, floor: NoiseFloor) -> StructureTest:
    """The whitened residual ``r`` of a fit on the rows that fit it (gross rows left out) against the floor:
    ``T = r^T r`` with ``m - p`` degrees of freedom (``p = n_free`` parameters), ``chi2(m - p)`` with a stated
    floor, ``(T / (m - p)) ~ F(m - p, nu)`` with an estimated one. A structure inside the block that fits (a change
    in its middle) shows here even where the held-out block after it holds only one state of it."""
    m = max(r.size - int(n_free), 1)
    T = float(r @ r)
    if np.isinf(floor.dof):
        p, dist = float(dists.chi2_sf(T, m)), f"chi2({m})"
    else:
        p, dist = float(dists.f_sf(T / m, m, floor.dof)), f"F({m}, {int(floor.dof)})"
    return StructureTest(T, m, p, float(np.sqrt(np.mean(r**2))) if r.size else 0.0, dist)


def row_rms(r: np.ndarray, row: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    ss = np.bincount(row, weights=r**2, minlength=n)
    cnt = np.bincount(row, minlength=n)
    return np.sqrt(ss / np.maximum(cnt, 1)), cnt


def gross_rows(r: np.ndarray, row: np.ndarray, n: int, *, max_fraction: float = 0.02) -> np.ndarray:
    """Rows ``(n,)`` bool whose whitened misfit is beyond both the floor's ``1e-6/n`` quantile and
    ``median + 8 MAD`` of the rows; none when more than ``max(2, max_fraction n)`` rows are (that is
    structure, not a few gross rows)."""
    e, cnt = row_rms(r, row, n)
    has = cnt > 0
    if has.sum() < 5:
        return np.zeros(n, dtype=bool)
    k = np.maximum(cnt, 1)
    thr_floor = np.sqrt(dists.chi2_isf(1e-6 / max(n, 1), k) / k)
    med = float(np.median(e[has]))
    mad = 1.4826 * float(np.median(np.abs(e[has] - med)))
    bad = has & (e > thr_floor) & (e > med + 8 * max(mad, 0.05 * med))
    if bad.sum() > max(2, int(max_fraction * has.sum())):
        return np.zeros(n, dtype=bool)
    return bad



@dataclass
class Fit:
    """A fitted extended model: the chosen atoms ``[(Atom, basis)]``, the extended vector ``z``, its free
    entries, the weighted calibration ``chi2``, and the model on the calibration and the confirmation rows."""

    chosen: list  # [(Atom, basis)]
    z: np.ndarray
    free: np.ndarray
    chi2: float
    model_cal: ExtendedModel
    model_val: ExtendedModel
    cache: dict = field(default_factory=dict, repr=False, compare=False)


# a fit has converged when a step changes the weighted chi2 by less than this share: far below what any test reads (a
# term's evidence is a Delta chi2 of order 1 and more on a chi2 of the rows' count)
FIT_FTOL = 1e-10


THREADS_MIN_ROWS = 2000  # calibration rows from which independent places are scored on threads


class Problem:
    """Everything the selection rounds share: observations, rows, features, weights.

    Three blocks of rows: ``cal`` (the model is fitted on them), ``val`` (the *confirmation* rows: the
    structure test and the held-out checks that choose the terms) and ``rep`` (the *report* rows: before/after
    are measured on them and nothing else; ``None`` when there are too few held-out rows for a separate block,
    then the report is on the confirmation rows). ``cal``, ``val``, ``rep`` index ``prep.obs``."""

    def __init__(self, prep: Prepared, floor: NoiseFloor, ctx: RowContext, free_geo: np.ndarray, *,
                 val: np.ndarray | None = None, rep: np.ndarray | None = None, threads: int = 1):
        self.prep = prep
        val = prep.val if val is None else np.asarray(val, int)
        self.val_idx = val
        self.rep_idx = None if rep is None else np.asarray(rep, int)
        self.obs_cal = prep.obs_cal.with_sigma(floor.sigma)
        # threads the scoring of independent places uses (twin.runtime.thread_map): below THREADS_MIN_ROWS
        # calibration rows a place's array work is too short to gain from them
        self.threads = threads if self.obs_cal.n >= THREADS_MIN_ROWS else 1
        self.threads_asked = threads  # what the caller allowed (a problem on more rows may use it)
        self.obs_val = prep.obs.subset(val).with_sigma(floor.sigma)
        self.rows_cal = prep.rows[prep.cal]
        self.rows_val = prep.rows[val]
        self.obs_rep = None if rep is None else prep.obs.subset(self.rep_idx).with_sigma(floor.sigma)
        self.rows_rep = None if rep is None else prep.rows[self.rep_idx]
        self.ctx = ctx
        self.free_geo = free_geo
        self.floor = floor
        self._F: dict[str, np.ndarray] = {}
        self._Fc: dict[str, np.ndarray] = {}
        self._Fu: dict[str, tuple | None] = {}
        self._newest_basis: weakref.ref | None = None  # the scoring basis that keeps its per-place quantities
        self._orders: dict = {}
        self._store: _ColumnStore | None = None
        self._keys: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
        self._cache: dict = {}
        self.w_cal = np.ones(self.obs_cal.n)
        self.keep_val = np.ones(self.obs_val.n, dtype=bool)
        # the evidence of a term is its Delta chi2 over this: 1 when the floor is the scatter a correct model leaves;
        # the geometric fit's residual variance per degree of freedom when the floor is only a lower bound of it
        # (a motion-capture system's marker noise, below the robot's own pose-to-pose scatter)
        self.evidence_scale = 1.0
        # the confirmation rows are sessions the calibration rows do not contain (set by the diagnosis)
        self.cross_session = False

    def _key(self, atom: Atom) -> str:
        key = self._keys.get(atom)
        if key is None:
            key = self._keys[atom] = repr(atom.features)
        return key

    def features(self, atom: Atom) -> np.ndarray:
        """Feature values ``(n_dataset_rows, K)`` of an atom on every row of the dataset (cached)."""
        key = self._key(atom)
        F = self._F.get(key)
        if F is None:
            F = feature_values(atom.features, self.ctx, self.prep.nominal, self._cache)
            self._F[key] = F
        return F

    def features_cal(self, atom: Atom) -> np.ndarray:
        """Feature values ``(n_cal, K)`` of an atom on the calibration rows (cached; the values on every row are
        kept only when :meth:`features` asks for them: most atoms are only ever scored on the calibration rows)."""
        key = self._key(atom)
        F = self._Fc.get(key)
        if F is None:
            F_all = self._F.get(key)
            if F_all is None:
                F_all = feature_values(atom.features, self.ctx, self.prep.nominal, self._cache)
            F = self._Fc[key] = F_all[self.rows_cal]
        return F

    def inner_features_cal(self, inner: tuple) -> np.ndarray:
        """Values ``(n_cal, K)`` of the features inside gated features (:func:`_gate`) on the calibration rows
        (cached)."""
        key = ("inner", repr(inner))
        got = self._orders.get(key)
        if got is None:
            got = self._orders[key] = feature_values(inner, self.ctx, self.prep.nominal, self._cache)[self.rows_cal]
        return got

    def channel_order_cal(self, ch: str) -> tuple[np.ndarray, np.ndarray]:
        """The calibration rows in the order of a channel's values (stable) and the sorted values (cached)."""
        key = ("order", ch)
        got = self._orders.get(key)
        if got is None:
            from .atoms import _ch

            v = np.asarray(_ch(self.ctx, None, ch), dtype=float)[self.rows_cal]
            order = np.argsort(v, kind="stable")
            got = self._orders[key] = (order, v[order])
        return got

    def column_store(self, atoms: list[Atom]) -> "_ColumnStore | None":
        """The store of the feature sets the screening multiplies most (:class:`_ColumnStore`), built from the
        first large call (the whole pool) and kept; None until then."""
        if self._store is None and len(atoms) >= _ColumnStore.MIN_ATOMS:
            self._store = _ColumnStore(self, atoms)
        return self._store

    def distinct_rows_cal(self, atom: Atom) -> tuple[np.ndarray, object] | None:
        """The distinct feature rows ``(u, K)`` of an atom on the calibration rows and the sparse ``(u, n_cal)``
        matrix summing a per-row quantity over the rows that share each, when there are at most half as many
        distinct rows as rows (steps, indicators, sessions); else None (cached)."""
        from scipy import sparse

        key = self._key(atom)
        if key not in self._Fu:
            F = self.features_cal(atom)
            Fu, inv = np.unique(F, axis=0, return_inverse=True)
            n = F.shape[0]
            self._Fu[key] = None if 2 * len(Fu) > n else (
                Fu, sparse.csr_matrix((np.ones(n), (inv.ravel(), np.arange(n))), shape=(len(Fu), n)))
        return self._Fu[key]

    def model(self, chosen: list, block: str) -> ExtendedModel:
        """The extended model with ``chosen`` atoms on the rows of ``block`` (``cal``, ``val``, ``rep``)."""
        obs, rows = {"cal": (self.obs_cal, self.rows_cal), "val": (self.obs_val, self.rows_val),
                     "rep": (self.obs_rep, self.rows_rep)}[block]
        if obs is None:
            raise ValueError(f"block {block!r}: this problem has no such rows")
        terms = [AtomTerm(a, self.features(a)[rows], B) for a, B in chosen]
        return ExtendedModel(self.prep.space, obs, terms, self.floor.axis_sigma)

    def fit(self, x0: np.ndarray, chosen: list, z_eff: list | None = None) -> Fit:
        """Gauss-Newton over the free geometry and the atoms' reduced coordinates on the calibration rows
        (gross rows at weight 0), from ``x0`` and ``z_eff`` (zero for new atoms)."""
        mc, mv = self.model(chosen, "cal"), self.model(chosen, "val")
        z0 = np.concatenate([x0] + ([np.zeros(t.r) for t in mc.terms] if z_eff is None else z_eff))
        free = np.concatenate([self.free_geo, np.arange(self.prep.space.size, mc.size)]).astype(int)
        # 1e-11 (SI) per step is far below any effect or geometric parameter that matters here
        gn = gauss_newton(lambda z: mc.residuals(z), z0, free, row_weights=self.w_cal, max_iter=30, xtol=1e-11,
                          ftol=FIT_FTOL, stage="extended")
        res = mc.residuals(gn.x, jacobian=False)
        rr = res.r * np.sqrt(self.w_cal[res.row])
        return Fit(list(chosen), gn.x, free, float(rr @ rr), mc, mv)

    def test_fit_block(self, fit: Fit) -> StructureTest:
        """:func:`fit_block_test` of ``fit`` on the calibration rows (gross rows at weight 0 left out)."""
        rc = fit.model_cal.residuals(fit.z, jacobian=False)
        return fit_block_test(rc.r[self.w_cal[rc.row] > 0], fit.free.size, self.floor)

    def test(self, fit: Fit, model: ExtendedModel | None = None, keep: np.ndarray | None = None) -> StructureTest:
        """The structure test of ``fit`` on the confirmation rows (or on ``model``'s rows, ``keep`` of them)."""
        mv = fit.model_val if model is None else model
        keep = self.keep_val if model is None else keep
        rv = mv.residuals(fit.z)
        rc = fit.model_cal.residuals(fit.z)
        kv = np.ones(rv.r.size, bool) if keep is None else keep[rv.row]
        Jc = rc.J[:, fit.free] * np.sqrt(self.w_cal[rc.row])[:, None]
        return structure_test(rv.r[kv], rv.J[kv][:, fit.free], Jc, self.floor)


def chi2_logsf(x, k):
    """``log P(chi2(k) > x)`` (scalars or arrays), finite where scipy's underflows to ``-inf`` (large ``x``: the
    leading term of the upper incomplete gamma function, ``-x/2 + (k/2 - 1) log(x/2) - lgamma(k/2)``)."""
    from scipy.special import gammaln

    x, k = np.asarray(x, float), np.asarray(k, float)
    v = np.asarray(dists.chi2_logsf(x, k), float)
    bad = ~np.isfinite(v) & np.isfinite(x) & (x > 0)
    if np.any(bad):
        xb, kb = np.broadcast_to(x, v.shape)[bad], np.broadcast_to(k, v.shape)[bad]
        v = v.copy()
        v[bad] = -xb / 2 + (kb / 2 - 1) * np.log(xb / 2) - gammaln(kb / 2)
    return float(v) if v.ndim == 0 else v


def raw_columns(model: ExtendedModel, atom: Atom, F: np.ndarray, z: np.ndarray, res) -> np.ndarray:
    x, phis = model.split(z)
    obs = model.effective_obs(phis)
    return model.columns(AtomTerm(atom, F, np.eye(F.shape[1])), x, obs, res)


class Scored:
    """An atom scored against a fit: its reduced ``basis`` ``(K, r)``, coefficients ``psi`` ``(r,)``, calibration
    evidence ``dchi2`` and pool-adjusted ``logp_adj``, the residual ``r`` it was scored against (projected off the
    current model, kept residuals), and on demand its reduced columns ``E`` ``(m_kept, r)``, their part ``Ep``
    beyond the current model and the fitted residual ``fitted = Ep psi``. ``ep_norm2``: ``|Ep|_F^2`` when the
    scoring knows it (the sum of the kept eigenvalues of the projected Gram matrix)."""

    def __init__(self, atom: Atom, basis: np.ndarray, psi: np.ndarray, dchi2: float, logp_adj: float, r: np.ndarray,
                 *, E: np.ndarray | None = None, Ep: np.ndarray | None = None, columns=None, Q: np.ndarray | None = None,
                 ep_norm2: float | None = None):
        self.atom, self.basis, self.psi, self.dchi2, self.logp_adj, self.r = atom, basis, psi, dchi2, logp_adj, r
        self._E, self._Ep, self._columns, self._Q = E, Ep, columns, Q
        self._ep_norm2 = ep_norm2
        self._span: np.ndarray | None = None

    def reduced_columns(self) -> np.ndarray:
        """``E`` ``(m_kept, r)``, built without keeping it when it is not kept already (a test over many atoms)."""
        return self._E if self._E is not None else self._columns() @ self.basis

    def ep_norm2(self) -> float:
        """``|Ep|_F^2``, the squared norm of the reduced columns beyond the current model."""
        if self._ep_norm2 is None:
            return float(np.sum(self.Ep**2))
        return self._ep_norm2

    def span(self) -> np.ndarray:
        """An orthonormal basis ``(m_kept, r)`` of ``Ep`` (QR; kept)."""
        if self._span is None:
            self._span = np.linalg.qr(self.Ep)[0]
        return self._span

    @property
    def E(self) -> np.ndarray:
        if self._E is None:
            self._E = self._columns() @ self.basis
        return self._E

    @property
    def Ep(self) -> np.ndarray:
        if self._Ep is None:
            E = self.E
            self._Ep = E - self._Q @ (self._Q.T @ E)
        return self._Ep

    @property
    def fitted(self) -> np.ndarray:
        return self.Ep @ self.psi


class _ColumnStore:
    """The screened pool's feature sets on the calibration rows, stored once however many places use them: per
    width ``K``, one block ``(n, K, g)`` of the sets several places use (the dictionary's) and one per place of the
    sets only it uses (a scanned order, a joint's own shapes), so that a place multiplies its per-row aggregates
    with a few contiguous blocks instead of a copy of its atoms' features. The calibration-row features of the stored sets
    (:meth:`Problem.features_cal`) become views of the blocks. One-step atoms are left out (suffix sums)."""

    MIN_ATOMS = 200

    def __init__(self, prob: Problem, atoms: list[Atom]):
        users: dict[str, set] = {}
        rep: dict[str, Atom] = {}
        for a in atoms:
            if _single_step(a):
                continue
            key = prob._key(a)
            users.setdefault(key, set()).add((a.place, a.target))
            rep.setdefault(key, a)
        # per width, one block of the sets several places use (a place multiplies the whole block: the few sets a
        # place lacks, its own joint's polynomial on a joint, cost less than many small blocks) and one block per
        # place of the sets only it uses (a scanned order)
        everyone = frozenset().union(*users.values())
        by_block: dict[tuple, list[str]] = {}
        for key, places in users.items():
            who = frozenset(places) if len(places) == 1 else everyone
            by_block.setdefault((who, len(rep[key].features)), []).append(key)
        self.blocks: list[tuple[frozenset, np.ndarray]] = []
        self.index: dict[str, tuple[int, int]] = {}
        for (places, K), keys in by_block.items():
            F = np.stack([prob.features_cal(rep[k]) for k in keys], axis=2)  # (n, K, g)
            b = len(self.blocks)
            self.blocks.append((places, F))
            for j, k in enumerate(keys):
                self.index[k] = (b, j)
                prob._Fc[k] = F[:, :, j]

    def has(self, key: str) -> bool:
        return key in self.index

    def stats(self, place: tuple, keys: list[str], w: np.ndarray, Qb: np.ndarray, br: np.ndarray) -> list:
        """:func:`_block_stats` of the stored sets ``keys`` against one place's aggregates (every set of a block
        the place uses is multiplied: the blocks are what the places share)."""
        need: dict[int, list[tuple[int, int]]] = {}
        for i, k in enumerate(keys):
            b, j = self.index[k]
            need.setdefault(b, []).append((i, j))
        out: list = [None] * len(keys)
        for b, items in need.items():
            F = self.blocks[b][1]
            if 4 * len(items) < F.shape[2]:  # a few sets of a large block: those alone
                got = _block_stats(F[:, :, [j for _, j in items]], w, Qb, br)
                for (i, _), st in zip(items, got):
                    out[i] = st
                continue
            got = _block_stats(F, w, Qb, br)
            for i, j in items:
                out[i] = got[j]
        return out


def _screenable(a: Atom) -> bool:
    """Atoms whose columns are one model column times their features (batch-screened)."""
    if len(a.features) > 4:
        return False
    return a.place in ("joint", "length", "scale") or (a.place == "param" and a.target not in ("tool", "base", "base_along")
                                                        and not a.target.startswith("tilt"))


def _screen(prob: Problem, fit: Fit, atoms: list[Atom], rc, keep, sw, Q, r, pool_sizes) -> np.ndarray:
    """Pool-adjusted log p-values ``(len(atoms),)`` of single-column-times-feature atoms, batched: columns
    scaled to unit norm, projected off the current model, directions below 1 % of a unit column dropped
    (eigenvalues of the small Gram matrices), ``Delta chi2 = sum (v^T E^T r)^2 / lambda``.

    An atom's columns are ``E[m, k] = b[m] F[row(m), k]`` (``b`` the model column of its place, ``F`` its
    features), so every product over the residuals is a product over the rows with per-row aggregates of
    ``b``: ``E^T E = F^T diag(w) F`` with ``w = sum_row b^2``, ``Q^T E = (sum_row Q b)^T F``,
    ``E^T r = F^T (sum_row b r)``; the projected Gram matrix is ``E^T E - (Q^T E)^T Q^T E``. The products over
    the rows are taken per feature set, not per atom: on the column store's blocks of the sets the places share
    (:class:`_ColumnStore`), and for a step in time (``1[t >= a]``, one per session start) as the sum of the
    aggregates over the rows from ``a`` on (suffix sums in the order of the channel)."""
    sb = scoring_basis(prob, fit)
    Qtr = sb.Qtr
    store = prob.column_store(atoms)
    groups: dict[tuple, list[int]] = {}
    for i, a in enumerate(atoms):
        groups.setdefault((a.place, a.target), []).append(i)
    logp = np.full(len(atoms), np.inf)

    def group_stats(item: tuple) -> list[tuple[int, tuple]]:
        (place, target), ids = item
        got_all: list[tuple[int, tuple]] = []  # (width K, (atom index, nrm2 (K,), EtE (K, K), QtE (p, K), Etr (K,)))
        w, Qb, br = _screen_aggregates(prob, fit, sb, atoms[ids[0]])  # (n,), (n, p), (n,)
        steps, stored, rest = [], [], []
        for i in ids:
            if _single_step(atoms[i]):
                steps.append(i)
            elif store is not None and store.has(prob._key(atoms[i])):
                stored.append(i)
            else:
                rest.append(i)
        if steps:
            for i, got in zip(steps, _step_stats(prob, [atoms[i] for i in steps], w, Qb, br)):
                got_all.append((1, (i, *got)))
        if stored:
            got = store.stats((place, target), [prob._key(atoms[i]) for i in stored], w, Qb, br)
            for i, st in zip(stored, got):
                got_all.append((len(atoms[i].features), (i, *st)))
        by_width: dict[int, list[int]] = {}
        for i in rest:
            by_width.setdefault(len(atoms[i].features), []).append(i)
        for K, gi in by_width.items():
            F = np.stack([prob.features_cal(atoms[i]) for i in gi], axis=2)  # (n, K, g)
            for i, st in zip(gi, _block_stats(F, w, Qb, br)):
                got_all.append((K, (i, *st)))
        return got_all

    stats: dict[int, list] = {}  # width K -> [(atom index, nrm2 (K,), EtE (K, K), QtE (p, K), Etr (K,))]
    for got_group in thread_map(group_stats, list(groups.items()), prob.threads):
        for K, st in got_group:
            stats.setdefault(K, []).append(st)
    for K, rows in stats.items():
        gi = np.array([t[0] for t in rows])
        nrm = np.sqrt(np.maximum(np.array([t[1] for t in rows]), 0.0))  # (g, K)
        EtE = np.array([t[2] for t in rows])  # (g, K, K)
        QtE = np.array([t[3] for t in rows])  # (g, p, K)
        Etr = np.array([t[4] for t in rows])  # (g, K)
        scale = np.where(nrm > 0, 1.0 / np.where(nrm > 0, nrm, 1.0), 0.0)
        QtE = QtE * scale[:, None, :]
        EtE = EtE * scale[:, :, None] * scale[:, None, :]
        G = EtE - QtE.transpose(0, 2, 1) @ QtE
        er = Etr * scale - (Qtr @ QtE)
        has = np.any(nrm > 0, axis=1)
        lam, V = np.linalg.eigh(G)
        ok = (lam > 1e-4) & has[:, None]  # singular value above 1 % of a unit column
        proj = np.einsum("gij,gi->gj", V, er)
        d = np.sum(np.where(ok, proj**2 / np.where(ok, lam, 1.0), 0.0), axis=1)
        k = ok.sum(axis=1)
        fine = k > 0
        logp[gi[fine]] = chi2_logsf(d[fine] / prob.evidence_scale, k[fine])
    return logp + np.array([np.log(pool_sizes[a.pool]) for a in atoms])


def _single_step(a: Atom) -> bool:
    """An atom of one feature, a step ``1[ch >= at]`` in a channel."""
    return len(a.features) == 1 and isinstance(a.features[0], Step)


def _tail_sums(X: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """``S[i] = sum_{j >= pos[i]} X[j]`` ``(len(pos), X.shape[1])`` for rows ``X`` ``(n, d)`` (0 for ``pos[i] = n``):
    the sums between consecutive distinct positions, accumulated from the last."""
    n = X.shape[0]
    out = np.zeros((len(pos), X.shape[1]))
    inside = pos < n
    if not np.any(inside):
        return out
    up = np.unique(pos[inside])
    tails = np.cumsum(np.add.reduceat(X, up, axis=0)[::-1], axis=0)[::-1]
    out[inside] = tails[np.searchsorted(up, pos[inside])]
    return out


def _block_stats(F: np.ndarray, w: np.ndarray, Qb: np.ndarray, br: np.ndarray) -> list:
    """The products over the rows of feature sets ``F`` ``(n, K, g)`` with the per-row aggregates, per set:
    ``sum w F_k^2`` ``(K,)``, ``sum w F_k F_l`` ``(K, K)``, ``Qb^T F`` ``(p, K)`` and ``br^T F`` ``(K,)``."""
    n, K, g = F.shape
    QtE = np.stack([Qb.T @ F[:, k, :] for k in range(K)], axis=2)  # (p, g, K)
    Etr = np.stack([br @ F[:, k, :] for k in range(K)], axis=1)  # (g, K)
    EtE = np.empty((g, K, K))
    for k in range(K):
        for m in range(k, K):
            EtE[:, k, m] = EtE[:, m, k] = np.einsum("n,ng,ng->g", w, F[:, k, :], F[:, m, :])
    nrm2 = np.diagonal(EtE, axis1=1, axis2=2)
    return [(nrm2[i], EtE[i], QtE[:, i, :], Etr[i]) for i in range(g)]


def _step_stats(prob: Problem, steps: list[Atom], w: np.ndarray, Qb: np.ndarray, br: np.ndarray) -> list:
    """:func:`_block_stats` of one-step atoms ``1[ch >= at]``: sums of the aggregates over the rows with
    ``ch >= at``, read off suffix sums in the channel's order (one pass over the rows for all the steps)."""
    out: list = [None] * len(steps)
    by_ch: dict[str, list[int]] = {}
    for i, a in enumerate(steps):
        by_ch.setdefault(a.features[0].ch, []).append(i)
    for ch, idx in by_ch.items():
        order, v = prob.channel_order_cal(ch)
        A = np.concatenate([w[order, None], Qb[order], br[order, None]], axis=1)  # (n, p + 2)
        at = np.array([steps[i].features[0].at for i in idx], dtype=float)
        for i, s in zip(idx, _tail_sums(A, np.searchsorted(v, at, side="left"))):
            out[i] = (s[:1], s[:1].reshape(1, 1), s[1:-1, None], s[-1:])
    return out


@dataclass(frozen=True)
class ScoringBasis:
    """What scoring atoms against a fit needs once: the calibration residuals with their Jacobian ``rc``, the
    square-root row weights per residual ``sw``, the residuals kept (weight > 0) ``keep``, an orthonormal basis
    ``Q`` of the free model columns (kept residuals) and the residual ``r`` projected off it; ``cache``: what the
    scoring derives from them once per place (:func:`_kept_base`, :func:`_row_aggregates`)."""

    rc: object
    sw: np.ndarray
    keep: np.ndarray
    Q: np.ndarray
    r: np.ndarray
    cache: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def rows(self) -> np.ndarray:
        """The calibration row of every kept residual ``(m_kept,)``."""
        got = self.cache.get("rows")
        if got is None:
            got = self.cache["rows"] = self.rc.row[self.keep]
        return got

    @property
    def Qtr(self) -> np.ndarray:
        """``Q^T r`` ``(p,)``."""
        got = self.cache.get("Qtr")
        if got is None:
            got = self.cache["Qtr"] = self.Q.T @ self.r
        return got

    @property
    def sw_kept(self) -> np.ndarray:
        """The square-root row weights of the kept residuals ``(m_kept,)``."""
        got = self.cache.get("sw_kept")
        if got is None:
            got = self.cache["sw_kept"] = self.sw[self.keep]
        return got


def _kept_base(prob: Problem, fit: Fit, sb: ScoringBasis, atom: Atom) -> np.ndarray:
    """The whitened model columns a product atom's features multiply (:meth:`ExtendedModel.product_base`) on the
    kept residuals ``(m_kept, c)``, unweighted; once per place and fit."""
    key = ("base", atom.place, atom.target)
    got = sb.cache.get(key)
    if got is None:
        model = fit.model_cal
        obs = model.effective_obs(model.split(fit.z)[1])
        got = sb.cache[key] = model.product_base(atom, fit.z[: prob.prep.space.size], obs, sb.rc)[sb.keep]
    return got


def _row_aggregates(prob: Problem, fit: Fit, sb: ScoringBasis, atom: Atom) -> tuple[np.ndarray, ...]:
    """Per calibration row, the sums over its kept residuals of ``base base^T`` ``(n, c, c)``, ``Q base^T``
    ``(n, p, c)`` and ``base r`` ``(n, c)`` (``base``: :func:`_kept_base` times the row weights); once per place and
    fit."""
    key = ("aggregates", atom.place, atom.target)
    got = sb.cache.get(key)
    if got is None:
        base = _kept_base(prob, fit, sb, atom) * sb.sw_kept[:, None]  # (m, c)
        slot, rows, Qg, rg = _row_slots(prob, sb)
        kmax, n, p = Qg.shape
        c = base.shape[1]
        bg = np.zeros((kmax, n, c))
        bg[slot, rows] = base
        # each row's sum over its residuals in their order, one slot at a time (a padded slot adds an exact 0)
        W = np.zeros((n, c, c))
        QB = np.zeros((n, p, c))
        Br = np.zeros((n, c))
        tmp = np.empty((n, p))
        for k in range(kmax):
            W += bg[k][:, :, None] * bg[k][:, None, :]
            for j in range(c):
                np.multiply(Qg[k], bg[k, :, j:j + 1], out=tmp)
                QB[:, :, j] += tmp
            Br += bg[k] * rg[k][:, None]
        got = sb.cache[key] = (W, QB, Br)
    return got


def _row_slots(prob: Problem, sb: ScoringBasis) -> tuple[np.ndarray, ...]:
    """The kept residuals laid out by calibration row: each one's slot (its place among its row's residuals, in
    their order) and row ``(m_kept,)``, and ``Q`` ``(kmax, n, p)`` and ``r`` ``(kmax, n)`` in that layout (zero in
    the slots a row does not fill); once per basis."""
    got = sb.cache.get("slots")
    if got is None:
        rows = sb.rows
        n = prob.obs_cal.n
        order = np.argsort(rows, kind="stable")
        counts = np.bincount(rows, minlength=n)
        start = np.concatenate([[0], np.cumsum(counts)[:-1]])
        slot = np.empty(len(rows), dtype=int)
        slot[order] = np.arange(len(rows)) - start[rows[order]]
        kmax = int(counts.max(initial=0))
        Qg = np.zeros((kmax, n, sb.Q.shape[1]))
        Qg[slot, rows] = sb.Q
        rg = np.zeros((kmax, n))
        rg[slot, rows] = sb.r
        got = sb.cache["slots"] = (slot, rows, Qg, rg)
    return got


def _screen_aggregates(prob: Problem, fit: Fit, sb: ScoringBasis, atom: Atom) -> tuple[np.ndarray, ...]:
    """The single-column form of :func:`_row_aggregates` the screening uses: ``w`` ``(n,)``, ``Qb`` ``(n, p)``,
    ``br`` ``(n,)``."""
    W, QB, Br = _row_aggregates(prob, fit, sb, atom)
    return W[:, 0, 0], QB[:, :, 0], Br[:, 0]


def scoring_basis(prob: Problem, fit: Fit) -> ScoringBasis:
    """The :class:`ScoringBasis` of ``fit`` under the problem's current row weights (cached on the fit). Only the
    newest basis keeps its per-place quantities (the selection scores against its latest fit; an older basis
    derives them again when asked)."""
    key = ("basis", id(prob.w_cal))
    got = fit.cache.get(key)
    if got is None:
        old = prob._newest_basis() if prob._newest_basis is not None else None
        if old is not None:
            old.cache.clear()
        rc = fit.model_cal.residuals(fit.z)
        sw = np.sqrt(prob.w_cal[rc.row])
        keep = sw > 0
        A = (rc.J[:, fit.free] * sw[:, None])[keep]
        Q, _ = np.linalg.qr(A)
        r = (rc.r * sw)[keep]
        r = r - Q @ (Q.T @ r)
        got = fit.cache[key] = ScoringBasis(rc, sw, keep, Q, r)
        prob._newest_basis = weakref.ref(got)
    return got


def score_atoms(prob: Problem, fit: Fit, atoms: list[Atom], pool_sizes: dict[str, int], *,
                exact_top: int = 40) -> list[Scored]:
    """Linearised evidence of the atoms against the current fit (see the module docstring). The catalogue
    and the broad atoms are scored exactly; the many small dictionary atoms are screened in batches and only
    the ``exact_top`` strongest of them scored exactly."""
    sb = scoring_basis(prob, fit)
    rc, sw, keep, Q, r = sb.rc, sb.sw, sb.keep, sb.Q, sb.r
    screen = [a for a in atoms if a.pool != "catalogue" and _screenable(a)]
    exact = [a for a in atoms if not (a.pool != "catalogue" and _screenable(a))]
    if screen:
        lp = _screen(prob, fit, screen, rc, keep, sw, Q, r, pool_sizes)
        exact += [screen[i] for i in np.argsort(lp)[:exact_top] if np.isfinite(lp[i])]
    products = [a for a in exact if _product(a)]
    others = [a for a in exact if not _product(a)]
    out = _score_products(prob, fit, products, sb, pool_sizes) if products else []
    for a in others:
        F = prob.features(a)[prob.rows_cal]
        if not np.any(F):
            continue
        E = raw_columns(fit.model_cal, a, F, fit.z, rc)[keep] * sw[keep][:, None]
        B = reduced_basis(E, Q=Q, max_rank=6)
        if B.shape[1] == 0:
            continue
        EB = E @ B
        Ep = EB - Q @ (Q.T @ EB)
        psi, *_ = np.linalg.lstsq(Ep, r, rcond=None)
        fitted = Ep @ psi
        d = float(fitted @ fitted)
        # log of the pool-adjusted p-value (smaller is stronger); chi2.logsf stays finite where sf underflows
        logp = chi2_logsf(d / prob.evidence_scale, B.shape[1]) + np.log(pool_sizes[a.pool])
        out.append(Scored(a, B, psi, d, logp, r, E=EB, Ep=Ep))
    order = {id(a): i for i, a in enumerate(exact)}
    return sorted(out, key=lambda s: order[id(s.atom)])


def _score_products(prob: Problem, fit: Fit, atoms: list[Atom], sb: ScoringBasis, pool_sizes: dict[str, int], *,
                    rel_tol: float = 1e-2, max_rank: int = 6) -> list[Scored]:
    """The exact score (as :func:`twin.diagnosis.extend.reduced_basis` and least squares on the reduced columns)
    of atoms whose columns are products ``E[m, k c + j] = F[row(m), k] base[m, j]``, through per-row aggregates of
    their base: ``E^T E = sum_row F F^T (x) W`` with ``W = sum_row base base^T``, ``Q^T E = sum_row (Q^T base) F``,
    ``E^T r = sum_row F (base^T r)``. The reduced basis is the eigenvectors of the column-scaled projected Gram
    matrix ``D (E^T E - (Q^T E)^T Q^T E) D`` whose singular values (square roots) pass ``rel_tol`` (at most
    ``max_rank``), and ``Delta chi2 = sum (v^T D (E^T r - (Q^T E)^T Q^T r))^2 / lambda``. The columns themselves
    are built only for the atoms whose ``Ep`` is asked for."""
    Q, r = sb.Q, sb.r
    Qtr = sb.Qtr
    groups: dict[tuple, list[Atom]] = {}
    for a in atoms:
        groups.setdefault((a.place, a.target, a.place == "plate" and a.varying_plate), []).append(a)

    def group_scores(members: list[Atom]) -> list[tuple]:
        pending = []
        W, QB, Br = _row_aggregates(prob, fit, sb, members[0])  # (n, c, c), (n, p, c), (n, c)
        items: dict[int, list] = {}  # K -> [(atom, E^T E, Q^T E, E^T r, any feature nonzero)]
        families: dict[tuple, list[Atom]] = {}
        rest: list[Atom] = []
        for a in members:
            gate = _gate(a)
            if gate is None:
                rest.append(a)
            else:
                families.setdefault((gate[0], repr(gate[2])), []).append(a)
        for fam in families.values():
            if len(fam) * W.shape[0] < GATE_SUFFIX_MIN:  # a small family: as every other atom
                rest += fam
                continue
            for a, st in zip(fam, _gate_grams(prob, fam, W, QB, Br)):
                items.setdefault(len(a.features), []).append((a, *st))
        by_width: dict[int, list[Atom]] = {}
        for a in rest:
            by_width.setdefault(len(a.features), []).append(a)
        for K, grp in by_width.items():
            F = np.stack([prob.features_cal(a) for a in grp], axis=1)  # (n, g, K)
            EtE, QtE, Etr = _product_grams_bounded(prob, grp, F, W, QB, Br)
            nonzero = np.any(F != 0, axis=(0, 2))
            items.setdefault(K, []).extend(zip(grp, EtE, QtE, Etr, nonzero))
        for K, it in items.items():
            grp = [t[0] for t in it]
            EtE, QtE, Etr = np.array([t[1] for t in it]), np.array([t[2] for t in it]), np.array([t[3] for t in it])
            nonzero = [bool(t[4]) for t in it]
            nrm = np.sqrt(np.maximum(np.diagonal(EtE, axis1=1, axis2=2), 0.0))  # (g, KC)
            has = nrm > 1e-12 * np.maximum(nrm.max(axis=1, keepdims=True), 1e-300)
            D = np.where(has, 1.0 / np.where(has, nrm, 1.0), 0.0)
            G = (EtE - QtE.transpose(0, 2, 1) @ QtE) * D[:, :, None] * D[:, None, :]
            e = (Etr - Qtr @ QtE) * D
            lam, V = _leading_eigh(G, max_rank)  # descending
            sv = np.sqrt(np.maximum(lam, 0.0))
            rks = np.minimum(np.sum(sv > rel_tol * np.maximum(sv[:, :1], 1.0), axis=1), max_rank)
            for i, a in enumerate(grp):
                rk = int(rks[i])
                if rk == 0 or not nonzero[i] or not np.any(has[i]):
                    continue
                Vr = V[i][:, :rk]
                proj = Vr.T @ e[i]
                pending.append((a, D[i][:, None] * Vr, proj / lam[i, :rk], float(np.sum(proj**2 / lam[i, :rk])), rk,
                                float(np.sum(lam[i, :rk]))))
        return pending

    pending = [t for got in thread_map(group_scores, list(groups.values()), prob.threads) for t in got]
    if not pending:
        return []
    logp = chi2_logsf(np.array([p[3] for p in pending]) / prob.evidence_scale, np.array([p[4] for p in pending]))
    return [Scored(a, B, psi, d, float(lp) + np.log(pool_sizes[a.pool]), r, Q=Q,
                   columns=_column_maker(prob, fit, a, sb), ep_norm2=ep2)
            for (a, B, psi, d, _, ep2), lp in zip(pending, np.atleast_1d(logp))]


WIDE_EIGH_MIN = 400  # from this size on, only the leading eigenpairs of a projected Gram matrix are computed


def _leading_eigh(G: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues ``(g, .)`` and eigenvectors ``(g, KC, .)`` of symmetric matrices ``G`` ``(g, KC, KC)`` in
    descending order: all of them, or for matrices of ``WIDE_EIGH_MIN`` rows and more (a step at each of 200
    session starts on a frame: 1,200 rows) the ``k`` leading ones alone, all the scoring uses."""
    KC = G.shape[-1]
    if KC < WIDE_EIGH_MIN or KC <= k:
        lam, V = np.linalg.eigh(G)
        return lam[:, ::-1], V[:, :, ::-1]
    from scipy.linalg import eigh

    lam = np.empty((len(G), k))
    V = np.empty((len(G), KC, k))
    for i, Gi in enumerate(G):
        w, v = eigh(Gi, subset_by_index=[KC - k, KC - 1])
        lam[i], V[i] = w[::-1], v[:, ::-1]
    return lam, V


GATE_SUFFIX_MIN = 1 << 20  # atoms x rows from which a family acting from different moments is summed by suffixes


def _gate(a: Atom) -> tuple[str, float, tuple] | None:
    """``(channel, at, inner features)`` of an atom that acts from a moment on: one step ``1[ch >= at]`` (no inner
    features), or features all gated at the same ``ch >= at`` (a compliance changed at a restart); else None."""
    fs = a.features
    if len(fs) == 1 and isinstance(fs[0], Step):
        return fs[0].ch, float(fs[0].at), ()
    if fs and all(isinstance(f, Gated) for f in fs):
        ch, at = fs[0].ch, fs[0].at
        if all(f.ch == ch and f.at == at for f in fs):
            return ch, float(at), tuple(f.f for f in fs)
    return None


def _gate_grams(prob: Problem, family: list[Atom], W: np.ndarray, QB: np.ndarray, Br: np.ndarray) -> list:
    """:func:`_product_grams` of atoms that differ only in the moment they act from (:func:`_gate`: the same
    channel and inner features): the per-row products of their inner features with the aggregates summed over the
    rows from each moment on, read off suffix sums in the channel's order (one pass over the rows for the family).
    Per atom ``(E^T E, Q^T E, E^T r, whether a feature is nonzero)``."""
    ch, _, inner = _gate(family[0])
    order, v = prob.channel_order_cal(ch)
    n = len(order)
    Fo = np.ones((n, 1)) if not inner else prob.inner_features_cal(inner)[order]  # (n, K)
    K, c, p = Fo.shape[1], W.shape[1], QB.shape[1]
    KC = K * c
    A = ((Fo[:, :, None] * Fo[:, None, :]).reshape(n, K * K, 1) * W[order].reshape(n, 1, c * c)).reshape(n, -1)
    B = (Fo[:, :, None, None] * QB[order][:, None, :, :]).reshape(n, K * p * c)
    C = (Fo[:, :, None] * Br[order][:, None, :]).reshape(n, K * c)
    X = np.concatenate([A, B, C, np.any(Fo != 0, axis=1)[:, None].astype(float)], axis=1)
    S = _tail_sums(X, np.searchsorted(v, np.array([_gate(a)[1] for a in family]), side="left"))
    g = len(family)
    a0, a1, a2 = K * K * c * c, K * K * c * c + K * p * c, K * K * c * c + K * p * c + K * c
    EtE = S[:, :a0].reshape(g, K, K, c, c).transpose(0, 1, 3, 2, 4).reshape(g, KC, KC)
    QtE = S[:, a0:a1].reshape(g, K, p, c).transpose(0, 2, 1, 3).reshape(g, p, KC)
    Etr = S[:, a1:a2].reshape(g, KC)
    return list(zip(EtE, QtE, Etr, S[:, a2] > 0))


PRODUCT_BATCH_MAX = 1 << 23  # elements of the per-row feature products one batch builds at once (64 MB)


def _product_grams(F: np.ndarray, W: np.ndarray, QB: np.ndarray, Br: np.ndarray) -> tuple[np.ndarray, ...]:
    """``E^T E`` ``(g, K c, K c)``, ``Q^T E`` ``(g, p, K c)`` and ``E^T r`` ``(g, K c)`` of a batch of product atoms
    with features ``F`` ``(n, g, K)`` from the per-row aggregates of their base ``W`` ``(n, c, c)``, ``QB``
    ``(n, p, c)``, ``Br`` ``(n, c)`` (:func:`_score_products`)."""
    n, g, K = F.shape
    c, p = W.shape[1], QB.shape[1]
    KC = K * c
    FF = (F[:, :, :, None] * F[:, :, None, :]).reshape(n, g * K * K)
    EtE = (FF.T @ W.reshape(n, c * c)).reshape(g, K, K, c, c).transpose(0, 1, 3, 2, 4).reshape(g, KC, KC)
    F2 = F.reshape(n, g * K)
    QtE = (F2.T @ QB.reshape(n, p * c)).reshape(g, K, p, c).transpose(0, 2, 1, 3).reshape(g, p, KC)
    Etr = (F2.T @ Br).reshape(g, KC)
    return EtE, QtE, Etr


def _product_grams_bounded(prob: Problem, grp: list[Atom], F: np.ndarray, W: np.ndarray, QB: np.ndarray,
                           Br: np.ndarray) -> tuple[np.ndarray, ...]:
    """:func:`_product_grams` with the per-row feature products of a batch held below ``PRODUCT_BATCH_MAX``
    elements: a batch beyond it is split into smaller batches of atoms; an atom too wide alone (a step at each of
    200 session starts) is evaluated on its distinct feature rows, the aggregates summed over the rows that share
    one (``sum_row F F^T (x) W = sum_distinct F F^T (x) sum_its_rows W``), or else over blocks of rows."""
    n, g, K = F.shape
    if n * g * K * K <= PRODUCT_BATCH_MAX:
        return _product_grams(F, W, QB, Br)
    if n * K * K <= PRODUCT_BATCH_MAX:
        step = max(1, PRODUCT_BATCH_MAX // (n * K * K))
        parts = [_product_grams(F[:, i:i + step], W, QB, Br) for i in range(0, g, step)]
        return tuple(np.concatenate(x, axis=0) for x in zip(*parts))
    parts = []
    for i, a in enumerate(grp):
        distinct = prob.distinct_rows_cal(a)
        if distinct is not None:
            Fu, U = distinct
            parts.append(_product_grams_wide(Fu, (U @ W.reshape(n, -1)).reshape(-1, *W.shape[1:]),
                                             (U @ QB.reshape(n, -1)).reshape(-1, *QB.shape[1:]), U @ Br))
        else:
            parts.append(_product_grams_wide(F[:, i], W, QB, Br))
    return tuple(np.concatenate(x, axis=0) for x in zip(*parts))


def _product_grams_wide(F: np.ndarray, W: np.ndarray, QB: np.ndarray, Br: np.ndarray) -> tuple[np.ndarray, ...]:
    """:func:`_product_grams` of one atom with many features ``F`` ``(n, K)`` without the ``(n, K^2)`` products:
    ``E^T E`` block by block of the base, ``F^T diag(W[:, i, j]) F``."""
    n, K = F.shape
    c, p = W.shape[1], QB.shape[1]
    EtE = np.empty((K, c, K, c))
    for i in range(c):
        for j in range(i, c):
            EtE[:, i, :, j] = (F * W[:, i, j, None]).T @ F
            if j > i:
                EtE[:, j, :, i] = EtE[:, i, :, j].T
    QtE = (F.T @ QB.reshape(n, p * c)).reshape(K, p, c).transpose(1, 0, 2).reshape(p, K * c)
    Etr = (F.T @ Br).reshape(K * c)
    return EtE.reshape(1, K * c, K * c), QtE[None], Etr[None]


def _product(a: Atom) -> bool:
    """Whether an atom's columns are its features times model columns (:meth:`ExtendedModel.product_base`)."""
    return not (a.place == "field" or (a.place == "param" and (a.target == "base_along" or a.target.startswith("tilt"))))


def _column_maker(prob: Problem, fit: Fit, atom: Atom, sb: ScoringBasis):
    """The weighted raw columns ``(m_kept, K c)`` of a product atom on the kept residuals, on demand: its features
    on each residual's row times the place's model columns (:meth:`ExtendedModel.columns`)."""
    def make() -> np.ndarray:
        base = _kept_base(prob, fit, sb, atom)
        if atom.place == "plate" and not atom.varying_plate:
            E = base
        else:
            Fr = prob.features_cal(atom)[sb.rows]
            E = (Fr[:, :, None] * base[:, None, :]).reshape(len(base), -1)
        return E * sb.sw_kept[:, None]
    return make


def order_candidates(scored: list[Scored], broad_dim: int = 4) -> list[Scored]:
    """Atoms in the order to try: by pool-adjusted evidence, except that a broad atom (``>= broad_dim``
    reduced parameters: compliance, a whole frame) goes behind the small atoms when small atoms together
    explain more within the same number of parameters (a broad atom collects a little of several effects;
    it must not pre-empt the small atoms that each hold one of them)."""
    order = _prefer_nested(sorted(scored, key=lambda s: s.logp_adj))
    if order and order[0].atom.pool == "generic":
        # the dictionary holds supersets of catalogue terms (a polynomial in q_j on theta_j contains the
        # gear-ratio direction): an unnamed term must beat the best named one clearly, not by fitting noise
        named = [s for s in order if s.atom.pool != "generic"]
        top = order[0]
        # "the same place": the same target, or a named atom whose columns lie within the unnamed one's (a joint-1
        # backlash is a rotation about base z, inside the base frame's six directions with the same sign)
        # the first such named atom in the order (the test is lazy: each _nested builds the atom's columns)
        first_same = next((s for s in named if (s.atom.place, s.atom.target) == (top.atom.place, top.atom.target)
                           or _nested(s, top)), None)
        same = first_same is not None
        cand = first_same if same else (named[0] if named else None)
        # at high signal-to-noise, effects not yet modelled leak a few per cent into any broader atom: the
        # margin grows with the evidence (5 % of it) for a named atom acting at the same place
        margin = max(CATALOGUE_MARGIN, CATALOGUE_SHARE * abs(cand.logp_adj)) if same else CATALOGUE_MARGIN
        if cand is not None and cand.logp_adj < top.logp_adj + margin:
            order = [cand] + [s for s in order if s is not cand]
    if not order or order[0].basis.shape[1] < broad_dim:
        return order
    best = order[0]
    # a named broad atom (compliance) answers to the named small atoms; an unnamed one to all
    small = [s for s in order if s.basis.shape[1] < broad_dim
             and (best.atom.pool != "catalogue" or s.atom.pool == "catalogue")]
    gain = _omp_gain(small, best.basis.shape[1])
    if gain >= best.dchi2 and small:
        return small[:1] + [s for s in order if s is not small[0]]
    return order


def _nested(small: Scored, big: Scored, share: float = 0.99) -> bool:
    """Whether ``small``'s projected columns lie (to ``share`` of their norm) within ``big``'s span."""
    if small.basis.shape[1] >= big.basis.shape[1] or small.r.shape != big.r.shape:
        return False
    # big's span is orthogonal to the current model, so its product with small's projected columns Ep is its product
    # with small's columns E (E - Ep lies in the model's span): no projection of small's columns is needed
    tot = small.ep_norm2()
    return tot > 0 and float(np.sum((big.span().T @ small.reduced_columns()) ** 2)) >= share * tot


def _prefer_nested(order: list[Scored], alpha_select: float = 0.01) -> list[Scored]:
    """When the leading atom's features contain those of a smaller significant atom at the same place (a product
    group holds the linear terms of its joints; a cubic holds the quadratic and the linear), the smallest such
    atom goes first: what the larger one adds beyond it must then earn its own place in a later round (its
    evidence and held-out confirmation), instead of riding on the part they share."""
    if not order:
        return order
    top = order[0]
    keys = {repr(f) for f in top.atom.features}
    best = None
    for s in order[1:]:
        if (s.atom.place, s.atom.target) != (top.atom.place, top.atom.target) or s.logp_adj >= np.log(alpha_select):
            continue
        sk = {repr(f) for f in s.atom.features}
        if sk < keys and (best is None or len(sk) < len(best.atom.features)
                          or (len(sk) == len(best.atom.features) and s.dchi2 > best.dchi2)):
            best = s
    return order if best is None else [best] + [s for s in order if s is not best]


def _omp_gain(small: list[Scored], budget: int, pool: int = 60) -> float:
    """Calibration ``Delta chi2`` that small atoms reach together within ``budget`` parameters: greedy
    orthogonal matching pursuit over their projected columns on the residual they were scored against (the
    ``pool`` strongest atoms)."""
    cand = sorted(small, key=lambda s: -s.dchi2)[:pool]
    if not cand:
        return 0.0
    r = cand[0].r
    Qs = [np.linalg.qr(s.Ep)[0] for s in cand]
    taken = np.zeros((len(r), 0))
    used = 0
    gain = 0.0
    avail = list(range(len(cand)))
    while avail:
        best = None
        for i in avail:
            Q = Qs[i] - taken @ (taken.T @ Qs[i])
            Qo, R = np.linalg.qr(Q)
            keep = np.abs(np.diag(R)) > 1e-8
            Qo = Qo[:, keep]
            g = float(np.sum((Qo.T @ r) ** 2))
            if best is None or g > best[0]:
                best = (g, i, Qo)
        g, i, Qo = best
        if used + Qo.shape[1] > budget:
            break
        gain += g
        used += Qo.shape[1]
        r = r - Qo @ (Qo.T @ r)
        taken = np.concatenate([taken, Qo], axis=1)
        avail.remove(i)
    return gain


def time_only(atom: Atom) -> bool:
    """Whether an atom's features are functions of the time channel alone (a drift, a step or a window, a transient,
    an oscillation in ``t_s`` or the row order, on any place)."""
    kinds = {f.kind for f in atom.features} - {"const"}
    return bool(kinds) and kinds <= {"pow", "step", "window", "exp", "sin", "cos"} and all(
        getattr(f, "ch", None) in ("t_s", "row") for f in atom.features if not isinstance(f, Const))


@dataclass(frozen=True)
class Confirmation:
    """The held-out check of a scored atom on the confirmation rows: ``z``, ``z`` without the most favourable row,
    whether the held-out residual norm drops (``better``), and for an atom of time alone, whether the mean
    residual of the nearest calibration rows in time predicts those rows at least as well (``local``: a wander
    of the cell correlated over a few rows, which a drift, a step or an oscillation fitted to this campaign
    follows only by chance and which does not continue into later rows)."""

    z: float
    z_without_best_row: float
    better: bool
    local: bool = False


def signed_rank_z(c: np.ndarray) -> float:
    """Wilcoxon's signed-rank statistic of ``c`` ``(n,)`` as a normal score: ``(W+ - n (n + 1) / 4) / sqrt(n (n + 1)
    (2 n + 1) / 24)``, ``W+`` the sum of the ranks of ``|c|`` over the positive entries (zeros dropped, ties at their
    mean rank). ~N(0, 1) when the entries are independent and symmetric about zero; 0 for fewer than two."""
    c = np.asarray(c, float)
    c = c[c != 0]
    n = c.size
    if n < 2:
        return 0.0
    w = float(dists.average_ranks(np.abs(c))[c > 0].sum())
    return (w - n * (n + 1) / 4.0) / np.sqrt(n * (n + 1) * (2 * n + 1) / 24.0)


def confirm(prob: Problem, fit: Fit, s: Scored, z_min: float) -> Confirmation:
    """Held-out check of a scored atom (:class:`Confirmation`); its prediction ``u`` on the confirmation rows is
    linearised, the geometry re-adjusting to it."""
    sb = scoring_basis(prob, fit)
    A = (sb.rc.J[:, fit.free] * sb.sw[:, None])[sb.keep]
    # geometry re-adjusts to the atom: beta_A = -A^+ E B psi
    beta_A = -np.linalg.lstsq(A, s.E @ s.psi, rcond=None)[0]
    rv = fit.model_val.residuals(fit.z)
    kv = prob.keep_val[rv.row]
    Fv = prob.features(s.atom)[prob.rows_val]
    Ev = raw_columns(fit.model_val, s.atom, Fv, fit.z, rv) @ s.basis
    u_all = Ev @ s.psi + rv.J[:, fit.free] @ beta_A
    u = u_all[kv]
    r = rv.r[kv]
    nu = float(np.linalg.norm(u))
    if nu <= 0:
        return Confirmation(0.0, 0.0, False)
    # per row c_k = r_k . u_k: under the null (u independent of the held-out residual) each is symmetric about zero
    # and the rows are independent, whatever the residual's size and its correlation within a row (an unmodelled
    # effect moves every coordinate of a row together: a coordinate-wise z would count them as independent and pass
    # a chance correlation as a confirmation). The rank test of their sum (Wilcoxon's signed ranks, as a normal
    # score) keeps that level and the power a few rows of large residual would take from a ratio of sums.
    contrib = np.bincount(rv.row[kv], weights=r * u, minlength=fit.model_val.obs.n)
    c = contrib[np.bincount(rv.row[kv], minlength=fit.model_val.obs.n) > 0]
    z = signed_rank_z(c)
    z_minus = signed_rank_z(np.delete(c, int(np.argmax(c)))) if c.size > 1 else 0.0
    err_term = float(np.sum((r - u) ** 2))
    better = err_term < float(r @ r)
    local = False
    if time_only(s.atom):
        U, Rv = neighbour_predictions(prob, fit)["time"]
        Ut = row_blocks(fit.model_val, u_all)
        ok = np.isfinite(Rv) & np.isfinite(U) & np.isfinite(Ut)
        # strictly better: a change that happened before the held-out block is predicted alike by the term and by
        # the last rows' state, and the term is the model that says so
        local = float(np.sum((Rv - U)[ok] ** 2)) < float(np.sum((Rv - Ut)[ok] ** 2))
    return Confirmation(z, z_minus, better, local)


def confirm_configurations(prob: Problem, fit: Fit, s: Scored, scored: list[Scored],
                           sizes: dict[str, int]) -> FoldConfirmation | None:
    """[configurations] The check of a scored atom between the sampled configurations
    (:func:`twin.diagnosis.configurations.fold_confirmation`): on each fold of the joint values it reads, the rows of
    the other folds choose again among it and its rivals (the atoms of ``scored`` at its place reading the same
    joints within :data:`twin.diagnosis.configurations.RIVAL_MARGIN` of its evidence) and the one chosen predicts the
    fold, the geometry re-adjusting, judged at :data:`twin.diagnosis.configurations.Z_MIN`; None when it reads no
    joint angle or its joints have too few blocks of values."""
    joints = joints_read(s.atom.features)
    if not joints:
        return None
    q = prob.ctx.q[prob.rows_cal][:, [j - 1 for j in joints]]
    folds = configuration_folds(q, block_widths(s.atom.features, joints, np.ptp(q, axis=0)))
    if folds is None:
        return None
    place = (s.atom.place, s.atom.target)
    rivals = [o for o in scored if o.atom.key != s.atom.key and (o.atom.place, o.atom.target) == place
              and joints_read(o.atom.features) == joints and o.logp_adj < s.logp_adj + RIVAL_MARGIN]
    sb = scoring_basis(prob, fit)
    A = (sb.rc.J[:, fit.free] * sb.sw[:, None])[sb.keep]
    return fold_confirmation(A, s.E, (sb.rc.r * sb.sw)[sb.keep], sb.rows, folds, CONFIGURATION_Z,
                             rivals=[o.E for o in rivals], log_pool=[np.log(sizes[o.atom.pool]) for o in [s, *rivals]],
                             evidence_scale=prob.evidence_scale)


NEIGHBOURS = 4  # rows a neighbour smoother averages
JOINT_WEIGHTS = np.array([1.0, 1.0, 1.0, 0.3, 0.3, 0.3])  # arm joints move the plate more than the wrist's


def joint_weights(n_joints: int) -> np.ndarray:
    """Weights ``(N,)`` of the joints in the neighbours' distance: the last three (the wrist) ``0.3``, the others 1
    (``JOINT_WEIGHTS`` for six joints)."""
    w = np.ones(n_joints)
    w[max(n_joints - 3, 0):] = 0.3
    return w


def row_blocks(model: ExtendedModel, r: np.ndarray) -> np.ndarray:
    """Whitened residuals ``(m,)`` as ``(n, 3 K)`` per row (point-major, x y z), NaN where not measured."""
    obs = model.obs
    K = obs.spheres.shape[1]
    shape = (K, 3, obs.n)
    mask = np.broadcast_to(obs.seen.T[:, None, :], shape)
    tmp = np.full(shape, np.nan)
    tmp[mask] = r
    return np.transpose(tmp, (2, 0, 1)).reshape(obs.n, 3 * K)


def neighbour_predictions(prob: Problem, fit: Fit) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per smoother (``joints``, ``time``): the mean whitened residual ``(n_v, 9)`` of the ``NEIGHBOURS`` nearest
    calibration rows of each confirmation row (joint space: joints scaled by their spread and ``JOINT_WEIGHTS``;
    time: ``t_s``, else the row order; rows with the same commanded joints excluded: a repeat shares the visit's
    error), and the confirmation rows' own residual ``(n_v, 9)`` (NaN where not measured or gross)."""
    key = ("neighbours", id(prob.w_cal), id(prob.keep_val))
    got = fit.cache.get(key)
    if got is not None:
        return got
    rc = fit.model_cal.residuals(fit.z, jacobian=False)
    rv = fit.model_val.residuals(fit.z, jacobian=False)
    Rc = row_blocks(fit.model_cal, rc.r)
    Rv = row_blocks(fit.model_val, rv.r)
    Rc[prob.w_cal <= 0] = np.nan
    Rv[~prob.keep_val] = np.nan
    qc, qv = prob.ctx.q[prob.rows_cal], prob.ctx.q[prob.rows_val]
    scale = np.ptp(np.vstack([qc, qv]), axis=0)
    w = (JOINT_WEIGHTS if qc.shape[1] == 6 else joint_weights(qc.shape[1])) / np.where(scale > 1e-9, scale, 1.0)
    same = np.all(np.abs(qv[:, None, :] - qc[None, :, :]) < 1e-9, axis=2)
    t = prob.ctx.t_s if prob.ctx.t_s is not None else np.arange(len(prob.ctx.q), dtype=float)
    out = {}
    for name, D in (("joints", np.linalg.norm((qv[:, None, :] - qc[None, :, :]) * w, axis=2)),
                    ("time", np.abs(t[prob.rows_val][:, None] - t[prob.rows_cal][None, :]))):
        D = np.where(same | np.all(np.isnan(Rc), axis=1)[None, :], np.inf, D)
        k = min(NEIGHBOURS, D.shape[1])
        nb = np.argsort(D, axis=1)[:, :k]
        with np.errstate(invalid="ignore"):
            U = np.nanmean(Rc[nb], axis=1)  # (n_v, 9)
        out[name] = (U, Rv)
    fit.cache[key] = out
    return out


def earlier_rows_prediction(prob: Problem, fit: Fit) -> tuple[np.ndarray, np.ndarray]:
    """The time smoother of a block of held-out rows: each confirmation row's residual predicted by the mean
    residual ``(n_v, 3 K)`` of the ``NEIGHBOURS`` confirmation rows measured before it (other visits only: a repeat
    shares its visit's error; NaN for the first rows), and the rows' own residual. The held-out rows are a block of
    time after the rows that fit: the calibration rows nearest in time are the same few for every one of them, and a
    prediction shared by every row is no test. Under the null (noise independent from row to row) each ``c_k =
    r_k . u_k`` has mean zero given the rows before it, so the self-normalised sum is still ~N(0, 1)."""
    rv = fit.model_val.residuals(fit.z, jacobian=False)
    Rv = row_blocks(fit.model_val, rv.r)
    Rv[~prob.keep_val] = np.nan
    rows = prob.rows_val
    qv = np.round(prob.ctx.q[rows], 9)
    U = np.full_like(Rv, np.nan)
    for k in range(len(rows)):
        prev = [i for i in range(k - 1, -1, -1) if not np.array_equal(qv[i], qv[k]) and np.isfinite(Rv[i]).any()]
        prev = prev[:NEIGHBOURS]
        if prev:
            with np.errstate(invalid="ignore"):
                U[k] = np.nanmean(Rv[prev], axis=0)
    return U, Rv


def smooth_confirm(prob: Problem, fit: Fit, z_min: float) -> dict:
    """Is the held-out residual predictable from the rows nearest to it, in joint space or in time?

    Joint space: each confirmation row's residual is predicted by the mean residual of its ``NEIGHBOURS`` nearest
    calibration rows (joints scaled by their spread and ``JOINT_WEIGHTS``), rows with the same commanded joints
    excluded (a repeat shares the visit's error); the calibration residuals are independent of the held-out ones.
    Time: by the confirmation rows measured just before it (:func:`earlier_rows_prediction`). A structure that is
    smooth in the configuration or in time makes neighbours alike; noise that changes from visit to visit (the
    robot's repeatability, an instrument error per pose) does not. Under that null per confirmation row ``c_k =
    r_k . u_k`` is zero-mean (given what predicts it), so ``z = sum c_k / sqrt(sum c_k^2)`` is ~N(0, 1) whatever
    the noise's size and its correlation within a row. Confirmed when ``z > z_min`` also without the most favourable
    row (either smoother)."""
    out = {}
    smoothers = {"joints": neighbour_predictions(prob, fit)["joints"], "time": earlier_rows_prediction(prob, fit)}
    for name, (U, Rv) in smoothers.items():
        c = np.nansum(Rv * U, axis=1)
        ok_rows = np.isfinite(c) & np.any(np.isfinite(Rv * U), axis=1)
        c = c[ok_rows]
        den = float(np.sqrt(np.sum(c**2)))
        z = float(c.sum() / den) if den > 0 else 0.0
        z_minus = float((c.sum() - c.max()) / np.sqrt(max(np.sum(c**2) - c.max() ** 2, 1e-300))) if c.size > 1 else 0.0
        out[name] = {"z": z, "z_without_best_row": z_minus, "rows": int(c.size)}
    best = max(out, key=lambda k: out[k]["z"])
    return {"by": best, "z": out[best]["z"], "confirmed": any(v["z"] > z_min and v["z_without_best_row"] > z_min
                                                              for v in out.values()), "smoothers": out}


def covariance(J: np.ndarray) -> np.ndarray:
    """``(J^T J)^+`` of whitened columns, column-scaled first (geometric and effect columns differ by many
    orders of magnitude: an unscaled pseudo-inverse truncates the small ones)."""
    d = np.linalg.norm(J, axis=0)
    d = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 0.0)
    Js = J * d
    return d[:, None] * np.linalg.pinv(Js.T @ Js, rcond=1e-12) * d[None, :]


def update_gross(prob: Problem, fit: Fit) -> None:
    rc = fit.model_cal.residuals(fit.z, jacobian=False)
    prob.w_cal = (~gross_rows(rc.r, rc.row, fit.model_cal.obs.n)).astype(float)
    rv = fit.model_val.residuals(fit.z, jacobian=False)
    prob.keep_val = ~gross_rows(rv.r, rv.row, fit.model_val.obs.n)


def refit_with(prob: Problem, src: Fit, chosen: list) -> Fit:
    """``chosen`` fitted on ``prob``'s calibration rows from ``src`` (new atoms from zero), refitted once its gross
    rows are down-weighted."""
    P = prob.prep.space.size
    full = prob.fit(src.z[:P], chosen, psi_init(src, chosen))
    update_gross(prob, full)
    return prob.fit(full.z[:P], chosen, psi_init(full, chosen))


def psi_init(fit: Fit, chosen: list) -> list[np.ndarray]:
    """Start values of the reduced coordinates: the current fit's for atoms already in, zero for new ones."""
    prev = {t.atom.key: fit.z[fit.model_cal.offsets[k]:fit.model_cal.offsets[k + 1]]
            for k, t in enumerate(fit.model_cal.terms)}
    return [prev.get(a.key, np.zeros(B.shape[1])) if prev.get(a.key) is not None and prev[a.key].size == B.shape[1]
            else np.zeros(B.shape[1]) for a, B in chosen]


def backward(prob: Problem, fit: Fit, alpha_select: float, sizes: dict) -> tuple[Fit, list[Atom]]:
    """Drop atoms whose removal costs no significant calibration evidence (one pass, weakest first)."""
    dropped: list[Atom] = []
    changed = True
    while changed and len(fit.chosen) > 1:
        changed = False
        rc = fit.model_cal.residuals(fit.z)
        sw = np.sqrt(prob.w_cal[rc.row])
        C = covariance(rc.J[:, fit.free] * sw[:, None])
        pos = {int(f): k for k, f in enumerate(fit.free)}
        worst = None
        for k, (a, B) in enumerate(fit.chosen):
            idx = [pos[i] for i in range(fit.model_cal.offsets[k], fit.model_cal.offsets[k + 1])]
            psi = fit.z[fit.model_cal.offsets[k]:fit.model_cal.offsets[k + 1]]
            Ck = C[np.ix_(idx, idx)]
            d = float(psi @ np.linalg.lstsq(Ck, psi, rcond=None)[0])  # chi2 cost of removing it (Wald)
            lp = chi2_logsf(d / prob.evidence_scale, len(idx)) + np.log(sizes[a.pool])
            if lp >= np.log(alpha_select) and (worst is None or lp > worst[0]):
                worst = (lp, k)
        if worst is not None:
            k = worst[1]
            dropped.append(fit.chosen[k][0])
            chosen = [c for i, c in enumerate(fit.chosen) if i != k]
            fit = prob.fit(fit.z[: prob.prep.space.size], chosen, psi_init(fit, chosen))
            changed = True
    return fit, dropped


def alternatives(best: Scored, scored: list[Scored], *, share: float = 0.9, log_evidence: float = 5.0) -> list[dict]:
    """Atoms the data cannot tell apart from ``best``: they reproduce >= ``share`` of its fitted residual and
    their evidence is within ``e^log_evidence`` of it."""
    f = best.fitted
    nf = float(f @ f)
    out = []
    for s in scored:
        if s is best or nf <= 0 or s.basis.shape[1] > best.basis.shape[1]:
            continue
        if 0.5 * (best.dchi2 - s.dchi2) > log_evidence:
            continue
        Qs, _ = np.linalg.qr(s.Ep)
        cover = float(np.sum((Qs.T @ f) ** 2)) / nf
        if cover >= share:
            out.append({"of": best.atom.label, "alternative": s.atom.label, "family": s.atom.family,
                        "channel": s.atom.channel, "target": s.atom.target,
                        "delta_chi2": s.dchi2, "delta_chi2_chosen": best.dchi2, "share_reproduced": cover})
    out.sort(key=lambda d: -d["delta_chi2"])
    return out[:3]



def prefer_play(prob: Problem, fit: Fit, scored: list[Scored], pool_sizes: dict[str, int]) -> list[Scored]:
    """Each scored sign backlash (the offset follows the direction of the last move) replaced by the backlash as
    a play operator with the half clearance that explains most (``PLAY_HALF_DEG``, then refined), when that
    explains significantly more: beyond ``chi2_1`` at 1 % / the number of clearances tried, on at least 3
    calibration rows where the two differ (rows after a move shorter than the clearance, which does not switch
    the side). Both are the one backlash of that joint, so they compete as one candidate: a joint with a
    clearance and short moves is not left to an unnamed function of its last move."""
    from .atoms import PLAY_HALF_DEG, play_backlash

    out = []
    for s in scored:
        if s.atom.family != "backlash" or {f.kind for f in s.atom.features} != {"sign"}:
            out.append(s)
            continue
        j = s.atom.features[0].j
        trial = score_atoms(prob, fit, [play_backlash(j, hd * np.pi / 180) for hd in PLAY_HALF_DEG], pool_sizes,
                            exact_top=len(PLAY_HALF_DEG))
        top = max(trial, key=lambda t: t.dchi2, default=None)
        better = top is not None and (top.dchi2 - s.dchi2) / prob.evidence_scale >= dists.chi2_isf(0.01 / len(PLAY_HALF_DEG), 1)
        if better:
            f_sign = prob.features(s.atom)[prob.rows_cal, 0]
            f_play = prob.features(top.atom)[prob.rows_cal, 0]
            better = int(np.sum(np.abs(np.abs(f_play) - np.abs(f_sign)) > 0.5)) >= 3
        out.append(top if better else s)
    return out


def refine(prob: Problem, fit: Fit, s: Scored, pool_sizes: dict[str, int]) -> Scored:
    """An atom with a continuous constant found on a coarse grid, moved to the value that explains most: a change
    point to the row time between its grid neighbours (the step's time is a parameter of the effect, not of the
    grid); a time constant (``exp``, ``lag``), a move width (``lastmove``), a clearance (``play``) or a period
    in time (``sin``/``cos`` of ``t_s``) over a log grid around it, zoomed twice, then to the maximum of the
    evidence within the last grid step (bounded scalar search: a play's clearance must be right to a fraction of
    a per cent, or the rows after short moves are mispredicted by that fraction of the clearance). Other atoms
    come back as they are."""
    kinds = {f.kind for f in s.atom.features}
    if "step" in kinds:
        return _refine_step(prob, fit, s, pool_sizes)
    if kinds == {"hinge"}:
        return _refine_hinge(prob, fit, s, pool_sizes)
    if s.atom.pool == "scan" and kinds <= {"sin", "cos"}:
        # an order off the whole cycles per joint turn only where terms are confirmed on another session
        return _refine_order(prob, fit, s, pool_sizes) if prob.cross_session else s
    timely = all(getattr(f, "ch", None) in ("t_s", "row") for f in s.atom.features)
    if any(_has(f, "tau") for f in s.atom.features):  # exp, lag, heat, settle, a field warming up
        key = "tau"
    elif "lastmove" in kinds or "play" in kinds:
        key = "w" if "lastmove" in kinds else "h"
    elif kinds <= {"sin", "cos"} and timely:
        key = "k"
    else:
        key = None
    if key is None:
        return s
    span_max = 4.0 if key != "k" else 1.25  # a period is sharp: zoom within +-25 % of the grid's
    best = s
    v0 = _constant(s.atom.features, key)
    for span in (span_max, span_max ** 0.25):
        vals = [v0 * span ** x for x in np.linspace(-1, 1, 9) if x != 0]
        trial = [_with_constant(best.atom, key, v) for v in vals]
        scored = score_atoms(prob, fit, trial, pool_sizes, exact_top=len(trial))
        top = max(scored, key=lambda t: t.dchi2, default=None)
        if top is not None and top.dchi2 > best.dchi2:
            best = top
        v0 = _constant(best.atom.features, key)
    return _polish(prob, fit, best, key, span_max ** (0.25 * 0.25), pool_sizes)


def polish_in_fit(prob: Problem, fit: Fit, k: int, key: str, ratio: float = 1.05) -> Fit:
    """The kept atom ``k`` of ``fit`` with its constant ``key`` moved to the minimum of the calibration chi2 of the
    whole model refitted (Gauss-Newton, the joint terms applied exactly), within a factor ``ratio`` of its value
    (bounded Brent search on its log, to 1e-4 of it). The linearised evidence that placed it is biased at the
    noise level when the effect is large (a 0.3 deg clearance moves the plate ~4 mm: its second-order term is
    ~10 um), and a clearance must be right to a fraction of a per cent."""
    from scipy.optimize import minimize_scalar

    atom, B = fit.chosen[k]
    v0 = _constant(atom.features, key)
    x = fit.z[: prob.prep.space.size]
    best = [fit]

    def cost(u: float) -> float:
        chosen = list(fit.chosen)
        chosen[k] = (_with_constant(atom, key, v0 * np.exp(u)), B)
        f = prob.fit(x, chosen, _psi_like(fit, chosen))
        if f.chi2 < best[0].chi2:
            best[0] = f
        return f.chi2

    minimize_scalar(cost, bounds=(-np.log(ratio), np.log(ratio)), method="bounded", options={"xatol": 1e-4})
    return best[0]


def _psi_like(fit: Fit, chosen: list) -> list[np.ndarray]:
    """Start values: the fit's reduced coordinates position by position (a term whose constant changed keeps
    its coefficients)."""
    return [fit.z[fit.model_cal.offsets[k]:fit.model_cal.offsets[k + 1]].copy() for k in range(len(chosen))]


def _polish(prob: Problem, fit: Fit, s: Scored, key: str, ratio: float, pool_sizes: dict[str, int],
            make=None) -> Scored:
    """``s`` with its constant ``key`` moved to the maximum of the calibration evidence within a factor ``ratio``
    of its value (bounded Brent search on the log of the constant, to 1e-4 of it); ``make(atom, v)`` builds the
    atom with the constant ``v`` (default: :func:`_with_constant`)."""
    from scipy.optimize import minimize_scalar

    make = make or (lambda atom, v: _with_constant(atom, key, v))
    v0 = _constant(s.atom.features, key)
    best = [s]

    def cost(u: float) -> float:
        got = score_atoms(prob, fit, [make(s.atom, v0 * np.exp(u))], pool_sizes, exact_top=1)
        if not got:
            return 0.0
        if got[0].dchi2 > best[0].dchi2:
            best[0] = got[0]
        return -got[0].dchi2

    minimize_scalar(cost, bounds=(-np.log(ratio), np.log(ratio)), method="bounded", options={"xatol": 1e-4})
    return best[0]


def _with_order(atom: Atom, k: float) -> Atom:
    """A scanned cyclic atom with its order (cycles per joint turn) set to ``k``; channel and label to match."""
    k0 = atom.features[0].k
    feats = tuple(replace_atom(f, k=float(k)) for f in atom.features)
    ch = atom.features[0].ch
    return replace_atom(atom, features=feats, channel=f"sin/cos({k:.4g} {ch})",
                label=atom.label.replace(f"order {k0:.4g}", f"order {k:.4g}"), meta=dict(atom.meta, order=float(k)))


def _refine_order(prob: Problem, fit: Fit, s: Scored, pool_sizes: dict[str, int]) -> Scored:
    """A scanned cyclic order (half-order grid) moved to the order that explains most within half a grid step
    (a stage's ratio need not be a half-integer), zoomed twice, then polished within the last grid step."""
    best = s
    for half in (0.25, 0.06):
        k0 = best.atom.features[0].k
        trial = [_with_order(best.atom, k) for k in k0 + np.linspace(-half, half, 9) if k > 0 and k != k0]
        scored = score_atoms(prob, fit, trial, pool_sizes, exact_top=len(trial))
        top = max(scored, key=lambda t: t.dchi2, default=None)
        if top is not None and top.dchi2 > best.dchi2:
            best = top
    k0 = best.atom.features[0].k
    return _polish(prob, fit, best, "k", 1.0 + 0.015 / k0, pool_sizes, make=_with_order)


def widen(prob: Problem, fit: Fit, s: Scored, alpha_select: float, max_rank: int = 18) -> Scored:
    """An accepted atom was scored on at most 6 directions (a broad atom must not fit noise); its further
    directions above 1 % of a unit column are kept when together they add significant calibration evidence
    (``chi2_sf(Delta chi2_more - Delta chi2, extra) < alpha_select``): a frame swaying in time moves along its
    six axes with a sine and a cosine, twelve directions."""
    sb = scoring_basis(prob, fit)
    rc, sw, keep, Q = sb.rc, sb.sw, sb.keep, sb.Q
    F = prob.features(s.atom)[prob.rows_cal]
    E = raw_columns(fit.model_cal, s.atom, F, fit.z, rc)[keep] * sw[keep][:, None]
    B = reduced_basis(E, Q=Q, max_rank=max_rank)
    if B.shape[1] <= s.basis.shape[1]:
        return s
    EB = E @ B
    Ep = EB - Q @ (Q.T @ EB)
    psi, *_ = np.linalg.lstsq(Ep, s.r, rcond=None)
    fitted = Ep @ psi
    d = float(fitted @ fitted)
    if chi2_logsf(max(d - s.dchi2, 0.0) / prob.evidence_scale, B.shape[1] - s.basis.shape[1]) >= np.log(alpha_select):
        return s
    return Scored(s.atom, B, psi, d, s.logp_adj, s.r, E=EB, Ep=Ep)


def _has(f: Feature, key: str) -> bool:
    """Whether the feature ``f`` has the constant ``key`` (a field of its kind, set)."""
    return getattr(f, key, None) is not None


def _constant(features, key: str):
    """The constant ``key`` of the first of ``features`` that has it (:func:`_has`)."""
    return next(getattr(f, key) for f in features if _has(f, key))


def _with_constant(atom: Atom, key: str, v: float) -> Atom:
    """``atom`` with the constant ``key`` (``tau`` [s], ``w`` or ``h`` [rad], ``k`` [rad/s]) of its features set to
    ``v``; channel and label renamed to match."""
    old = _constant(atom.features, key)
    feats = tuple(replace_atom(f, **{key: float(v)}) if _has(f, key) else f for f in atom.features)
    if key == "tau":
        o, n = f"{old:.4g}", f"{v:.4g}"
    elif key == "k":
        o, n = f"{2 * np.pi / old:.4g}", f"{2 * np.pi / v:.4g}"
    elif key == "w" and atom.channel.endswith(" mm)"):
        o, n = f"{old * 1e3:.3g} mm", f"{v * 1e3:.3g} mm"  # a prismatic joint's move width
    else:
        o, n = f"{np.rad2deg(old):.3g} deg", f"{np.rad2deg(v):.3g} deg"
    return replace_atom(atom, features=feats, channel=atom.channel.replace(o, n), label=atom.label.replace(o, n))


def _refine_hinge(prob: Problem, fit: Fit, s: Scored, pool_sizes: dict[str, int]) -> Scored:
    """A one-sided pull found past a decile of its joint's range moved to the angle that explains most between the
    neighbouring deciles (bounded Brent search on the angle, to 1e-5 rad)."""
    from scipy.optimize import minimize_scalar

    from .atoms import HINGE_POINTS, hinge_atom, joint_words

    f0 = s.atom.features[0]
    j = int(f0.ch[1:])
    model = prob.prep.nominal
    prismatic = model.joint_kinds[j - 1] == "prismatic"
    x = prob.ctx.q[:, j - 1]
    grid = np.quantile(x, np.linspace(0, 1, HINGE_POINTS + 2))
    k = int(np.argmin(np.abs(grid - f0.at)))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    best = [s]

    def cost(at: float) -> float:
        got = score_atoms(prob, fit, [hinge_atom(j, at, f0.side, f0.p, f0.h, prismatic=prismatic,
                                                 words=joint_words(model, j))], pool_sizes, exact_top=1)
        if not got:
            return 0.0
        if got[0].dchi2 > best[0].dchi2:
            best[0] = got[0]
        return -got[0].dchi2

    if hi > lo:
        minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 1e-5})
    return best[0]


def _refine_step(prob: Problem, fit: Fit, s: Scored, pool_sizes: dict[str, int]) -> Scored:
    """A change point found on the coarse grid (deciles of the channel) moved to the row time between its grid
    neighbours that explains most: the step's time is a parameter of the effect, not of the grid."""
    f0 = next(f for f in s.atom.features if isinstance(f, Step))
    ch = f0.ch
    values = np.unique(feature_values((Pow(ch=ch, p=1, c=0.0, h=1.0),), prob.ctx,
                                      prob.prep.nominal)[:, 0])
    grid = np.quantile(values, np.linspace(0, 1, 11))
    k = int(np.argmin(np.abs(grid - f0.at)))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    cands = [v for v in values if lo < v < hi and v != f0.at]
    trial = []
    for v in cands:
        feats = tuple(replace_atom(f, at=float(v)) if isinstance(f, Step) else f for f in s.atom.features)
        label = s.atom.label.replace(s.atom.channel, f"step({ch} >= {v:.6g})")
        trial.append(replace_atom(s.atom, features=feats, channel=f"step({ch} >= {v:.6g})", label=label))
    scored = score_atoms(prob, fit, trial, pool_sizes, exact_top=len(trial)) if trial else []
    best = max(scored, key=lambda t: t.dchi2, default=None)
    return best if best is not None and best.dchi2 > s.dchi2 else s
