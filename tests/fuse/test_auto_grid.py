"""PRESETS["auto"]: the pixel grid follows the rig (config.auto_config)."""

from __future__ import annotations

import numpy as np

from fuseflow.fuse import PRESETS, fuse_with_report
from fuseflow.fuse.config import AUTO_CORE_MS, AUTO_CORE_MS_PER_MPX, AUTO_MAX_EVERY_PIXEL, auto_config


def test_auto_config_fuses_every_pixel_within_the_time_budget_and_a_coarse_grid_above():
    cfg = PRESETS["auto"]
    assert AUTO_MAX_EVERY_PIXEL == int(AUTO_CORE_MS / AUTO_CORE_MS_PER_MPX * 1e6)
    assert 4 * 320 * 240 < AUTO_MAX_EVERY_PIXEL < 8 * 640 * 480 // 2  # the rigs of docs/fuse.md fall either side
    dense = PRESETS["dense"]
    for views, valid in ((8, AUTO_MAX_EVERY_PIXEL), (3, 1000), (16, 16 * 320 * 240 // 2)):
        out, why = auto_config(cfg, views, valid)
        assert out == cfg.replace(ash={"s0": dense.ash.s0}, smoothing={"radius": dense.smoothing.radius})
        assert "stride 1" in why
    for views, valid in ((8, AUTO_MAX_EVERY_PIXEL + 1), (4, 2 * AUTO_MAX_EVERY_PIXEL)):
        out, why = auto_config(cfg, views, valid)
        live = PRESETS["live"]
        assert (out.pixel_stride, out.ash.s0, out.mcm.max_missing) == (
            live.pixel_stride,
            live.ash.s0,
            live.mcm.max_missing,
        )
        assert (out.smoothing.radius, out.cvgc.k_neighbours, out.cvgc.multiview_mean) == (2, 4, False)
        assert out == cfg.replace(
            pixel_stride=2,
            ash={"s0": 1.0},
            smoothing={"radius": 2},
            cvgc={"k_neighbours": 4, "multiview_mean": False},
            mcm={"max_missing": live.mcm.max_missing},
        )
        assert "stride 2" in why and "10 frames/s" in why


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
    r = fuse_with_report(sim.render(0).frame, sim.rig, PRESETS["auto"].replace(target_points=3000))
    assert r.report.grid == ""


def test_the_coarse_grid_fuses_as_its_settings_given_up_front(monkeypatch):
    """Above the budget auto's cloud is that of the coarse settings as a plain config: the
    neighbour graph _prepare built for 7 cameras is cut to auto_config's 4 (the best first)."""
    from fuseflow.fuse import config
    from fuseflow.synth import SimConfig, Simulator

    sim = Simulator(SimConfig(cameras=6, resolution=(96, 72), frames=1, seed=3))
    frame = sim.render(0).frame
    monkeypatch.setattr(config, "AUTO_MAX_EVERY_PIXEL", 1000)
    a = fuse_with_report(frame, sim.rig, PRESETS["auto"])
    assert a.report.pixel_stride == 2
    coarse = PRESETS["default"].replace(
        pixel_stride=2, ash={"s0": 1.0}, smoothing={"radius": 2}, cvgc={"k_neighbours": 4, "multiview_mean": False}
    )
    b = fuse_with_report(frame, sim.rig, coarse)
    assert np.array_equal(a.cloud.xyz.numpy(), b.cloud.xyz.numpy())
    c = fuse_with_report(frame, sim.rig, coarse.replace(cvgc={"k_neighbours": 7}))
    assert len(c.cloud) != len(b.cloud) or not np.array_equal(c.cloud.xyz.numpy(), b.cloud.xyz.numpy())
    t = fuse_with_report(frame, sim.rig, PRESETS["auto"].replace(backend="torch"))  # the reference cuts it too
    tb = fuse_with_report(frame, sim.rig, coarse.replace(backend="torch"))
    assert t.report.backend == "torch" and np.array_equal(t.cloud.xyz.numpy(), tb.cloud.xyz.numpy())
