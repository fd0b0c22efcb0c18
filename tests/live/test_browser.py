"""The viewer in a real browser: `fuseflow live` on a small replay, headless Chromium (Debian's
chromium + chromium-driver, driven by selenium) opens the page; frames in the default (compact)
codec must decode, the frame counter advance and the canvas show points. Ctrl-C then stops the
command with its summary."""

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

webdriver = pytest.importorskip("selenium.webdriver")

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
DRIVER = shutil.which("chromedriver")
pytestmark = pytest.mark.skipif(  # never skipped in CI, where scripts/setup.sh test installs them
    not (CHROMIUM and DRIVER) and not os.environ.get("CI"),
    reason="needs chromium and chromedriver (scripts/setup.sh test installs them)",
)
ROOT = Path(__file__).resolve().parents[2]


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stats(port):
    return json.loads(urllib.request.urlopen(f"http://127.0.0.1:{port}/stats", timeout=2).read())


def _browser():
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for a in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=640,480",
              "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--disable-gpu-sandbox"):  # fmt: skip
        opts.add_argument(a)
    return webdriver.Chrome(options=opts, service=webdriver.ChromeService(executable_path=DRIVER))


def _wait_for(condition, seconds):
    """True once ``condition()`` holds, False after ``seconds`` (generous: a loaded CI machine)."""
    deadline = time.time() + seconds
    while not condition():
        if time.time() > deadline:
            return False
        time.sleep(0.1)
    return True


def _frames(driver):
    return int(driver.find_element("id", "frames").text or 0)


def test_page_draws_live_frames(dynamic_rec, tmp_path):
    port = _free_port()
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    cmd = [sys.executable, "-m", "fuseflow", "live", str(dynamic_rec), "--loop", "--rate", "5", "--preload",
           "--serve", str(port), "--duration", "300"]  # fmt: skip
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    driver = None
    try:
        deadline = time.time() + 40
        while True:  # the server is up once /stats answers
            try:
                _stats(port)
                break
            except OSError:
                assert proc.poll() is None and time.time() < deadline, (
                    proc.stdout.read() if proc.poll() else "no server"
                )
                time.sleep(0.2)
        driver = _browser()
        driver.get(f"http://127.0.0.1:{port}/")
        first = _wait_for(lambda: _frames(driver) >= 1, 90) and _frames(driver)  # cold: kernels compile
        later = _wait_for(lambda: _frames(driver) > first, 30) and _frames(driver)
        assert first >= 1 and later > first, (first, later)  # frames arrive and the counter advances
        assert int(driver.find_element("id", "cameras").text) == 4
        stats = driver.execute_script("return window.fuseflowStats")  # decode.js decoded them
        assert stats["version"] == 3 and driver.find_element("id", "codec").text == "compact", stats
        assert len(stats["decodeMs"]) >= 2 and "bad frame" not in driver.find_element("id", "status").text
        assert _stats(port)["clients"] == 1
        shot = tmp_path / "viewer.png"
        driver.save_screenshot(str(shot))
        shutil.copy(shot, Path(os.environ.get("FUSEFLOW_SCREENSHOT", tmp_path / "copy.png")))
        import cv2

        img = cv2.imread(str(shot))
        background = np.array([26, 22, 20])  # BGR of the page's clear colour (0.08, 0.086, 0.1)
        drawn = np.abs(img[120:, :].astype(int) - background).sum(-1) > 40  # below the text overlay
        assert drawn.mean() > 0.01, f"only {drawn.mean():.3%} of the canvas is drawn"
        assert len(np.unique(img[120:][drawn].reshape(-1, 3) // 32, axis=0)) > 5  # coloured points, not one flat colour
    finally:
        if driver is not None:
            driver.quit()
        proc.send_signal(signal.SIGINT)  # Ctrl-C
        out, _ = proc.communicate(timeout=30)
    assert proc.returncode == 0, out
    assert "interrupted" in out and "fused" in out
