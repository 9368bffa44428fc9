"""Photometric models: how projected light and the scene combine into the captured image.

``paper`` (default, the paper's section 3.1.2)::

    captured = beta * a * (contrast * P_w + brightness) + (1 - beta * a) * gamma * B + N(mu, sigma^2)

with ``P_w`` the projected image warped into the camera (zero where the projector does not light the
camera pixel), ``a`` the projected content's normalised alpha warped the same way, and ``B`` the
background (the scene as the camera sees it).

``physical``: ``B`` is the surface reflectance; linear light
``L = B_lin * (ambient + power * P_lin)``, then defocus blur, camera gain and vignetting, shot and read
noise, and the camera's response curve ``L^(1/response)``. Intensities are on the 0-255 scale.
"""

from __future__ import annotations

from functools import lru_cache
from statistics import NormalDist

import cv2
import numpy as np

from ..utils.jit import jit

BLENDS = ("paper", "physical")
# The paper blend's parameters that leave the projected image as it is (full contrast, no background,
# no gamma, no noise): a render of geometry alone, as the render and compensation tests use it
PAPER_IDENTITY = {
    "contrast": 1.0,
    "brightness": 0.0,
    "beta": 1.0,
    "alpha": 1.0,
    "alpha_var": 0.0,
    "gamma": 0.0,
    "noise_mu": 0.0,
    "noise_sigma": 0.0,
}
SENSOR_NOISE = ("noise_sigma", "shot_noise", "read_noise")  # the random parts of both blends (noise_mu is a bias)


def noiseless(p: dict[str, float]) -> dict[str, float]:
    """Photometric parameters ``p`` with the sensor's random noise off and its bias kept: the mean of
    many photos of one still scene (how a fixed rig's white and black photos are best shot)."""
    return {**p, **{k: 0.0 for k in SENSOR_NOISE if k in p}}


def composite(
    blend: str,
    image: np.ndarray,
    xy: np.ndarray,
    lit: np.ndarray,
    background: np.ndarray,
    p: dict[str, float],
    rng: np.random.Generator,
) -> np.ndarray:
    """Light the scene with the projector and combine it with the background into the captured image.

    Args:
        blend: ``"paper"`` or ``"physical"``.
        image: ``(H, W, 4)`` uint8 projector frame and its transparency (the paper's ``a`` = channel 3 / 255).
        xy, lit: the backward map of the camera's ``H x W`` pixels, row-major: ``(2, H*W)`` projector
            positions and a ``(H*W,)`` mask of lit pixels (see ``scene.backward``). The frame is sampled
            there with :func:`sample_where` (0 where unlit): ``P_w`` and ``a`` in the module docstring.
        background: ``(H, W, 3)`` uint8 scene image in the camera frame.
        p: drawn photometric parameters (see ``transforms._CONDITIONS``).
        rng: the sample's generator (noise).

    Returns:
        ``(H, W, 3)`` uint8 captured image.
    """
    h, w = background.shape[:2]
    if blend == "paper":  # sampling, blend and noise in one pass over the pixels
        xy, lit = _positions(xy, lit)
        if lit.size != h * w:
            raise ValueError(f"composite needs one position per camera pixel ({h * w}), got {lit.size}")
        raw = _noise_bits(rng, h * w * 3)  # the bits of gaussian_noise(rng, (h, w, 3))
        return _paper(
            _rgba(image),
            xy[0],
            xy[1],
            lit,
            np.ascontiguousarray(background),
            raw,
            normal_table(),
            *(float(p[k]) for k in _PAPER),
        )
    if blend != "physical":
        raise ValueError(f"unknown blend {blend!r}")
    warped = sample_where(image, xy, lit).reshape(h, w, 4)
    out = _physical(warped[..., :3], warped[..., 3:] / 255.0, background.astype(np.float32), p, rng)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


_PAPER = ("beta", "contrast", "brightness", "gamma", "noise_mu", "noise_sigma")


