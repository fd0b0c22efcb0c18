"""Version 3 of the compact frame codec (range-coded octree and colour): exact geometry and
bounded colour error, fewer bytes than version 2 at the same quantisation, the browser's decoder
(decode.js in node) giving bit-identical points on the same bytes, and every malformed message
(truncated, flipped, garbage behind a valid checksum, absurd header) rejected with one clear error
in both decoders, never a hang."""

import json
import shutil
import struct
import subprocess
import zlib
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree
from tests.live.test_codec import _surface

from fuseflow.errors import FormatError
from fuseflow.live.codec import COMPACT_HEADER, MAX_POINTS, CompactParams, decode_compact, encode_compact
from fuseflow.live.wire import decode_frame

DECODE_JS = Path(__file__).resolve().parents[2] / "src" / "fuseflow" / "live" / "static" / "decode.js"
needs_node = pytest.mark.skipif(shutil.which("node") is None, reason="needs node to run the viewer's decoder")


def _with_crc(data: bytes) -> bytes:
    """The message with its header's checksum made to match its (altered) streams."""
    return data[:48] + struct.pack("<I", zlib.crc32(data[COMPACT_HEADER:])) + data[52:]


def _garbage_frames(data: bytes, count: int, seed: int = 0) -> list[bytes]:
    """Messages with the header of ``data`` and random streams of the same sizes, valid checksums."""
    rng = np.random.default_rng(seed)
    return [_with_crc(data[:COMPACT_HEADER] + rng.bytes(len(data) - COMPACT_HEADER)) for _ in range(count)]


def test_positions_exact_to_the_cell_and_colour_within_the_bound():
    xyz, rgb = _surface()
    p = CompactParams(step_mm=2.0)
    d = decode_frame(encode_compact(xyz, rgb, 7, 1.0, 2.0, p))
    origin = xyz.min(0).astype(np.float64)
    cells = np.unique(np.floor((xyz - origin) / 0.002).astype(np.int64), axis=0)
    got = np.floor((d.xyz.astype(np.float64) - origin) / 0.002).astype(np.int64)
    assert d.version == 7 and len(got) == len(cells) and np.array_equal(np.unique(got, axis=0), cells)
    cheb, idx = cKDTree(d.xyz).query(xyz, p=np.inf)
    assert cheb.max() <= 0.001 + 1e-5  # half the 2 mm step per axis
    err = np.abs(d.rgb[idx].astype(int) - rgb.astype(int))
    assert np.percentile(err, 95) <= 12, np.percentile(err, 95)


def test_geometry_round_trips_at_extreme_shapes():
    rng = np.random.default_rng(3)
    shapes = {
        "one point": np.array([[0.5, 0.5, 0.5]]),
        "a full 8x8x8 block": np.stack(np.meshgrid(*[np.arange(8) * 0.003] * 3), -1).reshape(-1, 3),
        "sparse over 2 km (20 levels)": np.r_[[[0.0, 0.0, 0.0], [2000.0, 3.0, 1.0]], rng.uniform(0, 2000, (500, 3))],
    }
    for name, pts in shapes.items():
        xyz = pts.astype(np.float32) + 0.0001
        d = decode_frame(encode_compact(xyz, np.full((len(xyz), 3), 96, np.uint8), 0, 0.0, 0.0, CompactParams()))
        cheb, _ = cKDTree(d.xyz).query(xyz, p=np.inf)
        assert cheb.max() <= 0.0015 + 2.4e-7 * np.abs(xyz).max(), name  # half a 3 mm step (+ float32 rounding)
        assert np.all(d.rgb == 96), name  # grey on the luma step (8 and 12)


def test_fewer_bytes_than_version_2_at_the_same_quantisation():
    xyz, rgb = _surface(60000)
    for luma, chroma, block in ((4, 8, 4), (8, 16, 4), (8, 16, 1)):
        v3, v2 = (len(encode_compact(xyz, rgb, 0, 0.0, 0.0, CompactParams(3.0, luma, chroma, block, v)))
                  for v in (3, 2))  # fmt: skip
        assert v3 < 0.95 * v2, (luma, chroma, block, v3, v2)


def test_large_residuals_take_the_escape_code_and_round_trip():
    xyz = (np.stack(np.meshgrid(*[np.arange(16)] * 3), -1).reshape(-1, 3) * 0.01 + 0.001).astype(np.float32)
    rgb = np.random.default_rng(2).integers(0, 256, (len(xyz), 3)).astype(np.uint8)  # one point a cell
    h, dx, dc = decode_compact(encode_compact(xyz, rgb, 0, 0.0, 0.0, CompactParams(3.0, 1, 2, 1)))
    _, idx = cKDTree(dx).query(xyz)
    assert h.points == len(xyz) and np.abs(dc[idx].astype(int) - rgb.astype(int)).max() <= 2  # chroma step 2


