"""The live loop: frames from a source (cameras, or a recording replayed as cameras) are fused as
they arrive and handed to sinks (a web viewer, rerun, PLY files).

Two threads. The *capture* thread iterates the source (``source.frames()``: it blocks until the
cameras deliver, or until a replay's next frame is due) and puts each frame, stamped with the
host clock, into a one-frame mailbox (``LatestFrame``); it never waits for fusion. The *fusion*
loop (the caller's thread) takes the newest frame, fuses it and calls every sink. A frame that is
replaced in the mailbox before fusion took it is dropped and counted: memory stays bounded by one
waiting frame, and the fused stream stays current when fusion is slower than the cameras.

A source is a ``Source`` (a typed protocol: ``rig``, ``frames()``, ``close()``; ``RealSenseSource``,
``OrbbecSource``, ``ReplaySource`` and ``live.sources.OpenedSource`` are ones); a ``skipped`` count
(frames the source itself let go, e.g. a replay that fell behind) and a ``released`` time (a
replay's due time of the frame it yielded last) are read when present, and so is a ``status()``
(a source gathered from several machines, ``sources.ray_source.RaySource``: its nodes' clock
offsets, bytes and per-camera skew), shown in ``/stats`` as ``capture`` and kept in the summary.
Dropped views are fused from the other cameras, as ``run`` does, and counted per camera.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
import torch

from fuseflow.errors import FuseFlowError, ValidationError
from fuseflow.geometry.volume import crop_cloud
from fuseflow.pipeline.exports import resolve_crop
from fuseflow.pipeline.extrinsics import reindex_cameras
from fuseflow.types import Calibration, Frame, FusedCloud, Rig

__all__ = [
    "Captured",
    "LatestFrame",
    "LiveFrame",
    "LiveLoop",
    "LiveSettings",
    "LiveStats",
    "LiveSummary",
    "Sink",
    "Source",
]


@runtime_checkable
class Source(Protocol):
    """What the live loop reads: cameras that deliver frames."""

    rig: Rig
    """The cameras, in the order of every frame's views."""

    def frames(self) -> Iterator[Frame]:
        """Frames as the cameras deliver them (blocking until the next one); a view a camera did
        not deliver is marked not present; the iterator ends when the source does."""
        ...

    def close(self) -> None:
        """Stop delivering (a blocked ``frames()`` returns) and release the devices; idempotent."""
        ...


@dataclass
class Captured:
    """A frame as the capture thread received it."""

    frame: Frame
    captured: float
    """Host clock (``time.perf_counter``) when the source delivered the frame; for a replay, the
    time it released the frame (``ReplaySource.released``: when it was due), which does not move
    when the capture thread itself runs late."""
    number: int
    """Sequence number of the frame from this source (0, 1, ...; unique across replay loops)."""


class LatestFrame:
    """A one-frame mailbox: ``put`` replaces a frame nobody took yet (counted in ``dropped``),
    ``take`` waits for the newest one. ``close`` wakes a waiting ``take`` for good."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._item: Captured | None = None
        self.dropped = 0
        self.closed = False

    def put(self, item: Captured) -> None:
        with self._cond:
            if self._item is not None:
                self.dropped += 1
            self._item = item
            self._cond.notify_all()

    def waiting(self) -> int:
        """1 while a frame waits to be taken, else 0."""
        return int(self._item is not None)

    def take(self, timeout: float) -> Captured | None:
        """The newest frame, or None after ``timeout`` seconds or once closed and empty."""
        with self._cond:
            if self._item is None and not self.closed:
                self._cond.wait(timeout)
            item, self._item = self._item, None
            return item

    def close(self) -> None:
        with self._cond:
            self.closed = True
            self._cond.notify_all()


@dataclass
class LiveSettings:
    """What the live loop fuses and when it stops."""

    preset: str = "live"
    """FUSE preset (``fuseflow.fuse.PRESETS``)."""
    points: int | None = None
    """Target points per frame (``FuseConfig.target_points``); None = the preset's density."""
    device: str = "cpu"
    """Where FUSE runs: cpu or cuda."""
    frames: int | None = None
    """Stop after this many frames from the source (None: until the source ends or ``stop``)."""
    duration: float | None = None
    """Stop after this many seconds (None: no limit)."""
    warmup: bool = True
    """Fuse one synthetic frame before capture starts, so that loading the compiled kernels does
    not count against the first live frames."""
    crop: Any = None
    """The capture-volume crop, as ``fuse`` / ``run`` take it: None or "off" keeps every point,
    "auto" the capture volume of the calibration (its stored ``capture_volume``, else the placed
    rig's), "xmin,ymin,zmin,xmax,ymax,zmax" (metres, world frame) or a ``CaptureVolume``; each
    fused cloud is cropped before the sinks get it."""


