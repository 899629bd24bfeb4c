"""Every error the twin command reports names its subject: the file (or files) and the cause, never an empty
subject (`twin campaign: error: : ...`) nor a bare decoder message."""

import os
import shutil
from pathlib import Path

import pytest

from twin.cli import error_message, main
from twin.resources import model_file

GOLDEN = Path(__file__).resolve().parent / "golden" / "separation_dataset"


def _error(capsys, argv) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_oserror_without_a_file_gives_its_message_alone():
    """An OSError raised with a message only is reported as that message, with no empty subject before it."""
    msg = error_message(OSError("could not write images/pairs/0001_left.png"))
    assert msg.startswith("could not write images/pairs/0001_left.png") and not msg.startswith(":")


def test_missing_packaged_model_names_the_file():
    """A broken install missing a packaged MJCF model is reported with the model's file name."""
    with pytest.raises(FileNotFoundError) as e:
        model_file("no_such_model.xml")
    assert error_message(e.value).startswith("models/no_such_model.xml: packaged MJCF model missing")


def test_oserror_with_two_files_names_both(tmp_path):
    """An OSError of a rename names the source and the destination."""
    with pytest.raises(OSError) as e:
        os.replace(tmp_path / "absent.tmp", tmp_path / "out.json")
    msg = error_message(e.value)
    assert f"{tmp_path / 'absent.tmp'} -> {tmp_path / 'out.json'}: " in msg


def test_directory_given_for_a_file_is_named(tmp_path, capsys):
    """A folder given where a config file is expected is named with the cause."""
    line = _error(capsys, ["campaign", str(tmp_path), "--out", str(tmp_path / "out")])
    assert line.startswith(f"twin campaign: error: {tmp_path}: Is a directory")


def test_non_utf8_config_is_named(tmp_path, capsys):
    """A campaign config that is not UTF-8 text is named, with the byte where decoding failed."""
    p = tmp_path / "bad.toml"
    p.write_bytes(b"name = \"x\"\n\xff = 1\n")
    line = _error(capsys, ["campaign", str(p), "--out", str(tmp_path / "out")])
    assert line == f"twin campaign: error: {p}: not UTF-8 text (invalid start byte at byte 11)"


def test_non_utf8_dataset_file_is_named(tmp_path, capsys):
    """A dataset whose poses.csv is not UTF-8 text: the error names poses.csv."""
    ds = tmp_path / "ds"
    shutil.copytree(GOLDEN, ds)
    with open(ds / "poses.csv", "ab") as f:
        f.write(b"\xff\n")
    line = _error(capsys, ["calibrate", str(ds), "--out", str(tmp_path / "cal")])
    assert line.startswith(f"twin calibrate: error: {ds / 'poses.csv'}: not UTF-8 text")
    assert not (tmp_path / "cal").exists()


def test_bad_json_camera_is_named(tmp_path, capsys):
    """A camera file given to `twin plan` that is not JSON is named (a JSON decoder message names no file)."""
    cam = tmp_path / "camera.json"
    cam.write_text("{bad")
    line = _error(capsys, ["plan", "--robot", "irb1200", "--camera", str(cam), "--n", "3",
                           "--out", str(tmp_path / "j.csv")])
    assert line.startswith(f"twin plan: error: {cam}: not valid JSON")


def test_escaped_decode_error_says_what_it_is():
    """A UnicodeDecodeError no reader caught is reported as a file that is not UTF-8 text, not as a codec message."""
    exc = UnicodeDecodeError("utf-8", b"\xff", 0, 1, "invalid start byte")
    assert error_message(exc).startswith("a file given is not UTF-8 text (invalid start byte at byte 0)")


def test_a_thread_count_below_one_is_named_before_any_work(tmp_path, capsys):
    """twin diagnose --threads 0 names the option and its value, and writes nothing."""
    line = _error(capsys, ["diagnose", str(GOLDEN), "--out", str(tmp_path / "out"), "--threads", "0"])
    assert line == "twin diagnose: error: --threads must be a positive integer, got 0"
    assert not (tmp_path / "out").exists()


