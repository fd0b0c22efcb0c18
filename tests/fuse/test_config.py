"""FuseConfig's per-stage parts: validation, ``replace``, ``describe``, and the
kernels' parameter structs built from the stage configs."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fuseflow.errors import ValidationError
from fuseflow.fuse import ABLATIONS, PRESETS, FuseConfig, RPSConfig
from fuseflow.fuse.config import STAGES


def test_each_stage_validates_its_own_settings_and_names_them():
    for changes, name in (
        ({"rps": {"k_max": 0}}, "FuseConfig.rps.k_max"),
        ({"rps": {"k_fixed": 4}}, "FuseConfig.rps.k_fixed"),
        ({"mcm": {"window": 4}}, "FuseConfig.mcm.window"),
        ({"mcm": {"z_max": 0.05}}, "FuseConfig.mcm.z_max"),
        ({"cvgc": {"min_overlap": 1.5}}, "FuseConfig.cvgc.min_overlap"),
        ({"ash": {"s_max": 0.5}}, "FuseConfig.ash.s_max"),
        ({"smoothing": {"radius": 4}}, "FuseConfig.smoothing.radius"),
        ({"pixel_stride": 0}, "FuseConfig.pixel_stride"),
        ({"mcm": {"enabled": 1}}, "FuseConfig.mcm.enabled"),
    ):
        with pytest.raises(ValidationError, match=name.replace(".", r"\.")):
            FuseConfig().replace(**changes)
    with pytest.raises(ValidationError, match=r"FuseConfig\.rps: expected type RPSConfig"):
        dataclasses.replace(FuseConfig(), rps={"k_max": 2})  # a dict replaces nothing silently
    with pytest.raises(ValidationError, match="no setting 'kmax'"):
        FuseConfig().replace(rps={"kmax": 2})
    with pytest.raises(ValidationError, match="no setting 'k_max'"):
        FuseConfig().replace(k_max=2)


def test_replace_merges_a_stage_and_keeps_the_rest():
    live = PRESETS["live"]
    cfg = live.replace(rps={"k_max": 2}, pixel_stride=1)
    assert cfg.rps.k_max == 2 and cfg.pixel_stride == 1
    assert cfg.rps == dataclasses.replace(live.rps, k_max=2) and cfg.ash == live.ash and cfg.mcm == live.mcm
    assert live.replace(rps=RPSConfig(k_max=2)).rps == RPSConfig(k_max=2)  # a whole stage config
    assert live.replace() == live


def test_ablations_each_switch_off_one_stage():
    default = FuseConfig().describe()
    for name, cfg in ABLATIONS.items():
        changed = {k for k, v in cfg.describe().items() if v != default[k]}
        assert len(changed) == 1 and changed.pop().endswith(".enabled"), name
    assert set(STAGES) == {"smoothing", "mcm", "cvgc", "ash", "rps"}


def test_kernel_params_read_each_stage_config():
    from fuseflow.fuse.kernels.params import consensus_params, kernel_params

    cfg = FuseConfig().replace(
        mcm={"alpha": 21.0, "max_missing": 2, "noise_aware": True},
        cvgc={"tau": 0.07, "multiview_gate": 2.0},
        ash={"s0": 4.0, "s_max": 0.04},
        rps={"k_max": 5, "r_c": 0.25, "min_weight": 0.2, "consensus_gate": 2.5, "lone_cell_keep": 2},
        pixel_stride=2,
    )
    p = kernel_params(cfg)
    assert (p.pixel.alpha, p.pixel.mcm_max_missing, p.pixel.mcm_noise) == (np.float32(21.0), 2, True)
    assert (p.pixel.tau, p.pixel.mv_gate2, p.pixel.stride) == (np.float32(0.07), np.float32(4.0), 2)
    assert (p.pixel.r_c, p.pixel.min_weight) == (np.float32(0.25), np.float32(0.2))
    assert (p.cell.s0, p.cell.s_max, p.select.k_max, p.select.lone_keep) == (np.float32(4.0), np.float32(0.04), 5, 2)
    assert consensus_params(cfg).gate == np.float32(2.5)
    # the lone-point confirmation needs the multi-view mean, which needs CVGC
    assert kernel_params(cfg.replace(cvgc={"enabled": False})).select.lone_keep == 0
    assert kernel_params(cfg.replace(ash={"enabled": False})).cell.s_c == np.float32(cfg.ash.fixed_size)


def test_as_dict_keeps_the_recorded_flat_names():
    """manifest.json records and digests ``as_dict()``: its names are the recorded ones, so outputs
    written before keep resuming (a renamed key changes every resume digest)."""
    cfg = FuseConfig()
    flat = cfg.as_dict()
    assert len(flat) == len(cfg.describe())  # one flat name per setting
    assert flat["s0"] == cfg.ash.s0 and flat["use_mcm"] is True and flat["depth_smoothing"] == cfg.smoothing.radius
    assert set(flat) == set(
        "alpha beta delta z_max window use_mcm mcm_max_missing mcm_noise k_neighbours min_overlap tau "
        "visibility_aware use_cvgc coarse_size s0 s_min s_max use_ash fixed_size k0 ratio k_max r_c min_weight "
        "use_rps k_fixed range_priority lone_cell_mean lone_cell_keep multiview_mean multiview_gate consensus "
        "consensus_gate depth_smoothing smoothing_gate noise_sigma target_points pixel_stride budget_stride "
        "backend eps auto_grid".split()
    )
