"""The search for the metric scale s: coarse 1-D search, then the RC / closed-form fixed point.

The pixel a reprojection correspondence lands on depends on s, so (docs/design.md 3) s is found in
two steps that each alternate the two halves of the scale stage: the correspondences at a scale
(:mod:`fuseflow.calib.correspondences`, eq. 5, 8, 11) and the closed form on them
(:mod:`fuseflow.calib.scale`, eq. 9-12).

1. ``coarse_scale_search``: a log-spaced 1-D search that maximises the count of
   depth-consistent reprojections (robust start, no closed form).
2. ``fixed_point_scale``: from that start, correspondences and closed form alternate until
   |ds| / s < tol (annealed depth gate, clamped, Aitken-accelerated). One alternation is a
   *step function* ``step(geoms, cams, s, config) -> (ScaleEstimate, correspondences)``;
   :func:`rc_step` is GMAC's, and callers may pass their own (e.g. one that perturbs the
   correspondences, to measure how the stage copes with a wrong edge).

The per-edge / cycle / global orchestration on top of this is :mod:`fuseflow.calib.scale_stage`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from fuseflow.calib.config import CalibConfig
from fuseflow.calib.correspondences import (
    CameraData,
    EdgeGeometry,
    build_correspondences,
    consistent_counts,
    informative_mask,
)
from fuseflow.calib.errors import CalibrationError
from fuseflow.calib.scale import Correspondences, ScaleEstimate, closed_form_scale, huber_weights, residuals

__all__ = [
    "CoarseSearch",
    "FixedPointResult",
    "StepFunction",
    "coarse_scale_search",
    "final_gate",
    "fixed_point_scale",
    "one_step_scale",
    "rc_step",
]

#: One alternation of the fixed point: ``step(geoms, cams, s, config) -> (estimate, corrs)``:
#: the correspondences of the directed edges ``geoms`` at scale s (metres per backbone unit)
#: under ``config`` (its ``depth_tau`` is the current gate), and the closed-form scale on them.
StepFunction = Callable[
    [Sequence[EdgeGeometry], Sequence[CameraData], float, CalibConfig],
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
    config: CalibConfig,
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
    masks = [informative_mask(g, cams[g.i], config.informative_cos) for g in geoms]

    def counts(grid: np.ndarray, tau: float) -> np.ndarray:
        out = np.zeros(len(grid), dtype=np.int64)
        for g, m in zip(geoms, masks):
            out += consistent_counts(g, cams[g.i], cams[g.j], grid, tau, m)
        return out

    grid = s0 * np.logspace(-np.log10(config.scale_span), np.log10(config.scale_span), config.scale_grid)
    c = counts(grid, config.depth_tau)
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
    peaks = sorted(peaks, key=lambda k: -c[k])[: config.coarse_candidates]
    cands = [float(grid[k]) for k in peaks] + [float(x) for x in extra if np.isfinite(x) and x > 0]
    tau_fine = min(config.depth_tau_final, config.depth_tau)
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
    geoms: Sequence[EdgeGeometry], cams: Sequence[CameraData], s: float, config: CalibConfig
) -> tuple[ScaleEstimate, list[Correspondences]]:
    """GMAC's fixed-point step (a :data:`StepFunction`): RC correspondences of every directed
    edge in ``geoms`` at scale s (Huber-reweighted when ``config.robust``), and the
    ``config.closed_form`` scale on all of them together.

    Args:
        geoms: directed edges i -> j (backbone relative poses, unit scale).
        cams: per-camera RC data, indexed by camera index (rig order).
        s: current scale, metres per backbone unit (> 0).
        config: settings; ``depth_tau`` is the depth gate of this step.
    """
    corrs = [build_correspondences(g, cams[g.i], cams[g.j], s, config) for g in geoms]
    if config.robust:
        corrs = [
            c.reweighted(c.w * huber_weights(residuals(c, s, config.closed_form), config.huber_delta)) for c in corrs
        ]
    return closed_form_scale(corrs, config.closed_form), corrs


def final_gate(config: CalibConfig) -> CalibConfig:
    """``config`` with the depth gate at the fixed point's final value, min(depth_tau_final, depth_tau)."""
    return replace(config, depth_tau=min(config.depth_tau_final, config.depth_tau))


def one_step_scale(
    geoms: Sequence[EdgeGeometry],
    cams: Sequence[CameraData],
    s: float,
    config: CalibConfig,
    step: StepFunction | None = None,
) -> tuple[ScaleEstimate, list[Correspondences]]:
    """The closed form on the correspondences at a fixed s, at the final gate (the paper's
    fixed-correspondence approximation: no iteration). Raises CalibrationError like ``step``."""
    return (step or rc_step)(geoms, cams, s, final_gate(config))


def fixed_point_scale(
    geoms: Sequence[EdgeGeometry],
    cams: Sequence[CameraData],
    s0: float,
    config: CalibConfig,
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
    tol = config.fixed_point_tol
    tau_final = min(config.depth_tau_final, config.depth_tau)
    s = float(s0)
    hist = [s]
    k = 0
    converged = False
    prev: float | None = None
    est = corrs = None
    while k < config.fixed_point_iters:
        tau = max(tau_final, config.depth_tau * 0.6**k)
        cfg = replace(config, depth_tau=tau)
        est, corrs = step(geoms, cams, s, cfg)
        k += 1
        s_new = est.s
        if not np.isfinite(s_new) or s_new <= 0:
            raise CalibrationError(f"the scale fixed point left the positive reals (s = {s_new:g})")
        s_new = float(np.clip(s_new, s * (1 - config.max_step), s * (1 + config.max_step)))
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
                if abs(sa - s_new) < config.max_step * s_new:
                    s_new = sa
        prev, s = (s if at_final else None), s_new
        hist.append(s)
    est, corrs = step(geoms, cams, s, final_gate(config))
    return FixedPointResult(float(s), est, k, converged, tuple(hist), tuple(corrs))
