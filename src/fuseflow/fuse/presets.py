"""FUSE's named settings: the presets, the paper's ablations, the sensor noise tables, the
``auto`` preset's per-frame choice (``auto_config``). The ``NAME=VALUE`` form of a setting (the CLI's ``--set``) is read by
``fuseflow.cli.settings``. Measured numbers of each preset: docs/fuse.md.

* ``FuseConfig()`` / ``PRESETS["default"]``: the project's defaults (visibility-aware CVGC,
  a minimum joint weight for RPS candidates).
* ``PRESETS["paper"]``: the paper read literally (eq. 20-21 vote for every neighbour that has
  depth, eq. 27 filters on c only, no minimum joint weight, eq. 28 ranks by omega alone).
* ``PRESETS["fast"]``: ``cvgc.k_neighbours = 4``, ``ash.s0 = 6.3``: less time, fewer points.
* ``PRESETS["live"]``: the default with ``pixel_stride = 2``, ``ash.s0 = 1`` and no depth
  smoothing: candidates on every 2nd pixel of every 2nd row, nearly all of them kept; for full
  frames from ~8-camera rigs.
* ``PRESETS["dense"]``: the default with ``ash.s0 = 1``, 5x5 depth smoothing and
  ``mcm.max_missing = 6``: every pixel, nearly every candidate kept; the most complete cloud,
  about twice the default's points.
* ``PRESETS["auto"]`` (the CLI's default): ``dense``'s settings while the frame fits a time
  budget, a coarser grid otherwise (``auto_config``).
* Ablations exactly as the paper's Table VII: ``PRESETS["w/o CVGC"]``, ``["w/o MCM"]``,
  ``["w/o ASH"]``, ``["w/o RPS"]`` (each is the default with one component removed).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from fuseflow.errors import ValidationError
from fuseflow.fuse.config import FuseConfig
from fuseflow.geometry.noise import sensor_noise

__all__ = [
    "ABLATIONS",
    "AUTO_COARSE_STRIDE",
    "AUTO_SPACING_QUANTILE",
    "NOISE_SIGMA",
    "PRESETS",
    "auto_config",
    "preset",
    "preset_config",
]

#: Axial noise sigma(z) = a + b (z - z0)^2 (metres) by the simulator's sensor names, as plain
#: (a, b, z0) tuples of the one table, ``fuseflow.geometry.noise.SENSOR_NOISE``.
NOISE_SIGMA: dict[str, tuple[float, float, float]] = {
    "kinect": tuple(sensor_noise("kinect")),
    "realsense": tuple(sensor_noise("realsense")),
    "kinect2": tuple(sensor_noise("kinect2")),
}


_DEFAULT = FuseConfig()

#: Table VII ablations, each the default with one component removed.
ABLATIONS: dict[str, FuseConfig] = {
    "w/o CVGC": _DEFAULT.replace(cvgc={"enabled": False}),
    "w/o MCM": _DEFAULT.replace(mcm={"enabled": False}),
    "w/o ASH": _DEFAULT.replace(ash={"enabled": False}),
    "w/o RPS": _DEFAULT.replace(rps={"enabled": False}),
}

PRESETS: dict[str, FuseConfig] = {
    "default": _DEFAULT,
    "paper": _DEFAULT.replace(
        smoothing={"radius": 0},
        mcm={"max_missing": 0, "noise_aware": False},
        cvgc={"k_neighbours": 4, "visibility_aware": False, "multiview_mean": False},  # the paper fixes neither
        ash={"s0": 6.3},  # k_neighbours nor s0
        rps={"min_weight": 0.0, "range_priority": False, "lone_cell_mean": 0.0, "consensus": False},
    ),
    "fast": _DEFAULT.replace(cvgc={"k_neighbours": 4}, ash={"s0": 6.3}),
    # candidates on every 2nd pixel of every 2nd row (4x fewer); every stage costs per candidate,
    # so s0 is low enough that selection keeps nearly all of them
    # no depth smoothing: it costs `live` 14-25 % of its time (ICL, HO-Cap), which is its point
    "live": _DEFAULT.replace(pixel_stride=2, ash={"s0": 1.0}, mcm={"max_missing": 4}, smoothing={"radius": 0}),
    # completeness first: every pixel, nearly every candidate kept, 5x5 smoothing
    # an MCM window missing up to 6 of its 8 neighbours is measured on the ones it has: pixels
    # beside depth holes count (docs/fuse.md, Quality)
    "dense": _DEFAULT.replace(ash={"s0": 1.0}, smoothing={"radius": 2}, mcm={"max_missing": 6}),
    # the CLI's default: every pixel ("dense") while the frame's valid pixels fit a time budget or a
    # coarser grid would sample the surface more coarsely than 1 cm, the coarser grid otherwise (auto_config)
    "auto": _DEFAULT.replace(auto_grid=True),
    **ABLATIONS,
}

#: auto_config's time budget for fusing every pixel of a frame, in CPU milliseconds: 10 frames/s
#: (docs/live.md's rate for 8 x 640x480) on the 2 cores the speed tables are measured on.
AUTO_CORE_MS = 200.0
#: CPU milliseconds per million valid depth pixels of every-pixel fusion (``dense``'s settings)
#: on one core: the most measured on the real and simulated rigs, 249 on the simulated 8-ring
#: 320x240 (``fuseflow bench fuse-ratio REC --preset dense``; docs/fuse.md "Speed").
AUTO_CORE_MS_PER_MPX = 250.0
#: auto_config fuses every pixel of a frame with at most this many valid depth pixels (the
#: budget over the cost: 0.8 M; the simulated 4-ring 640x480 has 0.62 M, the 8-ring 1.23 M).
AUTO_MAX_EVERY_PIXEL = int(AUTO_CORE_MS / AUTO_CORE_MS_PER_MPX * 1e6)
#: The output resolution, metres: the coarse grid is taken only where it samples the surface at
#: least this finely. 1 cm: the scale the default s0 is set to (about a 1 cm TSDF's point count),
#: VoxelBlockGrid's voxel in the comparisons and the distance recall counts at.
AUTO_RESOLUTION = 0.01
#: The share of a frame's valid depth pixels the coarse grid must sample within AUTO_RESOLUTION
#: (``fuse.density.grid_spacing`` at this quantile): "nearly all of the seen surface".
AUTO_SPACING_QUANTILE = 0.9
#: The coarse grid's stride: ``live``'s grid, whose s0 and MCM window the coarse grid also takes.
AUTO_COARSE_STRIDE = PRESETS["live"].pixel_stride


def auto_config(
    cfg: FuseConfig, views: int, valid_pixels: int, coarse_spacing: Callable[[], float]
) -> tuple[FuseConfig, str]:
    """FuseConfig.auto_grid: the settings for a frame of ``views`` present views with
    ``valid_pixels`` valid depth pixels, on which the coarse grid (every AUTO_COARSE_STRIDE-th
    pixel of every AUTO_COARSE_STRIDE-th row) would place candidates ``coarse_spacing()`` metres
    apart on a facing surface at AUTO_SPACING_QUANTILE of the pixels (fuse.density.grid_spacing;
    called only above the time budget), and a one-line account of the choice.

    * ``valid_pixels`` <= AUTO_MAX_EVERY_PIXEL (every pixel fits the time budget): ``dense``'s
      settings on ``cfg``'s grid: every pixel, nearly every candidate kept.
    * above it, ``coarse_spacing()`` > AUTO_RESOLUTION (far surfaces: the coarse grid would sample
      them more coarsely than the output's 1 cm and lose surface): every pixel with ``dense``'s
      settings and the coarse grid's cheaper cross-view check (4 neighbour cameras, no multi-view
      mean), whatever the time.
    * else (8 x 640x480 at arm's or room range: 1.2-2.4 M) the coarse grid with s0 = 1
      (``live``'s), 5x5 smoothing, 4 neighbour cameras and no multi-view mean.
    Measured per rig in docs/fuse.md (Presets, Quality, Speed)."""
    what = f"{views} views, {valid_pixels / 1e6:.2f} M valid depth pixels"
    dense = PRESETS["dense"]
    every = cfg.replace(
        ash={"s0": dense.ash.s0},
        smoothing={"radius": dense.smoothing.radius},
        mcm={"max_missing": dense.mcm.max_missing},
    )
    if valid_pixels <= AUTO_MAX_EVERY_PIXEL:
        return every, f"auto: stride {every.pixel_stride}, s0 {every.ash.s0:g} ({what}: every pixel counts)"
    budget = f"more than {AUTO_MAX_EVERY_PIXEL / 1e6:.2f} M: every pixel would not fit 10 frames/s"
    gap = coarse_spacing()
    spacing = (
        f"stride {AUTO_COARSE_STRIDE} samples {AUTO_SPACING_QUANTILE:.0%} of the surface within {gap * 1000:.1f} mm"
    )
    cheap = {"k_neighbours": 4, "multiview_mean": False}
    if gap > AUTO_RESOLUTION:
        out = every.replace(cvgc=cheap)
        why = f"{spacing}, coarser than {AUTO_RESOLUTION * 1000:g} mm: every pixel, though {budget}"
        return out, f"auto: stride {out.pixel_stride}, s0 {out.ash.s0:g} ({what}; {why})"
    out = cfg.replace(
        pixel_stride=AUTO_COARSE_STRIDE,
        ash={"s0": PRESETS["live"].ash.s0},
        mcm={"max_missing": PRESETS["live"].mcm.max_missing},
        smoothing={"radius": 2},
        cvgc=cheap,
    )
    return out, f"auto: stride {out.pixel_stride}, s0 {out.ash.s0:g} ({what}; {budget}; {spacing})"


def preset_config(
    name: str, target_points: int | None = None, overrides: Mapping[str, Any] | None = None
) -> FuseConfig:
    """``PRESETS[name]``, with ``target_points`` when given and then ``overrides`` (keyword
    arguments of ``FuseConfig.replace``, e.g. ``{"rps": {"k_max": 2}}``): the `fuse` / `run`
    commands' --preset, --points and --set. ValidationError naming the presets for an unknown
    name, or the setting for a bad value."""
    if name not in PRESETS:
        raise ValidationError(f"no FUSE preset {name!r}; presets are {sorted(PRESETS)}")
    cfg = PRESETS[name] if target_points is None else PRESETS[name].replace(target_points=target_points)
    return cfg.replace(**overrides) if overrides else cfg


def preset(name: str) -> FuseConfig:
    """The named preset (``PRESETS`` keys); ValidationError listing the names otherwise."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ValidationError(f"no FUSE preset {name!r}; presets are {sorted(PRESETS)}") from None
