"""The fused per-pixel pass of an alignment step against the same step written plainly in numpy here."""

import cv2
import numpy as np
import pytest

from projreg.geometry.linearised import linearise
from projreg.geometry.splines import bspline_basis


def plain(projected, captured, gradient, texture, flow, slope):
    """The five weighted products, one numpy call at a time (OpenCV's warp and Sobel)."""
    h, w = projected.shape
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    mx, my = x + flow[..., 0], y + flow[..., 1]
    warped = cv2.remap(captured, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    inside = (mx >= 0) & (my >= 0) & (mx <= captured.shape[1] - 1) & (my <= captured.shape[0] - 1)
    r = warped - projected
    gx = (cv2.Sobel(warped, cv2.CV_32F, 1, 0) / 8 + gradient[0]) * slope
    gy = (cv2.Sobel(warped, cv2.CV_32F, 0, 1) / 8 + gradient[1]) * slope
    weight = texture * inside
    textured = weight > 0.5
    scale = 1.4826 * float(np.median(np.abs(r[textured]))) + 1e-3
    weight = weight / (1 + (r / scale) ** 2)
    return np.stack([weight * gx * gx, weight * gx * gy, weight * gy * gy, weight * gx * r, weight * gy * r])


@pytest.mark.parametrize("shape", [(40, 56), (33, 47)])
def test_products_match_the_plain_step(shape):
    h, w = shape
    rng = np.random.default_rng(h)
    projected = cv2.GaussianBlur(rng.uniform(0, 1, (h, w)).astype(np.float32), (0, 0), 1.5)
    captured = cv2.GaussianBlur(rng.uniform(0, 1, (h + 6, w - 4)).astype(np.float32), (0, 0), 1.5)
    gradient = (cv2.Sobel(projected, cv2.CV_32F, 1, 0) / 8, cv2.Sobel(projected, cv2.CV_32F, 0, 1) / 8)
    texture = rng.uniform(0, 1, (h, w)).astype(np.float32)
    start = rng.normal(0, 2, (h, w, 2)).astype(np.float32)
    start[:3] += 60  # some pixels land outside the captured frame
    kx, ky = 6, 5
    rows = bspline_basis(h, ky)
    control = rng.normal(0, 1.5, (ky, kx, 2))
    columns = np.stack([control[..., i] @ bspline_basis(w, kx).T for i in range(2)])  # [2, ky, w]
    flow = (start + np.stack([rows @ columns[i] for i in range(2)], axis=-1)).astype(np.float32)
    out = np.empty((5, h, w))
    linearise(projected, captured, gradient, texture, start, rows, columns, 0.5, out)
    want = plain(projected, captured, gradient, texture, flow, 0.5)
    np.testing.assert_allclose(out, want, rtol=2e-4, atol=1e-6 * np.abs(want).max())
