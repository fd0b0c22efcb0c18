"""A camera's depth sensor from rig.json (``Camera.sensor``): read and written, chosen per camera
by FUSE and by calib's joint refinement, written by the simulator; no sensor = the global choice."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from fuseflow.errors import FormatError, ValidationError
from fuseflow.geometry.noise import DEFAULT_SENSOR, SENSOR_NOISE, camera_noise
from fuseflow.io.recording import rig_from_json, rig_to_json
from fuseflow.types import Camera, Rig

K = np.array([[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]])


def _rig(*sensors):
    return Rig(tuple(Camera(f"c{k}", 64, 48, K, sensor=s) for k, s in enumerate(sensors)))


def test_rig_json_round_trip_and_unknown_names():
    doc = rig_to_json(_rig("realsense_d4xx", None))
    assert doc["cameras"][0]["sensor"] == "realsense_d4xx" and "sensor" not in doc["cameras"][1]
    back = rig_from_json(json.loads(json.dumps(doc)))
    assert [c.sensor for c in back.cameras] == ["realsense_d4xx", None]
    doc["cameras"][1]["sensor"] = "kinect_v9"
    with pytest.raises(FormatError, match=r"camera 'c1'.*sensor.*kinect_v9.*known"):
        rig_from_json(doc)
    doc["cameras"][1]["sensor"] = 3
    with pytest.raises(FormatError, match="sensor"):
        rig_from_json(doc)


def test_camera_noise_falls_back_to_the_global_choice():
    default = (0.002, 0.001, 0.5)
    assert camera_noise(None, default) == default
    assert camera_noise("kinect2", default) == SENSOR_NOISE["kinect_v2"]
    assert camera_noise("azure_kinect", default) == SENSOR_NOISE["azure_kinect"]
    with pytest.raises(ValidationError, match="unknown depth sensor"):
        camera_noise("nope", default)


def test_fuse_takes_sigma_from_the_cameras_sensor():
    """A rig naming realsense_d4xx on every camera fuses as FuseConfig(noise_sigma=that row) does
    on the same rig without sensors; mixed sensors keep the config's and say so."""
    from fuseflow.fuse import FuseConfig, fuse_with_report
    from fuseflow.synth import SimConfig, Simulator

    sim = Simulator(SimConfig(cameras=3, resolution=(80, 60), frames=1, noise="realsense", seed=3))
    frame, rig = sim.render(0).frame, sim.rig
    assert {c.sensor for c in rig.cameras} == {"realsense_d4xx"}  # the simulator writes it
    bare = Rig(tuple(replace(c, sensor=None) for c in rig.cameras))
    cfg = FuseConfig(backend="numba")
    rs = replace(cfg, noise_sigma=tuple(SENSOR_NOISE["realsense_d4xx"]))
    a = np.asarray(fuse_with_report(frame, rig, cfg).cloud.xyz)
    b = np.asarray(fuse_with_report(frame, bare, rs).cloud.xyz)
    c = np.asarray(fuse_with_report(frame, bare, cfg).cloud.xyz)
    assert np.array_equal(a, b) and len(a) > 100
    assert not (len(a) == len(c) and np.array_equal(a, c))  # sigma matters (multi-view mean)
    mixed = Rig((rig.cameras[0], *(replace(x, sensor="kinect_v2") for x in rig.cameras[1:])))
    res = fuse_with_report(frame, mixed, cfg)
    assert np.array_equal(np.asarray(res.cloud.xyz), c)
    assert any("different depth sensors" in w for w in res.report.warnings)


def test_joint_refinement_weighs_each_camera_by_its_sensor():
    from fuseflow.calib.joint_refine import SIGMA_A, SIGMA_B, SIGMA_Z0, _frame_views
    from fuseflow.types import Frame

    rig = _rig("kinect_v2", None)
    depth = np.full((2, 48, 64), 1.5, dtype=np.float32)
    frame = Frame(0, rig.ids, np.zeros((2, 48, 64, 3), np.uint8), depth, np.ones(2, bool)).to("cpu")
    views = _frame_views([frame], rig, list(rig.ids), 1, 200)
    assert views[0][0].noise == tuple(SENSOR_NOISE["kinect_v2"])
    assert views[0][1].noise == (SIGMA_A, SIGMA_B, SIGMA_Z0) == tuple(SENSOR_NOISE[DEFAULT_SENSOR])
