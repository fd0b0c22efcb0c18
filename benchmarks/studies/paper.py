"""The analogues of the paper's tables (section IV), regenerated on this machine: ``python -m benchmarks.paper``.

Tables (keys of :data:`TABLES`):

* ``gmac`` -- Table I/III: GMAC with the backbones available here (pycolmap SIFT, and a
  "perturbed ground truth" stand-in that isolates GMAC from the backbone) and its ablations,
  on a simulated 8-camera room and the ICL-NUIM living-room virtual rig. Rotation / translation
  error (docs/design.md 4) per calibration, mean +- std over seeds.
* ``static`` -- Table IV/VI: static scenes, N = 2, 4, 8: FUSE against naive, voxel, SOR and TSDF
  fusion. PFR, PNCC, OR; CD and F-score (1 cm) against the simulator's surface samples.
* ``dynamic`` -- Table V: the simulated studio with moving objects: the same metrics plus FPS and
  peak memory.
* ``ablation`` -- Table VII: FUSE and its ablations on the dynamic studio, N = 4.
* ``extrinsics`` -- Table VIII: FUSE (N = 4) with extrinsics from ground truth, GMAC, and the raw
  backbone scaled by the naive median depth ratio.
* ``fps`` -- Fig. 5: fusion FPS against N (PNG, drawn with OpenCV/numpy: matplotlib is not a
  dependency of this project).

Every cell (one table row on one data set and seed) is cached as JSON under the output folder
and skipped when present, so an interrupted run resumes. Numbers in the Markdown are mean +- std
over frames (pooled over seeds); calibration rows are over seeds (one calibration per seed).
"""

from __future__ import annotations

import json
import math
import os
import platform
import tempfile
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from fuseflow.errors import FuseFlowError, ValidationError

__all__ = ["PaperConfig", "QUICK", "FULL", "TABLES", "plan", "run", "render_markdown", "ICL_DIR", "icl_path"]

ICL_DIR = "icl-livingroom1"
"""Folder of the ICL-NUIM living room kt1 sequence inside the data folder (the shared data, never
copied into the repository; ``python -m benchmarks.paper --data-dir`` names the data folder)."""


def icl_path(data_dir: str | Path) -> Path:
    """The ICL-NUIM living room kt1 sequence inside ``data_dir`` (the shared data folder)."""
    return Path(data_dir) / ICL_DIR


TABLES = ("gmac", "static", "dynamic", "ablation", "extrinsics", "fps")

#: Fusion methods of Tables IV-VI: FUSE (default preset) and the baselines of fuseflow.eval.baselines.
METHODS = ("FUSE", "naive", "voxel 1 cm", "SOR", "TSDF 1 cm")
#: Table VII rows: FUSE presets (fuseflow.fuse.PRESETS keys).
ABLATION_ROWS = ("default", "paper", "w/o CVGC", "w/o MCM", "w/o ASH", "w/o RPS")
#: Table I/III rows (CalibConfig presets), besides the backbone with the naive scale.
GMAC_ROWS = {
    "GMAC (default)": "default",
    "GMAC (paper preset)": "paper",
    "w/o RC": "wo_rc",
    "w/o CC": "wo_cc",
    "w/o feature weight": "wo_feature",
}
ORIGINAL = "backbone + naive scale (Original)"
#: Table I/III row of the product's default calibration (``PaperConfig.default_calib_row``).
DEFAULT_ROW = "default: auto backbone + joint refinement"
#: Noise of the perturbed-ground-truth backbone stand-in: rotation (deg) and centre (mm) per camera.
PERTURB = (0.3, 10.0)


@dataclass(frozen=True)
class PaperConfig:
    """Sizes of one run. ``QUICK`` (CI) and ``FULL`` (docs/results.md) are the two used."""

    name: str
    resolution: tuple[int, int]
    """Simulated camera resolution (width, height)."""
    icl_stride: int
    """ICL frames (640x480) are subsampled by this stride (K scaled accordingly)."""
    cameras: tuple[int, ...]
    """N of Tables IV-VI."""
    fps_cameras: tuple[int, ...]
    """N of Fig. 5."""
    frames: int
    """Frames per simulated recording (per seed)."""
    seeds: int
    """Seeds (simulated scenes / ICL rig placements)."""
    calib_seeds: int
    """Seeds of Table I/III (one calibration each)."""
    calib_cameras: int = 8
    """N of Table I/III."""
    pipeline_cameras: int = 4
    """N of Tables VII and VIII."""
    surface_density: float = 10000.0
    """GT surface samples per m^2 (simulator)."""
    backbones: tuple[str, ...] = ("colmap", "perturbed")
    calib_resolution: tuple[int, int] | None = None
    """Resolution of the calibration cells (Tables I/III and VIII); None = ``resolution``. COLMAP
    needs full-size images: at 320x240 its mapper built no model of the 8-camera studio ring."""
    calib_icl_stride: int | None = None
    """ICL stride of the calibration cells; None = ``icl_stride``."""
    default_calib_row: bool = False
    """Tables I/III and VIII also run the product's default calibration (``CalibConfig()``: the
    ``auto`` backbone and joint refinement, beyond the paper): Table I/III row ``DEFAULT_ROW``,
    Table VIII row "default (auto) + GMAC"."""

    def for_calibration(self) -> PaperConfig:
        """This config with the calibration cells' resolution and ICL stride."""
        return replace(
            self,
            resolution=self.calib_resolution or self.resolution,
            icl_stride=self.calib_icl_stride or self.icl_stride,
        )


QUICK = PaperConfig(
    "quick", (96, 72), 4, (2, 4), (1, 2, 4), frames=2, seeds=1, calib_seeds=1, calib_cameras=4,
    surface_density=2500.0, backbones=("perturbed",),
)  # fmt: skip
FULL = PaperConfig(
    "full", (320, 240), 2, (2, 4, 8), (1, 2, 4, 6, 8), frames=3, seeds=2, calib_seeds=3,
    calib_resolution=(640, 480), calib_icl_stride=1, default_calib_row=True,
)  # fmt: skip


