"""Regression of the Figure 10/11 statistics of the CI campaigns: new seeds against prediction bands.

The bands (studies/separation_paper/results/regression.json, sections ``separation_ci`` and
``separation_paper_ci``) are built on seeds 1-20; the tests run seeds that did not build them and check each
statistic against a one-sided prediction interval for the mean of the new seeds (``check_prediction``: log scale
for the after-compensation errors, linear for the improvements). tests/test_regression_matched.py does the same for
the matched protocol."""

import copy
import json
from pathlib import Path

import pytest

from _shared import value_once
from twin.evaluation.regression import check_prediction, detectable_factor
from twin.runner.campaign import run_campaign, run_repeats
from twin.runner.config import load_campaign_config
from twin.runner.executor import open_executor

ROOT = Path(__file__).resolve().parent.parent
STUDY = ROOT / "studies" / "separation_paper"
CONFIG = STUDY / "separation_ci.toml"
PAPER_CONFIG = STUDY / "separation_paper_ci.toml"
BANDS = STUDY / "results" / "regression.json"
# One new seed of the rendered CI campaign (a seed costs ~30 s); every statistic at 99.9 %: the 24 after-means,
# after-maxima and improvements of its four methods raise a false alarm for unchanged code in <= 2.4 % of choices
# of the seed. One seed cannot test an ordering that fails in 1 of 20 band seeds: orderings are left to the
# paper-mode test, which pools six seeds.
CI_SEED = 101
CI_CONFIDENCE = {"mean": 0.999, "max": 0.999, "improvement_percent": 0.999}
# Six new seeds of the paper-mode campaign (~3 s each); after-means at 99 %, maxima and improvements at 99.9 %
# (as tests/test_regression_matched.py: a false alarm in <= 13 % of choices of new seeds, <= 10 % from the means).
PAPER_SEEDS = (101, 102, 103, 104, 105, 106)
PAPER_CONFIDENCE = {"mean": 0.99, "max": 0.999, "improvement_percent": 0.999}


def _bands(section: str) -> dict:
    data = json.loads(BANDS.read_text())
    assert section in data, f"{BANDS.relative_to(ROOT)} has no {section} section: run the command in docs/runner.md"
    return data[section]


@pytest.mark.parametrize("section, config, new", [("separation_ci", CONFIG, (CI_SEED,)),
                                                  ("separation_paper_ci", PAPER_CONFIG, PAPER_SEEDS)])
def test_bands_record_their_command_and_come_from_20_other_seeds(section, config, new):
    """The bands say how they were made, come from 20 seeds of this very config, carry the log-scale statistics of
    a prediction band, and none of their seeds is a seed the tests run."""
    b = _bands(section)
    assert str(config.relative_to(ROOT)) in b["command"] and "--seeds 20" in b["command"]
    assert len(b["seeds"]) == 20 and not set(new) & set(b["seeds"])
    after_means = [k for k in b["statistics"] if k.endswith(".measured.angle_deg.after.mean")]
    assert after_means and all("log_mean" in b["statistics"][k] for k in after_means)
    assert all(s["n"] == 20 for s in b["statistics"].values())


def _worse(results: dict, method: str, unit: str, factor: float) -> dict:
    """``results`` with ``method``'s measured after-compensation statistics of ``unit`` scaled by ``factor``."""
    out = copy.deepcopy(results)
    blk = out["methods"][method]["measured"][unit]
    for stat in ("mean", "max", "std", "rms"):
        if blk["after"].get(stat) is not None:
            blk["after"][stat] *= factor
    blk["improvement_percent"] = 100.0 * (1 - blk["after"]["mean"] / blk["before"]["mean"])
    return out


@pytest.fixture(scope="module")
def ci_run(tmp_path_factory):
    """The rendered CI campaign (half resolution, two stations, four methods) at a seed outside its bands (run once
    per test session, whichever worker asks first)."""
    def make():
        cfg = load_campaign_config(CONFIG).with_seed(CI_SEED)
        return run_campaign(cfg, tmp_path_factory.mktemp("ci") / "run", recording=False, figures=False).results

    return value_once(tmp_path_factory, "campaign_regression_ci_run", make)