@jit
def _paper(image, xs, ys, lit, background, raw, table, beta, contrast, brightness, gamma, mu, sigma):  # noqa: ANN001, ANN202
    """The paper's blend, pixel by pixel in float32, of the frame sampled at ``(xs, ys)`` where ``lit``
    (:func:`_bilinear4`), plus ``mu + sigma * noise`` (noise: ``table`` at 16-bit slices of ``raw``, as
    :func:`gaussian_noise`), rounded and clipped to uint8."""
    h, w = background.shape[0], background.shape[1]
    out = np.empty((h, w, 3), np.uint8)
    beta, contrast, brightness = np.float32(beta), np.float32(contrast), np.float32(brightness)
    gamma, mu, sigma = np.float32(gamma), np.float32(mu), np.float32(sigma)
    zero, full = np.float32(0.0), np.float32(255.0)
    for y in range(h):
        for x in range(w):
            i = y * w + x
            r = g = b = a = zero
            if lit[i] and np.isfinite(xs[i]) and np.isfinite(ys[i]):
                r, g, b, a = _bilinear4(image, xs[i], ys[i])
            wt = beta * (a / full)
            for c, fg in ((0, r), (1, g), (2, b)):
                out[y, x, c] = _blend1(
                    wt, fg, background[y, x, c], raw, table, 3 * i + c, contrast, brightness, gamma, mu, sigma
                )
    return out


@jit(inline=True)
def _blend1(wt, fg, bg, raw, table, k, contrast, brightness, gamma, mu, sigma):  # noqa: ANN001, ANN202
    """One channel of the paper's blend plus noise value ``k``, as uint8 (float32 throughout)."""
    noise = _normal1(raw, table, k)
    v = wt * (contrast * fg + brightness) + (np.float32(1.0) - wt) * gamma * np.float32(bg) + (noise * sigma + mu)
    return np.uint8(min(max(np.rint(v), 0.0), 255.0))


def gaussian_noise(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Standard normal noise, float32 of ``shape``: 16 random bits per value through a quantile table.

    Each value is ``normal_table()[b]`` for 16 bits ``b`` of the generator's raw 64-bit output (low bits
    first), i.e. the normal distribution quantised to 65,536 equally likely levels (tails cut at
    +-4.3 sigma; the table is scaled to unit variance). About 3x faster than numpy's float32
    ziggurat, which was the simulation's largest stage after the ray casts (docs/history/2026-11-log.md); for
    sensor noise added to 8-bit images the quantisation (a level spacing under 4e-5 sigma near 0) is
    invisible.
    """
    n = int(np.prod(shape))
    return _lookup16(_noise_bits(rng, n), normal_table(), n).reshape(shape)


def _noise_bits(rng: np.random.Generator, n: int) -> np.ndarray:
    """Raw 64-bit words holding 16 bits for each of ``n`` noise values (:func:`_normal1` reads them)."""
    return rng.bit_generator.random_raw(-(-n // 4))


@lru_cache(maxsize=1)
def normal_table() -> np.ndarray:
    """The 65,536 normal quantiles at ``(i + 0.5) / 65536``, scaled to unit variance, float32, read-only."""
    inv = NormalDist().inv_cdf
    table = np.array([inv((i + 0.5) / 65536) for i in range(65536)])
    table = (table / np.sqrt(np.mean(table**2))).astype(np.float32)
    table.flags.writeable = False
    return table


@jit
def _lookup16(raw, table, n):  # noqa: ANN001, ANN202
    out = np.empty(n, np.float32)
    for k in range(n):
        out[k] = _normal1(raw, table, k)
    return out


@jit(inline=True)
def _normal1(raw, table, k):  # noqa: ANN001, ANN202
    """Noise value ``k``: ``table`` at bits ``16 (k mod 4) ..`` of raw word ``k // 4``."""
    return table[(raw[k >> 2] >> np.uint64(16 * (k & 3))) & np.uint64(0xFFFF)]


def _gaussian(rng: np.random.Generator, shape: tuple, mu: float, sigma: float) -> np.ndarray:
    noise = gaussian_noise(rng, shape)
    noise *= np.float32(sigma)
    noise += np.float32(mu)
    return noise


