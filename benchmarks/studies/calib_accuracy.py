"""GMAC accuracy and timing benchmark (docs/design.md section 4 metrics): the library code of
``python -m benchmarks.calib_accuracy``, whose docstring (its ``--help``) defines the rows, the
data sets and the robustness count.

What only this module decides: without the simulator installed, ``sim4`` / ``sim8`` are an
analytic textured room with Kinect-model depth noise built here (the output says which);
``icl8`` is read from a folder the caller names.

:func:`run_calib_accuracy` runs it and hands each report line to a ``log`` callback (Markdown
tables per data set); ``python -m benchmarks.calib_accuracy`` prints them.
"""

from __future__ import annotations

import platform
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

import fuseflow
from fuseflow.calib import CalibConfig, calibrate, metric_scale
from fuseflow.calib.api import check_inputs
from fuseflow.calib.correspondences import prepare_cameras
from fuseflow.errors import ValidationError
from fuseflow.eval.metrics import pose_errors
from fuseflow.geometry.noise import SENSOR_NOISE, sigma

__all__ = [
    "DATA_SETS",
    "VARIANTS",
    "fmt",
    "header_line",
    "icl_frame",
    "open3d_multiway",
    "oracle_scale",
    "perturbed_truth",
    "run_calib_accuracy",
    "run_seed",
    "scaled",
    "sim_frame",
]

DATA_SETS = ("sim4", "sim8", "icl8")
"""Data set names: sim<N> (a simulated N-camera ring, N >= 2) and icl8."""

VARIANTS = {
    "GMAC z-only (paper eq. 12)": CalibConfig.preset("paper"),
    "GMAC full-3D": CalibConfig.preset("full3d"),
    "GMAC point-to-plane (default)": CalibConfig(),
    "GMAC + refinement": CalibConfig.preset("refined"),
    "w/o RC": CalibConfig.preset("wo_rc"),
    "w/o CC": CalibConfig.preset("wo_cc"),
    "w/o feature weight": CalibConfig.preset("wo_feature"),
    "GMAC robust (Huber)": CalibConfig.preset("robust"),
}


# ------------------------------------------------------------------ data
def _look_at(eye, target, up=(0.0, -1.0, 0.0)):
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(-up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z])
    T[:3, 3] = -T[:3, :3] @ eye
    return T


