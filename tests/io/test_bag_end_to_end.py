"""End to end: a simulated 4-camera recording written as four RealSense .bag files,
one camera 2 frames late, converts (`fuseflow convert`), calibrates (`fuseflow calibrate`) and
runs (`fuseflow run --sync-offsets auto`) with the late camera found and corrected.

Small and deterministic: the room scene (textured enough to calibrate) at 320x240, 12 frames at 5 fps (the walker moves ~16 cm a frame, well above
depth noise; the sync check does not yet resolve the ~3 cm a frame of 30 fps at this size, see
docs/formats.md "Camera-sync check")."""

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
from fuseflow.io import open_recording  # noqa: E402
from fuseflow.io.images import read_color, read_depth_raw  # noqa: E402
from fuseflow.synth import SimConfig, simulate_recording  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from recording_writers import write_realsense_bag  # noqa: E402

runner = CliRunner()
FPS, FRAMES, LATE, LATE_CAM = 5.0, 12, 2, "cam03"


@pytest.fixture(scope="module")
def bags(tmp_path_factory) -> Path:
    """Four bags of a dynamic studio; cam03's frames are those of 2 frames earlier (its view of
    instant k carries the stamp of k + 2), as a camera 2 frames late records them."""
    sim = tmp_path_factory.mktemp("e2e") / "sim"
    simulate_recording(sim, SimConfig(cameras=4, frames=FRAMES, scene="room", dynamic=True, resolution=(320, 240),
                                      seed=2, fps=FPS))  # fmt: skip
    rig = open_recording(sim).rig
    out = tmp_path_factory.mktemp("e2e_bags")
    base_ns = 50_000_000_000
    for cam in rig.cameras:
        color = np.stack([read_color(sim / cam.id / "color" / f"{t:06d}.png") for t in range(FRAMES)])
        depth = np.stack([read_depth_raw(sim / cam.id / "depth" / f"{t:06d}.png") for t in range(FRAMES)])
        k = np.arange(FRAMES) + (LATE if cam.id == LATE_CAM else 0)
        ns = base_ns + np.round(k * 1e9 / FPS).astype(np.int64)
        write_realsense_bag(out / f"{cam.id}.bag", cam.id, color, depth, ns / 1e9, cam.K,
                            depth_units=1 / cam.depth_scale)  # fmt: skip
    return out


def _run(rec: Path, out: Path, calib: Path, sync: str) -> tuple[dict, list[dict]]:
    res = runner.invoke(app, ["run", str(rec), "--out", str(out), "--calib", str(calib), "--sync-offsets", sync])
    assert res.exit_code == 0, res.output
    summary = json.loads((out / "summary.json").read_text())
    frames = [json.loads(line) for line in (out / "frames.jsonl").read_text().splitlines() if line.strip()]
    return summary, frames


def _late_cam_agreement(frames: list[dict]) -> float:
    vals = [f["agreement"].get(LATE_CAM) for f in frames]
    vals = [v for v in vals if v is not None]
    return float(np.mean(vals))


def test_four_late_bags_convert_calibrate_and_run_resynced(bags, tmp_path):
    rec = tmp_path / "rec"
    res = runner.invoke(app, ["convert", str(bags), str(rec)])
    assert res.exit_code == 0, res.output
    assert "cam03: 2 views: 2 at the start (its stream starts later" in " ".join(res.output.split())
    assert open_recording(rec).missing_views()[LATE_CAM] == [0, 1]  # paired by time: the late camera starts later

    calib = tmp_path / "calib.json"
    # defaults: frames are pooled where one leaves a camera unchecked
    res = runner.invoke(app, ["calibrate", str(rec), "-o", str(calib)])
    assert res.exit_code == 0, res.output

    checked, checked_frames = _run(rec, tmp_path / "check", calib, "check")
    fixed, fixed_frames = _run(rec, tmp_path / "auto", calib, "auto")
    # found: the late camera and its offset, in frames and in milliseconds (from the bag stamps)
    assert checked["sync_offsets"] == {LATE_CAM: LATE} == fixed["sync_offsets"]
    warning = next(w for w in checked["warnings"] if w.startswith(LATE_CAM))
    assert f"+{LATE} frames late, +{LATE * 1000 / FPS:.0f} ms" in warning
    # corrected: re-timed, the late camera's views agree better with its neighbours'
    before, after = _late_cam_agreement(checked_frames), _late_cam_agreement(fixed_frames)
    assert after > before + 0.02, (before, after)