# ------------------------------------------------------------------------------------------
# data
# ------------------------------------------------------------------------------------------


@dataclass
class Sample:
    """One frame to fuse: the frame, the rig with reference extrinsics, GT surface or None."""

    frame: Any
    rig: Any
    gt: Any
    """fuseflow.eval.reference.SurfaceReference, or None (no ground truth)."""
    label: str


def _subsample(frame, rig, stride: int):
    """Frame and rig at 1/stride resolution: pixel (stride*u, stride*v) becomes (u, v), K / stride."""
    import torch

    import fuseflow

    if stride == 1:
        return frame, rig
    cams = []
    for c in rig.cameras:
        K = np.array(c.K, dtype=np.float64)
        K[:2] /= stride
        cams.append(replace(c, width=len(range(0, c.width, stride)), height=len(range(0, c.height, stride)), K=K))
    f = fuseflow.Frame(
        frame.index,
        frame.camera_ids,
        frame.color[:, ::stride, ::stride].contiguous(),
        frame.depth[:, ::stride, ::stride].contiguous(),
        frame.present.clone() if isinstance(frame.present, torch.Tensor) else frame.present,
        timestamp=frame.timestamp,
    )
    return f, fuseflow.Rig(tuple(cams))


def _observable_surface(sim, sf):
    """The seen GT surface of frame sf (fuseflow.eval.reference.simulated_reference)."""
    from fuseflow.eval.reference import simulated_reference

    return simulated_reference(
        sim, sf.frame.index, (sf.surface_points.numpy(), sf.surface_normals.numpy()), sf.depth_gt.numpy()
    )


class _SimCache:
    """Simulators and rendered frames, reused across the cells of one data set."""

    def __init__(self) -> None:
        self._key = None
        self._sim = None
        self._frames: dict[int, Sample] = {}

    def sample(self, scene: str, dynamic: bool, n: int, seed: int, t: int, pc: PaperConfig) -> Sample:
        from fuseflow.synth import SimConfig, Simulator

        key = (scene, dynamic, n, seed, pc.resolution, pc.frames, pc.surface_density)
        if key != self._key:
            cfg = SimConfig(
                cameras=n, frames=pc.frames, scene=scene, dynamic=dynamic, resolution=pc.resolution,
                noise="kinect", seed=seed, surface_density=pc.surface_density,
            )  # fmt: skip
            self._key, self._sim, self._frames = key, Simulator(cfg), {}
        if t not in self._frames:
            sf = self._sim.render(t)
            self._frames[t] = Sample(sf.frame, self._sim.rig, _observable_surface(self._sim, sf), "sim")
        return self._frames[t]


_SIMS = _SimCache()


def icl_indices(n: int, seed: int, length: int = 211) -> list[int]:
    """Frames of the ICL trajectory used as the N cameras of virtual rig ``seed``: 26 apart (the
    spacing of benchmarks/calib_accuracy.py), starting at 11 * seed wrapped so that the last
    frame stays inside a sequence of ``length`` frames (kt1 has 211)."""
    span = 26 * (n - 1)
    if span >= length:
        raise ValidationError(f"an ICL virtual rig of {n} cameras 26 frames apart needs > {span} frames, got {length}")
    start = (11 * seed) % (length - span)
    return [start + 26 * k for k in range(n)]


def icl_sample(n: int, seed: int, pc: PaperConfig, icl_dir: Path | None) -> Sample:
    """The ICL virtual rig of N cameras (one static frame), subsampled by ``pc.icl_stride``.

    ``icl_dir``: the ICL-NUIM living room kt1 folder (:func:`icl_path`); None raises
    ValidationError (the ICL cells need the data folder)."""
    from fuseflow.io import make_virtual_rig, open_recording

    if icl_dir is None:
        raise ValidationError("the ICL-NUIM cells need the data folder: pass data_dir (or icl=False)")
    icl_dir = Path(icl_dir)
    if not icl_dir.is_dir():
        raise ValidationError(f"the ICL-NUIM data was not found at {icl_dir}")
    seq = open_recording(icl_dir)
    idx = icl_indices(n, seed, len(seq))
    with tempfile.TemporaryDirectory(prefix="fuseflow-icl-") as tmp:
        rig = make_virtual_rig(seq, idx, Path(tmp) / "rig")
        rec = open_recording(Path(tmp) / "rig")
        frame = rec[0]
    frame, rig = _subsample(frame, rig, pc.icl_stride)
    return Sample(frame, rig, None, f"ICL frames {idx}")


# ------------------------------------------------------------------------------------------
# fusion methods and metrics
# ------------------------------------------------------------------------------------------


def fusion_method(name: str) -> Callable:
    """``fn(frame, rig) -> FusedCloud`` for a row name of :data:`METHODS` or ``FUSE:<preset>``."""
    from fuseflow.eval import baselines as B

    if name == "FUSE" or name.startswith("FUSE:"):
        from fuseflow.fuse import fuse, preset

        cfg = preset(name.split(":", 1)[1] if ":" in name else "default")
        return lambda frame, rig: fuse(frame, rig, cfg)
    table = {
        "naive": B.naive_fusion,
        "voxel 1 cm": lambda f, r: B.voxel_downsampled_fusion(f, r, voxel=0.01),
        "SOR": B.sor_fusion,
        "TSDF 1 cm": lambda f, r: B.tsdf_fusion(f, r, voxel=0.01),
    }
    if name not in table:
        raise ValidationError(f"unknown fusion method {name!r}; methods: {list(METHODS)} or FUSE:<preset>")
    return table[name]


