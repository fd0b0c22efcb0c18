"""``fuseflow convert`` as one library call: any supported input to a FuseFlow recording.

Inputs recognised (``convert``):

* RealSense ``.bag`` files (one per device), or a directory holding them -> ``io.rosbag``
* Azure Kinect ``.mkv`` files (one per device), or a directory of them -> ``io.azure_kinect``
  (the two kinds may be mixed if every camera records the same colour resolution)
* an HO-Cap sequence directory -> ``io.hocap``
* a single-camera dataset (Open3D / Redwood / ICL-NUIM, TUM RGB-D) -> a one-camera recording,
  or with ``virtual_rig`` / ``cameras`` a K-camera static rig (``io.datasets``)
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fuseflow.errors import RecordingError, ValidationError
from fuseflow.types import Rig

__all__ = ["ConvertSummary", "convert", "open_camera_file", "parse_frame_range", "FRAMES_HELP", "CAMERA_FILE_SUFFIXES"]

CAMERA_FILE_SUFFIXES = (".bag", ".mkv")


@dataclass(frozen=True)
class ConvertSummary:
    """What ``convert`` wrote.

    Attributes:
        kind: "realsense", "azure-kinect", "mixed", "hocap", "virtual-rig" or "sequence".
        out: output directory. rig: the rig written. frames: frames written.
        message: one line for a person. seconds: wall time.
        details: kind-specific facts (per-camera files and serials, pairing, reference extrinsics).
    """

    kind: str
    out: Path
    rig: Rig
    frames: int
    message: str
    seconds: float
    details: dict[str, Any] = field(default_factory=dict)


FRAMES_HELP = "A:B[:step], a Python slice of frame positions (A, B optional or negative; B exclusive)"
"""The one ``--frames`` grammar of every command that selects frames (fuse, run, view, calibrate,
convert); counts of frames are ``--num-frames``."""


def parse_frame_range(spec: str | None, n: int) -> range:
    """``A:B[:step]`` (a Python slice: A and B optional or negative, B exclusive, step > 0) -> the
    positions it selects in range(n), possibly empty; None = all. ValidationError on anything else.
    The one parser of ``--frames`` (``FRAMES_HELP``)."""
    if spec is None:
        return range(n)
    parts = spec.split(":")
    try:
        if len(parts) not in (2, 3):
            raise ValueError(spec)
        vals = [int(p) if p.strip() else None for p in parts]
    except ValueError:
        raise ValidationError(
            f"--frames {spec!r}: expected A:B[:step] with integers (a Python slice), e.g. 0:100 or 0:50:10"
        ) from None
    if len(vals) == 3 and vals[2] is not None and vals[2] <= 0:
        raise ValidationError(f"--frames {spec!r}: step must be positive")
    return range(n)[slice(*vals)]


def open_camera_file(path: str | Path):
    """A ``CameraStream`` for one .bag (RealSense) or .mkv (Azure Kinect) file."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".bag":
        from fuseflow.io.rosbag import RealSenseBag

        return RealSenseBag(path)
    if suffix == ".mkv":
        from fuseflow.io.azure_kinect import AzureKinectMkv

        return AzureKinectMkv(path)
    raise ValidationError(f"{path}: not a camera recording (expected .bag or .mkv)")


def _camera_files(sources: Sequence[Path]) -> list[Path] | None:
    """The .bag/.mkv files named or contained in ``sources``; None when they are not camera files."""
    files: list[Path] = []
    for s in sources:
        if s.is_dir():
            inside = sorted(p for p in s.iterdir() if p.suffix.lower() in CAMERA_FILE_SUFFIXES)
            if not inside:
                return None
            files += inside
        elif s.suffix.lower() in CAMERA_FILE_SUFFIXES:
            if not s.exists():
                raise RecordingError(f"{s}: no such file")
            files.append(s)
        else:
            return None
    return files


def _where_dropped(missing: np.ndarray) -> str:
    """Where a camera's views are missing among the paired frames: at the start (its stream starts
    later than the others', as a late or later-started camera's does), at the end (it stops
    earlier, or the file is truncated) or in the middle (dropped frames, a damaged file)."""
    idx = np.flatnonzero(missing)
    lead = int(np.argmin(missing)) if not missing.all() else len(missing)
    trail = int(np.argmin(missing[::-1])) if not missing.all() else 0
    parts = [f"{len(idx)} views"]
    if lead:
        parts.append(f"{lead} at the start (its stream starts later than the others')")
    if trail:
        parts.append(f"{trail} at the end (it stops earlier, or the file is truncated)")
    if len(idx) - lead - trail > 0:
        parts.append(f"{len(idx) - lead - trail} in the middle (dropped frames or a damaged file)")
    return ", ".join(parts[:1]) + (": " + ", ".join(parts[1:]) if len(parts) > 1 else "")


