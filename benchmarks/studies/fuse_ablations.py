"""FUSE quality against the simulator's ground-truth surface: FUSE, its Table VII ablations and
switches, VoxelBlockGrid TSDF and naive fusion; plus FUSE's density / quality / time trade-off.

    python -m benchmarks.fuse_ablations --save

Data: two simulated rings of ``cameras`` cameras (8 by default) at 640x480 (fuseflow.synth,
scene "studio", Kinect-class noise with flying pixels, lateral noise, quantisation and dropout;
GT extrinsics): one static, one dynamic (walking figure, bouncing box, rolling sphere).
``frames`` frames of each.

Metrics per frame against the GT surface some camera saw (:func:`seen_reference`,
fuseflow.eval.reference: recall and completeness on its 1 cm samples, precision / accuracy /
outliers by the exact distance to the true surface), then the mean over frames:

* chamfer_mm, accuracy_mm (cloud -> surface), completeness_mm (surface -> cloud);
* precision, recall and F at 5 mm, 1 cm and 2 cm (f_5mm, precision_1cm, recall_2cm, ...);
* outlier_2cm: share of points farther than 2 cm from the surface;
* or_5mm: the paper's outlier ratio, share of points with fewer than 3 others within 5 mm
  (depends on density: see docs/metrics.md);
* points per frame; ms per frame (median, this process, after one warm-up call per method).

Rows (:func:`ablation_methods`): FUSE (default), the paper preset (eq. 20-21 and 27 as
written), each ablation of fuseflow.fuse.ABLATIONS, the default with visibility_aware /
min_weight / range_priority / ... changed, VoxelBlockGrid TSDF 1 cm (extracted at fuseflow's
weight threshold 1, at Open3D's 3 and at the best of 0-3 on the frame: the row's
``weight_threshold``), naive (every valid pixel) and naive + voxel 1 cm. The density rows (:func:`density_methods`) run FUSE with other s0
(eq. 24; it sets the points per fine cell) and k_max on the static rig.

(:mod:`benchmarks.studies.fuse_quality` is the grid of presets against VoxelBlockGrid over
many rigs: ``fuseflow bench fuse-quality``.)
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from typing import Any

from fuseflow.errors import ValidationError

__all__ = ["ablation_methods", "density_methods", "run_fuse_ablations", "run_rig", "score", "seen_reference"]

Log = Callable[[str], None]


def _quiet(line: str) -> None:
    del line


def ablation_methods() -> dict[str, Callable[[Any, Any], Any]]:
    """Row name -> ``(frame, rig) -> FusedCloud``: every row of the table (module docstring)."""
    from benchmarks.studies.fuse_quality import BestVBG
    from fuseflow.cli.settings import parse_settings
    from fuseflow.eval.baselines import (
        OPEN3D_WEIGHT_THRESHOLD,
        naive_fusion,
        tsdf_fusion,
        tsdf_fusion_at_thresholds,
        voxel_downsampled_fusion,
    )
    from fuseflow.fuse import ABLATIONS, PRESETS, FuseConfig, fuse

    def f(cfg):
        return lambda frame, rig: fuse(frame, rig, cfg)

    rows = {"FUSE": f(FuseConfig()), "FUSE paper preset": f(PRESETS["paper"])}
    rows.update({f"FUSE {k}": f(v) for k, v in ABLATIONS.items()})
    rows["FUSE visibility_aware=False"] = f(FuseConfig().replace(cvgc={"visibility_aware": False}))
    rows["FUSE min_weight=0"] = f(FuseConfig().replace(rps={"min_weight": 0.0}))
    # each switch flipped from the default
    for switch in ("rps.range_priority", "mcm.noise_aware", "rps.consensus", "cvgc.multiview_mean"):
        flip = not FuseConfig().describe()[switch]
        rows[f"FUSE {switch}={flip}"] = f(FuseConfig().replace(**parse_settings([f"{switch}={flip}"])))
    for k in (7,):  # more neighbours: more votes and more measurements for multiview_mean
        rows[f"FUSE k_neighbours={k}"] = f(FuseConfig().replace(cvgc={"k_neighbours": k}))
        off = FuseConfig().replace(cvgc={"k_neighbours": k, "multiview_mean": False})
        rows[f"FUSE k_neighbours={k} multiview_mean=False"] = f(off)
        rows[f"FUSE k_neighbours={k} s0=5"] = f(FuseConfig().replace(cvgc={"k_neighbours": k}, ash={"s0": 5.0}))
    rows["FUSE s0=5"] = f(FuseConfig().replace(ash={"s0": 5.0}))  # about VBG's point count (~430 k)
    for mm in (0, 1, 2, 3, 4):  # beyond the paper: gap-tolerant MCM window (mcm.py)
        if mm != FuseConfig().mcm.max_missing:
            rows[f"FUSE mcm_max_missing={mm}"] = f(FuseConfig().replace(mcm={"max_missing": mm}))
    for lone in (0.0, 1.5, 2.0, 3.0):  # beyond the paper: drop lone points of densely sampled coarse cells
        if lone != FuseConfig().rps.lone_cell_mean:
            rows[f"FUSE lone_cell_mean={lone:g}"] = f(FuseConfig().replace(rps={"lone_cell_mean": lone}))
    # beyond the paper: candidates on a pixel grid (the live preset: stride 2, s0 1, mcm_max_missing 4)
    rows["FUSE live preset"] = f(PRESETS["live"])
    rows["FUSE pixel_stride=2 s0=5"] = f(FuseConfig().replace(pixel_stride=2))
    for npt in (100_000, 200_000):  # a point budget, on the grid budget_stride picks and on every pixel
        rows[f"FUSE points={npt}"] = f(FuseConfig().replace(target_points=npt))
        rows[f"FUSE points={npt} budget_stride=False"] = f(FuseConfig().replace(target_points=npt, budget_stride=False))
    rows["FUSE lone_cell_keep=0"] = f(
        FuseConfig().replace(rps={"lone_cell_keep": 0})
    )  # one lone point per cell dropped
    for s_max in (0.01, 0.02):  # the fine cell's upper clip (eq. 24), 5 cm by default
        rows[f"FUSE s_max={s_max:g}"] = f(FuseConfig().replace(ash={"s_max": s_max}))
    rows["VBG TSDF 1 cm"] = lambda frame, rig: tsdf_fusion(frame, rig, voxel=0.01)
    rows["VBG TSDF 1 cm Open3D threshold"] = lambda frame, rig: tsdf_fusion_at_thresholds(
        frame, rig, [OPEN3D_WEIGHT_THRESHOLD], 0.01
    )[OPEN3D_WEIGHT_THRESHOLD]
    rows["VBG TSDF 1 cm best threshold"] = BestVBG()
    rows["naive"] = naive_fusion
    rows["naive + voxel 1 cm"] = lambda frame, rig: voxel_downsampled_fusion(frame, rig, voxel=0.01)
    return rows


def density_methods() -> dict[str, Callable[[Any, Any], Any]]:
    """The density rows: FUSE with other s0 (eq. 24) and k_max."""
    from fuseflow.fuse import FuseConfig, fuse

    out = {}
    for s0, k_max in ((3.2, 3), (4.5, 3), (6.3, 3), (9.0, 3), (6.3, 1)):  # (6.3, 3) = the default
        cfg = FuseConfig().replace(ash={"s0": s0}, rps={"k_max": k_max})
        out[f"FUSE s0={s0} k_max={k_max}"] = (lambda c: lambda frame, rig: fuse(frame, rig, c))(cfg)
    return out


def score(cloud, ref) -> dict:
    """``ref.score`` of the cloud plus the paper's outlier ratio at 5 mm (``or_5mm``)."""
    # fuseflow.eval.reference: precision / accuracy / outliers against the true surface,
    # recall / completeness on the seen samples; plus the paper's OR at 5 mm
    from fuseflow.eval.metrics import outlier_ratio

    pts = cloud.xyz.numpy()
    return {**ref.score(pts), "or_5mm": outlier_ratio(pts, radius=0.005).ratio}