# ---- a newcomer's hand-written files ---------------------------------------------------------------------------

def _golden_copy(tmp_path, edit=None, robot=None) -> Path:
    """The golden dataset copied, its poses.csv lines passed through ``edit`` (a function of the list of lines)
    and its robot name replaced by ``robot``."""
    ds = tmp_path / "ds"
    shutil.copytree(GOLDEN, ds)
    if edit is not None:
        lines = (ds / "poses.csv").read_text().splitlines()
        (ds / "poses.csv").write_text("\n".join(edit(lines)) + "\n")
    if robot is not None:
        t = ds / "dataset.toml"
        t.write_text(t.read_text().replace('robot = "irb1200"', f'robot = "{robot}"'))
    return ds


def test_a_poses_csv_with_a_byte_order_mark_or_trailing_separators_reads_as_without():
    """A spreadsheet's byte order mark before the header and empty cells beyond the header's columns: the same
    dataset."""
    import numpy as np

    from twin.dataset import read_dataset

    ref = read_dataset(GOLDEN)
    for name, edit in (("bom", lambda L: ["\ufeff" + L[0]] + L[1:]), ("trailing", lambda L: [L[0]] + [x + ",," for x in L[1:]])):
        import tempfile

        with tempfile.TemporaryDirectory() as d:
            ds = read_dataset(_golden_copy(Path(d), edit))
            assert np.array_equal(ds.q, ref.q) and np.array_equal(ds.spheres, ref.spheres, equal_nan=True), name


@pytest.mark.parametrize("edit,match", [
    (lambda L: [L[0]] + [x.replace(".", ",", 1) for x in L[1:]],
     r"poses.csv: row 2 \(pose_id 1\): 21 cells where the header has 20 columns \(beyond the header: "
     r"'p0:unlabelled;p1:unlabelled;p2:unlabelled'\): a ',' decimal mark in a ','-separated file"),
    (lambda L: [x.replace(",", ";") for x in L],
     r"missing required columns .* \(the header is one cell holding ';': the file is ';'-separated, this reader "
     r"expects ','\)"),
    (lambda L: [L[0] + ",q7"] + [x + ",0" for x in L[1:]],
     r"poses.csv: columns \['q7'\] name joints robot 'irb1200' does not have \(its 6 joints: q1, q2, q3, q4, q5, "
     r"q6\): joints of another robot\?"),
])
def test_a_poses_csv_read_shifted_or_of_another_robot_is_refused_naming_the_cause(tmp_path, edit, match):
    """Decimal commas in a ','-separated poses.csv (every cell after the first would shift), a ';'-separated one, a
    joint column the robot does not have: DatasetError naming the file, the row and the likely cause."""
    from twin.dataset import DatasetError, read_dataset

    with pytest.raises(DatasetError, match=match):
        read_dataset(_golden_copy(tmp_path, edit))


def test_a_joints_csv_of_another_robot_or_with_a_column_twice_is_refused_and_spaces_or_a_bom_are_read(tmp_path):
    """JOINTS.csv: a q7 column for a 6-joint robot and a joint named twice are refused naming the columns; spaces
    after the separators and a byte order mark are read as the plain file is."""
    import numpy as np

    from twin.dataset import DatasetError, read_joints_csv
    from twin.robots import get_robot

    r = get_robot("irb1200")
    head, row = "pose_id,q1,q2,q3,q4,q5,q6", "0,1,2,3,4,5,6"
    cases = {"q7": (f"{head},q7\n{row},7\n", r"columns \['q7'\] name joints the robot does not have"),
             "twice": (f"{head},q2\n{row},9\n", r"duplicate columns \['q2'\]")}
    for name, (text, match) in cases.items():
        (tmp_path / f"{name}.csv").write_text(text)
        with pytest.raises(DatasetError, match=match):
            read_joints_csv(tmp_path / f"{name}.csv", r)
    (tmp_path / "spaces.csv").write_text("\ufeff" + head.replace(",", ", ") + "\n" + row.replace(",", ", ") + "\n")
    assert np.allclose(read_joints_csv(tmp_path / "spaces.csv", r).q, np.radians([[1, 2, 3, 4, 5, 6]]))


