"""GMAC: target-free metric extrinsic calibration from one multi-view RGB-D frame (paper III-B).

``calibrate(frame_or_frames, rig, config=CalibConfig()) -> Calibration``. See design.md in this folder for
the stages and where they depart from the paper (docs/design.md section 3). Never imports
``fuseflow.fuse``, ``fuseflow.pipeline`` or ``fuseflow.eval`` (shared geometry comes from
``fuseflow.geometry``); pycolmap and Open3D are imported inside the stages that
use them.
"""

from fuseflow.calib.api import calibrate, metric_scale
from fuseflow.calib.backbones import BackboneResult, get_backbone
from fuseflow.calib.config import PRESETS, CalibConfig
from fuseflow.calib.errors import CalibrationError
from fuseflow.calib.report import CalibReport

__all__ = [
    "BackboneResult",
    "CalibConfig",
    "CalibReport",
    "CalibrationError",
    "PRESETS",
    "calibrate",
    "get_backbone",
    "metric_scale",
]
