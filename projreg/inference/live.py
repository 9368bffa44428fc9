"""The live loop: register the camera's frames as they arrive and pre-warp the content with the newest
flow (``projreg live``, :meth:`projreg.api.Registrar.live`).

    camera (newest frame) -> pipeline.track (the first frame in full, each next from the previous flow)
        -> [--predict-motion: the flow carried forward by the measured motion] -> prewarp(content) -> out

* **Real time.** The loop asks the camera for its newest frame only once the previous one is warped;
  frames that arrive meanwhile are dropped and counted (:mod:`projreg.inference.realtime`): a slow
  registration lowers the rate, never grows a queue.
* **The pair registered** is the content frame on show when the camera frame arrived and that frame
  (the camera sees the projector showing the content); the **pre-warp** is of the content frame on
  show when the flow is ready (:func:`~projreg.inference.compensate.prewarp`, ``compensate``'s
  coverage policy).
* **Latency**: from the camera frame's arrival to its pre-warped frame being ready, per frame. The
  network and the refinement are warmed up on the content before the camera starts.
* **Motion prediction** (``predict_motion``): the rig keeps moving while a frame is registered, so the
  flow is stale by the latency when it is shown. With two registered frames ``i0 < i1`` and flows
  ``F0, F1``, the flow shown is ``F1 + (F1 - F0) * h / (i1 - i0)`` (:func:`extrapolate`: constant
  velocity per pixel, per camera frame), ``h`` the latency measured for this frame in camera frames;
  only between two tracked frames (a full registration, first or after a lost track, is another
  estimator: its difference from a tracked flow is not the rig's motion).

Convention: flows float32 ``(H, W, 2)``, forward, projected -> captured, camera pixels; times in
seconds since the loop started.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from projsynth.errors import ProjsynthError
from projsynth.utils.files import write_atomic

from ..errors import ProjregError
from .compensate import check_aspect, prewarp
from .pipeline import Pipeline
from .realtime import Content, DeviceCamera, PlayedVideo, Shot
from .register import Registration
from .video import VideoWriter

Camera = PlayedVideo | DeviceCamera


@dataclass(frozen=True)
class LiveFrame:
    """One registered camera frame and what the loop did with it.

    ``index``: the camera frame's number (dropped ones counted); ``registration``: its registration
    (``step``: ``full``, ``tracked`` or ``lost``); ``flow``: the flow the pre-warp used (the
    registration's, or carried forward by ``horizon`` camera frames); ``projector``: the pre-warped
    content frame (uint8 RGB on the projector's grid); ``content_index``: the content frame pre-warped;
    ``arrival``, ``warped``: seconds since the loop started; ``dropped``: camera frames dropped so far.
    """

    index: int
    registration: Registration
    flow: np.ndarray
    projector: np.ndarray
    content_index: int
    arrival: float
    warped: float
    horizon: float
    dropped: int

    @property
    def latency_ms(self) -> float:
        """From the camera frame's arrival to its pre-warped frame, in milliseconds."""
        return 1000 * (self.warped - self.arrival)


def extrapolate(flow: np.ndarray, previous: np.ndarray, frames_between: int, horizon: float) -> np.ndarray:
    """``flow`` carried ``horizon`` camera frames forward at the constant velocity it moved at since
    ``previous``, ``frames_between`` camera frames before it: ``flow + (flow - previous) * horizon /
    frames_between`` (per pixel; float32 ``(H, W, 2)``)."""
    return (flow + (flow - previous) * np.float32(horizon / frames_between)).astype(np.float32)


class Live:
    """The live loop (module docstring) over ``camera``'s frames: iterate to run it, one
    :class:`LiveFrame` per registered frame, until the camera ends, ``limit`` frames are registered, or
    the caller stops (a ``break``, Ctrl-C); :meth:`summary` then says how it went. It runs once (its
    camera is released at the end): iterating it again is an error; another run is another ``Live``.

    Args:
        pipeline: the registration (:class:`~projreg.inference.pipeline.Pipeline`, with its refinement).
        camera: a :class:`~projreg.inference.realtime.PlayedVideo` or
            :class:`~projreg.inference.realtime.DeviceCamera`, not started.
        content: what the projector is given (:class:`~projreg.inference.realtime.Content`).
        predict_motion: carry each flow forward by the measured motion (module docstring).
        coverage, min_confidence, fill: which projector pixels show content, as ``compensate``'s.
        limit: stop after this many registered frames (None: when the camera ends).
    """

    def __init__(
        self,
        pipeline: Pipeline,
        camera: Camera,
        content: Content,
        *,
        predict_motion: bool = False,
        coverage: str = "complete",
        min_confidence: float = 0.0,
        fill: int = 0,
        limit: int | None = None,
    ) -> None:
        self.pipeline, self.camera, self.content = pipeline, camera, content
        self.predict_motion, self.limit = predict_motion, limit
        self.clock = camera.clock  # latencies are measured on the clock the frames arrive by
        self.warp = {"coverage": coverage, "min_confidence": min_confidence, "fill": fill}
        self.log: list[dict] = []  # per registered frame, its numbers (:meth:`records`), not its images
        self.started = self.stopped = 0.0
        self.arrived = 0
        self.ran = False

    def __iter__(self) -> Iterator[LiveFrame]:
        if self.ran:
            raise ProjregError("the live loop runs once (its camera was released); call Registrar.live again")
        self.ran = True
        taken: list[Shot] = []  # the shot being registered, alone (a frame is never kept longer)

        def pairs() -> Iterator[tuple[np.ndarray, np.ndarray]]:
            while self.limit is None or len(self.log) < self.limit:
                shot = self.camera.take()
                if shot is None:
                    return
                taken[:] = [shot]
                yield self.content.at(shot.arrival)[0], shot.image

        shown = self.content.at(0.0)[0]
        self.pipeline.full(shown, shown)  # lazy initialisation (threads, kernels) before the camera starts
        start = self.camera.start()
        self.content.start(start)
        self.started, previous = start, None
        try:
            for reg in self.pipeline.track(pairs(), where="camera frames"):
                shot, flow, horizon = taken[-1], reg.flow, 0.0
                tracked = reg.registered and reg.step == "tracked"
                if self.predict_motion and previous is not None and tracked:
                    horizon = (self.clock() - shot.arrival) * self.camera.fps
                    flow = extrapolate(reg.flow, previous[1], shot.index - previous[0], horizon)
                image, content_index = self.content.at(self.clock())
                check_aspect(image.shape, reg.camera_size, self.content.option)
                projector = prewarp(
                    image,
                    flow,
                    claimed=reg.claimed,
                    confidence=reg.confidence,
                    registered=reg.registered,
                    camera_size=reg.camera_size,
                    **self.warp,
                )
                warped = self.clock()
                previous = (shot.index, reg.flow) if tracked else None
                frame = LiveFrame(
                    shot.index,
                    reg,
                    flow,
                    projector,
                    content_index,
                    shot.arrival - start,
                    warped - start,
                    horizon,
                    shot.index - len(self.log),
                )
                self.log.append(_record(frame))
                yield frame
        finally:
            self.stopped = self.clock()
            self.arrived = self.camera.arrived(self.stopped)
            self.camera.close()
            self.content.close()

    def summary(self) -> dict:
        """How the loop went: ``frames_in`` (camera frames that arrived while it ran), ``registered``,
        ``dropped`` (arrived, not registered), ``fps`` (registered frames per second of the run),
        ``latency_ms`` (``median``, ``p95``, ``max``; None before a frame), ``steps`` (full, tracked,
        lost), ``seconds`` and ``predict_motion``."""
        latency = np.array([r["latency_ms"] for r in self.log])
        seconds = max(self.stopped - self.started, 1e-9)
        return {
            "frames_in": self.arrived,
            "registered": len(self.log),
            "dropped": self.arrived - len(self.log),
            "fps": len(self.log) / seconds,
            "latency_ms": None
            if not self.log
            else {stat: float(f(latency)) for stat, f in (("median", np.median), ("p95", _p95), ("max", np.max))},
            "steps": {step: sum(r["step"] == step for r in self.log) for step in ("full", "tracked", "lost")},
            "seconds": seconds,
            "predict_motion": self.predict_motion,
        }

    def records(self) -> list[dict]:
        """Per registered frame: ``index`` (camera frame), ``content_index``, ``arrival_s``, ``warped_s``,
        ``latency_ms``, ``step``, ``registered``, ``claimed`` (share of the projector's pixels),
        ``horizon_frames`` (motion prediction) and ``dropped`` (camera frames dropped before it)."""
        return list(self.log)


def _p95(values: np.ndarray) -> float:
    return float(np.percentile(values, 95))


def _record(f: LiveFrame) -> dict:
    """A :class:`LiveFrame`'s numbers (:meth:`Live.records`)."""
    return {
        "index": f.index,
        "content_index": f.content_index,
        "arrival_s": round(f.arrival, 6),
        "warped_s": round(f.warped, 6),
        "latency_ms": round(f.latency_ms, 3),
        "step": f.registration.step,
        "registered": f.registration.registered,
        "claimed": round(float(f.registration.claimed.mean()), 4),
        "horizon_frames": round(f.horizon, 3),
        "dropped": f.dropped,
    }


def record_live(
    live: Live,
    out: Path | None = None,
    stats: Path | None = None,
    progress: Callable[[LiveFrame], None] | None = None,
) -> dict:
    """Run ``live`` to its end or to Ctrl-C (which stops it cleanly): the pre-warped frames go to the
    video ``out`` (one per registered frame, at the camera's rate; :class:`~projreg.inference.video.VideoWriter`),
    :meth:`Live.summary` and :meth:`Live.records` to the JSON file ``stats`` (``{"summary": ...,
    "frames": [...]}``); ``progress`` is called with each frame. After Ctrl-C both files keep what was
    done; after an error neither is written.

    Returns:
        :meth:`Live.summary` with ``interrupted`` (True: stopped by Ctrl-C).
    """
    writer = None if out is None else VideoWriter(Path(out), live.camera.fps)
    frames, interrupted = iter(live), False
    try:
        for frame in frames:
            if writer is not None:
                writer.write(frame.projector)
            if progress is not None:
                progress(frame)
    except KeyboardInterrupt:
        interrupted = True
    except BaseException:
        if writer is not None:
            writer.discard()
        raise
    finally:
        frames.close()  # the loop's clean-up (camera released, its counts taken) whoever stopped it
    if writer is not None:
        writer.close()
    summary = live.summary() | {"interrupted": interrupted}
    if stats is not None:
        report = {"summary": summary, "frames": live.records()}
        try:
            write_atomic(Path(stats), (json.dumps(report, indent=1) + "\n").encode())
        except ProjsynthError as e:
            raise ProjregError(str(e)) from e
    return summary
