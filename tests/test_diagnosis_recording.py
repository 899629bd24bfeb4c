"""Tests of the diagnosis recording (``twin diagnose`` -> DIR/diagnosis.rrd), read back with rerun.chunk.RrdReader."""

import numpy as np
import pytest

import _diagnosis_helpers as H
from twin.cli import main
from twin.dataset import read_dataset, write_dataset
from twin.diagnosis import read_diagnosis
from twin.evaluation.recording import read_recording, record_diagnosis
from _recording_helpers import column  # tests/ is on sys.path under pytest


N_POSES = 80
T_S = np.linspace(0.0, 3600.0, N_POSES)


def _scalars(ents, path):
    return np.ravel(column(ents[path], "Scalars:scalars")).astype(float)


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory):
    """A backlash dataset with a time channel diagnosed through the CLI (plots skipped, recording on)."""
    root = tmp_path_factory.mktemp("diagrec")
    ds, _ = H.make_dataset(seed=7, n=N_POSES, effect=H.backlash(), t_s=T_S)
    write_dataset(root / "ds", ds)
    assert main(["diagnose", str(root / "ds"), "--out", str(root / "out"), "--no-plots"]) == 0
    ds = read_dataset(root / "ds")
    return ds, read_diagnosis(root / "out" / "diagnosis.json"), read_recording(root / "out" / "diagnosis.rrd")


def test_diagnosis_recording_has_the_documented_entity_paths(diagnosed):
    """The recording holds the residual series, the floor, the variables, the verdict document and the log."""
    _, _, ents = diagnosed
    for p in ("/diagnosis/residual/before", "/diagnosis/residual/after", "/diagnosis/residual/noise_floor",
              *(f"/diagnosis/variables/q_deg/q{j}" for j in range(1, 7)),
              *(f"/diagnosis/variables/approach_sign/j{j}" for j in range(1, 7)),
              "/diagnosis/variables/t_s", "/diagnosis/verdict", "/diagnosis/log"):
        assert p in ents, p
    assert "/diagnosis/variables/temp_c" not in ents  # not recorded in this dataset: not invented


def _held_out_rows(ds, d):
    """Dataset rows ``(k,)`` of the diagnosis' held-out block (confirmation and report rows), in order."""
    return np.flatnonzero(np.isin(ds.pose_id, d["rows"]["report"] + d["rows"]["confirmation"]))


def test_before_after_series_have_one_value_per_held_out_row(diagnosed):
    """Before/after/floor series hold one value per held-out row (confirmation and report rows, the diagnosis' block
    of time), on the pose timeline at the dataset row; before/after count the report rows."""
    ds, d, ents = diagnosed
    val_rows = _held_out_rows(ds, d)
    assert d["before"]["n_rows"] == d["held_out"]["n_report_rows"] == len(d["rows"]["report"])
    assert val_rows.size == len(d["rows"]["report"]) + len(d["rows"]["confirmation"])
    for name in ("before", "after", "noise_floor"):
        assert _scalars(ents, f"/diagnosis/residual/{name}").size == val_rows.size, name
    poses = column(ents["/diagnosis/residual/before"], "pose")
    np.testing.assert_array_equal(poses, val_rows)


def test_each_term_of_the_extended_model_is_plotted_per_held_out_row(diagnosed):
    """One terms/term<k> series per atom of diagnosis.json, one value per validation row; a backlash term
    takes two values (the clearance signed by the approach direction, 0 where the approach is unknown)."""
    ds, d, ents = diagnosed
    n_val = _held_out_rows(ds, d).size
    assert len(d["atoms"]) >= 1
    for k, a in enumerate(d["atoms"]):
        v = _scalars(ents, f"/diagnosis/terms/term{k + 1}")
        assert v.size == n_val
        if a["family"] == "backlash":
            assert len(set(np.round(np.abs(v[v != 0]), 9))) == 1


