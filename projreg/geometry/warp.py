"""Warping by a flow: pixel maps, where a flow lands in the captured frame, the captured image warped
back onto the projected grid, and the composition of a residual flow onto a base flow.

Convention: flow float32 ``(H, W, 2)``, forward, projected -> captured, pixels; ``flow[y, x] = (u, v)``.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np


@lru_cache(maxsize=4)
def pixel_maps(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel x and y coordinates of an ``h x w`` frame, float32 ``(h, w)`` each; cached, read-only."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    x.flags.writeable = y.flags.writeable = False
    return x, y


def lands_inside(flow: np.ndarray, size: tuple[int, int], margin: float = 0.0) -> np.ndarray:
    """Where ``flow`` (float ``(H, W, 2)``) lands inside a captured frame of ``size`` ``(Hc, Wc)``, bool
    ``(H, W)``: positions at most ``margin`` px beyond its outer pixel centres (0: a bilinear warp has data
    from all four neighbours; 0.5: within the outer pixels' areas); never where the flow is not finite.

    Example:
        >>> f = np.array([[[0.0, 0.0], [0.4, 0.0], [np.nan, 0.0]]], np.float32)
        >>> lands_inside(f, (1, 3)).tolist(), lands_inside(f, (1, 2), 0.5).tolist()
        ([[True, True, False]], [[True, True, False]])
    """
    h, w = flow.shape[:2]
    xs, ys = pixel_maps(h, w)
    with np.errstate(invalid="ignore", over="ignore"):
        x, y = xs + flow[..., 0].astype(np.float64), ys + flow[..., 1].astype(np.float64)
        return (x >= -margin) & (x <= size[1] - 1 + margin) & (y >= -margin) & (y <= size[0] - 1 + margin)


def warp_back(gray1: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """The captured image seen in the projector frame: ``out[p] = gray1[p + flow(p)]`` (bilinear)."""
    x, y = pixel_maps(*flow.shape[:2])
    return cv2.remap(gray1, x + flow[..., 0], y + flow[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def compose(base: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """``p -> q = p + r(p) -> q + base(q)``: a residual measured on an image warped back by ``base``.

    If ``warp_back(gray1, base)`` matches the projected image under ``residual``, the pair matches
    under the returned flow: ``r(p) + base(p + r(p))``.
    """
    x, y = pixel_maps(*base.shape[:2])
    moved = cv2.remap(
        base, x + residual[..., 0], y + residual[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
    )
    return (residual + moved).astype(np.float32)
