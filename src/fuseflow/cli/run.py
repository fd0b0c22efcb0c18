"""`fuseflow run`, `fuseflow demo` and `fuseflow view`: the composed product (FUSE-Flow)."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from fuseflow.cli.app import app, console, fail, parse_range, progress, warn


def _print_summary(s) -> None:
    from rich.table import Table

    t = Table(title=f"FUSE-Flow run: {s.out_dir}", show_header=False)
    t.add_row("frames", f"{s.frames} ({s.frames_fused_now} fused now, {s.frames_resumed} resumed)")
    t.add_row("calibration", s.calibration)
    t.add_row("fusion", f"{s.ms_per_frame:.1f} ms per frame on {s.device}; {s.fps:.2f} frames/s end to end")
    ppf = s.points_per_frame
    t.add_row("points per frame", f"{ppf['mean']:.0f} (min {ppf['min']:.0f}, max {ppf['max']:.0f})")
    t.add_row("peak memory", f"{s.peak_memory_mb:.0f} MB")
    if s.dropped_views:
        t.add_row("dropped views", ", ".join(f"{c}: {n} frames" for c, n in s.dropped_views.items()))
    if s.bumped_cameras:
        t.add_row("bumped cameras", ", ".join(f"{c} (from frame {f})" for c, f in s.bumped_cameras.items()))
    if s.recalibrations:
        t.add_row("recalibrated at", ", ".join(map(str, s.recalibrations)))
    console.print(t)
    for w in s.warnings:
        warn(w)


@app.command("run")
def run_cmd(
    rec: Path = typer.Argument(..., help="Recording directory (fuseflow format, Open3D/ICL or TUM layout)."),
    out: Path = typer.Option(..., "--out", help="Output directory: calib.json, clouds/<frame>.ply, summary.json."),
    calib: Path = typer.Option(None, "--calib", help="Use these extrinsics (calib.json) instead of running GMAC."),
    use_rig: bool = typer.Option(False, "--use-rig", help="Use the extrinsics in rig.json instead of running GMAC."),
    calib_frame: int = typer.Option(
        None, "--calib-frame", help="Frame position GMAC calibrates on (default: first good)."
    ),
    frames: str = typer.Option(None, "--frames", help="A:B, frame positions to fuse (default all)."),
    device: str = typer.Option("cpu", "--device", help="cpu or cuda."),
    recalibrate: str = typer.Option("off", "--recalibrate", help="off | auto: re-run GMAC when a camera is bumped."),
    ray: bool = typer.Option(False, "--ray", help="Fuse frames as Ray tasks (pip install 'fuseflow[ray]')."),
    ray_address: str = typer.Option(None, "--ray-address", help="Ray cluster address (default: start a local Ray)."),
    ray_cpus: int = typer.Option(None, "--ray-cpus", help="CPUs of a local Ray (default all)."),
) -> None:
    """Calibrate once (GMAC), fuse every frame (FUSE); resumes when run again on the same --out."""
    from fuseflow.io import open_recording, read_calibration
    from fuseflow.pipeline import PipelineConfig, run

    if device not in ("cpu", "cuda") and not device.startswith("cuda:"):
        fail(f"--device must be cpu or cuda, got {device!r}")
    if device.startswith("cuda"):
        import torch

        if not torch.cuda.is_available():
            fail("--device cuda: torch sees no CUDA device on this machine")
    if calib is not None and use_rig:
        fail("--calib and --use-rig both choose the extrinsics; pass one")
    recording = open_recording(rec)
    calibration = read_calibration(calib) if calib is not None else None
    ray_opts = None
    if ray or ray_address:
        from fuseflow.distributed import RayOptions

        ray_opts = RayOptions(address=ray_address, num_cpus=ray_cpus)
    cfg = PipelineConfig(device=device, recalibrate=recalibrate)
    positions = parse_range(frames, len(recording))
    with progress("fusing") as bar:
        task = bar.add_task(f"fusing {len(positions)} frames", total=len(positions))
        summary = run(
            recording, out, calibration=calibration, config=cfg, frames=positions, calib_frame=calib_frame,
            use_rig_extrinsics=use_rig, ray=ray_opts,
            on_frame=lambda r, done, total: bar.update(task, completed=done),
        )  # fmt: skip
    _print_summary(summary)


@app.command("demo")
def demo_cmd(
    out: Path = typer.Option(Path("fuseflow-demo"), "--out", help="Where the demo writes its results."),
    cameras: int = typer.Option(8, "--cameras", help="Simulated cameras."),
    frames: int = typer.Option(10, "--frames", help="Simulated frames."),
    seed: int = typer.Option(1, "--seed", help="Simulator seed."),
) -> None:
    """Simulate a dynamic rig, calibrate it with GMAC, fuse it with FUSE, score it against ground truth."""
    from fuseflow.demo import run_demo

    with progress("demo") as bar:
        task = bar.add_task("fusing", total=frames, visible=False)

        def stage(s: str) -> None:
            console.print(f"[bold]>[/] {s}", highlight=False)

        def frame(r, done: int, total: int) -> None:
            bar.update(task, completed=done, visible=True)

        res = run_demo(out, cameras=cameras, frames=frames, seed=seed, on_stage=stage, on_frame=frame)
    from rich.table import Table

    t = Table(title="FuseFlow demo: errors against the simulator's ground truth", show_header=False)
    t.add_row("rig", f"{res.cameras} cameras, {res.frames} frames, {res.resolution[0]}x{res.resolution[1]}, dynamic")
    t.add_row("GMAC cameras placed", f"{res.cameras_placed} of {res.cameras}")
    t.add_row("GMAC rotation error", f"{res.rotation_error_deg:.3f} deg (mean over camera pairs)")
    t.add_row("GMAC translation error", f"{res.translation_error_mm:.1f} mm (no scale alignment)")
    t.add_row("FUSE Chamfer distance", f"{res.chamfer_mm:.1f} mm (first, middle, last frame)")
    t.add_row("FUSE F-score @ 1 cm", f"{res.fscore_1cm:.3f}")
    t.add_row("points > 2 cm from surface", f"{100 * res.outlier_share_2cm:.2f} %")
    t.add_row("points per frame", f"{res.points_per_frame:.0f}")
    t.add_row("FUSE time", f"{res.ms_per_frame:.0f} ms per frame")
    t.add_row("wall time", f"simulate {res.simulate_s:.1f} s, calibrate + fuse {res.run_s:.1f} s")
    t.add_row("pictures", ", ".join(res.png))
    t.add_row("rerun", res.rrd or "not written (pip install 'fuseflow[viz]')")
    console.print(t)
    for w in res.warnings:
        warn(w)


def _view_inputs(path: Path):
    """(rig or None, [(frame number, FusedCloud loader)]) for a run directory or a recording."""
    from fuseflow.io import open_recording, read_calibration, read_ply

    if (path / "clouds").is_dir():
        clouds = sorted((path / "clouds").glob("*.ply"))
        if not clouds:
            fail(f"{path / 'clouds'} holds no .ply files")
        rig = None
        summary = path / "summary.json"
        if (path / "calib.json").exists() and summary.exists():
            try:
                rec = open_recording(json.loads(summary.read_text())["recording"])
                rig = read_calibration(path / "calib.json").apply(rec.rig)
            except Exception:  # the recording moved: show the clouds without frustums
                rig = None
        return rig, [(int(p.stem), (lambda p=p: read_ply(p))) for p in clouds]
    rec = open_recording(path)
    if not rec.rig.is_calibrated:
        fail(f"{path}: rig.json has no extrinsics; view a run directory (fuseflow run) or calibrate first")
    from fuseflow.fuse import fuse

    return rec.rig, [(rec.frame_numbers[t], (lambda t=t: fuse(rec[t], rec.rig))) for t in range(len(rec))]


def _world_up(rig) -> tuple[float, float, float]:
    """The world's up direction: the mean of the cameras' up axes (-y in OpenCV axes), since rig
    cameras are mounted roughly upright; (0, -1, 0) (the first camera's frame) without a rig."""
    import numpy as np

    if rig is None or not rig.is_calibrated:
        return (0.0, -1.0, 0.0)
    up = np.mean([-c.T_cam_world[1, :3] for c in rig], axis=0)  # row 1 of R = camera y in world
    n = float(np.linalg.norm(up))
    return tuple((up / n).tolist()) if n > 1e-6 else (0.0, -1.0, 0.0)


@app.command("view")
def view_cmd(
    path: Path = typer.Argument(..., help="A run directory (with clouds/) or a calibrated recording."),
    save_png: Path = typer.Option(None, "--save-png", help="Headless: render each frame to DIR/<frame>.png."),
    color_by: str = typer.Option("rgb", "--color-by", help="rgb or weight (PNG only; rerun shows both)."),
    rrd: Path = typer.Option(None, "--rrd", help="Write a rerun .rrd file instead of opening the viewer."),
    frames: str = typer.Option(None, "--frames", help="A:B, which frames to show."),
) -> None:
    """Show fused clouds per frame (rerun: cameras as frustums, clouds on a timeline, weight as colour)."""
    rig, items = _view_inputs(path)
    items = [items[i] for i in parse_range(frames, len(items))]
    if save_png is not None:
        from fuseflow.viz.render import orbit_camera, save_cloud_png

        view = None
        for number, load in items:
            cloud = load()
            if view is None and len(cloud):
                view = orbit_camera(cloud.xyz.numpy(), up=_world_up(rig))
            K, T = view if view is not None else (None, None)
            save_cloud_png(Path(save_png) / f"{number:06d}.png", cloud, color_by=color_by, K=K, T_cam_world=T)
        console.print(f"wrote {len(items)} PNGs to {save_png}")
        return
    from fuseflow.viz.rerun_log import RerunLogger

    logger = RerunLogger(save_to=rrd, spawn=rrd is None)
    if rig is not None:
        logger.log_rig(rig)
    for number, load in items:
        logger.log_cloud(number, load())
    logger.close()
    console.print(f"wrote {rrd}" if rrd is not None else f"sent {len(items)} frames to the rerun viewer")
