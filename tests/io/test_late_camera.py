"""A 4-camera rig recorded as four RealSense .bag files, one camera 2 frames late: it converts, the
timestamps show the late camera, and its offset is found from shifted depth agreement. Also the
simulator's --desync."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

pytest.importorskip("rosbags")

import fuseflow.cli  # noqa: E402, F401  (registers the commands)
from fuseflow.cli.app import app  # noqa: E402
from fuseflow.errors import ValidationError  # noqa: E402
from fuseflow.geometry import pair_agreement  # noqa: E402
from fuseflow.io import open_recording, read_rig  # noqa: E402
from fuseflow.io.convert import convert  # noqa: E402
from fuseflow.io.images import read_color, read_depth_raw  # noqa: E402
from fuseflow.io.timesync import read_timestamps  # noqa: E402
from fuseflow.pipeline.sync import estimate_frame_offset  # noqa: E402
from fuseflow.synth import SimConfig, simulate_recording  # noqa: E402
from fuseflow.synth.desync import apply_desync, parse_desync  # noqa: E402
from fuseflow.types import Frame  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from recording_writers import write_realsense_bag  # noqa: E402

runner = CliRunner()
FPS, FRAMES, LATE = 5.0, 10, 2  # 5 fps: the walker moves ~16 cm a frame, well above depth noise


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    out = tmp_path_factory.mktemp("late") / "sim"
    simulate_recording(out, SimConfig(cameras=4, frames=FRAMES, scene="studio", dynamic=True, resolution=(128, 96),
                                      seed=3, fps=FPS))  # fmt: skip
    return out


@pytest.fixture(scope="module")
def converted(sim, tmp_path_factory):
    """Four bags; cam03's device clock runs 2 frames late: its view of instant k carries the time of k + 2."""
    rec = open_recording(sim)
    rig = rec.rig
    bags = tmp_path_factory.mktemp("bags")
    rng = np.random.default_rng(7)
    base_ns = 50_000_000_000
    stamps = {}
    for cam in rig.cameras:
        color = np.stack([read_color(sim / cam.id / "color" / f"{t:06d}.png") for t in range(FRAMES)])
        depth = np.stack([read_depth_raw(sim / cam.id / "depth" / f"{t:06d}.png") for t in range(FRAMES)])
        k = np.arange(FRAMES) + (LATE if cam.id == "cam03" else 0)
        ns = base_ns + np.round(k * 1e9 / FPS).astype(np.int64) + rng.integers(-3_000_000, 3_000_000, FRAMES)
        stamps[cam.id] = ns
        write_realsense_bag(
            bags / f"{cam.id}.bag", cam.id, color, depth, ns / 1e9, cam.K, depth_units=1 / cam.depth_scale
        )
    out = tmp_path_factory.mktemp("conv") / "rec"
    s = convert([bags], out)
    return s, out, stamps, rig


def test_four_bags_convert_and_timestamps_show_the_late_camera(converted, sim):
    s, out, stamps, _ = converted
    assert s.kind == "realsense" and s.frames == FRAMES + LATE
    ts = read_timestamps(out)
    late = ts.view["cam03"]
    assert np.isnan(late[:LATE]).all() and np.isfinite(late[LATE:]).all()
    assert np.array_equal(np.round(late[LATE:] * 1e9).astype(np.int64), stamps["cam03"])
    for cid in ("cam00", "cam01", "cam02"):
        assert np.isnan(ts.view[cid][FRAMES:]).all()
        assert np.array_equal(np.round(ts.view[cid][:FRAMES] * 1e9).astype(np.int64), stamps[cid])
    rec = open_recording(out)
    assert rec.missing_views()["cam03"] == [0, 1]
    # frame f of the conversion holds cam03's view of instant f - 2, bit-exactly
    assert np.array_equal(
        read_depth_raw(out / "cam03/depth/000005.png"), read_depth_raw(sim / "cam03/depth/000003.png")
    )
    info = json.loads(runner.invoke(app, ["info", str(out), "--json"]).output)["timing"]
    first = {c: v["first_view_s"] for c, v in info["cameras"].items()}
    assert first["cam03"] - first["cam00"] == pytest.approx(LATE / FPS, abs=0.007)


