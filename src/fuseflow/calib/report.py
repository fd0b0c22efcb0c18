"""``CalibReport``: what one GMAC run did and measured (the ``report`` of its ``Calibration``).

Cameras and edges are named by camera id ("cam00", edge "cam00-cam03", triangle
"cam00-cam03-cam05"), scales are metres per backbone unit, and every value is plain JSON data,
so ``to_json()`` is exactly the ``"report"`` object of calib.json and ``from_json`` reads it back.
``finish_report`` builds it from the placement engine's record (``calib.placement.Placement``).

Read access by key (``report["scale"]``, ``report.get("warnings", [])``, ``"scale" in report``)
is kept for code written against the dict report of earlier releases; it is deprecated in favour
of the attributes (``report.scale``) and will be removed after one release.
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Mapping
from dataclasses import MISSING, dataclass, field, fields
from typing import Any

import numpy as np

from fuseflow.errors import ValidationError

__all__ = ["CalibReport", "finish_report", "build_report"]


@dataclass(eq=False)
class CalibReport(Mapping[str, Any]):
    """The GMAC report. One attribute per key of calib.json's ``"report"`` object, in its order."""

    method: str
    """Always "GMAC"."""
    backbone: str
    """Name of the backbone that gave the scale-ambiguous poses ("colmap", "precomputed:vggt", ...)."""
    backbone_info: dict[str, Any]
    """The backbone's own notes: mode, keypoints per camera, timings (JSON data, backbone-specific)."""
    config: dict[str, Any]
    """The :class:`~fuseflow.calib.config.CalibConfig` used, as a dict of its fields (``CalibConfig.as_dict``)."""
    scale: float
    """s*: the global metric scale, metres per backbone unit (eq. 14: T_i = [R_i | s* t_i])."""
    scale_before_pruning: float
    """The fixed point over all usable edges, before CC pruned any (= ``scale`` when none was)."""
    scale_coarse: float
    """The coarse 1-D search's scale, where the fixed point started."""
    scale_naive_median_depth_ratio: float | None
    """Baseline: median sensor depth / backbone depth at the backbone's points; None without them."""
    scale_std_error: float
    """Standard error of s* from the closed form's residuals, same unit as ``scale``."""
    closed_form: str
    """The closed form used: "plane", "full3d" or "zonly"."""
    fixed_point: dict[str, Any]
    """The global fixed point: {"iterations": int, "converged": bool}."""
    coarse_peak_spread: float
    """Relative width of the coarse search's peak (>= 95 % of its max count); wide = ill-conditioned."""
    edge_scales: dict[str, float]
    """Edge "a-b" -> that edge's own scale (what CC compares)."""
    correspondence_counts: dict[str, int]
    """Edge "a-b" -> correspondences behind its scale."""
    edges: list[str]
    """Edges with enough measured overlap at the coarse scale (candidates for CC)."""
    kept_edges: list[str]
    """Edges CC kept (all usable edges when CC is off); they decide which cameras are placed."""
    scale_edges: list[str]
    """The kept edges whose correspondences gave s* (match-only edges with ``global_from_matches``)."""
    pruned_edges: list[str]
    """Edges CC removed, in pruning order."""
    cycle_mode: str
    """"cycles", "median" (no triangle), "single" (one edge) or "off"."""
    cycle_residuals_relative: dict[str, float]
    """Triangle "a-b-c" -> |cycle translation| / mean edge length, after pruning."""
    cycle_residuals_relative_before_pruning: dict[str, float]
    """The same before pruning."""
    cycle_residuals_mm: dict[str, float]
    """Triangle "a-b-c" -> cycle residual in mm at s*, after pruning."""
    unconnected_cameras: list[str]
    """Cameras on no kept edge: not placed."""
    unregistered_cameras: list[str]
    """Cameras the backbone could not place: not placed."""
    depth_agreement: dict[str, float | None]
    """Camera -> mean share of its depth its neighbours confirm under the calibrated extrinsics
    (``fuseflow.geometry.depth_agreement``); None without a neighbour. Empty when the check is off."""
    suspect_cameras: list[str]
    """Cameras whose depth agreement is below ``min_depth_agreement`` (pose probably wrong)."""
    warnings: list[str]
    """Human-readable warnings, cameras and edges named by id."""
    ill_conditioned: bool
    """True when a warning says the scale is ill-conditioned."""
    refinement: dict[str, Any] | None
    """The refinement stage's diagnostics (``RefineResult`` without the poses), None when off."""
    timings_s: dict[str, float]
    """Wall-clock seconds per stage: "backbone", "scale", "refine" (when on), "total"."""
    world_anchor: str | None = None
    """The camera whose frame is the world (its extrinsic is the identity): the first placed
    camera in rig order (``posegraph.anchor_world``). None in reports written before it existed."""
    scale_check: float | None = None
    """Metric backbones (``rgbd``): GMAC's closed-form s* on their poses, a check (``scale`` is
    then 1; a warning when this is more than ``METRIC_SCALE_TOLERANCE`` (15 %) from 1). None for scale-free backbones, when the
    check could not run, and in reports written before it existed."""
    placed_by: dict[str, str] = field(default_factory=dict)
    """Camera -> the backbone whose pose placed it ("colmap", "rgbd", ...; with ``auto`` the
    source with the better depth agreement). Empty in reports written before it existed."""
    unplaced_reasons: dict[str, str] = field(default_factory=dict)
    """``auto``: camera -> why no source placed it (e.g. depth agreement below the threshold
    under every source). Empty otherwise and in reports written before it existed."""
    joint_refinement: dict[str, Any] | None = None
    """The depth-aware joint refinement (:mod:`fuseflow.calib.joint_refine`): whether it was kept
    and why not, iterations, overlapping pairs, per camera the share of samples within 1 cm of
    its neighbours' surfaces before / after and how far it moved (deg, mm). None when off and in
    reports written before it existed."""
    pair_agreement: dict[str, float] = field(default_factory=dict)
    """Edge "a-b" -> share of the pair's overlapping depth that agrees under the calibrated
    extrinsics (tau 5 %; :func:`fuseflow.calib.verdicts.pair_agreements`); pairs without overlap
    are absent. Empty in reports written before it existed."""
    camera_verdicts: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Camera -> {"verdict": "good" | "check it" | "ambiguous" | "unplaced", "reason", "placed_by",
    "routes", "pairs", "pairs_agreeing", "cycles", "floor", "floor_ok", "checks", "depth_agreement",
    "accuracy_deg", "accuracy_mm" (the printed bound), "estimate_deg", "estimate_mm" (what the verdict
    judges), "accuracy_from", "disagreeing", "turn"}
    (:func:`fuseflow.calib.verdicts.camera_verdicts` says how each is measured). Empty in reports
    written before it existed."""
    reference: dict[str, Any] | None = None
    """``calibrate --reference``: the per-camera differences to a reference calibration after
    aligning the two worlds (:func:`fuseflow.calib.reference.compare_to_reference`). None otherwise."""
    room: dict[str, Any] | None = None
    """The repeating room of the calibrated cloud (:mod:`fuseflow.calib.turns`): {"sides", "point",
    "up", "share"}, None when the room does not repeat."""

    # -- JSON -----------------------------------------------------------------------------------

    def to_json(self) -> dict[str, Any]:
        """The report as calib.json stores it: a dict with one key per attribute, in order.

        The values are this report's own objects (not copies); serialise, do not mutate.
        """
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> CalibReport:
        """The report from calib.json's ``"report"`` object (a dict as ``to_json`` gives).

        Raises:
            ValidationError: ``d`` is not a mapping, or lacks keys / has keys a GMAC report does not.
        """
        if not isinstance(d, Mapping):
            raise ValidationError(f"a GMAC report must be a JSON object, got {type(d).__name__}")
        names = [f.name for f in fields(cls)]
        optional = {f.name for f in fields(cls) if f.default is not MISSING or f.default_factory is not MISSING}
        missing = [k for k in names if k not in d and k not in optional]
        unknown = sorted(set(d) - set(names))
        if missing or unknown:
            raise ValidationError(f"not a GMAC report: missing keys {missing}, unknown keys {unknown}")
        return cls(**{k: d[k] for k in names if k in d})

    # -- deprecated read access by key (the dict report of earlier releases) ---------------------

    def __getitem__(self, key: str) -> Any:
        if not isinstance(key, str) or key not in self._keys():
            raise KeyError(key)
        return getattr(self, key)

    def __iter__(self) -> Iterator[str]:
        return iter(self._keys())

    def __len__(self) -> int:
        return len(fields(self))

    def __eq__(self, other: object) -> bool:
        if isinstance(other, CalibReport):
            return self.to_json() == other.to_json()
        if isinstance(other, Mapping):
            return self.to_json() == dict(other)
        return NotImplemented

    __hash__ = None  # type: ignore[assignment]  # mutable, like the dict it replaces

    @classmethod
    def _keys(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))


def finish_report(
    pl, ids: tuple[str, ...], settings: dict[str, Any], closed_form: str, min_agreement: float
) -> CalibReport:
    """The report of a placement (``calib.placement.Placement``), cameras named by id (frame order
    ``ids``). ``settings``: ``CalibConfig.as_dict()``; ``closed_form`` and ``min_agreement`` (the
    depth agreement below which a camera is suspect) are that config's values."""
    report = build_report(
        ids, pl.bb, pl.sr, settings, closed_form, min_agreement, pl.connected, pl.agreement, pl.refinement, pl.timings
    )
    report.world_anchor = pl.anchor
    report.scale_check = pl.scale_check
    report.warnings = pl.warnings + report.warnings
    report.placed_by = pl.placed_by if pl.placed_by is not None else dict.fromkeys(pl.T, pl.bb.name)
    report.unplaced_reasons = pl.unplaced_reasons or {}
    report.joint_refinement = pl.joint_refinement
    return report