def cloud_metrics(cloud, sample: Sample, seed: int = 0) -> dict[str, float]:
    """PFR (mm), PNCC, OR (%), points; with GT also CD (mm), accuracy / completeness (mm),
    F-score / precision / recall at 1 cm and the share of points > 2 cm from the surface (%)."""
    from fuseflow.eval import metrics as M

    out: dict[str, float] = {"points": float(len(cloud.xyz))}
    if len(cloud.xyz) == 0:
        return out
    out["pfr_mm"] = M.plane_fitting_residual(cloud, seed=seed).pfr_mm
    out["pncc"] = M.pncc(cloud, sample.frame, sample.rig, seed=seed).pncc
    out["or_pct"] = 100.0 * M.outlier_ratio(cloud).ratio
    # docs/design.md's OR (5 mm) counts every point of a cloud sparser than 5 mm as an outlier; the
    # same count at 2 cm is reported beside it (a project addition, labelled as such).
    out["or2_pct"] = 100.0 * M.outlier_ratio(cloud, radius=0.02).ratio
    if sample.gt is not None and len(sample.gt.samples):
        r = sample.gt.score(cloud.xyz)
        out.update(
            cd_mm=r["chamfer_mm"],
            acc_mm=r["accuracy_mm"],
            comp_mm=r["completeness_mm"],
            fscore=r["f_1cm"],
            precision=r["precision_1cm"],
            recall=r["recall_1cm"],
            gt_outlier_pct=100.0 * r["outlier_2cm"],
        )
    return out


def timed(fn: Callable, sample: Sample) -> tuple[Any, dict[str, float]]:
    """Run ``fn(frame, rig)`` once under fuseflow.eval.metrics.measure: (cloud, {ms, fps, rss_mib})."""
    from fuseflow.eval.metrics import measure

    with measure("cpu") as m:
        cloud = fn(sample.frame, sample.rig)
    return cloud, {"ms": 1000 * m.wall_s, "fps": 1.0 / m.wall_s, "rss_mib": m.peak_rss_bytes / 2**20}


# ------------------------------------------------------------------------------------------
# calibration
# ------------------------------------------------------------------------------------------


def perturbed_backbone(rig, seed: int):
    """Backbone stand-in: the reference poses, each camera rotated by PERTURB[0] degrees and its
    centre moved PERTURB[1] mm, at a random unknown scale in [0.1, 10] (GMAC must recover it)."""
    from fuseflow.calib import BackboneResult
    from fuseflow.synth.recording import perturb_extrinsics

    rng = np.random.default_rng([seed, 77])
    noisy = perturb_extrinsics(rig, PERTURB[0], PERTURB[1], rng)
    scale = float(np.exp(rng.uniform(np.log(0.1), np.log(10.0))))
    T = np.stack([np.array(c.T_cam_world) for c in noisy.cameras])
    T[:, :3, 3] /= scale
    return BackboneResult(T, np.ones(len(T), bool), name="perturbed-truth", info={"scale": scale})


def _scaled(bb, ids, s: float) -> dict[str, np.ndarray]:
    out = {}
    for k in np.flatnonzero(bb.registered):
        M = np.array(bb.T_cam_world[k], dtype=np.float64)
        M[:3, 3] *= s
        out[ids[k]] = M
    return out


def calibrations(sample: Sample, backbone: str, seed: int, rows: Iterable[str]) -> dict[str, dict]:
    """{row: {"T": {id: 4x4 list} | None, "seconds": s, "error": str}} for the backbone + naive
    scale row and the GMAC presets ``rows`` (keys of GMAC_ROWS), all on one backbone run."""
    import fuseflow
    from fuseflow.calib import CalibConfig, calibrate, get_backbone

    frame = sample.frame
    bare = fuseflow.Rig(tuple(c.with_extrinsics(None) for c in sample.rig.cameras))
    ids = frame.camera_ids
    out: dict[str, dict] = {}
    t0 = time.perf_counter()
    try:
        if backbone == "colmap":
            bb = get_backbone("colmap")(frame, bare, CalibConfig(seed=seed))
        else:
            bb = perturbed_backbone(sample.rig, seed)
    except FuseFlowError as exc:
        return {r: {"T": None, "error": f"backbone: {exc}"} for r in [ORIGINAL, *rows]}
    t_bb = time.perf_counter() - t0
    naive = None
    for row in rows:
        t = time.perf_counter()
        try:
            cal = calibrate(frame, bare, CalibConfig.preset(GMAC_ROWS[row], seed=seed), backbone_result=bb)
        except FuseFlowError as exc:
            out[row] = {"T": None, "error": str(exc)}
            continue
        out[row] = {
            "T": {k: np.asarray(v).tolist() for k, v in cal.T_cam_world.items()},
            "seconds": t_bb + time.perf_counter() - t,
        }
        naive = naive or cal.report.scale_naive_median_depth_ratio
    if naive:
        out[ORIGINAL] = {"T": {k: v.tolist() for k, v in _scaled(bb, ids, naive).items()}, "seconds": t_bb}
    else:
        out[ORIGINAL] = {"T": None, "error": "no naive scale (every GMAC run failed)"}
    return out


def default_calibration(sample: Sample, seed: int) -> dict:
    """{"T": {id: 4x4 list} | None, "seconds": s, "error": str} of ``calibrate`` with the
    product's default config (auto backbone, joint refinement); T is None when it fails or
    leaves a camera unplaced (the report's reason in "error")."""
    import fuseflow
    from fuseflow.calib import CalibConfig, calibrate

    bare = fuseflow.Rig(tuple(c.with_extrinsics(None) for c in sample.rig.cameras))
    t0 = time.perf_counter()
    try:
        cal = calibrate(sample.frame, bare, CalibConfig(seed=seed))
    except FuseFlowError as exc:
        return {"T": None, "error": str(exc)}
    return {"T": {k: np.asarray(v).tolist() for k, v in cal.T_cam_world.items()}, "seconds": time.perf_counter() - t0}


