"""File formats and dataset readers. Knows formats, no algorithms (docs/architecture.md)."""

from fuseflow.io.calibration import read_calibration, write_calibration
from fuseflow.io.convert import convert as convert_recordings
from fuseflow.io.datasets import SequenceRecording, make_virtual_rig, open_recording, read_rgbd_pair
from fuseflow.io.ply import read_ply, write_ply
from fuseflow.io.recording import FuseFlowRecording, Recording, read_rig, write_frame, write_rig
from fuseflow.io.timesync import pair_by_timestamp, read_timestamps

__all__ = [
    "FuseFlowRecording",
    "Recording",
    "SequenceRecording",
    "convert_recordings",
    "make_virtual_rig",
    "open_recording",
    "pair_by_timestamp",
    "read_calibration",
    "read_ply",
    "read_rgbd_pair",
    "read_rig",
    "read_timestamps",
    "write_calibration",
    "write_frame",
    "write_ply",
    "write_rig",
]
