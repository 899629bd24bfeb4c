"""The recording of a measured campaign (``record_measured_campaign``): the robot as segments between its joint
frames, measured and predicted points, the error per posture, read back with rerun.chunk.RrdReader."""

import numpy as np
import pytest

from twin.evaluation.recording import read_recording, record_measured_campaign
from _recording_helpers import column  # tests/ is on sys.path under pytest


def _inputs(n=5, K=4, F=10, seed=0):
    rng = np.random.default_rng(seed)
    J = np.cumsum(rng.normal(0, 0.1, (n, F, 3)), axis=1)
    M = rng.normal(0.5, 0.1, (n, K, 3))
    M[2, 1] = np.nan  # a point not seen
    geo = np.nan_to_num(M, nan=0.5) + rng.normal(0, 0.003, (n, K, 3))
    ext = np.nan_to_num(M, nan=0.5) + rng.normal(0, 0.001, (n, K, 3))
    return J, M, geo, ext


def test_measured_campaign_recording_holds_robot_points_and_error_per_posture(tmp_path):
    """Per posture: the robot's joint origins as one line strip, the measured points (seen ones only), each model's
    points and its error [mm] equal to the RMS 3-D distance to the measured points, computed here."""
    J, M, geo, ext = _inputs()
    ids = np.array([10, 11, 12, 40, 41])
    p = record_measured_campaign(tmp_path / "c.rrd", joint_origins_m=J, measured_m=M,
                                 predicted_m={"geometric": geo, "extended": ext}, posture_ids=ids,
                                 groups=["training", "training", "replayed", "outside", "new_in_range"],
                                 summary_markdown="# summary")
    ents = read_recording(p)
    for e in ("/campaign/robot", "/campaign/points/measured", "/campaign/points/geometric", "/campaign/points/extended",
              "/campaign/residual/geometric", "/campaign/residual/extended", "/campaign/group", "/campaign/summary"):
        assert e in ents, e
    np.testing.assert_array_equal(column(ents["/campaign/residual/extended"], "posture"), ids)
    strips = column(ents["/campaign/robot"], "LineStrips3D:strips")
    assert len(strips) == 5 and np.allclose(np.asarray(strips[3][0]), J[3])
    pts = column(ents["/campaign/points/measured"], "Points3D:positions")
    assert [len(x) for x in pts] == [4, 4, 3, 4, 4]
    for name, P in (("geometric", geo), ("extended", ext)):
        want = []
        for k in range(5):
            s = np.all(np.isfinite(M[k]), axis=1)
            want.append(np.sqrt(np.mean(np.sum((P[k][s] - M[k][s]) ** 2, axis=1))) * 1e3)
        got = np.ravel(column(ents[f"/campaign/residual/{name}"], "Scalars:scalars")).astype(float)
        np.testing.assert_allclose(got, want, rtol=1e-6)
    assert np.ravel(column(ents["/campaign/group"], "TextLog:text")).tolist()[3] == "outside"


def test_measured_campaign_recording_rejects_inconsistent_input(tmp_path):
    """Shapes that disagree, non-finite predictions or no model are ValueErrors naming the argument."""
    J, M, geo, ext = _inputs()
    kw = dict(joint_origins_m=J, measured_m=M, predicted_m={"geometric": geo}, posture_ids=np.arange(5), groups=["a"] * 5)
    with pytest.raises(ValueError, match="measured_m"):
        record_measured_campaign(tmp_path / "a.rrd", **{**kw, "measured_m": M[:4]})
    with pytest.raises(ValueError, match=r"predicted_m\['geometric'\]"):
        record_measured_campaign(tmp_path / "b.rrd", **{**kw, "predicted_m": {"geometric": geo * np.nan}})
    with pytest.raises(ValueError, match="predicted_m"):
        record_measured_campaign(tmp_path / "c.rrd", **{**kw, "predicted_m": {}})
    with pytest.raises(ValueError, match="groups"):
        record_measured_campaign(tmp_path / "d.rrd", **{**kw, "groups": ["a"]})