def pose_row(T: dict | None, rig) -> dict[str, float] | None:
    """Rotation / translation error against the rig's extrinsics; None when < 2 cameras placed."""
    from fuseflow.eval.metrics import pose_errors

    if not T or len(T) < 2:
        return None
    ref = {c.id: np.array(c.T_cam_world) for c in rig.cameras}
    e = pose_errors({k: np.array(v) for k, v in T.items()}, ref)
    return {"rot_deg": e.rotation_deg, "trans_mm": e.translation_mm}


def anchored_rig(T: dict, rig):
    """The rig with estimated extrinsics moved into the reference world by anchoring camera 0:
    T_k' = T_k inv(T_0) T_0^ref. Relative poses are untouched; the fused cloud can then be compared
    with the GT surface. None unless every camera was placed."""
    ids = [c.id for c in rig.cameras]
    if not T or any(i not in T for i in ids):
        return None
    T0 = np.array(T[ids[0]])
    A = np.linalg.inv(T0) @ np.array(rig.cameras[0].T_cam_world)
    est = {}
    for i in ids:
        M = np.array(T[i]) @ A
        u, _, vt = np.linalg.svd(M[:3, :3])  # re-orthonormalise the float round trip
        M[:3, :3] = u @ vt
        est[i] = M
    return rig.with_extrinsics(est)


# ------------------------------------------------------------------------------------------
# cells
# ------------------------------------------------------------------------------------------


@dataclass
class Cell:
    """One unit of cached work: ``compute() -> dict`` saved at ``DIR/cells/<key>.json``."""

    key: str
    table: str
    compute: Callable[[], dict]
    meta: dict = field(default_factory=dict)


def _slug(*parts: Any) -> str:
    s = "_".join(str(p) for p in parts)
    return "".join(ch if ch.isalnum() or ch in "-." else "-" for ch in s)


def _fusion_cell(
    dataset: str,
    n: int,
    method: str,
    seed: int,
    pc: PaperConfig,
    with_metrics: bool = True,
    icl_dir: Path | None = None,
) -> dict:
    """Fuse every frame of one data set / seed with ``method``: per-frame timings, then metrics.

    The first frame is fused once untimed (numba compilation, Open3D start-up), then the process
    idles 0.3 s so that worker threads left spinning by the previous cell's metrics (OpenMP
    busy-wait) do not steal the 2 cores; all frames are timed back to back before any metric runs.
    """
    fn = fusion_method(method)
    samples = _samples(dataset, n, seed, pc, icl_dir)
    fn(samples[0].frame, samples[0].rig)  # warm-up
    time.sleep(0.3)
    timed_runs = [timed(fn, s) for s in samples]
    frames = []
    for t, (s, (cloud, tm)) in enumerate(zip(samples, timed_runs)):
        row = dict(tm)
        if with_metrics:
            row.update(cloud_metrics(cloud, s, seed=t))
        else:
            row["points"] = float(len(cloud.xyz))
        frames.append(row)
    return {"frames": frames, "label": samples[0].label}


def _samples(dataset: str, n: int, seed: int, pc: PaperConfig, icl_dir: Path | None = None) -> list[Sample]:
    if dataset == "icl":
        return [icl_sample(n, seed, pc, icl_dir)]
    scene, dynamic = {"sim-room": ("room", False), "sim-studio-dyn": ("studio", True)}[dataset]
    return [_SIMS.sample(scene, dynamic, n, seed, t, pc) for t in range(pc.frames)]


def _gmac_cell(dataset: str, backbone: str, seed: int, pc: PaperConfig, icl_dir: Path | None = None) -> dict:
    """Table I/III rows of one data set and seed: the backbone's GMAC rows, or for backbone
    "default" the row ``DEFAULT_ROW``, the product's default ``calibrate`` on the same frame."""
    pc = pc.for_calibration()
    s = _samples(dataset, pc.calib_cameras, seed, pc, icl_dir)[0]
    if backbone == "default":
        cals = {DEFAULT_ROW: default_calibration(s, seed)}
    else:
        cals = calibrations(s, backbone, seed, GMAC_ROWS)
    rows = {}
    for name, c in cals.items():
        err = pose_row(c.get("T"), s.rig)
        placed = len(c.get("T") or {})
        rows[name] = {**(err or {}), "seconds": c.get("seconds"), "failed": err is None, "error": c.get("error"),
                      "placed": placed}  # fmt: skip
    return {"rows": rows, "label": s.label}


def _extrinsics_cell(dataset: str, source: str, seed: int, pc: PaperConfig, icl_dir: Path | None = None) -> dict:
    """FUSE on every frame with extrinsics from ``source``: "GT", "<backbone>:GMAC",
    "<backbone>:Original" or "default:GMAC" (the product's default calibration; each calibrated on
    the first frame of the seed), at the calibration resolution."""
    pc = pc.for_calibration()
    n = pc.pipeline_cameras
    samples = _samples(dataset, n, seed, pc, icl_dir)
    rig = samples[0].rig
    pose = None
    if source == "default:GMAC":
        cal = default_calibration(samples[0], seed)
    elif source != "GT":
        backbone, what = source.split(":")
        row = "GMAC (default)" if what == "GMAC" else ORIGINAL
        cal = calibrations(samples[0], backbone, seed, ["GMAC (default)"])[row]
    if source != "GT":
        pose = pose_row(cal.get("T"), rig)
        rig = anchored_rig(cal.get("T"), rig)
        if rig is None:
            return {"frames": [], "failed": True, "error": cal.get("error") or "not every camera placed", "pose": pose}
    fn = fusion_method("FUSE")
    frames = []
    for t, s in enumerate(samples):
        s2 = Sample(s.frame, rig, s.gt, s.label)
        cloud, tm = timed(fn, s2)
        # PNCC projects with the evaluated rig's extrinsics (that is what a user of these
        # extrinsics would see); CD / F-score compare with the true surface.
        frames.append({**tm, **cloud_metrics(cloud, s2, seed=t)})
    return {"frames": frames, "pose": pose, "label": samples[0].label}


