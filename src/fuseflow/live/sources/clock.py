"""Clocks of capture nodes: a node's clock (``NodeClock``) and the fusing host's estimate of its
offset (``OffsetEstimator``), NTP-style over round trips.

A probe is three stamps: ``t0`` (host clock when the request left), ``t1`` (node clock when it
answered) and ``t2`` (host clock when the answer came back). Assuming the answer was taken half
way through the round trip, the node's clock is ahead of the host's by ``t1 - (t0 + t2) / 2``,
and the error of that assumption is at most half the round trip (``(t2 - t0) / 2``: the answer
was taken somewhere inside it). ``OffsetEstimator`` keeps the last ``window`` probes and answers
with the one of the shortest round trip (the min-RTT filter: queueing delays only lengthen a
round trip, so the shortest one bounds the offset tightest); its uncertainty is that probe's
half round trip. A node stamp ``s`` is then ``s - offset`` on the host clock.

``StampDrift`` watches the corrected capture stamps of the frames fused together: per fused frame
and camera, the stamp minus the instant T it was paired to, less the median of that over the
cameras of the frame (the rig's consensus: a camera is compared with the others, not with T,
which follows the slowest node). Pairing takes each camera's frame nearest T, so that residual
never exceeds half a frame interval: a camera whose stamps slide steadily wraps round to the
neighbouring frame at half an interval. ``StampDrift`` therefore unwraps it over consecutive
frames (a step larger than half an interval is a wrap) and reports the median of the unwrapped
residual over the last ``window`` frames as the camera's drift: a camera whose median drift
exceeds half a frame interval has slid onto another frame than the one its stamps pair it with
(its stamps are wrong), or runs at another rate than the others (free-running, not in step).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

__all__ = ["NodeClock", "OffsetEstimate", "OffsetEstimator", "StampDrift", "probe"]


class NodeClock:
    """A capture node's clock: wall time (``time.time``, seconds) plus ``offset_s``.

    ``offset_s`` is 0 in use; tests give a node a clock that is off by a known amount
    (``fuseflow node --clock-offset-ms``) to check that the fusing host finds it."""

    def __init__(self, offset_s: float = 0.0, base: Callable[[], float] = time.time):
        self.offset_s = float(offset_s)
        self._base = base

    def __call__(self) -> float:
        return self._base() + self.offset_s


@dataclass(frozen=True)
class OffsetEstimate:
    """A node clock's offset to the host clock (node minus host), in seconds."""

    offset_s: float
    uncertainty_s: float
    """Half the round trip of the probe the offset came from: the offset is within this."""
    rtt_s: float
    samples: int
    """Probes in the window it was chosen from."""

    def to_json(self) -> dict[str, float | int]:
        return {"offset_ms": round(self.offset_s * 1e3, 3), "uncertainty_ms": round(self.uncertainty_s * 1e3, 3),
                "rtt_ms": round(self.rtt_s * 1e3, 3), "probes": self.samples}  # fmt: skip


def probe(node_clock: Callable[[], float], host_clock: Callable[[], float] = time.time) -> tuple[float, float, float]:
    """One round trip: (t0 host, t1 node, t2 host). ``node_clock`` blocks until the node answered."""
    t0 = host_clock()
    t1 = node_clock()
    t2 = host_clock()
    return t0, t1, t2


class OffsetEstimator:
    """The min-RTT offset over the last ``window`` probes (module docstring); thread-safe."""

    def __init__(self, window: int = 32):
        self._probes: deque[tuple[float, float]] = deque(maxlen=window)  # (rtt, offset)
        self._lock = threading.Lock()

    def add(self, t0: float, t1: float, t2: float) -> None:
        """A probe's three stamps (``probe``); a probe whose answer came back before it left
        (a clock step on the host) is ignored."""
        rtt = t2 - t0
        if rtt < 0:
            return
        with self._lock:
            self._probes.append((rtt, t1 - (t0 + t2) / 2.0))

    def estimate(self) -> OffsetEstimate | None:
        """The offset of the shortest round trip in the window; None before the first probe."""
        with self._lock:
            if not self._probes:
                return None
            rtt, offset = min(self._probes)
            return OffsetEstimate(offset, rtt / 2.0, rtt, len(self._probes))


@dataclass
class _Track:
    last: float | None = None
    unwrapped: float = 0.0
    window: deque = field(default_factory=deque)
    missed: int = 0
    warned: bool = False


class StampDrift:
    """Per camera, the drift of its corrected capture stamps from the other cameras' (module
    docstring), in seconds; ``interval`` is the frame interval (s), ``window`` the fused frames
    the median is taken over, ``least`` the frames a camera needs before it is judged. A camera
    missing from up to ``gap`` fused frames in a row (a frame that fell just outside the pairing
    tolerance as it wrapped) is unwrapped across the gap; after a longer one (a node that stalled
    or restarted) its track starts over."""

    def __init__(self, interval: float, window: int = 30, least: int = 10, gap: int = 5):
        self.interval = float(interval)
        self.window, self.least, self.gap = int(window), int(least), int(gap)
        self._tracks: dict[str, _Track] = {}

    def add(self, residuals: Mapping[str, float | None]) -> list[tuple[str, float]]:
        """One fused frame: camera -> its stamp minus T (s; None: not in the frame). Returns
        (camera, drift s) of the cameras whose median drift first exceeded half an interval."""
        here = {c: r for c, r in residuals.items() if r is not None}
        consensus = float(np.median(list(here.values()))) if here else 0.0
        out = []
        for cam, r in residuals.items():
            track = self._tracks.setdefault(cam, _Track(window=deque(maxlen=self.window)))
            if r is None:
                track.missed += 1
                if track.missed > self.gap:  # how many intervals it slid meanwhile is unknown: start over
                    track.last, track.window = None, deque(maxlen=self.window)
                continue
            track.missed = 0
            d = r - consensus
            if track.last is None:
                track.unwrapped = d
            else:
                step = d - track.last
                track.unwrapped += step - self.interval * round(step / self.interval)
            track.last = d
            track.window.append(track.unwrapped)
            drift = self.drift(cam)
            if drift is not None and abs(drift) > self.interval / 2 and not track.warned:
                track.warned = True
                out.append((cam, drift))
        return out

    def drift(self, cam: str) -> float | None:
        """The camera's median drift over the window (s); None before ``least`` frames."""
        track = self._tracks.get(cam)
        if track is None or len(track.window) < self.least:
            return None
        return float(np.median(track.window))
