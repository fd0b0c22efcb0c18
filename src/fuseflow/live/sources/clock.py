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
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

__all__ = ["NodeClock", "OffsetEstimate", "OffsetEstimator", "probe"]


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
