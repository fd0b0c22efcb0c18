"""FUSE-Flow (paper III-D, eq. 29): calibrate once with GMAC, then fuse every frame with FUSE.

Neither stage keeps scene state between frames. The pipeline adds what a deployment needs
around them, all explicit and per run, one module each:

- :mod:`runner`: ``run(rec, out_dir)``: calibrate on the first good frame (or take given
  extrinsics), fuse every frame to ``out_dir/clouds/<frame:06d>.ply``, keep a per-frame log
  (``frames.jsonl``) and a summary (``summary.json``); running again resumes where it stopped.
- :mod:`frames`: the per-frame work (``process_frame``) and ``stream(source, calibration)``, an
  iterator of FusedCloud from a recording or a live source.
- :mod:`fuse_only`: ``fuse_recording``, FUSE only with known extrinsics (``fuseflow fuse``).
- :mod:`health`: ``HealthMonitor`` flags a camera whose neighbour pairs all lost depth agreement
  (bumped); with ``recalibrate="auto"`` GMAC re-runs and its new pose joins the old world frame.
- :mod:`extrinsics`: which extrinsics are fused (placed cameras, merged recalibrations).
- :mod:`outputs`, :mod:`records`: the output directory and the typed per-frame and run records.
- :mod:`exports`, :mod:`mesh`: per-frame files (``OutputOptions``: ``--crop``, ``--format``,
  ``--mesh``), ``resolve_crop`` for any frame loop, the manifest's ``sequence``.
- :mod:`ray`: scale-out over frames on Ray (optional extra ``fuseflow[ray]``).

Imports calib and fuse (lazily, where used); neither imports it.
"""

from fuseflow.geometry import camera_agreement, pair_agreement
from fuseflow.pipeline.config import OutputOptions, PipelineConfig
from fuseflow.pipeline.exports import resolve_crop
from fuseflow.pipeline.extrinsics import merge_recalibration, placed_rig, reindex_cameras, resolve_rig, rigid_align
from fuseflow.pipeline.frames import first_good_frame, process_frame, stream
from fuseflow.pipeline.fuse_only import FuseRunSummary, fuse_recording, rig_for_fusion
from fuseflow.pipeline.health import HealthMonitor, frame_health
from fuseflow.pipeline.outputs import cloud_path, read_frame_log
from fuseflow.pipeline.ray import RayOptions
from fuseflow.pipeline.records import FrameRecord, RunSummary
from fuseflow.pipeline.runner import CalibrationChoice, choose_calibration, run

__all__ = [
    "CalibrationChoice",
    "FrameRecord",
    "FuseRunSummary",
    "HealthMonitor",
    "OutputOptions",
    "PipelineConfig",
    "RayOptions",
    "RunSummary",
    "camera_agreement",
    "choose_calibration",
    "cloud_path",
    "first_good_frame",
    "frame_health",
    "fuse_recording",
    "merge_recalibration",
    "pair_agreement",
    "placed_rig",
    "process_frame",
    "read_frame_log",
    "reindex_cameras",
    "resolve_crop",
    "resolve_rig",
    "rig_for_fusion",
    "rigid_align",
    "run",
    "stream",
]
