"""Sub-pixel decoding of binary Gray-code stripes (OpenCV's layout) from where each pattern and its inverse cross.

OpenCV's ``GrayCodePattern`` decoder gives each camera pixel the integer column and row of its code, so
its positions are off by up to half a projector pixel. Here, per camera pixel and projector axis:

1. **Code**: bit ``b`` is the sign of ``diff = pattern - inverse``; the Gray code gives the projector
   column (row) ``n``, whose pixel covers ``[n - 0.5, n + 0.5]``.
2. **Edges**: between two camera pixels adjacent along x or y whose codes differ by ``s`` in
   ``1..MAX_STEP``, each boundary ``m + 0.5`` in between belongs to one bit, ``ctz(m + 1)`` (a Gray code
   changes one bit per step); where that bit flips once between the two pixels its ``diff`` crosses zero
   at ``t = diff(a) / (diff(a) - diff(b))`` of the way from ``a`` to ``b``. The crossing is where the
   pattern's light equals the inverse's: a symmetric blur, albedo, ambient light and any monotone
   camera response leave it in place.
3. **Position**: a Gaussian-weighted local linear fit ``v = a + g . (q - c)`` of the boundary values
   ``v`` against the crossings' camera positions ``q`` around pixel ``c`` (moving least squares); ``a``
   is the sub-pixel position. The window is ``WINDOW_EDGES`` boundary spacings wide (measured). Each
   crossing also weighs by how sharply ``diff`` crosses (:func:`edge_crossings`): a fine bit that defocus
   or the camera's pixels wash out adds crossings the noise places, and they weigh next to nothing.

Masks come from the data, not fixed levels. The noise of ``diff`` is measured per pixel
(:func:`diff_noise`): where a bit is clear of its own edge its ``pattern + inverse`` equals ``white +
black`` for any response, so the median over the clear bits of ``|pattern + inverse - white - black|``
(twice the sensor noise), averaged over ``NOISE_WINDOW`` px, gives ``sigma`` of ``diff``; never less than
an 8-bit photo's quantisation (``MIN_DIFF_NOISE``), which is all the noise a noise-free photo has. A pixel
is kept where ``white - black > MIN_CONTRAST_SNR sigma``, every bit more than ``BIT_MARGIN_PX`` from its
own edge has the expected sign with ``|diff| > MIN_BIT_SNR sigma``, the crossings surround it (their
centroid measured from where the window's own centroid lies over the camera frame, so that the frame's
border is no exception; in the projector frame's first and last column or row, whose boundaries lie on
one side, the fit extrapolates), the fit's residual is small and its position lies within
``CODE_TOLERANCE_PX`` of its code and inside the projector. The camera -> projector positions then go
through :func:`projsynth.structured.invert.invert_map` like the fringe decoder's, there to the projector
frame's edge (``to_frame_edge``), as OpenCV's integer codes reach it.
"""

from __future__ import annotations

import cv2
import numpy as np

from .graybits import bits_agree, gray_stripe
from .invert import TARGET_NOISE_PX, WINDOW_RADIUS, frame_centroid

MAX_STEP = 3  # largest code step between adjacent camera pixels whose boundaries are located (camera coarser)
WINDOW_EDGES = 1.5  # Gaussian sigma of the fit, in boundary spacings (camera px between crossings)
WINDOW_RANGE = (1.0, 8.0)  # ... clipped to this, camera px
MIN_SPREAD = 0.05  # smallest eigenvalue of the crossings' spread / sigma^2: two boundaries at least
# crossings' weighted centroid from where the window's own lies over the camera frame (the pixel, inside it)
# / sigma: interpolation, not extrapolation
MAX_CENTROID = 0.75
MAX_RESIDUAL_PX = 0.3  # RMS misfit of the crossings' values to the local plane, projector px
CODE_TOLERANCE_PX = 1.0  # sub-pixel position vs the integer code (a bit flipped by noise at its edge: 0.5-1)
NOISE_WINDOW = 7  # px, box over which the per-pixel noise of diff is averaged
MIN_CONTRAST_SNR = 6.0  # white - black over the noise of diff
MIN_BIT_SNR = 3.0  # |pattern - inverse| over its noise, for a bit far from its own edge
# a bit is clear of its own edge (and counts in the noise of diff) where |pattern - inverse| is at least this
# share of white - black: near its edge a camera response that is not linear, or clipping, adds to e_b
CLEAR_BIT = 0.9
# the least noise of diff: an 8-bit photo's quantisation (step / sqrt(12) per photo, two photos), so that on
# noise-free photos a clear bit must still differ by a count and an unlit pixel is not "lit" by one count
MIN_DIFF_NOISE = 1 / (255 * 6**0.5)
# the fits' RMS residual at this percentile is the position noise handed to invert_map (it sets its window):
# the residual sees the crossings' scatter, not the interpolation error they share, so a high percentile
NOISE_PERCENTILE = 95
# the projector-side fit averages at least this many camera samples: precise positions alone would ask
# invert_map for windows so narrow that a discrete sampling fails its surround rules (on the analytic rig
# of test_decode.py at 240 x 320: 16% of the in-frame projector left out at 7 samples, 2.7% at 16)
MIN_WINDOW_SAMPLES = 16


