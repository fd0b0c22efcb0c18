"""Logging rigs and fused clouds to rerun (optional extra ``fuseflow[viz]``).

Entities: ``world/cameras/<id>`` (a Transform3D world-from-camera plus a Pinhole with OpenCV
axes, which rerun draws as a frustum), ``world/cloud`` (Points3D per frame on the ``frame``
timeline, coloured by RGB) and ``world/cloud_weight`` (the same points coloured by fusion
weight, TURBO colormap), hidden or shown in the viewer's blueprint panel.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fuseflow.errors import require
from fuseflow.types import FusedCloud, Rig
from fuseflow.viz.render import weight_colors

__all__ = ["RerunLogger", "import_rerun"]


def import_rerun() -> Any:
    """The rerun module, or FuseFlowError with the install hint."""
    return require("rerun", "viz", "the rerun viewer", "rerun-sdk")


class RerunLogger:
    """A rerun recording stream for one run: ``log_rig`` once, ``log_cloud`` per frame.

    Args:
        save_to: write an .rrd file here (open it later with ``rerun FILE``); None = no file.
        spawn: also open a live viewer window (needs a display).
    """

    def __init__(self, save_to: str | Path | None = None, spawn: bool = False, application_id: str = "fuseflow"):
        rr = import_rerun()
        self._rr = rr
        self.rec = rr.RecordingStream(application_id)
        if save_to is not None:
            Path(save_to).parent.mkdir(parents=True, exist_ok=True)
            self.rec.save(str(save_to))
        if spawn:
            self.rec.spawn(connect=save_to is None)
        self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Y_DOWN, static=True)

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

    def log_cloud(self, frame_index: int, cloud: FusedCloud, radius: float = 0.003) -> None:
        rr = self._rr
        c = cloud.to("cpu")
        self.rec.set_time("frame", sequence=int(frame_index))
        xyz = c.xyz.numpy()
        self.rec.log("world/cloud", rr.Points3D(xyz, colors=c.rgb.numpy(), radii=radius))
        self.rec.log("world/cloud_weight", rr.Points3D(xyz, colors=weight_colors(c.weight.numpy()), radii=radius))

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()
