"""Rows of two robots mixed in one campaign (``twin.estimator.mixture``): the split is found on robots, mixes and
shares drawn at random, told from one robot's backlash and from a second measurement frame, and said by `twin
calibrate` and `twin diagnose`."""

import json
import warnings

import numpy as np
import pytest

import _newcomer_chain as C
from twin.estimator import calibrate
from twin.estimator.mixture import split_rows, two_models

NOISE_MM = C.MIXED_NOISE_MM


def _split(folder, seed: int, second: str, blocks: bool = False):
    """A drawn mixed campaign (``_newcomer_chain.mixed_campaign``), calibrated and split: ``(dataset, labels, split)``."""
    ds, is_b = C.mixed_campaign(folder, seed, second=second, blocks=blocks)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return ds, is_b, split_rows(calibrate(ds), ds)


@pytest.mark.parametrize("seed", range(4))
def test_two_linear_models_are_separated_whatever_their_share(seed):
    """Two regressions drawn at random (rows, parameters, share, size): the assignment found puts at least 98 % of
    the rows with their own model and its cost is the noise's."""
    rng = np.random.default_rng(100 + seed)
    n, k, p = int(rng.integers(60, 200)), 3, int(rng.integers(4, 12))
    J = rng.normal(size=(n * k, p))
    row = np.repeat(np.arange(n), k)
    second = rng.random(n) < rng.uniform(0.2, 0.8)
    a, b = rng.normal(0, rng.uniform(5, 50), p), rng.normal(0, rng.uniform(5, 50), p)
    r = np.where(second[row], J @ b, J @ a) + rng.normal(size=n * k)
    tm = two_models(r, J, row, n, seed=seed)
    agree = max(np.mean(tm.second == second), np.mean(tm.second != second))
    assert agree >= 0.98
    assert tm.cost_two < 2.0 * n * k < tm.cost_one


def test_one_model_away_from_the_residuals_point_is_not_two_models():
    """Rows of one linear model whose parameters are not where the residuals were taken (r = J a + noise): the one
    model refitted on every row leaves the noise, and two models take no more than a selection can (under half)."""
    rng = np.random.default_rng(7)
    n, k, p = 150, 3, 8
    J = rng.normal(size=(n * k, p))
    row = np.repeat(np.arange(n), k)
    r = J @ rng.normal(0, 30, p) + rng.normal(size=n * k)
    tm = two_models(r, J, row, n, min_rows=10)
    assert tm.cost_one < 1.2 * (n * k - p) and tm.cost_two > 0.5 * tm.cost_one


def test_two_models_refuses_residuals_and_jacobians_that_disagree():
    """Residuals, Jacobian rows and row indices of different lengths are a ValueError naming them."""
    with pytest.raises(ValueError, match="r \\(m,\\), J \\(m, p\\) and row"):
        two_models(np.zeros(6), np.zeros((5, 2)), np.zeros(6, int), 2)


@pytest.mark.parametrize("seed", range(3))
def test_rows_of_two_robots_mixed_are_split_and_named(seed, tmp_path):
    """Rows of two robots as built (a drawn chain, share and order; interleaved, or in two blocks): the split finds the
    two groups (>= 95 % of the rows with their own robot), each fitted to within 3x the noise, and names two robots,
    not a joint or a frame."""
    ds, is_b, s = _split(tmp_path, 10 + seed, "robot", blocks=seed == 2)
    assert s.found and s.kind == "robots", s
    assert max(s.rms_two_mm) <= 3 * NOISE_MM < s.rms_one_mm / 5
    assert C.split_agreement(s.groups, ds.pose_id, is_b) >= 0.95
    assert "two robots" in s.text


@pytest.mark.parametrize("seed", range(2))
def test_one_robots_backlash_is_not_called_two_robots(seed, tmp_path):
    """One robot with backlash on a drawn joint: its rows differ by that joint's flank, so the split, where found,
    names one parameter, never two robots."""
    ds, _, s = _split(tmp_path, 20 + seed, "backlash")
    assert s.kind != "robots", s.text


