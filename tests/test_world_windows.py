"""Target windows: supersampled windows around the spheres (and the board) composited into a 1-sample frame."""

import cv2
import numpy as np
import pytest

from twin.instrument import StereoCalibration, measure_pair
from twin.world import World

pytestmark = pytest.mark.slow

SCALE = 0.25  # 648 x 486 images: cheap, spheres ~65 px across
BASE = {"preset": "separation_tables_2_4", "seed": 3}


def _world(**render) -> World:
    return World.from_config({"world": {**BASE, "render": {"scale": SCALE, **render}}})


@pytest.fixture(scope="module")
def worlds():
    """The default camera four ways: windows at 4 x 4 samples over the frame at 1 sample per pixel or per 2 x 2
    pixels, the full frame at 4 x 4, the full frame at 1."""
    ws = {"windows": _world(window_supersample=4), "windows_half": _world(window_supersample=4, frame_subsample=2),
          "full4": _world(supersample=4), "full1": _world()}
    yield ws
    for w in ws.values():
        w.close()


def _windows_of(world: World, cap) -> tuple:
    """The windows the world renders for this capture's spheres (left, right)."""
    c2w = world.true_cam2world(cap.station)[0]
    pts = (c2w[:3, :3] @ cap.spheres_meas.T).T + c2w[:3, 3]
    return world.target_windows(pts, np.full(3, 0.5 * world.nominal_plate.sphere_diameter), cap.station,
                                outline_arc_px=world.config.render.window_arc_px)


def _inside(shape: tuple[int, int], rects) -> np.ndarray:
    """Boolean mask ``shape`` of the pixels inside any window ``(u0, v0, u1, v1)``."""
    inside = np.zeros(shape, dtype=bool)
    for u0, v0, u1, v1 in rects:
        inside[v0:v1, u0:u1] = True
    return inside


def _poses(world: World, n: int) -> np.ndarray:
    return world.visible_configurations(0, n, seed=5)


@pytest.mark.parametrize("which", ["windows", "windows_half"])
def test_windowed_image_equals_full_supersampled_render_inside_the_windows(worlds, which):
    """Inside each window the image equals the full-frame 4x4 render (same noise), up to GL rounding, whatever
    the frame's sampling."""
    ww, wf = worlds[which], worlds["full4"]
    for q in _poses(ww, 2):
        a, b = ww.capture(q, 0, noise_seed=1, record=False), wf.capture(q, 0, noise_seed=1, record=False)
        for img_a, img_b, rects in zip((a.left, a.right), (b.left, b.right), _windows_of(ww, a)):
            assert len(rects) >= 3  # one window per sphere, or a ring of them along its outline
            for u0, v0, u1, v1 in rects:
                d = np.abs(img_a[v0:v1, u0:u1].astype(int) - img_b[v0:v1, u0:u1].astype(int))
                # the noise-free grey levels agree up to GL rounding: a sample one level apart changes the block mean
                # by 1/16 level (after the same noise and the 8-bit rounding, one level), and now and then a sample
                # on an outline flips (one of 16 samples: at most 255/16 levels)
                assert np.mean(d > 1) < 2e-3 and d.max() <= 16 and np.mean(d > 0) < 0.01, (d.max(), np.mean(d > 0))


def test_windowed_image_equals_the_one_sample_frame_outside_the_windows(worlds):
    """Outside the windows the image is the 1-sample frame's; inside, it differs (the windows are used)."""
    ww, w1 = worlds["windows"], worlds["full1"]
    q = _poses(ww, 1)[0]
    a, b = ww.capture(q, 0, noise_seed=2, record=False), w1.capture(q, 0, noise_seed=2, record=False)
    for img_a, img_b, rects in zip((a.left, a.right), (b.left, b.right), _windows_of(ww, a)):
        inside = _inside(img_a.shape, rects)
        d = np.abs(img_a.astype(int) - img_b.astype(int))
        assert d[~inside].max() == 0
        assert np.mean(d[inside] > 2) > 0.005  # the outlines are sampled differently


@pytest.mark.parametrize("which", ["windows", "windows_half"])
def test_detection_on_windows_matches_full_frame_supersample_4(worlds, which):
    """Sphere centres measured on windowed images match those on full-frame 4x4 images to 0.001 mm, with the
    frame under the windows at one sample per pixel or per 2 x 2 pixels."""
    ww, wf = worlds[which], worlds["full4"]
    il, ir = ww.true_intrinsics()
    cal = StereoCalibration(il, ir, ww.true_left2right(), 0.0, 0.0, 0.0)
    compared = 0
    for q in _poses(ww, 3):
        a, b = ww.capture(q, 0, noise_seed=3, record=False), wf.capture(q, 0, noise_seed=3, record=False)
        ma, mb = measure_pair(a.left, a.right, cal, ww.nominal_plate), measure_pair(b.left, b.right, cal, wf.nominal_plate)
        # the same spheres measured (one may be refused in both, e.g. its outline touching the arm)
        assert ma.reasons == mb.reasons
        for ca, cb in zip(ma.centres, mb.centres):
            if ca is not None:
                assert np.linalg.norm(ca - cb) * 1e3 <= 0.001  # measured <= 0.0007 mm
                compared += 1
    assert compared >= 6


