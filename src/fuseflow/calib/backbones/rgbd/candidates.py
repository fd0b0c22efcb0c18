"""Candidate relative poses of one camera pair (step 2 of the package outline): the ``floor``
route (top-down SIFT, 4-DoF), the ``sift3d`` / ``sift4`` routes (image matches lifted by depth,
6-DoF and 4-DoF), each by sequential RANSAC with a fixed seed."""

from __future__ import annotations

import numpy as np

from fuseflow.calib.backbones.rgbd.config import RGBDConfig
from fuseflow.calib.backbones.rgbd.evidence import CameraEvidence, image_matcher
from fuseflow.calib.geometric import kabsch
from fuseflow.types import invert_rigid


def _match(da: np.ndarray, db: np.ndarray, ratio: float) -> np.ndarray:
    """(K, 2) index pairs of ratio-test SIFT matches from descriptors a to b."""
    import cv2

    if len(da) < 2 or len(db) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    knn = cv2.BFMatcher(cv2.NORM_L2).knnMatch(da, db, k=2)
    out = [(m[0].queryIdx, m[0].trainIdx) for m in knn if len(m) == 2 and m[0].distance < ratio * m[1].distance]
    return np.array(out, dtype=np.int64).reshape(-1, 2)


def _ransac_sequential(fit_batch, fit_refine, residual, thr, m: int, k_min: int, cfg: RGBDConfig, seed: int):
    """Sequential RANSAC: up to cfg.hypotheses models, each the largest consensus of the matches
    the previous ones did not explain. fit_batch(idx (H, k_min)) -> models (H, 4, 4);
    residual(models (H, 4, 4), idx) -> (H, |idx|) distances, residual(models, idx, thr_idx) ->
    (H,) counts of distances under thr_idx (``calib.backbones.rgbd.ransac_kernels``); thr (m,) per-match threshold.
    Returns [(model (4, 4), inlier indices)]."""
    rng = np.random.default_rng(seed)
    left = np.arange(m)
    out = []
    for _ in range(cfg.hypotheses):
        if len(left) < max(cfg.min_inliers, k_min):
            break
        iters = cfg.ransac_iterations if k_min > 2 else cfg.ransac_iterations // 2
        idx = rng.integers(0, len(left), size=(iters, k_min))
        distinct = np.all(np.sort(idx, axis=1)[:, 1:] != np.sort(idx, axis=1)[:, :-1], axis=1)
        idx = idx[distinct]
        models = fit_batch(left[idx])
        ok = np.all(np.isfinite(models), axis=(1, 2))
        models = models[ok]
        if not len(models):
            break
        best = int(np.argmax(residual(models, left, thr[left])))
        sel = left[residual(models[best][None], left)[0] < thr[left]]
        if len(sel) < cfg.min_inliers:
            break
        model = models[best]
        for _ in range(3):  # refit on the consensus, re-collect
            model = fit_refine(sel)
            new = left[residual(model[None], left)[0] < thr[left]]
            if len(new) < cfg.min_inliers:
                break
            sel = new
        out.append((model, sel))
        left = np.setdiff1d(left, sel)
    return out


def _f64(a: np.ndarray) -> np.ndarray:
    """a as a C-contiguous float64 array (the compiled residuals' input; exact for float32)."""
    return np.ascontiguousarray(a, dtype=np.float64)


def _planar_models(pa: np.ndarray, pb: np.ndarray) -> callable:
    """Batched 2-point rigid 2-D fits pb ~ R(theta) pa + t, as 4x4 floor-frame transforms."""

    def fit(idx: np.ndarray) -> np.ndarray:
        A, B = pa[idx], pb[idx]  # (H, k, 2)
        ca, cb = A.mean(axis=1), B.mean(axis=1)
        a, b = A - ca[:, None], B - cb[:, None]
        s = np.sum(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0], axis=1)
        c = np.sum(a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1], axis=1)
        th = np.arctan2(s, c)
        T = np.tile(np.eye(4), (len(idx), 1, 1))
        T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = np.cos(th), -np.sin(th), np.sin(th), np.cos(th)
        T[:, :2, 3] = cb - np.einsum("hij,hj->hi", T[:, :2, :2], ca)
        if idx.shape[1] == 2:  # minimal sample: the two distances must agree
            la = np.linalg.norm(A[:, 0] - A[:, 1], axis=1)
            lb = np.linalg.norm(B[:, 0] - B[:, 1], axis=1)
            T[np.abs(la - lb) > 0.05 + 0.02 * la] = np.nan
        return T

    return fit


