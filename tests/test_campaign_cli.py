"""The `twin campaign` command: a small truth_noise campaign from a TOML file, table printed, files written."""

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _campaign_helpers import SMALL_TOML  # noqa: E402

from twin.cli import main


def test_twin_campaign_prints_the_comparison_and_writes_results(tmp_path, capsys):
    """`twin campaign CONFIG --out DIR` prints both tables with the paper's row and writes results.json."""
    cfg = tmp_path / "small.toml"
    cfg.write_text(SMALL_TOML.replace('methods = ["full_pose"]', 'methods = ["full_pose", "separation"]'))
    assert main(["campaign", str(cfg), "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "angle error (deg)" in out and "moved-distance error (mm)" in out and "paper (Fig. 10)" in out
    res = json.loads((tmp_path / "out" / "results.json").read_text())
    assert set(res["methods"]) == {"full_pose", "separation"} and res["counts"]["poses"] == 40
    assert (tmp_path / "out" / "table.txt").read_text().count("paper (Fig. 10)") == 1


def test_twin_campaign_names_a_bad_key(tmp_path, capsys):
    """A config with a misspelt key fails with exit code 2 and a message naming the key."""
    cfg = tmp_path / "bad.toml"
    cfg.write_text(SMALL_TOML.replace("[measurement]", "[measurement]\nnoise_mn = 1"))
    assert main(["campaign", str(cfg), "--out", str(tmp_path / "out")]) == 2
    assert "measurement.noise_mn" in capsys.readouterr().err


def test_twin_campaign_repeats_writes_mean_and_spread(tmp_path, capsys):
    """`--repeats 2` runs two seeds and writes repeats.json with every statistic's mean and spread."""
    cfg = tmp_path / "small.toml"
    cfg.write_text(SMALL_TOML)
    assert main(["campaign", str(cfg), "--out", str(tmp_path / "mc"), "--repeats", "2"]) == 0
    rep = json.loads((tmp_path / "mc" / "repeats.json").read_text())
    assert rep["seeds"] == [7, 8] and len(rep["per_seed"]) == 2
    s = rep["statistics"]["methods.full_pose.measured.angle_deg.after.mean"]
    assert s["n"] == 2 and s["min"] <= s["mean"] <= s["max"]
    assert "full_pose: angle_deg: mean" in capsys.readouterr().out
