"""Simulated datasets from a given model: for tests, benchmarks and measurement planning.

This is not the twin (``twin.world`` renders images and measures them with the instrument); it is the
estimator's own forward model with Gaussian noise added, so that identification can be exercised where
the answer is known. The caller owns the model it simulates from; nothing here reads any truth file.
"""

from __future__ import annotations

import numpy as np

from ..dataset import Dataset, Plate, default_plate
from ..kinematics import RobotModel, flange2base
from ..transforms import euler_zyx_from_matrix, invert_transform, matrix_from_euler_zyx, rotvec_to_matrix

__all__ = ["simulate_dataset", "random_configurations", "orientation_noise", "ORIENTATION_NOISE_READINGS"]

ORIENTATION_NOISE_READINGS = ("rotvec", "norm", "euler")


def orientation_noise(R: np.ndarray, sigma: float, reading: str, rng: np.random.Generator) -> np.ndarray:
    """Rotations ``R`` ``(n, 3, 3)`` with Gaussian orientation noise of ``sigma`` [rad], read one of three ways
    (the TM-MDH paper's "0.002 rad" does not say which):

    * ``"rotvec"``: ``exp(w) R`` with ``w ~ N(0, sigma^2 I3)``, sigma per rotation-vector component (RMS
      rotation angle ``sqrt(3) sigma``);
    * ``"norm"``: ``exp(w) R`` with ``w ~ N(0, sigma^2 / 3 I3)``, sigma the RMS *norm* of the rotation vector
      (the RMS rotation angle);
    * ``"euler"``: sigma on each of the Z-Y-X Euler angles of ``R`` (``R = Rz Ry Rx``, the paper's eq. 3).
    """
    R = np.asarray(R, dtype=float)
    if sigma < 0:
        raise ValueError(f"sigma must be >= 0, got {sigma!r}")
    n = R.shape[0]
    if reading == "rotvec":
        return rotvec_to_matrix(rng.normal(0.0, sigma, (n, 3))) @ R
    if reading == "norm":
        return rotvec_to_matrix(rng.normal(0.0, sigma / np.sqrt(3.0), (n, 3))) @ R
    if reading == "euler":
        return matrix_from_euler_zyx(euler_zyx_from_matrix(R) + rng.normal(0.0, sigma, (n, 3)))
    raise ValueError(f"reading must be one of {ORIENTATION_NOISE_READINGS}, got {reading!r}")


def random_configurations(model: RobotModel, n: int, rng: np.random.Generator, margin: float = 0.0) -> np.ndarray:
    """``n`` joint configurations ``(n, N)`` uniform inside the limits (clipped to +-pi, shrunk by
    ``margin`` [rad, m])."""
    lo = np.maximum(model.q_min, -np.pi) + margin
    hi = np.minimum(model.q_max, np.pi) - margin
    return rng.uniform(lo, hi, (int(n), model.n_joints))


def simulate_dataset(
    model: RobotModel,
    q: np.ndarray,
    *,
    robot_spec: str | dict,
    nominal: RobotModel | None = None,
    plate: Plate | None = None,
    kind: str = "spheres",
    base2meas: dict[str, np.ndarray] | None = None,
    station: np.ndarray | None = None,
    noise_position: float = 0.0,
    noise_orientation: float = 0.0,
    rng: np.random.Generator | None = None,
    set_: np.ndarray | None = None,
    pair: np.ndarray | None = None,
    declare_noise: bool = True,
    orientation_noise_reading: str = "rotvec",
) -> tuple[Dataset, dict[str, np.ndarray]]:
    """A :class:`Dataset` measured on ``model`` (its robot and ``tool2flange``) at joints ``q`` ``(n, N)``.

    ``kind``: ``"spheres"`` (the K points of ``plate``, noise ``noise_position`` [m] per coordinate), ``"pose"``
    (tool pose: position noise [m] per coordinate, rotation noise [rad] per rotation-vector component,
    applied on the left, or as :func:`orientation_noise` reads it with ``orientation_noise_reading``) or
    ``"both"``. Each row is measured in the frame of its ``station`` (default
    ``"0"``) through ``base2meas[station]`` (default: the model's). The plate geometry is given in the flange
    frame of the *nominal* ``tool2flange`` (``nominal``, default ``model``'s structure with identity tool),
    as ``dataset.toml`` states it. The noise is declared in the dataset (``[noise]``) when ``declare_noise``
    and positive. Returns the dataset and the noise-free truth (``spheres`` ``(n, 3, 3)``,
    ``pose`` ``(n, 4, 4)``) for evaluation.
    """
    q = np.asarray(q, dtype=float)
    n = q.shape[0]
    rng = rng if rng is not None else np.random.default_rng(0)
    plate = plate if plate is not None else default_plate()
    st = np.full(n, "0", dtype=object) if station is None else np.asarray(station, dtype=object).astype(str)
    bases = dict(base2meas) if base2meas else {s: model.base2meas for s in np.unique(st)}
    T_nom = (nominal.tool2flange if nominal is not None else np.eye(4))
    K = plate.n_points
    spheres_tool = (invert_transform(T_nom) @ np.c_[plate.spheres_flange, np.ones(K)].T).T[:, :3]
    F = flange2base(model, q) @ model.tool2flange
    B = np.stack([bases[s] for s in st])
    T = B @ F  # tool2meas (n, 4, 4)
    true_sph = np.einsum("nij,kj->nki", T[:, :3, :3], spheres_tool) + T[:, None, :3, 3]
    spheres = np.full((n, K, 3), np.nan)
    seen = np.zeros((n, K), dtype=bool)
    pose = np.full((n, 4, 4), np.nan)
    pose_seen = np.zeros(n, dtype=bool)
    if kind in ("spheres", "both"):
        spheres = true_sph + rng.normal(0.0, noise_position, true_sph.shape)
        seen[:] = True
    if kind in ("pose", "both"):
        pose = T.copy()
        pose[:, :3, 3] += rng.normal(0.0, noise_position, (n, 3))
        pose[:, :3, :3] = orientation_noise(T[:, :3, :3], noise_orientation, orientation_noise_reading, rng)
        pose_seen[:] = True
    if kind not in ("spheres", "pose", "both"):
        raise ValueError(f"kind must be 'spheres', 'pose' or 'both', got {kind!r}")
    from ..dataset import robot_from_spec

    ds = Dataset(
        robot=robot_from_spec(robot_spec),
        robot_spec=robot_spec,
        plate=plate,
        pose_id=np.arange(n, dtype=np.int64),
        q=q.copy(),
        spheres=spheres,
        sphere_seen=seen,
        pose=pose,
        pose_seen=pose_seen,
        set=None if set_ is None else np.asarray(set_, dtype=object),
        station=None if station is None else st,
        pair=None if pair is None else np.asarray(pair, dtype=np.int64),
        noise_position=noise_position if declare_noise and noise_position > 0 else None,
        noise_orientation=noise_orientation if declare_noise and kind != "spheres" and noise_orientation > 0 else None,
        provenance="simulated by twin.estimator.simulate from a given model",
    )
    return ds, {"spheres": true_sph, "pose": T}
