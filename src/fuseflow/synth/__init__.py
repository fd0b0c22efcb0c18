"""The simulator: synthetic multi-camera RGB-D rigs with exact ground truth.

Depends only on fuseflow.types, fuseflow.errors and fuseflow.io (ground truth must not depend on
the code it tests). Open3D and numba are imported when a Simulator renders, not here.

    from fuseflow.synth import SimConfig, Simulator, simulate_recording, read_ground_truth
    sim = Simulator(SimConfig(cameras=8, frames=10, scene="studio"))
    sf = sim.render(0)        # SimFrame: .frame, .depth_gt, .surface_points, .surface_normals
"""

from fuseflow.synth.config import KINECT_V1, REALSENSE_D435, AxialNoise, SensorModel, SimConfig
from fuseflow.synth.recording import GroundTruth, read_ground_truth, read_surface_ply, simulate_recording
from fuseflow.synth.simulator import SimFrame, Simulator, observable_mask, overlap_matrix, visible_mask

__all__ = [
    "AxialNoise",
    "GroundTruth",
    "KINECT_V1",
    "REALSENSE_D435",
    "SensorModel",
    "SimConfig",
    "SimFrame",
    "Simulator",
    "overlap_matrix",
    "read_ground_truth",
    "read_surface_ply",
    "simulate_recording",
    "visible_mask",
    "observable_mask",
]
