"""FUSE's quality on simulated rings against the seen ground-truth surface, over a grid of rigs.

    python -m benchmarks.fuse_quality --cameras 3,4,8 --resolutions 320x240,640x480 --seeds 11,29,47,61,73,89

Each cell is one simulated ring (``fuseflow.synth``, scene "studio", Kinect-class noise with
flying pixels, lateral noise, quantisation and dropout; GT extrinsics) of a camera count, a
resolution, a seed and static or dynamic (walking figure, bouncing box, rolling sphere). Its
first ``frames`` frames are fused by each method and scored by
``fuseflow.eval.reference`` (precision, recall and F at 5 mm, 1 cm and 2 cm, accuracy,
completeness, share of points beyond 2 cm), with the fusion time of each call (ms, this
process, after one warm-up call per method and rig).

Methods: a FUSE preset name (``auto``, ``default``, ``live``, ... of ``fuseflow.fuse.PRESETS``),
optionally with settings changed as ``--set`` changes them, joined by ``+``
(``dense+mcm.max_missing=4+smoothing.radius=1``), ``naive`` (every valid pixel) or Open3D's
VoxelBlockGrid TSDF at 1 cm, extracted at one of three weight thresholds:

* ``vbg``: fuseflow's baseline setting (``TSDFConfig.weight_threshold`` 1.0: seen by 2 views);
* ``vbg_o3d``: Open3D's default (3.0);
* ``vbg_best``: the threshold of 0, 1, 2, 3 that maximises F at 1 cm on the cell (the baseline
  at its best on that rig and seed; the row's ``weight_threshold`` says which; its ``ms`` is
  one integration and extraction at that threshold).

:func:`summarize_quality` gives, per rig, the mean over cells and the number of cells where the
first method's F at 1 cm is at least VoxelBlockGrid's (``vbg``, and ``vbg_best`` when it ran).
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Sequence
from typing import Any

from fuseflow.errors import ValidationError

__all__ = [
    "BEST",
    "BestVBG",
    "DEFAULT_METHODS",
    "fusion_methods",
    "run_fuse_quality",
    "run_method",
    "summarize_quality",
]

DEFAULT_METHODS = ("auto", "vbg", "vbg_o3d", "vbg_best", "naive")
"""The methods of the grid by default: FUSE's default, VoxelBlockGrid 1 cm at fuseflow's,
Open3D's and its best extraction threshold, every valid pixel."""

BEST = "vbg_best"
"""The method that picks VoxelBlockGrid's best extraction threshold per cell (module docstring)."""


def fusion_methods(names: Sequence[str]) -> dict[str, Callable[[Any, Any], Any]]:
    """Name -> ``(frame, rig) -> FusedCloud`` for each of ``names`` (module docstring)."""
    from fuseflow.cli.settings import parse_settings
    from fuseflow.eval.baselines import OPEN3D_WEIGHT_THRESHOLD, naive_fusion, tsdf_fusion, tsdf_fusion_at_thresholds
    from fuseflow.fuse import PRESETS, fuse

    out: dict[str, Callable[[Any, Any], Any]] = {}
    for name in names:
        preset, *settings = name.split("+")
        if name == "vbg":
            out[name] = lambda frame, rig: tsdf_fusion(frame, rig, voxel=0.01)
        elif name == "vbg_o3d":
            out[name] = lambda frame, rig: tsdf_fusion_at_thresholds(frame, rig, [OPEN3D_WEIGHT_THRESHOLD], 0.01)[
                OPEN3D_WEIGHT_THRESHOLD
            ]
        elif name == BEST:
            out[name] = BestVBG()
        elif name == "naive":
            out[name] = naive_fusion
        elif preset in PRESETS:
            out[name] = (lambda c: lambda frame, rig: fuse(frame, rig, c))(
                PRESETS[preset].replace(**parse_settings(settings))
            )
        else:
            raise ValidationError(
                f"unknown method {name!r}: a FUSE preset {sorted(PRESETS)}, 'vbg', 'vbg_o3d', '{BEST}' or 'naive'"
            )
    return out


class BestVBG:
    """VoxelBlockGrid 1 cm at the threshold of WEIGHT_THRESHOLDS with the best F at 1 cm."""

    def __call__(self, frame, rig):  # the warm-up call (no reference): one integration
        from fuseflow.eval.baselines import tsdf_fusion_at_thresholds

        return tsdf_fusion_at_thresholds(frame, rig, [1.0], 0.01)[1.0]

    @staticmethod
    def choose(frame, rig, ref) -> float:
        from fuseflow.eval.baselines import best_tsdf_threshold

        return best_tsdf_threshold(frame, rig, lambda c: ref.score(c.xyz)["f_1cm"], voxel=0.01).threshold


def run_method(fn, frame, rig, ref) -> tuple[Any, float, float | None]:
    """(cloud, ms, weight threshold or None) of one method on one frame; ``vbg_best`` chooses its
    threshold against ``ref`` first and is timed at that threshold alone."""
    from fuseflow.eval.baselines import tsdf_fusion_at_thresholds

    thr = fn.choose(frame, rig, ref) if isinstance(fn, BestVBG) else None
    t0 = time.perf_counter()
    cloud = fn(frame, rig) if thr is None else tsdf_fusion_at_thresholds(frame, rig, [thr], 0.01)[thr]
    return cloud, (time.perf_counter() - t0) * 1000.0, thr


