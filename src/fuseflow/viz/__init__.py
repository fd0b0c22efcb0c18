"""Looking at results: a headless point-cloud renderer (PNG), a Gaussian-splat renderer and rerun
logging."""

from fuseflow.viz.render import orbit_camera, render_cloud, save_cloud_png
from fuseflow.viz.splat_render import render_splats, save_splat_png

__all__ = ["orbit_camera", "render_cloud", "save_cloud_png", "render_splats", "save_splat_png"]
