"""Capture nodes on Ray: clock offsets found over round trips, frames paired as if the clocks
agreed, the same clouds as one host, a node killed mid-stream and restarted; the pieces without
Ray (offset filter, view codec, replays in step)."""

import threading
import time

import numpy as np
import pytest
import torch

from fuseflow.errors import ValidationError
from fuseflow.live.sources import ReplayOptions, open_source
from fuseflow.live.sources.clock import NodeClock, OffsetEstimator, StampDrift
from fuseflow.live.sources.frame_codec import ViewCodec, decode_views, encode_views

SPLIT = [("a", ("cam00", "cam01", "cam02"), 0.0), ("b", ("cam03", "cam04", "cam05"), 0.040),
         ("c", ("cam06", "cam07"), -0.025)]  # fmt: skip
REPLAY = ReplayOptions(rate=15.0, loop=True, preload=True, aligned=True)


def test_min_rtt_offset_within_half_round_trip():
    rng = np.random.default_rng(0)
    true = 0.040
    est = OffsetEstimator(window=32)
    for _ in range(32):
        out, back = rng.exponential(0.004), rng.exponential(0.004)  # asymmetric queueing delays
        t0 = 100.0 + rng.uniform(0, 1)
        est.add(t0, t0 + out + true, t0 + out + back)
    e = est.estimate()
    assert abs(e.offset_s - true) <= e.uncertainty_s
    assert abs(e.offset_s - true) < 0.002
    assert NodeClock(0.04, base=lambda: 1.0)() == pytest.approx(1.04)


def test_view_codec_depth_lossless_colour_jpeg_bounded(tmp_path, sim8):
    rec = sim8[1]
    f = rec[3]
    color, depth, present = f.color.numpy(), f.depth.numpy(), f.present.numpy()
    scales = [c.depth_scale for c in rec.rig.cameras]
    h, w = depth.shape[1:]
    for codec in (ViewCodec("jpeg", 90), ViewCodec("png"), ViewCodec("jpeg", 90, depth="png")):
        enc = encode_views(color, depth, present, scales, codec)
        c2, d2, p2 = decode_views(enc, scales, (h, w))
        assert np.array_equal(d2, depth) and np.array_equal(p2, present)
        err = np.abs(c2.astype(int) - color.astype(int))
        assert (
            (err.max() == 0) if codec.color == "png" else (err.mean() < 8.0)
        )  # the simulator's colour is noisy: about 6 levels
    with pytest.raises(ValidationError):
        ViewCodec("webp").check()
    with pytest.raises(ValidationError):
        ViewCodec("jpeg", depth="zip").check()


def test_lz4_wire_is_bit_for_bit_at_about_half_the_bytes_of_raw(sim8):
    from fuseflow.live.sources.node import wire_codec

    rec = sim8[1]
    f = rec[3]
    color, depth, present = f.color.numpy(), f.depth.numpy(), f.present.numpy().copy()
    present[2] = False
    scales = [c.depth_scale for c in rec.rig.cameras]
    h, w = depth.shape[1:]
    codec = wire_codec(ViewCodec(), "lz4")
    assert codec.name == "raw+lz4" and wire_codec(ViewCodec(), "raw").name == "raw"
    assert wire_codec(ViewCodec(), "jpeg").name == "jpeg+lz4"
    enc = encode_views(color, depth, present, scales, codec)
    c2, d2, p2 = decode_views(enc, scales, (h, w))
    assert np.array_equal(c2, color * present[:, None, None, None]) and np.array_equal(p2, present)
    assert np.array_equal(d2[present], depth[present])
    assert enc.nbytes < 0.6 * int(present.sum()) * h * w * (3 + 4)
    enc.depth[0] = enc.depth[0][:-10]  # a truncated view: a clear error, not garbage
    with pytest.raises(ValidationError):
        decode_views(enc, scales, (h, w))


