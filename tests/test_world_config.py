"""World configuration: TOML schema, units at the edge, validation naming the bad key."""

from pathlib import Path

import numpy as np
import pytest

from twin.presets import preset_deviation
from twin.robots import get_robot
from twin.world.config import WorldConfig, default_stations, load_world_config

ROOT = Path(__file__).resolve().parent.parent


def test_default_config_file_loads_and_matches_the_built_in_defaults():
    """experiments/world_default.toml parses and describes the same stations as the built-in default."""
    cfg = load_world_config(ROOT / "experiments" / "world_default.toml")
    assert cfg.robot == "irb1200" and cfg.preset == "separation_tables_2_4"
    assert [s.name for s in cfg.stations] == [s.name for s in default_stations()]
    for a, b in zip(cfg.stations, default_stations()):
        assert np.allclose(a.target, b.target) and np.isclose(a.azimuth, b.azimuth) and np.isclose(a.elevation, b.elevation)
    assert cfg.rig.baseline == pytest.approx(0.25) and cfg.rig.focal_px == pytest.approx(7272.7272727)


def test_errors_are_added_to_the_preset_in_si():
    """Explicit errors in mm/deg add to the preset's deviation, converted to SI."""
    cfg = WorldConfig.from_dict({"world": {"preset": "separation_tables_2_4", "errors": {"d1_mm": 0.5, "theta2_deg": 0.01}}})
    nominal = get_robot("irb1200")
    dev = cfg.deviation(nominal)
    pre = preset_deviation("separation_tables_2_4")
    assert dev[nominal.layout.index("d1")] == pytest.approx(pre["d1"] + 0.5e-3)
    assert dev[nominal.layout.index("theta2")] == pytest.approx(pre["theta2"] + np.deg2rad(0.01))


def test_error_with_the_wrong_unit_is_refused():
    """A length written in degrees is an error that names the key and the right spelling."""
    with pytest.raises(ValueError, match="d1_deg.*d1_mm"):
        WorldConfig.from_dict({"errors": {"d1_deg": 0.1}})


def test_unknown_key_is_refused():
    """A typo in a key is an error naming it, never a silent default."""
    with pytest.raises(ValueError, match="basline_mm"):
        WorldConfig.from_dict({"rig": {"basline_mm": 200}})


def test_preset_for_another_robot_is_refused():
    """The TM-MDH preset cannot be injected into the IRB-1200."""
    with pytest.raises(ValueError, match="brtirus0707a"):
        WorldConfig.from_dict({"robot": "irb1200", "preset": "tmmdh_tables_4_5"})


def test_random_errors_are_seeded():
    """Random deviations repeat with the seed, differ across seeds, and leave base/tool alone."""
    nominal = get_robot("irb1200")
    mk = lambda seed: WorldConfig.from_dict({"seed": seed, "random_errors": {"length_sigma_mm": 0.1, "angle_sigma_deg": 0.01}})
    a, b, c = mk(1).deviation(nominal), mk(1).deviation(nominal), mk(2).deviation(nominal)
    assert np.array_equal(a, b) and not np.allclose(a, c)
    assert np.all(a[nominal.layout.base_slice] == 0) and np.all(a[nominal.layout.tool_slice] == 0)


def test_bad_values_name_the_field():
    """Non-positive stand-off, scale above 1 and folded board geometry are refused with the field's name."""
    with pytest.raises(ValueError, match="standoff_mm"):
        WorldConfig.from_dict({"rig": {"standoff_mm": -1}})
    with pytest.raises(ValueError, match="scale"):
        WorldConfig.from_dict({"render": {"scale": 2}})
    with pytest.raises(ValueError, match="marker_mm"):
        WorldConfig.from_dict({"board": {"marker_mm": 20}})
    with pytest.raises(ValueError, match="target_mm"):
        WorldConfig.from_dict({"stations": [{"name": "x"}]})


@pytest.mark.parametrize("rig,station,match", [
    ({"baseline_mm": True}, {}, r"world.rig.baseline_mm must be a number, got True"),
    ({"baseline_mm": 1e308}, {}, r"world.rig.baseline_mm must be within 1e\+09"),
    ({}, {"azimuth_deg": True}, r"world.stations\[0\].azimuth_deg must be a number, got True"),
    ({}, {"elevation_deg": 1e308}, r"world.stations\[0\].elevation_deg must be within 1e\+09"),
    ({}, {"target_mm": [500, True, 550]}, r"world.stations\[0\].target_mm must be 3 numbers"),
    ({}, {"name": ["left", "left"]}, r"world.stations\[0\].name must be a non-empty string"),
])
def test_a_setting_of_another_type_or_beyond_any_rig_is_refused_naming_it(rig, station, match):
    """TOML's true where a number is due (Python would read 1), 1e308 (a typing error: a meaningless angle or an
    overflow in a render later), a list for a station's name: ValueError naming the field."""
    with pytest.raises(ValueError, match=match):
        WorldConfig.from_dict({"rig": rig, "stations": [{"name": "x", "target_mm": [500, 0, 550], **station}]})


def test_missing_file_is_a_value_error(tmp_path):
    """A missing config file is reported as such."""
    with pytest.raises(ValueError, match="not found"):
        load_world_config(tmp_path / "nope.toml")


def test_supersample_defaults_to_one_and_reads_an_integer():
    """render.supersample is 1 unless given; an integer from the TOML is kept."""
    assert WorldConfig.from_dict({}).render.supersample == 1
    assert WorldConfig.from_dict({"render": {"supersample": 2}}).render.supersample == 2


@pytest.mark.parametrize("bad", [0, -1, 1.5, 2.0, True, "2", 5])
def test_supersample_that_is_not_a_small_positive_integer_is_refused(bad):
    """Zero, negative, fractional, boolean, string and too-large supersampling factors name the key."""
    with pytest.raises(ValueError, match="render.supersample"):
        WorldConfig.from_dict({"render": {"supersample": bad}})
