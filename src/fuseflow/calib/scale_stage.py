"""GMAC's scale stage: one metric scale s* for the backbone's translations (paper eq. 5-13).

``metric_scale(bb, cams, settings) -> ScaleResult`` in named steps:

1. ``scale_search_centre``: s0 = median sensor depth / median backbone baseline.
2. ``candidate_edges``: every registered pair, both directions, with eq. (8)'s edge weight.
3. ``coarse_scale_search`` over all of them: a log-spaced 1-D search that maximises the count
   of depth-consistent reprojections (robust start, no closed form).
4. ``gate_edges``: keep pairs whose measured overlap at the coarse scale reaches ``min_overlap``.
5. ``per_edge_scales``: each kept edge's own fixed point (for the cycle check).
6. ``prune_edges``: triangle cycle residuals and pruning (eq. 13, :mod:`cycles`).
7. ``global_scale``: the fixed point over the edges CC kept (match-only ones when enough).
8. warnings on conditioning, and the naive median depth-ratio baseline for the report.

The pixel a reprojection correspondence lands on depends on s, so (docs/design.md 3) s is found by
alternating the two halves of the stage: the correspondences at a scale
(:mod:`fuseflow.calib.correspondences`, eq. 5, 8, 11) and the closed form on them
(:mod:`fuseflow.calib.scale`, eq. 9-12). ``fixed_point_scale`` alternates them from the coarse
start until |ds| / s < tol (annealed depth gate, clamped, Aitken-accelerated). Every fixed point
uses the same step function (:data:`StepFunction` ``step(geoms, cams, s, settings) ->
(ScaleEstimate, correspondences)``, default :func:`rc_step`; callers may pass their own, e.g. one
that perturbs the correspondences, to measure how the stage copes with a wrong edge).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from fuseflow.calib.backbones import BackboneResult
from fuseflow.calib.config import ScaleSettings, scale_settings
from fuseflow.calib.correspondences import (
    CameraData,
    EdgeGeometry,
    build_correspondences,
    edge_geometry,
    match_lookup,
    match_only,
)
from fuseflow.calib.cycles import prune_by_cycles
from fuseflow.calib.errors import CalibrationError
from fuseflow.calib.scale import (
    Correspondences,
    ScaleEstimate,
    closed_form_scale,
    huber_weights,
    naive_median_scale,
    residuals,
)
from fuseflow.calib.verdicts import SCALE_CHECK_WARNING
from fuseflow.types import invert_rigid

if TYPE_CHECKING:  # the public entry point also takes a whole CalibConfig
    from fuseflow.calib.config import CalibConfig

__all__ = [
    "ScaleResult",
    "metric_scale",
    "placement_scale",
    "METRIC_SCALE_TOLERANCE",
    "CoarseSearch",
    "FixedPointResult",
    "StepFunction",
    "coarse_scale_search",
    "final_gate",
    "fixed_point_scale",
    "one_step_scale",
    "rc_step",
    "scale_search_centre",
    "candidate_edges",
    "gate_edges",
    "per_edge_scales",
    "naive_scale",
    "edge_weight",
    "informative_mask",
    "consistent_count",
    "consistent_counts",
]

Edge = tuple[int, int]

#: One alternation of the fixed point: ``step(geoms, cams, s, settings) -> (estimate, corrs)``:
#: the correspondences of the directed edges ``geoms`` at scale s (metres per backbone unit)
#: under ``settings`` (its ``depth_tau`` is the current gate), and the closed-form scale on them.
StepFunction = Callable[
    [Sequence[EdgeGeometry], Sequence[CameraData], float, ScaleSettings],
    tuple[ScaleEstimate, list[Correspondences]],
]


@dataclass(frozen=True)
class CoarseSearch:
    """Result of the coarse 1-D scale search.

    Attributes:
        s: best grid scale. grid: (G,) scales. counts: (G,) consistent reprojections.
        peak_spread: relative width (max/min - 1) of the grid scales with count >= 95 % of max:
            a wide peak means the scene does not pin the scale (ill-conditioned).
    """

    s: float
    grid: np.ndarray
    counts: np.ndarray
    peak_spread: float


def coarse_scale_search(
    geoms: Sequence[EdgeGeometry],
    cams: Sequence[CameraData],
    s0: float,
    settings: ScaleSettings,
    extra: Sequence[float] = (),
) -> CoarseSearch:
    """Maximise the count of depth-consistent reprojections over s0 * [1/span, span] (log grid),
    then over finer grids around the best candidates (docs/design.md 3).

    Two things make the plain count biased on a camera ring (measured on the simulated studio,
    true poses: the count peaked 5 % low, the noise-free render 70 % high): points on surfaces
    parallel to the baselines (floor, ceiling) are consistent at every scale, and the share of
    the scene two cameras both see grows as the ring shrinks. So only informative samples
    (``informative_mask``, |cos(n, t)| >= ``informative_cos``) are counted, the wide gate
    ``depth_tau`` only proposes candidates (the ``coarse_candidates`` best local maxima of the
    log grid, plus ``extra`` scales, e.g. from keypoint matches), and the winner is the
    candidate whose fine grid (one coarse step either side) reaches the highest count at the
    tight gate ``depth_tau_final``, which is sharp at the true scale.
    """
    if not geoms:
        raise CalibrationError("no camera pairs to search the scale over")
    masks = [informative_mask(g, cams[g.i], settings.informative_cos) for g in geoms]

    def counts(grid: np.ndarray, tau: float) -> np.ndarray:
        out = np.zeros(len(grid), dtype=np.int64)
        for g, m in zip(geoms, masks):
            out += consistent_counts(g, cams[g.i], cams[g.j], grid, tau, m)
        return out

    grid = s0 * np.logspace(-np.log10(settings.scale_span), np.log10(settings.scale_span), settings.scale_grid)
    c = counts(grid, settings.depth_tau)
    if c.max() == 0:
        raise CalibrationError(
            "no scale in the search range makes any reprojection depth-consistent: the cameras do "
            "not overlap, or the backbone poses are wrong"
        )
    step = grid[1] / grid[0]
    near_max = grid[c >= 0.95 * c.max()]
    spread = float(near_max.max() / near_max.min() - 1.0)
    # candidates: local maxima of the wide-gate count, best first
    padded = np.concatenate([[-1], c, [-1]])
    peaks = [k for k in range(len(c)) if c[k] > 0 and padded[k + 1] >= padded[k] and padded[k + 1] >= padded[k + 2]]
    peaks = sorted(peaks, key=lambda k: -c[k])[: settings.coarse_candidates]
    cands = [float(grid[k]) for k in peaks] + [float(x) for x in extra if np.isfinite(x) and x > 0]
    tau_fine = min(settings.depth_tau_final, settings.depth_tau)
    best_s, best_c = cands[0], -1
    all_s, all_c = [grid], [c]
    for sc in cands:
        fine = sc * np.exp(np.linspace(-np.log(step), np.log(step), 41))
        cf = counts(fine, tau_fine)
        k = int(np.argmax(cf))
        if cf[k] > best_c:
            best_s, best_c = float(fine[k]), int(cf[k])
        all_s.append(fine)
        all_c.append(cf)
    s_all, c_all = np.concatenate(all_s), np.concatenate(all_c)
    order = np.argsort(s_all)
    return CoarseSearch(best_s, s_all[order], c_all[order], spread)


@dataclass(frozen=True)
class FixedPointResult:
    """The RC / closed-form alternation.

    Attributes:
        s: the converged scale. estimate: the closed form at the final correspondences.
        iterations: correspondence rebuilds. converged: |ds| / s < tol reached.
        history: scales visited. correspondences: the final per-edge sets.
    """

    s: float
    estimate: ScaleEstimate
    iterations: int
    converged: bool
    history: tuple[float, ...]
    correspondences: tuple[Correspondences, ...] = field(repr=False, default=())


def rc_step(
    geoms: Sequence[EdgeGeometry], cams: Sequence[CameraData], s: float, settings: ScaleSettings
) -> tuple[ScaleEstimate, list[Correspondences]]:
    """GMAC's fixed-point step (a :data:`StepFunction`): RC correspondences of every directed
    edge in ``geoms`` at scale s (Huber-reweighted when ``settings.robust``), and the
    ``settings.closed_form`` scale on all of them together.

    Args:
        geoms: directed edges i -> j (backbone relative poses, unit scale).
        cams: per-camera RC data, indexed by camera index (rig order).
        s: current scale, metres per backbone unit (> 0).
        settings: settings; ``depth_tau`` is the depth gate of this step.
    """
    corrs = [build_correspondences(g, cams[g.i], cams[g.j], s, settings) for g in geoms]
    if settings.robust:
        corrs = [
            c.reweighted(c.w * huber_weights(residuals(c, s, settings.closed_form), settings.huber_delta))
            for c in corrs
        ]
    return closed_form_scale(corrs, settings.closed_form), corrs


def final_gate(settings: ScaleSettings) -> ScaleSettings:
    """``settings`` with the depth gate at the fixed point's final value, min(depth_tau_final, depth_tau)."""
    return replace(settings, depth_tau=min(settings.depth_tau_final, settings.depth_tau))


