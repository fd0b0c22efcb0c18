"""`fuseflow simulate OUT`: write a synthetic multi-camera RGB-D recording with ground truth."""

from __future__ import annotations

import time
from pathlib import Path

import typer

from fuseflow.cli.app import OLD_FRAMES_COUNT, fail, frame_count, progress, say

_EFFECTS = ("axial_noise", "lateral_noise", "quantization", "flying_pixels", "grazing_dropout", "range_dropout",
            "random_dropout", "color_noise")  # fmt: skip


def _parse_disable(spec: str) -> dict:
    """'lateral_noise,flying_pixels' -> {"lateral_noise": False, ...} (color_noise -> 0.0)."""
    out: dict = {}
    for name in (x.strip() for x in spec.split(",") if x.strip()):
        if name not in _EFFECTS:
            fail(f"--disable: unknown effect {name!r}; expected names from {', '.join(_EFFECTS)}")
        out[name] = 0.0 if name == "color_noise" else False
    return out


def _parse_resolution(spec: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in spec.lower().split("x"))
    except ValueError:
        fail(f"--resolution expects WxH (e.g. 640x480), got {spec!r}")
        raise  # unreachable
    return w, h


def command(
    out: Path = typer.Argument(..., help="Output directory (must not already hold a recording)."),
    cameras: int = typer.Option(8, "--cameras", help="Number of cameras, 1..64."),
    num_frames: int = typer.Option(10, "--num-frames", help="Number of frames."),
    old_frames: int = OLD_FRAMES_COUNT,
    scene: str = typer.Option(
        "studio", "--scene", help="studio | room | wall (test scene) | symstudio | farroom | polyroom."
    ),
    dynamic: bool = typer.Option(False, "--dynamic", help="Add moving objects (walking figure, box, sphere)."),
    resolution: str = typer.Option("640x480", "--resolution", help="WxH pixels."),
    noise: str = typer.Option(
        "kinect",
        "--noise",
        help="kinect | realsense | kinect2 | azure | none (polyroom: kinect picks kinect2 or azure by seed).",
    ),
    seed: int = typer.Option(0, "--seed", help="Random seed (same seed, same recording)."),
    rig: str = typer.Option("auto", "--rig", help="auto | ring | dome | path to a rig.json with extrinsics."),
    uncalibrated: bool = typer.Option(False, "--uncalibrated", help="Write rig.json with null extrinsics."),
    calib_error_deg: float = typer.Option(0.0, "--calib-error-deg", help="Rotation error injected into rig.json."),
    calib_error_mm: float = typer.Option(0.0, "--calib-error-mm", help="Translation error injected into rig.json."),
    disable: str = typer.Option(
        "", "--disable", help="Comma-separated noise effects to switch off: " + ", ".join(_EFFECTS) + "."
    ),
    desync: str = typer.Option(
        "", "--desync", help="CAM:FRAMES[,...]: camera CAM (id or index) runs FRAMES frames late (negative: early)."
    ),
) -> None:
    """Simulate a camera rig around a scene; write the recording, gt.json, GT depth and surfaces."""
    frames = frame_count(num_frames, old_frames)
    from fuseflow.io.paths import prepare_output_dir
    from fuseflow.synth import SimConfig, simulate_recording
    from fuseflow.synth.desync import apply_desync, parse_desync

    w, h = _parse_resolution(resolution)
    parse_desync(desync)  # syntax checked before the (long) simulation; ids resolved after it
    cfg = SimConfig(
        cameras=cameras, frames=frames, scene=scene, dynamic=dynamic, resolution=(w, h), noise=noise, seed=seed,
        rig=rig, calib_error_deg=calib_error_deg, calib_error_mm=calib_error_mm, **_parse_disable(disable),
    )  # fmt: skip
    prepare_output_dir(out)  # a file in the way, no permission, read-only: one line, before any work
    t0 = time.perf_counter()
    with progress("simulating") as bar:
        task = bar.add_task(f"simulating {cameras} cameras x {frames} frames", total=frames)
        simulate_recording(out, cfg, uncalibrated=uncalibrated,
                           progress=lambda done, total: bar.update(task, completed=done))  # fmt: skip
    offsets = apply_desync(out, desync) if desync else {}
    say(
        f"wrote {out}: {frames} frames x {cameras} cameras {w}x{h}, scene {scene}"
        f"{' (dynamic)' if dynamic else ''}, noise {noise}, seed {seed}"
        + (f", desync {offsets}" if offsets else "")
        + f" in {time.perf_counter() - t0:.1f} s"
    )


#: ``--help`` examples (click keeps a paragraph after "\\b" as written).
EXAMPLES = """\b
Examples:
  fuseflow simulate /tmp/studio --cameras 8 --num-frames 30 --scene studio --dynamic --uncalibrated
  fuseflow simulate /tmp/small --cameras 3 --num-frames 2 --resolution 160x120
  fuseflow simulate /tmp/poly --scene polyroom --cameras 7 --num-frames 1 --resolution 320x240 --uncalibrated
"""
