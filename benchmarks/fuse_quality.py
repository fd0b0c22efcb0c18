"""FUSE quality against the simulator's ground-truth surface: FUSE, its Table VII ablations,
VoxelBlockGrid TSDF and naive fusion; plus FUSE's density / quality / time trade-off.

    flock /tmp/fuseflow-cpu.lock .venv/bin/python benchmarks/fuse_quality.py --json docs/data/fuse_quality.json

Data: two simulated 8-camera rings (``--cameras``) at 640x480 (fuseflow.synth, scene "studio", Kinect-class
noise with flying pixels, lateral noise, quantisation and dropout; GT extrinsics): one static,
one dynamic (walking figure, bouncing box, rolling sphere). ``--frames`` frames of each.

Metrics per frame against the GT surface some camera saw (fuseflow.eval.reference: recall and
completeness on its 1 cm samples, precision / accuracy / outliers by the exact distance to the
true surface), then the mean over frames:

* chamfer_mm, accuracy_mm (cloud -> surface), completeness_mm (surface -> cloud);
* precision, recall and F at 5 mm, 1 cm and 2 cm (f_5mm, precision_1cm, recall_2cm, ...);
* outlier_2cm: share of points farther than 2 cm from the surface;
* or_5mm: the paper's outlier ratio, share of points with fewer than 3 others within 5 mm
  (depends on density: see docs/metrics.md);
* points per frame; ms per frame (median, this process, after one warm-up call per method).

Rows: FUSE (default), the paper preset (eq. 20-21 and 27 as written), each ablation of
fuseflow.fuse.ABLATIONS, the default with visibility_aware / min_weight / range_priority changed, VoxelBlockGrid TSDF 1 cm, naive (every valid pixel) and naive + voxel
1 cm. The density section runs FUSE with other s0 (eq. 24; it sets the points per fine cell)
and k_max on the static rig.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np


def _methods():
    from fuseflow.eval.baselines import naive_fusion, tsdf_fusion, voxel_downsampled_fusion
    from fuseflow.fuse import ABLATIONS, PRESETS, FuseConfig, fuse, parse_settings

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
    rows["FUSE lone_cell_keep=0"] = f(FuseConfig().replace(rps={"lone_cell_keep": 0}))  # session 9's lone-point rule
    for s_max in (0.01, 0.02):  # the fine cell's upper clip (eq. 24), 5 cm by default
        rows[f"FUSE s_max={s_max:g}"] = f(FuseConfig().replace(ash={"s_max": s_max}))
    rows["VBG TSDF 1 cm"] = lambda frame, rig: tsdf_fusion(frame, rig, voxel=0.01)
    rows["naive"] = naive_fusion
    rows["naive + voxel 1 cm"] = lambda frame, rig: voxel_downsampled_fusion(frame, rig, voxel=0.01)
    return rows


def _density_methods():
    from fuseflow.fuse import FuseConfig, fuse

    out = {}
    for s0, k_max in ((3.2, 3), (4.5, 3), (6.3, 3), (9.0, 3), (6.3, 1)):  # (6.3, 3) = the default
        cfg = FuseConfig().replace(ash={"s0": s0}, rps={"k_max": k_max})
        out[f"FUSE s0={s0} k_max={k_max}"] = (lambda c: lambda frame, rig: fuse(frame, rig, c))(cfg)
    return out


def _score(cloud, ref) -> dict:
    # fuseflow.eval.reference: precision / accuracy / outliers against the true surface,
    # recall / completeness on the seen samples; plus the paper's OR at 5 mm
    from fuseflow.eval.metrics import outlier_ratio

    pts = cloud.xyz.numpy()
    return {**ref.score(pts), "or_5mm": outlier_ratio(pts, radius=0.005).ratio}


def _reference(sf, sim):
    """The seen GT surface of frame sf (fuseflow.eval.reference.simulated_reference)."""
    from fuseflow.eval.reference import simulated_reference

    pts, nrm = sf.surface_points.numpy(), sf.surface_normals.numpy()
    return simulated_reference(sim, sf.frame.index, (pts, nrm), sf.depth_gt.numpy())


def _tail_cells(sf, rig, gt, cfg) -> dict:
    """Where FUSE's points beyond 2 cm come from (torch reference, one frame): the RPS inputs
    (candidates, their fine cell, k per cell) are captured around select_representatives."""
    import importlib

    from fuseflow.fuse import fuse

    api = importlib.import_module("fuseflow.fuse.api")
    cap: dict = {}
    orig = api.select_representatives

    def grab(P, omega, inv, k, k_max):
        sel = orig(P, omega, inv, k, k_max)
        cap.update(P=P.numpy(), inv=inv.numpy(), k=k.numpy(), sel=sel.numpy())
        return sel

    api.select_representatives = grab
    try:
        fuse(sf.frame, rig, cfg.replace(backend="torch"))
    finally:
        api.select_representatives = orig
    inv, sel, k = cap["inv"], cap["sel"], cap["k"]
    bad = gt.distance_to_surface(cap["P"]) > 0.02
    n = np.bincount(inv)
    good = np.bincount(inv, weights=(~bad).astype(np.float64))
    c = inv[sel[bad[sel]]]  # cells of the selected points beyond 2 cm
    return {
        "candidates_beyond_2cm": float(bad.mean()),
        "selected_beyond_2cm": float(bad[sel].mean()),
        "tail_in_cells_without_good_candidate": float((good[c] == 0).mean()),
        "tail_in_singleton_cells": float((n[c] == 1).mean()),
        "tail_in_cells_with_k_good_candidates": float((good[c] >= k[c]).mean()),
    }


def _run_rig(
    name: str, dynamic: bool, methods: dict, frames: int, seed: int, res: tuple[int, int], cameras: int = 8
) -> list[dict]:
    from fuseflow.synth import SimConfig, Simulator

    sim = Simulator(SimConfig(cameras=cameras, frames=frames, resolution=res, dynamic=dynamic, seed=seed, rig="ring"))
    per: dict[str, list[dict]] = {m: [] for m in methods}
    ms: dict[str, list[float]] = {m: [] for m in methods}
    warm = set()
    for t in range(frames):
        sf = sim.render(t)
        gt = _reference(sf, sim)
        for m, fn in methods.items():
            if m not in warm:  # compile / start-up outside the timing
                fn(sf.frame, sim.rig)
                warm.add(m)
            t0 = time.perf_counter()
            cloud = fn(sf.frame, sim.rig)
            ms[m].append((time.perf_counter() - t0) * 1000.0)
            per[m].append(_score(cloud, gt))
        print(f"  {name} frame {t} done", flush=True)
    rows = []
    for m in methods:
        row = {"rig": name, "method": m, "frames": frames}
        for k in per[m][0]:
            row[k] = statistics.fmean(r[k] for r in per[m])
        row["ms"] = statistics.median(ms[m])
        rows.append(row)
        print(
            f"{name:8s} {m:30s} pts {row['points']:9.0f}  CD {row['chamfer_mm']:6.2f} mm  acc {row['accuracy_mm']:6.2f}  "
            f"F5 {row['f_5mm']:.3f}  F10 {row['f_1cm']:.3f}  out2cm {100 * row['outlier_2cm']:6.2f}%  "
            f"OR5 {100 * row['or_5mm']:6.2f}%  {row['ms']:7.1f} ms",
            flush=True,
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=2, help="frames per rig (mean over them)")
    ap.add_argument("--density-frames", type=int, default=1, help="frames of the density rows")
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--resolution", default="640x480")
    ap.add_argument("--cameras", type=int, default=8, help="cameras of the ring (default 8, issue 17's rigs)")
    ap.add_argument("--no-density", action="store_true", help="skip the density / quality trade-off rows")
    ap.add_argument("--only", default=None, help="comma-separated method names (default: all rows)")
    ap.add_argument(
        "--tail-cells",
        action="store_true",
        help="only print where FUSE's points beyond 2 cm sit (static rig, frame 0, default config)",
    )
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    w, h = (int(v) for v in args.resolution.lower().split("x"))
    if args.tail_cells:
        from fuseflow.fuse import FuseConfig
        from fuseflow.synth import SimConfig, Simulator

        sim = Simulator(SimConfig(cameras=8, frames=1, resolution=(w, h), dynamic=False, seed=args.seed, rig="ring"))
        sf = sim.render(0)
        gt = _reference(sf, sim)
        for rp in (False, True):
            out = _tail_cells(sf, sim.rig, gt, FuseConfig().replace(rps={"range_priority": rp}))
            print(f"range_priority={rp}: " + ", ".join(f"{k} {100 * v:.1f} %" for k, v in out.items()))
        return 0
    methods = _methods()
    if args.only:
        want = [m.strip() for m in args.only.split(",")]
        unknown = sorted(set(want) - set(methods))
        if unknown:
            ap.error(f"unknown methods {unknown}; methods are {sorted(methods)}")
        methods = {m: methods[m] for m in want}
    rows = []
    rows += _run_rig("static", False, methods, args.frames, args.seed, (w, h), args.cameras)
    rows += _run_rig("dynamic", True, methods, args.frames, args.seed, (w, h), args.cameras)
    density = []
    if not args.no_density:
        density = _run_rig("static", False, _density_methods(), args.density_frames, args.seed, (w, h))
    if args.json is not None:
        import torch

        meta = {
            "command": "benchmarks/fuse_quality.py " + " ".join(argv if argv is not None else sys.argv[1:]),
            "rigs": f"{args.cameras}-camera ring, studio scene, Kinect-class noise, GT extrinsics; static and dynamic",
            "resolution": [w, h],
            "frames": args.frames,
            "seed": args.seed,
            "reference": "fuseflow.eval.reference.simulated_reference: seen 1 cm samples (recall), exact "
            "distance to the true surface (precision)",
            "torch_threads": torch.get_num_threads(),
            "date": time.strftime("%Y-%m-%d %H:%M"),
        }
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"meta": meta, "rows": rows, "density": density}, indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
