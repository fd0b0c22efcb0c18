"""The live loop: replay timing, newest-frame-wins dropping with a slow fusion, dropouts, stopping."""

import threading
import time

import numpy as np
import pytest
import torch

import fuseflow
from fuseflow.errors import FuseFlowError, ValidationError
from fuseflow.live.loop import LatestFrame, LiveLoop, LiveSettings
from fuseflow.live.sources.replay import ReplaySource
from fuseflow.types import FusedCloud


def _tiny_rec(tmp_path, frames=6, n=3, drop=None):
    K = [[40.0, 0, 15.5], [0, 40.0, 11.5], [0, 0, 1]]
    cams = []
    for i in range(n):
        T = np.eye(4)
        T[0, 3] = 0.1 * i
        cams.append(fuseflow.Camera(f"c{i}", 32, 24, K, T_cam_world=T))
    rig = fuseflow.Rig(tuple(cams))
    rng = np.random.default_rng(0)
    for t in range(frames):
        depth = rng.uniform(1.0, 2.0, (n, 24, 32))
        color = rng.integers(0, 255, (n, 24, 32, 3), dtype=np.uint8)
        fuseflow.write_frame(tmp_path, rig, t, color, depth)
    fuseflow.write_rig(tmp_path, rig)
    if drop is not None:  # camera drop[0] delivers nothing from frame drop[1] on
        for t in range(drop[1], frames):
            (tmp_path / drop[0] / "depth" / f"{t:06d}.png").unlink()
    return fuseflow.open_recording(tmp_path)


class SlowFuse:
    """A stand-in for FUSE that takes ``seconds`` and returns one point per present view."""

    def __init__(self, seconds):
        self.seconds = seconds
        self.calls = 0

    def __call__(self, frame, rig):
        self.calls += 1
        time.sleep(self.seconds)
        m = int(frame.present.sum())
        cloud = FusedCloud(
            xyz=torch.zeros(m, 3), rgb=torch.zeros(m, 3, dtype=torch.uint8), weight=torch.ones(m),
            camera=torch.arange(m, dtype=torch.int16),
        )  # fmt: skip
        return cloud, self.seconds * 1000.0


class Collect:
    def __init__(self):
        self.infos, self.closed = [], False

    def send(self, cloud, info):
        self.infos.append(info)

    def close(self):
        self.closed = True


def test_replay_releases_frames_at_the_rate(tmp_path):
    rec = _tiny_rec(tmp_path, frames=6)
    src = ReplaySource(rec, rate=20.0, preload=True)
    t0 = time.perf_counter()
    times = [time.perf_counter() - t0 for _ in src.frames()]
    assert len(times) == 6 and src.skipped == 0
    assert times[-1] == pytest.approx(5 / 20.0, abs=0.08)  # 50 ms apart, not as fast as possible


def test_replay_lets_stale_frames_go_with_a_fake_clock(tmp_path):
    rec = _tiny_rec(tmp_path, frames=6)
    now = [0.0]
    src = ReplaySource(rec, rate=10.0, preload=True, clock=lambda: now[0], sleep=lambda s: None)
    got = []
    for f in src.frames():
        got.append(f.index)
        now[0] += 0.45 if f.index == 1 else 0.1  # the reader is slow once: at 0.55 s, frame 5 is due
    assert got == [0, 1, 5] and src.skipped == 3


def test_replay_loops_until_closed_and_rejects_bad_rate(tmp_path):
    rec = _tiny_rec(tmp_path, frames=2)
    now = [0.0]
    src = ReplaySource(rec, rate=200.0, loop=True, preload=True, clock=lambda: now[0],
                       sleep=lambda s: now.__setitem__(0, now[0] + s))  # fmt: skip
    got = []
    for f in src.frames():
        got.append(f.index)
        if len(got) == 5:
            src.close()
    assert got == [0, 1, 0, 1, 0] and now[0] == pytest.approx(4 / 200.0)
    with pytest.raises(ValidationError, match="--rate"):
        ReplaySource(rec, rate=0)


def test_latest_frame_keeps_only_the_newest():
    slot = LatestFrame()
    for k in range(3):
        slot.put(k)
    assert slot.take(0.01) == 2 and slot.dropped == 2
    assert slot.take(0.01) is None
    slot.close()
    assert slot.take(10.0) is None  # closed: no wait


