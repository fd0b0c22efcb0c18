"""The compact frame codec (version 3 by default, version 2 on request): round trip within its
stated error bounds, size, bad input (truncated, corrupt, inconsistent frames are one FormatError
each), the browser's decoder giving the same points as the Python one, and clients choosing their
codec."""

import json
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from fuseflow.errors import FormatError, ValidationError
from fuseflow.live.codec import COMPACT_HEADER, CompactParams, decode_compact, encode_compact
from fuseflow.live.wire import decode_frame, encode_frame
from fuseflow.types import FusedCloud

STATIC = Path(__file__).resolve().parents[2] / "src" / "fuseflow" / "live" / "static"


def _surface(m=20000, seed=0, grey=False, noisy=False):
    """Points on a 0.6 m sphere and a floor plane, colours varying smoothly over them (grey: the
    same in every channel; noisy: random, so a coder meets large residuals and escape codes)."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(m // 2, 3))
    sphere = 0.6 * d / np.linalg.norm(d, axis=1, keepdims=True) + [0.2, -0.1, 1.5]
    floor = np.c_[rng.uniform(-1.5, 1.5, m - m // 2), np.full(m - m // 2, 0.9), rng.uniform(0.3, 3.0, m - m // 2)]
    xyz = np.vstack([sphere, floor]).astype(np.float32)
    base = 128 + 100 * np.sin(xyz * [2.0, 3.0, 1.5] + [0.0, 1.0, 2.0])
    rgb = (base.mean(1, keepdims=True).repeat(3, 1) if grey else base).astype(np.uint8)
    if noisy:
        rgb = rng.integers(0, 256, (m, 3)).astype(np.uint8)
    return xyz, rgb


def _fused(xyz, rgb):
    m = len(xyz)
    return FusedCloud(torch.from_numpy(xyz), torch.from_numpy(rgb), torch.ones(m), torch.zeros(m, dtype=torch.int16))


def _cells(xyz, step, origin):
    return np.floor((xyz.astype(np.float64) - origin) / step).astype(np.int64)


def test_round_trip_positions_within_half_a_step_and_one_point_per_cell():
    xyz, rgb = _surface()
    p = CompactParams(step_mm=2.0)
    data = encode_compact(xyz, rgb, 7, 12.5, 40.0, p)
    d = decode_frame(data)
    assert (d.version, d.number, d.latency_ms, d.fuse_ms, d.points_in) == (7, 7, 12.5, 40.0, len(xyz))
    origin = xyz.min(0).astype(np.float64)
    cells = np.unique(_cells(xyz, 0.002, origin), axis=0)
    assert len(d.xyz) == len(cells) < len(xyz)  # points sharing a cell are merged
    assert np.array_equal(np.unique(_cells(d.xyz, 0.002, origin), axis=0), cells)  # every cell, once
    dist, _ = cKDTree(d.xyz).query(xyz, p=np.inf)  # Chebyshev: per axis
    assert dist.max() <= 0.001 + 1e-5  # each point has a decoded point within step / 2 per axis (2 mm grid)
    assert np.median(dist) > 1e-4  # and that is a real quantisation, not a copy


@pytest.mark.parametrize("version", [7, 3, 2])
def test_colour_error_bounds(version):
    xyz, grey = _surface(grey=True)
    for luma_step in (1, 4, 8):
        p = CompactParams(step_mm=0.5, luma_step=luma_step, chroma_block=1, version=version)  # few merged points
        h, dx, dc = decode_compact(encode_compact(xyz, grey, 0, 0.0, 0.0, p))
        _, idx = cKDTree(dx).query(xyz)
        err = np.abs(dc[idx].astype(int) - grey.astype(int))
        assert err.max() <= luma_step / 2 + 2, (luma_step, err.max())  # grey: luma only (+ rounding)
    xyz, rgb = _surface()
    p = (
        CompactParams(step_mm=0.5, version=version)
        if version != 2
        else CompactParams(step_mm=0.5, luma_step=4, chroma_step=8, version=2)
    )
    h, dx, dc = decode_compact(encode_compact(xyz, rgb, 0, 0.0, 0.0, p))
    _, idx = cKDTree(dx).query(xyz)
    err = np.abs(dc[idx].astype(int) - rgb.astype(int))
    assert np.median(err) <= 4 and np.percentile(err, 95) <= 12, (np.median(err), np.percentile(err, 95))


def test_compact_is_several_times_smaller_than_raw():
    xyz, rgb = _surface(60000)
    cloud = _fused(xyz, rgb)
    raw = encode_frame(cloud, 0, 0.0, 0.0, "raw")
    compact = encode_frame(cloud, 0, 0.0, 0.0, "compact")
    assert len(raw) > 4 * len(compact), (len(raw), len(compact))
    with pytest.raises(ValidationError, match="codec"):
        encode_frame(cloud, 0, 0.0, 0.0, "draco")


def test_empty_single_and_non_finite_points():
    for xyz in (np.zeros((0, 3), np.float32), np.array([[1.0, 2.0, 3.0]], np.float32)):
        d = decode_frame(encode_compact(xyz, np.full((len(xyz), 3), 200, np.uint8), 1, 0.0, 0.0, CompactParams()))
        assert d.xyz.shape == xyz.shape and np.all(np.abs(d.xyz - xyz) <= 0.0015 + 1e-6)  # half a 3 mm step
    xyz = np.array([[0.0, 0.0, 0.0], [np.nan, 0.0, 0.0], [0.1, 0.0, np.inf], [0.1, 0.1, 0.1]], np.float32)
    d = decode_frame(encode_compact(xyz, np.zeros((4, 3), np.uint8), 1, 0.0, 0.0, CompactParams()))
    assert len(d.xyz) == 2 and d.points_in == 2 and np.isfinite(d.xyz).all()


def test_too_fine_a_grid_for_the_extent_is_a_clear_error():
    xyz = np.array([[0.0, 0.0, 0.0], [5000.0, 0.0, 0.0]], np.float32)
    with pytest.raises(ValidationError, match="--grid-mm"):
        encode_compact(xyz, np.zeros((2, 3), np.uint8), 0, 0.0, 0.0, CompactParams(step_mm=1.0))
    with pytest.raises(ValidationError, match="--grid-mm"):
        CompactParams(step_mm=0.0).check()


@pytest.mark.parametrize("version", [7, 3, 2])
def test_truncated_corrupt_and_inconsistent_frames_are_rejected(version):
    xyz, rgb = _surface(3000)
    data = encode_compact(xyz, rgb, 3, 0.0, 0.0, CompactParams(version=version))
    head = COMPACT_HEADER if version != 2 else 64
    for n in range(0, len(data), 7):  # every truncation
        with pytest.raises(FormatError):
            decode_frame(data[:n])
    with pytest.raises(FormatError):
        decode_frame(data + b"\0")
    rng = np.random.default_rng(1)
    for pos in rng.integers(head, len(data), 60):  # a flipped bit in any stream
        bad = bytearray(data)
        bad[pos] ^= 1 << int(rng.integers(8))
        with pytest.raises(FormatError):
            decode_frame(bytes(bad))
    h = bytearray(data)
    h[12:16] = (int.from_bytes(data[12:16], "little") - 1).to_bytes(4, "little")  # M off by one
    with pytest.raises(FormatError):
        decode_frame(bytes(h))
    h = bytearray(data)
    h[44] = 40  # octree depth beyond the limit
    with pytest.raises(FormatError, match="levels"):
        decode_frame(bytes(h))
    h = bytearray(data)
    h[4] = 9  # unknown version
    with pytest.raises(FormatError, match="version"):
        decode_frame(bytes(h))


@pytest.mark.skipif(shutil.which("node") is None, reason="needs node to run the viewer's decoder")
def test_browser_decoder_matches_python(tmp_path):
    xyz, rgb = _surface(5000)
    data = encode_compact(xyz, rgb, 11, 3.0, 4.0, CompactParams(step_mm=3.0, chroma_block=3))
    v2 = encode_compact(xyz, rgb, 13, 3.0, 4.0, CompactParams(step_mm=3.0, chroma_block=3, version=2))
    cloud = _fused(xyz, rgb)
    raw = encode_frame(cloud, 12, 3.0, 4.0, "raw")
    script = f"""
