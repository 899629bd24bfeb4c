"""Tests of the blind study's scoring (studies/blind/blind_scoring.py): `twin diagnose` on a campaign folder with
an answer key."""

import csv
import json
import sys
from pathlib import Path

import numpy as np
import pytest

import _diagnosis_helpers as H
from twin.dataset import write_dataset
from twin.estimator.simulate import simulate_dataset

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "studies" / "blind"))
from blind_scoring import read_key, score_campaign, summarise  # noqa: E402
from twin.presets import preset_deviation
from twin.robots import irb1200
from twin.transforms import pose6_to_transform

_COLS = [f"{k}_{c}" for k in range(3) for c in "xyz"]


def _write_campaign(root, *, effect=None, category="clean", expected=(), n=160, n_test=40, seed=3):
    """A blind campaign: the dataset (first n rows, no effect declared, no noise stated) and the key with every
    row (n dataset rows, then n_test test rows), measured, true and effect columns [mm]."""
    rng = np.random.default_rng(seed)
    nominal = irb1200()
    true = nominal.perturbed(preset_deviation("separation_tables_2_4")).with_frames(
        base2meas=pose6_to_transform(np.array([0.2, -0.1, 1.1, 2.0, -0.3, 0.4])))
    q = H.configurations(rng, n + n_test, nominal)
    q_act = q if effect is None else effect(q, nominal)
    ds_eff, tr_eff = simulate_dataset(true, q_act, robot_spec="irb1200", nominal=nominal, noise_position=H.SIGMA,
                                      rng=rng, declare_noise=False)
    _, tr_geo = simulate_dataset(true, q, robot_spec="irb1200", nominal=nominal, rng=rng, declare_noise=False)
    roles = np.array(["validation" if k % 3 == 2 else "calibration" for k in range(n)] + ["test"] * n_test, dtype=object)
    ds = H._replace(ds_eff, q=q, set=roles.copy(), pose_id=np.arange(n + n_test))
    write_dataset(root / "dataset", ds.subset(np.arange(n)))
    (root / "key").mkdir(parents=True)
    (root / "key" / "key.json").write_text(json.dumps({
        "schema_version": 1, "name": root.name, "category": category, "expected_names": list(expected),
        "effects": [] if effect is None else [{"family": expected[0] if expected else None, "description": "test",
                                               "joints": [2], "links": [], "place": "joint", "channel": "q2"}]}))
    with open(root / "key" / "sequence.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["pose_id"] + [f"q{j}" for j in range(1, 7)] + ["role"] + [f"{p}{c}" for p in "mte" for c in _COLS])
        for k in range(n + n_test):
            m, t, e = ds_eff.spheres[k], tr_eff["spheres"][k], tr_eff["spheres"][k] - tr_geo["spheres"][k]
            w.writerow([k, *np.rad2deg(q[k]), roles[k], *(m.ravel() * 1e3), *(t.ravel() * 1e3), *(e.ravel() * 1e3)])
    return root


def test_read_key_refuses_an_unknown_category(tmp_path):
    """A key whose category is not clean/catalogue/outside/mixed is refused, naming the value."""
    root = _write_campaign(tmp_path / "c", n=30, n_test=5)
    meta = json.loads((root / "key" / "key.json").read_text())
    meta["category"] = "weird"
    (root / "key" / "key.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="'weird'"):
        read_key(root)


@pytest.mark.slow
def test_score_of_a_named_effect_and_of_a_clean_campaign(tmp_path):
    """A cyclic error on joint 2 is named (exactly), traced and within 1.3x of the oracle on the test block, scored
    on the diagnosis' report rows; a clean campaign raises no alarm; the summary counts both; the command run in this
    process scores as on the command line."""
    eff = _write_campaign(tmp_path / "cyc", effect=H.cyclic(amp_deg=0.01, joint=2, k=2), category="catalogue",
                          expected=("cyclic",))
    clean = _write_campaign(tmp_path / "clean", seed=4)
    r_eff = score_campaign(eff, tmp_path / "out_cyc")
    r_clean = score_campaign(clean, tmp_path / "out_clean", in_process=True)
    assert r_eff["structured"] and r_eff["named_right"] and r_eff["trace"]["all_traced"] and r_eff["extra_names"] == []
    d = json.loads((tmp_path / "out_cyc" / "diagnosis" / "diagnosis.json").read_text())
    assert r_eff["report"]["after"]["n"] == 3 * len(d["held_out"]["report_pose_ids"])  # 3 spheres per report row
    assert r_eff["test"]["before_over_oracle"] > 2.0
    assert r_eff["test"]["after_over_oracle"] < 1.3
    assert not r_clean["structured"]
    assert r_clean["test"]["after"]["rms"] == pytest.approx(r_clean["test"]["before"]["rms"])
    s = summarise([r_eff, r_clean])
    assert s["catalogue"]["named_right"] == 1 and s["clean"]["structured"] == 0