def extrinsic_sources(pc: PaperConfig) -> list[str]:
    out = ["GT"]
    for b in pc.backbones:
        # the perturbed stand-in has no depth of its own, so it has no naive-scale "Original"
        out += [f"{b}:GMAC"] + ([f"{b}:Original"] if b != "perturbed" else [])
    if pc.default_calib_row:
        out.append("default:GMAC")
    return out


def plan(
    pc: PaperConfig, tables: Sequence[str] = TABLES, icl: bool = True, data_dir: str | Path | None = None
) -> list[Cell]:
    """Every cell of the requested tables, in run order.

    ``icl``: include the ICL-NUIM cells; they read ``data_dir``/icl-livingroom1 when computed
    (:func:`icl_path`; None: computing one raises ValidationError)."""
    bad = sorted(set(tables) - set(TABLES))
    if bad:
        raise ValidationError(f"unknown tables {bad}; choose from {list(TABLES)}")
    static_sets = ["sim-room"] + (["icl"] if icl else [])
    icl_dir = icl_path(data_dir) if data_dir is not None else None
    cells: list[Cell] = []
    seeds = range(pc.seeds)

    def add(table, key, fn, **meta):
        cells.append(Cell(_slug(table, key), table, fn, meta))

    for table in TABLES:
        if table not in tables:
            continue
        if table == "gmac":
            for ds in static_sets:
                for b in pc.backbones:
                    for sd in range(pc.calib_seeds):
                        add(table, f"{ds}-{b}-s{sd}", lambda ds=ds, b=b, sd=sd: _gmac_cell(ds, b, sd, pc, icl_dir),
                            dataset=ds, backbone=b, seed=sd)  # fmt: skip
                if pc.default_calib_row:
                    for sd in range(pc.calib_seeds):
                        add(table, f"{ds}-default-s{sd}", lambda ds=ds, sd=sd: _gmac_cell(ds, "default", sd, pc, icl_dir),
                            dataset=ds, backbone="default", seed=sd)  # fmt: skip
        elif table in ("static", "dynamic"):
            sets = static_sets if table == "static" else ["sim-studio-dyn"]
            for ds in sets:
                for n in pc.cameras:
                    for sd in seeds:
                        for m in METHODS:
                            add(table, f"{ds}-N{n}-s{sd}-{m}", lambda ds=ds, n=n, m=m, sd=sd: _fusion_cell(ds, n, m, sd, pc, icl_dir=icl_dir),
                                dataset=ds, n=n, method=m, seed=sd)  # fmt: skip
        elif table == "ablation":
            n = pc.pipeline_cameras
            for sd in seeds:
                for a in ABLATION_ROWS:
                    m = f"FUSE:{a}"
                    add(table, f"N{n}-s{sd}-{a}", lambda m=m, sd=sd, n=n: _fusion_cell("sim-studio-dyn", n, m, sd, pc),
                        dataset="sim-studio-dyn", n=n, method=a, seed=sd)  # fmt: skip
        elif table == "extrinsics":
            for ds in static_sets:
                for sd in seeds:
                    for src in extrinsic_sources(pc):
                        add(table, f"{ds}-s{sd}-{src}", lambda ds=ds, src=src, sd=sd: _extrinsics_cell(ds, src, sd, pc, icl_dir),
                            dataset=ds, source=src, seed=sd)  # fmt: skip
        elif table == "fps":
            for n in pc.fps_cameras:
                for sd in seeds:
                    for m in METHODS:
                        add(table, f"N{n}-s{sd}-{m}",
                            lambda n=n, m=m, sd=sd: _fusion_cell("sim-studio-dyn", n, m, sd, pc, with_metrics=False),
                            dataset="sim-studio-dyn", n=n, method=m, seed=sd)  # fmt: skip
    return cells


def _cell_path(out: Path, cell: Cell) -> Path:
    return out / "cells" / f"{cell.key}.json"


def _clean(x: Any) -> Any:
    """JSON-safe: NaN / inf become strings that load back as floats."""
    if isinstance(x, float) and not math.isfinite(x):
        return str(x)
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, np.generic):
        return _clean(x.item())
    return x


def run(
    out: Path,
    pc: PaperConfig,
    tables: Sequence[str] = TABLES,
    command: str = "",
    progress: Callable[[int, int, str], None] | None = None,
    icl: bool = True,
    data_dir: str | Path | None = None,
) -> dict[str, Path]:
    """Compute the missing cells (cached ones are skipped), then write ``paper_tables.md`` and
    the Fig. 5 PNG. Returns {"markdown": path, "fig5": path or absent, "cells": n computed}.

    ``icl`` includes the ICL-NUIM cells, read from ``data_dir``/icl-livingroom1 (the shared data
    folder, :func:`icl_path`); ``data_dir`` may be None when every ICL cell is already cached."""
    out = Path(out)
    (out / "cells").mkdir(parents=True, exist_ok=True)
    cfg_file = out / "config.json"
    if cfg_file.exists():
        old = json.loads(cfg_file.read_text())
        if old.get("config") != _clean(asdict(pc)):
            raise ValidationError(
                f"{out} holds results of a different configuration ({old.get('config', {}).get('name')}); "
                "use another --out folder or delete it"
            )
    cfg_file.write_text(json.dumps({"config": _clean(asdict(pc))}, indent=1))
    cells = plan(pc, tables, icl=icl, data_dir=data_dir)
    done = 0
    for i, cell in enumerate(cells):
        path = _cell_path(out, cell)
        if progress:
            progress(i, len(cells), cell.key)
        if path.exists():
            continue
        t = time.perf_counter()
        res = cell.compute()
        res = {"meta": cell.meta, "seconds": time.perf_counter() - t, **res}
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(_clean(res), indent=1))
        os.replace(tmp, path)
        done += 1
    if progress:
        progress(len(cells), len(cells), "tables")
    results = {c.key: (c, json.loads(_cell_path(out, c).read_text())) for c in cells}
    files: dict[str, Path] = {}
    if "fps" in tables:
        files["fig5"] = write_fig5(out / "fig5_fps_vs_n.png", results, pc)
    md = render_markdown(results, pc, command, tables, fig5=files.get("fig5"))
    (out / "paper_tables.md").write_text(md)
    files["markdown"] = out / "paper_tables.md"
    files["computed"] = done  # type: ignore[assignment]
    return files


