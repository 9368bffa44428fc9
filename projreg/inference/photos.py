"""The captured image with the surface divided out, from the camera's photos of a full-white and a
full-black projection (the photos photometric compensation takes too).

On a textured wall in daylight the projection is a faint modulation of the wall's own pattern, and a
matcher follows the pattern. Per camera pixel and channel, in linear light,
``captured = black + (white - black) * projected``: the black photo is the ambient light on the
surface (and the projector's black level), ``white - black`` the projector's light on the surface's
colour. So

    projected_lin = (captured_lin - black_lin) / (white_lin - black_lin)

is the projected picture as the camera sees it, with the surface's texture and the ambient light gone;
it is clipped to [0, 1] and encoded back to 8 bits through the inverse gamma, so that it looks like
the projected image. With the devices' measured response (``projsynth response``), the photos are
linearised by the camera's curve and the ratio encoded back by the projector's inverse curve: the code
values the projector was sent, as the camera saw them. Where the white photo is not brighter than the
black by ``MARGIN`` grey levels the projector does not reach (a shadow, beyond the surface): 0 there.
With the white photo alone (no black), ``captured / white``: the surface's colour is divided out, the
ambient light is not (and where the projector does not reach, the captured image is the white photo:
full white there).

Convention: images uint8 RGB ``(H, W, 3)`` in the captured frame; the result is uint8 RGB of the
captured image's size.
"""

from __future__ import annotations

import numpy as np

from projsynth.structured.response import Response

from ..errors import ProjregError
from .radiometric import SWAPPED_SHARE, to_linear

GAMMA = 2.2
# grey levels (8-bit values) by which the white photo must exceed the black one for the projector to count as
# reaching a pixel: about 3 sigma of the difference of two photos with one grey level of read noise. Measured
# on a physical split (docs/design.md): 1-4 alike, 8 and more lose claimed pixels
MARGIN = 4


def normalise_capture(
    captured: np.ndarray,
    white: np.ndarray,
    black: np.ndarray | None = None,
    response: Response | None = None,
    *,
    gamma: float = GAMMA,
) -> np.ndarray:
    """``captured`` with the surface divided out (module docstring).

    Args:
        captured: the camera's photo of the projection, uint8 RGB ``(H, W, 3)``.
        white: the same camera's photo of a full-white projection, same size. Where it saturates the
            projector's light is underestimated and the result clips at white (measured: better than
            dropping those pixels, and than a dimmer white, docs/design.md).
        black: its photo of a full-black projection, same size; None: the ambient light stays in.
        response: the devices' measured curves; None: ``gamma`` for both.
        gamma: the devices' gamma without a measured response.

    Returns:
        uint8 RGB ``(H, W, 3)``: the projected picture as this camera sees it, 0 where the projector
        does not reach.

    Raises:
        ProjregError: photos of another size than ``captured``, a white photo darker than the black
            one on most of the frame (swapped), or one that is brighter nowhere.
    """
    if white.shape != captured.shape:
        raise ProjregError(
            f"--white is {white.shape[1]}x{white.shape[0]} px but the captured image is "
            f"{captured.shape[1]}x{captured.shape[0]}; shoot the photos with the camera of the captured image"
        )
    check_photos(white, black)
    floor = np.zeros_like(white) if black is None else black
    reached = white.astype(np.int16) - floor.astype(np.int16) >= MARGIN  # [H, W, 3]
    linear = (lambda im: to_linear(im, gamma)) if response is None else response.camera_linear
    c, w, b = linear(captured), linear(white), linear(floor)
    ratio = np.clip(np.where(reached, (c - b) / np.where(reached, w - b, 1), 0), 0, 1)
    if response is not None:
        return response.projector_codes(ratio)
    return np.rint(255 * ratio ** np.float32(1 / gamma)).astype(np.uint8)


def check_photos(white: np.ndarray, black: np.ndarray | None) -> None:
    """Refuse, with one line naming the option, photos that cannot be of this rig's white and black
    projections: of two sizes, swapped (the white darker on most of the frame), or a white photo
    brighter than the black (or than black, alone) by ``MARGIN`` nowhere."""
    floor = np.zeros_like(white) if black is None else black
    if floor.shape != white.shape:
        raise ProjregError(
            f"--white is {white.shape[1]}x{white.shape[0]} px but --black is {floor.shape[1]}x{floor.shape[0]}; "
            "shoot both with the camera of the captured images"
        )
    lift = white.astype(np.int16) - floor.astype(np.int16)  # [H, W, 3]
    darker = float(np.mean(lift.sum(axis=2) < 0))
    if darker > SWAPPED_SHARE:
        raise ProjregError(
            f"--white is darker than --black on {darker:.0%} of the frame: are the two photos swapped? "
            "--white is the camera's photo of a full-white projection"
        )
    if not (lift >= MARGIN).any():
        than = "black" if black is None else "--black"
        raise ProjregError(
            f"--white is nowhere brighter than {than} by {MARGIN} grey levels: the projector lights nothing "
            "the camera sees"
        )
