"""``run_live``: a source, the live loop and its sinks, composed; what ``fuseflow live`` runs."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fuseflow.errors import FuseFlowError
from fuseflow.live.codec import CompactParams
from fuseflow.live.loop import LiveLoop, LiveSettings, LiveSummary
from fuseflow.live.server import Access, LiveServer, is_loopback
from fuseflow.live.sinks import RecordSink, RerunSink, WebSink, rig_message
from fuseflow.pipeline.extrinsics import placed_rig
from fuseflow.types import Calibration, Rig

__all__ = ["LiveOutputs", "LiveResult", "StopRequest", "run_live", "rig_for_live"]


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
    access: Access = Access()
    """Origins, token and viewer cap of the server (``live.server.Access``)."""
    hold: bool = False
    """After the source ends, keep serving its last frame until ``StopRequest`` (or Ctrl-C)."""


class StopRequest:
    """Ends ``run_live`` from any thread or a signal handler: the loop stops after the frame it is
    fusing, the sinks close cleanly (no half-written file) and the summary has ``reason``.

    ``set`` takes no lock. A Python signal handler runs in the main thread between two bytecodes,
    also while that thread holds the lock inside ``threading.Event.wait``; an ``Event.set`` there
    waits for that lock forever (SIGTERM would never end the process). So the request is a plain
    flag and its waiters poll it (``wait``).
    """

    POLL_S = 0.02
    """How often ``wait`` looks at the flag (seconds): the delay between a request and its effect."""

    def __init__(self) -> None:
        self.reason = "stop"
        self._requested = False

    def set(self, reason: str = "stop") -> None:
        self.reason = reason  # before the flag: whoever sees the flag sees its reason
        self._requested = True

    def is_set(self) -> bool:
        return self._requested

    def wait(self, timeout: float) -> bool:
        """True once set; False after ``timeout`` seconds without a request."""
        deadline = time.monotonic() + timeout
        while not self._requested:
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            time.sleep(min(left, self.POLL_S))
        return True


@dataclass
class LiveResult:
    summary: LiveSummary
    url: str | None = None
    """The viewer's address while it ran."""
    clients: list[dict[str, Any]] = field(default_factory=list)
    """Per viewer client: frames sent and dropped, bytes, Mbit/s (``LiveServer.client_stats``)."""
    warnings: list[str] = field(default_factory=list)
    held_s: float = 0.0
    """Seconds the last frame was served after the source ended (``LiveOutputs.hold``)."""
    hold_ended_by: str | None = None
    """What ended the hold: the ``StopRequest`` reason ("interrupted", "terminated", ...)."""
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


def _server_warnings(server: LiveServer) -> list[str]:
    if is_loopback(server.host):
        return []
    if server.token:
        return [f"serving on {server.host}: whoever has the address with its token can watch"]
    return [f"serving on {server.host} without a token: anyone who can reach this machine can watch the stream"]


def _one_frame_hint(source: Any, outputs: LiveOutputs) -> list[str]:
    inner = getattr(source, "source", source)
    rec = getattr(inner, "rec", None)
    if outputs.serve is None or outputs.hold or rec is None or getattr(inner, "loop", False) or len(rec) != 1:
        return []
    return ["the recording has one frame: the replay ends before a browser can connect; "
            "add --hold to keep serving it (or --loop to repeat it)"]  # fmt: skip


def _watch(stop: StopRequest, loop: LiveLoop, done: threading.Event) -> None:
    while not done.is_set():
        if stop.wait(0.05):
            loop.stop(stop.reason)
            return


def _hold(server: LiveServer, web: WebSink, stop: StopRequest) -> float:
    """Serve the last frame until ``stop`` (or Ctrl-C); the seconds it was held."""
    t0 = time.perf_counter()
    web.hold()
    server.end("replay ended; the last frame is held")
    try:
        while not stop.wait(0.1):
            pass
    except KeyboardInterrupt:
        pass
    return time.perf_counter() - t0


