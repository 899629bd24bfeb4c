"""What every peer adapter returns, and the one piece of data preparation shared by the peers that need it."""

from __future__ import annotations

import contextlib
import io
import logging
import time
import warnings
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from twin.kinematics import RobotModel, flange2base

__all__ = ["PeerResult", "PeerUnavailable", "register_base_and_tool", "run_quietly", "timed"]


class PeerUnavailable(RuntimeError):
    """The peer library is not installed (``pip install .[peers]``)."""


@dataclass(frozen=True, eq=False)
class PeerResult:
    """A peer's calibration of one dataset, as the benchmark scores it.

    ``positions`` ``(m, 3)`` [m] and ``rotations`` ``(m, 3, 3)`` are the peer's predictions of the validation tool
    poses in the measurement frame (``rotations`` is ``None`` where the peer cannot predict orientation).
    ``fit_seconds`` is the wall time of the identification alone (data conversion and prediction excluded; the
    peer's own set-up such as parsing its configuration is included when the peer's API does it inside the
    call that fits). ``error`` holds the exception text when the peer failed (then the arrays are ``None``).
    ``data_used`` says which parts of the measurements the peer could use; ``notes`` anything else worth
    printing (settings, warnings the peer raised).
    """

    peer: str
    variant: str
    positions: np.ndarray | None
    rotations: np.ndarray | None
    fit_seconds: float | None
    settings: dict
    data_used: str
    error: str | None = None
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def ok(self) -> bool:
        return self.error is None


def timed(fn: Callable[[], object]) -> tuple[float, object]:
    """(wall time [s], result) of ``fn()``."""
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


@contextlib.contextmanager
def run_quietly():
    """Silence a peer's prints, logging and warnings (they cost time and flood the benchmark's output)."""
    buf = io.StringIO()
    prev = logging.root.manager.disable
    logging.disable(logging.CRITICAL)
    try:
        with warnings.catch_warnings(), contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
            warnings.simplefilter("ignore")
            yield buf
    finally:
        logging.disable(prev)


def _kabsch(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Rotation ``R`` minimising ``sum |R (s - s_mean) - (t - t_mean)|^2``."""
    H = (source - source.mean(0)).T @ (target - target.mean(0))
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    return Vt.T @ D @ U.T


def register_base_and_tool(
    nominal: RobotModel, q: np.ndarray, positions: np.ndarray, iterations: int = 30
) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form start for an unknown measurement frame and tool point, from measured positions alone.

    With the nominal joint geometry ``(R_i, p_i) = flange2base(q_i)``, the measured tool point obeys
    ``P_i = R_b (p_i + R_i t) + t_b``. Alternate Kabsch for ``R_b`` with a linear least-squares solve for
    ``(t_b, t)``. Returns ``base2meas`` ``(4, 4)`` and the tool point in the flange frame ``t`` ``(3,)`` [m].

    This is what a user of a peer without its own frame initialisation (pybotics, robotkinecal) has to do
    before calling it; FIGAROH does the same internally (``estimate_frames_closed_form``).
    """
    F = flange2base(nominal.with_frames(np.eye(4), np.eye(4)), q)
    R, p = F[:, :3, :3], F[:, :3, 3]
    P = np.asarray(positions, dtype=float)
    n = len(q)
    R_b, t_b, t = np.eye(3), np.zeros(3), np.zeros(3)
    for _ in range(iterations):
        R_b = _kabsch(p + R @ t, P)
        A = np.zeros((n, 3, 6))
        A[:, :, :3] = R_b @ R
        A[:, :, 3:] = np.eye(3)
        sol = np.linalg.lstsq(A.reshape(-1, 6), (P - p @ R_b.T).reshape(-1), rcond=None)[0]
        t, t_b = sol[:3], sol[3:]
    base2meas = np.eye(4)
    base2meas[:3, :3], base2meas[:3, 3] = R_b, t_b
    return base2meas, t
