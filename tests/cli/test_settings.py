"""The ``NAME=VALUE`` settings of `fuse` / `run`'s --set (``fuseflow.cli.settings``)."""

import dataclasses

import pytest

from fuseflow.cli.settings import fuse_config, parse_settings
from fuseflow.errors import ValidationError
from fuseflow.fuse import PRESETS, FuseConfig
from fuseflow.fuse.config import STAGES


def test_describe_and_parse_settings_round_trip_every_setting():
    cfg = PRESETS["paper"]
    flat = cfg.describe()
    assert flat["rps.k_max"] == cfg.rps.k_max and flat["pixel_stride"] == cfg.pixel_stride
    assert len(flat) == sum(len(dataclasses.fields(v)) for v in STAGES.values()) + len(dataclasses.fields(cfg)) - 5
    text = [f"{k}={','.join(map(str, v)) if isinstance(v, tuple) else v}" for k, v in flat.items()]
    assert FuseConfig().replace(**parse_settings(text)) == cfg
    assert parse_settings(["cvgc.multiview_mean=off", "target_points=none", "ash.s0=2"]) == {
        "cvgc": {"multiview_mean": False},
        "target_points": None,
        "ash": {"s0": 2.0},
    }
    for bad in ("rps.k_max", "rps.k_max=2.5", "mcm.enabled=maybe", "nothing=1"):
        with pytest.raises(ValidationError, match="--set"):
            parse_settings([bad])


def test_fuse_config_applies_settings_over_the_preset_and_points():
    cfg = fuse_config("live", 5000, ["rps.k_max=2"])
    assert cfg == PRESETS["live"].replace(target_points=5000, rps={"k_max": 2})
    assert fuse_config("dense") == PRESETS["dense"]
    with pytest.raises(ValidationError, match="no FUSE preset"):
        fuse_config("nope")
