"""Image operations the refinement and the baselines share: grey conversion, contrast normalisation,
albedo division, texture evidence, local and weighted NCC, ramps and dilations.

Convention: grey images float32 (or uint8 where stated) ``(H, W)``, origin top-left.
"""

from __future__ import annotations

import math

import cv2
import numpy as np


def to_gray(image: np.ndarray, equalize: bool = False) -> np.ndarray:
    """The shared preprocessing: uint8 RGB ``(H, W, 3)`` -> uint8 gray ``(H, W)``, optionally equalised."""
    gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    return cv2.equalizeHist(gray) if equalize else gray


def gaussian(image: np.ndarray, sigma: float, shrunk: float = 0.0) -> np.ndarray:
    """``image`` blurred by a Gaussian of ``sigma`` px (OpenCV's kernel: 4 sigma each side for float images).

    ``shrunk`` > 0: a ``sigma`` of at least twice ``shrunk`` is applied on the image shrunk ``f = sigma //
    shrunk`` times (area averages, whose own spread the Gaussian leaves out: ``sqrt(sigma^2 - (f^2 - 1) / 12)
    / f`` there) and brought back bilinearly; an image under ``4 f`` px a side is blurred at its own size. A
    mean that wide is smooth at that scale, and a full-size Gaussian of sigma 7 costs six times as much on a
    384 x 512 image."""
    h, w = image.shape[:2]
    f = int(sigma // shrunk) if shrunk > 0 else 1
    if f < 2 or min(h, w) < 4 * f:
        return cv2.GaussianBlur(image, (0, 0), sigma)
    small = cv2.resize(image, (w // f, h // f), interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small, (0, 0), math.sqrt(sigma * sigma - (f * f - 1) / 12) / f)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


def normalize_contrast(gray: np.ndarray, sigma: float, shrunk: float = 0.0) -> np.ndarray:
    """Local contrast normalisation: ``(g - mean) / std`` over a Gaussian window, as uint8 ``128 + 40 z``.

    The standard deviation is floored at 2 grey levels, so flat regions stay flat instead of turning
    their quantisation noise into texture. ``sigma`` 0 returns ``gray`` unchanged; ``shrunk``: as
    :func:`gaussian`'s.
    """
    if sigma == 0:
        return gray
    g = gray.astype(np.float32)
    mean = gaussian(g, sigma, shrunk)
    var = gaussian(g * g, sigma, shrunk) - mean * mean
    z = (g - mean) / np.sqrt(np.maximum(var, 4.0))
    return np.clip(128 + 40 * z, 0, 255).astype(np.uint8)


def divide_albedo(gray0: np.ndarray, warped: np.ndarray, window: int) -> np.ndarray:
    """``warped`` (the captured gray image in the projector frame) divided by the wall's reflectance.

    A textured wall (paint, brick, plaster) multiplies the projected light; through a power-law camera
    response the captured image is still the projected one times a reflectance map that carries the
    wall's own edges, which contrast normalisation keeps and DIS follows. The reflectance is estimated
    as the median, over a ``window`` x ``window`` square, of ``log(warped + 8) - log(gray0 + 8)``: a
    wall's stripes or bricks wider than half the window survive the median, the texture-scale
    structure a small misalignment leaves in the ratio does not. Returns float32 ``(H, W)``.
    """
    ratio = _log8(warped) - _log8(gray0)
    coded = np.clip(np.round(128 + 40 * ratio), 0, 255).astype(np.uint8)  # OpenCV's large medians take uint8
    return warped / cv2.LUT(cv2.medianBlur(coded, window), _REFLECTANCE)


_LEVELS = np.arange(256, dtype=np.float32)  # the uint8 grey levels
_LOG8 = np.log(_LEVELS + 8.0)  # log(g + 8) of each, looked up rather than computed pixel by pixel ...
_REFLECTANCE = np.exp((_LEVELS - 128) / 40)  # ... and the reflectance each code of the median stands for


def _log8(gray: np.ndarray) -> np.ndarray:
    """``log(gray + 8)``, float32 (a table lookup for uint8 images: the same values)."""
    return cv2.LUT(gray, _LOG8) if gray.dtype == np.uint8 else np.log(gray.astype(np.float32) + 8.0)


def near(mask: np.ndarray, radius: float) -> np.ndarray:
    """Pixels at most ``radius`` px (Euclidean) from a true pixel of ``mask``."""
    far = cv2.distanceTransform(np.where(mask, 0, 255).astype(np.uint8), cv2.DIST_L2, 5)
    return far <= radius


def texture_weight(gray: np.ndarray, floor: float = 0.0, sigma: float = 3.0) -> np.ndarray:
    """Per-pixel weight in [0, 1]: local gradient energy (Sobel, squared, Gaussian-averaged) relative
    to the frame's median or to ``floor``, whichever is larger, capped at 1.

    The floor makes the weight absolute where the frame is mostly flat: a picture covering a quarter of
    the frame, or one with almost no contrast, has a median energy near zero, and relative to that
    noise would count as texture. ``floor = 64 g^2`` is the energy of a ramp of ``g`` grey levels per
    pixel (a Sobel derivative is 8 times the slope).
    """
    g = gray.astype(np.float32)
    energy = gaussian(cv2.Sobel(g, cv2.CV_32F, 1, 0) ** 2 + cv2.Sobel(g, cv2.CV_32F, 0, 1) ** 2, sigma)
    return np.minimum(energy / (max(float(np.median(energy)), floor) + 1e-3), 1.0)


class LocalStats:
    """Gaussian-window mean and variance of a reference image, computed once, so that the local NCC of
    each image compared with it (:meth:`ncc`) blurs three maps instead of five. ``shrunk``: as :func:`gaussian`'s."""

    def __init__(self, image: np.ndarray, sigma: float, shrunk: float = 0.0) -> None:
        self.sigma, self.shrunk = sigma, shrunk
        self.image = image.astype(np.float32)
        self.mean = self._blur(self.image)
        self.var = self._blur(self.image * self.image) - self.mean * self.mean

    def _blur(self, img: np.ndarray) -> np.ndarray:
        return gaussian(img, self.sigma, self.shrunk)

    def ncc(self, other: np.ndarray) -> np.ndarray:
        """:func:`local_ncc` of the reference and ``other`` (aligned with it)."""
        b = other.astype(np.float32)
        mb = self._blur(b)
        cov = self._blur(self.image * b) - self.mean * mb
        var = np.maximum(self.var * (self._blur(b * b) - mb * mb), 1e-2)
        return cov / np.sqrt(var)


def local_ncc(gray0: np.ndarray, gray1: np.ndarray, sigma: float = 7.0) -> np.ndarray:
    """Local normalised cross-correlation of two aligned images (Gaussian window ``sigma``), float32
    ``(H, W)`` in [-1, 1]: 1 is a match up to local gain and offset, about 0 no match (and 0 where
    either image is flat)."""
    return LocalStats(gray0, sigma).ncc(gray1)


def weighted_ncc(gray0: np.ndarray, warped: np.ndarray, sigma: float, weight: np.ndarray | None) -> float:
    """:func:`alignment_score` of an image already warped into the projector frame."""
    return weighted_mean(local_ncc(gray0, warped, sigma), weight)


def weighted_mean(values: np.ndarray, weight: np.ndarray | None) -> float:
    """The mean of ``values`` weighted by ``weight`` (None: uniform)."""
    if weight is None:
        return float(values.mean())
    return float((values * weight).sum() / max(float(weight.sum()), 1e-6))


def ramp(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """0 at or below ``lo``, 1 at or above ``hi``, linear between (``lo > hi`` decreases instead).

    Example:
        >>> ramp(np.array([0.0, 0.5, 1.0, 2.0]), 0.0, 1.0).tolist()
        [0.0, 0.5, 1.0, 1.0]
    """
    return np.clip((np.asarray(x, np.float32) - lo) / (hi - lo), 0.0, 1.0)
