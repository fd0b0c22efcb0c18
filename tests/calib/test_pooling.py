"""``fuseflow.calibrate`` on a recording pools frames as ``fuseflow calibrate`` does (one policy,
``calib.pooling``), and the API warns once per camera left unplaced or not "good"."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

import fuseflow
from fuseflow.calib.errors import CalibrationError, CalibrationWarning
from fuseflow.cli import app as cli_app
from fuseflow.errors import FuseFlowError, ValidationError


class _Recording:
    """A 12-frame recording of 64x48 cameras ``ids`` whose frames are their numbers: enough for
    ``pooled_calibration`` with a stand-in attempt."""

    frame_numbers = list(range(12))

    def __init__(self, ids):
        K = np.array([[100.0, 0, 32], [0, 100.0, 24], [0, 0, 1]])
        self.rig = fuseflow.Rig(tuple(fuseflow.Camera(c, 64, 48, K) for c in ids))

    def __len__(self):
        return 12

    def __getitem__(self, t):
        return t

    def missing_views(self):
        return {}


@pytest.fixture(scope="module")
def ring4_rec(tmp_path_factory):
    """The simulated 4-camera 320x240 dynamic room ring of six frames."""
    from fuseflow.synth import SimConfig, simulate_recording

    out = tmp_path_factory.mktemp("ring4") / "rec"
    cfg = SimConfig(cameras=4, frames=6, scene="room", dynamic=True, resolution=(320, 240), seed=1)
    simulate_recording(out, cfg)
    return out


def test_api_on_a_recording_gives_the_cli_result_and_warns_per_camera(ring4_rec, tmp_path):
    rec = fuseflow.open_recording(ring4_rec)
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        cal = fuseflow.calibrate(rec)
    out = tmp_path / "c.json"
    res = CliRunner().invoke(cli_app, ["calibrate", str(ring4_rec), "--out", str(out)])
    assert res.exit_code == 0, res.output
    cli = fuseflow.read_calibration(out)
    assert set(cal.T_cam_world) == set(cli.T_cam_world)
    for c in cal.T_cam_world:
        np.testing.assert_allclose(cal.T_cam_world[c], cli.T_cam_world[c], atol=1e-6)
    unsure = [c for c in rec.rig.ids if cal.report.camera_verdicts[c]["verdict"] != "good"]
    ours = [str(w.message) for w in got if issubclass(w.category, CalibrationWarning)]
    assert len(ours) == len(unsure) and all(f"camera {c} " in m for c, m in zip(unsure, ours, strict=True))


def test_api_warns_for_an_unplaced_camera(ring4_rec):
    """A camera whose view shows nothing of the scene (noise on a flat wall) is unplaced: one
    CalibrationWarning names it."""
    rec = fuseflow.open_recording(ring4_rec)
    f = rec[0]
    color, depth = f.color.clone(), f.depth.clone()
    rng = np.random.default_rng(0)
    color[3] = torch.from_numpy(rng.integers(0, 255, color[3].shape, dtype=np.uint8))
    depth[3] = 3.0
    frame = type(f)(f.index, f.camera_ids, color, depth, f.present)
    bare = fuseflow.Rig(tuple(c.with_extrinsics(None) for c in rec.rig))
    with pytest.warns(CalibrationWarning, match=r"camera cam03 unplaced"):
        cal = fuseflow.calibrate(frame, bare)
    assert "cam03" not in cal.T_cam_world


def test_api_on_a_recording_rejects_another_rig(ring4_rec):
    rec = fuseflow.open_recording(ring4_rec)
    other = fuseflow.Rig(rec.rig.cameras[:3])
    with pytest.raises(ValidationError, match="differ from the recording"):
        fuseflow.calibrate(rec, other)
    with pytest.raises(ValidationError, match="a rig is needed"):
        fuseflow.calibrate(rec[0])
    assert issubclass(CalibrationError, FuseFlowError)


def test_a_backbone_that_reads_the_first_frame_only_is_not_pooled():
    """``colmap`` (and the neural and precomputed backbones) place from the first frame: pooling
    more frames would rerun them for the same poses, so one attempt is made, whatever its
    verdicts; ``auto`` and ``rgbd`` pool."""
    from types import SimpleNamespace

    from fuseflow.calib import CalibConfig
    from fuseflow.calib.pooling import pooled_calibration

    calls = []

    def attempt(frames, rig, config, progress=None):
        calls.append(len(frames))
        return SimpleNamespace(T_cam_world={}, report=SimpleNamespace(camera_verdicts={"a": {"verdict": "check it"}}))

    for backbone, attempts in (("colmap", 1), ("precomputed", 1), ("rgbd", 2), ("auto", 2)):
        calls.clear()
        pooled_calibration(
            _Recording(("a", "b")), [0], CalibConfig(backbone=backbone, backbone_path="x.npz"), True, attempt
        )
        assert len(calls) == attempts, (backbone, calls)


def test_pooled_frames_win_a_tie_in_good_cameras_when_the_one_frame_folded_cameras_onto_one_spot():
    """One frame of a repeating room folded cameras onto each other's spots (proof that both of
    a pair cannot be right); the pooled frames placed every camera on its own spot, none "good"
    in either (a camera the subject turns is never good): the pooled result is kept."""
    from types import SimpleNamespace

    from fuseflow.calib import CalibConfig
    from fuseflow.calib.pooling import pooled_calibration, unstacked_count

    ids = ("a", "b", "c")

    def at(*centres):
        out = {}
        for c, x in zip(ids, centres, strict=True):
            out[c] = np.eye(4)
            out[c][:3, 3] = -np.asarray(x, dtype=float)
        return out

    folded = at([0, 0, 0], [3.0, 0, 0], [3.02, 0, 0])  # b and c 2 cm apart
    spread = at([0, 0, 0], [3.0, 0, 0], [0, 3.0, 0])

    def attempt(frames, rig, config, progress=None):
        T = folded if len(frames) == 1 else spread
        return SimpleNamespace(
            T_cam_world=T, report=SimpleNamespace(camera_verdicts={c: {"verdict": "check it"} for c in ids})
        )

    assert unstacked_count(SimpleNamespace(T_cam_world=folded)) == 1
    assert unstacked_count(SimpleNamespace(T_cam_world=spread)) == 3
    out = pooled_calibration(_Recording(ids), [0], CalibConfig(), True, attempt)
    assert out.calibration.T_cam_world is spread and len(out.positions) > 1


def test_pooled_frames_win_a_tie_when_they_settle_turns_the_one_frame_left_ambiguous():
    """One frame left the room's turns open ("ambiguous": no axis found); the pooled frames found
    it and the subject checked every camera's turn, none "good" in either and no camera folded:
    the pooled result is kept."""
    from types import SimpleNamespace

    from fuseflow.calib import CalibConfig
    from fuseflow.calib.pooling import pooled_calibration, turn_checked_count

    ids = ("a", "b", "c")

    T = {}
    for c, x in zip(ids, ([0, 0, 0], [3.0, 0, 0], [0, 3.0, 0]), strict=True):
        T[c] = np.eye(4)
        T[c][:3, 3] = x
    open_turns = {c: {"verdict": "ambiguous"} for c in ids}
    open_turns["a"] = {"verdict": "check it", "turn": {"turn": 2, "margin": 0.01}}  # chosen, not applied
    checked = {c: {"verdict": "check it", "turn": {"turn": 0, "margin": 0.1, "moved": 1}} for c in ids}
    single = SimpleNamespace(T_cam_world=T, report=SimpleNamespace(camera_verdicts=open_turns))
    pooled = SimpleNamespace(T_cam_world=dict(T), report=SimpleNamespace(camera_verdicts=checked))
    assert turn_checked_count(single) == 0 and turn_checked_count(pooled) == 3

    def attempt(frames, rig, config, progress=None):
        return single if len(frames) == 1 else pooled

    assert pooled_calibration(_Recording(ids), [0], CalibConfig(), True, attempt).calibration is pooled


def _ring(scale: float = 1.0, turn_last_deg: float = 0.0, n: int = 5, radius: float = 3.3) -> dict:
    """Camera-from-world of ``n`` cameras on a ring looking at its centre, the ring's radius
    times ``scale``, the last camera turned by ``turn_last_deg`` about the vertical axis."""
    out = {}
    for k in range(n):
        a = 2 * np.pi * k / n + (np.radians(turn_last_deg) if k == n - 1 else 0.0)
        centre = radius * scale * np.array([np.cos(a), np.sin(a), 0.0])
        z = -centre / np.linalg.norm(centre)  # optical axis to the middle
        x = np.cross([0.0, 0.0, 1.0], z)
        R = np.stack([x, np.cross(z, x), z])  # rows: camera axes in the world
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, -R @ centre
        out[f"cam{k}"] = T
    return out


def test_a_good_camera_the_pooled_frames_contradict_is_check_it():
    """One frame's ring 1 % small (the ring of one frame's joint room axis about 2 cm off): its
    "good" camera is 6.3 m from the far ones there and 6.4 m in the pooled frames, which disagree
    by more than a good camera may be off: "check it", naming the camera and the pooled frames,
    in the result kept. Pooled frames within 5 mm leave it good."""
    from types import SimpleNamespace

    from fuseflow.calib import CalibConfig
    from fuseflow.calib.pooling import pooled_calibration

    ids = tuple(f"cam{k}" for k in range(5))

    def run(pooled_T):
        def attempt(frames, rig, config, progress=None):
            if len(frames) == 1:
                verdicts = {c: {"verdict": "check it"} for c in ids} | {"cam0": {"verdict": "good"}}
                return SimpleNamespace(T_cam_world=_ring(0.99), report=SimpleNamespace(camera_verdicts=verdicts))
            verdicts = {c: {"verdict": "check it"} for c in ids}
            return SimpleNamespace(T_cam_world=pooled_T, report=SimpleNamespace(camera_verdicts=verdicts))

        return pooled_calibration(_Recording(ids), [0], CalibConfig(), True, attempt)

    out = run(_ring(1.0))
    v = out.calibration.report.camera_verdicts["cam0"]
    assert len(out.positions) == 1, "no 'good' camera in either: the tie keeps the one frame's result"
    assert v["verdict"] == "check it"
    assert v["cross_check"]["camera"] in ("cam2", "cam3") and v["cross_check"]["mm"] > 50
    assert "pooled frames put it" in v["reason"] and "further from" in v["reason"]
    out = run(_ring(0.99 * 1.0008))  # 5 mm further over 6.3 m: the same rig
    assert out.calibration.report.camera_verdicts["cam0"] == {"verdict": "good"}


def test_cross_check_turned_camera_and_a_pair_turned_apart():
    """A second calibration that turns a "good" camera against most of the others contradicts
    it; one that turns another camera only leaves the good camera's distance to it unchecked
    (that pair compares two room turns) and the rest agree: still good."""
    from fuseflow.calib.verdicts import cross_check

    T = _ring()
    good = {c: {"verdict": "good"} for c in T}
    turned = dict(T)
    turned["cam4"] = _ring(turn_last_deg=36.0)["cam4"]
    out = cross_check(good, T, turned, "frames 0-4")
    assert out["cam4"]["verdict"] == "check it" and out["cam4"]["cross_check"]["turned_against"] == 4
    assert "frames 0-4 turned it" in out["cam4"]["reason"]
    assert all(out[c]["verdict"] == "good" for c in ("cam0", "cam1", "cam2", "cam3"))
    assert cross_check(good, T, {"cam0": T["cam0"]}, "x") == good  # nothing to compare: unchanged
    assert good["cam4"] == {"verdict": "good"}  # the input is not changed
