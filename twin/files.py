"""Reading the files a user names (configs, maps, calibrations, datasets) and the numbers in them: every error
names the file (and the row or key the caller puts in ``where``), never a bare ``UnicodeDecodeError``,
``TOMLDecodeError`` or ``JSONDecodeError``.

Each reader takes the ``ValueError`` subclass its caller reports with (``twin.dataset.DatasetError`` for a
dataset or a column map, ``ValueError`` elsewhere). A foundation module: it imports nothing of the library.
"""

from __future__ import annotations

import io
import json
import math
import os
import tomllib
from pathlib import Path
from typing import Any

__all__ = ["read_text", "open_text", "read_toml", "read_json", "parse_finite", "check_pose_id", "POSE_ID_MAX",
           "parse_marker_std", "MARKER_STD_COLUMN", "check_readings", "READING_MAX_SI", "check_row_width",
           "separator_hint", "duplicate_names", "columns_beyond_joints"]


def read_text(path: str | os.PathLike, error: type[ValueError] = ValueError) -> str:
    """The UTF-8 text of the file ``path`` (a path, or a :mod:`importlib.resources` traversable), without the byte
    order mark a spreadsheet may write first; a file that is not UTF-8 text raises ``error`` naming it. ``OSError``
    as :func:`open` raises it (its ``filename`` set)."""
    data = path.read_bytes() if hasattr(path, "read_bytes") else Path(path).read_bytes()
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    return text[1:] if text.startswith("\ufeff") else text


def open_text(path: str | os.PathLike, error: type[ValueError] = ValueError) -> io.StringIO:
    """The file ``path`` as a text stream for :mod:`csv` (``newline=""``), decoded as :func:`read_text` does."""
    return io.StringIO(read_text(path, error), newline="")


def read_toml(path: str | os.PathLike, error: type[ValueError] = ValueError, *, missing: str = "missing") -> dict:
    """The TOML file ``path`` as a dict. ``error`` naming the file: ``"<path>: <missing>"`` when there is no such
    file (``missing`` says what the caller expected there), ``"<path>: not valid TOML: ..."``, not UTF-8 text."""
    try:
        text = read_text(path, error)
    except FileNotFoundError:
        raise error(f"{path}: {missing}") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path}: not valid TOML: {exc}") from None


def read_json(path: str | os.PathLike, error: type[ValueError] = ValueError, *, missing: str = "missing") -> Any:
    """The JSON file ``path`` as Python values, with the errors of :func:`read_toml`
    (``"<path>: not valid JSON: ..."``)."""
    try:
        text = read_text(path, error)
    except FileNotFoundError:
        raise error(f"{path}: {missing}") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise error(f"{path}: not valid JSON: {exc}") from None


# [m, rad, degC] the largest reading of a joint, a coordinate, an angle or a temperature a cell may give once in SI
# units: 10 km, 10000 rad (1600 turns); far beyond any robot or instrument, well below where a unit's conversion or a
# fit's squares overflow (a cell of 1e308 is a typing or export error, named where it is read, not met as inf later)
READING_MAX_SI = 1e4


def check_readings(readings, row_words, error: type[ValueError] = ValueError) -> None:
    """Refuse the first entry beyond :data:`READING_MAX_SI` of a reader's arrays, once every row was read (a row's
    own width check, which says more of a shifted row, comes first). ``readings``: ``(values_si, column, unit)``
    triples, ``values_si`` ``(n, ...)`` in SI units (NaN for a cell not given), ``column(*index)`` the name of the
    column of an entry's trailing index, ``unit(*index)`` the SI size of the file's unit there; ``row_words(k)``: the
    words naming row ``k``. ``error`` names the row, the column and the value in the file's unit."""
    import numpy as np

    for values, column, unit in readings:
        values = np.asarray(values, float)
        bad = np.argwhere(np.abs(np.nan_to_num(values, nan=0.0)) > READING_MAX_SI)
        if len(bad):
            at = tuple(int(i) for i in bad[0])
            raise error(f"{row_words(at[0])}, column {column(*at[1:])!r}: {values[at] / unit(*at[1:]):.6g} is beyond "
                        f"any reading (more than {READING_MAX_SI:g} in SI units): a typing or export error?")


POSE_ID_MAX = 2**62  # a pose id's magnitude stays below this (ids are stored as 64-bit integers)