def test_malformed_messages_are_format_errors():
    xyz, rgb = _surface(3000)
    data = encode_compact(xyz, rgb, 3, 0.0, 0.0, CompactParams())
    for n in (0, 5, 40, COMPACT_HEADER, COMPACT_HEADER + 1, len(data) // 2, len(data) - 1):
        with pytest.raises(FormatError):
            decode_frame(data[:n])
    bad = bytearray(data)
    bad[COMPACT_HEADER + 10] ^= 0x10
    with pytest.raises(FormatError, match="checksum"):
        decode_frame(bytes(bad))
    m = int.from_bytes(data[12:16], "little")
    for frame in _garbage_frames(data, 30):  # valid checksum, nonsense streams: an error or M points
        try:
            got = len(decode_frame(frame).xyz)
        except FormatError:
            continue
        assert got == m
    huge = bytearray(data)
    huge[12:20] = struct.pack("<II", MAX_POINTS + 1, MAX_POINTS + 1)
    with pytest.raises(FormatError, match="points"):
        decode_frame(bytes(huge))
    fewer = bytearray(data)
    fewer[12:16] = struct.pack("<I", int.from_bytes(data[12:16], "little") - 1)
    with pytest.raises(FormatError, match="geometry"):
        decode_frame(bytes(fewer))


@needs_node
def test_browser_decoder_is_bit_identical_and_rejects_malformed_messages(tmp_path):
    xyz, rgb = _surface(30000)
    nx, nrgb = _surface(3000, seed=1, noisy=True)
    good = {
        "default.bin": encode_compact(xyz, rgb, 1, 2.0, 3.0, CompactParams()),
        "fine.bin": encode_compact(xyz, rgb, 2, 2.0, 3.0, CompactParams(1.0, 2, 4, 1)),
        "escape.bin": encode_compact(nx, nrgb, 3, 2.0, 3.0, CompactParams(0.5, 1, 2, 1)),
        "split.bin": encode_compact(nx, nrgb, 5, 2.0, 3.0, CompactParams(0.5, version=3)),  # split blocks, version 5
        "unsplit.bin": encode_compact(nx, nrgb, 6, 2.0, 3.0, CompactParams(0.5, split=0.0)),  # version 3
        "empty.bin": encode_compact(
            np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8), 4, 0.0, 0.0, CompactParams()
        ),  # fmt: skip
    }
    data = good["default.bin"]
    flipped = bytearray(data)
    flipped[len(data) // 2] ^= 0x01
    huge = bytearray(data)
    huge[12:20] = struct.pack("<II", MAX_POINTS + 1, MAX_POINTS + 1)
    bad = {"truncated.bin": data[:-3], "header-only.bin": data[:COMPACT_HEADER], "flipped.bin": bytes(flipped),
           "huge.bin": bytes(huge), **{f"garbage{i}.bin": g for i, g in enumerate(_garbage_frames(data, 12))}}  # fmt: skip
    for name, frame in {**good, **bad}.items():
        (tmp_path / name).write_bytes(frame)
    script = f"""
const fs = require("fs"); const {{ decodeFrame }} = require({json.dumps(str(DECODE_JS))});
(async () => {{
  for (const name of process.argv.slice(2)) {{
    const b = fs.readFileSync(name);
    try {{
      const f = await decodeFrame(b.buffer.slice(b.byteOffset, b.byteOffset + b.length));
      fs.writeFileSync(name + ".out", Buffer.concat([Buffer.from(f.xyz.buffer), Buffer.from(f.rgb.buffer, f.rgb.byteOffset, f.rgb.length)]));
      console.log(JSON.stringify({{ name, m: f.m, number: f.number, version: f.version, latency: f.latency, pointsIn: f.pointsIn }}));
    }} catch (e) {{ console.log(JSON.stringify({{ name, error: String(e.message) }})); }}
  }}
}})();
"""
    (tmp_path / "run.js").write_text(script)
    names = [str(tmp_path / n) for n in {**good, **bad}]
    out = subprocess.run(["node", str(tmp_path / "run.js"), *names], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    results = {Path(r["name"]).name: r for r in map(json.loads, out.stdout.split("\n")[:-1])}
    for name, frame in good.items():
        r, py = results[name], decode_frame(frame)
        m = len(py.xyz)
        assert (r["m"], r["number"], r["version"], r["pointsIn"]) == (m, py.number, py.version, py.points_in), name
        js = (tmp_path / (name + ".out")).read_bytes()
        assert np.array_equal(np.frombuffer(js[: 12 * m], np.float32).reshape(m, 3), py.xyz), name
        assert np.array_equal(np.frombuffer(js[12 * m :], np.uint8).reshape(m, 3), py.rgb), name
    assert {decode_frame(good[n]).version for n in ("split.bin", "unsplit.bin")} == {5, 3}
    for name in ("truncated.bin", "header-only.bin", "flipped.bin", "huge.bin"):
        assert "live frame" in results[name].get("error", ""), (name, results[name])
    for name, frame in bad.items():  # garbage behind a valid checksum: rejected, or M points as Python says
        r = results[name]
        try:
            m = len(decode_frame(frame).xyz)
        except FormatError:
            assert "error" in r, name
        else:
            assert r.get("m") == m, name


def test_codec_benchmark_rows(tmp_path):
    from benchmarks.studies.live_codec_versions import SETTINGS, measure, node_decode_ms, table

    xyz, rgb = _surface(5000)
    rows = measure("surface", xyz, rgb, repeats=1)
    by = {r["codec"]: r for r in rows}
    assert len(rows) == len(SETTINGS) and by["raw"]["bits_per_point"] == pytest.approx(72.0, abs=0.1)
    v2, v3 = by["v2, 3 mm / 4, 8, 4 (version 2 default)"], by["v7, 3 mm / 12, 16, 4, split 1.5 (default)"]
    assert v3["bits_per_point"] < v2["bits_per_point"] and 0 < v3["geometry_bits_per_point"] < v3["bits_per_point"]
    assert all(r["pos_err_over_half_step"] <= 1.0 + 1e-3 for r in rows if r["pos_err_over_half_step"] is not None)
    if shutil.which("node"):
        node_decode_ms(rows, 1, tmp_path)
        assert all(r["node_decode_ms"] > 0 for r in rows)
    assert len(table([{k: v for k, v in r.items() if k != "_data"} for r in rows])) == len(rows) + 2


def test_split_chroma_blocks_bound_the_colour_error_at_hard_colour_edges():
    xyz, _ = _surface(20000)
    rng = np.random.default_rng(4)
    palette = np.array([[220, 30, 30], [30, 200, 40], [40, 60, 220], [230, 220, 40], [240, 240, 240]], np.uint8)
    rgb = palette[rng.integers(0, len(palette), len(xyz))]  # neighbours of unrelated colours
    err = {}
    for split in (1.5, 0.0):
        h, dx, dc = decode_compact(encode_compact(xyz, rgb, 0, 0.0, 0.0, CompactParams(step_mm=0.5, split=split)))
        _, idx = cKDTree(dx).query(xyz)
        err[h.version] = np.percentile(np.abs(dc[idx].astype(int) - rgb.astype(int)), 95)
    assert err[7] <= 12 < err[3], err


def test_version_3_and_4_bytes_are_those_of_the_unsplit_format():
    from tests.live.test_codec_delta import _sequence

    from fuseflow.live.codec import InterEncoder

    xyz, rgb = _surface(5000, seed=2)
    key = encode_compact(xyz, rgb, 9, 1.0, 2.0, CompactParams(luma_step=8, split=0.0))
    enc = InterEncoder(CompactParams(luma_step=8, split=0.0))
    (x0, c0), (x1, c1) = _sequence(2, m=5000)
    enc.encode(x0, c0, 0)
    _, delta = enc.encode(x1, c1, 1, key=False)
    # lengths and CRC-32s of the same messages written before chroma blocks could split
    assert (len(key), zlib.crc32(key), len(delta), zlib.crc32(delta)) == (10316, 1421772074, 6155, 1163930191)


def test_the_default_luma_step_holds_the_colour_error_with_fewer_bits_than_a_finer_one():
    xyz, rgb = _surface(20000, seed=3)
    rgb = np.clip(rgb + np.random.default_rng(3).normal(0, 6, rgb.shape), 0, 255).astype(np.uint8)  # sensor noise
    out = {}
    for luma in (CompactParams().luma_step, 8):
        data = encode_compact(xyz, rgb, 0, 0.0, 0.0, CompactParams(luma_step=luma))
        h, dx, dc = decode_compact(data)
        _, idx = cKDTree(dx).query(xyz)
        out[luma] = (h.sizes[1], np.percentile(np.abs(dc[idx].astype(int) - rgb.astype(int)), 95))
    (default_bytes, default_p95), (fine_bytes, _) = out[CompactParams().luma_step], out[8]
    assert default_bytes < 0.9 * fine_bytes and default_p95 <= 12, out  # the colour stream's bytes


def test_the_split_of_bits_adds_up_to_the_coded_streams(tmp_path):
    from benchmarks.studies.live_codec_split import node_split_ms, split_row

    xyz, rgb = _surface(20000, seed=5)
    row = split_row("surface", xyz, rgb, repeats=1)
    parts = [v for k, v in row.items() if k.startswith(("child_bits", "single_flags", "index_bits"))]
    assert len(parts) == 6 and sum(parts) == pytest.approx(row["geometry_bits_per_point"], rel=0.01)
    colour = row["luma_bits"] + row["chroma_bits"] + row["split_flag_bits"]
    assert colour == pytest.approx(row["colour_bits_per_point"], rel=0.01) and row["luma_bits"] > 0
    data = encode_compact(xyz, rgb, 0, 0.0, 0.0, CompactParams(version=3))
    assert row["bits_per_point"] == pytest.approx((len(data) - 60) * 8 / len(xyz), abs=1e-3)  # the same streams
    if shutil.which("node"):
        node_split_ms([row], 1, tmp_path)
        assert row["node_decode_geometry_ms"] > 0 and row["node_decode_colour_ms"] > 0
