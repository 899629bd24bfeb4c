"""Tests of twin.runner.config and twin.runner.plan: campaign configs and pose plans."""

import tomllib
from pathlib import Path

import numpy as np
import pytest

import _newcomer_chain as C
from twin.runner.config import load_campaign_config, parse_campaign_config
from twin.runner.plan import make_plan, pose_seed
from twin.kinematics import flange2base

ROOT = Path(__file__).resolve().parent.parent
SEPARATION = ROOT / "experiments" / "separation.toml"


def _raw():
    return tomllib.loads(SEPARATION.read_text())


def test_separation_config_matches_the_paper_protocol():
    """The shipped config has 25 + 25 motion pairs, 40 distance tests of 50/60/80/100 mm, and five methods (the
    separation method in our variant and the paper-literal one)."""
    c = load_campaign_config(SEPARATION)
    g = {x.name: x for x in c.groups}
    assert (g["calibration"].count, g["compensation"].count, g["distance"].count) == (25, 25, 40)
    assert sorted(set(np.round(np.array(g["distance"].distances) * 1e3, 6))) == [50, 60, 80, 100]
    assert c.methods == ("distance", "full_pose", "separation", "separation_paper", "default")
    assert c.true_deviation()["theta2"] == pytest.approx(np.deg2rad(-0.3))


def test_unknown_key_is_named():
    """A misspelt key is refused with its dotted name, not ignored."""
    raw = _raw()
    raw["measurement"]["noise_mn"] = 0.01
    with pytest.raises(ValueError, match=r"measurement\.noise_mn"):
        parse_campaign_config(raw)


def test_preset_of_another_robot_is_refused():
    """A preset for another robot is refused, naming the key."""
    raw = _raw()
    raw["world"]["preset"] = "tmmdh_tables_4_5"
    with pytest.raises(ValueError, match="world.preset"):
        parse_campaign_config(raw)


def test_extra_errors_add_to_the_preset_in_si():
    """[world.errors] values in deg / mm are added to the preset, converted to rad / m."""
    raw = _raw()
    raw["world"]["errors"] = {"theta2_deg": 0.1, "d4_mm": 0.5}
    c = parse_campaign_config(raw)
    dev = c.true_deviation()
    assert dev["theta2"] == pytest.approx(np.deg2rad(-0.2))
    assert dev["d4"] == pytest.approx(-0.1e-3 + 0.5e-3)
    raw["world"]["errors"] = {"theta2": 0.1}
    with pytest.raises(ValueError, match=r"world\.errors\.theta2: a deviation needs a unit suffix"):
        parse_campaign_config(raw)


def test_quick_merges_its_table():
    """--quick applies [quick]: half resolution and fewer poses, and changes the fingerprint."""
    full = load_campaign_config(SEPARATION)
    quick = load_campaign_config(SEPARATION, quick=True)
    assert quick.world["render"]["scale"] == 0.5
    assert quick.stations()[0].cameras[0].intrinsics.width == 1296
    assert sum(g.count for g in quick.groups) < sum(g.count for g in full.groups)
    assert quick.fingerprint() != full.fingerprint()
    assert quick.with_seed(5).quick and quick.with_seed(5).seed == 5


def test_plan_is_reproducible_and_ordered():
    """The plan depends only on the config: pose ids count up, pairs are consecutive start/end rows."""
    c = load_campaign_config(SEPARATION, quick=True)
    a, b = make_plan(c), make_plan(c)
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_array_equal(a.pose_id, np.arange(a.n))
    s, e = a.pairs("calibration")
    np.testing.assert_array_equal(e, s + 1)
    assert list(a.group[: 2 * 15]) == ["calibration"] * 30
    other = make_plan(c.with_seed(c.seed + 1))
    assert not np.allclose(other.q, a.q)


def test_plan_distance_moves_have_the_commanded_distance():
    """Distance-move rows carry their distance and the nominal flange moves by it."""
    c = load_campaign_config(SEPARATION, quick=True)
    p = make_plan(c)
    s, e = p.pairs("distance")
    m = c.nominal_model()
    moved = np.linalg.norm(flange2base(m, p.q[e])[:, :3, 3] - flange2base(m, p.q[s])[:, :3, 3], axis=1)
    np.testing.assert_allclose(moved, p.distance[s], atol=1e-9)


def test_pose_seed_depends_on_seed_and_key():
    """Per-pose seeds are stable and differ between keys and campaigns."""
    assert pose_seed(1, "before/3") == pose_seed(1, "before/3")
    assert len({pose_seed(1, "before/3"), pose_seed(1, "before/4"), pose_seed(2, "before/3")}) == 3


