"""A stand-in for the slice of pyorbbecsdk that OrbbecSource uses, replaying per-device frames
(imported by tests/live/test_orbbec.py and tests/live/test_devices.py)."""

from types import SimpleNamespace

import numpy as np


class FakeOB:
    """``frames[serial]`` is a list of (rgb uint8 (H, W, 3), depth uint16 mm) or None (the device
    delivers nothing for that frame); past the end of its list a device delivers nothing."""

    OBSensorType = SimpleNamespace(COLOR_SENSOR="color", DEPTH_SENSOR="depth")
    OBFormat = SimpleNamespace(RGB="rgb", Y16="y16")
    OBStreamType = SimpleNamespace(COLOR_STREAM="color-stream")

    def __init__(self, frames, K, depth_scale_mm=1.0):
        self._frames = frames
        ob = self
        self.started, self.stopped = [], []

        class Device:
            def __init__(self, serial):
                self.serial = serial

            def get_device_info(self):
                return SimpleNamespace(get_serial_number=lambda: self.serial)

        class DeviceList:
            def __init__(self):
                self.devices = [Device(s) for s in ob._frames]

            def get_count(self):
                return len(self.devices)

            def get_device_by_index(self, i):
                return self.devices[i]

        class Config:
            def __init__(self):
                self.profiles = []

            def enable_stream(self, profile):
                self.profiles.append(profile)

        class Pipeline:
            def __init__(self, device):
                self.serial, self.k = device.serial, 0

            def get_stream_profile_list(self, sensor):
                return SimpleNamespace(get_video_stream_profile=lambda w, h, fmt, fps: (sensor, w, h, fmt, fps))

            def start(self, config):
                assert {p[0] for p in config.profiles} == {"color", "depth"}
                ob.started.append(self.serial)

            def get_camera_param(self):
                h, w = ob._frames[self.serial][0][0].shape[:2]
                intr = SimpleNamespace(fx=K[0][0], fy=K[1][1], cx=K[0][2], cy=K[1][2], width=w, height=h)
                return SimpleNamespace(rgb_intrinsic=intr)

            def wait_for_frames(self, timeout_ms):
                seq = ob._frames[self.serial]
                item = seq[self.k] if self.k < len(seq) else None
                self.k += 1
                if item is None:
                    return None
                rgb, d = item
                stamp = 33.0 * self.k
                depth = SimpleNamespace(get_data=lambda: np.ascontiguousarray(d).tobytes(),
                                        get_depth_scale=lambda: depth_scale_mm, get_timestamp=lambda: stamp)  # fmt: skip
                color = SimpleNamespace(get_data=lambda: np.ascontiguousarray(rgb).tobytes())
                fs = SimpleNamespace(get_depth_frame=lambda: depth, get_color_frame=lambda: color)
                fs.as_frame_set = lambda: fs
                return fs

            def stop(self):
                ob.stopped.append(self.serial)

        self.Context = lambda: SimpleNamespace(query_devices=DeviceList)
        self.Config = Config
        self.Pipeline = Pipeline
        self.AlignFilter = lambda align_to_stream: SimpleNamespace(process=lambda fs: fs)
