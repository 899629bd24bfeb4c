"""The three-sphere plate: labelling by distances, rigid plate pose, and the separation paper's frame.

Pure functions of sphere centres (no images).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from ..dataset import Plate
from ..transforms import euler_zyx_from_matrix, kabsch
from ..units import MM_PER_M, rad_to_deg

__all__ = [
    "PlateFit",
    "plate_pose_from_spheres",
    "paper_frame_from_spheres",
    "paper_euler_zyx_deg",
    "label_by_distances",
    "check_plate_labelable",
]


def _centres(centres, name: str = "centres") -> np.ndarray:
    if centres is None or any(c is None for c in centres):
        raise ValueError(f"{name}: all three sphere centres are needed (got a missing sphere)")
    p = np.asarray([np.asarray(c, dtype=float).reshape(3) for c in centres])
    if p.shape != (3, 3) or not np.all(np.isfinite(p)):
        raise ValueError(f"{name}: expected three finite centres (3, 3) [m], got {np.asarray(centres).shape}")
    return p


@dataclass(frozen=True, eq=False)
class PlateFit:
    """Rigid best fit of the plate's nominal sphere centres to measured ones.

    ``tool2meas`` ``(4, 4)`` maps the plate frame (the frame in which ``Plate.spheres_flange`` is given; the
    flange for a nominal tool) into the measurement frame; ``residuals`` ``(3,)`` [m] are the distances
    between fitted and measured centres, ``rms`` [m] their root mean square (a plate-shape check).
    """

    tool2meas: np.ndarray
    residuals: np.ndarray
    rms: float


def plate_pose_from_spheres(centres, plate: Plate) -> PlateFit:
    """Plate pose from three measured centres ``(3, 3)`` [m] (rows p0, p1, p2) by a least-squares rigid fit
    (:func:`twin.transforms.kabsch`): ``min_{R,t} sum_i |R s_i + t - p_i|^2`` with ``s_i`` the nominal
    centres.
    """
    p = _centres(centres)
    s = np.asarray(plate.spheres_flange, float)
    R, t = kabsch(s, p)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    res = np.linalg.norm(s @ R.T + t - p, axis=1)
    return PlateFit(T, res, float(np.sqrt(np.mean(res**2))))


def _cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x b`` of two 3-vectors: the products and differences ``np.cross`` forms, without its batching
    machinery (about ten times faster on one pair)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def paper_frame_from_spheres(centres) -> np.ndarray:
    """The separation paper's sphere frame (eq. 38-40) as a transform ``(4, 4)`` into the measurement frame.

    ``X = p0 - p1``, ``Z = (p0 - p1) x (p2 - p1)``, ``Y = Z x X`` (eq. 38), normalised (eq. 39), as the
    columns of ``R_cp`` (eq. 40). The origin is ``p3``, the centre of the circle through the three
    centres (the paper's circumscribed-circle centre).
    """
    p = _centres(centres)
    X = p[0] - p[1]
    Z = _cross3(p[0] - p[1], p[2] - p[1])
    if np.linalg.norm(Z) < 1e-12:
        raise ValueError("centres: the three sphere centres are collinear; the paper frame is undefined")
    Y = _cross3(Z, X)
    R = np.stack([X / np.linalg.norm(X), Y / np.linalg.norm(Y), Z / np.linalg.norm(Z)], axis=1)
    # circumcentre of the triangle p0 p1 p2
    a, b = p[0] - p[2], p[1] - p[2]
    axb = _cross3(a, b)
    centre = p[2] + _cross3(np.dot(a, a) * b - np.dot(b, b) * a, axb) / (2.0 * np.dot(axb, axb))
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = centre
    return T


def paper_euler_zyx_deg(frame2meas: np.ndarray) -> np.ndarray:
    """Eq. 43: ``(Rx, Ry, Rz)`` [deg] of ``R = Rz Ry Rx`` (``twin.transforms.euler_zyx_from_matrix``)."""
    return rad_to_deg(euler_zyx_from_matrix(np.asarray(frame2meas, float)[:3, :3]))


def check_plate_labelable(plate: Plate, tol: float) -> None:
    """Raise ``ValueError`` if two of the plate's pairwise distances are within ``2 * tol`` [m]: such a plate
    (e.g. spheres 120 deg apart) cannot be labelled by distances."""
    d = plate.pairwise_distances
    gaps = [abs(d[i] - d[j]) for i, j in ((0, 1), (0, 2), (1, 2))]
    if min(gaps) <= 2 * tol:
        raise ValueError(
            f"plate: pairwise sphere distances {np.round(d * MM_PER_M, 3).tolist()} mm are too close to each other "
            f"(within {2 * tol * MM_PER_M:.1f} mm) to label the spheres; use unequal spacing"
        )


_PAIRS = ((0, 1), (0, 2), (1, 2))


def label_by_distances(points: np.ndarray, plate: Plate, tol: float, weights: np.ndarray | None = None):
    """Assign plate labels 0, 1, 2 to points ``(n, 3)`` [m] by their pairwise distances.

    Every injective partial assignment is scored: it must keep every pairwise distance within ``tol`` [m]
    (``tol * weights`` combined per pair when ``weights`` ``(n,)`` >= 1 loosen it for rough points) of the
    plate's; the one labelling the most points wins, ties broken by the squared error. An assignment that
    leaves its points' labels ambiguous (another assignment of the same size, also consistent, labels the
    same points differently, e.g. any two points alone) is refused for those points.

    Returns ``labels`` ``(n,)`` with -1 for unlabelled points, and the list of point indices left
    unlabelled because of an ambiguity.
    """
    P = np.asarray(points, float).reshape(-1, 3)
    n = P.shape[0]
    w = np.ones(n) if weights is None else np.asarray(weights, float)
    D = plate.pairwise_distances
    dmat = {(0, 1): D[0], (1, 0): D[0], (0, 2): D[1], (2, 0): D[1], (1, 2): D[2], (2, 1): D[2]}
    best: list[tuple[int, float, dict]] = []
    for m in (3, 2):
        if m > n:
            continue
        found = []
        for idx in itertools.permutations(range(n), m):
            for labs in itertools.combinations(range(3), m):
                assign = dict(zip(labs, idx))  # label -> point
                ok, err = True, 0.0
                for la, lb in itertools.combinations(labs, 2):
                    i, j = assign[la], assign[lb]
                    e = abs(np.linalg.norm(P[i] - P[j]) - dmat[(la, lb)])
                    if e > tol * max(w[i], w[j]):
                        ok = False
                        break
                    err += e * e
                if ok:
                    found.append((err, assign))
        if found:
            best = sorted(found, key=lambda x: x[0])
            break
    labels = -np.ones(n, dtype=int)
    ambiguous: list[int] = []
    if not best:
        return labels, ambiguous
    err0, a0 = best[0]
    pts0 = set(a0.values())
    # another consistent assignment of the same size over the same points with different labels?
    rivals = [a for _, a in best[1:] if set(a.values()) == pts0 and a != a0]
    if rivals:
        ambiguous = sorted(pts0)
        return labels, ambiguous
    for la, i in a0.items():
        labels[i] = la
    return labels, ambiguous
