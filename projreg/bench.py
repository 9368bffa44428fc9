"""``projreg bench``: models and classical baselines on the same shards, in one run, one report.

Every method sees every evaluated sample, ``predict(projected, captured) -> flow`` (a captured image
of another size is resized to the projected one and the flow scaled back, :mod:`projreg.frames`); metrics
are the pooled ones of :class:`~projreg.metrics.EPEAccumulator` (EPE, buckets, outlier rates, per-image
mean, the per-pair distribution with the worst pair's id, and the EPE on the pixels a method claims with
the share it claims), overall and per group of samples:

* ``role``: ``natural_on_generated`` / ``generated_on_natural`` (``params["role"]``);
* ``family``: geometry family of the transform (``params["transform"]["family"]``);
* ``condition``: photometric condition (``params["transform"]["condition"]``);
* ``pair_role``: ``"pair P / ROLE"``, the columns of the paper's Table 2.

Models run through the geometric refinement of :mod:`projreg.refine` unless ``refine="off"``;
``refine="both"`` reports each model twice, refined under its name and the raw network as
``NAME-raw``. A method may return a :class:`~projreg.confidence.Prediction` (flow, claimed pixels,
registered or not) instead of a bare flow, which claims every pixel; ``sift-ransac`` claims none when
it finds no homography. Every result lists its ``pairs`` (per-pair figures) and names the pairs it
reported as not registered; ``versus_baselines`` compares each model with the best baseline pair by
pair (:func:`versus_baselines`). Groups appear in the order of their first sample. ``ms_per_pair`` is the median
wall-clock time of one ``predict`` call over the samples, after one untimed warm-up call on the
first sample.

Tracking (``track=True``, a sequence dataset of ``projsynth gen --frames N``): the samples are
taken sequence by sequence, and each refined model also runs as ``NAME+track`` and each dense
baseline as ``NAME+track`` (:mod:`projreg.track`: the first frame registered in full, each next one
from the previous frame's flow); every result then carries ``jitter`` (``track.JitterAccumulator``)
and the tracking rows ``tracking`` (how many frames were tracked, registered in full or re-registered
after a lost track) and ``ms_mean`` (the mean time per frame, full registrations included).
The report schema is documented in docs/cli/projreg.md.

Convention: flow forward, projected -> captured, ``(H, W, 2)`` in pixels, ``flow[y, x] = (u, v)``.
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from projsynth import ProjsynthError
from projsynth.export import png_bytes
from projsynth.flowio import write_atomic_all
from projsynth.shards import ShardReader

from . import ProjregError
from .baselines import make_baseline
from .checkpoint import reference_checkpoint, resolve_checkpoint
from .closedloop import UNCOMPENSATED, ClosedLoop, compensation_means, sheet_header, sheet_row
from .confidence import Prediction, as_prediction
from .evaluate import sample_indices
from .frames import register_any_size, resize_to
from .infer import FAST_MAX_SIDE, flows_resized, open_network
from .metrics import BUCKETS, KEYS, THRESHOLDS, EPEAccumulator
from .refine import FAST_REFINE, GeometricRefiner
from .track import FlowTracker, JitterAccumulator, Tracker

DEFAULT_BASELINES = ("dis-fast", "dis-medium", "farneback", "sift-ransac")
GATED = ("epe", *BUCKETS, *(f"px{t}" for t in THRESHOLDS))
GROUPS = ("role", "family", "condition", "pair_role")
TABLE_METRICS = (("EPE", "epe"), *((b, b) for b in BUCKETS))
REFINE_MODES = ("on", "off", "both")
SHEET_ROWS = 4
RATIO_LIMIT = 1.5  # issue 16: per pair, a model's EPE on its claimed pixels <= 1.5x the best baseline's


@dataclass(frozen=True)
class Method:
    """A named predictor: ``predict(projected, captured)`` -> float32 flow ``(H, W, 2)`` or a
    :class:`~projreg.confidence.Prediction`.

    ``kind`` is ``"model"`` (gated by ``--fail-above``) or ``"baseline"`` (never gated); ``refined``
    says whether the geometric refinement (``projreg.refine``) follows the network; ``tracker``: the
    :class:`~projreg.track.Tracker` or :class:`~projreg.track.FlowTracker` that ``predict`` is, for a
    tracking method (reset at the start of each sequence); ``prefetch``: given the next samples'
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
    (:func:`projreg.infer.open_network`; ``backend="onnxruntime"`` takes a ``.onnx`` file); ``fast`` is
    ``predict --fast``'s path (the network at ``FAST_MAX_SIDE``, the refinement ``FAST_REFINE``; names
    end in ``-fast``). ``track``: also the refined method tracking (:class:`~projreg.track.Tracker`),
    named ``name+track``; ``batch_size`` > 1: the methods get a ``prefetch`` (:class:`BatchedFlows`)
    shared between them.
    """

    refine: str = "on"
    device: torch.device | str | None = None
    precision: str = "fp32"
    backend: str = "torch"
    fast: bool = False
    track: bool = False
    batch_size: int = 1


def model_methods(path: Path, name: str | None = None, run: ModelRun = ModelRun()) -> list[Method]:
    """A checkpoint as methods named ``name`` (default: the file stem), run as ``run`` says (:class:`ModelRun`)."""
    refine, track, fast, batch_size = run.refine, run.track, run.fast, run.batch_size
    if refine not in REFINE_MODES:
        raise ProjregError(f"--refine must be one of {', '.join(REFINE_MODES)}, got {refine!r}")
    if track and refine == "off":
        raise ProjregError("--track follows each frame with the refinement; use --refine on or both")
    net = open_network(path, backend=run.backend, device=run.device, precision=run.precision)
    name = (name or Path(path).stem) + ("-fast" if fast else "")
    refiner = GeometricRefiner(FAST_REFINE if fast else None)
    max_side = FAST_MAX_SIDE if fast else sys.maxsize
    batched = BatchedFlows(net, max_side, batch_size) if batch_size > 1 else None

    def raw(img0: np.ndarray, img1: np.ndarray) -> np.ndarray:
        if batched is not None:
            return batched(img0, img1)
        return flows_resized(net, [(img0, img1)], max_side)[0]

    def refined(img0: np.ndarray, img1: np.ndarray) -> Prediction:
        return refiner.predict(img0, img1, raw(img0, img1))

    prefetch = None if batched is None else batched.prefetch
    if refine == "off":
        return [Method(name, "model", raw, prefetch=prefetch)]
    both = [
        Method(name, "model", refined, True, prefetch=prefetch),
        Method(f"{name}-raw", "model", raw, prefetch=prefetch),
    ]
    tracker = Tracker(refined, refiner)
    return (both if refine == "both" else both[:1]) + (
        [Method(f"{name}+track", "model", tracker, True, tracker)] if track else []
    )


class BatchedFlows:
    """Network flows computed ahead in batches (``bench --batch-size``), handed out by the arrays.

    :meth:`prefetch` runs the next pairs through the network, ``batch_size`` pairs of one size per
    call (:func:`~projreg.infer.flows_resized`); calling the object with a pair returns the flow
    prefetched for those arrays (the same projected array, an equal captured one), or computes it
    alone when it was not prefetched (a captured image resized to the projected one's size).
    """

    def __init__(self, net: Callable, max_side: int, batch_size: int) -> None:
        self.net, self.max_side, self.batch_size = net, max_side, batch_size
        self.pairs: list[tuple[np.ndarray, np.ndarray]] = []
        self.flows: list[np.ndarray] = []

    def prefetch(self, pairs: Sequence[tuple[np.ndarray, np.ndarray]]) -> None:
        self.pairs = list(pairs)
        self.flows = flows_resized(self.net, self.pairs, self.max_side, self.batch_size)

    def __call__(self, projected: np.ndarray, captured: np.ndarray) -> np.ndarray:
        for (a, b), flow in zip(self.pairs, self.flows, strict=True):
            if a is projected and (b is captured or np.array_equal(b, captured)):
                return flow
        return flows_resized(self.net, [(projected, captured)], self.max_side)[0]


def baseline_method(name: str, equalize: bool = False) -> Method:
    """A classical baseline by registry name (``projreg.baselines.BASELINES``).

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
    """A dense baseline tracking (:class:`~projreg.track.FlowTracker`), named ``name+track``; None for
    ``sift-ransac``, whose homography of matches has no use for a previous flow."""
    if name == "sift-ransac":
        return None
    tracker = FlowTracker(make_baseline(name, equalize).predict)
    return Method(f"{name}+track", "baseline", tracker, tracker=tracker)


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
        out["unregistered"] = [p["id"] for p in self.pairs if not p["registered"]]
        out["groups"] = {g: {k: acc.result() for k, acc in accs.items()} for g, accs in self.groups.items()}
        out["pairs"] = self.pairs
        return out


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
    backend: str = "torch",
    fast: bool = False,
    compensation: bool = False,
    photometric: bool = False,
    sheet: list[np.ndarray] | None = None,
    progress: Callable[[int, int], None] | None = None,
    track: bool = False,
    batch_size: int = 1,
) -> dict:
    """Benchmark checkpoints and baselines on one dataset directory.

    Args:
        data: a projsynth dataset directory (``manifest.json`` + shards).
        models: checkpoint paths; empty: the shipped reference model when it exists.
        baselines: baseline registry names, in report order.
        equalize: histogram-equalise both images before the baselines (see ``projreg.baselines``).
        refine: ``"on"``, ``"off"`` or ``"both"``: models with/without/both ways the geometric
            refinement (``model_methods``).
        limit: evaluate ``limit`` samples spread evenly over the dataset (None: all); with ``track``,
            ``limit`` whole sequences.
        extra_methods: more methods, reported after the others (a hook for callers and tests).
        device: where models run (``cpu``, ``cuda``, ``cuda:N``); default CUDA when available, else CPU.
        precision, backend: how models run (``fp32``/``bf16``/``fp16``, ``torch``/``onnxruntime``:
            :func:`projreg.infer.open_network`).
        fast: ``predict --fast``'s path for every model (network at ``FAST_MAX_SIDE``, ``FAST_REFINE``).
        compensation: also judge each method's compensation by what the camera sees
            (``comp_psnr``, ``comp_ssim`` and an ``uncompensated`` row; :mod:`projreg.closedloop`).
        photometric: with ``compensation``, also geometric-only vs geometric + photometric against the
            desired view (``geo_*``, ``photo_*``).
        sheet: with ``compensation``, a list that receives a contact-sheet row (``closedloop.sheet_row``)
            for each of the first ``SHEET_ROWS`` samples: the first method's pictures.
        progress: called ``(done, total)`` once the inputs are checked (``done`` 0), then after each sample.
        track: tracking mode on a sequence dataset (module docstring).
        batch_size: > 1: each model's network runs on this many samples per call (pairs of one size
            batched, :class:`BatchedFlows`); a model's ``ms_per_pair`` then counts its share of the
            batch's network call.

    Returns:
        The report: ``{"dataset": {...}, "reference_model": str | None, "results": [...]}``, one
        result per method (see docs/cli/projreg.md).
    """
    data = Path(data)
    _check_options(refine, batch_size, track, compensation, photometric)
    try:
        reader = ShardReader(data)
    except ProjsynthError as e:
        raise ProjregError(f"--data {data}: {e}") from e
    try:
        indices = _bench_indices(reader, data, track, limit)
        run = ModelRun(refine, device, precision, backend, fast, track, batch_size)
        methods, reference = resolve_methods(models, baselines, run, equalize)
        methods += list(extra_methods)
        if not methods:
            raise ProjregError("nothing to benchmark: no --model, no shipped reference model and --baselines none")
        names = [m.name for m in methods]
        if len(set(names)) < len(names):
            raise ProjregError(f"method names must be unique, got {', '.join(names)}")
        scores = [_Scores(track) for _ in methods]
        loop, uncompensated = (ClosedLoop(data, photometric), _Scores()) if compensation else (None, None)
        first = _read(reader, indices[0])
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
            flows = _score_sample(methods, scores, s, k, shares, track)
            if loop is not None:
                comp = loop.score(k, s, flows)
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
    return {
        "dataset": _dataset_info(reader, data, len(indices)),
        "reference_model": None if reference is None else str(reference),
        "results": results,
        "versus_baselines": versus_baselines(results),
    }


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
) -> dict[str, np.ndarray]:
    """Every method's flow for sample ``s`` (index ``k``), timed and scored; the flows with the pixels a
    method does not claim set to NaN (the compensation honours what a method claims)."""
    groups = sample_groups(s["params"])
    sid = str(s["params"].get("sample_id", k))
    if track and s["params"].get("frame", 0) == 0:  # a sequence starts: the trackers forget
        for m in methods:
            if m.tracker is not None:
                m.tracker.reset()
    flows = {}
    for m, sc in zip(methods, scores, strict=True):
        t0 = time.perf_counter()
        pred = as_prediction(register_any_size(m.predict, s["projected"], s["captured"]))
        sc.ms.append(1000 * (time.perf_counter() - t0) + shares.get(m.name, 0.0))
        sc.add(pred, s["flow"], s["valid"], groups, sid, str(s["params"].get("sequence", "")))
        flows[m.name] = pred.flow if pred.claimed is None else np.where(pred.claimed[..., None], pred.flow, np.nan)
    return flows


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


