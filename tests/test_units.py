"""The edge conversions of twin.units."""

import math

import numpy as np

from twin import units


def test_constants_are_inverse_pairs():
    """Each ``<TO>_PER_<FROM>`` constant times its reverse is one."""
    assert units.M_PER_MM * units.MM_PER_M == 1.0
    assert math.isclose(units.M_PER_UM * units.UM_PER_M, 1.0)
    assert math.isclose(units.RAD_PER_DEG * units.DEG_PER_RAD, 1.0)


def test_round_trips_keep_arrays_and_numbers():
    """mm -> m -> mm and deg -> rad -> deg return the input, for numbers and (n, 3) arrays."""
    rng = np.random.default_rng(7)
    a = rng.normal(size=(5, 3)) * 100.0
    np.testing.assert_allclose(units.m_to_mm(units.mm_to_m(a)), a, rtol=1e-15)
    np.testing.assert_allclose(units.rad_to_deg(units.deg_to_rad(a)), a, rtol=1e-15)
    assert units.mm_to_m(25.4) == 25.4e-3
    assert math.isclose(units.deg_to_rad(180.0), math.pi)
