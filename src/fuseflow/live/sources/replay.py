"""A recording replayed as if it were cameras: ``ReplaySource`` delivers its frames at the
recording's timestamps (or at a fixed rate) and never waits for whoever reads them.

The live loop (``live.loop``) reads a ``ReplaySource`` the way it reads ``RealSenseSource``:
``rig``, ``frames()``, ``close()``. ``frames()`` decodes the next frame, sleeps until it is due and
yields it; a frame whose successor is already due when it is decoded (the replay fell behind,
e.g. decoding is slower than the rate) is let go and counted in ``skipped``, as a camera
overwrites a frame the host did not read in time. Timing: frame k is due at
``start + (timestamp_k - timestamp_0)`` with the recording's timestamps (``Frame.timestamp``,
e.g. a converted .bag's ``timestamps.json``), or at ``start + k / rate`` with ``rate`` or when the
recording has no increasing timestamps (``DEFAULT_RATE``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator

from fuseflow.errors import ValidationError
from fuseflow.io.recording import Recording
from fuseflow.types import Frame

__all__ = ["ReplaySource", "DEFAULT_RATE"]

DEFAULT_RATE = 30.0
"""Frames per second of a replay whose recording has no timestamps and no ``rate`` is given."""


class ReplaySource:
    """Replay ``rec`` in real time, as a live source.

    Args:
        rec: the recording.
        rate: frames per second (None: the recording's timestamps, else ``DEFAULT_RATE``).
        loop: start again at the first frame after the last, until ``close``.
        preload: decode every frame once before the first is delivered and keep them in memory
            (the replay then costs no decoding: as cameras deliver decoded images). Memory is the
            recording's decoded size.
        clock, sleep: time source and sleep (tests pass fakes).
        start: ``clock`` time at which the first frame of the first pass was due (None: when
            ``frames()`` starts). Replays of one recording on several capture nodes whose clocks
            agree, given the same ``start`` (``align_start``), show the same frame at the same
            time, as cameras filming one scene do; with ``loop``, passes that ended before
            ``frames()`` starts are not replayed.
    """

    def __init__(
        self,
        rec: Recording,
        rate: float | None = None,
        loop: bool = False,
        preload: bool = False,
        clock: Callable[[], float] = time.perf_counter,
        sleep: Callable[[float], None] | None = None,
        start: float | None = None,
    ):
        if rate is not None and not rate > 0:
            raise ValidationError(f"--rate must be a positive number of frames per second, got {rate}")
        if len(rec) == 0:
            raise ValidationError(f"{rec.path}: the recording has no frames to replay")
        self.rec = rec
        self.rig = rec.rig
        self.rate = rate
        self.loop = loop
        self.skipped = 0
        self.delivered = 0
        self.start = start
        self.due: float | None = None
        """Clock time at which the frame ``frames()`` yielded last was due: when a camera
        filming the recording's scene would have captured it (a capture node's stamp)."""
        self.released: float | None = None
        """Clock time at which the frame ``frames()`` yielded last was released (when it was due,
        or when it was decoded if that was later): its capture time, read by the live loop."""
        self._clock = clock
        self._closed = threading.Event()
        self._sleep = sleep or (lambda s: self._closed.wait(s))
        self._cache: list[Frame] | None = [rec[t] for t in range(len(rec))] if preload else None

    def _frame(self, t: int) -> Frame:
        return self._cache[t] if self._cache is not None else self.rec[t]

    def _offsets(self, first: Frame) -> Callable[[int, Frame], float]:
        """Seconds after the start at which position t of one pass is due."""
        if self.rate is not None or first.timestamp is None:
            period = 1.0 / (self.rate or DEFAULT_RATE)
            return lambda t, f: t * period
        t0 = first.timestamp
        fallback = 1.0 / DEFAULT_RATE
        return lambda t, f: (f.timestamp - t0) if f.timestamp is not None else t * fallback

    def _period(self) -> float:
        """Time between passes when looping: the recording's span plus one frame period."""
        n = len(self.rec)
        if self.rate is not None or n < 2:
            return n / (self.rate or DEFAULT_RATE)
        a, b = self._frame(0).timestamp, self._frame(n - 1).timestamp
        if a is None or b is None or b <= a:
            return n / DEFAULT_RATE
        return (b - a) * n / (n - 1)

    def frames(self) -> Iterator[Frame]:
        """Yield each frame when it is due (see the module docstring); forever with ``loop``."""
        first = self._frame(0)
        due_in = self._offsets(first)
        span = self._period() if self.loop else 0.0
        now = self._clock()  # after the first frame is decoded: the replay starts with it
        start = now if self.start is None else self.start
        n = len(self.rec)
        k = int(max(0.0, now - start) // span) if span > 0 else 0  # pass number
        interval = 1.0 / (self.rate or DEFAULT_RATE)
        prev = None
        while not self._closed.is_set():
            base = start + k * span
            for t in range(n):
                if self._closed.is_set():
                    return
                frame = first if t == 0 and k == 0 else self._frame(t)
                due = base + due_in(t, frame)
                if prev is not None and due > prev:
                    interval = due - prev
                prev = due
                now = self._clock()
                last = t == n - 1 and not self.loop
                if now - due >= interval and not last:  # its successor is due already: this one is stale
                    self.skipped += 1
                    continue
                if due > now:
                    self._sleep(due - now)
                if self._closed.is_set():
                    return
                self.released = max(due, now)
                self.due = due
                self.delivered += 1
                yield frame
            if not self.loop:
                return
            k += 1

    def align_start(self, now: float) -> float:
        """A ``start`` shared by every replay of this recording: the latest multiple of one
        pass (the recording's span plus a frame period, ``loop``) at or before ``now``."""
        span = self._period()
        return (now // span) * span if span > 0 else now

    def __iter__(self) -> Iterator[Frame]:
        return self.frames()

    @property
    def closed(self) -> bool:
        return self._closed.is_set()

    def close(self) -> None:
        """Stop delivering (a waiting ``frames()`` returns at once)."""
        self._closed.set()
