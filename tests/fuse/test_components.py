"""Each equation of FUSE on tiny hand-computed inputs (paper eq. 16-28)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from tests.fuse.scenes import PLANE_Z, Rect, look_at, make_rig, render

from fuseflow.errors import ValidationError
from fuseflow.fuse import ABLATIONS, NOISE_SIGMA, PRESETS, FuseConfig, neighbour_graph, preset
from fuseflow.fuse.ash import adaptive_hash, fixed_hash
from fuseflow.fuse.cvgc import cvgc_counts, omega_geo
from fuseflow.fuse.mcm import confidence, gradient_and_variance
from fuseflow.fuse.neighbours import NeighbourGraph
from fuseflow.fuse.rps import cell_counts, consensus, select_representatives, selection_priority
from fuseflow.fuse.weights import joint_weight
from fuseflow.geometry import project_votes, relative_transforms


def test_config_presets_and_validation():
    assert PRESETS["default"] == FuseConfig()
    assert PRESETS["paper"].cvgc.visibility_aware is False and PRESETS["paper"].rps.min_weight == 0.0
    assert PRESETS["paper"].cvgc.tau == 0.05
    assert not ABLATIONS["w/o CVGC"].cvgc.enabled and not ABLATIONS["w/o MCM"].mcm.enabled
    assert not ABLATIONS["w/o ASH"].ash.enabled and not ABLATIONS["w/o RPS"].rps.enabled
    with pytest.raises(ValidationError, match="tau"):
        FuseConfig().replace(cvgc={"tau": 0.0})
    with pytest.raises(ValidationError, match="window"):
        FuseConfig().replace(mcm={"window": 4})
    assert PRESETS["paper"].rps.range_priority is False  # eq. (28) ranks by omega alone
    assert PRESETS["paper"].rps.lone_cell_mean == 0.0  # eq. (26) keeps k >= 1 in every cell
    assert PRESETS["paper"].cvgc.multiview_mean is False  # candidates are the pixels' own points
    assert PRESETS["default"] == FuseConfig() and "quality" not in PRESETS
    assert (FuseConfig().cvgc.k_neighbours, FuseConfig().ash.s0) == (7, 5.0)
    assert PRESETS["fast"] == FuseConfig().replace(cvgc={"k_neighbours": 4}, ash={"s0": 6.3})
    assert PRESETS["live"] == FuseConfig().replace(
        pixel_stride=2, ash={"s0": 1.0}, mcm={"max_missing": 4}, smoothing={"radius": 0}
    )
    assert PRESETS["paper"].pixel_stride == 1 and FuseConfig().pixel_stride == 1
    with pytest.raises(ValidationError, match="noise_sigma"):
        FuseConfig(noise_sigma=(0.0, 0.0019, 0.4))
    with pytest.raises(ValidationError, match="noise_sigma"):
        FuseConfig(noise_sigma=(0.0012, 0.0019))
    with pytest.raises(ValidationError, match="no FUSE preset"):
        preset("nope")


def test_mcm_gradient_variance_hand_computed():
    # 3x3 depth with a 0.1 m step to the right: centre pixel (1, 1)
    d = torch.tensor([[[2.0, 2.0, 2.1], [2.0, 2.0, 2.1], [2.0, 2.0, 2.1]]])
    g, v, full = gradient_and_variance(d, 3, eps=0.0)
    assert bool(full[0, 1, 1]) and not bool(full[0, 0, 0])  # border windows leave the image
    assert g[0, 1, 1].item() == pytest.approx(0.05 / 2.0, rel=1e-5)  # (2.1 - 2.0) / 2 / z
    values = np.array([2.0, 2.0, 2.1] * 3)
    assert v[0, 1, 1].item() == pytest.approx(values.var() / 4.0, rel=1e-4)
    c = confidence(d, alpha=20.0, beta=6000.0, eps=0.0)
    want = math.exp(-20.0 * 0.025 - 6000.0 * values.var() / 4.0)
    assert c[0, 1, 1].item() == pytest.approx(want, rel=1e-4)
    assert c[0, 0, 0].item() == 0.0  # incomplete window = edge pixel


def test_mcm_defaults_meet_the_design_targets():
    """docs/design.md 2.1: smooth 45-degree surface c > 0.8, a 5 % depth edge c < 0.05 (f = 525, z = 2 m,
    0.3 % relative noise)."""
    rng = np.random.default_rng(0)
    f, z0 = 525.0, 2.0
    u = np.arange(64)
    plane = z0 * (1 + u / f)[None, :].repeat(64, 0)  # slope of one pixel footprint per pixel
    plane = plane * (1 + 0.003 * rng.standard_normal(plane.shape))
    cfg = FuseConfig()
    c = confidence(torch.tensor(plane[None], dtype=torch.float32), cfg.mcm.alpha, cfg.mcm.beta)
    assert float(c[0, 1:-1, 1:-1].median()) > 0.8
    edge = np.full((16, 16), z0)
    edge[:, 8:] *= 1.05
    c = confidence(torch.tensor(edge[None], dtype=torch.float32), cfg.mcm.alpha, cfg.mcm.beta)
    assert float(c[0, 2:-2, 7:9].max()) < 0.05
    assert float(c[0, 2:-2, 2:5].min()) > 0.99
    off = confidence(torch.tensor(edge[None], dtype=torch.float32), cfg.mcm.alpha, cfg.mcm.beta, use_mcm=False)
    assert bool((off == 1).all())


@pytest.mark.parametrize("z0", [0.5, 1.0, 2.0, 3.0, 4.0, 4.45])
def test_noise_aware_mcm_meets_the_targets_at_every_range(z0):
    """mcm_noise: a smooth 45-degree surface with Kinect noise sigma(z) keeps c > 0.8 and a 5 % depth
    edge gets c < 0.05 at every range of the Kinect's 0.4-4.5 m (config.py, above MCM_ALPHA)."""
    cfg = FuseConfig().replace(mcm={"noise_aware": True})
    assert cfg.noise_sigma == NOISE_SIGMA["kinect"]
    a, b, zc = cfg.noise_sigma
    sigma = a + b * (z0 - zc) ** 2
    rng = np.random.default_rng(1)
    f = 525.0
    plane = z0 * (1 + np.arange(64) / f)[None, :].repeat(64, 0) + sigma * rng.standard_normal((64, 64))
    edge = np.full((64, 16), z0)
    edge[:, 8:] *= 1.05
    edge = edge + sigma * rng.standard_normal(edge.shape)

    def conf(d, noise):
        t = torch.tensor(d[None], dtype=torch.float32)
        return confidence(t, cfg.mcm.alpha, cfg.mcm.beta, noise_sigma=cfg.noise_sigma if noise else None)[0]

    smooth = conf(plane, True)[1:-1, 1:-1]
    assert float(smooth.median()) > 0.9 and float(smooth.quantile(0.1)) > 0.75
    assert float(conf(edge, True)[2:-2, 7:9].median()) < 0.05
    if z0 >= 4.0:  # the paper's measures lose smooth far surfaces to their noise
        assert float(conf(plane, False)[1:-1, 1:-1].median()) < 0.8
    # sigma = 0 changes nothing: the noise-free edge of the design test
    clean = np.full((16, 16), z0)
    clean[:, 8:] *= 1.05
    c = confidence(
        torch.tensor(clean[None], dtype=torch.float32), cfg.mcm.alpha, cfg.mcm.beta, noise_sigma=(0.0, 0.0, 0.0)
    )
    c0 = confidence(torch.tensor(clean[None], dtype=torch.float32), cfg.mcm.alpha, cfg.mcm.beta)
    assert torch.equal(c, c0)


