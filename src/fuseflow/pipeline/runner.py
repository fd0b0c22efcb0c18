"""``run(rec, out_dir)``: FUSE-Flow end to end (paper III-D, eq. 29): calibrate once, fuse every
frame, watch the cameras' health, write clouds, the calibration, a per-frame log and a summary.

The outline, one named step each: ``choose_calibration`` -> ``_plan`` (what to fuse, what to
resume) -> ``_fuse_frames`` (fuse, write, watch health, recalibrate a bumped camera) ->
``summarise``.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from fuseflow.errors import FuseFlowError, ValidationError
from fuseflow.io.calibration import read_calibration, write_calibration
from fuseflow.io.datasets import open_recording
from fuseflow.io.paths import prepare_output_dir
from fuseflow.io.recording import Recording, write_json_atomic
from fuseflow.pipeline.checks import below_calibration, frame_notes, low_agreement, validate_inputs
from fuseflow.pipeline.config import OutputOptions, PipelineConfig
from fuseflow.pipeline.exports import FrameWriter, recording_centres, resolve_outputs, with_volume, write_sequence
from fuseflow.pipeline.extrinsics import merge_recalibration, placed_rig
from fuseflow.pipeline.frames import first_good_frame, process_frame
from fuseflow.pipeline.health import HealthMonitor
from fuseflow.pipeline.outputs import (
    OutputManifest,
    calibration_digest,
    config_digest,
    fuseflow_version,
    open_output,
    peak_rss_mb,
    read_frame_log,
    recording_fingerprint,
    settings_digest,
    settings_doc,
)
from fuseflow.pipeline.ray import RayOptions, check_ray_address
from fuseflow.pipeline.records import FrameRecord, RunSummary
from fuseflow.types import Calibration, FusedCloud, Rig

__all__ = ["run", "choose_calibration", "CalibrationChoice", "summarise", "run_manifest"]

OnFrame = Callable[[FrameRecord, int, int], None]


@dataclass
class CalibrationChoice:
    """The extrinsics a run fuses with and where they came from."""

    rig: Rig
    """The placed cameras with their extrinsics, in the recording's rig order."""
    source: str
    """Human-readable origin: "given", "rig.json", "resumed from ...", "GMAC on frame N"."""
    frame: int | None = None
    """Frame number GMAC calibrated on (None when GMAC did not run)."""
    warnings: list[str] = field(default_factory=list)
    calibrated: dict | None = None
    """Per camera id, the depth agreement its calibration measured (calib.json's report), if any."""


def _measured_agreement(report) -> dict | None:
    """``depth_agreement`` of a calibration report (a CalibReport or calib.json's dict), if any."""
    value = report.get("depth_agreement") if isinstance(report, dict) else getattr(report, "depth_agreement", None)
    return dict(value) if isinstance(value, dict) else None


def choose_calibration(
    rec: Recording,
    out: Path,
    calibration: Calibration | None,
    config: PipelineConfig,
    calib_frame: int | None,
    use_rig_extrinsics: bool,
) -> CalibrationChoice:
    """Given extrinsics, else OUT/calib.json of an earlier run, else rig.json's (when asked),
    else GMAC on ``calib_frame`` (default: the first good frame, pooling frames when it is not
    enough: ``pipeline.calibration.calibrate_frames``). Writes OUT/calib.json."""
    calib_json = out / "calib.json"
    if calib_json.exists():  # an earlier run of the same manifest (open_output checked it)
        earlier = read_calibration(calib_json)
        rig, warnings = _placed(rec.rig, earlier)
        return CalibrationChoice(rig, f"resumed from {calib_json}", warnings=warnings,
                                 calibrated=_measured_agreement(earlier.report))  # fmt: skip
    if calibration is not None:
        rig, warnings = _placed(rec.rig, calibration)
        measured = _measured_agreement(calibration.report)
        report = {"source": "given"} | ({"depth_agreement": measured} if measured else {})
        write_calibration(calib_json, Calibration({c.id: c.T_cam_world for c in rig}, report), rig=rec.rig)
        return CalibrationChoice(rig, "given", warnings=warnings, calibrated=measured)
    if use_rig_extrinsics and rec.rig.is_calibrated:
        write_calibration(
            calib_json, Calibration({c.id: c.T_cam_world for c in rec.rig}, {"source": "rig.json"}), rig=rec.rig
        )
        return CalibrationChoice(rec.rig, "rig.json")
    from fuseflow.pipeline.calibration import calibrate_frames

    t = calib_frame if calib_frame is not None else first_good_frame(rec, config.min_valid_depth)
    done = calibrate_frames(rec, [t], config.calib_config(), pool=calib_frame is None)
    cal, used = done.calibration, done.positions
    warnings = []  # done.notes: the pooling shows in the choice's description
    unplaced = [c for c in rec.rig.ids if c not in cal.T_cam_world]
    if unplaced:
        warnings.append(f"GMAC could not place cameras {unplaced}; they are left out of fusion")
    warnings.extend(str(w) for w in getattr(cal.report, "warnings", ()))  # a Calibration's report may be a dict
    write_calibration(calib_json, cal, rig=rec.rig)
    number = rec.frame_numbers[used[0]]
    how = f"GMAC on frame {number}" if len(used) == 1 else f"GMAC on {len(used)} frames from frame {number}"
    return CalibrationChoice(placed_rig(rec.rig, cal), how, number, warnings, _measured_agreement(cal.report))


