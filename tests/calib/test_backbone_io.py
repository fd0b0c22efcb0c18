"""The precomputed export format and the neural adapters' code path (tiny stand-in model)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from fuseflow.calib import CalibConfig, CalibrationError, calibrate
from fuseflow.calib.backbones.neural import (
    _vggt_decode,
    decode_vggt_pose_encoding,
    mapanything_backbone,
    run_pose_model,
    vggt_backbone,
)
from fuseflow.calib.backbones.precomputed import load_precomputed, save_precomputed


def test_precomputed_roundtrip_reorders_and_calibrates(scene5, tmp_path):
    frame, rig, T = scene5
    T0 = T.copy()
    T0[:, :3, 3] /= 2.5
    order = [3, 0, 4, 1, 2]
    K = rig[0].K
    depth = frame.depth.numpy() / 2.5  # the model's depth, in its own scale
    p = save_precomputed(
        tmp_path / "bb.npz",
        [rig.ids[k] for k in order],
        T0[order],
        source="test",
        depth=depth[order],
        depth_K=np.stack([K] * 5),
    )
    bb = load_precomputed(p, rig)
    np.testing.assert_allclose(bb.T_cam_world, T0)
    cal = calibrate(frame, rig, CalibConfig(backbone="precomputed", backbone_path=str(p)))
    assert abs(cal.report["scale"] - 2.5) / 2.5 < 2e-3
    assert cal.report["scale_naive_median_depth_ratio"] == pytest.approx(2.5, rel=1e-3)
    assert cal.report["backbone"] == "precomputed:test"


def test_precomputed_errors(scene5, tmp_path):
    _, rig, T = scene5
    with pytest.raises(CalibrationError, match="not found"):
        load_precomputed(tmp_path / "none.npz", rig)
    p = save_precomputed(tmp_path / "few.npz", ["c0", "c1"], T[:2])
    with pytest.raises(CalibrationError, match=r"no poses for rig cameras \['c2'"):
        load_precomputed(p, rig)
    with pytest.raises(CalibrationError, match="backbone_path"):
        calibrate(*scene5[:2], CalibConfig(backbone="precomputed"))


class TinyPoseNet(torch.nn.Module):
    """A real (small) network: conv features -> per-camera token -> 9-D VGGT pose encoding."""

    def __init__(self):
        super().__init__()
        g = torch.Generator().manual_seed(0)
        self.conv = torch.nn.Conv2d(3, 8, 5, stride=4)
        self.head = torch.nn.Linear(8, 9)
        with torch.no_grad():
            for prm in self.parameters():
                prm.copy_(torch.randn(prm.shape, generator=g) * 0.5)

    def forward(self, imgs):  # (1, N, 3, h, w)
        b, n = imgs.shape[:2]
        tok = torch.relu(self.conv(imgs.flatten(0, 1))).mean(dim=(2, 3)).reshape(b, n, 8)
        return {"pose_enc": self.head(tok), "camera_tokens": tok}


def test_adapter_code_path_with_stand_in_model(scene5):
    frame, _, _ = scene5
    model = TinyPoseNet()
    res = run_pose_model(model, frame.color, _vggt_decode, "tiny")
    # independent decoding of the same forward pass with scipy's quaternion convention
    from fuseflow.calib.backbones.neural import images_tensor

    with torch.no_grad():
        out = model(images_tensor(frame.color)[None])
    pe = out["pose_enc"][0].double().numpy()
    for k in range(frame.num_views):
        np.testing.assert_allclose(res.T_cam_world[k, :3, :3], Rotation.from_quat(pe[k, 3:7]).as_matrix(), atol=1e-9)
        np.testing.assert_allclose(res.T_cam_world[k, :3, 3], pe[k, :3], atol=1e-12)
    assert res.features.shape == (frame.num_views, 8)
    # different images give different poses: the model really consumed them
    assert np.abs(res.T_cam_world[0] - res.T_cam_world[1]).max() > 1e-3
    assert decode_vggt_pose_encoding(out["pose_enc"]).shape == (1, frame.num_views, 4, 4)


def test_adapters_fail_clearly_without_packages(scene5):
    frame, rig, _ = scene5
    for fn, name in ((vggt_backbone, "vggt"), (mapanything_backbone, "mapanything")):
        with pytest.raises(CalibrationError, match=f"{name}"):
            fn(frame, rig, CalibConfig(backbone=name, backbone_path="/nonexistent/model.pt"))
