"""``precomputed`` backbone: poses (and optional features/depth) exported by a model run elsewhere.

File layout (``.npz``, written by ``scripts/export_backbone.py`` beside VGGT / MapAnything /
VGGSfM; all arrays in the order of ``camera_ids``):

=================  ==============  ====================================================
key                shape, dtype    meaning
=================  ==============  ====================================================
format             () str          "fuseflow-backbone/1"
source             () str          model name, e.g. "vggt"
camera_ids         (N,) str        the rig's camera ids (matched by id, any order)
T_cam_world        (N, 4, 4) f8    camera-from-world, OpenCV axes, ARBITRARY scale
registered         (N,) bool       optional; False = the model could not place the camera
features           (N, D) f4/f8    optional per-camera feature F_i (eq. 8's cosine)
overlap            (N, N) f4/f8    optional pairwise overlap in [0, 1]
depth              (N, h, w) f4    optional model depth (same arbitrary scale), for the
                                   naive median-depth-ratio baseline
depth_K            (N, 3, 3) f8    intrinsics of ``depth``'s pixel grid (needed with depth)
=================  ==============  ====================================================

A JSON file with the same keys (nested lists) is accepted too.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from fuseflow.calib.backbones.base import BackboneResult
from fuseflow.calib.errors import CalibrationError

__all__ = ["BACKBONE_FORMAT", "load_precomputed", "save_precomputed"]

BACKBONE_FORMAT = "fuseflow-backbone/1"


def save_precomputed(path, camera_ids, T_cam_world, source: str = "", **optional) -> Path:
    """Write the export file (see the module docstring); ``optional`` = registered, features,
    overlap, depth, depth_K."""
    path = Path(path)
    arrays = {
        "format": np.array(BACKBONE_FORMAT),
        "source": np.array(source),
        "camera_ids": np.array([str(c) for c in camera_ids]),
        "T_cam_world": np.asarray(T_cam_world, dtype=np.float64),
    }
    for k, v in optional.items():
        if v is not None:
            arrays[k] = np.asarray(v)
    np.savez_compressed(path, **arrays)
    return path


def _load(path: Path) -> dict:
    if not path.is_file():
        raise CalibrationError(f"precomputed backbone file not found: {path}")
    if path.suffix == ".json":
        try:
            return {k: np.asarray(v) for k, v in json.loads(path.read_text()).items()}
        except (ValueError, OSError) as exc:
            raise CalibrationError(f"{path}: not a readable JSON backbone export ({exc})") from None
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (ValueError, OSError) as exc:
        raise CalibrationError(f"{path}: not a readable .npz backbone export ({exc})") from None


def load_precomputed(path, rig) -> BackboneResult:
    """Read an export and reorder it to the rig's camera order."""
    path = Path(path)
    d = _load(path)
    fmt = str(d.get("format", ""))
    if fmt != BACKBONE_FORMAT:
        raise CalibrationError(f"{path}: field 'format' must be {BACKBONE_FORMAT!r}, got {fmt!r}")
    for key in ("camera_ids", "T_cam_world"):
        if key not in d:
            raise CalibrationError(f"{path}: missing field {key!r}")
    ids = [str(c) for c in d["camera_ids"]]
    missing = [c for c in rig.ids if c not in ids]
    if missing:
        raise CalibrationError(f"{path}: no poses for rig cameras {missing} (file has {ids})")
    order = [ids.index(c) for c in rig.ids]
    T = np.asarray(d["T_cam_world"], dtype=np.float64)
    if T.shape != (len(ids), 4, 4):
        raise CalibrationError(f"{path}: T_cam_world must be ({len(ids)}, 4, 4), got {T.shape}")
    reg = np.asarray(d.get("registered", np.ones(len(ids), bool)), dtype=bool)
    feats = d.get("features")
    ov = d.get("overlap")
    points = None
    if "depth" in d:
        if "depth_K" not in d:
            raise CalibrationError(f"{path}: 'depth' needs 'depth_K' (intrinsics of its pixel grid)")
        points = {}
        for new, old in enumerate(order):
            dep, Kd = np.asarray(d["depth"][old], dtype=np.float64), np.asarray(d["depth_K"][old], dtype=np.float64)
            Kr = rig[rig.ids[new]].K
            h, w = dep.shape
            v, u = np.mgrid[4:h:8, 4:w:8]
            z = dep[v, u]
            ok = z > 0
            # pixel in the depth grid -> normalised ray -> pixel of the rig camera
            x = (u[ok] - Kd[0, 2]) / Kd[0, 0]
            y = (v[ok] - Kd[1, 2]) / Kd[1, 1]
            uv = np.stack([Kr[0, 0] * x + Kr[0, 2], Kr[1, 1] * y + Kr[1, 2]], axis=1)
            points[new] = (uv, z[ok])
    return BackboneResult(
        T_cam_world=T[order],
        registered=reg[order],
        features=None if feats is None else np.asarray(feats, dtype=np.float64)[order],
        overlap=None if ov is None else np.asarray(ov, dtype=np.float64)[np.ix_(order, order)],
        points=points,
        name=f"precomputed:{d.get('source', '')}",
        info={"file": str(path)},
    )