# ------------------------------------------------------------------------------------------
# tables
# ------------------------------------------------------------------------------------------


def _f(x: Any) -> float:
    try:
        return float(x)
    except (TypeError, ValueError):
        return float("nan")


def ms(values: Iterable[Any], digits: int = 2) -> str:
    """'mean +- std' of the finite values ('-' when none; NaN count noted)."""
    v = np.array([_f(x) for x in values], dtype=float)
    good = v[np.isfinite(v)]
    if len(good) == 0:
        return "-"
    s = f"{good.mean():.{digits}f} ± {good.std():.{digits}f}"
    if len(good) < len(v):
        s += f" ({len(v) - len(good)} n/a)"
    return s


def _frames(results, pred) -> list[dict]:
    rows = []
    for cell, res in results.values():
        if pred(cell):
            rows.extend(res.get("frames", []))
    return rows


FUSION_COLS = [
    ("points", "points", 0),
    ("pfr_mm", "PFR (mm)", 2),
    ("pncc", "PNCC", 3),
    ("or_pct", "OR (%)", 1),
    ("or2_pct", "OR 2 cm (%)", 1),
    ("cd_mm", "CD (mm)", 1),
    ("fscore", "F@1cm", 3),
    ("gt_outlier_pct", ">2 cm (%)", 1),
    ("fps", "FPS", 2),
    ("rss_mib", "peak RSS (MiB)", 0),
]


def _fusion_table(rows: list[tuple[str, list[dict]]], gt: bool, timing: bool = True) -> list[str]:
    cols = [c for c in FUSION_COLS if (gt or c[0] not in ("cd_mm", "fscore", "gt_outlier_pct"))]
    if not timing:
        cols = [c for c in cols if c[0] not in ("fps", "rss_mib")]
    lines = ["| " + " | ".join(["row", "frames"] + [c[1] for c in cols]) + " |", "|" + "---|" * (len(cols) + 2)]
    for name, frames in rows:
        cells = [name, str(len(frames))] + [ms([fr.get(k) for fr in frames], d) for k, _, d in cols]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


DATASET_LABEL = {
    "sim-room": "simulated room (fuseflow.synth, static, Kinect v1 noise)",
    "sim-studio-dyn": "simulated studio with moving objects (fuseflow.synth, Kinect v1 noise)",
    "icl": "ICL-NUIM living room kt1 virtual rig (static; reference poses = Open3D trajectory estimate)",
}


def render_markdown(
    results: dict, pc: PaperConfig, command: str, tables: Sequence[str], fig5: Path | None = None
) -> str:
    """All requested tables as Markdown, with the machine, library versions and the command."""
    L = _md_preamble(pc, command)
    for table in tables:
        if table == "gmac":
            L += _md_gmac(results, pc)
        elif table in ("static", "dynamic"):
            L += _md_fusion(results, pc, table)
        elif table == "ablation":
            L += _md_ablation(results, pc)
        elif table == "extrinsics":
            L += _md_extrinsics(results, pc)
        elif table == "fps":
            L += _md_fps(results, pc, fig5)
    return "\n".join(L)


def _md_preamble(pc: PaperConfig, command: str) -> list[str]:
    """Title, command, machine and the sizes / definitions paragraph."""
    W, H = pc.resolution
    icl_res = f"{640 // pc.icl_stride}x{480 // pc.icl_stride}"
    L = [f"# FuseFlow paper tables ({pc.name} run)", ""]
    L += [f"Command: `{command}`", ""] if command else []
    L += ["Machine and libraries: " + machine_info(), ""]
    L += [
        f"Simulated cameras {W}x{H}, {pc.frames} frames per seed, seeds {pc.seeds}; ICL subsampled to {icl_res} "
        f"(stride {pc.icl_stride}); calibration cells (Tables I/III, VIII) at "
        f"{'x'.join(map(str, pc.for_calibration().resolution))}, ICL stride {pc.for_calibration().icl_stride}; "
        "device cpu. Numbers: mean ± std over frames (all seeds pooled). "
        "Metrics as docs/design.md section 4 / docs/metrics.md: PFR 1 cm band, up to 3 planes; PNCC 3x3 patches; "
        "OR = share of points with fewer than 5 neighbours within 5 mm; CD and F-score (1 cm) against the "
        "simulator's surface that a camera sees (fuseflow.eval.reference: recall on its samples, precision "
        "by the distance to the true surface); '>2 cm' = share of fused points farther than 2 cm from the "
        "true surface. FPS = 1 / wall time of one fusion call (after one "
        "warm-up call); peak RSS is the whole process's (Python, torch, Open3D included).",
        "",
    ]
    return L