def run_live(
    source: Any,
    calibration: Calibration | None,
    settings: LiveSettings = LiveSettings(),
    outputs: LiveOutputs = LiveOutputs(),
    on_start: Callable[[str | None, list[str]], None] | None = None,
    fuse_fn: Callable | None = None,
    stop: StopRequest | None = None,
) -> LiveResult:
    """Fuse ``source`` live into the sinks of ``outputs`` until it ends, a limit, ``stop`` or Ctrl-C.

    The source is closed, the server stopped and every file closed before this returns, also on
    errors; viewers are told the stream ended (``{"type": "end"}``) or failed (``"error"``).
    ``on_start(url, warnings)`` is called once the sinks are up and before the first frame (the
    CLI prints the address there).
    """
    sinks: list[Any] = []
    server = None
    warnings: list[str] = []
    stop = stop or StopRequest()
    done = threading.Event()
    try:
        rig = rig_for_live(source.rig, calibration)
        left_out = [c for c in source.rig.ids if c not in rig.ids]
        if left_out:
            warnings.append(f"the calibration does not place cameras {left_out}; they are left out of fusion")
        loop = LiveLoop(source, rig, settings, fuse_fn=fuse_fn, calibration=calibration)
        if outputs.serve is not None:
            outputs.compact.check()
            server = LiveServer(*outputs.serve, stats=loop.stats.snapshot, rig_message=rig_message(rig, source.rig.ids),
                                codec=outputs.codec, access=outputs.access).start()  # fmt: skip
            warnings += _server_warnings(server)
            web = WebSink(server, outputs.compact, loop.stats.extra)
            web.owns_server = False  # closed below, after the viewers are told how the stream ended
            sinks.append(web)
        if outputs.rerun is not None:
            sinks.append(RerunSink(outputs.rerun, rig))
        if outputs.record is not None:
            sinks.append(RecordSink(outputs.record, rig, source.rig, getattr(source, "description", "")))
        warnings += _one_frame_hint(source, outputs)
        loop.sinks = sinks
        if on_start is not None:
            on_start(server.url if server else None, warnings)
        threading.Thread(target=_watch, args=(stop, loop, done), name="fuseflow-stop", daemon=True).start()
        summary = loop.run()  # closes the source and the sinks (the server stays up)
    except BaseException as exc:
        done.set()
        for s in sinks:
            s.close()
        if server is not None:
            server.end(str(exc) or type(exc).__name__, error=not isinstance(exc, KeyboardInterrupt))
            time.sleep(0.3)  # the viewers get the message before the connection closes
            server.close()
        close = getattr(source, "close", None)
        if close is not None:
            close()
        raise
    done.set()
    return _finish(summary, server, sinks, warnings, outputs, stop)


def _finish(summary: LiveSummary, server: LiveServer | None, sinks: list[Any], warnings: list[str],
            outputs: LiveOutputs, stop: StopRequest) -> LiveResult:  # fmt: skip
    web = next((s for s in sinks if isinstance(s, WebSink)), None)
    held = 0.0
    if server is not None:
        if outputs.hold and web is not None and summary.stopped_by == "end of source":
            held = _hold(server, web, stop)
        else:
            server.end(summary.stopped_by)
            time.sleep(0.3)  # the viewers get the message before the connection closes
        server.close()
    clients = server.client_stats() if server is not None else []
    result = LiveResult(summary, server.url if server else None, clients, warnings, round(held, 2))
    if held:
        result.hold_ended_by = stop.reason if stop.is_set() else "interrupted"
    if web is not None and web.encode_ms:
        result.encode_ms_median = round(float(np.median(web.encode_ms)), 2)
        result.encode_cpu_ms_median = round(float(np.median(web.encode_cpu_ms)), 2)
        result.encoder_skipped = web.skipped
    return result
