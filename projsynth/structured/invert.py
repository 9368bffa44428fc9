"""From a camera -> projector map (what structured light decodes) to the projector -> camera flow.

Each camera pixel ``c`` that decoded knows the projector position ``p(c)`` it sees, with noise. The
flow at projector pixel ``X`` is the camera position whose ``p`` is ``X``: found by a weighted local
affine fit ``c = X + a + B (p - X)`` over the camera pixels whose ``p`` falls near ``X``; the
intercept ``a`` is the flow. The fit is exact for a locally affine map (any camera scale, rotation
or shear) and averages the decode noise of every sample in the window.

Implementation: every sample goes to its nearest projector pixel; per pixel the moments of the
samples' offsets ``d = p - B`` and camera offsets ``f = c - B`` are summed; the moments of the fit
at ``X`` are Gaussian-weighted sums over the neighbouring pixels ``B = X - o``, which are
separable convolutions of those moment images (offsets shift as ``d - o``, ``f - o``). Weights
depend on the pixel offset ``o`` only, never on the camera position, so the fit stays unbiased.

The window starts as wide as the decode noise asks (``window_sigma``); pixels whose fit fails there
(curvature, a fold, a hole) are fitted again in windows 1.5x narrower, down to ``SIGMA_RANGE[0]``.
A projector pixel is valid where the samples surround it (weighted centroid within ``MAX_CENTROID
sigma``, smallest spread ``>= MIN_SPREAD sigma^2``: interpolation, not extrapolation, so a pixel whose
camera position is outside the frame is not claimed), the fit is consistent (RMS residual below
``max(MAX_RESIDUAL_PX, 3x the median)``: a fold or a mix of two surfaces fails) and its camera
position lies in the frame ``[0, Wc-1] x [0, Hc-1]``. With ``to_frame_edge`` the centroid is measured
from where the window's own centroid lies over the projector frame (:func:`frame_centroid`): the frame's
outermost pixels, whose samples can only lie on its inner side, are claimed too.
"""

from __future__ import annotations

import cv2
import numpy as np

MAX_RESIDUAL_PX = 0.5
MAX_CENTROID = 0.35  # samples' weighted centroid from where the frame's pixels would put it / sigma
MIN_SPREAD = 0.3  # smallest eigenvalue of the samples' spread / sigma^2
TARGET_NOISE_PX = 0.015  # aim of the window size: decode noise / sqrt(effective samples)
SIGMA_RANGE = (0.7, 3.0)  # window (Gaussian sigma, projector px)
WINDOW_RADIUS = 2.5  # Gaussian windows are cut at this many sigma


def window_sigma(noise_px: float, density: float) -> float:
    """The Gaussian window whose ``4 pi sigma^2 density`` effective samples bring ``noise_px`` to the target.

    Args:
        noise_px: typical decode noise of one camera sample, projector px.
        density: camera samples per projector pixel.
    """
    samples = (noise_px / TARGET_NOISE_PX) ** 2
    return float(np.clip(np.sqrt(samples / (4 * np.pi * max(density, 1e-6))), *SIGMA_RANGE))