def _cell(cameras: int, res: tuple[int, int], seed: int, dynamic: bool, methods: dict, frames: int) -> list[dict]:
    """Rows of one simulated ring: per method the mean scores over ``frames`` frames."""
    from fuseflow.eval.reference import simulated_reference
    from fuseflow.synth import SimConfig, Simulator

    cfg = SimConfig(cameras=cameras, frames=frames, resolution=res, dynamic=dynamic, seed=seed, rig="ring")
    sim = Simulator(cfg)
    scores: dict[str, list[dict]] = {m: [] for m in methods}
    ms: dict[str, list[float]] = {m: [] for m in methods}
    thresholds: dict[str, list[float]] = {m: [] for m in methods}
    for t in range(frames):
        sf = sim.render(t)
        ref = simulated_reference(sim, t, (sf.surface_points.numpy(), sf.surface_normals.numpy()), sf.depth_gt.numpy())
        for m, fn in methods.items():
            if t == 0:
                fn(sf.frame, sim.rig)  # compilation / start-up outside the timing
            cloud, dt, thr = run_method(fn, sf.frame, sim.rig, ref)
            ms[m].append(dt)
            scores[m].append(ref.score(cloud.xyz))
            if thr is not None:
                thresholds[m].append(thr)
    rows = []
    for m in methods:
        row: dict = {"cameras": cameras, "resolution": f"{res[0]}x{res[1]}", "seed": seed, "dynamic": dynamic}
        row.update(method=m, frames=frames, ms=statistics.median(ms[m]))
        row.update({k: statistics.fmean(s[k] for s in scores[m]) for k in scores[m][0]})
        if thresholds[m]:
            row["weight_threshold"] = thresholds[m] if len(thresholds[m]) > 1 else thresholds[m][0]
        rows.append(row)
    return rows


def run_fuse_quality(
    cameras: Sequence[int] = (3, 4, 8),
    resolutions: Sequence[tuple[int, int]] = ((320, 240), (640, 480)),
    seeds: Sequence[int] = (11, 29, 47, 61, 73, 89),
    dynamics: Sequence[bool] = (False, True),
    methods: Sequence[str] = DEFAULT_METHODS,
    frames: int = 1,
    log: Callable[[str], None] | None = None,
) -> list[dict]:
    """One row per (cameras, resolution, seed, dynamic, method): the keys of
    ``SurfaceReference.score`` (mean over frames) plus cameras, resolution, seed, dynamic,
    method, frames and ms (median)."""
    if frames < 1:
        raise ValidationError(f"frames must be >= 1, got {frames}")
    fns = fusion_methods(methods)
    rows: list[dict] = []
    for n in cameras:
        for res in resolutions:
            for seed in seeds:
                for dyn in dynamics:
                    cell = _cell(n, tuple(res), seed, dyn, fns, frames)
                    rows += cell
                    if log:
                        for r in cell:
                            log(_line(r))
    return rows


def _line(r: dict) -> str:
    pr = "  ".join(
        f"P/R {r[f'precision_{k}']:.3f}/{r[f'recall_{k}']:.3f} F {r[f'f_{k}']:.3f} @{k}" for k in ("5mm", "1cm", "2cm")
    )
    kind = "dynamic" if r["dynamic"] else "static"
    return (f"{r['cameras']}-ring {r['resolution']} seed {r['seed']} {kind:7s} {r['method']:8s} "
            f"{r['points']:8.0f} pts  {pr}  >2cm {100 * r['outlier_2cm']:.2f} %  {r['ms']:.0f} ms")  # fmt: skip


def summarize_quality(rows: Sequence[dict], method: str | None = None, against: str = "vbg") -> list[dict]:
    """Per (cameras, resolution): for each method the mean of P, R, F at 1 cm and the share beyond
    2 cm over its cells, and ``wins``/``cells``: the cells where ``method`` (default: the first
    method of the rows) has F at 1 cm >= ``against``'s; ``wins_best``/``cells_best`` the same
    against ``vbg_best`` when it ran."""
    if not rows:
        return []
    method = method or rows[0]["method"]
    out = []
    rigs = sorted({(r["cameras"], r["resolution"]) for r in rows}, key=lambda k: (k[0], int(k[1].split("x")[0])))
    for n, res in rigs:
        mine = [r for r in rows if (r["cameras"], r["resolution"]) == (n, res)]
        s: dict = {"cameras": n, "resolution": res}
        for m in dict.fromkeys(r["method"] for r in mine):
            rs = [r for r in mine if r["method"] == m]
            for k in ("precision_1cm", "recall_1cm", "f_1cm", "outlier_2cm"):
                s[f"{m}_{k}"] = statistics.fmean(r[k] for r in rs)
        ours = {(r["seed"], r["dynamic"]): r["f_1cm"] for r in mine if r["method"] == method}
        theirs = {(r["seed"], r["dynamic"]): r["f_1cm"] for r in mine if r["method"] == against}
        both = sorted(set(ours) & set(theirs))
        s.update(method=method, against=against, cells=len(both), wins=sum(ours[c] >= theirs[c] for c in both))
        best = {(r["seed"], r["dynamic"]): r["f_1cm"] for r in mine if r["method"] == BEST}
        if best and method != BEST:
            both = sorted(set(ours) & set(best))
            s.update(cells_best=len(both), wins_best=sum(ours[c] >= best[c] for c in both))
        out.append(s)
    return out
