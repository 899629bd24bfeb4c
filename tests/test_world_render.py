"""Rendering: stereo pairs of the plate, the camera model's projection, board views, noise, distortion."""

import numpy as np
import pytest

import cv2

from twin.camera import distort_normalized, project_points, undistort_normalized
from twin.transforms import invert_transform
from twin.world import World
from twin.world.board import charuco_board, interior_corners

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def world():
    """The default world at full resolution (default distortion and principal-point offsets)."""
    w = World.from_config({"world": {"preset": "separation_tables_2_4", "seed": 3}})
    yield w
    w.close()


@pytest.fixture(scope="module")
def world_ss2():
    """The same world rendering 2 x 2 samples per pixel (render.supersample = 2)."""
    w = World.from_config({"world": {"preset": "separation_tables_2_4", "seed": 3, "render": {"supersample": 2}}})
    yield w
    w.close()


BOTH = pytest.mark.parametrize("which", ["world", "world_ss2"])


def _sphere_pixels_ok(img, uv, r_px, plate_level_max=60):
    """Bright at every projected centre, dark on the plate just outside each sphere's outline."""
    for u, v in uv:
        centre = img[int(round(v)) - 1:int(round(v)) + 2, int(round(u)) - 1:int(round(u)) + 2]
        if centre.mean() < 120:
            return False
    return True


def test_pair_at_a_typical_pose_shows_all_three_spheres(world):
    """At a typical pose every sphere's projected centre is bright in both images, the plate around it dark."""
    q = world.visible_configurations(0, 1, seed=5)[0]
    cap = world.capture(q, 0)
    assert cap.left.shape == (1944, 2592) and cap.left.dtype == np.uint8
    uvl, uvr = world.project_spheres(cap.spheres_meas, 0)
    il, _ = world.true_intrinsics()
    r_px = 0.5 * 25.4e-3 * il.fx / np.linalg.norm(cap.spheres_meas, axis=1)
    for img, uv in ((cap.left, uvl), (cap.right, uvr)):
        for (u, v), r in zip(uv, r_px):
            centre = img[int(round(v)) - 2:int(round(v)) + 3, int(round(u)) - 2:int(round(u)) + 3]
            assert centre.mean() > 120, (u, v, centre.mean())
        # a ring 1.6 radii out lies on the dark plate or backdrop for every sphere
        for (u, v), r in zip(uv, r_px):
            ang = np.linspace(0, 2 * np.pi, 24, endpoint=False)
            ring = img[np.round(v + 1.6 * r * np.sin(ang)).astype(int), np.round(u + 1.6 * r * np.cos(ang)).astype(int)]
            assert np.median(ring) < 60, (u, v, np.median(ring))


def test_every_default_station_sees_the_plate(world):
    """Each default station has reachable configurations whose three spheres are bright in both images."""
    for s in range(world.n_stations):
        q = world.visible_configurations(s, 1, seed=11)[0]
        cap = world.capture(q, s)
        for img, uv in zip((cap.left, cap.right), world.project_spheres(cap.spheres_meas, s)):
            vals = [img[int(round(v)), int(round(u))] for u, v in uv]
            assert min(vals) > 120, (s, vals)


def test_true_spheres_follow_the_true_model(world):
    """The true sphere centres equal tool2meas of the true model (station base2meas) applied to the plate."""
    from twin.kinematics import tool2meas

    q = world.visible_configurations(1, 1, seed=2)[0]
    spheres = world.true_spheres_meas(q, 1)
    T = tool2meas(world.true_model_for_station(1), q)[0]
    expect = world.true_spheres_tool @ T[:3, :3].T + T[:3, 3]
    assert np.max(np.abs(spheres - expect)) < 1e-12


def test_camera_extrinsics_match_mujoco(world):
    """The analytic camera poses equal MuJoCo's (cam_xpos/xmat through the one flip function)."""
    for s in range(world.n_stations):
        for a, b in zip(world.true_cam2world(s), world.mujoco_cam2world(s)):
            assert np.max(np.abs(a - b)) < 1e-9


