"""Live capture from several Orbbec cameras (Femto Bolt / Mega, Gemini 2 / 330; optional extra
``fuseflow[orbbec]``, the ``pyorbbecsdk2`` package, imported as ``pyorbbecsdk``).

``OrbbecSource`` has the shape of ``RealSenseSource``: one SDK pipeline per device, depth aligned
to colour (``AlignFilter`` to the colour stream), ``Frame`` objects in the library's conventions
(depth float32 metres, RGB uint8, camera axis first). Cameras are software-synchronised: each
``Frame`` takes the newest frameset of every device; a device that delivers nothing within
``timeout_ms`` is marked not present for that frame (a dropped view), so the stream goes on with
the others. For tight sync, wire the devices' sync cables and set each device's multi-device sync
mode (primary / secondary) with Orbbec's tools; device timestamps are kept in
``device_timestamps``.

Intrinsics come from the colour stream (``get_camera_param().rgb_intrinsic``); the depth unit from
each depth frame (``get_depth_scale()``: millimetres per unit). Extrinsics are unknown: calibrate
with GMAC. The module never imports the SDK at import time; tests inject a fake module that
replays a recording (tests/live/test_orbbec.py).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from fuseflow.errors import ValidationError, require
from fuseflow.live.sources.device import DeviceConfig, DeviceSource, select_serials
from fuseflow.types import Camera, Rig

__all__ = ["OrbbecConfig", "OrbbecSource"]


def _import_ob() -> Any:
    return require("pyorbbecsdk", "orbbec", "live Orbbec capture", "pyorbbecsdk2")


@dataclass(frozen=True)
class OrbbecConfig(DeviceConfig):
    """Stream settings shared by all devices (``DeviceConfig``), with this kind's depth range."""

    depth_range: tuple[float, float] = (0.25, 5.5)
    """Trustworthy depth range in metres (Femto Bolt NFOV unbinned: 0.25-5.46 m, Orbbec's datasheet)."""


class OrbbecSource(DeviceSource):
    """Iterate synchronised multi-device Orbbec frames as ``Frame`` objects.

    Args:
        serials: device serial numbers, in rig order; None takes every connected device (sorted
            by serial number).
        config: stream settings.
        ob_module: the pyorbbecsdk module, or a stand-in with the same API (tests).
    """

    def __init__(self, serials: Sequence[str] | None = None, config: OrbbecConfig = OrbbecConfig(),
                 ob_module: Any = None):  # fmt: skip
        self._ob = ob_module if ob_module is not None else _import_ob()
        self.config = config
        devices = self._devices()
        serials = select_serials(list(devices), serials, "Orbbec")
        self.serials = serials
        self._pipes: list[Any] = []
        self._align = self._ob.AlignFilter(align_to_stream=self._ob.OBStreamType.COLOR_STREAM)
        try:
            cams = [self._start(s, devices[s]) for s in serials]
        except Exception:
            self.close()
            raise
        self.rig = Rig(tuple(cams))
        self.rig.resolution  # noqa: B018 - one resolution for batching, clear error otherwise
        self._index = 0
        self.device_timestamps: list[list[float | None]] = []

    def _devices(self) -> dict[str, Any]:
        listing = self._ob.Context().query_devices()
        out = {}
        for i in range(listing.get_count()):
            dev = listing.get_device_by_index(i)
            out[str(dev.get_device_info().get_serial_number())] = dev
        return out

    def _start(self, serial: str, device: Any) -> Camera:
        ob, cfg = self._ob, self.config
        pipe = ob.Pipeline(device)
        config = ob.Config()
        for sensor, fmt in (
            (ob.OBSensorType.COLOR_SENSOR, ob.OBFormat.RGB),
            (ob.OBSensorType.DEPTH_SENSOR, ob.OBFormat.Y16),
        ):
            profiles = pipe.get_stream_profile_list(sensor)
            config.enable_stream(profiles.get_video_stream_profile(cfg.width, cfg.height, fmt, cfg.fps))
        pipe.start(config)
        self._pipes.append(pipe)
        intr = pipe.get_camera_param().rgb_intrinsic
        K = np.array([[intr.fx, 0.0, intr.cx], [0.0, intr.fy, intr.cy], [0.0, 0.0, 1.0]])
        return Camera(serial, int(intr.width), int(intr.height), K, 1000.0, cfg.depth_range)

    def _grab(self, i: int) -> tuple[np.ndarray, np.ndarray, float] | None:
        cam = self.rig.cameras[i]
        frames = self._pipes[i].wait_for_frames(self.config.timeout_ms)
        if frames is None:
            return None
        aligned = self._align.process(frames)
        if aligned is None:
            return None
        aligned = aligned.as_frame_set()
        d, c = aligned.get_depth_frame(), aligned.get_color_frame()
        if d is None or c is None:
            return None
        h, w = cam.height, cam.width
        raw = np.frombuffer(d.get_data(), dtype=np.uint16)
        color = np.frombuffer(c.get_data(), dtype=np.uint8)
        if raw.size != h * w or color.size != h * w * 3:
            raise ValidationError(
                f"Orbbec {cam.id}: got {raw.size} depth and {color.size // 3} colour pixels, expected {w}x{h} RGB"
            )
        depth = raw.reshape(h, w).astype(np.float32) * np.float32(d.get_depth_scale() / 1000.0)
        return color.reshape(h, w, 3), depth, float(d.get_timestamp()) / 1000.0
