"""Terms judged on configurations as well as on time: the harmonic orders a campaign's sampling of each joint
supports, and the confirmation of a term on rows whose joint values the rows that fitted it did not sample.

The held-out rows are a later block of time (:mod:`twin.diagnosis.blocks`). That catches a term that describes one
stretch of the campaign, not one that describes its configurations: the later rows of a campaign revisit the joint
values of its earlier rows (a grid takes each joint to a few values, again and again), so a term that matches the
pattern of the sampled values holds on them and says nothing of the values between. Two rules, each a pure function
of the commanded joints of the rows that fit:

* **The orders a joint's sampling supports** (:func:`joint_sampling`, :func:`offered`). On the rows' values
  ``x_i`` [rad] of a joint, the harmonics of orders ``n`` and ``m`` (``e^{i n x}``, ``e^{i m x}``) have the
  normalised cross products ``mean_i e^{i (n - m) x_i}`` and ``mean_i e^{i (n + m) x_i}``: their moduli are the
  sampling's *spectral window* ``W(d) = |mean_i e^{i d x_i}|`` at ``d = |n - m|`` and ``n + m``. Near ``d = 0`` it
  is near 1 (the main lobe: over a range ``R`` orders closer than about ``2 pi / R`` look alike on the rows and
  between them alike) and beyond it small for values spread at random (about ``1 / sqrt(rows)``). Values on a grid
  of step ``D`` bring it back to 1 at ``d = 2 pi / D``: there the orders ``n`` and ``2 pi / D - n`` take the same
  values on every row and differ between them (aliasing). The *alias frequency* ``d_a`` is the smallest whole
  ``d`` past the main lobe (past the first ``d`` with ``W(d) < ALIAS_COHERENCE``) with ``W(d) >= ALIAS_COHERENCE``;
  an order ``n`` is then told from every lower order (``n + m < d_a``) and from itself shifted (``2 n < d_a``) up to
  ``n_max = ceil(d_a / 2) - 1``, the joint's highest supported order (Nyquist's ``pi / D`` on a regular grid; none
  when the window never returns, as on random poses). A harmonic above it is not offered.
* **Confirmation between the sampled values** (:func:`block_widths`, :func:`configuration_folds`,
  :func:`fold_confirmation`). The values of each joint a term reads (:func:`joints_read`) are cut into groups where
  consecutive values are farther apart than twice the rows' mean spacing (:func:`value_groups`: a grid's node with
  its repeats and jitter is one group), and the groups into blocks of the term's own scale: one period of its
  harmonic of that joint (a block holds every phase of it), else a tenth of the range. A row's *fold* is the sum of
  its blocks' numbers over those joints modulo ``G = min(FOLDS, blocks)``, so that every fold's blocks lie between
  blocks of other folds, in each joint the term reads. Each fold in turn is left out, and the rows of the others
  make the choice again, as the selection made it, among the term and its rivals (the atoms the round scored at the
  same place reading the same joints whose evidence on every row is within :data:`RIVAL_MARGIN` of the term's: the
  other orders of a harmonic the rows barely tell from it): a term chosen for the pattern of the values it was
  fitted on is not chosen again by other values, or predicts nothing between them. The one chosen and the
  model (its columns ``A``: geometry and the terms kept so far, linearised at the current fit) fitted on those rows
  predict the fold's rows, ``u = A (beta - beta_0) + E psi`` (the term with the model re-adjusting to it;
  ``beta_0`` the model without it), against the fold's residual without the term ``e = r - A beta_0``. Per row
  ``c_k = e_k . u_k``, summed over the rows of one configuration (the term's joint values to within a twentieth of
  a block: a grid value's rows share one draw of whatever pattern it has, and count once); the term holds between
  the sampled values when Wilcoxon's signed-rank ``z`` of these sums exceeds ``z_min``, also without the most
  favourable one, and the left-out rows' residual norm drops (:data:`Z_MIN`, 2: nine grid values all in favour score
  ``z = 2.67``). Under the null (the term fits the pattern of the sampled values
  only) a fold's prediction is unrelated to its rows' residual and ``z ~ N(0, 1)``; a harmonic that is the robot's
  (one amplitude and phase over the joint's range)
  predicts every fold from the others. A term that reads no joint angle (of time, of the motion history, of the
  load or of the measured points) or whose joints' values make fewer than :data:`MIN_BLOCKS` blocks (a harmonic
  whose period exceeds a third of the range) is not judged here.

Everything here is arrays in, arrays out (rad, whitened residuals); the diagnosis calls it from its selection round.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scipy.special import gammaln

from ..estimator.distributions import chi2_logsf
from ..units import rad_to_deg
from .features import Feature, Hinge, Pow, Prod, Sin, Cos
from .structure import signed_rank_z

__all__ = [
    "ALIAS_COHERENCE",
    "Z_MIN",
    "RIVAL_MARGIN",
    "FOLDS",
    "MIN_BLOCKS",
    "UNIT_DIVISIONS",
    "ConfigurationFolds",
    "SPLIT_SPACINGS",
    "SAMPLING_RULE",
    "JointSampling",
    "FoldConfirmation",
    "spectral_window",
    "alias_frequency",
    "max_order",
    "value_groups",
    "joint_sampling",
    "sampling_report",
    "harmonic_orders",
    "offered",
    "joints_read",
    "block_widths",
    "configuration_folds",
    "fold_confirmation",
]

ALIAS_COHERENCE = 0.9  # W(d) from which two orders d apart (or summing to d) are one function on the rows
FOLDS = 5  # folds of the joint values a term is confirmed on (fewer when its joints have fewer blocks)
# [normal score] a term is confirmed between the sampled values beyond this: a second check of a term already
# significant on the calibration rows and confirmed on a later block of time, at the level of one test (2.3 %, one
# sided), not of a search; on a grid of 17 values it keeps a true harmonic on 39 of 40 draws and a harmonic chosen for
# a pattern of the values on 1 of 40 (3.0: 20 and 0 of 40; tests/test_diagnosis_configurations.py)
Z_MIN = 2.0
# [natural log of p] the rivals of a term whose choice is made again on each fold: those whose pool-adjusted p-value
# on every row is within this of the term's (the rows cannot tell them apart by more: as CATALOGUE_MARGIN, by which
# an unnamed term must lead a named one). A term ahead of every rival by more is judged alone; a pattern of a
# grid's values is fitted by the best of many near-equal harmonics, and with them re-chosen per fold it passes on
# 3-5 of 40 draws instead of 12-21 of 40 (tests/test_diagnosis_configurations.py)
RIVAL_MARGIN = 10.0
UNIT_DIVISIONS = 20  # a term's configuration: its joints' values to within a twentieth of a block (of its period)
MIN_BLOCKS = 3  # fewest blocks of a joint's values a term is confirmed between (two: one predicts the other only)
SAMPLING_RULE = ("per revolute joint, from the rows that fit: the spectral window W(d) = |mean exp(i d q)| of its "
                 "values; the alias frequency is the smallest whole d past the main lobe with W(d) >= 0.9 (orders n "
                 "and d - n take the same values on the rows); harmonics are offered up to ceil(d / 2) - 1 (none "
                 "above), every order when W never returns; a term of joint angles is also confirmed on folds of "
                 "blocks of its joints' values (one period of its harmonic wide) it was not fitted on")


@dataclass(frozen=True)
class JointSampling:
    """How the rows that fit sampled one joint: ``joint`` (1-based), ``revolute``, ``distinct_values``, ``groups``
    (:func:`value_groups`), ``range_deg``, ``alias_frequency`` (cycles per joint turn, :func:`alias_frequency`;
    None: none up to ``checked_to``) and
    ``max_order`` (the highest harmonic order the sampling supports; None: every order up to ``checked_to``, or a
    prismatic joint)."""

    joint: int
    revolute: bool
    distinct_values: int
    groups: int
    range_deg: float
    alias_frequency: int | None
    max_order: int | None
    checked_to: int

    def to_dict(self) -> dict:
        return {"joint": self.joint, "revolute": self.revolute, "distinct_values": self.distinct_values,
                "groups_of_values": self.groups, "range_deg": self.range_deg,
                "alias_frequency": self.alias_frequency, "max_order": self.max_order}


@dataclass(frozen=True)
class FoldConfirmation:
    """A term confirmed on folds of the joint values it reads (:func:`fold_confirmation`): ``z`` (Wilcoxon's
    signed-rank normal score of the per-row ``c_k``), ``z_without_best_row``, ``better`` (the left-out rows' residual
    norm drops), the number of ``folds``, of folds whose rows outside chose the term itself again (``rechosen``; a
    rival predicted the others) and of ``rows`` scored, and ``passed``."""

    z: float
    z_without_best_row: float
    better: bool
    folds: int
    rechosen: int
    rows: int
    passed: bool

    @property
    def decision(self) -> str:
        """The selection's words for a term that did not pass."""
        return (f"holds only at the sampled configurations (folds of its joints' values left out: z = {self.z:.2f} over "
                f"{self.rows} configurations, error {'reduced' if self.better else 'not reduced'}, chosen again on "
                f"{self.rechosen} of {self.folds} folds)")


