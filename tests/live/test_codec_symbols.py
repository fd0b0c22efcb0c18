"""Version 7 of the compact frame codec: the octree as one symbol per node (its occupancy byte in
the canonical frame of its face-neighbour pattern, from adaptive frequency tables): the same
points and colours as version 5 from the same cloud, deltas (version 6) after a version 7 key
frame, decode.js bit-identical to Python, malformed messages rejected by both, and the symmetry
tables sharing one model between mirror images."""

import json
import shutil
import subprocess

import numpy as np
import pytest
from tests.live.test_codec import _surface
from tests.live.test_codec_delta import _sequence
from tests.live.test_codec_v3 import DECODE_JS, _garbage_frames

from fuseflow.errors import FormatError, ValidationError
from fuseflow.live.codec import COMPACT_HEADER, CompactDecoder, CompactParams, InterEncoder, encode_compact
from fuseflow.live.codec_kernels import SYM_LAST, symmetry_tables
from fuseflow.live.wire import decode_frame

V7 = CompactParams()
"""The default: version 7 key frames."""
needs_node = pytest.mark.skipif(shutil.which("node") is None, reason="needs node to run the viewer's decoder")


def _clouds():
    rng = np.random.default_rng(4)
    xyz, rgb = _surface(30000)
    nx, nrgb = _surface(3000, seed=1, noisy=True)
    sparse = np.r_[[[0.0, 0.0, 0.0], [2000.0, 3.0, 1.0]], rng.uniform(0, 2000, (500, 3))].astype(np.float32) + 1e-4
    block = (np.stack(np.meshgrid(*[np.arange(8) * 0.003] * 3), -1).reshape(-1, 3) + 1e-4).astype(np.float32)
    grey = lambda a: np.full((len(a), 3), 96, np.uint8)  # noqa: E731
    return {"surface": (xyz, rgb), "noisy": (nx, nrgb), "sparse over 2 km": (sparse, grey(sparse)),
            "a full 8x8x8 block": (block, grey(block)), "one point": (block[:1], grey(block[:1]))}  # fmt: skip


def test_version_7_decodes_to_the_points_and_colours_of_version_5():
    for name, (xyz, rgb) in _clouds().items():
        d7 = decode_frame(encode_compact(xyz, rgb, 1, 0.0, 0.0, V7))
        d5 = decode_frame(encode_compact(xyz, rgb, 1, 0.0, 0.0, CompactParams(version=3)))
        assert (d7.version, d5.version) == (7, 5), name
        assert np.array_equal(d7.xyz, d5.xyz) and np.array_equal(d7.rgb, d5.rgb), name
    assert decode_frame(encode_compact(xyz, rgb, 1, 0.0, 0.0, CompactParams(split=0.0))).version == 3  # never split
    with pytest.raises(ValidationError, match="version"):
        CompactParams(version=5).check()


def test_deltas_follow_a_version_7_key_frame():
    enc, dec, ref = InterEncoder(V7), CompactDecoder(), CompactDecoder()
    for n, (xyz, rgb) in enumerate(_sequence(3, patchy=True)):
        key, delta = enc.encode(xyz, rgb, n)
        assert key[4] == 7 and (delta is None) == (n == 0)
        h, got_xyz, got_rgb = dec.decode(delta if delta is not None else key)
        _, want_xyz, want_rgb = ref.decode(key)
        assert h.version == (7 if n == 0 else 6)
        assert np.array_equal(got_xyz, want_xyz) and np.array_equal(got_rgb, want_rgb)


def test_the_symmetry_tables_share_one_model_between_mirror_images():
    cls, fwd, inv = symmetry_tables()
    assert sorted(set(cls.tolist())) == list(range(10))
    for nb in range(64):
        assert np.array_equal(inv[nb, fwd[nb]], np.arange(256)) and fwd[nb, 0] == 0
        children = np.searchsorted(SYM_LAST, fwd[nb, 1:]) + 1  # symbols number bytes by their children
        assert np.array_equal(children, [bin(b).count("1") for b in range(1, 256)])
    lower_x, upper_x, upper_z = 1 << 0, 1 << 1, 1 << 5  # one face neighbour: below / above along x, above along z
    assert cls[lower_x] == cls[upper_x] == cls[upper_z] != cls[0]
    # a child beside the neighbour, in each mirror image, is one symbol: k = 0 (x = 0) under a
    # lower x neighbour, k = 4 (x = 1) under an upper one, k = 1 (z = 1) under an upper z one
    assert fwd[lower_x, 1 << 0] == fwd[upper_x, 1 << 4] == fwd[upper_z, 1 << 1]
    assert fwd[lower_x, 1 << 4] != fwd[lower_x, 1 << 0]


