"""What the images say about a flow beyond its photometric score: whether a plane explains it, where
it may move outside its support, whether the content repeats (periodicity), and why a pair is not
verified.
"""

from __future__ import annotations

import math
from functools import lru_cache

import cv2
import numpy as np

from projsynth.utils.jit import jit

from ..geometry.images import weighted_ncc
from ..geometry.warp import warp_back


def bound_outside(flow: np.ndarray, prior: np.ndarray, support: np.ndarray, bound: float) -> np.ndarray:
    """``flow`` where ``support`` is true; elsewhere moved at most ``bound`` px away from ``prior``.

    Example:
        >>> f = np.array([[[30.0, 40.0], [1.0, 0.0]]], np.float32)
        >>> bound_outside(f, np.zeros_like(f), np.array([[False, False]]), 5.0)[0].tolist()
        [[3.0, 4.0], [1.0, 0.0]]
    """
    return _bound_outside(flow.astype(np.float32, copy=False), prior.astype(np.float32, copy=False), support, bound)


@jit
def _bound_outside(flow, prior, support, bound):  # pragma: no cover - numba
    h, w = flow.shape[:2]
    out = np.empty((h, w, 2), np.float32)
    limit, one, tiny = np.float32(bound), np.float32(1.0), np.float32(1e-6)  # float32 throughout
    for y in range(h):
        for x in range(w):
            du = flow[y, x, 0] - prior[y, x, 0]
            dv = flow[y, x, 1] - prior[y, x, 1]
            scale = one if support[y, x] else min(one, limit / max(math.hypot(du, dv), tiny))
            out[y, x, 0] = prior[y, x, 0] + du * scale
            out[y, x, 1] = prior[y, x, 1] + dv * scale
    return out


def registers(claimed: np.ndarray, share: float, windows: float, sigma: float) -> bool:
    """Whether a claim ``claimed`` (bool ``(H, W)``) is evidence enough to register the pair: at least
    ``share`` of the frame and at least ``windows`` local-NCC windows of Gaussian ``sigma`` (px) of area
    (``pi (2 sigma)^2`` each).

    The checks are per pixel, read from windows of that size: on a photo of another picture they pass by
    chance where two windows happen to look alike, on up to 4 windows' area of a frame (docs/model.md).
    In a small frame that is several percent of it, so the count of windows, not the share, tells a
    claim from chance there.

    Example:
        >>> claim = np.zeros((192, 256), bool); claim[:40, :60] = True  # 2,400 px, 4.9 % of the frame
        >>> registers(claim, 0.01, 6.0, 7.0), registers(claim, 0.01, 6.0, 3.5)
        (False, True)
    """
    count = int(claimed.sum())
    return count >= share * claimed.size and count >= windows * np.pi * (2 * sigma) ** 2


def unverified(claimed: np.ndarray, repeating: np.ndarray | None, textured: np.ndarray, share: float = 0.5) -> str:
    """Why a pair that passed no check is not registered: a repeating pattern when at least ``share`` of
    its texture repeats itself (no check can tell the right period from the next), else ``no region
    verified`` (what passes the checks is too little to tell from chance: :func:`registers`)."""
    repeats = 0.0 if repeating is None or not textured.any() else float(repeating[textured].mean())
    if repeats >= share:
        period = "a flow one period off would pass every check"
        return f"repeating pattern: {100 * repeats:.0f}% of the projected texture repeats itself ({period})"
    passed = f"{100 * claimed.mean():.1f}% of the frame passes the checks"
    return f"no region verified ({passed}, too little to tell from chance)"


def repeating(
    gray: np.ndarray,
    fine_peak: float = 0.85,
    coarse_peak: float = 0.93,
    tiles: tuple[int, ...] = (64, 128, 256),
    lobe: float = 0.3,
    overlap: float = 0.25,
) -> np.ndarray:
    """Pixels where the image repeats itself, bool ``(H, W)``: :func:`periodicity` at least ``fine_peak``
    in the first of ``tiles`` (px) or ``coarse_peak`` in the others (those that fit the image); ``lobe``
    and ``overlap``: :func:`periodicity`'s.

    The coarse windows ask for a closer repeat: a photograph of a regular thing (a brick wall) scores
    0.83-0.91 there, from its courses, while its detail differs from one brick to the next, which the
    photometric check sees; a repeated digital motif scores 0.98-1.00 (docs/model.md)."""
    out = np.zeros(gray.shape, bool)
    for job in repeat_jobs(gray, fine_peak, coarse_peak, tiles, lobe, overlap):
        out |= repeats_in(*job)
    return out


def repeat_jobs(
    gray: np.ndarray, fine_peak: float, coarse_peak: float, tiles: tuple[int, ...], lobe: float, overlap: float
) -> list[tuple]:
    """:func:`repeating`'s windows as independent jobs, the arguments of :func:`repeats_in` each (a caller
    with threads runs them side by side and ORs the maps); windows larger than the image are left out."""
    return [
        (gray, tile, coarse_peak if i else fine_peak, lobe, overlap)
        for i, tile in enumerate(tiles)
        if min(gray.shape) >= tile
    ]


def repeats_in(gray: np.ndarray, tile: int, peak: float, lobe: float, overlap: float) -> np.ndarray:
    """Where :func:`periodicity` in ``tile`` px windows reaches ``peak``, bool ``(H, W)``."""
    return periodicity(gray, tile, lobe, overlap) >= peak


