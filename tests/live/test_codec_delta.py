"""Compact deltas (version 4): a frame coded against the previous one decodes to exactly the
picture of its key frame, is smaller when points repeat, is refused without its reference (both
decoders), decode.js gives the same bits, and the server sends deltas only to viewers that hold
the reference, key frames to everyone else."""

import json
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from tests.live.test_codec import _fused, _surface

from fuseflow.errors import FormatError, ValidationError
from fuseflow.live.codec import CompactDecoder, CompactParams, InterEncoder, decode_compact

DECODE_JS = Path(__file__).resolve().parents[2] / "src" / "fuseflow" / "live" / "static" / "decode.js"


def _sequence(frames=4, m=20000, keep=0.7, seed=0, patchy=False):
    """Clouds of a surface where a fraction ``keep`` of the points (and their colours) repeat from
    one frame to the next and the others are drawn anew, as in a studio where most points stay
    (patchy: a fifth of the points with random colours, so that some chroma blocks split)."""
    xyz, rgb = _surface(m, seed)
    rng = np.random.default_rng(seed + 1)
    if patchy:
        rgb = np.where(rng.random(m)[:, None] < 0.2, rng.integers(0, 256, (m, 3)), rgb).astype(np.uint8)
    out = [(xyz, rgb)]
    for f in range(1, frames):
        new_xyz, new_rgb = _surface(m, seed + 10 + f)
        swap = rng.random(m) > keep
        xyz, rgb = np.where(swap[:, None], new_xyz, xyz), np.where(swap[:, None], new_rgb, rgb)
        out.append((xyz.astype(np.float32), rgb.astype(np.uint8)))
    return out


@pytest.mark.parametrize("split", [1.5, 0.0])
def test_a_delta_decodes_to_its_key_frames_picture_and_is_smaller(split):
    enc, dec = InterEncoder(CompactParams(split=split)), CompactDecoder()
    for n, (xyz, rgb) in enumerate(_sequence()):
        key, delta = enc.encode(xyz, rgb, n, key=True, delta=True)
        _, kx, kc = decode_compact(key)
        if n == 0:
            assert delta is None  # nothing to refer to yet
            dec.decode(key)
            continue
        h, dx, dc = dec.decode(delta)
        assert (h.version, h.reference, h.number) == (6 if split else 4, n - 1, n)
        assert np.array_equal(dx, kx) and np.array_equal(dc, kc)
        assert len(delta) < 0.8 * len(key), (len(delta), len(key))


def test_a_delta_without_its_reference_is_refused():
    (x0, c0), (x1, c1), (x2, c2) = _sequence(3)
    enc = InterEncoder(CompactParams())
    k0, _ = enc.encode(x0, c0, 0)
    _, d1 = enc.encode(x1, c1, 1, key=False)
    _, d2 = enc.encode(x2, c2, 2, key=False)
    with pytest.raises(FormatError, match="CompactDecoder"):
        decode_compact(d1)
    with pytest.raises(FormatError, match="holds no frame"):
        CompactDecoder().decode(d1)
    dec = CompactDecoder()
    dec.decode(k0)
    with pytest.raises(FormatError, match="delta against frame 1, but this decoder holds frame 0"):
        dec.decode(d2)  # frame 1 was missed
    with pytest.raises(ValidationError):
        InterEncoder(CompactParams(version=2))


def test_a_cloud_that_leaves_the_grid_starts_a_new_one_with_a_key_frame_only():
    (x0, c0), (x1, c1) = _sequence(2)
    enc = InterEncoder(CompactParams())
    enc.encode(x0, c0, 0)
    key, delta = enc.encode(x1 + np.float32(50.0), c1, 1, key=False)  # 50 m away
    assert delta is None and key is not None and decode_compact(key)[0].version == 7
    _, delta = enc.encode(x1 + np.float32(50.0), c1, 2, key=False)
    assert delta is not None  # on the new grid


