"""The synthetic IRB-1200 problem every method of the benchmark sees (ours and the peers alike).

* **Nominal model** (what a method is given): ``twin.robots.irb1200()`` with identity ``base2meas`` and
  ``tool2flange`` -- the base and tool frames are *unknown*, not merely perturbed.
* **Truth** (what generates the data, only the benchmark reads it): the nominal plus the separation paper's
  injected deviations (``twin.presets.preset_deviation("separation_tables_2_4")``, including beta2) plus a
  measurement frame 2 m away and turned by about 170 deg (``TRUE_BASE2MEAS_POSE6``), and a tool frame 56 mm
  off the flange and turned by about 35 deg (``TRUE_TOOL2FLANGE_POSE6``).
* **Measurements**: 6-DOF tool poses in the measurement frame (a laser-tracker probe, the TM-MDH paper's kind of
  data), with Gaussian noise of ``position`` [m] on each coordinate and ``orientation`` [rad] on each component
  of a rotation vector applied on the left (``R_meas = exp([n]x) R_true``).
* **Splits**: per seed, 100 calibration configurations (the 50-pose case uses the first 50 of them, so the two
  sizes are nested; larger sets, for the growth figures, are drawn whole) and 200 validation configurations, drawn uniformly inside 80 % of the joint limits (the
  wrist rolls q4 and q6 inside +-180 deg). The unit-normal noise draws are shared by the two noise levels of a
  seed (only the scale differs), so every comparison between cells is paired.

Validation is scored against the *noise-free* true tool poses: the methods only ever see the validation
joints.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from twin.dataset import Dataset, default_plate
from twin.kinematics import RobotModel, tool2meas
from twin.presets import preset_deviation
from twin.robots import irb1200
from twin.transforms import make_transform, pose6_to_transform, rotvec_to_matrix
from twin.units import MM_PER_M

__all__ = [
    "NoiseLevel",
    "NOISE_LEVELS",
    "TRUE_BASE2MEAS_POSE6",
    "TRUE_TOOL2FLANGE_POSE6",
    "Problem",
    "Split",
    "make_problem",
    "make_split",
    "sample_configurations",
    "to_dataset",
]

N_VALIDATION = 200
N_CALIBRATION_MAX = 100

# base2meas of the truth: (x, y, z) [m], rotation vector [rad] -- a tracker about 1.9 m in front of the robot,
# looking back at it (turned ~170 deg about the vertical and tilted by a few degrees).
TRUE_BASE2MEAS_POSE6 = np.array([1.85, 0.32, -0.41, 0.05, -0.08, 2.95])
# tool2flange of the truth: the measured tool frame 56 mm off the flange, turned ~35 deg about the flange axis.
TRUE_TOOL2FLANGE_POSE6 = np.array([0.012, -0.008, 0.055, 0.02, -0.01, 0.6])


@dataclass(frozen=True)
class NoiseLevel:
    """Measurement noise: 1-sigma per position coordinate [m] and per rotation-vector component [rad]."""

    position: float
    orientation: float

    @property
    def label(self) -> str:
        return f"{self.position * MM_PER_M:g} mm / {self.orientation:g} rad"

    @property
    def key(self) -> str:
        return f"{self.position * MM_PER_M:g}mm_{self.orientation:g}rad"


NOISE_LEVELS = (NoiseLevel(0.02e-3, 0.002), NoiseLevel(0.01e-3, 0.0002))


@dataclass(frozen=True, eq=False)
class Problem:
    """The nominal model a method is given and the truth that generates the data."""

    nominal: RobotModel
    truth: RobotModel
    preset: str


@dataclass(frozen=True, eq=False)
class Split:
    """One dataset of the benchmark: calibration rows with noisy 6-DOF measurements, validation joints.

    ``tool2meas_cal`` ``(n, 4, 4)``: measured tool poses (noisy) in the measurement frame; ``q_cal`` ``(n, 6)``
    [rad]. ``q_val`` ``(m, 6)`` [rad] and ``tool2meas_val_true`` ``(m, 4, 4)``: validation joints and their
    noise-free true tool poses (the methods never see the latter). ``tool2meas_cal_true`` keeps the noise-free
    calibration poses for tests.
    """

    seed: int
    noise: NoiseLevel
    q_cal: np.ndarray
    tool2meas_cal: np.ndarray
    tool2meas_cal_true: np.ndarray
    q_val: np.ndarray
    tool2meas_val_true: np.ndarray

    @property
    def n_cal(self) -> int:
        return int(self.q_cal.shape[0])

    @property
    def positions_cal(self) -> np.ndarray:
        """Measured tool positions ``(n, 3)`` [m]."""
        return self.tool2meas_cal[:, :3, 3]


@lru_cache(maxsize=None)
def make_problem(preset: str = "separation_tables_2_4") -> Problem:
    """Nominal IRB-1200 (identity base and tool) and the truth: preset deviations + unknown base and tool."""
    nominal = irb1200()
    truth = nominal.perturbed(preset_deviation(preset), name="irb1200-truth").with_frames(
        base2meas=pose6_to_transform(TRUE_BASE2MEAS_POSE6), tool2flange=pose6_to_transform(TRUE_TOOL2FLANGE_POSE6)
    )
    return Problem(nominal=nominal, truth=truth, preset=preset)


def sample_configurations(model: RobotModel, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` configurations ``(n, 6)`` [rad] uniform in 80 % of the joint limits (q4, q6 within +-pi)."""
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    centre = 0.5 * (model.q_min + model.q_max)
    half = 0.4 * (model.q_max - model.q_min)
    lo, hi = centre - half, centre + half
    for j in (3, 5):
        lo[j], hi[j] = max(lo[j], -np.pi), min(hi[j], np.pi)
    return rng.uniform(lo, hi, size=(n, 6))