def test_an_unknown_field_of_an_inline_robot_is_named_with_the_prismatic_hint():
    """A DH table with a field it does not read (here an attempt at a prismatic joint) and a joint table's joint with
    a misspelt field: DatasetError naming the table, the field and the fields it reads."""
    from twin.dataset import DatasetError, robot_from_spec

    dh = {"convention": "dh", "theta_deg": [0, 0], "d_mm": [100, 0], "a_mm": [0, 200], "alpha_deg": [90, 0],
          "prismatic_joints": [2]}
    with pytest.raises(DatasetError, match=r"table 'robot' \(dh/mdh table\): unknown field\(s\) \['prismatic_joints'\]"
                                           r".*a DH/MDH table has revolute joints only"):
        robot_from_spec(dh)
    chain = {"convention": "urdf", "joints": [{"name": "j", "type": "revolute", "xyz_mm": [0, 0, 1], "rpy_deg": [0, 0, 0],
                                              "limits": [-90, 90], "mass": 2.0}]}
    with pytest.raises(DatasetError, match=r"table 'robot.joints\[0\]' \(joint table\): unknown field\(s\) \['mass'\]"):
        robot_from_spec(chain)


def test_a_folder_given_for_a_calibration_is_named_with_what_to_give(tmp_path, capsys):
    """twin predict with the dataset folder (before any calibration) or with twin calibrate's output folder: the
    error says it is a folder and which file to give."""
    (tmp_path / "cal").mkdir()
    (tmp_path / "cal" / "calibration.json").write_text("{}")
    line = _error(capsys, ["predict", str(GOLDEN), str(tmp_path / "j.csv"), "--out", str(tmp_path / "p.csv")])
    assert line == (f"twin predict: error: {GOLDEN}: a folder, not a calibration.json: twin calibrate DATASET --out DIR "
                    "(or twin diagnose) writes DIR/calibration.json")
    line = _error(capsys, ["export", str(tmp_path / "cal"), "--out", str(tmp_path / "e")])
    assert line.endswith("a folder, not a calibration.json (it holds calibration.json: give that file)")


def test_diagnose_refuses_a_calibration_of_another_robot(tmp_path, capsys):
    """twin diagnose --calibration of the IRB 1200 on a dataset of another robot: refused naming both robots, nothing
    written."""
    assert main(["calibrate", str(GOLDEN), "--out", str(tmp_path / "cal"), "--quiet"]) == 0
    cal = tmp_path / "cal" / "calibration.json"
    ds = _golden_copy(tmp_path, robot="brtirus0707a")
    capsys.readouterr()
    line = _error(capsys, ["diagnose", str(ds), "--calibration", str(cal), "--out", str(tmp_path / "d"), "--no-plots",
                           "--no-recording", "--threads", "1"])
    assert line.startswith(f"twin diagnose: error: --calibration {cal}: dataset {ds}: robot 'brtirus0707a' (dh, ")
    assert line.endswith("is not the calibration's robot 'irb1200' (mdh, joints q1, q2, q3, q4, q5, q6)")
    assert not (tmp_path / "d").exists()