@pytest.mark.slow
def test_a_new_seed_of_the_ci_campaign_stays_in_the_prediction_bands(ci_run):
    """Seed 101 of separation_ci.toml (rendered, measured, four methods): every after-mean, after-max and
    improvement inside its 99.9 % prediction band for one new seed."""
    assert ci_run["methods_unavailable"] == {}
    res = check_prediction([ci_run], _bands("separation_ci"), confidence=CI_CONFIDENCE, orderings=False)
    assert res["missing"] == [] and res["outside"] == [], res


@pytest.mark.slow
def test_a_broken_ci_method_fails_the_bands(ci_run):
    """The same run with one method's after-compensation errors tripled fails on that method's after-mean (the
    test above can fail)."""
    b = _bands("separation_ci")
    factor = 3.0
    assert detectable_factor(b["statistics"]["full_pose.measured.angle_deg.after.mean"], 1, 0.999) < factor
    res = check_prediction([_worse(ci_run, "full_pose", "angle_deg", factor)], b, confidence=CI_CONFIDENCE,
                           orderings=False)
    assert "full_pose.measured.angle_deg.after.mean" in {o["statistic"] for o in res["outside"]}


@pytest.fixture(scope="module")
def paper_runs(tmp_path_factory):
    """The paper-mode CI campaign (true centres + N(0, 0.01^2) mm, five methods) at six new seeds, per seed (run once
    per test session)."""
    def make():
        cfg = load_campaign_config(PAPER_CONFIG)
        with open_executor("serial") as ex:
            return run_repeats(cfg, tmp_path_factory.mktemp("paper_ci"), list(PAPER_SEEDS), ex)["per_seed"]

    return value_once(tmp_path_factory, "campaign_regression_paper_runs", make)


@pytest.mark.slow
def test_new_seeds_of_the_paper_mode_campaign_stay_in_the_prediction_bands(paper_runs):
    """Six seeds that did not build the paper-mode bands: every after-mean (99 %), after-max and improvement
    (99.9 %) inside its prediction band, and every ordering that held in >= 95 % of the band seeds (paper claims,
    pairwise method orderings) holds for their pooled after-means."""
    res = check_prediction(paper_runs, _bands("separation_paper_ci"), confidence=PAPER_CONFIDENCE)
    assert res["missing"] == [] and res["outside"] == [] and res["failed_claims"] == [], res


@pytest.mark.slow
def test_a_30_percent_worse_full_pose_fails_the_paper_mode_bands(paper_runs):
    """Full pose's angle after-mean 30 % worse in the six new seeds fails its band. It is the tightest band of this
    campaign (six new seeds see x1.26; the other after-means x1.39-1.87: their seed-to-seed spread is wider, see
    studies/separation_paper/README.md)."""
    b = _bands("separation_paper_ci")
    assert detectable_factor(b["statistics"]["full_pose.measured.angle_deg.after.mean"], 6, 0.99) < 1.3
    runs = [_worse(r, "full_pose", "angle_deg", 1.3) for r in paper_runs]
    res = check_prediction(runs, b, confidence=PAPER_CONFIDENCE)
    assert "full_pose.measured.angle_deg.after.mean" in {o["statistic"] for o in res["outside"]}


def test_prediction_check_refuses_a_band_seed_and_skips_orderings_on_request():
    """A band seed cannot be checked against a prediction band; ``orderings=False`` checks statistics only."""
    b = _bands("separation_paper_ci")
    with pytest.raises(ValueError, match="band seeds"):
        check_prediction([{"seed": b["seeds"][0], "methods": {}}], b)
    fake = {"seed": 999, "methods": {}, "orderings": []}
    res = check_prediction([fake], b, orderings=False)
    assert res["failed_claims"] == [] and len(res["missing"]) > 0
