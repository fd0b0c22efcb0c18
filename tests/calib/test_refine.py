"""Optional refinement: a scale cannot fix rotations, ICP + pose graph must (docs/design.md 3)."""

from __future__ import annotations

import numpy as np

from fuseflow.calib import CalibConfig, calibrate
from fuseflow.calib.refine import refine_poses


def _rot_err_deg(T_est: dict, T_true: np.ndarray, ids) -> float:
    """Mean geodesic angle of relative rotations over camera pairs (docs/design.md 4)."""
    errs = []
    for a in range(len(ids)):
        for b in range(a + 1, len(ids)):
            Re = T_est[ids[a]][:3, :3] @ T_est[ids[b]][:3, :3].T
            Rt = T_true[a, :3, :3] @ T_true[b, :3, :3].T
            c = (np.trace(Re @ Rt.T) - 1) / 2
            errs.append(np.degrees(np.arccos(np.clip(c, -1, 1))))
    return float(np.mean(errs))


def test_refinement_lowers_rotation_error(scene5, backbone_builder):
    frame, rig, T = scene5
    ids = frame.camera_ids
    bb = backbone_builder(T, 3.7, rot_noise_deg=1.0, seed=3)
    # the ICP stage against no refinement at all (the joint refinement would do the same job);
    # no depth-agreement rule: it would leave the 1-deg-off cameras unplaced before the refinement
    plain = calibrate(frame, rig, CalibConfig(joint_refine=False, min_depth_agreement=0.0), backbone_result=bb)
    refined = calibrate(
        frame, rig, CalibConfig.preset("refined", joint_refine=False, min_depth_agreement=0.0), backbone_result=bb
    )
    e0, e1 = _rot_err_deg(plain.T_cam_world, T, ids), _rot_err_deg(refined.T_cam_world, T, ids)
    assert e0 > 1.0  # the scale stage leaves the backbone's rotations alone
    assert e1 < 0.5 * e0
    rr = refined.report["refinement"]
    assert rr["edges_used"] >= len(ids) - 1
    assert "refine" in refined.report["timings_s"]
    assert plain.report["refinement"] is None


def test_refinement_skips_pairs_without_overlap(scene5):
    """Two cameras placed 50 m apart: ICP finds no correspondence; the pair is skipped, no crash."""
    frame, rig, T = scene5
    far = T[1].copy()
    far[:3, 3] += np.array([50.0, 0.0, 0.0])
    depth = frame.depth.numpy()
    K = rig.K().double().numpy()
    rng = rig.depth_range().double().numpy()
    rr = refine_poses({0: T[0], 1: far}, depth, K, rng, [(0, 1)], CalibConfig(), color=frame.color.numpy())
    assert rr.edges_used == 0 and rr.fitness["0-1"] == 0.0
    np.testing.assert_allclose(rr.T_cam_world[1], far, atol=1e-9)