def _placed(rig: Rig, calibration: Calibration) -> tuple[Rig, list[str]]:
    """The cameras ``calibration`` places, with its extrinsics only (never mixed with rig.json's:
    two calibrations have two world frames), and a warning naming the cameras left out."""
    placed = placed_rig(rig, calibration)
    left_out = [c for c in rig.ids if c not in placed.ids]
    warnings = []
    if left_out:
        warnings.append(f"the calibration does not place cameras {left_out}; they are left out of fusion")
    return placed, warnings


def run_manifest(
    rec: Recording,
    calibration: Calibration | None,
    config: PipelineConfig,
    calib_frame: int | None,
    use_rig_extrinsics: bool,
) -> OutputManifest:
    """What a ``run`` with these arguments writes (``open_output`` compares it on resume)."""
    if calibration is not None:
        calib = f"given:{calibration_digest(calibration.T_cam_world)}"
    elif use_rig_extrinsics and rec.rig.is_calibrated:
        calib = "rig.json"
    else:
        frame = "first-good" if calib_frame is None else rec.frame_numbers[calib_frame]
        calib = f"gmac:{config_digest(config.calib_config())}:frame={frame}"
    pipeline = {k: v for k, v in asdict(config).items() if k not in ("fuse", "calib", "device")}
    if config.sync != "auto":  # "off" and "check" fuse the same clouds: the same run
        pipeline.pop("sync")
        pipeline.pop("sync_max_shift")
    if config.outputs == OutputOptions():
        pipeline.pop("outputs")  # the default outputs are not recorded
    settings = settings_doc(fuse=config.fuse_config(), pipeline=pipeline)
    return OutputManifest(
        command="run",
        recording=str(Path(rec.path).resolve()),
        recording_fingerprint=recording_fingerprint(rec),
        calibration=calib,
        config=settings_digest(settings),
        fuseflow_version=fuseflow_version(),
        settings=settings,
    )


def _frame_writer(
    rec: Recording,
    out: Path,
    given: Calibration | None,
    choice: CalibrationChoice,
    options: OutputOptions,
    first: int | None = None,
) -> FrameWriter:
    """The writer of the run's frame files, with its output frame and capture volume
    (``pipeline.exports.resolve_outputs`` on the frame at position ``first``: the given
    calibration's stored ones, else OUT/calib.json's, else found) written into OUT/calib.json."""
    calib_json = out / "calib.json"
    written = read_calibration(calib_json)
    keys = ("capture_volume", "world")
    stored = given if given is not None and any(k in given.report for k in keys) else written
    sel = [rec.rig.index(c) for c in choice.rig.ids]
    world, volume = resolve_outputs(options, choice.rig, stored, rec[first].subset(sel) if first is not None else None)
    updated = with_volume(written, volume, world)
    if any(updated.report.get(k) != written.report.get(k) for k in keys):
        write_calibration(calib_json, updated, rig=rec.rig)
    return FrameWriter(out, options, choice.rig, volume, recording_centres(rec.rig, choice.rig), world=world)