def build_report(
    ids: tuple[str, ...],
    bb,
    sr,
    settings: dict[str, Any],
    closed_form: str,
    min_agreement: float,
    connected: list[int],
    agreement: dict[str, float | None],
    refinement: dict[str, Any] | None,
    timings: dict[str, float],
) -> CalibReport:
    """The report of one run (``bb``: the ``BackboneResult``, ``sr``: the scale stage's
    ``ScaleResult``), cameras and edges named by id (camera index k -> ``ids[k]``)."""
    suspect = [c for c, a in agreement.items() if a is not None and a < min_agreement]
    unconnected = [ids[k] for k in range(len(ids)) if k not in connected]
    unregistered = [ids[k] for k in np.flatnonzero(~bb.registered)]
    name = lambda e: f"{ids[e[0]]}-{ids[e[1]]}"  # noqa: E731
    return CalibReport(
        method="GMAC",
        backbone=bb.name,
        backbone_info=bb.info,
        config=settings,
        scale=sr.s,
        scale_before_pruning=sr.s_initial,
        scale_coarse=sr.s_coarse,
        scale_naive_median_depth_ratio=sr.s_naive,
        scale_std_error=sr.std_error,
        closed_form=closed_form,
        fixed_point={"iterations": sr.iterations, "converged": sr.converged},
        coarse_peak_spread=sr.peak_spread,
        edge_scales={name(e): v for e, v in sr.edge_scales.items()},
        correspondence_counts={name(e): v for e, v in sr.edge_counts.items()},
        edges=[name(e) for e in sr.edges],
        kept_edges=[name(e) for e in sr.kept],
        scale_edges=[name(e) for e in sr.scale_edges],
        pruned_edges=[name(e) for e in sr.pruned],
        cycle_mode=sr.cycle_mode,
        cycle_residuals_relative=_rename(sr.cycle_residuals, ids),
        cycle_residuals_relative_before_pruning=_rename(sr.cycle_residuals_before, ids),
        cycle_residuals_mm=_rename(sr.cycle_residuals_mm, ids),
        unconnected_cameras=unconnected,
        unregistered_cameras=unregistered,
        depth_agreement=agreement,
        suspect_cameras=suspect,
        warnings=[edge_names(w, ids) for w in sr.warnings]
        + _placement_warnings(unconnected, unregistered)
        + _agreement_warnings(suspect, agreement, min_agreement),
        ill_conditioned=any("ill-conditioned" in w for w in sr.warnings),
        refinement=refinement,
        timings_s=timings,
    )