def _md_gmac(results: dict, pc: PaperConfig) -> list[str]:
    """Table I / III: GMAC and its ablations, per data set and backbone."""
    L: list[str] = []
    cells = [c for c, _ in results.values()]
    L += ["## Table I / III analogue: GMAC calibration and its ablations", ""]
    L += [
        f"N = {pc.calib_cameras}; one calibration per seed, mean ± std over seeds. Backbones: colmap = "
        "pycolmap SIFT + incremental mapping (the only learned-free backbone that runs offline here; "
        "VGGT / MapAnything / VGGSfM checkpoints are not available); perturbed = ground truth with "
        f"{PERTURB[0]} deg / {PERTURB[1]:g} mm per-camera noise at an unknown scale (a stand-in that "
        "isolates GMAC's scale recovery from the backbone). 'Original' = the backbone's poses scaled by "
        "the median sensor-depth / backbone-depth ratio. Time includes the backbone. Errors are means over "
        "pairs of the cameras a row placed (GMAC leaves out cameras without a kept edge; 'cameras placed'), "
        "so rows that place different cameras differ in rotation error without rotating anything: GMAC "
        "only rescales the backbone's translations (no refinement in these presets).",
        "",
    ]
    if pc.default_calib_row:
        L += [
            f"Row '{DEFAULT_ROW}' (beyond the paper): what `fuseflow calibrate` does by default, on the "
            "same frame: the metric RGB-D backbone, COLMAP where it adds a camera, each camera placed by "
            "the source with the best depth agreement, then the joint depth-aware refinement (docs/gmac.md).",
            "",
        ]
    for ds in dict.fromkeys(c.meta["dataset"] for c in cells if c.table == "gmac"):
        for b in [*pc.backbones, "default"]:
            sel = [res for c, res in results.values() if c.table == "gmac" and c.meta["dataset"] == ds
                   and c.meta["backbone"] == b]  # fmt: skip
            if not sel:
                continue
            title = "the product's default calibration (CalibConfig())" if b == "default" else f"backbone {b}"
            L += [f"### {DATASET_LABEL[ds]}, {title}", ""]
            L += [
                "| method | rot. error (deg) | trans. error (mm) | cameras placed | time (s) | failed |",
                "|---|---|---|---|---|---|",
            ]
            for row in [DEFAULT_ROW] if b == "default" else [ORIGINAL, *GMAC_ROWS]:
                if row == ORIGINAL and b == "perturbed":
                    L.append(f"| {row} | n/a: the stand-in has no depth for a naive scale | | | | |")
                    continue
                rs = [r["rows"][row] for r in sel if row in r["rows"]]
                ok = [r for r in rs if not r.get("failed")]
                L.append(
                    f"| {row} | {ms([r['rot_deg'] for r in ok])} | {ms([r['trans_mm'] for r in ok], 1)} | "
                    f"{ms([r.get('placed') for r in ok], 1)} of {pc.calib_cameras} | "
                    f"{ms([r.get('seconds') for r in ok], 1)} | {len(rs) - len(ok)}/{len(rs)} |"
                )
            L.append("")
    return L


def _md_fusion(results: dict, pc: PaperConfig, table: str) -> list[str]:
    """Tables IV / VI (static) or V (dynamic): the fusion methods per data set and N."""
    L: list[str] = []
    cells = [c for c, _ in results.values()]
    title = "Table IV / VI analogue: static scenes" if table == "static" else "Table V analogue: dynamic scene"
    L += [f"## {title}", ""]
    for ds in dict.fromkeys(c.meta["dataset"] for c in cells if c.table == table):
        L += [f"### {DATASET_LABEL[ds]}", ""]
        for n in pc.cameras:
            rows = [
                (m, _frames(results, lambda c, m=m, n=n, ds=ds, table=table: c.table == table and c.meta["dataset"] == ds
                            and c.meta["n"] == n and c.meta["method"] == m))
                for m in METHODS
            ]  # fmt: skip
            L += [f"N = {n}:", ""] + _fusion_table(rows, gt=ds != "icl") + [""]
    return L


def _md_ablation(results: dict, pc: PaperConfig) -> list[str]:
    """Table VII: FUSE and its ablations."""
    L: list[str] = []
    L += [f"## Table VII analogue: FUSE ablations (dynamic studio, N = {pc.pipeline_cameras})", ""]
    rows = [
        (f"FUSE ({a})" if a in ("default", "paper") else a,
         _frames(results, lambda c, a=a: c.table == "ablation" and c.meta["method"] == a))
        for a in ABLATION_ROWS
    ]  # fmt: skip
    L += _fusion_table(rows, gt=True) + [""]
    return L


def _md_extrinsics(results: dict, pc: PaperConfig) -> list[str]:
    """Table VIII: FUSE under fixed extrinsics from each source, with their pose errors."""
    L: list[str] = []
    cells = [c for c, _ in results.values()]
    L += [f"## Table VIII analogue: FUSE (N = {pc.pipeline_cameras}) under fixed extrinsics", ""]
    L += [
        "Calibrated on the first frame of each seed; the estimate is moved into the reference world by "
        "anchoring camera 0 (relative poses untouched) so CD compares with the true surface. 'pose' = the "
        "calibration's rotation / translation error. A failed calibration (a camera not placed) has no frames.",
        "",
    ]
    for ds in dict.fromkeys(c.meta["dataset"] for c in cells if c.table == "extrinsics"):
        L += [f"### {DATASET_LABEL[ds]}", ""]
        rows, poses = [], {}
        for src in extrinsic_sources(pc):
            sel = [res for c, res in results.values() if c.table == "extrinsics" and c.meta["dataset"] == ds
                   and c.meta["source"] == src]  # fmt: skip
            frames = [f for r in sel for f in r.get("frames", [])]
            nfail = sum(1 for r in sel if r.get("failed"))
            label = {"GT": "GT", "default:GMAC": "default (auto) + GMAC"}.get(src, src.replace(":", " + "))
            ps = [r["pose"] for r in sel if r.get("pose")]
            poses[label] = (ms([p["rot_deg"] for p in ps]), ms([p["trans_mm"] for p in ps], 1), nfail, len(sel))
            rows.append((label, frames))
        tab = _fusion_table(rows, gt=ds != "icl", timing=False)
        tab[0] = tab[0][:-1] + "| pose rot (deg) | pose trans (mm) | failed seeds |"
        tab[1] += "---|---|---|"
        for i, (label, _) in enumerate(rows):
            r, t, nf, nt = poses[label]
            tab[2 + i] += f" {r if label != 'GT' else '0'} | {t if label != 'GT' else '0'} | {nf}/{nt} |"
        L += tab + [""]
    return L


