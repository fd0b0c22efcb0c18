"""Metric RGB-D backbone (``rgbd``): camera poses in metres from sensor depth, for sparse wide-baseline rigs.

COLMAP cannot match across cameras 90-120 deg apart; the depth can. Outline
(``rgbd_backbone``), one or several frames of a static rig:

1. Per camera (``prepare_camera``): median colour / depth over the frames, the floor plane
   (:mod:`fuseflow.calib.floor`) and its metric top-down image with SIFT on it, keypoints of every
   frame's image (SIFT, or the learned ``RGBDConfig.matcher``, ``matchers``)
   lifted to 3-D by that frame's depth, and a subsampled point set for checks.
2. Per camera pair, candidate relative poses from three routes (several hypotheses each,
   sequential RANSAC with a fixed seed):
   ``floor``: top-down SIFT matches, 4-DoF RANSAC (yaw + shift on the floor; both floor planes
   fix roll, pitch and height); ``sift3d``: image SIFT matches pooled over frames, lifted by
   depth, 6-DoF 3-D RANSAC (Kabsch); ``sift4``: the same 3-D matches, 4-DoF on the floor (two
   correct matches suffice). With a learned matcher, its matches replace SIFT's in ``sift3d`` and
   ``sift4`` (the route names stay).
   Where the ``people`` extra is installed, ``people`` / ``people+icp`` (route (d),
   :mod:`fuseflow.calib.people`): the joints of a person both views see, and that pose refined
   by ICP. With 3 or more frames, ``subject`` (route (e), :mod:`fuseflow.calib.subject`): the
   head of a person walking through the rig, tracked by depth alone; its tracks also refute any
   candidate of the pair that moves one head track from the other.
3. Verification (``verify_pose``): every candidate is scored by depth agreement between the two
   views (``fuseflow.geometry.project_votes``, visibility-aware, both directions), on all points
   and on the points off the floor (a 180-deg flip on the floor agrees on the floor), plus a
   free-space check (share of points that camera j sees through). Never by inlier count: wrong
   flips had many inliers. The best candidate above the thresholds becomes an edge.
4. Global (:mod:`fuseflow.calib.posegraph`): cycle test on the metric relative poses, maximum-
   score spanning tree, joint robust least squares on the edges' 3-D correspondences.

Deterministic and order-independent: cameras are processed in the order of their ids, every
RANSAC has a fixed seed, and the world frame is re-anchored at the first placed camera in rig
order at the end. The poses are metric (``BackboneResult.metric``): GMAC's scale is then a check.

Modules, in the order a run uses them: ``config`` (RGBDConfig), ``evidence`` (per camera,
verification), ``candidates`` (floor / sift3d / sift4 RANSAC), ``judge`` (the subject's check),
``pairs`` (one edge per pair), ``choice`` (the joint choice in repeating rooms), ``poses`` (global
placement), ``geometric_route`` (shape-only registration of the cameras left), ``backbone`` (the
entry point); ``matchers`` (image matchers) and ``ransac_kernels`` (compiled RANSAC counts). Code
outside the package imports only the names below.
"""

import importlib

#: Each public name -> the module of the package that defines it.
_HOME = {
    "ALIASED_PAIRS": "choice",
    "MATCHERS": "config",
    "SUBJECT_MARGIN_M": "judge",
    "SUBJECT_REFUTE_M": "judge",
    "CameraEvidence": "evidence",
    "PairCheck": "evidence",
    "RGBDConfig": "config",
    "get_matcher": "matchers",
    "merge_repeats": "candidates",
    "nanmedian_frames": "evidence",
    "plausible": "evidence",
    "prepare_camera": "evidence",
    "relative_error": "poses",
    "rgbd_backbone": "backbone",
    "verify_pose": "evidence",
}

__all__ = [
    "ALIASED_PAIRS",
    "MATCHERS",
    "SUBJECT_MARGIN_M",
    "SUBJECT_REFUTE_M",
    "CameraEvidence",
    "PairCheck",
    "RGBDConfig",
    "get_matcher",
    "merge_repeats",
    "nanmedian_frames",
    "plausible",
    "prepare_camera",
    "relative_error",
    "rgbd_backbone",
    "verify_pose",
]


def __getattr__(name: str):
    """A public name, imported from its module on first use (module ``__getattr__``, PEP 562)."""
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{_HOME[name]}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
