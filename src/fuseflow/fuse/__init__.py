"""FUSE: stateless, reliability-guided multi-view point cloud fusion (paper III-C).

``fuse(frame, rig, config=FuseConfig()) -> FusedCloud``. One module per component: smooth
(noise-aware depth smoothing before MCM, beyond the paper), mcm (eq. 16-18), neighbours (the camera graph), cvgc (eq. 19-21), weights (eq. 22), ash (eq. 23-25),
rps (eq. 26-28); api prepares a frame and dispatches to one of two drivers, torch_driver (the
PyTorch reference, any device) or kernels/ (the compiled CPU path; numba is imported only when
that path runs); config holds the settings, presets the named ones and auto_config.
See docs/architecture.md and docs/fuse.md.
"""

from fuseflow.fuse.api import FuseReport, FuseResult, fuse, fuse_with_report, resolve_backend
from fuseflow.fuse.config import ASHConfig, CVGCConfig, FuseConfig, MCMConfig, RPSConfig, SmoothingConfig
from fuseflow.fuse.neighbours import NeighbourGraph, neighbour_graph
from fuseflow.fuse.presets import ABLATIONS, NOISE_SIGMA, PRESETS, preset

__all__ = [
    "ABLATIONS",
    "ASHConfig",
    "CVGCConfig",
    "MCMConfig",
    "RPSConfig",
    "SmoothingConfig",
    "NOISE_SIGMA",
    "PRESETS",
    "FuseConfig",
    "FuseReport",
    "FuseResult",
    "NeighbourGraph",
    "fuse",
    "fuse_with_report",
    "neighbour_graph",
    "preset",
    "resolve_backend",
]
