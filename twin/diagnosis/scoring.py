"""Scoring the candidates: the linearised calibration evidence of atoms against a fit (:func:`score_atoms`), the many
small dictionary atoms screened in batches and the strongest scored exactly, through per-row aggregates of the model
columns their features multiply (:mod:`twin.diagnosis.grams`).

Everything works on whitened residuals of :class:`~twin.diagnosis.extend.ExtendedModel` (per-axis noise of the
measurement frame, :class:`~twin.diagnosis.floor.NoiseFloor`).
"""

from __future__ import annotations

import functools
import weakref
from dataclasses import dataclass, field

import numpy as np

from ..runtime import thread_map
from .atoms import Atom
from .extend import AtomTerm, ExtendedModel, reduced_basis
from .features import Gated, Step
from .grams import block_stats, leading_eigh, product_grams, product_grams_wide, single_step, tail_sums
from .problem import Fit, Problem
from .structure import chi2_logsf

__all__ = ["raw_columns", "Scored", "ScoringBasis", "scoring_basis", "row_aggregates", "score_atoms", "memo_on_fit",
           "GATE_SUFFIX_MIN", "PRODUCT_BATCH_MAX"]


def raw_columns(model: ExtendedModel, atom: Atom, F: np.ndarray, z: np.ndarray, res) -> np.ndarray:
    """The whitened columns of ``atom`` with feature values ``F`` ``(n, K)`` on ``model``'s rows at ``z``, before any
    reduction (``res``: the model's residuals at ``z``, with their Jacobian)."""
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
    (:class:`ColumnStore`), and for a step in time (``1[t >= a]``, one per session start) as the sum of the
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
        # a place's atoms scored before against this basis (a round that rejected its candidates): the same sums
        key = ("screen", prob.threads, place, target, id(store), tuple(atoms[i].feature_key for i in ids))
        got = sb.memo.get(key)
        if got is None:
            at = {i: j for j, i in enumerate(ids)}
            got = sb.memo[key] = [(K, (at[st[0]], *st[1:])) for K, st in _group_stats(place, target, ids)]
        return [(K, (ids[st[0]], *st[1:])) for K, st in got]

    def _group_stats(place: str, target: str, ids: list[int]) -> list[tuple[int, tuple]]:
        got_all: list[tuple[int, tuple]] = []  # (width K, (atom index, nrm2 (K,), EtE (K, K), QtE (p, K), Etr (K,)))
        w, Qb, br = _screen_aggregates(prob, fit, sb, atoms[ids[0]])  # (n,), (n, p), (n,)
        steps, stored, rest = [], [], []
        for i in ids:
            if single_step(atoms[i]):
                steps.append(i)
            elif store is not None and store.has(atoms[i].feature_key):
                stored.append(i)
            else:
                rest.append(i)
        if steps:
            for i, got in zip(steps, _step_stats(prob, [atoms[i] for i in steps], w, Qb, br)):
                got_all.append((1, (i, *got)))
        if stored:
            got = store.stats((place, target), [atoms[i].feature_key for i in stored], w, Qb, br)
            for i, st in zip(stored, got):
                got_all.append((len(atoms[i].features), (i, *st)))
        by_width: dict[int, list[int]] = {}
        for i in rest:
            by_width.setdefault(len(atoms[i].features), []).append(i)
        for K, gi in by_width.items():
            F = np.stack([prob.features_cal(atoms[i]) for i in gi], axis=2)  # (n, K, g)
            for i, st in zip(gi, block_stats(F, w, Qb, br)):
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
    logs = _log_sizes(pool_sizes, atoms)
    return logp + np.array([logs[a.pool] for a in atoms])


def _log_sizes(pool_sizes: dict[str, int], atoms: list[Atom]) -> dict:
    """``np.log`` of the size of each pool of ``atoms`` (the Bonferroni factor of their p-values), once per pool."""
    return {k: np.log(pool_sizes[k]) for k in {a.pool for a in atoms}}


def _step_stats(prob: Problem, steps: list[Atom], w: np.ndarray, Qb: np.ndarray, br: np.ndarray) -> list:
    """:func:`block_stats` of one-step atoms ``1[ch >= at]``: sums of the aggregates over the rows with
    ``ch >= at``, read off suffix sums in the channel's order (one pass over the rows for all the steps)."""
    out: list = [None] * len(steps)
    by_ch: dict[str, list[int]] = {}
    for i, a in enumerate(steps):
        by_ch.setdefault(a.features[0].ch, []).append(i)
    for ch, idx in by_ch.items():
        order, v = prob.channel_order_cal(ch)
        A = np.concatenate([w[order, None], Qb[order], br[order, None]], axis=1)  # (n, p + 2)
        at = np.array([steps[i].features[0].at for i in idx], dtype=float)
        for i, s in zip(idx, tail_sums(A, np.searchsorted(v, at, side="left"))):
            out[i] = (s[:1], s[:1].reshape(1, 1), s[1:-1, None], s[-1:])
    return out


