"""Camera-sync check: is a camera's stream a few frames late or early against its neighbours?

Two checks, ``check_sync`` picks one ("auto": by recording length):

- **co-visible** (``check_sync_covisible``, module ``covisible``): per camera pair, the
  moving surface both cameras see, scored with one camera shifted; a sub-frame lag per pair
  from both directions, the per-camera offsets solved jointly over the pairs
  (``offsets.pair_lags``, ``solve_frame_offsets``). Works at 30 fps on recordings of
  60-90 frames (docs/formats.md "Camera-sync check").
- **agreement** (``sync_scores``): for a camera c and a shift s, the score of frame t is the
  depth agreement of c's view at t with its neighbours' views at t + s
  (``geometry.pair_agreement`` restricted to c's pairs, tau 2 %: the 5 % of the fusion vote
  hides the few-centimetre motion between frames). A camera k frames late shows at t what its
  neighbours showed at t - k, so it agrees best at s = -k; in a static scene every shift agrees
  alike and nothing is reported. ``offsets.estimate_frame_offset`` turns the scores into an
  offset only when one shift is consistently better. Used on short recordings (a dozen frames
  at 5 fps); biased by a frame at 30 fps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from fuseflow.errors import ValidationError
from fuseflow.geometry import pair_agreement
from fuseflow.io.recording import Recording
from fuseflow.io.timesync import read_timestamps, shift_views
from fuseflow.pipeline.sync.covisible import covisible_curves
from fuseflow.pipeline.sync.offsets import (
    OffsetEstimate,
    PairLag,
    estimate_frame_offset,
    pair_lags,
    solve_frame_offsets,
)
from fuseflow.types import Frame, Rig

__all__ = ["SyncReport", "check_sync", "check_sync_covisible", "sync_scores", "covisible_curves"]


@dataclass(frozen=True)
class SyncReport:
    """Per camera id, its estimated offset (``OffsetEstimate``: +k = k frames late) and the
    frames that were sampled."""

    offsets: dict[str, OffsetEstimate]
    frames: tuple[int, ...]
    method: str = "agreement"
    pairs: tuple[PairLag, ...] = ()
    sub_frame: dict[str, float] | None = None
    limit: str = ""
    """Why this check may miss an offset on this recording ("" when it can see one)."""

    def late(self) -> dict[str, int]:
        """Cameras with a non-zero offset: id -> frames late (negative: early)."""
        return {c: e.frames for c, e in self.offsets.items() if e.frames != 0}

    def warnings(self) -> list[str]:
        out = []
        for c, e in self.offsets.items():
            if e.frames:
                ms = "" if not np.isfinite(e.ms) else f", {e.ms:+.0f} ms"
                word = "late" if e.frames > 0 else "early"
                head = f"{c} is about {e.frames:+d} frame{'s' if abs(e.frames) != 1 else ''} {word}{ms}"
                if self.method == "covisible":
                    sub = (self.sub_frame or {}).get(c, float("nan"))
                    why = (f"the motion of the surface it shares with its neighbours lags by {sub:+.2f} frames, "
                           f"{e.consistency:.0%} of its {e.frames_used} camera pairs agree")  # fmt: skip
                else:
                    why = (f"its depth agrees best with its neighbours' frame t{-e.frames:+d} on {e.consistency:.0%} "
                           "of the sampled frames")  # fmt: skip
                out.append(f"{head} ({why}); --sync-offsets auto re-times it")
        return out


def _mixed(frames: dict[int, Frame], t: int, s: int, c: int) -> Frame | None:
    """Frame t + s with camera c's view replaced by its view at t (None when either is missing)."""
    if t not in frames or t + s not in frames:
        return None
    own, other = frames[t], frames[t + s]
    depth = other.depth.clone()
    depth[c] = own.depth[c]
    present = other.present.clone()
    present[c] = own.present[c]
    return Frame(other.index, other.camera_ids, other.color, depth, present)


