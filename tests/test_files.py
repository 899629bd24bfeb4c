"""twin.files: the readers of the files a user names, every error naming the file, and finite numbers."""

import pytest

from twin.dataset import DatasetError
from twin.files import parse_finite, read_json, read_toml


def test_read_toml_names_the_file_when_missing_invalid_or_not_utf8(tmp_path):
    """A missing file, bad TOML and non-UTF-8 bytes each raise the caller's error class naming the file."""
    p = tmp_path / "c.toml"
    with pytest.raises(DatasetError, match=rf"^{p}: no such column map$"):
        read_toml(p, DatasetError, missing="no such column map")
    p.write_text("a = [1,\n")
    with pytest.raises(ValueError, match=rf"^{p}: not valid TOML: "):
        read_toml(p)
    p.write_bytes(b"a = '\xff'\n")
    with pytest.raises(ValueError, match=rf"^{p}: not UTF-8 text"):
        read_toml(p)
    p.write_text("a = 1\n[b]\nc = 'x'\n")
    assert read_toml(p) == {"a": 1, "b": {"c": "x"}}


def test_read_json_names_the_file_when_missing_or_invalid(tmp_path):
    """A missing file says what was expected there; bad JSON is named; good JSON comes back as values."""
    p = tmp_path / "cal.json"
    with pytest.raises(ValueError, match=rf"^{p}: missing$"):
        read_json(p)
    p.write_text('{"a": 1,}')
    with pytest.raises(ValueError, match=rf"^{p}: not valid JSON: "):
        read_json(p)
    p.write_text('{"a": [1, 2.5]}')
    assert read_json(p) == {"a": [1, 2.5]}


def test_parse_finite_reads_both_decimal_marks_and_refuses_non_finite():
    """'1.5' and '1,5' (decimal ',') give 1.5; text, inf and nan are refused naming where and the text."""
    assert parse_finite("1.5", "x") == 1.5 and parse_finite("-1,5", "x", decimal=",") == -1.5
    with pytest.raises(DatasetError, match=r"^f.csv: row 3, column 'q1': not a number: 'abc'$"):
        parse_finite("abc", "f.csv: row 3, column 'q1'", DatasetError)
    for bad in ("inf", "nan", "-Infinity"):
        with pytest.raises(ValueError, match=rf"^w: not a finite number: '{bad}'$"):
            parse_finite(bad, "w")
    with pytest.raises(ValueError, match="decimal must be"):
        parse_finite("1", "w", decimal=";")
