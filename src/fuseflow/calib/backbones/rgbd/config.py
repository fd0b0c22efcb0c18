"""Settings of the rgbd backbone (``RGBDConfig``); ``CalibConfig.rgbd`` holds one."""

from __future__ import annotations

from dataclasses import dataclass, fields

from fuseflow.errors import ValidationError

MATCHERS = ("sift", "xfeat", "aliked", "disk")
"""Names accepted by ``get_matcher`` (``RGBDConfig.matcher``, ``fuseflow calibrate --matcher``)."""


@dataclass(frozen=True)
class RGBDConfig:
    """Settings of the metric RGB-D backbone. Every field: meaning, default's source, range."""

    seed: int = 0
    """Seed of every RANSAC (deterministic results). Any int."""

    sift_features: int = 3000
    """SIFT keypoints per image (OpenCV). >= 100. Default: ~0.1 s per 640x480 image on one core."""

    ratio: float = 0.8
    """Lowe ratio test for SIFT matches. (0, 1). Default: Lowe's 0.8; verification, not the
    ratio, guards against wrong matches."""

    floor_res: float = 0.005
    """Top-down floor image resolution, metres per pixel. Default 5 mm: about one camera pixel
    at 3 m for a 530 px focal length (notes/wide-baseline-calibration.md)."""

    floor_band: float = 0.02
    """Plane-fit inlier band, metres. Default: ~3 sigma of Kinect-class depth noise at 2.5 m."""

    floor_max_range: float = 6.0
    """Floor farther than this from a camera is not rendered, metres. Default: beyond the
    Kinect/RealSense working range (4.5 m) with margin."""

    floor_inlier_m: float = 0.03
    """4-DoF RANSAC inlier distance on the floor, metres (6 top-down pixels at 5 mm)."""

    inlier_m: float = 0.03
    """6-DoF 3-D RANSAC inlier distance at 0 m; grows by ``inlier_rel`` * depth. Default: ~3
    sigma of a SIFT keypoint lifted by Kinect-class depth at 2 m."""

    inlier_rel: float = 0.01
    """Depth-proportional part of the 3-D inlier distance (per metre of depth)."""

    ransac_iterations: int = 2000
    """Hypotheses per RANSAC run. Default: >99 % success at 20 % inliers for the 3-point model."""

    hypotheses: int = 3
    """Candidate poses per route and pair (sequential RANSAC: the best, then the best of the
    remaining matches, ...). Default 3: a correct pose hidden behind a wrong, larger consensus
    (the ring's symmetry) still reaches the verification."""

    min_inliers: int = 4
    """Fewest RANSAC inliers for a candidate. Default 4 (floor pairs with 3-12 correct inliers
    were seen); the verification decides, not this count."""

    samples: int = 5000
    """Depth pixels per camera used for verification (regular grid). Default: as
    ``fuseflow.geometry.pair_agreement``."""

    tau: float = 0.05
    """Relative depth residual under which two views agree (the paper's tau, eq. 21)."""

    min_agreement: float = 0.8
    """Fewest share of agreeing votes (both directions, all points) for an edge. (0, 1).
    Default: measured separation (benchmarks/calib_wide.py, -v dumps): right candidates
    0.92-0.99 on simulated rings and on hocap-8rs (its reference extrinsics: 0.94), wrong ones
    0.11-0.86."""

    min_structure_agreement: float = 0.7
    """Same, on points off the floor (walls, furniture, people). Floor-aligned flips agree on
    the floor but not here: measured right 0.77-0.99, wrong 0.06-0.57 (one 4-deg-off pose 0.94,
    caught by the free-space test)."""

    max_free_space: float = 0.08
    """Largest share of projected points that the other camera sees through (free-space
    violations over points with depth there). Measured right 0.006-0.056, wrong 0.12-0.79."""

    min_agree_points: int = 150
    """Fewest agreeing samples (both directions): a pose verified by a sliver of overlap is no
    evidence."""

    min_structure_votes: int = 100
    """Fewest votes on off-floor points; fewer: the pair cannot be told from a flip, no edge."""

    cycle_rot_deg: float = 2.0
    """Cycle test: largest rotation of a triangle's composed transform, degrees."""

    cycle_trans_m: float = 0.08
    """Cycle test: largest translation of a triangle's composed transform, metres."""

    sigma0: float = 0.005
    """Noise of a 3-D correspondence at 0 m, metres (keypoint localisation)."""

    sigma2: float = 0.0015
    """Depth-squared part of the correspondence noise, metres per m^2 (Kinect-class axial noise
    grows with z^2)."""

    refine: bool = True
    """Joint robust refinement of all cameras on the edges' correspondences (posegraph)."""

    matcher: str = "sift"
    """Image matcher of the ``sift3d`` / ``sift4`` routes (:mod:`fuseflow.calib.backbones.rgbd.matchers`): "sift",
    or "xfeat", "aliked", "disk" with ``fuseflow[matchers]``. The floor route always uses SIFT
    (rotation-invariant; the top-down views differ by any yaw). Default SIFT: XFeat placed no more
    cameras right on 3-4 camera rings (no right pair of its own; SIFT 3 of 54), put hocap-8rs
    1.8 deg off where SIFT is 0.6 (ALIKED, DISK: 2.2), and costs 2-3x the time (docs/gmac-rgbd.md, "Learned matchers")."""

    geometric: bool = True
    """Route (c), geometry only (:mod:`fuseflow.calib.geometric`): for cameras the other routes
    leave unplaced, FPFH + RANSAC + ICP candidates against every other camera, proposed only
    from a wide basin of convergence and verified like every candidate. Default on: it runs
    only where a camera is left unplaced, so rigs the other routes place pay nothing; on
    hocap-8rs it places the two cameras that look up through the ceiling rig
    (docs/gmac-rgbd.md)."""

    geometric_voxel: float = 0.02
    """Voxel of the geometry route's clouds, metres (FPFH radius 5 voxels = 10 cm)."""

    geometric_starts: int = 20
    """Distinct RANSAC hypotheses refined by ICP per pair in the geometry route."""

    geometric_min_starts: int = 3
    """Fewest ICP starts that must converge to a pose for the geometry route to propose it
    (and twice as many as to any other pose that passes the verification). Measured on
    hocap-8rs, 30 starts: right poses 7-28, wrong ones 1-4 (``calib.geometric`` docstring)."""

    geometric_edges_per_camera: int = 1
    """Route (c) candidates an unplaced camera gets per round, at most: its pairs with a placed
    camera are tried in order of descriptor consensus (the best FPFH-RANSAC hypothesis's
    inliers: it orders the work, never accepts a pose) until this many are proposed. The ICP
    stage is ~1.2 s a pair; on hocap-8rs each up-looking camera has 6 such pairs, one gives a
    candidate, and it ranks first (48 and 36 inliers against 5-30). Default 1: the rgbd backbone
    on hocap-8rs takes ~17 s instead of 28 s with every pair tried, with the same edges; the cost,
    a camera held by one route (c) edge closes no cycle with it (it is flagged as unchecked). A
    number >= the cameras tries every pair."""
    people: bool = False
    """Route (d), person keypoints (:mod:`fuseflow.calib.people`): each pair also gets the
    person's keypoint pose and its depth refinement as candidates. Off by default: on the
    simulated far-range 3-camera rig its poses were 10-19 cm off yet passed depth verification
    (docs/gmac-trust.md, "Person route"). Needs the ``people`` extra (mediapipe); where it is missing
    ``info["people"]`` says it was skipped and why."""

    subject: bool = True
    """Route (e), the moving subject (:mod:`fuseflow.calib.subject`): with 3 or more frames, the
    head of a person walking through the rig, tracked in every camera without a detector, gives
    each pair a candidate and judges every candidate of the pair (a pose that moves one head
    track away from the other is refuted). Steps aside without frames or a moving person."""

    spheres: bool = True
    """Route (f), moving spheres (:mod:`fuseflow.calib.backbones.rgbd.spheres`): with 5 or more
    frames, a ball (or any round moving object) tracked by sphere fits in every camera gives each
    pair candidates. Steps aside without frames or a moving sphere."""

    min_separation: float = 0.2
    """Physical plausibility: a relative pose that puts the two camera centres closer than this
    (metres) is rejected, not scored, unless the two views are nearly the same (agreement >=
    ``SAME_VIEW_AGREEMENT`` everywhere and off the floor). A device is ~10 cm wide; in a room
    that repeats, the aliases that stack one camera on another land within the rig's placement
    tolerance of it (measured 0.05-0.14 m on the simulated symmetric studio, 2-5 cm on a real
    dome) and agree better than the true pose (:mod:`fuseflow.calib.symmetry`)."""

    pair_hypotheses: int = 3
    """Verified, mutually distinct poses kept per pair for the joint choice
    (:func:`fuseflow.calib.symmetry.select_consistent`). 1 = the best only (no joint choice)."""

    ambiguity_ratio: float = 0.8
    """A camera held only by edges on no cycle is ambiguous (left unplaced, with the reason) when
    one of its pairs has another passing hypothesis scoring at least this share of the chosen
    one: nothing tells the two apart. (0, 1)."""

    def __post_init__(self) -> None:
        if self.matcher not in MATCHERS:
            raise ValidationError(f"RGBDConfig.matcher must be one of {', '.join(MATCHERS)}, got {self.matcher!r}")
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or f.name in ("seed", "matcher"):
                continue
            if not isinstance(v, (int, float)) or v <= 0:
                raise ValidationError(f"RGBDConfig.{f.name} must be a positive number, got {v!r}")
        for name in ("ratio", "tau", "min_agreement", "min_structure_agreement", "max_free_space", "ambiguity_ratio"):
            if not 0 < getattr(self, name) < 1:
                raise ValidationError(f"RGBDConfig.{name} must be in (0, 1), got {getattr(self, name)!r}")
