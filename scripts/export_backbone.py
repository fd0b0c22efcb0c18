#!/usr/bin/env python
"""Export a pose backbone's predictions for FuseFlow's ``precomputed`` backbone.

Run this on the machine where the model is installed (GPU box), then copy the .npz next to the
recording and calibrate with ``fuseflow calibrate REC --backbone precomputed --backbone-path X.npz``.
The layout is documented in ``fuseflow/calib/backbones/precomputed.py``.

    # VGGT (github.com/facebookresearch/vggt), local state dict:
    python scripts/export_backbone.py vggt REC --checkpoint model.pt --out poses.npz
    # MapAnything (github.com/facebookresearch/map-anything), local checkpoint:
    python scripts/export_backbone.py mapanything REC --checkpoint ckpt/model.safetensors --out poses.npz
    # VGGSfM (or any SfM) writes a COLMAP model; image names must be <camera id>.<ext>:
    python scripts/export_backbone.py colmap-model SPARSE_DIR --out poses.npz

REC is a FuseFlow recording (frame --frame) or a folder of images named <camera id>.png/.jpg.
Nothing is downloaded: checkpoints must be local files.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def _images(src: Path, frame: int):
    """(camera ids, (N, H, W, 3) uint8 torch tensor)."""
    import torch

    if (src / "rig.json").is_file():
        import fuseflow

        rec = fuseflow.open_recording(src)
        fr = rec[frame]
        return list(fr.camera_ids), fr.color
    import cv2

    files = sorted(p for p in src.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
    if not files:
        sys.exit(f"no images in {src}")
    imgs = [cv2.cvtColor(cv2.imread(str(p)), cv2.COLOR_BGR2RGB) for p in files]
    return [p.stem for p in files], torch.from_numpy(np.stack(imgs))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("model", choices=["vggt", "mapanything", "colmap-model"])
    ap.add_argument("src", type=Path, help="recording / image folder (vggt, mapanything) or COLMAP model dir")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--checkpoint", type=Path, help="local checkpoint file (vggt, mapanything)")
    ap.add_argument("--frame", type=int, default=0)
    a = ap.parse_args(argv)
    from fuseflow.calib.backbones.precomputed import save_precomputed

    if a.model == "colmap-model":
        import pycolmap

        rec = pycolmap.Reconstruction(str(a.src))
        ids, Ts = [], []
        for im in sorted(rec.images.values(), key=lambda im: im.name):
            T = np.eye(4)
            T[:3, :] = np.asarray(im.cam_from_world().matrix())
            ids.append(Path(im.name).stem)
            Ts.append(T)
        save_precomputed(a.out, ids, np.stack(Ts), source="colmap-model")
        print(f"wrote {a.out}: {len(ids)} cameras from {a.src}")
        return 0
    from fuseflow.calib.backbones import neural
    from fuseflow.calib.config import CalibConfig

    ids, color = _images(a.src, a.frame)
    cfg = CalibConfig(backbone=a.model, backbone_path=str(a.checkpoint) if a.checkpoint else None)

    class _F:  # the adapters read only .color
        pass

    fr = _F()
    fr.color = color
    res = neural.vggt_backbone(fr, None, cfg) if a.model == "vggt" else neural.mapanything_backbone(fr, None, cfg)
    save_precomputed(a.out, ids, res.T_cam_world, source=a.model, features=res.features)
    print(f"wrote {a.out}: {len(ids)} cameras, model {a.model}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
