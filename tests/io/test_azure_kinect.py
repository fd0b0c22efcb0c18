"""Azure Kinect .mkv files (written here in k4arecorder's Matroska layout) -> FuseFlow recording."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("av")

from fuseflow.errors import FormatError, RecordingError  # noqa: E402
from fuseflow.io import open_recording  # noqa: E402
from fuseflow.io.azure_kinect import AzureKinectMkv  # noqa: E402
from fuseflow.io.convert import convert  # noqa: E402
from fuseflow.io.images import read_color  # noqa: E402
from fuseflow.io.timesync import read_timestamps  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from recording_writers import k4a_calibration_json, write_k4a_mkv  # noqa: E402

T = 3
DEPTH_P = [0.5021, 0.5113, 0.4921, 0.4923] + [0.0] * 10 + [1.7]  # normalised cx, cy, fx, fy, no distortion
COLOR_P = [0.4987, 0.5062, 0.4812, 0.6413] + [0.0] * 10 + [1.7]
ANG = np.deg2rad(6.0)
R_C = np.array([[1, 0, 0], [0, np.cos(ANG), -np.sin(ANG)], [0, np.sin(ANG), np.cos(ANG)]])  # the real device's tilt
T_C = np.array([-0.0320, -0.0020, 0.0038])


def _plane(K, size, n, d, R=np.eye(3), t=np.zeros(3)):
    w, h = size
    nb, db = R @ n, d + (R @ n) @ t
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    return db / (nb[0] * (u - K[0, 2]) / K[0, 0] + nb[1] * (v - K[1, 2]) / K[1, 1] + nb[2])


def _recording(tmp_path: Path, name: str, serial: str | None, calib: bool = True, t0_us: int = 3_000_000):
    rng = np.random.default_rng(len(name))
    color = rng.integers(0, 256, (T, 720, 1280, 4), dtype=np.uint8)
    # depth: a tilted plane in the depth camera (NFOV unbinned, 640x576), millimetres
    Kd = np.array(
        [
            [DEPTH_P[2] * 1024, 0, DEPTH_P[0] * 1024 - 192 - 0.5],
            [0, DEPTH_P[3] * 1024, DEPTH_P[1] * 1024 - 180 - 0.5],
            [0, 0, 1],
        ]
    )
    plane = _plane(Kd, (640, 576), np.array([0.1, -0.2, 1.0]), 1.5)
    depth = np.rint(plane * 1000).astype(np.uint16)[None].repeat(T, 0)
    depth[:, :10] = 0
    stamps = t0_us + np.arange(T) * 33_333 + np.array([0, 7, -5])
    cal = k4a_calibration_json(DEPTH_P, COLOR_P, R_C, T_C) if calib else None
    path = write_k4a_mkv(tmp_path / f"{name}.mkv", color, depth, stamps, "BGRA_720P", "NFOV_UNBINNED", cal, serial)
    return path, color, depth, stamps, Kd


def test_mkv_intrinsics_timestamps_colour_and_raw_depth_round_trip(tmp_path):
    path, color, depth, stamps, Kd = _recording(tmp_path, "k", "000111222333")
    m = AzureKinectMkv(path)
    assert m.id == "000111222333" and (m.width, m.height) == (1280, 720) and m.depth_size == (640, 576)
    # the SDK's mode tables: colour 720p = 1280x960 binned, crop (0, 120); pixel centres at integers
    Kc = np.array(
        [
            [COLOR_P[2] * 1280, 0, COLOR_P[0] * 1280 - 0.5],
            [0, COLOR_P[3] * 960, COLOR_P[1] * 960 - 120 - 0.5],
            [0, 0, 1],
        ]
    )
    assert np.allclose(m.K, Kc, rtol=0, atol=1e-9) and np.allclose(m.K_depth, Kd, rtol=0, atol=1e-9)
    assert np.allclose(m.T_color_depth[:3, :3], R_C) and np.allclose(m.T_color_depth[:3, 3], T_C)
    assert np.array_equal(np.round(m.timestamps * 1e6).astype(np.int64), stamps)
    import av

    with av.open(str(path)) as c:
        pkts = [p for p in c.demux(c.streams.video[1]) if p.size]
    for k, p in enumerate(pkts):  # b16g blocks decode to the millimetres written
        assert np.array_equal(m.depth_raw(bytes(p)), depth[k])
    out = tmp_path / "rec"
    s = convert([path], out)
    assert s.kind == "azure-kinect" and s.frames == T
    rec = open_recording(out)
    assert rec.rig.cameras[0].depth_range == (0.5, 3.86) and np.allclose(rec.rig.cameras[0].K, Kc)
    for t in range(T):
        assert np.array_equal(read_color(out / "000111222333" / "color" / f"{t:06d}.png"), color[t][..., 2::-1])
    ts = read_timestamps(out)
    assert np.array_equal(np.round(ts.view["000111222333"] * 1e6).astype(np.int64), stamps)


def test_mkv_depth_is_transformed_into_the_colour_camera(tmp_path):
    """The depth plane, moved into the colour camera by the calibration's Rt, matches the analytic
    plane there: >= 97 % coverage where the depth camera sees, median error < 1.5 mm."""
    path, *_ = _recording(tmp_path, "p", "1")
    m = AzureKinectMkv(path)
    (_, _, raw), *_ = list(m.views({0}))
    truth = _plane(m.K, (1280, 720), np.array([0.1, -0.2, 1.0]), 1.5, R_C, T_C)
    got = raw.astype(np.float64) / 1000
    # colour pixels whose plane point projects well inside the depth image (columns >= 10 valid)
    v, u = np.mgrid[0:720, 0:1280]
    X = np.stack([(u - m.K[0, 2]) / m.K[0, 0] * truth, (v - m.K[1, 2]) / m.K[1, 1] * truth, truth], -1) - T_C
    Xd = X @ R_C  # R^T (X - t)
    ud = m.K_depth[0, 0] * Xd[..., 0] / Xd[..., 2] + m.K_depth[0, 2]
    vd = m.K_depth[1, 1] * Xd[..., 1] / Xd[..., 2] + m.K_depth[1, 2]
    seen = (ud > 12) & (ud < 637) & (vd > 2) & (vd < 573)
    assert seen.sum() > 100_000
    assert (got[seen] > 0).mean() >= 0.97
    ok = seen & (got > 0)
    assert np.median(np.abs(got[ok] - truth[ok])) < 0.0015


def test_two_mkv_cameras_pair_by_device_time(tmp_path):
    a, *_ = _recording(tmp_path, "a", "A", t0_us=3_000_000)
    b, *_ = _recording(tmp_path, "b", "B", t0_us=3_000_160)  # wired sync: 160 us subordinate delay
    s = convert([a, b], tmp_path / "rec")
    assert s.frames == T and s.details["dropped_views"] == {"A": 0, "B": 0}
    assert s.details["max_spread_ms"] == pytest.approx(0.160 + 0.0, abs=0.013)


def test_bad_mkv_files_give_one_line_errors(tmp_path):
    nocal, *_ = _recording(tmp_path, "nocal", "N", calib=False)
    with pytest.raises(FormatError, match=r"nocal\.mkv: no calibration\.json attachment"):
        AzureKinectMkv(nocal)
    junk = tmp_path / "junk.mkv"
    junk.write_bytes(b"\x1a\x45\xdf\xa3 not matroska")
    with pytest.raises(FormatError, match=r"junk\.mkv"):
        AzureKinectMkv(junk)
    with pytest.raises(RecordingError, match=r"missing\.mkv: no such file"):
        convert([tmp_path / "missing.mkv"], tmp_path / "o")


def test_missing_extra_is_named(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "av", None)
    with pytest.raises(RecordingError, match=r"pip install 'fuseflow\[recordings\]'"):
        AzureKinectMkv(tmp_path / "any.mkv")