def _agreement_warnings(suspect: list[str], agreement: dict[str, float | None], limit: float) -> list[str]:
    if not suspect:
        return []
    vals = ", ".join(f"{c} {agreement[c]:.2f}" for c in suspect)
    return [
        f"cameras {suspect} disagree with their neighbours' depth under these extrinsics ({vals}; below "
        f"{limit:.2f}): the backbone's poses are probably wrong (wrong matches between similar views); "
        "check the images for overlap and texture, or calibrate on another frame (--frame)"
    ]


def edge_names(text: str, ids) -> str:
    """The scale stage's warnings name edges by index, "(0, 4)"; users know camera ids."""
    return re.sub(r"\((\d+), (\d+)\)", lambda m: f"{ids[int(m[1])]}-{ids[int(m[2])]}", text)


def _placement_warnings(unconnected: list[str], unregistered: list[str]) -> list[str]:
    out = []
    if unregistered:
        out.append(f"the backbone could not register cameras {unregistered}; they are not placed")
    rest = [c for c in unconnected if c not in unregistered]
    if rest:
        out.append(f"cameras {rest} share no usable depth overlap with the others and are not placed")
    return out


def _rename(d: dict[str, float], ids) -> dict[str, float]:
    return {"-".join(ids[int(x)] for x in k.split("-")): v for k, v in d.items()}
