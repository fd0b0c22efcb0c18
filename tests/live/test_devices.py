"""`fuseflow live` sources: RealSense and Orbbec devices (fake SDK modules replaying a recording,
one camera stopping mid-stream), a recording, and .bag files; fused by the live loop into files."""

import json

import numpy as np
import pytest
from tests.live.fake_orbbec import FakeOB
from tests.live.test_realsense import FakeRS

import fuseflow
from fuseflow.errors import FuseFlowError, ValidationError
from fuseflow.io.images import read_depth_raw
from fuseflow.live import LiveOutputs, ReplayOptions, open_source, run_live
from fuseflow.live.loop import LiveLoop, LiveSettings, Source
from fuseflow.live.sources import parse_device_spec
from fuseflow.live.sources.device import DeviceConfig
from fuseflow.types import Calibration

K = [[40.0, 0, 15.5], [0, 40.0, 11.5], [0, 0, 1]]


def _recording(tmp_path, n=3, frames=6):
    rig = fuseflow.Rig(tuple(fuseflow.Camera(f"{900 + i}", 32, 24, K) for i in range(n)))
    rng = np.random.default_rng(4)
    for t in range(frames):
        fuseflow.write_frame(
            tmp_path, rig, t, rng.integers(0, 255, (n, 24, 32, 3), dtype=np.uint8), np.full((n, 24, 32), 1.5)
        )  # a wall 1.5 m in front of cameras side by side: every view agrees
    fuseflow.write_rig(tmp_path, rig)
    return fuseflow.open_recording(tmp_path)


def _per_device(rec, stop):
    frames = {}
    for i, cid in enumerate(rec.rig.ids):
        frames[cid] = [
            None if (cid == stop[0] and t >= stop[1]) else
            (rec[t].color[i].numpy(), read_depth_raw(rec.path / cid / "depth" / f"{t:06d}.png"))
            for t in range(len(rec))
        ]  # fmt: skip
    return frames


def _calibration(rig):
    T = {}
    for i, c in enumerate(rig.ids):
        E = np.eye(4)
        E[0, 3] = -0.05 * i
        T[c] = E
    return Calibration(T, {"source": "test"})


@pytest.mark.parametrize("kind", ["realsense", "orbbec"])
def test_device_source_live_with_a_camera_that_stops(tmp_path, kind):
    rec = _recording(tmp_path / "rec")
    frames = _per_device(rec, stop=("901", 2))
    module = FakeRS(frames, K) if kind == "realsense" else FakeOB(frames, K)
    opened = open_source([kind], modules={kind: module})
    assert opened.rig.ids == rec.rig.ids and kind in opened.description
    out = tmp_path / "out"
    result = run_live(opened, _calibration(rec.rig), LiveSettings(preset="live"), LiveOutputs(record=out))
    s = result.summary
    assert s.stopped_by == "end of source" and s.frames_in == 6 and s.frames_out + s.dropped == 6
    assert s.dropped_views.get("901", 0) >= 1 and set(s.dropped_views) == {"901"}
    assert any("camera 901 was missing" in w for w in s.warnings)
    lines = [json.loads(x) for x in (out / "frames.jsonl").read_text().splitlines()]
    assert len(lines) == s.frames_out == len(list((out / "clouds").glob("*.ply")))
    assert all(x["points"] > 0 for x in lines) and (out / "calib.json").exists()
    assert sorted(module.stopped) == sorted(rec.rig.ids)  # every device stopped at the end


def test_device_specs_and_errors(tmp_path):
    assert parse_device_spec("realsense") == ("realsense", None)
    assert parse_device_spec("orbbec:A1,B2") == ("orbbec", ["A1", "B2"])
    assert parse_device_spec(str(tmp_path)) is None
    with pytest.raises(ValidationError, match="serial"):
        parse_device_spec("realsense:")
    rec = _recording(tmp_path / "rec", frames=2)
    fake = FakeRS(_per_device(rec, stop=("x", 0)), K)
    opened = open_source(["realsense:902,900"], modules={"realsense": fake})
    assert opened.rig.ids == ("902", "900")
    assert isinstance(opened, Source) and isinstance(opened.source, Source)  # the typed protocol
    assert isinstance(opened.source.config, DeviceConfig) and opened.source.config.depth_range == (0.2, 6.0)
    with pytest.raises(ValidationError, match="reads a Source"):
        LiveLoop(object(), rec.rig)
    opened.close()
    with pytest.raises(FuseFlowError, match="--calib"):  # devices have no extrinsics of their own
        run_live(open_source(["realsense"], modules={"realsense": fake}), None)
    assert len(fake.stopped) >= 3  # closed on the error too


def test_recording_and_bag_sources(tmp_path, dynamic_rec):
    opened = open_source([str(dynamic_rec)], ReplayOptions(rate=50.0))
    assert "replay" in opened.description and opened.rig.is_calibrated
    opened.close()
    with pytest.raises(ValidationError, match="one recording"):
        open_source([str(dynamic_rec), str(dynamic_rec)])
    with pytest.raises(FuseFlowError):
        open_source([str(tmp_path / "nothing")])


def test_bag_files_replay_at_their_timestamps(tmp_path):
    pytest.importorskip("rosbags")
    import time

    from tests.io.recording_writers import write_realsense_bag

    rec = _recording(tmp_path / "rec", n=2, frames=4)
    for i, cid in enumerate(rec.rig.ids):
        color = np.stack([rec[t].color[i].numpy() for t in range(4)])
        depth = np.stack([read_depth_raw(rec.path / cid / "depth" / f"{t:06d}.png") for t in range(4)])
        write_realsense_bag(tmp_path / f"{cid}.bag", cid, color, depth, 100.0 + 0.1 * np.arange(4), np.array(K))
    opened = open_source([str(tmp_path / "900.bag"), str(tmp_path / "901.bag")])
    temp = opened.source.rec.path
    assert opened.rig.ids == ("900", "901") and "2 camera files" in opened.description
    t0 = time.perf_counter()
    got = list(opened.frames())
    assert len(got) == 4 and time.perf_counter() - t0 == pytest.approx(0.3, abs=0.15)  # 0.1 s apart
    opened.close()
    assert not temp.exists()  # the converted recording is removed
