"""One validation of a fusion's inputs (``pipeline.checks.validate_inputs``) behind `fuse`, `run`,
`live` and the Python API: calibrations in millimetres, depth ranges and settings that empty
every cloud, crops that hold no point, exchanged cameras; and the API as careful as the CLI."""

from __future__ import annotations

import json
import shutil
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

import fuseflow
from fuseflow.io import open_recording, write_calibration
from fuseflow.types import Calibration


def _calib(rec: Path, path: Path, edit, report=None) -> Path:
    """calib.json of ``rec``'s true extrinsics after ``edit`` (a calib.json from another tool:
    no depth-agreement report)."""
    rig = open_recording(rec).rig
    T = edit({c.id: np.array(c.T_cam_world) for c in rig})
    write_calibration(path, Calibration(T, report or {"source": "another tool"}), rig=rig)
    return path


def _mm(T):
    for v in T.values():
        v[:3, 3] *= 1000.0
    return T


def _swap(T):
    T["cam01"], T["cam02"] = T["cam02"], T["cam01"]
    return T


def _rig_edit(src: Path, dst: Path, depth_range) -> Path:
    shutil.copytree(src, dst)
    doc = json.loads((dst / "rig.json").read_text())
    for cam in doc["cameras"]:
        cam["depth_range"] = depth_range
    (dst / "rig.json").write_text(json.dumps(doc))
    return dst


def _live(invoke, rec, *args):
    return invoke("live", rec, "--num-frames", "2", "--rate", "50", *args)


# ------------------------------------------------------------------- fuse / run / live agree


def test_calibration_in_millimetres_is_refused_by_fuse_and_live(small_rec, tmp_path, invoke, expect):
    calib = _calib(small_rec, tmp_path / "mm.json", _mm)
    expect(invoke("fuse", small_rec, "--out", tmp_path / "o", "--calib", calib), 2, "millimetres")
    assert not (tmp_path / "o" / "clouds").exists()
    res = _live(invoke, small_rec, "--calib", calib, "--record", tmp_path / "r")
    expect(res, 2, "millimetres")


@pytest.mark.parametrize("command", ["fuse", "live"])
def test_depth_range_that_excludes_every_pixel_is_refused(small_rec, tmp_path, command, invoke, expect):
    rec = _rig_edit(small_rec, tmp_path / "rec", [0.0, 0.05])
    res = invoke("fuse", rec, "--out", tmp_path / "o") if command == "fuse" else _live(invoke, rec)
    expect(res, 2, "depth_range", "every cloud would be empty")


def test_z_max_setting_that_excludes_every_pixel_is_refused(small_rec, tmp_path, invoke, expect):
    res = invoke("fuse", small_rec, "--out", tmp_path / "o", "--set", "mcm.z_max=0.2")
    expect(res, 2, "0.1-0.2 m", "every cloud would be empty")


@pytest.mark.parametrize("setting", ["eps=1e308", "mcm.alpha=1e308", "mcm.beta=inf", "ash.s0=nan"])
@pytest.mark.parametrize("command", ["fuse", "run"])
def test_setting_that_overflows_float32_is_refused(small_rec, tmp_path, setting, command, invoke, expect):
    extra = ["--use-rig"] if command == "run" else []
    res = invoke(command, small_rec, "--out", tmp_path / "o", "--set", setting, *extra)
    expect(res, 2, setting.split("=")[0], "float32")


def test_settings_overflow_is_refused_through_the_api():
    from fuseflow.fuse import FuseConfig

    for change in ({"eps": 1e308}, {"mcm": {"alpha": 1e308}}):
        with pytest.raises(fuseflow.ValidationError, match="float32"):
            FuseConfig().replace(**change)