def test_slow_fusion_drops_old_frames_and_never_slows_capture(tmp_path):
    rec = _tiny_rec(tmp_path, frames=12)
    src = ReplaySource(rec, rate=40.0, preload=True)
    sink = Collect()
    loop = LiveLoop(src, rec.rig, LiveSettings(), sinks=[sink], fuse_fn=SlowFuse(0.1))
    t0 = time.perf_counter()
    s = loop.run()
    wall = time.perf_counter() - t0
    assert s.frames_in == 12 and src.skipped == 0  # capture kept the 40 fps schedule
    assert s.frames_out + s.dropped == 12 and s.dropped >= 6  # fusion took the newest, dropped the rest
    assert wall < 12 * 0.1  # not queued: fusing all 12 would take 1.2 s
    numbers = [i.number for i in sink.infos]
    assert numbers == sorted(numbers) and numbers[-1] == 11  # the newest frame is always fused
    assert s.stopped_by == "end of source" and sink.closed
    assert s.latency_ms_p95 is not None and s.latency_ms_p95 < 300


def test_fast_fusion_keeps_every_frame_and_reports_stats(tmp_path):
    rec = _tiny_rec(tmp_path, frames=6)
    loop = LiveLoop(ReplaySource(rec, rate=30.0, preload=True), rec.rig, fuse_fn=SlowFuse(0.0))
    s = loop.run()
    assert (s.frames_in, s.frames_out, s.dropped) == (6, 6, 0)
    snap = loop.stats.snapshot()
    assert snap["frames_out"] == 6 and snap["points"] == 3 and snap["latency_ms_p50"] < 100


def test_camera_that_stops_delivering_is_fused_around(tmp_path):
    rec = _tiny_rec(tmp_path, frames=5, drop=("c1", 2))
    loop = LiveLoop(ReplaySource(rec, rate=50.0, preload=True), rec.rig, fuse_fn=SlowFuse(0.0))
    s = loop.run()
    assert s.frames_out == 5 and s.dropped_views == {"c1": 3}
    assert any("camera c1 was missing in 3 of 5" in w for w in s.warnings)


def test_frames_and_duration_limits_and_stop(tmp_path):
    rec = _tiny_rec(tmp_path, frames=3)
    s = LiveLoop(ReplaySource(rec, rate=100.0, loop=True, preload=True), rec.rig, LiveSettings(frames=7),
                 fuse_fn=SlowFuse(0.0)).run()  # fmt: skip
    assert s.frames_in == 7 and s.stopped_by == "frames"
    src = ReplaySource(rec, rate=100.0, loop=True, preload=True)
    s = LiveLoop(src, rec.rig, LiveSettings(duration=0.3), fuse_fn=SlowFuse(0.0)).run()
    assert s.stopped_by == "duration" and 0.25 < s.wall_s < 1.5 and src.closed
    loop = LiveLoop(ReplaySource(rec, rate=100.0, loop=True, preload=True), rec.rig, fuse_fn=SlowFuse(0.0))
    threading.Timer(0.2, loop.stop).start()
    assert loop.run().stopped_by == "stop"
    assert not [t for t in threading.enumerate() if t.name == "fuseflow-capture"]


def test_real_fuse_and_rig_checks(dynamic_rec):
    rec = fuseflow.open_recording(dynamic_rec)
    src = ReplaySource(rec, rate=100.0)  # decoding cannot keep up with 100 fps: stale frames go
    s = LiveLoop(src, rec.rig, LiveSettings(preset="live")).run()
    assert s.frames_in == len(rec) == s.frames_out + s.dropped and s.frames_out >= 1 and s.points_mean > 1000
    other = fuseflow.Rig((fuseflow.Camera("zz", 200, 150, rec.rig[0].K, T_cam_world=np.eye(4)),))
    with pytest.raises(FuseFlowError, match="does not have"):
        LiveLoop(ReplaySource(rec), other)


def test_crop_keeps_the_box_and_refuses_a_bad_one(tmp_path):
    rec = _tiny_rec(tmp_path, frames=3)
    points = {}

    class Keep(Collect):
        def send(self, cloud, info):
            points[info.number] = len(cloud)

    for box, expect in (("-1,-1,-1,1,1,1", 3), ("1,1,1,2,2,2", 0)):  # SlowFuse's points lie at the origin
        points.clear()
        loop = LiveLoop(ReplaySource(rec, rate=30.0, preload=True), rec.rig, LiveSettings(crop=box), [Keep()],
                        fuse_fn=SlowFuse(0.0))  # fmt: skip
        loop.run()
        assert points and set(points.values()) == {expect}
    assert LiveLoop(ReplaySource(rec), rec.rig, LiveSettings(crop="auto"), fuse_fn=SlowFuse(0.0)).volume is not None
    with pytest.raises(ValidationError):
        LiveLoop(ReplaySource(rec), rec.rig, LiveSettings(crop="1,2,3"), fuse_fn=SlowFuse(0.0))
