"""End to end on the twin: rendered board views -> estimated rig -> rendered plate poses -> 3D centres.

The instrument sees only the images and the board's nominal geometry; the truth (``Capture.spheres_meas``)
is read here, in the test, to check it. Loose bounds: the tight figures live in the benchmark
(``experiments/bench_instrument.py``). Half resolution keeps the renders quick.
"""

import json

import numpy as np
import pytest

from twin.cli import main
from twin.dataset import read_dataset
from twin.instrument import BoardSpec, calibrate_stereo, measure_pair, plate_pose_from_spheres
from twin.transforms import rotation_angle_between
from twin.world import World

WORLD = {"render": {"scale": 0.5}, "board": {"views": 12}, "seed": 3}


def _rigid_residual(X, Y):
    """Residuals ``(n,)`` after the best rigid alignment of X onto Y (the frame error base2meas absorbs)."""
    mx, my = X.mean(0), Y.mean(0)
    U, _, Vt = np.linalg.svd((Y - my).T @ (X - mx))
    R = U @ np.diag([1, 1, np.linalg.det(U @ Vt)]) @ Vt
    return np.linalg.norm((X - mx) @ R.T + my - Y, axis=1), R


@pytest.fixture(scope="module")
def twin_run():
    with World.from_config(WORLD) as w:
        views = w.render_board_views()
        calib = calibrate_stereo([(v.left, v.right) for v in views], BoardSpec.from_table(w.rig_info()["board"]))
        caps = [w.capture(q, 0) for q in w.visible_configurations(0, 5, seed=1)]
        plate = w.nominal_plate
    return calib, caps, plate


@pytest.mark.slow
def test_rig_calibrated_from_rendered_board_views(twin_run):
    """The rendered board views calibrate the rig: every view used, sub-0.1 px reprojection RMS."""
    calib, _, _ = twin_run
    assert calib.n_views_used == 12 and calib.rms_px < 0.1
    assert 0.2 < calib.baseline < 0.3


@pytest.mark.slow
def test_rendered_plate_poses_measured_in_3d(twin_run):
    """All spheres of the rendered poses are measured; after one rigid alignment (the measurement frame
    is only known through the estimated rig) the 3D error is below 0.05 mm, and below 0.5 mm raw."""
    calib, caps, plate = twin_run
    X, Y = [], []
    for cap in caps:
        m = measure_pair(cap.left, cap.right, calib, plate)
        assert m.complete, m.status
        X.append(m.centres_array())
        Y.append(cap.spheres_meas)
    X, Y = np.concatenate(X), np.concatenate(Y)
    assert np.max(np.linalg.norm(X - Y, axis=1)) < 5e-4
    res, _ = _rigid_residual(X, Y)
    assert np.sqrt(np.mean(res**2)) < 5e-5


@pytest.mark.slow
def test_plate_orientation_from_rendered_poses(twin_run):
    """The plate frames fitted to the measured centres agree with the true plate orientation to 0.15 deg
    (after removing the frame rotation common to all poses). At half resolution the centres err by up to
    ~0.05 mm, and the closest spheres are 69 mm apart: 0.05/69 rad is 0.04 deg per sphere."""
    calib, caps, plate = twin_run
    X = [measure_pair(c.left, c.right, calib, plate).centres_array() for c in caps]
    _, R = _rigid_residual(np.concatenate(X), np.concatenate([c.spheres_meas for c in caps]))
    for x, cap in zip(X, caps):
        fit = plate_pose_from_spheres(x, plate)
        ang = np.degrees(rotation_angle_between(R @ fit.tool2meas[:3, :3], cap.tool2meas[:3, :3]))
        assert ang < 0.15


@pytest.mark.slow
def test_cli_measure_render(tmp_path, capsys):
    """`twin measure --render` renders, calibrates, measures and writes a valid dataset plus the truth."""
    cfg = tmp_path / "world.toml"
    cfg.write_text("[world]\nseed = 3\n[world.render]\nscale = 0.5\n[world.board]\nviews = 8\n")
    rc = main(["measure", "--render", "--world", str(cfg), "--poses", "2", "--out", str(tmp_path / "ds"),
               "--keep-images", str(tmp_path / "images"), "--quiet"])
    out = capsys.readouterr().out
    assert rc == 0
    assert json.loads(out[out.index("{"):])["complete_rows"] == 2
    ds = read_dataset(tmp_path / "ds")
    assert ds.n == 2 and ds.sphere_seen.all()
    assert (tmp_path / "truth.json").exists() and (tmp_path / "images" / "rig.toml").exists()
    assert len(list((tmp_path / "images" / "pairs").glob("*.png"))) == 4


@pytest.mark.slow
def test_world_image_folder_measured(tmp_path, capsys):
    """The folder `twin render` writes (the world's own writer) is measured by `twin measure IMAGES`."""
    cfg = tmp_path / "world.toml"
    cfg.write_text("[world]\nseed = 3\n[world.render]\nscale = 0.5\n[world.board]\nviews = 8\n")
    assert main(["render", str(cfg), "--out", str(tmp_path / "r"), "--per-station", "1", "--quiet"]) == 0
    rc = main(["measure", str(tmp_path / "r" / "images"), "--out", str(tmp_path / "ds"), "--quiet"])
    out = capsys.readouterr().out
    assert rc == 0
    ds = read_dataset(tmp_path / "ds")
    summary = json.loads(out[out.index("{"):])
    assert ds.n == summary["rows"] >= 4 and summary["complete_rows"] >= ds.n - 1
    assert ds.station is not None
