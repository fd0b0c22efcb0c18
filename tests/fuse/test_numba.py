"""The compiled CPU path (fuse/kernels/) gives the PyTorch reference's cloud.

Tolerance: both paths run the same float32 operations in the same order, but numba's exp /
sqrt and LLVM's contraction may differ from torch's by one ulp, which moves a point across a
cell border or flips a tie once in ~10^4 points (measured: 6-49 of 270k-470k points differ at
640x480 N = 8). So: point counts agree within 0.2 %, and at least 99.8 % of the points of each
cloud have a counterpart in the other within 1e-6 m with the same weight (1e-5), source camera
and colour.
"""

from __future__ import annotations

import sys
from dataclasses import replace

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree
from tests.fuse.scenes import PLANE_Z, Rect, look_at, make_rig, render

from fuseflow import Frame
from fuseflow.fuse import PRESETS, FuseConfig, fuse_with_report

pytest.importorskip("numba")


def assert_same_cloud(a, b, share: float = 0.998, tol: float = 1e-6) -> None:
    na, nb = len(a), len(b)
    assert abs(na - nb) <= 0.002 * max(na, nb) + 1, (na, nb)
    if na == 0 or nb == 0:
        assert na == nb
        return
    assert (a.support is None) == (b.support is None)
    for x, y in ((a, b), (b, a)):
        # the 3 nearest: with multiview_mean two cameras' points that average the same
        # measurements land within float rounding of each other, so the nearest may be the twin
        kq = min(3, len(y))
        d, j = cKDTree(y.xyz.numpy().astype(np.float64)).query(x.xyz.numpy().astype(np.float64), k=kq)
        d, j = d.reshape(len(x), kq), j.reshape(len(x), kq)
        sup = True if x.support is None else x.support.numpy()[:, None] == y.support.numpy()[j]
        same = (
            (d <= tol)
            & sup
            & (np.abs(x.weight.numpy()[:, None] - y.weight.numpy()[j]) <= 1e-5)
            & (x.camera.numpy()[:, None] == y.camera.numpy()[j])
            & (x.rgb.numpy()[:, None, :] == y.rgb.numpy()[j]).all(axis=2)
        ).any(axis=1)
        assert same.mean() >= share, f"only {same.mean():.5f} of {len(x)} points match"


def both(frame, rig, cfg: FuseConfig, share: float | None = None, tol: float | None = None):
    # with consensus a candidate that float rounding of exp() admits in one backend only moves
    # the mean of its cell: a looser position tolerance (10 um) and share
    if share is None:
        share = 0.995 if cfg.rps.consensus else 0.998
    if tol is None:
        tol = 1e-5 if cfg.rps.consensus else 1e-6
    rt = fuse_with_report(frame, rig, replace(cfg, backend="torch"))
    rn = fuse_with_report(frame, rig, replace(cfg, backend="numba"))
    assert rn.report.backend == "numba" and rt.report.backend == "torch"
    assert rn.report.valid_pixels == rt.report.valid_pixels
    assert abs(rn.report.candidates - rt.report.candidates) <= 0.002 * rt.report.candidates + 1
    assert rn.report.out_of_range == rt.report.out_of_range
    assert (rn.report.missing, rn.report.empty, rn.report.isolated) == (
        rt.report.missing,
        rt.report.empty,
        rt.report.isolated,
    )
    assert_same_cloud(rt.cloud, rn.cloud, share, tol)
    return rt, rn