@pytest.mark.parametrize("seed", range(2))
def test_a_knocked_instrument_is_named_a_second_frame(seed, tmp_path):
    """One robot seen from two instrument places interleaved (a drawn knock): found and named the measurement frame."""
    ds, is_b, s = _split(tmp_path, 30 + seed, "frame")
    assert s.found and s.kind == "frames", s
    assert C.split_agreement(s.groups, ds.pose_id, is_b) >= 0.95


@pytest.mark.parametrize("seed", range(2))
def test_one_robot_within_its_noise_is_not_split(seed, tmp_path):
    """A campaign of one robot as built (a drawn chain and rows): no split is reported (two models cannot do better
    than the noise)."""
    _, _, s = _split(tmp_path, 60 + seed, "none")
    assert not s.found, s.text


def test_split_rows_refuses_a_noise_that_is_not_a_positive_number(tmp_path):
    """noise_m of zero is a ValueError naming noise_m and its value."""
    ds, _ = C.mixed_campaign(tmp_path, 40, second="robot")
    with pytest.raises(ValueError, match="noise_m must be a positive number \\[m\\], got 0.0"):
        split_rows(None, ds, noise_m=0.0)


def test_calibrate_and_diagnose_say_the_rows_are_two_robots(tmp_path):
    """`twin calibrate` and `twin diagnose` on rows of two robots mixed: each prints the split with its groups'
    pose_ids and writes it (calibration.json's details.beyond_geometry.two_groups, diagnosis.json's two_groups)."""
    C.mixed_campaign(tmp_path, 50, second="robot")
    cal = C.twin(["calibrate", tmp_path / "ds", "--out", tmp_path / "cal"])
    assert cal.code == 0, cal.err
    assert "two robots mixed in one campaign" in cal.out
    beyond = json.loads((tmp_path / "cal" / "calibration.json").read_text())["details"]["beyond_geometry"]
    assert beyond["two_groups"]["found"] and beyond["two_groups"]["kind"] == "robots"
    dg = C.twin(["diagnose", tmp_path / "ds", "--out", tmp_path / "diag", "--no-plots", "--no-recording"])
    assert dg.code == 0, dg.err
    assert "two robots mixed in one campaign" in dg.out
    assert json.loads((tmp_path / "diag" / "diagnosis.json").read_text())["two_groups"]["found"]


@pytest.mark.parametrize("seed", [60, 61])
def test_diagnose_splits_a_second_robots_rows_appended_after_the_rows_it_fits(seed, tmp_path):
    """A second robot's file appended to the first's, its rows (a drawn 10-22 %) all after the rows the diagnosis
    fits its geometric model on: `twin diagnose` still finds the two robots and puts >= 95 % of every row with its
    own robot (the split looks at every row, not only the calibration rows)."""
    ds, is_b = C.mixed_campaign(tmp_path, seed, second="robot", blocks=True, share=(0.1, 0.22))
    dg = C.twin(["diagnose", tmp_path / "ds", "--out", tmp_path / "diag", "--no-plots", "--no-recording"])
    assert dg.code == 0, dg.err
    rows = json.loads((tmp_path / "diag" / "calibration_geometric.json").read_text())["rows"]
    fitted = set(rows["calibration_used"]) | {r["pose_id"] for r in rows.get("calibration_rejected", [])}
    assert not fitted & set(ds.pose_id[is_b].tolist()), "the case needs the second robot outside the fitted rows"
    g = json.loads((tmp_path / "diag" / "diagnosis.json").read_text())["two_groups"]
    assert g["found"] and g["kind"] == "robots", g
    assert C.split_agreement(g["groups"], ds.pose_id, is_b) >= 0.95


def test_split_rows_refuses_pose_ids_the_dataset_lacks(tmp_path):
    """pose_ids naming a row the dataset does not hold is a ValueError naming pose_ids and the row."""
    ds, _ = C.mixed_campaign(tmp_path, 41, second="robot")
    with pytest.raises(ValueError, match=r"pose_ids: 1 not in the dataset \(first \[999999\]\)"):
        split_rows(None, ds, pose_ids=[int(ds.pose_id[0]), 999999])
