"""The COLMAP backbone (the `paper` preset and the ablations; `auto` falls back to it): pycolmap SIFT + exhaustive matching + incremental mapping, offline.

Settings follow ../shared/notes/backbone-feasibility.md (measured on the ICL virtual rigs):
more SIFT features (``peak_threshold = 0.002``), no guided matching, PINHOLE cameras with the
rig's intrinsics held fixed, ``min_model_size = 2``. COLMAP's mappers refuse 2-image models, so
for N = 2 (or when the mapper fails) the two-view relative pose that matching stores in the
database (``compute_relative_pose``) is used. Beyond the notes (measured on the simulated
rigs, docs/gmac-backbones.md, "Backbone settings"): two-view tracks are triangulated, pixel centres are
converted between COLMAP's (0.5, 0.5) and docs/design.md's (0, 0) convention, and models that share
two or more cameras are merged (``merge_models``).

Outputs beyond the poses: the verified inlier matches of every pair (for RC), each camera's
co-visibility profile as its feature F_i (cosine of two profiles = how alike their views of
the scene are), the pairwise overlap (shared inlier matches / min keypoints), and the
backbone's own depth at triangulated keypoints (for the naive median-ratio baseline).
"""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from fuseflow.calib.backbones.base import BackboneResult
from fuseflow.calib.errors import CalibrationError
from fuseflow.errors import OutputError

__all__ = ["colmap_backbone", "merge_models", "MIN_KEYPOINTS"]

#: Fewer SIFT keypoints than this in an image = textureless for our purposes.
MIN_KEYPOINTS = 50
#: SIFT peak threshold (COLMAP default 0.0067); notes/backbone-feasibility.md: 0.002 registers 8/8.
PEAK_THRESHOLD = 0.002
#: Threads of COLMAP's feature extraction, matching and mapping. One: with two, repeated
#: calibrations of one frame agreed on an idle machine but differed by up to 3 mm when other
#: processes loaded the cores (parallel steps finish in a load-dependent order, and the RANSAC
#: samples follow); one thread gives identical results.
COLMAP_THREADS = 1
#: Seed of the two-view verification RANSAC: COLMAP's default (-1) draws a new seed every run, and
#: two calibrations of one frame then differed by 0.12 m; fixed, they are identical.
RANSAC_SEED = 0
#: COLMAP puts the centre of the top-left pixel at (0.5, 0.5); docs/conventions.md puts it at (0, 0).
#: Principal points go to COLMAP shifted by this and keypoints come back shifted by it (measured:
#: without it, ground-truth reprojections of verified matches are off by (-0.14, -0.04) px on average).
PIXEL_ORIGIN = 0.5


def _import_pycolmap():
    try:
        import pycolmap
    except ImportError as exc:  # pragma: no cover - pycolmap is a dependency
        raise CalibrationError("backbone 'colmap' needs pycolmap: pip install 'pycolmap>=4.2'") from exc
    return pycolmap


