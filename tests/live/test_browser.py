"""The viewer in a real browser: `fuseflow live` on a small replay, headless Chromium (Debian's
chromium + chromium-driver, driven by selenium) opens the page; frames in the default (compact)
codec must decode, the frame counter advance and the canvas show points. Ctrl-C then stops the
command with its summary. A server bound to all addresses: the page without its token, a page
of another origin and a page reached under another host name get nothing; the end of the replay
shows "ended"; the page then idles; with WebXR stubbed to offer immersive-vr, the page offers
"Enter VR" and draws in the XR loop."""

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


def _browser(*extra):
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for a in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=640,480",
              "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--disable-gpu-sandbox", *extra):  # fmt: skip
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
        # after a key frame the page holds the previous frame and is sent deltas (version 6); a frame
        # dropped for a slow page is followed by a key frame (version 7), so wait for a delta
        _wait_for(lambda: driver.execute_script("return window.fuseflowStats.version") == 6, 30)
        stats = driver.execute_script("return window.fuseflowStats")  # decode.js decoded them
        assert stats["version"] == 6 and driver.find_element("id", "codec").text == "compact", stats
        assert len(stats["decodeMs"]) >= 2 and "bad frame" not in driver.find_element("id", "status").text
        assert stats["split"] >= 1, stats  # the first (key) frame's geometry decoded in the page's worker
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


