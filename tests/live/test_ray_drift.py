"""Capture nodes on the fusing host's own Ray node: frames travel raw (bit for bit), and a node
whose capture stamps slide against its clock is warned about, once per camera, with its drift."""

import time

import numpy as np
import pytest

from fuseflow.live.sources import ReplayOptions

REPLAY = ReplayOptions(rate=15.0, loop=True, preload=True, aligned=True)
SLIDE = 0.02  # s a second: past half a frame interval (33 ms at 15 fps) within 3.3 s, and under half
# an interval between fused frames down to 0.6 fused frames a second (the drift is unwrapped)


@pytest.fixture(scope="module")
def local_nodes(tmp_path_factory):
    ray = pytest.importorskip("ray")
    from fuseflow.io import open_recording
    from fuseflow.live.sources.node import NAMESPACE, NodeOptions, spawn_node
    from fuseflow.synth import SimConfig, simulate_recording

    path = tmp_path_factory.mktemp("sim6") / "rec"
    simulate_recording(path, SimConfig(cameras=6, frames=8, scene="studio", dynamic=True, resolution=(96, 72),
                                       seed=1, fps=15.0))  # fmt: skip
    ray.init(address="local", num_cpus=1, namespace=NAMESPACE, include_dashboard=False, logging_level="ERROR",
             log_to_driver=False)  # fmt: skip
    here = ray.get_runtime_context().get_node_id()
    split = [("a", ("cam00", "cam01"), 0.0), ("b", ("cam02", "cam03"), 0.0), ("c", ("cam04", "cam05"), SLIDE)]
    try:
        handles = [spawn_node([str(path)], NodeOptions(name=n, cameras=cams, stamp_drift=d, replay=REPLAY), node_id=here)
                   for n, cams, d in split]  # fmt: skip
        yield open_recording(path), handles
    finally:
        ray.shutdown()


def test_node_on_this_ray_node_ships_raw_and_a_sliding_camera_is_warned(local_nodes):
    from fuseflow.live.sources.ray_source import RayLiveOptions, RaySource

    rec, _ = local_nodes
    src = RaySource(RayLiveOptions(address=None, nodes=3))
    t0, full = time.time(), None
    try:
        for frame in src.frames():
            if full is None and bool(frame.present.all()):
                full = frame
            if any("drifted" in m for _, m in src.events) and time.time() - t0 > 4.0 or time.time() - t0 > 30:
                break
        status = src.status()
    finally:
        src.close()
    assert {(n["link"], n["wire"]) for n in status["nodes"].values()} == {("same Ray node", "raw")}
    one = rec[full.index]  # raw: the views are the recording's, bit for bit
    assert np.array_equal(full.color.numpy(), one.color.numpy())
    assert np.array_equal(full.depth.numpy(), one.depth.numpy())
    drifted = [m for _, m in src.events if "drifted" in m]
    assert sorted(m.split()[1] for m in drifted) == ["cam04", "cam05"], src.events  # once each, only the sliding node's
    half = 500.0 / 15.0
    assert all(float(m.split("drifted ")[1].split(" ms")[0]) > half for m in drifted), drifted
    skew = status["skew"]
    assert all(abs(skew[c]["drift_ms"]) < 5.0 for c in ("cam00", "cam01", "cam02", "cam03"))
    assert skew["cam04"]["drift_ms"] > half
    assert all(skew[c]["median_ms"] <= half + 1.0 for c in skew)  # paired stamps alone never show it


def test_live_loop_fetches_only_the_frames_it_fuses(local_nodes):
    """Nodes capture at 15 fps, fusion takes 0.2 s a frame: frames are asked of the nodes only when
    fusion is ready for one, so the nodes ship about as many frames as are fused, not 15 a second."""
    from fuseflow.live.loop import LiveLoop, LiveSettings
    from fuseflow.live.sources.ray_source import RayLiveOptions, RaySource

    rec, _ = local_nodes
    src = RaySource(RayLiveOptions(address=None, nodes=3, in_flight=1))
    fused = []

    def slow(frame, rig):
        time.sleep(0.2)
        fused.append(frame.index)
        return _empty_cloud(), 200.0

    summary = LiveLoop(src, src.rig, LiveSettings(preset="live", duration=3.0), fuse_fn=slow).run()
    shipped = [n["frames"] for n in summary.capture["nodes"].values()]
    assert summary.frames_out >= 8
    assert all(s <= summary.frames_out + 2 for s in shipped), (shipped, summary.frames_out)
    assert summary.frames_in <= summary.frames_out + 2


def _empty_cloud():
    import torch

    from fuseflow.types import FusedCloud

    return FusedCloud(xyz=torch.zeros((0, 3)), rgb=torch.zeros((0, 3), dtype=torch.uint8), weight=torch.zeros(0),
                      camera=torch.zeros(0, dtype=torch.int16))  # fmt: skip