def test_series_values_agree_with_diagnosis_json(diagnosed):
    """The floor equals diagnosis.json's; the per-row RMS series of the report rows pool to its before/after
    position RMS."""
    ds, d, ents = diagnosed
    floor = _scalars(ents, "/diagnosis/residual/noise_floor")
    assert np.all(floor == d["noise_floor"]["position_mm"])
    rows = column(ents["/diagnosis/residual/before"], "pose")
    report = np.isin(ds.pose_id[rows], d["held_out"]["report_pose_ids"])
    assert report.sum() == d["before"]["n_rows"]
    for tag in ("before", "after"):
        e = _scalars(ents, f"/diagnosis/residual/{tag}")[report]
        # per row: RMS over the 9 sphere coordinates; diagnosis.json: RMS over spheres of the 3-D error norm
        assert np.sqrt(3.0 * np.mean(e**2)) == pytest.approx(d[tag]["position_mm"]["rms"], rel=1e-9), tag
    assert d["effects"] == ["backlash"]
    assert np.mean(_scalars(ents, "/diagnosis/residual/after")) < 0.5 * np.mean(_scalars(ents, "/diagnosis/residual/before"))


def test_variable_timelines_place_each_row_at_its_joint_angle(diagnosed):
    """On the q2_mdeg timeline each residual sits at its row's commanded q2 (the residual-vs-variable plot)."""
    ds, d, ents = diagnosed
    val_rows = _held_out_rows(ds, d)
    q2 = column(ents["/diagnosis/residual/before"], "q2_mdeg")
    np.testing.assert_array_equal(q2, np.round(np.rad2deg(ds.q[val_rows, 1]) * 1e3).astype(int))
    np.testing.assert_allclose(_scalars(ents, "/diagnosis/variables/t_s"), ds.t_s[val_rows])


def test_text_log_and_verdict_hold_structured_p_value_and_effects(diagnosed):
    """The text log's first line and the verdict document state structured, p_value and the effects of diagnosis.json."""
    _, d, ents = diagnosed
    texts = np.ravel(column(ents["/diagnosis/log"], "TextLog:text")).tolist()
    assert texts[0] == f"structured=True p_value={d['p_value']} effects=backlash"
    doc = np.ravel(column(ents["/diagnosis/verdict"], "TextDocument:text")).tolist()[0]
    assert "structured: **True**" in doc and "effects: **backlash**" in doc


def test_no_recording_flag_skips_the_file(tmp_path):
    """twin diagnose --no-recording writes diagnosis.json but no .rrd."""
    ds, _ = H.make_dataset(seed=2, n=40)
    write_dataset(tmp_path / "ds", ds)
    assert main(["diagnose", str(tmp_path / "ds"), "--out", str(tmp_path / "out"), "--no-plots", "--no-recording"]) == 0
    assert (tmp_path / "out" / "diagnosis.json").exists()
    assert not (tmp_path / "out" / "diagnosis.rrd").exists()


def test_record_diagnosis_rejects_incomplete_input(tmp_path):
    """Missing series keys, mismatched lengths, non-finite values or a missing floor raise ValueError naming the problem."""
    s = {"dataset_row": np.arange(3), "residual_rms_mm_before": np.ones(3), "residual_rms_mm_after": np.ones(3),
         "q_deg": np.zeros((3, 6))}
    v = {"structured": False, "p_value": 0.5, "effects": [], "noise_floor": {"position_mm": 0.005}}
    with pytest.raises(ValueError, match="residual_rms_mm_after"):
        record_diagnosis(tmp_path / "a.rrd", {k: s[k] for k in s if k != "residual_rms_mm_after"}, v)
    with pytest.raises(ValueError, match="shapes disagree"):
        record_diagnosis(tmp_path / "b.rrd", {**s, "residual_rms_mm_before": np.ones(4)}, v)
    with pytest.raises(ValueError, match="noise_floor"):
        record_diagnosis(tmp_path / "c.rrd", s, {**v, "noise_floor": {}})
    with pytest.raises(ValueError, match=r"series\['q_deg'\] holds non-finite values \(row 1\)"):
        record_diagnosis(tmp_path / "e.rrd", {**s, "q_deg": np.where(np.arange(3)[:, None] == 1, np.nan, 0.0) * np.ones((3, 6))}, v)
    with pytest.raises(ValueError, match=r"series\['t_s'\] must have shape"):
        record_diagnosis(tmp_path / "f.rrd", {**s, "t_s": np.zeros(2)}, v)
    assert record_diagnosis(tmp_path / "d.rrd", s, v).exists()
