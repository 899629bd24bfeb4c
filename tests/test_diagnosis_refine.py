"""Tests of twin.diagnosis.refine's helpers that need no campaign."""

import itertools

import numpy as np

from twin.diagnosis.refine import clip_value


def test_clip_value_is_np_clip_to_the_bit():
    """``clip_value`` gives ``np.clip``'s number for every order of value and bounds, signed zeros, infinities, NaN
    and bounds the wrong way round."""
    vals = [-2.5, -0.0, 0.0, 1e-300, 0.7, 3.0, np.inf, -np.inf, np.nan, np.float64(0.7)]
    for v, lo, hi in itertools.product(vals, repeat=3):
        got, want = float(clip_value(v, lo, hi)), float(np.clip(v, lo, hi))
        assert np.array_equal(np.array(got), np.array(want), equal_nan=True) and \
            np.signbit(got) == np.signbit(want), (v, lo, hi, got, want)
