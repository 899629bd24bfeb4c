"""The latest results of a computation kept and given again (twin.estimator.memo), and the predictions kept by
twin.estimator.problem.predict_points: the same numbers to the bit, never those of other inputs."""

import numpy as np
import pytest

from twin.dataset import default_plate
from twin.estimator.chain import Chain
from twin.estimator.memo import KeptResults, array_key
from twin.estimator.problem import ParamSpace, predict_points
from twin.robots import irb1200


def test_a_kept_result_is_given_again_read_only():
    """An equal key gives the kept result without computing it again; its arrays are read-only."""
    kept = KeptResults(2, 1 << 20)
    calls = []

    def compute():
        calls.append(1)
        return np.arange(3.0), np.ones(2)

    a = kept.get_or_compute(("f", array_key(np.zeros(2))), compute)
    b = kept.get_or_compute(("f", array_key(np.zeros(2))), compute)
    assert b is a and len(calls) == 1
    assert not a[0].flags.writeable and not a[1].flags.writeable
    kept.get_or_compute(("f", array_key(np.zeros(2, dtype=np.float32))), compute)  # another dtype: another key
    assert len(calls) == 2


def test_kept_results_are_bounded_by_count_and_bytes():
    """At most ``entries`` results, the oldest dropped first, and no more bytes than the bound but the latest."""
    kept = KeptResults(2, 1 << 20)
    for k in range(3):
        kept.put((k,), np.zeros(4))
    assert len(kept) == 2 and kept.get((0,)) is None and kept.get((2,)) is not None
    small = KeptResults(8, 100)
    small.put((0,), np.zeros(10))  # 80 bytes
    small.put((1,), np.zeros(10))
    assert len(small) == 1 and small.get((1,)) is not None
    with pytest.raises(ValueError, match="entries"):
        KeptResults(0, 1)


def test_kept_predictions_are_those_computed_for_the_same_inputs():
    """``predict_points`` gives for the same inputs the numbers a new evaluation computes, to the bit (its points
    without the Jacobian those of an evaluation with it), and for an ``x`` one ulp away not the kept ones."""
    m = irb1200()
    rng = np.random.default_rng(3)
    space = ParamSpace(Chain(m.convention, m.beta_joints), ("0",))
    x = space.from_model(m) + rng.normal(0, 1e-3, space.size)
    q = rng.uniform(-1.5, 1.5, (12, 6))
    st = np.zeros(12, int)
    pts_tool = default_plate().spheres_flange
    pts, Jk = predict_points(space, x, q, st, pts_tool, jacobian=True)
    again, none = predict_points(space, x.copy(), q.copy(), st, pts_tool, jacobian=False)
    assert again is pts and none is None
    fresh = ParamSpace(Chain(m.convention, m.beta_joints), ("0",))  # another space: computed anew
    pts2, Jk2 = predict_points(fresh, x, q, st, pts_tool, jacobian=True)
    assert pts2 is not pts and np.array_equal(pts2, pts) and np.array_equal(Jk2, Jk)
    x_next = x.copy()
    x_next[0] = np.nextafter(x[0], np.inf)
    moved, _ = predict_points(space, x_next, q, st, pts_tool)
    assert moved is not pts and not np.array_equal(moved, pts)


def test_an_owners_result_is_given_to_it_alone_and_dropped_once_it_is_gone():
    """A result kept for an owner is given to that owner only (not to another object under the same key) and is
    dropped at the next keep once the owner is gone."""
    import gc

    class Owner:
        pass

    kept = KeptResults(4, 1 << 20)
    a, b = Owner(), Owner()
    kept.put(("k",), np.zeros(2), owner=a)
    assert kept.get(("k",), owner=a) is not None and kept.get(("k",), owner=b) is None
    del a
    gc.collect()
    kept.put(("other",), np.ones(2), owner=b)
    assert len(kept) == 1 and all(r() is b for r in kept.owners())