def sync_scores(
    rec: Recording,
    rig: Rig,
    sel: list[int],
    positions: list[int],
    shifts: list[int],
    samples: int,
    tau: float,
) -> np.ndarray:
    """(N, F, S) scores: camera n's agreement at sampled position positions[f] with its
    neighbours at positions[f] + shifts[s]; NaN where a frame is out of range or nothing voted."""
    need = sorted({t + s for t in positions for s in shifts if 0 <= t + s < len(rec)})
    frames = {t: rec[t].subset(sel) for t in need}
    n = len(rig)
    out = np.full((n, len(positions), len(shifts)), np.nan)
    for f, t in enumerate(positions):
        for k, s in enumerate(shifts):
            for c in range(n):
                mixed = _mixed(frames, t, s, c)
                if mixed is None or not bool(mixed.present[c]):
                    continue
                row = pair_agreement(mixed, rig, samples, tau, only=c)[c]
                row = row[np.isfinite(row)]
                if row.size:
                    out[c, f, k] = float(row.mean())
    return out


def _period_s(rec: Recording) -> float | None:
    """The median frame period from the recording's timestamps.json, if it has one."""
    ts = read_timestamps(rec.path) if rec.path is not None else None
    if ts is None:
        return None
    periods = [np.nanmedian(np.diff(v)) for v in ts.view.values() if np.isfinite(v).sum() > 1]
    return float(np.median(periods)) if periods else None


COVISIBLE_MIN_FRAMES = 24
"""Positions (frames with every shift) below which ``check_sync`` "auto" uses the agreement check."""


def _positions(m: int, max_shift: int, count: int) -> list[int]:
    positions = sorted({int(round(x)) for x in np.linspace(max_shift, m - 1 - max_shift, min(count, m))})
    return [t for t in positions if 0 <= t < m] or [0]


def _window(m: int, reach: int, count: int) -> list[int]:
    """``count`` positions every other frame in the middle of the recording (all loaded frames
    also feed each pixel's background depth), or spread over it when it is short."""
    span = 2 * count
    if m - 2 * reach <= span:
        return _positions(m, reach, count)
    start = (m - span) // 2
    return list(range(start, start + span, 2))


def check_sync_covisible(
    rec: Recording, rig: Rig, sel: list[int], max_shift: int = 3, sample_frames: int = 48, tau: float = 0.03
) -> SyncReport:
    """The motion-based check (``covisible``): directed co-visible scores per camera pair on
    ``sample_frames`` positions (every other frame of a window in the middle of a long
    recording: 2 x 48 frames, 3.2 s at 30 fps), a sub-frame lag per pair kept only when both
    directions agree (``offsets.pair_lags``), and the offsets solved jointly
    (``offsets.solve_frame_offsets``). Cost: N (N - 1) x sample_frames x (2 max_shift + 5)
    projections of the moving pixels, plus loading ~2 x sample_frames frames."""
    # searched 2 frames past max_shift: a peak on the edge of the range cannot be refined, and
    # +-3 cut the -2 peak of a late camera's backward curve (measured, 30 fps seed 3); a short
    # recording (5 fps, 12 frames) keeps +-max_shift so that some positions have every shift
    reach = max_shift + 2 if len(rec) - 2 * (max_shift + 2) >= COVISIBLE_MIN_FRAMES else max_shift
    shifts = list(range(-reach, reach + 1))
    positions = _window(len(rec), reach, sample_frames)
    with torch.no_grad():
        curves, _ = covisible_curves(rec, rig, sel, positions, shifts, tau=tau)
    pairs = pair_lags(curves, shifts)
    solved = solve_frame_offsets(pairs, len(rig))
    frames, sub = np.where(np.abs(solved.frames) <= max_shift, solved.frames, 0), solved.sub_frame
    period = _period_s(rec)
    offsets = {}
    for n, c in enumerate(rig.ids):
        mine = [p for p in pairs if p.kept and n in (p.i, p.j)]
        fits = [p for p in mine if abs(p.lag - (sub[p.j] - sub[p.i])) < 0.5]
        k = int(frames[n])
        ms = k * period * 1000.0 if period else float("nan")
        gain = float(np.mean([p.prominence for p in mine])) if mine else 0.0
        offsets[c] = OffsetEstimate(k, ms, len(fits) / len(mine) if mine else 0.0, gain, len(mine), {})
    return SyncReport(offsets, tuple(rec.frame_numbers[t] for t in positions), "covisible", tuple(pairs),
                      {c: float(sub[n]) for n, c in enumerate(rig.ids)})  # fmt: skip


