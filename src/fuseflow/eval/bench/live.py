"""``fuseflow bench live`` (and ``python -m benchmarks.live_replay``): recordings replayed as cameras through ``fuseflow live --serve`` with
one WebSocket viewer attached: sustained fused frames per second, drop rate, latency (capture to
sent) p50 / p95, and the viewer's bandwidth.

Cases (``CASES``):

* ``sim4``: a simulated 4-camera 320x240 dynamic studio (30 frames at 15 fps, Kinect-class noise,
  ground-truth extrinsics), replayed in a loop at 15 fps.
* ``hocap8``: the 8 real RealSense cameras of hocap-8rs (640x480, reference extrinsics), its one
  frame replayed in a loop at 10 fps (a static rig filming a static scene).
* ``hocap8-200k``: the same with ``--points 200000``: the bandwidth of a 200 k-point stream.

Every case uses ``--preset live``, the viewer codec ``codec`` (``compact`` by default, ``raw``
for the 9-byte format) and ``--preload`` (decoded frames in memory, as cameras deliver
them: the replay then costs no PNG decoding). The viewer is a Python WebSocket client in this
process of its own that reads every message as fast as it can. Bandwidth is reported twice: measured (bytes
the viewer received / seconds: it scales with the fused frames per second this machine reached)
and at the camera rate (bytes per frame x the replay rate: what the stream needs when fusion keeps
up); the 200 k target is judged on the latter.
"""

from __future__ import annotations

import json
import platform
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fuseflow.errors import ValidationError, require

__all__ = ["CASES", "LiveCase", "run_live_bench", "TARGETS"]


@dataclass(frozen=True)
class LiveCase:
    name: str
    rate: float
    points: int | None = None
    description: str = ""


CASES = {
    "sim4": LiveCase("sim4", 15.0, None, "simulated 4 x 320x240 dynamic studio, 15 fps"),
    "hocap8": LiveCase("hocap8", 10.0, None, "hocap-8rs: 8 real RealSense 640x480, 10 fps"),
    "hocap8-200k": LiveCase("hocap8-200k", 10.0, 200_000, "hocap-8rs at 10 fps, --points 200000"),
}

TARGETS = {
    "sim4": "<= 5 % drops and latency p95 <= 250 ms",
    "hocap8": ">= 10 fused frames/s",
    "hocap8-200k": "<= 20 Mbit/s per client at the camera rate",
}


def _target_met(case: str, row: dict[str, Any]) -> bool:
    if case == "sim4":
        return row["drop_rate"] <= 0.05 and (row["latency_ms_p95"] or 1e9) <= 250
    if case == "hocap8":
        return row["fps"] >= 10.0 * 0.98  # sustained: within 2 % of the 10 fps replay
    return row["mbit_per_s_at_rate"] <= 20.0


def _recording(case: str, work: Path, data_dir: Path | None) -> Path:
    if case == "sim4":
        from fuseflow.synth import SimConfig, simulate_recording

        cfg = SimConfig(cameras=4, frames=30, scene="studio", dynamic=True, resolution=(320, 240), seed=0, fps=15.0)
        simulate_recording(work / "sim4", cfg)
        return work / "sim4"
    from fuseflow.io.hocap import convert_hocap

    if data_dir is None or not (Path(data_dir) / "hocap-8rs").is_dir():
        raise ValidationError(f"bench live {case}: hocap-8rs not found in {data_dir} (pass --data-dir)")
    out = work / "hocap8"
    if not out.exists():
        convert_hocap(Path(data_dir) / "hocap-8rs", out, with_extrinsics=True)
    return out


_VIEWER = """
import sys
from websockets.sync.client import connect
frames = size = 0
try:
    with connect(sys.argv[1], max_size=None, open_timeout=10) as ws:
        ws.recv(timeout=10)
        print("ready", flush=True)
        for message in ws:
            frames += 1
            size += len(message)
except Exception:
    pass
print(frames, size, flush=True)
"""


class _Viewer:
    """A WebSocket client in a process of its own (it must not take CPU time from the fusion
    loop's interpreter) that reads every message and counts frames and bytes."""

    def __init__(self, url: str, codec: str = "compact"):
        self.url = url.replace("http://", "ws://") + "ws?codec=" + codec
        self.frames = 0
        self.bytes = 0
        self.proc = subprocess.Popen([sys.executable, "-c", _VIEWER, self.url], stdout=subprocess.PIPE, text=True)
        if self.proc.stdout.readline().strip() != "ready":
            self.proc.kill()
            raise ValidationError(f"bench live: the viewer could not connect to {self.url}")

    def finish(self) -> None:
        """Wait for the viewer to see the server close, and read its counts."""
        out, _ = self.proc.communicate(timeout=30)
        frames, size = out.split()[-2:]
        self.frames, self.bytes = int(frames), int(size)


def _stand_in(recording: Any, points: int | None, ms: float) -> Callable:
    """A fusion that takes ``ms`` of wall time without using the CPU (a sleep) and returns the
    real FUSE cloud of the recording's first frame: it measures everything but FUSE itself."""
    from fuseflow.fuse import fuse
    from fuseflow.fuse.presets import preset_config

    cloud = fuse(recording[0], recording.rig, preset_config("live", points))

    def fuse_fn(frame: Any, rig: Any) -> tuple[Any, float]:
        time.sleep(ms / 1000.0)
        return cloud, ms

    return fuse_fn