def test_numba_equals_torch_consensus_switch(sim_frame):
    frame, rig = sim_frame
    on = FuseConfig()
    assert on.rps.consensus
    rt, rn = both(frame, rig, on)
    off, _ = both(frame, rig, on.replace(rps={"consensus": False}))
    noise, _ = both(frame, rig, on.replace(mcm={"noise_aware": True}))  # the noise-aware MCM branch, both backends
    assert noise.report.candidates != rt.report.candidates
    assert off.cloud.support is None and rt.cloud.support.dtype == torch.int16
    sup = rt.cloud.support
    assert int(sup.min()) >= 1 and int(sup.max()) <= len(rig.cameras) and float((sup >= 2).float().mean()) > 0.1
    # same selection, points moved along their rays by at most a few sigma
    assert len(off.cloud) == len(rt.cloud)
    moved = (rt.cloud.xyz - off.cloud.xyz).norm(dim=1)
    assert 0 < float(moved.median()) < 0.02 and float(moved.max()) < 0.2


def test_numba_equals_torch_gap_tolerant_mcm(sim_frame):
    """FuseConfig.mcm.max_missing: both backends agree with and without the gap-tolerant
    window, and tolerating missing neighbours adds candidates (the simulator drops pixels)."""
    frame, rig = sim_frame
    on = FuseConfig()
    assert on.mcm.max_missing == 4
    rt, _ = both(frame, rig, on)
    strict, _ = both(frame, rig, on.replace(mcm={"max_missing": 0}))
    assert rt.report.candidates > strict.report.candidates
    noisy, _ = both(frame, rig, on.replace(mcm={"noise_aware": True}))  # both branches of the kernel
    assert noisy.report.candidates != rt.report.candidates


def test_numba_equals_torch_multiview_mean(sim_frame):
    """FuseConfig.cvgc.multiview_mean: both backends agree with and without the multi-view mean,
    and the switch really moves the candidates (not a no-op on a simulated rig)."""
    frame, rig = sim_frame
    on = FuseConfig()
    assert on.cvgc.multiview_mean
    rt, _ = both(frame, rig, on)
    off, _ = both(frame, rig, on.replace(cvgc={"multiview_mean": False}))
    assert rt.report.candidates == off.report.candidates  # it moves points, never filters
    a, b = rt.cloud.xyz.numpy().astype(np.float64), off.cloud.xyz.numpy().astype(np.float64)
    assert (cKDTree(b).query(a)[0] > 1e-4).mean() > 0.1


@pytest.mark.parametrize("stride", [2, 3])
def test_numba_equals_torch_with_pixel_stride(sim_frame, stride):
    """FuseConfig.pixel_stride: both backends take the same grid of candidates (with and
    without MCM, whose stride-1 path starts at column 1), about 1 / stride^2 of them, each
    on the grid, and every output point comes from a grid pixel's measurement."""
    frame, rig = sim_frame
    full, _ = both(frame, rig, FuseConfig())
    rt, rn = both(frame, rig, replace(FuseConfig(), pixel_stride=stride))
    both(frame, rig, FuseConfig().replace(pixel_stride=stride, mcm={"enabled": False}))
    both(
        frame, rig, FuseConfig().replace(pixel_stride=stride, rps={"consensus": False}, cvgc={"multiview_mean": False})
    )
    assert rt.report.valid_pixels == full.report.valid_pixels  # the gate is unchanged
    share = rt.report.candidates / full.report.candidates
    assert 0.6 / stride**2 < share < 1.4 / stride**2, share
    assert 0 < len(rt.cloud) < len(full.cloud)
    # without averaging every output point is a grid pixel's own back-projection
    plain = fuse_with_report(frame, rig, FuseConfig().replace(pixel_stride=stride, backend="numba", rps={"consensus": False}, cvgc={"multiview_mean": False})).cloud  # fmt: skip
    for k in range(len(rig.cameras)):
        cam = rig.cameras[k]
        mine = plain.camera.numpy() == rig.index(cam.id)
        X = plain.xyz.numpy()[mine].astype(np.float64)
        Xc = X @ cam.T_cam_world[:3, :3].T + cam.T_cam_world[:3, 3]
        u = cam.K[0, 0] * Xc[:, 0] / Xc[:, 2] + cam.K[0, 1] * Xc[:, 1] / Xc[:, 2] + cam.K[0, 2]
        v = cam.K[1, 1] * Xc[:, 1] / Xc[:, 2] + cam.K[1, 2]
        assert np.abs(u - np.round(u)).max() < 1e-2 and np.abs(v - np.round(v)).max() < 1e-2
        assert (np.round(u).astype(int) % stride == 0).all() and (np.round(v).astype(int) % stride == 0).all()


