"""``open_source(spec)``: what ``fuseflow live SOURCE`` reads.

- ``realsense`` / ``realsense:SERIAL,SERIAL``: every connected RealSense (or these, in this order)
  through ``live.sources.realsense.RealSenseSource``.
- ``orbbec`` / ``orbbec:SERIAL,SERIAL``: Orbbec devices through ``live.sources.orbbec.OrbbecSource``.
- a recording directory (FuseFlow rig.json, Open3D/ICL or TUM layout): replayed as cameras
  (``live.sources.replay.ReplaySource``).
- one or more ``.bag`` / ``.mkv`` files, or a directory of them: converted once into a temporary
  FuseFlow recording by the readers of ``fuseflow convert`` (``io.convert``), then replayed; the
  temporary directory is removed by ``close()``.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fuseflow.errors import ValidationError
from fuseflow.io.convert import CAMERA_FILE_SUFFIXES
from fuseflow.live.sources.replay import ReplaySource
from fuseflow.types import Frame

__all__ = ["ReplayOptions", "open_source", "parse_device_spec", "OpenedSource"]


@dataclass(frozen=True)
class ReplayOptions:
    """How a recording is replayed (ignored for devices)."""

    rate: float | None = None
    loop: bool = False
    preload: bool = False
    aligned: bool = False
    """Pace by the wall clock (``time.time``) from a start shared by every replay of the
    recording (``ReplaySource.align_start``): capture nodes that replay some cameras each show
    the same frame at the same time."""


def parse_device_spec(spec: str) -> tuple[str, list[str] | None] | None:
    """("realsense" | "orbbec", serials or None) for a device SOURCE, None for anything else."""
    kind, sep, rest = spec.partition(":")
    if kind.lower() not in ("realsense", "orbbec"):
        return None
    if not sep:
        return kind.lower(), None
    serials = [s.strip() for s in rest.split(",") if s.strip()]
    if not serials:
        raise ValidationError(f"SOURCE {spec!r}: give serial numbers after the colon ({kind}:SERIAL,SERIAL)")
    return kind.lower(), serials


def _camera_files(specs: Sequence[str]) -> list[Path] | None:
    paths = [Path(s) for s in specs]
    if len(paths) == 1 and paths[0].is_dir() and not (paths[0] / "rig.json").exists():
        inside = sorted(p for p in paths[0].iterdir() if p.suffix.lower() in CAMERA_FILE_SUFFIXES)
        return inside or None
    if all(p.suffix.lower() in CAMERA_FILE_SUFFIXES for p in paths):
        return paths
    return None


class OpenedSource:
    """A source plus what must be cleaned up with it (a converted recording's temporary folder)."""

    def __init__(self, source: Any, description: str, temp: Path | None = None):
        self.source = source
        self.rig = source.rig
        self.description = description
        self._temp = temp

    @property
    def released(self) -> float | None:
        return getattr(self.source, "released", None)

    @property
    def skipped(self) -> int:
        return int(getattr(self.source, "skipped", 0))

    def frames(self) -> Iterator[Frame]:
        return self.source.frames()

    def close(self) -> None:
        close = getattr(self.source, "close", None)
        if close is not None:
            close()
        if self._temp is not None:
            shutil.rmtree(self._temp, ignore_errors=True)
            self._temp = None


def open_source(
    specs: Sequence[str], replay: ReplayOptions = ReplayOptions(), modules: dict | None = None
) -> OpenedSource:
    """Open SOURCE (module docstring). ``modules`` maps "realsense" / "orbbec" to a stand-in SDK
    module (tests)."""
    from fuseflow.io.datasets import open_recording

    specs = [str(s) for s in specs]
    if not specs:
        raise ValidationError("no SOURCE: give realsense, orbbec, a recording directory or .bag/.mkv files")
    device = parse_device_spec(specs[0])
    if device is not None:
        if len(specs) > 1:
            raise ValidationError(f"SOURCE {specs[0]!r} is a device: give it alone (serials after a colon)")
        kind, serials = device
        module = (modules or {}).get(kind)
        if kind == "realsense":
            from fuseflow.live.sources.realsense import RealSenseSource

            src = RealSenseSource(serials, rs_module=module)
        else:
            from fuseflow.live.sources.orbbec import OrbbecSource

            src = OrbbecSource(serials, ob_module=module)
        return OpenedSource(src, f"{kind}: {len(src.rig)} cameras ({', '.join(src.rig.ids)})")
    files = _camera_files(specs)
    if files is not None:
        from fuseflow.io.convert import convert

        temp = Path(tempfile.mkdtemp(prefix="fuseflow-live-"))
        try:
            convert(files, temp / "rec")
            rec = open_recording(temp / "rec")
        except BaseException:
            shutil.rmtree(temp, ignore_errors=True)
            raise
        src = _replay(rec, replay)
        return OpenedSource(src, f"replay of {len(files)} camera files ({len(rec)} frames)", temp)
    if len(specs) > 1:
        raise ValidationError(f"SOURCE: one recording directory, or .bag/.mkv files; got {specs}")
    rec = open_recording(specs[0])
    return OpenedSource(_replay(rec, replay),
                        f"replay of {rec.path} ({len(rec)} frames, {len(rec.rig)} cameras)")  # fmt: skip


def _replay(rec: Any, replay: ReplayOptions) -> ReplaySource:
    if not replay.aligned:
        return ReplaySource(rec, replay.rate, replay.loop, replay.preload)
    src = ReplaySource(rec, replay.rate, replay.loop, replay.preload, clock=time.time)
    src.start = src.align_start(time.time())
    return src
