"""OrbbecSource against a fake pyorbbecsdk module that replays a recording."""

import numpy as np
import pytest
import torch
from tests.live.fake_orbbec import FakeOB

import fuseflow
from fuseflow import FuseFlowError, RecordingError
from fuseflow.io.images import read_depth_raw
from fuseflow.live.sources.orbbec import OrbbecSource

K = [[100.0, 0, 15.5], [0, 100.0, 11.5], [0, 0, 1]]


def _recording(tmp_path, n=3, frames=4):
    rig = fuseflow.Rig(tuple(fuseflow.Camera(f"CL{100 + i}", 32, 24, K) for i in range(n)))
    rng = np.random.default_rng(2)
    for t in range(frames):
        fuseflow.write_frame(
            tmp_path, rig, t, rng.integers(0, 255, (n, 24, 32, 3), dtype=np.uint8), rng.uniform(0.5, 3, (n, 24, 32))
        )
    fuseflow.write_rig(tmp_path, rig)
    return fuseflow.open_recording(tmp_path)


def fake_from(rec, stop=None):
    """FakeOB replaying ``rec``; ``stop = (camera, t)``: that camera delivers nothing from frame t on."""
    frames = {}
    for i, cid in enumerate(rec.rig.ids):
        seq = []
        for t in range(len(rec)):
            if stop is not None and stop[0] == cid and t >= stop[1]:
                seq.append(None)
                continue
            seq.append((rec[t].color[i].numpy(), read_depth_raw(rec.path / cid / "depth" / f"{t:06d}.png")))
        frames[cid] = seq
    return FakeOB(frames, K)


def test_replays_recording_as_frames(tmp_path):
    rec = _recording(tmp_path)
    ob = fake_from(rec)
    with OrbbecSource(ob_module=ob) as src:
        assert src.rig.ids == rec.rig.ids and np.allclose(src.rig[0].K, K)
        got = list(src.frames())
    assert len(got) == 4 and sorted(ob.stopped) == sorted(rec.rig.ids)
    for t, f in enumerate(got):
        ref = rec[t]
        assert torch.equal(f.color, ref.color) and torch.allclose(f.depth, ref.depth)
    assert src.device_timestamps[0] == [0.033, 0.033, 0.033]


def test_camera_that_stops_delivering(tmp_path):
    rec = _recording(tmp_path)
    src = OrbbecSource(ob_module=fake_from(rec, stop=("CL101", 1)))
    got = list(src.frames())
    assert [f.missing for f in got] == [(), ("CL101",), ("CL101",), ("CL101",)]
    assert bool(got[2].present[0]) and not bool(got[2].present[1])


def test_serials_order_missing_device_and_package(tmp_path):
    rec = _recording(tmp_path)
    src = OrbbecSource(["CL102", "CL100"], ob_module=fake_from(rec))
    assert src.rig.ids == ("CL102", "CL100")
    f = src.read()
    assert torch.equal(f.color[0], rec[0].color[2])
    with pytest.raises(RecordingError, match="not connected"):
        OrbbecSource(["nope"], ob_module=fake_from(rec))
    try:
        import pyorbbecsdk  # noqa: F401
    except ImportError:
        with pytest.raises(FuseFlowError, match=r"pyorbbecsdk2: pip install 'fuseflow\[orbbec\]'"):
            OrbbecSource()