def _model_centroid(img, uv, K, half):
    """Intensity centroid taken in undistorted normalized coordinates (area-weighted), projected back [px].

    The probe is fronto-parallel, so its undistorted image is symmetric about the projection of its centre.
    """
    u0, v0 = int(round(uv[0])), int(round(uv[1]))
    win = img[v0 - half:v0 + half + 1, u0 - half:u0 + half + 1].astype(float)
    vv, uu = np.mgrid[v0 - half:v0 + half + 1, u0 - half:u0 + half + 1].astype(float)

    def und(u, v):
        return undistort_normalized(np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy], -1), K.dist)

    xy = und(uu, vv)
    du = und(uu + 0.5, vv) - und(uu - 0.5, vv)
    dv = und(uu, vv + 0.5) - und(uu, vv - 0.5)
    wgt = win * np.abs(du[..., 0] * dv[..., 1] - du[..., 1] * dv[..., 0])
    c = np.array([(wgt * xy[..., 0]).sum(), (wgt * xy[..., 1]).sum()]) / wgt.sum()
    d = distort_normalized(c[None], K.dist)[0]
    return np.array([K.fx * d[0] + K.cx, K.fy * d[1] + K.cy])


def _probe_error(world, p_meas, cam, K, T, intr_model=None):
    """Mean image-vs-model offset [px] of the probe at ``p_meas`` over four sub-pixel phases.

    Rendering an 8-bit textured target puts an error of up to ~0.01 px on its centroid that oscillates with
    the target's sub-pixel phase; averaging four phases a quarter pixel apart cancels it, a model error
    stays.
    """
    intr_model = intr_model or K
    z = (T[:3, :3] @ p_meas + T[:3, 3])[2]
    half = int(np.ceil(0.008 * K.fx / z)) + 8  # the whole probe quad and a rim of black
    errs = []
    for k in range(4):
        shift_cam = np.array([k / 4 / K.fx, k / 4 / K.fy, 0.0]) * z  # k/4 px along the pixel diagonal
        p = p_meas + T[:3, :3].T @ shift_cam
        img = world.render_probe(p, 0, cam, analog=True)
        uv = project_points(p[None], T, intr_model)[0]
        errs.append(_model_centroid(img, uv, intr_model, half) - uv)
    return np.mean(errs, axis=0)


@BOTH
def test_projection_of_a_known_point_matches_the_camera_model(which, request):
    """The image of a known point (fronto-parallel probe) sits where the true camera model projects it, to 0.01 px."""
    world = request.getfixturevalue(which)
    il, ir = world.true_intrinsics()
    l2r = world.true_left2right()
    rng = np.random.default_rng(0)
    errors = []
    for cam, K, T in (("left", il, np.eye(4)), ("right", ir, l2r)):
        for _ in range(4):
            z = rng.uniform(0.6, 0.9)
            half = int(np.ceil(0.008 * K.fx / z)) + 10
            uv_t = np.array([rng.uniform(half, K.width - half), rng.uniform(half, K.height - half)])
            ray = np.array([(uv_t[0] - K.cx) / K.fx, (uv_t[1] - K.cy) / K.fy, 1.0]) * z
            p = invert_transform(T)[:3, :3] @ ray + invert_transform(T)[:3, 3]  # left-camera (measurement) frame
            errors.append(np.linalg.norm(_probe_error(world, p, cam, K, T)))
    assert max(errors) < 0.01, errors


@BOTH
def test_projection_check_detects_a_wrong_principal_point(which, request):
    """The same check against a model with cx off by 0.03 px fails (so the test above can fail)."""
    from dataclasses import replace

    world = request.getfixturevalue(which)
    il, _ = world.true_intrinsics()
    wrong = replace(il, cx=il.cx + 0.03)
    err = _probe_error(world, np.array([0.02, -0.01, 0.7]), "left", il, np.eye(4), intr_model=wrong)
    assert np.linalg.norm(err) > 0.02