def _md_fps(results: dict, pc: PaperConfig, fig5: Path | None) -> list[str]:
    """Fig. 5: fusion FPS against N (and the PNG link)."""
    L: list[str] = []
    L += ["## Fig. 5 analogue: fusion FPS against N (dynamic studio)", ""]
    if fig5 is not None:
        L += [f"![FPS against N]({fig5.name})", ""]
    L += ["| N | " + " | ".join(METHODS) + " |", "|---|" + "---|" * len(METHODS)]
    for n in pc.fps_cameras:
        vals = [
            ms([f["fps"] for f in _frames(results, lambda c, n=n, m=m: c.table == "fps" and c.meta["n"] == n
                                          and c.meta["method"] == m)])
            for m in METHODS
        ]  # fmt: skip
        L.append(f"| {n} | " + " | ".join(vals) + " |")
    L.append("")
    return L


def fps_series(results: dict, pc: PaperConfig) -> dict[str, list[tuple[int, float, float]]]:
    """{method: [(N, mean FPS, std FPS)]} from the fps cells."""
    out = {}
    for m in METHODS:
        pts = []
        for n in pc.fps_cameras:
            v = [f["fps"] for c, r in results.values() if c.table == "fps" and c.meta["n"] == n
                 and c.meta["method"] == m for f in r.get("frames", [])]  # fmt: skip
            if v:
                pts.append((n, float(np.mean(v)), float(np.std(v))))
        out[m] = pts
    return out


COLORS = [(200, 60, 20), (40, 160, 40), (30, 120, 230), (180, 40, 180), (20, 170, 200)]  # BGR


def write_fig5(path: Path, results: dict, pc: PaperConfig) -> Path:
    """FPS against N as a PNG, drawn with OpenCV (matplotlib is not installed in this project):
    one polyline per method, error bars = std over frames, log-scaled FPS axis."""
    import cv2

    series = fps_series(results, pc)
    Wd, Hd, lm, r, t, b = 900, 560, 90, 210, 50, 70
    img = np.full((Hd, Wd, 3), 255, np.uint8)
    vals = [v for s in series.values() for _, v, _ in s if v > 0]
    if not vals:
        cv2.imwrite(str(path), img)
        return path
    lo, hi = math.floor(math.log10(min(vals) * 0.8)), math.ceil(math.log10(max(vals) * 1.25))
    ns = list(pc.fps_cameras)
    xmin, xmax = min(ns) - 0.5, max(ns) + 0.5

    def X(n):
        return int(lm + (n - xmin) / (xmax - xmin) * (Wd - lm - r))

    def Y(v):
        return int(Hd - b - (math.log10(max(v, 1e-9)) - lo) / (hi - lo) * (Hd - t - b))

    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.rectangle(img, (lm, t), (Wd - r, Hd - b), (0, 0, 0), 1)
    for e in range(lo, hi + 1):
        for m in (1, 2, 5):
            v = m * 10.0**e
            if 10.0**lo <= v <= 10.0**hi:
                y = Y(v)
                cv2.line(img, (lm, y), (Wd - r, y), (225, 225, 225) if m != 1 else (190, 190, 190), 1)
                cv2.putText(img, f"{v:g}", (lm - 45, y + 5), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    for n in ns:
        cv2.putText(img, str(n), (X(n) - 5, Hd - b + 22), font, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, "number of cameras N", (lm + 200, Hd - 20), font, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, "FPS", (15, (t + Hd - b) // 2), font, 0.6, (0, 0, 0), 1, cv2.LINE_AA)  # clear of the ticks
    W_, H_ = pc.resolution
    cv2.putText(img, f"Fusion FPS vs N, {W_}x{H_}, CPU (2 cores), mean +- std over frames", (lm, 30), font, 0.55,
                (0, 0, 0), 1, cv2.LINE_AA)  # fmt: skip
    for k, (m, pts) in enumerate(series.items()):
        col = COLORS[k % len(COLORS)]
        prev = None
        for n, v, s in pts:
            p = (X(n), Y(v))
            cv2.line(img, (p[0], Y(max(v - s, v * 0.05))), (p[0], Y(v + s)), col, 1, cv2.LINE_AA)
            cv2.circle(img, p, 4, col, -1, cv2.LINE_AA)
            if prev:
                cv2.line(img, prev, p, col, 2, cv2.LINE_AA)
            prev = p
        y = t + 25 + 25 * k
        cv2.line(img, (Wd - r + 15, y - 5), (Wd - r + 45, y - 5), col, 2, cv2.LINE_AA)
        cv2.putText(img, m, (Wd - r + 52, y), font, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.imwrite(str(path), img)
    return path


def machine_info() -> str:
    """CPU, core count, OS, Python and the versions of the libraries the numbers depend on."""
    import importlib.metadata as md

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    libs = []
    for name in ("fuseflow", "torch", "numpy", "open3d", "scipy", "numba", "pycolmap", "opencv-python-headless",
                 "opencv-python"):  # fmt: skip
        try:
            libs.append(f"{name} {md.version(name)}")
        except md.PackageNotFoundError:
            continue
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return (
        f"{cpu}, {cores} cores usable, {platform.system()} {platform.release()}, Python {platform.python_version()}; "
        + ", ".join(libs)
    )
