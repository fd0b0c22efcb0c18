"""CalibConfig.rgbd: the rgbd backbone's settings inside CalibConfig, its matcher and seed the
flat fields', recorded in calib.json only when they differ from the defaults."""

from __future__ import annotations

from dataclasses import replace

import pytest

from fuseflow.calib import CalibConfig
from fuseflow.calib.backbones.rgbd import RGBDConfig, rgbd_backbone
from fuseflow.errors import ValidationError


def test_flat_matcher_and_seed_set_the_rgbd_ones():
    assert CalibConfig().rgbd == RGBDConfig()
    cfg = CalibConfig.preset("default", matcher="xfeat", seed=3)
    assert (cfg.rgbd.matcher, cfg.rgbd.seed) == ("xfeat", 3)
    back = replace(cfg, matcher="sift", seed=0)
    assert back.rgbd == RGBDConfig()
    own = CalibConfig(rgbd=RGBDConfig(subject=False, matcher="disk", seed=5))
    assert own.rgbd == RGBDConfig(subject=False)  # matcher and seed: the flat fields'


def test_as_dict_records_rgbd_only_when_it_differs():
    assert "rgbd" not in CalibConfig().as_dict()
    assert "rgbd" not in CalibConfig(matcher="xfeat", seed=2).as_dict()
    d = CalibConfig(rgbd=RGBDConfig(people=True)).as_dict()
    assert d["rgbd"]["people"] is True and d["seed"] == 0


def test_rgbd_must_be_an_rgbd_config():
    with pytest.raises(ValidationError, match="rgbd must be an RGBDConfig"):
        CalibConfig(rgbd={"people": True})


def test_backbone_takes_the_calib_configs_rgbd(monkeypatch):
    from fuseflow.calib.backbones.rgbd import backbone

    seen = []
    monkeypatch.setattr(backbone, "_check_frames", lambda frames, rig: frames)
    monkeypatch.setattr(backbone, "_rgbd_backbone", lambda frames, rig, cfg: seen.append(cfg))
    rgbd_backbone([], None, CalibConfig(matcher="xfeat", rgbd=RGBDConfig(geometric=False)))
    rgbd_backbone([], None, None)
    rgbd_backbone([], None, RGBDConfig(seed=4))
    assert seen == [RGBDConfig(matcher="xfeat", geometric=False), RGBDConfig(), RGBDConfig(seed=4)]
