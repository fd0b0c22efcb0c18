"""``fuse(frame, rig, config) -> FusedCloud``: FUSE (paper III-C), stateless, one frame at a time.

Stages, each in its own module: MCM (mcm.py, eq. 16-18) -> back-projection -> CVGC over the
neighbour graph (neighbours.py, cvgc.py, eq. 19-21; with ``cvgc.multiview_mean`` each candidate also
becomes the mean of its agreeing neighbours' measurements) -> joint weight (weights.py, eq. 22) ->
ASH (ash.py, eq. 23-25) -> RPS (rps.py, eq. 26-28). This module checks and prepares the frame
and dispatches to one of two drivers: ``backend="torch"`` runs those modules (torch_driver.py,
the reference, any device); ``"numba"`` runs the same arithmetic fused into compiled CPU loops
(kernels/driver.py); ``"auto"`` picks numba for CPU tensors. A frame of numpy arrays gives a
cloud of numpy arrays, and on the numba path torch is never imported.
"""

from __future__ import annotations

import logging
import time
import warnings
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from fuseflow.errors import ValidationError
from fuseflow.fuse.config import FuseConfig
from fuseflow.fuse.neighbours import NeighbourGraph, neighbour_graph
from fuseflow.fuse.smooth import smooth_depth
from fuseflow.types import Frame, FusedCloud, Rig, to_numpy

if TYPE_CHECKING:
    import torch

__all__ = ["fuse", "fuse_frame", "fuse_with_report", "FuseResult", "FuseReport", "resolve_backend"]

log = logging.getLogger("fuseflow.fuse")


@dataclass(frozen=True)
class FuseReport:
    """What happened while fusing one frame.

    Attributes:
        backend: "torch" or "numba". device: where it ran.
        views: cameras in the frame. missing: ids of dropped views (not fused, no votes).
        empty: ids of present views with no valid depth. isolated: ids of cameras with no
            neighbour in the graph (their omega_geo is c(x), eq. 21).
        valid_pixels: pixels with depth in range. candidates: points passing eq. (27) and the
            minimum joint weight. out_of_range: candidates beyond the hash's addressable range.
        points: output points. ms: wall time of the call.
        pixel_stride: the pixel grid the candidates were taken on (FuseConfig.pixel_stride, or
            the coarser one FuseConfig.budget_stride picked for target_points, or auto_grid's).
        grid: with FuseConfig.auto_grid, what it chose and why (presets.auto_config); "" otherwise.
        warnings: human-readable lines about degraded inputs (also logged).
    """

    backend: str
    device: str
    views: int
    missing: tuple[str, ...] = ()
    empty: tuple[str, ...] = ()
    isolated: tuple[str, ...] = ()
    valid_pixels: int = 0
    candidates: int = 0
    out_of_range: int = 0
    points: int = 0
    ms: float = 0.0
    warnings: tuple[str, ...] = field(default=())
    pixel_stride: int = 1
    grid: str = ""


@dataclass(frozen=True)
class FuseResult:
    """A fused cloud (docs/design.md section 1) and its FuseReport."""

    cloud: FusedCloud
    report: FuseReport


@dataclass(frozen=True)
class _Prepared:
    """FUSE's inputs: torch tensors on the frame's device (torch backend) or numpy arrays (numba)."""

    depth: Any  # (N, H, W) float32, gated to each view's range, 0 for absent views
    color: Any  # (N, H, W, 3) uint8
    K: Any  # (N, 3, 3) float32
    T_cam_world: Any  # (N, 4, 4) float32
    T_world_cam: Any  # (N, 3, 4) float32
    rig_index: Any  # (N,) int16, rig position of each frame view
    present: Any  # (N,) bool
    graph: NeighbourGraph  # indices in frame order
    ids: tuple[str, ...]
    valid_per_view: tuple[int, ...]  # pixels with depth in range, per view


def resolve_backend(config: FuseConfig, device: torch.device | str) -> str:
    """The backend that ``config.backend`` selects for tensors on ``device``."""
    on_cpu = (device if isinstance(device, str) else device.type).split(":")[0] == "cpu"
    if config.backend == "torch":
        return "torch"
    if config.backend == "numba":
        if not on_cpu:
            raise ValidationError(
                f"backend 'numba' runs on CPU tensors; the frame is on {device} (use 'torch' or 'auto')"
            )
        return "numba"
    if not on_cpu:
        return "torch"
    try:
        import numba  # noqa: F401
    except ImportError:  # pragma: no cover - numba is a core dependency
        return "torch"
    return "numba"


