"""Which extrinsics a run fuses with: a calibration applied to a rig, a recalibration merged
into the old world frame, and camera indices mapped back to the recording's rig."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable

import numpy as np

from fuseflow.errors import FuseFlowError, ValidationError
from fuseflow.geometry.align import rigid_align  # moved to geometry; re-exported here
from fuseflow.types import Calibration, FusedCloud, Rig, invert_rigid

__all__ = ["placed_rig", "resolve_rig", "rigid_align", "merge_recalibration", "reindex_cameras"]


def placed_rig(rig: Rig, calibration: Calibration) -> Rig:
    """The cameras of ``rig`` that ``calibration`` places, with its extrinsics (FuseFlowError if < 1).

    A calibration that records the rig it was made for (calib.json's ``rig_fingerprint``) is
    refused (FuseFlowError naming the cameras) when a placed camera's resolution or intrinsics
    differ: extrinsics of another rig whose camera ids happen to match."""
    placed = [i for i, c in enumerate(rig.ids) if c in calibration.T_cam_world]
    if not placed:
        raise FuseFlowError(f"the calibration places none of the cameras {list(rig.ids)}")
    differ = _fingerprint_mismatch(rig.subset(placed), calibration)
    if differ:
        raise FuseFlowError(
            "the calibration was made for another rig: intrinsics or resolution differ for cameras "
            + "; ".join(differ)
            + ". Calibrate this recording (fuseflow calibrate), or remove 'rig_fingerprint' from calib.json "
            "if the intrinsics were only refined"
        )
    return calibration.apply(rig.subset(placed))


# Intrinsics may be re-estimated slightly (refined in place); another camera model or resolution
# moves fx or the principal point by far more than this share of fx.
FINGERPRINT_RTOL = 0.005


def _fingerprint_mismatch(rig: Rig, calibration: Calibration) -> list[str]:
    """'<id> (what differs)' for each camera of ``rig`` whose recorded fingerprint differs."""
    try:
        fingerprint = calibration.report.get("rig_fingerprint")
    except AttributeError:
        return []
    if not isinstance(fingerprint, dict):
        return []
    out = []
    for cam in rig.cameras:
        fp = fingerprint.get(cam.id)
        if fp is None:
            continue
        if (fp["width"], fp["height"]) != (cam.width, cam.height):
            out.append(f"{cam.id} ({fp['width']}x{fp['height']} in the calibration, {cam.width}x{cam.height} here)")
            continue
        K = np.asarray(fp["K"], dtype=np.float64)
        if np.abs(K - cam.K).max() > FINGERPRINT_RTOL * cam.K[0, 0]:
            fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
            out.append(
                f"{cam.id} (fx, fy, cx, cy {fx:.1f}, {fy:.1f}, {cx:.1f}, {cy:.1f} in the calibration, "
                f"{cam.K[0, 0]:.1f}, {cam.K[1, 1]:.1f}, {cam.K[0, 2]:.1f}, {cam.K[1, 2]:.1f} here)"
            )
    return out


def resolve_rig(rig: Rig, calibration: Calibration | Rig | None) -> Rig:
    """``rig`` with the extrinsics of ``calibration`` (a Calibration applied to it, a calibrated
    Rig used as is, None: the rig's own); FuseFlowError when a camera is left without extrinsics."""
    if isinstance(calibration, Rig):
        rig = calibration
    elif isinstance(calibration, Calibration):
        rig = calibration.apply(rig)
    elif calibration is not None:
        raise ValidationError(f"calibration must be a Calibration, a Rig or None, got {type(calibration).__name__}")
    if not rig.is_calibrated:
        missing = [c.id for c in rig if not c.is_calibrated]
        raise FuseFlowError(
            f"cameras without extrinsics: {missing}; calibrate first (fuseflow calibrate) or pass --calib"
        )
    return rig


def merge_recalibration(old: Rig, new: Calibration, moved: Iterable[str]) -> Rig:
    """Put the ``moved`` cameras' new poses into the old world frame; others keep theirs.

    GMAC's world frame is arbitrary (a reference camera), so the new calibration is aligned
    to the old one on the cameras that did not move (camera-centre Kabsch; rotations follow
    from the alignment). Needs >= 2 unmoved cameras placed by both, else the new calibration
    replaces the old one whole.
    """
    moved = set(moved)
    anchors = [c.id for c in old.cameras if c.id not in moved and c.id in new.T_cam_world and c.T_cam_world is not None]
    if len(anchors) < 2:
        return new.apply(old)
    src = np.stack([invert_rigid(new.T_cam_world[c])[:3, 3] for c in anchors])
    dst = np.stack([invert_rigid(old[c].T_cam_world)[:3, 3] for c in anchors])
    A_inv = invert_rigid(rigid_align(src, dst))  # A = old_world_from_new_world
    updates = {c: new.T_cam_world[c] @ A_inv for c in moved if c in new.T_cam_world}
    return old.with_extrinsics(updates)


def reindex_cameras(cloud: FusedCloud, sel: list[int]) -> FusedCloud:
    """``cloud.camera`` indexes the fused subset of cameras; map it to the source rig's indices."""
    if cloud.is_numpy:
        return dataclasses.replace(cloud, camera=np.asarray(sel, dtype=np.int16)[cloud.camera])
    import torch

    lut = torch.tensor(sel, dtype=torch.int16, device=cloud.camera.device)
    return dataclasses.replace(cloud, camera=lut[cloud.camera.long()])