def test_raw_views_travel_bit_for_bit(sim8):
    rec = sim8[1]
    f = rec[3]
    color, depth, present = f.color.numpy(), f.depth.numpy(), f.present.numpy().copy()
    present[1] = False
    scales = [c.depth_scale for c in rec.rig.cameras]
    enc = encode_views(color, depth, present, scales, ViewCodec("raw"))
    c2, d2, p2 = decode_views(enc, scales, depth.shape[1:])
    assert np.array_equal(c2, color) and np.array_equal(d2, depth) and np.array_equal(p2, present)
    h, w = depth.shape[1:]
    assert enc.nbytes == int(present.sum()) * h * w * (3 + 4)
    with pytest.raises(ValidationError):
        decode_views(enc, scales, (h + 1, w))


def test_raw16_wire_is_bit_for_bit_at_five_sevenths_of_raw(sim8):
    from fuseflow.live.sources.node import wire_codec

    rec = sim8[1]
    f = rec[3]
    color, depth, present = f.color.numpy(), f.depth.numpy(), f.present.numpy().copy()
    present[4] = False
    scales = [c.depth_scale for c in rec.rig.cameras]
    h, w = depth.shape[1:]
    codec = wire_codec(ViewCodec(), "raw16")
    assert codec.name == "raw16" and codec.arrays
    enc = encode_views(color, depth, present, scales, codec)
    assert enc.raw[1].dtype == np.uint16 and enc.nbytes == int(present.sum()) * h * w * (3 + 2)
    c2, d2, p2 = decode_views(enc, scales, (h, w))
    assert np.array_equal(c2, color) and np.array_equal(p2, present) and d2.dtype == np.float32
    assert np.array_equal(d2, depth)  # depth units / scale: what the recording's depth PNGs give
    with pytest.raises(ValidationError):
        decode_views(enc, scales, (h + 1, w))


def _residuals(cams, t, rate, slide):
    """Stamp minus paired instant per camera at time t: the nearest frame of a camera whose
    stamps run ``slide[cam]`` s/s off, so never more than half an interval (pairing wraps)."""
    half = 0.5 / rate
    out = {}
    for c in cams:
        r = slide.get(c, 0.0) * t + 0.0005 * np.sin(7 * t + len(c))
        out[c] = (r + half) % (2 * half) - half
    return out


def test_stamp_drift_unwraps_a_sliding_camera_and_warns_once():
    rate = 15.0
    cams = [f"cam{i:02d}" for i in range(8)]
    drift = StampDrift(1 / rate)
    warned = []
    for k in range(90):  # 6 s; cam06 and cam07 slide 20 ms a second
        t = k / rate
        got = drift.add(_residuals(cams, t, rate, {"cam06": 0.02, "cam07": 0.02}))
        warned += [(c, d, t) for c, d in got]
        assert max(abs(v) for v in _residuals(cams, t, rate, {"cam06": 0.02}).values()) <= 0.5 / rate + 1e-9
    assert sorted(c for c, _, _ in warned) == ["cam06", "cam07"]  # once each, the others never
    assert all(0.0333 < d < 0.045 for _, d, _ in warned)
    assert all(2.0 < t < 3.5 for _, _, t in warned)  # past half an interval (1.7 s) plus half the window
    assert drift.drift("cam06") == pytest.approx(0.02 * (89 - 15) / rate, abs=0.01)
    assert abs(drift.drift("cam00")) < 0.002
    steady = StampDrift(1 / rate)
    assert not any(steady.add(_residuals(cams, k / rate, rate, {})) for k in range(300))
    for _ in range(5):  # missing from a few frames: unwrapped across the gap
        steady.add({**_residuals(cams, 0, rate, {}), "cam06": None})
    assert steady.drift("cam06") is not None
    steady.add({**_residuals(cams, 0, rate, {}), "cam06": None})  # missing longer: its track starts over
    steady.add(_residuals(cams, 0, rate, {}))
    assert steady.drift("cam06") is None


