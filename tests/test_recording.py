"""Tests of twin.evaluation.recording: a synthetic campaign recording read back with rerun.chunk.RrdReader."""

import cv2
import numpy as np
import pytest

from twin.camera import CameraIntrinsics
from twin.evaluation.recording import CameraView, CampaignRecording, StationView, encode_image, read_recording

from twin.transforms import make_transform, rot_x
from _recording_helpers import column  # tests/ is on sys.path under pytest

K = CameraIntrinsics.ideal(320, 240, 15.225)
N_POSES = 6


def make_synthetic_recording(path, n_poses=N_POSES, size=(240, 320)):
    """A small recording with everything a campaign logs (also used by the browser test)."""
    rng = np.random.default_rng(0)
    meas2base = make_transform(rot_x(np.pi / 2), np.array([1.2, 0.0, 0.6]))
    right2left = make_transform(np.eye(3), np.array([0.25, 0.0, 0.0]))
    st = StationView("front", meas2base, (CameraView("left", np.eye(4), K), CameraView("right", right2left, K)))
    frames = np.tile(np.eye(4), (7, 1, 1))
    frames[:, 2, 3] = np.linspace(0.0, 0.8, 7)
    with CampaignRecording(path, methods=["separation"]) as rec:
        rec.log_stations([st])
        for i in range(n_poses):
            rec.set_pose(i)
            img = np.zeros(size + (3,), dtype=np.uint8)
            img[..., 0] = 255  # magenta: easy to find by pixels in the browser test
            img[..., 2] = 255
            cv2.circle(img, (size[1] // 2, size[0] // 2), 30, (255, 255, 255), -1)
            rec.log_images({"left": img, "right": img}, overlays={
                "left": {"centres_px": [[size[1] / 2, size[0] / 2]], "outlines_px": [[[130, 90], [190, 90], [190, 150]]]}
            })
            pts = np.array([[0.0, 0.0, 0.7], [0.06, 0.0, 0.7], [0.0, 0.05, 0.7]]) + 0.001 * i
            rec.log_measurement("front", pts, np.array([True, True, True]), make_transform(np.eye(3), pts[0]))
            rec.log_robot({"nominal": frames, "true": frames + 0.001, "calibrated/separation": frames})
            rec.log_scalars({"residuals/separation/angle_deg": 0.01 * i, "residuals/separation/position_mm": rng.random()})
            rec.log_text(f"pose {i}: sphere p2 rejected (synthetic)", level="WARN")
    return path


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = make_synthetic_recording(tmp_path_factory.mktemp("rec") / "synthetic.rrd")
    return path, read_recording(path)


def test_recording_has_the_documented_entity_paths(recording):
    """The file holds the documented entities: view coordinates, frustums, images, overlays, 3D, residuals, log."""
    _, ents = recording
    for p in ("/world", "/world/stations/front", "/world/stations/front/left", "/world/stations/front/right",
              "/images/left", "/images/right", "/images/left/centres", "/images/left/outlines",
              "/world/stations/front/measured/spheres", "/world/stations/front/measured/plate",
              "/world/robot/nominal/links", "/world/robot/true/axes", "/world/robot/calibrated/separation/links",
              "/residuals/separation/angle_deg", "/log"):
        assert p in ents, p


def test_recording_image_has_its_size(recording):
    """A logged image decodes to the size it was logged at."""
    _, ents = recording
    blobs = column(ents["/images/left"], "EncodedImage:blob")  # one row per log call: [blob bytes as a list]
    assert len(blobs) == N_POSES
    img = cv2.imdecode(np.frombuffer(bytes(blobs[0][0]), np.uint8), cv2.IMREAD_UNCHANGED)
    assert img.shape[:2] == (240, 320)


def test_recording_triangulated_point_round_trips(recording):
    """The triangulated centre of pose 2 reads back as logged (float32)."""
    _, ents = recording
    pos = column(ents["/world/stations/front/measured/spheres"], "Points3D:positions")
    assert len(pos) == N_POSES
    np.testing.assert_allclose(pos[2][1], [0.062, 0.002, 0.702], atol=1e-6)


def test_recording_residual_series_has_one_value_per_pose(recording):
    """The residual series has one scalar per pose, on the pose timeline."""
    _, ents = recording
    vals = column(ents["/residuals/separation/angle_deg"], "Scalars:scalars")
    assert len(vals) == N_POSES
    assert np.ravel(vals)[3] == pytest.approx(0.03)
    poses = column(ents["/residuals/separation/angle_deg"], "pose")
    assert sorted(poses) == list(range(N_POSES))


def test_text_log_holds_the_rejections(recording):
    """Rejected measurements appear in the text log with level WARN."""
    _, ents = recording
    texts = column(ents["/log"], "TextLog:text")
    assert any("rejected" in t for t in np.ravel(texts).tolist())


def test_encode_image_lossless_round_trips():
    """PNG encoding is lossless; JPEG is smaller than PNG on a noisy image."""
    img = np.random.default_rng(1).integers(0, 255, (64, 80), dtype=np.uint8)
    png, media = encode_image(img, lossless=True)
    assert media == "image/png"
    np.testing.assert_array_equal(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED), img)
    jpg, media = encode_image(img)
    assert media == "image/jpeg" and len(jpg) < len(png)
    with pytest.raises(ValueError, match="image must be uint8"):
        encode_image(img.astype(float))


def test_campaign_recording_reads_back(tmp_path):
    """A campaign's own recording holds its stations, models, measured spheres, one residual per evaluated motion and
    the diagnosis' verdict of its dataset (with the errors before and after)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _campaign_helpers import reference_full_pose, small_config

    from twin.runner.campaign import run_campaign
    from twin.runner.store import PoseStore

    run = run_campaign(small_config(outputs={"recording": True, "figures": False}, diagnosis={"enabled": True}), tmp_path,
                       implementations={"full_pose": reference_full_pose})
    ents = read_recording(run.files["recording"])
    for p in ("/world/stations/front/left", "/world/stations/left/right", "/world/robot/nominal/links",
              "/world/robot/true/links", "/world/robot/calibrated/full_pose/axes", "/world/stations/front/measured/spheres"):
        assert p in ents, p
    n_angle_pairs, n_moves = 4, 4  # the small config's compensation pairs and distance moves
    assert len(column(ents["/residuals/before/angle_deg"], "Scalars:scalars")) == n_angle_pairs
    assert len(column(ents["/residuals/full_pose/position_mm"], "Scalars:scalars")) == n_moves
    pos = column(ents["/world/stations/front/measured/spheres"], "Points3D:positions")
    stored = PoseStore(tmp_path / "work" / "poses").read("m/00000")
    np.testing.assert_allclose(pos[0], np.array([s for s in stored.spheres if s is not None]), atol=1e-6)
    verdict = column(ents["/diagnosis/verdict"], "TextDocument:text")[0][0]
    d = run.results["diagnosis"]
    assert "Diagnosis of the campaign's dataset" in verdict and f"p = {d['p_value']:.3g}" in verdict
    assert f"{d['before']['position_mm']['rms']:.4f}" in verdict and f"{d['after']['position_mm']['rms']:.4f}" in verdict
