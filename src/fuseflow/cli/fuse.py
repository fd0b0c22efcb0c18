"""`fuseflow fuse REC --out OUT`: FUSE every frame with known extrinsics, one PLY per frame
(``fuseflow.pipeline.fuse_recording``)."""

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
    parse_range,
    print_table,
    progress,
    warn,
)


def _grid(strides: list[int]) -> str:
    """The table's note on the pixel grids used, when any is coarser than every pixel."""
    if not strides or strides == [1]:
        return ""
    return f"; candidates on a pixel grid of stride {'/'.join(map(str, strides))} (point budget, preset or auto)"


def command(
    rec: Path = typer.Argument(..., help="Recording directory (fuseflow format, Open3D/ICL or TUM layout)."),
    out: Path = typer.Option(..., "--out", help=OUT_HELP),
    calib: Path = typer.Option(None, "--calib", help="Extrinsics to use (calib.json); default: rig.json's."),
    frames: str = typer.Option(None, "--frames", help=FRAMES_OPTION_HELP),
    device: str = typer.Option("cpu", "--device", help="cpu or cuda (cpu runs the compiled numba path)."),
    preset: str = typer.Option(
        "auto",
        "--preset",
        help=AUTO_HELP + " default (every pixel), dense, live (every 2nd pixel), fast, paper, 'w/o CVGC', ...",
    ),
    force: bool = typer.Option(
        False,
        "--force",
        help="Delete the outputs of a different earlier fuse in --out (only the files fuse writes) and start over.",
    ),
    points: int = typer.Option(None, "--points", help=POINTS_HELP),
    settings: list[str] = typer.Option(None, "--set", metavar="NAME=VALUE", help=SET_HELP),
    crop: str = oo.CROP,
    fmt: str = oo.FORMAT,
    drc_error_mm: float = oo.DRC_ERROR,
    mesh: bool = oo.MESH,
    mesh_ply: bool = oo.MESH_PLY,
    mesh_method: str = oo.MESH_METHOD,
    world: str = oo.WORLD,
    voxel: float = oo.VOXEL,
) -> None:
    """FUSE every frame with known extrinsics (no calibration, no health monitor): one PLY per frame."""
    from fuseflow.cli.settings import parse_settings
    from fuseflow.io import open_recording, read_calibration
    from fuseflow.pipeline import fuse_recording

    check_device(device)
    check_fuse_options(preset, points, settings)
    outputs = oo.output_options(crop, fmt, drc_error_mm, mesh, mesh_ply, mesh_method, world, voxel)
    recording = open_recording(rec)
    calibration = read_calibration(calib) if calib is not None else None
    positions = parse_range(frames, len(recording))
    with progress("fusing") as bar:
        task = bar.add_task(f"fusing {len(positions)} frames", total=len(positions))
        s = fuse_recording(
            recording, out, calibration, positions, preset, device,
            on_frame=lambda done, total: bar.update(task, completed=done),
            calibration_source=str(calib) if calib is not None else None, force=force, points=points,
            outputs=outputs, overrides=parse_settings(settings or ()),
        )  # fmt: skip
    ppf, ms = s.points_per_frame, s.fuse_ms_per_frame
    print_table(
        f"FUSE: {out}",
        [
            (
                "frames",
                f"{s.frames} ({s.cameras} cameras, preset {preset}; {s.frames_resumed} kept from an earlier call)",
            ),
            ("points per frame", f"{ppf['mean']:.0f} (min {ppf['min']}, max {ppf['max']}){_grid(s.pixel_strides)}"),
            *(("grid", g) for g in s.grid_choices),
            (
                "fusion",
                f"{ms['median']:.1f} ms per frame median ({ms['mean']:.1f} mean) on {device} ({s.backend} backend)",
            ),
            ("wall time", f"{s.wall_s:.1f} s with reading and writing ({s.frames / s.wall_s:.2f} frames/s)"),
            ("clouds", str(Path(out) / "clouds")),
            *oo.output_rows(out),
        ],
    )
    if s.left_out:
        warn(f"the calibration does not place cameras {s.left_out}; they are left out of fusion")
    for w in s.input_warnings:
        warn(w)
    for w, n in s.warnings.items():
        warn(f"{w} ({n} frames)")


#: ``--help`` examples (click keeps a paragraph after "\\b" as written).
EXAMPLES = """\b
Examples:
  fuseflow fuse /tmp/studio --calib /tmp/studio-calib.json --out /tmp/studio-clouds --frames 0:10
  fuseflow fuse /tmp/studio --out /tmp/clouds --preset live     # extrinsics from rig.json
  fuseflow fuse /tmp/studio --out /tmp/clouds --crop auto --format ply,glb,splat --voxel 5
"""