def versus_baselines(results: Sequence[dict], ratio_limit: float = RATIO_LIMIT) -> dict[str, dict]:
    """Each model against the best baseline *of each pair* (issue 16's targets), keyed by model name.

    Per pair, the best baseline is the one with the lowest EPE on the pixels it claims (a baseline
    that claims nothing on a pair, such as a failed ``sift-ransac``, does not compete there). A
    model's ratio on a pair is its EPE on the pixels it claims over that best EPE; pairs where it
    claims nothing (not registered) have no ratio. Returns, per model: ``baselines`` compared,
    ``pairs`` (with a baseline answer), ``rated`` (pairs with a ratio), ``worst_ratio`` and
    ``worst_ratio_id``, ``within`` (share of rated pairs with ratio <= ``ratio_limit``), ``claimed_mean``
    (mean per-pair share of valid pixels claimed, 0 for pairs claiming nothing), ``mean_pair_epe``
    (mean per-pair EPE on all valid pixels, claimed or not) and ``best_baseline`` /
    ``best_baseline_mean_pair_epe`` (the baseline with the lowest such mean). Empty without baselines.
    """
    base = [r for r in results if r["kind"] == "baseline"]
    if not base:
        return {}
    means = {r["name"]: _mean([p["epe"] for p in r["pairs"]]) for r in base}
    best_name = min(means, key=lambda n: math.inf if means[n] is None else means[n])
    out = {}
    for r in (r for r in results if r["kind"] == "model"):
        ratios, claims, epes, paired = [], [], [], 0
        for i, p in enumerate(r["pairs"]):
            best = [b["pairs"][i]["epe_claimed"] for b in base if b["pairs"][i]["epe_claimed"] is not None]
            if p["epe"] is None or not best:
                continue
            paired += 1
            claims.append(p["claimed"] or 0.0)
            epes.append(p["epe"])
            if p["epe_claimed"] is not None:
                ratios.append((p["epe_claimed"] / max(min(best), 1e-6), p["id"]))
        worst = max(ratios, default=(None, None))
        out[r["name"]] = {
            "baselines": [b["name"] for b in base],
            "pairs": paired,
            "rated": len(ratios),
            "worst_ratio": worst[0],
            "worst_ratio_id": worst[1],
            "within": _mean([float(q <= ratio_limit) for q, _ in ratios]),
            "claimed_mean": _mean(claims),
            "mean_pair_epe": _mean(epes),
            "best_baseline": best_name,
            "best_baseline_mean_pair_epe": means[best_name],
        }
    return out


