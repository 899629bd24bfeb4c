"""PRED.csv and TARGETS.csv readers/writers: round trips and clear errors."""

import numpy as np
import pytest

from twin.dataset import DatasetError
from twin.transforms import make_transform, rotvec_to_matrix
from twin.estimator.files import read_targets, read_targets_csv, write_targets_csv


def _targets(n=4, seed=0):
    rng = np.random.default_rng(seed)
    return make_transform(rotvec_to_matrix(rng.normal(0, 1, (n, 3))), rng.normal(0, 0.5, (n, 3)))


def test_targets_round_trip(tmp_path):
    """write_targets_csv then read_targets_csv returns the poses to 1 nm / 1e-12."""
    T = _targets()
    write_targets_csv(tmp_path / "t.csv", np.arange(4) + 10, T)
    pid, back = read_targets_csv(tmp_path / "t.csv")
    assert pid.tolist() == [10, 11, 12, 13]
    assert np.abs(back[:, :3, 3] - T[:, :3, 3]).max() < 1e-9 and np.abs(back[:, :3, :3] - T[:, :3, :3]).max() < 1e-11


@pytest.mark.parametrize("edit,match", [
    (lambda L: [L[0].replace("qw", "w")] + L[1:], "missing required columns"),
    (lambda L: L[:2] + [L[1]] + L[3:], "duplicate id"),
    (lambda L: [L[0], L[1].rsplit(",", 1)[0] + ",0.9"] + L[2:], "not a unit quaternion"),
    (lambda L: [L[0], L[1].replace(L[1].split(",")[1], "abc", 1)] + L[2:], "not a number"),
])
def test_targets_errors_name_the_problem(tmp_path, edit, match):
    """Missing columns, duplicate ids, non-unit quaternions and non-numbers are refused with file and row."""
    write_targets_csv(tmp_path / "t.csv", np.arange(4), _targets())
    L = (tmp_path / "t.csv").read_text().splitlines()
    (tmp_path / "t.csv").write_text("\n".join(edit(L)) + "\n")
    with pytest.raises(DatasetError, match=match):
        read_targets_csv(tmp_path / "t.csv")


def test_position_only_targets_are_read_without_an_orientation(tmp_path):
    """A TARGETS.csv of x, y, z only (a point marker): read_targets gives the positions [m] and no rotation; the pose
    reader still asks for the quaternion's columns."""
    (tmp_path / "t.csv").write_text("pose_id,x,y,z\n3,100.5,-20,700\n4,0,0,812.25\n")
    t = read_targets(tmp_path / "t.csv")
    assert t.pose_id.tolist() == [3, 4] and t.rotation is None
    assert np.allclose(t.position, [[0.1005, -0.02, 0.7], [0.0, 0.0, 0.81225]], atol=1e-12)
    with pytest.raises(DatasetError, match=r"missing required columns \['qw', 'qx', 'qy', 'qz'\]"):
        read_targets_csv(tmp_path / "t.csv")


def test_a_partial_quaternion_is_refused_naming_its_missing_columns(tmp_path):
    """x, y, z with qw alone: neither a position nor a pose; the missing quaternion columns are named."""
    (tmp_path / "t.csv").write_text("pose_id,x,y,z,qw\n3,100.5,-20,700,1\n")
    with pytest.raises(DatasetError, match=r"missing required columns \['qx', 'qy', 'qz'\]"):
        read_targets(tmp_path / "t.csv")


def test_pred_csv_without_a_column_names_it(tmp_path):
    """A PRED.csv lacking a required column gives a DatasetError naming the file and column, not a KeyError."""
    from twin.estimator.files import read_pred_csv

    p = tmp_path / "PRED.csv"
    p.write_text("pose_id,p0_x\n1,2.0\n")
    with pytest.raises(DatasetError, match=r"PRED.csv: missing required columns \['p0_y'"):
        read_pred_csv(p)
    with pytest.raises(DatasetError, match="missing"):
        read_pred_csv(tmp_path / "nothing.csv")
