"""Each stage's compiled kernel (fuse/kernels/) against a small plain-numpy reference of its
equations on a tiny input: MCM (eq. 16-18), CVGC (eq. 19-21), the depth gate, ASH (eq. 23-25),
RPS (eq. 26) and the shared helpers. The whole path against the PyTorch reference is
tests/fuse/test_numba.py."""

from __future__ import annotations

import numpy as np
import pytest

from fuseflow.fuse import FuseConfig
from fuseflow.geometry.camera import relative_transforms

pytest.importorskip("numba")

F = np.float32


def _params(**kw):
    from fuseflow.fuse.kernels import kernel_params

    return kernel_params(FuseConfig().replace(**kw))


# --- MCM (eq. 16-18) ---------------------------------------------------------------------


def _mcm_reference(win: np.ndarray, alpha: float, beta: float, eps: float, max_missing: int) -> float:
    """c(x) of one 3x3 window (float64): -1 when the centre has no depth or too many are missing."""
    z = win[1, 1]
    ok = win > 0
    if z <= 0 or 9 - ok.sum() > max_missing:
        return -1.0
    vals = win[ok].astype(np.float64)
    var = ((vals - vals.mean()) ** 2).mean()

    def grad(lo, hi):
        if lo > 0 and hi > 0:
            return (hi - lo) / 2
        if hi > 0:
            return hi - z
        if lo > 0:
            return z - lo
        return 0.0

    gx, gy = grad(win[1, 0], win[1, 2]), grad(win[0, 1], win[2, 1])
    g = np.sqrt(gx * gx + gy * gy) / (z + eps)
    v = var / (z * z + eps)
    return float(np.exp(-alpha * g - beta * v))


@pytest.mark.parametrize("max_missing", [0, 4])
@pytest.mark.parametrize("stride", [1, 2, 3])
def test_mcm_row_is_eq_16_to_18(max_missing, stride):
    """c(x) at the grid columns u0, u0 + stride, ... (u0 = 1 on every pixel, else stride)."""
    from fuseflow.fuse.kernels.mcm import mcm_row

    rng = np.random.default_rng(0)
    w = 48
    depth = (1.5 + 0.01 * rng.standard_normal((3, w))).astype(F)
    depth[rng.random((3, w)) < 0.1] = 0.0  # holes: incomplete windows
    prm = _params(mcm={"max_missing": max_missing}).pixel
    cc, gq, vr = np.empty(w, F), np.empty(w, F), np.empty(w, F)
    u0 = 1 if stride == 1 else stride
    mcm_row(depth[0], depth[1], depth[2], prm, u0, stride, gq, vr, cc)
    grid = range(u0, w - 1, stride)
    for u in grid:
        ref = _mcm_reference(depth[:, u - 1 : u + 2], prm.alpha, prm.beta, prm.eps, max_missing)
        if ref < 0:
            assert cc[u] < 0, u
        else:
            assert cc[u] == pytest.approx(ref, rel=2e-4, abs=1e-6), u
    assert sum(cc[u] >= 0 for u in grid) > 2 and sum(cc[u] < 0 for u in grid) > 0


# --- CVGC (eq. 19-21) --------------------------------------------------------------------