def _mean(values: Sequence[float]) -> float | None:
    return float(np.mean(values)) if len(values) else None


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


def parse_threshold(spec: str) -> tuple[str, float, str | None]:
    """``"[NAME:]METRIC=VALUE"`` -> ``(metric, value, name)``; METRIC one of ``GATED``; without NAME
    the threshold gates every model (``name`` None).

    Example:
        >>> parse_threshold("s40+=12.5")
        ('s40+', 12.5, None)
        >>> parse_threshold("reference-raw:epe=9")
        ('epe', 9.0, 'reference-raw')
    """
    target, sep, text = spec.partition("=")
    name, colon, metric = target.rpartition(":")
    metric, name = metric.strip(), name.strip() if colon else None
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not sep or metric not in GATED or not math.isfinite(value):
        raise ProjregError(
            f"--fail-above: expected [NAME:]METRIC=VALUE with METRIC in {', '.join(GATED)} and a "
            f"finite VALUE, got {spec!r}"
        )
    if name == "":
        raise ProjregError(f"--fail-above: empty method name before ':' in {spec!r}")
    return metric, value, name


def check_thresholds(report: dict, thresholds: Sequence[tuple[str, float, str | None]]) -> list[str]:
    """One line per model result whose metric exceeds its threshold (baselines are never gated).

    A threshold with a name gates only that model, and naming a model the report lacks is an error.
    A metric that is null (no pixel behind it) passes. Gating a report without any model result
    is an error: the gate would pass without testing anything.
    """
    models = [r for r in report["results"] if r["kind"] == "model"]
    if thresholds and not models:
        raise ProjregError("--fail-above: no model was benchmarked (no --model and no shipped reference model)")
    names = {r["name"] for r in models}
    for _, _, name in thresholds:
        if name is not None and name not in names:
            raise ProjregError(
                f"--fail-above: no model named {name!r} in the report; models: {', '.join(sorted(names))}"
            )
    return [
        f"{r['name']}: {metric} {r[metric]:.4f} > {limit:g}"
        for r in models
        for metric, limit, name in thresholds
        if name in (None, r["name"]) and r[metric] is not None and r[metric] > limit
    ]


