"""Writing a simulated recording with its ground truth, and reading the ground truth back.

Layout written by ``simulate_recording`` (the recording part is the project format, read by
``fuseflow.io.open_recording``)::

    OUT/rig.json                              true extrinsics (perturbed by calib_error, or
                                              null with uncalibrated=True)
    OUT/<cam>/color/<frame:06d>.png           8-bit RGB
    OUT/<cam>/depth/<frame:06d>.png           uint16 noisy depth, value / depth_scale = metres
    OUT/gt.json                               {"format": "fuseflow-gt/1", "cameras": {id: {"T_cam_world",
                                              "K"}}, "config": SimConfig fields, "frames": F,
                                              "depth": "png-uint16", "depth_scale": s}
    OUT/gt/<cam>/depth/<frame:06d>.png        uint16 noise-free depth at depth_scale (0 = no hit)
    OUT/gt/surface_<frame:06d>.ply            binary PLY, x y z nx ny nz float32 (Open3D reads it)
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fuseflow.errors import FormatError, RecordingError, ValidationError
from fuseflow.io.files import load_json, read_bytes, write_bytes_atomic, write_json_atomic
from fuseflow.synth.config import SimConfig
from fuseflow.synth.simulator import Simulator
from fuseflow.types import Rig

__all__ = ["GT_FORMAT", "GroundTruth", "simulate_recording", "read_ground_truth", "write_surface_ply",
           "read_surface_ply", "perturb_extrinsics"]  # fmt: skip

GT_FORMAT = "fuseflow-gt/1"


def write_surface_ply(path: str | Path, points: np.ndarray, normals: np.ndarray) -> Path:
    """Binary little-endian PLY with x y z nx ny nz (float32), written via a temp file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arr = np.empty(len(points), dtype=[(k, "<f4") for k in ("x", "y", "z", "nx", "ny", "nz")])
    for k, (src, c) in zip(("x", "y", "z", "nx", "ny", "nz"), [(points, 0), (points, 1), (points, 2),
                                                                (normals, 0), (normals, 1), (normals, 2)]):  # fmt: skip
        arr[k] = src[:, c]
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment fuseflow simulator ground-truth surface\n"
        f"element vertex {len(arr)}\n"
        + "".join(f"property float {k}\n" for k in ("x", "y", "z", "nx", "ny", "nz"))
        + "end_header\n"
    )
    return write_bytes_atomic(path, header.encode("ascii"), arr.tobytes())


