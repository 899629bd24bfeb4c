"""Plausibility of a dataset and of a fit: refuse what cannot be right, with the likely cause in words.

Checks on data a user has (nothing here reads truth):

* **Plate geometry per row.** The three pairwise sphere distances of the plate are known (``dataset.toml``
  ``[plate] spheres_mm``) and distinct, so each measured row can be checked: a row whose labels are permuted
  is relabelled (the permutation whose distances match the plate best, when it matches far better than the
  labels given); a row whose distances are off by more than ``k`` robust standard deviations of all rows is
  flagged and left out. The median ratio of measured to nominal distances tells units (1000x: millimetres
  written in metres or the reverse).
* **Joints.** Values outside the robot's limits; all joints within a few degrees of zero over a campaign that
  must move (joints written in radians in the degree columns).
* **Fit.** A residual scale far above 1 (the noise stated or estimated cannot explain the residual: the model
  cannot fit these data).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from itertools import permutations

import numpy as np

from ..dataset import Dataset

__all__ = ["PlateCheck", "ImplausibleData", "check_plate_rows", "check_joints", "check_fit", "plate_noise",
           "check_fit_against_plate"]

_PAIRS = ((0, 1), (0, 2), (1, 2))
_DEG = np.pi / 180.0


class ImplausibleData(ValueError):
    """The data cannot be right; the message names the likely cause."""


@dataclass(frozen=True, eq=False)
class PlateCheck:
    """The dataset with permuted labels fixed and implausible rows removed, and what was done.

    ``relabelled``: pose_ids whose sphere labels were permuted back; ``flagged``: ``{pose_id: reason}`` of the
    rows left out; ``distance_ratio``: median measured / nominal inter-sphere distance."""

    dataset: Dataset
    relabelled: tuple[int, ...] = ()
    flagged: dict = field(default_factory=dict)
    distance_ratio: float = 1.0

    def summary(self) -> dict:
        return {"relabelled": list(self.relabelled), "flagged": {str(k): v for k, v in self.flagged.items()},
                "distance_ratio": self.distance_ratio,
                "rule": "labels permuted back when another order matches the plate's distinct distances better; rows "
                        "whose distances are off by more than k robust sd of all rows left out"}


def _distances(P: np.ndarray) -> np.ndarray:
    return np.stack([np.linalg.norm(P[:, a] - P[:, b], axis=-1) for a, b in _PAIRS], axis=-1)


def check_plate_rows(ds: Dataset, *, k: float = 10.0, min_sd_m: float = 2e-6) -> PlateCheck:
    """Relabel permuted rows, flag rows the plate geometry rules out, check units (module docstring).

    ``k``: how many robust standard deviations (of the distance errors over all rows, at least ``min_sd_m``)
    make a row implausible. Raises :class:`ImplausibleData` when the distances are 1000x (or 1/1000x) the
    plate's, or when more than half of the complete rows are implausible.
    """
    if not isinstance(ds, Dataset):
        raise ValueError(f"ds must be a twin.dataset.Dataset, got {type(ds).__name__}")
    if not (k > 0):
        raise ValueError(f"k must be positive, got {k!r}")
    full = ds.sphere_seen.all(axis=1)
    if full.sum() == 0:
        return PlateCheck(ds)
    nom = _distances(ds.plate.spheres_flange[None])[0]  # (3,)
    P = ds.spheres[full]
    d = _distances(P)
    ratio = float(np.median(d / nom))
    if not 0.5 < ratio < 2.0:
        if 300 < ratio < 3000:
            cause = "sphere positions in micrometres, or the plate in metres?"
        elif 3e-4 < ratio < 3e-3:
            cause = "positions in metres? (poses.csv expects millimetres)"
        else:
            cause = "a different plate, or wrong units?"
        raise ImplausibleData(f"sphere distances are {ratio:.4g}x the plate's ({', '.join(f'{x * 1e3:.2f}' for x in nom)} "
                              f"mm in dataset.toml [plate]): {cause}")
    perms = list(permutations(range(3)))
    spheres = ds.spheres.copy()
    rows = np.flatnonzero(full)
    relabelled = []
    for r in rows:
        errs = []
        for p in perms:
            errs.append(float(np.sum((_distances(spheres[r][list(p)][None])[0] - nom) ** 2)))
        best = int(np.argmin(errs))
        if best != 0 and errs[0] > 100 * errs[best] and errs[0] > (50e-6) ** 2:
            spheres[r] = spheres[r][list(perms[best])]
            relabelled.append(int(ds.pose_id[r]))
    e = _distances(spheres[full]) - nom  # (m, 3)
    med = np.median(e, axis=0)  # a plate slightly off its nominal geometry: a common offset, not an error
    dev = np.abs(e - med)
    sd = np.maximum(1.4826 * np.median(dev, axis=0), min_sd_m)
    bad = np.any(dev > k * sd, axis=1)
    flagged = {}
    for r, b, x in zip(rows, bad, dev):
        if b:
            flagged[int(ds.pose_id[r])] = (f"plate geometry off: inter-sphere distances differ from the campaign's by "
                                           f"{', '.join(f'{v * 1e3:.3f}' for v in x)} mm (> {k:g} robust sd): not what the "
                                           f"instrument could have measured")
    if bad.mean() > 0.5:
        raise ImplausibleData(f"{int(bad.sum())} of {int(full.sum())} rows have sphere distances that do not fit the "
                              "plate in dataset.toml: wrong plate geometry or units?")
    out = replace(ds, spheres=spheres)
    if flagged:
        keep = ~np.isin(out.pose_id, list(flagged))
        out = out.subset(keep)
    return PlateCheck(out, tuple(relabelled), flagged, ratio)


def check_joints(ds: Dataset) -> list[str]:
    """Problems of the commanded joints in words (empty when none); :class:`ImplausibleData` when the joints
    cannot be degrees (every joint within 3.2 deg of zero over 10 rows or more: radians written in the degree
    columns)."""
    q = ds.q
    if ds.n >= 10 and np.all(np.abs(q) <= np.pi * _DEG * 1.02) and np.ptp(q, axis=0).max() > 0:
        raise ImplausibleData(f"every joint of the {ds.n} rows lies within {np.abs(q).max() / _DEG:.3g} deg of zero: "
                              "joints look like radians (poses.csv expects q1..q6 in degrees)")
    r = ds.robot
    lo, hi = np.asarray(r.q_min, float), np.asarray(r.q_max, float)
    out = []
    for j in range(q.shape[1]):
        b = np.flatnonzero((q[:, j] < lo[j] - 1e-9) | (q[:, j] > hi[j] + 1e-9))
        if b.size:
            out.append(f"q{j + 1} outside the robot's limits [{lo[j] / _DEG:.1f}, {hi[j] / _DEG:.1f}] deg in "
                       f"{b.size} rows (pose_id {[int(x) for x in ds.pose_id[b[:5]]]})")
    return out


def check_fit(residual_scale: float, *, limit: float = 30.0) -> None:
    """:class:`ImplausibleData` when the whitened residual is ``limit`` or more times what the noise explains."""
    if not np.isfinite(residual_scale):
        raise ImplausibleData(f"the fit's residual scale is {residual_scale!r}")
    if residual_scale >= limit:
        raise ImplausibleData(f"the model cannot fit these data: the residual is {residual_scale:.4g}x what the noise "
                              "explains (wrong robot, wrong units, swapped columns, or the stated noise far too small?)")


def plate_noise(ds: Dataset) -> float | None:
    """The instrument's error per coordinate [m] seen in the plate: the robust spread of the inter-sphere
    distances over the rows with all three spheres, divided by sqrt(2) (None with fewer than 10 such rows).
    No kinematic error changes these distances, so a fit cannot be much worse than this."""
    full = ds.sphere_seen.all(axis=1)
    if full.sum() < 10:
        return None
    d = _distances(ds.spheres[full])
    mad = 1.4826 * np.median(np.abs(d - np.median(d, axis=0)), axis=0)
    return float(np.sqrt(np.mean(mad**2) / 2.0))


def check_fit_against_plate(fit_rms_per_coordinate_m: float, sigma_plate_m: float | None, *,
                            limit: float = 30.0, min_sigma_m: float = 1e-6) -> None:
    """:class:`ImplausibleData` when the fit's residual per coordinate is ``limit`` or more times the
    instrument's error seen in the plate distances (the fit's own noise estimate cannot hide it)."""
    if sigma_plate_m is None or not np.isfinite(fit_rms_per_coordinate_m):
        return
    ratio = fit_rms_per_coordinate_m / max(sigma_plate_m, min_sigma_m)
    if ratio >= limit:
        raise ImplausibleData(f"the model cannot fit these data: the residual ({fit_rms_per_coordinate_m * 1e3:.4g} mm "
                              f"per coordinate) is {ratio:.0f}x the instrument's error seen in the plate's sphere "
                              "distances (rows of several camera stations without a 'station' column? wrong robot or "
                              "joint order?)")
