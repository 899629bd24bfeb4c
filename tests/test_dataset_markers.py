"""Datasets of any serial robot and any rigid marker set: K points per row, joint columns named after the robot,
a declared length unit checked against the data, relabelling of K points, and the motion-capture importer with
its named errors."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from twin.cli import main
from twin.dataset import DatasetError, Plate, read_dataset, write_dataset
from twin.estimator import simulate_dataset
from twin.estimator.plausibility import ImplausibleData, check_length_unit, check_plate_rows
from twin.kinematics import flange2base, tool2meas
from twin.importers.mocap import hand_eye, import_mocap, marker_geometry
from twin.robots import joint_table
from twin.transforms import pose6_to_transform
from twin.urdf import UrdfError, read_urdf_chain

DATA = Path(__file__).resolve().parent.parent / "data" / "tiago_mocap"
URDF = DATA / "tiago_48_schunk.urdf"
TRAIN = DATA / "qualisys_2021-11-30_static_postures.csv"
VALID = DATA / "qualisys_2021-11-26_static_postures.csv"
END = "wrist_ft_tool_link"
HAND = np.array([[0.06, 0.0, 0.07], [0.08, 0.0, -0.09], [0.17, 0.01, -0.06], [0.17, 0.0, 0.05]])


@pytest.fixture(scope="module")
def tiago():
    return read_urdf_chain(URDF, "base_link", END)


def _sim(model, k_points: int, n: int = 30, seed: int = 0, noise: float = 1e-4):
    rng = np.random.default_rng(seed)
    q = rng.uniform(np.maximum(model.q_min, -np.pi), np.minimum(model.q_max, np.pi), (n, model.n_joints))
    ds, _ = simulate_dataset(model, q, robot_spec=joint_table(model), plate=Plate(0.0, HAND[:k_points]),
                             noise_position=noise, rng=rng,
                             base2meas={"0": pose6_to_transform(np.array([0.0, 0.2, -0.2, 0.0, 0.0, 0.1]))})
    return ds


@pytest.mark.parametrize("k", [1, 4])
def test_dataset_of_k_points_round_trips(tmp_path, tiago, k):
    """A dataset of K points (1 reflector, a 4-point body) with the robot's joint names writes and reads back."""
    ds = _sim(tiago, k)
    write_dataset(tmp_path, ds)
    header = (tmp_path / "poses.csv").read_text().splitlines()[0].split(",")
    assert header[1:9] == list(tiago.joint_names) and f"p{k - 1}_z" in header and f"p{k}_x" not in header
    back = read_dataset(tmp_path)
    assert back.n_points == k and back.q.shape == (30, 8)
    assert np.abs(back.spheres - ds.spheres).max() < 1e-9 and np.abs(back.q - ds.q).max() < 1e-9