def invert_map(
    xp: np.ndarray,
    yp: np.ndarray,
    ok: np.ndarray,
    size: tuple[int, int],
    noise_px: float = 0.0,
    to_frame_edge: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """The projector -> camera flow of a decoded camera -> projector map.

    Args:
        xp, yp, ok: ``(Hc, Wc)``: the projector position each camera pixel sees, and where it is known.
        size: the projector's ``(H, W)``.
        noise_px: typical noise of ``xp``/``yp`` (projector px); sets the window (``window_sigma``).
        to_frame_edge: also claim the projector frame's outermost pixels, whose samples can only lie on
            its inner side: their centroid is measured from where the frame's own pixels would put it.

    Returns:
        ``(flow, valid)``: ``(H, W, 2)`` float32 camera px minus projector px (0 where not valid) and
        ``(H, W)`` bool.
    """
    h, w = size
    cy, cx = np.nonzero(ok)
    px, py = xp[ok].astype(np.float64), yp[ok].astype(np.float64)
    if px.size == 0:
        return np.zeros((h, w, 2), np.float32), np.zeros((h, w), bool)
    bx = np.clip(np.rint(px), 0, w - 1).astype(np.int64)
    by = np.clip(np.rint(py), 0, h - 1).astype(np.int64)
    index = by * w + bx
    density = px.size / np.unique(index).size
    m = _bin_moments(index, px - bx, py - by, cx - bx, cy - by, (h, w))
    flow, valid = np.zeros((h, w, 2), np.float32), np.zeros((h, w), bool)
    sigma, limit = window_sigma(noise_px, density), None
    while True:  # where the widest window fails (curvature, a fold, an edge), narrower ones may pass
        centre = frame_centroid(size, sigma) if to_frame_edge else (0.0, 0.0)
        f, v, limit = _fit(_window_moments(m, sigma), sigma, size, ok.shape, limit, centre)
        new = v & ~valid
        flow[new], valid[new] = f[new], True
        if sigma <= SIGMA_RANGE[0]:
            return flow, valid
        sigma = max(SIGMA_RANGE[0], sigma / 1.5)


def _bin_moments(index, dx, dy, fx, fy, size: tuple[int, int]) -> dict[str, np.ndarray]:  # noqa: ANN001
    """Per projector pixel, sums over its samples of 1, d, f and their products (``(H, W)`` float64)."""
    h, w = size
    terms = {
        "n": None,
        "dx": dx,
        "dy": dy,
        "dxx": dx * dx,
        "dxy": dx * dy,
        "dyy": dy * dy,
        "fx": fx,
        "fy": fy,
        "fxdx": fx * dx,
        "fxdy": fx * dy,
        "fydx": fy * dx,
        "fydy": fy * dy,
        "ff": fx * fx + fy * fy,
    }
    return {k: np.bincount(index, v, h * w).astype(np.float64).reshape(h, w) for k, v in terms.items()}


def _window_moments(m: dict[str, np.ndarray], sigma: float) -> dict[str, np.ndarray]:
    """The Gaussian-weighted moments of the fit at every pixel ``X`` (offsets taken from ``X``)."""
    r = int(np.ceil(WINDOW_RADIUS * sigma))
    t = np.arange(-r, r + 1, dtype=np.float64)
    g = np.exp(-t * t / (2 * sigma * sigma))
    k0, k1, k2 = g, g * t, g * t * t

    def conv(img: np.ndarray, kx: np.ndarray, ky: np.ndarray) -> np.ndarray:
        # sum_o K(o) img(X - o): correlation with the kernels reversed
        return cv2.sepFilter2D(img, cv2.CV_64F, kx[::-1].copy(), ky[::-1].copy(), borderType=cv2.BORDER_CONSTANT)

    def G(img: np.ndarray) -> np.ndarray:
        return conv(img, k0, k0)

    def Gx(img: np.ndarray) -> np.ndarray:  # weight G(o) o_x
        return conv(img, k1, k0)

    def Gy(img: np.ndarray) -> np.ndarray:
        return conv(img, k0, k1)

    n = m["n"]
    gxx, gyy, gxy = conv(n, k2, k0), conv(n, k0, k2), conv(n, k1, k1)
    gx_n, gy_n = Gx(n), Gy(n)
    gx_dx, gy_dx, gx_dy, gy_dy = Gx(m["dx"]), Gy(m["dx"]), Gx(m["dy"]), Gy(m["dy"])
    gx_fx, gy_fx, gx_fy, gy_fy = Gx(m["fx"]), Gy(m["fx"]), Gx(m["fy"]), Gy(m["fy"])
    # d' = d - o and f' = f - o at X = B + o; expand each product
    return {
        "w": G(n),
        "dx": G(m["dx"]) - gx_n,
        "dy": G(m["dy"]) - gy_n,
        "dxx": G(m["dxx"]) - 2 * gx_dx + gxx,
        "dxy": G(m["dxy"]) - gx_dy - gy_dx + gxy,
        "dyy": G(m["dyy"]) - 2 * gy_dy + gyy,
        "fx": G(m["fx"]) - gx_n,
        "fy": G(m["fy"]) - gy_n,
        "fxdx": G(m["fxdx"]) - gx_fx - gx_dx + gxx,
        "fxdy": G(m["fxdy"]) - gy_fx - gx_dy + gxy,
        "fydx": G(m["fydx"]) - gx_fy - gy_dx + gxy,
        "fydy": G(m["fydy"]) - gy_fy - gy_dy + gyy,
        "ff": G(m["ff"]) - 2 * gx_fx - 2 * gy_fy + gxx + gyy,
        "n": conv(n, (g > 0.05).astype(np.float64), (g > 0.05).astype(np.float64)),  # samples in the window
    }


def frame_centroid(size: tuple[int, int], sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """``(ex, ey)``, ``(H, W)`` each: from each pixel of a frame of ``size``, the centroid of a Gaussian window
    of ``sigma`` (radius ``2.5 sigma``) over the frame's own pixels: 0 inside, towards the inside within a
    window of the frame's border, where samples can only lie on one side."""
    r = int(np.ceil(WINDOW_RADIUS * sigma))
    t = np.arange(-r, r + 1, dtype=np.float64)
    g = np.exp(-t * t / (2 * sigma * sigma))
    frame = np.ones(size)

    def conv(kx: np.ndarray, ky: np.ndarray) -> np.ndarray:
        return cv2.sepFilter2D(frame, cv2.CV_64F, kx, ky, borderType=cv2.BORDER_CONSTANT)

    weight = conv(g, g)
    return conv(g * t, g) / weight, conv(g, g * t) / weight


def _fit(  # noqa: ANN202
    s: dict[str, np.ndarray],
    sigma: float,
    size: tuple[int, int],
    cam: tuple[int, int],
    limit: float | None,
    centre: tuple[np.ndarray | float, np.ndarray | float],
):
    """Solve the 3 x 3 weighted least squares per pixel and apply the validity rules (module docstring).

    ``limit``: the residual limit (None: ``max(MAX_RESIDUAL_PX, 3x the median residual)`` of this fit,
    returned for the narrower windows). ``centre``: where the samples' centroid should lie, from each pixel
    (:func:`_frame_centroid`, or 0)."""
    h, w = size
    hc, wc = cam
    cand = np.nonzero(s["n"].ravel() >= 4)[0]
    g = {k: v.ravel()[cand] for k, v in s.items()}
    A = np.empty((cand.size, 3, 3))
    A[:, 0] = np.stack([g["w"], g["dx"], g["dy"]], 1)
    A[:, 1] = np.stack([g["dx"], g["dxx"], g["dxy"]], 1)
    A[:, 2] = np.stack([g["dy"], g["dxy"], g["dyy"]], 1)
    bx = np.stack([g["fx"], g["fxdx"], g["fxdy"]], 1)
    by = np.stack([g["fy"], g["fydx"], g["fydy"]], 1)
    mx, my = g["dx"] / g["w"], g["dy"] / g["w"]
    cxx, cxy, cyy = g["dxx"] / g["w"] - mx * mx, g["dxy"] / g["w"] - mx * my, g["dyy"] / g["w"] - my * my
    spread = 0.5 * (cxx + cyy) - np.hypot(0.5 * (cxx - cyy), cxy)  # smallest eigenvalue of the spread
    ex, ey = (np.broadcast_to(c, size).ravel()[cand] for c in centre)
    good = (np.hypot(mx - ex, my - ey) <= MAX_CENTROID * sigma) & (spread >= MIN_SPREAD * sigma * sigma)
    A[~good] = np.eye(3)
    beta_x = np.linalg.solve(A, bx[..., None])[..., 0]
    beta_y = np.linalg.solve(A, by[..., None])[..., 0]
    rss = g["ff"] - np.einsum("ij,ij->i", beta_x, bx) - np.einsum("ij,ij->i", beta_y, by)
    rms = np.sqrt(np.maximum(rss, 0) / g["w"])
    if limit is None:
        limit = max(MAX_RESIDUAL_PX, 3 * float(np.median(rms[good]))) if good.any() else MAX_RESIDUAL_PX
    good &= rms <= limit
    X, Y = cand % w, cand // w
    u, v = beta_x[:, 0], beta_y[:, 0]
    good &= (X + u >= 0) & (X + u <= wc - 1) & (Y + v >= 0) & (Y + v <= hc - 1)
    flow = np.zeros((h * w, 2), np.float32)
    valid = np.zeros(h * w, bool)
    flow[cand[good], 0], flow[cand[good], 1] = u[good], v[good]
    valid[cand[good]] = True
    return flow.reshape(h, w, 2), valid.reshape(h, w), limit