def _fmt(value: float | None, scale: float = 1.0, digits: int = 2) -> str:
    return "–" if value is None else f"{scale * value:.{digits}f}"


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows])


def compact_table(report: dict) -> str:
    """One row per method: EPE, buckets, outlier rates in percent, ms per pair (and, with compensation,
    its PSNR and SSIM beside the EPE: where the two rankings disagree is what EPE cannot see; in
    tracking mode, the temporal jitter)."""
    comp = any("comp_psnr" in r for r in report["results"])
    jitter = any("jitter" in r for r in report["results"])
    header = ["method", "kind", "EPE", *BUCKETS, *(f"px{t} %" for t in THRESHOLDS), "ms/pair"]
    header += ["comp PSNR dB", "comp SSIM"] if comp else []
    header += ["jitter"] if jitter else []
    rows = [
        [
            r["name"],
            r["kind"],
            *(_fmt(r[k]) for k in ("epe", *BUCKETS)),
            *(_fmt(r[f"px{t}"], 100) for t in THRESHOLDS),
            _fmt(r["ms_per_pair"]),
        ]
        + ([_fmt(r.get("comp_psnr")), _fmt(r.get("comp_ssim"), digits=3)] if comp else [])
        + ([_fmt(r.get("jitter"), digits=3)] if jitter else [])
        for r in report["results"]
    ]
    return _table(header, rows)