def test_aligned_replays_show_the_same_frame(sim8):
    path = sim8[0]
    a = open_source([str(path)], ReplayOptions(rate=15.0, loop=True, aligned=True))
    time.sleep(0.3)
    b = open_source([str(path)], ReplayOptions(rate=15.0, loop=True, aligned=True))
    span = 8 / 15.0  # a pass: 8 frames at 15 fps
    assert (b.source.start - a.source.start) / span == pytest.approx(round((b.source.start - a.source.start) / span))
    ia, ib = next(iter(a.frames())), next(iter(b.frames()))
    # frame k of pass p is due at start + p x span + k / 15 on each: the same frame at the same time
    phase = ((a.source.due - b.source.due) * 15.0 - (ia.index - ib.index)) % 8
    assert min(phase, 8 - phase) == pytest.approx(0, abs=1e-4)
    a.close()
    b.close()


def test_node_that_cannot_reach_the_head_says_so_in_one_line(sim8):
    from typer.testing import CliRunner

    from fuseflow.cli import app

    res = CliRunner().invoke(app, ["node", str(sim8[0]), "--ray", "127.0.0.1:1"])
    assert res.exit_code == 2
    assert "cannot reach the Ray head at 127.0.0.1:1" in res.output
    assert "Traceback" not in res.output


@pytest.fixture(scope="module")
def sim8(tmp_path_factory):
    from fuseflow.io import open_recording
    from fuseflow.synth import SimConfig, simulate_recording

    path = tmp_path_factory.mktemp("sim8") / "rec"
    simulate_recording(path, SimConfig(cameras=8, frames=8, scene="studio", dynamic=True, resolution=(128, 96),
                                       seed=0, fps=15.0))  # fmt: skip
    return path, open_recording(path)


@pytest.fixture(scope="module")
def cluster(sim8):
    ray = pytest.importorskip("ray")
    from ray.cluster_utils import Cluster

    from fuseflow.live.sources.node import NAMESPACE, NodeOptions, spawn_node

    c = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    machines = [c.add_node(num_cpus=1, resources={f"cap{i}": 1}) for i in range(3)]
    ray.init(
        address=c.address, namespace=NAMESPACE, include_dashboard=False, logging_level="ERROR", log_to_driver=False
    )
    handles = [spawn_node([str(sim8[0])], NodeOptions(name=n, cameras=cams, clock_offset_s=off, replay=REPLAY), {f"cap{i}": 1})
               for i, (n, cams, off) in enumerate(SPLIT)]  # fmt: skip
    try:
        yield c, machines, handles
    finally:
        ray.shutdown()
        c.shutdown()


class _Keep:
    def __init__(self):
        self.got = []

    def send(self, cloud, info):
        self.got.append((info, cloud, time.time()))

    def close(self):
        pass


def _run(loop, frames, timeout=60.0):
    out = {}
    t = threading.Thread(target=lambda: out.setdefault("summary", loop.run()), daemon=True)
    t.start()
    deadline = time.time() + timeout
    while loop.stats.frames_out < frames and time.time() < deadline:
        time.sleep(0.05)
    loop.stop()
    t.join(30)
    assert not t.is_alive(), "the live loop did not stop"
    return out["summary"]


