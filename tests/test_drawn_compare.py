"""The comparison of two runs of drawn sets (studies/drawn/compare.py): what moved, per instance, and the totals."""

import copy
import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from studies.drawn.compare import compare, holds, main  # noqa: E402

SET = ROOT / "studies" / "drawn" / "results_300" / "results.json"


@pytest.fixture(scope="module")
def committed() -> dict:
    return json.loads(SET.read_text())


def _find(results: dict, name: str) -> dict:
    return next(i for i in results["instances"] if i["name"] == name)


def test_a_run_against_itself_moves_nothing_and_keeps_the_sets_totals(committed):
    """The committed set against itself: no instance moved, and its holding count and clean alarms are the totals its
    results.json states (the tables' figures)."""
    c = compare(committed, committed)
    assert c.moved == () and c.only_one_side == ()
    assert c.held_before == c.held_after == committed["totals"]["named_and_test_within_1.2"]
    assert c.alarms_before == c.alarms_after == committed["totals"]["clean_false_alarms"]
    assert c.n_effect == committed["totals"]["effect_instances"]


def test_an_instance_pushed_past_the_goal_moves_and_the_total_follows(committed):
    """An instance that held, its later rows set to 1.5x the oracle, is listed as no longer holding and the set's
    count drops by one."""
    name = next(i["name"] for i in committed["instances"] if holds(i) and i["category"] != "clean")
    new = copy.deepcopy(committed)
    inst = _find(new, name)
    inst["test"].update(after_over_oracle=1.5, within_goal=False, **{"within_1.2": False})
    c = compare(committed, new)
    assert [m.name for m in c.moved] == [name]
    assert c.moved[0].held_before and not c.moved[0].held_after
    assert c.held_after == c.held_before - 1


def test_a_small_ratio_change_is_not_a_move_and_a_larger_one_is(committed):
    """A later-rows ratio changed by 1 % is within the default tolerance; by 5 % it is listed though the instance
    holds on both sides."""
    name = next(i["name"] for i in committed["instances"] if (i.get("test") or {}).get("after_over_oracle"))
    for factor, listed in ((1.01, False), (1.05, True)):
        new = copy.deepcopy(committed)
        inst = _find(new, name)
        inst["test"]["after_over_oracle"] *= factor
        assert (name in [m.name for m in compare(committed, new).moved]) is listed


def test_a_clean_alarm_counts_as_an_alarm_and_not_in_the_effect_total(committed):
    """A clean instance turned into an alarm raises the alarms by one and leaves the effect instances' count as it
    was."""
    name = next(i["name"] for i in committed["instances"] if i["category"] == "clean" and i["named"])
    new = copy.deepcopy(committed)
    _find(new, name)["named"] = False
    c = compare(committed, new)
    assert c.alarms_after == c.alarms_before + 1 and c.held_after == c.held_before
    assert [m.name for m in c.moved] == [name]


def test_the_command_compares_two_folders_and_names_a_missing_file(tmp_path, capsys, committed):
    """``--old`` compares two folders and prints the moved instance; a folder without results.json is an error
    naming it, exit 2."""
    (tmp_path / "old").mkdir()
    (tmp_path / "new").mkdir()
    (tmp_path / "old" / "results.json").write_text(json.dumps(committed))
    new = copy.deepcopy(committed)
    name = new["instances"][0]["name"]
    new["instances"][0]["effects"] = ["not-a-family"]
    (tmp_path / "new" / "results.json").write_text(json.dumps(new))
    assert main([str(tmp_path / "new"), "--old", str(tmp_path / "old")]) == 0
    assert name in capsys.readouterr().out
    assert main([str(tmp_path / "empty"), "--old", str(tmp_path / "old")]) == 2
    assert "empty" in capsys.readouterr().err


def test_a_negative_tolerance_is_refused(committed):
    """ratio_tol below zero is a ValueError naming the argument."""
    with pytest.raises(ValueError, match="ratio_tol"):
        compare(committed, committed, ratio_tol=-0.1)


def test_the_same_families_in_another_order_are_not_a_move(committed):
    """An instance whose named families are listed in another order has not moved."""
    name = next(i["name"] for i in committed["instances"] if len(i.get("effects") or []) >= 2)
    new = copy.deepcopy(committed)
    _find(new, name)["effects"] = list(reversed(_find(new, name)["effects"]))
    assert compare(committed, new).moved == ()


def test_a_file_that_is_not_json_is_an_error_naming_it(tmp_path, capsys, committed):
    """A results.json that is not JSON, or an instance without a name, is an error naming the file or the entry
    (exit 2), not a traceback."""
    (tmp_path / "old").mkdir()
    (tmp_path / "new").mkdir()
    (tmp_path / "old" / "results.json").write_text(json.dumps(committed))
    (tmp_path / "new" / "results.json").write_text("{not json")
    assert main([str(tmp_path / "new"), "--old", str(tmp_path / "old")]) == 2
    assert "results.json" in capsys.readouterr().err
    (tmp_path / "new" / "results.json").write_text(json.dumps({"instances": [{"family": "clean"}]}))
    assert main([str(tmp_path / "new"), "--old", str(tmp_path / "old")]) == 2
    assert "instances[0]" in capsys.readouterr().err