def test_distortion_is_in_the_image(world):
    """With the default distortion a point near a corner lands pixels away from its pinhole projection."""
    il, _ = world.true_intrinsics()
    ideal = type(il)(il.fx, il.fy, il.cx, il.cy, il.width, il.height)
    p = np.array([(2300 - il.cx) / il.fx, (1700 - il.cy) / il.fy, 1.0]) * 0.7
    assert np.linalg.norm(project_points(p[None], np.eye(4), il) - project_points(p[None], np.eye(4), ideal)) > 2.0


def test_noise_has_the_configured_sigma(world):
    """Two renders of the same configuration differ by noise of sqrt(2) x the configured sigma."""
    q = world.visible_configurations(0, 1, seed=5)[0]
    a = world.capture(q, 0, record=False).left.astype(float)
    b = world.capture(q, 0, record=False).left.astype(float)
    ok = (a > 20) & (a < 235) & (b > 20) & (b < 235)
    assert ok.sum() > 10000
    sigma = np.std((a - b)[ok]) / np.sqrt(2)
    assert abs(sigma - world.config.render.noise_sigma) < 0.1 * world.config.render.noise_sigma


@BOTH
def test_board_views_give_sub_tenth_pixel_corners(which, request):
    """ChArUco corners detected by OpenCV in rendered board views lie within 0.1 px RMS of their true projections."""
    world = request.getfixturevalue(which)
    views = world.render_board_views(4, seed=1)
    assert len(views) == 4
    board = charuco_board(world.config.board)
    det = cv2.aruco.CharucoDetector(board)
    corners = interior_corners(world.config.board)
    il, ir = world.true_intrinsics()
    l2r = world.true_left2right()
    errs = []
    for v in views:
        for img, K, T in ((v.left, il, v.board2meas), (v.right, ir, l2r @ v.board2meas)):
            cc, ids, _, _ = det.detectBoard(img)
            assert ids is not None and len(ids) >= world.config.board.min_corners
            ids = ids.reshape(-1)
            cc = cv2.cornerSubPix(img, cc.reshape(-1, 1, 2).astype(np.float32), (5, 5), (-1, -1),
                                  (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)).reshape(-1, 2)
            truth = project_points(corners[ids], T, K)
            errs.append(np.linalg.norm(cc - truth, axis=1))
    e = np.concatenate(errs)
    assert np.sqrt(np.mean(e**2)) < 0.1, np.sqrt(np.mean(e**2))


def test_board_views_record_their_truth(world):
    """Each board view's truth (board2meas) is recorded for the truth file, indexed in order."""
    n0 = len(world.truth_board_views)
    views = world.render_board_views(2, seed=9)
    assert [k for k, _ in world.truth_board_views[n0:]] == [v.index for v in views]
    left, right = views[0]  # a view unpacks as its image pair
    assert left is views[0].left and right is views[0].right


def test_occlusion_check_sees_a_hidden_sphere(world):
    """A visible configuration (also with the plate spun about its normal) is clear; turned away, it is occluded."""
    q = world.visible_configurations(0, 1, seed=5)[0]
    assert not world.spheres_occluded(q, 0)
    turned = q.copy()
    turned[5] += np.pi  # spin the plate: still facing the rig, spheres still visible
    assert not world.spheres_occluded(turned, 0)
    behind = q.copy()
    behind[0] += np.pi  # the robot turns its back to the rig: the spheres are behind the arm
    assert world.spheres_occluded(behind, 0)


def test_noise_seed_makes_a_pair_independent_of_history(world):
    """With noise_seed the same pose renders identically whatever came before; without it the noise differs."""
    q = world.visible_configurations(0, 1, seed=5)[0]
    a = world.capture(q, 0, record=False, noise_seed=77)
    world.capture(q, 0, record=False)  # something else in between
    b = world.capture(q, 0, record=False, noise_seed=77)
    c = world.capture(q, 0, record=False)
    assert np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)
    assert not np.array_equal(a.left, c.left)
    assert not np.array_equal(a.left, a.right)


