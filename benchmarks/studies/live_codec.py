"""The live stream's frame codecs on real fused clouds: bytes a point, Mbit/s at 10 fps, encoding
CPU time, decoding time (Python, and the viewer's decoder in headless Chromium when selenium and
chromium are there), and the position and colour error of each point against what a viewer shows.

Clouds (``clouds``): the hocap-8rs frame fused with ``--preset live`` (every point, and
``--points 200000``) and a simulated 8-camera 640x480 studio fused the same way. Each is encoded
as ``raw`` and as ``compact`` at every grid step and colour setting asked for.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from fuseflow.live.codec import CompactParams, encode_compact
from fuseflow.live.wire import decode_frame, encode_frame

__all__ = ["clouds", "measure", "browser_decode_ms", "run_codec_bench"]


def clouds(data_dir: Path, work: Path) -> dict[str, Any]:
    """name -> FusedCloud: hocap8 (every point), hocap8-200k, sim8-200k (a simulated studio) and
    sim8-200k-crop (the same cropped to the rig's capture volume, ``--crop auto``)."""
    from fuseflow.fuse import fuse
    from fuseflow.fuse.presets import preset_config
    from fuseflow.io import open_recording
    from fuseflow.io.hocap import convert_hocap
    from fuseflow.synth import SimConfig, simulate_recording

    convert_hocap(Path(data_dir) / "hocap-8rs", work / "hocap8", with_extrinsics=True)
    cfg = SimConfig(cameras=8, frames=1, scene="studio", dynamic=True, resolution=(640, 480), seed=0, fps=10.0)
    simulate_recording(work / "sim8", cfg)
    from fuseflow.geometry.volume import crop_cloud
    from fuseflow.pipeline.exports import resolve_crop

    hocap, sim = open_recording(work / "hocap8"), open_recording(work / "sim8")
    sim200 = fuse(sim[0], sim.rig, preset_config("live", 200_000))
    return {
        "hocap8": fuse(hocap[0], hocap.rig, preset_config("live")),
        "hocap8-200k": fuse(hocap[0], hocap.rig, preset_config("live", 200_000)),
        "sim8-200k": sim200,
        "sim8-200k-crop": crop_cloud(sim200, resolve_crop("auto", sim.rig, None)),
    }


def cpu_ms(fn, repeats: int) -> tuple[Any, float]:
    """(the last result of ``fn()``, the median CPU time of ``repeats`` calls after a first one, ms)."""
    out, times = fn(), []
    for _ in range(repeats):
        t = time.thread_time()
        out = fn()
        times.append((time.thread_time() - t) * 1000.0)
    return out, float(np.median(times))


def _errors(xyz: np.ndarray, rgb: np.ndarray, data: bytes) -> dict[str, float]:
    """Per sent point: distance to the nearest decoded point (mm; per axis and Euclidean) and
    the absolute colour difference to it (0-255, per channel)."""
    from scipy.spatial import cKDTree

    d = decode_frame(data)
    tree = cKDTree(d.xyz)
    cheb, _ = tree.query(xyz, p=np.inf)
    eucl, idx = tree.query(xyz)
    err = np.abs(d.rgb[idx].astype(np.int16) - rgb.astype(np.int16))
    return {"points_sent": len(d.xyz), "pos_err_axis_max_mm": round(float(cheb.max()) * 1e3, 3),
            "pos_err_median_mm": round(float(np.median(eucl)) * 1e3, 3),
            "pos_err_max_mm": round(float(eucl.max()) * 1e3, 3), "rgb_err_median": float(np.median(err)),
            "rgb_err_p95": float(np.percentile(err, 95)), "rgb_err_p99": float(np.percentile(err, 99))}  # fmt: skip


def measure(name: str, cloud: Any, params: list[CompactParams], repeats: int = 5) -> list[dict[str, Any]]:
    """One row per codec setting: raw first, then each compact ``params``."""
    from scipy.spatial import cKDTree

    xyz = cloud.xyz.numpy().astype(np.float32)
    rgb = cloud.rgb.numpy().astype(np.uint8)
    spacing = float(np.median(cKDTree(xyz).query(xyz, k=2)[0][:, 1])) * 1e3
    rows = []
    settings: list[tuple[str, CompactParams | None]] = [("raw", None)] + [("compact", p) for p in params]
    for codec, p in settings:
        if p is None:
            data, enc = cpu_ms(lambda: encode_frame(cloud, 0, 0.0, 0.0, "raw"), repeats)
        else:
            data, enc = cpu_ms(lambda p=p: encode_compact(xyz, rgb, 0, 0.0, 0.0, p), repeats)
        _, dec = cpu_ms(lambda data=data: decode_frame(data), max(1, repeats // 2))
        row = {"cloud": name, "points": len(xyz), "codec": codec, "grid_mm": p.step_mm if p else None,
               "luma_step": p.luma_step if p else None, "chroma_step": p.chroma_step if p else None,
               "chroma_block": p.chroma_block if p else None, "bytes": len(data),
               "bytes_per_point": round(len(data) / max(len(xyz), 1), 3),
               "mbit_per_s_at_10fps": round(len(data) * 8 * 10 / 1e6, 2),
               "mbit_per_s_at_10fps_200k": round(len(data) / max(len(xyz), 1) * 200_000 * 8 * 10 / 1e6, 2),
               "encode_cpu_ms": round(enc, 1), "python_decode_cpu_ms": round(dec, 1),
               "nn_spacing_median_mm": round(spacing, 2),
               "geometry_bits_per_point": round(int.from_bytes(data[52:56], "little") * 8 / max(len(xyz), 1), 2)
               if p else 48.0}  # fmt: skip
        row.update(_errors(xyz, rgb, data))
        rows.append(row)
    return rows


def browser_decode_ms(frames: dict[str, bytes], seconds: float = 20.0) -> dict[str, float | None]:
    """Median time the viewer page (decode.js) takes to decode each frame in headless Chromium
    (the frame is sent repeatedly over a LiveServer); None for all when there is no browser."""
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    driver_path = shutil.which("chromedriver")
    try:
        from selenium import webdriver
    except ImportError:
        webdriver = None
    if webdriver is None or not chromium or not driver_path:
        return dict.fromkeys(frames)
    from fuseflow.live.server import LiveServer

    opts = webdriver.ChromeOptions()
    opts.binary_location = chromium
    for a in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--use-angle=swiftshader",
              "--enable-unsafe-swiftshader", "--window-size=640,480"):  # fmt: skip
        opts.add_argument(a)
    out: dict[str, float | None] = {}
    with tempfile.TemporaryDirectory():
        driver = webdriver.Chrome(options=opts, service=webdriver.ChromeService(executable_path=driver_path))
        try:
            for name, data in frames.items():
                with LiveServer("127.0.0.1", 0) as server:
                    driver.get(f"{server.url}?codec={'raw' if data[4] == 1 else 'compact'}")
                    end = time.time() + seconds
                    ms: list[float] = []
                    while time.time() < end and len(ms) < 12:
                        server.publish(data)
                        time.sleep(0.3)
                        ms = driver.execute_script("return window.fuseflowStats ? window.fuseflowStats.decodeMs : []")
                    out[name] = round(float(np.median(ms[2:] or ms)), 1) if ms else None
        finally:
            driver.quit()
    return out


def run_codec_bench(data_dir: Path, grids: list[float], browser: bool = True, log=print) -> dict[str, Any]:
    """Every cloud of ``clouds`` as raw and compact (each grid in ``grids``, plus a finer and a
    coarser colour at the default grid), and the browser's decoding time of the hocap8-200k frame
    (raw and the default compact) when ``browser``: {"rows": [...], "browser_decode_ms": {...}}."""
    import json

    params = [CompactParams(step_mm=float(g)) for g in grids]
    params += [CompactParams(luma_step=2, chroma_step=4, chroma_block=2),
               CompactParams(luma_step=8, chroma_step=16, chroma_block=8)]  # fmt: skip
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="live_codec_") as tmp:
        found = clouds(data_dir, Path(tmp))
        for name, cloud in found.items():
            for r in measure(name, cloud, params):
                log(json.dumps(r))
                rows.append(r)
    decode: dict[str, float | None] = {}
    if browser:
        c = found["hocap8-200k"]
        xyz, rgb = c.xyz.numpy(), c.rgb.numpy()
        decode = browser_decode_ms({"raw": encode_frame(c, 0, 0.0, 0.0, "raw"),
                                    "compact": encode_compact(xyz, rgb, 0, 0.0, 0.0, CompactParams())})  # fmt: skip
        log(f"headless Chromium decode ms (hocap8-200k): {decode}")
    return {"rows": rows, "browser_decode_ms": decode}