def _few_rows(tmp_path, n: int, joints: int = 6) -> Path:
    """The first ``n`` of 20 rows of a DH arm's campaign (``joints`` joints, a laser tracker's three points),
    imported."""
    import sys

    import numpy as np

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import _newcomer as N

    rng = np.random.default_rng(1)
    robot = N.make_robot(rng, "dh", joints)
    s = N.measure(N.perturbed(robot, rng), N.sample_joints(robot, rng, 20), N.random_frame(rng), rng, noise_mm=0.005,
                  markers=np.array([[0, 0, 0.1], [0.06, 0, 0.1], [0, 0.07, 0.12]]))
    sub = N.Session(q=s.q[:n], base2meas=s.base2meas, points=s.points[:n], markers=s.markers)
    tag = f"{n}" if joints == 6 else f"{n}_{joints}"
    m = N.write_campaign(tmp_path / f"lab{tag}", robot, [("a.csv", sub, {})], N.DIALECTS[0], noise_mm=0.005)
    assert main(["import", "--map", str(m), "--out", str(tmp_path / f"ds{tag}")]) == 0
    return tmp_path / f"ds{tag}"


def test_calibrate_warns_when_the_model_misses_the_validation_rows_more_than_the_nominal_robot(tmp_path, capsys):
    """Five rows of a 6-joint arm (four calibrate, one validates) leave a model worse than the nominal robot on the
    validation row: twin calibrate says so (and says nothing of it on 20 rows of the same campaign)."""
    out = {}
    for n in (5, 20):
        assert main(["calibrate", str(_few_rows(tmp_path, n)), "--out", str(tmp_path / f"cal{n}")]) == 0
        out[n] = capsys.readouterr().out
    assert "WARNING: the calibrated model misses the validation rows by more than the nominal robot does" in out[5]
    assert "WARNING: the calibrated model misses" not in out[20]


def test_diagnose_refuses_too_few_rows_unless_forced_and_then_marks_it(tmp_path, capsys):
    """Five rows of a 6-joint arm: twin diagnose refuses, naming the rows, what they cannot identify and the minimum;
    with --force it writes a diagnosis whose notes say it is not meaningful (20 rows: no refusal, no warning)."""
    import json

    ds5 = _few_rows(tmp_path, 5)
    argv = ["--no-plots", "--no-recording", "--threads", "1"]
    assert main(["diagnose", str(ds5), "--out", str(tmp_path / "d5"), *argv]) == 2
    err = capsys.readouterr().err
    assert "too few rows for a diagnosis: 5 rows, 4 of them fit" in err and "at least 7 rows that fit" in err
    assert not (tmp_path / "d5").exists()
    assert main(["diagnose", str(ds5), "--out", str(tmp_path / "d5"), "--force", *argv]) == 0
    out = capsys.readouterr().out
    assert "WARNING: rank deficiency from these configurations: " in out
    notes = json.loads((tmp_path / "d5" / "diagnosis.json").read_text())["notes"]
    assert any(n.startswith("NOT MEANINGFUL (written with --force): too few rows") for n in notes)
    assert main(["diagnose", str(_few_rows(tmp_path, 20)), "--out", str(tmp_path / "d20"), *argv]) == 0
    assert "WARNING" not in capsys.readouterr().out


def test_diagnose_refuses_too_few_rows_of_full_rank(tmp_path, capsys):
    """Six rows of a 5-joint arm (no rank deficiency, fewer than two coordinates per parameter on the rows that fit):
    twin diagnose refuses, naming the coordinates, the parameters and the minimum; nothing written."""
    ds = _few_rows(tmp_path, 6, joints=5)
    argv = ["--no-plots", "--no-recording", "--threads", "1"]
    assert main(["diagnose", str(ds), "--out", str(tmp_path / "d"), *argv]) == 2
    err = capsys.readouterr().err
    assert "too few rows for a diagnosis: 6 rows, " in err and "degrees of freedom to spare" in err
    assert "rows that fit (about " in err and not (tmp_path / "d").exists()


