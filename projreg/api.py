"""The in-memory API: register projector-camera pairs held as numpy arrays, no files (docs/api.md).

A :class:`Registrar` loads a network once (the shipped reference, a checkpoint, or an ONNX graph) with
a quality setting, and registers one pair, a batch, or the frames of a sequence (tracking); each answer
is a :class:`Registration`. :func:`compensate` pre-warps content with one, :func:`end_point_error`
measures one against a truth. ``projreg predict`` and ``projreg bench`` run the same code.

Conventions: images are uint8 RGB ``(H, W, 3)``; the captured image may have another size than the
projected one. A flow is float32 ``(H, W, 2)`` on the projected grid, forward (projected ->
captured), in captured pixels: ``flow[y, x] = (u, v)`` means projected pixel ``(x, y)`` is seen at
captured pixel ``(x + u, y + v)``. Errors are :class:`projreg.ProjregError` with the CLI's one-line
messages.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path

import numpy as np

from projsynth.errors import ProjsynthError
from projsynth.structured.response import Response, read_response

from .errors import ProjregError
from .evaluation.metrics import EPEAccumulator
from .geometry.frames import flow_to_captured, frame_scale, resize_to
from .inference.compensate import compensate as _prewarp
from .inference.radiometric import calibrate, solve
from .inference.register import Registration, check_image, register_pairs
from .inference.runtime import DEFAULT_BACKEND, open_network
from .inference.track import Tracker
from .prediction import CONFIDENT, Prediction
from .refine.config import DEFAULT_QUALITY
from .refine.config import quality as quality_setting
from .refine.refiner import GeometricRefiner


class Registrar:
    """A network and a refinement, loaded once, that register pairs in memory.

    Args:
        model: None or ``"reference"`` (the shipped model), a ``projreg train`` checkpoint, or a graph
            of ``projreg export --onnx``.
        quality: ``fast``, ``balanced`` (the default) or ``accurate``
            (:data:`projreg.refine.config.QUALITIES`): where the network runs and how far the refinement
            searches.
        device, precision, backend: where and how the network runs (``cpu``/``cuda``/``cuda:N``,
            ``fp32``/``bf16``/``fp16``, ``auto``/``torch``/``onnxruntime``), as ``predict``'s options.
        refine: follow the network with the geometric refinement (False: the network alone, every pixel
            claimed).
        max_side: the longest side the network sees at most (also bounded by the quality's).

    Raises:
        ProjregError: an option that cannot be honoured here, named as on the command line.
    """

    def __init__(
        self,
        model: str | Path | None = None,
        *,
        quality: str = DEFAULT_QUALITY,
        device: str | None = None,
        precision: str = "fp32",
        backend: str = DEFAULT_BACKEND,
        refine: bool = True,
        max_side: int = 1024,
    ) -> None:
        setting = quality_setting(quality)
        if max_side < 16:
            raise ProjregError(f"--max-side must be >= 16, got {max_side}")
        self.quality = setting.name
        self.max_side, self.finer_side = min(max_side, setting.network_side), setting.finer_side(max_side)
        self.network = open_network(model, backend=backend, device=device, precision=precision)
        self.refiner = GeometricRefiner(setting.refine) if refine else None

    def register(self, projected: np.ndarray, captured: np.ndarray) -> Registration:
        """The registration of one pair (module conventions)."""
        return self.register_batch([(projected, captured)])[0]

    def register_batch(self, pairs: Sequence[tuple[np.ndarray, np.ndarray]], batch_size: int = 1) -> list[Registration]:
        """The registrations of several pairs, in order; the network runs on ``batch_size`` pairs of one
        size per call."""
        return register_pairs(self.network, self.refiner, pairs, self.max_side, batch_size, self.finer_side)

    def track(self, frames: Iterable[tuple[np.ndarray, np.ndarray]]) -> Iterator[Registration]:
        """The registrations of a sequence's frames, in order: each frame refined from the previous one's
        flow, the network only for the first frame and where the track is lost (:mod:`projreg.inference.track`).
        Every frame of one sequence must have the sizes of the first."""
        if self.refiner is None:
            raise ProjregError("tracking follows each frame with the refinement; use refine=True")
        timings: dict[str, float] = {}

        def full(a: np.ndarray, b: np.ndarray) -> Prediction:
            reg = self.register(a, b)
            timings.update(reg.timings)
            return Prediction(reg.flow, reg.claimed, reg.registered, reg.reason)

        tracker, first = Tracker(full, self.refiner), None
        for projected, captured in frames:
            a, b = check_image("projected", projected), check_image("captured", captured)
            if first is None:
                first = (a.shape, b.shape)
            elif (a.shape, b.shape) != first:
                raise ProjregError(f"frame sizes changed within the sequence: {first} then {(a.shape, b.shape)}")
            timings.clear()
            t0 = time.perf_counter()
            pred = tracker(a, resize_to(b, a.shape))
            total = 1000 * (time.perf_counter() - t0)
            timings = timings or {"refine": total}
            flow = flow_to_captured(pred.flow, frame_scale(a.shape, b.shape))
            claimed = np.zeros(a.shape[:2], bool) if pred.claimed is None else pred.claimed
            yield Registration(
                flow, claimed, None, pred.registered, pred.reason, b.shape[:2], dict(timings), tracker.last
            )


def compensate(
    content: np.ndarray,
    registration: Registration,
    *,
    fill: int = 0,
    white: np.ndarray | None = None,
    black: np.ndarray | None = None,
    gamma: float | None = None,
    response: Response | str | Path | None = None,
) -> np.ndarray:
    """The projector image that makes the camera see ``content`` (uint8 RGB, spanning the camera frame,
    any size), ``fill`` where no claimed pixel lands; with ``white`` and ``black`` (the camera's photos
    of a full-white and a full-black projection) also corrected for the surface's colour and light, as
    ``projreg compensate --photometric``: with the devices' measured ``response`` (a
    :class:`projsynth.structured.response.Response`, e.g. from ``projsynth.fit_device_response``, or the
    path of a ``projsynth response`` file), else ``gamma`` for both (2.2 by default). Returns uint8 RGB
    on the projected grid."""
    image = check_image("content", content)
    camera = registration.camera_size
    if (white is None) != (black is None):
        raise ProjregError("photometric compensation needs both the white and the black photo")
    if white is None and (response is not None or gamma is not None):
        raise ProjregError("response and gamma set the photometric correction; give the white and black photos")
    if response is not None and gamma is not None:
        raise ProjregError("gamma is the assumption a measured response replaces; give one of the two")
    if isinstance(response, str | Path):
        try:
            response = read_response(Path(response))
        except ProjsynthError as e:
            raise ProjregError(str(e)) from e
    if white is not None:
        model = calibrate(check_image("white", white), check_image("black", black), gamma or 2.2, response=response)
        if white.shape[:2] != tuple(camera):
            raise ProjregError(f"white photo is {white.shape[:2]}, the registration's camera frame {tuple(camera)}")
        image = solve(resize_to(image, white.shape), model)[0]
    return _prewarp(image, registration.flow, registration.claimed, fill, camera_size=tuple(camera))


def end_point_error(
    flow: np.ndarray, truth: np.ndarray, valid: np.ndarray, claimed: np.ndarray | None = None
) -> dict[str, float | int | None]:
    """``projreg bench``'s metrics of one flow against a truth on its ``valid`` pixels (bool ``(H, W)``):
    ``epe`` (mean end-point error, px), the buckets ``s0-10``, ``s10-40``, ``s40+`` by the truth's
    magnitude, ``px1``/``px3``/``px5`` (shares of pixels off by more than that), ``pixels``; with
    ``claimed``, also ``epe_claimed`` and ``claimed`` (the claimed share of the valid pixels)."""
    acc = EPEAccumulator()
    acc.add(np.asarray(flow, np.float32), np.asarray(truth, np.float32), np.asarray(valid, bool), claimed)
    return acc.result()


__all__ = ["CONFIDENT", "Registrar", "Registration", "compensate", "end_point_error"]