def test_gap_tolerant_window_keeps_surfaces_with_dropouts_and_still_rejects_edges():
    """mcm_max_missing: a smooth 45-degree plane with 5 % isolated dropouts keeps c > 0.8 next to
    the holes (c = 0 there under docs/design.md's rule), a 5 % depth edge with the same dropouts keeps
    a median below 0.05 and no pixel above r_c, and 0 reproduces the strict rule exactly."""
    rng = np.random.default_rng(2)
    f, z0 = 525.0, 2.0
    plane = z0 * (1 + np.arange(64) / f)[None, :].repeat(64, 0) * (1 + 0.003 * rng.standard_normal((64, 64)))
    holes = rng.random((64, 64)) < 0.05
    plane[holes] = 0.0
    edge = np.full((64, 16), z0)
    edge[:, 8:] *= 1.05
    edge[rng.random(edge.shape) < 0.05] = 0.0
    cfg = FuseConfig()
    t = lambda d: torch.tensor(d[None], dtype=torch.float32)  # noqa: E731
    hp = np.pad(holes, 1).astype(int)
    n_missing = sum(hp[1 + dv : 65 + dv, 1 + du : 65 + du] for dv in (-1, 0, 1) for du in (-1, 0, 1))
    near_hole = torch.from_numpy((~holes & (n_missing >= 1) & (n_missing <= 3))[1:-1, 1:-1])
    strict = confidence(t(plane), cfg.mcm.alpha, cfg.mcm.beta)[0, 1:-1, 1:-1]
    tolerant = confidence(t(plane), cfg.mcm.alpha, cfg.mcm.beta, max_missing=3)[0, 1:-1, 1:-1]
    assert float(strict[near_hole].max()) == 0.0
    assert float(tolerant[near_hole].median()) > 0.8
    ce = confidence(t(edge), cfg.mcm.alpha, cfg.mcm.beta, max_missing=3)[0, 2:-2, 7:9]
    # an edge pixel whose far-side neighbours are missing can look smoother (here up to 0.19), so
    # the target is the median, and no edge pixel may pass the candidate threshold r_c
    assert float(ce.median()) < 0.05 and float(ce.max()) < cfg.rps.r_c
    assert torch.equal(
        confidence(t(plane), cfg.mcm.alpha, cfg.mcm.beta, max_missing=0),
        confidence(t(plane), cfg.mcm.alpha, cfg.mcm.beta),
    )


