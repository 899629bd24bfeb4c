"""The state of the selection: the problem every round shares (observations, the three blocks of rows, features,
weights; :class:`Problem`), a fitted extended model (:class:`Fit`), and the fits' moves the rounds make (refit with
other atoms, gross rows down-weighted, start values, the covariance of whitened columns).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, field

import numpy as np

from ..estimator.core import Prepared
from ..estimator.memo import KeptResults, array_key
from ..estimator.solvers import gauss_newton
from .atoms import MIN_ROWS, MIN_SIDE, Atom
from .candidates import RowContext
from .extend import AtomTerm, ExtendedModel, error_stats
from .floor import NoiseFloor
from .grams import block_stats, single_step
from .structure import StructureTest, fit_block_test, gross_rows, structure_test
from .values import feature_channel, feature_values, history_unknown

__all__ = ["Fit", "FIT_FTOL", "THREADS_MIN_ROWS", "MODELS_KEPT", "Problem", "ColumnStore", "covariance", "update_gross",
           "refit_with", "psi_init", "held_out_rms", "common_chi2", "runs_of_length"]


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
MODELS_KEPT = 16  # extended models a problem keeps for the same atoms and bases (Problem.model)


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
        self.newest_basis: weakref.ref | None = None  # the scoring basis that keeps its per-place quantities
        self._orders: dict = {}
        self._store: ColumnStore | None = None
        self._cache: dict = {}
        self._models = KeptResults(MODELS_KEPT, 0)  # the latest models, by block and (atom, basis) (Problem.model)
        self.w_cal = np.ones(self.obs_cal.n)
        # calibration rows at weight 0 because a kept term lacks their history (update_gross), not as gross
        self.history_out = np.zeros(self.obs_cal.n, dtype=bool)
        self.keep_val = np.ones(self.obs_val.n, dtype=bool)
        # the evidence of a term is its Delta chi2 over this: 1 when the floor is the scatter a correct model leaves;
        # the geometric fit's residual variance per degree of freedom when the floor is only a lower bound of it
        # (a motion-capture system's marker noise, below the robot's own pose-to-pose scatter)
        self.evidence_scale = 1.0
        # the confirmation rows are sessions the calibration rows do not contain (set by the diagnosis)
        self.cross_session = False

    def features(self, atom: Atom) -> np.ndarray:
        """Feature values ``(n_dataset_rows, K)`` of an atom on every row of the dataset (cached)."""
        key = atom.feature_key
        F = self._F.get(key)
        if F is None:
            F = feature_values(atom.features, self.ctx, self.prep.nominal, self._cache)
            self._F[key] = F
        return F

    def features_cal(self, atom: Atom) -> np.ndarray:
        """Feature values ``(n_cal, K)`` of an atom on the calibration rows (cached; the values on every row are
        kept only when :meth:`features` asks for them: most atoms are only ever scored on the calibration rows)."""
        key = atom.feature_key
        F = self._Fc.get(key)
        if F is None:
            F_all = self._F.get(key)
            if F_all is None:
                F_all = feature_values(atom.features, self.ctx, self.prep.nominal, self._cache)
            F = self._Fc[key] = F_all[self.rows_cal]
        return F

    def seed_features(self, values: dict, ctx: RowContext, model) -> None:
        """Take the feature values ``(n_dataset_rows, K)`` of atoms computed elsewhere (``values``, by atom) as their
        calibration-row values (:meth:`features_cal`), when they were computed on this problem's rows and nominal
        robot (``ctx``, ``model``); else nothing."""
        if ctx is not self.ctx or model is not self.prep.nominal:
            return
        for atom, F in values.items():
            self._Fc.setdefault(atom.feature_key, F[self.rows_cal])

    def inner_features_cal(self, inner: tuple) -> np.ndarray:
        """Values ``(n_cal, K)`` of the features inside gated features (:func:`twin.diagnosis.scoring._gate`) on the calibration rows
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
            v = np.asarray(feature_channel(self.ctx, None, ch), dtype=float)[self.rows_cal]
            order = np.argsort(v, kind="stable")
            got = self._orders[key] = (order, v[order])
        return got

    def column_store(self, atoms: list[Atom]) -> "ColumnStore | None":
        """The store of the feature sets the screening multiplies most (:class:`ColumnStore`), built from the
        first large call (the whole pool) and kept; None until then."""
        if self._store is None and len(atoms) >= ColumnStore.MIN_ATOMS:
            self._store = ColumnStore(self, atoms)
        return self._store

    def distinct_rows_cal(self, atom: Atom) -> tuple[np.ndarray, object] | None:
        """The distinct feature rows ``(u, K)`` of an atom on the calibration rows and the sparse ``(u, n_cal)``
        matrix summing a per-row quantity over the rows that share each, when there are at most half as many
        distinct rows as rows (steps, indicators, sessions); else None (cached)."""
        from scipy import sparse

        key = atom.feature_key
        if key not in self._Fu:
            F = self.features_cal(atom)
            Fu, inv = np.unique(F, axis=0, return_inverse=True)
            n = F.shape[0]
            self._Fu[key] = None if 2 * len(Fu) > n else (
                Fu, sparse.csr_matrix((np.ones(n), (inv.ravel(), np.arange(n))), shape=(len(Fu), n)))
        return self._Fu[key]

    def model(self, chosen: list, block: str) -> ExtendedModel:
        """The extended model with ``chosen`` atoms on the rows of ``block`` (``cal``, ``val``, ``rep``). The latest
        ``MODELS_KEPT`` are kept and given again for the same atoms and bases (their evaluations are kept by model: a
        refit starts where the previous fit of the same atoms ended)."""
        obs, rows = {"cal": (self.obs_cal, self.rows_cal), "val": (self.obs_val, self.rows_val),
                     "rep": (self.obs_rep, self.rows_rep)}[block]
        if obs is None:
            raise ValueError(f"block {block!r}: this problem has no such rows")
        key = (block, tuple((id(a), array_key(B)) for a, B in chosen))

        def build() -> ExtendedModel:
            terms = [AtomTerm(a, self.features(a)[rows], B) for a, B in chosen]
            return ExtendedModel(self.prep.space, obs, terms, self.floor.axis_sigma)

        # the model holds its atoms (their identities in the key stay theirs while it is kept); its size is not
        # counted (it references the problem's arrays)
        got = self._models.get(key)
        return got if got is not None else self._models.put(key, build(), nbytes=0)

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