def test_pixel_stride_is_validated():
    from fuseflow.errors import ValidationError

    for bad in (0, 9, 1.5, True):
        with pytest.raises(ValidationError, match="pixel_stride"):
            FuseConfig(pixel_stride=bad)


@pytest.fixture(scope="module")
def sim_frame():
    from fuseflow.synth import SimConfig, Simulator

    sim = Simulator(SimConfig(cameras=4, resolution=(160, 120), frames=1, seed=3))
    return sim.render(0).frame, sim.rig


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_numba_equals_torch_on_simulated_rig(sim_frame, name):
    frame, rig = sim_frame
    rt, rn = both(frame, rig, PRESETS[name])
    assert len(rt.cloud) > 1000  # a real scene, not a trivial one


@pytest.mark.parametrize("k_max", [1, 3])
def test_numba_equals_torch_with_range_priority(sim_frame, k_max):
    frame, rig = sim_frame
    cfg = FuseConfig().replace(rps={"range_priority": True, "k_max": k_max})
    rt, _ = both(frame, rig, cfg)
    off = fuse_with_report(frame, rig, cfg.replace(backend="torch", rps={"range_priority": False}))
    # the switch changes which points win (not a no-op on a real scene), not how many cells
    a, b = rt.cloud.xyz.numpy(), off.cloud.xyz.numpy()
    moved = cKDTree(b.astype(np.float64)).query(a.astype(np.float64))[0] > 1e-6
    assert moved.mean() > 0.01


@pytest.mark.parametrize("lone", [2.0, 4.0])
@pytest.mark.parametrize("keep", [0, 1, 2])
def test_numba_equals_torch_with_lone_cell_mean(sim_frame, lone, keep):
    frame, rig = sim_frame
    cfg = FuseConfig().replace(rps={"lone_cell_mean": lone, "lone_cell_keep": keep, "consensus": False})
    rt, _ = both(frame, rig, cfg)
    off = fuse_with_report(frame, rig, cfg.replace(backend="torch", rps={"lone_cell_mean": 0.0}))
    # it only removes points (lone ones), never adds or moves one
    a, b = rt.cloud.xyz.numpy().astype(np.float64), off.cloud.xyz.numpy().astype(np.float64)
    assert len(a) < len(b)
    assert (cKDTree(b).query(a)[0] <= 1e-7).all()
    if keep:  # sparing the confirmed lone points keeps more, and no fewer with a lower bar
        fewer = fuse_with_report(frame, rig, cfg.replace(backend="torch", rps={"lone_cell_keep": keep + 1}))
        drop_all = fuse_with_report(frame, rig, cfg.replace(backend="torch", rps={"lone_cell_keep": 0}))
        assert len(drop_all.cloud) <= len(fewer.cloud) <= len(rt.cloud)
        if keep == 1:  # every sampled configuration has confirmed lone points
            assert len(drop_all.cloud) < len(rt.cloud)


def test_lone_cell_keep_needs_the_multiview_support(sim_frame):
    """Without the multi-view mean no point counts as confirmed: lone_cell_keep changes nothing."""
    frame, rig = sim_frame
    base = FuseConfig().replace(cvgc={"multiview_mean": False}, rps={"consensus": False})
    for backend in ("torch", "numba"):
        a = fuse_with_report(frame, rig, base.replace(backend=backend, rps={"lone_cell_keep": 0})).cloud
        b = fuse_with_report(frame, rig, base.replace(backend=backend, rps={"lone_cell_keep": 3})).cloud
        assert torch.equal(a.xyz, b.xyz)