def worst_case_table(report: dict) -> str:
    """One row per method: pooled EPE beside the per-pair distribution, then what it claims."""
    header = [
        "method",
        "EPE",
        "pair median",
        "pair p90",
        "worst pair",
        "worst id",
        "claimed %",
        "EPE claimed",
        "not registered",
    ]
    rows = [
        [
            r["name"],
            _fmt(r["epe"]),
            _fmt(r["pair_median"]),
            _fmt(r["pair_p90"]),
            _fmt(r["worst_epe"]),
            str(r["worst_id"]) if r["worst_id"] is not None else "–",
            _fmt(r["claimed"], 100),
            _fmt(r["epe_claimed"]),
            str(len(r["unregistered"])),
        ]
        for r in report["results"]
    ]
    return _table(header, rows)


def versus_table(report: dict) -> str:
    """One row per model: the pair-by-pair comparison with the best baseline (``versus_baselines``)."""
    header = [
        "model",
        "pairs rated",
        f"within {RATIO_LIMIT:g}x %",
        "worst ratio",
        "worst ratio id",
        "claimed %",
        "mean pair EPE",
        "best baseline",
        "its mean pair EPE",
    ]
    rows = [
        [
            name,
            f"{v['rated']} / {v['pairs']}",
            _fmt(v["within"], 100),
            _fmt(v["worst_ratio"]),
            str(v["worst_ratio_id"]) if v["worst_ratio_id"] is not None else "–",
            _fmt(v["claimed_mean"], 100),
            _fmt(v["mean_pair_epe"]),
            v["best_baseline"],
            _fmt(v["best_baseline_mean_pair_epe"]),
        ]
        for name, v in report["versus_baselines"].items()
    ]
    return _table(header, rows)


