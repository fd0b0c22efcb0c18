"""``run_live``: a source, the live loop and its sinks, composed; what ``fuseflow live`` runs."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fuseflow.errors import FuseFlowError
from fuseflow.live.codec import CompactParams
from fuseflow.live.server import LiveServer, is_loopback
from fuseflow.live.sinks import RecordSink, RerunSink, WebSink, rig_message
from fuseflow.pipeline.extrinsics import placed_rig
from fuseflow.pipeline.live import LiveLoop, LiveSettings, LiveSummary
from fuseflow.types import Calibration, Rig

__all__ = ["LiveOutputs", "LiveResult", "run_live", "rig_for_live"]


@dataclass(frozen=True)
class LiveOutputs:
    """Which sinks run (any combination; none is allowed: the loop then only measures)."""

    serve: tuple[str, int] | None = None
    """(host, port) of the web viewer; None = no server."""
    rerun: str | None = None
    """"spawn", a rerun+http:// address, or an .rrd path (``RerunSink``); None = no rerun."""
    record: Path | None = None
    """Write clouds here (``RecordSink``); None = no files."""
    codec: str = "compact"
    """Frame codec of a viewer that does not ask for one (``/ws?codec=``): compact or raw."""
    compact: CompactParams = CompactParams()
    """Grid step and colour quantisation of the compact codec."""


@dataclass
class LiveResult:
    summary: LiveSummary
    url: str | None = None
    """The viewer's address while it ran."""
    clients: list[dict[str, Any]] = field(default_factory=list)
    """Per viewer client: frames sent and dropped, bytes, Mbit/s (``LiveServer.client_stats``)."""
    warnings: list[str] = field(default_factory=list)
    encode_ms_median: float | None = None
    """Median time the web sink's encoder thread took per frame (all codecs asked for)."""
    encode_cpu_ms_median: float | None = None
    """The same in CPU time of the encoder thread."""
    encoder_skipped: int = 0
    """Fused clouds the encoder thread never encoded (replaced while it was busy)."""


def rig_for_live(source_rig: Rig, calibration: Calibration | None) -> Rig:
    """The cameras to fuse: ``calibration``'s extrinsics (cameras it does not place are left out),
    or the source rig's own (a replayed rig.json with extrinsics); FuseFlowError otherwise."""
    if calibration is not None:
        return placed_rig(source_rig, calibration)
    placed = [i for i, c in enumerate(source_rig.cameras) if c.is_calibrated]
    if not placed:
        raise FuseFlowError("the source has no extrinsics: pass --calib calib.json (fuseflow calibrate makes one)")
    return source_rig.subset(placed)


def _server_warnings(host: str) -> list[str]:
    if is_loopback(host):
        return []
    return [f"serving on {host}: anyone who can reach this machine can watch the stream (no authentication)"]


def run_live(
    source: Any,
    calibration: Calibration | None,
    settings: LiveSettings = LiveSettings(),
    outputs: LiveOutputs = LiveOutputs(),
    on_start: Callable[[str | None, list[str]], None] | None = None,
    fuse_fn: Callable | None = None,
) -> LiveResult:
    """Fuse ``source`` live into the sinks of ``outputs`` until it ends, a limit, or Ctrl-C.

    The source is closed, the server stopped and every file closed before this returns, also on
    errors. ``on_start(url, warnings)`` is called once the sinks are up and before the first frame
    (the CLI prints the address there).
    """
    sinks: list[Any] = []
    server = None
    warnings: list[str] = []
    try:
        rig = rig_for_live(source.rig, calibration)
        left_out = [c for c in source.rig.ids if c not in rig.ids]
        if left_out:
            warnings.append(f"the calibration does not place cameras {left_out}; they are left out of fusion")
        loop = LiveLoop(source, rig, settings, fuse_fn=fuse_fn, calibration=calibration)
        if outputs.serve is not None:
            outputs.compact.check()
            server = LiveServer(*outputs.serve, stats=loop.stats.snapshot, rig_message=rig_message(rig),
                                codec=outputs.codec).start()  # fmt: skip
            warnings += _server_warnings(server.host)
            sinks.append(WebSink(server, outputs.compact, loop.stats.extra))
        if outputs.rerun is not None:
            sinks.append(RerunSink(outputs.rerun, rig))
        if outputs.record is not None:
            sinks.append(RecordSink(outputs.record, rig, source.rig))
        loop.sinks = sinks
        if on_start is not None:
            on_start(server.url if server else None, warnings)
        summary = loop.run()  # closes the source and the sinks
    except BaseException:
        for s in sinks:
            s.close()
        if server is not None:
            server.close()
        close = getattr(source, "close", None)
        if close is not None:
            close()
        raise
    clients = server.client_stats() if server is not None else []
    result = LiveResult(summary, server.url if server else None, clients, warnings)
    web = next((s for s in sinks if isinstance(s, WebSink)), None)
    if web is not None and web.encode_ms:
        result.encode_ms_median = round(float(np.median(web.encode_ms)), 2)
        result.encode_cpu_ms_median = round(float(np.median(web.encode_cpu_ms)), 2)
        result.encoder_skipped = web.skipped
    return result