def _values(x) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    if x.ndim != 1 or not np.all(np.isfinite(x)):
        raise ValueError(f"joint values must be a finite 1-D array, got shape {x.shape}")
    return x


def spectral_window(x, d) -> np.ndarray:
    """``W(d) = |mean_i exp(i d x_i)|`` of values ``x`` ``(n,)`` [rad] at frequencies ``d`` ``(k,)`` [cycles per
    turn]: the modulus of the normalised cross product, on these values, of two harmonics whose orders differ (or
    sum) by ``d``."""
    x = _values(x)
    d = np.asarray(d, dtype=float)
    if x.size == 0:
        raise ValueError("spectral_window needs at least one value")
    # in chunks of frequencies: (k, n) complex phases for thousands of rows
    out = np.empty(d.size)
    for s in range(0, d.size, 64):
        ph = np.outer(d[s:s + 64], x)
        out[s:s + 64] = np.hypot(np.cos(ph).mean(axis=1), np.sin(ph).mean(axis=1))
    return out


def alias_frequency(x, d_max: int) -> int | None:
    """The smallest whole ``d <= d_max`` past the main lobe of ``x``'s spectral window (past the first ``d`` with
    ``W(d) < ALIAS_COHERENCE``) where ``W(d) >= ALIAS_COHERENCE`` (the values sit at one phase of the harmonic of
    order ``d``: orders summing to ``d`` alias); None when there is none (or the window never leaves its main lobe:
    the values span too little for any order to repeat, which the scan's own range rule covers)."""
    if not (isinstance(d_max, (int, np.integer)) and d_max >= 1):
        raise ValueError(f"d_max must be a positive integer, got {d_max!r}")
    d = np.arange(1, int(d_max) + 1)
    W = spectral_window(x, d)
    low = np.flatnonzero(W < ALIAS_COHERENCE)
    if low.size == 0:
        return None
    back = np.flatnonzero(W[low[0]:] >= ALIAS_COHERENCE)
    return int(d[low[0] + back[0]]) if back.size else None


