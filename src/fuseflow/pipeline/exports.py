"""The per-frame files of a run or fuse besides its log: the cropped cloud in its format, the
optional mesh, and the ``sequence`` entry of manifest.json that lets a player stream the folder.

Library entry points for any frame loop (``run``, ``fuse_recording``, a live source):
``resolve_crop(crop, rig, calibration)`` -> a ``CaptureVolume`` or None, then
``geometry.volume.crop_cloud(cloud, volume)`` per frame; ``FrameWriter`` writes a frame's files.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fuseflow.geometry.volume import CaptureVolume, capture_volume, crop_cloud, parse_crop
from fuseflow.io.calibration import VOLUME_KEY
from fuseflow.io.exchange import write_cloud, write_glb_mesh
from fuseflow.io.files import write_json_atomic
from fuseflow.pipeline.config import OutputOptions
from fuseflow.types import Calibration, FusedCloud, Rig

__all__ = [
    "resolve_crop",
    "with_volume",
    "FrameWriter",
    "frame_file",
    "mesh_file",
    "write_sequence",
    "SEQUENCE_FORMAT",
    "world_up",
    "recording_centres",
]

SEQUENCE_FORMAT = "fuseflow-sequence/1"


def resolve_crop(crop: str | CaptureVolume | None, rig: Rig, calibration: Calibration | None = None):
    """The capture volume to crop to: None (no crop) for ``crop`` None or "off"; for "auto" the
    ``capture_volume`` stored in ``calibration`` (calib.json) when it has one, else the one
    computed from the placed ``rig``; a "xmin,ymin,zmin,xmax,ymax,zmax" string parsed
    (ValidationError on a bad box); a CaptureVolume as is."""
    if crop is None or crop == "off":
        return None
    if isinstance(crop, CaptureVolume):
        return crop
    if crop == "auto":
        stored = calibration.report.get(VOLUME_KEY) if calibration is not None else None
        if isinstance(stored, dict):
            return CaptureVolume.from_json(stored)
        if isinstance(stored, CaptureVolume):
            return stored
        return capture_volume(rig)
    return parse_crop(crop)


def with_volume(calibration: Calibration, volume: CaptureVolume | None) -> Calibration:
    """``calibration`` with ``volume`` in its report (written to calib.json's ``capture_volume``)."""
    if volume is None:
        return calibration
    return Calibration(dict(calibration.T_cam_world), {**calibration.report, VOLUME_KEY: volume.to_json()})


def frame_file(out: Path, number: int, fmt: str) -> Path:
    """OUT/clouds/<number:06d>.<fmt>."""
    return Path(out) / "clouds" / f"{number:06d}.{fmt}"


def mesh_file(out: Path, number: int, ext: str = "glb") -> Path:
    """OUT/meshes/<number:06d>.<ext>."""
    return Path(out) / "meshes" / f"{number:06d}.{ext}"


def recording_centres(recording_rig: Rig, fused: Rig) -> np.ndarray:
    """(N, 3) centres of ``fused``'s cameras in ``recording_rig``'s order (NaN where not fused)."""
    return np.array([fused[c].T_world_cam[:3, 3] if c in fused.ids else np.full(3, np.nan) for c in recording_rig.ids])


def world_up(rig: Rig) -> list[float]:
    """The world's up direction: the mean of the cameras' up axes (-y in OpenCV axes)."""
    up = np.mean([-c.T_cam_world[1, :3] for c in rig if c.is_calibrated], axis=0)
    n = float(np.linalg.norm(up))
    return (up / n).round(6).tolist() if n > 1e-6 else [0.0, -1.0, 0.0]


@dataclass
class FrameWriter:
    """Writes each frame's files under ``out`` as ``options`` say, and keeps the manifest entries."""

    out: Path
    options: OutputOptions
    rig: Rig
    """The fused rig (cameras in the order of the frames handed to ``mesh``)."""
    volume: CaptureVolume | None = None
    centres: np.ndarray | None = None
    """(N, 3) camera centres indexed by the written clouds' ``camera`` (the recording's rig
    order; NaN for a camera not fused), for the mesh normals; None: ``rig``'s order."""
    entries: dict[int, dict[str, Any]] = field(default_factory=dict)

    def done(self, number: int) -> bool:
        """Whether an earlier call wrote this frame's cloud (written last, so its mesh exists)."""
        return frame_file(self.out, number, self.options.cloud_format).exists()

    def crop(self, cloud: FusedCloud) -> FusedCloud:
        return crop_cloud(cloud, self.volume)

    def write(
        self, number: int, cloud: FusedCloud, frame: Callable[[], Any] | None = None, timestamp: float | None = None
    ) -> dict[str, Any]:
        """Write the (already cropped) cloud of frame ``number`` and, with ``options.mesh``, its
        mesh (``frame()`` gives the views for the "tsdf" method); returns the manifest entry."""
        opts = self.options
        entry: dict[str, Any] = {"index": int(number), "timestamp": timestamp}
        if opts.mesh:
            from fuseflow.pipeline.mesh import mesh_frame

            views = frame() if (opts.mesh_method == "tsdf" and frame is not None) else None
            mesh = mesh_frame(cloud, views, self.rig, opts.mesh_method, self.volume, self.centres)
            write_glb_mesh(mesh_file(self.out, number), mesh.vertices, mesh.faces, mesh.colors, mesh.normals)
            entry["mesh"] = f"meshes/{number:06d}.glb"
            entry["faces"] = int(len(mesh.faces))
            if opts.mesh_ply:
                _write_mesh_ply(mesh_file(self.out, number, "ply"), mesh)
                entry["mesh_ply"] = f"meshes/{number:06d}.ply"
        write_cloud(frame_file(self.out, number, opts.cloud_format), cloud, opts.cloud_format, opts.drc_error_mm)
        entry["cloud"] = f"clouds/{number:06d}.{opts.cloud_format}"
        entry["points"] = int(len(cloud))
        self.entries[int(number)] = entry
        return entry

    def resumed(self, number: int, timestamp: float | None, points: int) -> None:
        """Record the entry of a frame an earlier call wrote."""
        opts = self.options
        entry: dict[str, Any] = {"index": int(number), "timestamp": timestamp}
        if opts.mesh:
            entry["mesh"] = f"meshes/{number:06d}.glb"
            if opts.mesh_ply:
                entry["mesh_ply"] = f"meshes/{number:06d}.ply"
        entry["cloud"] = f"clouds/{number:06d}.{opts.cloud_format}"
        entry["points"] = int(points)
        self.entries[int(number)] = entry


def _write_mesh_ply(path: Path, mesh) -> Path:
    """Binary PLY mesh: vertex x y z nx ny nz red green blue, face vertex_indices (uchar, int)."""
    from fuseflow.io.files import write_bytes_atomic

    v = np.empty(len(mesh.vertices), [("p", "<f4", 3), ("n", "<f4", 3), ("c", "u1", 3)])
    v["p"], v["n"], v["c"] = mesh.vertices, mesh.normals, mesh.colors
    f = np.empty(len(mesh.faces), [("k", "u1"), ("i", "<i4", 3)])
    f["k"], f["i"] = 3, mesh.faces
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment fuseflow mesh, metres, world frame\n"
        f"element vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n"
        "property float nx\nproperty float ny\nproperty float nz\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\n"
        f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    return write_bytes_atomic(path, header.encode("ascii"), v.tobytes(), f.tobytes())


def write_sequence(out: Path, writer: FrameWriter, fps: float | None = None) -> dict[str, Any]:
    """Add the ``sequence`` document (frames in order, files, formats, crop, units) to
    OUT/manifest.json (docs/formats.md, "Output folder")."""
    from fuseflow.pipeline.outputs import MANIFEST

    opts = writer.options
    if fps is None:  # from the frames' timestamps, when they have them
        stamps = [e["timestamp"] for _, e in sorted(writer.entries.items()) if e.get("timestamp") is not None]
        steps = np.diff(stamps) if len(stamps) >= 2 else np.zeros(0)
        fps = round(1.0 / float(np.median(steps)), 3) if steps.size and np.median(steps) > 0 else None
    doc = {
        "format": SEQUENCE_FORMAT,
        "units": "m",
        "frame": "world (the calibration's, right-handed)",
        "up": world_up(writer.rig),
        "fps": fps,
        "cloud_format": opts.cloud_format,
        "drc_error_mm": opts.drc_error_mm if opts.cloud_format == "drc" else None,
        "mesh": {"format": "glb", "method": opts.mesh_method, "ply": opts.mesh_ply} if opts.mesh else None,
        "crop": writer.volume.to_json() if writer.volume is not None else None,
        "frames": [writer.entries[k] for k in sorted(writer.entries)],
    }
    path = Path(out) / MANIFEST
    manifest = json.loads(path.read_text()) if path.exists() else {}
    manifest["sequence"] = doc
    write_json_atomic(path, manifest)
    return doc
