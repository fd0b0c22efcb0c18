"""FuseConfig: every constant of FUSE (paper III-C), its source, and the named presets.

The paper fixes only tau = 0.05 (eq. 21). Every other value below is a project default with
its derivation written next to it (docs/design.md section 2). Measured numbers of each preset and
switch: docs/fuse.md. Presets:

* ``FuseConfig()`` / ``PRESETS["default"]``: the project's defaults (visibility-aware CVGC,
  a minimum joint weight for RPS candidates).
* ``PRESETS["paper"]``: the paper read literally (eq. 20-21 vote for every neighbour that has
  depth, eq. 27 filters on c only, no minimum joint weight, eq. 28 ranks by omega alone).
* ``PRESETS["quality"]``: the same as the default (an older name, kept).
* ``PRESETS["fast"]``: ``k_neighbours = 4``, ``s0 = 6.3``: less time, fewer points.
* ``PRESETS["live"]``: the default with ``pixel_stride = 2``, ``s0 = 1`` and no depth smoothing: candidates on every
  2nd pixel of every 2nd row, nearly all of them kept; for full frames from ~8-camera rigs.
* ``PRESETS["dense"]``: the default with ``s0 = 1`` and 5x5 depth smoothing: every pixel, nearly
  every candidate kept; the most complete cloud, about twice the default's points.
* Ablations exactly as the paper's Table VII: ``PRESETS["w/o CVGC"]``, ``["w/o MCM"]``,
  ``["w/o ASH"]``, ``["w/o RPS"]`` (each is the default with one component removed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Literal

from fuseflow.errors import ValidationError
from fuseflow.geometry.noise import DEFAULT_SENSOR, SENSOR_NOISE, sensor_noise

__all__ = ["FuseConfig", "PRESETS", "ABLATIONS", "NOISE_SIGMA", "preset", "auto_config"]

Backend = Literal["auto", "torch", "numba"]

# --- MCM defaults (eq. 16-18), derived from the sensor noise model --------------------------
# Kinect-class structured-light noise: sigma(z) = 1.2 mm + 1.9 mm * (z - 0.4)^2 (z in metres),
# i.e. a relative noise sigma/z of about 0.3 % at 1.5-2.5 m, focal length f ~ 525 px at 640x480.
#
# Smooth surface at 45 degrees, depth z: neighbouring pixels differ by ~ z / f (ray spacing
# z / f, slope tan 45 = 1), so the central-difference gradient gives g ~ 1 / f = 0.0019, plus
# noise sqrt(2) * 0.003 / 2 per axis -> g ~ 0.004-0.005 in total. The 3x3 variance of a plane
# at 45 degrees is (2/3) (z/f)^2 -> v = 2.4e-6, plus the noise (0.003)^2 = 9e-6 -> v ~ 1.2e-5.
# Requirement "c > 0.8":  alpha * 0.005 + beta * 1.2e-5 < -ln 0.8 = 0.223.
#
# Depth edge with a 5 % jump: central difference across it gives g = 0.05 / 2 = 0.025; a 3x3
# window holding 3 (or 6) pixels of the far side has variance (1/3)(2/3)(0.05 z)^2, so
# v = 5.6e-4. Requirement "c < 0.05": alpha * 0.025 + beta * 5.6e-4 > -ln 0.05 = 3.0.
#
# The variance term separates the two cases 47x, the gradient term only 5x, so beta carries
# the edge test: beta = 6000 gives 3.36 on the edge alone and 0.072 on the smooth surface;
# alpha = 20 adds 0.5 on the edge and 0.1 on the smooth surface. Check: smooth c = exp(-0.17)
# = 0.84 > 0.8, edge c = exp(-3.86) = 0.021 < 0.05. tests/fuse/test_components.py::test_mcm_defaults_meet_the_design_targets checks both numbers
# on synthetic depth maps.
#
# Noise-aware MCM (FuseConfig.mcm_noise, beyond the paper). The numbers above hold at 1.5-2.5 m
# only: Kinect noise is 0.47 % of depth at 3 m and 0.65 % at 4 m, so a smooth surface there gets
# v ~ (0.0065)^2 = 4.2e-5 and g ~ 0.006 from noise alone -> c = exp(-0.25 - 0.12) = 0.69 < 0.8
# (measured: median c 0.74 at 4 m, 0.70 at 4.45 m on the 45-degree test plane). With mcm_noise
# the expected noise is removed before dividing by z (mcm.py): gx^2 + gy^2 - sigma(z)^2
# (central differences: E = 2 (sigma^2 / 2)) and Var - sigma(z)^2 (3x3: E = (8/9) sigma^2, the
# 1/9 extra is margin). What is left of a smooth 45-degree surface is its geometry, g = 1 / f =
# 0.0019 and v = (2/3) / f^2 = 2.4e-6 at every range -> alpha g + beta v = 0.05, c ~ 0.95; a
# 5 % edge loses at most sigma^2 at the far end of the Kinect range (4.5 m: sigma / z = 0.73 %):
# v = 5.6e-4 - 5.3e-5 = 5.1e-4 and g = sqrt(0.025^2 - 0.0073^2) = 0.024 -> 3.04 + 0.48 = 3.5,
# c = 0.03 < 0.05. So alpha and beta stay. Measured on noisy synthetic maps at 0.5-4.45 m with
# the Kinect sigma(z): smooth median c 0.97-1.00 (10th percentile >= 0.80), 5 % edge median
# c <= 0.03 (tests/fuse/test_components.py::test_noise_aware_mcm_meets_the_targets_at_every_range);
# without it the smooth median falls to 0.74 at 4 m. A grid over alpha in {20, 30, 40} and beta
# in {6000, 8000, 10000} traded the smooth 10th percentile (0.82 -> 0.73) for the edge tail,
# so the paper-range values were kept.
MCM_ALPHA = 20.0
MCM_BETA = 6000.0

#: Axial noise sigma(z) = a + b (z - z0)^2 (metres) by the simulator's sensor names, as plain
#: (a, b, z0) tuples of the one table, ``fuseflow.geometry.noise.SENSOR_NOISE``.
NOISE_SIGMA: dict[str, tuple[float, float, float]] = {
    "kinect": tuple(sensor_noise("kinect")),
    "realsense": tuple(sensor_noise("realsense")),
    "kinect2": tuple(sensor_noise("kinect2")),
}


@dataclass(frozen=True)
class FuseConfig:
    """All parameters of FUSE (paper III-C). Frozen; build variants with ``dataclasses.replace``."""

    # ---- MCM, eq. (16)-(18)
    alpha: float = MCM_ALPHA
    """Weight of the relative depth gradient g(x) in eq. (18). Derivation above (MCM_ALPHA). >= 0."""
    beta: float = MCM_BETA
    """Weight of the normalised local variance v(x) in eq. (18). Derivation above (MCM_BETA). >= 0."""
    delta: float = 0.1
    """Minimum depth (m) in eq. (18): the closest range of Kinect/RealSense-class sensors is
    0.1-0.4 m. Each camera's own ``depth_range`` also gates. > 0."""
    z_max: float = 10.0
    """Maximum depth (m), docs/design.md 2.1 (1[z < z_max]); beyond 10 m these sensors return noise.
    > delta."""
    window: int = 3
    """r of the r x r variance window of eq. (17) (docs/design.md 2.1: r = 3). Odd, 3..7."""
    use_mcm: bool = True
    """False = the "w/o MCM" ablation of Table VII: c(x) = 1 for every valid pixel."""
    mcm_max_missing: int = 4
    """Beyond the paper: a 3x3 window with at most this many of its 8 neighbours without depth is
    measured on the pixels it has (mcm.py, gap-tolerant window); 0 = a missing neighbour makes
    an edge pixel (design.md 2.1, the ``paper`` preset). Default 4, 0..8; > 0 needs ``window`` = 3."""
    mcm_noise: bool = False
    """Beyond the paper: g(x) and v(x) of eq. (16)-(17) are measured after removing the sensor's
    expected axial noise sigma(z) (``noise_sigma``; derivation above MCM_ALPHA), so smooth
    surfaces keep c > 0.8 at every range. Default False (eq. 16-17 as written)."""

    # ---- neighbour graph (paper III-C-2, docs/design.md 2.2)
    k_neighbours: int = 7
    """K_max, the most neighbour cameras per camera; CVGC and the multi-view mean cost O(K_max) per
    point. Default 7, 1..16 (docs/fuse.md, Presets)."""
    min_overlap: float = 0.05
    """Overlap floor: a camera j is a neighbour of i only when at least this share of i's
    frustum samples lands in j's image in front of it. 0..1."""

    # ---- CVGC, eq. (19)-(21)
    tau: float = 0.05
    """Relative depth residual threshold of eq. (21); paper: tau = 0.05. > 0."""
    visibility_aware: bool = True
    """Beyond the paper (docs/design.md 2.3): when D_j is in front of the projected point by more
    than tau (the point is only occluded in j), j casts no vote; only D_j behind the point
    (free-space violation) votes against. False = eq. (20)-(21) as written."""
    use_cvgc: bool = True
    """False = the "w/o CVGC" ablation of Table VII: omega_geo(x) = c(x) (eq. 21's no-vote case),
    so the joint weight of eq. (22) reduces to c(x)."""

    # ---- ASH, eq. (23)-(25)
    coarse_size: float = 0.2
    """s_c (m), the coarse cell of eq. (23). 20 cm holds ~10^3-10^4 points of a surface 1-3 m
    away at 640x480, enough for a stable density estimate. 0.02..2."""
    s0: float = 5.0
    """s_0 of eq. (24), in m^(1/2): a fine cell of a surface holds about s_0^2 s_c points (a coarse
    cell with n surface points has rho = n / s_c^3). Default 5 (about a 1 cm TSDF's point
    count); ``target_points`` picks it per frame for a point budget. > 0."""
    s_min: float = 0.002
    """Lower clip of s_f in eq. (24) (m): about one pixel footprint at 1 m (1 / 525 m). > 0."""
    s_max: float = 0.05
    """Upper clip of s_f in eq. (24) (m): sparse regions get at most 5 cm cells. s_min..s_c."""
    use_ash: bool = True
    """False = the "w/o ASH" ablation of Table VII: one fixed grid of cell ``fixed_size`` and
    rho_bar in place of the fine-cell density in eq. (26)."""
    fixed_size: float = 0.01
    """Cell size (m) of the single fixed grid used when use_ash is False (1 cm, the TSDF
    baseline's voxel). > 0."""

    # ---- RPS, eq. (26)-(28)
    k0: float = 1.0
    """k_0 of eq. (26): base count of representatives per fine cell. > 0."""
    ratio: float = 1.0
    """r of eq. (26), the selection ratio. > 0."""
    k_max: int = 3
    """k_max of eq. (26): at most this many points per fine cell (and FPS rounds). 1..16."""
    r_c: float = 0.3
    """r_c of eq. (27): candidates need c(x) > r_c. 0.3 drops depth edges (c < 0.05 by the MCM
    derivation) and keeps smooth surfaces (c > 0.8) with margin. 0..1."""
    min_weight: float = 0.3
    """Beyond the paper: candidates also need the joint weight omega(x) of eq. (22) > this.
    Eq. (27) filters on c only, so a point that every neighbour contradicts would still win a
    cell where it is alone (a flying pixel usually is); 0.3 rejects omega_geo < ~0.2 for c ~ 0.9.
    0 = eq. (27) as written. 0..1."""
    use_rps: bool = True
    """False = the "w/o RPS" ablation of Table VII: a fixed ``k_fixed`` points per cell instead
    of eq. (26), keeping the candidate filter (27) and the weighted FPS (28)."""
    k_fixed: int = 1
    """Points per cell when use_rps is False. 1..k_max."""
    range_priority: bool = False
    """Beyond the paper: eq. (28) ranks the points of a fine cell by omega(x) / sigma(z(x))
    (``noise_sigma``, z the depth in the source camera) instead of omega(x), so a near camera's
    point is preferred; only *which* points are selected changes. Default False."""
    lone_cell_mean: float = 2.0
    """Beyond the paper: a fine cell holding a single candidate gets k = 0 in eq. (26) when its
    coarse cell holds at least this many candidates per occupied fine cell (a lone point on a
    densely sampled surface is off it), unless ``lone_cell_keep`` neighbours confirm it. Needs
    use_ash and use_rps. Default 2; 0 = off (eq. 26 as written, ``paper``). >= 0."""
    lone_cell_keep: int = 1
    """Beyond the paper: ``lone_cell_mean`` spares a lone point that at least this many neighbour
    cameras confirm (depth within ``multiview_gate``; needs ``multiview_mean``). Default 1;
    0 = drop every lone point of a dense coarse cell. 0..16."""
    multiview_mean: bool = True
    """Beyond the paper (cvgc.multiview_mean): each candidate becomes the inverse-variance
    (1 / sigma(z)^2, ``noise_sigma``) weighted 3-D mean of itself and the measured points Q_j of
    the neighbours whose depth at x_ij (eq. 19) agrees within ``multiview_gate``; CVGC's votes
    use the unaveraged point. Needs ``use_cvgc``. Default True; False = the pixels' own
    back-projections (``paper``)."""
    multiview_gate: float = 3.0
    """Agreement gate of ``multiview_mean`` in units of the combined expected noise
    sqrt(sigma(z_ij)^2 + sigma(D_j)^2) of the two depths compared: 3 keeps 99.7 % of the same
    surface's Gaussian noise. > 0."""
    consensus: bool = True
    """Beyond the paper (rps.consensus): after selection each representative moves along its ray to
    the omega-weighted mean of its fine cell's candidates that agree within ``consensus_gate``
    sigma(z); the cloud carries ``support`` (cameras among them). Default True; False = points
    are selected, never moved (``paper``)."""
    consensus_gate: float = 3.0
    """Agreement gate of ``consensus`` in units of the sensor's sigma(z) at the
    representative's depth: 3 sigma keeps 99.7 % of the same surface's Gaussian noise and
    rejects a second surface more than 3 sigma away (Kinect: 18 mm at 2 m, 42 mm at 3 m). > 0."""
    depth_smoothing: int = 1
    """Beyond the paper (fuse/smooth.py): before MCM each depth becomes the mean of the depths of
    its (2r+1)^2 window within ``smoothing_gate`` sigma(z) of it (r = this radius in pixels), so
    smooth surfaces lose up to 2r+1 times their axial noise and edges keep their own depths.
    Default 1 (3x3); 0 = off (``paper``). 0..3."""
    smoothing_gate: float = 2.5
    """Gate of ``depth_smoothing`` in units of the sensor's sigma(z) at the pixel's depth. > 0."""
    noise_sigma: tuple[float, float, float] = tuple(SENSOR_NOISE[DEFAULT_SENSOR])
    """(a, b, z0) of the axial noise model sigma(z) = a + b (z - z0)^2 (metres) used by ``mcm_noise``,
    ``range_priority``, ``multiview_mean`` and ``consensus`` (fuseflow.geometry.noise). Default:
    the Kinect v1 row of ``SENSOR_NOISE`` (structured light). a > 0, b >= 0."""

    target_points: int | None = None
    """Density control (beyond the paper): ``s0`` is searched per frame for about this many output
    points (fuse/density.py); with ``budget_stride`` a small budget also coarsens the pixel
    grid. Default None (s0 as given); >= 1."""

    pixel_stride: int = 1
    """Beyond the paper: candidates on every ``pixel_stride``-th pixel of every ``pixel_stride``-th
    row; MCM, CVGC lookups and the multi-view mean still read the full-resolution depth.
    Default 1 (every pixel), 1..8."""

    budget_stride: bool = True
    """Beyond the paper, with ``target_points`` only: candidates on the coarsest grid s <= 3 (and
    >= ``pixel_stride``) with target_points <= 0.75 V / s^2, V the frame's valid depth pixels
    (fuse/density.py); a grid more than 10 % short is fused again on ``pixel_stride``'s grid.
    Default True; False = ``pixel_stride`` whatever the budget."""

    # ---- execution
    backend: Backend = "auto"
    """"torch": the PyTorch reference (any device); "numba": fused compiled CPU kernels;
    "auto": numba on CPU tensors when numba is installed, torch otherwise (CUDA)."""
    eps: float = 1e-6
    """epsilon of eq. (16), (17), (20), (22), (24). > 0."""

    # ---- rig-adaptive grid
    auto_grid: bool = False
    """Grid and s0 per frame from the rig (``auto_config``; ``PRESETS["auto"]``, the CLI's default);
    ignored with ``target_points``."""

    def __post_init__(self) -> None:
        def bad(name: str, want: str) -> None:
            raise ValidationError(f"FuseConfig.{name}: expected {want}, got {getattr(self, name)!r}")

        for name in ("alpha", "beta", "r_c", "min_weight"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                bad(name, "a finite number >= 0")
        for name in (
            "delta",
            "z_max",
            "tau",
            "coarse_size",
            "s0",
            "s_min",
            "s_max",
            "fixed_size",
            "k0",
            "ratio",
            "consensus_gate",
            "multiview_gate",
            "smoothing_gate",
            "eps",
        ):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                bad(name, "a finite number > 0")
        if self.target_points is not None and (not isinstance(self.target_points, int) or self.target_points < 1):
            bad("target_points", "None or an integer >= 1")
        if self.z_max <= self.delta:
            bad("z_max", f"> delta ({self.delta})")
        if not isinstance(self.window, int) or self.window % 2 == 0 or not 3 <= self.window <= 7:
            bad("window", "an odd integer in 3..7")
        for name, lo, hi, note in (
            ("mcm_max_missing", 0, 8, ""),
            ("pixel_stride", 1, 8, ""),
            ("k_neighbours", 1, 16, ""),
            ("k_max", 1, 16, ""),
            ("lone_cell_keep", 0, 16, " (0 = drop every lone point)"),
            ("depth_smoothing", 0, 3, " (0 = off)"),
        ):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or not lo <= v <= hi:  # a bool is an int
                bad(name, f"an integer in {lo}..{hi}{note}")
        if self.mcm_max_missing > 0 and self.window != 3:
            bad("mcm_max_missing", f"0 with window = {self.window} (the gap-tolerant window is 3x3)")
        if not 0 <= self.min_overlap <= 1:
            bad("min_overlap", "a number in [0, 1]")
        if self.r_c >= 1 or self.min_weight >= 1:
            bad("r_c" if self.r_c >= 1 else "min_weight", "a number < 1")
        if not isinstance(self.k_fixed, int) or not 1 <= self.k_fixed <= self.k_max:
            bad("k_fixed", f"an integer in 1..k_max ({self.k_max})")
        if self.s_min > self.s_max or self.s_max > self.coarse_size:
            bad("s_max", f"s_min ({self.s_min}) <= s_max <= coarse_size ({self.coarse_size})")
        if self.coarse_size / self.s_min > 127 or self.coarse_size / self.fixed_size > 1e6:
            bad("s_min", f">= coarse_size / 127 ({self.coarse_size / 127:.4g}) so a fine index fits 7 bits")
        ns = self.noise_sigma
        if (
            not isinstance(ns, tuple)
            or len(ns) != 3
            or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in ns)
            or not ns[0] > 0
            or ns[1] < 0
        ):
            bad("noise_sigma", "a tuple (a, b, z0) of finite numbers with a > 0, b >= 0")
        if not (isinstance(self.lone_cell_mean, (int, float)) and 0 <= self.lone_cell_mean < float("inf")):
            bad("lone_cell_mean", "a finite number >= 0 (0 = off)")
        for name in ("range_priority", "mcm_noise", "consensus", "multiview_mean", "budget_stride", "auto_grid"):
            if not isinstance(getattr(self, name), bool):
                bad(name, "a bool")
        if self.backend not in ("auto", "torch", "numba"):
            bad("backend", "'auto', 'torch' or 'numba'")

    def describe(self) -> dict:
        """The fields as a plain dict (for benchmark rows and logs)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


_DEFAULT = FuseConfig()

#: Table VII ablations, each the default with one component removed.
ABLATIONS: dict[str, FuseConfig] = {
    "w/o CVGC": replace(_DEFAULT, use_cvgc=False),
    "w/o MCM": replace(_DEFAULT, use_mcm=False),
    "w/o ASH": replace(_DEFAULT, use_ash=False),
    "w/o RPS": replace(_DEFAULT, use_rps=False),
}

PRESETS: dict[str, FuseConfig] = {
    "default": _DEFAULT,
    "paper": replace(
        _DEFAULT,
        k_neighbours=4,  # the paper fixes neither k_neighbours nor s0
        s0=6.3,
        visibility_aware=False,
        min_weight=0.0,
        range_priority=False,
        lone_cell_mean=0.0,
        mcm_max_missing=0,
        mcm_noise=False,
        consensus=False,
        multiview_mean=False,
        depth_smoothing=0,
    ),
    "quality": _DEFAULT,
    "fast": replace(_DEFAULT, k_neighbours=4, s0=6.3),
    # candidates on every 2nd pixel of every 2nd row (4x fewer); every stage costs per candidate,
    # so s0 is low enough that selection keeps nearly all of them
    # no depth smoothing: it costs `live` 14-25 % of its time (ICL, HO-Cap), which is its point
    "live": replace(_DEFAULT, pixel_stride=2, s0=1.0, mcm_max_missing=4, depth_smoothing=0),
    # completeness first: every pixel, nearly every candidate kept, 5x5 smoothing
    "dense": replace(_DEFAULT, s0=1.0, depth_smoothing=2),
    # the CLI's default: every pixel ("dense") while the frame's valid pixels fit a time budget, a coarser grid above (auto_config)
    "auto": replace(_DEFAULT, auto_grid=True),
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
#: budget over the cost: 0.8 M; the simulated 4-ring 640x480 has 0.62 M, the 8-ring 1.23 M),
#: and the coarse grid above it.
AUTO_MAX_EVERY_PIXEL = int(AUTO_CORE_MS / AUTO_CORE_MS_PER_MPX * 1e6)


def auto_config(cfg: FuseConfig, views: int, valid_pixels: int) -> tuple[FuseConfig, str]:
    """FuseConfig.auto_grid: the settings for a frame of ``views`` present views with
    ``valid_pixels`` valid depth pixels, and a one-line account of the choice. While
    ``valid_pixels`` <= AUTO_MAX_EVERY_PIXEL (every pixel fits the time budget) ``dense``'s s0
    and smoothing on ``cfg``'s grid: every pixel, nearly every candidate kept. Above it
    (8 x 640x480: 1.2-2.4 M) every 2nd pixel of every 2nd row with s0 = 1 (``live``'s grid),
    5x5 smoothing, 4 neighbour cameras and no multi-view mean: on the simulated 8-ring 640x480
    that is 25-28 % less time than the default's 7 neighbours, multi-view mean and 3x3 smoothing
    on that grid, with higher precision and recall at 1 cm (docs/fuse.md)."""
    what = f"{views} views, {valid_pixels / 1e6:.2f} M valid depth pixels"
    if valid_pixels > AUTO_MAX_EVERY_PIXEL:
        live = PRESETS["live"]
        out = replace(cfg, pixel_stride=live.pixel_stride, s0=live.s0, mcm_max_missing=live.mcm_max_missing,
                      depth_smoothing=2, k_neighbours=4, multiview_mean=False)  # fmt: skip
        why = f"more than {AUTO_MAX_EVERY_PIXEL / 1e6:.2f} M: every pixel would not fit 10 frames/s"
        return out, f"auto: stride {out.pixel_stride}, s0 {out.s0:g} ({what}; {why})"
    dense = PRESETS["dense"]
    out = replace(cfg, s0=dense.s0, depth_smoothing=dense.depth_smoothing)
    return out, f"auto: stride {out.pixel_stride}, s0 {out.s0:g} ({what}: every pixel counts)"


def preset_config(name: str, target_points: int | None = None) -> FuseConfig:
    """``PRESETS[name]``, with ``target_points`` when given (the `fuse` / `run` commands' --preset
    and --points); ValidationError naming the presets for an unknown name."""
    if name not in PRESETS:
        raise ValidationError(f"no FUSE preset {name!r}; presets are {sorted(PRESETS)}")
    return PRESETS[name] if target_points is None else replace(PRESETS[name], target_points=target_points)


def preset(name: str) -> FuseConfig:
    """The named preset (``PRESETS`` keys); ValidationError listing the names otherwise."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ValidationError(f"no FUSE preset {name!r}; presets are {sorted(PRESETS)}") from None