def _run_case(
    case: LiveCase, rec: Path, duration: float, stand_in_ms: float | None = None, codec: str = "compact"
) -> dict[str, Any]:
    from fuseflow.io import open_recording
    from fuseflow.live import LiveOutputs, run_live
    from fuseflow.live.loop import LiveSettings
    from fuseflow.live.sources.replay import ReplaySource

    recording = open_recording(rec)
    source = ReplaySource(recording, rate=case.rate, loop=True, preload=True)
    viewers: list[_Viewer] = []
    settings = LiveSettings(preset="live", points=case.points, duration=duration)
    fuse_fn = _stand_in(recording, case.points, stand_in_ms) if stand_in_ms is not None else None
    res = run_live(source, None, settings, LiveOutputs(serve=("127.0.0.1", 0)),
                   on_start=lambda url, _w: viewers.append(_Viewer(url, codec)), fuse_fn=fuse_fn)  # fmt: skip
    viewers[0].finish()
    s, client = res.summary, (res.clients[0] if res.clients else {})
    row = {
        "case": case.name, "data": case.description, "fusion": "FUSE" if stand_in_ms is None else
        f"stand-in: sleeps {stand_in_ms:g} ms, returns frame 0's FUSE cloud", "cameras": len(recording.rig),
        "resolution": "x".join(map(str, recording.rig.resolution)), "rate": case.rate, "preset": "live",
        "points_target": case.points, "duration_s": s.wall_s, "frames_in": s.frames_in, "frames_out": s.frames_out,
        "dropped": s.dropped, "drop_rate": round(s.drop_rate, 4), "fps": s.fps, "latency_ms_p50": s.latency_ms_p50,
        "latency_ms_p95": s.latency_ms_p95, "fuse_ms_median": s.fuse_ms_median, "points_mean": s.points_mean,
        "codec": codec, "encode_ms_median": res.encode_ms_median,
        "encode_cpu_ms_median": res.encode_cpu_ms_median, "encoder_skipped": res.encoder_skipped,
        "client_frames": viewers[0].frames, "client_fps": round(viewers[0].frames / max(s.wall_s, 1e-9), 2),
        "client_dropped": client.get("dropped"),
        "bytes_per_frame": round(viewers[0].bytes / max(viewers[0].frames, 1)),
        "mbit_per_s": round(viewers[0].bytes * 8 / max(s.wall_s, 1e-9) / 1e6, 2),
    }  # fmt: skip
    # what the stream needs when fusion keeps up with the cameras: bytes per frame x the camera rate
    row["mbit_per_s_at_rate"] = round(row["bytes_per_frame"] * 8 * case.rate / 1e6, 2)
    row["bytes_per_point"] = round(row["bytes_per_frame"] / max(s.points_mean, 1.0), 3)
    row["target"] = TARGETS[case.name]
    row["target_met"] = _target_met(case.name, row)
    return row


def format_row(r: dict[str, Any]) -> str:
    return (
        f"{r['case']:<12} {'' if r['fusion'] == 'FUSE' else '(stand-in) '}{r['cameras']} x {r['resolution']} @ {r['rate']:g} fps: {r['fps']:.2f} fused/s, "
        f"drops {r['drop_rate']:.1%}, latency p50 {r['latency_ms_p50']} / p95 {r['latency_ms_p95']} ms, "
        f"FUSE {r['fuse_ms_median']} ms, encode {r['encode_ms_median']} ms ({r['encode_cpu_ms_median']} CPU), {r['points_mean']:.0f} points, "
        f"{r['codec']} {r['bytes_per_frame']} B/frame ({r['bytes_per_point']} B/point), viewer {r['client_fps']} fps, "
        f"{r['mbit_per_s']:.1f} Mbit/s per client ({r['mbit_per_s_at_rate']:.1f} at {r['rate']:g} fps) "
        f"[{r['target']}: {'met' if r['target_met'] else 'MISSED'}]"
    )


def run_live_bench(
    cases: list[str],
    duration: float = 20.0,
    data_dir: Path | None = None,
    json_path: Path | None = None,
    command: str = "",
    stand_in_ms: float | None = None,
    log: Callable[[str], None] = lambda s: None,
    codec: str = "compact",
) -> list[dict[str, Any]]:
    """Run each case for ``duration`` seconds; one row per case (also written to ``json_path``).

    ``stand_in_ms``: replace FUSE by a stand-in that sleeps this long and returns a real fused
    cloud (``_stand_in``): the capture, mailbox, encoding, server and viewer measured with a
    fusion of known duration and no CPU use, e.g. FUSE's time on a quiet machine. ``codec``: the
    viewer's frame codec (``fuseflow.live.wire.CODECS``)."""
    require("websockets", "live", "bench live")
    from fuseflow.live.wire import CODECS

    if codec not in CODECS:
        raise ValidationError(f"bench live: --codec must be one of {', '.join(CODECS)}, got {codec!r}")
    unknown = [c for c in cases if c not in CASES]
    if unknown:
        raise ValidationError(f"bench live: unknown cases {unknown}; cases are {sorted(CASES)}")
    import torch

    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_live_") as tmp:
        for name in cases:
            rec = _recording(name, Path(tmp), data_dir)
            row = _run_case(CASES[name], rec, duration, stand_in_ms, codec)
            log(format_row(row))
            rows.append(row)
    meta = {"command": command, "machine": platform.processor() or platform.machine(), "cpus": torch.get_num_threads(),
            "torch": torch.__version__, "date": time.strftime("%Y-%m-%d %H:%M")}  # fmt: skip
    if json_path is not None:
        Path(json_path).parent.mkdir(parents=True, exist_ok=True)
        Path(json_path).write_text(json.dumps({"meta": meta, "rows": rows}, indent=1) + "\n")
    return rows
