"""``projreg bench``: models and classical baselines on the same shards, in one run, one report.

Every method sees every evaluated sample, ``predict(projected, captured) -> flow`` (a captured image
of another size is resized to the projected one and the flow scaled back, :mod:`projreg.geometry.frames`); metrics
are the pooled ones of :class:`~projreg.evaluation.metrics.EPEAccumulator` (EPE, buckets, outlier rates, per-image
mean, the per-pair distribution with the worst pair's id, and the EPE on the pixels a method claims with
the share it claims), overall and per group of samples:

* ``role``: ``natural_on_generated`` / ``generated_on_natural`` (``params["role"]``);
* ``family``: geometry family of the transform (``params["transform"]["family"]``);
* ``condition``: photometric condition (``params["transform"]["condition"]``);
* ``pair_role``: ``"pair P / ROLE"``, the columns of the paper's Table 2.

Models run through the geometric refinement of :mod:`projreg.refine` unless ``refine="off"``;
``refine="both"`` reports each model twice, refined under its name and the raw network as
``NAME-raw``. A method may return a :class:`~projreg.prediction.Prediction` (flow, claimed pixels,
registered or not) instead of a bare flow, which claims every pixel; ``sift-ransac`` claims none when
it finds no homography. Every result lists its ``pairs`` (per-pair figures) and names the pairs it
reported as not registered; ``versus_baselines`` compares each model with the best baseline pair by
pair (:func:`versus_baselines`). Groups appear in the order of their first sample. ``ms_per_pair`` is the median
wall-clock time of one ``predict`` call over the samples, after one untimed warm-up call on the
first sample.

Tracking (``track=True``, a sequence dataset of ``projsynth gen --frames N``): the samples are
taken sequence by sequence, and each refined model also runs as ``NAME+track`` and each dense
baseline as ``NAME+track`` (:mod:`projreg.inference.track`: the first frame registered in full, each next one
from the previous frame's flow); every result then carries ``jitter`` (``track.JitterAccumulator``)
and the tracking rows ``tracking`` (how many frames were tracked, registered in full or re-registered
after a lost track) and ``ms_mean`` (the mean time per frame, full registrations included).
With ``photos=True`` (a generated dataset of built-in sources), each model also runs as ``NAME+photos``
on the captured image with the surface divided out by the sample's white and black photos
(:mod:`projreg.evaluation.rigphotos`). The report schema is documented in docs/cli/projreg.md.

Convention: flow forward, projected -> captured, ``(H, W, 2)`` in pixels, ``flow[y, x] = (u, v)``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import torch

from projsynth.dataset.shards import ShardReader
from projsynth.errors import ProjsynthError
from projsynth.utils.outputs import folder_files, refuse_overwriting_inputs

from ..errors import ProjregError
from ..geometry.frames import register_any_size, resize_to
from ..inference.runtime import DEFAULT_BACKEND
from ..inference.track import JitterAccumulator
from ..model.checkpoint import reference_checkpoint
from ..prediction import Prediction, as_prediction
from ..refine.config import DEFAULT_QUALITY
from .closedloop import RESPONSES, UNCOMPENSATED, ClosedLoop, compensation_means, sheet_row
from .methods import DEFAULT_BASELINES, REFINE_MODES, Method, ModelRun, resolve_methods
from .metrics import KEYS, EPEAccumulator, sample_indices
from .reliability import ReliabilityAccumulator
from .report import versus_baselines
from .rigphotos import RigPhotos

GROUPS = ("role", "family", "condition", "pair_role")
SHEET_ROWS = 4


def sample_groups(params: dict) -> dict[str, str]:
    """The group of a sample under each key of ``GROUPS``, from its shard parameters."""
    try:
        role, pair = params["role"], params["pair"]
        family, condition = params["transform"]["family"], params["transform"]["condition"]
    except (KeyError, TypeError) as e:
        raise ProjregError(f"sample {params.get('sample_id')!r} lacks parameter {e}; regenerate the dataset") from e
    return {"role": role, "family": family, "condition": condition, "pair_role": f"pair {pair} / {role}"}


class _Scores:
    """One method's accumulators (overall and per group) and per-sample timings."""

    def __init__(self, track: bool = False) -> None:
        self.jitter = JitterAccumulator() if track else None
        self.all = EPEAccumulator()
        self.reliability = ReliabilityAccumulator()  # fed by the methods that measure a confidence
        self.groups: dict[str, dict[str, EPEAccumulator]] = {g: {} for g in GROUPS}
        self.ms: list[float] = []
        self.comp: list[dict[str, float | None]] = []  # per sample, with --compensation
        self.pairs: list[dict] = []

    def add(
        self, pred: Prediction, gt: np.ndarray, valid: np.ndarray, groups: dict[str, str], sid: str, sequence: str = ""
    ) -> None:
        if self.jitter is not None:
            self.jitter.add(sequence, pred.flow, gt, valid)
        one = EPEAccumulator()
        one.add(pred.flow, gt, valid, pred.claimed, sid)
        if pred.confidence is not None and pred.registered:
            self.reliability.add(pred.flow, gt, valid, pred.confidence)
        self.all.merge(one)
        for g, key in groups.items():
            self.groups[g].setdefault(key, EPEAccumulator()).merge(one)
        r = one.result()
        self.pairs.append(
            {
                "id": sid,
                "epe": r["epe"],
                "epe_claimed": r["epe_claimed"],
                "claimed": r["claimed"],
                "registered": pred.registered,
            }
        )

    def result(self, method: Method) -> dict:
        out = {"name": method.name, "kind": method.kind, "refined": method.refined, **self.all.result()}
        out["ms_per_pair"] = float(np.median(self.ms)) if self.ms else None
        if self.jitter is not None:
            out["jitter"] = self.jitter.result()
        if method.tracker is not None:
            out["ms_mean"] = float(np.mean(self.ms)) if self.ms else None
            out["tracking"] = dict(method.tracker.counts)
        if self.comp:
            out.update(compensation_means(self.comp))
        if self.reliability.pixels.any():
            out["reliability"] = self.reliability.result()
        out["unregistered"] = [p["id"] for p in self.pairs if not p["registered"]]
        out["groups"] = {g: {k: acc.result() for k, acc in accs.items()} for g, accs in self.groups.items()}
        out["pairs"] = self.pairs
        return out


