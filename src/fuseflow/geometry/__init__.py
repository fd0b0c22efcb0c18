"""Shared multi-view geometry, the layer below FUSE, GMAC and the pipeline (docs/architecture.md).

- :mod:`camera`: pixel rays, back-projection, relative transforms E_j E_i^-1.
- :mod:`overlap`: field-of-view overlap between calibrated cameras and the bounded neighbour
  graph built from it (CVGC's N_i, paper III-C-2).
- :mod:`align`: rigid (Kabsch) alignment of corresponding points, e.g. two calibrations' camera centres.
- :mod:`agreement`: projection into another camera, depth lookup, the agreement vote (eq.
  19-20), and the per-pair / per-camera depth agreement built on it.

Imports only :mod:`fuseflow.types` and :mod:`fuseflow.errors`; ``fuse`` and ``calib`` both
call it and never each other.
"""

from fuseflow.geometry.agreement import (
    camera_agreement,
    depth_agreement,
    one_torch_thread,
    pair_agreement,
    project_votes,
    subsample_stride,
)
from fuseflow.geometry.align import rigid_align
from fuseflow.geometry.camera import backproject, pixel_rays, relative_transforms
from fuseflow.geometry.overlap import NeighbourGraph, fov_overlap, neighbour_graph

__all__ = [
    "NeighbourGraph",
    "backproject",
    "camera_agreement",
    "depth_agreement",
    "fov_overlap",
    "neighbour_graph",
    "one_torch_thread",
    "pair_agreement",
    "pixel_rays",
    "project_votes",
    "relative_transforms",
    "rigid_align",
    "subsample_stride",
]
