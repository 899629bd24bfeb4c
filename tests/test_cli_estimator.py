"""The estimator's CLI commands (calibrate, predict, compensate, export) on a dataset written by the library
and on one written by hand."""

import csv
import json

import numpy as np
import pytest

from twin.cli import main
from twin.dataset import Joints, write_dataset, write_joints_csv
from twin.kinematics import tool2base
from twin.robots import get_robot
from twin.estimator import Calibration
from twin.estimator.files import read_pred_csv, write_targets_csv
from twin.estimator.simulate import random_configurations, simulate_dataset

from _estimator_helpers import camera_base, random_truth


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """A two-station dataset written by twin.dataset.write_dataset, with motion pairs, and its calibration."""
    d = tmp_path_factory.mktemp("cli")
    rng = np.random.default_rng(1)
    truth = random_truth("irb1200", rng)
    B = {"0": camera_base(rng), "1": camera_base(rng)}
    q = random_configurations(get_robot("irb1200"), 120, rng)
    st = np.repeat(np.array(["0", "1"], dtype=object), 60)
    sets = np.array((["calibration"] * 4 + ["validation"]) * 24, dtype=object)
    ds, _ = simulate_dataset(truth, q, robot_spec="irb1200", base2meas=B, station=st, noise_position=1e-5, rng=rng,
                             set_=sets, pair=np.repeat(np.arange(60), 2))
    write_dataset(d / "ds", ds)
    assert main(["calibrate", str(d / "ds"), "--out", str(d / "cal"), "--quiet"]) == 0
    return d, truth, B


def test_calibrate_writes_a_calibration_and_reports(written, capsys):
    """calibrate prints the short report (identifiability, validation before/after) and writes a loadable file."""
    d, _, _ = written
    assert main(["calibrate", str(d / "ds"), "--out", str(d / "cal2")]) == 0
    out = capsys.readouterr().out
    assert "identifiable: 36 of 43" in out and "validation after" in out and "not identifiable" in out
    cal = Calibration.load(d / "cal2" / "calibration.json")
    assert cal.method == "best" and set(cal.stations) == {"0", "1"}
    d2 = json.loads((d / "cal2" / "calibration.json").read_text())
    for key in ("parameters", "covariance", "stations", "unidentifiable", "rows", "residuals", "noise", "identifiability"):
        assert key in d2


@pytest.mark.parametrize("method", ["distance", "fullpose", "separation", "lm", "clm"])
def test_calibrate_runs_every_method(written, method):
    """Every method of the papers runs from the command line on the same dataset."""
    d, _, _ = written
    assert main(["calibrate", str(d / "ds"), "--method", method, "--out", str(d / f"cal_{method}"), "--quiet"]) == 0
    cal = Calibration.load(d / f"cal_{method}" / "calibration.json")
    assert cal.residuals["validation"]["position_mm"]["rms"] < 0.2


def test_predict_writes_pred_csv_with_frames_and_sd(written, tmp_path):
    """predict: measurement frame for known stations, base frame otherwise; sd columns; same numbers as the API."""
    d, _, _ = written
    q = random_configurations(get_robot("irb1200"), 4, np.random.default_rng(2))
    write_joints_csv(tmp_path / "j.csv", Joints(pose_id=np.array([3, 5, 7, 9]), q=q,
                                                station=np.array(["0", "1", "other", "0"], dtype=object)))
    assert main(["predict", str(d / "cal" / "calibration.json"), str(tmp_path / "j.csv"), "--out", str(tmp_path / "p.csv")]) == 0
    p = read_pred_csv(tmp_path / "p.csv")
    assert p["frame"].tolist() == ["measurement", "measurement", "base", "measurement"]
    cal = Calibration.load(d / "cal" / "calibration.json")
    ref = cal.predict(np.deg2rad(np.round(np.rad2deg(q), 10)), np.array(["0", "1", "other", "0"], dtype=object))
    assert np.abs(p["spheres"] - ref.spheres).max() < 2e-9
    assert np.all(p["sd_spheres"] > 0)


