"""The readings of the TM-MDH Table 8 grid: where the (Delta theta1, Delta alpha2) deviation goes."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from studies.tmmdh import tmmdh_common as C  # noqa: E402

G = np.array([0.0, 0.5])


def test_initial_value_reading_moves_the_start_not_the_data():
    """'initial_value': the starts carry the deviation, every run sees the same poses."""
    sp, xn, X0, _, P, _ = C.grid_problem("initial_value", G)
    assert X0[3, sp.index("theta1")] - xn[sp.index("theta1")] == pytest.approx(0.5)
    assert X0[3, sp.index("alpha2")] - xn[sp.index("alpha2")] == pytest.approx(0.5)
    np.testing.assert_array_equal(P[0], P[3])


def test_preset_reading_moves_the_data_not_the_start():
    """'preset': every run starts from nominal, the poses of a deviated cell differ from the undeviated one."""
    _, xn, X0, _, P, _ = C.grid_problem("preset", G)
    np.testing.assert_array_equal(X0, np.repeat(xn[None], 4, axis=0))
    assert np.max(np.abs(P[3] - P[0])) > 0.01


def test_unknown_reading_is_rejected():
    """An unknown reading raises ValueError naming the argument."""
    with pytest.raises(ValueError, match="reading"):
        C.grid_problem("both", G)
