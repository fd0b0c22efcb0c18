"""Typed results of a run: ``FrameRecord`` (one line of frames.jsonl) and ``RunSummary``
(summary.json). Each converts to and from the JSON it is stored as."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

__all__ = ["FrameRecord", "RunSummary", "pairs_to_json", "pairs_from_json"]


def pairs_to_json(pairs: np.ndarray) -> list[list[float | None]]:
    """(N, N) float pair agreements -> nested lists, NaN as null, rounded to 4 decimals."""
    return [[None if not np.isfinite(x) else round(float(x), 4) for x in row] for row in np.asarray(pairs)]


def pairs_from_json(rows: list[list[float | None]] | None, n: int) -> np.ndarray:
    """Nested lists with nulls (``pairs_to_json``) -> (n, n) float64 with NaN; all NaN when absent."""
    if not rows:
        return np.full((n, n), np.nan)
    return np.array([[np.nan if x is None else x for x in row] for row in rows], dtype=np.float64).reshape(n, n)


@dataclass
class FrameRecord:
    """What happened to one frame (one line of frames.jsonl)."""

    index: int
    """Frame number (the recording's, not the position in it)."""
    points: int
    """Points in the fused cloud."""
    fuse_ms: float
    """Wall time of FUSE on this frame, milliseconds."""
    missing: list[str] = field(default_factory=list)
    """Ids of cameras whose view was dropped in this frame."""
    empty: list[str] = field(default_factory=list)
    """Ids of present cameras whose depth image has no measurement at all in this frame."""
    agreement: dict[str, float | None] = field(default_factory=dict)
    """Per camera, the mean agreement of its neighbour pairs (None: no vote)."""
    pairs: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    """(N, N) float64 pair agreements (``geometry.pair_agreement``) in the fused rig's order, NaN
    where a pair cast no vote."""
    flagged: list[str] = field(default_factory=list)
    """Cameras the health monitor flagged as bumped in this frame."""
    recalibrated: bool = False
    """GMAC re-ran on this frame (``recalibrate="auto"``)."""
    timestamp: float | None = None
    """The frame's time, seconds (its views' device time), or None when the recording has none."""
    notes: list[str] = field(default_factory=list)
    """FUSE's warnings about this frame (``pipeline.frames.fuse_notes``): cameras with no depth in
    range, cameras with no overlapping neighbour, points dropped, an empty cloud."""

    def to_json(self) -> dict[str, Any]:
        """The frames.jsonl line: ``pairs`` as nested lists with null for NaN."""
        d = {k: v for k, v in self.__dict__.items() if k != "pairs"}
        d["missing"], d["flagged"], d["empty"] = list(self.missing), list(self.flagged), list(self.empty)
        d["agreement"], d["notes"] = dict(self.agreement), list(self.notes)
        d["pairs"] = pairs_to_json(self.pairs)
        return {
            k: d[k]
            for k in (
                "index", "points", "fuse_ms", "missing", "empty", "agreement", "pairs", "flagged", "recalibrated",
                "timestamp",
                "notes",
            )
        }  # fmt: skip

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> FrameRecord:
        """Inverse of ``to_json`` (KeyError / ValueError on a malformed line)."""
        rows = d.get("pairs") or []
        return cls(
            index=int(d["index"]),
            points=int(d["points"]),
            fuse_ms=float(d["fuse_ms"]),
            missing=list(d.get("missing", [])),
            empty=list(d.get("empty", [])),
            agreement=dict(d.get("agreement", {})),
            pairs=pairs_from_json(rows, len(rows)),
            flagged=list(d.get("flagged", [])),
            recalibrated=bool(d.get("recalibrated", False)),
            timestamp=None if d.get("timestamp") is None else float(d["timestamp"]),
            notes=list(d.get("notes", [])),
        )


@dataclass
class RunSummary:
    """The result of ``run`` (also written as summary.json)."""

    recording: str
    out_dir: str
    frames: int
    frames_fused_now: int
    frames_resumed: int
    fps: float
    ms_per_frame: float
    """Median FUSE time of the frames fused in this call (the first frame of a fresh install also
    compiles the numba kernels: the demo in a fresh venv measured a 2018 ms mean over 10 frames
    against ~200 ms warm; the median leaves that out, ``fps`` does not)."""
    points_per_frame: dict[str, float]
    peak_memory_mb: float
    device: str
    calibration: str
    calibration_frame: int | None
    dropped_views: dict[str, int]
    bumped_cameras: dict[str, int]
    recalibrations: list[int]
    warnings: list[str]
    sync_offsets: dict[str, int] = field(default_factory=dict)
    """Cameras the sync check found late (+k frames) or early (-k); applied when ``sync="auto"``."""
    first_frame_ms: float = 0.0
    """FUSE time of the first frame fused in this call: it includes the start-up (numba loads or
    compiles its kernels in each new process)."""
    warm_ms_per_frame: float | None = None
    """Median FUSE time of the frames after the first (None with fewer than 2 fused now): the
    per-frame cost of a long recording."""
    nothing_to_do: bool = False
    """Every frame asked for was already in OUT: the numbers are those of the run that fused
    them (summary.json is left as it was)."""

    def to_json(self) -> dict[str, Any]:
        return {k: v for k, v in asdict(self).items() if k != "nothing_to_do"}

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> RunSummary:
        """Inverse of ``to_json``; fields an older summary.json lacks take their defaults."""
        names = {f for f in cls.__dataclass_fields__}
        return cls(**{k: v for k, v in doc.items() if k in names})
