"""Looking at results: a headless point-cloud renderer (PNG) and rerun logging."""

from fuseflow.viz.render import orbit_camera, render_cloud, save_cloud_png

__all__ = ["orbit_camera", "render_cloud", "save_cloud_png"]
