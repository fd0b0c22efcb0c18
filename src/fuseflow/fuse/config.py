"""FuseConfig: every constant of FUSE (paper III-C), its source, and the named presets.

The paper fixes only tau = 0.05 (eq. 21). Every other value below is a project default with
its derivation written next to it (docs/design.md section 2). Measured numbers of each preset and
switch: docs/fuse.md. Presets:

* ``FuseConfig()`` / ``PRESETS["default"]``: the project's defaults (visibility-aware CVGC,
  a minimum joint weight for RPS candidates).
* ``PRESETS["paper"]``: the paper read literally (eq. 20-21 vote for every neighbour that has
  depth, eq. 27 filters on c only, no minimum joint weight, eq. 28 ranks by omega alone).
* ``PRESETS["quality"]``: the same as the default (an older name, kept).
* ``PRESETS["fast"]``: ``cvgc.k_neighbours = 4``, ``ash.s0 = 6.3``: less time, fewer points.
* ``PRESETS["live"]``: the default with ``pixel_stride = 2``, ``ash.s0 = 1`` and no depth smoothing: candidates on every
  2nd pixel of every 2nd row, nearly all of them kept; for full frames from ~8-camera rigs.
* ``PRESETS["dense"]``: the default with ``ash.s0 = 1``, 5x5 depth smoothing and ``mcm.max_missing = 6``:
  every pixel, nearly every candidate kept; the most complete cloud, about twice the default's points.
* Ablations exactly as the paper's Table VII: ``PRESETS["w/o CVGC"]``, ``["w/o MCM"]``,
  ``["w/o ASH"]``, ``["w/o RPS"]`` (each is the default with one component removed).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, fields, replace
from typing import Any, Literal

from fuseflow.errors import ValidationError
from fuseflow.geometry.noise import DEFAULT_SENSOR, SENSOR_NOISE, sensor_noise

__all__ = [
    "FuseConfig",
    "SmoothingConfig",
    "MCMConfig",
    "CVGCConfig",
    "ASHConfig",
    "RPSConfig",
    "STAGES",
    "PRESETS",
    "ABLATIONS",
    "NOISE_SIGMA",
    "preset",
    "auto_config",
    "parse_settings",
]

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
# Noise-aware MCM (MCMConfig.noise_aware, beyond the paper). The numbers above hold at 1.5-2.5 m
# only: Kinect noise is 0.47 % of depth at 3 m and 0.65 % at 4 m, so a smooth surface there gets
# v ~ (0.0065)^2 = 4.2e-5 and g ~ 0.006 from noise alone -> c = exp(-0.25 - 0.12) = 0.69 < 0.8
# (measured: median c 0.74 at 4 m, 0.70 at 4.45 m on the 45-degree test plane). With noise_aware
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


def _fail(path: str, value: object, want: str) -> None:
    raise ValidationError(f"FuseConfig.{path}: expected {want}, got {value!r}")


def _check_numbers(cfg: object, stage: str, names: tuple[str, ...], positive: bool) -> None:
    """Each field of ``names`` is a finite number > 0 (``positive``) or >= 0."""
    for name in names:
        v = getattr(cfg, name)
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and abs(v) < 3.4e38  # float32 kernels
        if not ok or v < 0 or (positive and v == 0):
            _fail(f"{stage}{name}", v, "a finite float32 > 0" if positive else "a finite float32 >= 0")


def _check_ints(cfg: object, stage: str, bounds: tuple[tuple[str, int, int, str], ...]) -> None:
    """Each (name, lo, hi, note) field is an integer in lo..hi (a bool is not one)."""
    for name, lo, hi, note in bounds:
        v = getattr(cfg, name)
        if not isinstance(v, int) or isinstance(v, bool) or not lo <= v <= hi:
            _fail(f"{stage}{name}", v, f"an integer in {lo}..{hi}{note}")


def _check_bools(cfg: object, stage: str, names: tuple[str, ...]) -> None:
    for name in names:
        if not isinstance(getattr(cfg, name), bool):
            _fail(f"{stage}{name}", getattr(cfg, name), "a bool")


@dataclass(frozen=True)
class SmoothingConfig:
    """Noise-aware depth smoothing before MCM (beyond the paper; fuse/smooth.py)."""

    radius: int = 1
    """r: each depth becomes the mean of its (2r+1)^2 window's depths within ``gate`` sigma(z) of it.
    Pixels; default 1 (3x3), 0 = off (``paper``); 0..3."""
    gate: float = 2.5
    """Agreement gate in units of the sensor's sigma(z) at the pixel's depth. Default 2.5; > 0."""

    def __post_init__(self) -> None:
        _check_ints(self, "smoothing.", (("radius", 0, 3, " (0 = off)"),))
        _check_numbers(self, "smoothing.", ("gate",), positive=True)


@dataclass(frozen=True)
class MCMConfig:
    """Measurement confidence c(x), eq. (16)-(18) (fuse/mcm.py)."""

    alpha: float = MCM_ALPHA
    """Weight of the relative depth gradient g(x) in eq. (18); derivation above MCM_ALPHA. Default 20; >= 0."""
    beta: float = MCM_BETA
    """Weight of the normalised local variance v(x) in eq. (18); derivation above MCM_ALPHA. Default 6000; >= 0."""
    delta: float = 0.1
    """Minimum depth of eq. (18), metres (the closest range of Kinect/RealSense-class sensors; each
    camera's ``depth_range`` also gates). Default 0.1; > 0."""
    z_max: float = 10.0
    """Maximum depth, metres (docs/design.md 2.1; beyond 10 m these sensors return noise). Default 10; > delta."""
    window: int = 3
    """r of the r x r variance window of eq. (17), pixels. Default 3; odd, 3..7."""
    enabled: bool = True
    """False = the "w/o MCM" ablation of Table VII: c(x) = 1 for every valid pixel. Default True."""
    max_missing: int = 4
    """Beyond the paper: a 3x3 window missing at most this many of its 8 neighbours is measured on the
    pixels it has (mcm.py); 0 = a missing neighbour makes an edge (``paper``). Default 4; 0..8, > 0 needs window 3."""
    noise_aware: bool = False
    """Beyond the paper: g(x), v(x) measured after removing the expected noise sigma(z)^2 (mcm.py;
    derivation above MCM_ALPHA). Default False (eq. 16-17 as written)."""

    def __post_init__(self) -> None:
        _check_numbers(self, "mcm.", ("alpha", "beta"), positive=False)
        _check_numbers(self, "mcm.", ("delta", "z_max"), positive=True)
        if self.z_max <= self.delta:
            _fail("mcm.z_max", self.z_max, f"> delta ({self.delta})")
        if not isinstance(self.window, int) or self.window % 2 == 0 or not 3 <= self.window <= 7:
            _fail("mcm.window", self.window, "an odd integer in 3..7")
        _check_ints(self, "mcm.", (("max_missing", 0, 8, ""),))
        if self.max_missing > 0 and self.window != 3:
            _fail(
                "mcm.max_missing", self.max_missing, f"0 with window = {self.window} (the gap-tolerant window is 3x3)"
            )
        _check_bools(self, "mcm.", ("enabled", "noise_aware"))


@dataclass(frozen=True)
class CVGCConfig:
    """Cross-view geometric consistency, eq. (19)-(21), its neighbour graph (paper III-C-2) and
    the multi-view mean (fuse/cvgc.py, fuse/neighbours.py)."""

    k_neighbours: int = 7
    """K_max, the most neighbour cameras per camera; CVGC and the multi-view mean cost O(K_max) per
    point. Default 7; 1..16."""
    min_overlap: float = 0.05
    """Camera j is a neighbour of i when at least this share of i's frustum samples lands in j's
    image in front of it. Default 0.05; 0..1."""
    tau: float = 0.05
    """Relative depth residual threshold of eq. (21) (the paper's value). Default 0.05; > 0."""
    visibility_aware: bool = True
    """Beyond the paper (docs/design.md 2.3): a neighbour whose depth is in front of the point by
    more than tau casts no vote. Default True; False = eq. (20)-(21) as written."""
    enabled: bool = True
    """False = the "w/o CVGC" ablation of Table VII: omega_geo(x) = c(x), so omega = c. Default True."""
    multiview_mean: bool = True
    """Beyond the paper: each candidate becomes the 1 / sigma(z)^2-weighted mean of itself and the
    neighbours' agreeing points (cvgc.multiview_mean). Default True; needs ``enabled``."""
    multiview_gate: float = 3.0
    """Agreement gate of ``multiview_mean`` in units of sqrt(sigma(z_ij)^2 + sigma(D_j)^2). Default 3; > 0."""

    def __post_init__(self) -> None:
        _check_ints(self, "cvgc.", (("k_neighbours", 1, 16, ""),))
        if not (isinstance(self.min_overlap, (int, float)) and 0 <= self.min_overlap <= 1):
            _fail("cvgc.min_overlap", self.min_overlap, "a number in [0, 1]")
        _check_numbers(self, "cvgc.", ("tau", "multiview_gate"), positive=True)
        _check_bools(self, "cvgc.", ("visibility_aware", "enabled", "multiview_mean"))


@dataclass(frozen=True)
class ASHConfig:
    """Adaptive spatial hashing, eq. (23)-(25) (fuse/ash.py)."""

    coarse_size: float = 0.2
    """s_c of eq. (23), metres: holds ~10^3-10^4 points of a surface 1-3 m away at 640x480. Default 0.2; 0.02..2."""
    s0: float = 5.0
    """s_0 of eq. (24), m^(1/2): a fine cell holds about s_0^2 s_c points. Default 5 (about a 1 cm
    TSDF's point count); > 0 (FuseConfig.target_points searches it per frame)."""
    s_min: float = 0.002
    """Lower clip of s_f in eq. (24), metres (about one pixel footprint at 1 m). Default 0.002; >= coarse_size / 127."""
    s_max: float = 0.05
    """Upper clip of s_f in eq. (24), metres. Default 0.05; s_min..coarse_size."""
    enabled: bool = True
    """False = the "w/o ASH" ablation of Table VII: one fixed grid of ``fixed_size`` cells, rho_bar in eq. (26)."""
    fixed_size: float = 0.01
    """Cell size of the fixed grid when ``enabled`` is False, metres (the TSDF baseline's voxel). Default 0.01; > 0."""

    def __post_init__(self) -> None:
        _check_numbers(self, "ash.", ("coarse_size", "s0", "s_min", "s_max", "fixed_size"), positive=True)
        _check_bools(self, "ash.", ("enabled",))
        if self.s_min > self.s_max or self.s_max > self.coarse_size:
            _fail("ash.s_max", self.s_max, f"s_min ({self.s_min}) <= s_max <= coarse_size ({self.coarse_size})")
        if self.coarse_size / self.s_min > 127 or self.coarse_size / self.fixed_size > 1e6:
            _fail(
                "ash.s_min",
                self.s_min,
                f">= coarse_size / 127 ({self.coarse_size / 127:.4g}) so a fine index fits 7 bits",
            )


@dataclass(frozen=True)
class RPSConfig:
    """Representative point selection, eq. (26)-(28), and the consensus step (fuse/rps.py)."""

    r_c: float = 0.3
    """r_c of eq. (27): candidates need c(x) > r_c (drops depth edges, c < 0.05; keeps smooth
    surfaces, c > 0.8). Default 0.3; 0..1."""
    min_weight: float = 0.3
    """Beyond the paper: candidates also need omega(x) of eq. (22) >= this (rejects points every
    neighbour contradicts). Default 0.3; 0 = eq. (27) as written; 0..1."""
    k0: float = 1.0
    """k_0 of eq. (26): base count of representatives per fine cell. Default 1; > 0."""
    ratio: float = 1.0
    """r of eq. (26), the selection ratio. Default 1; > 0."""
    k_max: int = 3
    """k_max of eq. (26): at most this many points per fine cell (and FPS rounds). Default 3; 1..16."""
    enabled: bool = True
    """False = the "w/o RPS" ablation of Table VII: ``k_fixed`` points per cell instead of eq. (26),
    same filter (27) and FPS (28). Default True."""
    k_fixed: int = 1
    """Points per cell when ``enabled`` is False. Default 1; 1..k_max."""
    range_priority: bool = False
    """Beyond the paper: eq. (28) ranks a cell's points by omega / sigma(z) (z in the source camera)
    instead of omega, preferring near cameras. Default False."""
    lone_cell_mean: float = 2.0
    """Beyond the paper: k = 0 for a one-candidate fine cell whose coarse cell holds at least this many
    candidates per occupied fine cell (needs ASH). Default 2; 0 = off (``paper``); >= 0."""
    lone_cell_keep: int = 1
    """A lone point that at least this many neighbour cameras confirm is kept (needs
    cvgc.multiview_mean). Default 1; 0 = drop every lone point of a dense coarse cell; 0..16."""
    consensus: bool = True
    """Beyond the paper (rps.consensus): each representative moves along its ray to the omega-weighted
    mean of its fine cell's agreeing candidates. Default True; False = points never move (``paper``)."""
    consensus_gate: float = 3.0
    """Agreement gate of ``consensus`` in units of sigma(z) at the representative's depth. Default 3; > 0."""

    def __post_init__(self) -> None:
        _check_numbers(self, "rps.", ("r_c", "min_weight", "lone_cell_mean"), positive=False)
        if self.r_c >= 1 or self.min_weight >= 1:
            _fail("rps.r_c" if self.r_c >= 1 else "rps.min_weight", max(self.r_c, self.min_weight), "a number < 1")
        _check_numbers(self, "rps.", ("k0", "ratio", "consensus_gate"), positive=True)
        _check_ints(self, "rps.", (("k_max", 1, 16, ""), ("lone_cell_keep", 0, 16, " (0 = drop every lone point)")))
        _check_ints(self, "rps.", (("k_fixed", 1, self.k_max, " (1..k_max)"),))
        _check_bools(self, "rps.", ("enabled", "range_priority", "consensus"))


#: ``FuseConfig.as_dict``'s flat name of each setting whose field name alone is not unique or not
#: the recorded one (every other setting: its field name).
FLAT_NAMES: dict[str, str] = {
    "smoothing.radius": "depth_smoothing",
    "smoothing.gate": "smoothing_gate",
    "mcm.enabled": "use_mcm",
    "mcm.max_missing": "mcm_max_missing",
    "mcm.noise_aware": "mcm_noise",
    "cvgc.enabled": "use_cvgc",
    "ash.enabled": "use_ash",
    "rps.enabled": "use_rps",
}

#: The per-stage parts of a FuseConfig, by field name, in pipeline order.
STAGES: dict[str, type] = {
    "smoothing": SmoothingConfig,
    "mcm": MCMConfig,
    "cvgc": CVGCConfig,
    "ash": ASHConfig,
    "rps": RPSConfig,
}


@dataclass(frozen=True)
class FuseConfig:
    """All parameters of FUSE (paper III-C): one frozen config per stage plus the settings that
    span stages. Frozen; change a setting with ``cfg.replace(rps={"k_max": 2}, pixel_stride=2)``."""

    smoothing: SmoothingConfig = SmoothingConfig()
    """Depth smoothing before MCM (``SmoothingConfig``)."""
    mcm: MCMConfig = MCMConfig()
    """Measurement confidence, eq. (16)-(18) (``MCMConfig``)."""
    cvgc: CVGCConfig = CVGCConfig()
    """Cross-view consistency, eq. (19)-(21), the neighbour graph and the multi-view mean (``CVGCConfig``)."""
    ash: ASHConfig = ASHConfig()
    """Adaptive spatial hashing, eq. (23)-(25) (``ASHConfig``)."""
    rps: RPSConfig = RPSConfig()
    """Representative selection, eq. (26)-(28), and consensus (``RPSConfig``)."""

    noise_sigma: tuple[float, float, float] = tuple(SENSOR_NOISE[DEFAULT_SENSOR])
    """(a, b, z0) of the axial noise sigma(z) = a + b (z - z0)^2, metres (fuseflow.geometry.noise), used by
    every noise-gated stage. Default: the Kinect v1 row (a camera's rig.json ``sensor`` overrides it); a > 0, b >= 0."""
    pixel_stride: int = 1
    """Beyond the paper: candidates on every ``pixel_stride``-th pixel of every ``pixel_stride``-th row
    (MCM, CVGC and the multi-view mean still read full-resolution depth). Default 1; 1..8."""
    target_points: int | None = None
    """Beyond the paper: ``ash.s0`` is searched per frame for about this many points (fuse/density.py).
    Default None (s0 as given); >= 1."""
    budget_stride: bool = True
    """With ``target_points``: candidates on the coarsest grid s <= 3 with target_points <= 0.75 V / s^2
    (V valid depth pixels; fuse/density.py). Default True; False = ``pixel_stride`` whatever the budget."""
    auto_grid: bool = False
    """Grid and s0 per frame from the rig (``auto_config``; ``PRESETS["auto"]``, the CLI's default);
    ignored with ``target_points``. Default False."""
    backend: Backend = "auto"
    """"torch": the PyTorch reference (any device); "numba": compiled CPU kernels; "auto" (default):
    numba on CPU tensors when numba is installed, torch otherwise."""
    eps: float = 1e-6
    """epsilon of eq. (16), (17), (20), (22), (24). Default 1e-6; > 0."""

    def __post_init__(self) -> None:
        for name, kind in STAGES.items():
            if not isinstance(getattr(self, name), kind):
                _fail(
                    name,
                    getattr(self, name),
                    f"type {kind.__name__} (change one setting with cfg.replace({name}={{...}}))",
                )
        _check_numbers(self, "", ("eps",), positive=True)
        _check_ints(self, "", (("pixel_stride", 1, 8, ""),))
        tp = self.target_points
        if tp is not None and (not isinstance(tp, int) or isinstance(tp, bool) or tp < 1):
            _fail("target_points", tp, "None or an integer >= 1")
        ns = self.noise_sigma
        if (
            not isinstance(ns, tuple)
            or len(ns) != 3
            or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in ns)
            or not ns[0] > 0
            or ns[1] < 0
        ):
            _fail("noise_sigma", ns, "a tuple (a, b, z0) of finite numbers with a > 0, b >= 0")
        _check_bools(self, "", ("budget_stride", "auto_grid"))
        if self.backend not in ("auto", "torch", "numba"):
            _fail("backend", self.backend, "'auto', 'torch' or 'numba'")

    def replace(self, **changes: Any) -> FuseConfig:
        """A copy with ``changes``: a cross-stage setting by name (``pixel_stride=2``), a stage by
        a dict of its settings merged into it (``rps={"k_max": 2}``) or by a whole stage config.
        Unknown names raise ValidationError listing the valid ones."""
        out: dict[str, Any] = {}
        names = {f.name for f in fields(self)}
        for name, value in changes.items():
            if name not in names:
                raise ValidationError(f"FuseConfig has no setting {name!r}; settings are {sorted(names)}")
            if name in STAGES and isinstance(value, Mapping):
                stage = getattr(self, name)
                known = {f.name for f in fields(stage)}
                unknown = sorted(set(value) - known)
                if unknown:
                    raise ValidationError(
                        f"FuseConfig.{name} has no setting {unknown[0]!r}; settings are {sorted(known)}"
                    )
                value = replace(stage, **value)
            out[name] = value
        return replace(self, **out)

    def as_dict(self) -> dict[str, Any]:
        """Every setting under one flat name (the field's own, or ``FLAT_NAMES``' for the ones
        several stages share): the form ``manifest.json`` records and digests for a resume."""
        return {FLAT_NAMES.get(k, k.rpartition(".")[2]): v for k, v in self.describe().items()}

    def describe(self) -> dict[str, Any]:
        """Every setting by its dotted name (``"rps.k_max"``, ``"pixel_stride"``), as ``--set`` takes
        it: for benchmark rows and logs."""
        out: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in STAGES:
                out.update({f"{f.name}.{g.name}": getattr(value, g.name) for g in fields(value)})
            else:
                out[f.name] = value
        return out


