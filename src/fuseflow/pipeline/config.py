"""``PipelineConfig``: the settings of a FUSE-Flow run (FUSE and GMAC keep their own configs)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

from fuseflow.errors import ValidationError

if TYPE_CHECKING:
    from fuseflow.calib import CalibConfig
    from fuseflow.fuse import FuseConfig

__all__ = ["PipelineConfig"]


@dataclass(frozen=True)
class PipelineConfig:
    """Settings of a FUSE-Flow run (FUSE and GMAC keep their own configs)."""

    fuse: FuseConfig | None = None
    """fuseflow.fuse.FuseConfig; None = FuseConfig() defaults."""
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
    sync: Literal["off", "check", "auto"] = "off"
    """Camera-sync check (pipeline/sync.py) before fusing: "check" reports cameras whose depth
    agrees consistently better with their neighbours' earlier or later frames ("cam03 is about
    +2 frames late"); "auto" also re-times them for fusion. Costs ~ 8 x 7 x N restricted
    agreement passes per run."""
    sync_max_shift: int = 3
    """Largest offset, in frames, the sync check looks for. Range >= 1."""

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
        """The FuseConfig to fuse with (``fuse`` or the defaults)."""
        from fuseflow.fuse import FuseConfig

        return self.fuse if self.fuse is not None else FuseConfig()

    def calib_config(self) -> CalibConfig:
        """The CalibConfig to calibrate with (``calib`` or the defaults)."""
        from fuseflow.calib import CalibConfig

        return self.calib if self.calib is not None else CalibConfig()
