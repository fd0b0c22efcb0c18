"""Live capture from several Intel RealSense cameras (optional extra ``fuseflow[realsense]``).

``RealSenseSource`` opens one pyrealsense2 pipeline per device, aligns depth to colour, and
yields ``Frame`` objects in the library's conventions (depth float32 metres, RGB uint8, camera
axis first). Cameras are software-synchronised: each ``Frame`` takes the newest frameset of
every device; a device that delivers nothing within ``timeout_ms`` is marked not present for
that frame (a dropped view), so the stream goes on with N-1 views. For tight sync, wire the
cameras' hardware sync and set ``inter_cam_sync_mode`` (documented by Intel); timestamps of
each view are kept in ``device_timestamps``.

Intrinsics come from the colour stream profile (depth is aligned to colour); the depth scale
from the device's depth sensor (metres per unit). Extrinsics are unknown: calibrate with GMAC.

The module never imports pyrealsense2 at import time; tests inject a fake module that replays
a recording (tests/live/test_realsense.py).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from fuseflow.errors import RecordingError, ValidationError, require
from fuseflow.live.sources.device import DeviceConfig, DeviceSource, select_serials
from fuseflow.types import Camera, Rig

__all__ = ["RealSenseConfig", "RealSenseSource"]


def _import_rs() -> Any:
    return require("pyrealsense2", "realsense", "live RealSense capture")


@dataclass(frozen=True)
class RealSenseConfig(DeviceConfig):
    """Stream settings shared by all devices (``DeviceConfig``), with this kind's depth range."""

    depth_range: tuple[float, float] = (0.2, 6.0)
    """Trustworthy depth range in metres (D4xx-class sensors, Intel's datasheet)."""


class RealSenseSource(DeviceSource):
    """Iterate synchronised multi-device RealSense frames as ``Frame`` objects.

    Args:
        serials: device serial numbers, in rig order; None takes every connected device
            (sorted by serial number so the order is stable across runs).
        config: stream settings.
        rs_module: the pyrealsense2 module, or a stand-in with the same API (tests).
    """

    def __init__(
        self,
        serials: Sequence[str] | None = None,
        config: RealSenseConfig = RealSenseConfig(),
        rs_module: Any = None,
    ):
        self._rs = rs_module if rs_module is not None else _import_rs()
        self.config = config
        rs = self._rs
        found = [d.get_info(rs.camera_info.serial_number) for d in rs.context().query_devices()]
        serials = select_serials(found, serials, "RealSense")
        self.serials = serials
        self._pipes: list[Any] = []
        self._align = rs.align(rs.stream.color)
        cams = []
        try:
            for s in serials:
                cfg = rs.config()
                cfg.enable_device(s)
                cfg.enable_stream(rs.stream.depth, config.width, config.height, rs.format.z16, config.fps)
                cfg.enable_stream(rs.stream.color, config.width, config.height, rs.format.rgb8, config.fps)
                pipe = rs.pipeline()
                profile = pipe.start(cfg)
                self._pipes.append(pipe)
                intr = profile.get_stream(rs.stream.color).as_video_stream_profile().get_intrinsics()
                scale_m = float(profile.get_device().first_depth_sensor().get_depth_scale())
                if not scale_m > 0:
                    raise RecordingError(f"RealSense {s}: depth scale {scale_m} is not positive")
                K = np.array([[intr.fx, 0.0, intr.ppx], [0.0, intr.fy, intr.ppy], [0.0, 0.0, 1.0]])
                cams.append(Camera(s, int(intr.width), int(intr.height), K, 1.0 / scale_m, config.depth_range))
        except Exception:
            self.close()
            raise
        self.rig = Rig(tuple(cams))
        self.rig.resolution  # noqa: B018 - one resolution for batching, clear error otherwise
        self._index = 0
        self.device_timestamps: list[list[float | None]] = []

    def _grab(self, i: int) -> tuple[np.ndarray, np.ndarray, float] | None:
        cam = self.rig.cameras[i]
        frames = self._pipes[i].try_wait_for_frames(self.config.timeout_ms)
        ok, frames = frames if isinstance(frames, tuple) else (frames is not None, frames)
        if not ok:
            return None
        aligned = self._align.process(frames)
        d, c = aligned.get_depth_frame(), aligned.get_color_frame()
        if not d or not c:
            return None
        depth = np.asanyarray(d.get_data()).astype(np.float32) / np.float32(cam.depth_scale)
        color = np.asanyarray(c.get_data())
        if depth.shape != (cam.height, cam.width) or color.shape != (cam.height, cam.width, 3):
            raise ValidationError(
                f"RealSense {cam.id}: got depth {depth.shape} colour {color.shape}, expected {cam.width}x{cam.height}"
            )
        return color, depth, float(frames.get_timestamp()) / 1000.0