def one_step_scale(
    geoms: Sequence[EdgeGeometry],
    cams: Sequence[CameraData],
    s: float,
    settings: ScaleSettings,
    step: StepFunction | None = None,
) -> tuple[ScaleEstimate, list[Correspondences]]:
    """The closed form on the correspondences at a fixed s, at the final gate (the paper's
    fixed-correspondence approximation: no iteration). Raises CalibrationError like ``step``."""
    return (step or rc_step)(geoms, cams, s, final_gate(settings))


def fixed_point_scale(
    geoms: Sequence[EdgeGeometry],
    cams: Sequence[CameraData],
    s0: float,
    settings: ScaleSettings,
    step: StepFunction | None = None,
) -> FixedPointResult:
    """Alternate RC correspondences and the closed form from s0 until |ds| / s < tol.

    The depth gate is annealed from ``depth_tau`` down to ``depth_tau_final`` (x0.6 per step):
    a wide gate lets a poor start find the right surfaces, a tight one keeps near-occluded points
    (behind a surface a few % closer in camera j) out of the final estimate. Convergence is only
    declared at the final gate. Steps are clamped to +-``max_step`` relative; Aitken's
    extrapolation is tried every second step at the final gate (the map s -> s* is close to
    affine there) and kept only when it stays inside the clamp.

    Args:
        geoms: directed edges whose correspondences enter the (one, shared) closed form.
        cams: per-camera RC data, indexed by camera index. s0: start, metres per backbone unit.
        step: one alternation (default :func:`rc_step`); see :data:`StepFunction`.
    """
    step = step or rc_step
    tol = settings.fixed_point_tol
    tau_final = min(settings.depth_tau_final, settings.depth_tau)
    s = float(s0)
    hist = [s]
    k = 0
    converged = False
    prev: float | None = None
    est = corrs = None
    while k < settings.fixed_point_iters:
        tau = max(tau_final, settings.depth_tau * 0.6**k)
        cfg = replace(settings, depth_tau=tau)
        est, corrs = step(geoms, cams, s, cfg)
        k += 1
        s_new = est.s
        if not np.isfinite(s_new) or s_new <= 0:
            raise CalibrationError(f"the scale fixed point left the positive reals (s = {s_new:g})")
        s_new = float(np.clip(s_new, s * (1 - settings.max_step), s * (1 + settings.max_step)))
        at_final = tau <= tau_final
        if at_final and abs(s_new - s) / s_new < tol:
            s = s_new
            hist.append(s)
            converged = True
            break
        if at_final and prev is not None and k % 2 == 0:
            denom = s_new - 2 * s + prev
            if abs(denom) > 1e-15 * s_new:
                sa = s_new - (s_new - s) ** 2 / denom
                if abs(sa - s_new) < settings.max_step * s_new:
                    s_new = sa
        prev, s = (s if at_final else None), s_new
        hist.append(s)
    est, corrs = step(geoms, cams, s, final_gate(settings))
    return FixedPointResult(float(s), est, k, converged, tuple(hist), tuple(corrs))