@pytest.mark.parametrize("wire", ["auto", "jpeg"])
def test_offsets_found_frames_paired_and_clouds_as_one_host(cluster, sim8, wire):
    from fuseflow.fuse import fuse_with_report
    from fuseflow.fuse.presets import preset_config
    from fuseflow.live.loop import LiveLoop, LiveSettings
    from fuseflow.live.sources.ray_source import RayLiveOptions, RaySource

    c, _, _ = cluster
    rec = sim8[1]
    src = RaySource(RayLiveOptions(address=c.address, nodes=3, frame_codec=wire))
    keep = _Keep()
    loop = LiveLoop(src, src.rig, LiveSettings(preset="live"), sinks=[keep])
    summary = _run(loop, 12)
    nodes = summary.capture["nodes"]
    assert nodes["b"]["offset_ms"] == pytest.approx(40.0, abs=2.0)
    assert nodes["c"]["offset_ms"] == pytest.approx(-25.0, abs=2.0)
    assert nodes["a"]["offset_ms"] == pytest.approx(0.0, abs=2.0)
    assert summary.capture["paired"]["mixed_index"] == 0
    assert src.rig.ids == rec.rig.ids and summary.frames_out >= 5
    # the nodes run on other Ray nodes of this machine: auto ships the raw arrays
    assert {(n["link"], n["wire"]) for n in nodes.values()} == {
        ("same machine", "raw" if wire == "auto" else "jpeg+lz4")
    }
    assert not [m for _, m in src.events if "drifted" in m]
    drifts = [v["drift_ms"] for v in summary.capture["skew"].values()]
    assert all(d is not None and abs(d) < 5.0 for d in drifts)
    cfg = preset_config("live")
    full = [(i, cl) for i, cl, _ in keep.got if not i.missing]
    assert len(full) >= 3
    for info, cloud in full[:4]:  # depth lossless: geometry bit-identical; colour raw or within JPEG's error
        one = fuse_with_report(rec[info.index], rec.rig, cfg).cloud
        assert torch.equal(cloud.xyz, one.xyz) and torch.equal(cloud.weight, one.weight)
        assert torch.equal(cloud.camera, one.camera)
        if wire == "auto":
            assert torch.equal(cloud.rgb, one.rgb)
        else:
            assert (cloud.rgb.int() - one.rgb.int()).abs().float().mean() < 8.0


def test_frames_come_in_the_reply_from_another_ray_node_and_through_the_store_from_this_one(cluster):
    import ray

    _, _, handles = cluster
    node = handles[1]
    _, stamp = ray.get(node.newest.remote(-1, 5.0))
    ref = node.frame_at.remote(stamp, 0.01, "raw16")
    frame = ray.get(ref)
    assert frame.views.codec.name == "raw16" and frame.views.raw[0].shape[0] == 3
    # inline in the reply: held by this process, in no Ray node's object store (Ray's default
    # would have put the frame, over 100 kB, into the node's store for this Ray node to pull)
    assert ray.experimental.get_object_locations([ref])[ref]["node_ids"] == []
    answer = ray.get(node.frame_at.remote(stamp, 0.01, "raw", True))  # shared: put into the node's store
    assert isinstance(answer, list) and len(answer) == 1
    assert ray.experimental.get_object_locations(answer)[answer[0]]["node_ids"] != []
    assert np.array_equal(ray.get(answer[0]).views.raw[0], frame.views.raw[0])


def test_raw_stamps_of_offset_clocks_pair_wrong_frames(cluster):
    from fuseflow.live.sources.ray_source import RayLiveOptions, RaySource

    src = RaySource(RayLiveOptions(address=cluster[0].address, nodes=3, correct_clocks=False))
    n = 0
    for _ in src.frames():
        n += 1
        if n >= 20:
            break
    src.close()
    assert src.status()["paired"]["mixed_index"] > 0  # +40 ms vs -25 ms is about one frame at 15 fps


def _stand_in_loop(address):
    """A RaySource on ``address`` running in a LiveLoop on a thread, FUSE replaced by a stand-in
    that returns one point a present view: (source, kept frames, loop, thread, {"summary": ...})."""
    from fuseflow.live.loop import LiveLoop, LiveSettings
    from fuseflow.live.sources.ray_source import RayLiveOptions, RaySource
    from fuseflow.types import FusedCloud

    def stand_in(frame, rig):
        m = int(frame.present.sum())
        return FusedCloud(torch.zeros(m, 3), torch.zeros(m, 3, dtype=torch.uint8), torch.ones(m),
                          torch.arange(m, dtype=torch.int16)), 1.0  # fmt: skip

    src = RaySource(RayLiveOptions(address=address, nodes=3))
    keep = _Keep()
    loop = LiveLoop(src, src.rig, LiveSettings(warmup=False), sinks=[keep], fuse_fn=stand_in)
    out = {}
    t = threading.Thread(target=lambda: out.setdefault("summary", loop.run()), daemon=True)
    t.start()
    return src, keep, loop, t, out


