"""Route (f), moving spheres (``calib.backbones.rgbd.spheres``): a sphere fitted to what a camera
sees of a ball is the same centre from every side; same-frame centres of two cameras give their
relative pose. Synthetic checks with exact depth, and the real 3-Kinect room, where no other
route places any camera."""

from __future__ import annotations

import json

import numpy as np
import pytest
from tests.conftest import SHARED_DATA, look_at

import fuseflow
from fuseflow.calib.backbones.rgbd import RGBDConfig, rgbd_backbone
from fuseflow.calib.backbones.rgbd.spheres import camera_spheres, fit_sphere, sphere_pose
from fuseflow.eval.metrics import pose_errors
from fuseflow.types import invert_rigid

K = np.array([[300.0, 0, 159.5], [0, 300.0, 119.5], [0, 0, 1]])
RADIUS = 0.2


def _render(T_cam_world: np.ndarray, centre_w: np.ndarray) -> np.ndarray:
    """(240, 320) depth of a wall 5 m away along the view and a ball of RADIUS at ``centre_w``."""
    v, u = np.mgrid[0:240, 0:320].astype(np.float64)
    d = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    c = T_cam_world[:3, :3] @ centre_w + T_cam_world[:3, 3]
    # |z d - c| = r: z^2 |d|^2 - 2 z d.c + |c|^2 - r^2 = 0, the nearer root
    a, b, cc = (d**2).sum(-1), (d @ c), c @ c - RADIUS**2
    disc = b**2 - a * cc
    z = np.where(disc > 0, (b - np.sqrt(np.maximum(disc, 0))) / a, 5.0)
    return z.astype(np.float64)


def _rig_and_track(n_frames: int = 8):
    Ts = [look_at(np.array([3.0 * np.cos(a), -1.0, 3.0 * np.sin(a)]), [0.0, 0.0, 0.0]) for a in (0.0, 2.1)]
    rng = np.random.default_rng(1)
    centres = rng.uniform([-0.8, -0.6, -0.8], [0.8, 0.4, 0.8], (n_frames, 3))
    depths = [np.stack([_render(T, c) for c in centres]) for T in Ts]
    return Ts, centres, depths


def test_fit_sphere_finds_the_centre_behind_the_visible_cap():
    Ts, centres, depths = _rig_and_track(1)
    D = depths[0][0]
    v, u = np.nonzero(D < 4.9)
    z = D[v, u]
    P = np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z], axis=1)
    c, r, share = fit_sphere(P, np.random.default_rng(0))
    truth = Ts[0][:3, :3] @ centres[0] + Ts[0][:3, 3]
    assert np.linalg.norm(c - truth) < 0.005 and abs(r - RADIUS) < 0.005 and share > 0.95


def test_sphere_tracks_give_the_relative_pose():
    Ts, _, depths = _rig_and_track(8)
    sa, sb = camera_spheres(depths[0], K), camera_spheres(depths[1], K)
    assert all(len(s) == 1 for s in sa + sb)
    T, inl = sphere_pose(sa, sb)
    truth = Ts[1] @ invert_rigid(Ts[0])
    err = pose_errors(np.stack([np.eye(4), T]), np.stack([np.eye(4), truth]))
    assert inl.sum() == 8 and err.rotation_deg < 0.2 and err.translation_mm < 10


def test_a_ball_standing_still_fixes_no_pose():
    Ts, centres, _ = _rig_and_track(1)
    still = [np.stack([_render(T, centres[0])] * 6) for T in Ts]
    assert sphere_pose(camera_spheres(still[0], K), camera_spheres(still[1], K)) is None


KINECT3 = SHARED_DATA / "kinect3-room"


def test_kinect3_room_is_placed_by_the_moving_ball():
    """10 frames spread over the 25: every pair by the sphere route, within 3 deg / 15 cm of the
    capture's rough reference (pairwise, no alignment); without the route nothing is placed."""
    if not KINECT3.exists():
        pytest.skip(f"shared data not found at {KINECT3}")
    rec = fuseflow.open_recording(KINECT3)
    frames = [rec[t] for t in np.linspace(0, len(rec) - 1, 10).round().astype(int)]
    bare = fuseflow.Rig(tuple(c.with_extrinsics(None) for c in rec.rig))
    res = rgbd_backbone(frames, bare, RGBDConfig())
    assert res.registered.all(), res.info["pairs"]
    ref = json.loads((KINECT3 / "reference_calib.json").read_text())["cameras"]
    err = pose_errors(res.T_cam_world, np.stack([np.array(ref[c]["T_cam_world"]) for c in rec.rig.ids]))
    assert err.rotation_deg < 3.0 and err.translation_mm < 150, err


def test_kinect3_room_short_window_expects_what_the_pair_poses_miss():
    """Frames 5-16: a short ball track. Every pair pose carries its fit covariance's expected
    error; the worst of them (what a camera placed by these track poses prints) is within 3x of
    the worst pair's difference to the capture's rough reference, and beyond 5 cm, so the
    cameras cannot read "good"."""
    if not KINECT3.exists():
        pytest.skip(f"shared data not found at {KINECT3}")
    from fuseflow.calib.verdicts import GOOD_MM, edge_residual

    rec = fuseflow.open_recording(KINECT3)
    bare = fuseflow.Rig(tuple(c.with_extrinsics(None) for c in rec.rig))
    res = rgbd_backbone([rec[t] for t in range(5, 17)], bare, RGBDConfig())
    ref = json.loads((KINECT3 / "reference_calib.json").read_text())["cameras"]
    T_ref = {c: np.array(ref[c]["T_cam_world"]) for c in rec.rig.ids}
    edges = [p for p in res.info["pairs"] if p.get("edge")]
    assert len(edges) == 3 and all(p["edge"]["route"].startswith("sphere") for p in edges)
    diff = np.array([edge_residual(np.array(p["edge"]["T_ji"]), *(T_ref[c] for c in p["cameras"])) for p in edges])
    worst = np.array([max(p["edge"]["expected"][k] for p in edges) for k in ("deg", "mm")])
    assert np.all(worst > diff.max(axis=0) / 3) and np.all(worst < 3 * diff.max(axis=0)), (worst, diff)
    assert worst[1] > GOOD_MM