def test_numba_select_prefers_the_near_point_like_torch():
    """The compiled select with the ranking value of rps.selection_priority picks the near
    point of a cell whose two points have equal omega, in either input order."""
    from fuseflow.fuse.kernels import consensus_params, kernel_params
    from fuseflow.fuse.kernels.rps import select
    from fuseflow.fuse.rps import selection_priority

    P = np.array([[0.0, 0.0, 0.0], [0.001, 0.0, 0.0]], dtype=np.float32)
    omega = torch.tensor([0.9, 0.9])
    for z in ([3.5, 2.0], [2.0, 3.5]):
        pr = selection_priority(omega, torch.tensor(z), FuseConfig().noise_sigma).numpy()
        # k = 1 in every cell (fixed_k), lone_cell_mean off
        prm = kernel_params(FuseConfig().replace(rps={"lone_cell_mean": 0.0})).select._replace(fixed_k=True, k_const=1)
        src, nsel = np.full(2, -1, dtype=np.int64), np.zeros(1, dtype=np.int64)
        select(
            P,  # the points in slot order (here slot = pixel)
            pr,
            omega.numpy(),
            np.zeros(2, dtype=np.int16),  # camera of each slot
            np.array([0, 2]),  # one coarse cell holding points 0 and 1
            np.array([0, 1]),
            np.zeros(2, dtype=np.int32),  # one fine cell
            np.array([0.01], dtype=np.float32),
            np.array([1]),
            prm,
            np.array([0, 1]),  # one chunk of cells
            2,
            consensus_params(FuseConfig(), on=False),
            np.zeros((1, 3, 4), dtype=np.float32),
            np.zeros((1, 4, 4), dtype=np.float32),
            2,
            src,
            np.zeros(2, dtype=np.int16),
            nsel,
            np.zeros(2, dtype=np.uint8),  # confirming neighbours per pixel (lone_cell_keep)
        )
        assert nsel[0] == 1 and src[0] == (0 if z[0] < z[1] else 1)  # the chosen slot


def test_numba_equals_torch_on_analytic_scene_with_noise_and_edges():
    eyes = [(-0.6, 0.0, 0.0), (0.0, 0.3, 0.0), (0.6, 0.0, 0.0)]
    rig = make_rig(eyes)
    rects = [Rect(PLANE_Z), Rect(1.5, -0.2, 0.2, -0.2, 0.2)]  # wall and a box in front (depth edges)
    frame = render(rig, rects, noise=0.003, seed=1)
    configs = (
        FuseConfig(),
        FuseConfig().replace(cvgc={"visibility_aware": False}),
        FuseConfig().replace(rps={"k_max": 5, "k0": 2.0}),
    )
    for cfg in configs + (
        FuseConfig().replace(rps={"range_priority": True}),
        FuseConfig().replace(rps={"range_priority": True, "k_max": 5, "k0": 2.0}),
    ):
        rt, _ = both(frame, rig, cfg)
        assert len(rt.cloud) > 100


def _drop(frame: Frame, i: int, present: bool) -> Frame:
    depth = frame.depth.clone()
    depth[i] = 0
    pres = frame.present.clone()
    pres[i] = present
    return Frame(frame.index, frame.camera_ids, frame.color, depth, pres)


