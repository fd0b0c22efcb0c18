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
from typing import NamedTuple

import numpy as np

from fuseflow.synth.config import AxialNoise, SensorModel, SimConfig, sigma_terms

__all__ = [
    "sigma_z", "sigma_terms", "axial_sigma", "quantization_step", "apply_depth_noise", "apply_depth_noise_ref", "DepthNoiseParams",
    "NoiseDraws", "depth_noise_params",
]  # fmt: skip


def sigma_z(m: AxialNoise, fb: float, z, theta):
    """Axial noise std (metres) of model ``m`` at depth z (m) and incidence angle theta (rad);
    fb = focal_px * baseline_m (px m), read by the stereo term only. numpy arrays or scalars."""
    return sigma_terms(m.a, m.b, m.z0, m.c, m.stereo_rms, fb, z, theta)


def axial_sigma(sensor: SensorModel, z: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Published total axial std (metres) at depth z (m) and incidence angle theta (rad)."""
    if sensor.kind == "none":  # no sensor model at all (no baseline either)
        return np.zeros_like(z)
    return sigma_z(sensor.axial, sensor.focal_px * sensor.baseline_m, z, theta)


class DepthNoiseParams(NamedTuple):
    """Scalars of the per-pixel depth-noise kernel, built by ``depth_noise_params``."""

    axial_model: AxialNoise
    """Coefficients of sigma_z."""
    flying: bool
    """SimConfig.flying_pixels."""
    fly_rate: float
    """SensorModel.flying_pixel_rate."""
    axial: bool
    """SimConfig.axial_noise."""
    quantize: bool
    """SimConfig.quantization."""
    fb: float
    """focal_px * baseline_m (px m): z = f B / disparity."""
    q_step: float
    """Disparity quantum (px), SensorModel.disparity_subpixel."""
    graze: bool
    """SimConfig.grazing_dropout."""
    graze_lo: float
    """Incidence angle (rad) where grazing dropout starts (grazing_max_deg - 10)."""
    range_drop: bool
    """SimConfig.range_dropout."""
    z_min: float
    z_max: float
    """SensorModel.depth_range (m)."""
    rand_drop: bool
    """SimConfig.random_dropout."""
    drop_rate: float
    """SensorModel.dropout_rate."""
    depth_scale: np.float32
    """Output units per metre (SimConfig.depth_scale)."""


def depth_noise_params(cfg: SimConfig) -> DepthNoiseParams:
    """The kernel's parameters from ``cfg`` and its sensor preset (the one place they are read)."""
    sensor = cfg.sensor
    return DepthNoiseParams(
        axial_model=AxialNoise(*(float(v) for v in sensor.axial)),
        flying=bool(cfg.flying_pixels),
        fly_rate=float(sensor.flying_pixel_rate),
        axial=bool(cfg.axial_noise),
        quantize=bool(cfg.quantization),
        fb=float(sensor.focal_px * sensor.baseline_m),
        q_step=float(sensor.disparity_subpixel),
        graze=bool(cfg.grazing_dropout),
        graze_lo=math.radians(sensor.grazing_max_deg - 10.0),
        range_drop=bool(cfg.range_dropout),
        z_min=float(sensor.depth_range[0]),
        z_max=float(sensor.depth_range[1]),
        rand_drop=bool(cfg.random_dropout),
        drop_rate=float(sensor.dropout_rate),
        depth_scale=np.float32(cfg.depth_scale),
    )


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


class NoiseDraws(NamedTuple):
    """Every random array of one frame's depth noise, (N, H, W) float32 each."""

    g_u: np.ndarray
    """Standard normals: lateral displacement in u."""
    g_v: np.ndarray
    """Standard normals: lateral displacement in v."""
    u_fly: np.ndarray
    """Uniforms: does an edge pixel fly."""
    u_mix: np.ndarray
    """Uniforms: where between the two sides a flying pixel lands."""
    g_axial: np.ndarray
    """Standard normals: axial noise."""
    u_graze: np.ndarray
    """Uniforms: grazing-angle dropout."""
    u_drop: np.ndarray
    """Uniforms: random dropout."""


def _draws(shape: tuple[int, ...], rng: np.random.Generator) -> NoiseDraws:
    """Drawn in a fixed order whatever the switches (turning one effect off does not change the
    draws of the others)."""
    g_u = rng.standard_normal(shape, dtype=np.float32)
    g_v = rng.standard_normal(shape, dtype=np.float32)
    u_fly = rng.random(shape, dtype=np.float32)
    u_mix = rng.random(shape, dtype=np.float32)
    g_axial = rng.standard_normal(shape, dtype=np.float32)
    u_graze = rng.random(shape, dtype=np.float32)
    u_drop = rng.random(shape, dtype=np.float32)
    return NoiseDraws(g_u, g_v, u_fly, u_mix, g_axial, u_graze, u_drop)


def apply_depth_noise(cfg: SimConfig, z_clean: np.ndarray, theta: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Noisy depth from noise-free depth (numba kernels; ``apply_depth_noise_ref`` is the numpy twin).

    Args:
        z_clean: (N, H, W) float32 metres, 0 or inf where no surface.
        theta: (N, H, W) float32 incidence angle in radians (0 = surface faces the camera).
        rng: the frame's generator.
    Returns: (N, H, W) float32 metres, 0 = no measurement.
    """
    from fuseflow.synth.numba_kernels import depth_noise_nb, lateral_nb

    sensor = cfg.sensor
    z = np.where(np.isfinite(z_clean), z_clean, 0.0).astype(np.float32)
    if sensor.kind == "none":
        return z
    th = np.where(z > 0, theta, 0.0).astype(np.float32)
    r = _draws(z.shape, rng)
    if cfg.lateral_noise:
        z, th = lateral_nb(z, th, r.g_u, r.g_v, float(sensor.lateral_sigma_px))
    return depth_noise_nb(z, th, r, depth_noise_params(cfg))


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
        du = np.rint(r.g_u * sl).astype(np.int64)
        dv = np.rint(r.g_v * sl).astype(np.int64)
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
        fly = edge & (r.u_fly < sensor.flying_pixel_rate)
        z = np.where(fly, zmin + r.u_mix * (zmax - zmin), z).astype(np.float32)
    if cfg.axial_noise:
        sigma = axial_sigma(sensor, z, th)
        if cfg.quantization:
            sigma = np.sqrt(np.maximum(sigma**2 - quantization_step(sensor, z) ** 2 / 12.0, 0.0))
        z = np.where(z > 0, z + sigma * r.g_axial, 0.0).astype(np.float32)
    if cfg.quantization:
        z = _quantize(sensor, z)
    drop = z <= 0
    if cfg.grazing_dropout:
        lo = math.radians(sensor.grazing_max_deg - 10.0)
        p = np.clip((th - lo) / math.radians(10.0), 0.0, 1.0)
        drop |= r.u_graze < p
    if cfg.range_dropout:
        drop |= (z < sensor.depth_range[0]) | (z > sensor.depth_range[1])
    if cfg.random_dropout:
        drop |= r.u_drop < sensor.dropout_rate
    z = np.where(drop, 0.0, z).astype(np.float32)
    # the sensor reports whole depth units (1 mm at depth_scale 1000)
    return np.rint(z * np.float32(cfg.depth_scale)) / np.float32(cfg.depth_scale)
