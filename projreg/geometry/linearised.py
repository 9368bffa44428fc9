"""The per-pixel pass of one direct-alignment step (:mod:`~projreg.geometry.align`), fused: the captured
image warped back by the current flow (bilinear, edges replicated), the residual against the
projected image, its linearisation in the flow (efficient second-order: the mean of both images'
gradients) and the robust per-pixel weights and products the normal equations sum.

Written as three numba passes over the pixels and OpenCV's warp instead of about thirty numpy calls over
full-size arrays (the step reads and writes its images a few times instead of once per operation), all
without the GIL, so two alignments side by side on the refinement's threads both compute.

Convention: gray images float32 ``(h, w)`` on the projected grid (projected) and ``(hc, wc)`` on the
captured grid; flows float32 ``(h, w, 2)``, forward, projected -> captured, pixels.
"""

from __future__ import annotations

import cv2
import numpy as np

from projsynth.utils.jit import jit

MAD_TO_SIGMA = 1.4826  # a Gaussian's standard deviation per median absolute deviation
MIN_SCALE = 1e-3  # the Cauchy scale's floor, grey levels: a perfect match still weighs by its texture
TEXTURED = 0.5  # pixels whose texture weight exceeds this set the residuals' scale ...
MAD_SAMPLES = 16384  # ... the median of about this many of them, evenly spaced (sampling error about 1 %)


def linearise(
    projected: np.ndarray,
    captured: np.ndarray,
    gradient: tuple[np.ndarray, np.ndarray],
    texture: np.ndarray,
    start: np.ndarray,
    rows: np.ndarray,
    columns: np.ndarray,
    slope: float,
    out: np.ndarray,
    width: float = 1.0,
) -> None:
    """The robustly weighted products of one Gauss-Newton step at the flow ``start + rows @ columns``,
    written into ``out``.

    Args:
        projected, captured: the level's gray images.
        gradient: the projected image's gradient (x, y), grey levels per pixel.
        texture: the projected image's texture weight in [0, 1], ``(h, w)``.
        start: the flow the spline is added to at this level.
        rows, columns: the spline as a product: ``rows`` float64 ``(h, ky)`` (the basis along y),
            ``columns`` float64 ``(2, ky, w)`` (the control values times the basis along x, per component).
        slope: the residual's derivative per unit of its gradient (``0.5 * level scale``: the mean of
            the two gradients, in control values of the finest level).
        out: float64 ``(5, h, w)``, overwritten: ``w gx gx, w gx gy, w gy gy, w gx r, w gy r`` with ``r``
            the residual, ``g`` its derivative in the flow and ``w`` the texture weight inside the
            captured frame divided by ``1 + (r / s)^2`` (Cauchy; ``s``: ``width`` times the residuals' median
            absolute deviation over the textured pixels, about ``MAD_SAMPLES`` of them, as a standard deviation).
        width: the Cauchy's scale in standard deviations of the residuals.
    """
    h, w = projected.shape
    mapx, mapy = np.empty((h, w), np.float32), np.empty((h, w), np.float32)
    _positions(start, rows, columns, mapx, mapy)
    warped = cv2.remap(captured, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    residual, weight = np.empty((h, w), np.float32), np.empty((h, w), np.float32)
    spread = np.empty(h * w, np.float32)
    n = _residual(
        projected, warped, texture, mapx, mapy, captured.shape[0], captured.shape[1], residual, weight, spread
    )
    scale = width * MAD_TO_SIGMA * float(np.median(spread[: n : max(1, n // MAD_SAMPLES)])) + MIN_SCALE if n else 1.0
    _products(warped, residual, weight, gradient[0], gradient[1], slope, scale, out)


@jit
def _positions(start, rows, columns, mapx, mapy):  # pragma: no cover - numba
    """Where each pixel lands in the captured image: its position plus ``start + rows @ columns``."""
    h, w = mapx.shape
    ky = rows.shape[1]
    u = np.empty(w)
    v = np.empty(w)
    for y in range(h):
        u[:] = 0.0
        v[:] = 0.0
        for i in range(ky):
            b = rows[y, i]
            if b != 0.0:  # 4 of the ky basis functions are not zero on a row
                for x in range(w):
                    u[x] += b * columns[0, i, x]
                    v[x] += b * columns[1, i, x]
        for x in range(w):
            mapx[y, x] = x + (start[y, x, 0] + u[x])
            mapy[y, x] = y + (start[y, x, 1] + v[x])


@jit
def _residual(projected, warped, texture, mapx, mapy, hc, wc, residual, weight, spread):  # pragma: no cover
    """The residual and the texture weight inside the captured frame; the textured pixels' absolute
    residuals into ``spread``, their count returned."""
    h, w = projected.shape
    n = 0
    for y in range(h):
        for x in range(w):
            mx = mapx[y, x]
            my = mapy[y, x]
            r = warped[y, x] - projected[y, x]
            residual[y, x] = r
            wt = texture[y, x] if (mx >= 0) & (my >= 0) & (mx <= wc - 1) & (my <= hc - 1) else np.float32(0.0)
            weight[y, x] = wt
            if wt > TEXTURED:
                spread[n] = abs(r)
                n += 1
    return n


@jit
def _products(warped, residual, weight, px, py, slope, scale, out):  # pragma: no cover - numba
    """Sobel of the warped image (edges reflected, as OpenCV's default) averaged with the projected
    image's gradient; the Cauchy-weighted products."""
    h, w = warped.shape
    for y in range(h):
        ya = y - 1 if y > 0 else min(1, h - 1)
        yb = y + 1 if y < h - 1 else max(h - 2, 0)
        for x in range(w):
            xa = x - 1 if x > 0 else min(1, w - 1)
            xb = x + 1 if x < w - 1 else max(w - 2, 0)
            dx = (
                (warped[ya, xb] - warped[ya, xa])
                + 2 * (warped[y, xb] - warped[y, xa])
                + (warped[yb, xb] - warped[yb, xa])
            ) / 8
            dy = (
                (warped[yb, xa] - warped[ya, xa])
                + 2 * (warped[yb, x] - warped[ya, x])
                + (warped[yb, xb] - warped[ya, xb])
            ) / 8
            gx = (dx + px[y, x]) * slope
            gy = (dy + py[y, x]) * slope
            r = residual[y, x]
            q = r / scale
            wt = weight[y, x] / (1 + q * q)
            out[0, y, x] = wt * gx * gx
            out[1, y, x] = wt * gx * gy
            out[2, y, x] = wt * gy * gy
            out[3, y, x] = wt * gx * r
            out[4, y, x] = wt * gy * r
