"""The registration pipeline, configured once: what ``predict``, ``bench``, the API's
:class:`~projreg.api.Registrar` and the live loop hold instead of assembling its parts.

A quality (:data:`projreg.refine.config.QUALITIES`) resolves here, once, into

    the network's side -> the network -> the refiner (-> the finer pass: the network again at a larger
    side, only when the refinement's first stage leaves the frame unverified) -> a Registration
    the tracker: each frame of a sequence refined from the previous one's flow, in full where lost

and :meth:`Pipeline.register` (pairs, batched) and :meth:`Pipeline.track` (the frames of one sequence:
the one tracking loop) run it. A captured image of another size than the projected one is resized
for the network and the refinement, and its flow brought back to its own pixels
(:mod:`projreg.geometry.frames`); with the rig's photos, every captured image first has the surface
divided out (:mod:`projreg.inference.photos`).

Conventions: images uint8 RGB ``(H, W, 3)``; flows float32 ``(H, W, 2)`` on the projected grid, forward
(projected -> captured), in captured pixels.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path

import numpy as np

from ..errors import ProjregError
from ..geometry.frames import flow_to_captured, frame_scale, resize_to
from ..prediction import Prediction
from ..refine.config import DEFAULT_QUALITY
from ..refine.config import quality as resolve_quality
from ..refine.refiner import GeometricRefiner
from .photos import normalise_capture
from .register import Photos, Registration, check_image, checked_pair
from .runtime import DEFAULT_BACKEND, finer_flow, flows_resized, open_network
from .track import Tracker

FullRegistration = Callable[[np.ndarray, np.ndarray], Prediction]  # a same-size pair's registration in full


class Pipeline:
    """A network and its refinement as one quality sets them (module docstring), loaded once.

    Args:
        model: None or ``"reference"`` (the shipped model), a ``projreg train`` checkpoint, or a graph
            of ``projreg export --onnx`` (:func:`~projreg.inference.runtime.open_network`).
        quality: ``fast``, ``balanced`` (the default) or ``accurate``.
        device, precision, backend: where and how the network runs (``predict``'s options).
        refine: follow the network with the geometric refinement (False: the network alone, every pixel
            claimed, no tracking).
        max_side: the longest side the network sees at most, under the quality's own (None: the
            quality's); it also caps the finer pass (:meth:`~projreg.refine.config.Quality.finer_side`).

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
        max_side: int | None = None,
    ) -> None:
        setting = resolve_quality(quality)
        self.quality = setting.name
        self.network_side = setting.network_side if max_side is None else min(max_side, setting.network_side)
        self.finer_side = setting.finer_side(max_side)
        self.network = open_network(model, backend=backend, device=device, precision=precision)
        self.refiner = GeometricRefiner(setting.refine) if refine else None

    def flows(self, pairs: Sequence[tuple[np.ndarray, np.ndarray]], batch_size: int = 1) -> list[np.ndarray]:
        """The network's flow of each same-size pair, at the pipeline's side, ``batch_size`` pairs of one
        size per call (:func:`~projreg.inference.runtime.flows_resized`)."""
        return flows_resized(self.network, pairs, self.network_side, batch_size)

    def refined(self, projected: np.ndarray, captured: np.ndarray, flow: np.ndarray) -> Prediction:
        """The refinement of the network's ``flow`` of a same-size pair, with the finer pass on
        escalation (:func:`~projreg.inference.runtime.finer_flow`)."""
        finer = finer_flow(self.network, projected, captured, self.finer_side)
        return self._refiner().predict_info(projected, captured, flow, finer=finer)[0]

    def full(self, projected: np.ndarray, captured: np.ndarray) -> Prediction:
        """A same-size pair registered in full: the network, then the refinement."""
        return self.refined(projected, captured, self.flows([(projected, captured)])[0])

    def tracker(self, full: FullRegistration | None = None) -> Tracker:
        """A :class:`~projreg.inference.track.Tracker` of this refinement, registering in full with
        ``full`` (None: :meth:`full`) the first frame and where the track is lost."""
        return Tracker(full or self.full, self._refiner())

    def register(
        self,
        pairs: Sequence[tuple[np.ndarray, np.ndarray]],
        batch_size: int = 1,
        photos: Photos | None = None,
    ) -> list[Registration]:
        """Each pair registered: the network on the pair (the captured image resized to the projected one),
        ``batch_size`` pairs of one size per call, then the refinement (none: every pixel claimed); flows
        in each camera's own pixels. With ``photos`` (:func:`~projreg.inference.register.rig_photos`),
        every captured image first has the surface divided out."""
        views = [check_image("captured", b) for _, b in pairs]
        if photos is not None:
            views = [normalise_capture(b, *photos) for b in views]
        same = [(check_image("projected", a), resize_to(b, a.shape)) for (a, _), b in zip(pairs, views, strict=True)]
        t0 = time.perf_counter()
        flows = self.flows(same, batch_size)
        network_ms = 1000 * (time.perf_counter() - t0) / max(len(pairs), 1)
        out = []
        for (a, b), flow, (_, captured) in zip(same, flows, pairs, strict=True):
            camera, scale = captured.shape[:2], frame_scale(a.shape, captured.shape)
            if self.refiner is None:
                claimed = np.ones(a.shape[:2], bool)
                timings = {"network": network_ms}
                out.append(Registration(flow_to_captured(flow, scale), claimed, None, True, "", camera, timings))
                continue
            t0 = time.perf_counter()
            pred = self.refined(a, b, flow)
            timings = {"network": network_ms, "refine": 1000 * (time.perf_counter() - t0)}
            out.append(_registration(pred, scale, camera, timings))
        return out

    def track(
        self, frames: Iterable[tuple[np.ndarray, np.ndarray]], photos: Photos | None = None, where: str = "frames"
    ) -> Iterator[Registration]:
        """The registrations of one sequence's frames, in order, each yielded before the next frame is
        taken from ``frames`` (a live source hands over its newest): the first registered in full, each
        next from the previous one's flow, in full again where the track is lost
        (:mod:`projreg.inference.track`; ``Registration.step`` says which). Every frame must have the
        first one's sizes; ``photos`` as :meth:`register`, for every frame. ``where`` names the frames
        in errors (``frames[3]``).

        Raises:
            ProjregError: a frame that is not a pair of images, or whose sizes are not the first one's.
        """
        timings: dict[str, float] = {}

        def full(projected: np.ndarray, captured: np.ndarray) -> Prediction:
            t0 = time.perf_counter()
            flow = self.flows([(projected, captured)])[0]
            t1 = time.perf_counter()
            pred = self.refined(projected, captured, flow)
            timings.update(network=1000 * (t1 - t0), refine=1000 * (time.perf_counter() - t1))
            return pred

        tracker, first = self.tracker(full), None
        for i, frame in enumerate(frames):
            a, b = checked_pair(f"{where}[{i}]", frame)
            if photos is not None:
                b = normalise_capture(b, *photos)
            if first is None:
                first = (a.shape, b.shape)
            elif (a.shape, b.shape) != first:
                raise ProjregError(
                    f"{where}[{i}]: frame sizes changed within the sequence: {first} then {(a.shape, b.shape)}"
                )
            timings.clear()
            t0 = time.perf_counter()
            pred = tracker(a, resize_to(b, a.shape))
            total = 1000 * (time.perf_counter() - t0)
            step_ms = dict(timings) or {"refine": total}
            yield _registration(pred, frame_scale(a.shape, b.shape), b.shape[:2], step_ms, tracker.last)

    def _refiner(self) -> GeometricRefiner:
        if self.refiner is None:
            raise ProjregError("this pipeline has no refinement (refine=False); tracking and refining need it")
        return self.refiner


def _registration(
    pred: Prediction, scale: tuple[float, float], camera: tuple[int, int], timings: dict[str, float], step: str = ""
) -> Registration:
    """A refined prediction on the resized pair as a :class:`Registration` in the camera's pixels (a
    ``claimed`` of None: every pixel, :class:`~projreg.prediction.Prediction`'s convention)."""
    flow = flow_to_captured(pred.flow, scale)
    claimed = np.ones(pred.flow.shape[:2], bool) if pred.claimed is None else pred.claimed
    return Registration(flow, claimed, pred.confidence, pred.registered, pred.reason, camera, timings, step)