def test_markers_in_metres_declared_in_millimetres_are_refused(tmp_path, tiago):
    """poses.csv holding metres under a dataset.toml that declares mm: ImplausibleData naming metres."""
    ds = _sim(tiago, 4)
    write_dataset(tmp_path, ds)
    rows = list(csv.DictReader(open(tmp_path / "poses.csv")))
    with open(tmp_path / "poses.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            for c in r:
                if c[0] == "p" and c[1].isdigit():
                    r[c] = repr(float(r[c]) / 1000)
            w.writerow(r)
    wrong = read_dataset(tmp_path)
    with pytest.raises(ImplausibleData, match="positions in metres"):
        check_plate_rows(wrong)


def test_single_point_in_metres_declared_in_millimetres_is_refused(tmp_path, tiago):
    """K = 1 (no distances to check): the spread against the robot's motion names the unit."""
    ds = _sim(tiago, 1)
    write_dataset(tmp_path, ds)
    toml = (tmp_path / "dataset.toml").read_text().replace('unit = "mm"', 'unit = "m"')
    (tmp_path / "dataset.toml").write_text(toml)
    with pytest.raises(ImplausibleData, match="look like millimetres but dataset.toml declares unit 'm'"):
        check_length_unit(read_dataset(tmp_path))
    assert check_length_unit(ds) == pytest.approx(1.0, rel=0.05)


def test_declared_metre_unit_reads_metres(tmp_path, tiago):
    """A dataset written with length_unit 'm' holds metres in the file and reads back the same SI values."""
    from dataclasses import replace

    ds = replace(_sim(tiago, 4), length_unit="m")
    write_dataset(tmp_path, ds)
    assert 'unit = "m"' in (tmp_path / "dataset.toml").read_text()
    first = next(csv.DictReader(open(tmp_path / "poses.csv")))
    assert abs(float(first["p0_x"])) < 5
    assert np.abs(read_dataset(tmp_path).spheres - ds.spheres).max() < 1e-9


def test_missing_joint_column_is_named(tmp_path, tiago):
    """A poses.csv without one of the robot's joint columns: DatasetError naming the column."""
    write_dataset(tmp_path, _sim(tiago, 4))
    p = tmp_path / "poses.csv"
    p.write_text(p.read_text().replace("arm_5_joint", "arm_5_jiont", 1))
    with pytest.raises(DatasetError, match=r"missing required columns \['arm_5_joint'\]"):
        read_dataset(tmp_path)


def test_permuted_labels_of_four_points_are_relabelled(tiago):
    """Rows whose four point labels are permuted are put back by the distinct pairwise distances."""
    from dataclasses import replace

    ds = _sim(tiago, 4, noise=2e-5)
    sph = ds.spheres.copy()
    sph[[3, 7]] = sph[[3, 7]][:, [2, 0, 3, 1]]
    chk = check_plate_rows(replace(ds, spheres=sph))
    assert set(chk.relabelled) == {3, 7}
    assert np.abs(chk.dataset.spheres - ds.spheres).max() < 1e-12


def test_hand_eye_recovers_base_and_tool():
    """The closed-form hand-eye start recovers a known base2meas and tool2flange from exact poses (1e-9)."""
    rng = np.random.default_rng(3)
    F = np.stack([pose6_to_transform(np.r_[rng.uniform(-0.5, 0.5, 3), rng.uniform(-2, 2, 3)]) for _ in range(12)])
    X = pose6_to_transform(np.array([0.1, -0.3, 0.5, 0.2, -0.4, 1.0]))
    Y = pose6_to_transform(np.array([0.02, 0.05, 0.1, 1.2, 0.3, -0.5]))
    Xe, Ye = hand_eye(F, X @ F @ Y)
    assert np.abs(Xe - X).max() < 1e-9 and np.abs(Ye - Y).max() < 1e-9


def test_marker_geometry_is_the_rigid_shape():
    """The body-frame shape keeps every pairwise distance, has point 1 at the origin and point 2 on +x."""
    rng = np.random.default_rng(4)
    P = np.stack([HAND @ pose6_to_transform(np.r_[0, 0, 0, rng.uniform(-2, 2, 3)])[:3, :3].T + rng.uniform(-1, 1, 3)
                  for _ in range(6)])
    body, poses = marker_geometry(P)
    d = lambda A: np.linalg.norm(A[:, None] - A[None], axis=-1)  # noqa: E731
    assert np.abs(d(body) - d(HAND)).max() < 1e-12
    assert np.abs(body[0]).max() < 1e-15 and abs(body[1, 1]) < 1e-15 and abs(body[1, 2]) < 1e-15 and body[1, 0] > 0
    assert np.abs(np.einsum("nij,kj->nki", poses[:, :3, :3], body) + poses[:, None, :3, 3] - P).max() < 1e-12


def test_import_of_the_tiago_campaign(tmp_path):
    """The committed campaign imports: 37 calibration + 62 validation rows, 8 joints in degrees / millimetres,
    4 points in millimetres, the URDF copied, every input's sha256 in the provenance."""
    ds = import_mocap([(TRAIN, "calibration"), (VALID, "validation")], URDF, "base_link", END, tmp_path / "ds")
    back = read_dataset(tmp_path / "ds")
    assert back.n == 99 and (back.set == "calibration").sum() == 37 and back.n_points == 4
    assert back.robot.joint_names == ds.robot.joint_names and (tmp_path / "ds" / URDF.name).exists()
    assert "b6c0051e20c6a077a6d2cf64ba912996945bbb85d6860cd6cea7d8ff65b1b9af" in back.provenance
    raw = next(csv.DictReader(open(TRAIN)))
    assert back.q[0, 0] == pytest.approx(float(raw["torso_lift_joint"]), abs=1e-12)
    assert back.spheres[0, 0, 0] == pytest.approx(float(raw["x1"]), abs=1e-9)
    # the nominal placement reproduces the measured points to a few millimetres (the robot's real errors)
    T = tool2meas(back.robot.with_frames(base2meas=back.stations_base2meas["0"]), back.q)
    pred = np.einsum("nij,kj->nki", T[:, :3, :3], back.plate.spheres_flange) + T[:, None, :3, 3]
    assert np.sqrt(np.mean(np.sum((pred - back.spheres) ** 2, axis=-1))) < 0.015


def test_import_names_a_missing_joint_column(tmp_path):
    """A mocap CSV without one of the chain's joints: DatasetError naming the column and the file."""
    bad = tmp_path / "bad.csv"
    bad.write_text(TRAIN.read_text().replace("arm_3_joint", "arm_three", 1))
    with pytest.raises(DatasetError, match=r"bad.csv: missing joint columns \['arm_3_joint'\]"):
        import_mocap([(bad, "calibration")], URDF, "base_link", END, tmp_path / "ds")


def test_import_names_a_urdf_without_the_end_link(tmp_path):
    """An end link the URDF does not have: UrdfError naming the link."""
    with pytest.raises(UrdfError, match="'hand_link' is not a link"):
        import_mocap([(TRAIN, "calibration")], URDF, "base_link", "hand_link", tmp_path / "ds")


def test_import_refuses_markers_in_the_wrong_unit(tmp_path):
    """Marker columns in millimetres imported as metres: DatasetError saying they look like millimetres."""
    rows = list(csv.DictReader(open(TRAIN)))
    bad = tmp_path / "mm.csv"
    with open(bad, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            for c in r:
                if c[0] in "xyz" and c[1:].isdigit():
                    r[c] = repr(float(r[c]) * 1000)
            w.writerow(r)
    with pytest.raises(DatasetError, match="look like millimetres"):
        import_mocap([(bad, "calibration")], URDF, "base_link", END, tmp_path / "ds")
    import_mocap([(bad, "calibration")], URDF, "base_link", END, tmp_path / "ok", marker_unit="mm")


def test_import_refuses_a_non_rigid_marker_set(tmp_path):
    """One marker moved by 5 mm on some rows: DatasetError naming the pair of points and the spread."""
    rows = list(csv.DictReader(open(TRAIN)))
    bad = tmp_path / "loose.csv"
    with open(bad, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        for k, r in enumerate(rows):
            if k % 3 == 0:
                r["x3"] = repr(float(r["x3"]) + 0.005)
            w.writerow(r)
    with pytest.raises(DatasetError, match="not one rigid body: the distance between points"):
        import_mocap([(bad, "calibration")], URDF, "base_link", END, tmp_path / "ds")


def test_cli_import_then_calibrate_joint_offsets(tmp_path, capsys):
    """twin import + twin calibrate --level offsets on the campaign: 17 identifiable parameters, the torso and
    arm_1 offsets absorbed by the base and arm_7's by the tool, named in the report."""
    out = tmp_path / "ds"
    assert main(["import", str(TRAIN), "--validation", str(VALID), "--urdf", str(URDF), "--root", "base_link",
                 "--end", END, "--out", str(out)]) == 0
    assert main(["calibrate", str(out), "--out", str(tmp_path / "cal"), "--level", "offsets"]) == 0
    text = capsys.readouterr().out
    assert "identifiable: 17 of 20 parameters" in text
    assert "torso_lift_joint.offset - base_z" in text and "arm_7_joint.offset - tool_rx" in text


def test_cli_import_error_exits_2(tmp_path, capsys):
    """A bad import is a clear error (exit 2), not a traceback."""
    code = main(["import", str(TRAIN), "--urdf", str(URDF), "--root", "base_link", "--end", "nowhere",
                 "--out", str(tmp_path / "x")])
    assert code == 2 and "'nowhere' is not a link" in capsys.readouterr().err


def test_cli_predict_compensate_export_on_the_eight_joint_arm(tmp_path, capsys):
    """The CLI after import: predict writes the four points per JOINTS row, compensate returns the robot's joint
    columns and reaches the targets on the calibrated model, export writes a URDF and an MJCF MuJoCo loads."""
    import mujoco

    from twin.dataset import Joints, read_joints_csv, write_joints_csv
    from twin.estimator import Calibration
    from twin.estimator.files import read_pred_csv, write_targets_csv
    from twin.kinematics import tool2base

    out = tmp_path / "ds"
    assert main(["import", str(TRAIN), "--urdf", str(URDF), "--root", "base_link", "--end", END, "--out", str(out)]) == 0
    assert main(["calibrate", str(out), "--out", str(tmp_path / "cal"), "--level", "offsets", "--quiet"]) == 0
    calp = tmp_path / "cal" / "calibration.json"
    cal = Calibration.load(calp)
    ds = read_dataset(out)
    q = ds.q[[0, 5, 9]]
    q[:, 0] = np.clip(q[:, 0], 0.05, 0.3)
    write_joints_csv(tmp_path / "joints.csv", Joints(pose_id=np.arange(3), q=q), robot=cal.nominal)
    assert main(["predict", str(calp), str(tmp_path / "joints.csv"), "--out", str(tmp_path / "pred.csv")]) == 0
    pred = read_pred_csv(tmp_path / "pred.csv")
    assert pred["spheres"].shape == (3, 4, 3)
    assert np.abs(pred["spheres"] - cal.predict(read_joints_csv(tmp_path / "joints.csv", robot=cal.nominal).q).spheres).max() < 1e-6
    write_targets_csv(tmp_path / "targets.csv", np.arange(3), tool2base(cal.nominal, q))
    assert main(["compensate", str(calp), str(tmp_path / "targets.csv"), "--reference", str(tmp_path / "joints.csv"),
                 "--out", str(tmp_path / "cmd.csv")]) == 0
    cmd = read_joints_csv(tmp_path / "cmd.csv", robot=cal.nominal)
    assert np.abs(tool2base(cal.robot, cmd.q)[:, :3, 3] - tool2base(cal.nominal, q)[:, :3, 3]).max() < 1e-9
    assert main(["export", str(calp), "--out", str(tmp_path / "exp")]) == 0
    assert read_urdf_chain(tmp_path / "exp" / "robot.urdf", "base", "tool").n_joints == 8
    mujoco.MjModel.from_xml_path(str(tmp_path / "exp" / "robot.xml"))


def test_a_mocap_row_with_an_occluded_marker_is_kept_with_that_point_not_seen(tmp_path):
    """A FIGAROH mocap CSV with point 2 empty in one row and point 4 NaN in another: every row is kept, those points
    are written as not seen and the row's other points as measured (the generic path's rule)."""
    with open(TRAIN, newline="") as f:
        reader = csv.DictReader(f)
        fields, rows = reader.fieldnames, list(reader)[:16]
    for c in "xyz":
        rows[3][f"{c}2"] = ""
        rows[10][f"{c}4"] = "nan"
    occluded = tmp_path / "occluded.csv"
    with open(occluded, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields)
        w.writeheader()
        w.writerows(rows)
    import_mocap([(occluded, "calibration")], URDF, "base_link", END, tmp_path / "ds")
    ds = read_dataset(tmp_path / "ds")
    assert ds.n == len(rows)
    unseen = {(int(k), int(i)) for k, i in zip(*np.nonzero(~ds.sphere_seen))}
    assert unseen == {(3, 1), (10, 3)}
    want = np.array([[float(rows[3][f"{c}{i}"]) for c in "xyz"] for i in (1, 3, 4)])
    assert np.abs(ds.spheres[3, [0, 2, 3]] - want).max() < 1e-9


def test_import_refuses_to_replace_another_file_named_like_the_robot_file(tmp_path, capsys):
    """twin import --out a folder (no dataset in it) holding a different file of the URDF's name: refused naming it,
    the file unchanged; --force replaces it with the robot file."""
    out = tmp_path / "ds"
    out.mkdir()
    mine = out / URDF.name
    mine.write_text("<robot name='mine'/>\n")
    argv = ["import", str(TRAIN), "--urdf", str(URDF), "--root", "base_link", "--end", END, "--out", str(out)]
    assert main(argv) == 2
    assert f"it holds a {URDF.name} other than the robot file" in capsys.readouterr().err
    assert mine.read_text() == "<robot name='mine'/>\n" and not (out / "poses.csv").exists()
    assert main(argv + ["--force"]) == 0
    assert mine.read_bytes() == URDF.read_bytes()
