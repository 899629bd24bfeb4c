"""The edge conversions of twin.units."""

import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from twin import units


def test_constants_are_inverse_pairs():
    """Each ``<TO>_PER_<FROM>`` constant times its reverse is one."""
    assert units.M_PER_MM * units.MM_PER_M == 1.0
    assert math.isclose(units.M_PER_UM * units.UM_PER_M, 1.0)
    assert math.isclose(units.RAD_PER_DEG * units.DEG_PER_RAD, 1.0)
    assert units.RAD_PER_MRAD * units.MRAD_PER_RAD == 1.0


def test_round_trips_keep_arrays_and_numbers():
    """mm -> m -> mm and deg -> rad -> deg return the input, for numbers and (n, 3) arrays."""
    rng = np.random.default_rng(7)
    a = rng.normal(size=(5, 3)) * 100.0
    np.testing.assert_allclose(units.m_to_mm(units.mm_to_m(a)), a, rtol=1e-15)
    np.testing.assert_allclose(units.rad_to_deg(units.deg_to_rad(a)), a, rtol=1e-15)
    assert units.mm_to_m(25.4) == 25.4e-3
    assert math.isclose(units.deg_to_rad(180.0), math.pi)


def test_sequences_come_back_as_arrays():
    """A list or tuple converts element by element into an array, bit for bit as numpy's own conversion."""
    q_deg = [0.0, 10.0, 45.0, -170.0]
    assert np.array_equal(units.deg_to_rad(q_deg), np.radians(q_deg))
    assert np.array_equal(units.rad_to_deg(tuple(np.radians(q_deg))), np.degrees(np.radians(q_deg)))
    assert units.m_to_mm([0.5, 1.0]).tolist() == [500.0, 1000.0]


# A unit constant of a module's own (``_MM = 1e-3``, ``DEG = np.pi / 180``, ``M_PER_MM = ...``) or a numpy / math
# angle conversion: the edges convert with twin.units only.
_OWN_CONSTANT = re.compile(r"^_?(MM|DEG|UM|RAD|MRAD|(M|MM|UM|RAD|DEG|MRAD)_PER_(M|MM|UM|RAD|DEG|MRAD))\s*[:=]")
_OWN_CONVERSION = re.compile(r"\b(np|numpy|math)\.(degrees|radians|deg2rad|rad2deg)\("
                             r"|\bpi\s*/\s*180\b|\b180(\.0*)?\s*/\s*(np\.|math\.)?pi\b")
_REPO = Path(__file__).resolve().parent.parent
# the folders held to the rule; the blind campaigns' generators are written apart from twin on purpose (they do
# not import it: studies/blind/README.md)
_SCOPES = ["twin", "twin/diagnosis", "studies", "experiments"]


def _own_units(scope: str) -> list[str]:
    """``path:line: text`` of every own unit constant or numpy/math angle conversion in ``scope`` (twin/units.py
    excepted; ``twin`` means the package without twin/diagnosis, which is its own scope)."""
    root = _REPO / scope
    out = []
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(_REPO).as_posix()
        if rel == "twin/units.py" or "studies/blind/generators/" in rel:
            continue
        if scope == "twin" and rel.startswith("twin/diagnosis/"):
            continue
        for n, line in enumerate(path.read_text().splitlines(), 1):
            code = line.split("#", 1)[0]
            if _OWN_CONSTANT.match(code) or _OWN_CONVERSION.search(code):
                out.append(f"{rel}:{n}: {line.strip()}")
    return out


@pytest.mark.parametrize("scope", _SCOPES)
def test_no_module_defines_its_own_unit_constants(scope):
    """No module (twin/units.py aside) defines a unit constant of its own or converts angles with numpy/math."""
    assert _own_units(scope) == []


def test_own_unit_checker_catches_a_constant_and_a_conversion(tmp_path, monkeypatch):
    """The checker reports ``_MM = 1e-3`` and ``np.degrees(x)`` with file and line, and passes twin.units names."""
    pkg = tmp_path / "twin"
    pkg.mkdir()
    (pkg / "a.py").write_text("from .units import M_PER_MM\n_MM = 1e-3\nx = 2 * M_PER_MM\n")
    (pkg / "b.py").write_text("import numpy as np\ny = np.degrees(0.1)  # a conversion\nDEFAULT_NM_PER_RAD = 2.0\n")
    monkeypatch.setattr(sys.modules[__name__], "_REPO", tmp_path)
    assert _own_units("twin") == ["twin/a.py:2: _MM = 1e-3", "twin/b.py:2: y = np.degrees(0.1)  # a conversion"]