@pytest.mark.skipif(shutil.which("node") is None, reason="needs node to run the viewer's decoder")
@pytest.mark.parametrize("split", [1.5, 0.0])
def test_browser_decoder_decodes_deltas_bit_identically(tmp_path, split):
    enc, dec = InterEncoder(CompactParams(split=split)), CompactDecoder()
    names, expect = [], []
    for n, (xyz, rgb) in enumerate(_sequence(3, patchy=True)):
        key, delta = enc.encode(xyz, rgb, n, key=n == 0)
        data = delta if delta is not None else key
        (tmp_path / f"{n}.bin").write_bytes(data)
        names.append(str(tmp_path / f"{n}.bin"))
        expect.append(dec.decode(data))
    script = """
const fs = require("fs"); const { decodeFrame, createDecoder } = require(process.argv[2]);
(async () => {
  const dec = createDecoder(), out = [];
  const buf = (n) => { const b = fs.readFileSync(n); return b.buffer.slice(b.byteOffset, b.byteOffset + b.length); };
  let alone = "decoded";
  try { await decodeFrame(buf(process.argv[4])); } catch (e) { alone = e.message; }
  for (const n of process.argv.slice(3)) {
    const f = await dec.decodeFrame(buf(n));
    out.push({ version: f.version, held: dec.held(), xyz: Array.from(f.xyz.slice(0, 30)), sum: f.xyz.reduce((a, v) => a + v, 0),
               rgb: Buffer.from(f.rgb.buffer, f.rgb.byteOffset, f.rgb.length).toString("base64") });
  }
  console.log(JSON.stringify({ alone, out }));
})();
"""
    (tmp_path / "run.js").write_text(script)
    res = subprocess.run(["node", str(tmp_path / "run.js"), str(DECODE_JS), *names], capture_output=True, text=True,
                         timeout=120, check=True)  # fmt: skip
    got = json.loads(res.stdout)
    assert "delta against frame 0" in got["alone"] and "holds no frame" in got["alone"]
    import base64

    for n, (o, (h, xyz, rgb)) in enumerate(zip(got["out"], expect)):
        assert o["version"] == h.version == ((7 if split else 3) if n == 0 else (6 if split else 4)) and o["held"] == n
        assert np.allclose(o["xyz"], xyz.reshape(-1)[:30], atol=0) and o["sum"] == pytest.approx(
            float(xyz.sum()), rel=1e-6
        )
        assert base64.b64decode(o["rgb"]) == rgb.tobytes()


def _frame(ws, ack: bool, dec: CompactDecoder):
    """(version, number) of the next frame of a client (acknowledged, with what it holds)."""
    meta = json.loads(ws.recv(timeout=10)) if ack else None
    data = ws.recv(timeout=10)
    h, _, _ = dec.decode(data)
    if ack:
        assert meta["number"] == h.number
        ws.send(json.dumps({"type": "ack", "number": h.number, "held": h.number}))
    return h.version, h.number


def test_the_server_sends_deltas_to_viewers_that_hold_the_reference_and_key_frames_to_others():
    ws_client = pytest.importorskip("websockets.sync.client")
    from fuseflow.live.loop import LiveFrame
    from fuseflow.live.server import LiveServer
    from fuseflow.live.sinks import WebSink

    server = LiveServer("127.0.0.1", 0, codec="compact").start()
    sink = WebSink(server, CompactParams())
    url = f"ws://127.0.0.1:{server.port}/ws"
    seq = _sequence(5)
    try:
        with ws_client.connect(url + "?inter=1&ack=1", max_size=None) as a, ws_client.connect(url, max_size=None) as b:
            da, db = CompactDecoder(), CompactDecoder()
            a.recv(timeout=5), b.recv(timeout=5)  # the rig
            for _ in range(50):
                if server.clients == 2:
                    break
                time.sleep(0.05)
            got_a, got_b = [], []
            for n, (xyz, rgb) in enumerate(seq[:4]):
                sink.send(_fused(xyz, rgb), LiveFrame(n, n, time.perf_counter(), 1.0, ()))
                got_a.append(_frame(a, True, da))
                got_b.append(_frame(b, False, db))
            assert got_a == [(7, 0), (6, 1), (6, 2), (6, 3)] and got_b == [(7, n) for n in range(4)]
            with ws_client.connect(url + "?inter=1&ack=1", max_size=None) as c:  # a late viewer: a key frame first
                c.recv(timeout=5)
                dc = CompactDecoder()
                assert _frame(c, True, dc) == (7, 3)
                sink.send(_fused(*seq[4]), LiveFrame(4, 4, time.perf_counter(), 1.0, ()))
                assert (
                    _frame(c, True, dc) == (6, 4) and _frame(a, True, da) == (6, 4) and _frame(b, False, db) == (7, 4)
                )
    finally:
        sink.close()
        server.close()


def test_sequence_benchmark_rows(tmp_path):
    from benchmarks.studies.live_codec_versions import measure_sequence, table

    rows = measure_sequence("surface", _sequence(3, 5000), 1, tmp_path if shutil.which("node") else None)
    key, delta = rows
    assert key["codec"] == "key frames" and delta["codec"] == "a key frame, then deltas"
    assert delta["bits_per_point"] < key["bits_per_point"] and delta["frames"] == key["frames"] == 3
    assert delta["rgb_err_p95"] == key["rgb_err_p95"] and delta["pos_err_axis_max_mm"] <= 1.5 + 1e-3
    assert all(r.get("node_decode_ms", 1) > 0 for r in rows)
    assert len(table([{k: v for k, v in r.items() if k != "_frames"} for r in rows])) == 4


