"""PRESETS["auto"]: the pixel grid follows the rig (config.auto_config)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from fuseflow.fuse import PRESETS, fuse_with_report
from fuseflow.fuse.config import AUTO_MIN_VALID_PER_VIEW, AUTO_MIN_VIEWS, auto_config


def test_auto_config_takes_lives_grid_only_where_pixels_are_plentiful():
    cfg = PRESETS["auto"]
    plenty = AUTO_MIN_VIEWS * AUTO_MIN_VALID_PER_VIEW
    out, why = auto_config(cfg, AUTO_MIN_VIEWS, plenty)
    live = PRESETS["live"]
    assert (out.pixel_stride, out.ash.s0, out.mcm.max_missing) == (live.pixel_stride, live.ash.s0, live.mcm.max_missing)
    assert "stride 2" in why and "plentiful" in why
    assert out.smoothing.radius == cfg.smoothing.radius == 1 and live.smoothing.radius == 0  # live's grid, smoothed
    for views, valid in ((AUTO_MIN_VIEWS - 1, 10 * plenty), (AUTO_MIN_VIEWS, plenty - 1), (8, 8 * 320 * 240)):
        out, why = auto_config(cfg, views, valid)
        dense = PRESETS["dense"]
        assert (
            out == cfg.replace(ash={"s0": dense.ash.s0}, smoothing={"radius": dense.smoothing.radius})
            and "stride 1" in why
        )


def test_auto_preset_on_a_small_rig_is_dense_and_says_so():
    from fuseflow.synth import SimConfig, Simulator

    sim = Simulator(SimConfig(cameras=4, resolution=(96, 72), frames=1, seed=2))
    frame = sim.render(0).frame
    a = fuse_with_report(frame, sim.rig, PRESETS["auto"])
    b = fuse_with_report(frame, sim.rig, PRESETS["dense"])
    assert a.report.pixel_stride == 1 and a.report.grid.startswith("auto: stride 1")
    assert b.report.grid == ""
    assert np.array_equal(a.cloud.xyz.numpy(), b.cloud.xyz.numpy())


def test_a_point_budget_overrides_the_auto_grid():
    from fuseflow.synth import SimConfig, Simulator

    sim = Simulator(SimConfig(cameras=4, resolution=(96, 72), frames=1, seed=2))
    r = fuse_with_report(sim.render(0).frame, sim.rig, replace(PRESETS["auto"], target_points=3000))
    assert r.report.grid == ""