def parse_settings(assignments: Iterable[str]) -> dict[str, Any]:
    """``cfg.replace`` keyword arguments from ``NAME=VALUE`` strings (the CLI's ``--set``): NAME is
    a setting of ``FuseConfig().describe()`` (``rps.k_max``, ``pixel_stride``); VALUE is read as the
    setting's type (bool: true/false/1/0/on/off; noise_sigma: a,b,z0; target_points: none or an int)."""
    known = FuseConfig().describe()
    out: dict[str, Any] = {}
    for text in assignments:
        name, sep, raw = text.partition("=")
        name, raw = name.strip(), raw.strip()
        if not sep or name not in known:
            raise ValidationError(f"--set {text!r}: expected NAME=VALUE with NAME one of {', '.join(known)}")
        value = _parse_value(name, raw, known[name])
        stage, dot, field_name = name.partition(".")
        if dot:
            out.setdefault(stage, {})[field_name] = value
        else:
            out[name] = value
    return out


def _parse_value(name: str, raw: str, default: Any) -> Any:
    """``raw`` as the type of ``default`` (the setting's default value)."""
    low = raw.lower()
    try:
        if isinstance(default, bool):
            if low not in ("true", "false", "1", "0", "on", "off", "yes", "no"):
                raise ValueError(raw)
            return low in ("true", "1", "on", "yes")
        if name == "target_points":
            return None if low == "none" else int(raw)
        if isinstance(default, tuple):
            return tuple(float(v) for v in raw.split(","))
        if isinstance(default, int):
            return int(raw)
        if isinstance(default, float):
            return float(raw)
        return raw
    except ValueError:
        raise ValidationError(f"--set {name}={raw}: expected a value like {default!r}") from None


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
    "quality": _DEFAULT,
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


def preset_config(name: str, target_points: int | None = None, settings: Iterable[str] = ()) -> FuseConfig:
    """``PRESETS[name]``, with ``target_points`` when given and then the ``NAME=VALUE`` settings
    (``parse_settings``): the `fuse` / `run` commands' --preset, --points and --set.
    ValidationError naming the presets for an unknown name, or the settings for a bad one."""
    if name not in PRESETS:
        raise ValidationError(f"no FUSE preset {name!r}; presets are {sorted(PRESETS)}")
    cfg = PRESETS[name] if target_points is None else PRESETS[name].replace(target_points=target_points)
    changes = parse_settings(settings)
    return cfg.replace(**changes) if changes else cfg


def preset(name: str) -> FuseConfig:
    """The named preset (``PRESETS`` keys); ValidationError listing the names otherwise."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ValidationError(f"no FUSE preset {name!r}; presets are {sorted(PRESETS)}") from None
