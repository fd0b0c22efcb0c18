"""Broken input recordings: each fault kind is built from the simulator in a temporary
directory, run through the CLI (or the Python API where a file cannot carry the fault), and
checked for the exit code, no traceback, and the words that name the file or camera at fault.
docs/reliability.md lists each case with what the tool does."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

import fuseflow
from fuseflow.io import read_calibration, write_calibration
from fuseflow.types import Calibration

CAMS = ("cam00", "cam01", "cam02")


def copy_rec(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def _png(rec: Path, cam: str = "cam01", kind: str = "depth", frame: int = 0) -> Path:
    return rec / cam / kind / f"{frame:06d}.png"


def _edit_rig(rec: Path, edit) -> None:
    doc = json.loads((rec / "rig.json").read_text())
    edit(doc)
    (rec / "rig.json").write_text(json.dumps(doc))


# --------------------------------------------------------------------------- unreadable files

H, W = 120, 160


def _truncate(p: Path) -> None:
    p.write_bytes(p.read_bytes()[:200])


def _truncate_tail(p: Path) -> None:  # decodes to a part-grey image: only the end marker tells
    p.write_bytes(p.read_bytes()[:-20])


FILE_FAULTS = {
    # kind: (break the recording, file named, words)
    "truncated depth png": (lambda r: _truncate(_png(r)), "cam01/depth/000000.png", "not a readable image"),
    "truncated colour png (end cut)": (
        lambda r: _truncate_tail(_png(r, kind="color")),
        "cam01/color/000000.png",
        "truncated",
    ),
    "corrupt depth png (random bytes)": (
        lambda r: _png(r).write_bytes(np.random.default_rng(0).bytes(3000)),
        "cam01/depth/000000.png",
        "not a readable image",
    ),
    "empty colour file": (lambda r: _png(r, kind="color").write_bytes(b""), "cam01/color/000000.png", "empty"),
    "depth of the wrong size": (
        lambda r: cv2.imwrite(str(_png(r)), np.zeros((H // 2, W // 2), np.uint16)),
        "cam01/depth/000000.png",
        "80x60",
    ),
    "colour / depth size mismatch": (
        lambda r: cv2.imwrite(str(_png(r, kind="color")), np.zeros((H // 2, W // 2, 3), np.uint8)),
        "cam01/color/000000.png",
        "80x60",
    ),
    "8-bit depth png": (
        lambda r: cv2.imwrite(str(_png(r)), np.zeros((H, W), np.uint8)),
        "cam01/depth/000000.png",
        "16-bit",
    ),
}


@pytest.mark.parametrize("kind", list(FILE_FAULTS))
def test_unreadable_file_is_named(small_rec, tmp_path, kind, invoke, expect):
    breaks, name, words = FILE_FAULTS[kind]
    rec = copy_rec(small_rec, tmp_path / "rec")
    breaks(rec)
    expect(invoke("fuse", rec, "--out", tmp_path / "o"), 2, name, words)
    expect(invoke("run", rec, "--out", tmp_path / "o2", "--use-rig"), 2, name, words)
    # info lists without decoding; --check decodes every file and names each bad one
    expect(invoke("info", rec), 0, "cam01")
    res = invoke("info", rec, "--check")
    expect(res, 1, name, "1 unreadable file")


def test_info_check_names_every_bad_file_and_passes_a_good_recording(small_rec, tmp_path, invoke, expect):
    expect(invoke("info", small_rec, "--check"), 0, "every colour and depth file decodes")
    rec = copy_rec(small_rec, tmp_path / "rec")
    _truncate(_png(rec, "cam00", "color", 1))
    _truncate(_png(rec, "cam02", "depth", 0))
    expect(invoke("info", rec, "--check"), 1, "cam00/color/000001.png", "cam02/depth/000000.png", "2 unreadable")
    doc = json.loads(invoke("info", rec, "--check", "--json").stdout)
    assert doc["check"]["ok"] is False and len(doc["check"]["problems"]) == 2


def test_two_colour_files_for_one_view(small_rec, tmp_path, invoke, expect):
    rec = copy_rec(small_rec, tmp_path / "rec")
    cv2.imwrite(str(rec / "cam01" / "color" / "000000.jpg"), np.zeros((H, W, 3), np.uint8))
    for args in (("info",), ("info", "--check"), ("fuse", "--out", tmp_path / "o")):
        expect(invoke(args[0], rec, *args[1:]), 2, "cam01", "000000.jpg", "000000.png", "frame 0")


# --------------------------------------------------------------------------- bad rig.json values


def _set(cam: int, key: str, value):
    def edit(doc):
        doc["cameras"][cam][key] = value

    return edit


def _set_K(cam: int, row: int, col: int, value: float):
    def edit(doc):
        doc["cameras"][cam]["K"][row][col] = value

    return edit


def _nonrigid(doc):
    doc["cameras"][1]["T_cam_world"][0][0] = 2.0


RIG_FAULTS = {
    "principal point far outside the image": (_set_K(1, 0, 2, 5000.0), ("'cam01'", "principal point", "160x120")),
    "negative principal point": (_set_K(1, 1, 2, -40.0), ("'cam01'", "principal point")),
    "focal length for another resolution (fov 1 deg)": (_set_K(1, 0, 0, 9000.0), ("'cam01'", "field of view")),
    "focal length in mm (fov 179 deg)": (_set_K(1, 0, 0, 1.9), ("'cam01'", "field of view")),
    "camera id '..'": (_set(1, "id", ".."), ("'..'", "plain name")),
    "camera id with a slash": (_set(1, "id", "a/b"), ("'a/b'", "plain name")),
    "camera id hidden (leading dot)": (_set(1, "id", ".cam01"), ("'.cam01'", "plain name")),
    "empty camera id": (_set(1, "id", ""), ("cameras[1]", "'id'")),
    "non-rigid extrinsics": (_nonrigid, ("'cam01'", "not a rigid transform")),
    "K not 3x3": (_set(1, "K", [[1, 2], [3, 4]]), ("'cam01'", "3x3")),
}


@pytest.mark.parametrize("kind", list(RIG_FAULTS))
def test_bad_rig_json_value_is_named(small_rec, tmp_path, kind, invoke, expect):
    edit, words = RIG_FAULTS[kind]
    rec = copy_rec(small_rec, tmp_path / "rec")
    _edit_rig(rec, edit)
    expect(invoke("info", rec), 2, "rig.json", *words)
    expect(invoke("fuse", rec, "--out", tmp_path / "o"), 2, *words)
    assert not (tmp_path / "o").exists()


def test_camera_id_dotdot_never_reads_the_parent_folder(small_rec, tmp_path, invoke, expect):
    # the parent of the recording holds a "color"/"depth" layout: '..' would have read it
    rec = copy_rec(small_rec, tmp_path / "rec")
    shutil.copytree(rec / "cam01" / "color", tmp_path / "color")
    shutil.copytree(rec / "cam01" / "depth", tmp_path / "depth")
    _edit_rig(rec, _set(1, "id", ".."))
    expect(invoke("run", rec, "--out", tmp_path / "o", "--use-rig"), 2, "'..'", "plain name")


# --------------------------------------------------------------------------- calibration of another rig


def test_calibration_of_another_rig_is_refused(small_rec, tmp_path, invoke, expect, make_recording):
    other = make_recording(tmp_path / "other", cameras=3, frames=1, resolution=(128, 96), seed=7)
    other_rig = fuseflow.read_rig(other)
    # same ids, another rig: its extrinsics in its own world frame, its intrinsics in the fingerprint
    write_calibration(tmp_path / "c.json", Calibration({c.id: c.T_cam_world for c in other_rig}, {}), rig=other_rig)
    for cmd in ("fuse", "run"):
        res = invoke(cmd, small_rec, "--out", tmp_path / cmd, "--calib", tmp_path / "c.json")
        expect(res, 2, "another rig", "cam00", "cam01", "cam02", "128x96")
    # the same calibration written for this rig is accepted; files without a fingerprint still read
    rig = fuseflow.read_rig(small_rec)
    write_calibration(tmp_path / "same.json", Calibration({c.id: c.T_cam_world for c in rig}, {}), rig=rig)
    assert read_calibration(tmp_path / "same.json").report["rig_fingerprint"]["cam01"]["width"] == 160
    expect(invoke("fuse", small_rec, "--out", tmp_path / "ok", "--calib", tmp_path / "same.json"), 0)
    # run and fuse record the fingerprint of the recording's rig in the calib.json they write
    expect(invoke("run", small_rec, "--out", tmp_path / "r", "--use-rig", "--frames", "0:1"), 0)
    fp = json.loads((tmp_path / "r" / "calib.json").read_text())["rig_fingerprint"]
    assert sorted(fp) == list(CAMS) and fp["cam00"]["K"] == rig["cam00"].K.tolist()
    assert "rig_fingerprint" in json.loads((tmp_path / "ok" / "calib.json").read_text())


def test_calibration_fingerprint_names_the_camera_whose_intrinsics_differ(small_rec, tmp_path):
    from fuseflow.pipeline import placed_rig

    rig = fuseflow.read_rig(small_rec)
    cal = Calibration({c.id: c.T_cam_world for c in rig}, {})
    write_calibration(tmp_path / "c.json", cal, rig=rig)
    doc = json.loads((tmp_path / "c.json").read_text())
    doc["rig_fingerprint"]["cam02"]["K"][0][0] *= 1.2  # another lens on cam02 only
    (tmp_path / "c.json").write_text(json.dumps(doc))
    with pytest.raises(fuseflow.FuseFlowError, match=r"cam02 \(fx") as e:
        placed_rig(rig, read_calibration(tmp_path / "c.json"))
    assert "cam00" not in str(e.value) and "cam01" not in str(e.value)
    doc["rig_fingerprint"]["cam02"]["K"][0][0] /= 1.2 * 1.001  # refined by 0.1 %: still this rig
    (tmp_path / "c.json").write_text(json.dumps(doc))
    assert len(placed_rig(rig, read_calibration(tmp_path / "c.json"))) == 3


# --------------------------------------------------------------------------- degraded, not failed


def _zero_depth(rec: Path, cam: str = "cam01", frame: int = 0) -> None:
    cv2.imwrite(str(_png(rec, cam, "depth", frame)), np.zeros((H, W), np.uint16))


def _drop_view(rec: Path, cam: str = "cam02", frame: int = 1) -> None:
    _png(rec, cam, "color", frame).unlink()
    _png(rec, cam, "depth", frame).unlink()


DEGRADED = {
    # kind: (break, fuse's words, run's words)
    "all-zero depth in one view": (
        _zero_depth,
        ("no valid depth", "cam01", "at frames 0"),
        ("camera cam01 had no valid depth", "in 1 frames: 0"),
    ),
    "all-zero depth in every view": (
        lambda r: [_zero_depth(r, c) for c in CAMS],
        ("no valid depth", "cam00", "cam02", "at frames 0"),
        ("camera cam00 had no valid depth", "camera cam02 had no valid depth"),
    ),
    "missing view file (depth only)": (
        lambda r: _png(r, "cam01", "depth", 0).unlink(),
        ("views missing", "cam01", "at frames 0"),
        ("cam01", "missing in 1 frames"),
    ),
    "dropout mid-stream": (_drop_view, ("views missing", "cam02", "at frames 1"), ("cam02", "missing in 1 frames")),
}


@pytest.mark.parametrize("kind", list(DEGRADED))
def test_degraded_input_is_fused_with_a_specific_warning(small_rec, tmp_path, kind, invoke, expect):
    breaks, fuse_words, run_words = DEGRADED[kind]
    rec = copy_rec(small_rec, tmp_path / "rec")
    breaks(rec)
    expect(invoke("fuse", rec, "--out", tmp_path / "f"), 0, "points per frame", *fuse_words)
    summary = json.loads((tmp_path / "f" / "summary.json").read_text())
    assert any(fuse_words[0] in w for w in summary["warnings"])
    expect(invoke("run", rec, "--out", tmp_path / "r", "--use-rig"), 0, *run_words)


def test_nan_inf_negative_depth_are_no_measurement(small_rec):
    from fuseflow.io.images import clean_depth

    rec = fuseflow.open_recording(small_rec)
    f = rec[0]
    bad, zero = f.depth.clone(), f.depth.clone()
    bad[1, :10], bad[1, 10:20], bad[1, 20:30] = float("nan"), float("inf"), -1.0
    zero[1, :30] = 0.0
    # readers zero them at the input boundary and count them
    cleaned, n = clean_depth(bad[1].numpy())
    assert n == 30 * W and np.array_equal(cleaned, zero[1].numpy())
    # a Frame built in Python with them fuses exactly as with no measurement there
    a = fuseflow.fuse(fuseflow.Frame(f.index, f.camera_ids, f.color, bad, f.present), rec.rig)
    b = fuseflow.fuse(fuseflow.Frame(f.index, f.camera_ids, f.color, zero, f.present), rec.rig)
    assert len(a) > 0 and np.isfinite(a.xyz).all() and np.array_equal(a.xyz, b.xyz)  # numpy: a CPU frame


@pytest.mark.parametrize(
    "what, make, words",
    [
        (
            "depth (N, H, W) of another size",
            lambda f: (f.color[:, :60, :80], f.depth[:, :60, :80]),
            "'cam00' is 160x120",
        ),
        ("colour / depth size mismatch", lambda f: (f.color[:, :60, :80], f.depth), "frame color: expected shape"),
        ("colour without channels", lambda f: (f.color[..., 0], f.depth), "frame color"),
        ("one view short", lambda f: (f.color[:2], f.depth[:2]), r"expected shape \(3"),
        ("depth as float64", lambda f: (f.color, f.depth.double()), "float32"),
    ],
)
def test_wrong_shapes_through_the_api(small_rec, what, make, words):
    rec = fuseflow.open_recording(small_rec)
    f = rec[0]
    color, depth = make(f)
    with pytest.raises(fuseflow.ValidationError, match=words):
        fuseflow.fuse(fuseflow.Frame(f.index, f.camera_ids, color, depth, f.present), rec.rig)


def test_one_camera(tmp_path, invoke, expect, make_recording):
    rec = make_recording(tmp_path / "one", cameras=1, frames=1)
    expect(invoke("fuse", rec, "--out", tmp_path / "o"), 0, "points per frame")
    expect(invoke("calibrate", rec, "--out", tmp_path / "c.json"), 2, "at least two cameras", "got 1")


def test_no_overlap(small_rec, tmp_path, invoke, expect):
    rec = copy_rec(small_rec, tmp_path / "rec")

    def turn_away(doc):  # cam01 rotated 180 degrees about its y axis: it sees the other way
        T = np.array(doc["cameras"][1]["T_cam_world"])
        doc["cameras"][1]["T_cam_world"] = (np.diag([-1.0, 1, -1, 1]) @ T).tolist()

    _edit_rig(rec, turn_away)
    expect(invoke("fuse", rec, "--out", tmp_path / "o"), 0, "no overlapping neighbour", "cam01")


def test_textureless_scene(small_rec, tmp_path, invoke, expect):
    rec = copy_rec(small_rec, tmp_path / "rec")
    for c in CAMS:
        for p in (rec / c / "color").glob("*.png"):
            cv2.imwrite(str(p), np.full((H, W, 3), 128, np.uint8))
    expect(invoke("calibrate", rec, "--out", tmp_path / "c.json"), 2)
    expect(invoke("fuse", rec, "--out", tmp_path / "o"), 0, "points per frame")


def test_calibrate_on_a_frame_with_every_view_dropped(small_rec, tmp_path, invoke, expect):
    rec = copy_rec(small_rec, tmp_path / "rec")
    for c in CAMS:  # colour kept, depth gone: frame 0 still exists, with no view present
        _png(rec, c, "depth", 0).unlink()
    expect(
        invoke("calibrate", rec, "--out", tmp_path / "c.json", "--frame", "0"),
        2,
        "frame 0 has no view present",
        "cam00, cam01, cam02",
    )


def test_64_cameras(tmp_path, invoke, expect, make_recording):
    rec = make_recording(tmp_path / "big", cameras=64, frames=1, resolution=(32, 24))
    expect(invoke("info", rec, "--check"), 0, "64 cameras")
    expect(invoke("fuse", rec, "--out", tmp_path / "o"), 0, "points per frame")