def test_votes_count_agreeing_and_voting_neighbours():
    """Candidates of camera 0 projected into camera 1 onto pixels whose depth agrees (eq. 21's
    r < tau), lies behind (votes, disagrees), lies in front (occluded: no vote when visibility
    aware), or is missing (no vote)."""
    from fuseflow.fuse.kernels.common import ray_tables
    from fuseflow.fuse.kernels.cvgc import votes

    h = w = 16
    K = np.array([[20.0, 0, 7.5], [0, 20.0, 7.5], [0, 0, 1]], F)
    T = np.stack([np.eye(4), np.eye(4)]).astype(F)
    T[1, 0, 3] = -0.1  # camera 1 is 10 cm to the side
    M_rel = relative_transforms(T)
    depth = np.zeros((2, h, w), F)
    cases = {"agree": 1.01, "behind": 1.3, "front": 0.7, "none": 0.0}
    X, Y, Z, expect = [], [], [], []
    for k, (kind, f) in enumerate(cases.items()):
        u, v, zj = 3 + 2 * k, 5 + k, F(2.0)
        xj, yj = (u - 7.5) / 20.0 * zj, (v - 7.5) / 20.0 * zj  # pixel centre of camera 1 at zj
        p0 = np.linalg.inv(T[1].astype(np.float64)) @ np.array([xj, yj, zj, 1.0])  # in camera 0 (= world)
        X.append(p0[0]), Y.append(p0[1]), Z.append(p0[2])
        depth[1, v, u] = zj * f
        expect.append({"agree": (1, 1), "behind": (0, 1), "front": (0, 0), "none": (0, 0)}[kind])
    nc = len(X)
    X, Y, Z = (np.array(a, F) for a in (X, Y, Z))
    prm = _params().pixel._replace(mv_mean=False)
    xt, yt, skew0 = ray_tables(K[None].repeat(2, 0), h, w)
    i32 = [np.zeros(nc, np.int32) for _ in range(5)]  # idx, ius, ivs, ag, vo
    f32 = [np.zeros(nc, F) for _ in range(9)]  # zjs, dv, xq, yq, mx, my, mz, md, v0
    ns = np.zeros(nc, np.int32)
    idx, ius, ivs, ag, vo = i32
    zjs, dv, xq, yq, mx, my, mz, md, v0 = f32
    votes(depth.reshape(-1), K[None].repeat(2, 0), M_rel, xt, yt, skew0, 0, 1, h, w, nc, X, Y, Z, v0, prm,
          zjs, idx, ius, ivs, dv, xq, yq, ag, vo, mx, my, mz, md, ns)  # fmt: skip
    assert [(int(a), int(b)) for a, b in zip(ag, vo)] == expect
    assert np.allclose(zjs, 2.0, atol=1e-5) and (idx >= 0).all()
    # without the visibility switch an occluding depth votes too (and disagrees)
    ag[:], vo[:] = 0, 0
    votes(depth.reshape(-1), K[None].repeat(2, 0), M_rel, xt, yt, skew0, 0, 1, h, w, nc, X, Y, Z, v0,
          prm._replace(visibility_aware=False), zjs, idx, ius, ivs, dv, xq, yq, ag, vo, mx, my, mz, md, ns)  # fmt: skip
    assert list(vo) == [1, 1, 1, 0] and list(ag) == [1, 0, 0, 0]


# --- stage 1: the depth gate ---------------------------------------------------------------


def test_gate_rows_keeps_depth_inside_the_range_of_present_views():
    from fuseflow.fuse.kernels.pixels import gate_rows

    rng = np.random.default_rng(1)
    depth = rng.uniform(0.0, 5.0, (3, 4, 6)).astype(F)
    lo, hi = np.array([0.5, 1.0, 0.5], F), np.array([4.0, 3.0, 4.0], F)
    present = np.array([True, True, False])
    out, rows = np.empty_like(depth), np.empty(12, np.int64)
    gate_rows(depth, lo, hi, present, out, rows)
    keep = (depth > lo[:, None, None]) & (depth < hi[:, None, None]) & present[:, None, None]
    assert np.array_equal(out, np.where(keep, depth, 0))
    assert np.array_equal(rows, keep.sum(axis=2).reshape(-1))


# --- ASH (eq. 23-25) ---------------------------------------------------------------------


def test_fine_pass_is_eq_23_to_25():
    """One coarse cell: the fine size of eq. (24), fine cells of eq. (25) in first-appearance
    order (stable inside a cell), their densities' sum for rho_bar."""
    from fuseflow.fuse.kernels.ash import fine_pass

    cfg = FuseConfig()
    prm = _params().cell
    s_c, off, bits = float(prm.s_c), prm.offset, prm.bits
    rng = np.random.default_rng(2)
    n = 300
    q = np.array([3, -2, 5])  # the coarse cell
    P = ((q + rng.uniform(0.0, 1.0, (n, 3))) * s_c).astype(F)
    key = ((q[0] + off) << (2 * bits)) | ((q[1] + off) << bits) | (q[2] + off)
    start, cell_key, chunks = np.array([0, n]), np.array([key], np.int64), np.array([0, 1])
    members = np.arange(n, dtype=np.int32)
    fkey, om = np.empty(n, np.int32), rng.uniform(0.1, 1.0, n).astype(F)
    csize, rho_sum, fine_n = np.empty(1, F), np.empty(1), np.empty(1, np.int64)
    omc, camc, sup = np.empty(n, F), np.empty(n, np.int16), np.zeros(n, np.uint8)
    Pc = P.copy()
    fine_pass(Pc, start, cell_key, prm, chunks, n, True, members, fkey, csize, rho_sum, fine_n, om, om, False,
              n, omc, omc, camc, sup)  # fmt: skip
    rho = n / F(s_c) ** 3  # eq. (23)
    sf = np.clip(cfg.ash.s0 / np.sqrt(rho + cfg.eps), cfg.ash.s_min, cfg.ash.s_max)  # eq. (24)
    assert csize[0] == pytest.approx(sf, rel=1e-6)
    origin = (q * F(s_c)).astype(F)
    idx = np.clip(np.floor((P - origin) / csize[0]), 0, 127).astype(np.int64)  # eq. (25)
    groups = list(dict.fromkeys(map(tuple, idx)))
    order = sorted(range(n), key=lambda t: (groups.index(tuple(idx[t])), t))
    assert fine_n[0] == len(groups) and np.array_equal(members, np.array(order))
    assert np.array_equal(Pc, P[order]) and np.array_equal(omc, om[order])
    assert np.array_equal(fkey, np.array([groups.index(tuple(idx[t])) for t in order]))
    sizes = np.bincount(fkey)
    assert rho_sum[0] == pytest.approx(float((sizes / np.float64(csize[0]) ** 3).sum()), rel=1e-5)


