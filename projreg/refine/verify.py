"""Verify: the winner's per-pixel checks (:func:`checks`), the confidence they give (:func:`confidence`),
and the bridge that carries a registered answer's verdict across wide flat gaps (:func:`bridged`).

The maps are :mod:`~projreg.refine.confidence`'s; what they are read from (the candidates' memoised NCC
maps, DIS's round trip, the rivals' spread) is the pair's context. Convention: maps float32 ``(H, W)`` on
the projected grid; flows float32 ``(H, W, 2)``, forward, pixels.
"""

from __future__ import annotations

import numpy as np

from ..geometry.homography import fit_homography, homography_flow
from ..prediction import CONFIDENT
from .candidates import Candidate
from .confidence import eigen_ratio, gap_confidence, pass_marks, pixel_confidence
from .confidence import pinned as pinned_by
from .context import DisFlows, PairContext, flow_distance
from .selection import ambiguity, rivals
from .workers import Workers


def confidence(
    ctx: PairContext,
    cands: list[Candidate],
    scores: dict[str, float],
    best: Candidate,
    repeats: np.ndarray | None,
    dis: DisFlows,
) -> np.ndarray:
    """Per-pixel confidence in [0, 1] of candidate ``best`` (:func:`~projreg.refine.confidence.pixel_confidence`
    of :func:`checks`); 0 where the projected image repeats itself (``repeats``)."""
    cfg = ctx.config.confidence
    maps, radius = checks(ctx, cands, scores, best, dis), cfg.radius * max(ctx.shape)
    conf = pixel_confidence(ctx.evidence, *maps, radius, cfg, ctx.side.tensor)
    return conf if repeats is None else np.where(repeats, 0.0, conf).astype(np.float32)


def pinned(
    ctx: PairContext, cands: list[Candidate], scores: dict[str, float], best: Candidate, dis: DisFlows
) -> np.ndarray:
    """Where candidate ``best``'s passing texture pins its position on a bent surface, in [0, 1]
    (:func:`~projreg.refine.confidence.pinned`, at the checks' window ``selection.ncc_sigma``): the
    confidence's factor for the answer's claim."""
    cfg, side = ctx.config.confidence, ctx.side
    if side.corners is None:
        products = [side.tensor[..., k] for k in range(3)]
        side.corners = eigen_ratio(products, ctx.config.selection.ncc_sigma, ctx.config.images.shrunk_sigma)
    passed = pass_marks(*checks(ctx, cands, scores, best, dis), cfg)
    return pinned_by(side.corners, ctx.evidence, passed, best.flow, cfg.radius * max(ctx.shape), cfg, ctx.scale)


def checks(
    ctx: PairContext, cands: list[Candidate], scores: dict[str, float], best: Candidate, dis: DisFlows
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Candidate ``best``'s check maps: local NCC, forward-backward residual (px, DIS's flows ``dis``) and
    the rivals' spread (px, :func:`~projreg.refine.selection.ambiguity`); distances in the pair's own pixels
    (``ctx.scale`` times the context's, where its images are the pair shrunk): a claim's tolerance is the
    user's, whatever grid it was verified on."""
    margin = ctx.config.confidence.rival_margin
    ncc = ctx.ncc(best.key, best.flow)
    residual = ctx.round_trip(dis, best.key, best.flow)
    # the spread is kept by winner and rivals: the bridge asks for the same checks again
    key = f"spread:{best.key}:" + ",".join(c.key for c in rivals(cands, scores, best, margin))
    if key not in ctx.memo:
        ctx.memo[key] = ambiguity(ctx, cands, scores, best, ncc, margin)
    spread = ctx.memo[key]
    return (ncc, residual, spread) if ctx.scale == 1 else (ncc, ctx.scale * residual, ctx.scale * spread)


def bridged(
    ctx: PairContext,
    conf: np.ndarray,
    best: Candidate,
    cands: list[Candidate],
    scores: dict[str, float],
    repeats: np.ndarray | None,
    workers: Workers,
) -> np.ndarray:
    """``conf`` raised to the checks averaged across wide flat gaps
    (:func:`~projreg.refine.confidence.gap_confidence`) where ``best`` stays within ``bridge_px`` of the
    homography fitted to it on its claimed pixels; ``conf`` itself when that fit fails. The fit runs on
    ``workers``' pool beside the gap map.

    In a flat gap the answer is the surface model's interpolation; where the plane of the verified
    region says the same, two models of the gap agree and the gap is claimed."""
    cfg, (h, w) = ctx.config, ctx.shape
    fit = cfg.fit
    fitting = workers.submit(
        fit_homography, best.flow, ctx.refit_step, fit.ransac_px, conf >= CONFIDENT, fit.max_area_ratio, fit.min_hull
    )
    radius = cfg.confidence.radius * max(h, w)
    maps = checks(ctx, cands, scores, best, workers.dis_flows)
    gap = gap_confidence(ctx.evidence, *maps, radius, cfg.confidence, ctx.side.tensor)
    found = fitting.result()
    if found is None:
        return conf
    if repeats is not None:
        gap = np.where(repeats, 0.0, gap)
    agree = flow_distance(best.flow, homography_flow(found[0], h, w)) < cfg.confidence.bridge_px
    return np.where(agree, np.maximum(conf, gap), conf).astype(np.float32)