@pytest.mark.parametrize("name", ["default", "live"])
def test_numba_equals_torch_degraded_cases(name):
    eyes = [(-0.5, 0.0, 0.0), (0.0, 0.0, 0.1), (0.5, 0.0, 0.0)]
    rig = make_rig(eyes)
    frame = render(rig, [Rect(PLANE_Z)], noise=0.002)
    cfg = PRESETS[name]
    # a missing camera
    rt, _ = both(_drop(frame, 1, present=False), rig, cfg)
    assert rt.report.missing == ("cam1",) and len(rt.cloud) > 0
    # all-zero depth in one (present) camera
    rt, _ = both(_drop(frame, 0, present=True), rig, cfg)
    assert rt.report.empty == ("cam0",)
    # every camera empty: an empty cloud, no crash
    empty = Frame(0, frame.camera_ids, frame.color, torch.zeros_like(frame.depth), frame.present)
    rt, _ = both(empty, rig, cfg)
    assert len(rt.cloud) == 0
    # a single camera
    one = make_rig([(0.0, 0.0, 0.0)])
    rt, _ = both(render(one, [Rect(PLANE_Z)], noise=0.002), one, cfg)
    assert len(rt.cloud) > 0 and rt.report.isolated == ("cam0",)
    # two cameras with no overlap (looking in opposite directions)
    far = make_rig([(0.0, 0.0, 0.0), (0.0, 0.0, 1.0)])
    far = far.with_extrinsics({"cam0": look_at((0, 0, 0), (0, 0, -1.0)), "cam1": look_at((0, 0, 1.0), (0, 0, 2.0))})
    fr = render(far, [Rect(PLANE_Z), Rect(-1.5)], noise=0.002)
    rt, _ = both(fr, far, cfg)
    assert set(rt.report.isolated) == {"cam0", "cam1"} and len(rt.cloud) > 0


def test_numba_equals_torch_64_cameras():
    from fuseflow.synth import SimConfig, Simulator

    sim = Simulator(SimConfig(cameras=64, resolution=(32, 24), frames=1))
    rt, _ = both(sim.render(0).frame, sim.rig, FuseConfig())
    assert rt.report.views == 64 and len(rt.cloud) > 0


@pytest.mark.parametrize("factor", [0.5, 1.5])
def test_density_search_count_is_the_output_count(sim_frame, monkeypatch, factor):
    """The compiled s0 search counts min(k, n) per fine cell without running the FPS; at the s0
    it picks, that count is the size of the cloud the full selection then returns."""
    from fuseflow.fuse.density import search_s0 as search

    frame, rig = sim_frame
    base = len(fuse_with_report(frame, rig, FuseConfig(backend="numba")).cloud)
    seen = {}

    def spy(count_at, s0, target, *args, **kwargs):
        seen["s0"], seen["count"] = search(count_at, s0, target, *args, **kwargs)
        return seen["s0"], seen["count"]

    # by module object: the attribute fuseflow.fuse is the function fuse, not the package
    monkeypatch.setattr(sys.modules["fuseflow.fuse.density"], "search_s0", spy)
    cloud = fuse_with_report(frame, rig, FuseConfig(backend="numba", target_points=int(base * factor))).cloud
    assert seen["s0"] != FuseConfig().ash.s0 and len(cloud) == seen["count"]


def test_numba_equals_torch_with_skewed_intrinsics():
    """The compiled path takes pixel rays from per-row / per-column tables only when every
    camera has zero skew; a skewed K (here one camera of three) takes the inline formula and
    must still give the reference's cloud, with and without the multi-view mean."""
    from tests.fuse.scenes import K

    eyes = [(-0.6, 0.0, 0.0), (0.0, 0.3, 0.0), (0.6, 0.0, 0.0)]
    skewed = np.array(K, dtype=np.float64)
    skewed[0, 1] = 3.0
    base = make_rig(eyes)
    cams = list(base.cameras)
    cams[1] = replace(cams[1], K=skewed)
    rig = type(base)(tuple(cams))
    rects = [Rect(PLANE_Z), Rect(1.5, -0.2, 0.2, -0.2, 0.2)]
    frame = render(rig, rects, noise=0.003, seed=2)
    for cfg in (FuseConfig(), FuseConfig().replace(cvgc={"multiview_mean": False})):
        rt, _ = both(frame, rig, cfg)
        assert len(rt.cloud) > 100


def _arrays(cloud) -> list:
    return [
        t.numpy().copy() for t in (cloud.xyz, cloud.rgb, cloud.weight, cloud.camera, cloud.support) if t is not None
    ]


