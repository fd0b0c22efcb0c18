"""The output options `fuse` and `run` share: --crop, --format, --mesh (docs/formats.md)."""

from __future__ import annotations

import typer

CROP = typer.Option(
    None,
    "--crop",
    help="auto: keep the capture volume (the space the cameras look at together, stored in calib.json); "
    "or xmin,ymin,zmin,xmax,ymax,zmax in metres, world frame. Default: every point.",
)
FORMAT = typer.Option("ply", "--format", help="Cloud files: ply (all fields), drc (Draco) or glb (glTF points).")
DRC_ERROR = typer.Option(1.0, "--drc-error-mm", help="Draco position error bound, millimetres.")
MESH = typer.Option(False, "--mesh", help="Also write a mesh per frame: meshes/<frame>.glb.")
MESH_PLY = typer.Option(False, "--mesh-ply", help="With --mesh, also meshes/<frame>.ply.")
MESH_METHOD = typer.Option("poisson", "--mesh-method", help="poisson (default), tsdf or bpa (ball pivoting).")


def output_options(crop, fmt, drc_error_mm, mesh, mesh_ply, mesh_method):
    """The OutputOptions of these CLI values (ValidationError, a one-line message, on bad ones)."""
    from fuseflow.pipeline.config import OutputOptions

    if mesh_ply and not mesh:
        mesh = True
    return OutputOptions(
        crop=crop, cloud_format=fmt, drc_error_mm=drc_error_mm, mesh=mesh, mesh_ply=mesh_ply, mesh_method=mesh_method
    )