@dataclass(frozen=True)
class ScoringBasis:
    """What scoring atoms against a fit needs once: the calibration residuals with their Jacobian ``rc``, the
    square-root row weights per residual ``sw``, the residuals kept (weight > 0) ``keep``, an orthonormal basis
    ``Q`` of the free model columns (kept residuals) and the residual ``r`` projected off it; ``cache``: what the
    scoring derives from them once per place (:func:`_kept_base`, :func:`row_aggregates`); ``memo``: a place's
    atoms' sums and scores against this basis, by the atoms' features and the number of threads (kept while the
    basis lives: a round that rejected its candidates scores the rest of the same atoms against the same fit)."""

    rc: object
    sw: np.ndarray
    keep: np.ndarray
    Q: np.ndarray
    r: np.ndarray
    cache: dict = field(default_factory=dict, repr=False, compare=False)
    memo: dict = field(default_factory=dict, repr=False, compare=False)

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


def row_aggregates(prob: Problem, fit: Fit, sb: ScoringBasis, atom: Atom) -> tuple[np.ndarray, ...]:
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
    """The single-column form of :func:`row_aggregates` the screening uses: ``w`` ``(n,)``, ``Qb`` ``(n, p)``,
    ``br`` ``(n,)``."""
    W, QB, Br = row_aggregates(prob, fit, sb, atom)
    return W[:, 0, 0], QB[:, :, 0], Br[:, 0]


