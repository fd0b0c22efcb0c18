"""Where the live loop's fused clouds go: the web viewer (``WebSink``), rerun (``RerunSink``),
PLY files (``RecordSink``). Each has ``send(cloud, info)`` (called in the fusion loop) and
``close()``. ``WebSink.send`` only hands the cloud over: encoding runs in a thread of its own."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from fuseflow.io.calibration import write_calibration
from fuseflow.io.paths import prepare_output_dir
from fuseflow.io.ply import write_ply
from fuseflow.live.codec import CompactParams, InterEncoder
from fuseflow.live.loop import LiveFrame
from fuseflow.live.server import LiveServer
from fuseflow.live.wire import CODECS, encode_attributes, encode_frame
from fuseflow.pipeline.outputs import cloud_path
from fuseflow.types import Calibration, FusedCloud, Rig

__all__ = ["WebSink", "RerunSink", "RecordSink", "rig_message"]


def rig_message(rig: Rig, source_ids: tuple[str, ...] | None = None) -> str:
    """The text message a viewer gets on connect: the cameras with extrinsics (world-from-camera)
    and ``source_ids``, the source's cameras in the order a point's camera index counts them."""
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
    return json.dumps({"type": "rig", "cameras": cams, "source_ids": list(source_ids or rig.ids)})


class WebSink:
    """Encode each cloud (``fuseflow.live.wire``) in the codecs the viewers want and publish it.

    ``send`` puts the cloud in a one-frame slot and returns; an encoder thread takes the newest
    cloud, encodes it once per codec the connected clients use (none when nobody watches) and
    hands the bytes to the server. A cloud replaced before the encoder took it is counted in
    ``skipped`` (the encoder fell behind the fusion); ``encode_ms`` holds the last encoding
    times and ``encode_cpu_ms`` the encoder thread's CPU time for them (all codecs of a frame
    together). Both codecs are run once on a small cloud when the sink is made, so that compiling
    the codec's kernels (cached after the first run) does not fall on the first live frames.
    """

    def __init__(self, server: LiveServer, params: CompactParams = CompactParams(), stats: dict | None = None):
        self.server = server
        self.owns_server = True
        """``close`` also closes the server (``run_live`` clears it: it tells the viewers how the
        stream ended, or holds the last frame, before it closes the server itself)."""
        self.params = params
        self.stats = stats if stats is not None else {}
        """Updated after every frame with ``encoded``, ``encoder_skipped`` and ``encode_ms`` (the
        last frame's): the live loop's ``LiveStats.extra``, so ``/stats`` shows them."""
        self.stats.update(encoded=0, encoder_skipped=0, encode_ms=None)  # keys fixed from here on
        self.skipped = 0
        self.encoded = 0
        self.encode_ms: list[float] = []
        self.encode_cpu_ms: list[float] = []
        self._warmup()
        self._cond = threading.Condition()
        self._item: tuple[FusedCloud, LiveFrame] | None = None
        self._closed = False
        self._error: BaseException | None = None
        self._last: tuple[FusedCloud, LiveFrame] | None = None
        self.inter = InterEncoder(params) if params.version != 2 else None
        """Codes compact frames as deltas for the viewers that take them (``LiveServer.compact_needs``)."""
        self._keyless = False
        self._closing_key: tuple[int, bytes] | None = None
        """(frame number, compact key frame) that ``close`` coded for late viewers."""
        self._thread = threading.Thread(target=self._run, name="fuseflow-encoder", daemon=True)
        self._thread.start()

    def _warmup(self) -> None:
        import torch

        rng = np.random.default_rng(0)
        xyz = torch.from_numpy(rng.uniform(-1, 1, (64, 3)).astype(np.float32))
        rgb = torch.from_numpy(rng.integers(0, 256, (64, 3), dtype=np.uint8))
        cloud = FusedCloud(xyz, rgb, torch.ones(64), torch.zeros(64, dtype=torch.int16))
        for codec in CODECS:
            encode_frame(cloud, 0, 0.0, 0.0, codec, self.params)

    def send(self, cloud: FusedCloud, info: LiveFrame) -> None:
        if self._error is not None:
            raise self._error
        with self._cond:
            if self._item is not None:
                self.skipped += 1
            self._item = (cloud, info)
            self._cond.notify()

    def _run(self) -> None:
        while True:
            with self._cond:
                while self._item is None and not self._closed:
                    self._cond.wait()
                if self._item is None:
                    return
                (cloud, info), self._item = self._item, None
            try:
                self._encode(cloud, info)
            except BaseException as exc:  # noqa: BLE001 - re-raised by the next send()
                self._error = exc
                return

    def _encode(self, cloud: FusedCloud, info: LiveFrame) -> None:
        self._last = (cloud, info)
        codecs = self.server.codecs()
        if not codecs:
            return
        t0, c0 = time.perf_counter(), time.thread_time()
        latency = (t0 - info.captured) * 1000.0
        inter = self.inter is not None and "compact" in codecs
        frames = {c: encode_frame(cloud, info.number, latency, info.fuse_ms, c, self.params)
                  for c in sorted(codecs) if c in CODECS and not (inter and c == "compact")}  # fmt: skip
        if "raw.attrs" in codecs:
            frames["raw.attrs"] = encode_attributes(cloud, info.number)
        meta = {"number": info.number, "captured": time.time() - (t0 - info.captured)}
        if inter:
            ref = self.inter.reference
            frames.update(self._compact(cloud, info, latency, *self.server.compact_needs(ref)))
            meta["ref"] = ref
        self.encode_ms.append((time.perf_counter() - t0) * 1000.0)
        self.encode_cpu_ms.append((time.thread_time() - c0) * 1000.0)
        del self.encode_ms[:-1000], self.encode_cpu_ms[:-1000]
        self.encoded += 1
        self.stats.update(encoded=self.encoded, encoder_skipped=self.skipped, encode_ms=round(self.encode_ms[-1], 1))
        self.server.publish(frames, meta)

    def _compact(self, cloud: FusedCloud, info: LiveFrame, latency: float, key: bool, delta: bool) -> dict[str, bytes]:
        """The compact key frame and / or delta the viewers need ({"compact": ..., "compact.delta": ...})."""
        xyz = cloud.xyz.detach().cpu().numpy()
        rgb = cloud.rgb.detach().cpu().numpy()
        k, d = self.inter.encode(xyz, rgb, info.number, latency, info.fuse_ms, key=key, delta=delta)
        self._keyless = k is None
        return {n: b for n, b in (("compact", k), ("compact.delta", d)) if b is not None}

    def hold(self) -> None:
        """Publish the last cloud once more, encoded in every codec, so that viewers who connect
        later (any codec) are shown it (``fuseflow live --hold``); after ``close``."""
        self.close()
        if self._last is None:
            return
        cloud, info = self._last
        latency = (time.perf_counter() - info.captured) * 1000.0
        key = self._closing_key if self._closing_key is not None and self._closing_key[0] == info.number else None
        frames = {c: key[1] if key is not None and c == "compact" else
                  encode_frame(cloud, info.number, latency, info.fuse_ms, c, self.params) for c in CODECS}  # fmt: skip
        frames["raw.attrs"] = encode_attributes(cloud, info.number)
        self.server.publish(frames, {"number": info.number, "captured": time.time() - latency / 1000.0})

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify()
        self._thread.join(timeout=10.0)
        if self._keyless and self._last is not None:  # the last frame as a key frame, for late viewers
            cloud, info = self._last
            self._keyless = False
            latency = (time.perf_counter() - info.captured) * 1000.0
            key = encode_frame(cloud, info.number, latency, info.fuse_ms, "compact", self.params)
            self._closing_key = (info.number, key)  # ``hold`` sends it again rather than coding it twice
            self.server.publish({"compact": key}, {"number": info.number, "captured": time.time() - latency / 1000.0})
        if self.owns_server:
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
    ``OUT/calib.json`` (the extrinsics fused with), ``OUT/frames.jsonl`` (one line per frame:
    number, frame index, points, fuse_ms, missing views) and ``OUT/live.json`` (what was
    recorded: source, cameras; ``fuseflow info OUT`` reads it).

    A folder that already holds any of these is refused (OutputError naming them): a recording is
    never mixed with or written over another one. A cloud whose writing was cut short leaves no
    ``.tmp`` file behind (``close`` removes them)."""

    def __init__(self, out: str | Path, rig: Rig, source_rig: Rig | None = None, source: str = ""):
        out = Path(out)
        self._refuse_existing(out)
        self.out = prepare_output_dir(out)
        write_calibration(
            self.out / "calib.json",
            Calibration({c.id: c.T_cam_world for c in rig}, {"source": "live"}),
            rig=source_rig or rig,
        )
        doc = {"kind": "fuseflow live recording", "source": source, "cameras": list(rig.ids),
               "clouds": "clouds/<number:06d>.ply", "log": "frames.jsonl"}  # fmt: skip
        (self.out / "live.json").write_text(json.dumps(doc, indent=2) + "\n")
        self._log: Any = open(self.out / "frames.jsonl", "x")
        self.written = 0

    @staticmethod
    def _refuse_existing(out: Path) -> None:
        from fuseflow.errors import OutputError

        if not out.is_dir():
            return
        found = [n for n in ("frames.jsonl", "calib.json", "live.json") if (out / n).exists()]
        clouds = sorted((out / "clouds").glob("*.ply")) if (out / "clouds").is_dir() else []
        if clouds:
            found.append(f"clouds/ ({len(clouds)} .ply)")
        if found:
            raise OutputError(f"--record {out}: already holds {', '.join(found)}; record into a new folder "
                              "(nothing there is replaced or mixed with a new recording)")  # fmt: skip

    def send(self, cloud: FusedCloud, info: LiveFrame) -> None:
        write_ply(cloud_path(self.out, info.number), cloud)
        line = {"number": info.number, "index": info.index, "points": len(cloud),
                "fuse_ms": round(info.fuse_ms, 3), "missing": list(info.missing)}  # fmt: skip
        self._log.write(json.dumps(line) + "\n")
        self._log.flush()
        self.written += 1

    def close(self) -> None:
        self._log.close()
        for tmp in (self.out / "clouds").glob("*.ply.tmp"):
            tmp.unlink(missing_ok=True)