class ColumnStore:
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
            if single_step(a):
                continue
            key = a.feature_key
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
        """Whether the feature set ``key`` (:meth:`Problem.feature_key`) is stored."""
        return key in self.index

    def stats(self, place: tuple, keys: list[str], w: np.ndarray, Qb: np.ndarray, br: np.ndarray) -> list:
        """:func:`block_stats` of the stored sets ``keys`` against one place's aggregates (every set of a block
        the place uses is multiplied: the blocks are what the places share)."""
        need: dict[int, list[tuple[int, int]]] = {}
        for i, k in enumerate(keys):
            b, j = self.index[k]
            need.setdefault(b, []).append((i, j))
        out: list = [None] * len(keys)
        for b, items in need.items():
            F = self.blocks[b][1]
            if 4 * len(items) < F.shape[2]:  # a few sets of a large block: those alone
                got = block_stats(F[:, :, [j for _, j in items]], w, Qb, br)
                for (i, _), st in zip(items, got):
                    out[i] = st
                continue
            got = block_stats(F, w, Qb, br)
            for i, j in items:
                out[i] = got[j]
        return out


def covariance(J: np.ndarray) -> np.ndarray:
    """``(J^T J)^+`` of whitened columns, column-scaled first (geometric and effect columns differ by many
    orders of magnitude: an unscaled pseudo-inverse truncates the small ones)."""
    d = np.linalg.norm(J, axis=0)
    d = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 0.0)
    Js = J * d
    return d[:, None] * np.linalg.pinv(Js.T @ Js, rcond=1e-12) * d[None, :]


def update_gross(prob: Problem, fit: Fit) -> None:
    """The problem's gross rows set from ``fit``: calibration rows at weight 0 (``w_cal``) and confirmation rows left
    out of the tests (``keep_val``), by :func:`~twin.diagnosis.structure.gross_rows` of each block's residuals.

    Calibration rows whose history a term of ``fit`` needs and lacks (:func:`~twin.diagnosis.values.history_unknown`:
    a backlash's side before its joint first moves) are at weight 0 too (``history_out``): the term reads 0 there,
    so those rows carry its whole size unexplained, which the geometry's frames or a change would otherwise absorb.
    Only runs of such rows of 2 up to a change's side (``max(MIN_ROWS, MIN_SIDE n)``: the first rows, a restart's):
    a joint held still for a long stretch holds one unknown side there, which its zero takes up; a lone row's unknown
    side is a misfit no change can read as a state (a change needs ``MIN_ROWS`` a side), while its geometry counts."""
    rc = fit.model_cal.residuals(fit.z, jacobian=False)
    out = runs_of_length(history_unknown([a.features for a, _ in fit.chosen], prob.ctx)[prob.rows_cal], 2,
                         max(MIN_ROWS, int(np.ceil(MIN_SIDE * prob.obs_cal.n))))
    prob.history_out = out
    prob.w_cal = (~(gross_rows(rc.r[~out[rc.row]], rc.row[~out[rc.row]], fit.model_cal.obs.n) | out)).astype(float)
    rv = fit.model_val.residuals(fit.z, jacobian=False)
    prob.keep_val = ~gross_rows(rv.r, rv.row, fit.model_val.obs.n)


def runs_of_length(flag: np.ndarray, least: int, most: int) -> np.ndarray:
    """``flag`` ``(n,)`` bool with only its runs of consecutive ``True`` from ``least`` to ``most`` long kept."""
    flag = np.asarray(flag, bool)
    edges = np.flatnonzero(np.diff(np.concatenate(([0], flag.astype(np.int8), [0]))))
    out = np.zeros_like(flag)
    for a, b in zip(edges[::2], edges[1::2]):
        if least <= b - a <= most:
            out[a:b] = True
    return out


def common_chi2(a: Fit, b: Fit) -> float:
    """The calibration chi2 of fit ``a`` less that of fit ``b`` (both on one problem's rows), every row counted in both
    but those both set aside as gross (two fits' own chi2 weigh the rows each sets aside)."""
    ra, rb = a.model_cal.residuals(a.z, jacobian=False), b.model_cal.residuals(b.z, jacobian=False)
    n = a.model_cal.obs.n
    w = (~(gross_rows(ra.r, ra.row, n) & gross_rows(rb.r, rb.row, n))).astype(float)
    return float(np.sum(w[ra.row] * ra.r ** 2) - np.sum(w[rb.row] * rb.r ** 2))


def held_out_rms(prob: Problem, fit: Fit) -> float:
    """The position RMS [mm] of ``fit``'s prediction on ``prob``'s confirmation rows (the held-out rows it kept)."""
    return float(error_stats(fit.model_val, fit.z, prob.keep_val)["position_mm"]["rms"])


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
