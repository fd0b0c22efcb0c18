"""``fuseflow demo``: the whole product on data it makes itself, with its errors against ground truth.

1. simulate a small dynamic rig (fuseflow.synth) with an *uncalibrated* rig.json;
2. run FUSE-Flow on it (fuseflow.pipeline.run: GMAC on the first good frame, FUSE every frame);
3. compare the GMAC extrinsics with the true ones (docs/design.md section 4: rotation error in
   degrees, translation error in mm, no scale alignment);
4. compare the first, middle and last fused frames with the true surface the cameras saw
   (fuseflow.eval.reference; Chamfer distance,
   F-score at 1 cm, share of points farther than 2 cm from the surface; 100k random query
   points each way, an unbiased estimate that keeps the demo fast). GMAC's world frame is its own (a reference
   camera); the cloud is moved into the simulator's world by the rigid (rotation +
   translation, no scale) fit of GMAC's camera centres onto the true ones;
5. render the last fused frame headless to PNG (colour, and fusion weight: the frame is fused
   again in memory, Draco files keep no weight) and, when rerun-sdk is installed, log the rig
   and every fused frame (colour; at most ``viz.rerun_log.RERUN_POINTS`` points a frame) to an
   .rrd file.

The clouds are written as Draco (``DEMO_FORMAT``) in the floor frame (``--world``, z up), and
scored from those files: the demo's whole output stays under 150 MB.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fuseflow.types import FusedCloud, Rig, invert_rigid

__all__ = ["DemoResult", "run_demo", "align_world", "DEMO_FORMAT"]

DEMO_FORMAT = "drc"
"""The demo's cloud files: Draco, positions within 1 mm (``io.exchange``), 4.8 MB a frame of 1.17 M
points against 27 MB as PLY; the scores are measured on these files."""

METRIC_SAMPLE = 100_000
"""Points queried each way per evaluated frame (trees hold every point; see reference_metrics)."""


@dataclass
class DemoResult:
    """What ``run_demo`` measured. Errors are against the simulator's ground truth."""

    out_dir: str
    recording: str
    cameras: int
    frames: int
    resolution: tuple[int, int]
    simulate_s: float
    run_s: float
    cameras_placed: int
    rotation_error_deg: float
    translation_error_mm: float
    chamfer_mm: float
    fscore_1cm: float
    outlier_share_2cm: float
    points_per_frame: float
    ms_per_frame: float
    png: list[str] = field(default_factory=list)
    rrd: str | None = None
    warnings: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def align_world(est: Rig, ref: Rig) -> np.ndarray:
    """4x4 rigid transform ref_world_from_est_world fitting ``est``'s camera centres onto ``ref``'s.

    Kabsch on the centres of the cameras both rigs place (>= 3 needed for a unique rotation;
    with 2 the rotation about their baseline is taken from the first camera's orientation).
    """
    ids = [c.id for c in est if c.T_cam_world is not None and ref[c.id].T_cam_world is not None]
    if len(ids) < 3:
        # one camera's pose fixes the frame change exactly: ref_world <- cam <- est_world
        c = ids[0]
        return invert_rigid(ref[c].T_cam_world) @ est[c].T_cam_world
    from fuseflow.pipeline import rigid_align

    src = np.stack([est[c].T_world_cam[:3, 3] for c in ids])
    dst = np.stack([ref[c].T_world_cam[:3, 3] for c in ids])
    return rigid_align(src, dst)


def _out_to_calib(calib: Any) -> np.ndarray:
    """Calibration-world-from-output-frame of a run's clouds (calib.json's ``world``)."""
    doc = calib.report.get("world")
    return invert_rigid(np.asarray(doc["T_out_world"], np.float64)) if doc else np.eye(4)


def _transform(cloud: FusedCloud, A: np.ndarray) -> np.ndarray:
    xyz = cloud.xyz.cpu().numpy().astype(np.float64)
    return xyz @ A[:3, :3].T + A[:3, 3]