def run_bench(
    data: Path,
    *,
    models: Sequence[Path] = (),
    baselines: Sequence[str] = DEFAULT_BASELINES,
    equalize: bool = False,
    refine: str = "on",
    limit: int | None = None,
    extra_methods: Sequence[Method] = (),
    device: torch.device | str | None = None,
    precision: str = "fp32",
    backend: str = DEFAULT_BACKEND,
    quality: str = DEFAULT_QUALITY,
    compensation: bool = False,
    photometric: bool = False,
    response: str | None = None,
    sheet: list[np.ndarray] | None = None,
    progress: Callable[[int, int], None] | None = None,
    track: bool = False,
    batch_size: int = 1,
    photos: bool = False,
) -> dict:
    """Benchmark checkpoints and baselines on one dataset directory.

    Args:
        data: a projsynth dataset directory (``manifest.json`` + shards).
        models: checkpoint paths; empty: the shipped reference model when it exists.
        baselines: baseline registry names, in report order.
        equalize: histogram-equalise both images before the baselines (see ``projreg.evaluation.baselines``).
        refine: ``"on"``, ``"off"`` or ``"both"``: models with/without/both ways the geometric
            refinement (``model_methods``).
        limit: evaluate ``limit`` samples spread evenly over the dataset (None: all); with ``track``,
            ``limit`` whole sequences.
        extra_methods: more methods, reported after the others (a hook for callers and tests).
        device: where models run (``cpu``, ``cuda``, ``cuda:N``); default CUDA when available, else CPU.
        precision, backend: how models run (``fp32``/``bf16``/``fp16``, ``auto``/``torch``/``onnxruntime``:
            :func:`projreg.inference.runtime.open_network`).
        quality: the quality setting of every model (:data:`projreg.refine.config.QUALITIES`: where the
            network runs and how the refinement searches).
        compensation: also judge each method's compensation by what the camera sees
            (``comp_psnr``, ``comp_ssim`` and an ``uncompensated`` row; :mod:`projreg.evaluation.closedloop`).
        photometric: with ``compensation``, also geometric-only vs geometric + photometric against the
            desired view (``geo_*``, ``photo_*``).
        response: with ``photometric``, the devices' curves of the photometric model: ``gamma`` (None: the
            default), assumed, or ``measured`` per sample from grey levels (``closedloop.ClosedLoop``); the
            report's ``photometric_response`` says which, and how the fits went.
        sheet: with ``compensation``, a list that receives a contact-sheet row (``closedloop.sheet_row``)
            for each of the first ``SHEET_ROWS`` samples: the first method's pictures.
        progress: called ``(done, total)`` once the inputs are checked (``done`` 0), then after each sample.
        track: tracking mode on a sequence dataset (module docstring).
        batch_size: > 1: each model's network runs on this many samples per call (pairs of one size
            batched, :class:`BatchedFlows`); a model's ``ms_per_pair`` then counts its share of the
            batch's network call.
        photos: also each model as ``NAME+photos``, on the capture divided by the sample's white and
            black photos (module docstring; the ``+photos`` rows follow the models and baselines).

    Returns:
        The report: ``{"dataset": {...}, "reference_model": str | None, "results": [...]}``, one
        result per method (see docs/cli/projreg.md).
    """
    data = Path(data)
    _check_options(refine, batch_size, track, compensation, photometric)
    if photos and track:
        raise ProjregError("--photos registers single pairs; drop --track")
    if response is not None and not photometric:
        raise ProjregError("--response chooses the photometric model's device curves; add --photometric")
    response = response or RESPONSES[0]
    try:
        reader = ShardReader(data)
    except ProjsynthError as e:
        raise ProjregError(f"--data {data}: {e}") from e
    try:
        indices = _bench_indices(reader, data, track, limit)
        rig = RigPhotos(data) if photos else None
        run = ModelRun(refine, device, precision, backend, quality, track, batch_size)
        methods, reference = resolve_methods(models, baselines, run, equalize)
        methods += (rig.methods(methods) if rig else []) + list(extra_methods)
        if not methods:
            raise ProjregError("nothing to benchmark: no --model, no shipped reference model and --baselines none")
        names = [m.name for m in methods]
        if len(set(names)) < len(names):
            raise ProjregError(f"method names must be unique, got {', '.join(names)}")
        scores = [_Scores(track) for _ in methods]
        loop, uncompensated = (ClosedLoop(data, photometric, response), _Scores()) if compensation else (None, None)
        first = _read(reader, indices[0])
        if rig:
            rig.shoot(indices[0], first)
        _warm_up(methods, first)
        if progress:
            progress(0, len(indices))  # the bar from here: the inputs are good
        chunk: dict[int, dict] = {}
        for done, k in enumerate(indices, start=1):
            if done not in chunk:  # the next batch_size samples, read (and their network flows computed) together
                ks = indices[done - 1 : done - 1 + batch_size]
                chunk = {done + j: first if done + j == 1 else _read(reader, kj) for j, kj in enumerate(ks)}
                shares = _prefetch(methods, list(chunk.values()))
            s = chunk[done]
            if rig:
                rig.shoot(k, s)
            preds = _score_sample(methods, scores, s, k, shares, track)
            if loop is not None:
                comp = loop.score(k, s, preds)
                uncompensated.comp.append(comp.pop(UNCOMPENSATED))
                for m, sc in zip(methods, scores, strict=True):
                    sc.comp.append(comp[m.name])
                if sheet is not None and done <= SHEET_ROWS:
                    sheet.append(
                        sheet_row(loop.last_views, methods[0].name, f"{s['params']['sample_id']}: {methods[0].name}")
                    )
            if progress:
                progress(done, len(indices))
    finally:
        reader.close()
    results = [sc.result(m) for m, sc in zip(methods, scores, strict=True)]
    if uncompensated is not None:
        row = uncompensated.result(Method(UNCOMPENSATED, "none", lambda a, b: a))
        results.append({**row, **{k: None for k in KEYS if k not in ("pixels", "images")}, "ms_per_pair": None})
    report = {
        "dataset": _dataset_info(reader, data, len(indices)),
        "reference_model": None if reference is None else str(reference),
        "results": results,
        "versus_baselines": versus_baselines(results),
    }
    if loop is not None and photometric:
        report["photometric_response"] = {"mode": response, **(loop.fits if response == "measured" else {})}
    return report


