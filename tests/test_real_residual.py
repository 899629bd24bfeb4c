"""Tests of the real-residual study (studies/real_residual): the real-protocol residual scan."""

import json
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from studies.real_residual.realresidual import (EffectMagnitudes, aggregate_seeds, campaign_raw, judge,  # noqa: E402
                                               paper_real_targets, run_real_protocol, scan_point)
from twin.evaluation.targets import read_targets  # noqa: E402
from twin.runner.config import parse_campaign_config  # noqa: E402

BASE = tomllib.loads((ROOT / "studies" / "real_residual" / "separation_real.toml").read_text())
PAPER = paper_real_targets(read_targets())


def _scaled(ratios: dict) -> dict:
    """The paper's statistics, each mean multiplied by ``ratios[(unit, phase)]`` (1 when absent)."""
    return {u: {ph: {s: v * ratios.get((u, ph), 1.0) if s == "mean" else v for s, v in PAPER[u][ph].items()}
                for ph in PAPER[u]} for u in PAPER}


def test_paper_real_targets_come_from_the_targets_file():
    """The four judged means are the targets file's Figures 13/15 entries."""
    t = read_targets()["real"]
    assert PAPER["angle_deg"]["before"]["mean"] == t["figure13"]["angle_deg"]["before"]["mean"]
    assert PAPER["position_mm"]["after"]["mean"] == t["figure15"]["position_mm"]["after"]["mean"]


def test_judge_consistent_when_all_four_means_are_within_tolerance():
    """Every mean 15 % off (either side) is consistent at 20 %."""
    twin = _scaled({("angle_deg", "before"): 1.15, ("angle_deg", "after"): 0.85, ("position_mm", "before"): 1.15,
                    ("position_mm", "after"): 0.85})
    v = judge(twin, PAPER, tol=0.2)
    assert v["consistent"] and not v["reasons"] and all(c["within"] for c in v["checks"])


@pytest.mark.parametrize("unit, phase", [("angle_deg", "before"), ("angle_deg", "after"), ("position_mm", "before"),
                                         ("position_mm", "after")])
def test_judge_rules_out_when_any_one_mean_misses(unit, phase):
    """One mean 25 % off (the other three exact) rules the combination out, naming that statistic."""
    v = judge(_scaled({(unit, phase): 1.25}), PAPER, tol=0.2)
    assert not v["consistent"]
    assert len(v["reasons"]) == 1 and v["reasons"][0].startswith(f"{unit.split('_')[0]} {phase} mean")


def test_aggregate_seeds_gives_seed_mean_and_spread():
    """Two seeds' means 1 and 3 aggregate to mean 2, sample std sqrt(2)."""
    one = {"m": {u: {ph: {"mean": 1.0, "max": 2.0, "std": 0.5} for ph in ("before", "after")}
                 for u in ("angle_deg", "position_mm")}}
    two = json.loads(json.dumps(one))
    two["m"]["angle_deg"]["after"]["mean"] = 3.0
    a = aggregate_seeds([one, two])["m"]["angle_deg"]["after"]["mean"]
    assert a["mean"] == pytest.approx(2.0) and a["std"] == pytest.approx(np.sqrt(2.0)) and a["n"] == 2


def test_scan_point_judges_the_seed_mean_of_the_judged_method():
    """A point whose seeds average to the paper's figures is consistent for the judged method only."""
    def fake(base, mag, seed, methods):
        f = 0.9 if seed == 1 else 1.1  # seed-mean exactly the paper's
        return {"a": _scaled({(u, ph): f for u in PAPER for ph in ("before", "after")}),
                "b": _scaled({("angle_deg", "after"): 2.0})}

    p = scan_point(BASE, EffectMagnitudes(), [1, 2], PAPER, methods=("a", "b"), run=fake)
    assert p["verdict"]["consistent"] and p["verdicts"]["a"]["consistent"]
    assert not p["verdicts"]["b"]["consistent"]


def test_campaign_raw_puts_the_magnitudes_in_the_world():
    """Noise, repeatability, backlash, compliance, thermal and extra geometry reach a valid campaign config."""
    mag = EffectMagnitudes(noise_mm=0.05, repeatability_mm=0.02, backlash_deg=0.01, compliance_softness=2.0,
                           thermal_rise_k=5.0, extra_length_mm=0.3, extra_angle_deg=0.02)
    raw = campaign_raw(BASE, mag, 7, ("separation",))
    cfg = parse_campaign_config(raw)
    assert cfg.measurement.mode == "truth_noise" and cfg.measurement.noise_position == pytest.approx(0.05e-3)
    names = [e["name"] for e in raw["world"]["effects"]]
    assert names == ["repeatability", "backlash", "thermal", "compliance"]
    rep = raw["world"]["effects"][0]
    assert rep["seed"] == 7 and 1e-4 < rep["sigma_deg"] < 1e-2
    assert raw["world"]["random_errors"] == {"length_sigma_mm": 0.3, "angle_sigma_deg": 0.02}
    assert "effects" not in BASE["world"]  # the protocol itself is untouched


def test_effect_magnitudes_reject_negative_sizes():
    """A negative magnitude is refused, naming the field."""
    with pytest.raises(ValueError, match="backlash_deg"):
        EffectMagnitudes(backlash_deg=-0.01)


@pytest.mark.slow
def test_zero_effects_reproduce_the_geometric_only_real_protocol():
    """With no effects and near-zero noise, the campaign seed gives the committed images run's 'before' means on the
    world's truth (same plan, same Table 6 truth, no instrument) and leaves almost nothing after separation."""
    ref = json.loads((ROOT / "studies" / "real_residual" / "results" / "separation_real" / "results.json").read_text())
    want = ref["methods"]["separation"]["truth"]
    got = run_real_protocol(BASE, EffectMagnitudes(noise_mm=0.001), int(ref["seed"]), ("separation",))["separation"]
    for u in ("angle_deg", "position_mm"):
        assert got[u]["before"]["mean"] == pytest.approx(want[u]["before"]["mean"], rel=0.05)
        assert got[u]["after"]["mean"] < 0.05 * got[u]["before"]["mean"]
