"""The campaign and the diagnosis recordings in a real browser: Rerun's web viewer in headless Chromium, checked by
pixels."""

import functools
import http.server
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from urllib.parse import quote

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _diagnosis_helpers as H  # noqa: E402
from test_recording import make_synthetic_recording  # noqa: E402
from twin.evaluation.recording import SKELETON_COLOUR  # noqa: E402
from twin.evaluation.workspace import COLOUR_STOPS  # noqa: E402

pytestmark = [pytest.mark.browser, pytest.mark.slow]

CHROME_FLAGS = (
    "--headless --no-sandbox --disable-gpu --disable-quic --no-first-run --disable-background-networking "
    "--disable-component-update --disable-sync"
).split()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _rerun_binary() -> str:
    """The Rerun viewer binary itself (the `rerun` script is a Python wrapper that would outlive a kill)."""
    import rerun_cli

    path = Path(rerun_cli.__file__).resolve().parent / "rerun"
    assert path.exists(), f"rerun binary not found at {path}"
    return str(path)


def _near(img: np.ndarray, rgb, tol=40) -> np.ndarray:
    return np.all(np.abs(img[..., :3].astype(int) - np.array(rgb)) <= tol, axis=-1)


def _rendered(shot: np.ndarray) -> tuple[bool, bool, dict]:
    """(image rendered, 3D view rendered, details): magenta image pixels, and axis-arrow red pixels in the 3D
    view to the left of the image views."""
    magenta = _near(shot, (255, 0, 255), tol=30)
    info = {"magenta_px": int(magenta.sum())}
    if magenta.sum() < 2000:
        return False, False, info
    x_img = int(np.min(np.nonzero(magenta.any(axis=0))[0]))
    left = shot[:, :x_img]
    red = _near(left, (230, 40, 40), tol=45)
    grey_robot = _near(left, (160, 160, 160), tol=12)
    info.update(image_left_x=x_img, red_px=int(red.sum()), robot_px=int(grey_robot.sum()))
    return True, red.sum() > 30 and grey_robot.sum() > 30, info


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    """One headless Chromium (selenium) for the module's recordings."""
    chromium, driver_bin = shutil.which("chromium"), shutil.which("chromedriver")
    assert chromium and driver_bin, "chromium and chromium-driver are required: run `make sysdeps-browser` (make test does)"
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    user_data = tempfile.mkdtemp(prefix="chromium-", dir=tmp_path_factory.mktemp("browser"))
    opts = Options()
    for f in CHROME_FLAGS + [f"--user-data-dir={user_data}", "--window-size=1600,1000"]:
        opts.add_argument(f)
    opts.binary_location = chromium
    driver = webdriver.Chrome(service=Service(driver_bin), options=opts)
    try:
        yield driver
    finally:
        driver.quit()


class _FileHandler(http.server.SimpleHTTPRequestHandler):
    """Serves a folder's files to the web viewer's page (another origin: another port) and logs nothing."""

    def end_headers(self):
        self.send_header("Access-Control-Allow-Origin", "*")
        super().end_headers()

    def log_message(self, *args):
        pass