def max_order(alias: int | None) -> int | None:
    """The highest harmonic order told apart from every lower one and from itself shifted, given the alias frequency
    ``alias`` (``n + m < alias`` for every ``m <= n``): ``ceil(alias / 2) - 1``; None (no bound) without one."""
    return None if alias is None else int(np.ceil(alias / 2)) - 1


def _distinct(x: np.ndarray) -> np.ndarray:
    # values closer than 1e-9 rad are one commanded value
    u = np.unique(x)
    if u.size > 1:
        u = u[np.concatenate([[True], np.diff(u) > 1e-9])]
    return u


SPLIT_SPACINGS = 2.0  # a new group of values starts past this many mean spacings of the rows (range / (rows - 1))


def _group_labels(u: np.ndarray, rows: int) -> np.ndarray:
    """Group numbers of the sorted distinct values ``u`` of ``rows`` rows: a new group where consecutive values are
    farther apart than ``SPLIT_SPACINGS`` times the rows' mean spacing (their range over ``rows - 1``). A grid's
    nodes are apart by far more than that (its rows crowd at them) and the jitter and repeats around a node by far
    less; values spread at random exceed it between about one in eight neighbours (groups of a few)."""
    if u.size < 2:
        return np.zeros(u.size, dtype=int)
    gaps = np.diff(u)
    split = SPLIT_SPACINGS * (u[-1] - u[0]) / max(rows - 1, 1)
    return np.concatenate([[0], np.cumsum(gaps > split)]).astype(int)


