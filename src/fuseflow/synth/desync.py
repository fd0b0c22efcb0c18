"""Cameras out of sync: make a simulated recording in which some cameras run late or early.

A camera ``k`` frames late shows at frame t what the scene looked like at frame t - k (a sync
fault: its views are paired with the wrong instant). ``apply_desync`` rewrites a recording
written by ``simulate_recording`` in place: the camera's colour, depth and ground-truth depth
files are shifted by k frames; frames that would need a view from before the first (late) or
after the last (early) frame become dropped views. gt.json records the offsets under
``"desync": {camera id: frames}`` (the answer a sync check must find; the ground-truth surface
stays that of the true instant of each frame).
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path

from fuseflow.errors import RecordingError, ValidationError

__all__ = ["parse_desync", "apply_desync"]


def parse_desync(spec: str | None, camera_ids: tuple[str, ...] | None = None) -> dict[str, int]:
    """'cam03:2,cam05:-1' -> {"cam03": 2, "cam05": -1}. A camera may be given by id or by index."""
    out: dict[str, int] = {}
    if not spec:
        return out
    for item in (x.strip() for x in spec.split(",") if x.strip()):
        cam, sep, k = item.rpartition(":")
        try:
            frames = int(k)
        except ValueError:
            frames = None
        if not sep or not cam or frames is None:
            raise ValidationError(f"--desync expects CAM:FRAMES (e.g. cam03:2), got {item!r}")
        if camera_ids is not None and cam not in camera_ids:
            if cam.isdigit() and int(cam) < len(camera_ids):
                cam = camera_ids[int(cam)]
            else:
                raise ValidationError(f"--desync: unknown camera {cam!r}; cameras are {', '.join(camera_ids)}")
        out[cam] = frames
    return out


def _shift_folder(folder: Path, frames: int, k: int) -> None:
    """Rename <folder>/<t:06d>.<ext> to t + k; files shifted past either end are removed."""
    if not folder.is_dir():
        return
    files = {int(p.stem): p for p in folder.iterdir() if p.stem.isdigit()}
    order = sorted(files, reverse=k > 0)
    for t in order:
        p = files[t]
        dst_t = t + k
        if 0 <= dst_t < frames:
            os.replace(p, p.with_name(f"{dst_t:06d}{p.suffix}"))
        else:
            p.unlink()


def apply_desync(rec_dir: str | Path, offsets: Mapping[str, int] | str) -> dict[str, int]:
    """Shift the listed cameras of the simulated recording ``rec_dir`` by their offsets (frames,
    + = late; a "CAM:FRAMES,..." string is parsed with ``parse_desync``, cameras by id or index).
    Returns the offsets applied; gt.json gets ``"desync"``."""
    from fuseflow.io.files import load_json, write_json_atomic
    from fuseflow.io.recording import read_rig

    rec = Path(rec_dir)
    rig = read_rig(rec)
    if isinstance(offsets, str):
        offsets = parse_desync(offsets, rig.ids)
    gt_path = rec / "gt.json"
    gt = load_json(gt_path)
    frames = int(gt.get("frames", 0))
    for cid, k in offsets.items():
        if cid not in rig.ids:
            raise ValidationError(f"desync: unknown camera {cid!r}; cameras are {', '.join(rig.ids)}")
        if not isinstance(k, int) or abs(k) >= frames:
            raise ValidationError(
                f"desync: camera {cid!r}: offset must be an int with |k| < {frames} frames, got {k!r}"
            )
    if "desync" in gt:
        raise RecordingError(f"{gt_path}: this recording is already desynchronised ({gt['desync']})")
    for cid, k in offsets.items():
        if k == 0:
            continue
        for folder in (rec / cid / "color", rec / cid / "depth", rec / "gt" / cid / "depth"):
            _shift_folder(folder, frames, k)
    gt["desync"] = {cid: int(k) for cid, k in offsets.items()}
    write_json_atomic(gt_path, gt)
    (rec / "desync.json").write_text(json.dumps(gt["desync"], indent=2) + "\n")
    return dict(gt["desync"])
