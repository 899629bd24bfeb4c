"""The structure test's tail function: one entry gives the numbers of the same entry in an array, bit for bit."""

import numpy as np

from twin.diagnosis.structure import chi2_logsf


def test_chi2_logsf_of_one_entry_is_the_arrays_number_bit_for_bit():
    """chi2_logsf of a scalar or a one-entry array equals that entry of a call on many (both sides of the median, the
    tail where scipy underflows, the support's ends), as the same type and shape."""
    rng = np.random.default_rng(5)
    x = np.concatenate([rng.exponential(30.0, 400), [0.0, -1.0, 1e-300, 2e3, 5e4, 1e308, np.inf, np.nan]])
    k = np.concatenate([rng.integers(1, 40, 400).astype(float), [1.0, 3.0, 6.0, 2.0, 12.0, 5.0, 4.0, 1.0]])
    k[::50] = [0.0, -1.0, 0.5, np.nan, 36.0, 1.0, 2.0, 7.0, 3.0]
    many = chi2_logsf(x, k)
    for i in range(len(x)):
        one = chi2_logsf(x[i], k[i])
        assert type(one) is float and np.float64(one).tobytes() == many[i].tobytes()
        arr = chi2_logsf(x[i:i + 1], k[i])
        assert arr.shape == (1,) and arr.tobytes() == many[i:i + 1].tobytes()