@pytest.mark.parametrize("command", ["fuse", "run", "live"])
def test_crop_that_holds_no_point_is_refused(small_rec, tmp_path, command, invoke, expect):
    box = "100,100,100,101,101,101"
    if command == "live":
        res = _live(invoke, small_rec, "--crop", box)
    else:
        extra = ["--use-rig"] if command == "run" else []
        res = invoke(command, small_rec, "--out", tmp_path / "o", "--crop", box, *extra)
    expect(res, 2, "holds none of the", "every cloud would be empty")


def test_edited_capture_volume_that_holds_no_point_is_refused(small_rec, tmp_path, invoke, expect):
    calib = _calib(small_rec, tmp_path / "c.json", lambda T: T)
    doc = json.loads(calib.read_text())
    doc["capture_volume"] = {"min": [50, 50, 50], "max": [60, 60, 60]}
    calib.write_text(json.dumps(doc))
    res = invoke("fuse", small_rec, "--out", tmp_path / "o", "--calib", calib, "--crop", "auto")
    expect(res, 2, "holds none of the")


def test_capture_volume_in_millimetres_is_read_as_millimetres(small_rec, tmp_path, invoke, expect):
    from fuseflow.geometry.volume import CaptureVolume

    v = CaptureVolume.from_json({"min": [-1800, -1800, -100], "max": [1800, 1800, 2000], "units": "mm"})
    assert np.allclose(v.lo, [-1.8, -1.8, -0.1]) and np.allclose(v.hi, [1.8, 1.8, 2.0])
    with pytest.raises(fuseflow.ValidationError, match="units"):
        CaptureVolume.from_json({"min": [0, 0, 0], "max": [1, 1, 1], "units": "ft"})
    # end to end: a box of the whole room in mm keeps points (read as metres it would be 3.6 km wide)
    calib = _calib(small_rec, tmp_path / "c.json", lambda T: T)
    doc = json.loads(calib.read_text())
    doc["capture_volume"] = {"min": [-5000, -5000, -5000], "max": [5000, 5000, 5000], "units": "mm"}
    calib.write_text(json.dumps(doc))
    res = invoke("fuse", small_rec, "--out", tmp_path / "o", "--calib", calib, "--crop", "auto")
    expect(res, 0)
    written = json.loads((tmp_path / "o" / "calib.json").read_text())["capture_volume"]
    assert written["units"] == "m" and written["max"] == [5.0, 5.0, 5.0]


@pytest.mark.parametrize("command", ["fuse", "run", "live"])
def test_exchanged_cameras_without_a_report_are_named(small_rec, tmp_path, command, invoke, expect):
    """A calib.json from another tool (no depth-agreement report) with cam01 and cam02 exchanged,
    on a symmetric 3-camera ring where every camera still agrees 0.5-0.6 (above LOW_AGREEMENT):
    the exchange test names the two cameras; the right extrinsics give no such line."""
    bad = _calib(small_rec, tmp_path / "swapped.json", _swap)
    good = _calib(small_rec, tmp_path / "right.json", lambda T: T)
    for calib, swapped in ((bad, True), (good, False)):
        out = tmp_path / f"o-{swapped}"
        if command == "live":
            res = _live(invoke, small_rec, "--calib", calib)
        else:
            res = invoke(command, small_rec, "--out", out, "--calib", calib)
        expect(res, 0)
        flat = " ".join(res.output.split())
        if swapped:
            assert "cameras cam01 and cam02 look exchanged" in flat, res.output
        else:
            assert "look exchanged" not in flat, res.output


def test_exchange_test_holds_on_larger_rigs(tmp_path, make_recording):
    """6 cameras (all pairs tested) and 12 (the pairs among the 6 that agree least)."""
    from fuseflow.fuse import PRESETS
    from fuseflow.pipeline.checks import validate_inputs

    for n in (6, 12):
        rec = open_recording(make_recording(tmp_path / f"r{n}", cameras=n, frames=1))
        ids = rec.rig.ids
        assert validate_inputs(rec[0], rec.rig, PRESETS["auto"]) == []
        T = {c.id: c.T_cam_world for c in rec.rig}
        T[ids[0]], T[ids[3]] = T[ids[3]], T[ids[0]]
        found = validate_inputs(rec[0], rec.rig.with_extrinsics(T), PRESETS["auto"])
        assert any(f"cameras {ids[0]} and {ids[3]} look exchanged" in w for w in found), (n, found)


