"""``fuseflow bench live --nodes 3`` (and ``python -m benchmarks.live_replay --nodes 3``): one fused stream from capture nodes on Ray
against the same cameras on one host, on this machine.

Data: a simulated 8-camera 640x480 dynamic studio (``SimConfig(cameras=8, frames=10,
scene="studio", dynamic=True, resolution=(640, 480), seed=0, fps=15)``) replayed in a loop at
15 fps. One host: ``ReplaySource`` (preloaded) through the live loop (FUSE ``--preset live``,
no sinks). Nodes: a local Ray cluster (``ray.cluster_utils.Cluster``: a head and ``nodes``
nodes, each with a custom resource ``capK``) with one capture node actor per node replaying
cameras 0-2, 3-5 and 6-7 (``fuseflow node --cameras``), clocks off by 0, +40 and -25 ms; the
fusing host (this process) gathers them with ``RaySource`` into the same live loop, once per wire
format in ``wires``: ``auto`` (the nodes run on other Ray nodes of this machine: raw arrays, inline
in Ray's replies), ``raw16`` (colour arrays and 16-bit depth units), ``jpeg`` (JPEG quality 90 colour, lossless PNG depth: what crosses a
network) and ``auto@head`` (the same capture actors placed on this process's own Ray node: raw
through shared memory, the layout of a capture node on the fusing machine). Per run the one-host
rate is measured four times: without Ray before and after, and in this process with the cluster
up before and after the nodes' runs; the ratio uses the mean of the two with the cluster up,
``ratio_to_one_host_without_ray`` the other two. On a machine shared with other jobs the two
differ: FUSE does the same CPU work a frame in both, and the difference is time its threads wait
for a CPU, which other jobs' load decides (``benchmarks/investigations/live_autogroup_share.py``). The baseline with the cluster up runs in
the state of the nodes' runs and right before and after them, so the ratio is read against it. ``runs`` repeats the whole. Per fused frame with every view, the cloud is compared with the one-host FUSE
of the same recording frame: positions, weights and cameras bit for bit, colour bit for bit or as
the mean absolute difference. The rates compared are fused frames with all 8 views per second (a
frame a node did not deliver in time is fused from the others and not counted).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["SPLITS", "WIRES", "codec_costs", "run_nodes_bench"]

WIRES = ("auto", "raw", "raw16", "lz4", "jpeg", "png")
"""Frame codecs a run compares (``RayLiveOptions.frame_codec``)."""

SPLITS = [(("cam00", "cam01", "cam02"), 0.0), (("cam03", "cam04", "cam05"), 0.040), (("cam06", "cam07"), -0.025)]


class _Keep:
    """Keeps the first ``limit`` clouds fused from every view; counts fused frames with every view."""

    def __init__(self, limit: int = 6):
        self.got: list[tuple[Any, Any]] = []
        self.limit = limit
        self.complete = 0

    def send(self, cloud, info) -> None:
        if not info.missing:
            self.complete += 1
            if len(self.got) < self.limit:
                self.got.append((info, cloud))

    def close(self) -> None:
        pass


def _codec_row(color: np.ndarray, depth: np.ndarray, scales: list[float], reps: int = 5) -> dict[str, Any]:
    from fuseflow.live.sources.frame_codec import ViewCodec, decode_views, encode_views

    out = {}
    n = len(color)
    for codec in (
        ViewCodec("jpeg", 90),
        ViewCodec("jpeg", 90, depth="png"),
        ViewCodec("png"),
        ViewCodec("raw", depth_raw=False),
        ViewCodec("raw", depth_units=True),
    ):
        enc_t, dec_t = [], []
        for _ in range(reps):
            t0 = time.perf_counter()
            e = encode_views(color, depth, np.ones(n, bool), scales, codec)
            enc_t.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            c2, d2, _ = decode_views(e, scales, depth.shape[1:])
            dec_t.append(time.perf_counter() - t0)
        if e.raw is not None:  # raw16: the arrays
            cb, db = e.raw[0].nbytes / n, e.raw[1].nbytes / n
        else:
            cb, db = sum(len(b) for b in e.color) / n, sum(len(b) for b in e.depth) / n
        err = np.abs(c2.astype(int) - color.astype(int))
        out[codec.name] = {"color_bytes_per_view": int(cb), "depth_bytes_per_view": int(db),
                            "encode_ms_per_view": round(float(np.median(enc_t)) * 1e3 / n, 2),
                            "decode_ms_per_view": round(float(np.median(dec_t)) * 1e3 / n, 2),
                            "depth_identical": bool(np.array_equal(d2, depth)), "rgb_mean_abs_err": round(float(err.mean()), 2),
                            "mbit_per_s_8cams_15fps": round((cb + db) * 8 * 8 * 15 / 1e6, 1)}  # fmt: skip
    return out


def codec_costs(rec: Any, data_dir: Path | None) -> dict[str, Any]:
    """Bytes, encode / decode ms per view and the 8 x 15 fps bandwidth of the node codecs (JPEG 90
    colour with LZ4 or PNG depth, PNG colour, raw colour with LZ4 depth or 16-bit depth units) on frame 3 of the simulated recording and on hocap-8rs's 8 real
    RealSense views (when ``data_dir`` has it)."""
    import cv2

    f = rec[3]
    out = {"sim8": _codec_row(f.color.numpy(), f.depth.numpy(), [c.depth_scale for c in rec.rig.cameras])}
    root = Path(data_dir or "") / "hocap-8rs" / "frames"
    cams = sorted(p for p in root.glob("*") if p.is_dir()) if root.is_dir() else []
    if cams:
        color = np.stack([cv2.imread(str(c / "color_000000.jpg"))[..., ::-1] for c in cams])
        depth = np.stack([cv2.imread(str(c / "depth_000000.png"), cv2.IMREAD_UNCHANGED) for c in cams])
        out["hocap-8rs"] = _codec_row(color, depth.astype(np.float32) / np.float32(1000.0), [1000.0] * len(cams))
    return out


def _one_host(rec: Any, duration: float) -> dict[str, Any]:
    from fuseflow.live.loop import LiveLoop, LiveSettings
    from fuseflow.live.sources.replay import ReplaySource

    src = ReplaySource(rec, rate=15.0, loop=True, preload=True)
    keep = _Keep(0)
    s = LiveLoop(src, rec.rig, LiveSettings(preset="live", duration=duration), sinks=[keep]).run()
    return {"fps": s.fps, "complete_fps": round(keep.complete / s.wall_s, 3), "fuse_ms_median": s.fuse_ms_median, "latency_ms_p50": s.latency_ms_p50,
            "frames_out": s.frames_out, "drop_rate": round(s.drop_rate, 4)}  # fmt: skip


def _compare(rec: Any, keep: _Keep) -> dict[str, Any]:
    import torch

    from fuseflow.fuse import fuse_with_report
    from fuseflow.fuse.presets import preset_config

    cfg = preset_config("live")
    same, rgb = [], []
    for info, cloud in keep.got:
        one = fuse_with_report(rec[info.index], rec.rig, cfg).cloud
        same.append(bool(torch.equal(cloud.xyz, one.xyz) and torch.equal(cloud.weight, one.weight)
                         and torch.equal(cloud.camera, one.camera)))  # fmt: skip
        if same[-1]:
            rgb.append(float((cloud.rgb.int() - one.rgb.int()).abs().float().mean()))
    return {"clouds_compared": len(same), "geometry_bit_identical": sum(same),
            "rgb_mean_abs_diff": round(float(np.mean(rgb)), 3) if rgb else None}  # fmt: skip


def _gather(rec: Any, address: str, nodes: int, duration: float, wire: str) -> dict[str, Any]:
    from fuseflow.live.loop import LiveLoop, LiveSettings
    from fuseflow.live.sources.ray_source import RayLiveOptions, RaySource

    src = RaySource(RayLiveOptions(address=address, nodes=nodes, frame_codec=wire))
    keep = _Keep()
    s = LiveLoop(src, src.rig, LiveSettings(preset="live", duration=duration), sinks=[keep]).run()
    status = s.capture
    row = {"wire": wire, "fps": s.fps, "complete_fps": round(keep.complete / s.wall_s, 3), "fuse_ms_median": s.fuse_ms_median,
           "latency_ms_p50": s.latency_ms_p50, "frames_out": s.frames_out, "drop_rate": round(s.drop_rate, 4),
           "missing_views": s.dropped_views, "nodes": status["nodes"], "paired": status["paired"], "skew": status["skew"],
           "warnings": [m for _, m in src.events]}  # fmt: skip
    row.update(_compare(rec, keep))
    return row


def _nodes_run(path: Path, rec: Any, nodes: int, duration: float, wires: tuple[str, ...]) -> dict[str, Any]:
    import ray
    from ray.cluster_utils import Cluster

    from fuseflow.live.sources import ReplayOptions
    from fuseflow.live.sources.node import NAMESPACE, NodeOptions, spawn_node

    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    try:
        for k in range(nodes):
            cluster.add_node(num_cpus=1, resources={f"cap{k}": 1})
        ray.init(address=cluster.address, namespace=NAMESPACE, include_dashboard=False, logging_level="ERROR",
                 log_to_driver=False)  # fmt: skip
        replay = ReplayOptions(rate=15.0, loop=True, preload=True, aligned=True)
        splits = _splits(rec.rig.ids, nodes)
        here = ray.get_runtime_context().get_node_id()

        def spawn(on_head: bool) -> list:
            return [spawn_node([str(path)], NodeOptions(name=f"n{k}", cameras=cams, clock_offset_s=off, replay=replay),
                               None if on_head else {f"cap{k}": 1}, node_id=here if on_head else None)
                    for k, (cams, off) in enumerate(splits)]  # fmt: skip

        # one host again with the cluster up: on a machine shared with other jobs FUSE's share of
        # the CPU differs with the cluster up (same CPU work, less waiting for a CPU), so the
        # baseline is taken in the same state as the nodes' runs, before and after them
        handles = spawn(False)
        out = {"one_host_ray_up_before": _one_host(rec, duration)}
        out.update({w: _gather(rec, cluster.address, nodes, duration, w) for w in wires if not w.endswith("@head")})
        if any(w.endswith("@head") for w in wires):  # the capture actors on this process's Ray node
            for h in handles:
                ray.kill(h)
            _wait_gone()
            handles = spawn(True)
            out.update(
                {
                    w: _gather(rec, cluster.address, nodes, duration, w.split("@")[0])
                    for w in wires
                    if w.endswith("@head")
                }
            )
        out["one_host_ray_up_after"] = _one_host(rec, duration)
        del handles
        return out
    finally:
        ray.shutdown()
        cluster.shutdown()


def _wait_gone(timeout: float = 30.0) -> None:
    import ray

    from fuseflow.live.sources.node import NAMESPACE, PREFIX

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        names = ray.util.list_named_actors(all_namespaces=True)
        if not any(d.get("namespace") == NAMESPACE and d["name"].startswith(PREFIX) for d in names):
            return
        time.sleep(0.2)
    raise RuntimeError("the killed capture nodes are still registered")


def _splits(ids: tuple[str, ...], nodes: int) -> list[tuple[tuple[str, ...], float]]:
    if nodes == 3 and len(ids) == 8:
        return SPLITS
    parts = np.array_split(np.arange(len(ids)), nodes)
    offsets = [0.0, 0.040, -0.025]
    return [(tuple(ids[i] for i in p), offsets[k % 3]) for k, p in enumerate(parts)]


def _row(run: int, wire: str, multi: dict[str, Any], base: dict[str, dict], loads: list[float],
         resolution: tuple[int, int], duration: float, splits: list) -> dict[str, Any]:  # fmt: skip
    bytes_frame = sum(n["bytes_per_frame"] or 0 for n in multi["nodes"].values())
    ref = (base["one_host_ray_up_before"]["complete_fps"] + base["one_host_ray_up_after"]["complete_fps"]) / 2
    bare = (base["one_host_before"]["complete_fps"] + base["one_host_after"]["complete_fps"]) / 2
    row = {"case": f"nodes{len(splits)}-{wire}", "run": run, "wire": wire,
           "data": f"simulated 8 x {resolution[0]}x{resolution[1]} dynamic studio, 15 fps", **base, "nodes_run": multi,
           "ratio": round(multi["complete_fps"] / ref, 3) if ref else None,
           "ratio_note": "fused frames with all 8 views per second, nodes / mean of one host before and after them "
                         "in the same process with the Ray cluster up",
           "ratio_to_one_host_without_ray": round(multi["complete_fps"] / bare, 3) if bare else None,
           "target": ">= 0.9 of the one-host rate", "injected_offsets_ms": {f"n{k}": off * 1e3 for k, (_, off) in enumerate(splits)},
           "bytes_per_frame_all_cameras": bytes_frame, "mbit_per_s_at_15fps": round(bytes_frame * 8 * 15 / 1e6, 1),
           "fits_1gbit": bytes_frame * 8 * 15 < 1e9, "loadavg_1min": [round(x, 2) for x in loads],
           "duration_s": duration, "when": time.strftime("%Y-%m-%d %H:%M")}  # fmt: skip
    row["target_met"] = bool(row["ratio"] is not None and row["ratio"] >= 0.9)
    return row


def run_nodes_bench(nodes: int = 3, duration: float = 20.0, log=lambda s: None, resolution: tuple[int, int] = (640, 480),
                    data_dir: Path | None = None, runs: int = 1,
                    wires: tuple[str, ...] = ("auto", "jpeg", "auto@head")) -> list[dict[str, Any]]:  # fmt: skip
    """Rows per run and wire format: one-host rate (before and after), the nodes' rate, their
    ratio, offsets found, bytes per frame, encode / decode ms, the 1 Gbit/s check and the cloud
    comparison; the codec costs (bytes, ms per view) in the first row."""
    import os

    from fuseflow.io import open_recording
    from fuseflow.synth import SimConfig, simulate_recording

    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_live_nodes_") as tmp:
        path = Path(tmp) / "sim8"
        simulate_recording(path, SimConfig(cameras=8, frames=10, scene="studio", dynamic=True, resolution=resolution,
                                           seed=0, fps=15.0))  # fmt: skip
        rec = open_recording(path)
        codec = codec_costs(rec, data_dir)
        log(f"node codec: {codec}")
        splits = _splits(rec.rig.ids, nodes)
        for run in range(runs):
            loads = [os.getloadavg()[0]]
            before = _one_host(rec, duration)
            log(f"run {run}: one host {before['complete_fps']:.2f} fused/s, FUSE {before['fuse_ms_median']} ms")
            multi = _nodes_run(path, rec, nodes, duration, wires)
            loads.append(os.getloadavg()[0])
            after = _one_host(rec, duration)
            loads.append(os.getloadavg()[0])
            base = {"one_host_before": before, "one_host_after": after,
                    **{k: multi.pop(k) for k in ("one_host_ray_up_before", "one_host_ray_up_after")}}  # fmt: skip
            log(f"run {run}: one host {before['complete_fps']:.2f} / {after['complete_fps']:.2f} fused/s without Ray, "
                f"{base['one_host_ray_up_before']['complete_fps']:.2f} / {base['one_host_ray_up_after']['complete_fps']:.2f}"
                f" with the cluster up (FUSE {base['one_host_ray_up_before']['fuse_ms_median']} ms)")  # fmt: skip
            for wire, m in multi.items():
                row = _row(run, wire, m, base, loads, resolution, duration, splits)
                rows.append(row)
                log(f"run {run} {wire}: {m['complete_fps']:.2f} fused/s with every view ({m['fps']:.2f} in all), "
                    f"ratio {row['ratio']} (target >= 0.9: {'met' if row['target_met'] else 'MISSED'}; to one host "
                    f"without Ray {row['ratio_to_one_host_without_ray']}); FUSE "
                    f"{m['fuse_ms_median']} ms; wire {[(n['wire'], n['link']) for n in m['nodes'].values()][0]}; "
                    f"encode ms {[n['encode_ms'] for n in m['nodes'].values()]}, decode ms "
                    f"{[n['decode_ms'] for n in m['nodes'].values()]}; {row['bytes_per_frame_all_cameras'] / 1e3:.0f} kB "
                    f"per 8-camera frame = {row['mbit_per_s_at_15fps']} Mbit/s at 15 fps; offsets "
                    f"{[(k, n.get('offset_ms'), n.get('uncertainty_ms')) for k, n in m['nodes'].items()]}; geometry "
                    f"identical {m['geometry_bit_identical']}/{m['clouds_compared']}, rgb diff {m['rgb_mean_abs_diff']}; "
                    f"load {' -> '.join(f'{x:.1f}' for x in loads)}")  # fmt: skip
    if rows:
        rows[0]["codec"] = codec
    for wire in wires:
        ratios = [r["ratio"] for r in rows if r["wire"] == wire and r["ratio"] is not None]
        if ratios:
            med = float(np.median(ratios))
            log(f"{wire}: ratio over {len(ratios)} runs {[r for r in ratios]} (median {med:.3f}) "
                f"[>= 0.9 of the one-host rate: {'met' if med >= 0.9 else 'MISSED'}]")  # fmt: skip
    return rows
