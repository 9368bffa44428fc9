"""What a registration answers (:class:`Registration`: what ``predict`` writes and
:class:`projreg.api.Registrar` returns; :class:`~projreg.inference.pipeline.Pipeline` makes it), and the
checks of its inputs: images (:func:`check_image`) and the rig's photos (:func:`rig_photos`).

Conventions: images uint8 RGB ``(H, W, 3)`` (the captured one of any size); flows float32 ``(H, W, 2)``
on the projected grid, forward, in captured pixels.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from projsynth.structured.response import Response

from ..errors import ProjregError
from .photos import check_photos

# a rig's photos of a full-white and (optionally) a full-black projection, and the devices' measured response
Photos = tuple[np.ndarray, np.ndarray | None, Response | None]


@dataclass(frozen=True)
class Registration:
    """One registered pair.

    ``flow``: float32 ``(H, W, 2)`` (module conventions); ``claimed``: bool ``(H, W)``, the pixels the
    answer vouches for (``predict``'s EXR ``valid``); ``confidence``: float32 ``(H, W)`` in [0, 1],
    the refinement's per-pixel confidence (``predict``'s EXR ``confidence``), claimed where >=
    ``CONFIDENT`` on a registered pair (None without the refinement: the network alone measures none);
    the flow is the best estimate on every pixel, claimed or not, finite everywhere;
    ``registered``: False when the pair could not be registered at all, ``reason`` says why (its flow
    is then a placeholder and nothing is claimed); ``camera_size``: the captured image's ``(H, W)``;
    ``timings``: milliseconds per stage (``network``, ``refine``); ``step``: for tracking, how the frame
    was registered (``full``, ``tracked`` or ``lost``), else ``""``.
    """

    flow: np.ndarray
    claimed: np.ndarray
    confidence: np.ndarray | None
    registered: bool
    reason: str
    camera_size: tuple[int, int]
    timings: dict[str, float] = field(default_factory=dict)
    step: str = ""


def rig_photos(white: np.ndarray | None, black: np.ndarray | None, response: Response | None = None) -> Photos | None:
    """``(white, black, response)`` checked (:func:`~projreg.inference.photos.check_photos`), None without a
    white photo; a black photo or a response alone is refused (neither says what the projector lights)."""
    if white is None:
        for name, given in (("--black", black), ("--response", response)):
            if given is not None:
                raise ProjregError(f"{name} needs --white: the rig's photo of a full-white projection")
        return None
    if response is not None and not isinstance(response, Response):
        raise ProjregError(f"response: expected a projsynth Response, got {type(response).__name__}")
    photos = (check_image("white", white), None if black is None else check_image("black", black))
    check_photos(*photos)
    return (*photos, response)


MIN_IMAGE_SIDE = 8  # a smaller image holds no correspondence worth a flow (a 1 x 1 camera, an empty array)


def check_image(name: str, image: np.ndarray) -> np.ndarray:
    """``image`` as a uint8 RGB ``(H, W, 3)`` array of at least ``MIN_IMAGE_SIDE`` px a side, or one line
    naming it."""
    if not isinstance(image, np.ndarray):
        raise ProjregError(f"{name}: expected a uint8 RGB numpy array (H, W, 3), got {type(image).__name__}")
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ProjregError(f"{name}: expected a uint8 RGB array (H, W, 3), got {image.dtype} {image.shape}")
    if min(image.shape[:2]) < MIN_IMAGE_SIDE:
        raise ProjregError(
            f"{name}: {image.shape[1]}x{image.shape[0]} px; an image needs at least {MIN_IMAGE_SIDE} px a side"
        )
    return image


def checked_pair(where: str, pair: object) -> tuple[np.ndarray, np.ndarray]:
    """``pair`` as a checked ``(projected, captured)`` pair of images, or one line naming ``where``."""
    if not isinstance(pair, tuple | list) or len(pair) != 2:
        got = f"{len(pair)} items" if isinstance(pair, tuple | list) else type(pair).__name__
        raise ProjregError(f"{where}: expected a (projected, captured) pair, got {got}")
    return check_image(f"{where} projected", pair[0]), check_image(f"{where} captured", pair[1])
