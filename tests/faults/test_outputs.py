"""Unusable or used output locations: checked before any work, one line each; a used
output directory resumes only the run that wrote it."""

from __future__ import annotations

import errno
import json
import tempfile

import numpy as np
import pytest

from fuseflow.io import read_calibration, write_calibration
from fuseflow.types import Calibration


def _cmd(kind: str, rec, out):
    return {
        "fuse": ("fuse", rec, "--out", out),
        "run": ("run", rec, "--out", out, "--use-rig"),
        "calibrate": ("calibrate", rec, "--out", out),
        "simulate": ("simulate", out, "--cameras", "2", "--num-frames", "1", "--resolution", "64x48"),
    }[kind]


COMMANDS = ["fuse", "run", "calibrate", "simulate"]


@pytest.mark.parametrize("kind", COMMANDS)
def test_out_is_an_existing_file(small_rec, tmp_path, kind, invoke, expect):
    target = tmp_path / "taken"
    target.write_text("x")
    if kind == "calibrate":  # calibrate writes a file: overwriting one is what --out asks
        target = tmp_path / "dir"
        target.mkdir()
        expect(invoke(*_cmd(kind, small_rec, target)), 2, "is a directory")
        assert not list(tmp_path.glob("dir*.tmp"))
        return
    expect(invoke(*_cmd(kind, small_rec, target)), 2, str(target), "is a file")


@pytest.mark.parametrize("kind", COMMANDS)
def test_out_under_a_file(small_rec, tmp_path, kind, invoke, expect):
    (tmp_path / "f").write_text("x")
    target = tmp_path / "f" / "sub" / ("c.json" if kind == "calibrate" else "o")
    expect(invoke(*_cmd(kind, small_rec, target)), 2, "is a file, not a directory")


@pytest.mark.parametrize("why", [errno.EACCES, errno.EROFS])
@pytest.mark.parametrize("kind", COMMANDS)
def test_out_not_writable(small_rec, tmp_path, kind, why, monkeypatch, invoke, expect):
    # the tests run as root in CI, where chmod does not stop writes: fail the probe file instead
    def refuse(*a, **k):
        raise OSError(why, "refused")

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    target = tmp_path / ("c.json" if kind == "calibrate" else "o")
    words = {errno.EACCES: "no permission", errno.EROFS: "read-only"}[why]
    expect(invoke(*_cmd(kind, small_rec, target)), 2, "cannot write", words)


def test_run_resumes_only_its_own_outputs(small_rec, tmp_path, invoke, expect):
    out = tmp_path / "o"
    expect(invoke("run", small_rec, "--out", out, "--use-rig", "--frames", "0:1"), 0)
    expect(invoke("run", small_rec, "--out", out, "--use-rig"), 0, "1 fused now, 1 resumed")
    # another calibration into the same OUT: refused, says what differs, offers --force
    cal = read_calibration(out / "calib.json")
    moved = {c: T.copy() for c, T in cal.T_cam_world.items()}
    moved["cam01"][0, 3] += 0.05
    write_calibration(tmp_path / "other.json", Calibration(moved, {}))
    res = invoke("run", small_rec, "--out", out, "--calib", tmp_path / "other.json")
    expect(res, 2, "calibration", "--force")
    res = invoke("run", small_rec, "--out", out, "--calib", tmp_path / "other.json", "--force")
    expect(res, 0, "2 fused now, 0 resumed")
    assert json.loads((out / "manifest.json").read_text())["calibration"].startswith("given:")


def test_fuse_refuses_a_used_directory_from_another_recording(small_rec, tmp_path, invoke, expect, make_recording):
    other = make_recording(tmp_path / "other", seed=9)
    out = tmp_path / "o"
    expect(invoke("fuse", small_rec, "--out", out), 0)
    expect(invoke("fuse", other, "--out", out), 2, "recording content", "--force")
    expect(invoke("fuse", small_rec, "--out", out), 0)
    assert json.loads((out / "summary.json").read_text())["frames_resumed"] == 2
    (out / "manifest.json").unlink()  # outputs of an older version: no manifest
    expect(invoke("fuse", small_rec, "--out", out), 2, "no manifest.json", "--force")


@pytest.mark.parametrize("command", ["run", "fuse"])
def test_partial_calibration_is_never_filled_from_rig_json(small_rec, tmp_path, command, invoke, expect):
    from fuseflow.io import open_recording, read_ply

    rig = open_recording(small_rec).rig
    W = np.eye(4)
    W[:3, 3] = [1.0, 0.0, 0.0]  # another world frame: mixing it with rig.json's would be 1 m off
    partial = {c.id: c.T_cam_world @ W for c in rig.cameras[:2]}
    write_calibration(tmp_path / "partial.json", Calibration(partial, {}))
    res = invoke(command, small_rec, "--out", tmp_path / "o", "--calib", tmp_path / "partial.json")
    expect(res, 0, "does not place cameras", "cam02")
    cloud = read_ply(next((tmp_path / "o" / "clouds").glob("*.ply")))
    assert set(cloud.camera.tolist()) <= {0, 1}


def test_interrupted_run_says_how_to_resume(small_rec, tmp_path, monkeypatch, invoke, expect):
    import fuseflow.pipeline.runner as runner

    real = runner.process_frame
    calls = []

    def interrupt_second(*a, **k):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(runner, "process_frame", interrupt_second)
    out = tmp_path / "o"
    expect(invoke("run", small_rec, "--out", out, "--use-rig"), 130, "interrupted", "run the same command again")
    monkeypatch.setattr(runner, "process_frame", real)
    expect(invoke("run", small_rec, "--out", out, "--use-rig"), 0, "1 fused now, 1 resumed")
