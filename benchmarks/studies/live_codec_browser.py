"""decode.js in headless Chromium: the wall time from a compact key frame's bytes to its points
and colours, decoded on the page's thread alone (``createDecoder()``) and with its geometry in a
module worker (``decode-worker.js``) while the page's thread decodes its colours
(``createDecoder({ worker })``), in one page, the two alternating frame by frame; each decode
checks that both give the same points and colours. Beside it, the compact encoder's wall and
process CPU time (its two threads) on the same clouds.

The page and the static files (``fuseflow/live/static``) are served from a temporary folder by a
local HTTP server; Chromium runs with the flags of ``tests/live/test_browser.py``.
"""

from __future__ import annotations

import contextlib
import functools
import http.server
import os
import shutil
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

__all__ = ["PAGE", "browser", "serve", "decode_in_browser", "run_codec_browser"]

STATIC = Path(__file__).resolve().parents[2] / "src" / "fuseflow" / "live" / "static"

PAGE = """<!doctype html><meta charset="utf-8"><title>decode</title>
<script src="decode.js"></script>
<script>
const worker = new Worker("decode-worker.js", { type: "module" });
const same = (a, b) => a.length === b.length && a.every((v, i) => v === b[i]);
// frames: name -> [key frame url, delta url or null]; per name the wall ms of every decode of each
// path ("single", "worker"; "delta": the delta after the key frame, on the worker decoder) and
// whether the worker path gave the single path's points and colours
window.runDecode = async (frames, repeats) => {
  const out = {};
  for (const [name, [keyUrl, deltaUrl]] of Object.entries(frames)) {
    const key = await (await fetch(keyUrl)).arrayBuffer(), delta = deltaUrl && (await (await fetch(deltaUrl)).arrayBuffer());
    const r = { single: [], worker: [], delta: [], geoMain: [], geoWorker: [], same: true, split: 0, deltaSame: true };
    const dv = new DataView(key), s1 = dv.getUint32(52, true), job = [dv.getUint16(4, true), dv.getUint8(44), dv.getUint32(12, true)];
    const geoJob = () => new Promise((resolve) => {  // the worker's part alone: a geometry job and its answer
      const t0 = performance.now(), got = () => { worker.removeEventListener("message", got); resolve(performance.now() - t0); };
      worker.addEventListener("message", got);
      worker.postMessage({ id: -1, version: job[0], geo: key.slice(60, 60 + s1), levels: job[1], m: job[2], origin: [0, 0, 0], step: 1 });
    });
    for (let i = -2; i < repeats; i++) {  // two rounds to warm up, not counted
      for (const path of i % 2 ? ["single", "worker"] : ["worker", "single"]) {
        const dec = FuseFlowDecode.createDecoder(path === "worker" ? { worker } : undefined);
        const t0 = performance.now(), f = await dec.decodeFrame(key), ms = performance.now() - t0;
        if (i >= 0) r[path].push(ms);
        r[path + "Frame"] = f;
        if (path === "worker" && f.split) r.split++;
        if (delta) {
          const t1 = performance.now(), d = await dec.decodeFrame(delta), dms = performance.now() - t1;
          if (path === "worker" && i >= 0) r.delta.push(dms);
          r[path + "Delta"] = d;
        }
      }
      const g0 = performance.now();
      FuseFlowDecode.keyGeometry(job[0], new Uint8Array(key, 60, s1), job[1], job[2], [0, 0, 0], 1);  // this thread's part alone
      const gm = performance.now() - g0, gw = await geoJob();
      if (i >= 0) { r.geoMain.push(gm); r.geoWorker.push(gw); }
      r.same = r.same && same(r.singleFrame.xyz, r.workerFrame.xyz) && same(r.singleFrame.rgb, r.workerFrame.rgb);
      if (delta) r.deltaSame = r.deltaSame && same(r.singleDelta.xyz, r.workerDelta.xyz) && same(r.singleDelta.rgb, r.workerDelta.rgb);
    }
    out[name] = { single: r.single, worker: r.worker, delta: r.delta, geoMain: r.geoMain, geoWorker: r.geoWorker, same: r.same, deltaSame: r.deltaSame,
      split: r.split, m: r.singleFrame.m, version: r.workerFrame.version, deltaVersion: delta ? r.workerDelta.version : null };
  }
  return out;
};
</script>
"""


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args) -> None:  # noqa: D102 - no request log on the console
        pass


@contextlib.contextmanager
def serve(folder: Path) -> Iterator[str]:
    """The static files, PAGE (``decode.html``) and whatever else is in ``folder``, served on a free
    loopback port: yields the base URL."""
    for f in ("decode.js", "decode-worker.js"):
        shutil.copy(STATIC / f, folder / f)
    (folder / "decode.html").write_text(PAGE)
    handler = functools.partial(_Quiet, directory=str(folder))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/"
    finally:
        server.shutdown()
        server.server_close()


def browser():
    """Headless Chromium driven by selenium (Debian's chromium and chromedriver)."""
    from selenium import webdriver

    opts = webdriver.ChromeOptions()
    opts.binary_location = shutil.which("chromium") or shutil.which("chromium-browser")
    for a in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=640,480"):
        opts.add_argument(a)
    return webdriver.Chrome(options=opts, service=webdriver.ChromeService(executable_path=shutil.which("chromedriver")))


