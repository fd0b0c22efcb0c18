"""`fuseflow bench calib`: the GMAC accuracy / timing benchmark (benchmarks/calib_accuracy.py)."""

from __future__ import annotations

import runpy
from pathlib import Path

import typer

from fuseflow.cli.bench import _script, bench_app


@bench_app.command("calib")
def bench_calib(
    seeds: int = typer.Option(10, "--seeds", help="Seeds per data set (issue 6 asks for >= 10)."),
    data: str = typer.Option("sim4,sim8,icl8", "--data", help="Comma list of sim4, sim8, icl8."),
    quick: bool = typer.Option(False, "--quick", help="2 seeds on sim8 and icl8."),
    backbone: str = typer.Option(
        "colmap", "--backbone", help="colmap (the default backbone) or perturbed (ground truth + noise: GMAC alone)."
    ),
    no_peer: bool = typer.Option(False, "--no-peer", help="Skip the Open3D multiway registration peer."),
    json_out: Path = typer.Option(None, "--json", help="Also write every per-seed row as JSON."),
) -> None:
    """GMAC rotation / translation error and time per calibration, every variant and peer."""
    mod = runpy.run_path(str(_script("calib_accuracy.py")), run_name="fuseflow_bench_calib")
    argv = ["--seeds", str(seeds), "--data", data, "--backbone", backbone]
    argv += ["--quick"] if quick else []
    argv += ["--no-peer"] if no_peer else []
    if json_out is not None:
        argv += ["--json", str(json_out)]
    raise typer.Exit(mod["main"](argv))
