"""The independently rendered repeating studio (benchmarks.studies.independent_scene) and the
scoring of its calibration benchmark (benchmarks.studies.independent_run), on tiny inputs."""

from __future__ import annotations

import json
import math

import numpy as np
from benchmarks.studies.independent_run import camera_rows, score
from benchmarks.studies.independent_scene import make_studio, render_frame, rot, trace, write_studio

import fuseflow


def test_the_studio_writes_a_readable_recording_with_the_truth_beside_it(tmp_path):
    studio = make_studio(3, "320x240", frames=2, moving=True, sides=8, cameras=5)
    info = write_studio(tmp_path / "rec", studio)
    rec = fuseflow.open_recording(tmp_path / "rec")
    assert len(rec) == 2 and [c.id for c in rec.rig.cameras] == [f"cam{i}" for i in range(5)]
    assert all(c.T_cam_world is None and c.sensor == "kinect_v2" for c in rec.rig.cameras)
    frame = rec[1]
    assert tuple(frame.depth.shape) == (5, 240, 320) and tuple(frame.color.shape) == (5, 240, 320, 3)
    depth = np.asarray(frame.depth)
    assert 0.6 < (depth > 0).mean() < 0.99  # holes (dark, grazing, far, flying), but mostly measured
    ref = fuseflow.read_calibration(tmp_path / "rec" / "reference.json")
    for cam, c in zip(studio.cams, rec.rig.cameras):
        np.testing.assert_allclose(ref.T_cam_world[cam.id], cam.T_cam_world, atol=1e-9)
        np.testing.assert_allclose(c.K, cam.K, atol=1e-6)
    assert info["sides"] == 8 and json.loads((tmp_path / "rec" / "scene.json").read_text())["cameras"] == 5


def test_the_true_pose_puts_the_floor_at_zero_and_the_cameras_around_the_figure(tmp_path):
    """Depth back-projected with K and the written truth (camera-from-world) lands on the floor
    (z = 0) where the ray cast hit the floor: the extrinsics' direction, depth scale and z-depth
    round-trip through the files."""
    studio = make_studio(5, "320x240", sides=6, cameras=5)
    write_studio(tmp_path / "rec", studio)
    rec = fuseflow.open_recording(tmp_path / "rec")
    ref = fuseflow.read_calibration(tmp_path / "rec" / "reference.json")
    depth = np.asarray(rec[0].depth)
    for i, cam in enumerate(rec.rig.cameras):
        T = ref.T_cam_world[cam.id]
        centre = -T[:3, :3].T @ T[:3, 3]
        assert 2.5 <= math.hypot(centre[0], centre[1]) <= 3.5 and 1.1 <= centre[2] <= 2.5
        v, u = np.nonzero(depth[i] > 0)
        keep = v > 0.9 * cam.height  # the bottom rows look at the floor in front of the figure
        z = depth[i][v[keep], u[keep]]
        X = (np.linalg.inv(cam.K) @ np.stack([u[keep], v[keep], np.ones(keep.sum())])) * z
        world = T[:3, :3].T @ (X - T[:3, 3:4])
        assert np.median(np.abs(world[2])) < 0.02, cam.id


def test_the_rendering_is_deterministic_and_the_room_repeats_with_its_period():
    a = render_frame(make_studio(11, "320x240", cameras=5), 0)
    b = render_frame(make_studio(11, "320x240", cameras=5), 0)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    studio = make_studio(12, "320x240", sides=10, cameras=5)
    cam = studio.cams[0]  # the empty room (no figure), seen from a camera and from it turned by one period
    turned = type(cam)(cam.id, cam.K, cam.T_cam_world @ _rz(-36.0), cam.gain, cam.balance)
    a, b = (trace(studio.room, [], c, studio.sensor) for c in (cam, turned))
    np.testing.assert_allclose(a["depth"], b["depth"], atol=1e-6)
    assert np.percentile(np.abs(a["radiance"] - b["radiance"]), 99) < 1e-3  # (texel seams aside)
    off = type(cam)(cam.id, cam.K, cam.T_cam_world @ _rz(-18.0), cam.gain, cam.balance)
    assert np.median(np.abs(a["radiance"] - trace(studio.room, [], off, studio.sensor)["radiance"])) > 0.01


def _rz(deg: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = rot("z", deg)
    return T


def test_scoring_finds_a_camera_one_period_off_whatever_the_world_frame():
    from benchmarks.studies.independent_scene import look_at

    truth = {f"cam{k}": look_at(np.array([3 * math.cos(k), 3 * math.sin(k), 1.8]), np.zeros(3) + [0, 0, 0.7])
             for k in range(5)}  # fmt: skip
    W = _rz(70.0)
    W[:3, 3] = [1.0, -2.0, 0.3]
    est = {c: T @ W for c, T in truth.items()}
    est["cam2"] = truth["cam2"] @ _rz(45.0) @ W  # turned one period of an 8-sided room
    del est["cam4"]
    anchor, errs, enough = score(est, truth)
    assert enough and anchor != "cam2" and abs(errs["cam2"][0] - 45.0) < 1e-6
    report = {"cam0": {"verdict": "good"}, "cam1": {"verdict": "check it"}, "cam2": {"verdict": "good"}}
    calib = {"cameras": {c: {"T_cam_world": T.tolist()} for c, T in est.items()},
             "report": {"camera_verdicts": report}}  # fmt: skip
    rows = {r["camera"]: r for r in camera_rows(calib, truth, 45.0)}
    assert rows["cam2"]["silently_wrong"] and rows["cam2"]["periods"] == 1.0
    assert rows["cam0"]["within"] and rows["cam1"]["within"] and rows["cam1"]["flagged"]
    assert not rows["cam4"]["placed"] and not rows["cam4"]["within"]


def test_a_lone_right_camera_is_not_within():
    from benchmarks.studies.independent_scene import look_at

    truth = {"cam0": look_at(np.array([3.0, 0, 1.8]), np.array([0, 0, 0.7])),
             "cam1": look_at(np.array([-3.0, 0, 1.8]), np.array([0, 0, 0.7]))}  # fmt: skip
    est = {"cam0": truth["cam0"], "cam1": truth["cam1"] @ _rz(60.0)}
    calib = {"cameras": {c: {"T_cam_world": T.tolist()} for c, T in est.items()},
             "report": {"camera_verdicts": {"cam0": {"verdict": "good"}, "cam1": {"verdict": "good"}}}}  # fmt: skip
    rows = camera_rows(calib, truth, 60.0)
    assert not any(r["within"] for r in rows) and sum(r["silently_wrong"] for r in rows) == 1
