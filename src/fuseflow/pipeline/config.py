"""``PipelineConfig``: the settings of a FUSE-Flow run (FUSE and GMAC keep their own configs)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

from fuseflow.errors import ValidationError

if TYPE_CHECKING:
    from fuseflow.calib import CalibConfig
    from fuseflow.fuse import FuseConfig

__all__ = ["PipelineConfig", "OutputOptions"]


@dataclass(frozen=True)
class OutputOptions:
    """What a run or fuse writes for each frame besides its log (docs/formats.md)."""

    crop: str | None = None
    """None: keep every fused point (cropping is off unless asked); "auto": crop to the capture
    volume (calib.json's ``capture_volume`` when it has one, else the box of what the cameras see
    together, ``geometry.volume.seen_volume``); "xmin,ymin,zmin,xmax,ymax,zmax": that box in the
    output frame (``world``), metres."""
    cloud_format: str = "ply"
    """Cloud files, one or several joined by commas ("ply,drc,glb,splat"): binary PLY (all
    fields), Draco (positions within ``drc_error_mm``, colours), a GLB point cloud (positions,
    colours, weight) or Gaussian splats (``io.splat``, in OUT/splats/). ``formats`` lists them."""
    drc_error_mm: float = 1.0
    """Bound on the Draco position error, millimetres (``io.exchange.draco_bits``)."""
    mesh: bool = False
    """Also write meshes/<frame:06d>.glb (``pipeline.mesh``)."""
    mesh_ply: bool = False
    """With ``mesh``, also meshes/<frame:06d>.ply."""
    mesh_method: str = "range"
    """``pipeline.mesh.MESH_METHODS``: range (default: each camera's points as a range image,
    merged), tsdf, poisson or bpa."""
    world: str | None = None
    """The output frame (``geometry.world``): None = "floor" when a floor is found, else the
    first camera's; "floor"; "camera:<id>"; "calib" (the calibration's world as it is)."""
    voxel_mm: float | None = None
    """Thin each written cloud to one point per cube of this edge (millimetres; the point of
    highest weight in each); None = every fused point."""

    @property
    def formats(self) -> tuple[str, ...]:
        """The cloud formats to write, in the order given."""
        return tuple(dict.fromkeys(f.strip() for f in str(self.cloud_format).split(",") if f.strip()))

    def __post_init__(self) -> None:
        from fuseflow.io.exchange import CLOUD_FORMATS

        bad = [f for f in self.formats if f not in CLOUD_FORMATS]
        if bad or not self.formats:
            raise ValidationError(
                f"--format must be one or more of {', '.join(CLOUD_FORMATS)} joined by commas, got {self.cloud_format!r}"
            )
        if "drc" in self.formats:
            from fuseflow.io.exchange import draco_module

            draco_module()  # FormatError now, before any frame is fused, when DracoPy is missing
        if self.world not in (None, "auto", "floor", "calib") and not (
            isinstance(self.world, str) and self.world.startswith("camera:") and len(self.world) > 7
        ):
            raise ValidationError(f"--world must be floor, camera:ID or calib, got {self.world!r}")
        if self.voxel_mm is not None and not (isinstance(self.voxel_mm, (int, float)) and 0 < self.voxel_mm < 1e4):
            raise ValidationError(f"--voxel must be a positive number of millimetres, got {self.voxel_mm!r}")
        if not (isinstance(self.drc_error_mm, (int, float)) and 0 < self.drc_error_mm < 1e4):
            raise ValidationError(f"drc_error_mm must be a positive number of millimetres, got {self.drc_error_mm!r}")
        if self.mesh_method not in ("tsdf", "poisson", "bpa", "range"):
            raise ValidationError(f"mesh method must be tsdf, poisson, bpa or range, got {self.mesh_method!r}")
        if self.crop is not None and self.crop != "auto":
            from fuseflow.geometry.volume import parse_crop

            parse_crop(self.crop)  # a bad box fails here, before any work


@dataclass(frozen=True)
class PipelineConfig:
    """Settings of a FUSE-Flow run (FUSE and GMAC keep their own configs)."""

    fuse: FuseConfig | None = None
    """fuseflow.fuse.FuseConfig; None = the ``auto`` preset (``PRESETS["auto"]``: the pixel grid
    chosen from the rig), the default of ``fuseflow run`` and ``fuseflow fuse``."""
    calib: CalibConfig | None = None
    """fuseflow.calib.CalibConfig; None = CalibConfig() defaults."""
    device: str = "cpu"
    """Torch device for fusion: "cpu" or "cuda"."""
    recalibrate: Literal["off", "auto"] = "off"
    """"auto": re-run GMAC when a camera is flagged as bumped, and continue with its new pose."""
    min_valid_depth: float = 0.2
    """A frame is "good" for calibration when every camera is present with at least this share of
    pixels with depth. Range (0, 1]."""
    health_samples: int = 5000
    """Pixels per view the health check samples (a regular grid; cost ~ N K_max samples). Default
    5000 (docs/usage.md, "Health"); >= 1."""
    health_tau: float = 0.05
    """Relative depth residual under which a neighbour agrees (the paper's tau, eq. 21)."""
    health_warmup: int = 3
    """Frames whose median agreement becomes each camera's baseline. Range >= 1."""
    health_drop: float = 0.1
    """A pair "fell" when its agreement is this much (absolute share) below its baseline; a
    camera is suspect when most of its pairs fell (HealthMonitor). Range (0, 1)."""
    health_patience: int = 2
    """Consecutive suspect frames before a camera is flagged as bumped. Range >= 1."""
    sync: Literal["off", "check", "auto"] = "check"
    """Camera-sync check (pipeline/sync.py) before fusing; default "check", as ``fuseflow run``
    --sync-offsets. "off" skips it; "check" reports cameras whose depth
    agrees consistently better with their neighbours' earlier or later frames ("cam03 is about
    +2 frames late"); "auto" also re-times them for fusion. Costs ~ 8 x 7 x N restricted
    agreement passes per run."""
    sync_max_shift: int = 3
    """Largest offset, in frames, the sync check looks for. Range >= 1."""
    outputs: OutputOptions = OutputOptions()
    """Crop, cloud format and meshes (``OutputOptions``)."""

    def __post_init__(self) -> None:
        if self.sync not in ("off", "check", "auto"):
            raise ValidationError(f"sync must be 'off', 'check' or 'auto', got {self.sync!r}")
        if self.sync_max_shift < 1:
            raise ValidationError(f"sync_max_shift must be >= 1, got {self.sync_max_shift}")
        if self.recalibrate not in ("off", "auto"):
            raise ValidationError(f"recalibrate must be 'off' or 'auto', got {self.recalibrate!r}")
        if not 0 < self.min_valid_depth <= 1:
            raise ValidationError(f"min_valid_depth must be in (0, 1], got {self.min_valid_depth}")
        for name in ("health_samples", "health_warmup", "health_patience"):
            if getattr(self, name) < 1:
                raise ValidationError(f"{name} must be >= 1, got {getattr(self, name)}")
        if not 0 < self.health_drop < 1:
            raise ValidationError(f"health_drop must be in (0, 1), got {self.health_drop}")

    def fuse_config(self) -> FuseConfig:
        """The FuseConfig to fuse with (``fuse``, else the ``auto`` preset the CLI uses)."""
        from fuseflow.fuse import PRESETS

        return self.fuse if self.fuse is not None else PRESETS["auto"]

    def calib_config(self) -> CalibConfig:
        """The CalibConfig to calibrate with (``calib`` or the defaults)."""
        from fuseflow.calib import CalibConfig

        return self.calib if self.calib is not None else CalibConfig()
