"""Adapters for VGGT and MapAnything, run from a LOCAL checkpoint when the packages are installed.

FuseFlow never downloads weights: without the package, or without ``backbone_path`` pointing to
a checkpoint file on disk, these raise CalibrationError saying what to install / pass. Neither
package exists on this project's package index (notes/backbone-feasibility.md); users with a
GPU machine can also run ``scripts/export_backbone.py`` there and use ``precomputed``.

The model-independent part (image batching, decoding the model's camera output into
camera-from-world poses, features) is in :func:`run_pose_model`, which takes any torch module;
the tests drive it with a small stand-in network.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from fuseflow.calib.backbones.base import BackboneResult
from fuseflow.calib.errors import CalibrationError

__all__ = [
    "decode_vggt_pose_encoding",
    "run_pose_model",
    "vggt_backbone",
    "mapanything_backbone",
    "images_tensor",
]


def images_tensor(color: torch.Tensor, size: int = 518) -> torch.Tensor:
    """(N, H, W, 3) uint8 -> (N, 3, h, size) float in [0, 1], width ``size``, height a multiple of 14."""
    x = color.permute(0, 3, 1, 2).float() / 255.0
    n, _, H, W = x.shape
    h = max(14, int(round(H * size / W / 14)) * 14)
    return torch.nn.functional.interpolate(x, size=(h, size), mode="bilinear", align_corners=False)


def _quat_xyzw_to_R(q: torch.Tensor) -> torch.Tensor:
    q = q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    x, y, z, w = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
            2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
            2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(*q.shape[:-1], 3, 3)  # fmt: skip


def decode_vggt_pose_encoding(pose_enc: torch.Tensor) -> np.ndarray:
    """VGGT's "absT_quaR_FoV" encoding (..., 9) = [t (3), quaternion xyzw (4), fov_h, fov_w]
    -> (..., 4, 4) float64 camera-from-world (OpenCV axes, the model's arbitrary scale)."""
    pe = pose_enc.detach().double().cpu()
    T = torch.zeros(*pe.shape[:-1], 4, 4, dtype=torch.float64)
    T[..., :3, :3] = _quat_xyzw_to_R(pe[..., 3:7])
    T[..., :3, 3] = pe[..., :3]
    T[..., 3, 3] = 1
    return T.numpy()


def run_pose_model(
    model: torch.nn.Module,
    color: torch.Tensor,
    decode: Callable[[object], tuple[np.ndarray, np.ndarray | None]],
    name: str,
    size: int = 518,
) -> BackboneResult:
    """Run a pose model on (N, H, W, 3) uint8 images and decode its output.

    Args:
        model: torch module taking (1, N, 3, h, w) float images in [0, 1].
        decode: model output -> ((N, 4, 4) camera-from-world, (N, D) features or None).
    """
    imgs = images_tensor(color, size)[None]
    device = next(model.parameters()).device if any(True for _ in model.parameters()) else torch.device("cpu")
    model.eval()
    with torch.inference_mode():
        out = model(imgs.to(device))
    T, feats = decode(out)
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (color.shape[0], 4, 4):
        raise CalibrationError(
            f"backbone {name!r}: decoded poses have shape {T.shape}, expected ({color.shape[0]}, 4, 4)"
        )
    return BackboneResult(T, np.ones(len(T), bool), features=feats, name=name, info={"input": list(imgs.shape)})


def _vggt_decode(out) -> tuple[np.ndarray, np.ndarray | None]:
    T = decode_vggt_pose_encoding(out["pose_enc"])[0]
    feats = None
    if "camera_tokens" in out:
        feats = out["camera_tokens"][0].detach().double().cpu().reshape(T.shape[0], -1).numpy()
    return T, feats


def _checkpoint(config, what: str) -> Path:
    if not config.backbone_path:
        raise CalibrationError(
            f"backbone {what!r} needs backbone_path (--backbone-path): a local checkpoint file; "
            "FuseFlow never downloads weights"
        )
    p = Path(config.backbone_path)
    if not p.is_file():
        raise CalibrationError(f"backbone {what!r}: checkpoint {p} does not exist (FuseFlow never downloads weights)")
    return p


def vggt_backbone(frame, rig, config) -> BackboneResult:
    """VGGT (facebookresearch/vggt) from a local ``model.pt`` state dict."""
    try:
        from vggt.models.vggt import VGGT
    except ImportError:
        raise CalibrationError(
            "backbone 'vggt' needs the vggt package (pip install git+https://github.com/facebookresearch/vggt) "
            "and a local checkpoint via backbone_path; or run scripts/export_backbone.py where VGGT is "
            "installed and use backbone 'precomputed'"
        ) from None
    ckpt = _checkpoint(config, "vggt")
    model = VGGT()
    model.load_state_dict(torch.load(ckpt, map_location="cpu", weights_only=True))
    if torch.cuda.is_available():
        model = model.cuda()
    return run_pose_model(model, frame.color, _vggt_decode, "vggt")


def _mapanything_decode(out) -> tuple[np.ndarray, np.ndarray | None]:
    poses = [np.asarray(v["camera_poses"].detach().double().cpu())[0] for v in out]  # world-from-camera
    return np.stack([np.linalg.inv(P) for P in poses]), None


class _MapAnythingViews(torch.nn.Module):
    """Wrap MapAnything's list-of-views call in the (1, N, 3, h, w) convention of run_pose_model."""

    def __init__(self, model: torch.nn.Module):
        super().__init__()
        self.model = model

    def forward(self, imgs: torch.Tensor):
        views = [{"img": imgs[:, k], "data_norm_type": ["identity"]} for k in range(imgs.shape[1])]
        return self.model.infer(views) if hasattr(self.model, "infer") else self.model(views)


def mapanything_backbone(frame, rig, config) -> BackboneResult:
    """MapAnything (facebookresearch/map-anything) from a local checkpoint directory or file."""
    try:
        from mapanything.models import MapAnything
    except ImportError:
        raise CalibrationError(
            "backbone 'mapanything' needs the mapanything package (github.com/facebookresearch/map-anything) "
            "and a local checkpoint via backbone_path; or export with scripts/export_backbone.py and use "
            "backbone 'precomputed'"
        ) from None
    ckpt = _checkpoint(config, "mapanything")
    model = MapAnything.from_pretrained(str(ckpt.parent), local_files_only=True)
    return run_pose_model(_MapAnythingViews(model), frame.color, _mapanything_decode, "mapanything")
