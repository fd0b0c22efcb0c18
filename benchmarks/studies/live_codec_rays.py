"""Could the compact codec send a fused point as (camera, pixel, depth along the pixel's ray)
instead of as an occupied 3 mm cell? Each fused point carries the camera it came from
(``FusedCloud.camera``); this study measures, per fused cloud (``--preset live``, 200 k points):

- **off-ray**: how far each point lies from the ray through the centre of its nearest pixel of its
  camera (pixels: ``round(u), round(v)``, pixel centres at integers), in pixels and millimetres
  (the lateral distance at the point's depth). ``live`` fuses every 2nd pixel of every 2nd row,
  then ``cvgc.multiview_mean`` moves each point to the inverse-variance mean of its own and its
  neighbours' back-projections, off its ray;
- **the ideal bits a point** of the ray code at a position bound B (mm): per camera, a mask over
  the 2-pixel lattice (cell ``round(u / 2), round(v / 2)``) of which cells hold a point (one
  adaptive binary decision a cell, context: six causal neighbour cells), a flag per occupied cell
  for a further point in it, the depth along z quantised to a step of 2 b, predicted from the
  decoded depths of the causal neighbour cells (MED, as LOCO-I), and the point's offset from its
  cell's centre in pixels along u and v, quantised so the lateral error is at most a at the
  decoded depth (step 2 a f / z pixels), each residual an adaptive frequency-count symbol (+32,
  halved over 65 536; a residual past +-15 costs its Exp-Golomb bits). ``a = b = B / sqrt(3)``
  keeps every axis of the error within B but where the offset's error grows with the depth's
  (``share_over_bound``); ``a = b = B`` is reported too, with the per-axis error it leaves;
  "centre rays" sends no offset (the point decodes on its cell's centre ray);
- **colour in pixel order**: luma (step 12) and chroma (step 16, per point) predicted by MED from
  the decoded neighbours in the camera's lattice, against the compact codec's colour stream
  (Morton order, chroma blocks of 4 that split) of the same cloud.

Bits a point are -log2 p of every decision under its adaptive model over the fused points; the
camera's intrinsics and pose are not counted (sent once per rig). Points that project outside
their camera's image would need escape codes; their count is reported and they are left out.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
from numba import njit

__all__ = ["off_ray", "ray_code_bits", "ray_rows", "run_codec_rays"]

R_MAX = 15
"""Residuals in [-R_MAX, R_MAX] are one symbol; larger ones an escape plus Exp-Golomb bits."""


@njit(cache=True, inline="always")
def _bin(probs, c, bit):  # pragma: no cover - compiled
    p = probs[c]
    if bit == 0:
        probs[c] = p + ((2048 - p) >> 5)
        return -np.log2(p / 2048.0)
    probs[c] = p - (p >> 5)
    return -np.log2(1.0 - p / 2048.0)


@njit(cache=True, inline="always")
def _sym(freq, c, r):  # pragma: no cover - compiled
    """-log2 p of residual r in frequency table c (+32, halved over 65 536), escape beyond R_MAX."""
    s = r + R_MAX if -R_MAX <= r <= R_MAX else 2 * R_MAX + 1
    total = freq[c].sum()
    cost = -np.log2(freq[c, s] / total)
    freq[c, s] += 32
    if total + 32 > 65536:
        for j in range(freq.shape[1]):
            freq[c, j] = (freq[c, j] + 1) >> 1
    if s == 2 * R_MAX + 1:
        a = abs(r) - R_MAX
        cost += 1.0 + 2.0 * np.floor(np.log2(a)) + 1.0
    return cost


@njit(cache=True, inline="always")
def _med(w, n, nw):  # pragma: no cover - compiled
    if nw >= max(w, n):
        return min(w, n)
    if nw <= min(w, n):
        return max(w, n)
    return w + n - nw


@njit(cache=True, inline="always")
def _predict(img, have, y, x, gw, fallback):  # pragma: no cover - compiled
    """(prediction, neighbours present 0-2, activity) from decoded values of the causal cells
    (row-major scan: every occupied causal cell is decoded)."""
    hw = x > 0 and have[y, x - 1]
    hn = y > 0 and have[y - 1, x]
    hnw = x > 0 and y > 0 and have[y - 1, x - 1]
    if hw and hn:
        w, n = img[y, x - 1], img[y - 1, x]
        p = _med(w, n, img[y - 1, x - 1]) if hnw else 0.5 * (w + n)
        return p, 2, abs(w - n)
    if hw:
        return img[y, x - 1], 1, 0.0
    if hn:
        return img[y - 1, x], 1, 0.0
    hne = y > 0 and x + 1 < gw and have[y - 1, x + 1]
    if hne:
        return img[y - 1, x + 1], 1, 0.0
    return fallback, 0, 0.0


@njit(cache=True)
def ray_code_bits(gy, gx, z, du, dv, f, ray, yq, co, cg, gh, gw, a_mm, b_mm, lateral):  # pragma: no cover
    """Ideal bits of one camera's points sorted by lattice cell (gy, gx): [mask, extra flags,
    depth, offsets, luma, chroma], and the decoded (z, du, dv). a_mm, b_mm: lateral and depth
    bounds; ray: the length of the ray per unit depth (the depth step is 2 b / ray, so the error
    along the ray is at most b); lateral 0: no offset sent (decode on the cell's centre)."""
    out = np.zeros(6)
    probs = np.full(64 + 2, 1024, np.int64)
    freq = np.ones((12 + 8 + 3 * 6, 2 * R_MAX + 2), np.int64)
    occ = np.zeros((gh, gw), np.bool_)
    zimg = np.zeros((gh, gw))
    cimg = np.zeros((3, gh, gw))
    m = gy.shape[0]
    for i in range(m):
        occ[gy[i], gx[i]] = True
    zdec = np.zeros(m)
    udec = np.zeros(m)
    vdec = np.zeros(m)
    i = 0
    last_z = 0.0
    last_c = np.zeros(3)
    for y in range(gh):
        for x in range(gw):
            c = 0
            c |= 1 if x > 0 and occ[y, x - 1] else 0
            c |= 2 if y > 0 and occ[y - 1, x] else 0
            c |= 4 if x > 0 and y > 0 and occ[y - 1, x - 1] else 0
            c |= 8 if y > 0 and x + 1 < gw and occ[y - 1, x + 1] else 0
            c |= 16 if x > 1 and occ[y, x - 2] else 0
            c |= 32 if y > 1 and occ[y - 2, x] else 0
            bit = 1 if occ[y, x] else 0
            out[0] += _bin(probs, c, bit)
            if not bit:
                continue
            first = True
            while i < m and gy[i] == y and gx[i] == x:
                if not first or i + 1 < m:
                    more = 1 if i + 1 < m and gy[i + 1] == y and gx[i + 1] == x else 0
                    out[1] += _bin(probs, 64 + (0 if first else 1), more)
                # depth
                p, nn, act = _predict(zimg, occ, y, x, gw, last_z)
                if not first:
                    p, nn, act = zimg[y, x], 3, 0.0
                step = 2.0 * b_mm / 1000.0 / ray[i]
                ab = 0 if act < step else (1 if act < 4 * step else 2)
                r = int(np.round((z[i] - p) / step))
                out[2] += _sym(freq, min(nn, 3) * 3 + ab, r)
                zd = p + r * step
                zdec[i] = zd
                zimg[y, x] = zd
                last_z = zd
                # lateral offsets, pixels, step 2 a f / z
                if lateral:
                    q = 2.0 * a_mm / 1000.0 * f[i] / max(zd, 1e-3)
                    lv = min(7, int(1.4 / q))
                    ku = int(np.round(du[i] / q))
                    kv = int(np.round(dv[i] / q))
                    out[3] += _sym(freq, 12 + lv, ku) + _sym(freq, 12 + lv, kv)
                    udec[i] = ku * q
                    vdec[i] = kv * q
                # colour, MED per channel
                for ch in range(3):
                    val = yq[i] if ch == 0 else (co[i] if ch == 1 else cg[i])
                    pc, nc, ac = _predict(cimg[ch], occ, y, x, gw, last_c[ch])
                    if not first:
                        pc, nc, ac = cimg[ch, y, x], 2, 0.0
                    pr = int(np.round(pc))
                    ctx = 20 + ch * 6 + min(nc, 1) * 3 + (0 if ac < 1 else (1 if ac < 3 else 2))
                    cost = _sym(freq, ctx, int(val) - pr)
                    out[4 if ch == 0 else 5] += cost
                    cimg[ch, y, x] = val
                    last_c[ch] = val
                first = False
                i += 1
    return out, zdec, udec, vdec


def off_ray(xyz: np.ndarray, cam: np.ndarray, K: np.ndarray, T: np.ndarray) -> dict[str, np.ndarray]:
    """Per point: camera-frame depth z (m), image position (u, v) and focal length f (pixels)."""
    xc = np.einsum("mij,mj->mi", T[cam, :3, :3], xyz.astype(np.float64)) + T[cam, :3, 3]
    k = K[cam]
    z = xc[:, 2]
    u = (k[:, 0, 0] * xc[:, 0] + k[:, 0, 1] * xc[:, 1]) / z + k[:, 0, 2]
    v = k[:, 1, 1] * xc[:, 1] / z + k[:, 1, 2]
    ray = np.linalg.norm(xc, axis=1) / z
    return {"z": z, "u": u, "v": v, "f": k[:, 0, 0], "ray": ray}


def _decode(cam, K, T, z, u, v):
    """World points from (camera, u, v, z)."""
    k = K[cam]
    y = (v - k[:, 1, 2]) / k[:, 1, 1] * z
    x = ((u - k[:, 0, 2]) - k[:, 0, 1] * y / z) / k[:, 0, 0] * z
    xc = np.stack([x, y, z], 1) - T[cam, :3, 3]
    return np.einsum("mji,mj->mi", T[cam, :3, :3], xc)


def _ycocg(rgb: np.ndarray) -> tuple[np.ndarray, ...]:
    r, g, b = (rgb[:, i].astype(np.float64) for i in range(3))
    y = np.round((r + 2 * g + b) / 4 / 12).astype(np.int64)
    return y, np.round((r - b) / 16).astype(np.int64), np.round((g - (r + b) / 2) / 16).astype(np.int64)


def ray_rows(name, xyz, rgb, cam, K, T, wh, bounds=(1.5, 2.5, 4.0)) -> list[dict]:
    """The off-ray distances and one row of ideal bits per (bound, guarantee) for a cloud."""
    n = len(xyz)
    g = off_ray(xyz, cam, K, T)
    pu, pv = g["u"] - np.round(g["u"]), g["v"] - np.round(g["v"])
    px = np.hypot(pu, pv)
    mm = px * g["z"] / g["f"] * 1e3
    gx, gy = np.round(g["u"] / 2).astype(np.int64), np.round(g["v"] / 2).astype(np.int64)
    inside = (gx >= 0) & (gy >= 0) & (gx <= (wh[cam, 0] - 1) // 2) & (gy <= (wh[cam, 1] - 1) // 2)
    yq, co, cg = _ycocg(rgb)
    common = {"cloud": name, "points": n, "outside_image": int((~inside).sum()),
              "off_ray_px_p50_p95_max": [round(float(x), 3) for x in np.quantile(px, [0.5, 0.95, 1.0])],
              "off_ray_mm_p50_p95_max": [round(float(x), 3) for x in np.quantile(mm, [0.5, 0.95, 1.0])],
              "depth_m_median": round(float(np.median(g["z"])), 3)}  # fmt: skip
    rows = []
    for bound in bounds:
        for label, a, b, lateral in (("a = b = B / sqrt 3", bound / 3**0.5, bound / 3**0.5, 1),
                                     ("a = b = B", bound, bound, 1), ("centre rays, b = B", bound, bound, 0)):  # fmt: skip
            parts = np.zeros(6)
            err = np.zeros(n)
            for c in range(len(K)):
                sel = np.flatnonzero((cam == c) & inside)
                order = sel[np.lexsort((gx[sel], gy[sel]))]
                gh, gw = (wh[c, 1] - 1) // 2 + 1, (wh[c, 0] - 1) // 2 + 1
                du, dv = g["u"][order] - 2 * gx[order], g["v"][order] - 2 * gy[order]
                bits, zd, ud, vd = ray_code_bits(gy[order], gx[order], g["z"][order], du, dv, g["f"][order],
                                                 g["ray"][order], yq[order], co[order], cg[order], gh, gw, a, b, lateral)  # fmt: skip
                parts += bits
                dec = _decode(np.full(len(order), c), K, T, zd, 2 * gx[order] + ud, 2 * gy[order] + vd)
                err[order] = np.abs(dec - xyz[order]).max(1)
            total = parts.sum() / n
            rows.append({**common, "bound_mm": bound, "mode": label, "bits_per_point": round(float(total), 3),
                         "mask": round(parts[0] / n, 3), "extra_flags": round(parts[1] / n, 3),
                         "depth": round(parts[2] / n, 3), "offsets": round(parts[3] / n, 3),
                         "geometry": round(parts[:4].sum() / n, 3), "luma": round(parts[4] / n, 3),
                         "chroma": round(parts[5] / n, 3),
                         "position_error_mm_p95_max": [round(float(x) * 1e3, 3) for x in np.quantile(err[inside], [0.95, 1.0])],
                         "share_over_bound": round(float((err[inside] > bound / 1e3 + 1e-7).mean()), 4)})  # fmt: skip
    return rows


def _rig_clouds(data_dir: Path, work: Path) -> dict[str, tuple]:
    """name -> (xyz, rgb, camera, K (N,3,3), T_cam_world (N,4,4), (N,2) width-height): the clouds of
    ``live_codec_versions.fused_clouds`` and kinect3-room's first frame, with their rigs."""
    from fuseflow.fuse import fuse
    from fuseflow.fuse.presets import preset_config
    from fuseflow.io import open_recording, read_calibration
    from fuseflow.io.hocap import convert_hocap
    from fuseflow.synth import SimConfig, simulate_recording

    convert_hocap(data_dir / "hocap-8rs", work / "hocap8", with_extrinsics=True)
    simulate_recording(work / "sim8", SimConfig(cameras=8, frames=1, scene="studio", dynamic=True,
                                                resolution=(640, 480), seed=0, fps=10.0))  # fmt: skip
    simulate_recording(work / "poly8", SimConfig(cameras=8, frames=1, scene="polyroom", resolution=(640, 480),
                                                 seed=0, fps=10.0))  # fmt: skip
    k3 = data_dir / "kinect3-room"
    out = {}
    for name, folder in (("hocap8-200k", work / "hocap8"), ("sim8-200k", work / "sim8"),
                         ("polyroom8-200k", work / "poly8"), ("kinect3-room-frame0", k3)):  # fmt: skip
        rec = open_recording(folder)
        rig = rec.rig
        if folder == k3:
            rig = rig.with_extrinsics(read_calibration(k3 / "reference_calib.json").T_cam_world)
        c = fuse(rec[0], rig, preset_config("live", 200_000))
        out[name] = (c.xyz.numpy().astype(np.float32), c.rgb.numpy().astype(np.uint8), c.camera.numpy().astype(np.int64),
                     np.stack([k.K for k in rig]), np.stack([k.T_cam_world for k in rig]),
                     np.array([[k.width, k.height] for k in rig]))  # fmt: skip
    return out


def colour_coded_bits(xyz: np.ndarray, rgb: np.ndarray) -> float:
    """Bits a point of the default compact codec's colour stream (Morton order) of a cloud."""
    from fuseflow.live.codec import CompactParams, encode_compact

    msg = encode_compact(xyz, rgb, 0, 0.0, 0.0, CompactParams())
    return int.from_bytes(msg[56:60], "little") * 8 / len(xyz)


def run_codec_rays(data_dir: Path, log=print) -> dict:
    """Rows for hocap8, sim8, polyroom8 (200 k points) and kinect3-room's first frame."""
    rows = []
    load = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory(prefix="fuseflow-codec-") as tmp:
        clouds = _rig_clouds(Path(data_dir), Path(tmp))
    for name, (xyz, rgb, cam, K, T, wh) in clouds.items():
        morton = round(colour_coded_bits(xyz, rgb), 3)
        for r in ray_rows(name, xyz, rgb, cam, K, T, wh):
            r["colour_coded_morton"] = morton
            rows.append(r)
            log(f"{name} B={r['bound_mm']} {r['mode']}: {r['bits_per_point']} bits a point (geometry {r['geometry']}: "
                f"mask {r['mask']}, depth {r['depth']}, offsets {r['offsets']}; colour {r['luma']} + {r['chroma']} "
                f"against Morton {morton}); error p95/max {r['position_error_mm_p95_max']} mm; "
                f"off-ray mm {r['off_ray_mm_p50_p95_max']}")  # fmt: skip
    load.append(os.getloadavg()[0])
    return {"rows": rows, "meta": {"load_1min_start_end": [round(x, 1) for x in load]}}