def _shifted_scores(frames: list[Frame], rig, cam: int, others: list[int], shifts: list[int]) -> np.ndarray:
    """scores[t, k]: mean pair agreement (tau 2 %) of camera `cam` at frame t with `others` at t + shifts[k]."""
    scores = np.full((len(frames), len(shifts)), np.nan)
    for t, ft in enumerate(frames):
        if not bool(ft.present[cam]):
            continue
        for k, s in enumerate(shifts):
            if not 0 <= t + s < len(frames):
                continue
            fo = frames[t + s]
            depth, color, present = fo.depth.clone(), fo.color.clone(), fo.present.clone()
            depth[cam], color[cam], present[cam] = ft.depth[cam], ft.color[cam], True
            keep = [cam] + [j for j in others if bool(fo.present[j])]
            if len(keep) < 2:
                continue
            fr = Frame(index=t, camera_ids=fo.camera_ids, color=color, depth=depth, present=present).subset(keep)
            S = pair_agreement(fr, rig.subset(keep), tau=0.02)
            row = S[0, 1:]
            if np.isfinite(row).any():
                scores[t, k] = np.nanmean(row)
    return scores


def test_late_camera_offset_found_from_pair_agreement(converted):
    """The sync check's core (pipeline.sync.estimate_frame_offset) on agreements computed with
    fuseflow.geometry.pair_agreement: cam03 is +2 frames (400 ms) late, cam00 is in sync."""
    _, out, _, true_rig = converted
    rec = open_recording(out)
    rig = rec.rig.with_extrinsics({c.id: c.T_cam_world for c in true_rig.cameras})
    frames = [rec[t] for t in range(len(rec))]
    shifts = [-3, -2, -1, 0, 1]
    late = estimate_frame_offset(_shifted_scores(frames, rig, 3, [0, 1, 2], shifts), shifts, period_s=1 / FPS)
    assert late.frames == LATE and late.ms == pytest.approx(400.0) and late.consistency >= 0.6
    ok = estimate_frame_offset(_shifted_scores(frames, rig, 0, [1, 2], shifts), shifts, period_s=1 / FPS)
    assert ok.frames == 0


def test_desync_shifts_a_simulated_camera(sim, tmp_path):
    import shutil

    rec = tmp_path / "d"
    shutil.copytree(sim, rec)
    assert apply_desync(rec, "3:2") == {"cam03": 2}
    assert (rec / "cam03/color/000004.png").read_bytes() == (sim / "cam03/color/000002.png").read_bytes()
    assert (rec / "gt/cam03/depth/000009.png").read_bytes() == (sim / "gt/cam03/depth/000007.png").read_bytes()
    assert open_recording(rec).missing_views() == {"cam03": [0, 1]}
    assert json.loads((rec / "gt.json").read_text())["desync"] == {"cam03": 2}
    assert read_rig(rec).ids == read_rig(sim).ids
    with pytest.raises(ValidationError, match="CAM:FRAMES"):
        parse_desync("cam03")
    with pytest.raises(ValidationError, match="unknown camera 'cam09'"):
        parse_desync("cam09:1", ("cam00", "cam01"))


def test_simulate_cli_desync(tmp_path):
    out = tmp_path / "s"
    res = runner.invoke(app, ["simulate", str(out), "--cameras", "2", "--num-frames", "4", "--resolution", "48x36",
                              "--desync", "cam01:-1"])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "desync {'cam01': -1}" in res.output
    assert open_recording(out).missing_views() == {"cam01": [3]}
    bad = runner.invoke(app, ["simulate", str(tmp_path / "b"), "--desync", "x"])
    assert bad.exit_code == 2 and "CAM:FRAMES" in bad.output


def test_converted_frames_carry_the_device_timestamps(converted):
    """Frame.timestamp of a converted recording is a device timestamp from timestamps.json (the
    first present view's, in rig order); a frame where cam00 is dropped takes the next camera's."""
    _, out, stamps, _ = converted
    rec = open_recording(out)
    for t in (0, 5, FRAMES - 1):
        assert rec[t].timestamp == pytest.approx(stamps["cam00"][t] / 1e9, abs=1e-9)
    last = rec[FRAMES + LATE - 1]  # only cam03 has a view here
    assert last.timestamp == pytest.approx(stamps["cam03"][-1] / 1e9, abs=1e-9)