def _prepare(frame: Frame, rig: Rig, config: FuseConfig, backend: str = "torch") -> _Prepared:
    if not isinstance(frame, Frame):
        raise ValidationError(f"frame must be a fuseflow.Frame, got {type(frame).__name__}")
    if not isinstance(rig, Rig):
        raise ValidationError(f"rig must be a fuseflow.Rig, got {type(rig).__name__}")
    if not isinstance(config, FuseConfig):
        raise ValidationError(f"config must be a fuseflow.fuse.FuseConfig, got {type(config).__name__}")
    w, h = frame.resolution
    cams = []
    for cid in frame.camera_ids:
        cam = rig[cid]  # ValidationError naming the id when the rig lacks it
        if (cam.width, cam.height) != (w, h):
            raise ValidationError(f"camera {cid!r} is {cam.width}x{cam.height} in the rig but the frame is {w}x{h}")
        cams.append(cam)
    missing_T = [c.id for c in cams if c.T_cam_world is None]
    if missing_T:
        raise ValidationError(
            f"cameras without extrinsics (T_cam_world is null): {missing_T}; FUSE needs a calibrated rig "
            "(run `fuseflow calibrate` or pass a calib.json)"
        )
    lo = np.array([max(c.depth_range[0], config.mcm.delta) for c in cams], dtype=np.float32)
    hi = np.array([min(c.depth_range[1], config.mcm.z_max) for c in cams], dtype=np.float32)
    arrays = {
        "K": np.stack([c.K for c in cams]).astype(np.float32),
        "T_cam_world": np.stack([c.T_cam_world for c in cams]).astype(np.float32),
        "T_world_cam": np.stack([c.T_world_cam for c in cams])[:, :3, :].astype(np.float32),
        "rig_index": np.array([rig.index(c.id) for c in cams], dtype=np.int16),
    }
    graph = neighbour_graph(Rig(tuple(cams)), config.cvgc.k_neighbours, config.cvgc.min_overlap)
    if backend == "numba":  # numpy arrays throughout (CPU), no torch
        from fuseflow.fuse.kernels import gate_depth

        present = to_numpy(frame.present)
        depth, per_view = gate_depth(to_numpy(frame.depth), lo, hi, present)  # one parallel pass
        color = np.ascontiguousarray(to_numpy(frame.color))
    else:
        import torch

        from fuseflow.fuse.torch_driver import gate_depth

        frame = frame.to(frame.device)  # torch tensors (a numpy frame is shared, not copied)
        present, color = frame.present, frame.color
        depth, per_view = gate_depth(frame.depth, lo, hi, present)
        arrays = {k: torch.from_numpy(v).to(depth.device) for k, v in arrays.items()}
    return _Prepared(
        depth=depth, color=color, **arrays, present=present, graph=graph, ids=tuple(frame.camera_ids),
        valid_per_view=per_view,
    )  # fmt: skip


def _report(
    p: _Prepared, index: int, backend: str, points: int, valid: int, cand: int, oor: int, ms: float, stride: int
) -> FuseReport:
    """The FuseReport of one fused frame: degraded views from the prepared inputs, counts, time."""
    pres = p.present.tolist()
    missing = tuple(cid for cid, ok in zip(p.ids, pres) if not ok)
    per_view = p.valid_per_view
    empty = tuple(cid for cid, ok, nv in zip(p.ids, pres, per_view) if ok and nv == 0)
    idx = p.graph.index.tolist()
    isolated = tuple(
        cid for i, (cid, ok) in enumerate(zip(p.ids, pres)) if ok and not any(j >= 0 and pres[j] for j in idx[i])
    )
    notes = []
    if missing:
        notes.append(f"views missing from frame {index}: {list(missing)} (fused without them)")
    if empty:
        notes.append(f"views with no valid depth in frame {index}: {list(empty)}")
    if isolated and len(p.ids) > 1:
        notes.append(f"cameras with no overlapping neighbour: {list(isolated)} (omega_geo = c, eq. 21)")
    if oor:
        notes.append(f"{oor} points beyond the spatial hash's range were dropped")
    return FuseReport(
        backend=backend,
        device="cpu" if isinstance(p.depth, np.ndarray) else str(p.depth.device),
        views=len(p.ids),
        missing=missing,
        empty=empty,
        isolated=isolated,
        valid_pixels=valid,
        candidates=cand,
        out_of_range=oor,
        points=points,
        ms=ms,
        warnings=tuple(notes),
        pixel_stride=stride,
    )


