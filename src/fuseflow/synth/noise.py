"""Depth sensor noise models. Pure numpy functions over (N, H, W) arrays.

Sources (docs/simulator.md has the full derivation):

* Axial noise, structured light (Kinect v1 class): Nguyen, Izadi, Lovell, "Modeling Kinect
  sensor noise for improved 3D reconstruction and tracking", 3DIMPVT 2012:
  sigma_z(z, theta) = 0.0012 + 0.0019 (z - 0.4)^2 + 0.0001 / sqrt(z) * theta^2 / (pi/2 - theta)^2  [m]
* Axial noise, active stereo (RealSense D400 class): Grunnet-Jepsen et al., "Tuning depth
  cameras for best performance" (Intel, 2018): RMS = z^2 * subpixel / (f * baseline).
* Lateral noise: Nguyen et al. 2012, sigma_L = 0.8 + 0.035 theta / (pi/2 - theta) pixels.
* Disparity quantization: z = f b / d with d in 1/8 px (Kinect v1, Khoshelham & Elberink 2012)
  or 1/32 px (D400). The published sigma formulas were *measured* on quantized sensor output, so
  the Gaussian part is reduced to sigma_g^2 = sigma^2 - dz^2 / 12 when quantization is on (dz the
  local depth step): the total spread then follows the published formula.
* Flying (mixed) pixels at depth discontinuities, missing depth at grazing incidence and out of
  range, random dropouts: see the SensorModel field docs for the numbers.
"""

from __future__ import annotations

import math

import numpy as np

from fuseflow.synth.config import SensorModel, SimConfig

__all__ = ["axial_sigma", "quantization_step", "apply_depth_noise", "apply_depth_noise_ref"]


