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

import cv2
import numpy as np

BLENDS = ("paper", "physical")


def composite(
    blend: str,
    warped: np.ndarray,
    alpha: np.ndarray,
    background: np.ndarray,
    p: dict[str, float],
    rng: np.random.Generator,
) -> np.ndarray:
    """Combine warped projected light and the background into the captured image.

    Args:
        blend: ``"paper"`` or ``"physical"``.
        warped: ``(H, W, 3)`` float32 projected image sampled in the camera frame, 0-255 (0 unlit).
        alpha: ``(H, W)`` float32 in [0, 1], the warped transparency (0 where unlit).
        background: ``(H, W, 3)`` uint8 scene image in the camera frame.
        p: drawn photometric parameters (see ``transforms._CONDITIONS``).
        rng: the sample's generator (noise).

    Returns:
        ``(H, W, 3)`` uint8 captured image.
    """
    bg = background.astype(np.float32)
    a = alpha[..., None]
    if blend == "paper":
        w = np.float32(p["beta"]) * a
        fg = np.float32(p["contrast"]) * warped + np.float32(p["brightness"])
        out = w * fg + (1 - w) * np.float32(p["gamma"]) * bg
        out += _gaussian(rng, out.shape, p["noise_mu"], p["noise_sigma"])
    elif blend == "physical":
        out = _physical(warped, a, bg, p, rng)
    else:
        raise ValueError(f"unknown blend {blend!r}")
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def _gaussian(rng: np.random.Generator, shape: tuple, mu: float, sigma: float) -> np.ndarray:
    noise = rng.standard_normal(shape, dtype=np.float32)
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
    frame's edge at -0.5 / W-0.5) take the border pixels' values. (``cv2.remap`` quantises positions
    to 1/32 px; ground truth needs the exact position.)

    Returns:
        ``(N, 4)`` float32.
    """
    h, w, c = image.shape
    if c != 4:
        raise ValueError("sample_bilinear expects 4 channels (RGB + alpha)")
    x = np.clip(x, 0, w - 1)
    y = np.clip(y, 0, h - 1)
    x0 = np.minimum(x.astype(np.int32), w - 2)  # x >= 0, so truncation is floor
    y0 = np.minimum(y.astype(np.int32), h - 2)
    fx = (x - x0).astype(np.float32)[:, None]
    fy = (y - y0).astype(np.float32)[:, None]
    packed = np.ascontiguousarray(image).view(np.uint32).reshape(h * w)  # one gather per neighbour
    i = y0 * w + x0

    def tap(idx: np.ndarray) -> np.ndarray:
        return packed[idx].view(np.uint8).reshape(-1, 4).astype(np.float32)

    top = tap(i)
    top += (tap(i + 1) - top) * fx
    bottom = tap(i + w)
    bottom += (tap(i + w + 1) - bottom) * fx
    return top + (bottom - top) * fy
