"""What a method claims about its own flow: where it holds (``claimed``) and whether the pair registered.

Convention: ``flow`` float32 ``(H, W, 2)``, forward, projected -> captured, pixels; ``claimed`` bool
``(H, W)`` on the projected grid (None: every pixel); ``registered`` False when the method found no
evidence to register the pair at all (e.g. textureless content): its flow is then a placeholder.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..geometry.images import ramp


def pixel_confidence(
    texture: np.ndarray, ncc: np.ndarray, residual: np.ndarray, spread: np.ndarray, radius: float
) -> np.ndarray:
    """Per-pixel confidence of a flow in [0, 1]: checks on the textured pixels, spread to their
    neighbourhood (the smooth surface model interpolates between them), nothing far from texture.

    Each textured pixel passes or fails three checks (the weakest counts): the photometric check
    ``ncc``, local NCC between the projected image and the captured image warped back by the flow
    (0 at <= 0.3, 1 at >= 0.6); ``residual`` (px), the larger of the DIS residual still measured on
    the rectified pair and its forward-backward inconsistency (1 at <= 2 px, 0 at >= 4 px); and
    ``spread`` (px), how far the candidates that scored almost as well lie from this flow (1 at <= 2
    px, 0 at >= 4 px: two answers that explain the images equally well, as on a repetitive pattern,
    leave the pixel ambiguous). The pass marks are averaged around every pixel at two scales, and the
    larger counts (:func:`neighbourhood`): a Gaussian of sigma ``radius`` px, multiplied by how much
    texture it holds (0 at a texture density <= 0.05, 1 at >= 0.2), and one of twice that sigma, which
    asks for more texture (0 at <= 0.1): the coarse one carries the verdict across a flat gap between
    verified textured regions, which the surface model interpolates; a flat region far from any
    texture gets 0 whatever the flow.

    Args:
        texture: the projected image's texture weight in [0, 1] (``refine.texture_weight`` with its
            absolute floor), float ``(H, W)``.
        ncc, residual, spread: float ``(H, W)`` as above.
        radius: Gaussian sigma of the fine neighbourhood, px.

    Returns:
        float32 ``(H, W)``; the pixel is claimed where it is at least ``CONFIDENT``. The break points
        were chosen on the validation split, the coarse scale on development sets (docs/model.md).
    """
    passed = pass_marks(ncc, residual, spread)
    w = np.asarray(texture, np.float32)
    fine = neighbourhood(w, passed, radius, 0.05)
    return np.maximum(fine, neighbourhood(w, passed, 2 * radius, 0.1)).astype(np.float32)


def gap_confidence(
    texture: np.ndarray, ncc: np.ndarray, residual: np.ndarray, spread: np.ndarray, radius: float
) -> np.ndarray:
    """The checks' verdict carried across a wide flat gap: the pass marks (:func:`pixel_confidence`'s
    inputs) averaged at four times the sigma ``radius``, from a texture density of 0.1 (:func:`neighbourhood`).

    Alone it would claim flat regions the surface model only guesses (on a development set of real
    pictures one pair 15 px off at three times the sigma); ``refine`` uses it only where the answer also
    agrees with the plane of its own claimed pixels, a second model of the gap (docs/model.md).
    """
    passed = pass_marks(ncc, residual, spread)
    return neighbourhood(np.asarray(texture, np.float32), passed, 4 * radius, 0.1)


def pass_marks(ncc: np.ndarray, residual: np.ndarray, spread: np.ndarray) -> np.ndarray:
    """Each pixel's pass mark in [0, 1]: the weakest of the three checks (:func:`pixel_confidence`)."""
    return np.minimum.reduce([ramp(ncc, 0.3, 0.6), ramp(residual, 4.0, 2.0), ramp(spread, 4.0, 2.0)])


def neighbourhood(texture: np.ndarray, passed: np.ndarray, sigma: float, sparse: float) -> np.ndarray:
    """The ``passed`` marks (float ``(H, W)`` in [0, 1]) averaged around every pixel by a normalised
    convolution weighted by ``texture`` (Gaussian, ``sigma`` px), times how much texture the window
    holds: 0 at a density <= ``sparse``, 1 at >= 0.2.

    A sigma of 64 px or more is applied on the grid shrunk ``sigma // 32`` times (area averages) and the
    result brought back bilinearly: the map is smooth at that scale, and a full-size Gaussian that wide
    took seconds on a 1080 x 1920 pair (claims moved on about 1 % of the pixels, at the 0.5 boundary).

    Example:
        >>> w = np.zeros((40, 40), np.float32); w[:, :20] = 1.0
        >>> c = neighbourhood(w, np.ones_like(w), 3.0, 0.05)
        >>> round(float(c[20, 10]), 3), round(float(c[20, 35]), 3)
        (1.0, 0.0)
    """
    h, w = texture.shape
    shrink = max(1, int(sigma // 32))
    small = (max(1, w // shrink), max(1, h // shrink))
    weights = [texture, texture * passed]
    if shrink > 1:
        weights = [cv2.resize(a, small, interpolation=cv2.INTER_AREA) for a in weights]
    density, agree = (cv2.GaussianBlur(a, (0, 0), sigma / shrink) for a in weights)
    out = agree / np.maximum(density, 1e-6) * ramp(density, sparse, 0.2)
    return out if shrink == 1 else cv2.resize(out, (w, h), interpolation=cv2.INTER_LINEAR)