def test_noise_sigma_presets_mirror_the_simulator():
    from fuseflow.synth.config import KINECT_V1, REALSENSE_D435

    k = KINECT_V1.axial
    assert NOISE_SIGMA["kinect"] == (k.a, k.b, k.z0)
    r = REALSENSE_D435
    assert NOISE_SIGMA["realsense"][1] == pytest.approx(r.axial.stereo_rms / (r.focal_px * r.baseline_m))
    assert PRESETS["paper"].mcm.noise_aware is False


def test_consensus_hand_computed():
    """Two cameras on the z axis (origin, looking +z): a representative at depth 2.00, two agreeing
    candidates of the same cell (2.01 from camera 1, 1.995 from camera 0) and one far one (2.2,
    another surface): the point moves to their omega-weighted mean depth, support 2."""
    T_wc = torch.zeros(2, 3, 4)
    T_wc[:, :, :3] = torch.eye(3)
    T_cw = torch.eye(4).repeat(2, 1, 1)
    P = torch.tensor([[0.0, 0, 2.0], [0.0, 0, 2.01], [0.0, 0, 1.995], [0.0, 0, 2.2], [1.0, 0, 2.0]])
    omega = torch.tensor([1.0, 0.5, 1.0, 1.0, 1.0])
    cam = torch.tensor([0, 1, 0, 1, 0])
    inv = torch.tensor([0, 0, 0, 0, 1])
    sel = torch.tensor([0, 4])
    ns = (0.0012, 0.0019, 0.4)  # sigma(2 m) = 6.1 mm: gate 3 sigma = 18 mm keeps 2.01, drops 2.2
    xyz, sup = consensus(P, omega, cam, T_wc, T_cw, inv, sel, 3.0, ns)
    want = (1.0 * 2.0 + 0.5 * 2.01 + 1.0 * 1.995) / 2.5
    assert xyz[0, 2].item() == pytest.approx(want, abs=1e-6) and xyz[0, :2].abs().max().item() < 1e-7
    assert sup.tolist() == [2, 1] and torch.equal(xyz[1], P[4])  # alone in its cell: unchanged
    xyz, sup = consensus(P, omega, cam, T_wc, T_cw, inv, sel, 0.5, ns)  # 3 mm gate: only itself
    assert xyz[0, 2].item() == pytest.approx(2.0, abs=1e-6) and sup.tolist() == [1, 1]