@dataclass(frozen=True, kw_only=True)
class ScaleResult:
    """The scale stage's result (everything the report needs).

    Attributes:
        s: the global metric scale s*. s_initial: fixed point before pruning. s_coarse: coarse search.
        s_naive: the naive median depth-ratio scale (None when the backbone gives no depths).
        edge_scales: (i, j) -> per-edge scale. edge_counts: (i, j) -> correspondences.
        edges: candidate edges (i, j) with enough overlap. kept, pruned: after CC.
        cycle_mode: "cycles", "median", "single" or "off". cycle_residuals: "i-j-k" -> relative.
        std_error: relative standard error of s. iterations, converged: fixed point.
        peak_spread: relative width of the coarse-search peak. warnings: text.
    """

    s: float
    s_initial: float
    s_coarse: float
    s_naive: float | None
    edge_scales: dict[tuple[int, int], float]
    edge_counts: dict[tuple[int, int], int]
    edges: tuple[tuple[int, int], ...]
    kept: tuple[tuple[int, int], ...]
    pruned: tuple[tuple[int, int], ...]
    cycle_mode: str
    cycle_residuals: dict[str, float]
    cycle_residuals_before: dict[str, float]
    cycle_residuals_mm: dict[str, float]
    std_error: float
    iterations: int
    converged: bool
    peak_spread: float
    warnings: tuple[str, ...]
    scale_edges: tuple[tuple[int, int], ...] = ()
    """The kept edges whose correspondences gave s* (the match-only ones with
    ``global_from_matches``, else all kept edges)."""