def test_numba_workspace_reuse_across_shapes():
    """The per-thread workspace (and the gated depth, which lives in it) is kept between frames
    of one shape and replaced when the shape changes: the same frame gives the same cloud,
    bit for bit, whatever was fused before it."""
    from fuseflow.fuse.kernels import workspace as nk
    from fuseflow.synth import SimConfig, Simulator

    rig_a = make_rig([(-0.5, 0.0, 0.0), (0.0, 0.2, 0.1), (0.5, 0.0, 0.0)])
    frame_a = render(rig_a, [Rect(PLANE_Z), Rect(1.5, -0.2, 0.2, -0.2, 0.2)], noise=0.003, seed=2)
    sim = Simulator(SimConfig(cameras=6, resolution=(64, 48), frames=1))
    frame_b, rig_b = sim.render(0).frame, sim.rig
    cfg = FuseConfig(backend="numba")
    nk.release_workspace()
    a0 = _arrays(fuse_with_report(frame_a, rig_a, cfg).cloud)
    shape_a = nk._LOCAL.ws.shape
    b0 = _arrays(fuse_with_report(frame_b, rig_b, cfg).cloud)
    assert nk._LOCAL.ws.shape != shape_a
    a1 = _arrays(fuse_with_report(frame_a, rig_a, cfg).cloud)
    a2 = _arrays(fuse_with_report(frame_a, rig_a, cfg.replace(rps={"consensus": False})).cloud)
    a3 = _arrays(fuse_with_report(frame_a, rig_a, cfg).cloud)
    nk.release_workspace()
    b1 = _arrays(fuse_with_report(frame_b, rig_b, cfg).cloud)
    assert len(a0[0]) > 100 and len(b0[0]) > 100 and len(a2) == len(a0) - 1
    for x, y in ((a0, a1), (a0, a3), (b0, b1)):
        assert len(x) == len(y) and all(np.array_equal(p, q) for p, q in zip(x, y))


def test_cells_table_grows_with_the_cells():
    """ash.cells' hash table starts small and is rehashed as cells appear: cell ids in order of
    first appearance, run slots grouped by cell, as a dict gives them."""
    from fuseflow.fuse.kernels.ash import cells

    rng = np.random.default_rng(0)
    n_rows, w = 40, 200
    row_info = np.zeros((n_rows, 3), dtype=np.int64)
    runs = np.zeros((n_rows, w), dtype=np.int64)
    r_n = np.zeros((n_rows, w), dtype=np.int32)
    keys = rng.integers(0, 2**40, size=5000)
    for row in range(n_rows):
        nr = int(rng.integers(0, w))
        row_info[row, 2] = nr
        runs[row, :nr] = keys[rng.integers(0, len(keys), size=nr)]
        r_n[row, :nr] = rng.integers(1, 9, size=nr)
    ref_runs = [(int(runs[row, r]), int(r_n[row, r])) for row in range(n_rows) for r in range(row_info[row, 2])]
    order = list(dict.fromkeys(k for k, _ in ref_runs))
    cid = {k: i for i, k in enumerate(order)}
    sizes = np.zeros(len(order), dtype=np.int64)
    for k, c in ref_runs:
        sizes[cid[k]] += c
    ref_start = np.concatenate([[0], np.cumsum(sizes)])
    fill = ref_start[:-1].copy()
    ref_slot = []
    for k, c in ref_runs:
        ref_slot.append(fill[cid[k]])
        fill[cid[k]] += c
    run_slot = np.empty(len(ref_runs), dtype=np.int32)
    start, cell_key, largest, roff = cells(runs, r_n, row_info, run_slot)
    assert len(order) > 2000  # past several doublings of the 1024-entry table
    assert np.array_equal(start, ref_start) and np.array_equal(cell_key, np.array(order, dtype=np.int64))
    assert largest == sizes.max() and np.array_equal(run_slot, np.array(ref_slot))
    assert np.array_equal(roff, np.concatenate([[0], np.cumsum(row_info[:, 2])]))
