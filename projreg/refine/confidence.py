"""What a method claims about its own flow: where it holds (``claimed``) and whether the pair registered.

Convention: ``flow`` float32 ``(H, W, 2)``, forward, projected -> captured, pixels; ``claimed`` bool
``(H, W)`` on the projected grid (None: every pixel); ``registered`` False when the method found no
evidence to register the pair at all (e.g. textureless content): its flow is then a placeholder.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..geometry.images import gaussian, ramp
from .config import ConfidenceConfig


def pixel_confidence(
    texture: np.ndarray,
    ncc: np.ndarray,
    residual: np.ndarray,
    spread: np.ndarray,
    radius: float,
    cfg: ConfidenceConfig,
    tensor: np.ndarray | None = None,
) -> np.ndarray:
    """Per-pixel confidence of a flow in [0, 1]: checks on the textured pixels, spread to their
    neighbourhood (the smooth surface model interpolates between them), nothing far from texture.

    Each textured pixel passes or fails three checks (the weakest counts, :func:`pass_marks`): the
    photometric check ``ncc``, local NCC between the projected image and the captured image warped back
    by the flow; ``residual`` (px), the larger of the DIS residual still measured on the rectified pair
    and its forward-backward inconsistency; and ``spread`` (px), how far the candidates that scored
    almost as well lie from this flow (two answers that explain the images equally well, as on a
    repetitive pattern, leave the pixel ambiguous). The pass marks are averaged around every pixel at
    two scales, and the larger counts (:func:`neighbourhood`): a Gaussian of sigma ``radius`` px,
    multiplied by how much texture it holds (from ``cfg.sparse`` to ``cfg.dense``), and one of twice
    that sigma, which asks for more texture (from ``cfg.coarse_sparse``): the coarse one carries the
    verdict across a flat gap between verified textured regions, which the surface model interpolates;
    a flat region far from any texture gets 0 whatever the flow. With ``tensor``, the result is
    limited by how well the passing texture around the pixel fixes a position in both directions
    (:func:`spanned`, over ``cfg.span_radii`` times ``radius``, the reach of the surface model's
    coupling): along a lone edge or a set of parallel ones a flow can slide without failing any check.

    Args:
        texture: the projected image's texture weight in [0, 1] (absolute floor), float ``(H, W)``.
        ncc, residual, spread: float ``(H, W)`` as above.
        radius: Gaussian sigma of the fine neighbourhood, px.
        cfg: the pass marks' break points and the densities.
        tensor: the projected image's gradient products ``(gx^2, gx gy, gy^2)``, float ``(H, W, 3)``.

    Returns:
        float32 ``(H, W)``; the pixel is claimed where it is at least ``CONFIDENT``.
    """
    passed = pass_marks(ncc, residual, spread, cfg)
    w = np.asarray(texture, np.float32)
    fine = neighbourhood(w, passed, radius, cfg.sparse, cfg.dense, cfg.shrunk_sigma)
    coarse = neighbourhood(w, passed, 2 * radius, cfg.coarse_sparse, cfg.dense, cfg.shrunk_sigma)
    out = np.maximum(fine, coarse)
    if tensor is not None:
        out = out * spanned(tensor, w * passed, cfg.span_radii * radius, cfg)
    return out.astype(np.float32)


def gap_confidence(
    texture: np.ndarray,
    ncc: np.ndarray,
    residual: np.ndarray,
    spread: np.ndarray,
    radius: float,
    cfg: ConfidenceConfig,
    tensor: np.ndarray | None = None,
) -> np.ndarray:
    """The checks' verdict carried across a wide flat gap: the pass marks (:func:`pixel_confidence`'s
    inputs) averaged at four times the sigma ``radius``, from a texture density of ``cfg.coarse_sparse``.

    Alone it would claim flat regions the surface model only guesses; the refinement uses it only where
    the answer also agrees with the plane of its own claimed pixels, a second model of the gap
    (docs/model.md, "The bridge").
    """
    passed = pass_marks(ncc, residual, spread, cfg)
    texture = np.asarray(texture, np.float32)
    gap = neighbourhood(texture, passed, 4 * radius, cfg.coarse_sparse, cfg.dense, cfg.shrunk_sigma)
    return gap if tensor is None else gap * spanned(tensor, texture * passed, cfg.span_radii * radius, cfg)


def pass_marks(ncc: np.ndarray, residual: np.ndarray, spread: np.ndarray, cfg: ConfidenceConfig) -> np.ndarray:
    """Each pixel's pass mark in [0, 1]: the weakest of the three checks (:func:`pixel_confidence`), each a
    ramp between its fail and pass values."""
    return np.minimum.reduce(
        [
            ramp(ncc, cfg.ncc_fail, cfg.ncc_pass),
            ramp(residual, cfg.residual_fail_px, cfg.residual_pass_px),
            ramp(spread, cfg.spread_fail_px, cfg.spread_pass_px),
        ]
    )


def neighbourhood(
    texture: np.ndarray, passed: np.ndarray, sigma: float, sparse: float, dense: float = 0.2, shrunk: float = 6.0
) -> np.ndarray:
    """The ``passed`` marks (float ``(H, W)`` in [0, 1]) averaged around every pixel by a normalised
    convolution weighted by ``texture`` (Gaussian, ``sigma`` px), times how much texture the window
    holds: 0 at a density <= ``sparse``, 1 at >= ``dense``.

    A sigma of twice ``shrunk`` px (``confidence.shrunk_sigma``) or more is applied on the grid shrunk
    ``sigma // shrunk`` times (area averages) and the result brought back bilinearly: the map is smooth at
    that scale, and a full-size Gaussian that wide costs 5-25 ms on a 384 x 512 pair (seconds on a
    1080 x 1920 one).

    Example:
        >>> w = np.zeros((40, 40), np.float32); w[:, :20] = 1.0
        >>> c = neighbourhood(w, np.ones_like(w), 3.0, 0.05)
        >>> round(float(c[20, 10]), 3), round(float(c[20, 35]), 3)
        (1.0, 0.0)
    """

    def share(density: np.ndarray, agree: np.ndarray) -> np.ndarray:
        return agree / np.maximum(density, 1e-6) * ramp(density, sparse, dense)

    return averaged([texture, texture * passed], sigma, shrunk, share)


def spanned(tensor: np.ndarray, weight: np.ndarray, sigma: float, cfg: ConfidenceConfig) -> np.ndarray:
    """How well the texture around each pixel fixes a position in both directions, in [0, 1]: the
    smaller eigenvalue of the ``weight``-weighted structure tensor (a Gaussian of ``sigma`` px over
    ``tensor``'s gradient products, float ``(H, W, 3)``) over the larger, ramped from ``cfg.span_fail``
    (0: one edge direction only, a slide along it unseen) to ``cfg.span_pass`` (1).

    Example:
        >>> cfg = ConfidenceConfig()
        >>> t = np.zeros((32, 32, 3), np.float32); t[..., 0] = 1.0  # vertical edges only
        >>> float(spanned(t, np.ones((32, 32), np.float32), 4.0, cfg).max())
        0.0
        >>> t[..., 2] = 1.0  # and horizontal ones
        >>> float(spanned(t, np.ones((32, 32), np.float32), 4.0, cfg).min())
        1.0
    """

    def marks(xx: np.ndarray, xy: np.ndarray, yy: np.ndarray) -> np.ndarray:
        return ramp(_ratio(xx, xy, yy), cfg.span_fail, cfg.span_pass)

    w = np.asarray(weight, np.float32)
    return averaged([w * tensor[..., k] for k in range(3)], sigma, cfg.shrunk_sigma, marks)


def eigen_ratio(products: list[np.ndarray], sigma: float, shrunk: float) -> np.ndarray:
    """The smaller eigenvalue of the structure tensor over the larger, in [0, 1]: ``products`` (``gx^2``,
    ``gx gy``, ``gy^2``, float ``(H, W)`` each) averaged by a Gaussian of ``sigma`` px (:func:`averaged`)."""
    return averaged(products, sigma, shrunk, _ratio)


def _ratio(xx: np.ndarray, xy: np.ndarray, yy: np.ndarray) -> np.ndarray:
    half, root = (xx + yy) / 2, np.sqrt(((xx - yy) / 2) ** 2 + xy**2)
    return (half - root) / np.maximum(half + root, 1e-12)


def pinned(
    ratio: np.ndarray,
    texture: np.ndarray,
    passed: np.ndarray,
    flow: np.ndarray,
    radius: float,
    cfg: ConfidenceConfig,
    scale: float = 1.0,
) -> np.ndarray:
    """Where the passing texture near a pixel fixes its position on a bent surface, in [0, 1]: the share of
    the passing texture (``texture`` times the pass marks ``passed``, float ``(H, W)`` each,
    :func:`pixel_confidence`'s) whose own check window fixes a position in both directions (``ratio``: the
    :func:`eigen_ratio` of the projected image over one window, ramped from ``cfg.pin_fail`` to
    ``cfg.pin_pass``: a corner, a blob, a letter; not a curve), averaged within the ``flow``'s reach
    (:func:`reach`), ramped from 0 to ``cfg.pin_share``; 1 where the reach is ``cfg.span_radii`` radii or
    more (a flow that bends that little is :func:`spanned`'s to judge, over that reach). Times, where the
    reach is under two radii, the share of the pixel's confidence that does not rest on the coarse
    neighbourhood beyond it (:func:`_within_reach`).

    A curve alone fixes the position along itself only through the surface model's coupling to texture
    elsewhere, which holds while the surface between is near affine. Where the answer bends, that coupling
    reaches no farther than the flow stays near its chord, and a curve's pixels slide along it without
    failing any check (:func:`spanned` reads the tensor summed over the whole reach, where a curve's
    directions span both). ``scale``: the user's pixels per pixel of the grid (the bend tolerance is
    ``cfg.pin_bend_px`` of the user's). Every map here is smooth at a radius: it is computed on the grid
    shrunk ``radius // cfg.shrunk_sigma`` times (twice at least) and brought back bilinearly."""
    h, w = texture.shape
    weight = np.asarray(texture * passed, np.float32)
    f = max(2, int(radius // cfg.shrunk_sigma))  # a radius is 3 px or more on that grid
    small = (max(1, w // f), max(1, h // f))
    seen = cv2.resize(weight, small, interpolation=cv2.INTER_AREA)
    corner = cv2.resize(weight * ramp(ratio, cfg.pin_fail, cfg.pin_pass), small, interpolation=cv2.INTER_AREA)
    near = reach(flow, seen, radius, cfg, scale, f) / radius  # in radii
    if near.min() >= cfg.span_radii:  # nowhere bent: the span test's to judge everywhere
        return np.ones((h, w), np.float32)
    at = np.log2(np.clip(near, 1.0, cfg.span_radii))
    levels = [r for r in (1.0, 2.0, 4.0) if r < cfg.span_radii] + [cfg.span_radii]  # radii, each twice the last
    shares = [gaussian(corner, r * radius / f) / np.maximum(gaussian(seen, r * radius / f), 1e-6) for r in levels]
    marks, out = np.log2(levels), shares[0]
    for k in range(1, len(levels)):  # the share at the reach, between the levels on a log scale
        t = np.clip((at - marks[k - 1]) / (marks[k] - marks[k - 1]), 0.0, 1.0)
        out = np.where(at > marks[k - 1], (1 - t) * shares[k - 1] + t * shares[k], out)
    out = np.where(near >= cfg.span_radii, 1.0, ramp(out, 0.0, cfg.pin_share)).astype(np.float32)
    out = cv2.resize(out, (w, h), interpolation=cv2.INTER_LINEAR)
    if near.min() < 2.0:
        out = out * _within_reach(
            texture, passed, cv2.resize(near, (w, h), interpolation=cv2.INTER_LINEAR), radius, cfg
        )
    return out


def _within_reach(
    texture: np.ndarray, passed: np.ndarray, near: np.ndarray, radius: float, cfg: ConfidenceConfig
) -> np.ndarray:
    """The share of :func:`pixel_confidence`'s neighbourhood verdict (the larger of the fine and the coarse
    neighbourhood) left when the coarse one counts only as far as the answer's reach ``near`` (radii, float
    ``(H, W)``) allows: fully from two radii (its own sigma), not at all at one. The coarse neighbourhood
    carries the verdict across a flat gap, which the surface model interpolates: on a surface that bends
    within that gap, the interpolation is a guess."""
    texture = np.asarray(texture, np.float32)
    fine = neighbourhood(texture, passed, radius, cfg.sparse, cfg.dense, cfg.shrunk_sigma)
    coarse = neighbourhood(texture, passed, 2 * radius, cfg.coarse_sparse, cfg.dense, cfg.shrunk_sigma)
    either = np.maximum(fine, coarse)
    kept = np.maximum(fine, coarse * ramp(near, 1.0, 2.0))
    return np.where(either > 0, kept / np.maximum(either, 1e-6), 1.0).astype(np.float32)


def reach(
    flow: np.ndarray, weight: np.ndarray, radius: float, cfg: ConfidenceConfig, scale: float = 1.0, f: int = 1
) -> np.ndarray:
    """The distance (px of the flow's grid) over which ``flow`` stays within ``cfg.pin_bend_px`` (the user's
    pixels, ``scale`` of them per pixel of that grid) of a straight interpolation, ``sqrt(2 tolerance /
    bending)``: the bending is the Frobenius norm of the flow's second derivatives (at sigma ``radius``)
    averaged over ``weight`` around each pixel (a Gaussian of ``cfg.span_radii`` radii): the bending where the
    flow is seen, not where it interpolates. ``weight`` and the result are on the flow's grid shrunk ``f``
    times (area averages)."""
    small = weight.shape[::-1]
    pad = int(np.ceil(4 * radius / f))  # an odd reflection about the edge continues a plane: no bend there
    bend = np.zeros(weight.shape, np.float32)
    for k in range(2):
        a = cv2.resize(np.ascontiguousarray(flow[..., k], np.float32), small, interpolation=cv2.INTER_AREA)
        a = np.pad(a, pad, mode="reflect", reflect_type="odd")
        gy, gx = np.gradient(cv2.GaussianBlur(a, (0, 0), radius / f)[pad:-pad, pad:-pad])
        gxy, gxx = np.gradient(gx)
        bend += gxx**2 + 2 * gxy**2 + np.gradient(gy)[0] ** 2
    bend = np.sqrt(bend) / (f * f)  # px per px^2 on the flow's grid
    sigma = cfg.span_radii * radius / f
    seen = gaussian(weight * bend, sigma) / np.maximum(gaussian(weight, sigma), 1e-6)
    return np.sqrt(2 * cfg.pin_bend_px / scale / np.maximum(seen, 1e-9))


def averaged(maps: list[np.ndarray], sigma: float, shrunk: float, combine) -> np.ndarray:
    """``combine`` of the ``maps`` (float ``(H, W)``) each blurred by a Gaussian of ``sigma`` px, at full
    size: a sigma of twice ``shrunk`` px or more is applied on the grid shrunk ``sigma // shrunk`` times
    (area averages) and ``combine``'s result brought back bilinearly (:func:`neighbourhood`)."""
    h, w = maps[0].shape
    shrink = max(1, int(sigma // shrunk))
    if shrink > 1:
        small = (max(1, w // shrink), max(1, h // shrink))
        maps = [cv2.resize(np.asarray(a, np.float32), small, interpolation=cv2.INTER_AREA) for a in maps]
    out = combine(*(gaussian(np.asarray(a, np.float32), sigma / shrink) for a in maps))
    return out if shrink == 1 else cv2.resize(out, (w, h), interpolation=cv2.INTER_LINEAR)