@dataclass(frozen=True)
class _EdgeScales:
    scales: dict[Edge, float]
    counts: dict[Edge, int]
    match_only: set[Edge]


@dataclass(frozen=True)
class _Pruning:
    kept: tuple[Edge, ...]
    pruned: tuple[Edge, ...]
    mode: str
    residuals: dict[str, float]
    residuals_before: dict[str, float]
    residuals_mm: dict[str, float]


def metric_scale(
    bb: BackboneResult,
    cams: list[CameraData],
    settings: ScaleSettings | CalibConfig,
    step: StepFunction | None = None,
) -> ScaleResult:
    """Scale stage of GMAC on backbone poses ``bb`` and per-camera RC data ``cams``.

    Args:
        bb: the backbone's scale-ambiguous poses (rig order), at least two registered.
        cams: per-camera RC data from ``correspondences.prepare_cameras`` (rig order, metres).
        settings: the stage's settings (``config.scale_settings``; a public entry point, so a
            :class:`~fuseflow.calib.config.CalibConfig` is taken too and its settings used).
        step: the fixed-point step used for every per-edge and global fixed point (default
            :func:`rc_step`). An injection point: a step that
            transforms the correspondences (e.g. shifts one edge's points to mimic wrong
            matches) measures how the stage, and CC in particular, copes with them.

    Raises:
        CalibrationError: all registered cameras at one position, no overlapping pair, no edge
            with enough depth-consistent correspondences, or a fixed point leaving s > 0.
    """
    step = step or rc_step
    settings = scale_settings(settings)
    warnings: list[str] = []
    s0 = scale_search_centre(bb, cams)
    pairs = _registered_pairs(bb)
    geoms = candidate_edges(bb, pairs, settings)
    coarse = coarse_scale_search(_directed(geoms, pairs), cams, s0, settings)
    edges, overlap_meas = gate_edges(geoms, pairs, cams, coarse.s, settings)
    if bb.overlap is None and not settings.random_correspondences:
        geoms = _weighted_by_measured_overlap(geoms, overlap_meas, len(cams))
    if not edges:
        raise CalibrationError(
            f"no camera pair overlaps by at least {settings.min_overlap:.0%} at the best scale "
            f"(measured: { {f'{i}-{j}': round(v, 3) for (i, j), v in overlap_meas.items()} })"
        )
    es = per_edge_scales(geoms, edges, cams, coarse.s, settings, step)
    usable = [e for e in edges if e in es.scales]
    dropped = [e for e in edges if e not in es.scales]
    if dropped:
        warnings.append(f"edges {dropped} have fewer than {settings.min_correspondences} correspondences")
    if not usable:
        raise CalibrationError(f"no edge has {settings.min_correspondences} depth-consistent correspondences")
    pr = _prune_edges(bb, cams, es, usable, settings, warnings)
    global_edges = _global_edges(pr.kept, es.match_only, settings)
    fp = fixed_point_scale(_directed(geoms, global_edges), cams, coarse.s, settings, step=step)
    if not fp.converged:
        warnings.append(f"the scale fixed point did not converge in {fp.iterations} steps (history {fp.history[-3:]})")
    s_init = fp.s
    if pr.pruned:  # for the report: what the global estimate would have been without pruning
        s_init = fixed_point_scale(_directed(geoms, usable), cams, coarse.s, settings, step=step).s
    warnings += _conditioning_warnings(coarse, fp.estimate.relative_std_error, bb, settings)
    return ScaleResult(
        s=float(fp.s),
        s_initial=float(s_init),
        s_coarse=float(coarse.s),
        s_naive=naive_scale(bb, cams),
        edge_scales=es.scales,
        edge_counts=es.counts,
        edges=tuple(edges),
        kept=tuple(pr.kept),
        pruned=tuple(pr.pruned),
        cycle_mode=pr.mode,
        cycle_residuals=pr.residuals,
        cycle_residuals_before=pr.residuals_before,
        cycle_residuals_mm=pr.residuals_mm,
        std_error=float(fp.estimate.relative_std_error * fp.s),
        iterations=fp.iterations,
        converged=fp.converged,
        peak_spread=coarse.peak_spread,
        warnings=tuple(warnings),
        scale_edges=tuple(global_edges),
    )