def test_cvgc_residual_and_votes_hand_computed():
    K = torch.tensor([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]])
    M = torch.tensor([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0]])  # j = i
    depth_j = torch.zeros(101, 101)
    depth_j[50, 50] = 2.05  # 2.5 % behind a point at z = 2 -> agree
    depth_j[50, 60] = 2.5  # 25 % behind -> free-space violation, votes against
    depth_j[50, 40] = 1.0  # in front -> point occluded in j
    X = torch.tensor([[0.0, 0.0, 2.0], [0.2, 0.0, 2.0], [-0.2, 0.0, 2.0], [0.0, 0.2, 2.0], [5.0, 0.0, 2.0]])
    agree, vote = project_votes(X, M, K, depth_j, tau=0.05, visibility_aware=False)
    assert agree.tolist() == [True, False, False, False, False]
    assert vote.tolist() == [True, True, True, False, False]  # no depth / outside image: no vote
    agree, vote = project_votes(X, M, K, depth_j, tau=0.05, visibility_aware=True)
    assert vote.tolist() == [True, True, False, False, False]  # occluded: no vote
    # eq. (21): share of agreeing votes, c where there is none
    w = omega_geo(torch.tensor([1, 0, 0]), torch.tensor([2, 1, 0]), torch.tensor([0.9, 0.9, 0.7]))
    assert w.tolist() == pytest.approx([0.5, 0.0, 0.7])


def test_relative_transform_is_camera_i_to_camera_j():
    rig = make_rig([(-0.3, 0, 0), (0.3, 0.1, 0)])
    T = rig.T_cam_world()
    M = relative_transforms(T)
    X_w = np.array([0.1, 0.2, 2.0, 1.0])
    Xi = rig[0].T_cam_world @ X_w
    Xj = rig[1].T_cam_world @ X_w
    got = M[0, 1].double().numpy() @ Xi
    assert np.allclose(got, Xj[:3], atol=1e-5)


def test_joint_weight_harmonic_mean():
    c = torch.tensor([1.0, 0.9, 0.9, 0.0])
    g = torch.tensor([1.0, 0.1, 0.9, 1.0])
    w = joint_weight(c, g, eps=0.0)
    assert w.tolist() == pytest.approx([1.0, 2 * 0.09 / 1.0, 0.9, 0.0])
    assert bool((w <= 2 * torch.minimum(c, g)).all())  # the dual gate


def test_ash_hand_computed():
    s_c = 0.2
    # 8 points in coarse cell (0,0,0), 1 point in cell (1,0,0)
    P = torch.tensor([[0.01 * i + 0.0007, 0.05, 0.05] for i in range(8)] + [[0.25, 0.01, 0.01]], dtype=torch.float32)
    cells = adaptive_hash(P, s_c, s0=0.01, s_min=0.002, s_max=0.05, eps=0.0)
    rho = 8 / s_c**3
    s_f = min(max(0.01 / math.sqrt(rho), 0.002), 0.05)
    assert cells.cell_size[0].item() == pytest.approx(s_f, rel=1e-5)
    assert cells.cell_size[8].item() == pytest.approx(min(max(0.01 / math.sqrt(1 / s_c**3), 0.002), 0.05), rel=1e-5)
    fine_x = (cells.key[:8] >> 14) & 127
    assert fine_x.tolist() == [math.floor((0.01 * i + 0.0007) / s_f) for i in range(8)]
    assert len(set(cells.key.tolist())) == len({math.floor((0.01 * i + 0.0007) / s_f) for i in range(8)}) + 1
    fixed = fixed_hash(P, 0.1)
    assert len(set(fixed.key.tolist())) == 2


def test_rps_weighted_fps_hand_computed():
    # one cell, four points on a line; omega favours point 1; k = 3
    P = torch.tensor([[0.0, 0, 0], [0.001, 0, 0], [0.004, 0, 0], [0.010, 0, 0]])
    omega = torch.tensor([0.5, 0.9, 0.8, 0.3])
    inv = torch.zeros(4, dtype=torch.int64)
    sel = select_representatives(P, omega, inv, torch.tensor([3]), 3)
    # round 1: highest omega (1); round 2: argmax d*omega = {0: .0005, 2: .0024, 3: .0027} -> 3;
    # round 3: d to {1, 3}: {0: .001*.5, 2: .003*.8} -> 2
    assert sel.tolist() == [1, 3, 2]
    # eq. (26): denser cell gets more points
    key = torch.tensor([5, 5, 5, 5, 9])
    size = torch.full((5,), 0.01)
    inv, counts, k = cell_counts(key, size, k0=1.0, ratio=1.0, k_max=3, density_adaptive=True, k_fixed=0)
    assert counts.tolist() == [4, 1] and k.tolist() == [2, 1]  # rho / rho_bar = 4 / 2.5 -> ceil 1.6 = 2


