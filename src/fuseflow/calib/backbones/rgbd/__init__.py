"""Metric RGB-D backbone (package): camera poses in metres from sensor depth."""

from fuseflow.calib.backbones.rgbd.backbone import (
    ALIASED_PAIRS,
    SUBJECT_MARGIN_M,
    SUBJECT_REFUTE_M,
    CameraEvidence,
    PairCheck,
    RGBDConfig,
    merge_repeats,
    nanmedian_frames,
    plausible,
    prepare_camera,
    relative_error,
    rgbd_backbone,
    verify_pose,
)
from fuseflow.calib.backbones.rgbd.matchers import MATCHERS, get_matcher

__all__ = [
    "ALIASED_PAIRS",
    "MATCHERS",
    "SUBJECT_MARGIN_M",
    "SUBJECT_REFUTE_M",
    "CameraEvidence",
    "PairCheck",
    "RGBDConfig",
    "get_matcher",
    "merge_repeats",
    "nanmedian_frames",
    "plausible",
    "prepare_camera",
    "relative_error",
    "rgbd_backbone",
    "verify_pose",
]
