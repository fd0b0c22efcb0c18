"""decode.js in headless Chromium with its geometry worker (decode-worker.js): a key frame decodes
across the worker (geometry there, colours on the page's thread) to the same points and colours
as on the page's thread alone, for key frames of versions 7, 5 and 3; the delta after it still
decodes (on the page's thread, against what the worker sent back); a key frame whose header
disagrees with its geometry is refused, and the decoder goes on with the next one; a decoder whose
worker fails decodes on the page's thread."""

import shutil
from pathlib import Path

import pytest
from tests.live.test_codec_delta import _sequence

from fuseflow.live.codec import CompactParams, InterEncoder

pytest.importorskip("selenium.webdriver")
pytestmark = pytest.mark.skipif(
    not ((shutil.which("chromium") or shutil.which("chromium-browser")) and shutil.which("chromedriver")),
    reason="needs chromium and chromedriver (scripts/setup.sh test installs them)",
)

SCRIPT = """
const done = arguments[arguments.length - 1];
(async () => {
  const worker = new Worker("decode-worker.js", { type: "module" }), out = {};
  const get = async (u) => (await fetch(u)).arrayBuffer();
  const same = (a, b) => a.length === b.length && a.every((v, i) => v === b[i]);
  for (const v of ["v7", "v5", "v3"]) {
    const key = await get(v + "-key.bin"), delta = await get(v + "-delta.bin");
    const one = FuseFlowDecode.createDecoder(), two = FuseFlowDecode.createDecoder({ worker });
    const k1 = await one.decodeFrame(key), k2 = await two.decodeFrame(key);
    const d1 = await one.decodeFrame(delta), d2 = await two.decodeFrame(delta);
    out[v] = { m: k2.m, version: k2.version, split: !!k2.split, deltaVersion: d2.version, deltaSplit: !!d2.split,
      key: same(k1.xyz, k2.xyz) && same(k1.rgb, k2.rgb), delta: same(d1.xyz, d2.xyz) && same(d1.rgb, d2.rgb),
      deltaPoints: d2.m, held: two.held(), splitFrames: two.split(), keyBufferWhole: key.byteLength > 0 };
  }
  const dec = FuseFlowDecode.createDecoder({ worker }), bad = await get("bad.bin");
  out.bad = await dec.decodeFrame(bad).then(() => "decoded", (e) => e.message);
  const after = await dec.decodeFrame(await get("v7-key.bin"));
  out.after = { m: after.m, split: !!after.split, held: dec.held() };
  const lost = FuseFlowDecode.createDecoder({ worker: new Worker("no-such-worker.js", { type: "module" }) });
  const alone = await lost.decodeFrame(await get("v7-key.bin"));  // its worker never loads: this thread decodes
  out.lost = { m: alone.m, split: !!alone.split, same: same(alone.rgb, (await FuseFlowDecode.decodeFrame(await get("v7-key.bin"))).rgb) };
  return out;
})().then(done, (e) => done({ error: String(e) }));
"""


def test_a_key_frame_decodes_across_the_worker_as_on_one_thread(tmp_path):
    from benchmarks.studies.live_codec_browser import browser, serve

    clouds = _sequence(frames=2, m=20000, patchy=True)
    for name, params in (("v7", CompactParams()), ("v5", CompactParams(version=3)), ("v3", CompactParams(split=0))):
        enc = InterEncoder(params)
        key, _ = enc.encode(*clouds[0], 10, key=True, delta=False)
        _, delta = enc.encode(*clouds[1], 11, key=False, delta=True)
        (tmp_path / f"{name}-key.bin").write_bytes(key)
        (tmp_path / f"{name}-delta.bin").write_bytes(delta)
    key = bytearray((tmp_path / "v7-key.bin").read_bytes())
    key[12:16] = (int.from_bytes(key[12:16], "little") - 1).to_bytes(4, "little")  # M, outside the checksum
    (tmp_path / "bad.bin").write_bytes(bytes(key))
    with serve(Path(tmp_path)) as base:
        driver = browser()
        try:
            driver.set_script_timeout(120)
            driver.get(base + "decode.html")
            out = driver.execute_async_script(SCRIPT)
        finally:
            driver.quit()
    assert "error" not in out, out
    for name, version, delta_version in (("v7", 7, 6), ("v5", 5, 6), ("v3", 3, 4)):
        r = out[name]
        assert r["version"] == version and r["split"] and r["key"], r  # across the worker, same picture
        assert r["deltaVersion"] == delta_version and not r["deltaSplit"] and r["delta"], r  # the delta on this thread
        assert r["deltaPoints"] > 0 and r["held"] == 11 and r["splitFrames"] == 1 and r["keyBufferWhole"], r
    assert "the geometry stream" in out["bad"], out["bad"]  # the worker's error, as the frame's
    assert out["after"]["split"] and out["after"]["m"] == out["v7"]["m"] and out["after"]["held"] == 10, out
    # a decoder whose worker failed decodes on the page's thread
    assert out["lost"] == {"m": out["v7"]["m"], "split": False, "same": True}, out["lost"]
