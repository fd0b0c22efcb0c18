"""The metric RGB-D backbone on sparse wide-baseline rigs, against ground truth.

    python -m benchmarks.calib_wide sim --cameras 3,4 --scenes room --seeds 1,2,3
    python -m benchmarks.calib_wide hocap
    python -m benchmarks.calib_wide summary --out /tmp/fuseflow-calib_wide.jsonl

Data (``what``):

* ``sim``: ``fuseflow simulate`` rings of N cameras (room / studio, static, Kinect noise,
  640x480), reference = the recording's true extrinsics (rig.json). Each recording has F frames;
  the backbone runs on frame 0 alone and on all F frames.
* ``hocap``: ``hocap-8rs`` (8 RealSense, one frame; reference = target-based camera->master
  extrinsics, about 1 cm good), read by :func:`benchmarks.studies.calib_refine.load_hocap`.
* ``icl``: ``fuseflow convert icl-livingroom1 OUT --cameras 8 --every 26`` (virtual rig of 8
  frames of a static scene; reference = the data set's trajectory, about 1 cm good).
* ``pairs``: cameras 0 and 1 of each simulated ring and ICL rig, with their measured overlap.
* ``summary``: the markdown table of a results file.

Per run: cameras placed, rotation / translation error (fuseflow.eval.metrics.pose_errors over
the placed cameras: means over pairs, deg / mm, no alignment), the worst placed camera's error,
wrong edges accepted (an accepted pairwise pose more than 1 deg or 50 mm from the reference),
wrong cameras (placed, > 1 deg or 50 mm off) and of them those not flagged, and wall time. Rows
are appended as JSON lines to ``out``.

``backbone="raw"`` runs ``rgbd_backbone`` alone; ``colmap|rgbd|auto`` runs GMAC's ``calibrate``
with that backbone (there "wrong cams (unflagged)" counts wrong cameras not in
``suspect_cameras`` and "wrong edges" is not measured). ``matcher`` picks the image matcher of
the rgbd backbone (``RGBDConfig.matcher``; the learned ones need ``fuseflow[matchers]``).
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

import fuseflow
from benchmarks.studies.calib_refine import load_hocap
from fuseflow.calib.backbones.rgbd import MATCHERS, RGBDConfig, relative_error, rgbd_backbone
from fuseflow.eval.metrics import pose_errors
from fuseflow.types import Frame, Rig, invert_rigid

__all__ = ["MATCHERS", "WHAT", "WideOptions", "run_calib_wide", "evaluate", "evaluate_calibration", "depth_overlap",
           "sim_recording", "summary_lines"]  # fmt: skip

WRONG_DEG, WRONG_M = 1.0, 0.05
WHAT = ("sim", "hocap", "icl", "pairs", "summary")
"""The runs of :func:`run_calib_wide`."""

Log = Callable[[str], None]


@dataclass
class WideOptions:
    """One run's settings (module docstring); ``shared`` is the folder holding hocap-8rs and
    icl-livingroom1, ``data`` the folder for the simulated and converted recordings."""

    out: Path = Path("benchmarks/results/calib_wide.jsonl")
    data: Path = Path("/tmp/fuseflow-calib-wide")
    shared: Path = Path("../shared/data")
    cameras: tuple[int, ...] = (3, 4, 6, 8)
    scenes: tuple[str, ...] = ("room", "studio")
    seeds: tuple[int, ...] = (1, 2, 3)
    frames: int = 5
    only_frames: int | None = None
    dynamic: bool = False
    resolution: str = "640x480"
    every: tuple[int, ...] = (26,)
    backbone: str = "raw"
    matcher: str = "sift"


def _env() -> dict:
    return {
        "fuseflow": getattr(fuseflow, "__version__", "?"),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "cpu_threads": torch.get_num_threads(),
        "machine": platform.machine(),
        "device": "cpu",
    }


# ------------------------------------------------------------------ evaluation
def evaluate(result, T_ref: np.ndarray, ids: list[str]) -> dict:
    """Errors of a BackboneResult against reference camera-from-world extrinsics (N, 4, 4)."""
    reg = result.registered
    row: dict = {"placed": int(reg.sum()), "cameras": len(reg)}
    if reg.sum() >= 2:
        e = pose_errors(result.T_cam_world[reg], T_ref[reg])
        row["rot_deg"] = float(e.rotation_deg)
        row["trans_mm"] = float(e.translation_mm)
        per = list(e.per_camera.values())
        row["worst_cam_deg"] = float(max(p[0] for p in per))
        row["worst_cam_mm"] = float(max(p[1] for p in per))
        placed_ids = [ids[k] for k in np.flatnonzero(reg)]
        wrong = [c for c, p in zip(placed_ids, per) if p[0] > WRONG_DEG or p[1] > WRONG_M * 1000]
        flagged = [c for c in wrong if not result.info["cameras"][c]["cycle_checked"]]
        row["wrong_cameras"] = len(wrong)
        row["wrong_unflagged"] = len(wrong) - len(flagged)
    wrong_edges = accepted = 0
    for p in result.info["pairs"]:
        if p["edge"] is None:
            continue
        accepted += 1
        a, b = (ids.index(c) for c in p["cameras"])
        re, te = relative_error(np.array(p["edge"]["T_ji"]), T_ref[b] @ invert_rigid(T_ref[a]))
        wrong_edges += int(re > WRONG_DEG or te > WRONG_M)
    row["edges"] = accepted
    row.update(_image_route_counts(result.info["pairs"], T_ref, ids))
    row["wrong_edges"] = wrong_edges
    row["cycle_dropped"] = len(result.info["cycle_dropped"])
    row["routes"] = sorted({p["edge"]["route"] for p in result.info["pairs"] if p["edge"]})
    return row


def _image_route_counts(pairs: list[dict], T_ref: np.ndarray, ids: list[str]) -> dict:
    """What the image matcher (RGBDConfig.matcher) itself gave, before the floor route and the
    global solve: pairs with a RANSAC candidate of the image routes (sift3d / sift4) within 5 deg /
    200 mm of the reference (the feasibility note's "correct"), pairs where such a candidate
    passed the depth verification, and those of them within 1 deg / 50 mm; image matches summed."""
    right = verified = verified_right = matches = 0
    for p in pairs:
        a, b = (ids.index(c) for c in p["cameras"])
        T_ji = T_ref[b] @ invert_rigid(T_ref[a])
        errs = [
            (c["ok"], *relative_error(np.array(c["T_ji"]), T_ji))
            for c in p["candidates"]
            if c["route"] in ("sift3d", "sift4")
        ]
        right += any(r <= 5.0 and t <= 0.2 for _, r, t in errs)
        verified += any(ok for ok, _, _ in errs)
        verified_right += any(ok and r <= WRONG_DEG and t <= WRONG_M for ok, r, t in errs)
        matches += p.get("matches", 0)
    return {"pairs": len(pairs), "image_right": right, "image_verified": verified,
            "image_verified_right": verified_right, "image_matches": matches}  # fmt: skip


def evaluate_calibration(cal, T_ref: np.ndarray, ids: list[str]) -> dict:
    """Errors of a GMAC Calibration against reference camera-from-world extrinsics (N, 4, 4)."""
    placed = [c for c in ids if c in cal.T_cam_world]
    r = cal.report
    row: dict = {"placed": len(placed), "cameras": len(ids), "placed_by": dict(r.placed_by)}
    row["scale_check"] = r.scale_check
    if len(placed) >= 2:
        ref = {c: T_ref[ids.index(c)] for c in placed}
        e = pose_errors({c: cal.T_cam_world[c] for c in placed}, ref)
        row["rot_deg"] = float(e.rotation_deg)
        row["trans_mm"] = float(e.translation_mm)
        row["worst_cam_deg"] = float(max(p[0] for p in e.per_camera.values()))
        row["worst_cam_mm"] = float(max(p[1] for p in e.per_camera.values()))
        wrong = [c for c, p in e.per_camera.items() if p[0] > WRONG_DEG or p[1] > WRONG_M * 1000]
        row["wrong_cameras"] = len(wrong)
        unchecked = [w for w in r.warnings if "close no cycle" in w]  # auto's warning, named cameras
        row["wrong_unflagged"] = len(
            [c for c in wrong if c not in r.suspect_cameras and not any(repr(c) in w for w in unchecked)]
        )
    return row


def run_one(frames, rig, T_ref, meta: dict, opts: WideOptions, cfg: RGBDConfig, log: Log) -> dict:
    """One backbone (or ``calibrate``) run scored against ``T_ref``; its row appended to
    ``opts.out`` and logged (without ``env``). A failure is a row too."""
    t0 = time.perf_counter()
    try:
        if opts.backbone == "raw":
            row = evaluate(rgbd_backbone(frames, rig, cfg), T_ref, list(rig.ids))
        else:
            from fuseflow.calib import CalibConfig, calibrate

            cal = calibrate(frames, rig, CalibConfig(backbone=opts.backbone, matcher=cfg.matcher))
            row = evaluate_calibration(cal, T_ref, list(rig.ids))
    except Exception as exc:  # a failure is a row too
        row = {"placed": 0, "cameras": len(rig), "error": f"{type(exc).__name__}: {exc}"}
    row["time_s"] = time.perf_counter() - t0
    row["backbone"] = opts.backbone
    row["matcher"] = cfg.matcher
    row.update(meta)
    row["env"] = _env()
    with opts.out.open("a") as f:
        f.write(json.dumps(row) + "\n")
    log(json.dumps({k: v for k, v in row.items() if k != "env"}))
    return row


def _cli(*args: str) -> None:
    """``python -m fuseflow ARGS`` in a child process running this source tree."""
    env = dict(os.environ)
    src = str(Path(fuseflow.__file__).resolve().parents[1])
    env["PYTHONPATH"] = src + os.pathsep + env.get("PYTHONPATH", "")
    subprocess.run([sys.executable, "-m", "fuseflow", *args], check=True, env=env, stdout=subprocess.DEVNULL)


def sim_recording(data: Path, n: int, scene: str, seed: int, frames: int, res: str, dynamic: bool = False) -> Path:
    """The simulated recording of these settings under ``data``, made by ``fuseflow simulate``
    unless it is there already."""
    rec = data / f"{scene}{n}_s{seed}_f{frames}_{res}{'_dyn' if dynamic else ''}"
    if not (rec / "gt.json").exists():
        _cli("simulate", str(rec), "--cameras", str(n), "--scene", scene, "--seed", str(seed),
             "--num-frames", str(frames), "--resolution", res, *(["--dynamic"] if dynamic else []))  # fmt: skip
    return rec


def _bare(rec) -> tuple[np.ndarray, Rig]:
    """A recording's rig.json extrinsics (N, 4, 4) and its rig without them."""
    return np.stack([c.T_cam_world for c in rec.rig]), Rig(tuple(c.with_extrinsics(None) for c in rec.rig))


def _bench_sim(opts: WideOptions, log: Log) -> None:
    from fuseflow.io import open_recording

    for seed in opts.seeds:  # seed outermost: a cut-short run still covers every configuration
        for scene in opts.scenes:
            for n in opts.cameras:
                path = sim_recording(opts.data, n, scene, seed, opts.frames, opts.resolution, opts.dynamic)
                rec = open_recording(path)
                T_ref, bare = _bare(rec)
                all_frames = [rec[t] for t in range(len(rec))]
                for nf in sorted({1, len(all_frames)} if opts.only_frames is None else {opts.only_frames}):
                    meta = {"data": "sim", "scene": scene, "n": n, "seed": seed, "frames": nf, "res": opts.resolution,
                            "dynamic": opts.dynamic}  # fmt: skip
                    run_one(all_frames[:nf], bare, T_ref, meta, opts, RGBDConfig(matcher=opts.matcher), log)


def _bench_hocap(opts: WideOptions, log: Log) -> None:
    from fuseflow.geometry import depth_agreement

    frame, rig, T_ref = load_hocap(opts.shared / "hocap-8rs")
    meta = {"data": "hocap-8rs", "n": 8, "frames": 1}
    run_one([frame], rig, T_ref, meta, opts, RGBDConfig(matcher=opts.matcher), log)
    ref = depth_agreement(frame, rig, dict(zip(rig.ids, T_ref)))
    vals = [v for v in ref.values() if v is not None]
    log(json.dumps({"hocap_reference_depth_agreement_mean": float(np.mean(vals))}))


def _bench_icl(opts: WideOptions, log: Log) -> None:
    from fuseflow.io import open_recording

    src = opts.shared / "icl-livingroom1"
    n_frames = len(list((src / "depth").iterdir()))
    for every in opts.every:
        n = min(8, (n_frames - 1) // every + 1)  # 8 cameras 40 apart need 281 frames; ICL has fewer
        path = opts.data / f"icl{n}_every{every}"
        if not (path / "rig.json").exists():
            _cli("convert", str(src), str(path), "--cameras", str(n), "--every", str(every))
        rec = open_recording(path)
        T_ref, bare = _bare(rec)
        meta = {"data": "icl-livingroom1", "n": n, "every": every, "frames": 1}
        run_one([rec[0]], bare, T_ref, meta, opts, RGBDConfig(matcher=opts.matcher), log)


def depth_overlap(frame: Frame, rig: Rig, T: np.ndarray, a: int, b: int) -> float:
    """Share of camera a's valid depth that camera b sees at the same depth (5 %) under the
    true extrinsics T (N, 4, 4), averaged over both directions."""
    shares = []
    for i, j in ((a, b), (b, a)):
        K, Kj = rig.cameras[i].K, rig.cameras[j].K
        z = frame.depth[i].numpy()
        v, u = np.nonzero(z > 0)
        zz = z[v, u].astype(np.float64)
        P = np.stack([(u - K[0, 2]) / K[0, 0] * zz, (v - K[1, 2]) / K[1, 1] * zz, zz], 1)
        M = T[j] @ invert_rigid(T[i])
        X = P @ M[:3, :3].T + M[:3, 3]
        dj = frame.depth[j].numpy()
        h, w = dj.shape
        with np.errstate(divide="ignore", invalid="ignore"):
            uu = np.rint(Kj[0, 0] * X[:, 0] / X[:, 2] + Kj[0, 2])
            vv = np.rint(Kj[1, 1] * X[:, 1] / X[:, 2] + Kj[1, 2])
        ok = (X[:, 2] > 0) & (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h)
        d = dj[vv[ok].astype(int), uu[ok].astype(int)]
        shares.append(float(np.sum((d > 0) & (np.abs(d - X[ok, 2]) < 0.05 * X[ok, 2]))) / max(len(zz), 1))
    return float(np.mean(shares))


def _bench_pairs(opts: WideOptions, log: Log) -> None:
    """Two-camera rigs: cameras 0 and 1 of each simulated ring and ICL rig, with their measured
    overlap (a 2-camera rig with >= 30 % overlap must be placed)."""
    from fuseflow.io import open_recording

    paths = [sim_recording(opts.data, n, sc, seed, opts.frames, opts.resolution)
             for seed in opts.seeds for sc in opts.scenes for n in opts.cameras]  # fmt: skip
    paths += [opts.data / f"icl8_every{e}" for e in opts.every if (opts.data / f"icl8_every{e}" / "rig.json").exists()]
    for path in paths:
        rec = open_recording(path)
        T_ref = np.stack([c.T_cam_world for c in rec.rig])
        frame = rec[0].subset([0, 1])
        rig = Rig(tuple(c.with_extrinsics(None) for c in rec.rig.subset([0, 1])))
        meta = {"data": "pair", "scene": path.name, "n": 2, "frames": 1,
                "overlap": depth_overlap(rec[0], rec.rig, T_ref, 0, 1)}  # fmt: skip
        run_one([frame], rig, T_ref[:2], meta, opts, RGBDConfig(), log)


def summary_lines(out: Path) -> list[str]:
    """The markdown table of the results file ``out``: one line per (data, scene, N, frames,
    every, resolution) group."""
    rows = [json.loads(line) for line in out.read_text().splitlines() if line.strip()]
    groups: dict = {}
    for r in rows:
        data = r["data"] if r.get("backbone", "raw") == "raw" else f"{r['data']} [{r['backbone']}]"
        if r.get("matcher", "sift") != "sift":
            data += f" ({r['matcher']})"
        scene = r.get("scene", "") + (" dynamic" if r.get("dynamic") else "")
        key = (data, scene, r["n"], r.get("frames", 1), r.get("every", ""), r.get("res", ""))
        groups.setdefault(key, []).append(r)
    lines = ["| data | scene | N | frames | runs | all placed | placed (mean) | rot deg (mean / max) "
          "| trans mm (mean / max) | worst camera deg / mm | wrong edges | wrong cams (unflagged) | time s (median) "
          "| image pairs: right / verified (right) / all |"]  # fmt: skip
    lines.append("|" + "---|" * 14)
    for key in sorted(groups, key=str):
        g = groups[key]
        data, scene, n, nf, every, res = key
        full = sum(r["placed"] == r["cameras"] for r in g)
        placed = np.mean([r["placed"] for r in g])
        rot = [r["rot_deg"] for r in g if "rot_deg" in r]
        tr = [r["trans_mm"] for r in g if "trans_mm" in r]
        wc = [r["worst_cam_deg"] for r in g if "worst_cam_deg" in r]
        wm = [r["worst_cam_mm"] for r in g if "worst_cam_mm" in r]
        we = sum(r.get("wrong_edges", 0) for r in g)
        wcam = sum(r.get("wrong_cameras", 0) for r in g)
        wun = sum(r.get("wrong_unflagged", 0) for r in g)
        t = np.median([r["time_s"] for r in g])
        img = "-"
        if all("image_right" in r for r in g):
            s_ = {k: sum(r[k] for r in g) for k in ("image_right", "image_verified", "image_verified_right", "pairs")}
            img = f"{s_['image_right']} / {s_['image_verified']} ({s_['image_verified_right']}) / {s_['pairs']}"

        def mm(v, f):
            return f"{f(np.mean(v))} / {f(np.max(v))}" if v else "-"

        label = scene if scene else (f"every {every}" if every else "")
        label += f" {res}" if res and res != "640x480" else ""
        lines.append(f"| {data} | {label} | {n} | {nf} | {len(g)} | {full}/{len(g)} | {placed:.1f} | "
              f"{mm(rot, lambda x: f'{x:.3f}')} | {mm(tr, lambda x: f'{x:.1f}')} | "
              f"{(f'{max(wc):.2f} / {max(wm):.0f}') if wc else '-'} | {we} | {wcam} ({wun}) | {t:.1f} | {img} |")  # fmt: skip
    return lines


def run_calib_wide(what: str, opts: WideOptions, log: Log) -> None:
    """Run ``what`` (one of :data:`WHAT`) with ``opts``: rows appended to ``opts.out`` and logged,
    or for ``summary`` the table of ``opts.out`` logged line by line."""
    from fuseflow.errors import ValidationError

    if what not in WHAT:
        raise ValidationError(f"unknown run {what!r}: one of {', '.join(WHAT)}")
    if what == "summary":
        for line in summary_lines(opts.out):
            log(line)
        return
    opts.out.parent.mkdir(parents=True, exist_ok=True)
    opts.data.mkdir(parents=True, exist_ok=True)
    {"sim": _bench_sim, "hocap": _bench_hocap, "icl": _bench_icl, "pairs": _bench_pairs}[what](opts, log)