const fs = require("fs"); const {{ decodeFrame }} = require({json.dumps(str(STATIC / "decode.js"))});
(async () => {{
  for (const name of process.argv.slice(2)) {{
    const b = fs.readFileSync(name); const f = await decodeFrame(b.buffer.slice(b.byteOffset, b.byteOffset + b.length));
    fs.writeFileSync(name + ".out", Buffer.concat([Buffer.from(f.xyz.buffer), Buffer.from(f.rgb.buffer, f.rgb.byteOffset, f.rgb.length)]));
    console.log(JSON.stringify({{ m: f.m, number: f.number, version: f.version }}));
  }}
  try {{ await decodeFrame(fs.readFileSync(process.argv[2]).buffer.slice(0, 70)); console.log("no error"); }}
  catch (e) {{ console.log("rejected"); }}
}})();
"""
    (tmp_path / "run.js").write_text(script)
    frames = {"c.bin": data, "r.bin": raw, "v2.bin": v2}
    for name, frame in frames.items():
        (tmp_path / name).write_bytes(frame)
    out = subprocess.run(["node", str(tmp_path / "run.js"), *(str(tmp_path / n) for n in frames)],
                         capture_output=True, text=True, timeout=60)  # fmt: skip
    lines = out.stdout.split("\n")
    assert out.returncode == 0 and lines[3] == "rejected", out.stderr
    for (name, frame), line in zip(frames.items(), lines):
        meta, py = json.loads(line), decode_frame(frame)
        m = meta["m"]
        assert m == len(py.xyz) and meta["number"] == py.number and meta["version"] == py.version
        js = (tmp_path / (name + ".out")).read_bytes()
        jx = np.frombuffer(js[: 12 * m], np.float32).reshape(m, 3)
        jc = np.frombuffer(js[12 * m :], np.uint8).reshape(m, 3)
        assert np.allclose(jx, py.xyz, atol=1e-6) and np.array_equal(jc, py.rgb)


def test_clients_choose_their_codec_and_the_sink_encodes_off_the_fusion_thread():
    ws_client = pytest.importorskip("websockets.sync.client")
    from websockets.exceptions import InvalidStatus

    from fuseflow.live.loop import LiveFrame
    from fuseflow.live.server import LiveServer
    from fuseflow.live.sinks import WebSink

    server = LiveServer("127.0.0.1", 0, codec="compact").start()
    extra: dict = {}
    sink = WebSink(server, CompactParams(step_mm=3.0), extra)
    url = f"ws://127.0.0.1:{server.port}/ws"
    try:
        xyz, rgb = _surface(4000)
        sink.send(_fused(xyz, rgb), LiveFrame(1, 1, time.perf_counter(), 10.0, ()))
        time.sleep(0.3)
        assert sink.encoded == 0  # nobody watches: nothing is encoded
        with pytest.raises(InvalidStatus):
            ws_client.connect(url + "?codec=draco", open_timeout=5)
        with ws_client.connect(url, max_size=None) as a, ws_client.connect(url + "?codec=raw", max_size=None) as b:
            assert json.loads(a.recv(timeout=5))["codec"] == "compact"
            assert json.loads(b.recv(timeout=5))["codec"] == "raw"
            for _ in range(50):  # both handshakes registered
                if len(server.codecs()) == 2:
                    break
                time.sleep(0.05)
            xyz, rgb = _surface(4000)
            cloud = _fused(xyz, rgb)
            sink.send(cloud, LiveFrame(5, 5, time.perf_counter(), 10.0, ()))
            fa, fb = decode_frame(a.recv(timeout=10)), decode_frame(b.recv(timeout=10))
            assert (fa.version, fa.number, fa.step) == (7, 5, pytest.approx(0.003))
            assert (fb.version, fb.number, len(fb.xyz)) == (1, 5, 4000)
            assert sink.encoded == 1 and len(sink.encode_ms) == 1
            assert extra["encoded"] == 1 and extra["encoder_skipped"] == 0 and extra["encode_ms"] >= 0
    finally:
        sink.close()
    assert not server.running


def test_codec_benchmark_rows():
    from benchmarks.studies.live_codec import measure

    xyz, rgb = _surface(3000)
    raw, compact = measure("surface", _fused(xyz, rgb), [CompactParams(step_mm=2.0)], repeats=1)
    assert raw["codec"] == "raw" and raw["bytes_per_point"] == pytest.approx(9.0, abs=0.02)
    assert compact["codec"] == "compact" and compact["bytes_per_point"] < 4.0
    assert compact["pos_err_axis_max_mm"] <= 1.0 + 1e-3 and 0 < compact["geometry_bits_per_point"] < 32