def colmap_backbone(frame, rig, config) -> BackboneResult:
    """Run pycolmap on the frame's colour images with the rig's intrinsics fixed.

    Steps: write the images -> SIFT features (``_extract_features``) -> textureless check ->
    exhaustive matching and two-view verification (``_match_pairs``) -> incremental mapping,
    merging split models (``_incremental_poses``) -> two-view fallback (``_two_view_poses``) ->
    co-visibility overlap and features (``_covisibility``).

    Raises CalibrationError naming textureless cameras (< MIN_KEYPOINTS keypoints), or when
    fewer than two cameras can be registered.
    """
    pycolmap = _import_pycolmap()
    # COLMAP's process-wide generator: without a reseed, the first backbone run in a process and
    # the later ones drew different RANSAC samples (2.9 mm apart on a 6-camera frame)
    pycolmap.set_random_seed(int(config.seed))
    pycolmap.logging.minloglevel = 2  # errors only: the library does not print
    t0 = time.perf_counter()
    n = frame.color.shape[0]
    K = np.stack([rig[cid].K for cid in frame.camera_ids])
    present = frame.present.cpu().numpy()
    with tempfile.TemporaryDirectory(prefix="fuseflow-colmap-") as tmp:
        tmp = Path(tmp)
        names, used = _write_images(frame.color.cpu().numpy(), present, tmp / "images")
        db_path = tmp / "db.db"
        name_to_idx = {nm: k for k, nm in enumerate(names)}
        id_to_idx, kps = _extract_features(pycolmap, db_path, tmp / "images", used, K, name_to_idx)
        _check_texture(frame, kps, present)
        t_extract = time.perf_counter() - t0
        matches, two_view = _match_pairs(pycolmap, db_path, id_to_idx, kps)
        t_match = time.perf_counter() - t0 - t_extract
        T0, registered, points, mode = _incremental_poses(
            pycolmap, db_path, tmp / "images", tmp / "sparse", used, name_to_idx, n, config
        )
        if registered.sum() < 2:
            mode = "two-view"
            T0, registered, points = _two_view_poses(frame, K, kps, matches, two_view, n)
    t_total = time.perf_counter() - t0
    overlap, feats = _covisibility(matches, kps, n)
    return BackboneResult(
        T_cam_world=T0,
        registered=registered,
        features=feats,
        overlap=overlap,
        matches=matches,
        points=points,
        name="colmap",
        info={
            "mode": mode,
            "keypoints": {frame.camera_ids[k]: int(len(v)) for k, v in sorted(kps.items())},
            "verified_pairs": len(matches),
            "seconds": {"extract": t_extract, "match": t_match, "total": t_total},
        },
    )


def _write_images(color: np.ndarray, present: np.ndarray, img_dir: Path) -> tuple[list[str], list[str]]:
    """Write the present views (colour (N, H, W, 3) uint8 RGB) as PNGs; returns (name of every
    view, names of the written ones)."""
    import cv2

    img_dir.mkdir()
    names = [f"{i:04d}.png" for i in range(len(color))]
    for i in range(len(color)):
        if present[i] and not cv2.imwrite(str(img_dir / names[i]), cv2.cvtColor(color[i], cv2.COLOR_RGB2BGR)):
            free = shutil.disk_usage(img_dir).free / 1e6
            raise OutputError(
                f"cannot write COLMAP's workspace image {img_dir / names[i]} ({free:.0f} MB free in the temporary "
                "directory): free space there or point TMPDIR at a disk with room"
            )
    return names, [names[i] for i in range(len(color)) if present[i]]


def _extract_features(pycolmap, db_path: Path, img_dir: Path, used: list[str], K: np.ndarray, name_to_idx):
    """SIFT into a new database with each image's PINHOLE intrinsics fixed to the rig's.

    Returns (COLMAP image id -> camera index, camera index -> keypoints (M, 2) in docs/design.md pixels).
    """
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"
    fx, fy, cx, cy = K[0, 0, 0], K[0, 1, 1], K[0, 0, 2] + PIXEL_ORIGIN, K[0, 1, 2] + PIXEL_ORIGIN
    reader.camera_params = f"{fx},{fy},{cx},{cy}"
    ext = pycolmap.FeatureExtractionOptions()
    ext.sift.peak_threshold = PEAK_THRESHOLD
    ext.num_threads = COLMAP_THREADS
    pycolmap.extract_features(
        db_path,
        img_dir,
        image_names=used,
        camera_mode=pycolmap.CameraMode.PER_IMAGE,
        reader_options=reader,
        extraction_options=ext,
        device=pycolmap.Device.cpu,
    )
    db = pycolmap.Database.open(db_path)
    id_to_idx, kps = {}, {}
    for im in db.read_all_images():
        k = name_to_idx[im.name]
        id_to_idx[im.image_id] = k
        cam = db.read_camera(im.camera_id)
        cam.params = np.array([K[k, 0, 0], K[k, 1, 1], K[k, 0, 2] + PIXEL_ORIGIN, K[k, 1, 2] + PIXEL_ORIGIN])
        db.update_camera(cam)
        kps[k] = np.asarray(db.read_keypoints(im.image_id))[:, :2] - PIXEL_ORIGIN
    db.close()
    return id_to_idx, kps