def _check_sync(rec: Recording, state: _RunState, config: PipelineConfig) -> tuple[Recording, dict[str, int]]:
    """The camera-sync check (``config.sync``): report late or early cameras, and with "auto"
    return the recording with them re-timed (``io.timesync.shift_views``)."""
    if config.sync == "off":
        return rec, {}
    from fuseflow.io.timesync import shift_views
    from fuseflow.pipeline.sync import check_sync

    sel = [rec.rig.index(c) for c in state.rig.ids]
    report = check_sync(rec, state.rig, sel, max_shift=config.sync_max_shift)
    state.warnings.extend(report.warnings())
    offsets = report.late()
    if config.sync == "auto" and not offsets and report.limit:
        state.warnings.append(f"--sync-offsets auto found no camera out of sync, but {report.limit}")
    if config.sync == "auto" and offsets:
        return shift_views(rec, offsets), offsets
    return rec, offsets


def _check_inputs(rec: Recording, rig: Rig, positions: list[int], config: PipelineConfig, volume) -> list[str]:
    """Before fusing, on the first frame to fuse: ``pipeline.checks.validate_inputs`` (depth_range,
    the extrinsics' scale, the crop box, exchanged cameras); ValidationError when every cloud
    would be empty."""
    if not positions:
        return []
    return validate_inputs(rec[positions[0]], rig, config.fuse_config(), volume, agreement=False)  # summarise


def _finished(rec: Recording, out: Path, positions: list[int], writer: FrameWriter) -> bool:
    """Every frame asked for is in OUT already (logged in frames.jsonl, its file written)."""
    previous = read_frame_log(out / "frames.jsonl")
    return all(rec.frame_numbers[t] in previous and writer.done(rec.frame_numbers[t]) for t in positions)


@dataclass
class _RunState:
    """What the frame loop carries from frame to frame (explicit, per run)."""

    rig: Rig
    monitor: HealthMonitor
    calib_json: Path
    records: list[FrameRecord] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    fuse_ms: list[float] = field(default_factory=list)
    fused_now: int = 0
    resumed: int = 0
    writer: FrameWriter | None = None


def _recalibrate(rec: Recording, t: int, sel: list[int], state: _RunState, flagged: list[str], config) -> bool:
    """Re-run GMAC on frame position ``t`` and merge the flagged cameras' new poses into the old
    world frame; False (and a warning) when GMAC fails."""
    from fuseflow.calib import calibrate

    number = rec.frame_numbers[t]
    try:
        cal = calibrate(rec[t].subset(sel), state.rig, config.calib_config())
    except FuseFlowError as exc:
        state.warnings.append(f"recalibration at frame {number} failed: {exc}")
        return False
    state.rig = merge_recalibration(state.rig, cal, flagged)
    report = cal.report.to_json() if hasattr(cal.report, "to_json") else cal.report
    write_calibration(
        state.calib_json,
        with_volume(
            Calibration(
                {c.id: c.T_cam_world for c in state.rig},
                {"source": f"recalibrated at frame {number}", "gmac": report},
            ),
            state.writer.volume if state.writer is not None else None,
            state.writer.world if state.writer is not None else None,
        ),
    )
    for c in flagged:
        state.monitor.reset(c)
    return True


def _frame_results(
    rec: Recording, todo: list[int], sel: list[int], state: _RunState, config: PipelineConfig, ray: RayOptions | None
) -> Iterator[tuple[FusedCloud, FrameRecord]]:
    """(cloud, record) of each position in ``todo``, in order: in this process with the rig as it
    is when the frame's turn comes (a recalibration changes it), or as Ray tasks (no
    recalibration there: the rig is fixed)."""
    if ray is None:
        for t in todo:
            yield process_frame(rec[t], sel, state.rig, config)
        return
    from fuseflow.pipeline.ray import ray_frame_results

    for _, cloud, record, _ in ray_frame_results(str(rec.path), todo, sel, state.rig, config, ray):
        yield cloud, record


