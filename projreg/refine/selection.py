"""How the refinement chooses between its candidates: the winner (:func:`select`) and the rivals that
explain the images about as well (:func:`ambiguity`), which leave the winner's pixels ambiguous.

Scores are texture-weighted mean local NCC (:meth:`~projreg.refine.context.PairContext.score`), by
:attr:`~projreg.refine.candidates.Candidate.key`; flows float32 ``(H, W, 2)``, forward, pixels.
"""

from __future__ import annotations

import numpy as np

from .candidates import Candidate
from .context import PairContext, flow_distance


def select(cands: list[Candidate], scores: dict[str, float], plane_margin: float) -> Candidate:
    """The winning candidate: the highest score (ties: the first tried), unless a homography alone
    scores within ``plane_margin`` of it: where a plane explains the images as well as the plane plus
    its fitted residual, the residual adds only DIS's noise."""
    order = {c.key: i for i, c in enumerate(cands)}

    def rank(c: Candidate) -> tuple[float, int]:
        return scores[c.key], -order[c.key]

    best = max(cands, key=rank)
    plane = max((c for c in cands if c.plane), key=rank, default=None)
    return plane if plane is not None and scores[plane.key] >= scores[best.key] - plane_margin else best


def ambiguity(
    ctx: PairContext,
    cands: list[Candidate],
    scores: dict[str, float],
    best: Candidate,
    ncc: np.ndarray,
    margin: float,
) -> np.ndarray:
    """How far, per pixel, the rivals of ``best`` (whose local NCC map is ``ncc``) that explain the images
    about as well lie from it (px, float32 ``(H, W)``).

    A rival scores within ``margin`` (``confidence.rival_margin``) of the winner (a refitted plane is its
    candidate simplified, not another explanation: never a rival) and counts at a pixel only where its
    own local NCC is within ``margin`` of the winner's there: two answers that both explain a
    neighbourhood (a repeating pattern) leave it ambiguous; a rival that fails there is just wrong."""
    spread = np.zeros(ctx.shape, np.float32)
    for c in rivals(cands, scores, best, margin):
        explains = ctx.ncc(c.key, c.flow) >= ncc - margin
        spread = np.maximum(spread, np.where(explains, flow_distance(c.flow, best.flow), 0.0))
    return spread


def rivals(cands: list[Candidate], scores: dict[str, float], best: Candidate, margin: float) -> list[Candidate]:
    """The candidates that score within ``margin`` of ``best`` and are not a refitted plane (:func:`ambiguity`)."""
    return [c for c in cands if c.key != best.key and not c.refitted and scores[c.key] >= scores[best.key] - margin]