#: A metric backbone's poses are trusted at s* = 1; GMAC's own s* further than this from 1 warns.
#: On correct poses of simulated rings it reads 0.90-0.99 (docs/gmac-rgbd.md), so a tighter bound
#: warns on correct calibrations; wrong depth units (mm vs 0.1 mm, 1/8 mm) move it by 2-10x.
METRIC_SCALE_TOLERANCE = 0.15


def placement_scale(
    bb: BackboneResult, cams: list[CameraData], settings: ScaleSettings
) -> tuple[ScaleResult, float | None, list[str]]:
    """The scale the cameras are placed at: (the stage's result, the check's s* or None, warnings).
    A scale-free backbone gets ``metric_scale``'s s* (no check, no warning). A metric one
    (``bb.metric``) is placed at s = 1 and the stage runs on its poses as a check: the s* it
    found (None when it could not run); s* far from 1 means the backbone's metric poses and the
    sensor depth disagree (wrong pose, depth scale, intrinsics)."""
    if not bb.metric:
        return metric_scale(bb, cams, settings), None, []
    try:
        sr = metric_scale(bb, cams, settings)
    except CalibrationError as e:
        empty = ScaleResult(
            s=1.0, s_initial=1.0, s_coarse=1.0, s_naive=None, edge_scales={}, edge_counts={}, edges=(), kept=(),
            pruned=(), cycle_mode="off", cycle_residuals={}, cycle_residuals_before={}, cycle_residuals_mm={},
            std_error=0.0, iterations=0, converged=True, peak_spread=0.0, warnings=(),
        )  # fmt: skip
        return empty, None, [f"the scale check on the metric backbone's poses could not run: {e}"]
    check = sr.s
    warnings = []
    if abs(check - 1.0) > METRIC_SCALE_TOLERANCE:
        warnings.append(
            f"{SCALE_CHECK_WARNING} {check:.4f}, more than "
            f"{METRIC_SCALE_TOLERANCE:.0%} from 1 (correct poses read 0.90-0.99): check the depth units "
            "(rig.json depth_scale) and the intrinsics; the poses are used at scale 1"
        )
    return replace(sr, s=1.0, s_initial=1.0), check, warnings