def read_surface_ply(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(points (S, 3), normals (S, 3)) float32 from a file written by ``write_surface_ply``."""
    path = Path(path)
    data = read_bytes(path)
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        raise FormatError(f"{path}: not a PLY file")
    header = data[:end].decode("ascii", "replace").splitlines()
    props = [ln.split()[-1] for ln in header if ln.startswith("property")]
    if "format binary_little_endian 1.0" not in header or props != ["x", "y", "z", "nx", "ny", "nz"]:
        raise FormatError(f"{path}: expected binary PLY with float x y z nx ny nz, got header {header}")
    n = int(next(ln.split()[-1] for ln in header if ln.startswith("element vertex")))
    body = np.frombuffer(data, dtype="<f4", offset=end + len(b"end_header\n"))
    if body.size != 6 * n:
        raise FormatError(f"{path}: {n} vertices declared, {body.size / 6:g} present (truncated?)")
    body = body.reshape(n, 6)
    return body[:, :3].copy(), body[:, 3:].copy()


def perturb_extrinsics(rig: Rig, deg: float, mm: float, rng: np.random.Generator) -> Rig:
    """Rig whose every T_cam_world is rotated by ``deg`` about a random axis (through the camera
    centre) and whose camera centre moves ``mm`` in a random direction."""
    out = {}
    for cam in rig.cameras:
        axis = rng.standard_normal(3)
        axis /= np.linalg.norm(axis)
        a = math.radians(deg)
        Kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        dR = np.eye(3) + math.sin(a) * Kx + (1 - math.cos(a)) * Kx @ Kx
        direction = rng.standard_normal(3)
        direction /= np.linalg.norm(direction)
        T_wc = cam.T_world_cam
        T_wc_new = np.eye(4)
        T_wc_new[:3, :3] = T_wc[:3, :3] @ dR
        T_wc_new[:3, 3] = T_wc[:3, 3] + direction * mm / 1000.0
        T = np.eye(4)
        T[:3, :3] = T_wc_new[:3, :3].T
        T[:3, 3] = -T_wc_new[:3, :3].T @ T_wc_new[:3, 3]
        out[cam.id] = T
    return rig.with_extrinsics(out)


def _rig_to_write(rig: Rig, cfg: SimConfig, uncalibrated: bool) -> Rig:
    """The rig of rig.json: null extrinsics, perturbed ones (cfg.calib_error_*), or ``rig`` itself."""
    if uncalibrated:
        return Rig(tuple(c.with_extrinsics(None) for c in rig.cameras))
    if cfg.calib_error_deg > 0 or cfg.calib_error_mm > 0:
        return perturb_extrinsics(rig, cfg.calib_error_deg, cfg.calib_error_mm,
                                  np.random.default_rng([cfg.seed, 0xCA1]))  # fmt: skip
    return rig


def _gt_doc(rig: Rig, cfg: SimConfig, extrinsics: str) -> dict:
    """gt.json: the true cameras, the config, and what rig.json holds ('true', 'perturbed', 'none')."""
    return {
        "format": GT_FORMAT,
        "cameras": {c.id: {"T_cam_world": c.T_cam_world.tolist(), "K": c.K.tolist()} for c in rig.cameras},
        "config": cfg.to_json(),
        "frames": cfg.frames,
        "depth": "png-uint16",
        "depth_scale": cfg.depth_scale,
        "rig_json_extrinsics": extrinsics,
    }


def simulate_recording(
    out_dir: str | Path,
    cfg: SimConfig,
    uncalibrated: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> Path:
    """Simulate ``cfg`` and write the recording plus ground truth into ``out_dir``.

    rig.json gets the true extrinsics, perturbed when cfg.calib_error_deg / _mm are set, or
    null extrinsics when ``uncalibrated``. ``progress(done, total)`` is called after each frame.
    Returns ``out_dir``.
    """
    from fuseflow.io import write_frame, write_rig
    from fuseflow.io.images import write_depth

    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise RecordingError(f"{out}: exists and is not a directory")
    if out.is_dir() and (out / "rig.json").exists():
        raise RecordingError(f"{out}: already holds a recording (rig.json); choose an empty directory")
    if cfg.scene == "polyroom":
        from fuseflow.synth.studio_b import PolyroomSimulator

        sim = PolyroomSimulator(cfg)
        moving = sim.moving
    else:
        sim = Simulator(cfg)
        moving = any(p.moving for p in sim.scene.parts)
    rig = sim.rig
    written = _rig_to_write(rig, cfg, uncalibrated)
    out.mkdir(parents=True, exist_ok=True)
    write_rig(out, written)
    extrinsics = "none" if uncalibrated else ("perturbed" if written is not rig else "true")
    write_json_atomic(out / "gt.json", _gt_doc(rig, cfg, extrinsics))

    def write(t: int, sf) -> None:
        write_frame(out, written, t, sf.frame.color, sf.frame.depth)
        dgt = sf.depth_gt.numpy()
        for i, cam in enumerate(rig.cameras):
            write_depth(out / "gt" / cam.id / "depth" / f"{t:06d}.png", dgt[i], cam.depth_scale)
        ply = out / "gt" / f"surface_{t:06d}.ply"
        if t > 0 and not moving:
            # static scene: the surface of every frame is that of frame 0; a hard link saves
            # ~30 MB per frame at the default density (a copy where links are not supported)
            try:
                os.link(out / "gt" / "surface_000000.ply", ply)
                return
            except OSError:
                pass
        write_surface_ply(ply, sf.surface_points.numpy(), sf.surface_normals.numpy())

    # frame t is written (PNG encoding releases the GIL) while frame t + 1 renders; at most one
    # frame waits, so memory stays at two frames
    with ThreadPoolExecutor(max_workers=1) as pool:
        pending = None
        for t in range(cfg.frames):
            sf = sim.render(t)
            if pending is not None:
                pending.result()
                if progress is not None:
                    progress(t, cfg.frames)
            pending = pool.submit(write, t, sf)
        pending.result()
    if progress is not None:
        progress(cfg.frames, cfg.frames)
    return out


@dataclass(frozen=True)
class GroundTruth:
    """Ground truth of a simulated recording.

    Attributes:
        path: the recording directory.
        rig: the true rig (T_cam_world of every camera, K, resolution, depth_scale).
        config: the SimConfig the recording was made with.
        frames: number of frames.
    """

    path: Path
    rig: Rig
    config: SimConfig
    frames: int

    def _check(self, t: int) -> int:
        if isinstance(t, bool) or not isinstance(t, (int, np.integer)) or not 0 <= t < self.frames:
            raise ValidationError(f"frame index must be an integer in [0, {self.frames}), got {t!r}")
        return int(t)

    def depth(self, t: int):
        """(N, H, W) float32 torch tensor: noise-free depth in metres of frame t (0 = no hit),
        quantized to 1 / depth_scale (1 mm by default)."""
        import torch

        from fuseflow.io.images import read_depth

        t = self._check(t)
        return torch.from_numpy(
            np.stack([read_depth(self.path / "gt" / c.id / "depth" / f"{t:06d}.png", c.depth_scale) for c in self.rig])
        )

    def surface(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        """(points (S, 3), normals (S, 3)) float32 world metres: the true surface at frame t."""
        t = self._check(t)
        return read_surface_ply(self.path / "gt" / f"surface_{t:06d}.ply")


def read_ground_truth(rec_dir: str | Path) -> GroundTruth:
    """Read OUT/gt.json of a simulated recording; errors name the file and the field."""
    from fuseflow.io.recording import rig_from_json

    rec = Path(rec_dir)
    path = rec / "gt.json"
    doc = load_json(path)
    if not isinstance(doc, dict) or doc.get("format") != GT_FORMAT:
        raise FormatError(f"{path}: field 'format' must be {GT_FORMAT!r}")
    try:
        rig_doc = json.loads((rec / "rig.json").read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise RecordingError(f"{rec / 'rig.json'}: cannot read ({exc})") from None
    cams = doc.get("cameras")
    if not isinstance(cams, dict):
        raise FormatError(f"{path}: field 'cameras' must be an object id -> {{T_cam_world, K}}")
    for c in rig_doc.get("cameras", []):
        if c.get("id") not in cams:
            raise FormatError(f"{path}: no ground truth for camera {c.get('id')!r}")
        c["T_cam_world"] = cams[c["id"]]["T_cam_world"]
        c["K"] = cams[c["id"]]["K"]
    rig = rig_from_json(rig_doc, str(path))
    try:
        cfg = SimConfig.from_json(doc.get("config", {}))
    except (TypeError, ValidationError) as exc:
        raise FormatError(f"{path}: field 'config': {exc}") from None
    return GroundTruth(rec, rig, cfg, int(doc.get("frames", cfg.frames)))
