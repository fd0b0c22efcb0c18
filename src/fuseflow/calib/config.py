"""GMAC configuration: one frozen dataclass, named presets and the paper's ablation switches.

Presets (``CalibConfig.preset(name)``):

* ``"default"``: point-to-plane closed form, RC with backbone keypoint matches, cycle pruning, no
  refinement (call with ``refine=True`` or the ``"refined"`` preset to add ICP + pose graph).
* ``"paper"``: paper reproduction (section III-B as corrected by docs/design.md section 3): the
  corrected z-only closed form of eq. (12), projective RC only, CC, no refinement.
* ``"refined"``: ``"default"`` plus the point-to-plane ICP / pose-graph stage.
* ``joint_refine`` (the depth-aware joint refinement of all cameras) is on in ``"default"`` and
  ``"refined"``, off in ``"paper"`` and in the ablations, which measure the paper's method.
* Ablations of the paper's Table III: ``"wo_rc"`` (uniform random correspondences, no depth
  gating and no overlap/validity weights), ``"wo_cc"`` (no cycle pruning), ``"wo_feature"``
  (cos(F_i, F_j) = 1 in eq. (8)).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any, Literal

from fuseflow.calib.backbones.rgbd import RGBDConfig
from fuseflow.errors import ValidationError

__all__ = ["CalibConfig", "PRESETS", "ScaleSettings", "RefineSettings", "scale_settings", "refine_settings"]


@dataclass(frozen=True)
class CalibConfig:
    """All GMAC settings. Every field: meaning, default's source, valid range."""

    backbone: str = "auto"
    """Pose backbone: "auto" (``rgbd`` first, COLMAP + GMAC's scale for the cameras it leaves
    unplaced or suspect), "rgbd", "colmap", "precomputed", "vggt", "mapanything". Default "auto"
    (docs/gmac.md, Backbones); the paper and ablation presets use "colmap"."""

    backbone_path: str | None = None
    """Export file (precomputed) or local checkpoint (vggt/mapanything); unused by colmap."""

    matcher: str = "sift"
    """Image matcher of the ``rgbd`` backbone (also inside ``auto``): "sift" (default), or "xfeat",
    "aliked", "disk" with the learned-matcher packages (docs/install.md, docs/gmac-rgbd.md)."""

    closed_form: Literal["plane", "full3d", "zonly"] = "plane"
    """Scale estimator: "plane" s = sum w (n.t)(n.(Y - RX)) / sum w (n.t)^2 (default: converges
    where the point-to-point forms stall, see scale.py and docs/gmac.md), "full3d"
    s = sum w t.(Y - RX) / sum w |t|^2 (docs/design.md 3) or "zonly", the corrected eq. (12)."""

    samples_per_camera: int = 3000
    """Pixels sampled per camera on a regular grid for RC (eq. 5). Range >= 100. Default: enough
    for a scale to 0.1 % at ~3 ms per edge evaluation; more costs time linearly."""

    depth_tau: float = 0.05
    """RC depth-consistency gate |d - z| < depth_tau * z (relative, as the paper's tau of
    eq. 21). Range (0, 1). Default 5 %: ~5 sigma of Kinect-class noise at 3 m."""

    depth_tau_final: float = 0.015
    """The fixed point anneals the gate from depth_tau down to this (x0.6 per step): near-occluded
    points (a few % behind a surface of camera j) then stay out of the estimate. Range (0, 1).
    Default 1.5 %: ~3 sigma of Kinect-class noise at 3 m (0.5 %), measured on the synthetic room."""

    max_step: float = 0.1
    """Largest relative change of s per fixed-point step. Range (0, 1). Default 10 %: about one
    cell of the coarse search grid."""

    use_matches: bool = True
    """Edges with >= 5 gated backbone keypoint matches per direction (when it has them) take
    their correspondences from the matches, whose pixels do not move with s, instead of from
    reprojection (beyond the paper; see ``correspondences.match_correspondences``)."""

    global_from_matches: bool = True
    """With ``use_matches``: when at least two kept edges are match-only, the global s* is
    estimated from those edges alone; reprojection edges still take part in CC and connect
    cameras (every placed camera gets the one s*). Reprojection correspondences are biased low
    on rings (docs/gmac.md); matches are not."""

    match_rel_tol: float = 0.01
    """Floor of the robust gate on keypoint matches: a match is kept when the scale it implies is
    within max(3 robust sigmas, this relative band) of its edge's median. Range (0, 1)."""

    random_correspondences: bool = False
    """Ablation "w/o RC" (Table III): uniform random pixels of i projected into j, no depth
    gate, no overlap or validity weights, no keypoint matches."""

    feature_weight: bool = True
    """Use cos(F_i, F_j) in eq. (8); False is ablation "w/o feature weight" (Table III)."""

    robust: bool = False
    """Huber IRLS weights on the residual on top of eq. (8) (docs/design.md 3: an ablation switch)."""

    huber_delta: float = 0.02
    """Huber threshold in metres of residual for ``robust``. Range > 0. Default: ~2 sigma of
    Kinect depth noise at 3 m."""

    scale_grid: int = 96
    """Points of the coarse log-spaced 1-D scale search (docs/design.md 3). Range >= 8."""

    coarse_candidates: int = 3
    """Local maxima of the wide-gate coarse count that get a fine search at the tight gate
    (``depth_tau_final``); the best fine count wins. Range >= 1. Default: on the simulated
    studio ring the wide-gate count alone peaked at a wrong scale (docs/gmac.md)."""

    informative_cos: float = 0.25
    """The coarse search counts only samples whose surface normal has |cos| >= this with the
    edge's baseline (surfaces parallel to the baseline are consistent at every scale and bias
    the count). Range [0, 1). 0 counts every sample."""

    scale_span: float = 100.0
    """The coarse search covers [s0 / span, s0 * span], s0 from sensor depth over backbone
    baseline. Range > 1. Default: two decades either side."""

    fixed_point_tol: float = 1e-4
    """Stop the RC / closed-form alternation when |ds| / s < tol (docs/design.md 3)."""

    fixed_point_iters: int = 40
    """Cap on alternation steps (Aitken-accelerated). Range >= 1."""

    min_overlap: float = 0.05
    """overlap_ij below this drops the edge (eq. 8 gating). Range [0, 1)."""

    min_correspondences: int = 50
    """An edge needs at least this many gated correspondences. Range >= 3."""

    cycle_consistency: bool = True
    """Per-edge scales, triplet cycle residuals and pruning (docs/design.md 3); False is "w/o CC"."""

    delta_cycle: float = 0.03
    """Prune while an edge's mean relative cycle residual |c| / mean(|t|) over its triangles
    exceeds this. Range > 0. Default 3 %: ~3x the per-edge scale spread on clean edges."""

    max_pruned_fraction: float = 0.5
    """Never prune more than this share of the edges. Range (0, 1]."""

    refine: bool = False
    """Rigid refinement: point-to-plane ICP per overlapping pair + Open3D pose graph (beyond
    the paper; off in paper mode)."""

    joint_refine: bool = True
    """Depth-aware joint refinement of all placed cameras at once (:mod:`fuseflow.calib.joint_refine`:
    dense point-to-plane residuals between every overlapping pair plus the metric backbone's
    keypoint tracks, sigma(z)-weighted, Huber loss), kept only when the depth fit does not get
    measurably worse. Beyond the paper; off in the ``paper`` preset."""

    icp_voxel: float = 0.02
    """Voxel size (m) of the clouds given to ICP. Default 2 cm (Open3D's coloured-ICP recipe
    scale). > 0."""

    icp_max_distance: float = 0.04
    """ICP correspondence distance (m). Range > 0. Default 2 voxels (Open3D's coloured-ICP recipe)."""

    refine_neighbors: int = 2
    """Edges per camera given to ICP (its best by correspondence count). Range >= 1. Default: a
    connected, loop-carrying graph at ~N ICP runs instead of N(N-1)/2."""

    ill_conditioned_spread: float = 0.2
    """Warn when the coarse search's consistent-count peak (>= 95 % of max) spans more than this
    relative scale range, or when a closed form's relative standard error exceeds 1 %."""

    min_depth_agreement: float = 0.8
    """Final check (beyond the paper): a camera whose depth agrees with its neighbours' (as FUSE's
    CVGC, ``fuseflow.geometry.pair_agreement``, tau = 5 %) on less than this share is listed in
    ``suspect_cameras`` with a warning. Default 0.8 (docs/gmac.md, item 8); [0, 1], 0 = off."""

    seed: int = 0
    """Seed of every random choice (ablation sampling, pixel jitter, the rgbd backbone's RANSAC)."""

    rgbd: RGBDConfig = field(default_factory=RGBDConfig)
    """Settings of the ``rgbd`` backbone (also inside ``auto``), :class:`RGBDConfig`. Its ``matcher``
    and ``seed`` are this config's ``matcher`` and ``seed``: the values given here are replaced."""

    def __post_init__(self) -> None:
        def need(cond: bool, what: str) -> None:
            if not cond:
                raise ValidationError(f"CalibConfig: {what}")

        need(isinstance(self.rgbd, RGBDConfig), f"rgbd must be an RGBDConfig, got {type(self.rgbd).__name__}")
        if (self.rgbd.matcher, self.rgbd.seed) != (self.matcher, self.seed):
            object.__setattr__(self, "rgbd", replace(self.rgbd, matcher=self.matcher, seed=self.seed))

        need(
            self.closed_form in ("plane", "full3d", "zonly"),
            f"closed_form must be 'plane', 'full3d' or 'zonly', got {self.closed_form!r}",
        )
        need(isinstance(self.backbone, str) and bool(self.backbone), f"backbone must be a name, got {self.backbone!r}")
        need(
            self.matcher in ("sift", "xfeat", "aliked", "disk"),
            f"matcher must be 'sift', 'xfeat', 'aliked' or 'disk', got {self.matcher!r}",
        )
        need(self.samples_per_camera >= 100, f"samples_per_camera must be >= 100, got {self.samples_per_camera}")
        need(0 < self.depth_tau < 1, f"depth_tau must be in (0, 1), got {self.depth_tau}")
        need(0 < self.depth_tau_final < 1, f"depth_tau_final must be in (0, 1), got {self.depth_tau_final}")
        need(0 < self.max_step < 1, f"max_step must be in (0, 1), got {self.max_step}")
        need(0 < self.match_rel_tol < 1, f"match_rel_tol must be in (0, 1), got {self.match_rel_tol}")
        need(self.huber_delta > 0, f"huber_delta must be > 0, got {self.huber_delta}")
        need(self.scale_grid >= 8, f"scale_grid must be >= 8, got {self.scale_grid}")
        need(self.coarse_candidates >= 1, f"coarse_candidates must be >= 1, got {self.coarse_candidates}")
        need(0 <= self.informative_cos < 1, f"informative_cos must be in [0, 1), got {self.informative_cos}")
        need(self.scale_span > 1, f"scale_span must be > 1, got {self.scale_span}")
        need(0 < self.fixed_point_tol < 1, f"fixed_point_tol must be in (0, 1), got {self.fixed_point_tol}")
        need(self.fixed_point_iters >= 1, f"fixed_point_iters must be >= 1, got {self.fixed_point_iters}")
        need(0 <= self.min_overlap < 1, f"min_overlap must be in [0, 1), got {self.min_overlap}")
        need(self.min_correspondences >= 3, f"min_correspondences must be >= 3, got {self.min_correspondences}")
        need(self.delta_cycle > 0, f"delta_cycle must be > 0, got {self.delta_cycle}")
        need(
            0 < self.max_pruned_fraction <= 1, f"max_pruned_fraction must be in (0, 1], got {self.max_pruned_fraction}"
        )
        need(self.icp_voxel > 0 and self.icp_max_distance > 0, "icp_voxel and icp_max_distance must be > 0")
        need(self.refine_neighbors >= 1, f"refine_neighbors must be >= 1, got {self.refine_neighbors}")
        need(self.ill_conditioned_spread > 0, "ill_conditioned_spread must be > 0")
        need(
            0 <= self.min_depth_agreement <= 1, f"min_depth_agreement must be in [0, 1], got {self.min_depth_agreement}"
        )

    def as_dict(self) -> dict:
        """The fields as a dict (calib.json's ``report.config``), ``rgbd`` only when it differs from
        ``RGBDConfig``'s defaults (other than ``matcher`` and ``seed``, which are this config's)."""
        out = asdict(self)
        if self.rgbd == RGBDConfig(matcher=self.matcher, seed=self.seed):
            del out["rgbd"]
        return out

    @staticmethod
    def preset(name: str, **overrides) -> CalibConfig:
        """A named preset (see the module docstring), with field overrides."""
        if name not in PRESETS:
            raise ValidationError(f"unknown GMAC preset {name!r}; choose one of {sorted(PRESETS)}")
        known = {f.name for f in fields(CalibConfig)}
        bad = sorted(set(overrides) - known)
        if bad:
            raise ValidationError(f"unknown CalibConfig fields {bad}")
        return replace(PRESETS[name], **overrides)


