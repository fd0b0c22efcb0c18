"""Calibrating one frame twice gives the same calib.json: seeded RANSAC in COLMAP's
two-view verification and mapper, and the world anchored at the first placed camera."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fuseflow.io import open_recording


@pytest.fixture(scope="module")
def rec6(tmp_path_factory, make_recording):
    return make_recording(tmp_path_factory.mktemp("det") / "rec", cameras=6, frames=1, seed=2, resolution=(320, 240))


def test_two_calibrations_of_one_frame_are_identical(rec6, tmp_path, invoke, expect):
    pytest.importorskip("pycolmap")
    for name in ("a.json", "b.json"):
        expect(invoke("calibrate", rec6, "--out", tmp_path / name), 0)
    a, b = (json.loads((tmp_path / n).read_text()) for n in ("a.json", "b.json"))
    assert a["cameras"].keys() == b["cameras"].keys() and a["cameras"]
    for c in a["cameras"]:
        np.testing.assert_allclose(a["cameras"][c]["T_cam_world"], b["cameras"][c]["T_cam_world"], atol=1e-9)
    anchor = a["report"]["world_anchor"]
    rig = open_recording(rec6).rig
    assert anchor == next(c for c in rig.ids if c in a["cameras"])  # first placed camera in rig order
    np.testing.assert_allclose(a["cameras"][anchor]["T_cam_world"], np.eye(4), atol=1e-12)


def test_anchor_world_keeps_relative_poses():
    from fuseflow.calib.api import anchor_world

    rng = np.random.default_rng(0)
    T = {}
    for c in ("cam00", "cam01", "cam02"):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        M = np.eye(4)
        M[:3, :3] = q * np.sign(np.linalg.det(q))
        M[:3, 3] = rng.normal(size=3)
        T[c] = M
    placed = {c: T[c] for c in ("cam01", "cam02")}
    out, anchor = anchor_world(placed, ("cam00", "cam01", "cam02"))
    assert anchor == "cam01"
    np.testing.assert_allclose(out["cam01"], np.eye(4))
    rel = lambda d: d["cam02"] @ np.linalg.inv(d["cam01"])  # noqa: E731
    np.testing.assert_allclose(rel(out), rel(placed), atol=1e-12)
    assert anchor_world({}, ("cam00",)) == ({}, None)
