"""The one validation of a fusion's inputs, shared by ``fuse``, ``run``, ``live`` and the Python
API (``fuseflow.stream``): ``validate_inputs`` on the first frame to fuse, before any cloud is
written, and the checks after fusing.

Before (``validate_inputs``): a depth_range (or ``mcm.delta`` / ``mcm.z_max``) that excludes every
pixel, extrinsics whose translations cannot be in metres, a crop box that holds no measured
point (each a ValidationError: every cloud would be empty), cameras whose depth disagrees with
their neighbours and two cameras whose extrinsics look exchanged (warnings). Settings that
overflow the float32 kernels are refused by ``FuseConfig`` itself. After: cameras whose depth
does not agree with their neighbours over the run, FUSE's per-frame warnings, empty clouds."""

from __future__ import annotations

import itertools
from typing import TYPE_CHECKING

import numpy as np

from fuseflow.errors import ValidationError
from fuseflow.types import Frame, Rig, to_numpy

if TYPE_CHECKING:
    from fuseflow.fuse import FuseConfig
    from fuseflow.geometry.volume import CaptureVolume

__all__ = [
    "validate_inputs",
    "check_crop",
    "check_swaps",
    "SWAP_GAIN",
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
        d = to_numpy(frame.depth[i])
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


MIN_AGREEMENT_PIXELS = 64 * 48
"""``low_agreement`` judges views of at least this many pixels. Agreement falls with resolution
at the right extrinsics (each pixel spans more surface): medians over the cameras of frame 0 of
simulated studios (seed 4, 5000 samples, tau 5 %): 8 cameras 0.83 at 160x120, 0.70 at 80x60,
0.65 at 64x48, 0.56 at 48x36, 0.46 at 32x24; 32 cameras 0.65 at 64x48, 0.47 at 32x24 (0.39-0.64)."""


def low_agreement(records, threshold: float = LOW_AGREEMENT, view_pixels: int | None = None) -> str | None:
    """A warning naming the cameras whose median agreement over ``records`` (FrameRecord) is
    below ``threshold``, or None. Views smaller than ``MIN_AGREEMENT_PIXELS`` (``view_pixels``:
    the smallest camera's width x height) are too coarse to judge: a line says the check was
    not made when some camera is below ``threshold`` there."""
    low = {c: a for c, a in _medians(records).items() if a < threshold}
    if low and view_pixels is not None and view_pixels < MIN_AGREEMENT_PIXELS:
        return (
            f"the depth-agreement check of the calibration was not made: views of {view_pixels} pixels are too "
            f"small to judge it (agreement is low at any extrinsics below {MIN_AGREEMENT_PIXELS} pixels, 64x48)"
        )
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


SWAP_GAIN = 0.04
"""Two cameras look exchanged when exchanging their extrinsics raises the rig's mean depth
agreement (``geometry.camera_agreement`` of one frame, ``SWAP_SAMPLES`` samples a view, tau 5 %)
by more than this. Measured on frame 0 of ``fuseflow simulate --scene studio --resolution
160x120 --seed 4`` recordings and of HO-Cap's 8 RealSense cameras (``fuseflow convert
--with-extrinsics``): with the right extrinsics every exchange scores 0.06-0.20 below them (3, 4,
6 and 8 cameras: 0.82, 0.80, 0.83, 0.82 against a best exchange of 0.63, 0.65, 0.74, 0.76;
HO-Cap 0.91 against 0.74); with cam00 and cam01 exchanged, exchanging them back scores 0.09-0.36
above (0.63 -> 0.82, 0.65 -> 0.80, 0.74 -> 0.83, 0.73 -> 0.82; HO-Cap 0.55 -> 0.91). The
threshold sits between the two; ``tests/faults/test_checks.py`` holds it on 3, 6 and 12 cameras."""

SWAP_SAMPLES = 1500
"""Depth samples a view for the exchange test: HO-Cap's 28 pairs (8 cameras, 640x480) took 0.35 s
in one measurement and 1.2-1.5 s in another on the project's shared 2-core machine (load average
17 during the second; the whole ``validate_inputs`` 1.3 s there, a process's first call 5.4 s
with its imports)."""

SWAP_ALL_PAIRS = 10
"""Rigs of up to this many cameras test every pair; larger rigs test the pairs among the
``SWAP_WORST`` cameras that agree least (two exchanged cameras both disagree)."""

SWAP_WORST = 6


def _subset(frame: Frame, rig: Rig) -> Frame:
    """The views of ``rig``'s cameras, in its order."""
    if tuple(frame.camera_ids) == rig.ids:
        return frame
    return frame.subset([frame.camera_ids.index(c) for c in rig.ids])


def _mean_agreement(frame: Frame, rig: Rig) -> tuple[float, np.ndarray]:
    from fuseflow.geometry import camera_agreement, pair_agreement

    per_camera = camera_agreement(pair_agreement(frame.to("cpu"), rig, SWAP_SAMPLES, 0.05))
    finite = per_camera[np.isfinite(per_camera)]
    return (float(finite.mean()) if finite.size else float("nan")), per_camera


def check_swaps(frame: Frame, rig: Rig, absolute: bool = True) -> list[str]:
    """A warning naming two cameras whose extrinsics look exchanged (exchanging them raises the
    mean depth agreement of ``frame`` by more than ``SWAP_GAIN``), and with ``absolute`` one
    naming the cameras whose agreement in ``frame`` is below ``LOW_AGREEMENT`` (views of at
    least ``MIN_AGREEMENT_PIXELS``), or none. ``frame`` holds the views of ``rig`` in its
    order; rigs of fewer than 2 cameras are not tested."""
    placed = [c for c in rig if c.T_cam_world is not None]
    if len(placed) < 2 or len(placed) != len(rig):
        return []
    base, per_camera = _mean_agreement(frame, rig)
    if not np.isfinite(base):
        return []
    out = []
    low = {c: float(a) for c, a in zip(rig.ids, per_camera) if np.isfinite(a) and a < LOW_AGREEMENT}
    if absolute and low and min(c.width * c.height for c in rig) >= MIN_AGREEMENT_PIXELS:
        named = ", ".join(f"{c} {a:.2f}" for c, a in low.items())
        out.append(
            f"cameras whose depth disagrees with their neighbours in frame {frame.index} (agreement {named}; "
            "about 0.8 or more when the extrinsics fit): the calibration does not fit this recording (cameras "
            "swapped or renamed, another rig's calibration, or moved since); check it, or calibrate this recording"
        )
    ids = rig.ids
    order = list(range(len(ids)))
    if len(ids) > SWAP_ALL_PAIRS:
        order = sorted(order, key=lambda i: per_camera[i] if np.isfinite(per_camera[i]) else -1.0)[:SWAP_WORST]
    T = {c.id: c.T_cam_world for c in rig}
    best, pair = base, None
    for i, j in itertools.combinations(order, 2):
        swapped = dict(T)
        swapped[ids[i]], swapped[ids[j]] = T[ids[j]], T[ids[i]]
        score, _ = _mean_agreement(frame, rig.with_extrinsics(swapped))
        if np.isfinite(score) and score > best:
            best, pair = score, (ids[min(i, j)], ids[max(i, j)])
    if pair is None or best - base <= SWAP_GAIN:
        return out
    return out + [
        f"cameras {pair[0]} and {pair[1]} look exchanged: their depth agrees with their neighbours' "
        f"{best:.2f} with their extrinsics swapped, {base:.2f} as given (mean over the rig, frame {frame.index}); "
        "check the camera ids in calib.json (cables or serial numbers exchanged?) or calibrate this recording"
    ]


def _world_samples(frame: Frame, rig: Rig, delta: float, z_max: float, per_view: int = 4000) -> np.ndarray:
    """(M, 3) world points of a subsampled grid of each present view's depth inside its range."""
    out = []
    for cam in rig:
        i = frame.camera_ids.index(cam.id)
        if not bool(frame.present[i]) or cam.T_world_cam is None:
            continue
        d = to_numpy(frame.depth[i])
        h, w = d.shape
        s = max(1, int(np.sqrt(h * w / per_view)))
        v, u = np.mgrid[0:h:s, 0:w:s]
        z = d[::s, ::s]
        lo, hi = max(cam.depth_range[0], delta), min(cam.depth_range[1], z_max)
        ok = np.isfinite(z) & (z >= lo) & (z <= hi)
        K = cam.K
        x = (u[ok] - K[0, 2]) / K[0, 0] * z[ok]
        y = (v[ok] - K[1, 2]) / K[1, 1] * z[ok]
        X = np.stack([x, y, z[ok]], axis=1)
        T = cam.T_world_cam
        out.append(X @ T[:3, :3].T + T[:3, 3])
    return np.concatenate(out) if out else np.zeros((0, 3))


def check_crop(frame: Frame, rig: Rig, volume: CaptureVolume | None, delta: float, z_max: float) -> None:
    """ValidationError when the crop box ``volume`` holds none of ``frame``'s measured points
    (sampled, inside the depth ranges): every cropped cloud would be empty."""
    if volume is None:
        return
    pts = _world_samples(frame, rig, delta, z_max)
    if not len(pts) or volume.contains(pts).any():
        return
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    span = ", ".join(f"{a} {a0:.2f} to {a1:.2f}" for a, a0, a1 in zip("xyz", lo, hi))
    box = ", ".join(f"{v:g}" for v in [*volume.lo, *volume.hi])
    raise ValidationError(
        f"the crop box ({volume.kind}: {box}, metres, world frame) holds none of the {len(pts)} measured points "
        f"sampled from frame {frame.index} (they span {span} m): every cloud would be empty; widen the box, check "
        "that it is in metres (calib.json's capture_volume 'units'), or crop with auto or off"
    )


def validate_inputs(
    frame: Frame,
    rig: Rig,
    cfg: FuseConfig,
    volume: CaptureVolume | None = None,
    swaps: bool = True,
    agreement: bool = True,
) -> list[str]:
    """Every check before fusing, on one frame (the first to fuse) of the views of ``rig``'s
    cameras: ValidationError when every cloud would be empty (depth_range or the settings'
    delta / z_max exclude every pixel, translations in millimetres, a crop box with no point),
    else the warnings (cameras outside their range, cameras that cannot share a point; with
    ``swaps`` two cameras exchanged, and with ``agreement`` cameras whose depth disagrees with
    their neighbours in this frame: ``run`` judges that over all its frames instead). What
    ``fuse``, ``run``, ``live`` and ``stream`` run."""
    frame = _subset(frame, rig)
    delta, z_max = cfg.mcm.delta, cfg.mcm.z_max
    warnings = check_depth_range(frame, rig, delta, z_max)
    warnings += check_scale(frame, rig, delta, z_max)
    check_crop(frame, rig, volume, delta, z_max)
    if swaps:
        warnings += check_swaps(frame, rig, absolute=agreement)
    return warnings
