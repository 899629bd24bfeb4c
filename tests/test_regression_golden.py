"""The 6R robots' results stay bit-identical to the golden file written at an earlier commit (see
``tests/_regression_golden.py``): forward and inverse kinematics, Jacobians, the batched chain, calibrations of a
measured campaign and of simulated datasets with every method, prediction, compensation, identifiability, planning
and export."""

from __future__ import annotations

import json

import numpy as np
import pytest

from _regression_golden import GOLDEN, compute


def _diff(a, b, path: str, out: list[str]) -> None:
    """Append to ``out`` the paths where ``a`` (golden) and ``b`` (now) differ at all."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                out.append(f"{path}.{k}: only in {'golden' if k in a else 'now'}")
            else:
                _diff(a[k], b[k], f"{path}.{k}", out)
        return
    if isinstance(a, list) and isinstance(b, list):
        try:
            A = np.asarray(a, dtype=float)
            B = np.asarray(b, dtype=float)
        except (TypeError, ValueError):
            A = B = None
        if A is not None and A.dtype != object:
            if A.shape != B.shape:
                out.append(f"{path}: shape {A.shape} -> {B.shape}")
            elif not np.array_equal(A, B, equal_nan=True):
                k = np.argmax(np.abs(np.nan_to_num(A - B)).ravel())
                out.append(f"{path}: max difference {np.abs(np.nan_to_num(A - B)).max():.3g} "
                           f"(at flat index {k}: {A.ravel()[k]!r} -> {B.ravel()[k]!r})")
            return
        if len(a) != len(b):
            out.append(f"{path}: length {len(a)} -> {len(b)}")
            return
        for i, (x, y) in enumerate(zip(a, b)):
            _diff(x, y, f"{path}[{i}]", out)
        return
    if isinstance(a, float) and isinstance(b, float) and np.isnan(a) and np.isnan(b):
        return
    if a != b:
        out.append(f"{path}: {a!r} -> {b!r}")


@pytest.fixture(scope="module")
def golden_and_now():
    return json.loads(GOLDEN.read_text())["values"], compute()


@pytest.mark.parametrize("part", ["kinematics", "calibrations", "predict", "compensate", "identifiability", "export", "plan"])
def test_six_joint_results_are_bit_identical_to_the_golden_file(golden_and_now, part):
    """Every number of this part equals the golden value exactly (0 ulp): the 6R code paths did not change."""
    golden, now = golden_and_now
    diffs: list[str] = []
    _diff(golden[part], now[part], part, diffs)
    assert not diffs, f"{len(diffs)} differences, first: " + "; ".join(diffs[:8])


def test_the_comparison_detects_a_one_ulp_change(golden_and_now):
    """The comparison itself is strict: one unit in the last place of one Jacobian-free number is reported."""
    golden, _ = golden_and_now
    g = json.loads(json.dumps(golden["calibrations"]["sep.best"]))
    changed = json.loads(json.dumps(g))
    changed["x"][3] = float(np.nextafter(changed["x"][3], np.inf))
    diffs: list[str] = []
    _diff(g, changed, "x", diffs)
    assert len(diffs) == 1 and "x.x" in diffs[0]
