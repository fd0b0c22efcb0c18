"""Timestamps of several cameras: pairing views by device timestamp, the per-view timestamp
file of a converted recording, stream statistics, and a recording re-timed by whole frames
(``shift_views``). Estimating a camera's frame offset is an algorithm and lives above io, in
``fuseflow.pipeline.sync``.

Everything here is pure numpy over timestamps: it reads no images and imports no geometry.

Conventions: timestamps are float64 **seconds** on the cameras' shared time base (RealSense
"Global Time", or wired-sync Azure Kinect device time); a frame period is in seconds; an offset
of +k frames means the camera is k frames *late*: its view paired with frame t shows the scene
its neighbours showed at frame t - k.

``REC/timestamps.json`` (written by the converters, read by ``read_timestamps``)::

    {"format": "fuseflow-timestamps/1",
     "unit": "s",
     "tolerance_s": 0.0167,                 # pairing tolerance used
     "frames": [0, 1, 2, ...],              # frame numbers of the recording
     "cameras": {"<id>": {"timestamp": [t0, t1, null, ...],     # device time of each view, null = dropped
                          "device_frame": [n0, n1, null, ...],  # the device's frame counter, or null
                          "stream": [s0, s1, ...]}}}            # every timestamp the camera delivered
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fuseflow.errors import FormatError, ValidationError
from fuseflow.io.recording import Recording

__all__ = [
    "TIMESTAMPS_FORMAT",
    "Pairing",
    "StreamStats",
    "nominal_period",
    "pair_by_timestamp",
    "stream_stats",
    "write_timestamps",
    "read_timestamps",
    "Timestamps",
    "ShiftedRecording",
    "shift_views",
]

TIMESTAMPS_FORMAT = "fuseflow-timestamps/1"


def _check_stamps(stamps: Sequence[np.ndarray], names: Sequence[str] | None) -> list[np.ndarray]:
    out = []
    for i, s in enumerate(stamps):
        a = np.asarray(s, dtype=np.float64).reshape(-1)
        who = names[i] if names is not None else f"camera {i}"
        if a.size == 0:
            raise ValidationError(f"{who}: no timestamps")
        if not np.all(np.isfinite(a)):
            raise ValidationError(f"{who}: timestamps must be finite seconds")
        if np.any(np.diff(a) <= 0):
            k = int(np.argmax(np.diff(a) <= 0))
            raise ValidationError(
                f"{who}: timestamps must increase strictly (index {k + 1}: {a[k + 1]!r} after {a[k]!r})"
            )
        out.append(a)
    return out


def nominal_period(stamps: Sequence[np.ndarray]) -> float:
    """The frame period in seconds: the median of every camera's median frame interval.

    Args:
        stamps: per camera, (M_i,) float64 seconds, strictly increasing.
    Returns the period, or 0.0 when no camera has two frames.
    """
    meds = [float(np.median(np.diff(s))) for s in stamps if len(s) > 1]
    return float(np.median(meds)) if meds else 0.0


@dataclass(frozen=True)
class Pairing:
    """Views of several cameras paired into frames by nearest timestamp.

    Attributes:
        index: (F, N) int64, the view (position in that camera's timestamp list) paired into
            frame f, or -1 where camera n has no view within the tolerance (a dropped view).
        time: (F,) float64 seconds, the median timestamp of the views of each frame.
        spread: (F,) float64 seconds, latest minus earliest timestamp of the views of each frame.
        tolerance: the tolerance in seconds that was used.
        period: the nominal frame period in seconds (``nominal_period``).
    """

    index: np.ndarray
    time: np.ndarray
    spread: np.ndarray
    tolerance: float
    period: float

    @property
    def dropped(self) -> np.ndarray:
        """(N,) int: per camera, how many frames have no view of it."""
        return (self.index < 0).sum(axis=0)


def pair_by_timestamp(
    stamps: Sequence[np.ndarray], tolerance: float | None = None, names: Sequence[str] | None = None
) -> Pairing:
    """Pair the views of N cameras into frames by nearest timestamp.

    The frame times are the union of all cameras' timestamps, merged where they lie within
    ``tolerance`` of an earlier frame time (the camera with the most views sets them first).
    Each camera then gives each frame its nearest view within ``tolerance``; a view claimed by
    two frames goes to the nearer one. A camera with no view within the tolerance of a frame
    is a dropped view of that frame.

    Args:
        stamps: per camera, (M_i,) float64 seconds, strictly increasing, on one time base.
        tolerance: seconds; default half the nominal frame period (``nominal_period``).
        names: camera names for error messages.
    """
    st = _check_stamps(stamps, names)
    period = nominal_period(st)
    if tolerance is None:
        tolerance = period / 2 if period > 0 else 0.0
    if tolerance < 0 or not np.isfinite(tolerance):
        raise ValidationError(f"pairing tolerance must be >= 0 seconds, got {tolerance!r}")
    order = sorted(range(len(st)), key=lambda i: -len(st[i]))
    ticks = st[order[0]].copy()
    for i in order[1:]:
        # timestamps of camera i that no frame time covers open new frames
        k = np.clip(np.searchsorted(ticks, st[i]), 1, len(ticks) - 1) if len(ticks) > 1 else np.zeros(len(st[i]), int)
        near = np.minimum(np.abs(ticks[k] - st[i]), np.abs(ticks[np.maximum(k - 1, 0)] - st[i]))
        new = st[i][near > tolerance]
        if new.size:
            ticks = np.sort(np.concatenate([ticks, new]))
    F, N = len(ticks), len(st)
    index = np.full((F, N), -1, dtype=np.int64)
    for i, s in enumerate(st):
        k = np.searchsorted(s, ticks)
        lo, hi = np.clip(k - 1, 0, len(s) - 1), np.clip(k, 0, len(s) - 1)
        pick = np.where(np.abs(s[lo] - ticks) <= np.abs(s[hi] - ticks), lo, hi)
        d = np.abs(s[pick] - ticks)
        ok = d <= tolerance
        # a view claimed by two frames keeps the nearer frame
        best: dict[int, int] = {}
        for f in np.flatnonzero(ok):
            v = int(pick[f])
            if v not in best or d[f] < d[best[v]]:
                best[v] = int(f)
        for v, f in best.items():
            index[f, i] = v
    times = np.array([[st[i][v] if v >= 0 else np.nan for i, v in enumerate(row)] for row in index]).reshape(F, N)
    with np.errstate(all="ignore"):
        time = np.nanmedian(times, axis=1)
        spread = np.nanmax(times, axis=1) - np.nanmin(times, axis=1)
    keep = np.isfinite(time)
    return Pairing(index[keep], time[keep], spread[keep], float(tolerance), period)


@dataclass(frozen=True)
class StreamStats:
    """What one camera's timestamps say about its stream.

    Attributes:
        frames: number of views. fps: 1 / median frame interval (0 with fewer than 2 views).
        gaps: intervals longer than 1.5 median intervals (frames the device skipped).
        longest_gap_s: the longest interval, seconds. first_s, last_s: first and last timestamp.
    """

    frames: int
    fps: float
    gaps: int
    longest_gap_s: float
    first_s: float
    last_s: float


def stream_stats(stamps: np.ndarray) -> StreamStats:
    """Frame rate and gaps of one camera. ``stamps``: (M,) float64 seconds, increasing."""
    s = np.asarray(stamps, dtype=np.float64).reshape(-1)
    if s.size == 0:
        return StreamStats(0, 0.0, 0, 0.0, float("nan"), float("nan"))
    if s.size < 2:
        return StreamStats(1, 0.0, 0, 0.0, float(s[0]), float(s[0]))
    d = np.diff(s)
    med = float(np.median(d))
    return StreamStats(
        int(s.size),
        1.0 / med if med > 0 else 0.0,
        int((d > 1.5 * med).sum()),
        float(d.max()),
        float(s[0]),
        float(s[-1]),
    )


# --------------------------------------------------------------------------- timestamps.json


@dataclass(frozen=True)
class Timestamps:
    """The per-view timestamps of a converted recording (``REC/timestamps.json``).

    Attributes:
        frames: (F,) frame numbers. tolerance: pairing tolerance, seconds.
        view: camera id -> (F,) float64 seconds, NaN where the view is dropped.
        device_frame: camera id -> (F,) float64 device frame counters, NaN where unknown.
        stream: camera id -> (M,) float64 seconds, every timestamp the camera delivered.
    """

    frames: np.ndarray
    tolerance: float
    view: Mapping[str, np.ndarray]
    device_frame: Mapping[str, np.ndarray]
    stream: Mapping[str, np.ndarray]

    def spread(self) -> np.ndarray:
        """(F,) seconds: latest minus earliest view timestamp of each frame (NaN with no view)."""
        t = np.stack(list(self.view.values()), axis=1)
        with np.errstate(all="ignore"):
            return np.nanmax(t, axis=1) - np.nanmin(t, axis=1)


def _nullable(a: np.ndarray) -> list[Any]:
    return [
        None if not np.isfinite(v) else (int(v) if float(v).is_integer() and abs(v) < 2**53 else float(v)) for v in a
    ]


def write_timestamps(
    root: str | Path,
    frames: Sequence[int],
    view: Mapping[str, np.ndarray],
    stream: Mapping[str, np.ndarray],
    tolerance: float,
    device_frame: Mapping[str, np.ndarray] | None = None,
) -> Path:
    """Write ``root/timestamps.json`` (schema in the module docstring); returns the path.

    Args:
        view: camera id -> (F,) float64 seconds per frame, NaN for a dropped view.
        stream: camera id -> (M,) float64 seconds, all of the camera's timestamps.
        device_frame: camera id -> (F,) device frame counters (NaN unknown), optional.
    """
    from fuseflow.io.recording import write_json_atomic

    doc = {
        "format": TIMESTAMPS_FORMAT,
        "unit": "s",
        "tolerance_s": float(tolerance),
        "frames": [int(f) for f in frames],
        "cameras": {
            cid: {
                "timestamp": [None if not np.isfinite(v) else float(v) for v in np.asarray(t, dtype=np.float64)],
                "device_frame": _nullable(
                    np.asarray(device_frame[cid], dtype=np.float64)
                    if device_frame is not None and cid in device_frame
                    else np.full(len(frames), np.nan)
                ),
                "stream": [float(v) for v in np.asarray(stream[cid], dtype=np.float64)],
            }
            for cid, t in view.items()
        },
    }
    path = Path(root) / "timestamps.json"
    write_json_atomic(path, doc)
    return path


def read_timestamps(root: str | Path) -> Timestamps | None:
    """Read ``root/timestamps.json``; None when the recording has none. Errors name the field."""
    from fuseflow.io.files import load_json

    path = Path(root) / "timestamps.json"
    if not path.exists():
        return None
    doc = load_json(path)
    if not isinstance(doc, dict) or doc.get("format") != TIMESTAMPS_FORMAT:
        raise FormatError(f"{path}: field 'format' must be {TIMESTAMPS_FORMAT!r}")
    try:
        frames = np.array(doc["frames"], dtype=np.int64)
        cams = doc["cameras"]
        view, dev, stream = {}, {}, {}
        for cid, c in cams.items():
            view[cid] = np.array([np.nan if v is None else v for v in c["timestamp"]], dtype=np.float64)
            dev[cid] = np.array([np.nan if v is None else v for v in c.get("device_frame", [])], dtype=np.float64)
            stream[cid] = np.array(c.get("stream", []), dtype=np.float64)
            if view[cid].shape != frames.shape:
                raise FormatError(
                    f"{path}: camera {cid!r}: 'timestamp' has {view[cid].size} entries, 'frames' {frames.size}"
                )
        return Timestamps(frames, float(doc.get("tolerance_s", float("nan"))), view, dev, stream)
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise FormatError(
            f"{path}: expected fields 'frames' and 'cameras' {{id: {{'timestamp': [...]}}}}: {exc}"
        ) from None


class ShiftedRecording(Recording):
    """A recording whose cameras are re-timed by whole frames: camera c's view at position t is
    the base recording's view at t + offsets[c] (a camera k frames late shows instant t at
    t + k). Views shifted past either end are dropped views. Made by ``shift_views``."""

    def __init__(self, base: Recording, offsets: Mapping[str, int]):
        self.base = base
        self.offsets = {c: int(k) for c, k in offsets.items()}
        self.rig, self.path, self.frame_numbers = base.rig, base.path, base.frame_numbers
        self._position = {n: t for t, n in enumerate(base.frame_numbers)}

    def _load_view(self, cam_index: int, number: int):
        t = self._position[number] + self.offsets.get(self.rig.ids[cam_index], 0)
        if not 0 <= t < len(self.base):
            return None
        return self.base._load_view(cam_index, self.base.frame_numbers[t])

    def missing_views(self) -> dict[str, list[int]]:
        base = self.base.missing_views()
        out: dict[str, list[int]] = {}
        for c in self.rig.ids:
            k = self.offsets.get(c, 0)
            gone = set(base.get(c, []))
            out[c] = [
                n
                for t, n in enumerate(self.frame_numbers)
                if not 0 <= t + k < len(self.frame_numbers) or self.frame_numbers[t + k] in gone
            ]
        return {c: v for c, v in out.items() if v}


def shift_views(rec: Recording, offsets: Mapping[str, int]) -> Recording:
    """``rec`` with camera c's views taken ``offsets[c]`` frames later (``ShiftedRecording``):
    what ``fuseflow run --sync-offsets`` fuses. Unknown camera ids are a ValidationError."""
    unknown = [c for c in offsets if c not in rec.rig.ids]
    if unknown:
        raise ValidationError(f"sync offsets name cameras {unknown} that the rig {list(rec.rig.ids)} does not have")
    return ShiftedRecording(rec, offsets)
