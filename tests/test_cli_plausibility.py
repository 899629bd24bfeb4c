"""Refusing what cannot be right in `twin predict`, `twin compensate` and `twin export`: joints in
radians or beyond the limits, targets in the wrong units or out of reach, a calibration written with --force."""

import csv
import json

import numpy as np
import pytest

from twin.cli import main
from twin.dataset import Joints, read_joints_csv, write_joints_csv
from twin.estimator import Calibration
from twin.estimator.files import write_targets_csv
from twin.estimator.plausibility import ImplausibleData, check_joint_values, check_targets, forced_reasons, tool_reach
from twin.estimator.simulate import random_configurations
from twin.kinematics import tool2base
from twin.robots import get_robot

from _estimator_helpers import write_clean_dataset


@pytest.fixture(scope="module")
def cal(tmp_path_factory):
    """A clean 80-row single-station dataset, its calibration, and a copy of that calibration marked forced."""
    d = tmp_path_factory.mktemp("plaus_cli")
    write_clean_dataset(d / "ds", 80, seed=12)
    assert main(["calibrate", str(d / "ds"), "--out", str(d / "cal"), "--quiet"]) == 0
    j = json.loads((d / "cal" / "calibration.json").read_text())
    j["details"]["plausibility"]["forced"] = ["every joint of the 80 rows lies within 3 deg of zero: joints look like radians"]
    (d / "forced").mkdir()
    (d / "forced" / "calibration.json").write_text(json.dumps(j))
    return d / "cal" / "calibration.json", d / "forced" / "calibration.json"


def _joints(path, q, pid=None):
    pid = np.arange(len(q)) if pid is None else pid
    write_joints_csv(path, Joints(pose_id=pid, q=q))
    return path


def _targets(n=12, seed=5):
    """Reachable plate poses (from joints well inside the limits) and those joints."""
    nom = get_robot("irb1200")
    q = random_configurations(nom, n, np.random.default_rng(seed), margin=0.3)
    return tool2base(nom, q), q


def _run(*argv):
    return main([str(a) for a in argv])


def test_predict_refuses_joints_written_in_radians(cal, tmp_path, capsys):
    """predict: JOINTS.csv holding radians in the degree columns: exit 2, 'joints look like radians', no file."""
    q = random_configurations(get_robot("irb1200"), 20, np.random.default_rng(1))
    j = _joints(tmp_path / "j.csv", np.deg2rad(q))  # each value read back as (q in rad) degrees
    assert _run("predict", cal[0], j, "--out", tmp_path / "p.csv") == 2
    err = capsys.readouterr().err
    assert "joints look like radians" in err and "nothing written" in err
    assert not (tmp_path / "p.csv").exists()


def test_predict_refuses_joints_beyond_the_limits(cal, tmp_path, capsys):
    """predict: one row beyond q2's limit: exit 2 naming the joint and the pose_id, no file."""
    rob = get_robot("irb1200")
    q = random_configurations(rob, 5, np.random.default_rng(2))
    q[3, 1] = rob.q_max[1] + 0.2
    j = _joints(tmp_path / "j.csv", q, pid=np.array([10, 11, 12, 13, 14]))
    assert _run("predict", cal[0], j, "--out", tmp_path / "p.csv") == 2
    err = capsys.readouterr().err
    assert "q2 outside the robot's limits" in err and "[13]" in err
    assert not (tmp_path / "p.csv").exists()


def test_predict_force_predicts_implausible_joints_with_a_warning(cal, tmp_path, capsys):
    """predict --force: joints beyond the limits predicted anyway, every row, with the reason on stderr."""
    rob = get_robot("irb1200")
    q = random_configurations(rob, 5, np.random.default_rng(2))
    q[3, 1] = rob.q_max[1] + 0.2
    j = _joints(tmp_path / "j.csv", q)
    assert _run("predict", cal[0], j, "--out", tmp_path / "p.csv", "--force") == 0
    assert "warning:" in capsys.readouterr().err
    assert len((tmp_path / "p.csv").read_text().splitlines()) == 6


