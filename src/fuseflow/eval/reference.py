"""The reference surface of every simulated quality number: the ground-truth surface some camera saw.

A ground-truth surface sample counts as *seen* when at least one camera of the rig

* faces it: the sample's normal points towards the camera centre, at an incidence angle (ray
  against normal) below the sensor's grazing limit (``grazing_max_deg``; the simulated Kinect
  returns no depth beyond 75 deg), and it lies in front of the camera;
* images it: it projects inside the image, and the noise-free depth at the *nearest* pixel (the
  simulator casts each pixel's ray through its integer coordinates) agrees with the sample's
  depth within ``SEEN_TOL_M`` + ``SEEN_TOL_REL`` * z, so occluded samples are not seen;
* measures it: its depth lies inside the camera's ``depth_range`` (the sensor returns nothing
  outside; the studio's far walls are in the simulator's surface but beyond 4.5 m).

Scores (:meth:`SurfaceReference.score`):

* recall at d and completeness: on the seen samples (their nearest fused point). The samples are
  area-uniform (1 cm spacing by default), so their density sets only the variance of recall;
* precision at d, accuracy and the share beyond 2 cm: the distance of each fused point to the
  true surface (the simulator's triangles at that instant, exact). Against 1 cm samples a point
  lying exactly on the surface is 5 mm from its nearest sample on average and within 5 mm only
  54 % of the time (a Poisson sample of 1e4 per m^2: 1 - exp(-pi 1e4 d^2)), which biases
  sample-based precision at 5 mm and 1 cm low. Without triangles (``distance_to_surface`` None)
  the samples stand in, with that bias.

Check (tests/eval/test_reference.py): every valid pixel of the noise-free depth, fused by plain
back-projection, has precision and recall near 1 at 1 cm on an 8-camera 640x480 ring.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from fuseflow.errors import ValidationError
from fuseflow.eval.metrics import SurfaceDistances, as_points, surface_distances
from fuseflow.types import Rig

__all__ = [
    "SEEN_TOL_M",
    "SEEN_TOL_REL",
    "THRESHOLDS",
    "SurfaceReference",
    "seen_mask",
    "simulated_reference",
]

SEEN_TOL_M = 0.01
"""Occlusion test: a sample is imaged when the noise-free depth at its pixel is within this many
metres (plus ``SEEN_TOL_REL`` * z) of its own depth."""
SEEN_TOL_REL = 0.01
"""Relative part of the occlusion tolerance (1 % of the depth)."""
THRESHOLDS = (0.005, 0.01, 0.02)
"""Distances (m) at which precision, recall and F are reported: 5 mm, 1 cm, 2 cm."""


def seen_mask(
    points: np.ndarray,
    normals: np.ndarray,
    depth_gt: np.ndarray,
    rig: Rig,
    grazing_max_deg: float | None = None,
    tol_m: float = SEEN_TOL_M,
    tol_rel: float = SEEN_TOL_REL,
) -> np.ndarray:
    """(S,) bool: the samples (S, 3) world metres with unit normals (S, 3) that some camera of
    ``rig`` sees (module docstring), given the noise-free depth (N, H, W) metres in rig order.
    ``grazing_max_deg`` None: any incidence below 90 deg counts."""
    P = np.asarray(points, np.float64).reshape(-1, 3)
    Nn = np.asarray(normals, np.float64).reshape(-1, 3)
    D = np.asarray(depth_gt, np.float32)
    if len(Nn) != len(P):
        raise ValidationError(f"seen_mask: {len(P)} points but {len(Nn)} normals")
    if D.ndim != 3 or len(D) != len(rig):
        raise ValidationError(f"seen_mask: depth_gt must be (N, H, W) with N = {len(rig)} cameras, got {D.shape}")
    cos_min = math.cos(math.radians(grazing_max_deg)) if grazing_max_deg is not None else 0.0
    seen = np.zeros(len(P), bool)
    for i, cam in enumerate(rig.cameras):
        todo = np.flatnonzero(~seen)
        if len(todo) == 0:
            break
        p = P[todo]
        R, t = cam.T_cam_world[:3, :3], cam.T_cam_world[:3, 3]
        centre = -R.T @ t
        ray = centre - p
        dist = np.linalg.norm(ray, axis=1)
        facing = (ray * Nn[todo]).sum(1) > cos_min * dist
        Xc = p @ R.T + t
        z = Xc[:, 2]
        lo, hi = cam.depth_range
        ok = facing & (z >= lo) & (z <= hi)
        uvw = Xc[ok] @ np.asarray(cam.K, np.float64).T
        u = np.rint(uvw[:, 0] / uvw[:, 2])
        v = np.rint(uvw[:, 1] / uvw[:, 2])
        inside = (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        idx = np.flatnonzero(ok)[inside]
        d = D[i, v[inside].astype(np.int64), u[inside].astype(np.int64)]
        zz = z[idx]
        seen[todo[idx[(d > 0) & (np.abs(d - zz) < tol_m + tol_rel * zz)]]] = True
    return seen


@dataclass(frozen=True)
class SurfaceReference:
    """The seen ground-truth surface of one instant.

    Attributes:
        samples: (S, 3) float64 world metres, the seen surface samples (recall, completeness).
        distance_to_surface: (M, 3) world points -> (M,) metres to the true surface (precision,
            accuracy, outliers); None: the distance to the nearest sample stands in.
    """

    samples: np.ndarray
    distance_to_surface: Callable[[np.ndarray], np.ndarray] | None = None

    def distances(self, points: Any, sample: int | None = None, seed: int = 0) -> SurfaceDistances:
        """Both ways' distances (fuseflow.eval.metrics.SurfaceDistances): fused point -> true
        surface, seen sample -> nearest fused point. ``sample``: query at most this many random
        points of each side (seeded), None = all."""
        pts = as_points(points)
        dist = surface_distances(pts, self.samples, sample, seed)
        if self.distance_to_surface is None or len(pts) == 0:
            return dist
        if sample is not None and len(pts) > sample:
            pts = pts[np.random.default_rng(seed).choice(len(pts), sample, replace=False)]
        to_ref = np.asarray(self.distance_to_surface(pts), np.float64)
        return SurfaceDistances(to_ref, dist.to_prediction)

    def score(self, points: Any, thresholds: Sequence[float] = THRESHOLDS, outlier_m: float = 0.02) -> dict:
        """Quality of a cloud against this surface: ``points``, ``chamfer_mm``, ``accuracy_mm``,
        ``completeness_mm``, ``precision_X``, ``recall_X``, ``f_X`` for each threshold X (as
        ``5mm``, ``1cm``, ``2cm``), and ``outlier_2cm`` (share of points beyond ``outlier_m``)."""
        dist = self.distances(points)
        cd = dist.chamfer()
        out = {
            "points": len(dist.to_reference),
            "chamfer_mm": cd.chamfer_mm,
            "accuracy_mm": cd.accuracy_mm,
            "completeness_mm": cd.completeness_mm,
        }
        for d in thresholds:
            f = dist.fscore(d)
            key = threshold_name(d)
            out.update({f"precision_{key}": f.precision, f"recall_{key}": f.recall, f"f_{key}": f.f_score})
        out[f"outlier_{threshold_name(outlier_m)}"] = dist.outlier_share(outlier_m)
        return out


def threshold_name(d: float) -> str:
    """0.005 -> '5mm', 0.01 -> '1cm', 0.02 -> '2cm' (keys of :meth:`SurfaceReference.score`)."""
    mm = round(d * 1000.0, 3)
    return f"{mm / 10:g}cm" if mm % 10 == 0 else f"{mm:g}mm"


def simulated_reference(
    sim: Any, t: int, surface: tuple[np.ndarray, np.ndarray], depth_gt: np.ndarray
) -> SurfaceReference:
    """The seen surface of a ``fuseflow.synth.Simulator``'s frame ``t``: its GT samples
    ``surface`` = (points, normals) restricted by :func:`seen_mask` (the grazing limit of the
    simulated sensor when its grazing dropout is on) and, for precision, the exact distance to the
    scene's triangles at that instant."""
    import open3d as o3d

    cfg = sim.cfg
    graze = cfg.sensor.grazing_max_deg if (cfg.grazing_dropout and cfg.noise != "none") else None
    pts, nrm = surface
    keep = seen_mask(pts, nrm, depth_gt, sim.rig, graze)
    tri = np.asarray(sim.scene.triangles_at(t / cfg.fps)[0], np.float32).reshape(-1, 3)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(tri), o3d.core.Tensor(np.arange(len(tri), dtype=np.uint32).reshape(-1, 3)))

    def to_surface(p: np.ndarray) -> np.ndarray:
        return scene.compute_distance(o3d.core.Tensor(np.ascontiguousarray(p, np.float32))).numpy()

    return SurfaceReference(np.asarray(pts, np.float64)[keep], to_surface)