def run_demo(
    out_dir: str | Path = "fuseflow-demo",
    cameras: int = 8,
    frames: int = 10,
    resolution: tuple[int, int] = (640, 480),
    seed: int = 1,
    scene: str = "studio",
    work_dir: str | Path | None = None,
    rerun: bool = True,
    on_stage: Callable[[str], None] | None = None,
    on_frame: Callable[[Any, int, int], None] | None = None,
) -> DemoResult:
    """Simulate, calibrate, fuse, measure and render (see the module docstring).

    Args:
        out_dir: where the run's outputs go (calib.json, clouds/, summary.json, demo.json, PNGs,
            demo.rrd); the simulated recording goes to a temporary directory unless ``work_dir``.
        rerun: write OUT/demo.rrd when rerun-sdk is importable.
        on_stage: called with a short description as each stage starts.
        on_frame: forwarded to ``fuseflow.pipeline.run`` (progress).
    """
    from fuseflow.io.recording import write_json_atomic
    from fuseflow.synth import SimConfig

    stage = on_stage or (lambda s: None)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    tmp = tempfile.TemporaryDirectory(prefix="fuseflow-demo-") if work_dir is None else None
    rec_dir = Path(tmp.name if tmp is not None else work_dir) / "recording"
    try:
        stage(f"simulating {cameras} cameras x {frames} frames ({resolution[0]}x{resolution[1]}, dynamic {scene})")
        cfg = SimConfig(cameras=cameras, frames=frames, scene=scene, dynamic=True, resolution=resolution, seed=seed)
        gt, sim_s = _simulate(rec_dir, cfg)
        stage("calibrating with GMAC, then fusing every frame with FUSE")
        summary, run_s = _calibrate_and_fuse(rec_dir, out, on_frame)
        stage("measuring against ground truth")
        scores = _score(out, gt, rec_dir)
        stage("rendering")
        pngs = _render_pngs(out, scores.last_xyz, scores.last_cloud)
        warnings = list(summary.warnings)
        rrd = _write_rrd(out, scores.est, gt.frames, warnings) if rerun else None
        result = DemoResult(
            out_dir=str(out),
            recording=str(rec_dir) if tmp is None else "(temporary, removed)",
            cameras=cameras,
            frames=frames,
            resolution=tuple(resolution),
            simulate_s=round(sim_s, 2),
            run_s=round(run_s, 2),
            cameras_placed=scores.cameras_placed,
            rotation_error_deg=scores.rotation_error_deg,
            translation_error_mm=scores.translation_error_mm,
            chamfer_mm=scores.chamfer_mm,
            fscore_1cm=scores.fscore_1cm,
            outlier_share_2cm=scores.outlier_share_2cm,
            points_per_frame=float(summary.points_per_frame["mean"]),
            ms_per_frame=float(summary.ms_per_frame),
            png=pngs,
            rrd=rrd,
            warnings=warnings,
        )
        write_json_atomic(out / "demo.json", result.to_json())
        if tmp is not None:  # summary.json must not name a folder that is removed below
            _unname_recording(out / "summary.json")
        return result
    finally:
        if tmp is not None:
            tmp.cleanup()


def _unname_recording(path: Path) -> None:
    """The run's summary.json with its ``recording`` marked as the removed temporary folder."""
    import json

    from fuseflow.io.recording import write_json_atomic

    doc = json.loads(path.read_text())
    doc["recording"] = "(temporary, removed)"
    write_json_atomic(path, doc)


def _simulate(rec_dir: Path, cfg: Any) -> tuple[Any, float]:
    """Step 1: write the simulated recording (uncalibrated rig.json) to ``rec_dir``; returns its
    ground truth and the seconds the simulation took."""
    from fuseflow.synth import read_ground_truth, simulate_recording

    t0 = time.perf_counter()
    simulate_recording(rec_dir, cfg, uncalibrated=True)
    sim_s = time.perf_counter() - t0
    return read_ground_truth(rec_dir), sim_s


def _calibrate_and_fuse(
    rec_dir: Path, out: Path, on_frame: Callable[[Any, int, int], None] | None
) -> tuple[Any, float]:
    """Step 2: fuseflow.pipeline.run from scratch (GMAC, then FUSE on every frame); returns its
    RunSummary and the seconds it took."""
    from fuseflow.pipeline import PipelineConfig, run
    from fuseflow.pipeline.config import OutputOptions

    t0 = time.perf_counter()
    # a demo always starts fresh; its simulated rig is in sync, so the sync check is skipped
    # Draco clouds (1 mm): a 10-frame demo writes ~50 MB of clouds instead of ~270 MB of PLY
    config = PipelineConfig(sync="off", outputs=OutputOptions(cloud_format=DEMO_FORMAT))
    summary = run(rec_dir, out, config=config, on_frame=on_frame, force=True)
    return summary, time.perf_counter() - t0


@dataclass
class _Scores:
    """What steps 3-4 measured, plus what the later steps draw (the GMAC rig, the last frame)."""

    est: Rig
    cameras_placed: int
    rotation_error_deg: float
    translation_error_mm: float
    chamfer_mm: float
    fscore_1cm: float
    outlier_share_2cm: float
    last_cloud: FusedCloud
    last_xyz: np.ndarray