def _sphere_centre_errors_px(world, qs):
    """Image-centre errors ``(n, 2)`` [px] of the instrument's sphere centres (true cameras) vs the true projections."""
    from twin.instrument import StereoCalibration, measure_pair

    il, ir = world.true_intrinsics()
    l2r = world.true_left2right()
    exact = StereoCalibration(il, ir, l2r, 0.0, 0.0, 0.0)
    out = []
    for q in qs:
        cap = world.capture(q, 0, record=False, noise_seed=1)
        m = measure_pair(cap.left, cap.right, exact, world.nominal_plate)
        uvl, uvr = world.project_spheres(cap.spheres_meas, 0)
        for k in range(3):
            for img, uv in ((m.left[k], uvl), (m.right[k], uvr)):
                if img is not None:
                    out.append(img.centre_px - uv[k])
    return np.array(out)


def test_supersampling_smooths_sphere_outlines(world, world_ss2):
    """With 2 x 2 samples per pixel the measured sphere centres sit less than half as far from truth (< 0.02 px RMS)."""
    qs = world.visible_configurations(0, 4, seed=5)
    e1 = _sphere_centre_errors_px(world, qs)
    e2 = _sphere_centre_errors_px(world_ss2, qs)
    assert len(e1) >= 20 and len(e2) >= 20
    rms1, rms2 = (float(np.sqrt(np.mean(np.sum(e**2, axis=1)))) for e in (e1, e2))
    assert rms2 < 0.5 * rms1 and rms2 < 0.02, (rms1, rms2)


def test_supersampled_pair_keeps_size_noise_and_truth(world, world_ss2):
    """A supersampled pair is (H, W) uint8 with the configured noise, and its truth equals the one-sample world's."""
    q = world.visible_configurations(0, 1, seed=5)[0]
    a = world_ss2.capture(q, 0, record=False)
    b = world_ss2.capture(q, 0, record=False)
    assert a.left.shape == (1944, 2592) and a.left.dtype == np.uint8
    assert np.array_equal(a.spheres_meas, world.capture(q, 0, record=False, render=False).spheres_meas)
    x, y = a.left.astype(float), b.left.astype(float)
    ok = (x > 20) & (x < 235) & (y > 20) & (y < 235)
    sigma = np.std((x - y)[ok]) / np.sqrt(2)
    assert abs(sigma - world_ss2.config.render.noise_sigma) < 0.1 * world_ss2.config.render.noise_sigma


class _MarkSamples:
    """An image effect that records what it is given and paints a bright block of 8 x 8 samples."""

    name = "mark_samples"
    changes_image = True

    def __init__(self):
        self.seen = []

    def joints(self, q, ctx):
        return q

    def geometry(self, robot, ctx):
        return robot

    def image(self, img, ctx, camera):
        self.seen.append((img.shape, img.dtype))
        out = img.copy()
        r0, c0 = self.corner(img.shape)
        out[r0:r0 + 8, c0:c0 + 8] = 250
        return out

    @staticmethod
    def corner(shape):
        """Top-left sample of the block: in the upper middle of the image, on the dark backdrop."""
        return int(0.2 * shape[0]), int(0.5 * shape[1])

    def params(self):
        return {}