def check_sync(
    rec: Recording,
    rig: Rig,
    sel: list[int],
    max_shift: int = 3,
    sample_frames: int | None = None,
    samples: int = 5000,
    tau: float = 0.02,
    method: str = "auto",
) -> SyncReport:
    """Estimate every camera's frame offset; ``sel`` maps ``rig`` (placed cameras) to the
    recording's views. ``method`` "covisible": ``check_sync_covisible`` on ``sample_frames``
    (default 48) positions; "agreement": the per-pixel agreement check below (default 8
    positions; biased by a frame at 30 fps); "auto" (default): covisible when the recording has
    at least ``COVISIBLE_MIN_FRAMES`` + 2 (max_shift + 2) frames, else agreement. On 12-frame
    5-fps recordings (6 usable positions) both found a camera 2 frames late on 4 of 5 seeds
    with no false alarm, the co-visible check 10x faster; "auto" keeps the agreement check there,
    which also ran end to end on converted .bag files (tests/io/test_bag_end_to_end.py).

    Agreement: on ``sample_frames`` positions spread over ``rec`` (shifts
    -max_shift..max_shift), cameras are found one at a time (the most confident first) and the
    rest re-estimated with it re-timed. Costs ~ (late cameras + 1) x sample_frames x
    (2 max_shift + 1) x N restricted agreement passes."""
    if method == "auto":
        method = "covisible" if len(rec) >= COVISIBLE_MIN_FRAMES + 2 * (max_shift + 2) else "agreement"
    if method == "covisible":
        return check_sync_covisible(rec, rig, sel, max_shift, sample_frames or 48)
    if method != "agreement":
        raise ValidationError(f"sync check method must be 'auto', 'covisible' or 'agreement', got {method!r}")
    shifts = list(range(-max_shift, max_shift + 1))
    positions = _positions(len(rec), max_shift, sample_frames or 8)
    period = _period_s(rec)
    found: dict[str, OffsetEstimate] = {}
    # One camera at a time, most confident first: an in-sync camera next to a late one agrees
    # with it at the opposite shift (measured: cam00 -2 beside cam03 +2 in tests/io/
    # test_bag_end_to_end.py), so the others are re-estimated with the late camera re-timed.
    for _ in range(len(rig)):
        view = shift_views(rec, {c: e.frames for c, e in found.items()}) if found else rec
        with torch.no_grad():
            scores = sync_scores(view, rig, sel, positions, shifts, samples, tau)
        est = {c: estimate_frame_offset(scores[i], shifts, period) for i, c in enumerate(rig.ids)}
        new = [(e.gain, c) for c, e in est.items() if e.frames != 0 and c not in found]
        if not new:
            break
        c = max(new)[1]
        found[c] = est[c]
    offsets = {c: (found[c] if c in found else est[c]) for c in rig.ids}
    return SyncReport(
        offsets, tuple(rec.frame_numbers[t] for t in positions), limit=_agreement_limit(len(rec), period, max_shift)
    )


#: Frame rate above which the agreement check misses a camera 2 frames late (docs/formats.md
#: "Camera-sync check": 0 of 5 seeds at 30 fps, 4 of 5 at 5 fps): the scene moves too little per frame.
AGREEMENT_MAX_FPS = 10.0


def _agreement_limit(frames: int, period: float | None, max_shift: int) -> str:
    """The agreement check's blind spot on this recording, in words ("" outside it)."""
    if period is None or period <= 0 or 1.0 / period <= AGREEMENT_MAX_FPS:
        return ""
    return (f"on {frames} frames at {1.0 / period:.0f} fps the sync check cannot see an offset of a frame or two: "
            f"the motion check needs at least {COVISIBLE_MIN_FRAMES + 2 * (max_shift + 2)} frames (docs/formats.md, "
            "\"Camera-sync check\"); record longer, or check the cameras' sync cable")  # fmt: skip
