"""`fuseflow convert SRC... OUT`: camera recordings (.bag, .mkv), HO-Cap, or a dataset to a FuseFlow
recording. Parsing and printing only: the work is ``fuseflow.io.convert.convert``."""

from __future__ import annotations

from pathlib import Path

import typer

from fuseflow.cli.app import FRAMES_OPTION_HELP, fail, parse_int_list, say


def command(
    paths: list[Path] = typer.Argument(
        ...,
        help="Inputs, then the output directory. Inputs: RealSense .bag / Azure Kinect .mkv files (one per camera) "
        "or a directory of them; an HO-Cap sequence; an Open3D/Redwood/ICL-NUIM or TUM RGB-D dataset.",
    ),
    tolerance_ms: float = typer.Option(
        None, "--tolerance-ms", help=".bag/.mkv: pair views within this many ms (default: half a frame period)."
    ),
    with_extrinsics: bool = typer.Option(
        False, "--with-extrinsics", help="HO-Cap: keep the reference extrinsics in rig.json (master camera = world)."
    ),
    virtual_rig: str = typer.Option(
        None, "--virtual-rig", help="Frame indices, e.g. 0,30,60: one camera per frame of a static scene."
    ),
    cameras: int = typer.Option(
        None, "--cameras", help="Virtual rig of this many cameras taken every --every frames from frame 0."
    ),
    every: int = typer.Option(30, "--every", help="Frame step for --cameras."),
    frames: str = typer.Option(None, "--frames", help="Plain (single-camera) conversion: " + FRAMES_OPTION_HELP),
    tum_intrinsics: str = typer.Option(
        None, "--tum-intrinsics", help="TUM sensor: freiburg1, freiburg2, freiburg3 or ros (default: from folder name)."
    ),
    force: bool = typer.Option(False, "--force", help="Write into a non-empty output directory."),
) -> None:
    """Convert recordings into one FuseFlow recording: several cameras' .bag/.mkv files paired by
    timestamp, an HO-Cap sequence, or a dataset (with --virtual-rig/--cameras, a K-camera static rig
    whose reference extrinsics come from the dataset's trajectory)."""
    from fuseflow.io.convert import convert as run_convert

    if len(paths) < 2:
        fail("convert needs at least one input and the output directory")
    try:
        s = run_convert(
            paths[:-1], paths[-1], tolerance_s=None if tolerance_ms is None else tolerance_ms / 1000.0,
            with_extrinsics=with_extrinsics,
            virtual_rig=None if virtual_rig is None else parse_int_list(virtual_rig, "--virtual-rig"),
            cameras=cameras, every=every, frames=frames, tum_intrinsics=tum_intrinsics, force=force,
        )  # fmt: skip
    except KeyboardInterrupt:  # convert does not resume: say how to start it again
        fail(f"interrupted; {paths[-1]} holds part of the conversion: run the same command with --force to "
             "convert again into it", code=130)  # fmt: skip
    say(f"{s.message} ({s.seconds:.1f} s)")


#: ``--help`` examples (click keeps a paragraph after "\\b" as written).
EXAMPLES = """\b
Examples:
  fuseflow convert cam1.bag cam2.bag cam3.bag /data/rig
  fuseflow convert ../shared/data/hocap-8rs /tmp/hocap --with-extrinsics
"""
