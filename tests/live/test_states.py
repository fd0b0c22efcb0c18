"""`fuseflow live` states: the end of a replay, --hold, a one-frame recording, SIGTERM with a
summary and complete files, --record never replacing or mixing a recording, `info` on a
--record folder, and bad --serve / --duration values."""

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import fuseflow
from fuseflow.cli import app
from fuseflow.live import LiveOutputs, ReplayOptions, open_source, run_live
from fuseflow.live.app import StopRequest
from fuseflow.live.loop import LiveSettings

ROOT = Path(__file__).resolve().parents[2]
K = [[40.0, 0, 15.5], [0, 40.0, 11.5], [0, 0, 1]]


def _invoke(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def _recording(path, frames):
    """Three 32x24 cameras side by side, looking at a wall 1.5 m away, with extrinsics."""
    cams = []
    for i in range(3):
        T = np.eye(4)
        T[0, 3] = -0.05 * i
        cams.append(fuseflow.Camera(f"{900 + i}", 32, 24, K, T_cam_world=T))
    rig = fuseflow.Rig(tuple(cams))
    rng = np.random.default_rng(4)
    for t in range(frames):
        color = rng.integers(0, 255, (3, 24, 32, 3), dtype=np.uint8)
        fuseflow.write_frame(path, rig, t, color, np.full((3, 24, 32), 1.5))
    fuseflow.write_rig(path, rig)
    return path


def test_bad_serve_and_duration_are_clear_errors(dynamic_rec):
    res = _invoke("live", dynamic_rec, "--serve", "")
    assert res.exit_code == 2 and "--serve expects [HOST:]PORT" in res.output and "empty" in res.output
    for bad in ("nan", "inf"):
        res = _invoke("live", dynamic_rec, "--duration", bad)
        assert res.exit_code == 2 and "--duration must be a finite number" in res.output
    res = _invoke("live", dynamic_rec, "--hold")
    assert res.exit_code == 2 and "--hold" in res.output and "--serve" in res.output
    res = _invoke("live", dynamic_rec, "--serve", "0", "--token", "short")
    assert res.exit_code == 2 and "--token" in res.output


def test_record_refuses_an_existing_recording_and_info_reads_it(tmp_path):
    rec = _recording(tmp_path / "rec", frames=3)
    out = tmp_path / "out"
    res = _invoke("live", rec, "--rate", "5", "--record", out)
    assert res.exit_code == 0, res.output
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    res = _invoke("live", rec, "--rate", "20", "--record", out)
    assert res.exit_code == 2 and "already holds" in res.output and "frames.jsonl" in res.output
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before  # nothing replaced
    other = tmp_path / "other"
    (other / "clouds").mkdir(parents=True)
    (other / "clouds" / "000000.ply").write_text("mine")
    res = _invoke("live", rec, "--rate", "20", "--record", other)
    assert res.exit_code == 2 and "clouds/ (1 .ply)" in res.output
    assert (other / "clouds" / "000000.ply").read_text() == "mine"
    n = len((out / "frames.jsonl").read_text().splitlines())  # 3, fewer where fusion falls behind
    res = _invoke("info", out)
    text = " ".join(res.output.split())  # the console wraps long lines
    assert res.exit_code == 0, res.output
    assert "fuseflow live recording" in text and f"{n} frame" in text and f"{n} cloud" in text
    doc = json.loads(_invoke("info", out, "--json").output)
    assert n >= 1 and doc["frames"] == doc["clouds"] == n and doc["cameras"] == ["900", "901", "902"]
    assert doc["points"]["min"] > 0 and doc["clouds_not_logged"] == [] == doc["logged_without_cloud"]


def test_one_frame_recording_hints_at_hold(tmp_path):
    pytest.importorskip("websockets")
    rec = _recording(tmp_path / "rec", frames=1)
    res = _invoke("live", rec, "--serve", "0")
    assert res.exit_code == 0 and "one frame" in res.output and "--hold" in res.output


def test_hold_serves_the_last_frame_after_the_replay(tmp_path):
    ws_client = pytest.importorskip("websockets.sync.client")
    rec = _recording(tmp_path / "rec", frames=2)
    opened = open_source([str(rec)], ReplayOptions(rate=20.0))
    stop, urls, out = StopRequest(), [], {}
    outputs = LiveOutputs(serve=("127.0.0.1", 0), codec="raw", hold=True)

    def run():
        out["result"] = run_live(opened, None, LiveSettings(), outputs, on_start=lambda u, w: urls.append(u), stop=stop)

    thread = threading.Thread(target=run)
    thread.start()
    try:
        deadline = time.time() + 60
        while not urls and time.time() < deadline:
            time.sleep(0.05)
        time.sleep(1.0)  # the replay (2 frames at 20 fps) is over: the server holds its last frame
        url = urls[0].replace("http://", "ws://") + "ws"
        with ws_client.connect(url, open_timeout=5, max_size=None) as c:
            assert json.loads(c.recv(timeout=5))["type"] == "rig"
            frame = fuseflow.live.decode_frame(c.recv(timeout=10))
            assert len(frame.xyz) > 0
            end = json.loads(c.recv(timeout=5))
            assert end["type"] == "end" and "held" in end["reason"]
    finally:
        stop.set("terminated")
        thread.join(timeout=30)
    result = out["result"]
    assert result.summary.stopped_by == "end of source" and result.held_s > 0.5


SIGNAL_WHILE_WAITING = """
import os, random, signal, threading
from fuseflow.live import StopRequest
stop = None
signal.signal(signal.SIGUSR1, lambda *a: stop.set("terminated"))
for trial in range(300):
    stop = StopRequest()
    threading.Timer(random.uniform(0.0002, 0.003), os.kill, (os.getpid(), signal.SIGUSR1)).start()
    while not stop.wait(0):  # the main thread waits on the request when the signal comes
        pass
    assert stop.reason == "terminated"
print("300 stops")
"""


def test_a_signal_handler_stops_a_waiting_main_thread():
    """``StopRequest.set`` from a signal handler while the main thread is in ``wait``: the
    request lands every time (a ``threading.Event`` deadlocks here within a few tries)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    res = subprocess.run([sys.executable, "-c", SIGNAL_WHILE_WAITING], env=env, capture_output=True, text=True,
                         timeout=60)  # fmt: skip
    assert res.returncode == 0 and "300 stops" in res.stdout, res.stderr


def test_sigterm_stops_with_a_summary_and_complete_files(dynamic_rec, tmp_path):
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    cmd = [sys.executable, "-m", "fuseflow", "live", str(dynamic_rec), "--loop", "--rate", "10", "--record", str(out)]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.time() + 120
        log = out / "frames.jsonl"
        while not (log.exists() and len(log.read_text().splitlines()) >= 3):
            assert proc.poll() is None and time.time() < deadline, proc.stdout.read() if proc.poll() is not None else ""
            time.sleep(0.1)
        proc.send_signal(signal.SIGTERM)
        text, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, text
    assert "terminated" in text and "fused" in text
    assert not list(out.rglob("*.tmp"))
    lines = (out / "frames.jsonl").read_text().splitlines()
    assert len(lines) == len(list((out / "clouds").glob("*.ply")))
