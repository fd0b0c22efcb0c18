"""The output options `fuse` and `run` share: --crop, --format, --world, --voxel, --mesh
(docs/formats.md)."""

from __future__ import annotations

import typer

CROP = typer.Option(
    None,
    "--crop",
    help="Off unless given: every fused point is written. auto: keep the box of what several cameras "
    "see together (a ring: any two; one side: half of them), from the floor up to head-room (stored in calib.json); or xmin,ymin,zmin,xmax,ymax,zmax "
    "in metres, in the output frame (--world).",
)
FORMAT = typer.Option(
    "ply",
    "--format",
    help="Cloud files, one or more joined by commas: ply (all fields), drc (Draco), glb (glTF points), "
    "splat (3D Gaussian splats, splats/<frame>.ply). Example: --format ply,drc,glb,splat.",
)
WORLD = typer.Option(
    None,
    "--world",
    help="Output frame: floor (z up, origin on the floor under the capture volume; glb: +y up), camera:ID "
    "(that camera's frame) or calib (the calibration's world). Default: floor when a floor is found, "
    "else the first camera's frame.",
)
VOXEL = typer.Option(
    None, "--voxel", help="Thin each written cloud to one point per cube of this edge, millimetres (default: all)."
)
DRC_ERROR = typer.Option(1.0, "--drc-error-mm", help="Draco position error bound, millimetres.")
MESH = typer.Option(False, "--mesh", help="Also write a mesh per frame: meshes/<frame>.glb.")
MESH_PLY = typer.Option(False, "--mesh-ply", help="With --mesh, also meshes/<frame>.ply.")
MESH_METHOD = typer.Option(
    "range",
    "--mesh-method",
    help="range (default: each camera's fused points as a range image, merged; under 1 CPU s a frame), "
    "poisson (screened Poisson), tsdf or bpa (ball pivoting).",
)


def output_options(crop, fmt, drc_error_mm, mesh, mesh_ply, mesh_method, world=None, voxel=None):
    """The OutputOptions of these CLI values (ValidationError, a one-line message, on bad ones)."""
    from fuseflow.pipeline.config import OutputOptions

    if mesh_ply and not mesh:
        mesh = True
    return OutputOptions(
        crop=crop, cloud_format=fmt, drc_error_mm=drc_error_mm, mesh=mesh, mesh_ply=mesh_ply, mesh_method=mesh_method,
        world=world, voxel_mm=voxel,
    )  # fmt: skip


def output_rows(out) -> list[tuple[str, str]]:
    """The table rows that say the output frame and what the crop kept, from OUT/manifest.json."""
    import json
    from pathlib import Path

    try:
        seq = json.loads((Path(out) / "manifest.json").read_text()).get("sequence") or {}
    except (OSError, ValueError):
        return []
    rows = [("formats", ", ".join(seq.get("formats") or [seq.get("cloud_format", "ply")]))]
    world = seq.get("world") or {}
    if world:
        floor = world.get("floor")
        how = f"; floor seen by {len(floor['cameras'])} cameras" if floor else "; no floor found"
        rows.append(("world", f"{seq.get('frame', world.get('name'))}{how}"))
    crop = seq.get("crop")
    if crop is None:
        rows.append(("crop", "off (every fused point written; --crop auto to keep what the cameras see together)"))
    else:
        size = " x ".join(f"{hi - lo:.2f}" for lo, hi in zip(crop["min"], crop["max"]))
        kept = seq.get("crop_kept")
        share = f"; kept {100 * kept:.1f} % of the fused points" if kept is not None else ""
        ring = f", cut to a {crop['radius']:.2f} m radius" if crop.get("radius") else ""
        rows.append(("crop", f"{crop.get('kind')} box {size} m{ring}{share}"))
    return rows
