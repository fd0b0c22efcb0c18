"""Numba kernels of the simulator's two per-pixel / per-sample loops (compiled on first use,
cached on disk). Each has a plain numpy twin in the calling module's docstring terms; tests
compare them."""

from __future__ import annotations

import warnings

import numba
import numpy as np

from fuseflow.io.numba_cache import use_usable_cache
from fuseflow.synth.config import sigma_terms

# numba warns once per process that the installed TBB is too old and falls back to another
# threading layer; that is not the user's concern.
warnings.filterwarnings("ignore", message="The TBB threading layer requires", category=numba.NumbaWarning)
use_usable_cache(__file__)  # before any @njit(cache=True) below


@numba.njit(parallel=True, cache=True, fastmath=False)
def sample_texture_nb(textures, tex_id, uv_px):  # pragma: no cover - compiled
    """Bilinear, wrap-around: textures (K, S, S, 3) uint8; uv_px (M, 2) float32 texel coords."""
    M = uv_px.shape[0]
    out = np.empty((M, 3), np.float32)
    for m in numba.prange(M):
        r, g, b = _bilinear3(textures, tex_id[m], uv_px[m, 0] - 0.5, uv_px[m, 1] - 0.5)
        out[m, 0] = r / 255.0
        out[m, 1] = g / 255.0
        out[m, 2] = b / 255.0
    return out


@numba.njit(parallel=True, cache=True)
def visible_nb(points, normals, T_cam_world, K, centres, depth_gt, tol_m, tol_rel):  # pragma: no cover
    """(S,) bool: seen by a camera whose depth agrees within tol_m + tol_rel z (see visible_mask)."""
    S = points.shape[0]
    N, H, W = depth_gt.shape
    out = np.zeros(S, np.bool_)
    for s in numba.prange(S):
        px, py, pz = points[s, 0], points[s, 1], points[s, 2]
        for i in range(N):
            if (centres[i, 0] - px) * normals[s, 0] + (centres[i, 1] - py) * normals[s, 1] + (
                centres[i, 2] - pz
            ) * normals[s, 2] <= 0:
                continue
            T = T_cam_world[i]
            x = T[0, 0] * px + T[0, 1] * py + T[0, 2] * pz + T[0, 3]
            y = T[1, 0] * px + T[1, 1] * py + T[1, 2] * pz + T[1, 3]
            z = T[2, 0] * px + T[2, 1] * py + T[2, 2] * pz + T[2, 3]
            if z <= 1e-6:
                continue
            u = np.rint((K[i, 0, 0] * x + K[i, 0, 1] * y) / z + K[i, 0, 2])
            v = np.rint(K[i, 1, 1] * y / z + K[i, 1, 2])
            if u < 0 or u >= W or v < 0 or v >= H:
                continue
            d = depth_gt[i, int(v), int(u)]
            if d > 0 and abs(d - z) < tol_m + tol_rel * z:
                out[s] = True
                break
    return out


@numba.njit(inline="always", cache=True)
def _bilinear3(textures, ti, px, py):  # pragma: no cover - compiled
    """Bilinear, wrap-around RGB texel values (0..255) of texture ti at texel coordinates (px, py)."""
    S = textures.shape[1]
    fx0 = np.floor(px)
    fy0 = np.floor(py)
    fx = px - fx0
    fy = py - fy0
    x0 = int(fx0) % S
    y0 = int(fy0) % S
    x1 = (x0 + 1) % S
    y1 = (y0 + 1) % S
    w00 = (1 - fx) * (1 - fy)
    w01 = fx * (1 - fy)
    w10 = (1 - fx) * fy
    w11 = fx * fy
    t = textures[ti]
    r = t[y0, x0, 0] * w00 + t[y0, x1, 0] * w01 + t[y1, x0, 0] * w10 + t[y1, x1, 0] * w11
    g = t[y0, x0, 1] * w00 + t[y0, x1, 1] * w01 + t[y1, x0, 1] * w10 + t[y1, x1, 1] * w11
    b = t[y0, x0, 2] * w00 + t[y0, x1, 2] * w01 + t[y1, x0, 2] * w10 + t[y1, x1, 2] * w11
    return r, g, b