def test_tiny_views_give_no_false_calibration_alarm(tmp_path, invoke, expect, make_recording):
    """32 cameras at 32x24 with their true extrinsics: agreement is low at any extrinsics there
    (0.39-0.64), so the absolute check says it was not made instead of "does not fit"."""
    rec = make_recording(tmp_path / "r", cameras=32, frames=2, resolution=(32, 24))
    res = invoke("run", rec, "--out", tmp_path / "o", "--use-rig", "--sync-offsets", "off")
    expect(res, 0, "was not made")
    assert "does not fit" not in " ".join(res.output.split())


# ------------------------------------------------------------------------------ the Python API


def test_api_fuse_defaults_to_auto_and_returns_numpy(small_rec):
    from fuseflow.fuse import PRESETS, fuse_with_report

    rec = open_recording(small_rec)
    cloud = fuseflow.fuse(rec[0], rec.rig)
    assert isinstance(cloud.xyz, np.ndarray) and cloud.xyz.dtype == np.float32
    auto = fuse_with_report(rec[0], rec.rig, PRESETS["auto"]).cloud
    assert len(cloud) == len(auto)
    clouds = list(fuseflow.stream(rec, rec.rig))
    assert [len(c) for c in clouds[:1]] == [len(cloud)] and isinstance(clouds[0].xyz, np.ndarray)


def test_api_fuse_and_stream_warn_when_they_fuse_fewer_cameras(small_rec):
    rec = open_recording(small_rec)
    bare = fuseflow.Rig(tuple(c.with_extrinsics(None) for c in rec.rig))
    calib = Calibration({c: rec.rig[c].T_cam_world for c in ("cam00", "cam01")})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cloud = fuseflow.fuse(rec[0], calib.apply(bare))  # cam02 has no extrinsics: left out
        clouds = list(fuseflow.stream(rec, calib))
    lines = [str(w.message) for w in caught]
    assert len(cloud) > 0 and set(np.unique(cloud.camera).tolist()) == {0, 1}
    assert len(clouds) == 2
    assert any("['cam02']" in w and "2 of 3" in w for w in lines), lines
    assert any("does not place cameras ['cam02']" in w for w in lines), lines


def test_api_stream_runs_the_shared_checks(small_rec, tmp_path):
    rec = open_recording(small_rec)
    T = _swap({c.id: np.array(c.T_cam_world) for c in rec.rig})
    with pytest.warns(UserWarning, match="cam01 and cam02 look exchanged"):
        next(iter(fuseflow.stream(rec, Calibration(T))))
    with pytest.raises(fuseflow.ValidationError, match="millimetres"):
        next(iter(fuseflow.stream(rec, Calibration(_mm({c.id: np.array(c.T_cam_world) for c in rec.rig})))))


def test_calibration_repr_fits_a_few_lines():
    T = {f"cam{i:02d}": np.eye(4) for i in range(12)}
    report = {
        "source": "GMAC",
        "camera_verdicts": {c: {"verdict": "good" if i else "check it"} for i, c in enumerate(T)},
        "warnings": ["one", "two"],
        "big": list(range(20000)),
    }
    text = repr(Calibration(T, report))
    assert len(text.splitlines()) <= 3 and len(text) < 400, text
    assert "12 cameras" in text and "11 good" in text and "1 check it" in text and "2 warnings" in text


# ---------------------------------------------------------------------------- runs and files


