"""`fuseflow bench ...`: the benchmarks a user runs on their own machine and recordings.

``bench_app`` is the group; its subcommands are registered in the list at the end of this module:
``fuse`` (fuseflow.eval.bench.fuse_speed: per-frame time and memory of FUSE and the baselines on
this machine) and ``fuse-ratio`` (fuseflow.eval.bench.fuse_ratio: FUSE against VoxelBlockGrid on
the user's own recordings). The studies behind the documented numbers (paper tables, calibration
accuracy, quality grids, live replay, ...) are programs of the source tree's ``benchmarks/``
(docs/architecture.md says why).
"""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

import typer

from fuseflow.cli.app import OLD_FRAMES_COUNT, fail, frame_count, guarded

DATA_DIR_HELP = (
    "The shared data folder holding icl-livingroom1 (ICL-NUIM). Default ../shared/data, relative to the "
    "working directory (run from the project root), or the environment variable FUSEFLOW_DATA."
)


def _data_dir_option() -> Path:
    return typer.Option(Path("../shared/data"), "--data-dir", envvar="FUSEFLOW_DATA", help=DATA_DIR_HELP)


def _echo(line: str) -> None:
    typer.echo(line)


def bench_fuse(
    cameras: str = typer.Option("1,2,4,8,16", "--cameras", help="Comma list of camera counts N."),
    num_frames: int = typer.Option(7, "--num-frames", help="Timed frames per N (median over them, after warm-up)."),
    old_frames: int = OLD_FRAMES_COUNT,
    device: str = typer.Option("cpu", "--device", help="cpu or cuda."),
    json_out: Path = typer.Option(None, "--json", help="Write one JSON row per (method, N)."),
    no_baselines: bool = typer.Option(False, "--no-baselines", help="Time FUSE only."),
    methods_opt: str = typer.Option(
        None, "--methods", help="Comma list of methods (fuse, fuse_auto, fuse_live, vbg, naive_voxel, ...)."
    ),
    data: str = typer.Option("sim", "--data", help="Comma list of sim, icl, hocap (real 8-camera rigs, N <= 8)."),
    data_dir: Path = _data_dir_option(),
) -> None:
    """FUSE per-frame time and peak memory against VoxelBlockGrid TSDF and naive + voxel fusion."""
    frames = frame_count(num_frames, old_frames)
    from fuseflow.eval.bench import BenchmarkFailed
    from fuseflow.eval.bench.fuse_speed import DEFAULT_METHODS, parse_options, run_fuse_speed

    cams, resolution = parse_options(cameras, "640x480")
    command = f"fuseflow bench fuse --cameras {cameras} --num-frames {frames} --device {device} --data {data}"
    command += (f" --json {shlex.quote(str(json_out))}" if json_out is not None else "") + (
        " --no-baselines" if no_baselines else ""
    )
    methods = ["fuse"] if no_baselines else list(DEFAULT_METHODS)
    if methods_opt and not no_baselines:
        methods = [m.strip() for m in methods_opt.split(",") if m.strip()]
        command += f" --methods {methods_opt}"
    names = [d.strip() for d in data.split(",") if d.strip()]
    try:
        run_fuse_speed(cams, frames, device=device, methods=methods, resolution=resolution, json_path=json_out,
                       command=command, log=_echo, data=names, data_dir=data_dir)  # fmt: skip
    except BenchmarkFailed as exc:
        fail(str(exc), code=1)


def bench_fuse_ratio(
    recordings: list[Path] = typer.Argument(..., help="Recordings (fuseflow format); the first frame of each."),
    preset: str = typer.Option("auto", "--preset", help="FUSE preset."),
    rounds: int = typer.Option(5, "--rounds", help="Interleaved FUSE / VBG rounds (median ratio over them)."),
    json_out: Path = typer.Option(None, "--json", help="Write the rows as JSON."),
) -> None:
    """FUSE vs VoxelBlockGrid 1 cm as an interleaved time ratio (robust to a loaded machine)."""
    from fuseflow.eval.bench.fuse_ratio import run_fuse_ratio
    from fuseflow.eval.results import write_result

    rows = run_fuse_ratio(recordings, preset, rounds, log=_echo)
    if json_out is not None:
        command = "fuseflow bench " + " ".join(shlex.quote(a) for a in sys.argv[2:])
        write_result(json_out, "fuse_ratio", command, rows, {"preset": preset, "rounds": rounds})


bench_app = typer.Typer(
    help="Benchmarks: FUSE speed on this machine and against VoxelBlockGrid on your recordings.",
    no_args_is_help=True,
    rich_markup_mode=None,
)
for _name, _command in (
    ("fuse", bench_fuse),
    ("fuse-ratio", bench_fuse_ratio),
):
    bench_app.command(_name)(guarded(_command))