def _fuse_at(p: _Prepared, cfg: FuseConfig, backend: str) -> tuple[FusedCloud, int, int, int]:
    """(cloud, valid pixels, candidates, out-of-range) with the compiled kernels or the reference
    (kernels.fuse_numba, torch_driver.fuse_torch; with ``target_points`` each searches s0 with
    density.fit_s0). The depth is smoothed first (FuseConfig.smoothing) at this grid's pixels."""
    k = cfg.cvgc.k_neighbours
    if p.graph.index.shape[1] > k:  # auto_config's grid takes fewer than _prepare's
        g = p.graph  # the k most-overlapping neighbours come first (neighbour_graph)
        p = replace(p, graph=NeighbourGraph(g.index[:, :k], g.overlap[:, :k]))
    if cfg.smoothing.radius > 0:
        smoothed = smooth_depth(p.depth, cfg.smoothing.radius, cfg.smoothing.gate, cfg.noise_sigma, cfg.pixel_stride)
        p = replace(p, depth=smoothed)
    if backend == "numba":
        from fuseflow.fuse.kernels import fuse_numba

        return fuse_numba(p, cfg)
    from fuseflow.fuse.torch_driver import fuse_torch

    return fuse_torch(p, cfg)


def _fuse_prepared(p: _Prepared, cfg: FuseConfig, backend: str) -> tuple[FusedCloud, int, int, int, int]:
    """``_fuse_at`` on the pixel grid FuseConfig.budget_stride picks for target_points (its cloud
    is kept unless it ends more than density.BUDGET_SHORT below the budget: then the frame is
    fused again on pixel_stride's grid); the stride used is the last item."""
    if cfg.target_points is not None and cfg.budget_stride:
        from fuseflow.fuse.density import BUDGET_SHORT, budget_stride

        s = budget_stride(cfg.pixel_stride, cfg.target_points, sum(p.valid_per_view))
        if s > cfg.pixel_stride:
            out = _fuse_at(p, replace(cfg, pixel_stride=s), backend)
            if len(out[0]) >= (1.0 - BUDGET_SHORT) * cfg.target_points:
                return (*out, s)
            log.info("pixel_stride %d gave %d points for a budget of %d; fused on stride %d", s, len(out[0]),
                     cfg.target_points, cfg.pixel_stride)  # fmt: skip
    return (*_fuse_at(p, cfg, backend), cfg.pixel_stride)


def fuse_with_report(frame: Frame, rig: Rig, config: FuseConfig | None = None) -> FuseResult:
    """FUSE one frame and report what happened (missing / empty / isolated cameras, counts).

    Args:
        frame: the N views of one instant: depth (N, H, W) float32 metres (0 = none), colour
            (N, H, W, 3) uint8, ``present`` (N,) bool; torch tensors on any device, or numpy
            arrays (CPU).
        rig: a rig holding every camera of the frame (matched by id) with extrinsics
            (T_cam_world, camera-from-world, metres). Cameras of the rig absent from the frame
            are ignored.
        config: FuseConfig (default: ``FuseConfig()``).

    Returns:
        FuseResult: ``cloud`` (FusedCloud on the frame's device, numpy arrays for a numpy
        frame: xyz world metres, rgb, weight
        = eq. 22, camera = rig index of the source camera) and ``report``.
    """
    cfg = FuseConfig() if config is None else config
    t0 = time.perf_counter()
    if not isinstance(frame, Frame):
        raise ValidationError(f"frame must be a fuseflow.Frame, got {type(frame).__name__}")
    backend = resolve_backend(cfg, frame.device) if isinstance(cfg, FuseConfig) else "torch"
    p = _prepare(frame, rig, cfg, backend)
    cfg, sensor_note = _sensor_noise(cfg, rig, p.ids)
    grid = ""
    if cfg.auto_grid and cfg.target_points is None:
        from fuseflow.fuse.density import grid_spacing
        from fuseflow.fuse.presets import AUTO_COARSE_STRIDE, AUTO_SPACING_QUANTILE, auto_config

        views = sum(1 for ok in p.present.tolist() if ok)

        def spacing() -> float:
            return grid_spacing(p.depth, p.K, AUTO_COARSE_STRIDE, AUTO_SPACING_QUANTILE)

        cfg, grid = auto_config(cfg, views, sum(p.valid_per_view), spacing)
    cloud, valid, cand, oor, stride = _fuse_prepared(p, cfg, backend)
    if frame.is_numpy != cloud.is_numpy:  # the cloud holds what the frame held
        cloud = cloud.numpy() if frame.is_numpy else cloud.to("cpu")
    if not cloud.is_numpy and cloud.device.type == "cuda":
        import torch

        torch.cuda.synchronize(cloud.device)
    ms = (time.perf_counter() - t0) * 1000.0
    report = replace(_report(p, frame.index, backend, len(cloud), valid, cand, oor, ms, stride), grid=grid)
    if sensor_note:
        report = replace(report, warnings=(*report.warnings, sensor_note))
    return FuseResult(cloud, report)