# --- RPS (eq. 26) ------------------------------------------------------------------------


def test_cell_k_and_count_are_eq_26():
    from fuseflow.fuse.kernels.rps import cell_k, count_kept

    sel = _params(rps={"lone_cell_mean": 0.0}).select._replace(rho_bar=F(2.0e5))
    sf3 = F(0.01) ** 3
    for n in (1, 2, 3, 5, 9):
        ref = int(np.clip(np.ceil(sel.k0 * (n / sf3) / sel.rho_bar * sel.ratio), 1, sel.k_max))
        assert cell_k(n, 50, 10, sf3, sel, 0) == ref
    lone = sel._replace(lone_cell_mean=2.0, lone_keep=1)
    assert cell_k(1, 50, 10, sf3, lone, 0) == 0  # a lone point of a dense coarse cell
    k1 = cell_k(1, 50, 10, sf3, sel, 0)  # eq. (26) for one point
    assert k1 >= 1
    assert cell_k(1, 50, 10, sf3, lone, 1) == k1  # ... confirmed by a neighbour camera
    assert cell_k(1, 5, 10, sf3, lone, 0) == k1  # a sparse coarse cell keeps it
    # count_kept: min(k, n) per fine cell, summed per coarse cell
    gsize = np.array([1, 4, 9, 2, 7])
    start, fine_n, csize = np.array([0, 3, 5]), np.array([3, 2]), np.array([0.01, 0.01], F)
    out = np.empty(2, np.int64)
    count_kept(start, gsize, np.zeros(5, np.int16), csize, fine_n, sel, out)
    ks = [min(cell_k(int(n), 0, 1, sf3, sel, 0), int(n)) for n in gsize]
    assert list(out) == [sum(ks[:3]), sum(ks[3:])]


# --- shared helpers ----------------------------------------------------------------------


def test_shared_helpers():
    from fuseflow.fuse.kernels.common import cam_of, chunk_bounds, ray_tables, ray_x

    K = np.array([[[500.0, 0, 319.5], [0, 510.0, 239.5], [0, 0, 1]]], F)
    xt, yt, skew0 = ray_tables(K, 4, 6)
    assert skew0 and np.array_equal(yt[0], (np.arange(4, dtype=F) - F(239.5)) / F(510.0))
    assert np.array_equal(xt[0], (np.arange(6, dtype=F) - F(319.5)) / F(500.0))
    Ks = K.copy()
    Ks[0, 0, 1] = 2.0
    xs, ys, skew = ray_tables(Ks, 4, 6)
    assert not skew and ray_x(Ks, xs, 0, 3, ys[0, 2], skew) == (F(3) - F(319.5) - F(2.0) * ys[0, 2]) / F(500.0)
    hw = 640 * 480
    for p in np.random.default_rng(3).integers(0, 64 * hw, 2000):
        assert cam_of(np.int64(p), hw, 1.0 / hw) == p // hw
    start = np.concatenate([[0], np.cumsum(np.random.default_rng(4).integers(1, 50, 100))])
    b = chunk_bounds(start, 8)
    assert b[0] == 0 and b[-1] == 100 and (np.diff(b) >= 0).all()


def test_a_kernel_cache_is_stamped_with_every_file_of_the_package():
    """A kernel inlines kernels of the package's other files and sigma(z) of geometry/noise.py:
    its cache is valid only while none of them changed (io/numba_cache.py)."""
    from pathlib import Path

    from fuseflow.fuse import kernels
    from fuseflow.fuse.kernels.pixels import pixels
    from fuseflow.geometry import noise

    stamped = {Path(f).name for f, _, _ in pixels._cache._impl.locator.get_source_stamp()}
    package = {p.name for p in Path(kernels.__file__).parent.glob("*.py")}
    assert package <= stamped and "noise.py" in stamped and Path(noise.__file__).name == "noise.py"
