"""Registering pairs held in memory: the network on a batch, then the refinement of each pair, whatever
the camera's size (:func:`register_pairs`); what ``predict`` writes and :class:`projreg.api.Registrar`
returns.

Conventions: images uint8 RGB ``(H, W, 3)`` (the captured one of any size); flows float32 ``(H, W, 2)``
on the projected grid, forward, in captured pixels.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from projsynth.structured.response import Response

from ..errors import ProjregError
from ..geometry.frames import flow_to_captured, frame_scale, resize_to
from ..refine.refiner import GeometricRefiner
from .photos import check_photos, normalise_capture
from .runtime import Network, finer_flow, flows_resized

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


def register_pairs(
    net: Network,
    refiner: GeometricRefiner | None,
    pairs: Sequence[tuple[np.ndarray, np.ndarray]],
    max_side: int,
    batch_size: int = 1,
    finer_side: int | None = None,
    photos: Photos | None = None,
) -> list[Registration]:
    """Each pair registered: the network on the pair (the captured image resized to the projected one,
    the pair shrunk to ``max_side``), ``batch_size`` pairs of one size per call, then the refinement
    (None: the network alone, every pixel claimed), which may ask for the network's flow again at up to
    ``finer_side`` (:func:`~projreg.inference.runtime.finer_flow`); flows in each camera's own pixels.
    With ``photos`` (:func:`rig_photos`), every captured image first has the surface divided out
    (:func:`~projreg.inference.photos.normalise_capture`)."""
    views = [check_image("captured", b) for _, b in pairs]
    if photos is not None:
        views = [normalise_capture(b, *photos) for b in views]
    same = [(check_image("projected", a), resize_to(b, a.shape)) for (a, _), b in zip(pairs, views, strict=True)]
    t0 = time.perf_counter()
    flows = flows_resized(net, same, max_side, batch_size)
    network_ms = 1000 * (time.perf_counter() - t0) / max(len(pairs), 1)
    out = []
    for (a, b), flow, (_, captured) in zip(same, flows, pairs, strict=True):
        camera = captured.shape[:2]
        scale = frame_scale(a.shape, captured.shape)
        if refiner is None:
            claimed = np.ones(a.shape[:2], bool)
            out.append(
                Registration(flow_to_captured(flow, scale), claimed, None, True, "", camera, {"network": network_ms})
            )
            continue
        t0 = time.perf_counter()
        pred, info = refiner.predict_info(a, b, flow, finer=finer_flow(net, a, b, finer_side))
        timings = {"network": network_ms, "refine": 1000 * (time.perf_counter() - t0)}
        flow = flow_to_captured(pred.flow, scale)
        out.append(Registration(flow, pred.claimed, pred.confidence, pred.registered, pred.reason, camera, timings))
    return out


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