def scale_search_centre(bb: BackboneResult, cams: list[CameraData]) -> float:
    """s0, the centre of the coarse search: median sensor depth (m) of the registered cameras'
    samples over the median distance between registered backbone camera centres (backbone units).

    Raises CalibrationError when the backbone put all registered cameras at one position.
    """
    reg = np.flatnonzero(bb.registered)
    depths = np.concatenate([c.X[:, 2] for k, c in enumerate(cams) if k in set(reg) and len(c.X)])
    centers = np.stack([invert_rigid(bb.T_cam_world[k])[:3, 3] for k in reg])
    base = np.median(np.linalg.norm(centers[:, None] - centers[None], axis=2)[np.triu_indices(len(reg), 1)])
    if not np.isfinite(base) or base <= 0:
        raise CalibrationError("the backbone placed all registered cameras at the same position")
    return float(np.median(depths)) / float(base)


def _registered_pairs(bb: BackboneResult) -> list[Edge]:
    reg = np.flatnonzero(bb.registered)
    return [(int(a), int(b)) for ai, a in enumerate(reg) for b in reg[ai + 1 :]]


def candidate_edges(bb: BackboneResult, pairs: list[Edge], settings: ScaleSettings) -> dict[Edge, list[EdgeGeometry]]:
    """Both directions (i -> j, j -> i) of each pair (i < j), with the backbone's relative pose,
    eq. (8)'s edge weight (1 for ``random_correspondences``) and the keypoint matches."""

    def both_directions(e: Edge) -> list[EdgeGeometry]:
        i, j = e
        w = (
            edge_weight(i, j, bb.overlap, bb.features, settings.feature_weight)
            if not settings.random_correspondences
            else 1.0
        )
        return [
            edge_geometry(bb.T_cam_world, i, j, w, match_lookup(bb.matches, i, j)),
            edge_geometry(bb.T_cam_world, j, i, w, match_lookup(bb.matches, j, i)),
        ]

    return {e: both_directions(e) for e in pairs}


def _directed(geoms_by_edge: dict[Edge, list[EdgeGeometry]], edges) -> list[EdgeGeometry]:
    return [g for e in edges for g in geoms_by_edge[e]]


def gate_edges(
    geoms: dict[Edge, list[EdgeGeometry]], pairs: list[Edge], cams: list[CameraData], s: float, settings: ScaleSettings
) -> tuple[list[Edge], dict[Edge, float]]:
    """Edge gating by measured overlap at scale s (eq. 8: overlap_ij gates edges).

    Returns (pairs whose mean directed share of depth-consistent samples at gate ``depth_tau``
    reaches ``min_overlap``, pair -> that measured share).
    """
    edges, overlap_meas = [], {}
    for e in pairs:
        o = []
        for g in geoms[e]:
            n_i = max(len(cams[g.i].X), 1)
            o.append(consistent_count(g, cams[g.i], cams[g.j], s, settings.depth_tau) / n_i)
        overlap_meas[e] = float(np.mean(o))
        if overlap_meas[e] >= settings.min_overlap:
            edges.append(e)
    return edges, overlap_meas


def _weighted_by_measured_overlap(
    geoms: dict[Edge, list[EdgeGeometry]], overlap_meas: dict[Edge, float], n: int
) -> dict[Edge, list[EdgeGeometry]]:
    """A backbone without an overlap matrix: eq. (8)'s overlap_ij is the measured one."""
    ov = np.eye(n)
    for (i, j), v in overlap_meas.items():
        ov[i, j] = ov[j, i] = v
    return {
        e: [EdgeGeometry(g.i, g.j, g.R, g.t, g.weight * ov[g.i, g.j], g.matches) for g in gs] for e, gs in geoms.items()
    }


