"""Units at the edges: the one place where millimetres and degrees meet the library's SI.

Inside the library every length is in metres [m] and every angle in radians [rad]. Tables, CSV files, the CLI
and the report files speak millimetres [mm], micrometres [um] and degrees [deg]; they convert with the constants
and functions below, never with a literal ``1e-3`` or ``180 / pi`` of their own.

Each constant is named ``<TO>_PER_<FROM>``: multiply a value in FROM by it to get TO, e.g.
``length_m = length_mm * M_PER_MM``.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "M_PER_MM",
    "MM_PER_M",
    "M_PER_UM",
    "UM_PER_M",
    "RAD_PER_DEG",
    "DEG_PER_RAD",
    "mm_to_m",
    "m_to_mm",
    "deg_to_rad",
    "rad_to_deg",
]

M_PER_MM = 1e-3
"""[m] per [mm]."""
MM_PER_M = 1e3
"""[mm] per [m]."""
M_PER_UM = 1e-6
"""[m] per [um]."""
UM_PER_M = 1e6
"""[um] per [m]."""
RAD_PER_DEG = math.pi / 180.0
"""[rad] per [deg]."""
DEG_PER_RAD = 180.0 / math.pi
"""[deg] per [rad]."""


def mm_to_m(value_mm):
    """A length in [mm] (a number or an array of any shape) in [m]."""
    return np.multiply(value_mm, M_PER_MM) if isinstance(value_mm, np.ndarray) else value_mm * M_PER_MM


def m_to_mm(value_m):
    """A length in [m] (a number or an array of any shape) in [mm]."""
    return np.multiply(value_m, MM_PER_M) if isinstance(value_m, np.ndarray) else value_m * MM_PER_M


def deg_to_rad(value_deg):
    """An angle in [deg] (a number or an array of any shape) in [rad]."""
    return np.multiply(value_deg, RAD_PER_DEG) if isinstance(value_deg, np.ndarray) else value_deg * RAD_PER_DEG


def rad_to_deg(value_rad):
    """An angle in [rad] (a number or an array of any shape) in [deg]."""
    return np.multiply(value_rad, DEG_PER_RAD) if isinstance(value_rad, np.ndarray) else value_rad * DEG_PER_RAD
