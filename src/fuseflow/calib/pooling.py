"""GMAC on a recording's frames, pooling frames when one is not enough: the one policy behind
``fuseflow.calibrate(recording)``, ``fuseflow calibrate`` and ``fuseflow run``.

``pooled_calibration`` runs GMAC (the ``attempt`` function: ``calib.calibrate``) on the chosen
frames; with ``pool`` (the caller chose no frame) and 3 or more frames in the recording, when the
one frame raises ``CalibrationError`` or leaves a camera not "good", GMAC runs again on up to
POOLED_FRAMES frames spread over the recording (a person or a ball moving through a static rig is
then a target: the moving-subject and moving-sphere routes). Each attempt's "good" cameras are
checked against the other attempt's extrinsics (``verdicts.cross_check``: a camera whose distance
to another the two put more than ``verdicts.GOOD_MM`` apart is "check it"). Then the result with
more "good" cameras is kept, then the one with more placed cameras not sharing a spot with
another (``unstacked_count``: two cameras on one spot prove a fold), then more cameras whose room turn is
settled (``turn_checked_count``: not "ambiguous", no turn the subject chose left unapplied), then
more placed; a tie keeps the one frame's. A backbone that reads the first
frame only (``colmap``, the neural ones, ``precomputed``: not ``auto`` or ``MULTI_FRAME_BACKBONES``)
is not pooled: more frames would give it the same poses. The attempts' own
``CalibrationWarning``s are held back: the caller warns once, about the result it keeps
(``warn_verdicts``)."""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from fuseflow.calib.backbones import MULTI_FRAME_BACKBONES
from fuseflow.calib.errors import CalibrationError, CalibrationWarning
from fuseflow.calib.verdicts import STACKED_M, cross_check
from fuseflow.types import Calibration, Frame, Rig, invert_rigid

__all__ = [
    "POOLED_FRAMES",
    "Calibrated",
    "RecordingLike",
    "first_complete",
    "good_count",
    "missing_positions",
    "pooled_calibration",
    "spread_positions",
    "turn_checked_count",
    "unstacked_count",
    "warn_verdicts",
]

#: Frames pooled when one frame leaves a camera not "good" (10 cameras x 10 frames of a symmetric
#: studio calibrate in about a minute on 2 cores: docs/gmac.md).
POOLED_FRAMES = 10


@runtime_checkable
class RecordingLike(Protocol):
    """What pooling reads of a recording (``fuseflow.io.Recording`` has it; calib does not import
    io's readers): ``len(rec)``, ``rec[t]`` (a Frame), ``rec.rig``, ``rec.frame_numbers`` and
    ``rec.missing_views()``."""

    rig: Rig
    frame_numbers: Any

    def __len__(self) -> int: ...

    def __getitem__(self, t: int) -> Frame: ...

    def missing_views(self) -> dict[str, list[int]]: ...


@dataclass
class Calibrated:
    """GMAC's result, the frame positions it used, those frames, and what the pooling did (lines
    for a user)."""

    calibration: Calibration
    positions: list[int]
    frames: list[Frame]
    notes: list[str] = field(default_factory=list)


def missing_positions(rec: RecordingLike) -> dict[int, set[str]]:
    """Frame position -> ids of the cameras with no view there, from the file listings (empty when
    the reader cannot tell without decoding)."""
    try:
        by_camera = rec.missing_views()
    except NotImplementedError:
        return {}
    position = {number: t for t, number in enumerate(rec.frame_numbers)}
    out: dict[int, set[str]] = {}
    for cam, numbers in by_camera.items():
        for number in numbers:
            if number in position:
                out.setdefault(position[number], set()).add(cam)
    return out


def first_complete(rec: RecordingLike) -> int:
    """The first frame position with every camera present (0 when none is)."""
    missing = missing_positions(rec)
    return next((t for t in range(len(rec)) if t not in missing), 0)


def spread_positions(rec: RecordingLike, first: int) -> list[int]:
    """Up to POOLED_FRAMES frame positions spread evenly over the recording, ``first`` first,
    frames with every camera present preferred (the first one carries the scale stage)."""
    missing = missing_positions(rec)
    pick_from = [t for t in range(len(rec)) if t not in missing]
    if len(pick_from) < 3:
        pick_from = list(range(len(rec)))
    k = min(POOLED_FRAMES, len(pick_from))
    chosen = [pick_from[int(i)] for i in np.linspace(0, len(pick_from) - 1, k).round()]
    return [first] + sorted(set(chosen) - {first})


def good_count(calibration: Calibration) -> int:
    """Cameras whose verdict is "good"."""
    verdicts = getattr(calibration.report, "camera_verdicts", None) or {}  # a dict report has none
    return sum(v.get("verdict") == "good" for v in verdicts.values())