def _fuse_frames(
    rec: Recording,
    out: Path,
    positions: list[int],
    state: _RunState,
    config: PipelineConfig,
    ray: RayOptions | None,
    on_frame: OnFrame | None,
) -> None:
    """Resume the frames OUT already has, fuse the others; write each cloud and log line."""
    sel = [rec.rig.index(c) for c in state.rig.ids]
    log_path = out / "frames.jsonl"
    previous = read_frame_log(log_path)
    writer = state.writer
    done = {t for t in positions if rec.frame_numbers[t] in previous and writer.done(rec.frame_numbers[t])}
    results = _frame_results(rec, [t for t in positions if t not in done], sel, state, config, ray)
    n = len(state.rig)
    with open(log_path, "a") as log:
        for k, t in enumerate(positions):
            number = rec.frame_numbers[t]
            if t in done:
                record = previous[number]
                writer.resumed(number, record.timestamp, record.points)
                state.resumed += 1
                if record.pairs.size:  # rebuild the health baselines
                    state.monitor.update(record.pairs.reshape(n, n))
            else:
                cloud, record = next(results)
                state.fuse_ms.append(record.fuse_ms)
                cloud = writer.crop(cloud)
                record.points = len(cloud)
                writer.write(number, cloud, lambda t=t: rec[t].subset(sel), record.timestamp)
                record.flagged = state.monitor.update(record.pairs.reshape(n, n))
                if record.flagged and config.recalibrate == "auto":
                    record.recalibrated = _recalibrate(rec, t, sel, state, record.flagged, config)
                log.write(json.dumps(record.to_json()) + "\n")
                log.flush()
                state.fused_now += 1
            state.records.append(record)
            if on_frame:
                on_frame(record, k + 1, len(positions))


def summarise(rec: Recording, out: Path, state: _RunState, choice: CalibrationChoice, wall: float, device: str):
    """The RunSummary of the frames in ``state`` (dropped views, bumped cameras, timings)."""
    dropped: dict[str, int] = {}
    bumped: dict[str, int] = {}
    empty: dict[str, list[int]] = {}
    for r in state.records:
        for c in r.empty:
            empty.setdefault(c, []).append(r.index)
        for c in r.missing:
            dropped[c] = dropped.get(c, 0) + 1
        for c in r.flagged:
            bumped.setdefault(c, r.index)
    warnings = list(state.warnings)
    warnings += [
        f"camera {c} was missing in {n} frames; those frames were fused from the other views"
        for c, n in dropped.items()
    ]
    warnings += [
        f"camera {c} had no valid depth (an all-zero depth image) in {len(n)} frames: "
        + ", ".join(map(str, n[:10]))
        + (f" and {len(n) - 10} more" if len(n) > 10 else "")
        for c, n in empty.items()
    ]
    warnings += [f"camera {c} lost agreement with its neighbours from frame {n} (bumped?)" for c, n in bumped.items()]
    warnings += frame_notes(state.records)
    smallest = min((c.width * c.height for c in choice.rig), default=None)
    checks = [low_agreement(state.records, view_pixels=smallest), below_calibration(state.records, choice.calibrated)]
    warnings += [w for w in checks if w]
    pts = np.array([r.points for r in state.records], dtype=np.float64)
    stat = (lambda f: float(f(pts))) if pts.size else (lambda f: 0.0)  # noqa: E731
    return RunSummary(
        recording=str(rec.path),
        out_dir=str(out),
        frames=len(state.records),
        frames_fused_now=state.fused_now,
        frames_resumed=state.resumed,
        fps=(state.fused_now / wall) if state.fused_now and wall > 0 else 0.0,
        ms_per_frame=float(np.median(state.fuse_ms)) if state.fuse_ms else 0.0,
        first_frame_ms=float(state.fuse_ms[0]) if state.fuse_ms else 0.0,
        warm_ms_per_frame=float(np.median(state.fuse_ms[1:])) if len(state.fuse_ms) > 1 else None,
        points_per_frame={"mean": stat(np.mean), "min": stat(np.min), "max": stat(np.max)},
        peak_memory_mb=peak_rss_mb(),
        device=device,
        calibration=choice.source,
        calibration_frame=choice.frame,
        dropped_views=dropped,
        bumped_cameras=bumped,
        recalibrations=[r.index for r in state.records if r.recalibrated],
        warnings=warnings,
    )