def test_import_refuses_an_out_folder_that_holds_a_dataset_unless_forced(tmp_path, capsys):
    """twin import --out a folder holding a dataset: refused naming the folder; --force replaces dataset.toml and
    poses.csv and leaves the user's other files; an input that the dataset would overwrite is refused even forced."""
    ds = _few_rows(tmp_path, 5)
    m = tmp_path / "lab5" / "map.toml"
    (ds / "my_notes.csv").write_text("measured by hand\n")
    before = (ds / "poses.csv").read_bytes()
    (ds / "poses.csv").write_text("edited\n")
    assert main(["import", "--map", str(m), "--out", str(ds)]) == 2
    assert f"--out {ds}: the folder already holds a dataset (dataset.toml, poses.csv)" in capsys.readouterr().err
    assert (ds / "poses.csv").read_text() == "edited\n"
    assert main(["import", "--map", str(m), "--out", str(ds), "--force"]) == 0
    assert (ds / "poses.csv").read_bytes() == before and (ds / "my_notes.csv").read_text() == "measured by hand\n"
    shutil.copyfile(tmp_path / "lab5" / "a.csv", tmp_path / "lab5" / "poses.csv")
    assert main(["import", "--map", str(m), str(tmp_path / "lab5" / "poses.csv"), "--out", str(tmp_path / "lab5"),
                 "--force"]) == 2
    assert "would replace the input" in capsys.readouterr().err


def test_a_misspelt_table_of_dataset_toml_is_named(tmp_path):
    """A dataset.toml whose stations table is misspelt ([station.front]: its base2meas would be ignored): DatasetError
    naming the key and the keys dataset.toml holds."""
    from twin.dataset import DatasetError, read_dataset

    ds = _golden_copy(tmp_path)
    t = ds / "dataset.toml"
    t.write_text(t.read_text().replace("[stations.front]", "[station.front]"))
    with pytest.raises(DatasetError, match=r"dataset.toml: unknown key\(s\) or table\(s\) \['station'\]; dataset.toml "
                                           r"holds \['markers', 'noise', 'plate', 'provenance', 'robot', "):
        read_dataset(ds)


def _with_temperature(tmp_path, gaps) -> Path:
    """A clean 40-row IRB-1200 dataset with a temp_c column (20..22 degC) empty in the rows ``gaps``."""
    import sys
    from dataclasses import replace

    import numpy as np

    from twin.dataset import read_dataset, write_dataset

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _estimator_helpers import write_clean_dataset

    ds = read_dataset(write_clean_dataset(tmp_path / "clean", 40, seed=3))
    t = 20.0 + np.linspace(0.0, 2.0, ds.n)
    t[list(gaps)] = np.nan
    write_dataset(tmp_path / "ds", replace(ds, temp_c=t))
    return tmp_path / "ds"


def test_diagnose_leaves_out_the_rows_without_a_temperature_and_names_them(tmp_path, capsys):
    """temp_c empty in 2 of 40 rows: twin diagnose diagnoses the 38 others and names the two (pose_id) in the notes
    of diagnosis.json and on stdout."""
    import json

    ds = _with_temperature(tmp_path, (5, 17))
    argv = ["--no-plots", "--no-recording", "--threads", "1"]
    assert main(["diagnose", str(ds), "--out", str(tmp_path / "d"), *argv]) == 0
    note = "column 'temp_c' is empty in 2 of 40 rows (pose_id [5, 17]): those rows are left out of the diagnosis"
    assert note in capsys.readouterr().out
    notes = json.loads((tmp_path / "d" / "diagnosis.json").read_text())["notes"]
    assert any(n.startswith(note) and "38 rows diagnosed" in n for n in notes)


def test_a_temperature_column_empty_in_every_row_is_dropped_for_the_diagnosis(tmp_path):
    """temp_c empty in every row: the dataset the diagnosis reads has no temperature, and the note says so; a
    dataset without gaps is returned as it is, without a note."""
    from twin.commands.diagnose import without_temperature_gaps
    from twin.dataset import read_dataset

    ds = read_dataset(_with_temperature(tmp_path, range(40)))
    out, note = without_temperature_gaps(ds)
    assert out.temp_c is None and out.n == 40 and "empty in 40 of 40 rows" in note and "without a temperature" in note
    clean = read_dataset(tmp_path / "clean")
    assert without_temperature_gaps(clean) == (clean, "")
