"""Live: cameras in, one fused cloud out, as it happens (``fuseflow live``, docs/live.md).

- :mod:`sources`: ``open_source(SOURCE)``: RealSense or Orbbec devices (``sources.realsense``,
  ``sources.orbbec`` over ``sources.device``), or a recording replayed as cameras
  (``sources.replay``).
- :mod:`loop`: ``LiveLoop``: capture in a thread, fuse the newest frame, hand clouds to sinks;
  the ``Source`` and ``Sink`` protocols.
- :mod:`app`: ``run_live``: the live loop with its sinks;
  ``StopRequest`` ends it cleanly from another thread or a signal handler.
- :mod:`server`: ``LiveServer``: the viewer page at ``/``, frames over a WebSocket at ``/ws``
  (each viewer at most one frame behind), ``/stats``; ``Access``: who may watch (Origin, Host,
  token, viewer cap). The page, its scripts and three.js are package data (``static/``).
- :mod:`wire`: the binary frame format (``encode_frame`` / ``decode_frame``).
- :mod:`sinks`: ``WebSink``, ``RerunSink``, ``RecordSink``.

Above pipeline and viz (it composes both), below eval and cli. Inside: app over sinks, over the
server and the loop, over the sources (an import-linter contract).
"""

from fuseflow.live.app import LiveOutputs, LiveResult, StopRequest, rig_for_live, run_live
from fuseflow.live.server import Access, LiveServer, parse_address
from fuseflow.live.sources import ReplayOptions, open_source
from fuseflow.live.wire import decode_frame, encode_frame

__all__ = [
    "Access",
    "LiveOutputs",
    "LiveResult",
    "LiveServer",
    "ReplayOptions",
    "StopRequest",
    "decode_frame",
    "encode_frame",
    "open_source",
    "parse_address",
    "rig_for_live",
    "run_live",
]
