"""The calibration's fast paths against the numpy forms they replace (same results)."""

import warnings

import numpy as np
import pytest

from fuseflow.calib.backbones.rgbd import nanmedian_frames
from fuseflow.calib.backbones.rgbd.ransac_kernels import planar_counts, rigid_counts


def _rotations(rng, n):
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], 1)  # fmt: skip


@pytest.fixture
def data():
    rng = np.random.default_rng(3)
    H, K = 300, 400
    M = np.tile(np.eye(4), (H, 1, 1))
    M[:, :3, :3] = _rotations(rng, H)
    M[:, :3, 3] = rng.normal(size=(H, 3)) * 0.5
    A = rng.normal(size=(K, 3)) + [0, 0, 3]
    B = A @ M[7, :3, :3].T + M[7, :3, 3] + rng.normal(size=(K, 3)) * 0.01  # model 7 explains B
    return M, A, B, 0.05 + 0.01 * B[:, 2]


def test_rigid_matches_einsum(data):
    M, A, B, thr = data
    ref = np.linalg.norm(np.einsum("hij,kj->hki", M[:, :3, :3], A) + M[:, None, :3, 3] - B[None], axis=2)
    counts = rigid_counts(M, A, B, thr)
    np.testing.assert_array_equal(counts, (ref < thr).sum(axis=1))
    near = ref[7] * (1 + 1e-9)  # thresholds just above model 7's distances: all of them count
    assert rigid_counts(M[7:8], A, B, near)[0] == len(A)
    assert int(np.argmax(counts)) == 7 and counts[7] > 0.5 * len(A)


def test_planar_matches_einsum(data):
    M, A, B, thr = data
    M2 = M.copy()
    c, s = M[:, 0, 0], M[:, 1, 0]  # any 2-D rotation per model
    n = np.hypot(c, s)
    M2[:, :2, :2] = np.stack([np.stack([c / n, -s / n], -1), np.stack([s / n, c / n], -1)], 1)
    pa = A[:, :2].copy()
    pb = pa @ M2[7, :2, :2].T + M2[7, :2, 3] + np.random.default_rng(4).normal(size=pa.shape) * 0.01
    dh = np.random.default_rng(5).uniform(0, 0.08, len(pa))  # some over the threshold
    dh[::17] = np.nan  # a NaN height never makes an inlier (numpy.maximum propagates it)
    q = np.einsum("hij,kj->hki", M2[:, :2, :2], pa) + M2[:, None, :2, 3]
    ref = np.maximum(np.linalg.norm(q - pb[None], axis=2), dh[None])
    counts = planar_counts(M2, pa, pb, dh, thr)
    np.testing.assert_array_equal(counts, (ref < thr).sum(axis=1))
    assert int(np.argmax(counts)) == 7 and counts[7] > 0.15 * len(pa)
    big = np.full(len(pa), 1e9)  # every finite residual counts, the NaN heights never
    assert planar_counts(M2[:1], pa, pb, dh, big)[0] == np.isfinite(dh).sum()


def test_empty_inputs():
    M = np.tile(np.eye(4), (3, 1, 1))
    e = np.zeros((0, 3))
    np.testing.assert_array_equal(rigid_counts(M, e, e, np.zeros(0)), [0, 0, 0])
    assert planar_counts(M, e[:, :2], e[:, :2], np.zeros(0), np.zeros(0)).shape == (3,)


@pytest.mark.parametrize("frames", [1, 2, 3, 10])
def test_nanmedian_frames_is_numpys(frames):
    rng = np.random.default_rng(frames)
    X = (rng.random((frames, 40, 50)) * 4).astype(np.float32)
    X[rng.random(X.shape) < 0.3] = np.nan
    X[:, :5] = np.nan  # pixels no frame saw
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        ref = np.nanmedian(X, axis=0)
    out = nanmedian_frames(X)
    assert out.dtype == ref.dtype
    np.testing.assert_array_equal(out, ref)  # NaN where numpy has NaN, else the same bits
    assert np.isnan(out[:5]).all() and np.isfinite(out[5:]).any()
