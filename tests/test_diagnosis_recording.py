"""Tests of the diagnosis recording (``twin diagnose`` -> DIR/diagnosis.rrd), read back with rerun.chunk.RrdReader."""

import re

import numpy as np
import pytest

import _diagnosis_helpers as H
from twin.cli import main
from twin.dataset import read_dataset, write_dataset
from twin.diagnosis import read_diagnosis
from twin.estimator import Calibration
from twin.evaluation.recording import read_recording, record_diagnosis
from twin.evaluation.workspace import size_colours
from twin.kinematics import flange2base
from twin.units import MM_PER_M
from _recording_helpers import column  # tests/ is on sys.path under pytest


N_POSES = 80
T_S = np.linspace(0.0, 3600.0, N_POSES)


def _scalars(ents, path):
    return np.ravel(column(ents[path], "Scalars:scalars")).astype(float)


@pytest.fixture(scope="module")
def diagnosed_folder(tmp_path_factory):
    """A backlash dataset with a time channel diagnosed through the CLI (plots skipped, recording on): the folder."""
    root = tmp_path_factory.mktemp("diagrec")
    ds, _ = H.make_dataset(seed=7, n=N_POSES, effect=H.backlash(), t_s=T_S)
    write_dataset(root / "ds", ds)
    assert main(["diagnose", str(root / "ds"), "--out", str(root / "out"), "--no-plots"]) == 0
    return root


@pytest.fixture(scope="module")
def diagnosed(diagnosed_folder):
    """The diagnosed dataset, diagnosis.json and the recording's chunks by entity path."""
    root = diagnosed_folder
    ds = read_dataset(root / "ds")
    return ds, read_diagnosis(root / "out" / "diagnosis.json"), read_recording(root / "out" / "diagnosis.rrd")


@pytest.fixture(scope="module")
def blocked_geometric(diagnosed_folder):
    """The geometric model fitted on the calibration rows, as twin diagnose wrote it (the robot the recording draws)."""
    return Calibration.load(diagnosed_folder / "out" / "calibration_geometric_blocked.json")


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


# --- the workspace: the robot, the measured points and the residual vectors in the measurement frame -------------

WS = "/diagnosis/workspace"


def _rgb(packed):
    """Rerun's packed 0xRRGGBBAA colours as ``(n, 3)`` RGB."""
    c = np.asarray(packed, dtype=np.uint64)
    return np.stack([(c >> 24) & 255, (c >> 16) & 255, (c >> 8) & 255], axis=-1).astype(np.uint8)


def _legend(ents):
    """The legend document and the arrow scale and top of the colour map it states."""
    text = np.ravel(column(ents[f"{WS}/legend"], "TextDocument:text")).tolist()[0]
    scale = float(re.search(r"\*\*arrows x([0-9.e+-]+)\*\*", text).group(1))
    top = float(re.search(r"red ([0-9.e+-]+) mm and beyond", text).group(1))
    return text, scale, top


def test_workspace_entities_are_recorded(diagnosed):
    """The recording holds the robot, its joints and tool lines, the measured points, the arrows before/after, the
    maps before/after, the base, the scale arrow and the legend; the legend states the frame and the arrow scale."""
    _, _, ents = diagnosed
    for p in ("robot", "robot/joints", "robot/tool", "measured", "arrows/before", "arrows/after", "map/before",
              "map/after", "base", "scale", "legend"):
        assert f"{WS}/{p}" in ents, p
    text, scale, top = _legend(ents)
    assert "measurement frame of station" in text and scale >= 1 and top > 0
    label = np.ravel(column(ents[f"{WS}/scale"], "Arrows3D:labels")).tolist()[0]
    assert label == f"{top:g} mm, red (arrows x{scale:g})"
    vec = np.asarray(column(ents[f"{WS}/scale"], "Arrows3D:vectors")[0], dtype=float)
    assert np.linalg.norm(vec) == pytest.approx(top / MM_PER_M * scale, rel=1e-6)