def test_compensate_writes_joints_and_refuses_unreachable_targets(written, tmp_path, capsys):
    """compensate: JOINTS.csv whose commands reach the targets on the calibrated robot; an unreachable target
    gives exit code 2 and a message naming the file."""
    d, _, _ = written
    rng = np.random.default_rng(3)
    nom = get_robot("irb1200")
    q = random_configurations(nom, 5, rng, margin=0.3)
    T = tool2base(nom, q)
    write_targets_csv(tmp_path / "t.csv", np.arange(5), T)
    write_joints_csv(tmp_path / "ref.csv", Joints(pose_id=np.arange(5), q=q))
    assert main(["compensate", str(d / "cal" / "calibration.json"), str(tmp_path / "t.csv"), "--out",
                 str(tmp_path / "q.csv"), "--reference", str(tmp_path / "ref.csv")]) == 0
    rows = list(csv.DictReader(open(tmp_path / "q.csv")))
    qc = np.deg2rad([[float(r[f"q{i}"]) for i in range(1, 7)] for r in rows])
    cal = Calibration.load(d / "cal" / "calibration.json")
    assert np.abs(tool2base(cal.robot, qc)[:, :3, 3] - T[:, :3, 3]).max() < 1e-8
    T2 = T.copy()
    T2[2, :3, 3] = [3.0, 0, 0]
    write_targets_csv(tmp_path / "t2.csv", np.arange(5), T2)
    assert main(["compensate", str(d / "cal" / "calibration.json"), str(tmp_path / "t2.csv"), "--out", str(tmp_path / "q2.csv")]) == 2
    assert "t2.csv" in capsys.readouterr().err


def test_export_mjcf_reproduces_the_calibrated_kinematics(written, tmp_path):
    """export: parameters.csv/.md and an MJCF whose tool and sphere sites match the calibrated model's FK."""
    import mujoco

    d, _, _ = written
    assert main(["export", str(d / "cal" / "calibration.json"), "--out", str(tmp_path)]) == 0
    cal = Calibration.load(d / "cal" / "calibration.json")
    rows = list(csv.DictReader(open(tmp_path / "parameters.csv")))
    assert [r["name"] for r in rows] == list(cal.names)
    assert "| theta2 | deg |" in (tmp_path / "parameters.md").read_text()
    m = mujoco.MjModel.from_xml_path(str(tmp_path / "robot.xml"))
    data = mujoco.MjData(m)
    q = random_configurations(get_robot("irb1200"), 5, np.random.default_rng(4))
    T = tool2base(cal.robot, q)
    sph = cal.predict(q, np.array(["none"] * 5, dtype=object)).spheres
    for k in range(5):
        data.qpos[:6] = q[k]
        mujoco.mj_kinematics(m, data)  # positions of bodies and sites only: no dynamics needed
        sid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "plate")
        assert np.abs(data.site_xpos[sid] - T[k, :3, 3]).max() < 1e-9
        assert np.abs(data.site_xmat[sid].reshape(3, 3) - T[k, :3, :3]).max() < 1e-9
        for s in range(3):
            sid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, f"sphere{s}")
            assert np.abs(data.site_xpos[sid] - sph[k, s]).max() < 1e-9


HAND_TOML = """schema_version = 1
provenance = "typed by hand: a small arm measured with a stereo rig from two places"

[robot]
name = "my_arm"
convention = "mdh"
beta_joints = [2]
theta_deg = [0, -90, 0, 0, 0, 0]
d_mm = [399.1, 0, 0, 351, 0, 82]
a_mm = [0, 0, 350, 42, 0, 0]
alpha_deg = [0, -90, 0, -90, 90, -90]
beta_deg = [0]
q_min_deg = [-170, -100, -200, -270, -130, -360]
q_max_deg = [170, 130, 70, 270, 130, 360]

[plate]
sphere_diameter_mm = 25.4
spheres_mm = [[60.0, 0.0, 50.0], [-60.0, 0.0, 50.0], [-20.5212, 56.3816, 50.0]]
"""