def _noisy(T: np.ndarray, unit_p: np.ndarray, unit_r: np.ndarray, noise: NoiseLevel) -> np.ndarray:
    R = rotvec_to_matrix(noise.orientation * unit_r) @ T[:, :3, :3]
    return make_transform(R, T[:, :3, 3] + noise.position * unit_p)


def make_split(problem: Problem, seed: int, n_cal: int, noise: NoiseLevel, n_val: int = N_VALIDATION) -> Split:
    """The dataset of one cell (seed, number of calibration poses, noise level); deterministic in ``seed``."""
    if n_cal < 1:
        raise ValueError(f"n_cal must be >= 1, got {n_cal}")
    if n_val < 1:
        raise ValueError(f"n_val must be >= 1, got {n_val}")
    rng = np.random.default_rng(seed)
    n_draw = max(N_CALIBRATION_MAX, n_cal)  # up to 100 poses the sets are nested (the growth runs go beyond)
    q_cal = sample_configurations(problem.nominal, n_draw, rng)
    unit_p = rng.standard_normal((n_draw, 3))
    unit_r = rng.standard_normal((n_draw, 3))
    q_val = sample_configurations(problem.nominal, n_val, np.random.default_rng([seed, 1]))
    q_cal, unit_p, unit_r = q_cal[:n_cal], unit_p[:n_cal], unit_r[:n_cal]
    T_cal = tool2meas(problem.truth, q_cal)
    return Split(
        seed=seed,
        noise=noise,
        q_cal=q_cal,
        tool2meas_cal=_noisy(T_cal, unit_p, unit_r, noise),
        tool2meas_cal_true=T_cal,
        q_val=q_val,
        tool2meas_val_true=tool2meas(problem.truth, q_val),
    )


def to_dataset(problem: Problem, split: Split) -> Dataset:
    """The split as a measured :class:`twin.dataset.Dataset` (what our estimator reads): the calibration rows
    with their 6-DOF poses, ``set = "calibration"``, the noise level in ``[noise]`` and no nominal
    ``base2meas`` (the frames are unknown). The truth is not in it."""
    n = split.n_cal
    return Dataset(
        robot=problem.nominal,
        robot_spec="irb1200",
        plate=default_plate(),
        pose_id=np.arange(n),
        q=split.q_cal.copy(),
        spheres=np.full((n, 3, 3), np.nan),
        sphere_seen=np.zeros((n, 3), dtype=bool),
        pose=split.tool2meas_cal.copy(),
        pose_seen=np.ones(n, dtype=bool),
        set=np.full(n, "calibration", dtype=object),
        noise_position=split.noise.position,
        noise_orientation=split.noise.orientation,
        provenance=f"benchmark synthetic IRB-1200, preset {problem.preset}, seed {split.seed}, noise {split.noise.label}",
    )
