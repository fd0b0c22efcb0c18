"""fuseflow.pipeline.run / stream: outputs, resume after interruption, dropout, bumped camera."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

import fuseflow
from fuseflow.errors import FuseFlowError
from fuseflow.io import open_recording, read_calibration, read_ply
from fuseflow.pipeline import HealthMonitor, PipelineConfig, cloud_path, merge_recalibration, run, stream
from fuseflow.pipeline.config import OutputOptions
from fuseflow.types import Calibration, invert_rigid


def _clouds_equal(a, b) -> bool:
    a, b = a.numpy(), b.numpy()  # stream's clouds hold numpy arrays, read_ply's torch tensors
    return all(np.array_equal(getattr(a, k), getattr(b, k)) for k in ("xyz", "rgb", "weight", "camera"))


def test_run_writes_every_frame_calib_and_summary(static_rec, tmp_path):
    out = tmp_path / "out"
    s = run(static_rec, out, use_rig_extrinsics=True)
    rec = open_recording(static_rec)
    assert s.frames == s.frames_fused_now == len(rec) and s.frames_resumed == 0
    assert s.calibration == "rig.json" and not s.dropped_views and not s.bumped_cameras
    for t in range(len(rec)):
        cloud = read_ply(cloud_path(out, t))
        assert len(cloud) > 1000
    cal = read_calibration(out / "calib.json")
    for c in rec.rig:
        np.testing.assert_allclose(cal.T_cam_world[c.id], c.T_cam_world, atol=1e-12)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == len(rec) and summary["points_per_frame"]["mean"] > 1000
    lines = (out / "frames.jsonl").read_text().splitlines()
    assert [json.loads(x)["index"] for x in lines] == list(range(len(rec)))


def test_interrupted_run_resumes_to_identical_outputs(static_rec, tmp_path):
    full = tmp_path / "full"
    run(static_rec, full, use_rig_extrinsics=True)

    part = tmp_path / "part"

    def stop_after_two(record, done, total):
        if done == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run(static_rec, part, use_rig_extrinsics=True, on_frame=stop_after_two)
    written = sorted(p.name for p in (part / "clouds").glob("*"))
    assert written == ["000000.ply", "000001.ply"]  # complete files only, no temporaries
    s = run(static_rec, part, use_rig_extrinsics=True)
    assert s.frames_resumed == 2 and s.frames_fused_now == s.frames - 2
    for t in range(s.frames):
        assert _clouds_equal(read_ply(cloud_path(part, t)), read_ply(cloud_path(full, t)))
    again = run(static_rec, part, use_rig_extrinsics=True)
    assert again.frames_fused_now == 0 and again.frames_resumed == s.frames


def test_run_without_extrinsics_or_calibration_is_a_clear_error(static_rec, tmp_path):
    rec = open_recording(static_rec)
    bare = fuseflow.Rig(tuple(c.with_extrinsics(None) for c in rec.rig))
    with pytest.raises(FuseFlowError, match="without extrinsics"):
        list(stream(rec, bare))


def test_given_calibration_is_used_and_written(static_rec, tmp_path):
    rec = open_recording(static_rec)
    cal = Calibration({c.id: c.T_cam_world for c in rec.rig}, {})
    s = run(rec, tmp_path / "o", calibration=cal, frames=range(0, 2))
    assert s.calibration == "given" and s.frames == 2
    assert set(read_calibration(tmp_path / "o" / "calib.json").T_cam_world) == set(rec.rig.ids)


def test_dropped_views_keep_the_stream_running(static_rec, tmp_path):
    rec_dir = tmp_path / "rec"
    shutil.copytree(static_rec, rec_dir)
    for t in (1, 2):
        for p in (rec_dir / "cam02").glob(f"*/{t:06d}.*"):
            p.unlink()
    s = run(rec_dir, tmp_path / "out", use_rig_extrinsics=True)
    assert s.frames == 6 and s.dropped_views == {"cam02": 2}
    assert any("cam02 was missing in 2 frames" in w for w in s.warnings)
    recs = [json.loads(x) for x in (tmp_path / "out" / "frames.jsonl").read_text().splitlines()]
    assert [r["missing"] for r in recs] == [[], ["cam02"], ["cam02"], [], [], []]
    for t in (1, 2):
        cams = set(read_ply(cloud_path(tmp_path / "out", t)).camera.tolist())
        assert 2 not in cams and cams  # fused from the other three views
    assert recs[1]["agreement"]["cam02"] is None


def test_stream_yields_the_clouds_run_writes(dynamic_rec, tmp_path):
    out = tmp_path / "out"
    run(dynamic_rec, out, use_rig_extrinsics=True, config=PipelineConfig(outputs=OutputOptions(world="calib")))
    clouds = list(stream(dynamic_rec))
    assert len(clouds) == 5
    for t, c in enumerate(clouds):
        assert _clouds_equal(c, read_ply(cloud_path(out, t)))
    # a dynamic scene: consecutive frames differ
    assert not np.array_equal(clouds[0].xyz, clouds[-1].xyz)  # numpy: stream's clouds on the CPU


def test_bumped_camera_is_flagged(bumped_rec, tmp_path):
    rec, cam, t_bump, _ = bumped_rec
    s = run(rec, tmp_path / "out", use_rig_extrinsics=True)
    assert list(s.bumped_cameras) == [cam]
    assert t_bump <= s.bumped_cameras[cam] <= t_bump + 2  # patience 2: flagged on the 1st or 2nd bad frame
    recs = [json.loads(x) for x in (tmp_path / "out" / "frames.jsonl").read_text().splitlines()]
    before = np.mean([r["agreement"][cam] for r in recs[:t_bump]])
    after = np.mean([r["agreement"][cam] for r in recs[t_bump:]])
    assert before > 0.6 and after < before - 0.1
    assert any(f"camera {cam} lost agreement" in w for w in s.warnings)


def test_recalibrate_auto_restores_agreement(bumped_rec, tmp_path, monkeypatch):
    """With --recalibrate auto, GMAC re-runs on the flagged frame and the bumped camera's new pose
    is merged into the old world frame. GMAC itself is tested in tests/calib; here it is replaced
    by an oracle that returns the true poses in a *different* world frame (as GMAC would: its
    world is its reference camera), so the merge must do the frame change."""
    import fuseflow.calib as calib_mod

    rec, cam, t_bump, T_new = bumped_rec
    true_rig = open_recording(rec).rig.with_extrinsics({cam: T_new})
    W = np.eye(4)
    W[:3, :3] = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    W[:3, 3] = [0.3, -1.2, 0.5]  # new_world_from_old_world
    calls = []

    def oracle(frame, rig, config=None):
        calls.append(frame.index)
        return Calibration({c.id: c.T_cam_world @ invert_rigid(W) for c in true_rig}, {"oracle": True})

    monkeypatch.setattr(calib_mod, "calibrate", oracle)
    s = run(rec, tmp_path / "out", use_rig_extrinsics=True, config=PipelineConfig(recalibrate="auto"))
    assert len(calls) == 1 and s.recalibrations == [calls[0]] and calls[0] >= t_bump
    cal = read_calibration(tmp_path / "out" / "calib.json")
    np.testing.assert_allclose(cal.T_cam_world[cam], T_new, atol=1e-6)  # back in the old world frame
    recs = [json.loads(x) for x in (tmp_path / "out" / "frames.jsonl").read_text().splitlines()]
    assert recs[-1]["agreement"][cam] > 0.6  # agreement restored after recalibration


def test_merge_recalibration_keeps_unmoved_cameras(static_rec):
    rig = open_recording(static_rec).rig
    W = np.eye(4)
    W[:3, 3] = [1.0, 2.0, 3.0]
    new = Calibration({c.id: c.T_cam_world @ invert_rigid(W) for c in rig}, {})
    merged = merge_recalibration(rig, new, ["cam00"])
    for c in rig:
        np.testing.assert_allclose(merged[c.id].T_cam_world, c.T_cam_world, atol=1e-9)


def test_health_monitor_blames_the_camera_all_of_whose_pairs_fell():
    ids = ["a", "b", "c", "d"]
    m = HealthMonitor(ids, warmup=2, drop=0.1, patience=2)
    base = np.full((4, 4), 0.85)
    np.fill_diagonal(base, np.nan)
    for _ in range(2):
        assert m.update(base) == []
    bumped = base.copy()
    bumped[1, :] = bumped[:, 1] = 0.5  # every pair of b fell; a, c, d each lost one pair
    bumped[1, 1] = np.nan
    assert m.update(bumped) == []  # first suspect frame: patience
    assert m.update(bumped) == ["b"]
    one_pair = base.copy()
    one_pair[0, 2] = one_pair[2, 0] = 0.4  # a single pair fell: nobody to blame
    for _ in range(3):
        assert m.update(one_pair) == []
    no_votes = base.copy()
    no_votes[3, :] = no_votes[:, 3] = np.nan  # d missing: ignored, not flagged
    assert m.update(no_votes) == []


def test_pipeline_config_validates():
    with pytest.raises(FuseFlowError, match="recalibrate"):
        PipelineConfig(recalibrate="sometimes")
    with pytest.raises(FuseFlowError, match="health_samples"):
        PipelineConfig(health_samples=0)


def test_stream_leaves_out_cameras_the_calibration_does_not_place(static_rec):
    rec = open_recording(static_rec)
    cal = Calibration({c.id: c.T_cam_world for c in rec.rig if c.id != "cam01"}, {})
    clouds = list(stream(rec, cal))
    assert len(clouds) == len(rec)
    # camera indices refer to the recording's rig, not to the fused subset
    assert set(clouds[0].camera.tolist()) == {0, 2, 3} and len(clouds[0]) > 1000


def test_run_pools_frames_when_gmac_fails_on_one(static_rec, tmp_path, monkeypatch):
    """`run` without --calib-frame: a GMAC that places too few cameras from the first good frame
    is run again on frames spread over the recording (pipeline.calibration.calibrate_frames);
    with --calib-frame it is not, and the error stays."""
    import fuseflow.calib as calib_mod
    from fuseflow.calib import CalibrationError

    true_rig, calls = open_recording(static_rec).rig, []

    def one_frame_fails(frames, rig, config=None, progress=None):
        calls.append([f.index for f in frames])
        if len(frames) == 1:
            raise CalibrationError("the backbone placed fewer than two cameras")
        return Calibration({c.id: c.T_cam_world for c in true_rig}, {"oracle": True})

    monkeypatch.setattr(calib_mod, "calibrate", one_frame_fails)
    s = run(static_rec, tmp_path / "a", frames=range(2))
    assert calls == [[0], [0, 1, 2, 3, 4, 5]] and s.calibration == "GMAC on 6 frames from frame 0", (calls, s)
    calls.clear()
    with pytest.raises(CalibrationError):
        run(static_rec, tmp_path / "b", frames=range(2), calib_frame=1)
    assert calls == [[1]]