def _check_texture(frame, kps: dict[int, np.ndarray], present: np.ndarray) -> None:
    n = len(present)
    textureless = [frame.camera_ids[k] for k in range(n) if present[k] and len(kps.get(k, [])) < MIN_KEYPOINTS]
    if textureless:
        raise CalibrationError(
            f"cameras {textureless} have fewer than {MIN_KEYPOINTS} SIFT keypoints: the images look "
            "textureless (or are blank); the image-based backbone cannot place them"
        )


def _match_pairs(pycolmap, db_path: Path, id_to_idx, kps):
    """Exhaustive matching with two-view verification.

    Returns ({(i, j), i < j: (uv_i (K, 2), uv_j (K, 2))} verified inlier matches,
    {(i, j): (4, 4) T_j_i} two-view relative poses where COLMAP computed one).
    """
    match_opts = pycolmap.FeatureMatchingOptions()
    match_opts.guided_matching = False
    match_opts.num_threads = COLMAP_THREADS
    verify = pycolmap.TwoViewGeometryOptions()
    verify.compute_relative_pose = True
    verify.ransac.random_seed = RANSAC_SEED  # -1 (COLMAP's default) seeds from the clock
    pycolmap.match_exhaustive(
        db_path, matching_options=match_opts, verification_options=verify, device=pycolmap.Device.cpu
    )
    db = pycolmap.Database.open(db_path)
    pair_ids, geoms = db.read_two_view_geometries()
    db.close()
    matches: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
    two_view: dict[tuple[int, int], np.ndarray] = {}
    for pid, g in zip(pair_ids, geoms):
        a, b = pycolmap.pair_id_to_image_pair(pid)
        ia, ib = id_to_idx[a], id_to_idx[b]
        m = np.asarray(g.inlier_matches)
        if len(m) == 0:
            continue
        uva, uvb = kps[ia][m[:, 0]], kps[ib][m[:, 1]]
        if ia > ib:
            ia, ib, uva, uvb = ib, ia, uvb, uva
            flip = True
        else:
            flip = False
        matches[(ia, ib)] = (uva.astype(np.float64), uvb.astype(np.float64))
        try:
            T = np.eye(4)
            T[:3, :] = np.asarray(g.cam2_from_cam1.matrix())
            two_view[(ia, ib)] = np.linalg.inv(T) if flip else T
        except Exception:  # noqa: BLE001 - pairs without a relative pose simply lack one
            pass
    return matches, two_view


def _mapper_options(pycolmap, config):
    opts = pycolmap.IncrementalPipelineOptions()
    opts.min_model_size = 2
    opts.ba_refine_focal_length = False
    opts.ba_refine_principal_point = False
    opts.ba_refine_extra_params = False
    opts.num_threads = COLMAP_THREADS
    opts.random_seed = int(config.seed)
    opts.mapper.random_seed = int(config.seed)
    # A rig frame is N images with wide baselines and few (50-400) matches per pair, not a
    # video: COLMAP's defaults (30 inliers and a 25 % inlier ratio to register an image,
    # 100 inliers and 16 deg to initialise) split an 8-camera simulated studio into three
    # 3-image models. These thresholds register all 8 (rotation error 0.12 deg there).
    opts.mapper.abs_pose_min_num_inliers = 15
    opts.mapper.abs_pose_min_inlier_ratio = 0.1
    opts.mapper.init_min_num_inliers = 50
    opts.mapper.init_min_tri_angle = 4.0
    # Most tracks of a wide-baseline rig are seen by two cameras only; COLMAP's default
    # ignores them when triangulating, which left ~300 3D points from ~4700 verified
    # matches on the simulated studio and mean rotation errors of 0.5-1.3 deg that varied
    # from run to run. Keeping them: ~3500-4200 points and 0.02-0.03 deg.
    opts.triangulation.ignore_two_view_tracks = False
    return opts


