"""Regression of the matched Figure 10/11 protocol (studies/separation_paper/separation_matched.toml, truth_noise mode):
seeds that did not build the bands, against prediction bands tight enough to catch a 20 % worsening."""

import copy
import json
from pathlib import Path

import pytest

from _shared import value_once
from twin.runner.campaign import run_repeats
from twin.runner.config import load_campaign_config
from twin.runner.executor import open_executor
from twin.evaluation.regression import check_prediction, detectable_factor
from twin.evaluation.targets import read_targets

ROOT = Path(__file__).resolve().parent.parent
STUDY = ROOT / "studies" / "separation_paper"
CONFIG = STUDY / "separation_matched.toml"
BANDS = STUDY / "results" / "regression.json"
SECTION = "separation_matched"
# Six seeds outside the band seeds (20230601..20230620): the prediction band is for the mean of 6 new seeds
# (with 4, a 20 % worse distance-only angle mean of seeds 20230701-04 stays 3 % under its limit: their mean lies
# 7 % below the band's typical value).
NEW_SEEDS = (20230701, 20230702, 20230703, 20230704, 20230705, 20230706)
# One-sided levels per statistic: the 10 after-means at 99 % (a false alarm for unchanged code in <= 10 % of
# choices of new seeds), the 10 maxima and 10 improvements at 99.9 % (<= 2 % together).
CONFIDENCE = {"mean": 0.99, "max": 0.999, "improvement_percent": 0.999}
METHODS = ("distance", "full_pose", "separation", "separation_paper", "default")
# After-compensation means whose seed-to-seed spread lets 6 new seeds see a 20 % worsening at 99 %
# (detectable_factor < 1.2). Distance-only, separation and paper-literal separation position means spread too much
# (sd of log 0.22-0.41 over the 20 band seeds): no number of new seeds brings them under 1.2 with 20 band seeds.
# Nor does the paper-literal separation's angle mean (x1.26): it takes the camera-to-base rotation from
# dataset.toml, which states the nominal rig, and the rig is placed with error, differently for every seed.
DETECTABLE = ({(m, "angle_deg") for m in METHODS if m != "separation_paper"}
              | {("full_pose", "position_mm"), ("default", "position_mm")})


def _bands():
    data = json.loads(BANDS.read_text())
    assert SECTION in data, f"studies/separation_paper/results/regression.json has no {SECTION} section: run the command in {CONFIG.name}"
    return data[SECTION]


def test_bands_come_from_20_seeds_of_this_config_and_not_the_test_seeds():
    """The bands were made by regression_bands.py on separation_matched.toml over 20 seeds, none a test seed."""
    b = _bands()
    assert "studies/separation_paper/separation_matched.toml" in b["command"] and "--seeds 20" in b["command"]
    assert len(b["seeds"]) == 20 and not set(NEW_SEEDS) & set(b["seeds"])
    assert all(s["n"] == 20 for s in b["statistics"].values())


def test_matched_before_statistics_are_the_papers_within_15_percent():
    """Over the 20 band seeds the 'before' angle and position means are within 15 % of Figure 10's (targets file)."""
    fig10 = read_targets()["simulation"]["figure10"]
    st = _bands()["statistics"]
    for unit in ("angle_deg", "position_mm"):
        ours = st[f"full_pose.measured.{unit}.before.mean"]["mean"]
        paper = fig10[unit]["before"]["mean"]
        assert abs(ours / paper - 1) <= 0.15, (unit, ours, paper)


def test_prediction_bands_see_a_20_percent_worsening_where_the_spread_allows():
    """For the after-means in DETECTABLE a run at the typical value fails when 20 % worse; for the others it would not."""
    st = _bands()["statistics"]
    for m in METHODS:
        for unit in ("angle_deg", "position_mm"):
            f = detectable_factor(st[f"{m}.measured.{unit}.after.mean"], len(NEW_SEEDS), CONFIDENCE["mean"])
            assert (f < 1.2) == ((m, unit) in DETECTABLE), (m, unit, f)


@pytest.fixture(scope="module")
def new_runs(tmp_path_factory):
    """The matched campaign at the six new seeds on two processes, per-seed results (run once per test session)."""
    def make():
        cfg = load_campaign_config(CONFIG)
        with open_executor("process", 2, None) as ex:
            return run_repeats(cfg, tmp_path_factory.mktemp("matched"), list(NEW_SEEDS), ex)["per_seed"]

    return value_once(tmp_path_factory, "regression_matched_new_runs", make)


@pytest.mark.slow
def test_new_seeds_stay_in_the_prediction_bands_and_keep_the_orderings(new_runs):
    """Six new seeds: every after-mean (99 %), after-max and improvement (99.9 %) inside its prediction band, and every ordering
    that held in >= 95 % of the band seeds (paper claims and pairwise method orderings) holds for their pooled
    after-means."""
    res = check_prediction(new_runs, _bands(), confidence=CONFIDENCE)
    assert res["missing"] == [] and res["outside"] == [] and res["failed_claims"] == [], res


def _degraded(runs, method, unit, factor=1.2):
    out = copy.deepcopy(runs)
    for r in out:
        blk = r["methods"][method]["measured"][unit]
        for stat in ("mean", "max", "std", "rms"):
            if blk["after"].get(stat) is not None:
                blk["after"][stat] *= factor
        blk["improvement_percent"] = 100.0 * (1 - blk["after"]["mean"] / blk["before"]["mean"])
    return out


@pytest.mark.slow
@pytest.mark.parametrize("method, unit", sorted(DETECTABLE))
def test_a_20_percent_worse_method_fails_the_bands(new_runs, method, unit):
    """Scaling one method's after-compensation statistics by 1.2 in the new seeds makes the band check fail on
    that method's after-mean."""
    res = check_prediction(_degraded(new_runs, method, unit), _bands(), confidence=CONFIDENCE)
    assert f"{method}.measured.{unit}.after.mean" in {o["statistic"] for o in res["outside"]}, res["outside"]


def test_prediction_check_refuses_a_band_seed():
    """A run whose seed built the bands cannot be checked against a prediction band (it would not be new)."""
    b = _bands()
    with pytest.raises(ValueError, match="band seeds"):
        check_prediction([{"seed": b["seeds"][0], "methods": {}}], b)