def floor_candidates(a: CameraEvidence, b: CameraEvidence, cfg: RGBDConfig, frame_pairs) -> list[dict]:
    """Candidates of the two 4-DoF routes: ``floor`` (top-down SIFT) and ``sift4`` (image SIFT
    matches expressed on the floor). frame_pairs: (X_a (K, 3), X_b (K, 3)) pooled 3-D matches."""
    if a.plane is None or b.plane is None:
        return []
    from fuseflow.calib.backbones.rgbd.ransac_kernels import planar_counts

    Fa, Fb = a.plane.T_cam_floor(), b.plane.T_cam_floor()
    out = []
    routes = []
    if len(a.td_desc) and len(b.td_desc):
        mm = _match(a.td_desc, b.td_desc, cfg.ratio)
        if len(mm):
            pa, pb = a.td_xy[mm[:, 0]], b.td_xy[mm[:, 1]]
            za = np.zeros(len(pa))
            routes.append(("floor", pa, pb, za, za, None, None))
    Xa, Xb = frame_pairs
    if len(Xa):
        Pa = (Xa - Fa[:3, 3]) @ Fa[:3, :3]  # floor coordinates
        Pb = (Xb - Fb[:3, 3]) @ Fb[:3, :3]
        routes.append(("sift4", Pa[:, :2], Pb[:, :2], Pa[:, 2], Pb[:, 2], Xa, Xb))
    for route, pa, pb, ha, hb, Xa_, Xb_ in routes:
        fit = _planar_models(pa, pb)
        thr_h = cfg.floor_inlier_m if route == "floor" else cfg.inlier_m + cfg.inlier_rel * Xb_[:, 2]
        thr = np.broadcast_to(
            np.asarray(cfg.floor_inlier_m if route == "floor" else thr_h, dtype=np.float64), (len(pa),)
        )

        def residual(models, idx, thr_idx=None, pa=pa, pb=pb, ha=ha, hb=hb):
            dh = np.abs(ha[idx] - hb[idx])  # heights must agree too
            if thr_idx is not None:
                return planar_counts(models, _f64(pa[idx]), _f64(pb[idx]), _f64(dh), _f64(thr_idx))
            q = np.einsum("hij,kj->hki", models[:, :2, :2], pa[idx]) + models[:, None, :2, 3]
            return np.maximum(np.linalg.norm(q - pb[idx][None], axis=2), dh[None])

        models = _ransac_sequential(fit, lambda s, fit=fit: fit(s[None])[0], residual, thr, len(pa), 2, cfg, cfg.seed)
        for model, sel in models:
            T_ba = Fb @ model @ invert_rigid(Fa)
            if route == "floor":
                Xa_s = np.c_[pa[sel], np.zeros(len(sel))] @ Fa[:3, :3].T + Fa[:3, 3]
                Xb_s = np.c_[pb[sel], np.zeros(len(sel))] @ Fb[:3, :3].T + Fb[:3, 3]
            else:
                Xa_s, Xb_s = Xa_[sel], Xb_[sel]
            out.append({"route": route, "T_ba": T_ba, "inliers": int(len(sel)), "X_a": Xa_s, "X_b": Xb_s})
    return out


def sift3d_candidates(Xa: np.ndarray, Xb: np.ndarray, cfg: RGBDConfig) -> list[dict]:
    """6-DoF 3-D RANSAC (Kabsch) on depth-lifted image matches."""
    if len(Xa) < max(cfg.min_inliers, 3):
        return []
    from fuseflow.calib.backbones.rgbd.ransac_kernels import rigid_counts

    thr = cfg.inlier_m + cfg.inlier_rel * Xb[:, 2]

    def fit(idx):
        T = kabsch(Xa[idx], Xb[idx])
        if idx.shape[1] == 3:  # minimal sample: reject near-degenerate (collinear, tiny) triples
            A = Xa[idx]
            area = np.linalg.norm(np.cross(A[:, 1] - A[:, 0], A[:, 2] - A[:, 0]), axis=1)
            T[area < 0.01] = np.nan
        return T

    def residual(models, idx, thr_idx=None):
        if thr_idx is not None:
            return rigid_counts(models, _f64(Xa[idx]), _f64(Xb[idx]), _f64(thr_idx))
        q = np.einsum("hij,kj->hki", models[:, :3, :3], Xa[idx]) + models[:, None, :3, 3]
        return np.linalg.norm(q - Xb[idx][None], axis=2)

    models = _ransac_sequential(fit, lambda s: fit(s[None])[0], residual, thr, len(Xa), 3, cfg, cfg.seed + 1)
    return [{"route": "sift3d", "T_ba": T, "inliers": int(len(s)), "X_a": Xa[s], "X_b": Xb[s]} for T, s in models]


#: Matches of different frames whose keypoints are within this many pixels of each other in both
#: images (Chebyshev distance over the four coordinates) are one scene point (``merge_repeats``).
SAME_MATCH_PX = 1.0


def pooled_matches(a: CameraEvidence, b: CameraEvidence, cfg: RGBDConfig) -> tuple[np.ndarray, np.ndarray]:
    """3-D matches of the image route (cfg.matcher), pooled over frames (same instant in both
    cameras), a static point matched in several frames counted once (``merge_repeats``)."""
    XA, XB, UV = [], [], []
    for (xa, da), (xb, db) in zip(a.kp, b.kp):
        mm = image_matcher(cfg).match(da, db)
        XA.append(xa[mm[:, 0]])
        XB.append(xb[mm[:, 1]])
        UV.append(np.c_[da.uv[mm[:, 0]], db.uv[mm[:, 1]]])
    if not XA:
        return np.zeros((0, 3)), np.zeros((0, 3))
    return merge_repeats(np.concatenate(UV), np.concatenate(XA), np.concatenate(XB))


def merge_repeats(uv: np.ndarray, Xa: np.ndarray, Xb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One 3-D match per scene point: matches (uv (M, 4) pixel coordinates in image a then b,
    Xa, Xb (M, 3) their lifted points) whose keypoints lie within ``SAME_MATCH_PX`` of each other
    in both images (chains of them) become one, at the mean of their points, in the order of
    their first member. A static rig re-detects the same keypoints in every frame, with the same
    localisation error (the image is the same, only the depth noise differs): pooled k times, one
    keypoint's error counted k times against the floor route's, computed once from the median
    image, so pooling 10 frames without merging comes out less accurate than 1 frame. The mean
    keeps the depth noise averaged over the frames."""
    if len(uv) < 2:
        return Xa, Xb
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    pairs = cKDTree(uv).query_pairs(SAME_MATCH_PX, p=np.inf, output_type="ndarray")
    m = len(uv)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(m, m))
    k, label = connected_components(graph, directed=False)
    count = np.bincount(label, minlength=k)[:, None]
    A, B = np.zeros((k, 3)), np.zeros((k, 3))
    np.add.at(A, label, Xa)
    np.add.at(B, label, Xb)
    return A / count, B / count