@numba.njit(parallel=True, cache=True)
def shade_nb(t_hit, prim, bary, normals, rays, tri_uv, tex, tint, pid, textures, lights, light_w, color_noise,
             prm):  # pragma: no cover - compiled  # fmt: skip
    """Per pixel: noise-free depth, incidence angle, part id and Lambert-shaded texture colour.

    t_hit (N, H, W) float32 (inf = miss); prim (N, H, W) uint32; bary (N, H, W, 2); normals
    (N, H, W, 3) geometric normals; rays (N, H, W, 6); tri_uv (T, 3, 2) metres; tex (T,) int;
    tint (T, 3); pid (T,) int; textures (K, S, S, 3) uint8 spanning S / prm.texels_per_m metres;
    lights (L, 3) unit; light_w (L,); color_noise (N, H, W, 3) float32 standard normals, used
    when prm.noise_std > 0; prm: ``simulator.ShadeParams`` (second texture layer, blend
    contrast, ambient term, colour noise std).
    Returns depth_gt (0 = miss), theta (rad), part (-1 = miss), colour uint8 (N, H, W, 3).
    The numpy twin is ``fuseflow.synth.simulator._shade_ref``.
    """
    N, H, W = t_hit.shape
    scale = prm.texels_per_m
    l2c, l2s, l2k, l2u, l2v = prm.l2_cos, prm.l2_sin, prm.l2_inv_scale, prm.l2_shift_u, prm.l2_shift_v
    contrast, ambient, noise_std = prm.contrast, prm.ambient, prm.noise_std
    depth = np.zeros((N, H, W), np.float32)
    theta = np.zeros((N, H, W), np.float32)
    part = np.full((N, H, W), -1, np.int32)
    color = np.zeros((N, H, W, 3), np.uint8)
    for n in numba.prange(N):
        for y in range(H):
            for x in range(W):
                z = t_hit[n, y, x]
                r0 = 0.0
                r1 = 0.0
                r2 = 0.0
                if np.isfinite(z):
                    depth[n, y, x] = z
                    k = prim[n, y, x]
                    part[n, y, x] = pid[k]
                    dx, dy, dz = rays[n, y, x, 3], rays[n, y, x, 4], rays[n, y, x, 5]
                    dl = np.sqrt(dx * dx + dy * dy + dz * dz)
                    nx, ny, nz = normals[n, y, x, 0], normals[n, y, x, 1], normals[n, y, x, 2]
                    c = -(nx * dx + ny * dy + nz * dz) / dl
                    if c < 0:  # two-sided: the normal facing the camera
                        nx, ny, nz, c = -nx, -ny, -nz, -c
                    theta[n, y, x] = np.arccos(min(c, np.float32(1.0)))
                    b1, b2 = bary[n, y, x, 0], bary[n, y, x, 1]
                    b0 = 1 - b1 - b2
                    um = b0 * tri_uv[k, 0, 0] + b1 * tri_uv[k, 1, 0] + b2 * tri_uv[k, 2, 0]
                    vm = b0 * tri_uv[k, 0, 1] + b1 * tri_uv[k, 1, 1] + b2 * tri_uv[k, 2, 1]
                    lam = 0.0
                    for li in range(lights.shape[0]):
                        lam += max(nx * lights[li, 0] + ny * lights[li, 1] + nz * lights[li, 2], 0.0) * light_w[li]
                    shade = ambient + (1 - ambient) * lam
                    ti = tex[k]
                    ti2 = (ti + 1) % textures.shape[0]
                    u2 = (l2c * um - l2s * vm) * l2k + l2u
                    v2 = (l2s * um + l2c * vm) * l2k + l2v
                    a0, a1, a2 = _bilinear3(textures, ti, um * scale - 0.5, vm * scale - 0.5)
                    c0, c1, c2 = _bilinear3(textures, ti2, u2 * scale - 0.5, v2 * scale - 0.5)
                    r0, r1, r2 = a0 + c0, a1 + c1, a2 + c2
                    # blend of the two layers, contrast restored (texture.surface_albedo_ref)
                    r0 = min(max(0.5 + contrast * (r0 / 510.0 - 0.5), 0.0), 1.0) * 255.0 * tint[k, 0] * shade
                    r1 = min(max(0.5 + contrast * (r1 / 510.0 - 0.5), 0.0), 1.0) * 255.0 * tint[k, 1] * shade
                    r2 = min(max(0.5 + contrast * (r2 / 510.0 - 0.5), 0.0), 1.0) * 255.0 * tint[k, 2] * shade
                for ch in range(3):
                    val = r0 if ch == 0 else (r1 if ch == 1 else r2)
                    if noise_std > 0:
                        val += color_noise[n, y, x, ch] * noise_std
                    color[n, y, x, ch] = np.uint8(min(max(np.rint(val), 0.0), 255.0))
    return depth, theta, part, color


