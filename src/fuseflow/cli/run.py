"""`fuseflow run REC --out OUT`: the composed product (FUSE-Flow): calibrate once, fuse every frame."""

from __future__ import annotations

from pathlib import Path

import typer

from fuseflow.cli import output_options as oo
from fuseflow.cli.app import (
    AUTO_HELP,
    FRAMES_OPTION_HELP,
    OUT_HELP,
    POINTS_HELP,
    SET_HELP,
    check_device,
    check_fuse_options,
    fail,
    parse_range,
    print_table,
    progress,
    say,
    warn,
)


def speed_line(s) -> str:
    """The fusion row: warm per-frame time and the first frame's start-up apart (a short
    recording's median is mostly start-up), and the end-to-end rate."""
    if s.warm_ms_per_frame is not None:
        return (
            f"{s.warm_ms_per_frame:.1f} ms per frame warm (median after the first) on {s.device}; first frame "
            f"{s.first_frame_ms:.0f} ms (start-up included); {s.fps:.2f} frames/s end to end"
        )
    return f"{s.first_frame_ms or s.ms_per_frame:.1f} ms for one frame on {s.device}, start-up included"


def output_size(path: Path) -> str:
    """'412 MB in 31 files' for everything under ``path``."""
    files = [p for p in Path(path).rglob("*") if p.is_file()]
    return f"{sum(p.stat().st_size for p in files) / 1e6:.1f} MB in {len(files)} files"


def _print_summary(s) -> None:
    ppf = s.points_per_frame
    if s.nothing_to_do:
        say(f"nothing to do: every frame asked for is already in {s.out_dir}; the numbers are the run that fused them")
    rows = [
        ("frames", f"{s.frames} ({s.frames_fused_now} fused now, {s.frames_resumed} resumed)"),
        ("calibration", s.calibration),
        ("fusion", speed_line(s)),
        ("points per frame", f"{ppf['mean']:.0f} (min {ppf['min']:.0f}, max {ppf['max']:.0f})"),
        ("peak memory", f"{s.peak_memory_mb:.0f} MB"),
    ]
    if s.dropped_views:
        rows.append(("dropped views", ", ".join(f"{c}: {n} frames" for c, n in s.dropped_views.items())))
    if s.bumped_cameras:
        rows.append(("bumped cameras", ", ".join(f"{c} (from frame {f})" for c, f in s.bumped_cameras.items())))
    if s.recalibrations:
        rows.append(("recalibrated at", ", ".join(map(str, s.recalibrations))))
    if s.sync_offsets:
        rows.append(("out of sync", ", ".join(f"{c}: {k:+d} frames" for c, k in s.sync_offsets.items())))
    rows += oo.output_rows(s.out_dir)
    rows.append(("output", output_size(Path(s.out_dir))))
    print_table(f"FUSE-Flow run: {s.out_dir}", rows)
    for w in s.warnings:  # on stderr: a run piped into a file or another tool still shows them
        warn(w, stderr=True)


