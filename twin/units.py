"""Units at the edges: the one place where millimetres and degrees meet the library's SI.

Inside the library every length is in metres [m] and every angle in radians [rad]. Tables, CSV files, the CLI
and the report files speak millimetres [mm], micrometres [um], degrees [deg] and milliradians [mrad]; they convert
with the constants and functions below, never with a literal ``1e-3`` or ``180 / pi`` of their own.

Each constant is named ``<TO>_PER_<FROM>``: multiply a value in FROM by it to get TO, e.g.
``length_m = length_mm * M_PER_MM``.
"""

from __future__ import annotations

import math

__all__ = [
    "M_PER_MM",
    "MM_PER_M",
    "M_PER_UM",
    "UM_PER_M",
    "RAD_PER_DEG",
    "DEG_PER_RAD",
    "RAD_PER_MRAD",
    "MRAD_PER_RAD",
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
RAD_PER_MRAD = 1e-3
"""[rad] per [mrad]."""
MRAD_PER_RAD = 1e3
"""[mrad] per [rad]."""


def _scale(value, factor: float):
    """``value * factor``: a number stays a number; an array, list or tuple comes back as an array."""
    if isinstance(value, (int, float)):
        return value * factor
    import numpy as np  # arrays only: importing the constants loads no numpy (the CLI's parser imports them)

    return np.multiply(value, factor)


def mm_to_m(value_mm):
    """A length in [mm] (a number, or an array, list or tuple of any shape: an array back) in [m]."""
    return _scale(value_mm, M_PER_MM)


def m_to_mm(value_m):
    """A length in [m] (a number, or an array, list or tuple of any shape: an array back) in [mm]."""
    return _scale(value_m, MM_PER_M)


def deg_to_rad(value_deg):
    """An angle in [deg] (a number, or an array, list or tuple of any shape: an array back) in [rad]."""
    return _scale(value_deg, RAD_PER_DEG)


def rad_to_deg(value_rad):
    """An angle in [rad] (a number, or an array, list or tuple of any shape: an array back) in [deg]."""
    return _scale(value_rad, DEG_PER_RAD)
