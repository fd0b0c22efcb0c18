"""Logging rigs and fused clouds to rerun (optional extra ``fuseflow[viz]``).

Entities: ``world/cameras/<id>`` (a Transform3D world-from-camera plus a Pinhole with OpenCV
axes, which rerun draws as a frustum), ``world/cloud`` (Points3D per frame on the ``frame``
timeline, coloured by RGB) and ``world/cloud_weight`` (the same points coloured by fusion
weight, TURBO colormap), hidden or shown in the viewer's blueprint panel.

Size: each frame's cloud is subsampled to at most ``RERUN_POINTS`` points (an even random
subset, seeded by the frame number) unless ``log_cloud(..., max_points=None)``: a rerun file
stores every point twice (colour and weight), 20 bytes a point each.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fuseflow.errors import require
from fuseflow.types import FusedCloud, Rig
from fuseflow.viz.render import weight_colors

__all__ = ["RerunLogger", "import_rerun", "RERUN_POINTS"]

RERUN_POINTS = 100_000
"""Points logged per frame by default (``fuseflow view --rerun-full`` logs every point)."""


def import_rerun() -> Any:
    """The rerun module, or FuseFlowError with the install hint."""
    return require("rerun", "viz", "the rerun viewer", "rerun-sdk")


class RerunLogger:
    """A rerun recording stream for one run: ``log_rig`` once, ``log_cloud`` per frame.

    Args:
        save_to: write an .rrd file here (open it later with ``rerun FILE``); None = no file.
        spawn: also open a live viewer window (needs a display).
        z_up: the world is a z-up frame (``--world floor``); else the first camera's axes (y down).
    """

    def __init__(
        self,
        save_to: str | Path | None = None,
        spawn: bool = False,
        application_id: str = "fuseflow",
        z_up: bool = False,
    ):
        rr = import_rerun()
        self._rr = rr
        self.rec = rr.RecordingStream(application_id)
        if save_to is not None:
            Path(save_to).parent.mkdir(parents=True, exist_ok=True)
            self.rec.save(str(save_to))
        if spawn:
            self.rec.spawn(connect=save_to is None)
        view = rr.ViewCoordinates.RIGHT_HAND_Z_UP if z_up else rr.ViewCoordinates.RIGHT_HAND_Y_DOWN
        self.rec.log("world", view, static=True)

    def log_rig(self, rig: Rig, static: bool = True) -> None:
        """Cameras as frustums (only calibrated cameras can be placed)."""
        rr = self._rr
        for cam in rig.cameras:
            if cam.T_world_cam is None:
                continue
            T = cam.T_world_cam
            path = f"world/cameras/{cam.id}"
            self.rec.log(path, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]), static=static)
            self.rec.log(
                path,
                rr.Pinhole(
                    image_from_camera=cam.K,
                    resolution=[cam.width, cam.height],
                    camera_xyz=rr.ViewCoordinates.RDF,
                    image_plane_distance=0.15,
                ),
                static=static,
            )

    def log_cloud(
        self,
        frame_index: int,
        cloud: FusedCloud,
        radius: float = 0.003,
        max_points: int | None = RERUN_POINTS,
        with_weight: bool = True,
    ) -> int:
        """Log one frame's cloud (at most ``max_points`` of it; None: all) and, ``with_weight``
        (False for clouds read from files without weights), its weight layer; returns the points
        logged."""
        import numpy as np

        rr = self._rr
        c = cloud.to("cpu")
        self.rec.set_time("frame", sequence=int(frame_index))
        xyz, rgb, w = c.xyz.numpy(), c.rgb.numpy(), c.weight.numpy()
        if max_points is not None and len(xyz) > max_points:
            keep = np.sort(np.random.default_rng(int(frame_index)).choice(len(xyz), max_points, replace=False))
            xyz, rgb, w = xyz[keep], rgb[keep], w[keep]
        self.rec.log("world/cloud", rr.Points3D(xyz, colors=rgb, radii=radius))
        if with_weight:
            self.rec.log("world/cloud_weight", rr.Points3D(xyz, colors=weight_colors(w), radii=radius))
        return len(xyz)

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()
