"""The products over the calibration rows that scoring sums: a feature set's Gram matrices against per-row aggregates
of the model columns it multiplies (``E^T E``, ``Q^T E``, ``E^T r``), suffix sums for terms that act from a moment on,
and the leading eigenpairs of wide projected Gram matrices (:mod:`twin.diagnosis.scoring` states what they compute).
"""

from __future__ import annotations

import numpy as np

from .atoms import Atom
from .features import Step

__all__ = ["single_step", "tail_sums", "block_stats", "product_grams",
           "product_grams_wide", "WIDE_EIGH_MIN", "leading_eigh"]


def single_step(a: Atom) -> bool:
    """An atom of one feature, a step ``1[ch >= at]`` in a channel."""
    return len(a.features) == 1 and isinstance(a.features[0], Step)


def tail_sums(X: np.ndarray, pos: np.ndarray) -> np.ndarray:
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


def block_stats(F: np.ndarray, w: np.ndarray, Qb: np.ndarray, br: np.ndarray) -> list:
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


def product_grams(F: np.ndarray, W: np.ndarray, QB: np.ndarray, Br: np.ndarray) -> tuple[np.ndarray, ...]:
    """``E^T E`` ``(g, K c, K c)``, ``Q^T E`` ``(g, p, K c)`` and ``E^T r`` ``(g, K c)`` of a batch of product atoms
    with features ``F`` ``(n, g, K)`` from the per-row aggregates of their base ``W`` ``(n, c, c)``, ``QB``
    ``(n, p, c)``, ``Br`` ``(n, c)`` (:func:`twin.diagnosis.scoring._score_products`)."""
    n, g, K = F.shape
    c, p = W.shape[1], QB.shape[1]
    KC = K * c
    FF = (F[:, :, :, None] * F[:, :, None, :]).reshape(n, g * K * K)
    EtE = (FF.T @ W.reshape(n, c * c)).reshape(g, K, K, c, c).transpose(0, 1, 3, 2, 4).reshape(g, KC, KC)
    F2 = F.reshape(n, g * K)
    QtE = (F2.T @ QB.reshape(n, p * c)).reshape(g, K, p, c).transpose(0, 2, 1, 3).reshape(g, p, KC)
    Etr = (F2.T @ Br).reshape(g, KC)
    return EtE, QtE, Etr


def product_grams_wide(F: np.ndarray, W: np.ndarray, QB: np.ndarray, Br: np.ndarray) -> tuple[np.ndarray, ...]:
    """:func:`product_grams` of one atom with many features ``F`` ``(n, K)`` without the ``(n, K^2)`` products:
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


WIDE_EIGH_MIN = 400  # from this size on, only the leading eigenpairs of a projected Gram matrix are computed


def leading_eigh(G: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
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
