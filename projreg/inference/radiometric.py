"""Photometric (radiometric) compensation: what the projector must show so the camera sees the colours
wanted on a textured, coloured or partly lit surface.

Model, per camera pixel and channel, in the camera's linear light:

    F^-1(camera) = offset + gain * g(projector)

with ``F^-1`` the camera's response read backwards and ``g`` the projector's (code value -> light, 0 at
black, 1 at white): either **measured** from photos of grey levels (a
:class:`projsynth.structured.response.Response`, ``projsynth response``), or **assumed**, ``x^gamma`` for
both devices (2.2 by default, 1 for a linear device such as the paper's blend).

``offset`` is the photo of a full-black projection (ambient light on the surface's own texture, the
projector's black level), ``offset + gain`` the photo of a full-white one: two shots calibrate every
pixel. The projector cannot remove light, so the surface's texture under ambient light (``offset``)
can only be hidden by lifting every pixel to a **common floor**; nor can it add more than ``gain``. The
wanted view is therefore mapped, **globally**, to ``floor + s * wanted_lin``, with the floor and the
contrast ``s`` chosen (:func:`best_mapping`) so that the camera's view, read back to the wanted view's
scale, is closest to it: a high floor hides the surface's texture but leaves little contrast (and
noise grows), a large contrast clips on dark albedo. A per-pixel scale would reproduce the surface's
own pattern instead of hiding it. The projector value is ``g^-1((target - offset) / gain)``, the
light clipped to [0, 1].

Convention: images ``(H, W, 3)`` uint8 RGB in the **camera** frame; the result is the projector
value each camera pixel needs, still in the camera frame: the geometric pre-warp
(:func:`projreg.inference.compensate.compensate`) then takes it to the projector frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from projsynth.structured.response import Response

from ..errors import ProjregError

FLOOR_PERCENTILES = (0, 25, 50, 75, 90, 95, 99)
SCALE_PERCENTILES = (1, 5, 10, 25, 50)
NOISE_LIN = 0.004  # about one camera grey level at mid-grey, in linear light (gamma 2.2)
MIN_GAIN = 1e-3  # a pixel the projector cannot brighten gets no light
SWAPPED_SHARE = 0.5  # white darker than black on more of the frame than this: refused (swapped photos)
CLIPPED_SHARE = 0.05  # white photo saturated on more of the frame than this: a warning


@dataclass(frozen=True)
class Radiometry:
    """Per camera pixel and channel: ``offset`` and ``gain`` ``(Hc, Wc, 3)`` in the camera's linear light, and
    the devices' ``curves`` (measured, or :meth:`Response.from_gamma`)."""

    offset: np.ndarray
    gain: np.ndarray
    curves: Response
    clipped: float = 0.0  # share of camera pixels where the white photo saturates (gain underestimated)


def to_linear(image: np.ndarray, gamma: float) -> np.ndarray:
    return (image.astype(np.float32) / np.float32(255)) ** np.float32(gamma)


def calibrate(
    white: np.ndarray,
    black: np.ndarray,
    gamma: float = 2.2,
    level: float = 1.0,
    response: Response | None = None,
) -> Radiometry:
    """The per-pixel model from the camera's photos of a white (projector value ``level`` in (0, 1],
    full white by default) and a full-black projection. A white photo must not clip: where the camera
    saturates, the gain is underestimated (lower the exposure, or ``level``).

    ``response``: the devices' measured curves, which replace ``gamma``; None: ``x^gamma`` for both devices.

    Raises:
        ProjregError: the photos differ in size or ``gamma`` is outside (0.5, 4).
    """
    if white.shape != black.shape:
        raise ProjregError(
            f"--white is {white.shape[1]}x{white.shape[0]} but --black is "
            f"{black.shape[1]}x{black.shape[0]}; shoot both with one camera setting"
        )
    if not 0.5 < gamma < 4:
        raise ProjregError(f"--gamma: expected a display/camera gamma in (0.5, 4), got {gamma}")
    darker = float(np.mean(white.astype(np.int16).sum(axis=2) < black.astype(np.int16).sum(axis=2)))
    if darker > SWAPPED_SHARE:
        raise ProjregError(
            f"--white is darker than --black on {darker:.0%} of the frame: are the two photos swapped? "
            "--white is the camera's photo of a full-white projection"
        )
    curves = Response.from_gamma(gamma) if response is None else response
    offset = curves.camera_linear(black)
    shown = [np.interp(255 * level, np.arange(256), curves.projector[c]) for c in range(3)]  # g(level)
    gain = np.maximum(curves.camera_linear(white) - offset, 0) / np.asarray(shown, np.float32)
    return Radiometry(offset, gain, curves, clipped=float(np.mean((white == 255).any(axis=2))))


def solve(wanted: np.ndarray, model: Radiometry, region: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """The projector value each camera pixel needs to show ``wanted`` (module docstring).

    Args:
        wanted: ``(Hc, Wc, 3)`` uint8 desired camera view.
        model: from :func:`calibrate`, same size.
        region: ``(Hc, Wc)`` bool: where the projector lights the surface (None: where any gain is
            above ``MIN_GAIN``); the mapping is chosen there.

    Returns:
        ``(image, scale)``: ``(Hc, Wc, 3)`` uint8 projector values in the camera frame, and ``s``.
    """
    if wanted.shape != model.gain.shape:
        raise ProjregError(
            f"the desired view is {wanted.shape[1]}x{wanted.shape[0]} but the white/black photos "
            f"are {model.gain.shape[1]}x{model.gain.shape[0]}; resize it to the camera frame"
        )
    lit = model.gain.mean(axis=2) > MIN_GAIN
    region = lit if region is None else region & lit
    if not region.any():
        raise ProjregError("the white and black photos do not differ anywhere: the projector lights nothing")
    wanted_lin = model.curves.camera_linear(wanted)
    floor, scale = best_mapping(wanted_lin[region], model.offset[region], model.gain[region])
    need = (floor + scale * wanted_lin - model.offset) / np.maximum(model.gain, MIN_GAIN)
    need = np.where(model.gain > MIN_GAIN, np.clip(need, 0, 1), 0)
    return model.curves.projector_codes(need), scale


def best_mapping(wanted: np.ndarray, offset: np.ndarray, gain: np.ndarray) -> tuple[np.ndarray, float]:
    """The global mapping ``floor + s * wanted`` (linear light) whose photo shows ``wanted`` best.

    Candidates: ``floor`` at percentiles of ``offset`` (per channel), ``s`` at percentiles of the
    headroom ``gain - (floor - offset)``. Each is scored by what the camera would show, read back to
    the wanted view's scale: ``(clipping error^2 + NOISE_LIN^2) / s^2``: a high floor hides the
    surface's texture but leaves little contrast, a large ``s`` clips. Args are ``(N, 3)`` samples of the
    region the projector lights.
    """
    best = (np.inf, offset.min(axis=0), 1e-3)
    for fp in FLOOR_PERCENTILES:
        floor = np.percentile(offset, fp, axis=0)  # [3]
        headroom = (gain - np.maximum(floor - offset, 0)).min(axis=1)
        for sp in SCALE_PERCENTILES:
            s = float(np.percentile(headroom, sp))
            if s <= 1e-4:
                continue
            target = floor + s * wanted
            shown = offset + gain * np.clip((target - offset) / np.maximum(gain, MIN_GAIN), 0, 1)
            cost = (float(np.mean((shown - target) ** 2)) + NOISE_LIN**2) / s**2
            if cost < best[0]:
                best = (cost, floor, s)
    return best[1].astype(np.float32), best[2]
