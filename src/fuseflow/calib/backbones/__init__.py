"""Backbones: scale-ambiguous camera poses (paper eq. 3) from one multi-view RGB(-D) frame.

A backbone is a callable ``backbone(frame, rig, config) -> BackboneResult``. Implementations:

* ``auto`` (the default, :mod:`fuseflow.calib.auto`): ``rgbd`` first, ``colmap`` for the cameras
  it leaves unplaced or suspect, each camera from the source with the better depth agreement.
* ``colmap``: pycolmap SIFT + exhaustive matching + incremental mapping with the rig's
  fixed intrinsics; for N = 2 (which COLMAP's mappers refuse) the two-view relative pose stored
  in the matching database. Offline, CPU, no weights.
* ``precomputed``: an ``.npz`` exported by VGGT / MapAnything / VGGSfM run elsewhere
  (layout in :mod:`fuseflow.calib.backbones.precomputed`, exporter ``scripts/export_backbone.py``).
* ``vggt``, ``mapanything``: run those packages from a local checkpoint when installed.
* ``rgbd``: metric poses from sensor depth for sparse wide-baseline rigs (floor-rectified and
  depth-lifted SIFT, every pair verified by depth agreement, pose graph);
  :mod:`fuseflow.calib.backbones.rgbd`.

Unless the result says ``metric=True``, its translation scale is treated as unknown.
"""

from __future__ import annotations

from collections.abc import Callable

from fuseflow.calib.backbones.base import BackboneResult
from fuseflow.calib.errors import CalibrationError

__all__ = ["BackboneResult", "get_backbone", "BACKBONES", "MULTI_FRAME_BACKBONES"]


def _colmap(frame, rig, config):
    from fuseflow.calib.backbones.colmap import colmap_backbone

    return colmap_backbone(frame, rig, config)


def _precomputed(frame, rig, config):
    from fuseflow.calib.backbones.precomputed import load_precomputed

    if not config.backbone_path:
        raise CalibrationError("backbone 'precomputed' needs backbone_path (the exported .npz)")
    return load_precomputed(config.backbone_path, rig)


def _vggt(frame, rig, config):
    from fuseflow.calib.backbones.neural import vggt_backbone

    return vggt_backbone(frame, rig, config)


def _mapanything(frame, rig, config):
    from fuseflow.calib.backbones.neural import mapanything_backbone

    return mapanything_backbone(frame, rig, config)


def _rgbd(frame, rig, config):
    from fuseflow.calib.backbones.rgbd import rgbd_backbone

    return rgbd_backbone(frame, rig, config)


BACKBONES: dict[str, Callable] = {
    "colmap": _colmap,
    "precomputed": _precomputed,
    "vggt": _vggt,
    "mapanything": _mapanything,
    "rgbd": _rgbd,
}


#: Backbones called with every frame given to ``calibrate`` (a list of Frames of a static rig,
#: cameras in the rig's order); the others get the first frame.
MULTI_FRAME_BACKBONES = frozenset({"rgbd"})


def get_backbone(name: str) -> Callable:
    """The backbone callable registered under ``name``."""
    try:
        return BACKBONES[name]
    except KeyError:
        raise CalibrationError(f"unknown backbone {name!r}; available: {sorted(BACKBONES)}") from None
