"""Regression of the Figure 10/11 statistics: one seed of the CI campaign against the bands over 20 seeds.

These are the loose ``minmax`` bands (they contain every band seed): they catch a broken pipeline, not a 20 %
worsening of one method. tests/test_regression_matched.py tests new seeds of the matched protocol against
prediction bands that do catch it (where the seed-to-seed spread allows)."""

import json
from pathlib import Path

import pytest

from twin.runner.campaign import run_campaign
from twin.runner.config import load_campaign_config
from twin.evaluation.regression import check_against_bands, tracked_statistics

ROOT = Path(__file__).resolve().parent.parent
STUDY = ROOT / "studies" / "separation_paper"
CONFIG = STUDY / "separation_ci.toml"
BANDS = STUDY / "results" / "regression.json"


def _bands():
    data = json.loads(BANDS.read_text())
    assert "separation_ci" in data, "studies/separation_paper/results/regression.json has no separation_ci section: run the command in docs/runner.md"
    return data["separation_ci"]


def test_regression_file_records_its_command_and_enough_seeds():
    """The bands say how they were made and come from at least 20 seeds of this very config."""
    b = _bands()
    assert "studies/separation_paper/separation_ci.toml" in b["command"] and "--seeds" in b["command"]
    assert len(b["seeds"]) >= 20
    assert all(s["n"] >= 20 for s in b["statistics"].values())


def test_band_check_flags_a_shifted_statistic():
    """The check itself fails a statistic moved far outside its band (so the regression test can fail)."""
    b = _bands()
    name, band = next(iter(b["statistics"].items()))
    method, source, unit, phase, stat = name.split(".")
    fake = {"methods": {method: {source: {unit: {phase: {stat: band["max"] + 10 * band["std"] + 1.0}}}}}, "orderings": []}
    res = check_against_bands(fake, b)
    assert [o["statistic"] for o in res["outside"]] == [name]


@pytest.mark.slow
def test_one_seed_of_the_ci_campaign_stays_in_the_bands(tmp_path):
    """Seed 1 of studies/separation_paper/separation_ci.toml (rendered, measured, four methods) falls inside every band, and
    every ordering claim that held in >= 95 % of the band seeds holds."""
    b = _bands()
    cfg = load_campaign_config(CONFIG).with_seed(b["seeds"][0])
    run = run_campaign(cfg, tmp_path / "ci", recording=False, figures=False)
    assert run.results["methods_unavailable"] == {}
    res = check_against_bands(run.results, b)
    assert res["missing"] == [], f"statistics missing from the run: {res['missing']}"
    assert res["outside"] == [], f"outside the regression bands: {res['outside']}"
    assert res["failed_claims"] == [], f"paper orderings that held in >= 95 % of seeds failed: {res['failed_claims']}"
    assert len(tracked_statistics(run.results["methods"])) == len(b["statistics"])


PAPER_CONFIG = STUDY / "separation_paper_ci.toml"
OUTSIDE_SEED = 101  # not among the seeds that built the bands (1..20)


def _paper_bands():
    data = json.loads(BANDS.read_text())
    assert "separation_paper_ci" in data, "studies/separation_paper/results/regression.json has no separation_paper_ci section: run docs/runner.md's command"
    return data["separation_paper_ci"]


@pytest.fixture(scope="module")
def paper_mode_run(tmp_path_factory):
    """One campaign of studies/separation_paper/separation_paper_ci.toml (true centres + noise, no rendering), seed 101."""
    cfg = load_campaign_config(PAPER_CONFIG).with_seed(OUTSIDE_SEED)
    return run_campaign(cfg, tmp_path_factory.mktemp("paper_ci") / "run", recording=False, figures=False)


def test_paper_mode_bands_come_from_other_seeds():
    """The paper-mode bands come from >= 20 seeds, none of them the seed the regression test runs."""
    b = _paper_bands()
    assert len(b["seeds"]) >= 20 and OUTSIDE_SEED not in b["seeds"]


def test_paper_mode_seed_outside_the_bands_seeds_stays_in_the_bands(paper_mode_run):
    """A seed that did not build the bands (paper measurement mode, five methods incl. separation_paper) falls
    inside every band, and every ordering that held in >= 95 % of the band seeds holds."""
    b = _paper_bands()
    assert paper_mode_run.results["methods_unavailable"] == {}
    res = check_against_bands(paper_mode_run.results, b)
    assert res["missing"] == [] and res["outside"] == [] and res["failed_claims"] == [], res
