"""`fuseflow demo`: the whole product on simulated data, scored against ground truth
(fuseflow.eval.demo.run_demo)."""

from __future__ import annotations

from pathlib import Path

import typer

from fuseflow.cli.app import OLD_FRAMES_COUNT, frame_count, print_table, progress, say, warn
from fuseflow.cli.run import output_size


def command(
    out: Path = typer.Option(Path("fuseflow-demo"), "--out", help="Where the demo writes its results."),
    cameras: int = typer.Option(8, "--cameras", help="Simulated cameras."),
    num_frames: int = typer.Option(10, "--num-frames", help="Simulated frames."),
    old_frames: int = OLD_FRAMES_COUNT,
    seed: int = typer.Option(1, "--seed", help="Simulator seed."),
) -> None:
    """Simulate a dynamic rig, calibrate it with GMAC, fuse it with FUSE, score it against ground truth."""
    frames = frame_count(num_frames, old_frames)
    from fuseflow.eval.demo import run_demo

    with progress("demo") as bar:
        task = bar.add_task("fusing", total=frames, visible=False)

        def stage(s: str) -> None:
            say(f"> {s}")

        def frame(r, done: int, total: int) -> None:
            bar.update(task, completed=done, visible=True)

        res = run_demo(out, cameras=cameras, frames=frames, seed=seed, on_stage=stage, on_frame=frame)
    _print_result(res)
    say(f"output: {output_size(out)} in {out}")


def _print_result(res) -> None:
    print_table(
        "FuseFlow demo: errors against the simulator's ground truth",
        [
            ("rig", f"{res.cameras} cameras, {res.frames} frames, {res.resolution[0]}x{res.resolution[1]}, dynamic"),
            ("GMAC cameras placed", f"{res.cameras_placed} of {res.cameras}"),
            ("GMAC rotation error", f"{res.rotation_error_deg:.3f} deg (mean over camera pairs)"),
            ("GMAC translation error", f"{res.translation_error_mm:.1f} mm (no scale alignment)"),
            ("FUSE Chamfer distance", f"{res.chamfer_mm:.1f} mm (first, middle, last frame)"),
            ("FUSE F-score @ 1 cm", f"{res.fscore_1cm:.3f}"),
            ("points > 2 cm from surface", f"{100 * res.outlier_share_2cm:.2f} %"),
            ("points per frame", f"{res.points_per_frame:.0f}"),
            ("FUSE time", f"{res.ms_per_frame:.0f} ms per frame"),
            ("wall time", f"simulate {res.simulate_s:.1f} s, calibrate + fuse {res.run_s:.1f} s"),
            ("pictures", ", ".join(res.png)),
            ("rerun", res.rrd or "not written (pip install 'fuseflow[viz]')"),
        ],
    )
    for w in res.warnings:
        warn(w)


#: ``--help`` examples (click keeps a paragraph after "\\b" as written).
EXAMPLES = """\b
Examples:
  fuseflow demo                          # ./fuseflow-demo: simulate, calibrate, fuse, score
  fuseflow demo --out /tmp/demo --cameras 4 --num-frames 3
"""