@pytest.mark.parametrize("ss", [1, 2])
def test_image_effects_see_the_ideal_render_on_the_sampling_grid(ss):
    """An image effect gets the uint8 ideal render at s times the image size, and what it paints reaches the image."""
    fx = _MarkSamples()
    cfg = {"seed": 3, "render": {"scale": 0.25, "supersample": ss, "noise_sigma": 0.0}}
    with World.from_config(cfg, effects=[fx]) as w:
        W, H = w.image_size
        q = w.visible_configurations(0, 1, seed=5)[0]
        marked, _ = w.render_pair(q, 0)
        w.effects.clear()
        plain, _ = w.render_pair(q, 0)
        il, _ = w.true_intrinsics()
    assert fx.seen == [((ss * H, ss * W), np.dtype(np.uint8))] * 2
    assert marked.shape == (H, W)
    # the block lands where the lens puts its rays: its centre on the sampling grid, back to an output pixel of
    # the ideal render (pixel centres s*u + (s-1)/2), as a ray, through the true camera model
    from twin.world.rig import render_focal_px

    r0, c0 = _MarkSamples.corner((ss * H, ss * W))
    ideal_uv = (np.array([c0, r0]) + 3.5 - 0.5 * (ss - 1)) / ss
    ray = np.append((ideal_uv - [W / 2 - 0.5, H / 2 - 0.5]) / render_focal_px(il), 1.0)
    expect = project_points(ray[None], np.eye(4), il)[0]
    diff = np.clip(marked.astype(float) - plain.astype(float), 0, None)
    v, u = np.mgrid[0:H, 0:W]
    centre = np.array([(diff * u).sum(), (diff * v).sum()]) / diff.sum()
    assert np.linalg.norm(centre - expect) < 0.05, (centre, expect)  # measured 0.003 px (s = 1), 0.001 px (s = 2)
    assert diff.sum() > 0.5 * 64 / ss**2 * 100  # the block's area in output pixels, at least 100 levels brighter


def test_render_larger_than_the_gl_limit_is_refused():
    """A supersampled render beyond the GL's largest offscreen buffer is a ValueError naming supersample."""
    import mujoco

    from twin.world.render import ImageFormer, gl_max_renderbuffer_px

    ctx = mujoco.GLContext(64, 64)
    ctx.make_current()
    limit = gl_max_renderbuffer_px()
    ctx.free()
    assert limit is not None and limit >= 4096
    w = limit // 2 + 1
    model = mujoco.MjModel.from_xml_string(
        f'<mujoco><visual><global offwidth="{2 * w}" offheight="64"/></visual><worldbody/></mujoco>')
    with pytest.raises(ValueError, match="supersample"):
        ImageFormer(model, w, 32, supersample=2)


def test_render_board_at_a_given_pose(world):
    """render_board draws the board where asked (corners within 0.2 px of their projections); record=False leaves no truth."""
    from twin.instrument import BoardSpec, detect_board

    il, _ = world.true_intrinsics()
    T = np.eye(4)
    T[:3, 3] = [-0.099, -0.072, 0.7]  # board centre on the optical axis, fronto-parallel, 700 mm away
    n0 = len(world.truth_board_views)
    view = world.render_board(T, 0, record=False)
    assert view.index == -1 and len(world.truth_board_views) == n0
    bv = detect_board(view.left, BoardSpec.from_table(world.rig_info()["board"]))
    assert len(bv.ids) >= 40
    err = np.linalg.norm(bv.corners_px - project_points(bv.object_points, T, il), axis=1)
    assert np.sqrt(np.mean(err**2)) < 0.2
    with pytest.raises(ValueError, match="board2meas"):
        world.render_board(np.eye(3), 0)


def test_bare_render_shows_the_placed_robot(world):
    """World.place + render_bare: MuJoCo's own render of both cameras, RGB at the image size, which changes when
    the robot is placed elsewhere (what the benchmarks time against the full image formation)."""
    import mujoco

    q = world.visible_configurations(0, 1, seed=2)[0]
    w, h = world.image_size
    r = mujoco.Renderer(world.model, h, w)
    try:
        world.place(q, 0)
        a = world.render_bare(r)
        world.place(q + np.deg2rad([10, 0, 0, 0, 0, 0]), 0)
        b = world.render_bare(r)
    finally:
        r.close()
    assert len(a) == 2 and a[0].shape == (h, w, 3) and a[0].dtype == np.uint8
    assert np.abs(a[0].astype(int) - b[0].astype(int)).mean() > 0.5
    with pytest.raises(ValueError, match="station"):
        world.place(q, 99)
