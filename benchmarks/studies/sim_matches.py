"""SIFT matches between the cameras of simulated rigs: is the texture rich enough for
target-free calibration.

For each scene, one frame of an N-camera ring at 640x480 (Kinect noise, colour noise on) is
rendered; per image, OpenCV SIFT keypoints; per camera pair, Lowe's ratio test (0.75) on 2-NN
matches, then RANSAC on the fundamental matrix (1 px, confidence 0.999): the inliers are the
reported matches. Each inlier is also checked against the ground truth (keypoint of camera i
back-projected with the noise-free depth and projected into camera j lands within 3 px of its
match): 'correct' is that share.

    python -m benchmarks.sim_matches --scenes studio room   (prints the report)
"""

from __future__ import annotations

import itertools

import numpy as np

__all__ = ["pair_matches", "correct_share", "run_scene", "summary", "scene_report"]


def pair_matches(kp, des, i: int, j: int, ratio: float) -> tuple[np.ndarray, np.ndarray, int]:
    """(pts_i, pts_j) of RANSAC-verified matches and the count after the ratio test."""
    import cv2

    if des[i] is None or des[j] is None or len(kp[i]) < 2 or len(kp[j]) < 2:
        return np.zeros((0, 2)), np.zeros((0, 2)), 0
    knn = cv2.BFMatcher(cv2.NORM_L2).knnMatch(des[i], des[j], k=2)
    good = [m for m, *rest in knn if rest and m.distance < ratio * rest[0].distance]
    if len(good) < 8:
        return np.zeros((0, 2)), np.zeros((0, 2)), len(good)
    pi = np.float64([kp[i][m.queryIdx].pt for m in good])
    pj = np.float64([kp[j][m.trainIdx].pt for m in good])
    _, mask = cv2.findFundamentalMat(pi, pj, cv2.FM_RANSAC, 1.0, 0.999)
    if mask is None:
        return np.zeros((0, 2)), np.zeros((0, 2)), len(good)
    keep = mask.ravel().astype(bool)
    return pi[keep], pj[keep], len(good)


def correct_share(pi: np.ndarray, pj: np.ndarray, depth_i: np.ndarray, ci, cj, tol_px: float = 3.0) -> float:
    """Share of matches whose GT reprojection from camera i into camera j is within tol_px."""
    if len(pi) == 0:
        return float("nan")
    u = np.rint(pi[:, 0]).astype(int).clip(0, ci.width - 1)
    v = np.rint(pi[:, 1]).astype(int).clip(0, ci.height - 1)
    z = depth_i[v, u].astype(np.float64)
    X = (np.stack([pi[:, 0], pi[:, 1], np.ones(len(pi))], -1) @ np.linalg.inv(ci.K).T) * z[:, None]
    Xw = X @ ci.T_world_cam[:3, :3].T + ci.T_world_cam[:3, 3]
    Xj = Xw @ cj.T_cam_world[:3, :3].T + cj.T_cam_world[:3, 3]
    uv = (Xj @ cj.K.T)[:, :2] / Xj[:, 2:3]
    err = np.linalg.norm(uv - pj, axis=1)
    return float(((z > 0) & (err < tol_px)).mean())


def run_scene(scene: str, cameras: int, seed: int, ratio: float, noise: str, dynamic: bool) -> dict:
    """One frame of ``scene``: keypoints per image and, per camera pair, RANSAC inliers, matches
    after the ratio test, the GT-verified share and the GT overlap."""
    import cv2

    from fuseflow.synth import SimConfig, Simulator

    sim = Simulator(SimConfig(cameras=cameras, frames=1, scene=scene, seed=seed, noise=noise, dynamic=dynamic))
    sf = sim.render(0)
    color = sf.frame.color.numpy()
    depth_gt = sf.depth_gt.numpy()
    sift = cv2.SIFT_create()
    kp, des = [], []
    for img in color:
        k, d = sift.detectAndCompute(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY), None)
        kp.append(k)
        des.append(d)
    n = len(color)
    inl = np.zeros((n, n), int)
    ratio_ok = np.zeros((n, n), int)
    correct = np.full((n, n), np.nan)
    for i, j in itertools.combinations(range(n), 2):
        pi, pj, r = pair_matches(kp, des, i, j, ratio)
        inl[i, j] = inl[j, i] = len(pi)
        ratio_ok[i, j] = ratio_ok[j, i] = r
        correct[i, j] = correct[j, i] = correct_share(pi, pj, depth_gt[i], sim.rig.cameras[i], sim.rig.cameras[j])
    ov = sim.pairwise_overlap(0)
    return dict(keypoints=[len(k) for k in kp], inliers=inl, ratio=ratio_ok, correct=correct, overlap=ov)


def summary(name: str, vals: np.ndarray) -> str:
    """One line: min, median and max of ``vals``."""
    return f"{name}: min {vals.min():.0f}, median {np.median(vals):.0f}, max {vals.max():.0f}"


def scene_report(scene: str, r: dict, n: int, seed: int, noise: str) -> list[str]:
    """The report lines of ``run_scene``'s result ``r`` for an n-camera ring."""
    iu = np.triu_indices(n, 1)
    neighbours = np.array([[i, (i + 1) % n] for i in range(n)]) if n > 2 else np.array([[0, 1]])
    inl = r["inliers"]
    nb = inl[neighbours[:, 0], neighbours[:, 1]]
    corr = r["correct"][iu]
    weights = inl[iu]
    good = np.rint(np.nan_to_num(r["correct"]) * inl).astype(int)  # GT-verified inliers
    out = [f"\n## {scene}: {n} cameras, 640x480, noise {noise}, seed {seed}",
           f"SIFT keypoints per image: min {min(r['keypoints'])}, max {max(r['keypoints'])}",
           summary("RANSAC inliers, all pairs", inl[iu]), summary("RANSAC inliers, ring neighbours", nb),
           summary("GT-verified inliers (within 3 px of the true reprojection), all pairs", good[iu]),
           summary("GT-verified inliers, ring neighbours", good[neighbours[:, 0], neighbours[:, 1]]),
           f"pairs with >= 20 GT-verified inliers: {(good[iu] >= 20).sum()} of {len(iu[0])}"]  # fmt: skip
    if weights.sum() > 0:
        ok = ~np.isnan(corr)
        out.append(f"share of RANSAC inliers that are GT-verified: all pairs "
                   f"{np.average(corr[ok], weights=weights[ok]):.1%}, ring neighbours "
                   f"{good[neighbours[:, 0], neighbours[:, 1]].sum() / max(nb.sum(), 1):.1%}")  # fmt: skip
    out += ["RANSAC inliers / GT-verified inliers (row i, column j):", "    " + "".join(f"{j:>10d}" for j in range(n))]
    for i in range(n):
        cells = ["-" if i == j else f"{inl[i, j]}/{good[i, j]}" for j in range(n)]
        out.append(f"{i:>4d}" + "".join(f"{c:>10}" for c in cells))
    out.append("GT overlap, ring neighbours (share of i's pixels seen by i+1): "
               + ", ".join(f"{r['overlap'][i, j]:.2f}" for i, j in neighbours))  # fmt: skip
    return out