def _view_until(driver, rrd: Path, shot_path: Path, check, timeout_s: float = 90.0) -> tuple[bool, bool, dict]:
    """Serve ``rrd`` by its URL with `rerun URL --serve-web`, open it in ``driver`` and take screenshots until
    ``check(shot)`` returns (True, True, info) or the time is up; the last check's result.

    The file goes to the viewer by an HTTP URL (a file server of this process) rather than as a path: given a path,
    `rerun --serve-web` keeps one thread polling the file at a full core for as long as it serves (about 10 s of CPU
    per recording viewed here); given the URL, it serves the web viewer alone and the page reads the file."""
    from PIL import Image

    handler = functools.partial(_FileHandler, directory=str(rrd.parent))
    files = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=files.serve_forever, daemon=True).start()
    url = f"http://127.0.0.1:{files.server_address[1]}/{quote(rrd.name)}"
    web_port, grpc_port = _free_port(), _free_port()
    server = subprocess.Popen(
        [_rerun_binary(), url, "--serve-web", "--bind", "127.0.0.1",
         "--web-viewer-port", str(web_port), "--port", str(grpc_port)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
    )
    try:
        deadline = time.time() + 20
        while time.time() < deadline:  # wait for the web server
            try:
                socket.create_connection(("127.0.0.1", web_port), timeout=0.5).close()
                break
            except OSError:
                assert server.poll() is None, "rerun --serve-web exited early"
                time.sleep(0.3)
        driver.get(f"http://127.0.0.1:{web_port}/?url={quote(url, safe='')}")
        result: tuple[bool, bool, dict] = (False, False, {})
        start = time.time()
        while time.time() < start + timeout_s and not (result[0] and result[1]):
            time.sleep(2.0)
            driver.save_screenshot(str(shot_path))
            result = check(np.asarray(Image.open(shot_path).convert("RGB")))
            print(f"{time.time() - start:.1f}s", result)
        return result
    finally:
        # The page keeps drawing (about 0.4 of a core with software GL) until the browser leaves it: leave it
        # before the next fixture or test runs.
        driver.get("about:blank")
        # The --serve-web process would outlive the test: stop it by its PID.
        os.kill(server.pid, signal.SIGTERM)
        try:
            server.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.kill(server.pid, signal.SIGKILL)
            server.wait(timeout=10)
        files.shutdown()
        files.server_close()


def test_recording_renders_in_headless_chromium(browser, tmp_path):
    """Opened in the web viewer that `rerun --serve-web` serves, the recording in headless Chromium shows the 3D view
    and an image."""
    rrd = make_synthetic_recording(tmp_path / "synthetic.rrd")
    shot_path = tmp_path / "viewer.png"
    ok_img, ok_3d, info = _view_until(browser, rrd, shot_path, _rendered)
    assert ok_img, f"no image rendered in the viewer (screenshot {shot_path}): {info}"
    assert ok_3d, f"3D view not rendered (screenshot {shot_path}): {info}"


# The diagnosis' 3-D views take the left part of the top row (after the viewer's own panel, before the residual
# plot): in a 1600-pixel-wide window about x 12-55 %, y 5-45 % of the page.
DIAGNOSIS_3D_REGION = (0.12, 0.55, 0.05, 0.45)


def _diagnosis_rendered(shot: np.ndarray) -> tuple[bool, bool, dict]:
    """(robot drawn, map and arrows drawn, details) in the 3-D views' region: the skeleton's bronze, and the colour
    map's cyan, green and yellow (colours nothing else of the viewer uses there: a diagnosis recording without the
    3-D views shows none of the three and under 50 pixels near the bronze)."""
    h, w = shot.shape[:2]
    x0, x1, y0, y1 = DIAGNOSIS_3D_REGION
    region = shot[int(y0 * h):int(y1 * h), int(x0 * w):int(x1 * w)]
    robot = _near(region, SKELETON_COLOUR, tol=12)
    cmap = np.zeros(region.shape[:2], dtype=bool)
    for _, name, rgb in COLOUR_STOPS:
        if name in ("cyan", "green", "yellow"):
            cmap |= _near(region, rgb, tol=30)
    info = {"robot_px": int(robot.sum()), "colour_map_px": int(cmap.sum())}
    return robot.sum() > 400, cmap.sum() > 50, info


@pytest.fixture(scope="module")
def diagnosis_rrd(tmp_path_factory):
    """A diagnosis recording written by `twin diagnose` on a small backlash dataset."""
    from twin.cli import main
    from twin.dataset import write_dataset

    root = tmp_path_factory.mktemp("diagbrowser")
    ds, _ = H.make_dataset(seed=7, n=60, effect=H.backlash())
    write_dataset(root / "ds", ds)
    assert main(["diagnose", str(root / "ds"), "--out", str(root / "out"), "--no-plots"]) == 0
    return root / "out" / "diagnosis.rrd"


def test_diagnosis_recording_shows_the_robot_and_the_residual_map(browser, diagnosis_rrd, tmp_path):
    """The diagnosis recording opened in the web viewer draws the robot's skeleton and the points and arrows coloured
    by their residual in its 3-D views."""
    shot_path = tmp_path / "diagnosis.png"
    ok_robot, ok_map, info = _view_until(browser, diagnosis_rrd, shot_path, _diagnosis_rendered)
    assert ok_robot, f"no robot in the diagnosis' 3-D views (screenshot {shot_path}): {info}"
    assert ok_map, f"no residual map in the diagnosis' 3-D views (screenshot {shot_path}): {info}"