def test_predict_on_plausible_joints_warns_of_nothing(cal, tmp_path, capsys):
    """predict: joints within the limits and a calibration that was not forced: exit 0, nothing on stderr."""
    j = _joints(tmp_path / "j.csv", random_configurations(get_robot("irb1200"), 20, np.random.default_rng(3)))
    assert _run("predict", cal[0], j, "--out", tmp_path / "p.csv") == 0
    assert capsys.readouterr().err == ""


def test_predict_names_a_station_the_calibration_does_not_know(cal, tmp_path, capsys):
    """predict: a JOINTS.csv row whose station the calibration does not know (a typing error) is predicted in the
    robot base frame, and stderr says which station, on how many rows, and which stations the calibration knows."""
    q = random_configurations(get_robot("irb1200"), 4, np.random.default_rng(3))
    j = tmp_path / "j.csv"
    write_joints_csv(j, Joints(pose_id=np.arange(4), q=q, station=np.array(["0", "0", "O", "0"], dtype=object)))
    assert _run("predict", cal[0], j, "--out", tmp_path / "p.csv") == 0
    err = capsys.readouterr().err
    assert "station(s) the calibration does not know ('O': 1 row(s); it knows '0')" in err
    with open(tmp_path / "p.csv", newline="") as f:
        assert [r["frame"] for r in csv.DictReader(f)] == ["measurement", "measurement", "base", "measurement"]


def test_predict_warns_of_a_forced_calibration(cal, tmp_path, capsys):
    """predict with a calibration written by `calibrate --force`: the file is written, the reason is warned."""
    j = _joints(tmp_path / "j.csv", random_configurations(get_robot("irb1200"), 5, np.random.default_rng(3)))
    assert _run("predict", cal[1], j, "--out", tmp_path / "p.csv") == 0
    err = capsys.readouterr().err
    assert "written by `twin calibrate --force` past" in err and "joints look like radians" in err
    assert (tmp_path / "p.csv").exists()


def test_compensate_refuses_targets_in_metres(cal, tmp_path, capsys):
    """compensate: TARGETS.csv with metres in the millimetre columns: exit 2, 'positions in metres?', no file."""
    T, _ = _targets()
    T[:, :3, 3] *= 1e-3
    write_targets_csv(tmp_path / "t.csv", np.arange(len(T)), T)
    assert _run("compensate", cal[0], tmp_path / "t.csv", "--out", tmp_path / "q.csv") == 2
    assert "positions in metres?" in capsys.readouterr().err
    assert not (tmp_path / "q.csv").exists()


def test_compensate_refuses_targets_in_micrometres(cal, tmp_path, capsys):
    """compensate: positions 1000x too large: exit 2, 'beyond the robot's reach', 'micrometres?', no file."""
    T, _ = _targets()
    T[:, :3, 3] *= 1e3
    write_targets_csv(tmp_path / "t.csv", np.arange(len(T)), T)
    assert _run("compensate", cal[0], tmp_path / "t.csv", "--out", tmp_path / "q.csv") == 2
    err = capsys.readouterr().err
    assert "beyond the robot's reach" in err and "micrometres?" in err
    assert not (tmp_path / "q.csv").exists()


def test_compensate_names_a_target_beyond_the_reach(cal, tmp_path, capsys):
    """compensate: one target 2.5 m from the base among reachable ones: exit 2 naming its pose_id, no file."""
    T, _ = _targets()
    T[4, :3, 3] = [2.5, 0.0, 0.4]
    write_targets_csv(tmp_path / "t.csv", np.arange(100, 100 + len(T)), T)
    assert _run("compensate", cal[0], tmp_path / "t.csv", "--out", tmp_path / "q.csv") == 2
    err = capsys.readouterr().err
    assert "1 of 12 targets lie beyond the robot's reach" in err and "[104]" in err
    assert not (tmp_path / "q.csv").exists()


def test_compensate_refuses_reference_joints_in_radians(cal, tmp_path, capsys):
    """compensate --reference holding radians: exit 2 naming the reference file, no file (the branch it would
    pick is the one nearest zero, silently)."""
    T, q = _targets()
    write_targets_csv(tmp_path / "t.csv", np.arange(len(T)), T)
    ref = _joints(tmp_path / "ref.csv", np.deg2rad(q))
    assert _run("compensate", cal[0], tmp_path / "t.csv", "--out", tmp_path / "q.csv", "--reference", ref) == 2
    err = capsys.readouterr().err
    assert "ref.csv" in err and "joints look like radians" in err
    assert not (tmp_path / "q.csv").exists()


