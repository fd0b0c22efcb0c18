"""The default backbone: pycolmap SIFT + exhaustive matching + incremental mapping, offline.

Settings follow ../shared/notes/backbone-feasibility.md (measured on the ICL virtual rigs):
more SIFT features (``peak_threshold = 0.002``), no guided matching, PINHOLE cameras with the
rig's intrinsics held fixed, ``min_model_size = 2``. COLMAP's mappers refuse 2-image models, so
for N = 2 (or when the mapper fails) the two-view relative pose that matching stores in the
database (``compute_relative_pose``) is used.

Outputs beyond the poses: the verified inlier matches of every pair (for RC), each camera's
co-visibility profile as its feature F_i (cosine of two profiles = how alike their views of
the scene are), the pairwise overlap (shared inlier matches / min keypoints), and the
backbone's own depth at triangulated keypoints (for the naive median-ratio baseline).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from fuseflow.calib.backbones import BackboneResult
from fuseflow.calib.errors import CalibrationError

__all__ = ["colmap_backbone", "MIN_KEYPOINTS"]

#: Fewer SIFT keypoints than this in an image = textureless for our purposes.
MIN_KEYPOINTS = 50
#: SIFT peak threshold (COLMAP default 0.0067); notes/backbone-feasibility.md: 0.002 registers 8/8.
PEAK_THRESHOLD = 0.002


def _import_pycolmap():
    try:
        import pycolmap
    except ImportError as exc:  # pragma: no cover - pycolmap is a dependency
        raise CalibrationError("backbone 'colmap' needs pycolmap: pip install 'pycolmap>=4.2'") from exc
    return pycolmap


def colmap_backbone(frame, rig, config) -> BackboneResult:
    """Run pycolmap on the frame's colour images with the rig's intrinsics fixed.

    Raises CalibrationError naming textureless cameras (< MIN_KEYPOINTS keypoints), or when
    fewer than two cameras can be registered.
    """
    import cv2

    pycolmap = _import_pycolmap()
    pycolmap.logging.minloglevel = 2  # errors only: the library does not print
    t0 = time.perf_counter()
    color = frame.color.cpu().numpy()
    n = color.shape[0]
    K = np.stack([rig[cid].K for cid in frame.camera_ids])
    present = frame.present.cpu().numpy()
    with tempfile.TemporaryDirectory(prefix="fuseflow-colmap-") as tmp:
        tmp = Path(tmp)
        img_dir = tmp / "images"
        img_dir.mkdir()
        names = [f"{i:04d}.png" for i in range(n)]
        for i in range(n):
            if present[i]:
                cv2.imwrite(str(img_dir / names[i]), cv2.cvtColor(color[i], cv2.COLOR_RGB2BGR))
        used = [names[i] for i in range(n) if present[i]]
        db_path = tmp / "db.db"
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = "PINHOLE"
        fx, fy, cx, cy = K[0, 0, 0], K[0, 1, 1], K[0, 0, 2], K[0, 1, 2]
        reader.camera_params = f"{fx},{fy},{cx},{cy}"
        ext = pycolmap.FeatureExtractionOptions()
        ext.sift.peak_threshold = PEAK_THRESHOLD
        ext.num_threads = 2
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
        name_to_idx = {nm: k for k, nm in enumerate(names)}
        id_to_idx, kps = {}, {}
        for im in db.read_all_images():
            k = name_to_idx[im.name]
            id_to_idx[im.image_id] = k
            cam = db.read_camera(im.camera_id)
            cam.params = np.array([K[k, 0, 0], K[k, 1, 1], K[k, 0, 2], K[k, 1, 2]])
            db.update_camera(cam)
            kps[k] = np.asarray(db.read_keypoints(im.image_id))[:, :2]
        db.close()
        textureless = [frame.camera_ids[k] for k in range(n) if present[k] and len(kps.get(k, [])) < MIN_KEYPOINTS]
        if textureless:
            raise CalibrationError(
                f"cameras {textureless} have fewer than {MIN_KEYPOINTS} SIFT keypoints: the images look "
                "textureless (or are blank); the image-based backbone cannot place them"
            )
        t_extract = time.perf_counter() - t0
        match_opts = pycolmap.FeatureMatchingOptions()
        match_opts.guided_matching = False
        match_opts.num_threads = 2
        verify = pycolmap.TwoViewGeometryOptions()
        verify.compute_relative_pose = True
        pycolmap.match_exhaustive(
            db_path, matching_options=match_opts, verification_options=verify, device=pycolmap.Device.cpu
        )
        db = pycolmap.Database.open(db_path)
        pair_ids, geoms = db.read_two_view_geometries()
        db.close()
        t_match = time.perf_counter() - t0 - t_extract
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
        T0 = np.tile(np.eye(4), (n, 1, 1))
        registered = np.zeros(n, bool)
        points: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        mode = "incremental"
        recs = {}
        if len(used) >= 3:
            opts = pycolmap.IncrementalPipelineOptions()
            opts.min_model_size = 2
            opts.ba_refine_focal_length = False
            opts.ba_refine_principal_point = False
            opts.ba_refine_extra_params = False
            opts.num_threads = 2
            opts.random_seed = int(config.seed)
            # A rig frame is N images with wide baselines and few (50-400) matches per pair, not a
            # video: COLMAP's defaults (30 inliers and a 25 % inlier ratio to register an image,
            # 100 inliers and 16 deg to initialise) split an 8-camera simulated studio into three
            # 3-image models. These thresholds register all 8 (rotation error 0.12 deg there).
            opts.mapper.abs_pose_min_num_inliers = 15
            opts.mapper.abs_pose_min_inlier_ratio = 0.1
            opts.mapper.init_min_num_inliers = 50
            opts.mapper.init_min_tri_angle = 4.0
            out = tmp / "sparse"
            out.mkdir()
            try:
                recs = pycolmap.incremental_mapping(db_path, img_dir, out, options=opts)
            except Exception:  # noqa: BLE001 - a failed mapper falls back to two-view poses
                recs = {}
        if recs:
            rec = max(recs.values(), key=lambda r: r.num_reg_images())
            for im in rec.images.values():
                if not im.has_pose:
                    continue
                k = name_to_idx[im.name]
                T = np.eye(4)
                T[:3, :] = np.asarray(im.cam_from_world().matrix())
                T0[k] = T
                registered[k] = True
                uv, z = [], []
                for p2 in im.points2D:
                    if p2.has_point3D():
                        X = rec.points3D[p2.point3D_id].xyz
                        uv.append(p2.xy)
                        z.append((T[:3, :3] @ X + T[:3, 3])[2])
                if uv:
                    points[k] = (np.asarray(uv, dtype=np.float64), np.asarray(z, dtype=np.float64))
        if registered.sum() < 2:
            mode = "two-view"
            if not two_view:
                raise CalibrationError(
                    "the colmap backbone found no verified image pair: the cameras share too little "
                    f"texture (keypoints per camera: { {frame.camera_ids[k]: len(v) for k, v in kps.items()} })"
                )
            (ia, ib), T = max(two_view.items(), key=lambda kv: len(matches[kv[0]][0]))
            T0[:] = np.eye(4)
            registered[:] = False
            T0[ib] = T
            registered[[ia, ib]] = True
            points = _triangulate_pair(K[ia], K[ib], T, *matches[(ia, ib)], ia, ib)
    t_total = time.perf_counter() - t0
    cov = np.zeros((n, n))
    for (a, b), (uva, _) in matches.items():
        cov[a, b] = cov[b, a] = len(uva)
    nk = np.array([max(len(kps.get(k, [])), 1) for k in range(n)], dtype=np.float64)
    overlap = np.clip(cov / np.minimum(nk[:, None], nk[None, :]) * 4.0, 0.0, 1.0)
    np.fill_diagonal(overlap, 1.0)
    feats = cov + np.diag(np.maximum(cov.max(axis=1), 1.0))
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
