"""GMAC on a recording's frames, pooling frames when one is not enough: shared by
``fuseflow calibrate`` and ``fuseflow run`` (the policy: :mod:`fuseflow.calib.pooling`, which
``fuseflow.calibrate(recording)`` uses too)."""

from __future__ import annotations

from collections.abc import Callable

from fuseflow.calib.pooling import POOLED_FRAMES, Calibrated, missing_positions, pooled_calibration, spread_positions
from fuseflow.io.recording import Recording
from fuseflow.types import Frame

__all__ = ["POOLED_FRAMES", "Calibrated", "calibrate_frames", "missing_positions", "spread_positions"]


def calibrate_frames(
    rec: Recording,
    positions: list[int],
    config,
    pool: bool,
    progress: Callable | None = None,
    frames: list[Frame] | None = None,
) -> Calibrated:
    """``calib.pooling.pooled_calibration`` with ``fuseflow.calib.calibrate`` as the attempt:
    GMAC on the frames at ``positions``; with ``pool`` (the user chose no frame) and 3 or more
    frames, frames spread over the recording are pooled when the one frame raises or leaves a
    camera not "good". Raises CalibrationError when no attempt places two cameras."""
    import fuseflow.calib as calib

    return pooled_calibration(rec, positions, config, pool, calib.calibrate, progress=progress, frames=frames)
