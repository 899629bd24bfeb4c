"""PerRunPoseBatch: a batch of LM runs where each run fits its own measured poses (TM-MDH Table 8, preset
reading), and the paper's first-order orientation residual."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from studies.tmmdh import tmmdh_common as C  # noqa: E402
from twin.estimator.core import prepare  # noqa: E402
from twin.estimator.lm import LMSettings, PerRunPoseBatch, PoseBatch, levenberg_marquardt  # noqa: E402
from twin.kinematics import tool2meas  # noqa: E402
from twin.transforms import rot_z  # noqa: E402


def _setup(n=12):
    q = C.poses(n, seed=3)
    ds, true = C.dataset(q)
    prep = prepare(ds, use_given_bases=True)
    return prep, q, true["pose"]


def _per_run(prep, q, T, **kw):
    return PerRunPoseBatch(prep.space, q, T[:, :, :3, 3], T[:, :, :3, :3], **kw)


def test_same_data_matches_pose_batch():
    """With every run holding the same poses, residuals and Jacobian equal PoseBatch's (plus a zero row)."""
    prep, q, T = _setup()
    pb = PoseBatch(prep.space, prep.obs_cal.with_sigma(1e-3, 1.0))
    pr = _per_run(prep, q, np.stack([T, T]), sigma_position=1e-3)
    X = np.stack([prep.x_nominal, prep.x_nominal + 1e-3])
    r0, J0 = pb(X)
    r1, J1 = pr(pr.starts(X))
    np.testing.assert_allclose(r1, r0, atol=1e-12)
    np.testing.assert_allclose(J1[:, :-1], J0, atol=1e-12)
    assert not np.any(J1[:, -1])


def test_residual_follows_the_run_index_column():
    """A row is compared with the poses its last column names, whatever its position in the batch."""
    prep, q, T = _setup()
    T2 = T.copy()
    T2[:, :3, 3] += 0.01
    pr = _per_run(prep, q, np.stack([T, T2]))
    X = pr.starts(np.stack([prep.x_nominal, prep.x_nominal]))
    rms = pr.position_rms(X[::-1])
    assert rms[0] > rms[1] + 5e-3


def test_lm_fits_each_run_to_its_own_robot():
    """LM over a batch of two different robots reproduces each robot's poses (runs finishing apart)."""
    prep, q, _ = _setup()
    tr = C.truth_model()
    T = np.stack([tool2meas(tr, q), tool2meas(tr.perturbed({"alpha2": 0.3}), q)])
    pr = _per_run(prep, q, T)
    X0 = pr.starts(np.repeat(prep.x_nominal[None], 2, axis=0))
    r = levenberg_marquardt(pr, X0, pr.free(np.ones(prep.space.size, bool)), settings=LMSettings(max_iter=60))
    assert np.all(pr.position_rms(r.X) < 1e-9)
    np.testing.assert_array_equal(r.X[:, -1], [0.0, 1.0])


def test_first_order_residual_is_sine_of_the_angle():
    """'first_order' gives sin(angle) * axis where 'log' gives angle * axis."""
    prep, q, T = _setup(n=1)
    Tm = T.copy()
    Tm[:, :3, :3] = rot_z(np.array(2.0)) @ T[:, :3, :3]
    x = prep.space.from_model(C.truth_model(), {"0": C.truth_model().base2meas})[None]
    for kind, expect in (("log", 2.0), ("first_order", np.sin(2.0))):
        pr = _per_run(prep, q, Tm[None], rotation_residual=kind)
        r, _ = pr(pr.starts(x), part="orientation", jacobian=False)
        np.testing.assert_allclose(r[0], [0.0, 0.0, expect], atol=1e-9)


def test_bad_rotation_residual_is_rejected():
    """An unknown rotation_residual raises ValueError naming it."""
    prep, q, T = _setup()
    with pytest.raises(ValueError, match="rotation_residual"):
        _per_run(prep, q, T[None], rotation_residual="euler")
