"""What a recording holds, as a JSON-ready dict (``fuseflow info``): cameras, frames, calibration,
missing views, and for a converted multi-device recording (``timestamps.json``) each camera's
frame rate and gaps and the spread of the paired views' timestamps."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["recording_summary", "timing_summary", "check_recording_files"]


def timing_summary(path: str | Path) -> dict[str, Any] | None:
    """Per-camera fps / gaps / dropped views and the pairing spread (ms), from timestamps.json;
    None when the recording has no per-view timestamps."""
    from fuseflow.io.timesync import read_timestamps, stream_stats

    ts = read_timestamps(path)
    if ts is None:
        return None
    cams = {}
    for cid, view in ts.view.items():
        st = stream_stats(ts.stream.get(cid, view[np.isfinite(view)]))
        first = view[np.isfinite(view)]
        cams[cid] = {
            "fps": st.fps,
            "stream_frames": st.frames,
            "gaps": st.gaps,
            "longest_gap_ms": st.longest_gap_s * 1000,
            "dropped_views": int((~np.isfinite(view)).sum()),
            "first_view_s": float(first[0]) if first.size else None,
        }
    spread = ts.spread()
    spread = spread[np.isfinite(spread)] * 1000
    return {
        "tolerance_ms": ts.tolerance * 1000,
        "spread_ms": {
            "median": float(np.median(spread)) if spread.size else None,
            "p95": float(np.percentile(spread, 95)) if spread.size else None,
            "max": float(spread.max()) if spread.size else None,
        },
        "cameras": cams,
    }


def recording_summary(path: str | Path) -> dict[str, Any]:
    """Cameras, frames, resolution, calibration state, missing views (and timing) of a recording."""
    from fuseflow.io.datasets import SequenceRecording, open_recording

    rec = open_recording(path)
    rig = rec.rig
    missing = rec.missing_views()
    summary: dict[str, Any] = {
        "path": str(path),
        "layout": getattr(rec, "layout", "fuseflow"),
        "frames": len(rec),
        "cameras": len(rig),
        "resolution": list(rig.resolution),
        "calibrated": rig.is_calibrated,
        "camera_list": [
            {
                "id": c.id,
                "width": c.width,
                "height": c.height,
                "fx": c.K[0, 0],
                "fy": c.K[1, 1],
                "cx": c.K[0, 2],
                "cy": c.K[1, 2],
                "depth_scale": c.depth_scale,
                "depth_range": list(c.depth_range),
                "calibrated": c.is_calibrated,
                "missing_views": len(missing.get(c.id, [])),
            }
            for c in rig.cameras
        ],
        "missing_views": missing,
    }
    if isinstance(rec, SequenceRecording):
        summary["poses"] = rec.has_poses
    else:
        timing = timing_summary(path)
        if timing is not None:
            summary["timing"] = timing
    return summary


def check_recording_files(path: str | Path) -> list[str]:
    """Decode every colour and depth file of the recording at ``path`` (``fuseflow info --check``):
    one line per unreadable, truncated or wrongly sized file, naming it; empty when all are good."""
    from fuseflow.io.datasets import open_recording

    return open_recording(path).check_files()
