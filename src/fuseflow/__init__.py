"""FuseFlow: target-free calibration (GMAC) and stateless multi-view fusion (FUSE) for RGB-D rigs.

Conventions (docs/conventions.md): metres; OpenCV camera axes; ``T_cam_world`` is
camera-from-world; batched tensors put the camera axis first.
"""

from fuseflow.calib import calibrate
from fuseflow.errors import FormatError, FuseFlowError, RecordingError, ValidationError
from fuseflow.fuse.api import fuse_frame as fuse
from fuseflow.io import (
    Recording,
    make_virtual_rig,
    open_recording,
    read_calibration,
    read_ply,
    read_rig,
    write_calibration,
    write_frame,
    write_ply,
    write_rig,
)
from fuseflow.pipeline import run, stream
from fuseflow.types import Calibration, Camera, Frame, FusedCloud, Rig, View

__version__ = "0.3.0"

__all__ = [
    "Calibration",
    "Camera",
    "FormatError",
    "Frame",
    "FuseFlowError",
    "FusedCloud",
    "Recording",
    "RecordingError",
    "Rig",
    "ValidationError",
    "View",
    "calibrate",
    "fuse",
    "make_virtual_rig",
    "open_recording",
    "read_calibration",
    "read_ply",
    "read_rig",
    "run",
    "stream",
    "write_calibration",
    "write_frame",
    "write_ply",
    "write_rig",
]