def test_node_killed_mid_stream_is_missing_within_a_second_and_rejoins(cluster, sim8):
    import ray

    from fuseflow.live.sources.node import NodeOptions, spawn_node

    c, _, handles = cluster
    v = 2
    name, cams, off = SPLIT[v]

    src, keep, loop, t, out = _stand_in_loop(c.address)
    try:
        time.sleep(1.5)
        ray.kill(handles[v])  # the capture node's process dies (its machine and Ray stay up)
        killed = time.time()
        deadline = time.time() + 20
        while not any(m.startswith(f"capture node {name} ") for _, m in src.events):
            assert time.time() < deadline
            time.sleep(0.05)
        warned = next(w for w, m in src.events if m.startswith(f"capture node {name} "))
        last_seen = max(w for i, _, w in keep.got if cams[0] not in i.missing)
        assert warned - last_seen <= 1.0 and warned - killed <= 1.0
        time.sleep(1.0)
        after = [i for i, _, w in keep.got if w > warned + 0.1]
        assert after and all(set(i.missing) == set(cams) for i in after)  # fusion goes on from the others
        handles[v] = spawn_node(
            [str(sim8[0])], NodeOptions(name=name, cameras=cams, clock_offset_s=off, replay=REPLAY), {f"cap{v}": 1}
        )
        back = time.time()
        while not any(w > back and not i.missing for i, _, w in keep.got):
            assert time.time() < back + 20, [m for _, m in src.events]
            time.sleep(0.1)
        assert src.status()["nodes"][name]["state"] == "ok"
    finally:
        loop.stop()
        t.join(30)
    summary = out["summary"]
    assert summary.dropped_views.get(cams[0], 0) > 0, [m for _, m in src.events]
    assert any("joined" in m for _, m in src.events)


def test_whole_ray_node_removed_mid_stream_is_missing_and_rejoins_when_added_back(cluster, sim8):
    import ray

    from fuseflow.live.sources.node import NodeOptions, spawn_node

    c, machines, handles = cluster
    v = 1
    name, cams, off = SPLIT[v]

    src, keep, loop, t, out = _stand_in_loop(c.address)
    try:
        time.sleep(1.5)
        c.remove_node(machines[v])  # the capture machine's Ray node (raylet, its actors) goes away
        removed = time.time()
        while not any(m.startswith(f"capture node {name} ") for _, m in src.events):
            assert time.time() < removed + 20
            time.sleep(0.05)
        warned = next(w for w, m in src.events if m.startswith(f"capture node {name} "))
        assert warned - removed <= 1.0
        time.sleep(1.0)
        after = [i for i, _, w in keep.got if w > warned + 0.1]
        assert after and all(set(i.missing) == set(cams) for i in after)
        machines[v] = c.add_node(num_cpus=1, resources={f"cap{v}": 1})
        handles[v] = spawn_node(
            [str(sim8[0])], NodeOptions(name=name, cameras=cams, clock_offset_s=off, replay=REPLAY), {f"cap{v}": 1}
        )
        back = time.time()
        while not any(w > back and not i.missing for i, _, w in keep.got):
            assert time.time() < back + 30, [m for _, m in src.events]
            time.sleep(0.1)
        time.sleep(2.0)  # the added node stays up (Ray's health check keeps it)
        assert src.status()["nodes"][name]["state"] == "ok"
        alive = {n["NodeID"] for n in ray.nodes() if n["Alive"]}
        assert machines[v].node_id in alive
    finally:
        loop.stop()
        t.join(30)
    assert out["summary"].dropped_views.get(cams[0], 0) > 0


def test_bad_frame_codec_or_node_colour_says_so_in_one_line(sim8):
    from typer.testing import CliRunner

    from fuseflow.cli import app

    res = CliRunner().invoke(app, ["live", "--ray", "127.0.0.1:1", "--frame-codec", "webp"])
    assert res.exit_code == 2 and "--frame-codec must be one of auto, raw, raw16, lz4, jpeg, png" in res.output
    res = CliRunner().invoke(app, ["node", str(sim8[0]), "--ray", "127.0.0.1:1", "--color", "raw"])
    assert res.exit_code == 2 and "--color must be jpeg or png" in res.output
    assert "Traceback" not in res.output
