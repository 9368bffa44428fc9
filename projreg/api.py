"""The in-memory API: register projector-camera pairs held as numpy arrays, no files (docs/api.md).

A :class:`Registrar` loads a network once (the shipped reference, a checkpoint, or an ONNX graph) with
a quality setting, and registers one pair, a batch, or the frames of a sequence (tracking); each answer
is a :class:`Registration`; :meth:`Registrar.live` runs the live loop on a camera or a video played
in real time. :func:`compensate` pre-warps content with one, :func:`warp_map` and
:func:`export_warp` give its pre-warp as a map for show software (an STMap, a mesh, ``cv2.remap``
maps), :func:`end_point_error` measures one against a truth. ``projreg predict`` and ``projreg bench``
run the same code.

Conventions: images are uint8 RGB ``(H, W, 3)``; the captured image may have another size than the
projected one. A flow is float32 ``(H, W, 2)`` on the projected grid, forward (projected ->
captured), in captured pixels: ``flow[y, x] = (u, v)`` means projected pixel ``(x, y)`` is seen at
captured pixel ``(x + u, y + v)``. Errors are :class:`projreg.ProjregError` with the CLI's one-line
messages.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path

import numpy as np

from projsynth.errors import ProjsynthError
from projsynth.structured.response import Response, read_response

from .checks import check_flag, check_path, is_int
from .errors import ProjregError
from .evaluation.metrics import EPEAccumulator
from .geometry.frames import resize_to
from .inference.compensate import as_it_is, check_aspect, check_coverage, prewarp
from .inference.live import Live, LiveFrame
from .inference.pipeline import Pipeline
from .inference.radiometric import calibrate, solve
from .inference.realtime import Content, DeviceCamera, PlayedVideo
from .inference.register import Registration, check_image, checked_pair, rig_photos
from .inference.runtime import DEFAULT_BACKEND
from .inference.warpfiles import export_warp_file, write_warp
from .inference.warpmaps import WarpMap
from .inference.warpmaps import warp_map as flow_warp_map
from .prediction import CONFIDENT
from .refine.config import DEFAULT_QUALITY


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
        if not is_int(max_side) or max_side < 16:
            raise ProjregError(f"max_side: expected an integer >= 16, got {max_side!r}")
        if model is not None and not isinstance(model, str | os.PathLike):
            raise ProjregError(f"model: expected None, 'reference' or a path, got {type(model).__name__}")
        if model is not None:
            check_path("model", model)  # '' would be read as the current folder
        self.pipeline = Pipeline(
            model,
            quality=quality,
            device=device,
            precision=precision,
            backend=backend,
            refine=check_flag("refine", refine),
            max_side=max_side,
        )
        self.quality = self.pipeline.quality

    def register(
        self,
        projected: np.ndarray,
        captured: np.ndarray,
        *,
        white: np.ndarray | None = None,
        black: np.ndarray | None = None,
        response: Response | str | Path | None = None,
    ) -> Registration:
        """The registration of one pair (module conventions). ``white`` and ``black``: the camera's photos
        of a full-white and a full-black projection, of the captured image's size; the captured image
        is then registered with the surface divided out (:mod:`projreg.inference.photos`; ``white``
        alone: its colour, not the ambient light); ``response``: the devices' measured curves (a
        :class:`projsynth.structured.response.Response` or a ``projsynth response`` file) linearise them
        instead of gamma 2.2."""
        pair = check_image("projected", projected), check_image("captured", captured)
        return self.register_batch([pair], white=white, black=black, response=response)[0]

    def register_batch(
        self,
        pairs: Sequence[tuple[np.ndarray, np.ndarray]],
        batch_size: int = 1,
        *,
        white: np.ndarray | None = None,
        black: np.ndarray | None = None,
        response: Response | str | Path | None = None,
    ) -> list[Registration]:
        """The registrations of several pairs, in order; the network runs on ``batch_size`` pairs of one
        size per call. ``white``, ``black``: as :meth:`register`, one pair of photos for every pair (a
        fixed rig)."""
        if not is_int(batch_size) or batch_size < 1:
            raise ProjregError(f"batch_size: expected an integer >= 1, got {batch_size!r}")
        pairs = _checked_pairs(pairs)
        photos = rig_photos(white, black, _response(response))
        return self.pipeline.register(pairs, batch_size, photos)

    def track(
        self,
        frames: Iterable[tuple[np.ndarray, np.ndarray]],
        *,
        white: np.ndarray | None = None,
        black: np.ndarray | None = None,
        response: Response | str | Path | None = None,
    ) -> Iterator[Registration]:
        """The registrations of a sequence's frames, in order: each frame refined from the previous one's
        flow, the network only for the first frame and where the track is lost (:mod:`projreg.inference.track`).
        Every frame of one sequence must have the sizes of the first. ``white``, ``black``: as
        :meth:`register`, the same photos for every frame."""
        if self.pipeline.refiner is None:
            raise ProjregError("tracking follows each frame with the refinement; use refine=True")
        if not isinstance(frames, Iterable) or isinstance(frames, np.ndarray):
            raise ProjregError(
                f"frames: expected an iterable of (projected, captured) pairs, got {type(frames).__name__}"
            )
        return self.pipeline.track(frames, rig_photos(white, black, _response(response)))

    def live(
        self,
        captured: int | str | os.PathLike | PlayedVideo | DeviceCamera,
        content: np.ndarray | str | os.PathLike | Content,
        *,
        predict_motion: bool = False,
        coverage: str = "complete",
        min_confidence: float = 0.0,
        fill: int = 0,
        limit: int | None = None,
    ) -> Live:
        """The live loop, as ``projreg live`` (:mod:`projreg.inference.live`): iterate over the answer for
        a :class:`~projreg.inference.live.LiveFrame` per registered camera frame, each registered from the
        previous one (tracking) and its pre-warped content frame (``LiveFrame.projector``, to show);
        frames that arrive meanwhile are dropped; then ``.summary()`` gives frames in, registered,
        dropped, fps and latency (median, p95) and ``.records()`` the numbers of every frame.

        Args:
            captured: an OpenCV camera index, a video file played as a camera in real time, or a
                :class:`~projreg.inference.realtime.PlayedVideo` / ``DeviceCamera`` (e.g. with a clock).
            content: what the projector is given to show: uint8 RGB ``(H, W, 3)``, an image file or a
                video (played at its rate, looping), or a :class:`~projreg.inference.realtime.Content`.
            predict_motion: carry each flow forward by the motion measured between the last two
                registrations, over the loop's latency.
            coverage, min_confidence, fill: which projector pixels show content, as :func:`compensate`.
            limit: stop after this many registered frames (None: when the camera ends).
        """
        if self.pipeline.refiner is None:
            raise ProjregError("the live loop tracks each frame with the refinement; use refine=True")
        check_coverage(coverage, min_confidence)
        if not (is_int(fill) and 0 <= fill <= 255):
            raise ProjregError(f"fill: must be an integer in 0..255, got {fill!r}")
        if limit is not None and (not is_int(limit) or limit < 1):
            raise ProjregError(f"limit: expected None or an integer >= 1, got {limit!r}")
        motion = check_flag("predict_motion", predict_motion)
        if isinstance(content, np.ndarray | str | os.PathLike):
            content = Content(content, "content")
        elif not isinstance(content, Content):
            raise ProjregError(f"content: expected an image array or a path, got {type(content).__name__}")
        if is_int(captured):
            camera = DeviceCamera(int(captured), "captured")
        elif isinstance(captured, str | os.PathLike):
            camera = PlayedVideo(check_path("captured", captured), "captured")
        elif isinstance(captured, PlayedVideo | DeviceCamera):
            camera = captured
        else:
            raise ProjregError(
                f"captured: expected a camera index, a video path or a camera, got {type(captured).__name__}"
            )
        options = {"coverage": coverage, "min_confidence": min_confidence, "fill": fill}
        return Live(self.pipeline, camera, content, predict_motion=motion, limit=limit, **options)


def _response(response: Response | str | Path | None) -> Response | None:
    """A measured response given as itself or as the path of a ``projsynth response`` file."""
    if not isinstance(response, str | os.PathLike):
        return response
    try:
        return read_response(check_path("response", response))
    except ProjsynthError as e:
        raise ProjregError(str(e)) from e


def _checked_pairs(pairs: object) -> list[tuple[np.ndarray, np.ndarray]]:
    """``pairs`` as a list of checked ``(projected, captured)`` images, or one line naming the bad one."""
    if isinstance(pairs, np.ndarray) or not isinstance(pairs, Iterable):
        raise ProjregError(f"pairs: expected a sequence of (projected, captured) pairs, got {type(pairs).__name__}")
    return [checked_pair(f"pairs[{i}]", pair) for i, pair in enumerate(pairs)]


def compensate(
    content: np.ndarray,
    registration: Registration,
    *,
    fill: int = 0,
    white: np.ndarray | None = None,
    black: np.ndarray | None = None,
    gamma: float | None = None,
    response: Response | str | Path | None = None,
    coverage: str = "complete",
    min_confidence: float = 0.0,
) -> np.ndarray:
    """The projector image that makes the camera see ``content`` (uint8 RGB, spanning the camera frame,
    any size, of the frame's aspect), as ``projreg compensate``: by default content on every projector
    pixel whose flow lands in the camera frame, ``fill`` elsewhere, and a registration that did not
    register projected as it is (``coverage="claimed"``: only the claimed pixels; ``min_confidence``:
    only where the confidence reaches it; :mod:`projreg.inference.compensate`). With ``white`` and
    ``black`` (the camera's photos of a full-white and a full-black projection) also corrected for the
    surface's colour and light, as ``--photometric``: with the devices' measured ``response`` (a
    :class:`projsynth.structured.response.Response`, e.g. from ``projsynth.fit_device_response``, or the
    path of a ``projsynth response`` file), else ``gamma`` for both (2.2 by default). Returns uint8 RGB
    on the projected grid."""
    _check_registration(registration)
    if not (is_int(fill) and 0 <= fill <= 255):
        raise ProjregError(f"fill: must be an integer in 0..255, got {fill!r}")
    image = check_image("content", content)
    camera = registration.camera_size
    check_aspect(image.shape, tuple(camera), "content")
    if (white is None) != (black is None):
        raise ProjregError("photometric compensation needs both the white and the black photo")
    if white is None and (response is not None or gamma is not None):
        raise ProjregError("response and gamma set the photometric correction; give the white and black photos")
    if response is not None and gamma is not None:
        raise ProjregError("gamma is the assumption a measured response replaces; give one of the two")
    response = _response(response)
    if white is not None:
        model = calibrate(
            check_image("white", white), check_image("black", black), 2.2 if gamma is None else gamma, response=response
        )
        if white.shape[:2] != tuple(camera):
            raise ProjregError(f"white photo is {white.shape[:2]}, the registration's camera frame {tuple(camera)}")
        image = solve(resize_to(image, white.shape), model)[0]
    return prewarp(image, **_answer(registration), coverage=coverage, min_confidence=min_confidence, fill=fill)


def warp_map(registration: Registration, *, coverage: str = "complete", min_confidence: float = 0.0) -> WarpMap:
    """The pre-warp of :func:`compensate` as a map, for a loop that warps every frame of a video: for every
    projector pixel the content point it shows, in normalised UV (an STMap's convention: ``u = (x + 0.5)
    / W`` to the right, ``v = 1 - (y + 0.5) / H`` up, ``(x, y)`` in pixels of a ``W x H`` content spanning
    the camera frame), and ``shown``, the pixels :func:`compensate` gives content with the same
    ``coverage`` and ``min_confidence`` (a registration that did not register: the identity map).
    ``WarpMap.remap_maps((H, W))`` gives ``cv2.remap``'s maps for a content of that size,
    ``WarpMap.stmap()`` the STMap's RGBA (:mod:`projreg.inference.warpmaps`)."""
    return flow_warp_map(**_answer(_check_registration(registration)), coverage=coverage, min_confidence=min_confidence)


def export_warp(
    source: Registration | str | os.PathLike,
    out: str | os.PathLike,
    *,
    step: int | None = None,
    content_size: tuple[int, int] | None = None,
    coverage: str = "complete",
    min_confidence: float = 0.0,
) -> dict:
    """Write the pre-warp of a registration, or of a flow EXR file (``projreg predict``'s), for show
    software, as ``projreg warp``: the format from the suffix of ``out``, ``.exr`` an STMap, ``.obj`` a
    mesh with a vertex every ``step`` projector pixels (16 by default), ``.npz`` ``cv2.remap``'s maps
    for a content of ``content_size`` ``(H, W)`` (default: the camera frame's), each with the coverage
    of :func:`compensate` (docs/show.md; :mod:`projreg.inference.warpfiles`). Returns what was written:
    ``format``, ``size``, ``shown`` and, for a mesh, its interpolation error ``error_mean`` and
    ``error_max`` in camera pixels (:func:`projreg.inference.warpfiles.write_warp`), with ``registered``
    and ``as_it_is`` (the pair was not registered: the map is the identity)."""
    out = check_path("out", out)
    if isinstance(source, str | os.PathLike):
        return export_warp_file(
            check_path("source", source),
            out,
            step=step,
            content_size=content_size,
            coverage=coverage,
            min_confidence=min_confidence,
        )
    m = warp_map(source, coverage=coverage, min_confidence=min_confidence)
    result = write_warp(m, out, step=step, content_size=content_size)
    return result | {"registered": source.registered, "as_it_is": as_it_is(source.registered, coverage)}


def _answer(reg: Registration) -> dict:
    """A registration as the arguments of :func:`~projreg.inference.compensate.prewarp` and
    :func:`~projreg.inference.warpmaps.warp_map`, which take the coverage apart."""
    return {
        "flow": reg.flow,
        "claimed": reg.claimed,
        "confidence": reg.confidence,
        "registered": reg.registered,
        "camera_size": tuple(reg.camera_size),
    }


def _check_registration(registration: object) -> Registration:
    if not isinstance(registration, Registration):
        raise ProjregError(
            f"registration: expected a Registration (Registrar.register's answer), got {type(registration).__name__}"
        )
    return registration


def end_point_error(
    flow: np.ndarray, truth: np.ndarray, valid: np.ndarray, claimed: np.ndarray | None = None
) -> dict[str, float | int | None]:
    """``projreg bench``'s metrics of one flow against a truth on its ``valid`` pixels (bool ``(H, W)``):
    ``epe`` (mean end-point error, px), the buckets ``s0-10``, ``s10-40``, ``s40+`` by the truth's
    magnitude, ``px1``/``px3``/``px5`` (shares of pixels off by more than that), ``pixels``; with
    ``claimed``, also ``epe_claimed`` and ``claimed`` (the claimed share of the valid pixels)."""
    flow, truth, valid = np.asarray(flow, np.float32), np.asarray(truth, np.float32), np.asarray(valid)
    for name, f in (("flow", flow), ("truth", truth)):
        if f.shape[:2] == valid.shape and f.ndim == 3 and not np.isfinite(f[valid.astype(bool)]).all():
            bad = int((~np.isfinite(f[valid.astype(bool)]).all(axis=-1)).sum())
            raise ProjregError(f"{name}: {bad} valid pixel(s) hold NaN or Inf; a flow is scored where it is finite")
    acc = EPEAccumulator()
    acc.add(flow, truth, valid, claimed)
    return acc.result()


__all__ = [
    "CONFIDENT",
    "LiveFrame",
    "Registrar",
    "Registration",
    "WarpMap",
    "compensate",
    "end_point_error",
    "export_warp",
    "warp_map",
]
