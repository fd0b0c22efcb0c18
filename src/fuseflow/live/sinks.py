"""Where the live loop's fused clouds go: the web viewer (``WebSink``), rerun (``RerunSink``),
PLY files (``RecordSink``). Each has ``send(cloud, info)`` (called in the fusion loop) and
``close()``."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

from fuseflow.io.calibration import write_calibration
from fuseflow.io.paths import prepare_output_dir
from fuseflow.io.ply import write_ply
from fuseflow.live.server import LiveServer
from fuseflow.live.wire import encode_frame
from fuseflow.pipeline.live import LiveFrame
from fuseflow.pipeline.outputs import cloud_path
from fuseflow.types import Calibration, FusedCloud, Rig

__all__ = ["WebSink", "RerunSink", "RecordSink", "rig_message"]


def rig_message(rig: Rig) -> str:
    """The text message a viewer gets on connect: the cameras with extrinsics (world-from-camera)."""
    cams = [
        {
            "id": c.id,
            "width": c.width,
            "height": c.height,
            "K": c.K.tolist(),
            "T_world_cam": c.T_world_cam.reshape(-1).tolist(),
        }
        for c in rig.cameras
        if c.T_cam_world is not None
    ]
    return json.dumps({"type": "rig", "cameras": cams})


class WebSink:
    """Encode each cloud (``fuseflow.live.wire``) and publish it to the server's clients."""

    def __init__(self, server: LiveServer):
        self.server = server

    def send(self, cloud: FusedCloud, info: LiveFrame) -> None:
        latency = (time.perf_counter() - info.captured) * 1000.0
        self.server.publish(encode_frame(cloud, info.number, latency, info.fuse_ms))

    def close(self) -> None:
        self.server.close()


class RerunSink:
    """Log the rig once and every cloud to rerun (``viz.rerun_log.RerunLogger``).

    Args:
        target: "spawn" (open a viewer window), a ``rerun+http://...`` address (connect to a
            running viewer), or a path ending in .rrd (save a recording).
    """

    def __init__(self, target: str, rig: Rig):
        from fuseflow.viz.rerun_log import RerunLogger

        if target == "spawn":
            self.logger = RerunLogger(spawn=True, application_id="fuseflow-live")
        elif "://" in target:
            self.logger = RerunLogger(application_id="fuseflow-live")
            self.logger.rec.connect_grpc(target)
        else:
            self.logger = RerunLogger(save_to=target, application_id="fuseflow-live")
        self.logger.log_rig(rig)

    def send(self, cloud: FusedCloud, info: LiveFrame) -> None:
        self.logger.log_cloud(info.number, cloud)

    def close(self) -> None:
        self.logger.close()


class RecordSink:
    """Write clouds as ``run`` does: ``OUT/clouds/<number:06d>.ply`` (the source sequence number),
    ``OUT/calib.json`` (the extrinsics fused with) and ``OUT/frames.jsonl`` (one line per frame:
    number, frame index, points, fuse_ms, missing views)."""

    def __init__(self, out: str | Path, rig: Rig, source_rig: Rig | None = None):
        self.out = prepare_output_dir(out)
        write_calibration(
            self.out / "calib.json",
            Calibration({c.id: c.T_cam_world for c in rig}, {"source": "live"}),
            rig=source_rig or rig,
        )
        self._log: Any = open(self.out / "frames.jsonl", "w")
        self.written = 0

    def send(self, cloud: FusedCloud, info: LiveFrame) -> None:
        write_ply(cloud_path(self.out, info.number), cloud)
        line = {"number": info.number, "index": info.index, "points": len(cloud),
                "fuse_ms": round(info.fuse_ms, 3), "missing": list(info.missing)}  # fmt: skip
        self._log.write(json.dumps(line) + "\n")
        self._log.flush()
        self.written += 1

    def close(self) -> None:
        self._log.close()