def test_finished_run_asked_again_skips_the_checks(small_rec, tmp_path, invoke, expect, monkeypatch):
    """A rerun with nothing to fuse neither reads frames for the checks nor runs the sync check;
    a check-only option (--sync-offsets off / check) is the same run."""
    out = tmp_path / "o"
    expect(invoke("run", small_rec, "--out", out, "--use-rig"), 0, "2 fused now")
    import fuseflow.pipeline.runner as runner
    import fuseflow.pipeline.sync as sync

    def boom(*a, **k):
        raise AssertionError("checked again with nothing to do")

    monkeypatch.setattr(sync, "check_sync", boom)
    monkeypatch.setattr(runner, "_check_inputs", boom)
    t0 = time.perf_counter()
    expect(invoke("run", small_rec, "--out", out, "--use-rig"), 0, "nothing to do")
    assert time.perf_counter() - t0 < 10
    expect(invoke("run", small_rec, "--out", out, "--use-rig", "--sync-offsets", "off"), 0, "nothing to do")


def test_interrupt_inside_a_compiled_kernel_exits_130(small_rec, tmp_path, invoke, expect, monkeypatch):
    """numba reports Ctrl-C inside a kernel as SystemError("... returned a result with an
    exception set") chained to the KeyboardInterrupt: the same clean exit 130 as elsewhere."""
    import sys

    fuse_pkg = sys.modules["fuseflow.fuse"]  # fuseflow.fuse is the function

    def interrupted(*a, **k):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise SystemError("CPUDispatcher(<function cells>) returned a result with an exception set") from exc

    monkeypatch.setattr(fuse_pkg, "fuse_with_report", interrupted)
    res = invoke("run", small_rec, "--out", tmp_path / "o", "--use-rig", "--sync-offsets", "off")
    expect(res, 130, "interrupted")


def test_force_keeps_files_it_did_not_write(small_rec, tmp_path, invoke, expect):
    out = tmp_path / "o"
    expect(invoke("fuse", small_rec, "--out", out), 0)
    mine = out / "clouds" / "notes.txt"
    mine.write_text("a user's file")
    expect(invoke("fuse", small_rec, "--out", out, "--preset", "live", "--force"), 0)
    assert mine.read_text() == "a user's file"
    assert sorted(p.name for p in (out / "clouds").glob("*.ply")) == ["000000.ply", "000001.ply"]


def test_calibrate_names_the_picture_it_replaces_and_hints_at_millimetres(tmp_path, invoke, expect, make_recording):
    rec = tmp_path / "rec"
    from fuseflow.synth import SimConfig, simulate_recording

    simulate_recording(rec, SimConfig(cameras=3, frames=1, scene="room", resolution=(320, 240), seed=2))
    ref = _calib(rec, tmp_path / "ref-mm.json", _mm)
    out = tmp_path / "c.json"
    (tmp_path / "c.png").write_bytes(b"a picture the user made")
    res = invoke("calibrate", rec, "--out", out, "--backbone", "rgbd", "--reference", ref)
    expect(res, 0, "replaced the picture", "millimetres", "divide its translations by 1000")


def test_fuse_table_merges_grid_choices():
    from fuseflow.pipeline.fuse_only import _Fused

    done = _Fused()
    for gap in (13.8, 13.9, 14.1):
        done.add_grid(f"auto: stride 2, s0 1 (8 views, 2.41 M valid depth pixels; within {gap} mm)")
    done.add_grid("auto: stride 1, s0 1.5 (8 views, 0.5 M valid depth pixels: every pixel counts)")
    lines = done.grid_lines()
    assert len(lines) == 2 and lines[0].startswith("auto: stride 2, s0 1 in 3 frames (first: 8 views"), lines


# -------------------------------------------------------------------------------------- pictures


def test_camera_labels_are_not_cut_to_a_shared_tail():
    from fuseflow.viz.render import camera_labels

    serials = ["105322251564", "113522250549", "117222250549", "cam01"]
    labels = camera_labels(serials)
    assert len(set(labels.values())) == 4 and labels["cam01"] == "cam01"
    assert labels["113522250549"] != labels["117222250549"]


