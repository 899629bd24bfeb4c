"""Feature values: a gravity-torque mix is the sum of its weighted regressor columns, taken in their order from 0."""

import numpy as np

from twin.diagnosis.features import GravMix
from twin.diagnosis.values import _grav_mix


def test_a_gravity_mix_is_its_columns_summed_in_order_from_zero_bit_for_bit():
    """_grav_mix equals ``sum(w * column for ...)`` to the bit, signed zeros included (a joint whose regressor
    columns vanish, zero weights), with the stacked columns kept once per joint and column set."""
    rng = np.random.default_rng(2)
    for trial in range(200):
        Yg = rng.normal(size=(50, 6, 6, 10)) * rng.choice([0.0, 1e-3, 1.0, 1e3], size=(1, 6, 6, 10))
        if trial % 5 == 0:
            Yg[:] = -0.0
        cols = tuple((int(rng.integers(1, 7)), int(rng.integers(0, 10))) for _ in range(int(rng.integers(1, 12))))
        w = tuple(float(v) for v in rng.normal(size=len(cols)) * rng.choice([0.0, -0.0, 1.0, 1e8], size=len(cols)))
        f = GravMix(i=int(rng.integers(1, 7)), cols=cols, w=w, h=0.3)
        cache = {"grav": Yg}
        ref = sum(wj * Yg[:, f.i - 1, kk - 1, c] for wj, (kk, c) in zip(f.w, f.cols))
        assert _grav_mix(f, cache).tobytes() == ref.tobytes()
        assert _grav_mix(f, cache).tobytes() == ref.tobytes()  # from the kept columns