def _incremental_poses(pycolmap, db_path: Path, img_dir: Path, out: Path, used: list[str], name_to_idx, n: int, config):
    """COLMAP's incremental mapper (>= 3 images), split models merged (``merge_models``).

    Returns (T0 (n, 4, 4) backbone-unit camera-from-world, identity where unregistered,
    registered (n,) bool, {camera index: (uv, z)} triangulated keypoint depths, mode text).
    """
    T0 = np.tile(np.eye(4), (n, 1, 1))
    registered = np.zeros(n, bool)
    points: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    mode = "incremental"
    recs = {}
    if len(used) >= 3:
        out.mkdir()
        try:
            recs = pycolmap.incremental_mapping(db_path, img_dir, out, options=_mapper_options(pycolmap, config))
        except Exception:  # noqa: BLE001 - a failed mapper falls back to two-view poses
            recs = {}
    if recs:
        models = [_model_poses(r, name_to_idx) for r in recs.values()]
        merged, n_models = merge_models(models)
        for k, (T, uv, z) in merged.items():
            T0[k] = T
            registered[k] = True
            if len(uv):
                points[k] = (uv, z)
        if n_models > 1:
            mode = f"incremental ({n_models} models merged)"
    return T0, registered, points, mode


def _two_view_poses(frame, K: np.ndarray, kps, matches, two_view, n: int):
    """Fallback for N = 2 or a failed mapper: the verified pair with the most matches, placed by
    its two-view relative pose. Returns (T0, registered, points) as ``_incremental_poses``."""
    if not two_view:
        raise CalibrationError(
            "the colmap backbone found no verified image pair: the cameras share too little "
            f"texture (keypoints per camera: { {frame.camera_ids[k]: len(v) for k, v in kps.items()} })"
        )
    (ia, ib), T = max(two_view.items(), key=lambda kv: len(matches[kv[0]][0]))
    T0 = np.tile(np.eye(4), (n, 1, 1))
    registered = np.zeros(n, bool)
    T0[ib] = T
    registered[[ia, ib]] = True
    return T0, registered, _triangulate_pair(K[ia], K[ib], T, *matches[(ia, ib)], ia, ib)