def _start_live(args, port):
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    cmd = [sys.executable, "-m", "fuseflow", "live", *map(str, args), "--serve", f"0.0.0.0:{port}"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    url, deadline = None, time.time() + 60
    while url is None:  # the command prints the address (with its token) once it serves
        line = proc.stdout.readline()
        assert line and time.time() < deadline, "no address printed"
        if "viewer at" in line or "?token=" in line:
            url = line[line.index("http://") :].split()[0] if "http://" in line else None
        if url is None and "viewer at" in line:  # the console wrapped the address onto the next line
            url = proc.stdout.readline().split()[0]
    return proc, url


def _cpu_seconds(root_pid):
    """User + system CPU seconds of ``root_pid`` and every process below it (Linux /proc)."""
    children, total = {}, 0.0
    for d in Path("/proc").iterdir():
        try:
            fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
            children.setdefault(int(fields[1]), []).append((int(d.name), int(fields[11]) + int(fields[12])))
        except (OSError, ValueError, IndexError):
            continue
    todo = [root_pid]
    while todo:
        for pid, ticks in children.get(todo.pop(), []):
            total += ticks / os.sysconf("SC_CLK_TCK")
            todo.append(pid)
    return total


XR_STUB = """
(() => {
  window.__xr = { sessions: 0 };
  delete window.XRWebGLBinding;  // the stub session has no projection layers: an XRWebGLLayer it is
  for (const C of [window.WebGLRenderingContext, window.WebGL2RenderingContext])
    if (C) C.prototype.makeXRCompatible = () => Promise.resolve();
  window.XRWebGLLayer = class { constructor() { this.framebuffer = null; this.framebufferWidth = 640;
    this.framebufferHeight = 480; this.ignoreDepthValues = true; this.antialias = false; }
    getViewport() { return { x: 0, y: 0, width: 640, height: 480 }; } };
  const f = 1 / Math.tan(0.5), proj = new Float32Array([f / 1.33, 0, 0, 0, 0, f, 0, 0, 0, 0, -1.0002, -1, 0, 0, -0.02, 0]);
  const eye = new Float32Array([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 1.6, 0, 1]);
  const pose = { transform: { matrix: eye, position: { x: 0, y: 1.6, z: 0 }, orientation: { x: 0, y: 0, z: 0, w: 1 } },
    views: [{ eye: "none", projectionMatrix: proj, transform: { matrix: eye, position: { x: 0, y: 1.6, z: 0 },
      orientation: { x: 0, y: 0, z: 0, w: 1 } } }] };
  class Session extends EventTarget {
    constructor() { super(); this.inputSources = []; this.renderState = {}; this.enabledFeatures = []; this.visibilityState = "visible"; }
    updateRenderState(s) { Object.assign(this.renderState, s); }
    requestReferenceSpace() { return Promise.resolve({ getOffsetReferenceSpace() { return this; } }); }
    requestAnimationFrame(cb) { return window.requestAnimationFrame((t) => cb(t, { session: this, getViewerPose: () => pose, getPose: () => null })); }
    cancelAnimationFrame(id) { window.cancelAnimationFrame(id); }
    end() { this.dispatchEvent(new Event("end")); return Promise.resolve(); }
  }
  const xr = new EventTarget();
  xr.isSessionSupported = (mode) => Promise.resolve(mode === "immersive-vr");
  xr.requestSession = () => { window.__xr.sessions += 1; return Promise.resolve(new Session()); };
  Object.defineProperty(navigator, "xr", { value: xr, configurable: true });
})();
"""


def _text(driver):
    return driver.find_element("tag name", "body").text


def test_access_end_idle_and_xr(dynamic_rec, tmp_path):
    """One server on 0.0.0.0 replaying 5 frames at 2 fps, then holding the last one."""
    import http.server
    import threading

    port, other = _free_port(), _free_port()
    proc, url = _start_live([dynamic_rec, "--rate", "2", "--preload", "--hold", "--codec", "raw"], port)
    assert "0.0.0.0" not in url and "?token=" in url
    token = url.split("?token=")[1]
    page = (b"<script>window.got = []; const ws = new WebSocket('ws://127.0.0.1:%d/ws');"
            b"ws.onmessage = (e) => window.got.push(String(e.data).slice(0, 40));"
            b"ws.onclose = () => window.wsClosed = true;</script>" % port)  # fmt: skip

    class Evil(http.server.BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802 - the http.server name
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.end_headers()
            self.wfile.write(page)

        def log_message(self, *a):
            pass

    evil = http.server.HTTPServer(("127.0.0.1", other), Evil)
    threading.Thread(target=evil.serve_forever, daemon=True).start()
    driver = _browser("--host-resolver-rules=MAP attacker.example 127.0.0.1, MAP evil.example 127.0.0.1")
    try:
        driver.get(f"http://127.0.0.1:{port}/")  # no token
        assert "needs its token" in _text(driver)
        driver.get(f"http://attacker.example:{port}/?token={token}")  # a rebound name: wrong Host
        assert "is not this server's address" in _text(driver)
        driver.get(f"http://evil.example:{other}/")  # another origin's page opens our socket
        assert _wait_for(lambda: driver.execute_script("return window.wsClosed === true"), 10)
        assert driver.execute_script("return window.got") == []
        refused = json.loads(urllib.request.urlopen(f"http://127.0.0.1:{port}/stats?token={token}").read())["refused"]
        assert set(refused) == {"token", "host", "origin"} and refused["origin"] == 1, refused  # (+ favicon.ico)
        driver.get(f"http://127.0.0.1:{port}/?token={token}")
        assert _wait_for(lambda: "replay ended" in driver.find_element("id", "status").text, 120), _text(driver)
        stats = driver.execute_script("return window.fuseflowStats")
        assert stats["frames"] >= 1 and _frames(driver) >= 1
        if stats.get("lastFrameAt") and stats["frames"] > 1:  # it watched the replay's end live
            assert stats["endedAt"] - stats["lastFrameAt"] < 1000
        # idle: nothing changes, so nothing is drawn (< 2 % of a core for the whole browser)
        time.sleep(3.0)  # the page load settles
        renders, cpu0, t0 = stats["renders"], _cpu_seconds(driver.service.process.pid), time.time()
        time.sleep(5.0)
        busy = (_cpu_seconds(driver.service.process.pid) - cpu0) / (time.time() - t0)
        assert driver.execute_script("return window.fuseflowStats.renders") == renders
        assert busy < 0.02, f"the idle page used {busy:.1%} of a core"
        # colour by camera (raw codec: each point's camera comes with the frame): the frustum colours
        rgb = len(driver.execute_script("return window.fuseflowColours()"))
        driver.execute_script("const s = document.getElementById('colour'); s.value = 'camera';"
                              "s.dispatchEvent(new Event('change'))")  # fmt: skip
        by_camera = driver.execute_script("return window.fuseflowColours()")
        assert 2 <= len(by_camera) <= 4 < rgb, (len(by_camera), rgb)  # 4 cameras, one colour each
        # WebXR offered by the (stubbed) browser: "Enter VR", and drawing in the XR loop
        driver.execute_cdp_cmd("Page.addScriptToEvaluateOnNewDocument", {"source": XR_STUB})
        driver.get(f"http://127.0.0.1:{port}/?token={token}")
        assert _wait_for(lambda: "ENTER VR" in _text(driver).upper(), 30), _text(driver)
        assert _wait_for(lambda: _frames(driver) >= 1, 30)
        button = next(b for b in driver.find_elements("tag name", "button") if "ENTER VR" in b.text.upper())
        before = driver.execute_script("return window.fuseflowStats.renders")
        button.click()
        assert _wait_for(lambda: driver.execute_script("return window.fuseflowStats.xrFrames") >= 10, 30)
        assert driver.execute_script("return window.__xr.sessions") == 1
        assert driver.execute_script("return window.fuseflowStats.renders") >= before + 10
    finally:
        driver.quit()
        evil.shutdown()
        proc.send_signal(signal.SIGTERM)
        try:
            out, _ = proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            raise
    assert proc.returncode == 0, out
    assert "terminated" in out and "held" in out