def _room_frame(n: int, seed: int, size=(640, 480)):
    """Analytic textured room (box + 4 boxes), Kinect-model depth noise; (frame, rig, T_true)."""
    rng = np.random.default_rng(seed)
    room = (np.array([-3.0, -2.2, -3.0]), np.array([3.0, 1.0, 3.0]))
    objs = [
        (np.array([-0.6, 0.2, -0.5]), np.array([0.1, 1.0, 0.3])),
        (np.array([0.5, -0.3, 0.2]), np.array([1.1, 1.0, 0.9])),
        (np.array([-1.2, 0.5, 0.8]), np.array([-0.7, 1.0, 1.4])),
        (np.array([0.9, 0.1, -1.3]), np.array([1.6, 1.0, -0.7])),
    ]
    tex_rng = np.random.default_rng(1234)
    dirs = tex_rng.normal(size=(48, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    freqs = tex_rng.uniform(4, 40, 48)[:, None] * dirs
    phase = tex_rng.uniform(0, 2 * np.pi, 48)
    amp = tex_rng.uniform(0.5, 1.0, (48, 3))
    W, H = size
    f = 0.82 * W
    K = np.array([[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1]])
    Ts, depths, colors = [], [], []
    for k in range(n):
        a = 2 * np.pi * k / n + rng.uniform(-0.15, 0.15)
        r = rng.uniform(1.7, 2.3)
        eye = np.array([r * np.cos(a), rng.uniform(-0.9, -0.2), r * np.sin(a)])
        T = _look_at(eye, [rng.uniform(-0.4, 0.4), rng.uniform(0.0, 0.6), rng.uniform(-0.4, 0.4)])
        v, u = np.mgrid[0:H, 0:W].astype(np.float64)
        rays = np.stack([(u - K[0, 2]) / f, (v - K[1, 2]) / f, np.ones_like(u)], -1).reshape(-1, 3)
        R, t = T[:3, :3], T[:3, 3]
        o = -R.T @ t
        d = rays @ R
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            lo, hi = (room[0] - o) * inv, (room[1] - o) * inv
            depth = np.maximum(lo, hi).min(1)
            for a0, b0 in objs:
                lo, hi = (a0 - o) * inv, (b0 - o) * inv
                tn, tf = np.minimum(lo, hi).max(1), np.maximum(lo, hi).min(1)
                hit = (tn <= tf) & (tn > 0) & (tn < depth)
                depth = np.where(hit, tn, depth)
        P = o + d * depth[:, None]
        s = np.sin(P @ freqs.T + phase)
        col = 0.5 + 0.5 * np.tanh(2.0 * (s @ amp) / np.sqrt(48))
        # Kinect v1 axial noise (fuseflow.geometry.noise), 1 mm steps
        z = depth.reshape(H, W)
        z = z + rng.normal(size=z.shape) * sigma(z, *SENSOR_NOISE["kinect_v1"])
        z = np.round(z * 1000) / 1000
        z[rng.random(z.shape) < 0.02] = 0  # dropouts
        Ts.append(T)
        depths.append(z.astype(np.float32))
        colors.append((np.clip(col, 0, 1) * 255).astype(np.uint8).reshape(H, W, 3))
    cams = tuple(fuseflow.Camera(f"c{k}", W, H, K, depth_range=(0.3, 8.0)) for k in range(n))
    frame = fuseflow.Frame(
        0, tuple(c.id for c in cams), torch.from_numpy(np.stack(colors)), torch.from_numpy(np.stack(depths)),
        torch.ones(n, dtype=torch.bool),
    )  # fmt: skip
    return frame, fuseflow.Rig(cams), {f"c{k}": Ts[k] for k in range(n)}


def sim_frame(n: int, seed: int, scene: str = "studio", dynamic: bool = False):
    """(frame, bare rig, reference {id: T}, data label): frame 0 of a simulated ring, Kinect noise."""
    try:
        from fuseflow.synth import SimConfig, Simulator

        sim = Simulator(SimConfig(cameras=n, frames=1, scene=scene, dynamic=dynamic, noise="kinect", seed=seed))
        rig = sim.rig
        ref = {c.id: c.T_cam_world for c in rig}
        bare = fuseflow.Rig(tuple(c.with_extrinsics(None) for c in rig))
        label = f"fuseflow.synth {scene} ring{', dynamic' if dynamic else ''}, kinect noise"
        return sim.render(0).frame, bare, ref, label
    except ImportError:
        frame, rig, ref = _room_frame(n, seed)
        return frame, rig, ref, "analytic room (benchmark-local), kinect noise"


def icl_frame(seed: int, tmp: Path, icl: Path):
    """(frame, bare rig, reference {id: T}, data label): the ICL-NUIM living room virtual rig of 8
    frames 26 apart starting at 3 x seed (``icl``: the icl-livingroom1 folder; ``tmp``: scratch)."""
    from fuseflow.io.datasets import open_recording

    seq = open_recording(icl)
    idx = [3 * seed + 26 * k for k in range(8)]
    out = tmp / f"icl-{seed}"
    rig = fuseflow.make_virtual_rig(seq, idx, out)
    rec = fuseflow.open_recording(out)
    ref = {c.id: c.T_cam_world for c in rig}
    return rec[0], fuseflow.Rig(tuple(c.with_extrinsics(None) for c in rig)), ref, f"ICL living room frames {idx}"


# ------------------------------------------------------------------ peer
def open3d_multiway(frame, rig):
    """Open3D RGB-D odometry between consecutive cameras (identity init) and for all pairs as loop
    closures, then pose-graph optimisation: the classical target-free peer (no backbone)."""
    import open3d as o3d

    n = frame.num_views
    W, H = frame.resolution
    rgbd = []
    for k in range(n):
        K = rig[k].K
        intr = o3d.camera.PinholeCameraIntrinsic(W, H, K[0, 0], K[1, 1], K[0, 2], K[1, 2])
        col = o3d.geometry.Image(np.ascontiguousarray(frame.color[k].numpy()))
        dep = o3d.geometry.Image(np.ascontiguousarray(frame.depth[k].numpy()))
        rgbd.append(o3d.geometry.RGBDImage.create_from_color_and_depth(col, dep, 1.0, 8.0, False))
    opt = o3d.pipelines.odometry.OdometryOption()
    reg = o3d.pipelines.registration
    graph = reg.PoseGraph()
    graph.nodes.append(reg.PoseGraphNode(np.eye(4)))
    odo = np.eye(4)
    for i in range(n):
        for j in range(i + 1, n):
            ok, T, info = o3d.pipelines.odometry.compute_rgbd_odometry(
                rgbd[i], rgbd[j], intr, np.eye(4), o3d.pipelines.odometry.RGBDOdometryJacobianFromHybridTerm(), opt
            )
            if j == i + 1:
                if ok:
                    odo = T @ odo
                graph.nodes.append(reg.PoseGraphNode(np.linalg.inv(odo)))
                graph.edges.append(reg.PoseGraphEdge(i, j, T if ok else np.eye(4), info, uncertain=False))
            elif ok:
                graph.edges.append(reg.PoseGraphEdge(i, j, T, info, uncertain=True))
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        reg.global_optimization(
            graph,
            reg.GlobalOptimizationLevenbergMarquardt(),
            reg.GlobalOptimizationConvergenceCriteria(),
            reg.GlobalOptimizationOption(max_correspondence_distance=0.05, edge_prune_threshold=0.25, reference_node=0),
        )
    return {rig[k].id: np.linalg.inv(np.asarray(graph.nodes[k].pose)) for k in range(n)}


# ------------------------------------------------------------------ run
def scaled(bb, ids, s):
    """{id: T_cam_world} of the backbone's registered cameras with translations multiplied by s."""
    T = {}
    for k in np.flatnonzero(bb.registered):
        M = bb.T_cam_world[k].copy()
        M[:3, 3] *= s
        T[ids[k]] = M
    return T


def oracle_scale(bb, ids, ref):
    """argmin_s sum |s t_ij - t_ij_ref|^2 over pairs: the best any scale method can do."""
    reg = [k for k in np.flatnonzero(bb.registered) if ids[k] in ref]
    num = den = 0.0
    for a in range(len(reg)):
        for b in range(a + 1, len(reg)):
            i, j = reg[a], reg[b]
            Ti, Tj = bb.T_cam_world[i], bb.T_cam_world[j]
            R = Ti[:3, :3] @ Tj[:3, :3].T
            t0 = Ti[:3, 3] - R @ Tj[:3, 3]
            Ri, Rj = ref[ids[i]], ref[ids[j]]
            tr = Ri[:3, 3] - (Ri[:3, :3] @ Rj[:3, :3].T) @ Rj[:3, 3]
            num += t0 @ tr
            den += t0 @ t0
    return num / den


def perturbed_truth(ref, ids, seed, rot_deg, center_m):
    """A stand-in backbone: the reference poses with a random unknown scale, each camera rotated
    by ~rot_deg (random axis) and its centre moved by ~center_m (metres, before scaling). It
    isolates GMAC's own error from the backbone's (the colmap backbone fails on wide rigs)."""
    from scipy.spatial.transform import Rotation

    from fuseflow.calib import BackboneResult

    rng = np.random.default_rng(1000 + seed)
    scale = float(np.exp(rng.uniform(np.log(0.1), np.log(10))))
    T0 = []
    for cid in ids:
        T = np.array(ref[cid], dtype=np.float64)
        C = -T[:3, :3].T @ T[:3, 3] + rng.normal(size=3) * center_m / np.sqrt(3)
        R = Rotation.from_rotvec(np.radians(rot_deg) * rng.normal(size=3) / np.sqrt(3)).as_matrix() @ T[:3, :3]
        M = np.eye(4)
        M[:3, :3] = R
        M[:3, 3] = -R @ C / scale
        T0.append(M)
    return BackboneResult(np.stack(T0), np.ones(len(ids), bool), name="perturbed-truth", info={"scale": scale})


def shifted_step(edge: tuple[int, int], offset: float):
    """GMAC's fixed-point step (``calib.scale_stage.rc_step``) with ``edge``'s points in camera j
    shifted by ``offset`` metres along the baseline (Y' = Y + offset t / |t|): the edge then
    implies a baseline that much too long, as wrong matches would (the robustness injection)."""
    from fuseflow.calib.scale import Correspondences, closed_form_scale
    from fuseflow.calib.scale_stage import rc_step

    def step(geoms, cams_, s, config):
        _, corrs = rc_step(geoms, cams_, s, config)
        out = [
            c
            if (min(c.i, c.j), max(c.i, c.j)) != edge
            else Correspondences(c.i, c.j, c.RX, c.Y + offset * c.t / np.linalg.norm(c.t), c.t, c.w, c.is_match, c.n)
            for c in corrs
        ]
        return closed_form_scale(out, config.closed_form), out

    return step


def run_seed(frame, rig, ref, seed, rows, robust, backbone="colmap", noise=(0.3, 0.01), peer=True):
    """Every row of one seed: appends a result dict per row name to ``rows`` and counts the
    injected wrong-match edge in ``robust``; returns the backbone's seconds."""
    from fuseflow.calib import get_backbone

    ids = frame.camera_ids
    t = time.perf_counter()
    if backbone == "colmap":
        bb = get_backbone("colmap")(frame, rig, CalibConfig(seed=seed))
    else:
        bb = perturbed_truth(ref, ids, seed, *noise)
    t_bb = time.perf_counter() - t

    def add(name, T, secs, extra=None):
        if len(T) < 2:
            rows.setdefault(name, []).append({"failed": True, "seconds": secs})
            return
        e = pose_errors(T, {k: v for k, v in ref.items()})
        rows.setdefault(name, []).append(
            {"rot": e.rotation_deg, "trans": e.translation_mm, "seconds": secs, "placed": len(T), **(extra or {})}
        )

    cal0 = None
    for name, cfg in VARIANTS.items():
        t = time.perf_counter()
        try:
            cal = calibrate(frame, rig, replace(cfg, seed=seed), backbone_result=bb)
        except fuseflow.FuseFlowError as exc:
            rows.setdefault(name, []).append({"failed": True, "error": str(exc)})
            continue
        extra = {"pruned": len(cal.report.pruned_edges), "suspect": len(cal.report.suspect_cameras)}
        add(name, cal.T_cam_world, t_bb + time.perf_counter() - t, extra)
        if cal0 is None or name.startswith("GMAC point"):
            cal0 = cal
    if cal0 is not None and cal0.report.scale_naive_median_depth_ratio:
        add("backbone + naive median depth ratio", scaled(bb, ids, cal0.report.scale_naive_median_depth_ratio), t_bb)
    add("backbone + oracle scale (lower bound)", scaled(bb, ids, oracle_scale(bb, ids, ref)), t_bb)
    t = time.perf_counter()
    try:
        if peer:
            add("Open3D RGB-D odometry + multiway", open3d_multiway(frame, rig), time.perf_counter() - t)
    except Exception as exc:  # noqa: BLE001 - a failed peer is a result, not a crash
        rows.setdefault("Open3D RGB-D odometry + multiway", []).append({"failed": True, "error": str(exc)})
    # robustness: inject a wrong-match edge between the first two registered cameras
    depth, K, drange = check_inputs(frame, rig)
    cams = prepare_cameras(depth, K, drange, CalibConfig().samples_per_camera, seed)
    reg = np.flatnonzero(bb.registered)
    if len(reg) >= 3:
        e = (int(reg[0]), int(reg[1]))
        try:
            sr = metric_scale(bb, cams, CalibConfig(), step=shifted_step(e, 0.3))
            robust["injected"] += 1
            robust["pruned"] += int(e in sr.pruned)
        except fuseflow.FuseFlowError:
            pass
    return t_bb


def fmt(vals):
    """mean +- std of a list (3 and 2 significant digits), or "-" when empty."""
    v = np.array(vals, dtype=float)
    return f"{v.mean():.3g} +- {v.std():.2g}" if len(v) else "-"


def header_line(seeds: int) -> str:
    """The report's first line: machine, library versions, device, seeds."""
    import open3d
    import pycolmap

    return (
        f"# GMAC benchmark: {platform.processor() or platform.machine()}, torch {torch.__version__}, "
        f"pycolmap {pycolmap.__version__}, open3d {open3d.__version__}, numpy {np.__version__}, device cpu, "
        f"seeds {seeds}"
    )


def _check_data(data: Sequence[str]) -> None:
    for d in data:
        if not (d == "icl8" or (d.startswith("sim") and d[3:].isdigit())):
            raise ValidationError(f"unknown data {d!r}")


def _frame_for(data: str, seed: int, tmp: Path, icl: Path | None):
    if data.startswith("sim"):
        return sim_frame(int(data[3:]), seed)
    if icl is None:
        raise ValidationError("icl8 needs the ICL-NUIM living room folder (icl)")
    return icl_frame(seed, tmp, icl)


def _backbone_name(backbone: str, noise: tuple[float, float]) -> str:
    if backbone == "colmap":
        return "colmap (pycolmap SIFT)"
    return f"perturbed ground truth ({noise[0]} deg, {noise[1] * 1000:g} mm per camera)"


def dataset_report(data: str, label: str, frame: Any, rows: dict[str, list], robust: dict, bname: str) -> list[str]:
    """The report lines of one data set: heading, Markdown table, robustness and failure counts."""
    W, H = frame.resolution
    lines = [f"\n## {data}: {label}; N = {frame.num_views}, {W}x{H}, backbone {bname}\n"]
    lines.append(
        "| method | rotation error (deg) | translation error (mm) | time per calibration (s) "
        f"| cameras placed (of {frame.num_views}) | failed seeds |"
    )
    lines.append("|---|---|---|---|---|---|")
    for name, rs in rows.items():
        ok = [r for r in rs if not r.get("failed")]
        lines.append(
            f"| {name} | {fmt([r['rot'] for r in ok])} | {fmt([r['trans'] for r in ok])} | "
            f"{fmt([r['seconds'] for r in ok])} | {fmt([r['placed'] for r in ok])} | {len(rs) - len(ok)}/{len(rs)} |"
        )
    lines.append(f"\nInjected wrong-match edge pruned by CC in {robust['pruned']}/{robust['injected']} seeds.")
    default = [r for r in rows.get("GMAC point-to-plane (default)", []) if not r.get("failed")]
    bad = [r for r in default if r["rot"] > 1.0]
    lines.append(
        f"GMAC default: {len(bad)}/{len(default)} seeds with a rotation error above 1 deg (backbone "
        f"failures); the depth-agreement check named suspect cameras in {sum(r['suspect'] > 0 for r in bad)} "
        f"of them and in {sum(r['suspect'] > 0 for r in default if r['rot'] <= 1.0)} of the others."
    )
    return lines


def run_calib_accuracy(
    seeds: int = 10,
    data: Sequence[str] = DATA_SETS,
    backbone: str = "colmap",
    noise: tuple[float, float] = (0.3, 0.01),
    peer: bool = True,
    icl: Path | None = None,
    save: Callable[[dict[str, Any]], Any] | None = None,
    log: Callable[[str], None] | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Run every row on every data set and seed; return {data: {"label", "rows", "robustness"}}.

    Args:
        seeds: seeds per data set (one calibration per row and seed).
        data: names of :data:`DATA_SETS` (sim<N> for any N >= 2).
        backbone: "colmap" (the product's default) or "perturbed" (ground truth + ``noise``:
            rotation deg, centre metres per camera; isolates GMAC from the backbone).
        peer: also run the Open3D multiway registration peer.
        icl: the ICL-NUIM living room 1 folder (needed by icl8).
        save: called with the result so far after every data set (a long run leaves its finished parts).
        log: called with each report line (header, then per data set a Markdown table).
        progress: called with "<data> seed <k> done" after each seed.
    """
    log, progress = log or (lambda s: None), progress or (lambda s: None)
    data = list(data)
    _check_data(data)
    if backbone not in ("colmap", "perturbed"):
        raise ValidationError(f"backbone must be colmap or perturbed, got {backbone!r}")
    log(header_line(seeds))
    everything: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for d in data:
            rows: dict[str, list] = {}
            robust = {"injected": 0, "pruned": 0}
            label, frame = "", None
            for seed in range(seeds):
                frame, rig, ref, label = _frame_for(d, seed, Path(tmp), icl)
                run_seed(frame, rig, ref, seed, rows, robust, backbone, noise, peer)
                progress(f"  {d} seed {seed} done")
            for line in dataset_report(d, label, frame, rows, robust, _backbone_name(backbone, noise)):
                log(line)
            everything[d] = {"label": label, "rows": rows, "robustness": robust}
            if save is not None:  # after every data set, so a long run leaves its finished parts
                save(everything)
    return everything