def seen_reference(sf, sim):
    """The seen GT surface of frame sf (fuseflow.eval.reference.simulated_reference)."""
    from fuseflow.eval.reference import simulated_reference

    pts, nrm = sf.surface_points.numpy(), sf.surface_normals.numpy()
    return simulated_reference(sim, sf.frame.index, (pts, nrm), sf.depth_gt.numpy())


def run_rig(
    name: str,
    dynamic: bool,
    methods: dict,
    frames: int,
    seed: int,
    res: tuple[int, int],
    cameras: int = 8,
    log: Log = _quiet,
) -> list[dict]:
    """One simulated ring (``cameras`` cameras, static or ``dynamic``): per method the mean
    scores over ``frames`` frames and the median ms; a line per frame and per row to ``log``."""
    from benchmarks.studies.fuse_quality import run_method
    from fuseflow.synth import SimConfig, Simulator

    sim = Simulator(SimConfig(cameras=cameras, frames=frames, resolution=res, dynamic=dynamic, seed=seed, rig="ring"))
    per: dict[str, list[dict]] = {m: [] for m in methods}
    ms: dict[str, list[float]] = {m: [] for m in methods}
    warm = set()
    for t in range(frames):
        sf = sim.render(t)
        gt = seen_reference(sf, sim)
        for m, fn in methods.items():
            if m not in warm:  # compile / start-up outside the timing
                fn(sf.frame, sim.rig)
                warm.add(m)
            cloud, dt, thr = run_method(fn, sf.frame, sim.rig, gt)
            ms[m].append(dt)
            per[m].append(score(cloud, gt) | ({"weight_threshold": thr} if thr is not None else {}))
        log(f"  {name} frame {t} done")
    rows = []
    for m in methods:
        row = {"rig": name, "method": m, "frames": frames}
        for k in per[m][0]:
            row[k] = statistics.fmean(r[k] for r in per[m])
        row["ms"] = statistics.median(ms[m])
        rows.append(row)
        log(
            f"{name:8s} {m:30s} pts {row['points']:9.0f}  CD {row['chamfer_mm']:6.2f} mm  acc {row['accuracy_mm']:6.2f}  "
            f"F5 {row['f_5mm']:.3f}  F10 {row['f_1cm']:.3f}  out2cm {100 * row['outlier_2cm']:6.2f}%  "
            f"OR5 {100 * row['or_5mm']:6.2f}%  {row['ms']:7.1f} ms"
        )
    return rows