def decode_edges(
    stack: dict[str, np.ndarray], bits_x: int, bits_y: int, size: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, dict]:
    """Per camera pixel, the sub-pixel projector position it sees (module docstring).

    Args:
        stack: photos ``(Hc, Wc)`` float32 in [0, 1] by pattern name without ``NN-``: ``col{b}``,
            ``col{b}-inv``, ``row{b}``, ``row{b}-inv``, ``white``, ``black``.
        bits_x, bits_y: column and row bits.
        size: the projector's ``(H, W)``.

    Returns:
        ``(xp, yp, ok, noise_px, stats)``: ``(Hc, Wc)`` float64 projector x and y (pixel centres at
        integers), ``(Hc, Wc)`` bool where both are trusted, the noise of one position (projector px: the
        fits' RMS residual at ``NOISE_PERCENTILE``, the larger axis) and, for ``decode.json``, the
        median noise of ``diff`` in 8-bit DN and the counts of lit camera pixels and of those whose
        code lies beyond ``size`` (a wrong projector size).
    """
    white, black = stack["white"], stack["black"]
    diffs = {
        a: [stack[f"{a}{b}"] - stack[f"{a}{b}-inv"] for b in range(n)] for a, n in (("col", bits_x), ("row", bits_y))
    }
    sigma = diff_noise(stack, bits_x, bits_y)
    lit = white - black > MIN_CONTRAST_SNR * sigma
    ok = lit.copy()
    coords, noises, codes = [], [], {}
    for axis, extent in (("col", size[1]), ("row", size[0])):
        code = gray_stripe(diffs[axis])
        codes[axis] = code
        trusted = lit & bits_agree(diffs[axis], code.astype(np.float64), 1, MIN_BIT_SNR * sigma)
        pos, fit_ok, noise = _fit_edges(diffs[axis], code, trusted, white - black, extent)
        ok &= trusted & fit_ok & (np.abs(pos - code) <= CODE_TOLERANCE_PX) & (pos >= -0.5) & (pos <= extent - 0.5)
        coords.append(pos)
        noises.append(noise)
    beyond = lit & ((codes["col"] >= size[1]) | (codes["row"] >= size[0]))
    stats = {
        "diff_noise_dn": round(float(np.median(sigma[lit])) * 255, 3) if lit.any() else None,
        "camera_pixels_lit": int(lit.sum()),
        "camera_pixels_beyond_projector": int(beyond.sum()),
    }
    return coords[0], coords[1], ok, max(noises), stats


def window_noise(noise_px: float) -> float:
    """The position noise to hand :func:`~projsynth.structured.invert.invert_map`: the measured one, but
    never below what makes its window hold ``MIN_WINDOW_SAMPLES`` samples (it holds ``(noise / target)^2``)."""
    return max(noise_px, TARGET_NOISE_PX * float(np.sqrt(MIN_WINDOW_SAMPLES)))


