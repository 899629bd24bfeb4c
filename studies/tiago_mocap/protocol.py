"""The comparison protocol of the TIAGo study: FIGAROH's split of the validation postures and the error
statistics per point (3-D distance, the same definition FIGAROH 1.0.2 uses: RMS over points of the Euclidean
position error)."""

from __future__ import annotations

import numpy as np

GROUPS = ("replayed", "new_in_range", "outside")


def split_validation(q_train: np.ndarray, q_val: np.ndarray, replay_tolerance: float, range_margin: float):
    """Group of every validation posture ``(n_val,)``: ``replayed`` (every joint within ``replay_tolerance`` of
    one training posture), ``new_in_range`` (not replayed, every joint inside the training range widened by
    ``range_margin``), ``outside``; and the distances behind the decision."""
    d = np.abs(q_val[:, None, :] - q_train[None, :, :]).max(axis=-1)
    nearest = d.min(axis=1)
    beyond = np.maximum(q_train.min(axis=0) - q_val, q_val - q_train.max(axis=0)).max(axis=1)
    group = np.where(nearest <= replay_tolerance, "replayed", np.where(beyond <= range_margin, "new_in_range", "outside"))
    return group, nearest, beyond


def stats(e: np.ndarray) -> dict:
    """``{n, rmse, max, mean}`` [mm] of point errors ``e`` [mm] (any shape)."""
    e = np.asarray(e, dtype=float).reshape(-1)
    if e.size == 0:
        return {"n": 0, "rmse": None, "max": None, "mean": None}
    return {"n": int(e.size), "rmse": float(np.sqrt(np.mean(e**2))), "max": float(e.max()), "mean": float(e.mean())}


def by_group(e_val: np.ndarray, group: np.ndarray) -> dict:
    """Statistics of validation point errors ``(n_val, K)`` [mm] overall and per group."""
    out = {"all": stats(e_val)}
    for g in GROUPS:
        out[g] = stats(e_val[group == g])
    return out