@dataclass
class LiveFrame:
    """What a sink gets with each fused cloud."""

    number: int
    """Sequence number of the source frame (``Captured.number``)."""
    index: int
    """The frame's own index (a recording's frame number; a device source counts from 0)."""
    captured: float
    """Host clock (``time.perf_counter``) when the source delivered the frame."""
    fuse_ms: float
    missing: tuple[str, ...]
    """Cameras that delivered no view for this frame (fused from the others)."""


class Sink(Protocol):
    """Where fused clouds go: ``send`` per frame (fast: it runs in the fusion loop), ``close`` once."""

    def send(self, cloud: FusedCloud, info: LiveFrame) -> None: ...

    def close(self) -> None: ...


class LiveStats:
    """Counters of a running live loop, safe to read from another thread (``snapshot``)."""

    def __init__(self, window_s: float = 2.0, latencies: int = 1000) -> None:
        self._lock = threading.Lock()
        self.frames_in = 0
        self.frames_out = 0
        self.dropped = 0
        self.skipped = 0
        self.points = 0
        self.started = time.perf_counter()
        self._out_times: deque[float] = deque()
        self._window = window_s
        self._latency: deque[float] = deque(maxlen=latencies)
        self.missing: dict[str, int] = {}
        self.extra: dict[str, Any] = {}
        """Values a caller adds to ``snapshot`` (none by default; the server adds its clients to
        ``/stats`` itself)."""

    def frame_in(self) -> None:
        with self._lock:
            self.frames_in += 1

    def frame_out(self, latency_s: float, points: int, missing: Sequence[str]) -> None:
        now = time.perf_counter()
        with self._lock:
            self.frames_out += 1
            self.points = points
            self._latency.append(latency_s * 1000.0)
            self._out_times.append(now)
            while self._out_times and now - self._out_times[0] > self._window:
                self._out_times.popleft()
            for c in missing:
                self.missing[c] = self.missing.get(c, 0) + 1

    def set_dropped(self, n: int, skipped: int = 0) -> None:
        """``n`` frames never fused so far, ``skipped`` of them let go by the source itself."""
        with self._lock:
            self.dropped = n
            self.skipped = skipped

    def snapshot(self) -> dict[str, Any]:
        """frames_in (delivered by the source or let go by it), frames_out, dropped, fps (fused frames per second over the last
        ``window_s``), latency_ms_p50 / p95 (capture to sent, over the last frames), points (of
        the last frame), missing views per camera, uptime, and ``extra``."""
        now = time.perf_counter()
        with self._lock:
            times = [t for t in self._out_times if now - t <= self._window]
            fps = (len(times) - 1) / (times[-1] - times[0]) if len(times) > 1 and times[-1] > times[0] else 0.0
            lat = np.array(self._latency, dtype=np.float64)
            return {
                "frames_in": self.frames_in + self.skipped,
                "frames_out": self.frames_out,
                "dropped": self.dropped,
                "fps": round(fps, 2),
                "latency_ms_p50": round(float(np.percentile(lat, 50)), 1) if lat.size else None,
                "latency_ms_p95": round(float(np.percentile(lat, 95)), 1) if lat.size else None,
                "points": self.points,
                "missing_views": dict(self.missing),
                "uptime_s": round(now - self.started, 2),
                **self.extra,
            }

    def latencies_ms(self) -> np.ndarray:
        with self._lock:
            return np.array(self._latency, dtype=np.float64)


@dataclass
class LiveSummary:
    """The result of a live loop."""

    frames_in: int
    """Frames the source produced: delivered to the loop, or let go by the source (a replay behind)."""
    frames_out: int
    dropped: int
    """Source frames never fused: replaced in the mailbox while fusion was busy, plus frames the
    source let go (a replay that fell behind)."""
    wall_s: float
    fps: float
    """Fused frames per second over the whole run."""
    latency_ms_p50: float | None
    latency_ms_p95: float | None
    fuse_ms_median: float | None
    points_mean: float
    stopped_by: str
    """"end of source", "frames", "duration", "stop" or another reason given to ``LiveLoop.stop``
    ("interrupted" for Ctrl-C, "terminated" for SIGTERM in ``fuseflow live``)."""
    dropped_views: dict[str, int] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    capture: dict[str, Any] = field(default_factory=dict)
    """The source's ``status()`` at the end, when it has one (capture nodes: clock offsets and
    their uncertainty, bytes per frame, encode / decode ms, per-camera skew)."""

    @property
    def drop_rate(self) -> float:
        return self.dropped / self.frames_in if self.frames_in else 0.0

    def to_json(self) -> dict[str, Any]:
        return {**asdict(self), "drop_rate": round(self.drop_rate, 4)}


