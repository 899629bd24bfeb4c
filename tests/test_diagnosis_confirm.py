"""The held-out confirmation's allowance for rows that are not independent in time (twin.diagnosis.confirm)."""

import numpy as np

from twin.diagnosis.atoms import Atom
from twin.diagnosis.confirm import moves_the_cell, of_time, reads_the_wander, serial_inflation, vector_inflation
from twin.diagnosis.features import Sin, Step

T_S = np.arange(80.0) * 30.0  # 80 rows, one every 30 s


def _ar1(rng: np.random.Generator, rho: float, n: int) -> np.ndarray:
    x = np.zeros(n)
    for i in range(1, n):
        x[i] = rho * x[i - 1] + np.sqrt(1.0 - rho**2) * rng.normal()
    return x


def test_independent_rows_inflate_the_variance_little():
    """Over 20 series of 80 white rows the inflation is 1 in the median and below 1.6 in every one (its estimate's
    scatter: a chance correlation of neighbouring rows)."""
    got = [serial_inflation(np.random.default_rng(s).normal(size=80), T_S) for s in range(20)]
    assert max(got) < 1.6 and np.median(got) == 1.0, got


def test_rows_correlated_over_a_few_inflate_the_variance():
    """Rows of an AR(1) with correlation 0.7 from one to the next (a sum's variance 5.7x the independent rows') give
    an inflation beyond 2 in the median of 20 series, beyond every white series'."""
    got = [serial_inflation(_ar1(np.random.default_rng(s), 0.7, 80), T_S) for s in range(20)]
    assert np.median(got) > 2.0, got


def test_a_level_and_a_drift_are_not_counted_as_dependence():
    """A level and a linear drift in time under white rows (a term's misfit over the block) inflate nothing."""
    rng = np.random.default_rng(3)
    e = 5.0 + 0.1 * T_S / 30.0 + rng.normal(size=80)
    assert serial_inflation(e, T_S) < 1.2


def test_only_a_term_of_time_on_the_measurement_side_moves_with_the_cell():
    """A step of a station's measurement frame is a term the cell's wander moves alike from row to row; a step of a
    joint's zero or of the tool is not (the arm's pose turns it from row to row)."""
    step = (Step(ch="t_s", at=100.0),)
    base = Atom("change", "param", "base", step, "", "", "change")
    joint = Atom("change", "joint", "theta4", step, "", "", "change")
    tool = Atom("change", "param", "tool", step, "", "", "change")
    assert of_time(base) and moves_the_cell(base)
    assert of_time(joint) and not moves_the_cell(joint)
    assert not moves_the_cell(tool)


def test_a_change_of_the_measurement_frame_is_read_along_its_prediction_alone():
    """An oscillation of a station's frame in time reads the wander on every coordinate; a step of that frame (a bumped
    instrument, constant over its rows) does not, nor does a term through the arm."""
    oscillation = Atom("unnamed", "param", "base", (Sin(ch="t_s", k=2.0 * np.pi / 1400.0),), "", "", "generic")
    step = Atom("change", "param", "base", (Step(ch="t_s", at=100.0),), "", "", "change")
    joint = Atom("unnamed", "joint", "theta2", (Sin(ch="t_s", k=2.0 * np.pi / 1400.0),), "", "", "generic")
    assert reads_the_wander(oscillation)
    assert not reads_the_wander(step)
    assert not reads_the_wander(joint)


N_ROWS, N_COORDS = 80, 9  # rows of three points, x y z each
SMOOTH = np.outer(np.linspace(0.5, 1.5, N_ROWS), np.ones(N_COORDS))  # a prediction that changes slowly in time


def _wander(rng: np.random.Generator) -> np.ndarray:
    """White rows plus a translation of all three points, an AR(1) of correlation 0.7 at half the white noise."""
    return rng.normal(size=(N_ROWS, N_COORDS)) + 0.5 * np.sqrt(3.0) * np.tile(_ar3(rng), (1, 3))


def _ar3(rng: np.random.Generator) -> np.ndarray:
    return np.column_stack([_ar1(rng, 0.7, N_ROWS) for _ in range(3)])


def test_white_rows_inflate_a_smooth_prediction_little():
    """Over 20 series of white rows, a prediction smooth in time is inflated by at most 1.3 (1 in the median)."""
    got = [vector_inflation(np.random.default_rng(s).normal(size=(N_ROWS, N_COORDS)), SMOOTH) for s in range(20)]
    assert max(got) < 1.3 and np.median(got) == 1.0, got


def test_a_wander_inflates_a_smooth_prediction():
    """Rows with a wander of the three points together (AR(1), correlation 0.7, half the white noise) inflate a
    prediction smooth in time beyond 1.5 in every one of 20 series and beyond 2 in the median."""
    got = [vector_inflation(_wander(np.random.default_rng(s)), SMOOTH) for s in range(20)]
    assert min(got) > 1.5 and np.median(got) > 2.0, got


def test_a_wander_does_not_inflate_a_prediction_that_turns_from_row_to_row():
    """The same wander under a prediction that changes sign from one row to the next inflates nothing."""
    turns = SMOOTH * ((-1.0) ** np.arange(N_ROWS))[:, None]
    got = [vector_inflation(_wander(np.random.default_rng(s)), turns) for s in range(20)]
    assert max(got) == 1.0, got