def _check_options(refine: str, batch_size: int, track: bool, compensation: bool, photometric: bool) -> None:
    if refine not in REFINE_MODES:
        raise ProjregError(f"--refine must be one of {', '.join(REFINE_MODES)}, got {refine!r}")
    if batch_size < 1:
        raise ProjregError(f"--batch-size must be >= 1, got {batch_size}")
    if track and batch_size > 1:
        raise ProjregError("--track registers frame after frame; drop --batch-size")
    if photometric and not compensation:
        raise ProjregError("--photometric needs --compensation (it scores the camera's view of a compensation)")


def _bench_indices(reader: ShardReader, data: Path, track: bool, limit: int | None) -> list[int]:
    """The samples to evaluate: ``limit`` spread evenly (with ``track``, ``limit`` whole sequences)."""
    frames = reader.manifest.get("frames", 1)
    if track and frames < 2:
        raise ProjregError(f"--track: {data} holds single frames; make sequences with `projsynth gen --frames N`")
    if track:
        indices = [s * frames + f for s in sample_indices(len(reader) // frames, limit) for f in range(frames)]
    else:
        indices = sample_indices(len(reader), limit)
    if not indices:
        raise ProjregError(f"--data {data}: the dataset has no samples")
    return indices


def _warm_up(methods: list[Method], sample: dict) -> None:
    """One pair through every method before timing: lazy initialisation, allocator, CUDA kernels."""
    for m in methods:
        register_any_size(m.predict, sample["projected"], sample["captured"])
        if m.tracker is not None:
            m.tracker.counts = dict.fromkeys(m.tracker.counts, 0)


def _score_sample(
    methods: list[Method], scores: list[_Scores], s: dict, k: int, shares: dict[str, float], track: bool
) -> dict[str, Prediction]:
    """Every method's answer for sample ``s`` (index ``k``), timed and scored, by method name."""
    groups = sample_groups(s["params"])
    sid = str(s["params"].get("sample_id", k))
    if track and s["params"].get("frame", 0) == 0:  # a sequence starts: the trackers forget
        for m in methods:
            if m.tracker is not None:
                m.tracker.reset()
    preds = {}
    for m, sc in zip(methods, scores, strict=True):
        t0 = time.perf_counter()
        pred = as_prediction(register_any_size(m.predict, s["projected"], s["captured"]))
        sc.ms.append(1000 * (time.perf_counter() - t0) + shares.get(m.name, 0.0))
        sc.add(pred, s["flow"], s["valid"], groups, sid, str(s["params"].get("sequence", "")))
        preds[m.name] = pred
    return preds


def _dataset_info(reader: ShardReader, data: Path, evaluated: int) -> dict:
    man = reader.manifest
    return {
        "path": str(data),
        "num_samples": len(reader),
        "evaluated": evaluated,
        "size": man.get("size"),
        "camera_size": man.get("camera_size", man.get("size")),
        "seed": man.get("seed"),
        "split": man.get("split"),
        "config_hash": man.get("config_hash"),
    }


def _prefetch(methods: Sequence[Method], samples: Sequence[dict]) -> dict[str, float]:
    """Each distinct ``prefetch`` of ``methods`` on the samples' pairs, once; its milliseconds per
    pair, keyed by the names of the methods that share it."""
    pairs = [(s["projected"], resize_to(s["captured"], s["projected"].shape)) for s in samples]
    spent: dict[Callable, float] = {}
    for m in methods:
        if m.prefetch is not None and m.prefetch not in spent:
            t0 = time.perf_counter()
            m.prefetch(pairs)
            spent[m.prefetch] = 1000 * (time.perf_counter() - t0) / len(pairs)
    return {m.name: spent[m.prefetch] for m in methods if m.prefetch is not None}


def _read(reader: ShardReader, k: int) -> dict:
    try:
        return reader.read(k)
    except ProjsynthError as e:
        raise ProjregError(str(e)) from e


def check_outputs(data: Path, models: Sequence[Path], outputs: Sequence[tuple[str, Path | None]]) -> None:
    """Refuse, before any work, a report path that is one of the inputs (a file of the dataset, a
    model) or another report path: the report would destroy what it measured.

    Raises:
        ProjregError: naming both options.
    """
    inputs = folder_files("--data", Path(data))
    for spec in models:
        path = Path(spec)
        if path.exists():
            inputs.append(("--model", path))
    reference = reference_checkpoint()
    if reference is not None:
        inputs.append(("--model", reference))
    try:
        refuse_overwriting_inputs(outputs, inputs)
    except ProjsynthError as e:
        raise ProjregError(str(e)) from None