def _covisibility(matches, kps, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(overlap (n, n) in [0, 1]: 4 x shared inlier matches / the smaller keypoint count,
    features (n, n): each camera's co-visibility profile, its F_i for eq. 8)."""
    cov = np.zeros((n, n))
    for (a, b), (uva, _) in matches.items():
        cov[a, b] = cov[b, a] = len(uva)
    nk = np.array([max(len(kps.get(k, [])), 1) for k in range(n)], dtype=np.float64)
    overlap = np.clip(cov / np.minimum(nk[:, None], nk[None, :]) * 4.0, 0.0, 1.0)
    np.fill_diagonal(overlap, 1.0)
    feats = cov + np.diag(np.maximum(cov.max(axis=1), 1.0))
    return overlap, feats


def _model_poses(rec, name_to_idx) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """One COLMAP model as {camera index: (T_cam_world (4, 4), keypoint uv (M, 2), depth (M,))}:
    each registered image's pose and the backbone-unit depth of its triangulated keypoints."""
    out = {}
    for im in rec.images.values():
        if not im.has_pose:
            continue
        T = np.eye(4)
        T[:3, :] = np.asarray(im.cam_from_world().matrix())
        uv, z = [], []
        for p2 in im.points2D:
            if p2.has_point3D():
                X = rec.points3D[p2.point3D_id].xyz
                uv.append(np.asarray(p2.xy) - PIXEL_ORIGIN)
                z.append((T[:3, :3] @ X + T[:3, 3])[2])
        out[name_to_idx[im.name]] = (
            T,
            np.asarray(uv, dtype=np.float64).reshape(-1, 2),
            np.asarray(z, dtype=np.float64),
        )
    return out


def merge_models(models: list[dict[int, tuple]]) -> tuple[dict[int, tuple], int]:
    """Merge COLMAP models that share cameras into the largest one; returns (merged, models used).

    COLMAP's incremental mapper sometimes splits a rig frame into overlapping models (measured:
    the simulated static studio, seed 2, came back as cameras {3..7} and {0, 1, 2, 3, 7}). Each
    model has its own similarity gauge, so a model joins when it shares >= 2 cameras with the
    merged set: its world is mapped by the similarity x_A = sigma R x_B + tau fitted to the
    shared cameras (R: chordal mean of R_A^T R_B; sigma: median ratio of centre distances; tau:
    mean centre offset), and its other cameras are added (depths scale by sigma). A model that
    shares fewer than two cameras cannot be placed in the same gauge and is left out.
    """
    if not models:
        return {}, 0
    order = sorted(range(len(models)), key=lambda m: -len(models[m]))
    merged = dict(models[order[0]])
    used = 1
    pending = [models[m] for m in order[1:]]
    grew = True
    while grew and pending:
        grew = False
        for mb in list(pending):
            shared = sorted(set(mb) & set(merged))
            new = [k for k in mb if k not in merged]
            if len(shared) < 2 or not new:
                if not new:
                    pending.remove(mb)
                continue
            RA = np.stack([merged[k][0][:3, :3] for k in shared])
            RB = np.stack([mb[k][0][:3, :3] for k in shared])
            cA = np.stack([-merged[k][0][:3, :3].T @ merged[k][0][:3, 3] for k in shared])
            cB = np.stack([-mb[k][0][:3, :3].T @ mb[k][0][:3, 3] for k in shared])
            U, _, Vt = np.linalg.svd(np.einsum("kji,kjl->il", RA, RB))  # sum_k R_A^T R_B
            R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
            iu = np.triu_indices(len(shared), 1)
            dA = np.linalg.norm(cA[:, None] - cA[None], axis=2)[iu]
            dB = np.linalg.norm(cB[:, None] - cB[None], axis=2)[iu]
            ok = dB > 1e-12
            if not ok.any():
                pending.remove(mb)
                continue
            sigma = float(np.median(dA[ok] / dB[ok]))
            tau = np.mean(cA - sigma * cB @ R.T, axis=0)
            for k in new:
                T, uv, z = mb[k]
                Rk = T[:3, :3] @ R.T
                ck = sigma * R @ (-T[:3, :3].T @ T[:3, 3]) + tau
                Tk = np.eye(4)
                Tk[:3, :3] = Rk
                Tk[:3, 3] = -Rk @ ck
                merged[k] = (Tk, uv, z * sigma)
            pending.remove(mb)
            used += 1
            grew = True
    return merged, used


def _triangulate_pair(Ka, Kb, T_b_a, uva, uvb, ia, ib):
    """Backbone-unit depths of a pair's matches (DLT), for the naive baseline in two-view mode."""
    import cv2

    Pa = Ka @ np.eye(4)[:3]
    Pb = Kb @ T_b_a[:3]
    Xh = cv2.triangulatePoints(Pa, Pb, uva.T, uvb.T)
    X = (Xh[:3] / Xh[3]).T
    za = X[:, 2]
    zb = (X @ T_b_a[:3, :3].T + T_b_a[:3, 3])[:, 2]
    ok = (za > 0) & (zb > 0)
    return {ia: (uva[ok], za[ok]), ib: (uvb[ok], zb[ok])}
