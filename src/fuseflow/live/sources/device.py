"""What the live camera sources share (``realsense.RealSenseSource``, ``orbbec.OrbbecSource``):
their stream settings (``DeviceConfig``), one frame from every device, dropped views marked not present, iteration that stops when every
device stops delivering, and stopping the pipelines. A subclass sets ``rig`` (the cameras in
order), ``_pipes`` (objects with ``stop()``), ``_index`` and ``device_timestamps``, and
implements ``_grab(i)``: (colour HxWx3 uint8, depth HxW float32 metres, device time s) of camera
``i``, or None when it delivered nothing."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from fuseflow.io.images import clean_depth
from fuseflow.types import Frame, Rig

__all__ = ["DeviceConfig", "DeviceSource"]


@dataclass(frozen=True)
class DeviceConfig:
    """Stream settings shared by all devices of a source (each device kind subclasses it with its
    own trustworthy depth range)."""

    width: int = 640
    """Colour and (aligned) depth width in pixels; a mode the devices support."""
    height: int = 480
    """Image height in pixels."""
    fps: int = 30
    """Frames per second requested from every device."""
    timeout_ms: int = 200
    """Wait for a device's frameset this long before marking its view dropped for a frame."""
    depth_range: tuple[float, float] = (0.2, 6.0)
    """Trustworthy depth range in metres."""


def select_serials(found: list[str], asked: list[str] | None, vendor: str) -> list[str]:
    """The serials to open: ``asked`` (every connected one when None), each connected.
    RecordingError naming the absent ones (or that none is connected)."""
    from fuseflow.errors import RecordingError

    found = sorted(found)
    serials = found if asked is None else list(asked)
    if not serials:
        raise RecordingError(f"no {vendor} device connected")
    absent = [s for s in serials if s not in found]
    if absent:
        raise RecordingError(f"{vendor} devices not connected: {absent}; connected: {found}")
    return serials


class DeviceSource:
    """Base of the live device sources (module docstring)."""

    rig: Rig
    _pipes: list[Any]
    _index: int
    device_timestamps: list[list[float | None]]

    def _grab(self, i: int) -> tuple[np.ndarray, np.ndarray, float] | None:
        raise NotImplementedError

    def read(self) -> Frame:
        """Grab one frame from every device (dropped views marked not present)."""
        w, h = self.rig.resolution
        n = len(self.rig)
        color = np.zeros((n, h, w, 3), np.uint8)
        depth = np.zeros((n, h, w), np.float32)
        present = np.zeros(n, bool)
        invalid = np.zeros(n, np.int64)
        stamps: list[float | None] = []
        for i in range(n):
            got = self._grab(i)
            stamps.append(None if got is None else got[2])
            if got is not None:
                color[i] = got[0]
                depth[i], invalid[i] = clean_depth(got[1])
                present[i] = True
        self.device_timestamps.append(stamps)
        known = [s for s in stamps if s is not None]
        frame = Frame(
            index=self._index,
            camera_ids=self.rig.ids,
            color=torch.from_numpy(color),
            depth=torch.from_numpy(depth),
            present=torch.from_numpy(present),
            invalid_depth=torch.from_numpy(invalid),
            timestamp=float(np.median(known)) if known else None,
        )
        self._index += 1
        return frame

    def frames(self, count: int | None = None) -> Iterator[Frame]:
        """Yield ``count`` frames (forever when None); stops when every device stops delivering."""
        k = 0
        while count is None or k < count:
            f = self.read()
            if not bool(f.present.any()):
                return
            yield f
            k += 1

    def __iter__(self) -> Iterator[Frame]:
        return self.frames()

    def close(self) -> None:
        for p in self._pipes:
            try:
                p.stop()
            except Exception:  # noqa: BLE001 - stopping a dead pipeline must not mask the real error
                pass
        self._pipes = []

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
