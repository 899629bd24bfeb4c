"""The campaign recording in a real browser: Rerun's web viewer in headless Chromium, checked by pixels."""

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_recording import make_synthetic_recording  # noqa: E402

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


def test_recording_renders_in_headless_chromium(tmp_path):
    """Served with `rerun --serve-web`, the web viewer in headless Chromium shows the 3D view and an image."""
    chromium, driver_bin = shutil.which("chromium"), shutil.which("chromedriver")
    assert chromium and driver_bin, "chromium and chromium-driver are required: run `make sysdeps-browser` (make test does)"
    from PIL import Image
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    rrd = make_synthetic_recording(tmp_path / "synthetic.rrd")
    web_port, grpc_port = _free_port(), _free_port()
    server = subprocess.Popen(
        [_rerun_binary(), str(rrd), "--serve-web", "--bind", "127.0.0.1",
         "--web-viewer-port", str(web_port), "--port", str(grpc_port)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
    )
    user_data = tempfile.mkdtemp(prefix="chromium-", dir=tmp_path)
    driver = None
    try:
        deadline = time.time() + 20
        while time.time() < deadline:  # wait for the web server
            try:
                socket.create_connection(("127.0.0.1", web_port), timeout=0.5).close()
                break
            except OSError:
                assert server.poll() is None, "rerun --serve-web exited early"
                time.sleep(0.3)
        opts = Options()
        for f in CHROME_FLAGS + [f"--user-data-dir={user_data}", "--window-size=1600,1000"]:
            opts.add_argument(f)
        opts.binary_location = chromium
        driver = webdriver.Chrome(service=Service(driver_bin), options=opts)
        url = f"http://127.0.0.1:{web_port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc_port}%2Fproxy"
        driver.get(url)
        shot_path = tmp_path / "viewer.png"
        ok_img = ok_3d = False
        info: dict = {}
        deadline = time.time() + 90
        while time.time() < deadline and not (ok_img and ok_3d):
            time.sleep(2.0)
            driver.save_screenshot(str(shot_path))
            shot = np.asarray(Image.open(shot_path).convert("RGB"))
            ok_img, ok_3d, info = _rendered(shot)
            print(f"{time.time() - deadline + 90:.1f}s", ok_img, ok_3d, info)
        assert ok_img, f"no image rendered in the viewer (screenshot {shot_path}): {info}"
        assert ok_3d, f"3D view not rendered (screenshot {shot_path}): {info}"
    finally:
        if driver is not None:
            driver.quit()
        # The --serve-web process keeps a core busy after the browser leaves: stop it by its PID.
        os.kill(server.pid, signal.SIGTERM)
        try:
            server.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.kill(server.pid, signal.SIGKILL)
            server.wait(timeout=10)