def scoring_basis(prob: Problem, fit: Fit) -> ScoringBasis:
    """The :class:`ScoringBasis` of ``fit`` under the problem's current row weights (cached on the fit). Only the
    newest basis keeps its per-place quantities (the selection scores against its latest fit; an older basis
    derives them again when asked)."""
    key = ("basis", id(prob.w_cal))
    got = fit.cache.get(key)
    if got is None:
        old = prob.newest_basis() if prob.newest_basis is not None else None
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
        prob.newest_basis = weakref.ref(got)
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
        # a place's atoms scored before against this basis (a round that rejected its candidates): the same numbers
        key = ("products", prob.threads, rel_tol, max_rank, tuple(a.feature_key for a in members),
               members[0].place, members[0].target, members[0].place == "plate" and members[0].varying_plate)
        got = sb.memo.get(key)
        if got is None:
            at = {id(a): j for j, a in enumerate(members)}
            got = sb.memo[key] = [(at[id(t[0])], *t[1:]) for t in _group_scores(members)]
        return [(members[t[0]], *t[1:]) for t in got]

    def _group_scores(members: list[Atom]) -> list[tuple]:
        pending = []
        W, QB, Br = row_aggregates(prob, fit, sb, members[0])  # (n, c, c), (n, p, c), (n, c)
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
            lam, V = leading_eigh(G, max_rank)  # descending
            sv = np.sqrt(np.maximum(lam, 0.0))
            rks = np.minimum(np.sum(sv > rel_tol * np.maximum(sv[:, :1], 1.0), axis=1), max_rank).tolist()
            has_any = np.any(has, axis=1).tolist()
            for i, a in enumerate(grp):
                rk = rks[i]
                if rk == 0 or not nonzero[i] or not has_any[i]:
                    continue
                Vr = V[i][:, :rk]
                lr = lam[i, :rk]
                proj = Vr.T @ e[i]
                pending.append((a, D[i][:, None] * Vr, proj / lr, float(np.sum(proj**2 / lr)), rk, float(np.sum(lr))))
        return pending

    pending = [t for got in thread_map(group_scores, list(groups.values()), prob.threads) for t in got]
    if not pending:
        return []
    logp = chi2_logsf(np.array([p[3] for p in pending]) / prob.evidence_scale, np.array([p[4] for p in pending]))
    logs = _log_sizes(pool_sizes, [p[0] for p in pending])
    return [Scored(a, B, psi, d, float(lp) + logs[a.pool], r, Q=Q,
                   columns=_column_maker(prob, fit, a, sb), ep_norm2=ep2)
            for (a, B, psi, d, _, ep2), lp in zip(pending, np.atleast_1d(logp))]


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
    """:func:`product_grams` of atoms that differ only in the moment they act from (:func:`_gate`: the same
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
    S = tail_sums(X, np.searchsorted(v, np.array([_gate(a)[1] for a in family]), side="left"))
    g = len(family)
    a0, a1, a2 = K * K * c * c, K * K * c * c + K * p * c, K * K * c * c + K * p * c + K * c
    EtE = S[:, :a0].reshape(g, K, K, c, c).transpose(0, 1, 3, 2, 4).reshape(g, KC, KC)
    QtE = S[:, a0:a1].reshape(g, K, p, c).transpose(0, 2, 1, 3).reshape(g, p, KC)
    Etr = S[:, a1:a2].reshape(g, KC)
    return list(zip(EtE, QtE, Etr, S[:, a2] > 0))


PRODUCT_BATCH_MAX = 1 << 23  # elements of the per-row feature products one batch builds at once (64 MB)


def _product_grams_bounded(prob: Problem, grp: list[Atom], F: np.ndarray, W: np.ndarray, QB: np.ndarray,
                           Br: np.ndarray) -> tuple[np.ndarray, ...]:
    """:func:`product_grams` with the per-row feature products of a batch held below ``PRODUCT_BATCH_MAX``
    elements: a batch beyond it is split into smaller batches of atoms; an atom too wide alone (a step at each of
    200 session starts) is evaluated on its distinct feature rows, the aggregates summed over the rows that share
    one (``sum_row F F^T (x) W = sum_distinct F F^T (x) sum_its_rows W``), or else over blocks of rows."""
    n, g, K = F.shape
    if n * g * K * K <= PRODUCT_BATCH_MAX:
        return product_grams(F, W, QB, Br)
    if n * K * K <= PRODUCT_BATCH_MAX:
        step = max(1, PRODUCT_BATCH_MAX // (n * K * K))
        parts = [product_grams(F[:, i:i + step], W, QB, Br) for i in range(0, g, step)]
        return tuple(np.concatenate(x, axis=0) for x in zip(*parts))
    parts = []
    for i, a in enumerate(grp):
        distinct = prob.distinct_rows_cal(a)
        if distinct is not None:
            Fu, U = distinct
            parts.append(product_grams_wide(Fu, (U @ W.reshape(n, -1)).reshape(-1, *W.shape[1:]),
                                             (U @ QB.reshape(n, -1)).reshape(-1, *QB.shape[1:]), U @ Br))
        else:
            parts.append(product_grams_wide(F[:, i], W, QB, Br))
    return tuple(np.concatenate(x, axis=0) for x in zip(*parts))


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


def _memo_key(prob: Problem, x, pins: list):
    """The key of one argument of a call :func:`memo_on_fit` keeps: a scored atom by its atom's content and its numbers'
    bytes, an atom by its content, arrays by their bytes, containers by their items, anything else by its identity
    (the object is kept in ``pins`` so its id is not reused while the key lives)."""
    if isinstance(x, Scored):
        pins.append(x.r)
        return ("scored", _memo_key(prob, x.atom, pins), x.basis.shape, x.basis.tobytes(), x.psi.tobytes(), x.dchi2,
                x.logp_adj, id(x.r))
    if isinstance(x, Atom):
        return ("atom", x.family, x.place, x.target, x.channel, x.label, x.pool, x.joints, x.feature_key,
                repr(sorted(x.meta.items())))
    if isinstance(x, np.ndarray):
        return ("array", x.shape, x.dtype.str, x.tobytes())
    if isinstance(x, dict):
        return ("dict", tuple((k, _memo_key(prob, v, pins)) for k, v in sorted(x.items())))
    if isinstance(x, (list, tuple)):
        return (type(x).__name__, tuple(_memo_key(prob, v, pins) for v in x))
    if x is None or isinstance(x, (bool, int, float, str)):
        return x
    pins.append(x)
    return ("id", id(x))


def memo_on_fit(fn):
    """``fn(prob, fit, *args, **kwargs)`` computed once per fit for equal arguments under the problem's current row
    weights, kept in ``fit.cache``: a selection round that rejected its candidates leaves the fit as it was, and the
    next round asks again for the same refinements and scans against it. Equal arguments: the same atoms (by content),
    scored atoms with the same numbers to the bit, the same other objects. The call must depend on nothing else of
    the problem than its rows, features and weights (``w_cal``, ``keep_val``, ``evidence_scale``, ``cross_session``),
    and must leave the problem as it found it. A result that is one of the arguments is returned as the argument of
    the new call (callers test ``refined is not s``); any other result is the same object on every hit. The number of
    threads is part of the key (a test compares a call on one thread with the same call on two)."""

    @functools.wraps(fn)
    def call(prob: Problem, fit: Fit, *args, **kwargs):
        pins: list = [prob.w_cal, prob.keep_val]
        key = (fn.__qualname__, id(prob), id(prob.w_cal), id(prob.keep_val), prob.evidence_scale, prob.cross_session,
               prob.threads,
               _memo_key(prob, args, pins), _memo_key(prob, kwargs, pins))
        store = fit.cache.setdefault("memo", {})
        hit = store.get(key)
        if hit is not None:
            got, which, _ = hit
            return args[which] if which is not None else got
        got = fn(prob, fit, *args, **kwargs)
        which = next((i for i, a in enumerate(args) if got is a), None)
        store[key] = (None if which is not None else got, which, pins)
        return got
    return call