def diff_noise(stack: dict[str, np.ndarray], bits_x: int, bits_y: int) -> np.ndarray:
    """``(Hc, Wc)`` float32: the standard deviation of one ``pattern - inverse`` at each camera pixel.

    ``e_b = pattern_b + inverse_b - white - black`` is 0 plus four photos' noise (sigma ``2 s``) where bit
    ``b`` is clear of its own edge; near the edge a camera response that is not linear, or clipping, adds to
    it. So only the clear bits count: ``|pattern - inverse|`` at least ``CLEAR_BIT`` of ``white - black``
    (``pattern + inverse`` and ``pattern - inverse`` have independent noise, so the choice does not bias
    ``e_b``); the median of their ``|e_b|`` is ``0.6745 * 2 s``, and ``diff`` has ``sqrt(2) s``. Averaged over
    ``NOISE_WINDOW`` px (a pixel without a clear bit takes its neighbours'), never below ``MIN_DIFF_NOISE``.
    """
    white, black = stack["white"], stack["black"]
    names = [f"{a}{b}" for a, n in (("col", bits_x), ("row", bits_y)) for b in range(n)]
    clear = np.stack([np.abs(stack[k] - stack[f"{k}-inv"]) >= CLEAR_BIT * (white - black) for k in names])
    e = np.stack([np.abs(stack[k] + stack[f"{k}-inv"] - white - black) for k in names])  # [B, Hc, Wc]
    e = np.sort(np.where(clear, e, np.inf), axis=0)  # the clear bits' |e_b| first, in order
    count = clear.sum(axis=0)
    middle = [np.take_along_axis(e, np.maximum(i, 0)[None], 0)[0] for i in ((count - 1) // 2, count // 2)]
    s = np.where(count > 0, 0.5 * (middle[0] + middle[1]), 0) / (0.6745 * 2)
    has = (count > 0).astype(np.float32)
    box = (NOISE_WINDOW, NOISE_WINDOW)
    s2 = cv2.blur((s * s).astype(np.float32), box, borderType=cv2.BORDER_REFLECT)
    n = cv2.blur(has, box, borderType=cv2.BORDER_REFLECT)
    s2 = np.maximum(s2, 0) / np.maximum(n, np.float32(1 / NOISE_WINDOW**2))  # a box sum can dip below 0
    return np.maximum(np.sqrt(2 * s2), np.float32(MIN_DIFF_NOISE))


def edge_crossings(
    diffs: list[np.ndarray], code: np.ndarray, trusted: np.ndarray, contrast: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every located stripe boundary between adjacent trusted camera pixels (module docstring, step 2).

    ``contrast``: ``(Hc, Wc)`` white - black.

    Returns:
        ``(qx, qy, v, weight)``: 1-D float64, the crossing's camera position, its projector coordinate
        ``m + 0.5`` and its weight in the fit: the square of how sharply ``diff`` crosses, ``diff(a) - diff(b)``
        over the two pixels' ``white - black`` (1: a sharp edge between them; near 0: a bit that defocus or
        the camera's pixels wash out, whose crossing the noise places).
    """
    hc, wc = code.shape
    qx, qy, vs, ws = [], [], [], []
    for dy, dx in ((0, 1), (1, 0)):
        a = (slice(0, hc - dy), slice(0, wc - dx))
        b = (slice(dy, hc), slice(dx, wc))
        step = code[b] - code[a]
        pair = trusted[a] & trusted[b] & (np.abs(step) >= 1) & (np.abs(step) <= MAX_STEP)
        ya, xa = np.nonzero(pair)
        span = contrast[a][pair] + contrast[b][pair]
        lo = np.minimum(code[a][pair], code[b][pair])
        s = np.abs(step[pair])
        for i in range(MAX_STEP):
            m = lo + i  # boundary m + 0.5, if i < s
            bit = _ctz(m + 1)
            once = i < s
            for j in range(MAX_STEP):  # the bit must flip exactly once between the two pixels
                other = (j != i) & (j < s)
                once &= ~(other & (_ctz(lo + j + 1) == bit))
            for b_index, diff in enumerate(diffs):
                sel = once & (bit == b_index)
                if not sel.any():
                    continue
                da, db = diff[a][pair][sel], diff[b][pair][sel]
                cross = da * db < 0
                t = da[cross] / (da[cross] - db[cross])
                qx.append(xa[sel][cross] + dx * t)
                qy.append(ya[sel][cross] + dy * t)
                vs.append(m[sel][cross] + 0.5)
                ws.append(np.minimum(((da[cross] - db[cross]) / span[sel][cross]) ** 2, 1.0))
    if not vs:
        return np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0)
    return tuple(np.concatenate(c).astype(np.float64) for c in (qx, qy, vs, ws))


def _fit_edges(
    diffs: list[np.ndarray], code: np.ndarray, trusted: np.ndarray, contrast: np.ndarray, extent: int
) -> tuple[np.ndarray, np.ndarray, float]:
    """The local linear fit of the crossings, each weighted by its sharpness (module docstring, step 3).

    Returns:
        ``(pos, ok, noise)``: ``(Hc, Wc)`` float64 projector coordinate (the code where the fit fails),
        ``(Hc, Wc)`` bool where it holds, and its RMS residual at ``NOISE_PERCENTILE`` (projector px).
    """
    hc, wc = code.shape
    qx, qy, v, weight = edge_crossings(diffs, code, trusted, contrast)
    if v.size < 3:
        return code.astype(np.float64), np.zeros(code.shape, bool), 0.0
    spacing = max(trusted.sum(), 1) / v.size  # camera px per boundary, along a camera axis
    sigma = float(np.clip(WINDOW_EDGES * spacing, *WINDOW_RANGE))
    bx = np.clip(np.rint(qx), 0, wc - 1).astype(np.int64)
    by = np.clip(np.rint(qy), 0, hc - 1).astype(np.int64)
    index = by * wc + bx
    terms = {
        "count": None,
        "n": weight,
        "x": weight * qx,
        "y": weight * qy,
        "xx": weight * qx * qx,
        "xy": weight * qx * qy,
        "yy": weight * qy * qy,
        "v": weight * v,
        "vx": weight * v * qx,
        "vy": weight * v * qy,
        "vv": weight * v * v,
    }
    r = int(np.ceil(WINDOW_RADIUS * sigma))
    t = np.arange(-r, r + 1, dtype=np.float64)
    g = np.exp(-t * t / (2 * sigma * sigma))
    # weights depend on the bin offset only (Gaussian over bins), so every moment is one separable filter
    m = {
        k: cv2.sepFilter2D(
            np.bincount(index, w, hc * wc).reshape(hc, wc).astype(np.float64),
            cv2.CV_64F,
            g,
            g,
            borderType=cv2.BORDER_CONSTANT,
        )
        for k, w in terms.items()
    }
    cy, cx = np.mgrid[0:hc, 0:wc].astype(np.float64)
    w = np.maximum(m["n"], 1e-12)
    mx, my = m["x"] / w - cx, m["y"] / w - cy  # centroid relative to the pixel
    cxx = m["xx"] / w - (m["x"] / w) ** 2
    cxy = m["xy"] / w - (m["x"] / w) * (m["y"] / w)
    cyy = m["yy"] / w - (m["y"] / w) ** 2
    cvx = m["vx"] / w - (m["v"] / w) * (m["x"] / w)
    cvy = m["vy"] / w - (m["v"] / w) * (m["y"] / w)
    det = cxx * cyy - cxy * cxy
    spread = 0.5 * (cxx + cyy) - np.hypot(0.5 * (cxx - cyy), cxy)
    # the frame's first and last column (row) have boundaries on one side only: there the fit extrapolates,
    # by at most the pixel's own half width (the position must stay in the frame and near its code)
    outer = (code == 0) | (code == extent - 1)
    ex, ey = frame_centroid((hc, wc), sigma)  # at the camera frame's border too the crossings are one-sided
    centred = np.hypot(mx - ex, my - ey) <= MAX_CENTROID * sigma
    good = (m["count"] > 0.5) & (spread >= MIN_SPREAD * sigma * sigma) & (centred | outer)
    det = np.where(good, det, 1.0)
    gx = (cvx * cyy - cvy * cxy) / det
    gy = (cvy * cxx - cvx * cxy) / det
    pos = m["v"] / w - gx * mx - gy * my  # the plane through the weighted means, evaluated at the pixel
    cvv = m["vv"] / w - (m["v"] / w) ** 2
    rms = np.sqrt(np.maximum(cvv - gx * cvx - gy * cvy, 0))
    good &= rms <= MAX_RESIDUAL_PX
    typical = float(np.percentile(rms[good], NOISE_PERCENTILE)) if good.any() else 0.0
    return np.where(good, pos, code), good, typical


def _ctz(n: np.ndarray) -> np.ndarray:
    """Trailing zero bits of positive int64 ``n``: the Gray-code bit that flips between ``n - 1`` and ``n``."""
    low = n & -n
    return np.log2(low.astype(np.float64)).astype(np.int64)