PRESETS: dict[str, CalibConfig] = {
    "default": CalibConfig(),
    "paper": CalibConfig(backbone="colmap", closed_form="zonly", use_matches=False, refine=False, joint_refine=False),
    "refined": CalibConfig(refine=True),
    "wo_rc": CalibConfig(backbone="colmap", random_correspondences=True, joint_refine=False),
    "wo_cc": CalibConfig(backbone="colmap", cycle_consistency=False, joint_refine=False),
    "wo_feature": CalibConfig(backbone="colmap", feature_weight=False, joint_refine=False),
    "zonly": CalibConfig(backbone="colmap", closed_form="zonly", joint_refine=False),
    "full3d": CalibConfig(backbone="colmap", closed_form="full3d", joint_refine=False),
    "robust": CalibConfig(backbone="colmap", robust=True, joint_refine=False),
}


@dataclass(frozen=True)
class ScaleSettings:
    """What the scale stage (``calib.scale_stage``) and the correspondences it builds
    (``calib.correspondences``) read: the :class:`CalibConfig` fields of the same names (their
    meaning and ranges are there), built once by ``scale_settings``."""

    closed_form: Literal["plane", "full3d", "zonly"]
    depth_tau: float
    depth_tau_final: float
    max_step: float
    use_matches: bool
    global_from_matches: bool
    match_rel_tol: float
    random_correspondences: bool
    feature_weight: bool
    robust: bool
    huber_delta: float
    scale_grid: int
    coarse_candidates: int
    informative_cos: float
    scale_span: float
    fixed_point_tol: float
    fixed_point_iters: int
    min_overlap: float
    min_correspondences: int
    cycle_consistency: bool
    delta_cycle: float
    max_pruned_fraction: float
    ill_conditioned_spread: float


@dataclass(frozen=True)
class RefineSettings:
    """What the ICP / pose-graph refinement (``calib.refine``) reads: the :class:`CalibConfig`
    fields of the same names, built once by ``refine_settings``."""

    icp_voxel: float
    icp_max_distance: float
    refine_neighbors: int


def _settings(cls: type, config: Any) -> Any:
    """``cls`` from the fields of the same names of ``config`` (a :class:`CalibConfig`), or
    ``config`` itself when it already is one."""
    if isinstance(config, cls):
        return config
    return cls(**{f.name: getattr(config, f.name) for f in fields(cls)})


def scale_settings(config: CalibConfig | ScaleSettings) -> ScaleSettings:
    """The scale stage's settings of ``config``."""
    return _settings(ScaleSettings, config)


def refine_settings(config: CalibConfig | RefineSettings) -> RefineSettings:
    """The refinement's settings of ``config``."""
    return _settings(RefineSettings, config)