def to_markdown(report: dict) -> str:
    """The paper's Table 2 (method x metric rows, ``pair P / role`` columns + all), then ``compact_table``,
    ``worst_case_table`` and, with baselines and models, ``versus_table``."""
    ds = report["dataset"]
    flows = [r for r in report["results"] if r["kind"] != "none"]  # the uncompensated row has no flow
    columns = list(dict.fromkeys(k for r in flows for k in r["groups"]["pair_role"]))
    rows = [
        [r["name"], label, *(_fmt(r["groups"]["pair_role"].get(c, {}).get(key)) for c in columns), _fmt(r[key])]
        for r in flows
        for label, key in TABLE_METRICS
    ]
    size = "x".join(str(v) for v in ds["size"]) if ds["size"] else "?"
    ref = report["reference_model"]
    lines = [
        f"# projreg bench: {ds['path']}",
        "",
        f"{ds['evaluated']} of {ds['num_samples']} samples, {size}, split {ds['split']}, seed {ds['seed']}, "
        f"config {str(ds['config_hash'])[:12]}; reference model: {ref if ref else 'none'}.",
        "",
        _table(["method", "metric", *columns, "all"], rows),
        "",
        compact_table(report),
        "",
        "Per pair (EPE of each pair's valid pixels) and on the pixels each method claims:",
        "",
        worst_case_table(report),
        "",
    ]
    if report["versus_baselines"]:
        lines += ["Each model against the best baseline of each pair:", "", versus_table(report), ""]
    return "\n".join(lines)


def write_outputs(
    report: dict, *, json_path: Path | None, markdown_path: Path | None, sheet: tuple[Path, list] | None = None
) -> None:
    """The report as JSON and/or Markdown (and a contact sheet ``(path, rows)``), all or nothing (one
    unwritable path leaves none)."""
    files = [(Path(json_path), (json.dumps(report, indent=1) + "\n").encode())] if json_path else []
    if markdown_path:
        files.append((Path(markdown_path), to_markdown(report).encode()))
    if sheet is not None and sheet[1]:
        rows = sheet[1]
        picture = np.vstack([sheet_header(rows[0].shape[1] // 5), *rows])
        files.append((Path(sheet[0]), png_bytes(Path(sheet[0]), picture)))
    try:
        write_atomic_all(files, make_parents=True)
    except ProjsynthError as e:
        raise ProjregError(str(e)) from e
