"""Warping by a flow: pixel maps, the captured image warped back onto the projected grid, and the
composition of a residual flow onto a base flow.

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