def test_skeleton_per_held_out_row_ends_at_the_calibrated_flange(diagnosed, blocked_geometric):
    """One skeleton per held-out row (fewer than the cap) on the pose timeline, base + 6 joint frames, ending at the
    flange of calibration_geometric_blocked.json's forward kinematics in the measurement frame."""
    ds, d, ents = diagnosed
    rows = _held_out_rows(ds, d)
    np.testing.assert_array_equal(column(ents[f"{WS}/robot"], "pose"), rows)
    strips = [np.asarray(x[0], dtype=float) for x in column(ents[f"{WS}/robot"], "LineStrips3D:strips")]
    assert len(strips) == rows.size and all(s.shape == (7, 3) for s in strips)
    station = str(ds.station[rows[0]]) if ds.station is not None else blocked_geometric.stations[0]
    model = blocked_geometric.model(station)
    flange = (model.base2meas @ flange2base(model, ds.q[rows]))[:, :3, 3]
    np.testing.assert_allclose(np.array([s[-1] for s in strips]), flange, atol=1e-6)  # float32 in the file
    np.testing.assert_allclose(np.array([s[0] for s in strips]), np.broadcast_to(model.base2meas[:3, 3], flange.shape),
                               atol=1e-6)


def test_arrows_are_the_residual_vectors_at_the_stated_scale(diagnosed, blocked_geometric):
    """Arrows start at the row's measured points (3 spheres seen); divided by the stated scale their per-row RMS
    is the plotted residual, before and after; their colour is their size on the colour map."""
    ds, d, ents = diagnosed
    rows = _held_out_rows(ds, d)
    _, scale, top = _legend(ents)
    origins = [np.asarray(x, dtype=float) for x in column(ents[f"{WS}/arrows/before"], "Arrows3D:origins")]
    assert [len(o) for o in origins] == list(ds.sphere_seen[rows].sum(axis=1))
    np.testing.assert_allclose(np.concatenate(origins), ds.spheres[rows][ds.sphere_seen[rows]], atol=1e-6)
    for tag in ("before", "after"):
        vec = [np.asarray(x, dtype=float) / scale for x in column(ents[f"{WS}/arrows/{tag}"], "Arrows3D:vectors")]
        rms_mm = np.array([np.sqrt(np.mean(v**2)) for v in vec]) * MM_PER_M
        np.testing.assert_allclose(rms_mm, _scalars(ents, f"/diagnosis/residual/{tag}"), rtol=1e-5)
        colours = _rgb(np.concatenate(column(ents[f"{WS}/arrows/{tag}"], "Arrows3D:colors")))
        size = np.linalg.norm(np.concatenate(vec), axis=1) * MM_PER_M
        assert np.mean(np.all(np.abs(colours.astype(int) - size_colours(size, top)) <= 1, axis=1)) == 1.0


def test_before_arrows_point_from_the_geometric_prediction_to_the_measurement(diagnosed, blocked_geometric):
    """The before arrows are measured minus predicted: they agree with the measured points minus the prediction of
    calibration_geometric_blocked.json to within the difference of the two geometric fits (the diagnosis refits the
    geometry with its gross rows down-weighted): the RMS of the difference is under 0.25 of the arrows' RMS, where
    the opposite sign would give about 2."""
    ds, d, ents = diagnosed
    rows = _held_out_rows(ds, d)
    _, scale, _ = _legend(ents)
    vec = np.concatenate([np.asarray(x, dtype=float) / scale for x in column(ents[f"{WS}/arrows/before"], "Arrows3D:vectors")])
    pred = blocked_geometric.predict(ds.q[rows], None if ds.station is None else ds.station[rows]).spheres
    want = (ds.spheres[rows] - pred)[ds.sphere_seen[rows]]
    ratio = np.sqrt(np.mean((vec - want) ** 2)) / np.sqrt(np.mean(vec**2))
    print(f"difference / arrows RMS: {ratio:.3f}; with the opposite sign: "
          f"{np.sqrt(np.mean((vec + want) ** 2)) / np.sqrt(np.mean(vec**2)):.3f}")
    assert ratio < 0.25


def test_maps_hold_every_held_out_point_coloured_by_its_residual(diagnosed):
    """The static maps hold every seen point of the held-out rows, coloured by the size of the row's arrows."""
    ds, d, ents = diagnosed
    rows = _held_out_rows(ds, d)
    _, scale, top = _legend(ents)
    for tag in ("before", "after"):
        pts = np.asarray(column(ents[f"{WS}/map/{tag}"], "Points3D:positions")[0], dtype=float)
        np.testing.assert_allclose(pts, ds.spheres[rows][ds.sphere_seen[rows]], atol=1e-6)
        vec = np.concatenate([np.asarray(x, dtype=float) / scale for x in column(ents[f"{WS}/arrows/{tag}"], "Arrows3D:vectors")])
        colours = _rgb(column(ents[f"{WS}/map/{tag}"], "Points3D:colors")[0])
        want = size_colours(np.linalg.norm(vec, axis=1) * MM_PER_M, top)
        assert np.all(np.abs(colours.astype(int) - want) <= 1)