def check_pose_id(value: int, text: str, where: str, error: type[ValueError] = ValueError) -> int:
    """``value`` (the integer a ``pose_id`` cell ``text`` gives) when within :data:`POSE_ID_MAX`; ``error`` naming
    ``where`` and the cell otherwise (an id of 20 digits is a typing or export error, not an overflow later)."""
    if abs(value) >= POSE_ID_MAX:
        raise error(f"{where}: {text!r} is beyond the ids a dataset holds (|id| < 2**{POSE_ID_MAX.bit_length() - 1})")
    return int(value)


MARKER_STD_COLUMN = "marker_std_mm"  # optional poses.csv column: the instrument's marker noise of the row [mm]


def parse_marker_std(text: str, where: str, error: type[ValueError] = ValueError) -> float:
    """A ``marker_std_mm`` cell (a standard deviation [mm]) as a finite number >= 0; ``error`` naming ``where``
    otherwise."""
    v = parse_finite(text, where, error)
    if v < 0:
        raise error(f"{where} has {text!r}, expected a finite number >= 0 [mm]")
    return v


def parse_finite(text: str, where: str, error: type[ValueError] = ValueError, *, decimal: str = ".") -> float:
    """The text of a cell or an argument as a finite float, read with the decimal mark ``decimal`` (``"."`` or
    ``","``). ``error`` ``"<where>: not a number: '<text>'"`` or ``"<where>: not a finite number: '<text>'"``
    (inf, nan) otherwise."""
    if decimal not in (".", ","):
        raise ValueError(f"decimal must be '.' or ',', got {decimal!r}")
    try:
        v = float(text.replace(",", ".") if decimal == "," else text)
    except (TypeError, ValueError, AttributeError):
        raise error(f"{where}: not a number: {text!r}") from None
    if not math.isfinite(v):
        raise error(f"{where}: not a finite number: {text!r}")
    return v


def check_row_width(header: list[str], row: list[str], where: str, error: type[ValueError] = ValueError, *,
                    separator: str = ",") -> None:
    """Refuse a CSV row with more cells than the ``header`` has columns unless the cells beyond are empty (a
    spreadsheet's trailing separators): such a row would be read shifted. ``error`` names ``where`` (the file and
    row), both counts and the cells beyond, or, when the header is one cell holding another separator
    (:func:`separator_hint`), that separator."""
    beyond = row[len(header):]
    if any(c.strip() for c in beyond):
        hint = separator_hint(header, separator)
        if hint:  # the header is one cell holding another separator: that separator, not the decimal mark, is why
            raise error(f"{where}: {len(row)} cells where the header has {len(header)} column{hint}")
        causes = (["a ',' decimal mark in a ','-separated file (write '.' decimals, or another separator)"]
                  if separator == "," else []) + [f"a cell holding the separator {separator!r} without quotes"]
        raise error(f"{where}: {len(row)} cells where the header has {len(header)} columns (beyond the header: "
                    f"{', '.join(repr(c) for c in beyond[:4])}{' ...' if len(beyond) > 4 else ''}): "
                    f"{', or '.join(causes)}")


def separator_hint(header: list[str], separator: str = ",") -> str:
    """Words to add to a missing-column error when the ``header`` read with ``separator`` is one cell holding another
    usual separator (``;``, tab, ``,``, ``|``): the file is separated by that one. Empty otherwise."""
    if len(header) != 1:
        return ""
    for sep, name in ((";", "';'"), ("\t", "tab"), (",", "','"), ("|", "'|'")):
        if sep != separator and sep in header[0]:
            return f" (the header is one cell holding {name}: the file is {name}-separated, this reader expects {separator!r})"
    return ""


def duplicate_names(header: list[str]) -> list[str]:
    """The non-empty column names the ``header`` holds more than once (sorted)."""
    return sorted({h for h in header if h and header.count(h) > 1})


def columns_beyond_joints(header, joint_cols) -> list[str]:
    """The columns ``q<k>`` of ``header`` beyond a robot whose joint columns ``joint_cols`` are ``q1..qN`` (a file
    of another robot's joints); empty for a robot whose joints have names."""
    if tuple(joint_cols) != tuple(f"q{j}" for j in range(1, len(joint_cols) + 1)):
        return []
    return [h for h in header if h.startswith("q") and h[1:].isdigit() and h not in joint_cols]
