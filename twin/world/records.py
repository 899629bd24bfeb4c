"""Records the world hands out: a :class:`Capture` (one measurement with its truth) and a :class:`BoardView`.

Kept apart from :mod:`twin.world.world` so that :mod:`twin.world.truth` can name them without importing the
world (no import cycle: ``world -> truth -> records``, ``world -> records``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Capture", "BoardView"]


@dataclass(frozen=True)
class Capture:
    """One measurement: the images and the truth behind them (SI; frames as in ``docs/conventions.md``).

    ``left``/``right`` ``(H, W)`` uint8; ``q_cmd``/``q_actual`` ``(6,)`` [rad]; ``spheres_meas`` ``(3, 3)`` [m]
    true sphere centres in the station's measurement frame (left camera, OpenCV axes); ``tool2meas``
    ``(4, 4)`` true plate pose there; ``params`` the actual parameter vector when an effect changed the
    geometry for this measurement (else ``None``: the world's true parameters apply).
    """

    pose_id: int
    station: int
    q_cmd: np.ndarray
    q_actual: np.ndarray
    left: np.ndarray
    right: np.ndarray
    spheres_meas: np.ndarray
    tool2meas: np.ndarray
    t_s: float
    temp_c: float
    params: np.ndarray | None = None


@dataclass(frozen=True)
class BoardView:
    """One board view: images and the true ``board2meas`` ``(4, 4)`` (left camera, OpenCV axes; truth)."""

    index: int
    left: np.ndarray
    right: np.ndarray
    board2meas: np.ndarray

    def __iter__(self):
        """Unpacks as the image pair: ``for left, right in world.render_board_views(n)``."""
        return iter((self.left, self.right))
