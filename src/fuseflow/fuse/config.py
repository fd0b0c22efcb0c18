"""FuseConfig: every constant of FUSE (paper III-C) and its source, one frozen config per stage.

The paper fixes only tau = 0.05 (eq. 21). Every other value below is a project default with
its derivation written next to it (docs/design.md section 2; MCM's alpha and beta: fuse/mcm.py).
The named presets, the ablations and ``auto_config`` (the ``auto`` preset's per-frame choice)
are in ``fuseflow.fuse.presets``; measured numbers of each preset and switch: docs/fuse.md.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from typing import Any, Literal

from fuseflow.errors import ValidationError
from fuseflow.fuse import validation as check
from fuseflow.geometry.noise import DEFAULT_SENSOR, SENSOR_NOISE

__all__ = ["FuseConfig", "SmoothingConfig", "MCMConfig", "CVGCConfig", "ASHConfig", "RPSConfig", "STAGES"]

Backend = Literal["auto", "torch", "numba"]

# MCM defaults (eq. 16-18), derived from the sensor noise model in fuse/mcm.py (module docstring).
MCM_ALPHA = 20.0
MCM_BETA = 6000.0


@dataclass(frozen=True)
class SmoothingConfig:
    """Noise-aware depth smoothing before MCM (beyond the paper; fuse/smooth.py)."""

    radius: int = 1
    """r: each depth becomes the mean of its (2r+1)^2 window's depths within ``gate`` sigma(z) of it.
    Pixels; default 1 (3x3), 0 = off (``paper``); 0..3."""
    gate: float = 2.5
    """Agreement gate in units of the sensor's sigma(z) at the pixel's depth. Default 2.5; > 0."""

    def __post_init__(self) -> None:
        check.ints(self, "smoothing.", (("radius", 0, 3, " (0 = off)"),))
        check.numbers(self, "smoothing.", ("gate",), positive=True)


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
        check.numbers(self, "mcm.", ("alpha", "beta"), positive=False)
        check.numbers(self, "mcm.", ("delta", "z_max"), positive=True)
        if self.z_max <= self.delta:
            check.fail("mcm.z_max", self.z_max, f"> delta ({self.delta})")
        if not isinstance(self.window, int) or self.window % 2 == 0 or not 3 <= self.window <= 7:
            check.fail("mcm.window", self.window, "an odd integer in 3..7")
        check.ints(self, "mcm.", (("max_missing", 0, 8, ""),))
        if self.max_missing > 0 and self.window != 3:
            want = f"0 with window = {self.window} (the gap-tolerant window is 3x3)"
            check.fail("mcm.max_missing", self.max_missing, want)
        check.bools(self, "mcm.", ("enabled", "noise_aware"))


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
        check.ints(self, "cvgc.", (("k_neighbours", 1, 16, ""),))
        if not (isinstance(self.min_overlap, (int, float)) and 0 <= self.min_overlap <= 1):
            check.fail("cvgc.min_overlap", self.min_overlap, "a number in [0, 1]")
        check.numbers(self, "cvgc.", ("tau", "multiview_gate"), positive=True)
        check.bools(self, "cvgc.", ("visibility_aware", "enabled", "multiview_mean"))


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
        check.numbers(self, "ash.", ("coarse_size", "s0", "s_min", "s_max", "fixed_size"), positive=True)
        check.bools(self, "ash.", ("enabled",))
        if self.s_min > self.s_max or self.s_max > self.coarse_size:
            check.fail("ash.s_max", self.s_max, f"s_min ({self.s_min}) <= s_max <= coarse_size ({self.coarse_size})")
        if self.coarse_size / self.s_min > 127 or self.coarse_size / self.fixed_size > 1e6:
            want = f">= coarse_size / 127 ({self.coarse_size / 127:.4g}) so a fine index fits 7 bits"
            check.fail("ash.s_min", self.s_min, want)


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
        check.numbers(self, "rps.", ("r_c", "min_weight", "lone_cell_mean"), positive=False)
        if self.r_c >= 1 or self.min_weight >= 1:
            check.fail("rps.r_c" if self.r_c >= 1 else "rps.min_weight", max(self.r_c, self.min_weight), "a number < 1")
        check.numbers(self, "rps.", ("k0", "ratio", "consensus_gate"), positive=True)
        check.ints(self, "rps.", (("k_max", 1, 16, ""), ("lone_cell_keep", 0, 16, " (0 = drop every lone point)")))
        check.ints(self, "rps.", (("k_fixed", 1, self.k_max, " (1..k_max)"),))
        check.bools(self, "rps.", ("enabled", "range_priority", "consensus"))


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
                check.fail(
                    name,
                    getattr(self, name),
                    f"type {kind.__name__} (change one setting with cfg.replace({name}={{...}}))",
                )
        check.numbers(self, "", ("eps",), positive=True)
        check.ints(self, "", (("pixel_stride", 1, 8, ""),))
        check.target_points(self.target_points)
        check.noise_sigma(self.noise_sigma)
        check.bools(self, "", ("budget_stride", "auto_grid"))
        if self.backend not in ("auto", "torch", "numba"):
            check.fail("backend", self.backend, "'auto', 'torch' or 'numba'")

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
