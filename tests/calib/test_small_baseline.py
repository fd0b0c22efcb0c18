"""Rigs whose cameras sit a few centimetres apart (a hand-held camera's frames taken as a rig):
the joint choice must not veto them as stacked, and calibration must be metric-precise.

Data: ../shared/data/icl-noisy5 (five ICL-NUIM frames, 23 mm apart, Kinect-like depth noise,
ground-truth poses), converted as docs/fuse.md converts it."""

from __future__ import annotations

import numpy as np
import pytest
from tests.conftest import SHARED_DATA

import fuseflow
from fuseflow.calib.backbones.rgbd import RGBDConfig
from fuseflow.calib.backbones.rgbd.choice import joint_separation
from fuseflow.calib.symmetry import Hypothesis

ICL_NOISY = SHARED_DATA / "icl-noisy5"


def _shift(x: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = x
    return T


def test_joint_separation_follows_the_shortest_verified_baseline():
    cfg = RGBDConfig()
    far = [Hypothesis(0, 1, _shift(1.5), 1.0), Hypothesis(1, 2, _shift(2.0), 1.0)]
    assert joint_separation(far, cfg) == cfg.min_separation
    close = far + [Hypothesis(0, 2, _shift(0.023), 1.0)]
    assert joint_separation(close, cfg) == pytest.approx(0.0115)


@pytest.fixture(scope="module")
def icl_noisy5(tmp_path_factory):
    from typer.testing import CliRunner

    from fuseflow.cli import app as cli_app

    if not ICL_NOISY.exists():
        pytest.skip(f"shared data not found at {ICL_NOISY}")
    out = tmp_path_factory.mktemp("icln") / "rec"
    res = CliRunner().invoke(cli_app, ["convert", str(ICL_NOISY), str(out), "--cameras", "5", "--every", "1"])
    assert res.exit_code == 0, res.output
    return out


def test_noisy_icl_five_views_calibrate_within_half_a_degree(icl_noisy5):
    """Every pair's verified pose is shorter than ``min_separation``: the joint choice had no
    hypothesis to start from and raised IndexError."""
    from fuseflow.eval.metrics import pose_errors

    rec = fuseflow.open_recording(icl_noisy5)
    bare = fuseflow.Rig(tuple(c.with_extrinsics(None) for c in rec.rig))
    cal = fuseflow.calibrate(rec[0], bare)
    assert set(cal.T_cam_world) == set(rec.rig.ids)
    err = pose_errors(cal.T_cam_world, {c.id: c.T_cam_world for c in rec.rig})
    assert err.rotation_deg <= 0.5
    assert err.translation_mm <= 5.0
