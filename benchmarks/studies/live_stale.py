"""The age of the frame a slow viewer shows (``python -m benchmarks.live_stale``): a recording replayed
as cameras through the live loop and its server; one viewer, in a process of its own, that needs
``viewer_ms`` to decode and show a frame and acknowledges each frame once shown (``/ws?ack=1``, as
the page does). Per frame shown: its age, from the capture stamp (the source's release time, in
the server's clock: the same machine) to the moment it is shown, split into capture to sent
(``sent_age``: fusion, encoding and the wait for the acknowledgement), sent to the viewer starting
on it (``in_transit``) and the viewer's own time (``busy``). Bound checked per frame: age <= 2 frame
intervals + busy. Cases: ``sim4`` (a simulated 4-camera 320x240 dynamic studio, 30 frames, looped),
``hocap8`` (hocap-8rs: 8 real RealSense 640x480, its frame looped); FUSE preset ``live`` on the
CPU, compact codec; ``stand_in_ms`` replaces FUSE by a sleep.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

__all__ = ["run_stale_bench"]

_VIEWER = r"""
import json, sys, time
from websockets.sync.client import connect
from fuseflow.live.wire import decode_frame

url, work_ms, seconds = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
rows, meta = [], None
with connect(url, max_size=None, open_timeout=10) as ws:
    ws.recv(timeout=10)  # the rig
    print("ready", flush=True)
    end = time.time() + seconds
    while time.time() < end:
        try:
            m = ws.recv(timeout=5)
        except TimeoutError:
            break
        if isinstance(m, str):
            doc = json.loads(m)
            if doc.get("type") == "frame":
                meta = doc
            elif doc.get("type") in ("end", "error"):
                break
            continue
        t0 = time.perf_counter()
        frame = decode_frame(m)
        decode_ms = (time.perf_counter() - t0) * 1000
        rest = work_ms / 1000 - (time.perf_counter() - t0)
        if rest > 0:
            time.sleep(rest)  # the rest of a slow viewer's work on this frame (drawing it)
        shown = time.time()
        busy_ms = (time.perf_counter() - t0) * 1000
        age = (shown - meta["captured"]) * 1000
        rows.append({"number": meta["number"], "age_ms": age, "busy_ms": busy_ms, "decode_ms": decode_ms,
                     "sent_age_ms": meta["age_ms"], "points": len(frame.xyz)})
        ws.send(json.dumps({"type": "ack", "number": meta["number"], "age_ms": round(age, 1),
                            "decode_ms": round(busy_ms, 1), "dropped": 0, "held_ms": 0}))
print(json.dumps(rows), flush=True)
"""


def _recording(case: str, work: Path, data_dir: Path) -> Path:
    if case == "sim4":
        from fuseflow.synth import SimConfig, simulate_recording

        cfg = SimConfig(cameras=4, frames=30, scene="studio", dynamic=True, resolution=(320, 240), seed=0, fps=15.0)
        simulate_recording(work / "sim4", cfg)
        return work / "sim4"
    from fuseflow.io.hocap import convert_hocap

    convert_hocap(data_dir / "hocap-8rs", work / "hocap8", with_extrinsics=True)
    return work / "hocap8"


def _stand_in(recording, ms: float):
    """A fusion that sleeps ``ms`` (no CPU) and returns frame 0's FUSE cloud: the protocol's share of
    the age without this machine's fusion speed in it."""
    import time

    from fuseflow.fuse import fuse
    from fuseflow.fuse.presets import preset_config

    cloud = fuse(recording[0], recording.rig, preset_config("live", None))

    def fuse_fn(frame, rig):
        time.sleep(ms / 1000.0)
        return cloud, ms

    return fuse_fn


def _run_case(case: str, rec: Path, rate: float, viewer_ms: float, duration: float, stand_in_ms: float | None) -> dict:
    from fuseflow.io import open_recording
    from fuseflow.live import LiveOutputs, run_live
    from fuseflow.live.loop import LiveSettings
    from fuseflow.live.sources.replay import ReplaySource

    recording = open_recording(rec)
    source = ReplaySource(recording, rate=rate, loop=True, preload=True)
    procs: list[subprocess.Popen] = []

    def start(url: str, _warnings: list[str]) -> None:
        ws = url.replace("http://", "ws://") + "ws?ack=1"
        p = subprocess.Popen([sys.executable, "-c", _VIEWER, ws, str(viewer_ms), str(duration - 3)],
                             stdout=subprocess.PIPE, text=True)  # fmt: skip
        assert p.stdout.readline().strip() == "ready"
        procs.append(p)

    fuse_fn = _stand_in(recording, stand_in_ms) if stand_in_ms is not None else None
    res = run_live(source, None, LiveSettings(preset="live", duration=duration), LiveOutputs(serve=("127.0.0.1", 0)),
                   on_start=start, fuse_fn=fuse_fn)  # fmt: skip
    out, _ = procs[0].communicate(timeout=60)
    rows = json.loads(out.strip().splitlines()[-1])[2:]  # the first two: the kernels of a cold viewer
    interval = 1000.0 / rate
    age = np.array([r["age_ms"] for r in rows])
    busy = np.array([r["busy_ms"] for r in rows])
    over = age - (2 * interval + busy)
    sent = np.array([r["sent_age_ms"] for r in rows])
    s = res.summary
    return {
        "case": case, "fusion": "FUSE" if stand_in_ms is None else f"stand-in {stand_in_ms:g} ms", "cameras": len(recording.rig), "resolution": "x".join(map(str, recording.rig.resolution)),
        "rate": rate, "viewer_ms": viewer_ms, "frames_shown": len(rows),
        "viewer_fps": round(len(rows) / max(duration - 3, 1e-9), 2),
        "age_ms_median": round(float(np.median(age)), 1), "age_ms_p95": round(float(np.percentile(age, 95)), 1),
        "age_ms_max": round(float(age.max()), 1), "busy_ms_median": round(float(np.median(busy)), 1),
        "age_minus_busy_ms_max": round(float((age - busy).max()), 1),
        "sent_age_ms_median": round(float(np.median(sent)), 1), "sent_age_ms_max": round(float(sent.max()), 1),
        "in_transit_ms_max": round(float((age - busy - sent).max()), 1), "bound_ms": f"2 x {interval:g} + busy",
        "frames_over_bound": int((over > 0).sum()), "worst_over_bound_ms": round(float(over.max()), 1),
        "fused_fps": s.fps, "latency_ms_p50": s.latency_ms_p50, "latency_ms_p95": s.latency_ms_p95,
        "fuse_ms_median": s.fuse_ms_median, "drop_rate": round(s.drop_rate, 4),
        "server_age_ms_max": (res.clients[0] if res.clients else {}).get("age_ms_max"),
        "server_dropped_for_viewer": (res.clients[0] if res.clients else {}).get("dropped"),
    }  # fmt: skip


def run_stale_bench(cases: list[str], rate: float = 10.0, viewer_ms: float = 500.0, duration: float = 20.0,
                    data_dir: Path = Path("../shared/data"), stand_in_ms: float | None = None,
                    log: Callable[[str], None] = print) -> list[dict]:  # fmt: skip
    """One row per case (each also handed to ``log`` as a JSON line)."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="fuseflow-stale-") as tmp:
        for case in cases:
            rec = _recording(case, Path(tmp), Path(data_dir))
            row = _run_case(case, rec, rate, viewer_ms, duration, stand_in_ms)
            log(json.dumps(row))
            rows.append(row)
    return rows