def test_joints_csv_group_takes_poses_from_a_plan_file(tmp_path):
    """A joints_csv group (e.g. written by twin plan) is measured as given; consecutive rows can form pairs."""
    from twin.dataset import Joints, write_joints_csv

    c = load_campaign_config(SEPARATION, quick=True)
    q = make_plan(c).q[:4]
    write_joints_csv(tmp_path / "plan.csv", Joints(np.arange(4), q, station=np.array(["front"] * 4, dtype=object)))
    raw = _raw()
    raw.pop("quick")  # its [[poses]] replaced below: the [quick] table that addresses the old ones goes with them
    raw["poses"] = [{"name": "planned", "set": "calibration", "kind": "joints_csv", "path": str(tmp_path / "plan.csv")},
                    {"name": "check", "set": "validation", "kind": "joints_csv", "path": str(tmp_path / "plan.csv"),
                     "pairing": "consecutive", "evaluate": ["angle"]}]
    p = make_plan(parse_campaign_config(raw))
    np.testing.assert_allclose(p.q[:4], q, atol=1e-12)
    assert list(p.role[4:]) == ["start", "end", "start", "end"] and list(p.role[:4]) == ["single"] * 4
    raw["poses"][1]["pairing"] = "none"
    with pytest.raises(ValueError, match="no motion to evaluate"):
        parse_campaign_config(raw)


def test_motion_keys_are_read_in_si():
    """turn_deg / shift_mm / distance_turn_deg / max_joint_step_deg reach the sampler in rad and m."""
    raw = _raw()
    raw["sampling"]["turn_deg"] = [0, 18]
    raw["sampling"]["shift_mm"] = [50, 100]
    raw["poses"][2]["sampling"]["distance_turn_deg"] = [20, 45]
    raw["poses"][2]["sampling"]["max_joint_step_deg"] = 40
    g = {x.name: x for x in parse_campaign_config(raw).groups}
    assert g["compensation"].sampling.turn == pytest.approx((0.0, np.deg2rad(18)))
    assert g["compensation"].sampling.shift == pytest.approx((0.05, 0.1))
    assert g["distance"].sampling.distance_turn == pytest.approx((np.deg2rad(20), np.deg2rad(45)))
    assert g["distance"].sampling.max_joint_step == pytest.approx(np.deg2rad(40))


@pytest.mark.parametrize("key, value, message", [
    ("turn_deg", [30, 10], "turn"), ("shift_mm", [50, 100], "shift_mm"), ("distance_turn_deg", [0], "distance_turn_deg"),
])
def test_bad_motion_keys_are_refused_naming_them(key, value, message):
    """A reversed turn range, a shift without a turn, or a malformed range is refused naming the key."""
    raw = _raw()
    raw["sampling"][key] = value
    with pytest.raises(ValueError, match=message):
        parse_campaign_config(raw)


def test_matched_config_is_the_paper_protocol_with_local_motions():
    """separation_matched.toml: truth_noise, 25 + 25 local motion pairs, 40 turning moves of 50/60/80/100 mm, five methods."""
    c = load_campaign_config(ROOT / "studies" / "separation_paper" / "separation_matched.toml")
    g = {x.name: x for x in c.groups}
    assert c.measurement.mode == "truth_noise" and c.measurement.noise_position == pytest.approx(1e-5)
    assert (g["calibration"].count, g["compensation"].count, g["distance"].count) == (25, 25, 40)
    assert sorted(set(np.round(np.array(g["distance"].distances) * 1e3, 6))) == [50, 60, 80, 100]
    assert g["calibration"].sampling.turn is not None and g["distance"].sampling.distance_turn[1] > 0
    assert set(c.methods) == {"distance", "full_pose", "separation", "separation_paper", "default"}


@pytest.mark.parametrize("kind", [k for k in C.MAP_CORRUPTIONS if k != "map_file_missing"])
@pytest.mark.parametrize("quick", [False, True])
def test_a_corrupted_campaign_config_loads_or_is_refused_naming_the_key(kind, quick, tmp_path):
    """experiments/separation.toml corrupted one way (a key dropped or twice, a value of another type, 1e308, a
    name beyond ASCII, broken TOML...): it loads, or ValueError naming the file; never another exception."""
    p = tmp_path / "separation.toml"
    p.write_text(SEPARATION.read_text())
    C.corrupt_map(p, kind, np.random.default_rng(940000 + C.MAP_CORRUPTIONS.index(kind)))
    try:
        load_campaign_config(p, quick=quick)
    except ValueError as exc:
        assert str(p) in str(exc) or "separation.toml" in str(exc), exc


@pytest.mark.parametrize("bad", ["scale = \"half\"", "scale = -0.5", "scale = true"])
def test_a_fault_in_the_quick_table_is_named_without_quick(bad, tmp_path):
    """A value of the [quick] table that the quick run would refuse is refused on every load, --quick or not, naming
    the file, the key and the [quick] variant."""
    p = tmp_path / "separation.toml"
    text = SEPARATION.read_text()
    assert "world = { render = { scale = 0.5 } }" in text
    p.write_text(text.replace("world = { render = { scale = 0.5 } }", f"world = {{ render = {{ {bad} }} }}"))
    for quick in (False, True):
        with pytest.raises(ValueError) as err:
            load_campaign_config(p, quick=quick)
        assert str(p) in str(err.value) and "scale" in str(err.value), err.value
    assert "[quick] variant" in str(pytest.raises(ValueError, load_campaign_config, p).value)