def convert(
    sources: Sequence[str | Path],
    out: str | Path,
    *,
    tolerance_s: float | None = None,
    with_extrinsics: bool = False,
    virtual_rig: Sequence[int] | None = None,
    cameras: int | None = None,
    every: int = 30,
    frames: str | None = None,
    tum_intrinsics: str | None = None,
    force: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> ConvertSummary:
    """Convert ``sources`` into the FuseFlow recording ``out`` (see the module docstring).

    Args:
        tolerance_s: .bag/.mkv pairing tolerance, seconds (default half a frame period).
        with_extrinsics: HO-Cap: write the reference extrinsics into rig.json.
        virtual_rig / cameras / every / frames / tum_intrinsics: single-camera datasets.
        force: write into a non-empty ``out``.
    """
    t0 = time.perf_counter()
    srcs = [Path(s) for s in sources]
    out = Path(out)
    if not srcs:
        raise ValidationError("convert: no input given")
    if out.exists() and (not out.is_dir() or any(out.iterdir())) and not force:
        raise ValidationError(f"{out}: output directory is not empty (use --force to write into it)")
    for s in srcs:
        if not s.exists():
            raise RecordingError(f"{s}: no such file or directory")
    files = _camera_files(srcs)
    if files is not None:
        from fuseflow.io.multicam import convert_streams

        streams = [open_camera_file(f) for f in files]
        kinds = {f.suffix.lower() for f in files}
        kind = "realsense" if kinds == {".bag"} else "azure-kinect" if kinds == {".mkv"} else "mixed"
        res = convert_streams(streams, out, tolerance_s, progress)
        p = res.pairing
        spread_ms = float(p.spread.max() * 1000) if len(p.spread) else 0.0
        details = {
            "files": {s.id: str(s.source) for s in streams},
            "tolerance_ms": p.tolerance * 1000,
            "period_ms": p.period * 1000,
            "dropped_views": {s.id: int(n) for s, n in zip(streams, p.dropped)},
            "max_spread_ms": spread_ms,
        }
        msg = (f"wrote {len(p.index)} frames x {len(streams)} cameras ({kind}) to {out}; views paired within "
               f"{p.tolerance * 1000:.1f} ms (max spread {spread_ms:.1f} ms), {int(p.dropped.sum())} dropped views")  # fmt: skip
        short = [f"{s.id}: {_where_dropped(p.index[:, n] < 0)} from {s.source}" for n, s in enumerate(streams)
                 if p.dropped[n]]  # fmt: skip
        if short:  # name the files and where their views are missing
            msg += f" ({'; '.join(short)})"
        return ConvertSummary(kind, out, res.rig, len(p.index), msg, time.perf_counter() - t0, details)
    if len(srcs) != 1:
        raise ValidationError(
            f"convert: several inputs must all be .bag or .mkv files (got {', '.join(map(str, srcs))})"
        )
    src = srcs[0]
    from fuseflow.io.hocap import convert_hocap, is_hocap

    if is_hocap(src):
        rig, seq = convert_hocap(src, out, with_extrinsics)
        n = len({f for per in seq.files.values() for f in per})
        msg = (f"wrote HO-Cap {src} ({len(rig)} cameras, {n} frame(s)) to {out}; reference extrinsics "
               + ("in rig.json and " if with_extrinsics else "") + "in reference_calib.json")  # fmt: skip
        return ConvertSummary("hocap", out, rig, n, msg, time.perf_counter() - t0,
                              {"master": seq.master, "extrinsics": str(seq.extrinsics_file)})  # fmt: skip
    return _convert_dataset(src, out, virtual_rig, cameras, every, frames, tum_intrinsics, t0)


def _convert_dataset(src, out, virtual_rig, cameras, every, frames, tum_intrinsics, t0) -> ConvertSummary:
    from fuseflow.io.datasets import SequenceRecording, convert_sequence, make_virtual_rig, open_recording

    rec = SequenceRecording.tum(src, tum_intrinsics) if (src / "rgb.txt").exists() else open_recording(src)
    if not isinstance(rec, SequenceRecording):
        raise ValidationError(f"{src}: already a FuseFlow recording; nothing to convert")
    if virtual_rig is not None and cameras is not None:
        raise ValidationError("give either --virtual-rig or --cameras, not both")
    if cameras is not None:
        if cameras < 1 or every < 1:
            raise ValidationError("--cameras and --every must be positive")
        idx = [k * every for k in range(cameras)]
        if idx[-1] >= len(rec):
            raise ValidationError(
                f"--cameras {cameras} --every {every} needs frame {idx[-1]}, the dataset has {len(rec)}"
            )
        virtual_rig = idx
    if virtual_rig is not None:
        idx = [int(i) for i in virtual_rig]
        rig = make_virtual_rig(rec, idx, out)
        msg = f"wrote a {len(rig)}-camera virtual rig (frames {idx}) to {out}"
        return ConvertSummary("virtual-rig", out, rig, 1, msg, time.perf_counter() - t0, {"frames": idx})
    rng = parse_frame_range(frames, len(rec))
    rig = convert_sequence(rec, out, list(rng))
    return ConvertSummary("sequence", out, rig, len(rng), f"wrote {len(rng)} frames of one camera to {out}",
                          time.perf_counter() - t0)  # fmt: skip