def test_every_sphere_outline_lies_inside_its_windows_with_margin(worlds):
    """Every point of each sphere's true outline (its tangent cone, distortion included) is >= 4 px inside a window."""
    import cv2

    ww = worlds["windows"]
    r = 0.5 * ww.nominal_plate.sphere_diameter
    for q in _poses(ww, 3):
        cap = ww.capture(q, 0, render=False, record=False)
        for cam, (c2w, intr), rects in zip((0, 1), zip(ww.true_cam2world(0), ww.true_intrinsics()), _windows_of(ww, cap)):
            w2c = np.linalg.inv(c2w)
            left2world = ww.true_cam2world(0)[0]
            for p_meas in cap.spheres_meas:
                p = w2c[:3, :3] @ (left2world[:3, :3] @ p_meas + left2world[:3, 3]) + w2c[:3, 3]
                d = np.linalg.norm(p)
                # the tangent circle: centre p (1 - r^2/d^2), radius r sqrt(1 - r^2/d^2), normal p/d
                n = p / d
                e1 = np.cross(n, [0.0, 1.0, 0.0])
                e1 /= np.linalg.norm(e1)
                e2 = np.cross(n, e1)
                a = np.linspace(0, 2 * np.pi, 64, endpoint=False)[:, None]
                rim = p * (1 - r**2 / d**2) + r * np.sqrt(1 - r**2 / d**2) * (np.cos(a) * e1 + np.sin(a) * e2)
                K = np.array([[intr.fx, 0, intr.cx], [0, intr.fy, intr.cy], [0, 0, 1.0]])
                uv = cv2.projectPoints(rim, np.zeros(3), np.zeros(3), K, np.asarray(intr.dist, float))[0].reshape(-1, 2)
                inside = np.zeros(len(uv), bool)
                for u0, v0, u1, v1 in rects:
                    inside |= (uv[:, 0] >= u0 + 4) & (uv[:, 0] <= u1 - 5) & (uv[:, 1] >= v0 + 4) & (uv[:, 1] <= v1 - 5)
                assert inside.all(), (cam, uv[~inside], rects)


def test_window_partly_outside_the_image_is_clipped_to_the_image(worlds):
    """A target straddling the image border gets one window, clipped at the border, not dropped."""
    ww, wf = worlds["windows"], worlds["full4"]
    q = _poses(ww, 1)[0]
    cap = ww.capture(q, 0, render=False, record=False)
    W, H = ww.image_size
    # a ball of the sphere's size on the left image's border row: half of it outside the image
    il = ww.true_intrinsics()[0]
    z = float(cap.spheres_meas[0, 2])
    p_meas = np.array([(W / 2 - il.cx) * z / il.fx, (0 - il.cy) * z / il.fy, z])
    c2w = ww.true_cam2world(0)[0]
    p_world = c2w[:3, :3] @ p_meas + c2w[:3, 3]
    rects = ww.target_windows(p_world[None], np.array([0.0127]), 0)[0]
    assert len(rects) == 1 and rects[0][1] == 0 and rects[0][3] < H // 2


def test_spheres_hidden_by_the_arm_are_flagged_not_misplaced(worlds):
    """Spheres behind the arm: the windows show the arm as the full 4x4 frame does, and the instrument flags the pair."""
    ww, wf = worlds["windows"], worlds["full4"]
    q = _poses(ww, 1)[0].copy()
    q[0] += np.pi  # the robot turns its back to the rig: the spheres are behind the arm
    assert ww.spheres_occluded(q, 0)
    a, b = ww.capture(q, 0, noise_seed=4, record=False), wf.capture(q, 0, noise_seed=4, record=False)
    for img_a, img_b, rects in zip((a.left, a.right), (b.left, b.right), _windows_of(ww, a)):
        for u0, v0, u1, v1 in rects:
            d = np.abs(img_a[v0:v1, u0:u1].astype(int) - img_b[v0:v1, u0:u1].astype(int))
            assert d.max() <= 1 and np.mean(d > 0) < 0.01
    il, ir = ww.true_intrinsics()
    m = measure_pair(a.left, a.right, StereoCalibration(il, ir, ww.true_left2right(), 0.0, 0.0, 0.0), ww.nominal_plate)
    assert not m.complete


def test_window_supersample_is_validated():
    """render.window_supersample outside 0..8 or not an integer is a ValueError naming the field."""
    for bad in (-1, 9, 2.5, True):
        with pytest.raises(ValueError, match="window_supersample"):
            World.from_config({"world": {**BASE, "render": {"scale": SCALE, "window_supersample": bad}}})