def command(
    rec: Path = typer.Argument(..., help="Recording directory (fuseflow format, Open3D/ICL or TUM layout)."),
    out: Path = typer.Option(..., "--out", help=OUT_HELP),
    calib: Path = typer.Option(None, "--calib", help="Use these extrinsics (calib.json) instead of running GMAC."),
    use_rig: bool = typer.Option(False, "--use-rig", help="Use the extrinsics in rig.json instead of running GMAC."),
    calib_frame: int = typer.Option(
        None, "--calib-frame", help="Frame position GMAC calibrates on (default: first good)."
    ),
    frames: str = typer.Option(None, "--frames", help=FRAMES_OPTION_HELP),
    device: str = typer.Option("cpu", "--device", help="cpu or cuda."),
    preset: str = typer.Option(
        "auto",
        "--preset",
        help=AUTO_HELP + " default (every pixel), dense, live (every 2nd pixel), fast, paper, ...",
    ),
    points: int = typer.Option(None, "--points", help=POINTS_HELP),
    settings: list[str] = typer.Option(None, "--set", metavar="NAME=VALUE", help=SET_HELP),
    recalibrate: str = typer.Option("off", "--recalibrate", help="off | auto: re-run GMAC when a camera is bumped."),
    ray: bool = typer.Option(False, "--ray", help="Fuse frames as Ray tasks (pip install 'fuseflow[ray]')."),
    ray_address: str = typer.Option(None, "--ray-address", help="Ray cluster address (default: start a local Ray)."),
    ray_cpus: int = typer.Option(None, "--ray-cpus", help="CPUs of a local Ray (default all)."),
    force: bool = typer.Option(
        False,
        "--force",
        help="Delete the outputs of a different earlier run in --out (only the files run writes) and start over.",
    ),
    sync_offsets: str = typer.Option(
        "check",
        "--sync-offsets",
        help="off | check: report cameras whose depth agrees best with their neighbours' earlier or later "
        "frames (a camera out of sync) | auto: also re-time them for fusion.",
    ),
    crop: str = oo.CROP,
    fmt: str = oo.FORMAT,
    drc_error_mm: float = oo.DRC_ERROR,
    mesh: bool = oo.MESH,
    mesh_ply: bool = oo.MESH_PLY,
    mesh_method: str = oo.MESH_METHOD,
    world: str = oo.WORLD,
    voxel: float = oo.VOXEL,
) -> None:
    """Calibrate once (GMAC), fuse every frame (FUSE); resumes when run again on the same --out."""
    from fuseflow.cli.settings import fuse_config
    from fuseflow.io import open_recording
    from fuseflow.pipeline import PipelineConfig, RayOptions, run

    check_device(device)
    check_fuse_options(preset, points, settings)
    outputs = oo.output_options(crop, fmt, drc_error_mm, mesh, mesh_ply, mesh_method, world, voxel)
    recording = open_recording(rec)
    calibration = _given_extrinsics(rec, recording, calib, use_rig)
    ray_opts = RayOptions(address=ray_address, num_cpus=ray_cpus) if (ray or ray_address) else None
    if sync_offsets == "auto" and ray_opts is not None:
        fail("--sync-offsets auto re-times views in this process; use check or off with --ray")
    cfg = PipelineConfig(
        device=device,
        recalibrate=recalibrate,
        sync=sync_offsets,
        fuse=fuse_config(preset, points, settings or ()),
        outputs=outputs,
    )
    positions = parse_range(frames, len(recording))
    gmac = calibration is None and not (use_rig and recording.rig.is_calibrated) and not (out / "calib.json").exists()
    fusing = f"fusing {len(positions)} frames"
    with progress("fusing") as bar:
        first = ("calibrating (GMAC), then " if gmac else "checking inputs, then ") + fusing
        if not bar.console.is_terminal:  # no bar when piped: one plain line per stage
            say(first)
        task = bar.add_task(first, total=len(positions))
        summary = run(
            recording, out, calibration=calibration, config=cfg, frames=positions, calib_frame=calib_frame,
            use_rig_extrinsics=use_rig, ray=ray_opts, force=force,
            on_frame=lambda r, done, total: bar.update(task, completed=done, description=fusing),
        )  # fmt: skip
    _print_summary(summary)
    if gmac:
        _print_calibration(recording, out, summary.calibration_frame)


def _given_extrinsics(rec: Path, recording, calib: Path | None, use_rig: bool):
    """The calibration ``--calib`` names (None for rig.json's or GMAC's); refuses ``--calib`` with
    ``--use-rig``, and ``--use-rig`` on a rig without extrinsics (as ``fuseflow fuse`` does)."""
    from fuseflow.io import read_calibration

    if calib is not None and use_rig:
        fail("--calib and --use-rig both choose the extrinsics; pass one")
    if use_rig and not recording.rig.is_calibrated:
        fail(
            f"--use-rig: {rec}/rig.json has no extrinsics: run fuseflow calibrate first, pass --calib, or drop --use-rig"
        )
    return read_calibration(calib) if calib is not None else None


def _print_calibration(recording, out: Path, number: int | None) -> None:
    """GMAC ran: its per-camera verdict table and the report picture (OUT/calib.png), as
    `fuseflow calibrate` prints and writes them."""
    from types import SimpleNamespace

    from fuseflow.cli.calibrate import print_verdicts, write_picture
    from fuseflow.io import read_calibration
    from fuseflow.types import Rig

    cal = read_calibration(out / "calib.json")
    verdicts = cal.report.get("camera_verdicts")
    if not verdicts:
        return
    print_verdicts(verdicts)
    numbers = list(recording.frame_numbers)
    frame = recording[numbers.index(number) if number in numbers else 0]
    rig = Rig(tuple(c.with_extrinsics(None) for c in recording.rig))
    drawn = SimpleNamespace(T_cam_world=cal.T_cam_world, report=SimpleNamespace(**cal.report))  # the fields it reads
    picture = write_picture(out / "calib.json", frame, rig, drawn)
    if picture:
        say(f"wrote {picture}")


#: ``--help`` examples (click keeps a paragraph after "\\b" as written).
EXAMPLES = """\b
Examples:
  fuseflow run /tmp/studio --out /tmp/studio-run          # GMAC on the first good frame, then fuse
  fuseflow run /data/rig --calib calib.json --out /data/run --sync-offsets auto
"""
