"""What ``projreg bench`` measures: each model (network, refinement, fast path, tracking, batched network
calls) and each classical baseline as a :class:`Method` with its own timing."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..errors import ProjregError
from ..inference.pipeline import Pipeline
from ..inference.runtime import DEFAULT_BACKEND
from ..inference.track import FlowTracker, Tracker
from ..model.checkpoint import reference_checkpoint, resolve_checkpoint
from ..prediction import Prediction
from ..refine.config import DEFAULT_QUALITY
from .baselines import make_baseline

DEFAULT_BASELINES = ("dis-fast", "dis-medium", "farneback", "sift-ransac")


REFINE_MODES = ("on", "off", "both")


@dataclass(frozen=True)
class Method:
    """A named predictor: ``predict(projected, captured)`` -> float32 flow ``(H, W, 2)`` or a
    :class:`~projreg.prediction.Prediction`.

    ``kind`` is ``"model"`` (gated by ``--fail-above``) or ``"baseline"`` (never gated); ``refined``
    says whether the geometric refinement (``projreg.refine``) follows the network; ``tracker``: the
    :class:`~projreg.inference.track.Tracker` or :class:`~projreg.inference.track.FlowTracker` that
    ``predict`` is, for a tracking method (reset at the start of each sequence); ``prefetch``: given the next samples'
    ``(projected, captured)`` pairs, computes their network flows in batches, which ``predict`` then
    uses for those very arrays (``bench --batch-size``).
    """

    name: str
    kind: str
    predict: Callable[[np.ndarray, np.ndarray], np.ndarray | Prediction]
    refined: bool = False
    tracker: Tracker | FlowTracker | None = None
    prefetch: Callable[[Sequence[tuple[np.ndarray, np.ndarray]]], None] | None = None


@dataclass(frozen=True)
class ModelRun:
    """How every checkpoint of a bench runs (:func:`model_methods`).

    ``refine`` (``REFINE_MODES``): ``"on"``, the network then the geometric refinement; ``"off"``, the
    network alone; ``"both"``, the refined method named ``name`` and the network alone named
    ``name-raw``. ``device``, ``precision`` and ``backend`` say where and how the network runs
    (:func:`projreg.inference.runtime.open_network`; ``backend="onnxruntime"`` takes a ``.onnx`` file); ``quality``
    names the setting of :data:`projreg.refine.config.QUALITIES` (the network's side and the refinement;
    names end in ``-fast`` or ``-balanced`` for those two). ``track``: also the refined method tracking
    (:class:`~projreg.inference.track.Tracker`),
    named ``name+track``; ``batch_size`` > 1: the methods get a ``prefetch`` (:class:`BatchedFlows`)
    shared between them.
    """

    refine: str = "on"
    device: torch.device | str | None = None
    precision: str = "fp32"
    backend: str = DEFAULT_BACKEND
    quality: str = DEFAULT_QUALITY
    track: bool = False
    batch_size: int = 1


def model_methods(path: Path, name: str | None = None, run: ModelRun = ModelRun()) -> list[Method]:
    """A checkpoint as methods named ``name`` (default: the file stem), run as ``run`` says (:class:`ModelRun`)."""
    refine, track, batch_size = run.refine, run.track, run.batch_size
    if refine not in REFINE_MODES:
        raise ProjregError(f"--refine must be one of {', '.join(REFINE_MODES)}, got {refine!r}")
    if track and refine == "off":
        raise ProjregError("--track follows each frame with the refinement; use --refine on or both")
    pipeline = Pipeline(path, quality=run.quality, device=run.device, precision=run.precision, backend=run.backend)
    name = (name or Path(path).stem) + ("" if pipeline.quality == DEFAULT_QUALITY else f"-{pipeline.quality}")
    batched = BatchedFlows(pipeline, batch_size) if batch_size > 1 else None

    def raw(img0: np.ndarray, img1: np.ndarray) -> np.ndarray:
        if batched is not None:
            return batched(img0, img1)
        return pipeline.flows([(img0, img1)])[0]

    def refined(img0: np.ndarray, img1: np.ndarray) -> Prediction:
        return pipeline.refined(img0, img1, raw(img0, img1))

    prefetch = None if batched is None else batched.prefetch
    if refine == "off":
        return [Method(name, "model", raw, prefetch=prefetch)]
    both = [
        Method(name, "model", refined, True, prefetch=prefetch),
        Method(f"{name}-raw", "model", raw, prefetch=prefetch),
    ]
    tracker = pipeline.tracker(refined)
    return (both if refine == "both" else both[:1]) + (
        [Method(f"{name}+track", "model", tracker, True, tracker)] if track else []
    )


class BatchedFlows:
    """Network flows computed ahead in batches (``bench --batch-size``), handed out by the arrays.

    :meth:`prefetch` runs the next pairs through the pipeline's network, ``batch_size`` pairs of one size
    per call (:meth:`~projreg.inference.pipeline.Pipeline.flows`); calling the object with a pair returns the flow
    prefetched for those arrays (the same projected array, an equal captured one), or computes it
    alone when it was not prefetched (a captured image resized to the projected one's size).
    """

    def __init__(self, pipeline: Pipeline, batch_size: int) -> None:
        self.pipeline, self.batch_size = pipeline, batch_size
        self.pairs: list[tuple[np.ndarray, np.ndarray]] = []
        self.flows: list[np.ndarray] = []

    def prefetch(self, pairs: Sequence[tuple[np.ndarray, np.ndarray]]) -> None:
        self.pairs = list(pairs)
        self.flows = self.pipeline.flows(self.pairs, self.batch_size)

    def __call__(self, projected: np.ndarray, captured: np.ndarray) -> np.ndarray:
        for (a, b), flow in zip(self.pairs, self.flows, strict=True):
            if a is projected and (b is captured or np.array_equal(b, captured)):
                return flow
        return self.pipeline.flows([(projected, captured)])[0]


def baseline_method(name: str, equalize: bool = False) -> Method:
    """A classical baseline by registry name (``projreg.evaluation.baselines.BASELINES``).

    Baselines claim every pixel, except ``sift-ransac`` when it found no homography (its zero flow
    then says "no answer"; ``last_status`` is not ``"ok"``): it claims none and is not registered;
    ``refine-only`` claims what the refinement verified, as the refined model does.
    """
    baseline = make_baseline(name, equalize)

    def predict(img0: np.ndarray, img1: np.ndarray) -> Prediction:
        flow = baseline.predict(img0, img1)
        if isinstance(flow, Prediction):  # refine-only claims pixels itself
            return flow
        status = getattr(baseline, "last_status", "ok")
        if status == "ok":
            return Prediction(flow)
        return Prediction(flow, np.zeros(flow.shape[:2], bool), False, status)

    return Method(name, "baseline", predict)


def baseline_track_method(name: str, equalize: bool = False) -> Method | None:
    """A dense baseline tracking (:class:`~projreg.inference.track.FlowTracker`), named ``name+track``; None for
    ``sift-ransac``, whose homography of matches has no use for a previous flow."""
    if name == "sift-ransac":
        return None
    tracker = FlowTracker(make_baseline(name, equalize).predict)
    return Method(f"{name}+track", "baseline", tracker, tracker=tracker)


def resolve_methods(
    models: Sequence[Path],
    baselines: Sequence[str],
    run: ModelRun = ModelRun(),
    equalize: bool = False,
) -> tuple[list[Method], Path | None]:
    """Checkpoints then baselines as methods; without checkpoints, the shipped reference model if any.

    Each checkpoint gives one to three methods (:func:`model_methods`, as ``run`` says); with
    ``run.track``, the dense baselines' tracking methods follow the baselines.

    Returns:
        ``(methods, reference)``: ``reference`` is the shipped checkpoint when it was added, else None.
        A checkpoint whose stem is already taken is named by its path without suffix.
    """
    reference = None if models else reference_checkpoint()
    methods: list[Method] = []
    if reference is not None:
        methods += model_methods(reference, "reference", run)
    paths = [resolve_checkpoint(p) for p in models]
    for i, path in enumerate(paths):
        if path.resolve() in {q.resolve() for q in paths[:i]}:
            raise ProjregError(f"--model {path}: given twice")
    for spec, path in zip(models, paths, strict=True):
        if str(spec) == "reference" and path == reference_checkpoint():
            reference = path
        taken = {m.name for m in methods} | set(baselines)
        name = path.stem if path.stem not in taken else str(path.with_suffix(""))
        methods += model_methods(path, name, run)
    methods += [baseline_method(name, equalize) for name in baselines]
    if run.track:
        methods += [m for m in (baseline_track_method(name, equalize) for name in baselines) if m is not None]
    return methods, reference
