"""Tests of twin.evaluation.regression's prediction bands (one-sided intervals for the mean of new seeds)."""

import math

import numpy as np
import pytest
from scipy.stats import t as student_t

from twin.evaluation.regression import bands_from_repeats, check_prediction, detectable_factor, prediction_band

NAME = "m.measured.angle_deg.after.mean"
IMP = "m.measured.angle_deg.improvement_percent"


def _per_seed(after, imp):
    return {"methods": {"m": {"measured": {"angle_deg": {"after": {"mean": after}, "improvement_percent": imp}}}},
            "orderings": []}


def _bands(n=20, seed=0):
    rng = np.random.default_rng(seed)
    after = np.exp(rng.normal(math.log(0.02), 0.1, n))
    imp = rng.normal(88.0, 1.0, n)
    rep = {"seeds": list(range(n)), "orderings": {}, "per_seed": [_per_seed(a, i) for a, i in zip(after, imp)]}
    return bands_from_repeats(rep, "cmd", "cfg"), after, imp


def test_log_upper_limit_is_the_student_prediction_interval():
    """The upper limit is exp(mean log + t_{c,n-1} sd_log sqrt(1/k + 1/n)) of the band seeds."""
    b, after, _ = _bands()
    la = np.log(after)
    want = math.exp(la.mean() + student_t.ppf(0.99, 19) * la.std(ddof=1) * math.sqrt(1 / 4 + 1 / 20))
    assert prediction_band(b["statistics"][NAME], "log_upper", 4, 0.99) == pytest.approx(want, rel=1e-12)
    assert detectable_factor(b["statistics"][NAME], 4, 0.99) == pytest.approx(want / math.exp(la.mean()), rel=1e-12)


def test_check_prediction_passes_typical_and_fails_worse_runs():
    """New runs at the band's typical values pass; 30 % larger errors or 5 points less improvement fail."""
    b, after, imp = _bands()
    typical = [_per_seed(float(np.exp(np.log(after).mean())), float(imp.mean())) | {"seed": 100 + k} for k in range(4)]
    assert check_prediction(typical, b)["outside"] == []
    worse = [_per_seed(r["methods"]["m"]["measured"]["angle_deg"]["after"]["mean"] * 1.3, float(imp.mean()) - 5)
             | {"seed": 100 + k} for k, r in enumerate(typical)]
    assert {o["statistic"] for o in check_prediction(worse, b)["outside"]} == {NAME, IMP}


@pytest.mark.parametrize("kw, message", [({"n_new": 0}, "n_new"), ({"confidence": 1.0}, "confidence"),
                                         ({"kind": "both"}, "kind")])
def test_prediction_band_refuses_bad_arguments(kw, message):
    """Bad n_new, confidence or kind is a ValueError naming it."""
    b, _, _ = _bands()
    args = {"band": b["statistics"][NAME], "kind": "log_upper", **kw}
    with pytest.raises(ValueError, match=message):
        prediction_band(**args)