def test_malformed_version_7_messages_are_format_errors():
    xyz, rgb = _surface(3000)
    data = encode_compact(xyz, rgb, 3, 0.0, 0.0, V7)
    for n in (COMPACT_HEADER, len(data) // 2, len(data) - 1):
        with pytest.raises(FormatError):
            decode_frame(data[:n])
    m = int.from_bytes(data[12:16], "little")
    for frame in _garbage_frames(data, 30):  # valid checksum, nonsense streams: an error or M points
        try:
            got = len(decode_frame(frame).xyz)
        except FormatError:
            continue
        assert got == m


@needs_node
def test_browser_decoder_decodes_version_7_bit_identically_and_rejects_what_python_rejects(tmp_path):
    frames = {f"{name}.bin": encode_compact(xyz, rgb, i, 0.0, 0.0, V7) for i, (name, (xyz, rgb))
              in enumerate(_clouds().items())}  # fmt: skip
    data = frames["surface.bin"]
    frames.update(
        {"truncated.bin": data[:-3], **{f"garbage{i}.bin": g for i, g in enumerate(_garbage_frames(data, 12))}}
    )
    for name, frame in frames.items():
        (tmp_path / name).write_bytes(frame)
    script = """
const fs = require("fs"); const { decodeFrame } = require(process.argv[2]);
(async () => {
  for (const name of process.argv.slice(3)) {
    const b = fs.readFileSync(name);
    try {
      const f = await decodeFrame(b.buffer.slice(b.byteOffset, b.byteOffset + b.length));
      fs.writeFileSync(name + ".out", Buffer.concat([Buffer.from(f.xyz.buffer), Buffer.from(f.rgb.buffer, f.rgb.byteOffset, f.rgb.length)]));
      console.log(JSON.stringify({ name, m: f.m, version: f.version }));
    } catch (e) { console.log(JSON.stringify({ name, error: String(e.message) })); }
  }
})();
"""
    (tmp_path / "run.js").write_text(script)
    out = subprocess.run(["node", str(tmp_path / "run.js"), str(DECODE_JS), *(str(tmp_path / n) for n in frames)],
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert out.returncode == 0, out.stderr
    results = {r["name"].rsplit("/", 1)[-1]: r for r in map(json.loads, out.stdout.split("\n")[:-1])}
    decoded = 0
    for name, frame in frames.items():
        r = results[name]
        try:
            py = decode_frame(frame)
        except FormatError:
            assert "live frame" in r.get("error", ""), (name, r)
            continue
        m = len(py.xyz)
        assert (r.get("m"), r.get("version")) == (m, 7), (name, r)
        js = (tmp_path / (name + ".out")).read_bytes()
        assert np.array_equal(np.frombuffer(js[: 12 * m], np.float32).reshape(m, 3), py.xyz), name
        assert np.array_equal(np.frombuffer(js[12 * m :], np.uint8).reshape(m, 3), py.rgb), name
        decoded += name in _clouds_names()
    assert decoded == len(_clouds_names()) and "error" in results["truncated.bin"]


def _clouds_names() -> set[str]:
    return {f"{name}.bin" for name in _clouds()}


@needs_node
def test_browser_decoder_decodes_deltas_after_a_version_7_key_frame(tmp_path):
    enc, dec, names, expect = InterEncoder(V7), CompactDecoder(), [], []
    for n, (xyz, rgb) in enumerate(_sequence(3, patchy=True)):
        key, delta = enc.encode(xyz, rgb, n, key=n == 0)
        (tmp_path / f"{n}.bin").write_bytes(delta if delta is not None else key)
        names.append(str(tmp_path / f"{n}.bin"))
        expect.append(dec.decode(delta if delta is not None else key))
    script = """
const fs = require("fs"); const dec = require(process.argv[2]).createDecoder();
(async () => {
  for (const n of process.argv.slice(3)) {
    const b = fs.readFileSync(n), f = await dec.decodeFrame(b.buffer.slice(b.byteOffset, b.byteOffset + b.length));
    fs.writeFileSync(n + ".out", Buffer.concat([Buffer.from(f.xyz.buffer), Buffer.from(f.rgb.buffer, f.rgb.byteOffset, f.rgb.length)]));
    console.log(f.version);
  }
})();
"""
    (tmp_path / "run.js").write_text(script)
    out = subprocess.run(["node", str(tmp_path / "run.js"), str(DECODE_JS), *names], capture_output=True, text=True,
                         timeout=120, check=True)  # fmt: skip
    assert out.stdout.split() == ["7", "6", "6"]
    for name, (_, xyz, rgb) in zip(names, expect):
        js, m = (tmp_path / f"{name}.out").read_bytes(), len(xyz)
        assert np.array_equal(np.frombuffer(js[: 12 * m], np.float32).reshape(m, 3), xyz)
        assert np.array_equal(np.frombuffer(js[12 * m :], np.uint8).reshape(m, 3), rgb)


def test_the_model_study_counts_the_coded_streams():
    from benchmarks.studies.live_codec_symbols import VARIANTS, symbol_rows

    xyz, rgb = _surface(20000, seed=5)
    rows = {r["model"]: r for r in symbol_rows("surface", xyz, rgb)}
    v5 = rows["v5"]
    assert v5["geometry_bits_per_point"] == pytest.approx(v5["coded_geometry_bits_per_point"], rel=0.01)
    v7 = next(r for name, r in rows.items() if name.startswith("v7"))
    data = encode_compact(xyz, rgb, 0, 0.0, 0.0, V7)
    assert v7["geometry_bits_per_point"] == pytest.approx(
        int.from_bytes(data[52:56], "little") * 8 / len(xyz), abs=1e-3
    )
    assert v7["decisions_per_point"] < v5["decisions_per_point"] / 3  # one symbol a node against its bits
    direct = [rows[label]["direct_nodes"] for label, _, mode in VARIANTS if mode]
    assert min(direct) > 0 and v5["spacing_bound_bits_per_point"] > 0


KEY_AND_DELTA_SHA256 = "5c3a521d3d3744e5d0d214434e18b51394e7b35babcdfc8868db692c6fa52e53"
"""The bytes of every cloud of ``_clouds`` in four settings, then a 3-frame sequence's key frames
and deltas: what the format's readers (Python, decode.js) were checked against; an encoder made
faster must write them unchanged."""


def test_the_encoder_writes_the_same_bytes_for_fixed_clouds():
    import hashlib

    h = hashlib.sha256()
    for xyz, rgb in _clouds().values():
        for p in (V7, CompactParams(version=3), CompactParams(split=0.0), CompactParams(luma_step=1, chroma_step=2)):
            h.update(encode_compact(xyz, rgb, 1, 0.0, 0.0, p))
    enc = InterEncoder(V7)
    for n, (xyz, rgb) in enumerate(_sequence(3, patchy=True)):
        for message in enc.encode(xyz, rgb, n):
            h.update(message or b"")
    assert h.hexdigest() == KEY_AND_DELTA_SHA256


def test_colour_coded_as_made_equals_the_listed_decisions_range_coded():
    from fuseflow.live.codec_kernels import COL_CONTEXTS, colour_code, colour_decisions, colour_values, range_code

    rng = np.random.default_rng(7)
    mean = rng.uniform(0, 255, (5000, 3))
    mean[:2000] = np.round(mean[:2000] / 40) * 40  # long runs of zero residuals, then large ones (escapes)
    for luma, chroma, split in ((12, 16, 1.5), (1, 2, 1.5), (8, 16, 0.0)):
        qy, qc, flags = colour_values(mean, luma, chroma, 4, split)
        for rleaf, rq in ((np.full(5000, -1, np.int64), np.zeros((0, 3), np.int64)),
                          (np.where(np.arange(5000) % 3 == 0, rng.integers(0, 4000, 5000), -1),
                           rng.integers(-30, 30, (4000, 3)))):  # fmt: skip
            listed = range_code(*colour_decisions(qy, qc, 4, rleaf, rq, flags, split > 0), COL_CONTEXTS)
            assert np.array_equal(colour_code(qy, qc, 4, rleaf, rq, flags, split > 0), listed)
