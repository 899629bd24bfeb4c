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
