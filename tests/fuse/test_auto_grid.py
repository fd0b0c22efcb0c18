"""PRESETS["auto"]: the pixel grid follows the rig (presets.auto_config)."""

from __future__ import annotations

import numpy as np

from fuseflow.fuse import PRESETS, fuse_with_report
from fuseflow.fuse.density import grid_spacing
from fuseflow.fuse.presets import (
    AUTO_CORE_MS,
    AUTO_CORE_MS_PER_MPX,
    AUTO_MAX_EVERY_PIXEL,
    AUTO_RESOLUTION,
    auto_config,
)


def _spacing(value: float):
    calls = []

    def spacing() -> float:
        calls.append(value)
        return value

    return spacing, calls


def test_auto_config_fuses_every_pixel_within_the_time_budget_and_a_coarse_grid_above():
    cfg = PRESETS["auto"]
    assert AUTO_MAX_EVERY_PIXEL == int(AUTO_CORE_MS / AUTO_CORE_MS_PER_MPX * 1e6)
    assert 4 * 320 * 240 < AUTO_MAX_EVERY_PIXEL < 8 * 640 * 480 // 2  # the rigs of docs/fuse.md fall either side
    dense = PRESETS["dense"]
    every = cfg.replace(
        ash={"s0": dense.ash.s0},
        smoothing={"radius": dense.smoothing.radius},
        mcm={"max_missing": dense.mcm.max_missing},
    )
    for views, valid in ((8, AUTO_MAX_EVERY_PIXEL), (3, 1000), (16, 16 * 320 * 240 // 2)):
        spacing, calls = _spacing(AUTO_RESOLUTION / 2)
        out, why = auto_config(cfg, views, valid, spacing)
        assert out == every and "stride 1" in why
        assert calls == []  # within the budget the spacing is not needed
    for views, valid in ((8, AUTO_MAX_EVERY_PIXEL + 1), (4, 2 * AUTO_MAX_EVERY_PIXEL)):
        out, why = auto_config(cfg, views, valid, _spacing(AUTO_RESOLUTION)[0])
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
        assert "stride 2" in why and "10 frames/s" in why and "10.0 mm" in why


def test_auto_config_takes_every_pixel_where_the_coarse_grid_would_sample_coarser_than_1_cm():
    cfg = PRESETS["auto"]
    spacing, calls = _spacing(AUTO_RESOLUTION * 1.01)
    out, why = auto_config(cfg, 8, 3 * AUTO_MAX_EVERY_PIXEL, spacing)
    assert calls == [AUTO_RESOLUTION * 1.01]
    dense = PRESETS["dense"]
    assert out == cfg.replace(
        ash={"s0": dense.ash.s0},
        smoothing={"radius": dense.smoothing.radius},
        mcm={"max_missing": dense.mcm.max_missing},
        cvgc={"k_neighbours": 4, "multiview_mean": False},
    )
    assert out.pixel_stride == 1 and "stride 1" in why and "10.1 mm, coarser than 10 mm" in why


def test_grid_spacing_is_the_quantile_of_stride_z_over_f_on_numpy_and_torch():
    import torch

    K = np.array([[[500.0, 0, 32], [0, 500.0, 24], [0, 0, 1]], [[250.0, 0, 32], [0, 1000.0, 24], [0, 0, 1]]])
    depth = np.zeros((2, 48, 64), np.float32)
    depth[0, :24] = 1.0  # f = 500: z / f = 2 mm
    depth[0, 24:] = 2.5  # 5 mm
    depth[1] = 5.0  # f = sqrt(250 * 1000) = 500: 10 mm
    # every 8th pixel of every 8th row: view 0 has 24 samples at 2 mm and 24 at 5 mm, view 1 48 at 10 mm
    assert abs(grid_spacing(depth, K, 2, 0.2) - 2 * 0.002) < 1e-9
    assert abs(grid_spacing(depth, K, 2, 0.4) - 2 * 0.005) < 1e-9
    assert abs(grid_spacing(depth, K, 3, 0.9) - 3 * 0.010) < 1e-9
    t = grid_spacing(torch.from_numpy(depth), torch.from_numpy(K).float(), 3, 0.9)
    assert abs(t - 3 * 0.010) < 1e-7
    assert grid_spacing(np.zeros_like(depth), K, 2, 0.9) == 0.0
    assert grid_spacing(torch.zeros(2, 48, 64), torch.from_numpy(K).float(), 2, 0.9) == 0.0


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
    """Above the budget, on a frame the coarse grid samples finely enough, auto's cloud is that of
    the coarse settings as a plain config: the neighbour graph _prepare built for 7 cameras is
    cut to auto_config's 4 (the best first). Sampled too coarsely, it fuses every pixel."""
    from fuseflow.fuse import presets
    from fuseflow.synth import SimConfig, Simulator

    sim = Simulator(SimConfig(cameras=6, resolution=(96, 72), frames=1, seed=3))
    frame = sim.render(0).frame
    monkeypatch.setattr(presets, "AUTO_MAX_EVERY_PIXEL", 1000)
    far = fuse_with_report(frame, sim.rig, PRESETS["auto"])  # 96x72: stride 2 samples every ~9 cm
    assert far.report.pixel_stride == 1 and "coarser than 10 mm" in far.report.grid
    monkeypatch.setattr(presets, "AUTO_RESOLUTION", 1.0)
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
