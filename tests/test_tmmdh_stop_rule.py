"""The C-LM stop rule of the TM-MDH convergence study reads the measurements, never the truth."""

import inspect
import sys
from dataclasses import replace
from pathlib import Path


sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from studies.tmmdh import tmmdh_common as C  # noqa: E402
from twin.estimator.core import prepare  # noqa: E402
from twin.estimator.lm import PoseBatch  # noqa: E402


def _batch(shift_m=0.0):
    ds, true = C.dataset(C.poses(12, seed=3))
    prep = prepare(ds, use_given_bases=True)
    obs = prep.obs_cal.with_sigma(1.0, 1.0)
    obs = replace(obs, pose_p=obs.pose_p + shift_m)
    return PoseBatch(prep.space, obs), prep, true


def test_stop_rule_takes_no_truth():
    """The rule is built from the pose batch (measurements) and a tolerance only."""
    assert list(inspect.signature(C.clm_stop_rule).parameters) == ["pb", "tol_m"]


def test_stop_rule_follows_the_measured_poses_not_the_truth():
    """Parameters that reproduce the truth stop on truthful data and do not stop when the measurements are
    1 mm off (a rule reading the truth would stop in both cases)."""
    pb, prep, _ = _batch()
    # the vector that reproduces the measurements: find it as the truth's parameters in this space
    x_true = prep.space.from_model(C.truth_model(), {"0": C.truth_model().base2meas})
    assert C.clm_stop_rule(pb)(x_true[None])[0]
    pb_off, _, _ = _batch(shift_m=1e-3)
    assert not C.clm_stop_rule(pb_off)(x_true[None])[0]
    assert C.data_position_rms(pb_off, x_true[None])[0] > 0.5e-3