def value_groups(x) -> np.ndarray:
    """Group numbers ``(n,)`` of values ``x`` ``(n,)`` [rad], in the order of the values: a new group starts where
    consecutive distinct values are farther apart than ``SPLIT_SPACINGS`` times the rows' mean spacing
    (:func:`_group_labels`): a grid's node (its repeats and the jitter around it) is one group, values spread at
    random make groups of a few."""
    x = _values(x)
    u = _distinct(x)
    label_u = _group_labels(u, x.size)
    return label_u[np.clip(np.searchsorted(u, x - 1e-9), 0, u.size - 1)].astype(int)


def joint_sampling(q, revolute, *, max_order_checked: int = 150) -> tuple[JointSampling, ...]:
    """Per joint, how the rows ``q`` ``(n, N)`` [rad] sampled it (:class:`JointSampling`): the alias frequency of its
    values searched up to ``2 * max_order_checked + 1`` and the highest harmonic order that supports; ``revolute``
    ``(N,)`` bool (a prismatic joint gets no harmonics, no bound)."""
    q = np.asarray(q, dtype=float)
    if q.ndim != 2 or q.shape[0] < 1:
        raise ValueError(f"q must be (rows, joints) with at least one row, got shape {q.shape}")
    rev = [bool(v) for v in revolute]
    if len(rev) != q.shape[1]:
        raise ValueError(f"revolute has {len(rev)} entries for {q.shape[1]} joints")
    if not (isinstance(max_order_checked, (int, np.integer)) and max_order_checked >= 1):
        raise ValueError(f"max_order_checked must be a positive integer, got {max_order_checked!r}")
    out = []
    for j in range(q.shape[1]):
        x = _values(q[:, j])
        u = _distinct(x)
        if rev[j] and u.size < 2:
            alias, top = None, 0  # one value: every harmonic is a constant there
        elif rev[j]:
            alias = alias_frequency(x, 2 * int(max_order_checked) + 1)
            top = max_order(alias)
        else:
            alias, top = None, None
        labels = _group_labels(u, x.size)
        out.append(JointSampling(j + 1, rev[j], int(u.size), int(labels.max(initial=0) + 1),
                                 float(rad_to_deg(np.ptp(x))), alias, top, int(max_order_checked)))
    return tuple(out)


def sampling_report(sampling) -> dict:
    """The ``sampling`` entry of ``diagnosis.json``: the rule, the order checked to, and each joint's figures."""
    sampling = tuple(sampling)
    return {"rule": SAMPLING_RULE, "checked_to_order": sampling[0].checked_to if sampling else None,
            "joints": [s.to_dict() for s in sampling]}


def _subfeatures(features) -> list[Feature]:
    out = []
    for f in features:
        out.append(f)
        inner = getattr(f, "f", None)
        if isinstance(inner, Feature):
            out += _subfeatures((inner,))
    return out


def _joint_of(ch) -> int | None:
    if isinstance(ch, str) and ch.startswith("q") and ch[1:].isdigit():
        return int(ch[1:])
    return None


