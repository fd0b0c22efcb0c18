"""FUSE's quality on simulated rings against the seen ground-truth surface, over a grid of rigs.

    fuseflow bench fuse-quality --cameras 3,4,8 --resolutions 320x240,640x480 --seeds 11,29,47,61,73,89

Each cell is one simulated ring (``fuseflow.synth``, scene "studio", Kinect-class noise with
flying pixels, lateral noise, quantisation and dropout; GT extrinsics) of a camera count, a
resolution, a seed and static or dynamic (walking figure, bouncing box, rolling sphere). Its
first ``frames`` frames are fused by each method and scored by
``fuseflow.eval.reference`` (precision, recall and F at 5 mm, 1 cm and 2 cm, accuracy,
completeness, share of points beyond 2 cm), with the fusion time of each call (ms, this
process, after one warm-up call per method and rig).

Methods: a FUSE preset name (``auto``, ``default``, ``live``, ... of ``fuseflow.fuse.PRESETS``),
optionally with settings changed as ``--set`` changes them, joined by ``+``
(``dense+mcm.max_missing=4+smoothing.radius=1``), ``vbg`` (Open3D VoxelBlockGrid TSDF, 1 cm)
or ``naive`` (every valid pixel).
:func:`summarize_quality` gives, per rig, the mean over cells and the number of cells where the
first method's F at 1 cm is at least VoxelBlockGrid's.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Sequence
from typing import Any

from fuseflow.errors import ValidationError

__all__ = ["DEFAULT_METHODS", "fusion_methods", "run_fuse_quality", "summarize_quality"]

DEFAULT_METHODS = ("auto", "vbg", "naive")
"""The methods of the grid by default: FUSE's default, VoxelBlockGrid 1 cm, every valid pixel."""


def fusion_methods(names: Sequence[str]) -> dict[str, Callable[[Any, Any], Any]]:
    """Name -> ``(frame, rig) -> FusedCloud`` for each of ``names`` (module docstring)."""
    from fuseflow.eval.baselines import naive_fusion, tsdf_fusion
    from fuseflow.fuse import PRESETS, fuse
    from fuseflow.fuse.config import parse_settings

    out: dict[str, Callable[[Any, Any], Any]] = {}
    for name in names:
        preset, *settings = name.split("+")
        if name == "vbg":
            out[name] = lambda frame, rig: tsdf_fusion(frame, rig, voxel=0.01)
        elif name == "naive":
            out[name] = naive_fusion
        elif preset in PRESETS:
            out[name] = (lambda c: lambda frame, rig: fuse(frame, rig, c))(
                PRESETS[preset].replace(**parse_settings(settings))
            )
        else:
            raise ValidationError(f"unknown method {name!r}: a FUSE preset {sorted(PRESETS)}, 'vbg' or 'naive'")
    return out


def _cell(cameras: int, res: tuple[int, int], seed: int, dynamic: bool, methods: dict, frames: int) -> list[dict]:
    """Rows of one simulated ring: per method the mean scores over ``frames`` frames."""
    from fuseflow.eval.reference import simulated_reference
    from fuseflow.synth import SimConfig, Simulator

    cfg = SimConfig(cameras=cameras, frames=frames, resolution=res, dynamic=dynamic, seed=seed, rig="ring")
    sim = Simulator(cfg)
    scores: dict[str, list[dict]] = {m: [] for m in methods}
    ms: dict[str, list[float]] = {m: [] for m in methods}
    for t in range(frames):
        sf = sim.render(t)
        ref = simulated_reference(sim, t, (sf.surface_points.numpy(), sf.surface_normals.numpy()), sf.depth_gt.numpy())
        for m, fn in methods.items():
            if t == 0:
                fn(sf.frame, sim.rig)  # compilation / start-up outside the timing
            t0 = time.perf_counter()
            cloud = fn(sf.frame, sim.rig)
            ms[m].append((time.perf_counter() - t0) * 1000.0)
            scores[m].append(ref.score(cloud.xyz))
    rows = []
    for m in methods:
        row: dict = {"cameras": cameras, "resolution": f"{res[0]}x{res[1]}", "seed": seed, "dynamic": dynamic}
        row.update(method=m, frames=frames, ms=statistics.median(ms[m]))
        row.update({k: statistics.fmean(s[k] for s in scores[m]) for k in scores[m][0]})
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
    method of the rows) has F at 1 cm >= ``against``'s."""
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
        out.append(s)
    return out