def test_range_priority_selects_the_near_point_of_equal_omega_first():
    # one cell, a point 3.5 m from its camera and one 2 m from its camera, equal omega
    P = torch.tensor([[0.0, 0, 0], [0.001, 0, 0], [0.005, 0, 0]])
    omega = torch.tensor([0.9, 0.9, 0.9])
    inv = torch.zeros(3, dtype=torch.int64)
    sigma = FuseConfig().noise_sigma
    assert select_representatives(P, omega, inv, torch.tensor([1]), 1).tolist() == [0]  # tie: input order
    for z, near in (([3.5, 2.0, 3.5], 1), ([2.0, 3.5, 3.5], 0)):
        pr = selection_priority(omega, torch.tensor(z), sigma)
        # sigma(2 m) = 1.2 + 1.9 * 1.6^2 = 6.06 mm, sigma(3.5 m) = 19.46 mm
        assert pr[near].item() == pytest.approx(0.9 / 0.006064, rel=1e-5)
        assert select_representatives(P, pr, inv, torch.tensor([1]), 1).tolist() == [near]
    # FPS round 2 (eq. 28 on the ranking value): d * omega / sigma. From point 1 (z = 2 m):
    # point 0 at 1 mm, 3.5 m (0.001 / 0.01946 = 0.051) loses to point 2 at 4 mm, 3.5 m (0.206);
    # a near point 2 mm away (0.002 / 0.00606 = 0.33) beats both.
    pr = selection_priority(torch.full((4,), 0.9), torch.tensor([3.5, 2.0, 3.5, 2.0]), sigma)
    P4 = torch.tensor([[0.0, 0, 0], [0.001, 0, 0], [0.005, 0, 0], [0.003, 0, 0]])
    sel = select_representatives(P4, pr, torch.zeros(4, dtype=torch.int64), torch.tensor([3]), 3)
    assert sel.tolist() == [1, 3, 2]


@pytest.mark.parametrize("backend", ["torch", "numba"])
def test_range_priority_prefers_the_near_camera_and_keeps_weights(backend):

    from fuseflow.fuse import fuse

    # cam0 2 m from the wall, cam1 1 m from it (both look at the same patch); cam0 comes first
    # in input order, so ties (equal omega) go to the far camera without the switch
    rig = make_rig([(0.05, 0.0, 0.0), (-0.05, 0.0, 1.0)])
    frame = render(rig, [Rect(PLANE_Z)], noise=0.0005, seed=2)
    base = FuseConfig().replace(backend=backend, rps={"k_max": 1})
    off = fuse(frame, rig, base)
    on = fuse(frame, rig, base.replace(rps={"range_priority": True}))

    # the near camera's footprint on the wall: |x|, |y| < ~0.6 m
    def near_share(cloud):
        xyz = cloud.xyz.numpy()
        inner = (np.abs(xyz[:, 0]) < 0.4) & (np.abs(xyz[:, 1]) < 0.3)
        return (cloud.camera.numpy()[inner] == 1).mean()

    assert near_share(on) > 0.95 and near_share(on) > near_share(off) + 0.2
    # only the selection changes: with every point of every cell kept, same points and weights
    # (multiview_mean off: it pulls the two cameras' points of a patch together, so some cells
    # then hold more than 16 points and "keep all" would not keep them all)
    keep_all = base.replace(rps={"k_max": 16, "k0": 1000.0}, cvgc={"multiview_mean": False})
    a, b = fuse(frame, rig, keep_all), fuse(frame, rig, keep_all.replace(rps={"range_priority": True}))
    oa, ob = np.lexsort(a.xyz.numpy().T), np.lexsort(b.xyz.numpy().T)
    assert np.array_equal(a.xyz.numpy()[oa], b.xyz.numpy()[ob])
    assert np.array_equal(a.weight.numpy()[oa], b.weight.numpy()[ob])