def harmonic_orders(features) -> dict[int, float]:
    """The highest harmonic order per joint (1-based) among ``features`` (``sin``/``cos`` of a joint channel
    ``q<j>``, nested ones included); empty when there is none."""
    out: dict[int, float] = {}
    for f in _subfeatures(features):
        if isinstance(f, (Sin, Cos)):
            j = _joint_of(f.ch)
            if j is not None:
                out[j] = max(out.get(j, 0.0), abs(float(f.k)))
    return out


def offered(features, sampling) -> bool:
    """Whether a term of ``features`` may be offered given the joints' ``sampling`` (:func:`joint_sampling`): none of
    its harmonics is above its joint's ``max_order``."""
    top = {s.joint: s.max_order for s in sampling}
    return all(top.get(j) is None or k <= top[j] + 1e-9 for j, k in harmonic_orders(features).items())


def joints_read(features) -> tuple[int, ...]:
    """The joints (1-based, sorted) whose commanded angle a term's features read by name (powers, harmonics,
    products and pulls past an angle of ``q<j>``, nested ones included). Features of time, of the motion history,
    of the gravity load or of the measured points read none here."""
    js: set[int] = set()
    for f in _subfeatures(features):
        if isinstance(f, (Pow, Sin, Cos, Hinge)):
            chs = (f.ch,)
        elif isinstance(f, Prod):
            chs = tuple(f.ch)
        else:
            continue
        js |= {j for j in map(_joint_of, chs) if j is not None}
    return tuple(sorted(js))


def block_widths(features, joints, ranges, *, folds: int = FOLDS) -> tuple[float, ...]:
    """The width [rad] of the blocks of each joint's values a term of ``features`` is confirmed between, for its
    ``joints`` (1-based) with the ``ranges`` [rad] the rows span: one period ``2 pi / k`` of its highest harmonic
    ``k`` of that joint (a block holds every phase of it: the term must bring them from other periods), else the
    range over ``2 folds`` (each fold two or more stretches of the range)."""
    orders = harmonic_orders(features)
    if len(joints) != len(ranges):
        raise ValueError(f"joints {joints!r} and ranges {ranges!r} differ in length")
    if not (isinstance(folds, (int, np.integer)) and folds >= 2):
        raise ValueError(f"folds must be an integer >= 2, got {folds!r}")
    return tuple(2 * np.pi / orders[j] if orders.get(j, 0) > 0 else float(R) / (2 * int(folds))
                 for j, R in zip(joints, ranges))


@dataclass(frozen=True)
class ConfigurationFolds:
    """The folds of a term's rows (:func:`configuration_folds`): ``fold`` ``(n,)`` each row's fold, ``unit`` ``(n,)``
    each row's configuration for the term (its joints' values to within :data:`UNIT_DIVISIONS` of a block: the
    rows of one grid value are one unit, whose pattern is one draw) and the number of ``blocks`` of the joint with
    the most."""

    fold: np.ndarray
    unit: np.ndarray
    blocks: int


def configuration_folds(q, widths, *, folds: int = FOLDS) -> ConfigurationFolds | None:
    """The folds of the rows from the values ``q`` ``(n, k)`` [rad] of the joints a term reads and the blocks'
    ``widths`` ``(k,)`` [rad] (:func:`block_widths`): each joint's groups of values (:func:`value_groups`: a grid's
    value is never cut) go to the block of width ``widths[c]`` their centre falls in, numbered in order; a row's
    fold is the sum of its blocks' numbers over the joints modulo ``G = min(folds, most blocks of a joint)``, so
    that each fold's blocks lie between blocks of other folds in every joint; a row's unit is its values binned at
    ``widths / UNIT_DIVISIONS``. None when no joint has :data:`MIN_BLOCKS` blocks (nothing to leave out between)."""
    q = np.asarray(q, dtype=float)
    if q.ndim == 1:
        q = q[:, None]
    w = np.atleast_1d(np.asarray(widths, dtype=float))
    if q.ndim != 2 or q.shape[1] == 0 or w.shape != (q.shape[1],):
        raise ValueError(f"q must be (rows, joints read) with one width per joint, got q {q.shape}, widths {w.shape}")
    if not np.all(w > 0):
        raise ValueError(f"widths must be positive [rad], got {w.tolist()}")
    if not (isinstance(folds, (int, np.integer)) and folds >= 2):
        raise ValueError(f"folds must be an integer >= 2, got {folds!r}")
    blocks = np.empty(q.shape, dtype=int)
    bins = np.empty(q.shape, dtype=int)
    for c in range(q.shape[1]):
        x = _values(q[:, c])
        g = value_groups(x)
        centre = np.bincount(g, weights=x) / np.bincount(g)
        # a value on a block's edge (a grid aligned with the period) goes to the block it starts
        b = np.floor((centre - centre.min()) / w[c] + 1e-9).astype(int)
        blocks[:, c] = np.unique(b, return_inverse=True)[1].ravel()[g]
        bins[:, c] = np.floor((x - x.min()) * UNIT_DIVISIONS / w[c] + 1e-9).astype(int)
    most = int(blocks.max(initial=0)) + 1
    if most < MIN_BLOCKS:
        return None
    G = min(int(folds), most)
    unit = np.unique(bins, axis=0, return_inverse=True)[1].ravel()
    return ConfigurationFolds((blocks.sum(axis=1) % G).astype(int), unit.astype(int), most)