def decode_in_browser(frames: dict[str, tuple[bytes, bytes | None]], repeats: int, timeout_s: float = 600) -> dict:
    """name -> (key frame, delta after it or None) decoded ``repeats`` times per path in one
    headless Chromium page: the page's per-name result (wall ms lists, ``same``, ``split``)."""
    with tempfile.TemporaryDirectory(prefix="fuseflow-decode-") as tmp, serve(Path(tmp)) as base:
        urls = {}
        for i, (name, (key, delta)) in enumerate(frames.items()):
            (Path(tmp) / f"k{i}.bin").write_bytes(key)
            if delta is not None:
                (Path(tmp) / f"d{i}.bin").write_bytes(delta)
            urls[name] = [f"k{i}.bin", f"d{i}.bin" if delta is not None else None]
        driver = browser()
        try:
            driver.set_script_timeout(timeout_s)
            driver.get(base + "decode.html")
            return driver.execute_async_script(
                "const done = arguments[arguments.length - 1];"
                "runDecode(arguments[0], arguments[1]).then(done, (e) => done({ error: String(e) }));",
                urls,
                repeats,
            )
        finally:
            driver.quit()


def _encode_times(xyz: np.ndarray, rgb: np.ndarray, repeats: int) -> tuple[bytes, list[float], list[float]]:
    """The default compact key frame, and the wall and process CPU ms of each of ``repeats`` encodes."""
    from fuseflow.live.codec import CompactParams, encode_compact

    data, wall, cpu = encode_compact(xyz, rgb, 0, 0.0, 0.0, CompactParams()), [], []
    for _ in range(repeats):
        c, w = time.process_time(), time.perf_counter()
        encode_compact(xyz, rgb, 0, 0.0, 0.0, CompactParams())
        cpu.append((time.process_time() - c) * 1e3)
        wall.append((time.perf_counter() - w) * 1e3)
    return data, wall, cpu


def _spread(ms: list[float]) -> dict:
    a = np.asarray(ms, float)
    return {"median": round(float(np.median(a)), 1), "min": round(float(a.min()), 1),
            "p90": round(float(np.percentile(a, 90)), 1), "max": round(float(a.max()), 1)}  # fmt: skip


def _key_and_delta(xyz: np.ndarray, rgb: np.ndarray) -> tuple[bytes, bytes]:
    """The key frame (version 7) of (xyz, rgb) as the live sink codes it (``InterEncoder``), and a
    delta (version 6) after it: the same cloud, every point moved by 0.5 mm noise (seed 0)."""
    from fuseflow.live.codec import CompactParams, InterEncoder

    enc = InterEncoder(CompactParams())
    key, _ = enc.encode(xyz, rgb, 0, key=True, delta=False)
    moved = xyz + np.random.default_rng(0).normal(0, 5e-4, xyz.shape).astype(np.float32)
    return key, enc.encode(moved, rgb, 1, key=False, delta=True)[1]


def run_codec_browser(
    data_dir: Path, repeats: int = 20, encode_repeats: int = 7, work: Path | None = None, log=print
) -> dict:
    """Rows per cloud (hocap8-200k, sim8-200k: ``live_codec_versions.fused_clouds``): decode wall
    ms in Chromium, single thread and with the worker (median, min, p90, max over ``repeats``; the
    median over rounds of worker / single, the two decoded one after the other in each round), the
    parts alone in each round (the geometry on the page's thread, a geometry job of the worker,
    colours = single less the geometry) and their larger per round, the time a key frame would take
    with each thread on a core of its own; the delta after it (``_key_and_delta``), and the encoder's wall and CPU ms (over ``encode_repeats``); the load average
    before and after."""
    from benchmarks.studies.live_codec_versions import fused_clouds

    with tempfile.TemporaryDirectory(prefix="fuseflow-codec-browser-") as tmp:
        clouds = fused_clouds(data_dir, Path(work or tmp))
    clouds = {k: v for k, v in clouds.items() if k in ("hocap8-200k", "sim8-200k")}
    load0 = os.getloadavg()
    frames, enc = {}, {}
    for name, (xyz, rgb) in clouds.items():
        _, wall, cpu = _encode_times(xyz, rgb, encode_repeats)
        frames[name], enc[name] = _key_and_delta(xyz, rgb), (wall, cpu)
        log(f"{name}: encode wall {_spread(wall)} cpu {_spread(cpu)}")
    res = decode_in_browser(frames, repeats)
    if "error" in res:
        raise RuntimeError(res["error"])
    load1 = os.getloadavg()
    rows = []
    for name, r in res.items():
        colours = np.subtract(r["single"], r["geoMain"])  # this thread's decode less its geometry, per round
        bound = np.maximum(r["geoWorker"], colours)
        row = {"cloud": name, "points": len(clouds[name][0]), "points_sent": r["m"], "bytes": len(frames[name][0]),
               "decode_single_ms": _spread(r["single"]), "decode_worker_ms": _spread(r["worker"]),
               "worker_over_single": round(float(np.median(np.divide(r["worker"], r["single"]))), 3),
               "geometry_alone_ms": _spread(r["geoMain"]), "geometry_in_worker_ms": _spread(r["geoWorker"]),
               "colours_alone_ms": _spread(colours), "two_free_cores_bound_ms": _spread(bound),
               "decode_delta_ms": _spread(r["delta"]), "same_points_and_colours": r["same"] and r["deltaSame"],
               "frames_split": r["split"], "encode_wall_ms": _spread(enc[name][0]), "encode_cpu_ms": _spread(enc[name][1])}  # fmt: skip
        log(str(row))
        rows.append(row)
    meta = {"repeats": repeats, "encode_repeats": encode_repeats, "load_before": [round(x, 2) for x in load0],
            "load_after": [round(x, 2) for x in load1], "cpus": os.cpu_count()}  # fmt: skip
    log(str(meta))
    return {"rows": rows, "meta": meta}