def test_compensate_on_plausible_targets_writes_every_row_silently(cal, tmp_path, capsys):
    """compensate: reachable targets in millimetres, plausible reference joints: exit 0, every row, no warning."""
    T, q = _targets()
    write_targets_csv(tmp_path / "t.csv", np.arange(len(T)), T)
    ref = _joints(tmp_path / "ref.csv", q)
    assert _run("compensate", cal[0], tmp_path / "t.csv", "--out", tmp_path / "q.csv", "--reference", ref) == 0
    assert capsys.readouterr().err == ""
    assert len(read_joints_csv(tmp_path / "q.csv").pose_id) == len(T)


def test_compensate_warns_of_a_forced_calibration(cal, tmp_path, capsys):
    """compensate with a calibration written by `calibrate --force`: written, with the reason warned."""
    T, _ = _targets()
    write_targets_csv(tmp_path / "t.csv", np.arange(len(T)), T)
    assert _run("compensate", cal[1], tmp_path / "t.csv", "--out", tmp_path / "q.csv") == 0
    assert "written by `twin calibrate --force` past" in capsys.readouterr().err
    assert (tmp_path / "q.csv").exists()


def test_export_marks_a_forced_calibration(cal, tmp_path, capsys):
    """export of a forced calibration: warned on stderr and stated at the top of parameters.md."""
    assert _run("export", cal[1], "--out", tmp_path / "x") == 0
    assert "written by `twin calibrate --force` past" in capsys.readouterr().err
    assert "**Forced**" in (tmp_path / "x" / "parameters.md").read_text()


def test_forced_reasons_is_empty_for_a_calibration_that_was_not_forced(cal):
    """A plain calibration reads as not forced; the marked copy gives its reason."""
    assert forced_reasons(Calibration.load(cal[0]).details) == []
    assert len(forced_reasons(Calibration.load(cal[1]).details)) == 1


def test_check_targets_accepts_poses_the_robot_reaches():
    """Plate poses computed from joints within the limits pass the target check."""
    T, _ = _targets(n=200, seed=9)
    check_targets(T, np.arange(200), get_robot("irb1200"))


def test_tool_reach_bounds_every_sampled_pose():
    """The reach bounds the plate's distance from the base over fresh configurations within the limits."""
    rob = get_robot("irb1200")
    _, reach = tool_reach(rob)
    q = np.random.default_rng(4).uniform(rob.q_min, rob.q_max, (2000, 6))
    assert np.linalg.norm(tool2base(rob, q)[:, :3, 3], axis=-1).max() <= 1.02 * reach


def test_check_joint_values_radians_rule_needs_ten_rows():
    """Nine rows near zero may be real (poses around home); ten are refused as radians."""
    rob = get_robot("irb1200")
    q = np.random.default_rng(6).uniform(-0.04, 0.04, (10, 6))
    assert check_joint_values(q[:9], np.arange(9), rob.q_min, rob.q_max) == []
    with pytest.raises(ImplausibleData, match="radians"):
        check_joint_values(q, np.arange(10), rob.q_min, rob.q_max)


def test_predict_leaves_no_partial_file_when_the_output_cannot_be_written(cal, tmp_path, capsys):
    """predict --out naming an existing folder: a named error, the folder untouched, no temporary file left."""
    j = _joints(tmp_path / "j.csv", random_configurations(get_robot("irb1200"), 5, np.random.default_rng(3)))
    (tmp_path / "out").mkdir()
    assert _run("predict", cal[0], j, "--out", tmp_path / "out") == 2
    assert "error:" in capsys.readouterr().err
    assert list((tmp_path / "out").iterdir()) == [] and not any(p.name.endswith(".tmp") for p in tmp_path.iterdir())


