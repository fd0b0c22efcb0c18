"""Checks that catch a run that would be silently wrong: before fusing (a depth_range that
excludes every pixel, extrinsics whose translations cannot be in metres) and after (cameras
whose depth does not agree with their neighbours: extrinsics that do not fit the recording,
FUSE's per-frame warnings, empty clouds)."""

from __future__ import annotations

import numpy as np

from fuseflow.errors import ValidationError
from fuseflow.types import Frame, Rig

__all__ = [
    "check_depth_range",
    "check_scale",
    "low_agreement",
    "LOW_AGREEMENT",
    "below_calibration",
    "CALIBRATION_DROP",
    "frame_notes",
]

LOW_AGREEMENT = 0.5
"""A camera whose median depth agreement with its neighbours (``pipeline.health``, tau = 5 %) is
below this fits the recording badly. Measured on frame 0 (``pipeline.health.frame_health``,
5000 samples): right extrinsics 0.90-0.99 on HO-Cap (``convert --with-extrinsics``) and
0.79-0.86 on simulated 4- and 6-camera studios; two HO-Cap cameras swapped 0.12-0.16 (the
others 0.59-0.85), all eight shuffled 0.07-0.23; a 6-camera studio in reverse order 0.20-0.53."""

CALIBRATION_DROP = 0.12
"""A camera whose median agreement in a run is this far below the agreement its calibration
measured (calib.json ``report.depth_agreement``, the same score) no longer fits. Measured: right
extrinsics on a dynamic simulated 4-camera 320x240 room, 32 frames: 0.86-0.89 in the run against
0.87-0.90 at calibration (drops <= 0.02); cam01 and cam02 of a symmetric 3-camera 160x120 studio
swapped (seeds 4-7): 0.48-0.66 against 0.79-0.86 (drops 0.20-0.37), mostly above ``LOW_AGREEMENT``."""

UNIT_FACTOR = 100.0
"""Cameras whose nearest neighbour is more than this many times the deepest measured depth
away cannot share a single point: translations in millimetres (x 1000) land here."""


def _depth_span(frame: Frame, rig: Rig, delta: float, z_max: float) -> tuple[dict[str, int], float, float, float]:
    """Per camera of ``rig`` the pixels with depth inside its depth_range (FUSE's gate), and the
    min, max and 99th percentile of all measured depth in the frame."""
    inside, measured = {}, []
    for cam in rig:
        i = frame.camera_ids.index(cam.id)
        if not bool(frame.present[i]):
            continue
        d = frame.depth[i].detach().cpu().numpy()
        d = d[d > 0]
        lo, hi = max(cam.depth_range[0], delta), min(cam.depth_range[1], z_max)
        inside[cam.id] = int(((d >= lo) & (d <= hi)).sum())
        measured.append(d)
    allm = np.concatenate(measured) if measured else np.zeros(0)
    if not allm.size:
        return inside, 0.0, 0.0, 0.0
    return inside, float(allm.min()), float(allm.max()), float(np.percentile(allm, 99))


def check_depth_range(frame: Frame, rig: Rig, delta: float, z_max: float) -> list[str]:
    """ValidationError when no measured depth of ``frame`` lies inside any camera's depth_range
    (every cloud would be empty); a warning per camera whose own range excludes all its depth."""
    inside, lo, hi, _ = _depth_span(frame, rig, delta, z_max)
    if hi == 0.0 or not inside:
        return []
    ranges = ", ".join(f"{c.id} {c.depth_range[0]:g}-{c.depth_range[1]:g} m" for c in rig if c.id in inside)
    if not any(inside.values()):
        raise ValidationError(
            f"no depth pixel of frame {frame.index} lies inside the cameras' depth_range ({ranges}; FUSE also keeps "
            f"only {delta:g}-{z_max:g} m) while the measured depth spans {lo:.2f}-{hi:.2f} m: every cloud would be "
            "empty; fix depth_range in rig.json (metres) or the depth scale"
        )
    out = [c for c, n in inside.items() if n == 0]
    if not out:
        return []
    return [f"cameras {out}: no depth pixel of frame {frame.index} lies inside their depth_range; they add nothing"]


