"""GMAC's error type: calibration cannot proceed with this input (beyond a malformed argument)."""

from __future__ import annotations

from fuseflow.errors import FuseFlowError

__all__ = ["CalibrationError", "CalibrationWarning"]


class CalibrationError(FuseFlowError, RuntimeError):
    """The input is well-formed but cannot be calibrated: no depth, textureless images, no
    overlap between cameras, a backbone that registered too few cameras. The message names the
    cameras at fault and what was expected."""


class CalibrationWarning(UserWarning):
    """A calibration that finished but left a camera unplaced or not "good" (one warning per
    camera, its verdict's reason)."""