class LiveLoop:
    """Capture in a thread, fuse the newest frame, hand each cloud to the sinks.

    Args:
        source: a ``Source``; its ``rig`` gives the frame's camera order.
        rig: the cameras to fuse, with extrinsics (``pipeline.placed_rig``); cameras of the
            source that ``rig`` lacks are left out.
        settings: preset, point budget, device and stop conditions.
        sinks: objects with ``send(cloud, info)`` and ``close()``; they run in the fusion loop.
        fuse_fn: ``(frame, rig) -> (cloud, fuse_ms)``; default FUSE with ``settings`` (tests
            pass a slow stand-in).
        calibration: where ``rig``'s extrinsics came from; ``settings.crop="auto"`` takes the
            capture volume stored in it, when it has one.
    """

    def __init__(
        self,
        source: Source,
        rig: Rig,
        settings: LiveSettings = LiveSettings(),
        sinks=(),
        fuse_fn=None,
        calibration: Calibration | None = None,
    ):
        if not isinstance(source, Source):
            raise ValidationError(f"the live loop reads a Source (rig, frames(), close()); got {type(source).__name__}")
        missing = [c for c in rig.ids if c not in source.rig.ids]
        if missing:
            raise FuseFlowError(f"the calibration places cameras {missing} that the source does not have")
        self.source = source
        self.rig = rig
        self.settings = settings
        self.sinks = list(sinks)
        self.stats = LiveStats()
        self._sel = [source.rig.ids.index(c) for c in rig.ids]
        self._fuse = fuse_fn or self._fuse_frame
        self.volume = resolve_crop(settings.crop, rig, calibration)
        self._cfg = None
        self._slot = LatestFrame()
        self._stop = threading.Event()
        self._stop_reason = "stop"
        self._error: BaseException | None = None
        self._ended = False
        self._fuse_ms: list[float] = []
        self._points: list[int] = []
        self._status_at = 0.0

    def stop(self, reason: str = "stop") -> None:
        """Ask the loop to finish (from any thread); ``run`` returns its summary, whose
        ``stopped_by`` is ``reason`` (e.g. "terminated" for SIGTERM)."""
        self._stop_reason = reason
        self._stop.set()
        self._slot.close()

    def _fuse_frame(self, frame: Frame, rig: Rig) -> tuple[FusedCloud, float]:
        from fuseflow.fuse import fuse_with_report
        from fuseflow.fuse.presets import preset_config

        if self._cfg is None:
            self._cfg = preset_config(self.settings.preset, self.settings.points)
        res = fuse_with_report(frame.to(self.settings.device), rig, self._cfg)
        return res.cloud.to("cpu"), res.report.ms

    def _warmup(self) -> None:
        """FUSE a synthetic frame of this rig (random depth within each camera's range)."""
        w, h = self.rig.resolution
        n = len(self.rig)
        rng = np.random.default_rng(0)
        near = max(c.depth_range[0] for c in self.rig.cameras)
        far = min(c.depth_range[1] for c in self.rig.cameras)
        depth = rng.uniform(near, max(near, min(far, near + 2.0)), (n, h, w)).astype(np.float32)
        frame = Frame(
            index=-1, camera_ids=self.rig.ids, color=torch.zeros((n, h, w, 3), dtype=torch.uint8),
            depth=torch.from_numpy(depth), present=torch.ones(n, dtype=torch.bool),
        )  # fmt: skip
        self._fuse(frame, self.rig)

    def _capture(self) -> None:
        limit = self.settings.frames
        n = 0
        paced_by = getattr(self.source, "paced_by", None)  # a source that fetches only what is fused
        if callable(paced_by):
            paced_by(self._slot.waiting)
        try:
            for frame in self.source.frames():
                if self._stop.is_set():
                    break
                self.stats.frame_in()
                released = getattr(self.source, "released", None)  # a replay's release time
                self._slot.put(Captured(frame, released if released is not None else time.perf_counter(), n))
                n += 1
                if limit is not None and n >= limit:
                    break
            self._ended = True
        except BaseException as exc:  # noqa: BLE001 - re-raised in the fusion thread by run()
            self._error = exc
        finally:
            self._slot.close()

    def _dropped(self) -> int:
        return self._slot.dropped + int(getattr(self.source, "skipped", 0))

    def _step(self, item: Captured) -> None:
        frame = item.frame
        if len(self._sel) != frame.num_views or self._sel != list(range(frame.num_views)):
            frame = frame.subset(self._sel)
        cloud, ms = self._fuse(frame, self.rig)
        cloud = crop_cloud(cloud, self.volume)
        if len(self._sel) != item.frame.num_views:
            cloud = reindex_cameras(cloud, self._sel)
        info = LiveFrame(item.number, int(item.frame.index), item.captured, float(ms), tuple(frame.missing))
        for sink in self.sinks:
            sink.send(cloud, info)
        self._fuse_ms.append(float(ms))
        self._points.append(len(cloud))
        self.stats.set_dropped(self._dropped(), int(getattr(self.source, "skipped", 0)))
        self.stats.frame_out(time.perf_counter() - item.captured, len(cloud), info.missing)
        status = getattr(self.source, "status", None)
        if callable(status) and time.perf_counter() - self._status_at > 0.5:
            self._status_at = time.perf_counter()
            self.stats.extra["capture"] = status()

    def _loop(self, t0: float) -> str:
        duration = self.settings.duration
        while True:
            if self._stop.is_set():
                return self._stop_reason
            if duration is not None and time.perf_counter() - t0 >= duration:
                return "duration"
            item = self._slot.take(timeout=0.05)
            if item is not None:
                self._step(item)
            elif self._slot.closed and not self._stop.is_set():
                if self._error is not None:
                    raise self._error
                return "frames" if self.settings.frames is not None and self._ended_by_limit() else "end of source"

    def _ended_by_limit(self) -> bool:
        return self.settings.frames is not None and self.stats.frames_in >= self.settings.frames

    def run(self) -> LiveSummary:
        """Run until the source ends, a limit is reached, ``stop`` or Ctrl-C; then stop the
        capture thread, close the source and the sinks, and return the summary."""
        if self.settings.warmup:
            self._warmup()
        t0 = time.perf_counter()
        self.stats.started = t0
        thread = threading.Thread(target=self._capture, name="fuseflow-capture", daemon=True)
        thread.start()
        try:
            stopped_by = self._loop(t0)
        except KeyboardInterrupt:
            stopped_by = "interrupted"
        finally:
            self._stop.set()
            self._slot.close()
            self._shutdown(thread)
            if self._slot.take(0.0) is not None:  # captured, never fused
                self._slot.dropped += 1
        return self._summary(stopped_by, time.perf_counter() - t0)

    def _shutdown(self, thread: threading.Thread) -> None:
        thread.join(timeout=5.0)
        close = getattr(self.source, "close", None)
        if close is not None:
            close()
        thread.join(timeout=5.0)
        for sink in self.sinks:
            sink.close()

    def _summary(self, stopped_by: str, wall: float) -> LiveSummary:
        lat = self.stats.latencies_ms()
        out = self.stats.frames_out
        dropped_views = dict(self.stats.missing)
        warnings = [
            f"camera {c} was missing in {n} of {out} fused frames; those frames were fused from the other views"
            for c, n in dropped_views.items()
        ]
        status = getattr(self.source, "status", None)
        capture = status() if callable(status) else {}
        return LiveSummary(
            frames_in=self.stats.frames_in + int(getattr(self.source, "skipped", 0)),
            frames_out=out,
            dropped=self._dropped(),
            wall_s=round(wall, 3),
            fps=round(out / wall, 3) if wall > 0 else 0.0,
            latency_ms_p50=round(float(np.percentile(lat, 50)), 1) if lat.size else None,
            latency_ms_p95=round(float(np.percentile(lat, 95)), 1) if lat.size else None,
            fuse_ms_median=round(float(np.median(self._fuse_ms)), 1) if self._fuse_ms else None,
            points_mean=round(float(np.mean(self._points)), 1) if self._points else 0.0,
            stopped_by=stopped_by,
            dropped_views=dropped_views,
            warnings=warnings,
            capture=capture,
        )