def run_fuse_ablations(
    frames: int = 2,
    density_frames: int = 1,
    seed: int = 11,
    resolution: tuple[int, int] = (640, 480),
    cameras: int = 8,
    density: bool = True,
    only: list[str] | None = None,
    command: str = "",
    log: Log = _quiet,
) -> dict:
    """The table: ``{"meta", "rows", "density"}``, rows of the static then the dynamic ring for
    the methods ``only`` names (default: every row of :func:`ablation_methods`), density rows
    on the static ring (8 cameras) unless ``density`` is False."""
    import torch

    methods = ablation_methods()
    if only:
        unknown = sorted(set(only) - set(methods))
        if unknown:
            raise ValidationError(f"unknown methods {unknown}; methods are {sorted(methods)}")
        methods = {m: methods[m] for m in only}
    rows = run_rig("static", False, methods, frames, seed, resolution, cameras, log)
    rows += run_rig("dynamic", True, methods, frames, seed, resolution, cameras, log)
    dens = run_rig("static", False, density_methods(), density_frames, seed, resolution, log=log) if density else []
    meta = {
        "command": command,
        "rigs": f"{cameras}-camera ring, studio scene, Kinect-class noise, GT extrinsics; static and dynamic",
        "resolution": list(resolution),
        "frames": frames,
        "seed": seed,
        "reference": "fuseflow.eval.reference.simulated_reference: seen 1 cm samples (recall), exact "
        "distance to the true surface (precision)",
        "torch_threads": torch.get_num_threads(),
        "date": time.strftime("%Y-%m-%d %H:%M"),
    }
    return {"meta": meta, "rows": rows, "density": dens}
