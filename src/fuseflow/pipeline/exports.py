"""The per-frame files of a run or fuse besides its log: the cloud in each asked format (PLY,
Draco, GLB, Gaussian splats) in the output frame, the optional mesh, and the ``sequence`` entry
of manifest.json that lets a player stream the folder.

Library entry points for any frame loop (``run``, ``fuse_recording``, a live source):
``resolve_outputs(options, rig, calibration, frame)`` -> the output frame (``geometry.world.World``:
the floor frame when a floor is found) and the crop (a ``CaptureVolume`` or None), then
``geometry.volume.crop_cloud(cloud, volume)`` and ``world.apply(xyz)`` per frame;
``resolve_crop(crop, rig, calibration)`` alone for the crop; ``FrameWriter`` writes a frame's files.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fuseflow.errors import ValidationError
from fuseflow.geometry.volume import CaptureVolume, capture_volume, crop_cloud, parse_crop
from fuseflow.geometry.world import World
from fuseflow.io.calibration import VOLUME_KEY, WORLD_KEY
from fuseflow.io.exchange import write_cloud, write_glb_mesh
from fuseflow.io.files import write_json_atomic
from fuseflow.pipeline.config import OutputOptions
from fuseflow.types import Calibration, FusedCloud, Rig, to_numpy

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
    "resolve_outputs",
    "find_floor",
    "thin_cloud",
]

SEQUENCE_FORMAT = "fuseflow-sequence/1"


def resolve_crop(
    crop: str | CaptureVolume | None,
    rig: Rig,
    calibration: Calibration | None = None,
    world: World | None = None,
    seen: CaptureVolume | None = None,
):
    """The capture volume to crop to: None (no crop) for ``crop`` None or "off"; for "auto" the
    ``capture_volume`` stored in ``calibration`` (calib.json) when it has one, else ``seen`` (the
    box of what the cameras see together, ``resolve_outputs``), else the one computed from the
    placed ``rig``'s geometry; a "xmin,ymin,zmin,xmax,ymax,zmax" string parsed (ValidationError
    on a bad box) as a box in ``world``'s output frame (the calibration's world without one); a
    CaptureVolume as is."""
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
        return seen if seen is not None else capture_volume(rig)
    box = parse_crop(crop)
    if world is None or world.name == "calib":
        return box
    return CaptureVolume(box.lo, box.hi, world.T_out_world, "explicit")


def with_volume(calibration: Calibration, volume: CaptureVolume | None, world: World | None = None) -> Calibration:
    """``calibration`` with ``volume`` and ``world`` in its report (written to calib.json's
    ``capture_volume`` and ``world``); either may be None (left as it is)."""
    report = dict(calibration.report)
    if volume is not None:
        report[VOLUME_KEY] = volume.to_json()
    if world is not None:
        report[WORLD_KEY] = world.to_json()
    return Calibration(dict(calibration.T_cam_world), report)


def frame_file(out: Path, number: int, fmt: str) -> Path:
    """OUT/clouds/<number:06d>.<fmt>; Gaussian splats (fmt "splat"): OUT/splats/<number:06d>.ply."""
    if fmt == "splat":
        return Path(out) / "splats" / f"{number:06d}.ply"
    return Path(out) / "clouds" / f"{number:06d}.{fmt}"


def thin_cloud(cloud: FusedCloud, voxel_mm: float | None) -> FusedCloud:
    """One point per cube of edge ``voxel_mm`` millimetres (the one of highest weight, in the
    cloud's order); the cloud itself for None."""
    if voxel_mm is None or len(cloud) == 0:
        return cloud
    c = cloud.numpy()
    keys = np.floor(np.asarray(c.xyz, np.float64) / (voxel_mm / 1000.0)).astype(np.int64)
    order = np.lexsort((-np.asarray(c.weight), keys[:, 2], keys[:, 1], keys[:, 0]))
    k = keys[order]
    first = np.ones(len(k), bool)
    first[1:] = (k[1:] != k[:-1]).any(axis=1)
    keep = np.sort(order[first])
    sup = None if c.support is None else c.support[keep]
    return FusedCloud.from_numpy(c.xyz[keep], c.rgb[keep], c.weight[keep], c.camera[keep], sup)


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


def _frame_depths(frame, rig: Rig) -> list[np.ndarray | None]:
    """One depth image per camera of ``rig`` (a frame in the rig's order), None where absent."""
    depth = to_numpy(frame.depth)
    present = to_numpy(frame.present)
    return [np.asarray(depth[i], np.float64) if present[i] else None for i in range(len(rig))]


def _report_planes(report: Any, T: dict[str, np.ndarray]) -> dict[str, tuple[np.ndarray, float]]:
    """Camera -> world floor plane (n, d) from the per-camera floor fits a GMAC report holds
    (``{"cameras": {id: {"floor": {"normal", "height_m"}}}}`` anywhere in it)."""
    found: dict[str, tuple[np.ndarray, float]] = {}
    stack = [report]
    while stack:
        doc = stack.pop()
        doc = doc.to_json() if hasattr(doc, "to_json") else doc
        if isinstance(doc, list):
            stack.extend(doc)
        if not isinstance(doc, dict):
            continue
        cams = doc.get("cameras")
        for c, ci in cams.items() if isinstance(cams, dict) else ():
            fl = ci.get("floor") if isinstance(ci, dict) else None
            if c in T and isinstance(fl, dict) and "normal" in fl and "height_m" in fl:
                n = np.asarray(fl["normal"], np.float64)
                found[c] = (T[c][:3, :3].T @ n, float(n @ T[c][:3, 3] + fl["height_m"]))
        stack.extend(v for k, v in doc.items() if k != "cameras")
    return found


def _depth_planes(depths: list[np.ndarray | None], rig: Rig) -> dict[str, tuple[np.ndarray, float]]:
    """Camera -> world floor plane (n, d) fitted in its depth (``calib.floor.fit_floor_plane``)."""
    from fuseflow.calib.floor import fit_floor_plane

    planes = {}
    for cam, d in zip(rig, depths):
        if d is None or not cam.is_calibrated:
            continue
        z = d[::2, ::2]
        v, u = np.nonzero((z >= cam.depth_range[0]) & (z <= cam.depth_range[1]))
        zz, K = z[v, u], cam.K
        X = np.stack([(u * 2 - K[0, 2]) / K[0, 0] * zz, (v * 2 - K[1, 2]) / K[1, 1] * zz, zz], axis=1)
        p = fit_floor_plane(X)
        if p is not None:
            R, t = cam.T_cam_world[:3, :3], cam.T_cam_world[:3, 3]
            planes[cam.id] = (R.T @ p.normal, float(p.normal @ t + p.height))
    return planes


def find_floor(rig: Rig, calibration: Calibration | None, depths: list[np.ndarray | None] | None):
    """The rig's floor (``geometry.world.floor_consensus``) from the per-camera floors a GMAC
    report holds, else from a plane fit in each camera's depth of one frame; None when fewer
    than two cameras agree on one."""
    from fuseflow.geometry.world import floor_consensus

    T = {c.id: c.T_cam_world for c in rig if c.is_calibrated}
    floor = floor_consensus(_report_planes(calibration.report, T)) if calibration is not None else None
    if floor is None and depths is not None:
        floor = floor_consensus(_depth_planes(depths, rig))
        if floor is not None:
            floor["source"] = "depth"
    elif floor is not None:
        floor["source"] = "calibration"
    return floor


def _camera_world(choice: str, rig: Rig, floor) -> World:
    from fuseflow.geometry.world import camera_frame

    if choice == "calib":
        return World("calib", np.eye(4), floor)
    cid = choice.removeprefix("camera:")  # "camera:" alone: the first placed camera
    if not cid:
        cid = next((c.id for c in rig if c.is_calibrated), "")
    if cid not in rig.ids or not rig[cid].is_calibrated:
        placed = [c.id for c in rig if c.is_calibrated]
        raise ValidationError(f"--world camera:{cid}: no placed camera of that id (placed: {', '.join(placed)})")
    return World(f"camera:{cid}", camera_frame(rig[cid].T_cam_world), floor)


def resolve_outputs(
    options: OutputOptions, rig: Rig, calibration: Calibration | None = None, frame: Any = None
) -> tuple[World, CaptureVolume | None]:
    """The output frame and the crop box of a run (docs/formats.md, "Output frame" and "Crop").

    A ``world`` stored in ``calibration`` (calib.json) is kept when ``options.world`` is unset or
    names it. Otherwise the floor is found (``find_floor``: the calibration's report, else the
    depth of ``frame``, the first frame to fuse, in ``rig``'s order) and the world is "floor"
    (default when found), "camera:<id>" (default: the first placed camera, when no floor) or
    "calib". The floor frame's origin lies under the centre of the box the cameras see together
    (``geometry.volume.seen_volume`` of ``covisible_points`` of ``frame``); that box is the
    "auto" crop (unless calib.json stores one). ValidationError for ``--world floor`` without a
    floor or an unknown camera."""
    from fuseflow.geometry.volume import covisible_points, seen_volume
    from fuseflow.geometry.world import floor_frame

    stored = calibration.report.get(WORLD_KEY) if calibration is not None else None
    choice = options.world or "auto"
    world = World.from_json(stored) if isinstance(stored, dict) and choice in ("auto", stored.get("name")) else None
    need_seen = world is None or (
        options.crop == "auto" and VOLUME_KEY not in (calibration.report if calibration else {})
    )
    depths = _frame_depths(frame, rig) if frame is not None and need_seen else None
    seen_pts = covisible_points(depths, rig) if depths is not None else None
    seen = None
    if world is None:
        floor = find_floor(rig, calibration, depths)
        if choice == "floor" and floor is None:
            raise ValidationError(
                "--world floor: no floor found (fewer than two cameras see the same large horizontal plane); "
                "use --world camera:ID"
            )
        if floor is not None and choice in ("auto", "floor"):
            placed = [c for c in rig if c.is_calibrated]
            first = placed[0].T_world_cam[:3, 3]
            mean = np.mean([c.T_world_cam[:3, 3] for c in placed], axis=0)
            T0 = floor_frame(floor, mean, first)
            box = seen_volume(*seen_pts, rig, T0) if seen_pts is not None else None
            world = World("floor", floor_frame(floor, box.centre() if box is not None else mean, first), floor)
        else:
            world = _camera_world(choice if choice != "auto" else "camera:", rig, floor)
    if seen_pts is not None:
        seen = seen_volume(*seen_pts, rig, world.T_out_world if world.name == "floor" else None)
    volume = resolve_crop(options.crop, rig, calibration, world, seen)
    # as calib.json stores them: a resumed call crops and places exactly as the first one
    world = World.from_json(world.to_json())
    return world, None if volume is None else CaptureVolume.from_json(volume.to_json())


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
    world: World | None = None
    """The output frame (None: the calibration's world as it is)."""
    fused_points: int = 0
    """Points handed to ``crop`` (before cropping), over the frames cropped in this process."""
    kept_points: int = 0
    """Of those, the points the crop kept."""

    def done(self, number: int) -> bool:
        """Whether an earlier call wrote this frame's files in every asked format (written last,
        so its mesh exists)."""
        return all(frame_file(self.out, number, f).exists() for f in self.options.formats)

    def crop(self, cloud: FusedCloud) -> FusedCloud:
        kept = crop_cloud(cloud, self.volume)
        self.fused_points += len(cloud)
        self.kept_points += len(kept)
        return kept

    def _placed(self, cloud: FusedCloud) -> FusedCloud:
        """The cloud moved into the output frame and thinned there (``voxel_mm``)."""
        c = cloud.numpy()
        if self.world is not None and self.world.name != "calib":
            c = dataclasses.replace(c, xyz=self.world.apply(c.xyz))  # numpy stays numpy (no torch)
        return thin_cloud(c, self.options.voxel_mm)

    def _by_rig(self, cloud: FusedCloud) -> FusedCloud:
        """For the "range" mesh: the cloud with ``camera`` as an index into ``rig`` (the written
        clouds index the recording's cameras, ``centres``' rows; NaN rows: not fused)."""
        if self.options.mesh_method != "range" or self.centres is None or len(self.centres) == len(self.rig):
            return cloud
        c = cloud.numpy()
        present = np.nonzero(np.isfinite(self.centres).all(axis=1))[0]
        remap = np.full(len(self.centres), -1, np.int64)
        remap[present] = np.arange(len(present))
        cam = np.asarray(c.camera, np.int64)
        cam = np.where((cam >= 0) & (cam < len(remap)), remap[np.clip(cam, 0, len(remap) - 1)], -1)
        return FusedCloud.from_numpy(c.xyz, c.rgb, c.weight, cam, c.support)

    def _up(self) -> np.ndarray | None:
        return None if self.world is None else self.world.gltf_from_out

    def write(
        self, number: int, cloud: FusedCloud, frame: Callable[[], Any] | None = None, timestamp: float | None = None
    ) -> dict[str, Any]:
        """Write the (already cropped) cloud of frame ``number`` in every format and, with
        ``options.mesh``, its mesh (``frame()`` gives the views for the "tsdf" method); returns
        the manifest entry."""
        opts = self.options
        entry: dict[str, Any] = {"index": int(number), "timestamp": timestamp}
        if opts.mesh:
            from fuseflow.pipeline.mesh import mesh_frame

            views = frame() if (opts.mesh_method == "tsdf" and frame is not None) else None
            mesh = mesh_frame(self._by_rig(cloud), views, self.rig, opts.mesh_method, self.volume, self.centres)
            if self.world is not None and self.world.name != "calib":
                mesh = type(mesh)(
                    self.world.apply(mesh.vertices), mesh.faces, mesh.colors, self.world.rotate(mesh.normals)
                )
            write_glb_mesh(
                mesh_file(self.out, number), mesh.vertices, mesh.faces, mesh.colors, mesh.normals, self._up()
            )
            entry["mesh"] = f"meshes/{number:06d}.glb"
            entry["faces"] = int(len(mesh.faces))
            if opts.mesh_ply:
                _write_mesh_ply(mesh_file(self.out, number, "ply"), mesh)
                entry["mesh_ply"] = f"meshes/{number:06d}.ply"
        placed = self._placed(cloud)
        for fmt in opts.formats[::-1]:  # the first format last: ``done`` and a resume look at every one
            write_cloud(frame_file(self.out, number, fmt), placed, fmt, opts.drc_error_mm, self._up())
        self._files(entry, number, len(placed))
        self.entries[int(number)] = entry
        return entry

    def _files(self, entry: dict[str, Any], number: int, points: int) -> None:
        files = {f: frame_file(self.out, number, f).relative_to(self.out).as_posix() for f in self.options.formats}
        entry["cloud"] = files[self.options.formats[0]]
        entry["files"] = files
        entry["points"] = int(points)

    def resumed(self, number: int, timestamp: float | None, points: int) -> None:
        """Record the entry of a frame an earlier call wrote."""
        opts = self.options
        entry: dict[str, Any] = {"index": int(number), "timestamp": timestamp}
        if opts.mesh:
            entry["mesh"] = f"meshes/{number:06d}.glb"
            if opts.mesh_ply:
                entry["mesh_ply"] = f"meshes/{number:06d}.ply"
        self._files(entry, number, points)
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


_SPLAT_DOC = {
    "layout": "3dgs-ply",
    "folder": "splats",
    "sh_degree": 0,
    "properties": "x y z nx ny nz f_dc_0 f_dc_1 f_dc_2 opacity scale_0 scale_1 scale_2 rot_0 rot_1 rot_2 rot_3",
    "opacity": "logit of FUSE's weight clipped to [0.05, 0.99]",
    "scale": "log of half the mean distance to the 3 nearest points, isotropic",
}


def _out_volume(volume: CaptureVolume, world: World | None) -> CaptureVolume:
    """``volume`` placed in the output frame (its ``T_box_world`` from output coordinates)."""
    if world is None or world.name == "calib":
        return volume
    T = volume.T_box_world @ np.linalg.inv(world.T_out_world)
    T[3] = (0.0, 0.0, 0.0, 1.0)
    return CaptureVolume(volume.lo, volume.hi, T, volume.kind, volume.radius, volume.axis)


def _frame_text(world: World | None) -> str:
    """The manifest's one-line description of the output frame."""
    if world is None or world.name == "calib":
        return "world (the calibration's, right-handed)"
    if world.name == "floor":
        return "floor (z up, origin on the floor under the capture volume's centre, x towards the first camera)"
    return f"{world.name} (OpenCV axes: x right, y down, z forward)"


def write_sequence(out: Path, writer: FrameWriter, fps: float | None = None) -> dict[str, Any]:
    """Add the ``sequence`` document (frames in order, files, formats, crop, units) to
    OUT/manifest.json (docs/formats.md, "Output folder")."""
    from fuseflow.pipeline.outputs import MANIFEST

    opts = writer.options
    if fps is None:  # from the frames' timestamps, when they have them
        stamps = [e["timestamp"] for _, e in sorted(writer.entries.items()) if e.get("timestamp") is not None]
        steps = np.diff(stamps) if len(stamps) >= 2 else np.zeros(0)
        fps = round(1.0 / float(np.median(steps)), 3) if steps.size and np.median(steps) > 0 else None
    world = writer.world
    doc = {
        "format": SEQUENCE_FORMAT,
        "units": "m",
        "frame": _frame_text(world),
        "up": world.up if world is not None else world_up(writer.rig),
        "world": world.to_json() if world is not None else None,
        "fps": fps,
        "cloud_format": opts.formats[0],
        "formats": list(opts.formats),
        "voxel_mm": opts.voxel_mm,
        "drc_error_mm": opts.drc_error_mm if "drc" in opts.formats else None,
        "splat": _SPLAT_DOC if "splat" in opts.formats else None,
        "mesh": {"format": "glb", "method": opts.mesh_method, "ply": opts.mesh_ply} if opts.mesh else None,
        "crop": _out_volume(writer.volume, world).to_json() if writer.volume is not None else None,
        "crop_kept": round(writer.kept_points / writer.fused_points, 6) if writer.fused_points else None,
        "frames": [writer.entries[k] for k in sorted(writer.entries)],
    }
    path = Path(out) / MANIFEST
    manifest = json.loads(path.read_text()) if path.exists() else {}
    manifest["sequence"] = doc
    write_json_atomic(path, manifest)
    return doc