def axial_sigma(sensor: SensorModel, z: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Published total axial std (metres) at depth z (m) and incidence angle theta (rad)."""
    if sensor.kind == "structured-light":
        th = np.minimum(theta, math.radians(89.0))
        return (
            0.0012 + 0.0019 * (z - 0.4) ** 2 + 0.0001 / np.sqrt(np.maximum(z, 1e-3)) * th**2 / (math.pi / 2 - th) ** 2
        )
    if sensor.kind == "stereo":
        return z**2 * sensor.stereo_subpixel_rms / (sensor.focal_px * sensor.baseline_m)
    return np.zeros_like(z)


def quantization_step(sensor: SensorModel, z: np.ndarray) -> np.ndarray:
    """Depth step (m) of one disparity quantum at depth z: z^2 q / (f b)."""
    if sensor.baseline_m <= 0 or sensor.disparity_subpixel <= 0:
        return np.zeros_like(z)
    return z**2 * sensor.disparity_subpixel / (sensor.focal_px * sensor.baseline_m)


def _quantize(sensor: SensorModel, z: np.ndarray) -> np.ndarray:
    fb = sensor.focal_px * sensor.baseline_m
    q = sensor.disparity_subpixel
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.round(fb / z / q) * q
        out = np.where((z > 0) & (d > 0), fb / d, 0.0)
    return out.astype(np.float32)


def _draws(shape: tuple[int, ...], rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Every random array of one frame's depth noise, drawn in a fixed order whatever the switches
    (turning one effect off does not change the draws of the others)."""
    return {
        "g_u": rng.standard_normal(shape, dtype=np.float32),
        "g_v": rng.standard_normal(shape, dtype=np.float32),
        "u_fly": rng.random(shape, dtype=np.float32),
        "u_mix": rng.random(shape, dtype=np.float32),
        "g_axial": rng.standard_normal(shape, dtype=np.float32),
        "u_graze": rng.random(shape, dtype=np.float32),
        "u_drop": rng.random(shape, dtype=np.float32),
    }


def apply_depth_noise(cfg: SimConfig, z_clean: np.ndarray, theta: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Noisy depth from noise-free depth (numba kernels; ``apply_depth_noise_ref`` is the numpy twin).

    Args:
        z_clean: (N, H, W) float32 metres, 0 or inf where no surface.
        theta: (N, H, W) float32 incidence angle in radians (0 = surface faces the camera).
        rng: the frame's generator.
    Returns: (N, H, W) float32 metres, 0 = no measurement.
    """
    from fuseflow.synth._kernels import depth_noise_nb, lateral_nb

    sensor = cfg.sensor
    z = np.where(np.isfinite(z_clean), z_clean, 0.0).astype(np.float32)
    if sensor.kind == "none":
        return z
    th = np.where(z > 0, theta, 0.0).astype(np.float32)
    r = _draws(z.shape, rng)
    if cfg.lateral_noise:
        z, th = lateral_nb(z, th, r["g_u"], r["g_v"], float(sensor.lateral_sigma_px))
    return depth_noise_nb(
        z, th, r["u_fly"], r["u_mix"], r["g_axial"], r["u_graze"], r["u_drop"],
        {"structured-light": 1, "stereo": 2}.get(sensor.kind, 0), cfg.flying_pixels, float(sensor.flying_pixel_rate),
        cfg.axial_noise, cfg.quantization, float(sensor.focal_px * sensor.baseline_m), float(sensor.disparity_subpixel),
        float(sensor.stereo_subpixel_rms), cfg.grazing_dropout, math.radians(sensor.grazing_max_deg - 10.0),
        cfg.range_dropout, float(sensor.depth_range[0]), float(sensor.depth_range[1]), cfg.random_dropout,
        float(sensor.dropout_rate), np.float32(cfg.depth_scale),
    )  # fmt: skip


def apply_depth_noise_ref(
    cfg: SimConfig, z_clean: np.ndarray, theta: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """Plain numpy reference of ``apply_depth_noise`` (same draws, same result up to float rounding)."""
    sensor = cfg.sensor
    z = np.where(np.isfinite(z_clean), z_clean, 0.0).astype(np.float32)
    if sensor.kind == "none":
        return z
    N, H, W = z.shape
    th = np.where(z > 0, theta, 0.0).astype(np.float32)
    r = _draws(z.shape, rng)
    if cfg.lateral_noise:
        # each pixel reads the surface at a pixel displaced by N(0, sigma_L) (rounded)
        sl = sensor.lateral_sigma_px + 0.035 * np.minimum(th, 1.5) / (math.pi / 2 - np.minimum(th, 1.5))
        du = np.rint(r["g_u"] * sl).astype(np.int64)
        dv = np.rint(r["g_v"] * sl).astype(np.int64)
        uu = np.clip(np.arange(W)[None, None, :] + du, 0, W - 1)
        vv = np.clip(np.arange(H)[None, :, None] + dv, 0, H - 1)
        nn = np.arange(N)[:, None, None]
        z = z[nn, vv, uu]
        th = th[nn, vv, uu]
    if cfg.flying_pixels:
        # discontinuity: the 3x3 neighbourhood spans more than 5 % of the depth (or a hole)
        zp = np.pad(z, ((0, 0), (1, 1), (1, 1)), mode="edge")
        win = np.stack([zp[:, 1 + dy : 1 + dy + H, 1 + dx : 1 + dx + W] for dy in (-1, 0, 1) for dx in (-1, 0, 1)])
        valid = win > 0
        zmax = np.where(valid, win, 0).max(0)
        zmin = np.where(valid, win, np.inf).min(0)
        edge = (z > 0) & (zmax - zmin > 0.05 * z) & np.all(valid, axis=0)
        fly = edge & (r["u_fly"] < sensor.flying_pixel_rate)
        z = np.where(fly, zmin + r["u_mix"] * (zmax - zmin), z).astype(np.float32)
    if cfg.axial_noise:
        sigma = axial_sigma(sensor, z, th)
        if cfg.quantization:
            sigma = np.sqrt(np.maximum(sigma**2 - quantization_step(sensor, z) ** 2 / 12.0, 0.0))
        z = np.where(z > 0, z + sigma * r["g_axial"], 0.0).astype(np.float32)
    if cfg.quantization:
        z = _quantize(sensor, z)
    drop = z <= 0
    if cfg.grazing_dropout:
        lo = math.radians(sensor.grazing_max_deg - 10.0)
        p = np.clip((th - lo) / math.radians(10.0), 0.0, 1.0)
        drop |= r["u_graze"] < p
    if cfg.range_dropout:
        drop |= (z < sensor.depth_range[0]) | (z > sensor.depth_range[1])
    if cfg.random_dropout:
        drop |= r["u_drop"] < sensor.dropout_rate
    z = np.where(drop, 0.0, z).astype(np.float32)
    # the sensor reports whole depth units (1 mm at depth_scale 1000)
    return np.rint(z * np.float32(cfg.depth_scale)) / np.float32(cfg.depth_scale)