def _score(out: Path, gt: Any, rec_dir: Path) -> _Scores:
    """Steps 3-4: GMAC's extrinsics against the true ones, and the first, middle and last fused
    frames (moved into the simulator's world) against the surface the cameras can measure."""
    from fuseflow.eval.metrics import pose_errors
    from fuseflow.io.calibration import read_calibration
    from fuseflow.io.exchange import read_cloud
    from fuseflow.pipeline.exports import frame_file

    calib = read_calibration(out / "calib.json")
    est = calib.apply(gt.rig.subset([gt.rig.index(c) for c in calib.camera_ids]))
    pe = pose_errors(calib, gt.rig)
    A = align_world(est, gt.rig) @ _out_to_calib(calib)  # the clouds are in the output frame (--world)
    from fuseflow.synth import Simulator

    sim = Simulator(gt.config)  # the same scene (same config and seed), for its triangles
    cds, fss, outs = [], [], []
    for t in sorted({0, gt.frames // 2, gt.frames - 1}):  # first, middle, last frame
        m = _frame_metrics(_transform(read_cloud(frame_file(out, t, DEMO_FORMAT)), A), gt, sim, t)
        cds.append(m.chamfer().chamfer_mm)
        fss.append(m.fscore(0.01).f_score)
        outs.append(m.outlier_share(0.02))
    last_cloud = _fused_again(rec_dir, calib, gt.frames - 1)  # with its weights, which Draco does not keep
    return _Scores(
        est=est,
        cameras_placed=len(calib.camera_ids),
        rotation_error_deg=float(pe.rotation_deg),
        translation_error_mm=float(pe.translation_mm),
        chamfer_mm=float(np.mean(cds)),
        fscore_1cm=float(np.mean(fss)),
        outlier_share_2cm=float(np.mean(outs)),
        last_cloud=last_cloud,
        last_xyz=_transform(last_cloud, align_world(est, gt.rig)),
    )


def _fused_again(rec_dir: Path, calib: Any, t: int) -> FusedCloud:
    """Frame position ``t`` fused as the run fused it (its calibration, the ``auto`` preset), in
    the calibration's world."""
    from fuseflow.fuse import PRESETS, fuse
    from fuseflow.io import open_recording

    rec = open_recording(rec_dir)
    sel = [rec.rig.index(c) for c in calib.camera_ids]
    return fuse(rec[t].subset(sel), calib.apply(rec.rig).subset(sel), PRESETS["auto"])


def _frame_metrics(xyz: np.ndarray, gt: Any, sim: Any, t: int) -> Any:
    """Distances (fuseflow.eval.metrics.SurfaceDistances) of (M, 3) world points to frame t's seen
    surface (fuseflow.eval.reference): fused point -> true surface, seen sample -> cloud."""
    from fuseflow.eval.reference import simulated_reference

    ref = simulated_reference(sim, t, gt.surface(t), gt.depth(t).numpy())
    # 100k random queries each way against the full clouds: an unbiased, fast estimate
    return ref.distances(xyz, sample=METRIC_SAMPLE, seed=t)


def _render_pngs(out: Path, last_xyz: np.ndarray, last_cloud: FusedCloud) -> list[str]:
    """Step 5: the last fused frame (world points ``last_xyz``) headless, by colour and by weight."""
    from fuseflow.viz.render import orbit_camera, save_cloud_png

    pngs: list[str] = []
    shown = FusedCloud.from_numpy(
        last_xyz.astype(np.float32), last_cloud.rgb.numpy(), last_cloud.weight.numpy(), last_cloud.camera.numpy()
    )
    K, T = orbit_camera(last_xyz, azimuth_deg=35.0, elevation_deg=25.0, up=(0.0, 0.0, 1.0))
    for by in ("rgb", "weight"):
        p = out / f"demo_{by}.png"
        save_cloud_png(p, shown, color_by=by, K=K, T_cam_world=T)
        pngs.append(str(p))
    return pngs


def _write_rrd(out: Path, est: Rig, frames: int, warnings: list[str]) -> str | None:
    """Step 5 (rerun): OUT/demo.rrd with the GMAC rig and every fused frame; None (and a warning appended
    to ``warnings``) when rerun is missing or broken."""
    from fuseflow.io.calibration import read_calibration
    from fuseflow.io.exchange import has_weight, read_cloud
    from fuseflow.pipeline.exports import frame_file

    try:
        from fuseflow.viz.rerun_log import RerunLogger

        world = read_calibration(out / "calib.json").report.get("world") or {}
        logger = RerunLogger(
            save_to=out / "demo.rrd", application_id="fuseflow-demo", z_up=world.get("name") == "floor"
        )
    except Exception as exc:  # rerun missing or broken: the demo still stands
        warnings.append(f"no .rrd written ({exc})")
        return None
    from fuseflow.types import Calibration

    back = _out_to_calib(read_calibration(out / "calib.json"))  # frustums in the clouds' frame
    logger.log_rig(Calibration({c.id: c.T_cam_world @ back for c in est if c.is_calibrated}, {}).apply(est))
    for t in range(frames):
        path = frame_file(out, t, DEMO_FORMAT)
        logger.log_cloud(t, read_cloud(path), with_weight=has_weight(path))
    logger.close()
    return str(out / "demo.rrd")
