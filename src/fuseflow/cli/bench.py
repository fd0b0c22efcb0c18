"""`fuseflow bench ...`: the benchmarks a user runs on their own machine and recordings.

``bench_app`` is the group; its subcommands are registered in the list at the end of this module:
``fuse`` (fuseflow.eval.bench.fuse_speed: per-frame time and memory of FUSE and the baselines on
this machine), ``fuse-ratio`` (fuseflow.eval.bench.fuse_ratio: FUSE against VoxelBlockGrid on
the user's own recordings) and ``live`` (fuseflow.eval.bench.live: recordings replayed through
``fuseflow live`` with a viewer; with ``--nodes``, fuseflow.eval.bench.live_nodes: capture nodes
on a local Ray cluster against one host). The other studies behind the documented numbers (paper
tables, calibration accuracy, quality grids, ...) are programs of the source tree's
``benchmarks/`` (docs/architecture.md says why).
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


def bench_live(
    cases: str = typer.Option("sim4,hocap8", "--cases", help="Comma list of sim4, hocap8, hocap8-200k."),
    duration: float = typer.Option(20.0, "--duration", help="Seconds each case (each run with --nodes) streams."),
    nodes: int = typer.Option(None, "--nodes", help="Capture nodes on a local Ray cluster against one host."),
    runs: int = typer.Option(3, "--runs", help="--nodes: repetitions of the whole comparison (median ratio)."),
    wires: str = typer.Option(
        "auto,jpeg,auto@head",
        "--wires",
        help="--nodes: frame codecs (auto, raw, raw16, lz4, jpeg, png; @head: the capture actors on the fusing process's "
        "own Ray node).",
    ),
    resolution: str = typer.Option("640x480", "--resolution", help="--nodes: WxH of the simulated 8 cameras."),
    data_dir: Path = typer.Option(
        Path("../shared/data"), "--data-dir", envvar="FUSEFLOW_DATA", help="The folder holding hocap-8rs."
    ),
    json_out: Path = typer.Option(None, "--json", help="Write the rows as JSON."),
) -> None:
    """Live streaming on this machine: fused frames/s, drops, latency and bandwidth of replayed
    recordings with a viewer; with --nodes, capture nodes on Ray against one host (rate ratio)."""
    from fuseflow.eval.results import write_result

    if not duration > 0:
        fail(f"--duration must be a positive number of seconds, got {duration}")
    command = "fuseflow bench " + " ".join(shlex.quote(a) for a in sys.argv[2:])
    if nodes is not None:
        rows, meta = _bench_nodes(nodes, duration, runs, wires, resolution, data_dir)
    else:
        from fuseflow.eval.bench.live import run_live_bench

        names = [c.strip() for c in cases.split(",") if c.strip()]
        rows = run_live_bench(names, duration, data_dir, command=command, log=_echo)
        meta = {"cases": names, "duration_s": duration}
    if json_out is not None:
        write_result(json_out, "live_nodes" if nodes is not None else "live_replay", command, rows, meta)


def _bench_nodes(nodes: int, duration: float, runs: int, wires: str, resolution: str, data_dir: Path):
    from fuseflow.eval.bench.live_nodes import WIRES, run_nodes_bench

    if not 1 <= nodes <= 8:
        fail(f"--nodes must be 1..8 (the simulated rig has 8 cameras), got {nodes}")
    if runs < 1:
        fail(f"--runs must be at least 1, got {runs}")
    names = tuple(w.strip() for w in wires.split(",") if w.strip())
    bad = [
        w for w in names if w.split("@")[0] not in WIRES or w.count("@") > 1 or w.split("@")[1:] not in ([], ["head"])
    ]
    if not names or bad:
        fail(f"--wires takes {', '.join(WIRES)}, each optionally with @head; got {wires!r}")
    try:
        w, h = (int(v) for v in resolution.lower().split("x"))
    except ValueError:
        fail(f"--resolution must be WIDTHxHEIGHT, e.g. 640x480, got {resolution!r}")
    if not (16 <= w <= 4096 and 16 <= h <= 4096):
        fail(f"--resolution must be between 16x16 and 4096x4096, got {resolution!r}")
    rows = run_nodes_bench(nodes, duration, log=_echo, resolution=(w, h), data_dir=data_dir, runs=runs, wires=names)
    return rows, {"nodes": nodes, "duration_s": duration, "runs": runs, "wires": list(names), "resolution": [w, h]}


bench_app = typer.Typer(
    help="Benchmarks: FUSE speed on this machine and against VoxelBlockGrid on your recordings; live streaming.",
    no_args_is_help=True,
    rich_markup_mode=None,
)
for _name, _command in (
    ("fuse", bench_fuse),
    ("fuse-ratio", bench_fuse_ratio),
    ("live", bench_live),
):
    bench_app.command(_name)(guarded(_command))