def test_damaged_deltas_are_format_errors_and_leave_nothing_to_refer_to():
    import struct
    import zlib

    (x0, c0), (x1, c1) = _sequence(2, 5000)
    enc = InterEncoder(CompactParams())
    k0, _ = enc.encode(x0, c0, 0)
    _, d1 = enc.encode(x1, c1, 1, key=False)
    rng = np.random.default_rng(5)
    for trial in range(30):
        body = bytearray(d1[64:])
        if trial % 2:
            body = bytearray(rng.bytes(len(body)))  # garbage behind a valid checksum
        else:
            body[rng.integers(len(body))] ^= 1 << int(rng.integers(8))
        bad = d1[:48] + struct.pack("<I", zlib.crc32(bytes(body))) + d1[52:64] + bytes(body)
        dec = CompactDecoder()
        dec.decode(k0)
        try:
            h, xyz, _ = dec.decode(bad)
        except FormatError:
            with pytest.raises(FormatError, match="holds no frame"):
                dec.decode(d1)  # the failed frame is not a reference either
        else:
            assert h.points == len(xyz)  # a flip the coder absorbs still decodes consistently
    with pytest.raises(FormatError, match="checksum"):
        dec = CompactDecoder()
        dec.decode(k0)
        dec.decode(d1[:-1] + bytes([d1[-1] ^ 1]))


def test_a_frame_is_coded_once_per_kind_however_many_viewers_want_it(monkeypatch):
    from fuseflow.live import codec
    from fuseflow.live.loop import LiveFrame
    from fuseflow.live.sinks import WebSink

    class Viewers:  # two viewers that need key frames and two that take deltas
        def __init__(self):
            self.published = []

        def codecs(self):
            return {"compact"}

        def compact_needs(self, reference):
            return True, reference is not None

        def publish(self, frames, meta):
            self.published.append((sorted(frames), meta))

        def close(self):
            pass

    calls = []
    streams = codec._streams
    monkeypatch.setattr(codec, "_streams", lambda *a: calls.append(a[4] is not None) or streams(*a))
    server = Viewers()
    sink = WebSink(server, CompactParams())
    calls.clear()  # the sink's warm-up
    try:
        for n, (xyz, rgb) in enumerate(_sequence(3, 5000)):
            sink.send(_fused(xyz, rgb), LiveFrame(n, n, time.perf_counter(), 1.0, ()))
            for _ in range(200):
                if len(server.published) > n:
                    break
                time.sleep(0.02)
    finally:
        sink.close()
    assert [p[0] for p in server.published] == [["compact"], ["compact", "compact.delta"], ["compact", "compact.delta"]]
    assert calls == [False, True, False, True, False]  # per frame: the key frame, and from the second a delta


def test_holding_the_last_frame_sends_the_key_frame_closing_coded_instead_of_coding_it_again(monkeypatch):
    from fuseflow.live import codec
    from fuseflow.live.loop import LiveFrame
    from fuseflow.live.sinks import WebSink

    class DeltaViewer:  # one viewer that holds every frame: the last one is sent as a delta only
        def __init__(self):
            self.published = []

        def codecs(self):
            return {"compact"}

        def compact_needs(self, reference):
            return reference is None, reference is not None

        def publish(self, frames, meta):
            self.published.append((frames, meta))

        def close(self):
            pass

    keys = []
    streams = codec._streams
    monkeypatch.setattr(codec, "_streams", lambda *a: (keys.append(1) if a[4] is None else None) or streams(*a))
    server = DeltaViewer()
    sink = WebSink(server, CompactParams())
    sink.owns_server = False
    for n, (xyz, rgb) in enumerate(_sequence(2, 5000)):
        sink.send(_fused(xyz, rgb), LiveFrame(n, n, time.perf_counter(), 1.0, ()))
        for _ in range(200):
            if len(server.published) > n:
                break
            time.sleep(0.02)
    keys.clear()  # the first frame's key frame
    sink.hold()  # closes the sink (a key frame of the last frame for late viewers), then sends it in every codec
    codecs = [sorted(f) for f, _ in server.published[2:]]
    assert keys == [1] and codecs == [["compact"], ["compact", "raw", "raw.attrs"]]
    closing, held = server.published[2][0]["compact"], server.published[3][0]["compact"]
    assert held is closing and decode_compact(held)[0].number == 1