def test_weight_picture_spreads_its_colour_scale_and_says_what_it_shows(tmp_path):
    """Fusion weights crowd near 1: drawn on a 0-1 scale nearly every point is the same red."""
    import cv2

    from fuseflow.viz import save_cloud_png
    from fuseflow.viz.render import weight_colors

    g = np.linspace(-0.5, 0.5, 120)
    x, y = np.meshgrid(g, g)
    xyz = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1)
    w = np.linspace(0.9, 1.0, len(xyz))
    cloud = fuseflow.FusedCloud.from_numpy(xyz, np.full_like(xyz, 128), w, np.zeros(len(xyz)))
    png = save_cloud_png(tmp_path / "w.png", cloud, color_by="weight", width=400, height=300)
    img = cv2.imread(str(png))[20:-60, 60:-110]  # the cloud, without the bar, gizmo and captions
    inked = img[np.abs(img.astype(int) - img[0, 0].astype(int)).sum(-1) > 30].tolist()  # not the background
    top = {tuple(c) for c in weight_colors(np.linspace(0.9, 1.0, 1000))[:, ::-1].tolist()}  # 0-1 scale's red end
    share = sum(tuple(c) in top for c in inked) / max(len(inked), 1)
    assert len(inked) > 5000 and share < 0.3, f"{share:.0%} of the cloud in the red end of a 0-1 scale"
    from fuseflow.viz.render import weight_caption, weight_range

    lo, hi = weight_range(w)
    assert 0.9 <= lo < 0.91 and 0.99 < hi <= 1.0
    assert "fusion weight" in weight_caption((lo, hi)) and f"{lo:.2f}" in weight_caption((lo, hi))


def test_setup_script_waits_for_the_apt_lock_and_says_so(tmp_path):
    """Every apt-get of scripts/setup.sh goes through apt_get, which passes DPkg::Lock::Timeout
    (exit 100 at once when another package manager holds the lock, otherwise)."""
    import subprocess

    script = (Path(__file__).resolve().parents[2] / "scripts" / "setup.sh").read_text()
    calls = [ln for ln in script.splitlines() if "apt-get" in ln and not ln.lstrip().startswith(("#", "echo"))]
    assert calls and all("DPkg::Lock::Timeout" in ln for ln in calls), calls
    fake = tmp_path / "bin"
    fake.mkdir()
    (fake / "apt-get").write_text('#!/bin/sh\necho "apt-get $*"\n')
    (fake / "apt-get").chmod(0o755)
    func = script[script.index("APT_LOCK_WAIT=") : script.index("\n}\n") + 3]
    res = subprocess.run(["bash", "-c", f"SUDO=''\n{func}\napt_get update"], capture_output=True, text=True,
                         env={"PATH": f"{fake}:/usr/bin:/bin"})  # fmt: skip
    assert "apt-get -o DPkg::Lock::Timeout=600 update" in res.stdout and "waits up to 600 s" in res.stderr


@pytest.mark.parametrize("command", ["fuse", "live"])
def test_permuted_extrinsics_are_named_by_fuse_and_live(tmp_path, command, invoke, expect, make_recording):
    """Six cameras in reverse order: `run` names them after fusing (probe); `fuse` and `live` on
    the first frame, with the same words."""
    rec = make_recording(tmp_path / "rec6", cameras=6, frames=1)
    calib = _calib(rec, tmp_path / "c.json", lambda T: dict(zip(T, list(T.values())[::-1])))
    if command == "live":
        res = invoke("live", rec, "--num-frames", "1", "--rate", "50", "--calib", calib)
    else:
        res = invoke("fuse", rec, "--out", tmp_path / "o", "--calib", calib)
    expect(res, 0, "disagrees with their neighbours", "does not fit this recording")