def periodicity(gray: np.ndarray, tile: int = 64, lobe: float = 0.3, overlap: float = 0.25) -> np.ndarray:
    """Per pixel, how well the image repeats itself around it, float32 ``(H, W)`` in [0, 1]: near 1 on a
    grating, a checkerboard or a tiled motif, whose match one period away is as good as the true
    one; low on an edge or a ramp, which stay similar under every move along them (the aperture
    problem, which the smooth surface model resolves from their neighbours).

    Each ``tile`` x ``tile`` window (side by side, Hann-weighted) gives its autocorrelation (FFT,
    zero-padded, divided by the window's own so a shift is not penalised for the smaller overlap);
    the score is its highest value outside the central lobe (the connected region >= ``lobe`` around zero
    shift, which holds an edge's ridge), within half a tile; the tiles' scores are interpolated over
    the frame. The window's edge weights leave periods up to about ``0.45 tile`` visible (64: 28 px).

    Example:
        >>> x = np.arange(128, dtype=np.float32)
        >>> grating = np.tile(128 + 100 * np.sin(2 * np.pi * x / 7), (96, 1)).astype(np.uint8)
        >>> bool(periodicity(grating)[48, 64] > 0.8)
        True
        >>> edge = np.tile(np.where(x < 64, 40, 200), (96, 1)).astype(np.uint8)
        >>> bool(periodicity(edge)[48, 64] < 0.3)
        True
    """
    h, w = gray.shape
    if min(h, w) < tile:
        return np.zeros((h, w), np.float32)
    g = gray.astype(np.float32)
    starts = [np.unique(np.r_[np.arange(0, n - tile + 1, tile), n - tile]) for n in (h, w)]
    hann, window = _hann_window(tile)
    tiles = np.stack([g[y : y + tile, x : x + tile] for y in starts[0] for x in starts[1]])  # [T, tile, tile]
    tiles = (tiles - tiles.mean(axis=(1, 2), keepdims=True)) * hann
    live = np.flatnonzero(tiles.std(axis=(1, 2)) >= 1e-3)  # a flat tile does not repeat (score 0)
    ac = _autocorrelation(tiles[live]) / window  # [T', tile + 1, tile + 1]
    ac = ac / np.maximum(ac[:, tile // 2, tile // 2 : tile // 2 + 1, None], 1e-6)
    ac[:, window < overlap * window.max()] = 0.0  # shifts whose windows barely overlap say nothing
    scores = np.zeros(len(tiles), np.float32)
    for i, a in zip(live, ac, strict=True):
        if not np.isfinite(a).all():
            continue
        _, labels = cv2.connectedComponents((a >= lobe).astype(np.uint8), connectivity=8)
        outside = labels != labels[tile // 2, tile // 2]
        scores[i] = float(np.clip(a[outside].max(initial=0.0), 0.0, 1.0))
    grid = scores.reshape(len(starts[0]), len(starts[1]))
    centres = [s + tile / 2 for s in starts]  # tile centres, px
    x, y = (
        np.interp(np.arange(w), centres[1], np.arange(len(centres[1]))),
        np.interp(np.arange(h), centres[0], np.arange(len(centres[0]))),
    )
    mx, my = np.meshgrid(x.astype(np.float32), y.astype(np.float32))
    return cv2.remap(grid, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _autocorrelation(a: np.ndarray) -> np.ndarray:
    """The linear autocorrelation of ``tile x tile`` arrays ``a`` ``[..., tile, tile]`` at shifts up to half a
    tile each way, ``[..., tile + 1, tile + 1]`` with zero shift at the centre: by FFT zero-padded to 1.5
    tiles, the least that keeps those shifts free of the circular wrap. OpenCV's real transforms, one tile
    at a time (a third of numpy's time on these sizes), in float32."""
    tile = a.shape[-1]
    n = tile + tile // 2
    shifts = np.arange(-(tile // 2), tile // 2 + 1) % n  # zero shift at the centre
    flat = np.asarray(a, np.float32).reshape(-1, tile, tile)
    out = np.empty((len(flat), tile + 1, tile + 1), np.float32)
    padded = np.zeros((n, n), np.float32)
    for i, x in enumerate(flat):
        padded[:tile, :tile] = x
        spectrum = cv2.dft(padded)  # packed real transform
        power = cv2.mulSpectrums(spectrum, spectrum, 0, conjB=True)
        ac = cv2.dft(power, flags=cv2.DFT_INVERSE | cv2.DFT_SCALE | cv2.DFT_REAL_OUTPUT)
        out[i] = ac[np.ix_(shifts, shifts)]
    return out.reshape(*a.shape[:-2], tile + 1, tile + 1)


@lru_cache(maxsize=8)
def _hann_window(tile: int) -> tuple[np.ndarray, np.ndarray]:
    """The 2-D Hann window of a tile and its own autocorrelation (floored at 1e-6): the weight each shift's
    overlap carries."""
    hann = np.outer(np.hanning(tile), np.hanning(tile)).astype(np.float32)
    return hann, np.maximum(_autocorrelation(hann), 1e-6)


def alignment_score(
    gray0: np.ndarray, gray1: np.ndarray, flow: np.ndarray, sigma: float = 7.0, weight: np.ndarray | None = None
) -> float:
    """How well ``flow`` aligns the pair: the mean of :func:`local_ncc` between ``gray0`` and ``gray1``
    warped back by ``flow``, weighted by ``weight`` (the projected image's texture; None: uniform).

    Weighting by texture makes the score count coverage: a flow that aligns one textured corner
    and misaligns the rest of the texture scores by the whole texture, not by a median that flat
    regions (NCC about 0 under any flow) dominate.
    """
    return weighted_ncc(gray0, warp_back(gray1, flow), sigma, weight)