def per_edge_scales(
    geoms: dict[Edge, list[EdgeGeometry]],
    edges: list[Edge],
    cams: list[CameraData],
    s_coarse: float,
    settings: ScaleSettings,
    step: StepFunction,
) -> _EdgeScales:
    """Each edge's own scale, for CC: its fixed point from the robust coarse scale.

    The global estimate only ever sees the edges CC keeps, so one wrong edge cannot drag it. An
    edge whose own fixed point walks to a scale where its correspondences fail the depth gate
    (what a wrong edge does) gets the one-step closed form at the coarse scale instead (the
    paper's fixed-correspondence approximation), so it shows up in the cycle residuals instead
    of vanishing. Edges with neither are left out.
    """
    scales: dict[Edge, float] = {}
    counts: dict[Edge, int] = {}
    matched_edges: set[Edge] = set()
    for e in edges:
        try:
            fe = fixed_point_scale(geoms[e], cams, s_coarse, settings, step=step)
            matched = match_only(fe.correspondences)
            if fe.s > 0 and (fe.estimate.count >= settings.min_correspondences or matched):
                scales[e], counts[e] = fe.s, fe.estimate.count
                if matched:
                    matched_edges.add(e)
                continue
        except CalibrationError:
            pass
        try:
            est_e, _ = one_step_scale(geoms[e], cams, s_coarse, settings, step)
        except CalibrationError:
            continue
        if est_e.count >= settings.min_correspondences and est_e.s > 0:
            scales[e], counts[e] = est_e.s, est_e.count
    return _EdgeScales(scales, counts, matched_edges)


