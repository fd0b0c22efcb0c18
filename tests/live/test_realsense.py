"""RealSenseSource against a fake pyrealsense2 module that replays a recording."""

from types import SimpleNamespace

import numpy as np
import pytest
import torch

import fuseflow
from fuseflow import FuseFlowError, RecordingError
from fuseflow.live.sources.realsense import RealSenseConfig, RealSenseSource


class FakeRS:
    """The slice of the pyrealsense2 API that RealSenseSource uses, replaying per-device frames.

    ``frames[serial]`` is a list of (rgb uint8, depth uint16) or None (device delivers nothing).
    """

    camera_info = SimpleNamespace(serial_number="serial")
    stream = SimpleNamespace(depth="depth", color="color")
    format = SimpleNamespace(z16="z16", rgb8="rgb8")

    def __init__(self, frames, K, depth_unit=0.001):
        self._frames = frames
        self._K = K
        self._unit = depth_unit
        self.started = []
        self.stopped = []
        rs = self

        class Device:
            def __init__(self, s):
                self.s = s

            def get_info(self, what):
                return self.s

            def first_depth_sensor(self):
                return SimpleNamespace(get_depth_scale=lambda: rs._unit)

        class Config:
            def enable_device(self, s):
                self.serial = s

            def enable_stream(self, *a):
                pass

        class Pipeline:
            def start(self, cfg):
                self.serial, self.k = cfg.serial, 0
                rs.started.append(cfg.serial)
                h, w = rs._frames[cfg.serial][0][0].shape[:2]
                intr = SimpleNamespace(fx=K[0][0], fy=K[1][1], ppx=K[0][2], ppy=K[1][2], width=w, height=h)
                vsp = SimpleNamespace(get_intrinsics=lambda: intr)
                return SimpleNamespace(
                    get_stream=lambda s: SimpleNamespace(as_video_stream_profile=lambda: vsp),
                    get_device=lambda: Device(cfg.serial),
                )

            def try_wait_for_frames(self, timeout_ms):
                seq = rs._frames[self.serial]
                item = seq[self.k] if self.k < len(seq) else None
                self.k += 1
                if item is None:
                    return False, None
                rgb, d = item
                fs = SimpleNamespace(
                    get_depth_frame=lambda: SimpleNamespace(get_data=lambda: d),
                    get_color_frame=lambda: SimpleNamespace(get_data=lambda: rgb),
                    get_timestamp=lambda: 1000.0 * self.k,
                )
                return True, fs

            def stop(self):
                rs.stopped.append(self.serial)

        self.config = Config
        self.pipeline = Pipeline
        self.align = lambda to: SimpleNamespace(process=lambda fs: fs)
        self.context = lambda: SimpleNamespace(query_devices=lambda: [Device(s) for s in rs._frames])


def _recording(tmp_path, n=3, frames=3):
    K = [[100.0, 0, 15.5], [0, 100.0, 11.5], [0, 0, 1]]
    rig = fuseflow.Rig(tuple(fuseflow.Camera(f"{1000 + i}", 32, 24, K) for i in range(n)))
    rng = np.random.default_rng(1)
    for t in range(frames):
        fuseflow.write_frame(
            tmp_path, rig, t, rng.integers(0, 255, (n, 24, 32, 3), dtype=np.uint8), rng.uniform(0.5, 3, (n, 24, 32))
        )
    fuseflow.write_rig(tmp_path, rig)
    return fuseflow.open_recording(tmp_path), K


def _fake_from(rec, K, drop=None):
    from fuseflow.io.images import read_depth_raw

    frames = {}
    for i, cid in enumerate(rec.rig.ids):
        seq = []
        for t in range(len(rec)):
            if drop == (cid, t):
                seq.append(None)
                continue
            f = rec[t]
            raw = read_depth_raw(rec.path / cid / "depth" / f"{t:06d}.png")
            seq.append((f.color[i].numpy(), raw))
        frames[cid] = seq
    return FakeRS(frames, K)


def test_replays_recording_as_frames(tmp_path):
    rec, K = _recording(tmp_path)
    rs = _fake_from(rec, K)
    with RealSenseSource(rs_module=rs) as src:
        assert src.rig.ids == rec.rig.ids and src.rig[0].depth_scale == 1000.0
        assert np.allclose(src.rig[0].K, K)
        got = list(src.frames())
    assert len(got) == 3 and sorted(rs.stopped) == sorted(rec.rig.ids)
    for t, f in enumerate(got):
        ref = rec[t]
        assert torch.equal(f.color, ref.color) and torch.allclose(f.depth, ref.depth)


def test_dropped_device_frame_keeps_stream_running(tmp_path):
    rec, K = _recording(tmp_path)
    rs = _fake_from(rec, K, drop=("1001", 1))
    src = RealSenseSource(rs_module=rs, config=RealSenseConfig(width=32, height=24))
    got = list(src.frames())
    assert [f.missing for f in got] == [(), ("1001",), ()]
    assert src.device_timestamps[1][1] is None


def test_missing_device_and_missing_package(tmp_path):
    rec, K = _recording(tmp_path)
    with pytest.raises(RecordingError, match="not connected"):
        RealSenseSource(["nope"], rs_module=_fake_from(rec, K))
    try:
        import pyrealsense2  # noqa: F401
    except ImportError:
        with pytest.raises(FuseFlowError, match=r"pip install 'fuseflow\[realsense\]'"):
            RealSenseSource()