def test_predict_with_a_temperature_term_names_the_rows_without_a_temperature(cal, tmp_path, capsys):
    """An extended calibration whose term reads temp_c and a JOINTS.csv whose temp_c is empty in two rows: predict
    refuses naming the column and those rows' pose_id (no NaN prediction); without the term it predicts them."""
    from dataclasses import replace

    from twin.diagnosis.atoms import Atom
    from twin.diagnosis.features import Pow

    c = Calibration.load(cal[0])
    term = Atom("thermal", "length", "all_lengths", (Pow(ch="temp_c", p=1, c=20.0, h=1.0),), "temp_c",
                "links growing with temperature", "catalogue")
    replace(c, effects=({**term.spec(), "values": [1e-5]},)).save(tmp_path / "thermal.json")
    q = random_configurations(get_robot("irb1200"), 5, np.random.default_rng(3))
    temp = np.array([20.0, np.nan, 21.0, np.nan, 22.0])
    write_joints_csv(tmp_path / "j.csv", Joints(pose_id=np.arange(10, 15), q=q, temp_c=temp))
    assert np.isnan(read_joints_csv(tmp_path / "j.csv").temp_c).tolist() == np.isnan(temp).tolist()
    assert _run("predict", tmp_path / "thermal.json", tmp_path / "j.csv", "--out", tmp_path / "p.csv") == 2
    assert "column 'temp_c' is empty in 2 of 5 rows (pose_id [11, 13])" in capsys.readouterr().err
    assert _run("predict", cal[0], tmp_path / "j.csv", "--out", tmp_path / "p.csv") == 0
    assert "nan" not in (tmp_path / "p.csv").read_text().lower()


def test_a_short_joints_file_near_zero_is_warned_as_radians_and_degrees_are_not(cal, tmp_path, capsys):
    """Five rows whose joints all lie within pi degrees of zero (radians in the degree columns): predict warns and
    says why it does not refuse; five rows of the same joints in degrees: no warning."""
    q = random_configurations(get_robot("irb1200"), 5, np.random.default_rng(3))
    assert _run("predict", cal[0], _joints(tmp_path / "rad.csv", q * np.pi / 180), "--out", tmp_path / "p.csv") == 0
    err = capsys.readouterr().err
    assert "rad.csv: every joint of its 5 row(s) lies within" in err and "radians written in the degree columns?" in err
    assert _run("predict", cal[0], _joints(tmp_path / "deg.csv", q), "--out", tmp_path / "p.csv") == 0
    assert "radians" not in capsys.readouterr().err


def test_a_joints_file_in_radians_beyond_pi_is_warned_naming_the_joint_and_degrees_are_not(cal, tmp_path, capsys):
    """Twelve rows in radians whose q6 goes beyond pi rad (past the pi-degree refusal): predict warns naming the
    file, the joint and the limits' span; the same rows in degrees: no warning."""
    rob = get_robot("irb1200")
    q = np.random.default_rng(5).uniform(rob.q_min, rob.q_max, (12, 6))
    assert np.abs(q).max() > np.pi
    assert _run("predict", cal[0], _joints(tmp_path / "rad.csv", q * np.pi / 180), "--out", tmp_path / "p.csv") == 0
    err = capsys.readouterr().err
    assert "rad.csv: every joint of its 12 row(s) lies within" in err and "q6 reads" in err
    assert "span up to 720 deg: radians written in the degree columns?" in err
    assert _run("predict", cal[0], _joints(tmp_path / "deg.csv", q), "--out", tmp_path / "p.csv") == 0
    assert "radians" not in capsys.readouterr().err


def test_a_joints_file_with_repeated_pose_ids_is_refused_naming_them(cal, tmp_path, capsys):
    """JOINTS.csv whose pose_id 3 appears in rows 3 and 4: predict refuses naming the id and the rows, no file."""
    q = random_configurations(get_robot("irb1200"), 5, np.random.default_rng(3))
    j = _joints(tmp_path / "j.csv", q, np.array([1, 2, 3, 3, 5]))
    assert _run("predict", cal[0], j, "--out", tmp_path / "p.csv") == 2
    assert "j.csv: column 'pose_id' has duplicate ids [3] (pose_id 3 in rows [3, 4])" in capsys.readouterr().err
    assert not (tmp_path / "p.csv").exists()