def _sensor_noise(cfg: FuseConfig, rig: Rig, ids: tuple[str, ...]) -> tuple[FuseConfig, str]:
    """``cfg`` with noise_sigma from the frame's cameras' sensors (Camera.sensor, rig.json; a
    camera naming none keeps cfg.noise_sigma), and a warning line. The kernels take one sigma(z)
    per frame: cameras naming different sensors keep cfg.noise_sigma, and the line says so."""
    from fuseflow.geometry.noise import camera_noise

    models = {tuple(camera_noise(rig[c].sensor, cfg.noise_sigma)) for c in ids}
    if len(models) == 1:
        (m,) = models
        return (cfg if m == tuple(cfg.noise_sigma) else replace(cfg, noise_sigma=m)), ""
    names = sorted({str(rig[c].sensor) for c in ids})
    return cfg, f"cameras name different depth sensors ({', '.join(names)}): sigma(z) is noise_sigma {cfg.noise_sigma}"


def fuse(frame: Frame, rig: Rig, config: FuseConfig | None = None) -> FusedCloud:
    """FUSE one frame (paper III-C): the fused cloud only; degraded inputs are logged.

    See :func:`fuse_with_report` for the arguments and the report.
    """
    result = fuse_with_report(frame, rig, config)
    for line in result.report.warnings:
        log.warning(line)
    return result.cloud


def fuse_frame(frame: Frame, rig: Rig, config: FuseConfig | None = None) -> FusedCloud:
    """``fuseflow.fuse``: FUSE one frame as the CLI does, for a user of the Python API.

    * ``config`` None is the ``auto`` preset (``PRESETS["auto"]``: the pixel grid chosen per frame,
      the default of ``fuseflow fuse`` / ``run`` and of ``fuseflow.stream``).
    * Cameras of the frame that ``rig`` does not place (no extrinsics, e.g. ``calib.apply(rig)``
      of a calibration that left them unplaced) are left out, with a warning naming them; every
      degraded input FUSE reports (missing or empty views, isolated cameras) is a warning too
      (``warnings.warn``, UserWarning).
    * The cloud holds numpy arrays unless the frame is on a GPU (a frame on ``cuda`` gives a
      cloud there): ``cloud.xyz`` is an (M, 3) float32 array.

    ``fuseflow.fuse.fuse`` / ``fuse_with_report`` are the engine underneath: FuseConfig() by
    default, the cloud where the frame's tensors are, warnings in the report and the log."""
    from fuseflow.fuse.presets import PRESETS

    if not isinstance(frame, Frame):
        raise ValidationError(f"frame must be a fuseflow.Frame, got {type(frame).__name__}")
    if not isinstance(rig, Rig):
        raise ValidationError(f"rig must be a fuseflow.Rig, got {type(rig).__name__}")
    cfg = PRESETS["auto"] if config is None else config
    known = [c for c in frame.camera_ids if c in rig.ids]
    unplaced = [c for c in known if rig[c].T_cam_world is None]
    if unplaced and len(unplaced) < len(known):
        keep = [i for i, c in enumerate(frame.camera_ids) if c not in unplaced]
        warnings.warn(
            f"cameras {unplaced} have no extrinsics (the calibration did not place them): fused from "
            f"{len(keep)} of {frame.num_views} cameras",
            stacklevel=2,
        )
        frame = frame.subset(keep)
    result = fuse_with_report(frame, rig, cfg)
    for line in result.report.warnings:
        warnings.warn(line, stacklevel=2)
    cloud = result.cloud
    return cloud if cloud.is_numpy or cloud.device.type != "cpu" else cloud.numpy()
