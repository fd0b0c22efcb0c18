"""`fuseflow convert`: a dataset (Open3D/Redwood/ICL, TUM) to a FuseFlow recording or virtual rig."""

from __future__ import annotations

from pathlib import Path

import typer

from fuseflow.cli.app import console, fail, parse_int_list, parse_range


def command(
    src: Path = typer.Argument(..., help="Dataset directory: Open3D/Redwood/ICL-NUIM (color/, depth/) or TUM RGB-D."),
    out: Path = typer.Argument(..., help="Output recording directory (must not exist or be empty)."),
    virtual_rig: str = typer.Option(
        None, "--virtual-rig", help="Frame indices, e.g. 0,30,60: one camera per frame of a static scene."
    ),
    cameras: int = typer.Option(
        None, "--cameras", help="Virtual rig of this many cameras taken every --every frames from frame 0."
    ),
    every: int = typer.Option(30, "--every", help="Frame step for --cameras."),
    frames: str = typer.Option(None, "--frames", help="A:B frame range for a plain (single-camera) conversion."),
    tum_intrinsics: str = typer.Option(
        None, "--tum-intrinsics", help="TUM sensor: freiburg1, freiburg2, freiburg3 or ros (default: from folder name)."
    ),
    force: bool = typer.Option(False, "--force", help="Write into a non-empty output directory."),
) -> None:
    """Convert a dataset into a FuseFlow recording; with --virtual-rig/--cameras, a K-camera static rig
    whose reference extrinsics come from the dataset's trajectory."""
    from fuseflow.io.datasets import SequenceRecording, convert_sequence, make_virtual_rig, open_recording

    if out.exists() and any(out.iterdir()) and not force:
        fail(f"{out}: output directory is not empty (use --force to write into it)")
    rec = SequenceRecording.tum(src, tum_intrinsics) if (src / "rgb.txt").exists() else open_recording(src)
    if not isinstance(rec, SequenceRecording):
        fail(f"{src}: already a FuseFlow recording; nothing to convert")
    if virtual_rig is not None and cameras is not None:
        fail("give either --virtual-rig or --cameras, not both")
    if cameras is not None:
        if cameras < 1 or every < 1:
            fail("--cameras and --every must be positive")
        indices = [k * every for k in range(cameras)]
        if indices[-1] >= len(rec):
            fail(f"--cameras {cameras} --every {every} needs frame {indices[-1]}, the dataset has {len(rec)}")
        virtual_rig = ",".join(map(str, indices))
    if virtual_rig is not None:
        idx = parse_int_list(virtual_rig, "--virtual-rig")
        rig = make_virtual_rig(rec, idx, out)
        console.print(f"wrote a {len(rig)}-camera virtual rig (frames {idx}) to {out}")
    else:
        rng = parse_range(frames, len(rec))
        convert_sequence(rec, out, list(rng))
        console.print(f"wrote {len(rng)} frames of one camera to {out}")
