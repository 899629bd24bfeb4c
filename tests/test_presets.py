"""Tests of twin.presets: the papers' injected deviations load onto the right robots."""

import numpy as np
import pytest

from twin.presets import PRESETS, preset_deviation, preset_robot
from twin.robots import get_robot


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_every_preset_names_parameters_of_its_robot(name):
    """Each preset's keys are parameters of its robot and perturbing with it works."""
    model = get_robot(preset_robot(name))
    dev = preset_deviation(name)
    for k in dev:
        model.layout.index(k)
    assert np.isfinite(model.perturbed(dev).params).all()


def test_separation_theta2_theta3_sum_is_table2_value():
    """Table 4's theta2 (-0.3 deg) and theta3 (-0.1 deg) sum to Table 2's -0.4 deg, injected once."""
    dev = preset_deviation("separation_tables_2_4")
    assert np.rad2deg(dev["theta2"] + dev["theta3"]) == pytest.approx(-0.4)
    assert dev["a1"] == pytest.approx(1e-3) and np.rad2deg(dev["beta2"]) == pytest.approx(0.1)


def test_tmmdh_base_rotation_from_zyx_angles():
    """Table 5's base angles (beta 0.001 about y, gamma 0.005 about x) become a rotation vector of that size."""
    dev = preset_deviation("tmmdh_tables_4_5")
    r = np.array([dev["base_rx"], dev["base_ry"], dev["base_rz"]])
    assert np.linalg.norm(r) == pytest.approx(np.hypot(0.001, 0.005), rel=1e-5)
    assert dev["base_x"] == pytest.approx(0.05e-3)


def test_unknown_preset_is_named():
    """An unknown preset name is refused with its name."""
    with pytest.raises(ValueError, match="unknown preset 'nope'"):
        preset_deviation("nope")