def _physical(warped: np.ndarray, a: np.ndarray, bg: np.ndarray, p: dict, rng: np.random.Generator) -> np.ndarray:
    h, w = bg.shape[:2]
    reflect = (bg / 255.0) ** 2.2
    light = np.float32(p["ambient"]) + np.float32(p["power"]) * a * (warped / 255.0) ** 2.2
    lin = reflect * light
    if p["defocus_px"] > 0.05:
        lin = cv2.GaussianBlur(lin, (0, 0), p["defocus_px"])
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    r2 = ((xs - (w - 1) / 2) ** 2 + (ys - (h - 1) / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    lin = lin * (np.float32(p["gain"]) * (1 - np.float32(p["vignetting"]) * r2))[..., None]
    lin = np.clip(lin, 0, None)
    lin += np.sqrt(lin) * _gaussian(rng, lin.shape, 0.0, p["shot_noise"])
    out = 255.0 * np.clip(lin, 0, 1) ** (1.0 / p["response"])
    return out + _gaussian(rng, out.shape, 0.0, p["read_noise"])


def sample_bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Sample ``image`` ``(H, W, 4)`` uint8 at float positions with exact bilinear weights.

    Convention: pixel centres at integers; positions outside ``[0, W-1] x [0, H-1]`` (up to the
    frame's edge at -0.5 / W-0.5) take the border pixels' values; non-finite positions give 0.
    (``cv2.remap`` quantises positions to 1/32 px; ground truth needs the exact position.)

    Returns:
        ``(N, 4)`` float32.
    """
    image = _rgba(image)
    x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
    x, y = np.ascontiguousarray(x.ravel()), np.ascontiguousarray(y.ravel())
    return _sample_where(image, x, y, np.ones(x.size, np.bool_))


def sample_where(image: np.ndarray, xy: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """:func:`sample_bilinear` at ``xy`` ``(2, N)`` where ``mask`` ``(N,)`` is true, 0 elsewhere."""
    xy, mask = _positions(xy, mask)
    return _sample_where(_rgba(image), xy[0], xy[1], mask)


def _positions(xy: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    xy = np.ascontiguousarray(xy, np.float64)
    mask = np.ascontiguousarray(mask, np.bool_)
    if xy.ndim != 2 or xy.shape[0] != 2 or mask.shape != (xy.shape[1],):
        raise ValueError(f"sampling needs positions (2, N) and a mask (N,), got {xy.shape} and {mask.shape}")
    return xy, mask


def _rgba(image: np.ndarray) -> np.ndarray:
    if image.ndim != 3 or image.shape[2] != 4 or image.dtype != np.uint8:
        raise ValueError(f"sampling expects a (H, W, 4) uint8 image (RGB + alpha), got {image.dtype} {image.shape}")
    if image.shape[0] < 2 or image.shape[1] < 2:
        raise ValueError(f"sampling needs at least 2 x 2 pixels, got {image.shape[:2]}")
    return np.ascontiguousarray(image)


@jit(inline=True)
def _bilinear4(image, x, y):  # noqa: ANN001, ANN202
    """The four channels of ``image`` at finite ``(x, y)``, exact bilinear weights, float32, border-clamped."""
    h, w = image.shape[0], image.shape[1]
    x, y = min(max(x, 0.0), w - 1.0), min(max(y, 0.0), h - 1.0)
    x0, y0 = min(int(x), w - 2), min(int(y), h - 2)  # x >= 0, so truncation is floor
    fx, fy = np.float32(x - x0), np.float32(y - y0)
    return (
        _lerp2(image, x0, y0, 0, fx, fy),
        _lerp2(image, x0, y0, 1, fx, fy),
        _lerp2(image, x0, y0, 2, fx, fy),
        _lerp2(image, x0, y0, 3, fx, fy),
    )


@jit(inline=True)
def _lerp2(image, x0, y0, c, fx, fy):  # noqa: ANN001, ANN202
    top = np.float32(image[y0, x0, c])
    top += (np.float32(image[y0, x0 + 1, c]) - top) * fx
    bottom = np.float32(image[y0 + 1, x0, c])
    bottom += (np.float32(image[y0 + 1, x0 + 1, c]) - bottom) * fx
    return top + (bottom - top) * fy


@jit
def _sample_where(image, xs, ys, mask):  # noqa: ANN001, ANN202
    out = np.zeros((xs.size, 4), np.float32)
    for i in range(xs.size):
        if mask[i] and np.isfinite(xs[i]) and np.isfinite(ys[i]):  # nan would index anywhere
            out[i, 0], out[i, 1], out[i, 2], out[i, 3] = _bilinear4(image, xs[i], ys[i])
    return out
