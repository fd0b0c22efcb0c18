"""The output directory of a run: where clouds go, the per-frame log (frames.jsonl) that lets a
run resume, and the summary. Every file is written atomically (an interrupted run leaves only
complete files)."""

from __future__ import annotations

import json
import resource
from pathlib import Path

from fuseflow.pipeline.records import FrameRecord

__all__ = ["cloud_path", "read_frame_log", "peak_rss_mb"]


def cloud_path(out_dir: str | Path, index: int) -> Path:
    """Where ``run`` writes the cloud of frame ``index``: OUT/clouds/<index:06d>.ply."""
    return Path(out_dir) / "clouds" / f"{index:06d}.ply"


def read_frame_log(path: Path) -> dict[int, FrameRecord]:
    """The records of frames.jsonl by frame number; lines cut by an interruption are skipped."""
    previous: dict[int, FrameRecord] = {}
    if not path.exists():
        return previous
    for line in path.read_text().splitlines():
        try:
            r = FrameRecord.from_json(json.loads(line))
        except (json.JSONDecodeError, KeyError, ValueError, TypeError):
            continue  # a line cut by an interruption
        previous[r.index] = r
    return previous


def peak_rss_mb() -> float:
    """Peak resident memory of this process, MB."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