@numba.njit(parallel=True, cache=True)
def lateral_nb(z, th, g_u, g_v, sigma0_px):  # pragma: no cover - compiled
    """Lateral noise: each pixel reads depth and angle at a pixel displaced by
    rint(N(0, sigma_L)) in u and v, sigma_L = sigma0 + 0.035 theta / (pi/2 - theta) (Nguyen 2012)."""
    N, H, W = z.shape
    zo = np.empty_like(z)
    tho = np.empty_like(th)
    for n in numba.prange(N):
        for y in range(H):
            for x in range(W):
                t = min(th[n, y, x], np.float32(1.5))
                sl = sigma0_px + 0.035 * t / (np.pi / 2 - t)
                xs = min(max(x + int(np.rint(g_u[n, y, x] * sl)), 0), W - 1)
                ys = min(max(y + int(np.rint(g_v[n, y, x] * sl)), 0), H - 1)
                zo[n, y, x] = z[n, ys, xs]
                tho[n, y, x] = th[n, ys, xs]
    return zo, tho


_sigma_nb = numba.njit(inline="always", cache=True)(sigma_terms)


@numba.njit(parallel=True, cache=True)
def depth_noise_nb(z, th, r, prm):  # pragma: no cover - compiled
    """Flying pixels, axial noise, disparity quantization, dropouts and output units, per pixel.

    z, th (N, H, W) float32 depth (m) and incidence angle (rad); r: ``noise.NoiseDraws``;
    prm: ``noise.DepthNoiseParams`` (axial sigma: ``noise.sigma_terms`` of prm.axial_model,
    fb = focal_px * baseline_m, q_step = disparity quantum in px). Mirrors
    ``fuseflow.synth.noise.apply_depth_noise_ref``.
    """
    u_fly, u_mix, g_axial, u_graze, u_drop = r.u_fly, r.u_mix, r.g_axial, r.u_graze, r.u_drop
    # scalars only inside the parallel loop (numba's parfor lowering fails on a tuple live in it)
    a, b, z0, c, s = prm.axial_model
    fb, q_step, depth_scale = prm.fb, prm.q_step, prm.depth_scale
    flying, fly_rate, axial, quantize = prm.flying, prm.fly_rate, prm.axial, prm.quantize
    graze, graze_lo, range_drop, z_min, z_max = prm.graze, prm.graze_lo, prm.range_drop, prm.z_min, prm.z_max
    rand_drop, drop_rate = prm.rand_drop, prm.drop_rate
    N, H, W = z.shape
    out = np.zeros_like(z)
    for n in numba.prange(N):
        for y in range(H):
            for x in range(W):
                zz = z[n, y, x]
                if zz <= 0:
                    continue
                if flying:
                    zmin = np.inf
                    zmax = 0.0
                    full = True
                    for dy in range(-1, 2):
                        for dx in range(-1, 2):
                            w = z[n, min(max(y + dy, 0), H - 1), min(max(x + dx, 0), W - 1)]
                            if w > 0:
                                zmin = min(zmin, w)
                                zmax = max(zmax, w)
                            else:
                                full = False
                    if full and zmax - zmin > 0.05 * zz and u_fly[n, y, x] < fly_rate:
                        zz = np.float32(zmin + u_mix[n, y, x] * (zmax - zmin))
                t = th[n, y, x]
                if axial:
                    sig = _sigma_nb(a, b, z0, c, s, fb, zz, t)  # noise.sigma_terms
                    if quantize and q_step > 0:
                        dz = zz * zz * q_step / fb
                        sig = np.sqrt(max(sig * sig - dz * dz / 12.0, 0.0))
                    zz = np.float32(zz + sig * g_axial[n, y, x])
                if quantize and q_step > 0 and zz > 0:
                    d = np.rint(fb / zz / q_step) * q_step
                    zz = np.float32(fb / d) if d > 0 else np.float32(0.0)
                drop = zz <= 0
                if graze:
                    p = min(max((t - graze_lo) / np.radians(10.0), 0.0), 1.0)
                    drop = drop or u_graze[n, y, x] < p
                if range_drop:
                    drop = drop or zz < z_min or zz > z_max
                if rand_drop:
                    drop = drop or u_drop[n, y, x] < drop_rate
                if not drop:
                    out[n, y, x] = np.rint(zz * depth_scale) / depth_scale
    return out