def test_half_frame_differs_only_smoothly_outside_the_windows(worlds):
    """With frame_subsample 2 the frame outside the windows is the coarse render resampled: close to the 1-sample
    frame (smooth shading, backdrop) but not equal to it (the frame really is coarser)."""
    wh, w1 = worlds["windows_half"], worlds["full1"]
    q = _poses(wh, 1)[0]
    a, b = wh.capture(q, 0, noise_seed=2, record=False), w1.capture(q, 0, noise_seed=2, record=False)
    for img_a, img_b, rects in zip((a.left, a.right), (b.left, b.right), _windows_of(wh, a)):
        inside = _inside(img_a.shape, rects)
        d = np.abs(img_a.astype(int) - img_b.astype(int))
        # away from edges (grey range over the 5 x 5 neighbourhood below 8 levels) the coarse frame is the fine one
        # up to a level; on edges (the arm's, the plate's) it is blurred
        rng = cv2.dilate(img_b, np.ones((5, 5), np.uint8)).astype(int) - cv2.erode(img_b, np.ones((5, 5), np.uint8))
        smooth = (rng < 8) & ~inside
        assert np.mean(d[smooth] > 1) < 1e-3
        assert np.mean(d[~inside & ~smooth] > 1) > 0.01  # the frame really is coarser


def test_frame_subsample_is_validated():
    """render.frame_subsample other than 1/2/4, without windows or with supersampling is a ValueError naming it."""
    for render in ({"frame_subsample": 3, "window_supersample": 4}, {"frame_subsample": 2},
                   {"frame_subsample": 2, "window_supersample": 4, "supersample": 2},
                   {"frame_subsample": 4, "window_supersample": 4}):  # 486 rows are not divisible by 4
        with pytest.raises(ValueError, match="frame_subsample"):
            World.from_config({"world": {**BASE, "render": {"scale": SCALE, **render}}})


class _Brighten:
    """An image effect adding 10 grey levels to the whole ideal render."""

    name = "brighten"
    changes_image = True

    def joints(self, q, ctx):
        return q

    def geometry(self, robot, ctx):
        return robot

    def image(self, img, ctx, camera):
        return np.minimum(img.astype(np.int16) + 10, 255).astype(np.uint8)

    def params(self):
        return {}


def test_image_effects_turn_the_windows_off():
    """With an image effect the windowed world forms the full one-sample frame (effects need one whole sampling
    grid), also when the frame would otherwise be coarse."""
    imgs = []
    for render in ({"window_supersample": 4}, {"window_supersample": 4, "frame_subsample": 2}, {}):
        cfg = {"world": {**BASE, "render": {"scale": SCALE, **render}}}
        with World.from_config(cfg, effects=[_Brighten()]) as w:
            q = _poses(w, 1)[0]
            imgs.append(w.capture(q, 0, noise_seed=5, record=False).left)
    assert np.array_equal(imgs[0], imgs[2]) and np.array_equal(imgs[1], imgs[2])


def test_target_windows_reject_bad_input(worlds):
    """Targets not (n, 3), radii of the wrong length or negative are ValueErrors naming the argument."""
    w = worlds["windows"]
    with pytest.raises(ValueError, match="targets_world"):
        w.target_windows(np.zeros((2, 2)), np.zeros(2))
    with pytest.raises(ValueError, match="radii"):
        w.target_windows(np.zeros((2, 3)), np.zeros(3))
    with pytest.raises(ValueError, match="radii"):
        w.target_windows(np.zeros((1, 3)), np.array([-0.01]))


def test_board_view_windows_equal_full_supersampled_render(worlds):
    """A board view's corner windows equal the full-frame 4x4 render."""
    ww, wf, w1 = worlds["windows"], worlds["full4"], worlds["full1"]
    T = ww.render_board_views(1, seed=2)[0].board2meas
    a, b, c = (w.render_board(T, 0, noise=False, record=False) for w in (ww, wf, w1))
    wins = ww.board_windows(T, 0)
    for img_a, img_b, img_c, rects in ((a.left, b.left, c.left, wins[0]), (a.right, b.right, c.right, wins[1])):
        assert len(rects) >= 20  # one per inner corner the camera sees
        inside = _inside(img_a.shape, rects)
        d4 = np.abs(img_a.astype(int) - img_b.astype(int))[inside]
        d1 = np.abs(img_a.astype(int) - img_c.astype(int))
        assert np.mean(d1[inside] > 0) > 0.05  # the corners are sampled differently from the one-sample frame
        # GL rounding: a handful of samples on a texel edge flip (one sample of 16 is at most 16 levels)
        assert np.mean(d4 > 1) < 1e-4 and d4.max() <= 16 and np.mean(d4 > 0) < 0.01
