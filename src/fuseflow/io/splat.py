"""Fused clouds as 3D Gaussian splats: the PLY layout of 3D Gaussian Splatting (Kerbl et al.,
SIGGRAPH 2023) that splat viewers load (SuperSplat / PlayCanvas, Spark, the Unity and Unreal
splat players, the reference SIBR viewer).

One Gaussian per fused point, binary little-endian PLY, one ``vertex`` element with float32
properties, in this order: ``x y z`` (metres, output frame), ``nx ny nz`` (0: unused),
``f_dc_0 f_dc_1 f_dc_2`` (colour as the degree-0 spherical-harmonic coefficient,
``(rgb / 255 - 0.5) / SH_C0``), ``opacity`` (the logit of the opacity), ``scale_0 scale_1
scale_2`` (natural log of the standard deviation, metres; isotropic), ``rot_0 rot_1 rot_2
rot_3`` (unit quaternion w, x, y, z: the identity).

- **scale**: ``SCALE_SHARE`` (0.5) of the local sample spacing, the mean distance to the point's
  ``SPACING_NEIGHBOURS`` (3) nearest neighbours (a KD-tree), clipped to [``MIN_SIGMA_M``,
  ``MAX_SIGMA_M``]: neighbouring splats overlap at about one standard deviation, so a surface
  reads closed without blurring across gaps much wider than the sampling.
- **opacity**: FUSE's weight (eq. 22, in [0, 1]) clipped to [``MIN_OPACITY``, ``MAX_OPACITY``]:
  points the cameras agree on are opaque, doubtful ones faint.

``read_splat`` reads the file back into positions, colours and opacities (``FusedCloud`` with the
opacity as weight).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fuseflow.errors import FormatError
from fuseflow.io.files import write_bytes_atomic
from fuseflow.types import FusedCloud

__all__ = ["write_splat", "read_splat", "splat_fields", "SPLAT_PROPERTIES", "SH_C0"]

SH_C0 = 0.28209479177387814
"""The degree-0 real spherical harmonic, 1 / (2 sqrt(pi))."""
SPLAT_PROPERTIES = (
    "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
    "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
)  # fmt: skip
SPACING_NEIGHBOURS = 3
SCALE_SHARE = 0.5
MIN_SIGMA_M = 0.0005
MAX_SIGMA_M = 0.05
MIN_OPACITY = 0.05
MAX_OPACITY = 0.99


def splat_fields(cloud: FusedCloud) -> np.ndarray:
    """The structured (M,) float32 array of ``SPLAT_PROPERTIES`` for ``cloud`` (module docstring)."""
    from scipy.spatial import cKDTree

    c = cloud.numpy()
    xyz = np.asarray(c.xyz, np.float64).reshape(-1, 3)
    arr = np.zeros(len(xyz), dtype=[(name, "<f4") for name in SPLAT_PROPERTIES])
    if len(xyz) == 0:
        return arr
    k = min(SPACING_NEIGHBOURS, len(xyz) - 1)
    if k >= 1:
        dist = cKDTree(xyz).query(xyz, k=k + 1, workers=-1)[0][:, 1:]
        spacing = dist.mean(axis=1)
    else:
        spacing = np.full(len(xyz), MIN_SIGMA_M / SCALE_SHARE)
    sigma = np.clip(SCALE_SHARE * spacing, MIN_SIGMA_M, MAX_SIGMA_M)
    alpha = np.clip(np.asarray(c.weight, np.float64), MIN_OPACITY, MAX_OPACITY)
    dc = (np.asarray(c.rgb, np.float64) / 255.0 - 0.5) / SH_C0
    for a, name in enumerate("xyz"):
        arr[name] = xyz[:, a]
    for a in range(3):
        arr[f"f_dc_{a}"] = dc[:, a]
        arr[f"scale_{a}"] = np.log(sigma)
    arr["opacity"] = np.log(alpha / (1.0 - alpha))
    arr["rot_0"] = 1.0
    return arr


def write_splat(path: str | Path, cloud: FusedCloud) -> Path:
    """Write ``cloud`` as a 3D Gaussian splat PLY (module docstring), atomically."""
    arr = splat_fields(cloud)
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment fuseflow gaussian splats, metres\n"
        f"element vertex {len(arr)}\n" + "".join(f"property float {n}\n" for n in SPLAT_PROPERTIES) + "end_header\n"
    )
    return write_bytes_atomic(Path(path), header.encode("ascii"), arr.tobytes())


def read_splat(path: str | Path) -> FusedCloud:
    """A splat PLY as a FusedCloud: positions, colours from f_dc (clipped to 0-255), the
    opacity (sigmoid of the stored logit) as weight; FormatError when the layout differs."""
    from fuseflow.io.ply import read_ply_columns

    path = Path(path)
    cols = read_ply_columns(path)
    missing = [n for n in SPLAT_PROPERTIES if n not in cols]
    if missing:
        raise FormatError(f"{path}: not a Gaussian splat PLY (no {', '.join(missing)})")
    xyz = np.stack([cols["x"], cols["y"], cols["z"]], axis=1)
    rgb = np.clip(np.stack([cols[f"f_dc_{a}"] for a in range(3)], axis=1) * SH_C0 + 0.5, 0, 1) * 255
    alpha = 1.0 / (1.0 + np.exp(-np.asarray(cols["opacity"], np.float64)))
    return FusedCloud.from_numpy(xyz, np.rint(rgb), alpha, np.full(len(xyz), -1))