def _prune_edges(
    bb: BackboneResult,
    cams: list[CameraData],
    es: _EdgeScales,
    usable: list[Edge],
    settings: ScaleSettings,
    warnings: list[str],
) -> _Pruning:
    """CC (eq. 13) on the usable edges' own scales; appends the no-triangle warning."""
    if not settings.cycle_consistency:
        return _Pruning(tuple(usable), (), "off", {}, {}, {})
    pts = {k: c.X[:: max(1, len(c.X) // 64)] for k, c in enumerate(cams)}
    cyc = prune_by_cycles(
        bb.T_cam_world,
        {e: es.scales[e] for e in usable},
        settings.delta_cycle,
        settings.max_pruned_fraction,
        pts,
        {e: float(es.counts[e]) for e in usable},
    )
    if cyc.mode == "median":
        warnings.append("the edge graph has no triangle: cycle check replaced by the median of per-edge scales")

    def fmt(d):
        return {f"{a}-{b}-{c}": float(v) for (a, b, c), v in d.items()}

    return _Pruning(
        cyc.kept, cyc.pruned, cyc.mode, fmt(cyc.residuals), fmt(cyc.residuals_before), fmt(cyc.residuals_mm)
    )


def _global_edges(kept, match_only_edges: set[Edge], settings: ScaleSettings) -> list[Edge]:
    """The kept edges s* is estimated from: with ``global_from_matches`` the match-only ones
    when there are at least two, else all kept edges."""
    if settings.use_matches and settings.global_from_matches:
        kept_matches = [e for e in kept if e in match_only_edges]
        if len(kept_matches) >= 2:
            return kept_matches
    return list(kept)


def _conditioning_warnings(
    coarse: CoarseSearch, relative_std_error: float, bb: BackboneResult, settings: ScaleSettings
) -> list[str]:
    out = []
    if coarse.peak_spread > settings.ill_conditioned_spread and not (settings.use_matches and bb.matches):
        out.append(
            f"ill-conditioned: scales within {coarse.peak_spread:.0%} of each other explain the depth equally "
            "well (baselines parallel to the dominant surfaces)"
        )
    if relative_std_error > 0.01:
        out.append(f"ill-conditioned: relative standard error of s* is {relative_std_error:.1%}")
    return out


def edge_weight(
    i: int,
    j: int,
    overlap: np.ndarray | None,
    features: np.ndarray | None,
    use_features: bool,
) -> float:
    """eq. (8)'s edge factor overlap_ij * cos(F_i, F_j) (cos clipped to [0, 1])."""
    w = 1.0 if overlap is None else float(overlap[i, j])
    if use_features and features is not None:
        fi, fj = features[i], features[j]
        den = float(np.linalg.norm(fi) * np.linalg.norm(fj))
        w *= max(0.0, float(fi @ fj) / den) if den > 0 else 0.0
    return w


def informative_mask(g: EdgeGeometry, cam_i: CameraData, min_cos: float) -> np.ndarray:
    """(M,) bool: camera-i samples whose surface normal (rotated into j) has |cos| >= min_cos
    with the baseline t_ji. Only such points say anything about s: a surface parallel to the
    baseline (the floor under a level camera ring) maps onto itself at every scale, so its
    reprojections are depth-consistent whatever s is."""
    tn = float(np.linalg.norm(g.t))
    if min_cos <= 0 or tn == 0:
        return np.ones(len(cam_i.X), bool)
    ui = cam_i.uv[:, 0].astype(np.int64)
    vi = cam_i.uv[:, 1].astype(np.int64)
    n = cam_i.normals[vi, ui].astype(np.float64) @ g.R.T
    return np.abs(n @ (g.t / tn)) >= min_cos


def consistent_count(
    g: EdgeGeometry, cam_i: CameraData, cam_j: CameraData, s: float, tau: float, mask: np.ndarray | None = None
) -> int:
    """Number of camera-i samples (those in ``mask`` when given) whose reprojection at scale s is
    depth-consistent in j (``consistent_counts`` at one scale)."""
    return int(consistent_counts(g, cam_i, cam_j, np.array([s], dtype=np.float64), tau, mask)[0])


def consistent_counts(
    g: EdgeGeometry,
    cam_i: CameraData,
    cam_j: CameraData,
    scales: np.ndarray,
    tau: float,
    mask: np.ndarray | None = None,
) -> np.ndarray:
    """Camera-i samples (those in ``mask`` when given) whose reprojection is depth-consistent in
    j, at every scale of ``scales`` (G,) at once: (G,) int64.

    ``reproject``'s test per point and scale (X_ij = R X + s t, projection, nearest pixel, depth
    gate) on (G, M) arrays, without what the count does not use (validity, normals), and with the
    projection written out instead of a (G M, 3) x (3, 3) matrix product (OpenBLAS threads that
    product, 15-20x slower than one thread on a loaded 2-core machine). The coarse scale search
    evaluates ~220 scales per edge; one ``consistent_count`` call per scale would be the largest
    part of the metric scale check."""
    X = cam_i.X if mask is None else cam_i.X[mask]
    scales = np.asarray(scales, dtype=np.float64)
    if len(X) == 0 or len(scales) == 0:
        return np.zeros(len(scales), dtype=np.int64)
    RX = X @ g.R.T
    st = scales[:, None] * g.t[None]  # (G, 3): s * t, as in ``reproject``
    x = RX[None, :, 0] + st[:, 0:1]
    y = RX[None, :, 1] + st[:, 1:2]
    z = RX[None, :, 2] + st[:, 2:3]
    K = cam_j.K
    front = z > 1e-3
    zs = np.where(front, z, 1.0)
    H, W = cam_j.shape
    with np.errstate(invalid="ignore"):
        ui = np.floor((x * K[0, 0] + y * K[0, 1] + z * K[0, 2]) / zs + 0.5)
        vi = np.floor((x * K[1, 0] + y * K[1, 1] + z * K[1, 2]) / zs + 0.5)
    ok = front & (ui >= 0) & (ui < W) & (vi >= 0) & (vi < H)
    d = np.zeros(z.shape)
    d[ok] = cam_j.depth[vi[ok].astype(np.int64), ui[ok].astype(np.int64)]
    hit = ok & (d > 0) & (np.abs(d - z) < tau * np.maximum(z, 1e-6))
    return np.count_nonzero(hit, axis=1).astype(np.int64)


def naive_scale(bb: BackboneResult, cams: list[CameraData]) -> float | None:
    """The naive baseline: median sensor depth / backbone depth at the backbone's own points
    (``bb.points``); None when the backbone has none or too few have sensor depth."""
    if not bb.points:
        return None
    sd, bd = [], []
    for k, (uv, z) in bb.points.items():
        H, W = cams[k].shape
        ui = np.clip(np.round(uv[:, 0]).astype(int), 0, W - 1)
        vi = np.clip(np.round(uv[:, 1]).astype(int), 0, H - 1)
        sd.append(cams[k].depth[vi, ui])
        bd.append(z)
    try:
        return naive_median_scale(np.concatenate(sd), np.concatenate(bd))
    except CalibrationError:
        return None