def _log_sf(x: float, k: int) -> float:
    # log P(chi2(k) > x), finite where the tail underflows (its leading term)
    v = float(chi2_logsf(x, k))
    if not np.isfinite(v) and np.isfinite(x) and x > 0:
        v = -x / 2 + (k / 2 - 1) * np.log(x / 2) - float(gammaln(k / 2))
    return v


def _pinv(M: np.ndarray) -> np.ndarray:
    # pseudo-inverse of normal equations of whitened columns scaled to unit diagonal (geometry and term columns
    # differ by orders of magnitude): directions the other folds do not determine stay at zero
    d = np.sqrt(np.clip(np.diag(M), 0.0, None))
    s = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 0.0)
    return s[:, None] * np.linalg.pinv(M * s[:, None] * s[None, :], rcond=1e-12, hermitian=True) * s[None, :]


def _fold_sums(X: np.ndarray, Y: np.ndarray, f_res: np.ndarray, G: int) -> np.ndarray:
    # X^T Y over each fold's residuals (G, a, b)
    return np.stack([X[f_res == g].T @ Y[f_res == g] for g in range(G)])


def fold_confirmation(A, E, r, row, folds: ConfigurationFolds, z_min: float, *, rivals=(), log_pool=None,
                      evidence_scale: float = 1.0) -> FoldConfirmation:
    """A term confirmed on folds of the configurations (module docstring): ``A`` ``(m, p)`` the model's whitened
    columns, ``E`` ``(m, k)`` the term's, ``r`` ``(m,)`` the whitened residual of the current fit, ``row`` ``(m,)``
    the row of each residual (0..n-1), ``folds`` each row's fold and configuration unit (:func:`configuration_folds`).

    On each fold the choice is made again on the other folds' rows, among the term and its ``rivals`` (column
    blocks ``(m, k_i)``: the atoms the selection scored at the same place reading the same joints), as the selection
    makes it: the lowest ``log P(chi2(k_i) > Delta chi2_i / evidence_scale) + log_pool[i]`` (``log_pool``: the log
    of each one's pool size, the term's first; default zeros), ``Delta chi2_i = b_i^T S_i^+ b_i`` with
    ``S_i = E_i^T E_i - E_i^T A (A^T A)^+ A^T E_i`` and ``b_i = E_i^T (r - A beta_0)`` on those rows. The one chosen
    predicts the fold. Passed when the signed-rank ``z`` of the per-row ``c_k`` exceeds ``z_min``, also without the
    most favourable unit, and the left-out rows' residual norm drops; the ``c_k`` are summed per configuration unit
    (a grid value's rows share its pattern: one draw, not one per row) and ranked over the units; ``rechosen``
    counts the folds whose choice was the term itself."""
    A, r = np.asarray(A, float), np.asarray(r, float)
    blocks = [np.asarray(X, float) for X in (E, *rivals)]
    blocks = [X[:, None] if X.ndim == 1 else X for X in blocks]
    if not isinstance(folds, ConfigurationFolds):
        raise ValueError(f"folds must be the ConfigurationFolds of configuration_folds, got {type(folds).__name__} "
                         "(None: the term's joints have too few blocks of values to be judged between them)")
    row, fold, unit = np.asarray(row, int), folds.fold, folds.unit
    m = r.size
    if A.shape[0] != m or any(X.shape[0] != m for X in blocks) or row.shape != (m,):
        raise ValueError(f"A {A.shape}, E and rivals {[X.shape for X in blocks]}, r {r.shape} and row {row.shape} "
                         "must have the same rows")
    if fold.ndim != 1:
        raise ValueError(f"fold must be one fold per row (configuration_folds), got shape {fold.shape}")
    if m and (row.min() < 0 or row.max() >= fold.size):
        raise ValueError(f"row must index fold (0..{fold.size - 1})")
    lp = np.zeros(len(blocks)) if log_pool is None else np.asarray(log_pool, float)
    if lp.shape != (len(blocks),):
        raise ValueError(f"log_pool needs one entry per option ({len(blocks)}), got shape {lp.shape}")
    if not evidence_scale > 0:
        raise ValueError(f"evidence_scale must be positive, got {evidence_scale!r}")
    p = A.shape[1]
    f_res = fold[row]
    G = int(fold.max(initial=-1)) + 1
    AA, Ar = _fold_sums(A, A, f_res, G), _fold_sums(A, r[:, None], f_res, G)[:, :, 0]
    per = [(_fold_sums(A, X, f_res, G), _fold_sums(X, X, f_res, G), _fold_sums(X, r[:, None], f_res, G)[:, :, 0])
           for X in blocks]
    n_units = int(unit.max(initial=-1)) + 1
    c = np.zeros(n_units)
    seen = np.zeros(n_units, dtype=bool)
    e2, e2_with, rechosen = 0.0, 0.0, 0
    for g in range(G):
        sel = f_res == g
        if not np.any(sel):
            continue
        Ci = _pinv(AA.sum(0) - AA[g])
        beta0 = Ci @ (Ar.sum(0) - Ar[g])
        best = None
        for i, (AX, XX, Xr) in enumerate(per):
            AXt, XXt, Xrt = AX.sum(0) - AX[g], XX.sum(0) - XX[g], Xr.sum(0) - Xr[g]
            S = XXt - AXt.T @ Ci @ AXt
            b = Xrt - AXt.T @ beta0
            d = float(b @ np.linalg.pinv(S, rcond=1e-10, hermitian=True) @ b)
            score = _log_sf(d / evidence_scale, blocks[i].shape[1]) + lp[i]
            if best is None or score < best[0]:
                best = (score, i)
        i = best[1]
        rechosen += i == 0
        AX, XX, Xr = per[i]
        Mt = np.block([[AA.sum(0) - AA[g], AX.sum(0) - AX[g]], [(AX.sum(0) - AX[g]).T, XX.sum(0) - XX[g]]])
        theta = _pinv(Mt) @ np.concatenate([Ar.sum(0) - Ar[g], Xr.sum(0) - Xr[g]])
        Ag = A[sel]
        e = r[sel] - Ag @ beta0
        u = Ag @ (theta[:p] - beta0) + blocks[i][sel] @ theta[p:]
        c += np.bincount(unit[row[sel]], weights=e * u, minlength=n_units)
        seen[np.unique(unit[row[sel]])] = True
        e2 += float(e @ e)
        e2_with += float((e - u) @ (e - u))
    cr = c[seen]
    z = signed_rank_z(cr)
    z_minus = signed_rank_z(np.delete(cr, int(np.argmax(cr)))) if cr.size > 1 else 0.0
    better = e2_with < e2
    return FoldConfirmation(float(z), float(z_minus), bool(better), G, int(rechosen), int(cr.size),
                            bool(z > z_min and z_minus > z_min and better))
