"""FUSE-Flow (paper III-D, eq. 29): calibrate once with GMAC, then fuse every frame with FUSE.

Neither stage keeps scene state between frames. The pipeline adds what a deployment needs
around them, all explicit and per run:

* ``stream(source, calibration)``: an iterator of FusedCloud, one per frame of a recording or
  a live source (e.g. ``fuseflow.io.realsense.RealSenseSource``).
* ``run(rec, out_dir)``: calibrate on the first good frame (or take given extrinsics), fuse
  every frame to ``out_dir/clouds/<frame:06d>.ply``, keep a per-frame log
  (``frames.jsonl``) and a summary (``summary.json``). Outputs are written atomically, so an
  interrupted run leaves only complete files, and running again resumes where it stopped.
* Health monitoring (``HealthMonitor``): per pair of neighbouring cameras and frame, the share
  of their depth that agrees (the CVGC vote of eq. 19-21 on a subsampled grid). A camera whose
  pairs all fall below their baselines was probably bumped; it is flagged,
  and with ``recalibrate="auto"`` GMAC re-runs on the current frame and the bumped camera's
  new pose is put into the old world frame (the others keep theirs).
* Dropped views: a camera missing from a frame is fused without (FUSE handles N-1 views) and
  counted in the summary.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from fuseflow.errors import FuseFlowError, ValidationError
from fuseflow.geometry import camera_agreement, pair_agreement
from fuseflow.io.calibration import read_calibration, write_calibration
from fuseflow.io.datasets import open_recording
from fuseflow.io.ply import write_ply
from fuseflow.io.recording import Recording, write_json_atomic
from fuseflow.types import Calibration, Frame, FusedCloud, Rig, invert_rigid

__all__ = [
    "placed_rig",
    "reindex_cameras",
    "rigid_align",
    "PipelineConfig",
    "FrameRecord",
    "RunSummary",
    "HealthMonitor",
    "camera_agreement",
    "pair_agreement",
    "merge_recalibration",
    "first_good_frame",
    "stream",
    "run",
    "cloud_path",
]


@dataclass(frozen=True)
class PipelineConfig:
    """Settings of a FUSE-Flow run (FUSE and GMAC keep their own configs)."""

    fuse: Any = None
    """fuseflow.fuse.FuseConfig; None = FuseConfig() defaults."""
    calib: Any = None
    """fuseflow.calib.CalibConfig; None = CalibConfig() defaults."""
    device: str = "cpu"
    """Torch device for fusion: "cpu" or "cuda"."""
    recalibrate: Literal["off", "auto"] = "off"
    """"auto": re-run GMAC when a camera is flagged as bumped, and continue with its new pose."""
    min_valid_depth: float = 0.2
    """A frame is "good" for calibration when every camera is present with at least this share of
    pixels with depth. Range (0, 1]."""
    health_samples: int = 5000
    """Pixels per view the health check samples (a regular grid; cost ~ N K_max samples).
    With 5000, the pair agreements of a static simulated 4-camera rig varied by
    at most 0.04 from frame to frame, while a 6-degree bump lowered its pairs by 0.07-0.37. Range >= 1."""
    health_tau: float = 0.05
    """Relative depth residual under which a neighbour agrees (the paper's tau, eq. 21)."""
    health_warmup: int = 3
    """Frames whose median agreement becomes each camera's baseline. Range >= 1."""
    health_drop: float = 0.1
    """A pair "fell" when its agreement is this much (absolute share) below its baseline; a
    camera is suspect when most of its pairs fell (HealthMonitor). Range (0, 1)."""
    health_patience: int = 2
    """Consecutive suspect frames before a camera is flagged as bumped. Range >= 1."""

    def __post_init__(self) -> None:
        if self.recalibrate not in ("off", "auto"):
            raise ValidationError(f"recalibrate must be 'off' or 'auto', got {self.recalibrate!r}")
        if not 0 < self.min_valid_depth <= 1:
            raise ValidationError(f"min_valid_depth must be in (0, 1], got {self.min_valid_depth}")
        for name in ("health_samples", "health_warmup", "health_patience"):
            if getattr(self, name) < 1:
                raise ValidationError(f"{name} must be >= 1, got {getattr(self, name)}")
        if not 0 < self.health_drop < 1:
            raise ValidationError(f"health_drop must be in (0, 1), got {self.health_drop}")


@dataclass
class FrameRecord:
    """What happened to one frame (one line of frames.jsonl)."""

    index: int
    points: int
    fuse_ms: float
    missing: list[str] = field(default_factory=list)
    agreement: dict[str, float | None] = field(default_factory=dict)
    """Per camera, the mean agreement of its neighbour pairs (None: no vote)."""
    pairs: list[list[float | None]] = field(default_factory=list)
    """(N, N) pair agreements (``pair_agreement``) in the calibrated rig's order."""
    flagged: list[str] = field(default_factory=list)
    recalibrated: bool = False


@dataclass
class RunSummary:
    """The result of ``run`` (also written as summary.json)."""

    recording: str
    out_dir: str
    frames: int
    frames_fused_now: int
    frames_resumed: int
    fps: float
    ms_per_frame: float
    """Median FUSE time of the frames fused in this call (the first frame of a fresh install also
    compiles the numba kernels: the demo in a fresh venv measured a 2018 ms mean over 10 frames
    against ~200 ms warm; the median leaves that out, ``fps`` does not)."""
    points_per_frame: dict[str, float]
    peak_memory_mb: float
    device: str
    calibration: str
    calibration_frame: int | None
    dropped_views: dict[str, int]
    bumped_cameras: dict[str, int]
    recalibrations: list[int]
    warnings: list[str]

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def cloud_path(out_dir: str | Path, index: int) -> Path:
    """Where ``run`` writes the cloud of frame ``index``: OUT/clouds/<index:06d>.ply."""
    return Path(out_dir) / "clouds" / f"{index:06d}.ply"


# --------------------------------------------------------------------------- health


class HealthMonitor:
    """Flags cameras that no longer agree with their neighbours (a bumped camera).

    Works on pair agreements (``pair_agreement``): a camera that moved disagrees with *all* its
    neighbours, while each of those neighbours disagrees only with it. So a camera is suspect
    in a frame when at least half of its pairs (and at least 2, where it has 2 or more) fell by
    more than ``drop`` below their baseline, and its mean drop is the largest among the cameras
    sharing those pairs. State, explicit and per run: each pair's baseline (median of its first
    ``warmup`` frames with votes) and each camera's count of consecutive suspect frames;
    ``patience`` suspect frames in a row flag it.
    """

    def __init__(self, camera_ids: Iterable[str], warmup: int = 3, drop: float = 0.1, patience: int = 2):
        self.ids = tuple(camera_ids)
        self.warmup, self.drop, self.patience = warmup, drop, patience
        n = len(self.ids)
        self._history: dict[tuple[int, int], list[float]] = {}
        self._suspect = np.zeros(n, dtype=np.int64)

    def _baseline(self, i: int, j: int) -> float | None:
        h = self._history.get((min(i, j), max(i, j)), [])
        return float(np.median(h)) if len(h) >= self.warmup else None

    def update(self, pairs: np.ndarray) -> list[str]:
        """Feed one frame's (N, N) pair agreement in rig order; return the cameras flagged now."""
        n = len(self.ids)
        drops = np.full((n, n), np.nan)
        for i in range(n):
            for j in range(i + 1, n):
                a = pairs[i, j]
                if not np.isfinite(a):
                    continue
                base = self._baseline(i, j)
                if base is None:
                    self._history.setdefault((i, j), []).append(float(a))
                else:
                    drops[i, j] = drops[j, i] = base - float(a)
        score = np.full(n, -np.inf)
        suspect = np.zeros(n, dtype=bool)
        for i in range(n):
            d = drops[i][np.isfinite(drops[i])]
            if d.size == 0:
                continue
            score[i] = float(d.mean())
            fell = int((d > self.drop).sum())
            suspect[i] = fell >= max(min(2, d.size), (d.size + 1) // 2)
        for i in range(n):  # of two cameras sharing fallen pairs, blame the one that fell most
            if suspect[i]:
                for j in range(n):
                    if j != i and np.isfinite(drops[i, j]) and drops[i, j] > self.drop and score[j] > score[i]:
                        suspect[i] = False
        self._suspect = np.where(suspect, self._suspect + 1, 0)
        return [self.ids[i] for i in range(n) if self._suspect[i] >= self.patience]

    def reset(self, cid: str) -> None:
        """Forget the baselines of a camera's pairs (after it was recalibrated)."""
        i = self.ids.index(cid)
        for key in [k for k in self._history if i in k]:
            del self._history[key]
        self._suspect[i] = 0


# --------------------------------------------------------------------------- calibration


def first_good_frame(rec: Recording, min_valid: float = 0.2, limit: int = 30) -> int:
    """Index of the first frame (among the first ``limit``) with every camera present and at least
    ``min_valid`` of each camera's pixels with depth; FuseFlowError when none is."""
    for t in range(min(len(rec), limit)):
        f = rec[t]
        valid = (f.depth > 0).flatten(1).float().mean(1)
        if bool(f.present.all()) and bool((valid >= min_valid).all()):
            return t
    raise FuseFlowError(
        f"no frame among the first {min(len(rec), limit)} has every camera present with >= "
        f"{min_valid:.0%} valid depth; pass --calib with known extrinsics or --calib-frame"
    )


def rigid_align(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """4x4 rigid A minimising |A src_k - dst_k| over camera centres (Kabsch), src, dst (M, 3)."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    H = (src - mu_s).T @ (dst - mu_d)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    A = np.eye(4)
    A[:3, :3] = R
    A[:3, 3] = mu_d - R @ mu_s
    return A


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
    centre = lambda T: invert_rigid(T)[:3, 3]  # noqa: E731
    src = np.stack([centre(new.T_cam_world[c]) for c in anchors])
    dst = np.stack([centre(old[c].T_cam_world) for c in anchors])
    A = rigid_align(src, dst)  # old_world_from_new_world
    A_inv = invert_rigid(A)
    updates = {c: new.T_cam_world[c] @ A_inv for c in moved if c in new.T_cam_world}
    return old.with_extrinsics(updates)


# --------------------------------------------------------------------------- stream and run


def _fuse_fn(config: PipelineConfig) -> Callable[[Frame, Rig], FusedCloud]:
    from fuseflow.fuse import FuseConfig, fuse

    cfg = config.fuse if config.fuse is not None else FuseConfig()
    return lambda frame, rig: fuse(frame, rig, cfg)


def reindex_cameras(cloud: FusedCloud, sel: list[int]) -> FusedCloud:
    """``cloud.camera`` indexes the fused subset of cameras; map it to the source rig's indices."""
    lut = torch.tensor(sel, dtype=torch.int16, device=cloud.camera.device)
    return FusedCloud(cloud.xyz, cloud.rgb, cloud.weight, lut[cloud.camera.long()])


def process_frame(frame: Frame, sel: list[int], rig: Rig, config: PipelineConfig) -> tuple[FusedCloud, FrameRecord]:
    """Fuse one frame and measure its cameras' agreement: the per-frame work of ``run``.

    ``sel`` picks the frame's views that ``rig`` has (cameras GMAC could not place are left
    out). Stateless: the same inputs give the same outputs, in any process (see distributed.py).
    """
    full = frame.num_views
    if len(sel) != full:
        frame = frame.subset(sel)
    frame = frame.to(config.device)
    fuse = _fuse_fn(config)
    t0 = time.perf_counter()
    cloud = fuse(frame, rig)
    if frame.device.type == "cuda":
        torch.cuda.synchronize()
    ms = (time.perf_counter() - t0) * 1000.0
    if len(sel) != full:
        cloud = reindex_cameras(cloud, sel)
    pairs = pair_agreement(frame, rig, config.health_samples, config.health_tau)
    agreement = camera_agreement(pairs)
    record = FrameRecord(
        index=frame.index,
        points=len(cloud),
        fuse_ms=round(ms, 3),
        missing=list(frame.missing),
        agreement={c: (None if not np.isfinite(a) else round(float(a), 4)) for c, a in zip(rig.ids, agreement)},
        pairs=[[None if not np.isfinite(x) else round(float(x), 4) for x in row] for row in pairs],
    )
    return cloud, record


def placed_rig(rig: Rig, calibration: Calibration) -> Rig:
    """The cameras of ``rig`` that ``calibration`` places, with its extrinsics (FuseFlowError if < 1)."""
    placed = [i for i, c in enumerate(rig.ids) if c in calibration.T_cam_world]
    if not placed:
        raise FuseFlowError(f"the calibration places none of the cameras {list(rig.ids)}")
    return calibration.apply(rig.subset(placed))


def _resolve_rig(rig: Rig, calibration: Calibration | Rig | None) -> Rig:
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


def stream(
    source: Recording | str | Path | Any,
    calibration: Calibration | Rig | None = None,
    config: PipelineConfig = PipelineConfig(),
) -> Iterator[FusedCloud]:
    """Yield one FusedCloud per frame of ``source``, fused with FUSE.

    Args:
        source: a Recording, a recording path, or any object with ``.rig`` that iterates
            Frames (a live source such as RealSenseSource).
        calibration: extrinsics to use (a Calibration, or a calibrated Rig); None = the
            source rig's own extrinsics. Cameras a Calibration does not place (GMAC reports
            them unconnected) are left out of fusion.
    """
    if isinstance(source, (str, Path)):
        source = open_recording(source)
    if isinstance(calibration, Calibration):
        rig = placed_rig(source.rig, calibration)
    else:
        rig = _resolve_rig(source.rig, calibration)
    fuse = _fuse_fn(config)
    for frame in source:
        if tuple(frame.camera_ids) == rig.ids:
            yield fuse(frame.to(config.device), rig)
            continue
        sel = [frame.camera_ids.index(c) for c in rig.ids if c in frame.camera_ids]
        yield reindex_cameras(fuse(frame.subset(sel).to(config.device), rig), sel)


def _peak_rss_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run(
    rec: Recording | str | Path,
    out_dir: str | Path,
    calibration: Calibration | None = None,
    config: PipelineConfig = PipelineConfig(),
    frames: range | None = None,
    calib_frame: int | None = None,
    use_rig_extrinsics: bool = False,
    on_frame: Callable[[FrameRecord, int, int], None] | None = None,
    ray: Any = None,
) -> RunSummary:
    """Calibrate once, fuse every frame, write clouds, the calibration and a summary.

    Resumes: frames whose cloud exists in ``out_dir`` are skipped (their records are read back
    from frames.jsonl), and an existing ``out_dir/calib.json`` is reused.

    Args:
        calibration: known extrinsics; None = GMAC on ``calib_frame`` (default: the first good
            frame), unless ``use_rig_extrinsics`` and the recording's rig is calibrated.
        frames: which frame positions to fuse (default all).
        on_frame: called after each frame with (record, done, total), e.g. for a progress bar.
        ray: a ``fuseflow.distributed.RayOptions`` to fuse frames as Ray tasks (outputs are
            identical to the single-process run); None = fuse in this process.
    """
    if ray is not None and config.recalibrate == "auto":
        raise ValidationError(
            "recalibrate='auto' needs frames fused in order in one process; it is not available with Ray"
        )
    if not isinstance(rec, Recording):
        rec = open_recording(rec)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    warnings: list[str] = []
    calib_json = out / "calib.json"
    calib_source, calib_t = "", None
    if calibration is not None:
        rig, calib_source = _resolve_rig(rec.rig, calibration), "given"
        write_calibration(calib_json, Calibration({c.id: c.T_cam_world for c in rig}, {"source": "given"}))
    elif calib_json.exists():
        rig, calib_source = placed_rig(rec.rig, read_calibration(calib_json)), f"resumed from {calib_json}"
    elif use_rig_extrinsics and rec.rig.is_calibrated:
        rig, calib_source = rec.rig, "rig.json"
        write_calibration(calib_json, Calibration({c.id: c.T_cam_world for c in rig}, {"source": "rig.json"}))
    else:
        from fuseflow.calib import CalibConfig, calibrate

        calib_t = calib_frame if calib_frame is not None else first_good_frame(rec, config.min_valid_depth)
        cal = calibrate(rec[calib_t], rec.rig, config.calib if config.calib is not None else CalibConfig())
        unplaced = [c for c in rec.rig.ids if c not in cal.T_cam_world]
        if unplaced:
            warnings.append(f"GMAC could not place cameras {unplaced}; they are left out of fusion")
        warnings.extend(str(w) for w in cal.report.get("warnings", []))
        write_calibration(calib_json, cal)
        rig = placed_rig(rec.rig, cal)
        calib_source = f"GMAC on frame {rec.frame_numbers[calib_t]}"

    positions = list(frames if frames is not None else range(len(rec)))
    log_path = out / "frames.jsonl"
    previous: dict[int, dict] = {}
    if log_path.exists():
        for line in log_path.read_text().splitlines():
            try:
                r = json.loads(line)
                previous[int(r["index"])] = r
            except (json.JSONDecodeError, KeyError, ValueError):
                continue  # a line cut by an interruption
    monitor = HealthMonitor(rig.ids, config.health_warmup, config.health_drop, config.health_patience)
    sel = [rec.rig.index(c) for c in rig.ids]
    records: list[dict] = []
    dropped: dict[str, int] = {}
    bumped: dict[str, int] = {}
    recal: list[int] = []
    fused_now = resumed = 0
    fuse_ms: list[float] = []
    ray_results = None
    if ray is not None:
        from fuseflow.distributed import ray_frame_results

        todo = [
            t
            for t in positions
            if not (cloud_path(out, rec.frame_numbers[t]).exists() and rec.frame_numbers[t] in previous)
        ]
        ray_results = ray_frame_results(str(rec.path), todo, sel, rig, config, ray)
    t_start = time.perf_counter()
    with open(log_path, "a") as log:
        for k, t in enumerate(positions):
            number = rec.frame_numbers[t]
            path = cloud_path(out, number)
            if path.exists() and number in previous:
                records.append(previous[number])
                resumed += 1
                if previous[number].get("pairs"):  # rebuild the health baselines
                    prev_pairs = [[np.nan if x is None else x for x in row] for row in previous[number]["pairs"]]
                    monitor.update(np.array(prev_pairs, dtype=np.float64).reshape(len(rig), len(rig)))
                if on_frame:
                    on_frame(FrameRecord(**previous[number]), k + 1, len(positions))
                continue
            if ray_results is not None:
                _, cloud, rec_, _ = next(ray_results)
            else:
                cloud, rec_ = process_frame(rec[t], sel, rig, config)
            fuse_ms.append(rec_.fuse_ms)
            write_ply(path, cloud)
            pairs = np.array([[np.nan if x is None else x for x in row] for row in rec_.pairs], dtype=np.float64)
            rec_.flagged = flagged = monitor.update(pairs.reshape(len(rig), len(rig)))
            if flagged and config.recalibrate == "auto":
                from fuseflow.calib import CalibConfig, calibrate

                try:
                    cal = calibrate(
                        rec[t].subset(sel), rig, config.calib if config.calib is not None else CalibConfig()
                    )
                    rig = merge_recalibration(rig, cal, flagged)
                    write_calibration(
                        calib_json,
                        Calibration(
                            {c.id: c.T_cam_world for c in rig},
                            {"source": f"recalibrated at frame {number}", "gmac": cal.report},
                        ),
                    )
                    for c in flagged:
                        monitor.reset(c)
                    rec_.recalibrated = True
                except FuseFlowError as exc:
                    warnings.append(f"recalibration at frame {number} failed: {exc}")
            log.write(json.dumps(asdict(rec_)) + "\n")
            log.flush()
            records.append(asdict(rec_))
            fused_now += 1
            if on_frame:
                on_frame(rec_, k + 1, len(positions))
    wall = time.perf_counter() - t_start
    for r in records:
        for c in r.get("missing", []):
            dropped[c] = dropped.get(c, 0) + 1
        for c in r.get("flagged", []):
            bumped.setdefault(c, r["index"])
        if r.get("recalibrated"):
            recal.append(r["index"])
    pts = np.array([r["points"] for r in records], dtype=np.float64)
    for c, n in dropped.items():
        warnings.append(f"camera {c} was missing in {n} frames; those frames were fused from the other views")
    for c, n in bumped.items():
        warnings.append(f"camera {c} lost agreement with its neighbours from frame {n} (bumped?)")
    summary = RunSummary(
        recording=str(rec.path),
        out_dir=str(out),
        frames=len(records),
        frames_fused_now=fused_now,
        frames_resumed=resumed,
        fps=(fused_now / wall) if fused_now and wall > 0 else 0.0,
        ms_per_frame=float(np.median(fuse_ms)) if fuse_ms else 0.0,
        points_per_frame={
            "mean": float(pts.mean()) if pts.size else 0.0,
            "min": float(pts.min()) if pts.size else 0.0,
            "max": float(pts.max()) if pts.size else 0.0,
        },
        peak_memory_mb=_peak_rss_mb(),
        device=config.device,
        calibration=calib_source,
        calibration_frame=None if calib_t is None else rec.frame_numbers[calib_t],
        dropped_views=dropped,
        bumped_cameras=bumped,
        recalibrations=recal,
        warnings=warnings,
    )
    write_json_atomic(out / "summary.json", summary.to_json())
    return summary