def check_scale(frame: Frame, rig: Rig, delta: float, z_max: float) -> list[str]:
    """Extrinsics against the measured depth: ValidationError when every camera's nearest
    neighbour is more than ``UNIT_FACTOR`` x the deepest measurement away (translations in
    millimetres); a warning when it is more than twice that (no two cameras can see one point)."""
    if len(rig) < 2:
        return []
    _, _, _, deep = _depth_span(frame, rig, delta, z_max)
    if deep <= 0.0:
        return []
    centres = np.array([c.T_world_cam[:3, 3] for c in rig if c.T_world_cam is not None])
    if len(centres) < 2:
        return []
    dist = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    np.fill_diagonal(dist, np.inf)
    nearest = dist.min(axis=1)
    near, far = float(nearest.min()), float(nearest.max())
    said = f"the extrinsics place each camera {near:.3g}-{far:.3g} m from its nearest neighbour while depth reaches {deep:.2f} m"
    if near > UNIT_FACTOR * deep:
        raise ValidationError(
            f"{said}: the translations look like millimetres (calibrations are in metres); divide them by 1000 "
            "or calibrate again (fuseflow calibrate)"
        )
    if near > 2.0 * deep:
        return [f"{said}: no two cameras can see one point (translations in other units?)"]
    return []


def low_agreement(records, threshold: float = LOW_AGREEMENT) -> str | None:
    """A warning naming the cameras whose median agreement over ``records`` (FrameRecord) is
    below ``threshold``, or None."""
    low = {c: a for c, a in _medians(records).items() if a < threshold}
    if not low:
        return None
    named = ", ".join(f"{c} {a:.2f}" for c, a in low.items())
    return (
        f"cameras whose depth disagrees with their neighbours (median agreement {named}; about 0.8 or more "
        "when the extrinsics fit): the calibration does not fit this recording (cameras swapped or renamed, "
        "another rig's calibration, or moved since); check it, or calibrate this recording (drop --calib / --use-rig)"
    )


def _medians(records) -> dict[str, float]:
    values: dict[str, list[float]] = {}
    for r in records:
        for c, a in r.agreement.items():
            if a is not None:
                values.setdefault(c, []).append(float(a))
    return {c: float(np.median(v)) for c, v in values.items() if v}


def below_calibration(records, calibrated: dict | None, drop: float = CALIBRATION_DROP) -> str | None:
    """A warning naming the cameras whose median agreement over ``records`` fell more than ``drop``
    below what their calibration measured (``calibrated``: camera id -> agreement, from calib.json's
    report; None or empty: no check), leaving out those ``low_agreement`` already names; or None."""
    if not calibrated:
        return None
    low = {
        c: (a, float(calibrated[c]))
        for c, a in _medians(records).items()
        if isinstance(calibrated.get(c), (int, float)) and LOW_AGREEMENT <= a < float(calibrated[c]) - drop
    }
    if not low:
        return None
    named = ", ".join(f"{c} {a:.2f} (calibration: {b:.2f})" for c, (a, b) in low.items())
    return (
        f"cameras whose depth agrees with their neighbours less than when they were calibrated ({named}): "
        "the calibration may not fit this recording (cameras swapped or renamed, or moved since); check it, "
        "or calibrate this recording (drop --calib / --use-rig)"
    )


def frame_notes(records) -> list[str]:
    """FUSE's per-frame warnings (``FrameRecord.notes``) grouped by kind: "<kind> at frames 0, 3"."""
    frames: dict[str, list[int]] = {}
    for r in records:
        for note in r.notes:
            frames.setdefault(note, []).append(r.index)
    out = []
    for note, nums in frames.items():
        head = ", ".join(map(str, nums[:10]))
        out.append(f"{note} at frames {head}" + (f" and {len(nums) - 10} more" if len(nums) > 10 else ""))
    return out