def test_neighbour_graph_bounded_and_cached():
    eyes = [(np.cos(a) * 1.5, 0.0, PLANE_Z - np.sin(a) * 1.5) for a in np.linspace(0.3, 2.8, 6)]
    rig = make_rig(eyes)
    g = neighbour_graph(rig, k_max=2)
    assert g.index.shape == (6, 2)
    assert all(i not in row for i, row in enumerate(g.index.tolist()))
    assert not np.shares_memory(neighbour_graph(rig, k_max=2).index, g.index)  # copies out
    from fuseflow.geometry.overlap import _graph_cached

    hits = _graph_cached.cache_info().hits
    neighbour_graph(rig, k_max=2)
    assert _graph_cached.cache_info().hits == hits + 1
    # an arc around one target: every camera has a neighbour, ordered by overlap
    assert (g.index[:, 0] >= 0).all()
    assert bool((g.overlap[:, 0] >= g.overlap[:, 1]).all())
    # cameras looking away from each other: no neighbours
    far = make_rig([(0, 0, 0), (0, 0, 1.0)])
    far = far.with_extrinsics({"cam0": look_at((0, 0, 0), (0, 0, -1.0)), "cam1": look_at((0, 0, 1.0), (0, 0, 2.0))})
    assert (neighbour_graph(far, k_max=2, min_overlap=0.05).index == -1).all()


def test_cvgc_counts_uses_graph_and_present():
    rig = make_rig([(-0.3, 0, 0), (0.3, 0, 0)])
    fr = render(rig, [Rect(PLANE_Z)])
    K = rig.K()
    T = rig.T_cam_world()
    X = torch.tensor([[0.0, 0.0, 2.0]])
    graph = NeighbourGraph(torch.tensor([[1], [0]]), torch.tensor([[1.0], [1.0]]))
    a, v = cvgc_counts(X, torch.tensor([0]), fr.depth, K, T, graph, torch.tensor([True, True]))
    assert (a.item(), v.item()) == (1, 1)
    a, v = cvgc_counts(X, torch.tensor([0]), fr.depth, K, T, graph, torch.tensor([True, False]))
    assert (a.item(), v.item()) == (0, 0)


def test_lone_cell_mean_drops_only_lone_points_of_dense_coarse_cells():
    """k = 0 for a one-point fine cell when its coarse cell averages >= lone_cell_mean points per
    occupied fine cell; a lone point of a sparse coarse cell, and a populated cell, keep k >= 1."""
    from fuseflow.fuse.ash import FINE_BITS
    from fuseflow.fuse.rps import cell_counts, select_representatives

    coarse = lambda c: c << (3 * FINE_BITS)  # noqa: E731
    # coarse 1: fine cells 0 (6 points), 1 (6 points), 2 (lone) -> 13 / 3 = 4.3 per fine cell
    # coarse 2: fine cells 0 (1 point), 1 (2 points) -> 1.5 per fine cell (sparse)
    key = torch.tensor(
        [coarse(1) | 0] * 6 + [coarse(1) | 1] * 6 + [coarse(1) | 2] + [coarse(2) | 0] + [coarse(2) | 1] * 2
    )
    size = torch.full((len(key),), 0.02)
    inv, counts, k_off = cell_counts(key, size, 3.0, 1.0, 3, True, 0)
    _, _, k_on = cell_counts(key, size, 3.0, 1.0, 3, True, 0, lone_cell_mean=4.0)
    lone_cell = int(inv[12])
    assert k_off[lone_cell] >= 1 and k_on[lone_cell] == 0
    others = torch.arange(len(k_on)) != lone_cell
    assert torch.equal(k_on[others], k_off[others])
    P = torch.rand(len(key), 3)
    sel = select_representatives(P, torch.rand(len(key)), inv, k_on, 3)
    assert 12 not in sel.tolist() and 13 in sel.tolist()  # sparse coarse cell's lone point stays
    with pytest.raises(ValidationError, match="lone_cell_mean"):
        FuseConfig().replace(rps={"lone_cell_mean": -1.0})