def run(
    rec: Recording | str | Path,
    out_dir: str | Path,
    calibration: Calibration | None = None,
    config: PipelineConfig = PipelineConfig(),
    frames: range | None = None,
    calib_frame: int | None = None,
    use_rig_extrinsics: bool = False,
    on_frame: OnFrame | None = None,
    ray: RayOptions | None = None,
    force: bool = False,
) -> RunSummary:
    """Calibrate once, fuse every frame, write clouds, the calibration and a summary.

    Resumes: when ``out_dir`` holds an earlier run with the same manifest (recording content,
    calibration source, settings, version: ``pipeline.outputs.OutputManifest``), frames whose
    cloud exists are skipped (their records are read back from frames.jsonl) and its calib.json
    is reused. A used ``out_dir`` that does not match is an OutputError saying what differs,
    unless ``force`` (delete the earlier outputs and start over). The output location is
    checked before any work starts.

    Args:
        calibration: known extrinsics; None = GMAC on ``calib_frame`` (default: the first good
            frame), unless ``use_rig_extrinsics`` and the recording's rig is calibrated.
        frames: which frame positions to fuse (default all).
        on_frame: called after each frame with (record, done, total), e.g. for a progress bar.
        ray: ``RayOptions`` to fuse frames as Ray tasks (outputs are identical to the
            single-process run); None = fuse in this process.
        force: start over in a used ``out_dir`` whose manifest does not match.
    """
    if ray is not None and config.recalibrate == "auto":
        raise ValidationError(
            "recalibrate='auto' needs frames fused in order in one process; it is not available with Ray"
        )
    if ray is not None and config.sync == "auto":
        raise ValidationError("sync='auto' re-times views in this process; it is not available with Ray")
    if isinstance(calibration, Rig):  # a calibrated rig: its extrinsics are the calibration
        calibration = Calibration({c.id: c.T_cam_world for c in calibration if c.is_calibrated}, {"source": "given"})
    elif calibration is not None and not isinstance(calibration, Calibration):
        raise ValidationError(f"calibration must be a Calibration, a Rig or None, got {type(calibration).__name__}")
    out = prepare_output_dir(out_dir)
    if not isinstance(rec, Recording):
        rec = open_recording(rec)
    if calib_frame is not None and not 0 <= calib_frame < len(rec):
        raise ValidationError(
            f"calibration frame {calib_frame} (--calib-frame) is beyond the recording: it has {len(rec)} frames, "
            f"positions 0 to {len(rec) - 1}"
        )
    if ray is not None and ray.address is not None:
        check_ray_address(ray.address)  # before any work: Ray itself retries for minutes
    open_output(out, run_manifest(rec, calibration, config, calib_frame, use_rig_extrinsics), force)
    choice = choose_calibration(rec, out, calibration, config, calib_frame, use_rig_extrinsics)
    monitor = HealthMonitor(choice.rig.ids, config.health_warmup, config.health_drop, config.health_patience)
    state = _RunState(choice.rig, monitor, out / "calib.json", warnings=list(choice.warnings))
    positions = list(frames if frames is not None else range(len(rec)))
    state.writer = _frame_writer(rec, out, calibration, choice, config.outputs, positions[0] if positions else None)
    offsets: dict[str, int] = {}
    if not _finished(rec, out, positions, state.writer):  # nothing to check when nothing is fused
        state.warnings += _check_inputs(rec, choice.rig, positions, config, state.writer.volume)
        rec, offsets = _check_sync(rec, state, config)
    t_start = time.perf_counter()
    _fuse_frames(rec, out, positions, state, config, ray, on_frame)
    summary = summarise(rec, out, state, choice, time.perf_counter() - t_start, config.device)
    summary.sync_offsets = offsets
    write_sequence(out, state.writer)
    if state.fused_now == 0 and (out / "summary.json").exists():
        return _earlier_summary(out, summary)
    write_json_atomic(out / "summary.json", summary.to_json())
    return summary


def _earlier_summary(out: Path, now: RunSummary) -> RunSummary:
    """Nothing was fused now: the earlier run's summary.json (its timings and warnings) is kept
    as it is and returned, marked ``nothing_to_do``; ``now`` when it cannot be read."""
    try:
        earlier = RunSummary.from_json(json.loads((out / "summary.json").read_text()))
    except (OSError, ValueError, TypeError):
        write_json_atomic(out / "summary.json", now.to_json())
        return now
    earlier.frames_fused_now, earlier.frames_resumed, earlier.nothing_to_do = 0, now.frames_resumed, True
    return earlier