def _hand_dataset(folder, rng, n=70):
    """Write poses.csv by hand: other column order, CRLF, 3 decimals, station names, an operator column, one row
    with a sphere hidden (status says why), one row not measured at all."""
    truth = random_truth("irb1200", rng)
    B = {"left": camera_base(rng), "right": camera_base(rng)}
    q = random_configurations(get_robot("irb1200"), n, rng)
    st = np.array(["left" if k % 3 else "right" for k in range(n)], dtype=object)
    ds, _ = simulate_dataset(truth, q, robot_spec="irb1200", base2meas=B, station=st, noise_position=1e-5, rng=rng)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "dataset.toml").write_text(HAND_TOML)
    head = "station,pose_id,q1,q2,q3,q4,q5,q6,operator,p0_x,p0_y,p0_z,p1_x,p1_y,p1_z,p2_x,p2_y,p2_z,status"
    lines = [head]
    for k in range(n):
        qd = ",".join(f"{v:.6f}" for v in np.rad2deg(q[k]))
        sph = [",".join(f"{v * 1e3:.4f}" for v in ds.spheres[k, s]) for s in range(3)]
        status = ""
        if k == 5:
            sph[2] = ",,"
            status = "p2:occluded"
        if k == 9:
            sph = [",,"] * 3
            status = "no detection"
        lines.append(f"{st[k]},{1000 + k},{qd},ann,{sph[0]},{sph[1]},{sph[2]},{status}")
    (folder / "poses.csv").write_bytes(("\r\n".join(lines) + "\r\n").encode())
    return truth


def test_calibrate_a_hand_written_dataset(tmp_path, capsys):
    """A hand-written dataset (inline robot, named stations, no set/noise columns, a hidden sphere and an
    unmeasured row) calibrates; the hold-out and the skipped row are reported; predict/compensate/export run."""
    _hand_dataset(tmp_path / "hand", np.random.default_rng(7))
    assert main(["calibrate", str(tmp_path / "hand"), "--out", str(tmp_path / "cal")]) == 0
    out = capsys.readouterr().out
    assert "held out a seeded random 20%" in out
    cal = Calibration.load(tmp_path / "cal" / "calibration.json")
    assert cal.nominal.name == "my_arm" and set(cal.stations) == {"left", "right"}
    assert cal.noise["position_source"].startswith("estimated")
    assert cal.noise["position_mm"] == pytest.approx(0.01, rel=0.25)
    assert [r["pose_id"] for r in cal.rows["skipped"]] == [1009]
    assert cal.residuals["validation"]["position_mm"]["rms"] < 0.05
    write_joints_csv(tmp_path / "j.csv", Joints(pose_id=np.arange(3), q=np.zeros((3, 6)), station=np.array(["left"] * 3, dtype=object)))
    assert main(["predict", str(tmp_path / "cal" / "calibration.json"), str(tmp_path / "j.csv"), "--out", str(tmp_path / "p.csv")]) == 0
    assert main(["export", str(tmp_path / "cal" / "calibration.json"), "--out", str(tmp_path / "exp")]) == 0


def _nan_q3(text):
    lines = text.split("\r\n")
    cells = lines[2].split(",")
    cells[4] = "nan"  # q3 of the second data row
    lines[2] = ",".join(cells)
    return "\r\n".join(lines)


@pytest.mark.parametrize("edit,match", [
    (lambda t: t.replace("q3,", "qq3,", 1), "missing required columns ['q3']"),
    (_nan_q3, "column 'q3': not a finite number"),
])
def test_calibrate_refuses_broken_files_with_a_clear_message(tmp_path, capsys, edit, match):
    """A missing joint column or a NaN joint: exit code 2 and a message naming the problem (no traceback)."""
    _hand_dataset(tmp_path / "hand", np.random.default_rng(8))
    p = tmp_path / "hand" / "poses.csv"
    p.write_bytes(edit(p.read_bytes().decode()).encode())
    assert main(["calibrate", str(tmp_path / "hand"), "--out", str(tmp_path / "cal")]) == 2
    err = capsys.readouterr().err
    assert match in err and "poses.csv" in err


def test_option_for_the_wrong_method_is_refused(written, capsys):
    """--solver with --method best is a clear error, not silently ignored."""
    d, _, _ = written
    assert main(["calibrate", str(d / "ds"), "--out", str(d / "x"), "--solver", "scaled"]) == 2
    assert "--solver applies to" in capsys.readouterr().err


def test_out_naming_an_existing_file_is_a_named_error(written, tmp_path, capsys):
    """--out pointing at an existing file: exit code 2, the path named, no traceback, the file untouched."""
    d, _, _ = written
    f = tmp_path / "taken.txt"
    f.write_text("mine")
    assert main(["calibrate", str(d / "ds"), "--out", str(f), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert str(f) in err and "Traceback" not in err and f.read_text() == "mine"
