"""``fuseflow demo``: the whole product on data it makes itself, with its errors against ground truth.

1. simulate a small dynamic rig (fuseflow.synth) with an *uncalibrated* rig.json;
2. run FUSE-Flow on it (fuseflow.pipeline.run: GMAC on the first good frame, FUSE every frame);
3. compare the GMAC extrinsics with the true ones (DESIGN.md section 4: rotation error in
   degrees, translation error in mm, no scale alignment);
4. compare the first, middle and last fused frames with the true surface the cameras can
   measure (visible and inside the depth range; Chamfer distance,
   F-score at 1 cm, share of points farther than 2 cm from the surface; 100k random query
   points each way, an unbiased estimate that keeps the demo fast). GMAC's world frame is its own (a reference
   camera); the cloud is moved into the simulator's world by the rigid (rotation +
   translation, no scale) fit of GMAC's camera centres onto the true ones;
5. render the last fused frame headless to PNG (colour, and fusion weight) and, when rerun-sdk
   is installed, log the rig and every fused frame to an .rrd file.
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

__all__ = ["DemoResult", "run_demo", "align_world"]

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
    from fuseflow.eval.metrics import pose_errors, reference_metrics
    from fuseflow.io.calibration import read_calibration
    from fuseflow.io.ply import read_ply
    from fuseflow.io.recording import write_json_atomic
    from fuseflow.pipeline import cloud_path, run
    from fuseflow.synth import SimConfig, observable_mask, read_ground_truth, simulate_recording
    from fuseflow.viz.render import orbit_camera, save_cloud_png

    stage = on_stage or (lambda s: None)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    tmp = None
    if work_dir is None:
        tmp = tempfile.TemporaryDirectory(prefix="fuseflow-demo-")
        rec_dir = Path(tmp.name) / "recording"
    else:
        rec_dir = Path(work_dir) / "recording"
    try:
        stage(f"simulating {cameras} cameras x {frames} frames ({resolution[0]}x{resolution[1]}, dynamic {scene})")
        cfg = SimConfig(cameras=cameras, frames=frames, scene=scene, dynamic=True, resolution=resolution, seed=seed)
        t0 = time.perf_counter()
        simulate_recording(rec_dir, cfg, uncalibrated=True)
        sim_s = time.perf_counter() - t0
        gt = read_ground_truth(rec_dir)

        stage("calibrating with GMAC, then fusing every frame with FUSE")
        for stale in (out / "calib.json", out / "frames.jsonl", out / "summary.json"):
            stale.unlink(missing_ok=True)  # a demo always starts fresh (run() would resume)
        for old in (out / "clouds").glob("*.ply") if (out / "clouds").is_dir() else ():
            old.unlink()
        t0 = time.perf_counter()
        summary = run(rec_dir, out, on_frame=on_frame)
        run_s = time.perf_counter() - t0

        stage("measuring against ground truth")
        calib = read_calibration(out / "calib.json")
        est = calib.apply(gt.rig.subset([gt.rig.index(c) for c in calib.camera_ids]))
        pe = pose_errors(calib, gt.rig)
        A = align_world(est, gt.rig)
        cds, fss, outs = [], [], []
        for t in sorted({0, gt.frames // 2, gt.frames - 1}):  # first, middle, last frame
            cloud = read_ply(cloud_path(out, t))
            xyz = _transform(cloud, A)
            surf, nrm = gt.surface(t)
            # score against the surface the cameras can measure (visible and inside the depth
            # range): the studio's far walls are in the simulator's surface but beyond 4.5 m
            surf = surf[observable_mask(surf, nrm, gt.depth(t).numpy(), gt.rig)]
            # 100k random queries each way against the full clouds: an unbiased, fast estimate
            m = reference_metrics(xyz, surf, f_threshold=0.01, outlier_threshold=0.02, sample=METRIC_SAMPLE, seed=t)
            cds.append(m.chamfer.chamfer_mm)
            fss.append(m.fscore.f_score)
            outs.append(m.outlier_share)
        last_cloud = read_ply(cloud_path(out, gt.frames - 1))
        last_xyz = _transform(last_cloud, A)

        stage("rendering")
        pngs: list[str] = []
        shown = FusedCloud.from_numpy(
            last_xyz.astype(np.float32), last_cloud.rgb.numpy(), last_cloud.weight.numpy(), last_cloud.camera.numpy()
        )
        K, T = orbit_camera(last_xyz, azimuth_deg=35.0, elevation_deg=25.0, up=(0.0, 0.0, 1.0))
        for by in ("rgb", "weight"):
            p = out / f"demo_{by}.png"
            save_cloud_png(p, shown, color_by=by, K=K, T_cam_world=T)
            pngs.append(str(p))
        rrd = None
        warnings = list(summary.warnings)
        if rerun:
            try:
                from fuseflow.viz.rerun_log import RerunLogger

                logger = RerunLogger(save_to=out / "demo.rrd", application_id="fuseflow-demo")
            except Exception as exc:  # rerun missing or broken: the demo still stands
                warnings.append(f"no .rrd written ({exc})")
            else:
                logger.log_rig(est)
                for t in range(gt.frames):
                    logger.log_cloud(t, read_ply(cloud_path(out, t)))
                logger.close()
                rrd = str(out / "demo.rrd")
        result = DemoResult(
            out_dir=str(out),
            recording=str(rec_dir) if tmp is None else "(temporary, removed)",
            cameras=cameras,
            frames=frames,
            resolution=tuple(resolution),
            simulate_s=round(sim_s, 2),
            run_s=round(run_s, 2),
            cameras_placed=len(calib.camera_ids),
            rotation_error_deg=float(pe.rotation_deg),
            translation_error_mm=float(pe.translation_mm),
            chamfer_mm=float(np.mean(cds)),
            fscore_1cm=float(np.mean(fss)),
            outlier_share_2cm=float(np.mean(outs)),
            points_per_frame=float(summary.points_per_frame["mean"]),
            ms_per_frame=float(summary.ms_per_frame),
            png=pngs,
            rrd=rrd,
            warnings=warnings,
        )
        write_json_atomic(out / "demo.json", result.to_json())
        return result
    finally:
        if tmp is not None:
            tmp.cleanup()