def unstacked_count(calibration: Calibration) -> int:
    """Placed cameras whose centre is at least ``verdicts.STACKED_M`` from every other placed
    camera's: two cameras on one spot cannot both be right (a repeating room folds cameras onto
    each other's spots), so neither counts."""
    T = calibration.T_cam_world
    if len(T) < 2:
        return len(T)
    centres = np.stack([invert_rigid(np.asarray(M))[:3, 3] for M in T.values()])
    d = np.linalg.norm(centres[:, None] - centres[None], axis=2)
    np.fill_diagonal(d, np.inf)
    return int((d.min(axis=1) >= STACKED_M).sum())


def turn_checked_count(calibration: Calibration) -> int:
    """Placed cameras whose room turn nothing leaves open: not "ambiguous" (a repeating room whose
    turn the subject could not decide) and not turned by the subject's choice without applying it."""
    verdicts = getattr(calibration.report, "camera_verdicts", None) or {}
    out = 0
    for c in calibration.T_cam_world:
        v = verdicts.get(c) or {}
        turn = v.get("turn") or {}
        out += v.get("verdict") != "ambiguous" and not turn.get("turn")
    return out


def _rank(calibration: Calibration) -> tuple[int, int, int, int]:
    return (good_count(calibration), unstacked_count(calibration), turn_checked_count(calibration),
            len(calibration.T_cam_world))  # fmt: skip


def _cross_checked(calibration: Calibration, other: Calibration, what: str) -> None:
    """``calibration``'s verdicts checked against ``other``'s extrinsics (``verdicts.cross_check``)."""
    verdicts = getattr(calibration.report, "camera_verdicts", None)
    if verdicts:
        calibration.report.camera_verdicts = cross_check(verdicts, calibration.T_cam_world, other.T_cam_world, what)


def _quiet(attempt: Callable, frames: list[Frame], rig: Rig, config, progress) -> Calibration:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)
        return attempt(frames, rig, config, progress=progress)


def pooled_calibration(
    rec: RecordingLike,
    positions: list[int],
    config,
    pool: bool,
    attempt: Callable,
    progress: Callable | None = None,
    frames: list[Frame] | None = None,
) -> Calibrated:
    """GMAC (``attempt(frames, rig, config, progress=...)``) on the frames at ``positions``, pooled
    as the module docstring says. ``frames``: the frames at ``positions`` when the caller has read
    them already. Raises CalibrationError when no attempt places two cameras (naming both
    attempts when pooling ran)."""
    rig = Rig(tuple(c.with_extrinsics(None) for c in rec.rig))
    pools = config is None or config.backbone == "auto" or config.backbone in MULTI_FRAME_BACKBONES
    spread = spread_positions(rec, positions[0]) if pool and pools and len(positions) == 1 else []
    frames = frames if frames is not None else [rec[t] for t in positions]
    try:
        single = _quiet(attempt, frames, rig, config, progress)
    except CalibrationError as exc:
        if len(spread) < 3:
            raise
        single, why = None, f"one frame placed too few cameras ({exc})"
    else:
        good = good_count(single)
        if len(spread) < 3 or good == len(rig):
            return Calibrated(single, positions, frames)
        why = f"frame {positions[0]} left {len(rig) - good} camera(s) not 'good'"
    notes = [f"{why}: pooling {len(spread)} frames spread over the recording ({spread[0]}..{max(spread)})"]
    pooled_frames = [frames[0]] + [rec[t] for t in spread[1:]]  # spread starts at positions[0]
    try:
        pooled = _quiet(attempt, pooled_frames, rig, config, progress)
    except CalibrationError as exc:
        if single is None:  # both attempts named: the user sees that pooling ran
            raise CalibrationError(f"{why}; {len(spread)} pooled frames also failed: {exc}") from None
        kept = "the pooled frames placed too few cameras: kept one frame's"
        return Calibrated(single, positions, frames, [*notes, kept])
    if single is not None:
        _cross_checked(single, pooled, f"the {len(spread)} pooled frames")
        _cross_checked(pooled, single, f"frame {positions[0]} alone")
    if single is not None and _rank(pooled) <= _rank(single):
        kept = f"the pooled frames were no better ({good_count(pooled)} 'good'): kept one frame's result"
        return Calibrated(single, positions, frames, [*notes, kept])
    return Calibrated(pooled, spread, pooled_frames, notes)


def warn_verdicts(calibration: Calibration, ids) -> None:
    """One ``CalibrationWarning`` per camera of ``ids`` that is unplaced or not "good", with the
    verdict's reason (what ``fuseflow calibrate`` prints in its table)."""
    verdicts = getattr(calibration.report, "camera_verdicts", None) or {}
    for c in ids:
        v = verdicts.get(c) or {}
        if c not in calibration.T_cam_world:
            warnings.warn(
                f"camera {c} unplaced: {v.get('reason', 'GMAC could not place it')}",
                CalibrationWarning,
                3,
            )
        elif v and v.get("verdict") != "good":
            warnings.warn(
                f"camera {c} {v.get('verdict')}: {v.get('reason', '')}",
                CalibrationWarning,
                3,
            )
