"""`fuseflow bench ...`: benchmark programs (benchmarks/*.py) reachable from the CLI.

``bench_app`` is the sub-app; each benchmark module adds its command to it
(this module: ``fuse``; cli/bench_calib.py: ``calib``).
"""

from __future__ import annotations

import runpy
from pathlib import Path

import typer

from fuseflow.cli.app import fail

bench_app = typer.Typer(help="Benchmarks: speed / quality tables measured on this machine.", no_args_is_help=True)


def _script(name: str) -> Path:
    script = Path(__file__).resolve().parents[3] / "benchmarks" / name
    if not script.is_file():
        fail(f"the benchmark program is part of the source tree and was not found at {script}")
    return script


@bench_app.command("fuse")
def bench_fuse(
    cameras: str = typer.Option("1,2,4,8,16", "--cameras", help="Comma list of camera counts N."),
    frames: int = typer.Option(7, "--frames", help="Timed frames per N (median over them, after warm-up)."),
    device: str = typer.Option("cpu", "--device", help="cpu or cuda."),
    json_out: Path = typer.Option(None, "--json", help="Write one JSON row per (method, N)."),
    no_baselines: bool = typer.Option(False, "--no-baselines", help="Time FUSE only."),
) -> None:
    """FUSE per-frame time and peak memory against VoxelBlockGrid TSDF and naive + voxel fusion."""
    mod = runpy.run_path(str(_script("fuse_speed.py")), run_name="fuseflow_bench_fuse")
    argv = ["--cameras", cameras, "--frames", str(frames), "--device", device]
    if json_out is not None:
        argv += ["--json", str(json_out)]
    if no_baselines:
        argv.append("--no-baselines")
    raise typer.Exit(mod["main"](argv))


# the subcommands of other modules register on bench_app when imported
from fuseflow.cli import bench_calib as _bench_calib  # noqa: E402, F401
from fuseflow.cli import bench_paper as _bench_paper  # noqa: E402, F401
