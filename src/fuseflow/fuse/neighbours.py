"""The neighbour graph N_i of CVGC (paper III-C-2, |N_i| <= K_max; docs/design.md 2.2).

The graph is pure geometry of the calibrated rig (field-of-view overlap, nothing about the
scene), so it lives in :mod:`fuseflow.geometry.overlap`, where GMAC's depth-agreement check and
the pipeline's health monitor use it too. This module is where a reader of the paper finds it
from the FUSE side.
"""

from fuseflow.geometry.overlap import NeighbourGraph, fov_overlap, neighbour_graph

__all__ = ["NeighbourGraph", "neighbour_graph", "fov_overlap"]
